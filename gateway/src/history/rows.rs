//! What each event writes: its rows and the subject's state row, in the writer's
//! transaction. The figures' columns come from the catalogue (`super::figures`);
//! what a bite row keeps beside them (its channel, second period, quality, the wear
//! reference, what it put into the gap pool) is listed here.

use std::sync::OnceLock;

use rusqlite::types::Value as SqlValue;
use rusqlite::{params, Transaction};

use super::bite_row::{CONTEXT_COLUMNS, OWN_COLUMNS};
use super::context_columns::{
    context_values, evidence_context_columns, evidence_context_values, real,
};
use super::figures::{bite_columns, to_sql, upsert_state};
use super::run::{insert_settings, DrivelineSettings};
use crate::state::events::{
    AlarmRecord, BiteRecord, ChatterWindow, HistoryEvent, StateRecord, SubjectResults,
};

/// Insert one event as the writer does (its rows, its state row) in `transaction`
/// under the run `run_id`; bulk loads (the year fixture, `examples/history_year.rs`)
/// call it in transactions of their own.
pub fn insert(
    transaction: &Transaction<'_>,
    run_id: i64,
    event: &HistoryEvent,
) -> rusqlite::Result<()> {
    match event {
        HistoryEvent::Bite(bite) => insert_bite(transaction, run_id, bite).map(drop),
        HistoryEvent::CapturedBite(bite, capture) => {
            let bite_id = insert_bite(transaction, run_id, bite)?;
            super::captures::insert_of_bite(transaction, run_id, capture, bite_id)
        }
        HistoryEvent::Capture(capture) => super::captures::insert(transaction, run_id, capture),
        HistoryEvent::Alarm(alarm) => insert_alarm(transaction, run_id, alarm),
        HistoryEvent::State(state) => insert_state(transaction, state),
        HistoryEvent::WearReset {
            time,
            driveline,
            origin,
        } => {
            transaction
                .prepare_cached(
                    "INSERT INTO wear_estimates (run_id, driveline, time, event, origin, peer)
                     VALUES (?1, ?2, ?3, 'reset', ?4, ?5)",
                )?
                .execute(params![
                    run_id,
                    driveline,
                    time.to_string(),
                    origin.name(),
                    origin.peer().map(|peer| peer.to_string())
                ])?;
            // The trend starts again with the next bite.
            transaction
                .prepare_cached("UPDATE driveline_state SET gap_trend = NULL WHERE driveline = ?1")?
                .execute(params![driveline])?;
            Ok(())
        }
        HistoryEvent::Settings { time, drivelines } => {
            let settings: Vec<_> = drivelines.iter().map(DrivelineSettings::of).collect();
            insert_settings(transaction, run_id, &time.to_string(), &settings)
        }
        HistoryEvent::FatigueReset(reset) => {
            transaction
                .prepare_cached(
                    "INSERT INTO fatigue_resets (run_id, time, driveline, component_index,
                         component, life_used, origin, peer)
                     VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                )?
                .execute(params![
                    run_id,
                    reset.time.to_string(),
                    reset.driveline,
                    i64::try_from(reset.index).unwrap_or(i64::MAX),
                    reset.component,
                    reset.life_used,
                    reset.origin.name(),
                    reset.origin.peer().map(|peer| peer.to_string())
                ])?;
            Ok(())
        }
        HistoryEvent::FatigueLedger { driveline, saved } => {
            save_fatigue_ledger(transaction, driveline, saved)
        }
        HistoryEvent::ChatterStarted { .. }
        | HistoryEvent::ChatterWindow { .. }
        | HistoryEvent::ChatterEnded { .. } => insert_chatter(transaction, run_id, event),
        HistoryEvent::OutageStarted { .. }
        | HistoryEvent::OutageWorse { .. }
        | HistoryEvent::OutageEnded { .. } => insert_outage(transaction, run_id, event),
    }
}

/// A chatter episode's start, window or end.
fn insert_chatter(
    transaction: &Transaction<'_>,
    run_id: i64,
    event: &HistoryEvent,
) -> rusqlite::Result<()> {
    match event {
        HistoryEvent::ChatterStarted {
            time,
            mill,
            window,
            context,
            thresholds_group,
        } => {
            let mut values = vec![
                thresholds_group
                    .as_ref()
                    .map_or(SqlValue::Null, |name| SqlValue::Text(name.clone())),
                SqlValue::Integer(run_id),
                SqlValue::Text(mill.clone()),
                SqlValue::Text(time.to_string()),
                SqlValue::Real(window.sigma_n_hz),
                SqlValue::Real(window.k_mean),
                real(window.frequency_hz),
                SqlValue::Integer(window.synchronized.into()),
            ];
            values.extend(evidence_context_values(context.as_ref()));
            let placeholders: Vec<String> = (1..=values.len()).map(|i| format!("?{i}")).collect();
            transaction
                .prepare_cached(&format!(
                    "INSERT INTO chatter_episodes (thresholds_group, run_id, mill, started_at,
                         min_sigma_n_hz, max_k_mean, frequency_hz, alarm, {}, windows)
                     VALUES ({}, 1)",
                    evidence_context_columns(),
                    placeholders.join(", ")
                ))?
                .execute(rusqlite::params_from_iter(values))?;
            Ok(())
        }
        HistoryEvent::ChatterWindow { mill, window } => chatter_window(transaction, mill, window),
        HistoryEvent::ChatterEnded {
            time,
            mill,
            ended_by,
        } => {
            transaction
                .prepare_cached(
                    "UPDATE chatter_episodes SET ended_at = ?2, ended_by = ?3
                 WHERE mill = ?1 AND ended_at IS NULL",
                )?
                .execute(params![mill, time.to_string(), ended_by.name()])?;
            Ok(())
        }
        _ => Ok(()),
    }
}

/// A source outage's start, worsening or end.
fn insert_outage(
    transaction: &Transaction<'_>,
    run_id: i64,
    event: &HistoryEvent,
) -> rusqlite::Result<()> {
    match event {
        HistoryEvent::OutageStarted {
            time,
            source,
            status,
        } => {
            transaction
            .prepare_cached(
                "INSERT INTO source_outages (run_id, source, started_at, worst_status, blocks_missed)
                 VALUES (?1, ?2, ?3, ?4, 0)",
            )?
            .execute(params![run_id, source, time.to_string(), status])?;
            Ok(())
        }
        HistoryEvent::OutageWorse { source } => {
            transaction
                .prepare_cached(
                    "UPDATE source_outages SET worst_status = 'lost'
                 WHERE source = ?1 AND ended_at IS NULL",
                )?
                .execute([source])?;
            Ok(())
        }
        HistoryEvent::OutageEnded {
            time,
            source,
            blocks_missed,
            ended_by,
        } => {
            transaction
                .prepare_cached(
                    "UPDATE source_outages SET ended_at = ?2, ended_by = ?3, blocks_missed = ?4
                 WHERE source = ?1 AND ended_at IS NULL",
                )?
                .execute(params![
                    source,
                    time.to_string(),
                    ended_by.name(),
                    i64::try_from(*blocks_missed).unwrap_or(i64::MAX)
                ])?;
            Ok(())
        }
        _ => Ok(()),
    }
}

fn chatter_window(
    transaction: &Transaction<'_>,
    mill: &str,
    window: &ChatterWindow,
) -> rusqlite::Result<()> {
    transaction
        .prepare_cached(
            "UPDATE chatter_episodes SET windows = windows + 1,
                 min_sigma_n_hz = min(coalesce(min_sigma_n_hz, ?2), ?2),
                 max_k_mean = max(coalesce(max_k_mean, ?3), ?3),
                 frequency_hz = coalesce(?4, frequency_hz),
                 alarm = max(alarm, ?5)
             WHERE mill = ?1 AND ended_at IS NULL",
        )?
        .execute(params![
            mill,
            window.sigma_n_hz,
            window.k_mean,
            window.frequency_hz,
            window.synchronized
        ])?;
    Ok(())
}

/// The columns of a bite row beside the catalogue's figures, in the order
/// [`bite_facts`] gives their values: the row's own (as read back), what the bite
/// put into the gap pool, which a restart pools again, and its process context.
const BITE_FACTS: [&str; 15] = [
    OWN_COLUMNS[0],
    OWN_COLUMNS[1],
    OWN_COLUMNS[2],
    OWN_COLUMNS[3],
    OWN_COLUMNS[4],
    OWN_COLUMNS[5],
    OWN_COLUMNS[6],
    "gap_taf_sigma",
    "gap_period_shift_sigma_s",
    CONTEXT_COLUMNS[0],
    CONTEXT_COLUMNS[1],
    CONTEXT_COLUMNS[2],
    CONTEXT_COLUMNS[3],
    CONTEXT_COLUMNS[4],
    CONTEXT_COLUMNS[5],
];

fn bite_facts(run_id: i64, bite: &BiteRecord) -> Vec<SqlValue> {
    let context = bite.context.unwrap_or_default();
    vec![
        SqlValue::Integer(run_id),
        SqlValue::Text(bite.driveline.clone()),
        SqlValue::Text(bite.channel.clone()),
        real(bite.second_period_s),
        SqlValue::Text(bite.quality.to_owned()),
        real(bite.reference_taf),
        real(bite.shift_over_linear_s),
        real(bite.pooled.map(|p| p.taf_sigma)),
        real(bite.pooled.map(|p| p.period_shift_sigma_s)),
    ]
    .into_iter()
    .chain(context_values(&context))
    .collect()
}

/// The statement that inserts a bite's row: its facts and the catalogue's bite
/// columns. Built once (the writer runs it for every bite, and its text is the key of
/// the connection's statement cache).
fn insert_bite_sql() -> &'static str {
    static SQL: OnceLock<String> = OnceLock::new();
    SQL.get_or_init(|| {
        let columns: Vec<&str> = BITE_FACTS
            .into_iter()
            .chain(bite_columns().map(|(_, column)| column))
            .collect();
        let placeholders: Vec<String> = (1..=columns.len()).map(|i| format!("?{i}")).collect();
        format!(
            "INSERT INTO bites ({}) VALUES ({})",
            columns.join(", "),
            placeholders.join(", ")
        )
    })
}

/// The bite's row (its figures by the catalogue's bite columns), its wear estimate
/// when it has wear measures, and its driveline's state row; the row's id.
fn insert_bite(
    transaction: &Transaction<'_>,
    run_id: i64,
    bite: &BiteRecord,
) -> rusqlite::Result<i64> {
    let mut values = bite_facts(run_id, bite);
    values.extend(bite_columns().map(|(figure, _)| to_sql(figure.value(&bite.figures))));
    transaction
        .prepare_cached(insert_bite_sql())?
        .execute(rusqlite::params_from_iter(values))?;
    let bite_id = transaction.last_insert_rowid();
    for (index, component) in bite.state.fatigue_components.iter().enumerate() {
        transaction
            .prepare_cached(
                "INSERT INTO fatigue_bites (bite_id, component_index, component, damage, life_used)
                 VALUES (?1, ?2, ?3, ?4, ?5)",
            )?
            .execute(params![
                bite_id,
                i64::try_from(index).unwrap_or(i64::MAX),
                component.name,
                component.figures.bite_damage,
                component.figures.life_used
            ])?;
    }
    let time = bite.time.to_string();
    let state = &bite.state;
    let gap = bite.figures.gap.filter(|_| bite.gap_state.is_some());
    if state.wear_index.is_some() || gap.is_some() {
        transaction
            .prepare_cached(
                "INSERT INTO wear_estimates (run_id, driveline, time, event, origin,
                     wear_index, wear_trend, reference_taf, reference_level_knm,
                     shift_over_linear_s, gap_mrad, gap_low_mrad, gap_high_mrad, gap_coupling,
                     bites_pooled, state, alarm_latched)
                 VALUES (?1, ?2, ?3, 'bite', 'analysis', ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12,
                     ?13, ?14, ?15)",
            )?
            .execute(params![
                run_id,
                bite.driveline,
                time,
                state.wear_index,
                state.wear_trend,
                bite.reference_taf,
                bite.reference_level_knm,
                bite.shift_over_linear_s,
                gap.map(|g| g.gap_mrad),
                gap.map(|g| g.low_mrad),
                gap.map(|g| g.high_mrad),
                gap.and_then(|g| g.coupling)
                    .and_then(|c| i64::try_from(c).ok()),
                gap.and_then(|g| i64::try_from(g.bites_pooled).ok()),
                bite.gap_state.map(|state| state.name()),
                gap.map(|_| state.gap_alarm),
            ])?;
    }
    upsert_state(transaction, &bite.driveline, bite.time, state)?;
    if let Some(trend) = &bite.gap_trend {
        transaction
            .prepare_cached("UPDATE driveline_state SET gap_trend = ?2 WHERE driveline = ?1")?
            .execute(params![bite.driveline, trend])?;
    }
    if let Some(saved) = &bite.fatigue_ledger {
        save_fatigue_ledger(transaction, &bite.driveline, saved)?;
    }
    Ok(bite_id)
}

/// The fatigue ledger's saved form into `driveline`'s state row (written before it).
fn save_fatigue_ledger(
    transaction: &Transaction<'_>,
    driveline: &str,
    saved: &str,
) -> rusqlite::Result<()> {
    transaction
        .prepare_cached("UPDATE driveline_state SET fatigue_ledger = ?2 WHERE driveline = ?1")?
        .execute(params![driveline, saved])?;
    Ok(())
}

/// The alarm's row (the subject's state after it comes as its own event).
fn insert_alarm(
    transaction: &Transaction<'_>,
    run_id: i64,
    alarm: &AlarmRecord,
) -> rusqlite::Result<()> {
    let origin = alarm.origin.map_or("analysis", |origin| origin.name());
    let peer = alarm
        .origin
        .and_then(|origin| origin.peer())
        .map(|peer| peer.to_string());
    transaction
        .prepare_cached(
            "INSERT INTO alarms (run_id, time, subject, kind, event, origin, peer, value, threshold)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
        )?
        .execute(params![
            run_id,
            alarm.time.to_string(),
            alarm.subject,
            alarm.kind.name(),
            alarm.event.name(),
            origin,
            peer,
            alarm.value,
            alarm.threshold
        ])?;
    Ok(())
}

/// The subject's state row.
fn insert_state(transaction: &Transaction<'_>, state: &StateRecord) -> rusqlite::Result<()> {
    match &state.results {
        SubjectResults::Driveline(results) => {
            upsert_state(transaction, &state.subject, state.time, results.as_ref())
        }
        SubjectResults::TandemMill(results) => {
            upsert_state(transaction, &state.subject, state.time, results.as_ref())
        }
    }
}

#[cfg(test)]
mod tests {
    use rusqlite::Connection;

    use super::*;
    use crate::history::query::{
        CaptureRow, ChatterRow, Filter, HistoryReader, Record, StoredCoil,
    };
    use crate::state::captures::CaptureKind;
    use crate::state::context::{
        Coil, ContextError, ContextReading, MillState, ProcessContext, StaleTags,
    };
    use crate::testing::{capture_without_samples, chatter_started, history_file};
    use millgate_config::text::AsciiText;

    /// Captures and chatter episodes keep the trusted values of their context and
    /// say how far it could be trusted: a valid one its values, a stale tag's value
    /// none (the others kept), an invalid context none at all; a product filter
    /// finds them by their product.
    #[test]
    fn evidence_keeps_only_the_context_the_gateway_trusts_and_says_why() {
        let (folder, path, mut connection) = history_file("evidence-context");
        let rolled = ProcessContext {
            weld: Some(false),
            speed_mpm: Some(1200.0),
            coil: Some(Coil::Number(4_000_000_123)),
            product: Some(205),
            thickness_mm: Some(0.25),
            pass: Some(3),
            state: Some(MillState::Rolling),
        };
        let valid = ContextReading {
            context: Ok(rolled),
            stale: StaleTags::default(),
        };
        let mut coil_stale = StaleTags::default();
        coil_stale.insert("coil");
        let stale = ContextReading {
            context: Ok(ProcessContext {
                coil: None,
                ..rolled
            }),
            stale: coil_stale,
        };
        let invalid = ContextReading {
            context: Err(ContextError::Speed(-3.0)),
            stale: StaleTags::default(),
        };
        // A text coil (`type = "ascii"`) is kept as TEXT in the same column.
        let text = ContextReading {
            context: Ok(ProcessContext {
                coil: AsciiText::new("CH-4711").map(Coil::Text),
                ..rolled
            }),
            stale: StaleTags::default(),
        };
        let transaction = connection.transaction().unwrap();
        for (subject, context) in [
            ("A", Some(valid)),
            ("B", Some(stale)),
            ("C", Some(invalid)),
            ("D", None),
            ("E", Some(text)),
        ] {
            insert(
                &transaction,
                1,
                &HistoryEvent::Capture(Box::new(capture_without_samples(
                    CaptureKind::Chatter,
                    subject,
                    context,
                ))),
            )
            .unwrap();
            insert(&transaction, 1, &chatter_started(subject, context, None)).unwrap();
        }
        transaction.commit().unwrap();
        let reader = HistoryReader::open(&path).unwrap();
        let captures: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
        let episodes: Vec<ChatterRow> = reader.rows(&Filter::default()).unwrap();
        let json: Vec<serde_json::Value> = captures
            .iter()
            .map(|row| serde_json::to_value(row).unwrap())
            .chain(
                episodes
                    .iter()
                    .map(|row| serde_json::to_value(row).unwrap()),
            )
            .collect();
        let keys = [
            "coil",
            "product",
            "speed_mpm",
            "thickness_mm",
            "pass",
            "mill_state",
            "context_status",
            "context_note",
        ];
        let expected = [
            serde_json::json!([
                4_000_000_123u32,
                205,
                1200.0,
                0.25,
                3,
                "rolling",
                "valid",
                null
            ]),
            serde_json::json!([
                null,
                205,
                1200.0,
                0.25,
                3,
                "rolling",
                "stale",
                "no fresh value of coil (source stale or tag not delivered)"
            ]),
            serde_json::json!([
                null,
                null,
                null,
                null,
                null,
                null,
                "invalid",
                "speed_mpm -3 is not allowed (must be >= 0 m/min)"
            ]),
            serde_json::json!([null, null, null, null, null, null, null, null]),
            serde_json::json!(["CH-4711", 205, 1200.0, 0.25, 3, "rolling", "valid", null]),
        ];
        for (index, row) in json.iter().enumerate() {
            let got = serde_json::Value::Array(keys.iter().map(|k| row[*k].clone()).collect());
            assert_eq!(got, expected[index % 5], "{row}");
        }
        // A number stays a number, a text is a text, as read back.
        let coils: Vec<_> = captures.iter().map(|row| row.coil.clone()).collect();
        assert_eq!(coils[0], Some(StoredCoil::Number(4_000_000_123)));
        assert_eq!(coils[4], Some(StoredCoil::Text("CH-4711".to_owned())));
        let of_product = Filter {
            product: Some(205),
            ..Filter::default()
        };
        let subjects =
            |rows: Vec<CaptureRow>| rows.into_iter().map(|r| r.subject).collect::<Vec<_>>();
        assert_eq!(subjects(reader.rows(&of_product).unwrap()), ["A", "B", "E"]);
        let mills: Vec<String> = reader
            .rows::<ChatterRow>(&of_product)
            .unwrap()
            .into_iter()
            .map(|r| r.mill)
            .collect();
        assert_eq!(mills, ["A", "B", "E"]);
        // A numeric coil is found by its digits; a stale or invalid context's is unknown.
        let of_coil = Filter {
            coil: Some("4000000123".to_owned()),
            ..Filter::default()
        };
        assert_eq!(subjects(reader.rows(&of_coil).unwrap()), ["A"]);
        assert!(CaptureRow::columns().contains(&"context_status"));
        drop((reader, connection));
        let _ = std::fs::remove_dir_all(&folder);
    }

    /// A text coil that SQLite's INTEGER affinity would have turned into a number
    /// (leading zeros, an exponent, a point, spaces) is kept as written in captures and
    /// chatter episodes (bites write the same columns: `coil_text_e2e`), and
    /// `CAST(coil AS TEXT)` gives it to a reader of the file; a text coil stored as a real before this (SQLite's conversion) reads
    /// back as that real's digits instead of failing its row.
    #[test]
    fn text_coils_that_look_like_numbers_read_back_as_written() {
        let (folder, path, mut connection) = history_file("coil-text");
        let coils = [
            "04711", " 42", "12.5", "24E0123", "1e400", "-7", "CH-4711", "H-12",
        ];
        let transaction = connection.transaction().unwrap();
        for coil in coils {
            let context = ContextReading {
                context: Ok(ProcessContext {
                    coil: AsciiText::new(coil).map(Coil::Text),
                    ..ProcessContext::default()
                }),
                stale: StaleTags::default(),
            };
            insert(
                &transaction,
                1,
                &HistoryEvent::Capture(Box::new(capture_without_samples(
                    CaptureKind::Chatter,
                    coil,
                    Some(context),
                ))),
            )
            .unwrap();
            insert(&transaction, 1, &chatter_started(coil, Some(context), None)).unwrap();
        }
        transaction.commit().unwrap();
        let reader = HistoryReader::open(&path).unwrap();
        // Found by the coil as written: `04711` is not `4711`.
        let of_coil = |coil: &str| Filter {
            coil: Some(coil.to_owned()),
            ..Filter::default()
        };
        for (coil, subjects) in [
            ("04711", vec!["04711"]),
            ("4711", vec![]),
            (" 42", vec![" 42"]),
        ] {
            let found: Vec<CaptureRow> = reader.rows(&of_coil(coil)).unwrap();
            let found: Vec<String> = found.into_iter().map(|r| r.subject).collect();
            assert_eq!(found, subjects, "captures of coil {coil:?}");
            let found: Vec<ChatterRow> = reader.rows(&of_coil(coil)).unwrap();
            let found: Vec<String> = found.into_iter().map(|r| r.mill).collect();
            assert_eq!(found, subjects, "chatter episodes of coil {coil:?}");
        }
        let texts = |stored: Vec<Option<StoredCoil>>| -> Vec<String> {
            stored.into_iter().map(|c| c.unwrap().to_string()).collect()
        };
        let captures: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
        let episodes: Vec<ChatterRow> = reader.rows(&Filter::default()).unwrap();
        assert_eq!(texts(captures.into_iter().map(|r| r.coil).collect()), coils);
        assert_eq!(texts(episodes.into_iter().map(|r| r.coil).collect()), coils);
        for table in ["captures", "chatter_episodes"] {
            let stored: Vec<(String, String)> = connection
                .prepare(&format!(
                    "SELECT typeof(coil), CAST(coil AS TEXT) FROM {table} ORDER BY id"
                ))
                .unwrap()
                .query_map([], |row| Ok((row.get(0)?, row.get(1)?)))
                .unwrap()
                .collect::<Result<_, _>>()
                .unwrap();
            let kinds: Vec<&str> = stored.iter().map(|(kind, _)| kind.as_str()).collect();
            assert_eq!(
                kinds,
                ["blob", "blob", "blob", "blob", "blob", "blob", "text", "text"],
                "{table}"
            );
            let as_text: Vec<&str> = stored.iter().map(|(_, text)| text.as_str()).collect();
            assert_eq!(as_text, coils, "{table}");
        }
        // What SQLite made of such a text before: a real. Read, not refused.
        connection
            .execute("UPDATE captures SET coil = 12.5 WHERE subject = '12.5'", [])
            .unwrap();
        connection
            .execute(
                "UPDATE captures SET coil = 2.4e124 WHERE subject = '24E0123'",
                [],
            )
            .unwrap();
        let captures: Vec<CaptureRow> = reader.rows(&Filter::default()).unwrap();
        let read: Vec<String> = texts(captures.into_iter().map(|r| r.coil).collect());
        assert_eq!(read[2], "12.5");
        assert_eq!(read[3], "2.4e124");
        drop((reader, connection));
        let _ = std::fs::remove_dir_all(&folder);
    }

    /// Every text SQLite's INTEGER affinity stores as a number (asked of SQLite itself,
    /// over every text of up to four characters from digits, signs, a point, exponent
    /// letters, spaces and a tab) is one `numeric_looking` protects: none is turned
    /// into a number.
    #[test]
    fn every_text_sqlite_would_turn_into_a_number_is_kept_as_written() {
        let connection = Connection::open_in_memory().unwrap();
        connection
            .execute_batch("CREATE TABLE c (coil INTEGER)")
            .unwrap();
        let alphabet = ['0', '9', '+', '-', '.', 'e', 'E', ' ', '\t', 'x'];
        let mut texts = vec![String::new()];
        let mut all = Vec::new();
        for _ in 0..4 {
            texts = texts
                .iter()
                .flat_map(|text| alphabet.iter().map(move |c| format!("{text}{c}")))
                .collect();
            all.extend(texts.iter().cloned());
        }
        let mut converted = 0;
        for text in &all {
            connection.execute("DELETE FROM c", []).unwrap();
            connection
                .execute("INSERT INTO c VALUES (?1)", [text.as_str()])
                .unwrap();
            let kind: String = connection
                .query_row("SELECT typeof(coil) FROM c", [], |row| row.get(0))
                .unwrap();
            if kind != "text" {
                converted += 1;
                assert!(
                    matches!(
                        StoredCoil::text_value(text),
                        rusqlite::types::Value::Blob(_)
                    ),
                    "{text:?} is stored by SQLite as {kind}"
                );
            }
            // What the history writes reads back as written.
            connection.execute("DELETE FROM c", []).unwrap();
            connection
                .execute("INSERT INTO c VALUES (?1)", [StoredCoil::text_value(text)])
                .unwrap();
            let read: StoredCoil = connection
                .query_row("SELECT coil FROM c", [], |row| row.get(0))
                .unwrap();
            assert_eq!(read, StoredCoil::Text(text.clone()));
        }
        assert!(converted > 100, "{converted} of {} converted", all.len());
    }
}
