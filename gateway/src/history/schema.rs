//! The history file's schema and its migrations.
//!
//! The schema version is SQLite's `PRAGMA user_version`. [`MIGRATIONS`] holds the SQL
//! of each version in order; [`migrate`] applies every step above the file's version
//! and sets the new version in one transaction, so a file is either at its old
//! version or fully at the new one. A file written by a newer millgate (a version
//! above the last step) is refused rather than guessed at. (No migration crate
//! supports rust-version 1.89 today; this table of steps is all the gateway needs.)
//!
//! Conventions: times are UTC ISO-8601 text (see [`crate::state::time`]); torques kN*m,
//! periods s, frequencies Hz, gaps mrad referred to the rolls; booleans 0/1; `NULL`
//! is "not measured". `run_id` is the gateway run ([`gateway_runs`]) that recorded a
//! row.
//!
//! [`gateway_runs`]: MIGRATIONS

use rusqlite::{Connection, TransactionBehavior};

/// The SQL of each schema version, in order: entry `i` takes a file from version `i`
/// to `i + 1`. Never edit a released step; add one.
pub const MIGRATIONS: &[&str] = &[
    // Version 1.
    r#"
CREATE TABLE gateway_runs (
    id          INTEGER PRIMARY KEY,
    started_at  TEXT NOT NULL,
    stopped_at  TEXT,            -- NULL while running; after a kill it stays NULL
    ended       TEXT,            -- 'stopped' (clean), 'unclean' (set at the next start)
    version     TEXT NOT NULL,   -- millgate version
    config_name TEXT NOT NULL
);
CREATE TABLE bites (
    id                  INTEGER PRIMARY KEY,
    run_id              INTEGER NOT NULL REFERENCES gateway_runs(id),
    driveline           TEXT NOT NULL,
    time                TEXT NOT NULL,
    bite_counter        INTEGER NOT NULL,  -- the driveline's counter after this bite
    channel             TEXT NOT NULL,
    static_torque_knm   REAL NOT NULL,
    peak_torque_knm     REAL NOT NULL,
    taf                 REAL,
    first_period_s      REAL,
    second_period_s     REAL,
    period_shift_s      REAL,
    beta1_hz            REAL,              -- eq. (1) fit, when it converged
    beta2_hz            REAL,
    quality             TEXT NOT NULL,     -- 'good', 'few_crossings', 'low_static'
    degraded            INTEGER NOT NULL,  -- the window had gaps, NaN or saturation
    wear_index          REAL,              -- TAF / linear reference TAF - 1
    wear_trend          REAL,              -- EWMA after this bite
    reference_taf       REAL,
    shift_over_linear_s REAL,
    -- The gap diagnosis, when the driveline has one (NULL before it existed).
    gap_mrad            REAL,
    gap_low_mrad        REAL,
    gap_high_mrad       REAL,
    gap_coupling        TEXT,
    bites_pooled        INTEGER
);
CREATE INDEX bites_by_driveline_time ON bites(driveline, time);
CREATE INDEX bites_by_time ON bites(time);
CREATE TABLE wear_estimates (
    id                  INTEGER PRIMARY KEY,
    run_id              INTEGER NOT NULL REFERENCES gateway_runs(id),
    driveline           TEXT NOT NULL,
    time                TEXT NOT NULL,
    event               TEXT NOT NULL,     -- 'bite' (a new estimate) or 'reset' (trend reset)
    origin              TEXT NOT NULL,     -- 'analysis', or who reset: 'hmi', 'plc', 'local'
    peer                TEXT,              -- the Modbus client that sent the reset
    wear_index          REAL,
    wear_trend          REAL,
    reference_taf       REAL,
    reference_level_knm REAL,
    shift_over_linear_s REAL,
    gap_mrad            REAL,
    gap_low_mrad        REAL,
    gap_high_mrad       REAL,
    gap_coupling        TEXT,
    bites_pooled        INTEGER,
    state               TEXT,              -- 'ok', 'warning', 'alarm' (gap diagnosis)
    alarm_latched       INTEGER
);
CREATE INDEX wear_by_driveline_time ON wear_estimates(driveline, time);
CREATE INDEX wear_by_time ON wear_estimates(time);
CREATE TABLE alarms (
    id          INTEGER PRIMARY KEY,
    run_id      INTEGER NOT NULL REFERENCES gateway_runs(id),
    time        TEXT NOT NULL,
    subject     TEXT NOT NULL,     -- the driveline or tandem mill
    kind        TEXT NOT NULL,     -- 'taf_warning', 'taf_alarm', 'chatter_alarm', 'wear_alarm' (v6: 'gap_alarm'; also 'gap_warning', 'chatter_warning')
    event       TEXT NOT NULL,     -- 'raised', 'cleared', 'acknowledged'
    origin      TEXT NOT NULL,     -- 'analysis', 'hmi', 'plc', 'local'
    peer        TEXT,              -- the Modbus client that acknowledged
    value       REAL,              -- what raised it (TAF, K_mean)
    threshold   REAL
);
CREATE INDEX alarms_by_time ON alarms(time);
CREATE TABLE chatter_episodes (
    id               INTEGER PRIMARY KEY,
    run_id           INTEGER NOT NULL REFERENCES gateway_runs(id),
    mill             TEXT NOT NULL,
    started_at       TEXT NOT NULL,
    ended_at         TEXT,             -- NULL while it lasts
    ended_by         TEXT,             -- 'analysis', 'window_restart', 'stop', 'restart'
    windows          INTEGER NOT NULL,
    min_sigma_n_hz   REAL,
    max_k_mean       REAL,
    frequency_hz     REAL,             -- chatter frequency of the last window
    alarm            INTEGER NOT NULL  -- both conditions held in a window
);
CREATE INDEX chatter_by_time ON chatter_episodes(started_at);
CREATE TABLE source_outages (
    id            INTEGER PRIMARY KEY,
    run_id        INTEGER NOT NULL REFERENCES gateway_runs(id),
    source        TEXT NOT NULL,
    started_at    TEXT NOT NULL,
    ended_at      TEXT,             -- NULL while it lasts
    ended_by      TEXT,             -- 'recovered', 'stop', 'restart'
    worst_status  TEXT NOT NULL,    -- 'stale' or 'lost'
    blocks_missed INTEGER NOT NULL  -- blocks lost on the source's channels meanwhile
);
CREATE INDEX outages_by_time ON source_outages(started_at);
-- The state a start restores, one row per driveline, updated with each event.
CREATE TABLE driveline_state (
    driveline         TEXT PRIMARY KEY,
    updated_at        TEXT NOT NULL,
    bite_counter      INTEGER NOT NULL,
    last_bite_time    TEXT,
    static_torque_knm REAL,
    peak_torque_knm   REAL,
    taf               REAL,
    period_shift_s    REAL,
    beta1_hz          REAL,
    beta2_hz          REAL,
    wear_index        REAL,
    wear_trend        REAL,
    degraded          INTEGER NOT NULL,
    warning           INTEGER NOT NULL,
    alarm_latched     INTEGER NOT NULL,
    extra             TEXT              -- JSON: further restorable state
);
-- Each run's driveline settings, for reports (thresholds, model).
CREATE TABLE driveline_settings (
    id               INTEGER PRIMARY KEY,
    run_id           INTEGER NOT NULL REFERENCES gateway_runs(id),
    time             TEXT NOT NULL,    -- the run's start
    driveline        TEXT NOT NULL,
    taf_warning      REAL NOT NULL,
    taf_alarm        REAL NOT NULL,
    model            TEXT,             -- the driveline model file, as configured
    gap_warning_mrad REAL,             -- the gap diagnosis' thresholds
    gap_alarm_mrad   REAL
);
CREATE TABLE mill_state (
    mill          TEXT PRIMARY KEY,
    updated_at    TEXT NOT NULL,
    alarm_latched INTEGER NOT NULL
);
"#,
    // Version 2: the Sparkplug B edge node's session number.
    r#"
CREATE TABLE sparkplug_node (
    node       TEXT PRIMARY KEY,  -- 'group_id/node_id'
    bd_seq     INTEGER NOT NULL,  -- the last MQTT session's bdSeq, 0..=255
    updated_at TEXT NOT NULL
);
"#,
    // Version 3: what a bite put into the gap pool (a restart pools the last ones
    // again: static_torque_knm, taf and period_shift_s are the bite's own columns),
    // and the latched gap alarm.
    r#"
ALTER TABLE bites ADD COLUMN gap_taf_sigma REAL;             -- NULL: not pooled
ALTER TABLE bites ADD COLUMN gap_period_shift_sigma_s REAL;
ALTER TABLE driveline_state ADD COLUMN gap_alarm_latched INTEGER NOT NULL DEFAULT 0;
"#,
    // Version 4: the Sparkplug store-and-forward cursor: every bite up to this
    // `bites.id` the broker has confirmed; later ones are replayed, flagged historical,
    // at the next session. NULL: not set yet (the node starts at the file's last bite).
    r#"
ALTER TABLE sparkplug_node ADD COLUMN replay_cursor INTEGER;
"#,
    // Version 5: the web page's queries on a year of bites (a million rows per
    // driveline). The bites index by driveline and time also holds what the gap and
    // TAF series aggregate, so a month or a year of one driveline is read from the
    // index alone (its entries lie together) instead of from the table pages, where
    // the drivelines' rows interleave; it serves every query the old one did. The
    // wear resets get a partial index: the last reset of a driveline was a scan of
    // all its wear estimates.
    r#"
DROP INDEX bites_by_driveline_time;
CREATE INDEX bites_by_driveline_time
    ON bites(driveline, time, degraded, taf, gap_mrad, gap_low_mrad, gap_high_mrad);
CREATE INDEX wear_resets_by_driveline_time ON wear_estimates(driveline, time)
    WHERE event = 'reset';
"#,
    // Version 6: one name and type per figure (the catalogue of published figures).
    // The coupling holding the gap is an integer (it was its decimal text), the gap
    // alarm is `gap_alarm` (it was `wear_alarm`), and the gap warning, now an alarm
    // event like the others, is kept for the restart. Every bite row is rewritten once
    // (a year of bites: about a minute on an SD card).
    r#"
ALTER TABLE bites RENAME COLUMN gap_coupling TO gap_coupling_text;
ALTER TABLE bites ADD COLUMN gap_coupling INTEGER;
UPDATE bites SET gap_coupling = CAST(gap_coupling_text AS INTEGER)
    WHERE gap_coupling_text IS NOT NULL;
ALTER TABLE bites DROP COLUMN gap_coupling_text;
ALTER TABLE wear_estimates RENAME COLUMN gap_coupling TO gap_coupling_text;
ALTER TABLE wear_estimates ADD COLUMN gap_coupling INTEGER;
UPDATE wear_estimates SET gap_coupling = CAST(gap_coupling_text AS INTEGER)
    WHERE gap_coupling_text IS NOT NULL;
ALTER TABLE wear_estimates DROP COLUMN gap_coupling_text;
UPDATE alarms SET kind = 'gap_alarm' WHERE kind = 'wear_alarm';
ALTER TABLE driveline_state ADD COLUMN gap_warning INTEGER NOT NULL DEFAULT 0;
"#,
    // Version 7: captures, the samples behind each bite, chatter episode and manual
    // request (see `captures.rs`): the row says what and when (the columns a list or a
    // retention step reads), `meta` how to read the samples (channels, units, scale,
    // gaps, the bite window's analysis settings; JSON); `capture_data` the samples
    // (deflated), in a table of their own: a list of a year of captures reads the small
    // rows only, and two blobs of a bite (~1.7 KiB) share a 4 KiB page (with the row
    // beside it, one bite's capture took a page of its own). `capture_totals` keeps
    // the count and bytes of the captures up to date through triggers, so the budget
    // check reads one row instead of summing a year of rows.
    r#"
CREATE TABLE captures (
    id                   INTEGER PRIMARY KEY,
    run_id               INTEGER NOT NULL REFERENCES gateway_runs(id),
    kind                 TEXT NOT NULL,     -- 'bite', 'chatter', 'manual'
    subject              TEXT NOT NULL,     -- the driveline, tandem mill or request name
    bite_id              INTEGER,           -- bites.id of the bite (a bite capture)
    bite_counter         INTEGER,           -- the driveline's bite counter after it
    bite_time            TEXT,              -- bites.time of the bite
    started_at           TEXT NOT NULL,     -- the first sample, UTC ISO-8601 (ms)
    first_sample_unix_ns INTEGER NOT NULL,  -- the first sample, ns since the Unix epoch
    kernel_time          INTEGER NOT NULL,  -- times from CAN kernel receive timestamps
    sample_rate_hz       REAL NOT NULL,
    samples              INTEGER NOT NULL,  -- per channel
    duration_s           REAL NOT NULL,     -- samples / sample_rate_hz
    keep                 INTEGER NOT NULL,  -- 0 ordinary bite, 1 warning, 2 alarm/chatter/manual
    meta                 TEXT NOT NULL,     -- JSON: channels, gaps, analysis settings
    bytes                INTEGER NOT NULL   -- length of its capture_data.data
);
CREATE TABLE capture_data (
    id   INTEGER PRIMARY KEY,               -- the capture's id
    data BLOB NOT NULL                      -- the samples, deflated (see meta)
);
CREATE INDEX captures_by_subject_time ON captures(subject, started_at);
CREATE INDEX captures_by_time ON captures(started_at);
CREATE INDEX captures_by_bite ON captures(bite_id);
CREATE INDEX captures_by_keep ON captures(keep, id);
CREATE INDEX captures_by_run ON captures(run_id);
CREATE TABLE capture_totals (
    id       INTEGER PRIMARY KEY CHECK (id = 1),
    captures INTEGER NOT NULL,
    bytes    INTEGER NOT NULL
);
INSERT INTO capture_totals (id, captures, bytes) VALUES (1, 0, 0);
CREATE TRIGGER captures_added AFTER INSERT ON captures BEGIN
    UPDATE capture_totals SET captures = captures + 1, bytes = bytes + new.bytes;
END;
CREATE TRIGGER captures_deleted AFTER DELETE ON captures BEGIN
    DELETE FROM capture_data WHERE id = old.id;
    UPDATE capture_totals SET captures = captures - 1, bytes = bytes - old.bytes;
END;
"#,
    // Version 8: the configuration's hash with each run (SHA-256 of its canonical
    // TOML, `millgate_config::Config::hash`), so a capture's export names the
    // configuration that produced it; NULL for runs recorded before.
    r#"
ALTER TABLE gateway_runs ADD COLUMN config_hash TEXT;
"#,
    // Version 9: the state row keeps every figure of the last bite a start restores
    // (the catalogue's state columns): the first period and the gap estimate, which
    // were read back only once the gap maps were ready to pool the last bites again.
    // NULL in a row written before: restored as no value.
    r#"
ALTER TABLE driveline_state ADD COLUMN first_period_s REAL;
ALTER TABLE driveline_state ADD COLUMN gap_mrad REAL;
ALTER TABLE driveline_state ADD COLUMN gap_low_mrad REAL;
ALTER TABLE driveline_state ADD COLUMN gap_high_mrad REAL;
ALTER TABLE driveline_state ADD COLUMN gap_coupling INTEGER;
ALTER TABLE driveline_state ADD COLUMN bites_pooled INTEGER;
"#,
    // Version 10: the first mode's damping ratio of each bite (eq. (1) fit), kept with
    // the bite and restored with the state. NULL for bites recorded before.
    r#"
ALTER TABLE bites ADD COLUMN first_mode_damping REAL;
ALTER TABLE driveline_state ADD COLUMN first_mode_damping REAL;
"#,
    // Version 11: the gap's wear trend. Each bite and the state row keep the growth
    // with its interval and the forecast of the gap alarm (gap_forecast: 0 forecast,
    // 1 at_alarm, 2 not_growing, 3 beyond_horizon, 4 too_few_bites); the state row
    // keeps the trend's saved form (JSON), which a start continues. NULL before: a
    // start without a saved trend folds the last bites since the wear reset in again.
    r#"
ALTER TABLE bites ADD COLUMN gap_growth_mrad_per_day REAL;
ALTER TABLE bites ADD COLUMN gap_growth_low_mrad_per_day REAL;
ALTER TABLE bites ADD COLUMN gap_growth_high_mrad_per_day REAL;
ALTER TABLE bites ADD COLUMN gap_forecast INTEGER;
ALTER TABLE bites ADD COLUMN days_to_gap_alarm REAL;
ALTER TABLE bites ADD COLUMN days_to_gap_alarm_low REAL;
ALTER TABLE bites ADD COLUMN days_to_gap_alarm_high REAL;
ALTER TABLE bites ADD COLUMN gap_alarm_date TEXT;
ALTER TABLE driveline_state ADD COLUMN gap_growth_mrad_per_day REAL;
ALTER TABLE driveline_state ADD COLUMN gap_growth_low_mrad_per_day REAL;
ALTER TABLE driveline_state ADD COLUMN gap_growth_high_mrad_per_day REAL;
ALTER TABLE driveline_state ADD COLUMN gap_forecast INTEGER;
ALTER TABLE driveline_state ADD COLUMN days_to_gap_alarm REAL;
ALTER TABLE driveline_state ADD COLUMN days_to_gap_alarm_low REAL;
ALTER TABLE driveline_state ADD COLUMN days_to_gap_alarm_high REAL;
ALTER TABLE driveline_state ADD COLUMN gap_alarm_date TEXT;
ALTER TABLE driveline_state ADD COLUMN gap_trend TEXT;
"#,
    // Version 12: the fatigue ledger (issue 38). Each bite and the state row keep the
    // worst component's figures (the catalogue's columns); `fatigue_bites` every
    // component's damage and life used at each bite (damage NULL: untrusted torque,
    // counted in the life all the same), deleted with its bite; the state row keeps
    // the ledger's saved form (JSON: lives, installations, days, the rainflow
    // residue), which a start continues; `fatigue_resets` who reset which component
    // when, and the life it had used.
    r#"
ALTER TABLE bites ADD COLUMN fatigue_forecast INTEGER;
ALTER TABLE bites ADD COLUMN fatigue_component INTEGER;
ALTER TABLE bites ADD COLUMN fatigue_life_used REAL;
ALTER TABLE bites ADD COLUMN fatigue_rate_per_day REAL;
ALTER TABLE bites ADD COLUMN days_to_fatigue_limit REAL;
ALTER TABLE bites ADD COLUMN fatigue_limit_date TEXT;
ALTER TABLE bites ADD COLUMN fatigue_bite_damage REAL;
ALTER TABLE driveline_state ADD COLUMN fatigue_forecast INTEGER;
ALTER TABLE driveline_state ADD COLUMN fatigue_component INTEGER;
ALTER TABLE driveline_state ADD COLUMN fatigue_life_used REAL;
ALTER TABLE driveline_state ADD COLUMN fatigue_rate_per_day REAL;
ALTER TABLE driveline_state ADD COLUMN days_to_fatigue_limit REAL;
ALTER TABLE driveline_state ADD COLUMN fatigue_limit_date TEXT;
ALTER TABLE driveline_state ADD COLUMN fatigue_bite_damage REAL;
ALTER TABLE driveline_state ADD COLUMN fatigue_ledger TEXT;
CREATE TABLE fatigue_bites (
    bite_id         INTEGER NOT NULL,  -- bites.id
    component_index INTEGER NOT NULL,  -- index in drivelines[].fatigue.components
    component       TEXT NOT NULL,
    damage          REAL,              -- since the bite before; NULL: untrusted torque
    life_used       REAL NOT NULL,     -- since the component's installation
    PRIMARY KEY (bite_id, component_index)
) WITHOUT ROWID;
CREATE TRIGGER bites_deleted_fatigue AFTER DELETE ON bites BEGIN
    DELETE FROM fatigue_bites WHERE bite_id = old.id;
END;
CREATE TABLE fatigue_resets (
    id              INTEGER PRIMARY KEY,
    run_id          INTEGER NOT NULL REFERENCES gateway_runs(id),
    time            TEXT NOT NULL,
    driveline       TEXT NOT NULL,
    component_index INTEGER NOT NULL,
    component       TEXT NOT NULL,
    life_used       REAL NOT NULL,     -- what it had used until the reset
    origin          TEXT NOT NULL,     -- plc, hmi, local, opcua, web
    peer            TEXT
);
CREATE INDEX fatigue_resets_by_driveline_time ON fatigue_resets(driveline, time);
"#,
    // Version 13: the process context (issue 39). A bite's gate (the catalogue's
    // `last_bite_gated`: 0 pooled into the wear trend, 1 not for the mill's state, 2
    // not for its speed; NULL without drivelines[].context, and for every bite before)
    // and the context it was rolled in (NULL: not read, or the context invalid).
    r#"
ALTER TABLE bites ADD COLUMN gated INTEGER;
ALTER TABLE bites ADD COLUMN speed_mpm REAL;
ALTER TABLE bites ADD COLUMN coil INTEGER;
ALTER TABLE bites ADD COLUMN product INTEGER;
ALTER TABLE bites ADD COLUMN thickness_mm REAL;
ALTER TABLE bites ADD COLUMN pass INTEGER;
ALTER TABLE bites ADD COLUMN mill_state TEXT;      -- idle, threading, rolling, maintenance
"#,
    // Version 14: the process context on the evidence (issue 39 item 3). Each capture
    // (a bite's at its bite, a chatter episode's when its warning was raised) and each
    // chatter episode (at its start) keeps the context of its time, as the bites do,
    // and how far it can be trusted: context_status 'valid', 'stale' (a configured
    // tag had no fresh value: that value NULL), 'invalid' (an impossible value: every
    // value NULL), with context_note saying why; NULL without context tags and for
    // every row before. Columns added, no row rewritten; the product indexes are
    // partial (no entry for the rows without a product, every row before).
    r#"
ALTER TABLE captures ADD COLUMN speed_mpm REAL;
ALTER TABLE captures ADD COLUMN coil INTEGER;
ALTER TABLE captures ADD COLUMN product INTEGER;
ALTER TABLE captures ADD COLUMN thickness_mm REAL;
ALTER TABLE captures ADD COLUMN pass INTEGER;
ALTER TABLE captures ADD COLUMN mill_state TEXT;   -- idle, threading, rolling, maintenance
ALTER TABLE captures ADD COLUMN context_status TEXT;  -- valid, stale, invalid
ALTER TABLE captures ADD COLUMN context_note TEXT;
CREATE INDEX captures_by_product ON captures(product, started_at) WHERE product IS NOT NULL;
ALTER TABLE chatter_episodes ADD COLUMN speed_mpm REAL;
ALTER TABLE chatter_episodes ADD COLUMN coil INTEGER;
ALTER TABLE chatter_episodes ADD COLUMN product INTEGER;
ALTER TABLE chatter_episodes ADD COLUMN thickness_mm REAL;
ALTER TABLE chatter_episodes ADD COLUMN pass INTEGER;
ALTER TABLE chatter_episodes ADD COLUMN mill_state TEXT;
ALTER TABLE chatter_episodes ADD COLUMN context_status TEXT;
ALTER TABLE chatter_episodes ADD COLUMN context_note TEXT;
CREATE INDEX chatter_by_product ON chatter_episodes(product, started_at)
    WHERE product IS NOT NULL;
"#,
    // Version 15: the thresholds that judged a chatter episode (issue 39): the name of
    // the mill's product group whose gain_thresholds were in use when its warning was
    // raised; NULL for the mill's own thresholds, and for every episode before. A column
    // added, no row rewritten.
    r#"
ALTER TABLE chatter_episodes ADD COLUMN thresholds_group TEXT;
"#,
];

/// `PRAGMA application_id` of a millgate history: the bytes "MLGT" (0x4D4C4754), set
/// on every file the gateway creates or migrates, so `file(1)` and other tools can
/// tell a history from other SQLite files, and millgate refuses another
/// application's file rather than adding its tables to it.
pub const APPLICATION_ID: i64 = 0x4D4C_4754;

/// The schema version this millgate writes.
pub fn current_version() -> i64 {
    MIGRATIONS.len() as i64
}

/// Why the schema could not be brought up to date.
#[derive(Debug, thiserror::Error)]
pub enum SchemaError {
    /// The file is at a version this millgate does not know.
    #[error(
        "the history file has schema version {found}, newer than this millgate's {known}: \
         use a newer millgate, or another file"
    )]
    TooNew {
        /// `user_version` of the file.
        found: i64,
        /// The last version this millgate knows.
        known: i64,
    },
    /// The file is an SQLite database of another application: another
    /// `application_id`, or tables and no millgate schema version.
    #[error(
        "not a millgate history: an SQLite file of another application ({}); \
         use another file",
        if *application_id == 0 {
            "tables, but no millgate schema".to_owned()
        } else {
            format!("application_id {application_id:#010x}, millgate's is {APPLICATION_ID:#010x}")
        }
    )]
    Foreign {
        /// The file's `PRAGMA application_id`.
        application_id: i64,
    },
    /// SQLite refused a step (the file is corrupt, read-only, full, ...).
    #[error("migrating the history schema: {0}")]
    Sqlite(#[from] rusqlite::Error),
}

/// Refuses a file that is not a millgate history: one whose `application_id` is
/// another application's, or (an id of 0, as before millgate set one) that has tables
/// but no `gateway_runs`. Reads only; call it before anything changes the file.
pub fn check_owner(connection: &Connection) -> Result<(), SchemaError> {
    let application_id: i64 =
        connection.pragma_query_value(None, "application_id", |row| row.get(0))?;
    if application_id == APPLICATION_ID {
        return Ok(());
    }
    if application_id != 0 {
        return Err(SchemaError::Foreign { application_id });
    }
    let (tables, runs): (i64, i64) = connection.query_row(
        "SELECT count(*), count(*) FILTER (WHERE name = 'gateway_runs')
         FROM sqlite_schema WHERE type = 'table'",
        [],
        |row| Ok((row.get(0)?, row.get(1)?)),
    )?;
    if tables > 0 && runs == 0 {
        return Err(SchemaError::Foreign { application_id });
    }
    Ok(())
}

/// Bring `connection`'s file to [`current_version`] in one transaction and mark it
/// as millgate's ([`APPLICATION_ID`]); returns the version it was at (0 for a new
/// file). Refuses another application's file ([`check_owner`]) and a newer schema.
pub fn migrate(connection: &mut Connection) -> Result<i64, SchemaError> {
    check_owner(connection)?;
    let found: i64 = connection.pragma_query_value(None, "user_version", |row| row.get(0))?;
    let known = current_version();
    if found > known {
        return Err(SchemaError::TooNew { found, known });
    }
    if found == known {
        // A file of a millgate from before the application id.
        let application_id: i64 =
            connection.pragma_query_value(None, "application_id", |row| row.get(0))?;
        if application_id != APPLICATION_ID {
            connection.pragma_update(None, "application_id", APPLICATION_ID)?;
        }
        return Ok(found);
    }
    // IMMEDIATE: take the write lock before reading anything, so two processes
    // starting on one file cannot both migrate.
    let transaction = connection.transaction_with_behavior(TransactionBehavior::Immediate)?;
    let version: i64 = transaction.pragma_query_value(None, "user_version", |row| row.get(0))?;
    for step in &MIGRATIONS[usize::try_from(version).unwrap_or(0)..] {
        transaction.execute_batch(step)?;
    }
    transaction.pragma_update(None, "user_version", known)?;
    transaction.pragma_update(None, "application_id", APPLICATION_ID)?;
    transaction.commit()?;
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_file_gets_every_table_and_the_version() {
        let mut connection = Connection::open_in_memory().unwrap();
        assert_eq!(migrate(&mut connection).unwrap(), 0);
        let version: i64 = connection
            .pragma_query_value(None, "user_version", |row| row.get(0))
            .unwrap();
        assert_eq!(version, current_version());
        let mut tables: Vec<String> = connection
            .prepare("SELECT name FROM sqlite_schema WHERE type = 'table' ORDER BY name")
            .unwrap()
            .query_map([], |row| row.get(0))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        tables.sort();
        assert_eq!(
            tables,
            [
                "alarms",
                "bites",
                "capture_data",
                "capture_totals",
                "captures",
                "chatter_episodes",
                "driveline_settings",
                "driveline_state",
                "fatigue_bites",
                "fatigue_resets",
                "gateway_runs",
                "mill_state",
                "source_outages",
                "sparkplug_node",
                "wear_estimates"
            ]
        );
        // Migrating again changes nothing.
        assert_eq!(migrate(&mut connection).unwrap(), current_version());
    }

    #[test]
    fn a_version_3_file_gains_the_replay_cursor_and_keeps_its_bd_seq() {
        let mut connection = Connection::open_in_memory().unwrap();
        for step in &MIGRATIONS[..3] {
            connection.execute_batch(step).unwrap();
        }
        connection.pragma_update(None, "user_version", 3).unwrap();
        connection
            .execute(
                "INSERT INTO sparkplug_node (node, bd_seq, updated_at) VALUES ('plant/f1', 41, 't')",
                [],
            )
            .unwrap();
        assert_eq!(migrate(&mut connection).unwrap(), 3);
        let (bd_seq, cursor): (i64, Option<i64>) = connection
            .query_row(
                "SELECT bd_seq, replay_cursor FROM sparkplug_node WHERE node = 'plant/f1'",
                [],
                |row| Ok((row.get(0)?, row.get(1)?)),
            )
            .unwrap();
        assert_eq!((bd_seq, cursor), (41, None));
        let version: i64 = connection
            .pragma_query_value(None, "user_version", |row| row.get(0))
            .unwrap();
        assert_eq!(version, current_version());
    }

    #[test]
    fn version_5_moves_a_version_4_file_to_the_web_indexes_and_keeps_its_rows() {
        let mut connection = Connection::open_in_memory().unwrap();
        for step in &MIGRATIONS[..4] {
            connection.execute_batch(step).unwrap();
        }
        connection.pragma_update(None, "user_version", 4).unwrap();
        connection
            .execute_batch(
                "INSERT INTO gateway_runs (started_at, version, config_name)
                     VALUES ('2026-01-01T00:00:00.000Z', 't', 't');
                 INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                     static_torque_knm, peak_torque_knm, quality, degraded, taf, gap_mrad)
                     VALUES (1, 'F1', '2026-01-01T00:00:01.000Z', 1, 'c', 400, 520,
                         'good', 0, 1.3, 0.5);
                 INSERT INTO wear_estimates (run_id, driveline, time, event, origin)
                     VALUES (1, 'F1', '2026-01-01T00:00:02.000Z', 'reset', 'hmi');",
            )
            .unwrap();
        assert_eq!(migrate(&mut connection).unwrap(), 4);
        let plan = |sql: &str| -> String {
            connection
                .prepare(&format!("EXPLAIN QUERY PLAN {sql}"))
                .unwrap()
                .query_map([], |row| row.get::<_, String>(3))
                .unwrap()
                .collect::<Result<Vec<_>, _>>()
                .unwrap()
                .join("; ")
        };
        // The series read the index alone; the last reset is a probe of its index.
        let series = plan(
            "SELECT count(*), min(gap_low_mrad), max(gap_high_mrad), avg(taf), max(taf),
                 max(gap_mrad) FROM bites
             WHERE driveline = 'F1' AND time >= '2026' AND time < '2027' AND degraded = 0",
        );
        assert!(
            series.contains("COVERING INDEX bites_by_driveline_time"),
            "{series}"
        );
        let reset = plan(
            "SELECT max(time) FROM wear_estimates
             WHERE driveline = 'F1' AND event = 'reset' AND time < '2027'",
        );
        assert!(reset.contains("wear_resets_by_driveline_time"), "{reset}");
        let rows: (i64, f64, String) = connection
            .query_row(
                "SELECT count(*), taf, (SELECT event FROM wear_estimates) FROM bites",
                [],
                |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)),
            )
            .unwrap();
        assert_eq!(rows, (1, 1.3, "reset".into()));
    }

    fn application_id(connection: &Connection) -> i64 {
        connection
            .pragma_query_value(None, "application_id", |row| row.get(0))
            .unwrap()
    }

    #[test]
    fn new_and_migrated_files_carry_millgate_s_application_id() {
        let mut new = Connection::open_in_memory().unwrap();
        migrate(&mut new).unwrap();
        assert_eq!(application_id(&new), APPLICATION_ID);
        // A file of an older millgate: version 4 (migrated), and current (marked).
        for version in [4, current_version()] {
            let mut old = Connection::open_in_memory().unwrap();
            for step in &MIGRATIONS[..usize::try_from(version).unwrap()] {
                old.execute_batch(step).unwrap();
            }
            old.pragma_update(None, "user_version", version).unwrap();
            assert_eq!(application_id(&old), 0);
            assert_eq!(migrate(&mut old).unwrap(), version);
            assert_eq!(
                application_id(&old),
                APPLICATION_ID,
                "from version {version}"
            );
        }
    }

    #[test]
    fn another_application_s_file_is_refused_and_left_alone() {
        // Fossil's id, and one of no application but with its own tables.
        for (id, table) in [(0x0F05_5112, None), (0, Some("CREATE TABLE notes (x)"))] {
            let mut connection = Connection::open_in_memory().unwrap();
            connection
                .pragma_update(None, "application_id", id)
                .unwrap();
            if let Some(table) = table {
                connection.execute_batch(table).unwrap();
            }
            let error = migrate(&mut connection).unwrap_err();
            let text = error.to_string();
            assert!(matches!(error, SchemaError::Foreign { .. }), "{text}");
            assert!(text.starts_with("not a millgate history"), "{text}");
            if id != 0 {
                assert!(text.contains("application_id 0x0f055112"), "{text}");
            }
            let tables: i64 = connection
                .query_row(
                    "SELECT count(*) FROM sqlite_schema WHERE name = 'bites'",
                    [],
                    |row| row.get(0),
                )
                .unwrap();
            assert_eq!(tables, 0, "no millgate table added");
            assert_eq!(application_id(&connection), id);
        }
    }

    #[test]
    fn version_6_makes_the_coupling_an_integer_and_names_the_gap_alarm() {
        let mut connection = Connection::open_in_memory().unwrap();
        for step in &MIGRATIONS[..5] {
            connection.execute_batch(step).unwrap();
        }
        connection.pragma_update(None, "user_version", 5).unwrap();
        connection
            .execute_batch(
                "INSERT INTO gateway_runs (started_at, version, config_name)
                     VALUES ('2026-01-01T00:00:00.000Z', 't', 't');
                 INSERT INTO bites (run_id, driveline, time, bite_counter, channel,
                     static_torque_knm, peak_torque_knm, quality, degraded, gap_mrad,
                     gap_coupling)
                     VALUES (1, 'F1', '2026-01-01T00:00:01.000Z', 1, 'c', 400, 520,
                         'good', 0, 2.5, '1'),
                            (1, 'F1', '2026-01-01T00:00:02.000Z', 2, 'c', 400, 520,
                         'good', 0, 2.5, NULL);
                 INSERT INTO wear_estimates (run_id, driveline, time, event, origin,
                     gap_coupling) VALUES (1, 'F1', '2026-01-01T00:00:01.000Z', 'bite',
                     'analysis', '0');
                 INSERT INTO alarms (run_id, time, subject, kind, event, origin)
                     VALUES (1, '2026-01-01T00:00:03.000Z', 'F1', 'wear_alarm', 'raised',
                         'analysis');
                 INSERT INTO driveline_state (driveline, updated_at, bite_counter,
                     degraded, warning, alarm_latched)
                     VALUES ('F1', 't', 2, 0, 0, 0);",
            )
            .unwrap();
        assert_eq!(migrate(&mut connection).unwrap(), 5);
        let couplings: Vec<(Option<i64>, String)> = connection
            .prepare("SELECT gap_coupling, typeof(gap_coupling) FROM bites ORDER BY id")
            .unwrap()
            .query_map([], |row| Ok((row.get(0)?, row.get(1)?)))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(
            couplings,
            [(Some(1), "integer".into()), (None, "null".into())]
        );
        let (wear, kind, gap_warning): (i64, String, i64) = connection
            .query_row(
                "SELECT (SELECT gap_coupling FROM wear_estimates),
                        (SELECT kind FROM alarms),
                        (SELECT gap_warning FROM driveline_state)",
                [],
                |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)),
            )
            .unwrap();
        assert_eq!((wear, kind.as_str(), gap_warning), (0, "gap_alarm", 0));
    }

    /// A version 13 file (`rows` captures and as many chatter episodes, written as v13
    /// wrote them) at `path`.
    fn version_13_file(path: &std::path::Path, rows: i64) -> Connection {
        let connection = Connection::open(path).unwrap();
        for step in &MIGRATIONS[..13] {
            connection.execute_batch(step).unwrap();
        }
        connection.pragma_update(None, "user_version", 13).unwrap();
        connection
            .execute_batch(&format!(
                "INSERT INTO gateway_runs (started_at, version, config_name)
                     VALUES ('2026-01-01T00:00:00.000Z', 't', 't');
                 WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < {rows})
                 INSERT INTO captures (run_id, kind, subject, started_at, first_sample_unix_ns,
                     kernel_time, sample_rate_hz, samples, duration_s, keep, meta, bytes)
                     SELECT 1, 'bite', 'F1', printf('2026-01-01T%06d', i), i, 0, 2000, 1300,
                         0.65, 0, '{{\"format\":1,\"channels\":[],\"gaps\":[],\"analysis\":null,\"version\":\"t\"}}', 3000
                     FROM n;
                 WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < {rows})
                 INSERT INTO chatter_episodes (run_id, mill, started_at, windows, alarm)
                     SELECT 1, 'TCM', printf('2026-01-01T%06d', i), 3, 0 FROM n;"
            ))
            .unwrap();
        connection
    }

    /// Version 14 adds the context columns to the captures and the chatter episodes
    /// without rewriting a row: a v13 file's rows are kept with no context (NULL, the
    /// status too), the file grows by the two partial indexes' root pages only, and
    /// a product filter reads its index.
    #[test]
    fn version_14_gives_captures_and_episodes_a_context_without_rewriting_a_v13_file() {
        let folder = std::env::temp_dir().join(format!(
            "millgate-schema-v14-{}-{}",
            std::process::id(),
            crate::state::time::UtcTime::now().unix_ms()
        ));
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("history.db");
        let mut connection = version_13_file(&path, 20_000);
        let pages = |connection: &Connection| -> i64 {
            connection
                .pragma_query_value(None, "page_count", |row| row.get(0))
                .unwrap()
        };
        let before = pages(&connection);
        assert_eq!(migrate(&mut connection).unwrap(), 13);
        let after = pages(&connection);
        assert!(
            after - before <= 2,
            "{before} pages before, {after} after: a row was rewritten"
        );
        for table in ["captures", "chatter_episodes"] {
            let (rows, without): (i64, i64) = connection
                .query_row(
                    &format!(
                        "SELECT count(*), count(*) FILTER (WHERE context_status IS NULL
                             AND coil IS NULL AND product IS NULL AND speed_mpm IS NULL
                             AND thickness_mm IS NULL AND pass IS NULL AND mill_state IS NULL
                             AND context_note IS NULL) FROM {table}"
                    ),
                    [],
                    |row| Ok((row.get(0)?, row.get(1)?)),
                )
                .unwrap();
            assert_eq!((rows, without), (20_000, 20_000), "{table}");
            let plan: String = connection
                .query_row(
                    &format!(
                        "EXPLAIN QUERY PLAN SELECT id FROM {table}
                         WHERE product = 205 AND started_at >= '2026'"
                    ),
                    [],
                    |row| row.get(3),
                )
                .unwrap();
            assert!(plan.contains("_by_product"), "{table}: {plan}");
        }
        drop(connection);
        let _ = std::fs::remove_dir_all(&folder);
    }

    /// Version 15 adds the thresholds' group to the chatter episodes without rewriting
    /// a row: a v14 file's episodes (their context kept) have none (NULL: the mill's
    /// thresholds), and an episode written now keeps its group.
    #[test]
    fn version_15_gives_episodes_their_thresholds_group_without_rewriting_a_v14_file() {
        use crate::history::query::{ChatterRow, Filter, HistoryReader};
        use crate::state::time::UtcTime;
        use crate::testing::chatter_started;

        let folder = std::env::temp_dir().join(format!(
            "millgate-schema-v15-{}-{}",
            std::process::id(),
            UtcTime::now().unix_ms()
        ));
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("history.db");
        let mut connection = version_13_file(&path, 2_000);
        connection.execute_batch(MIGRATIONS[13]).unwrap();
        connection.pragma_update(None, "user_version", 14).unwrap();
        connection
            .execute_batch(
                "UPDATE chatter_episodes SET product = 205, context_status = 'valid'
                     WHERE id = 1",
            )
            .unwrap();
        let pages = |connection: &Connection| -> i64 {
            connection
                .pragma_query_value(None, "page_count", |row| row.get(0))
                .unwrap()
        };
        let before = pages(&connection);
        assert_eq!(migrate(&mut connection).unwrap(), 14);
        assert_eq!(pages(&connection), before, "a row was rewritten");
        let transaction = connection.transaction().unwrap();
        for group in [Some("thin gauge"), None] {
            let started = chatter_started("TCM", None, group);
            crate::history::rows::insert(&transaction, 1, &started).unwrap();
        }
        transaction.commit().unwrap();
        drop(connection);
        let rows: Vec<ChatterRow> = HistoryReader::open(&path)
            .unwrap()
            .rows(&Filter::default())
            .unwrap();
        assert_eq!(rows.len(), 2_002);
        assert!(rows[..2_000].iter().all(|r| r.thresholds_group.is_none()));
        assert_eq!(
            (rows[0].product, rows[0].context_status.as_deref()),
            (Some(205), Some("valid")),
            "the v14 context kept"
        );
        assert_eq!(rows[2_000].thresholds_group.as_deref(), Some("thin gauge"));
        assert_eq!(rows[2_001].thresholds_group, None);
        let _ = std::fs::remove_dir_all(&folder);
    }

    /// The declared type a catalogue figure's column must have.
    fn affinity(figure_type: crate::state::catalogue::FigureType) -> &'static str {
        use crate::state::catalogue::FigureType;
        match figure_type {
            FigureType::Real => "REAL",
            FigureType::Count | FigureType::Index | FigureType::Bool => "INTEGER",
            FigureType::State(_) | FigureType::Sequence => "INTEGER",
            FigureType::Time => "TEXT",
        }
    }

    /// The declared columns of `table`: name and type.
    fn declared(connection: &Connection, table: &str) -> Vec<(String, String)> {
        connection
            .prepare("SELECT name, type FROM pragma_table_info(?1)")
            .unwrap()
            .query_map([table], |row| Ok((row.get(0)?, row.get(1)?)))
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap()
    }

    /// Every column a figure of `figures` names in `table` (`column` picks the bite or
    /// the state column) exists with its type's affinity.
    fn holds<R>(
        connection: &Connection,
        table: &str,
        figures: &[crate::state::catalogue::Figure<R>],
        column: fn(&crate::state::catalogue::Columns) -> Option<&'static str>,
    ) {
        let columns = declared(connection, table);
        for figure in figures {
            let Some(name) = column(&figure.columns) else {
                continue;
            };
            let declared = columns
                .iter()
                .find(|(column, _)| column == name)
                .map(|(_, declared)| declared.as_str());
            assert_eq!(
                declared,
                Some(affinity(figure.figure_type)),
                "{table}.{name} for figure {}",
                figure.key
            );
        }
    }

    #[test]
    fn the_catalogue_columns_exist_with_their_figures_types() {
        use crate::state::catalogue::{DRIVELINE, TANDEM_MILL};
        let mut connection = Connection::open_in_memory().unwrap();
        migrate(&mut connection).unwrap();
        holds(&connection, "bites", DRIVELINE, |c| c.bite);
        holds(&connection, "driveline_state", DRIVELINE, |c| c.state);
        holds(&connection, "mill_state", TANDEM_MILL, |c| c.state);
        // A bites column named like a figure is that figure's.
        for (name, _) in declared(&connection, "bites") {
            if let Some(figure) = DRIVELINE.iter().find(|f| f.key == name) {
                assert_eq!(
                    figure.columns.bite,
                    Some(name.as_str()),
                    "bites.{name} is figure {name}'s column"
                );
            }
        }
        // Every bites column is read back: the row's own, a figure's, or the gap
        // pool's (read by the restore).
        let reader_columns =
            <crate::history::query::BiteRow as crate::history::query::Record>::columns();
        for (name, _) in declared(&connection, "bites") {
            assert!(
                reader_columns.contains(&name.as_str())
                    || ["gap_taf_sigma", "gap_period_shift_sigma_s"].contains(&name.as_str()),
                "bites.{name} is neither exported nor the gap pool's"
            );
        }
    }

    #[test]
    fn a_newer_file_is_refused_and_left_alone() {
        let mut connection = Connection::open_in_memory().unwrap();
        connection
            .pragma_update(None, "user_version", current_version() + 1)
            .unwrap();
        let error = migrate(&mut connection).unwrap_err();
        assert!(
            error.to_string().starts_with(&format!(
                "the history file has schema version {}, newer",
                current_version() + 1
            )),
            "{error}"
        );
    }

    #[test]
    fn a_failing_step_leaves_the_file_at_its_old_version() {
        let mut connection = Connection::open_in_memory().unwrap();
        // A table in the way of step 1: the step fails half-way, nothing is kept.
        connection
            .execute_batch("CREATE TABLE alarms (x INTEGER)")
            .unwrap();
        assert!(migrate(&mut connection).is_err());
        let version: i64 = connection
            .pragma_query_value(None, "user_version", |row| row.get(0))
            .unwrap();
        assert_eq!(version, 0);
        let bites: i64 = connection
            .query_row(
                "SELECT count(*) FROM sqlite_schema WHERE name = 'bites'",
                [],
                |row| row.get(0),
            )
            .unwrap();
        assert_eq!(bites, 0, "the step's first tables were rolled back");
    }
}
