//! `millgate chatter commission --config MILL.toml --input STABLE.csv [--input ...]
//! [--mill NAME] [--margin PCT] [--speed-column NAME] [--format text|json]`: a tandem
//! mill's chatter thresholds from recordings of its stable rolling.
//!
//! The recordings (CSVs, and with `--db --captures` captures the history keeps) go
//! through `analysis::chatter::commission` (how the thresholds, the release level and `k_max` come
//! about, and which recordings are refused), grouped by product: a CSV by its `product`
//! column, a capture by the product it carries (schema v14) when its context was
//! valid; a capture whose context was stale or invalid counts for the mill's
//! thresholds only, and the output says so. The thresholds are printed as the TOML
//! line `gain_thresholds = [...]` to paste into the mill's `[[tandem_mills]]` entry,
//! with `slow_down_release` (and a warning when the margin leaves the release no room
//! below the alarm: raise `--margin`), how many windows and seconds the recordings
//! gave, the speeds they covered (with `--speed-column`, a column of the recordings
//! holding the mill's speed), the largest band RMS per stand and, for
//! `detector = "paper"`, `k_max`. A stand above [`NOTE_FACTOR`] times its median gain is
//! noted with the time, for the engineer to look at.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use millgate_config::Config;

use super::mill::mill_index;
use crate::analysis::chatter::commission::{
    commission_by_product, Commissioning, GroupCommissioning, NotPooled, DEFAULT_MARGIN_PERCENT,
    DEFAULT_MIN_GROUP_RECORDINGS, NOTE_FACTOR, RELEASE_CEILING,
};
use crate::analysis::chatter::Recording;
use crate::cli::capture::Picked;
use crate::cli::OutputFormat;
use crate::history::query::{CaptureRow, Filter, HistoryReader};
use crate::records::stands;

/// Arguments of `millgate chatter commission`.
#[derive(Debug, Clone, clap::Args)]
pub struct CommissionArgs {
    /// Gateway configuration with the `[[tandem_mills]]` entry (`gain_thresholds` may
    /// be left out: they are what this computes).
    #[arg(long)]
    pub config: PathBuf,
    /// A CSV of stable rolling, header `t,<stand channel>,...` (as `millgate chatter`
    /// reads); once per recording.
    #[arg(long = "input", required_unless_present = "db")]
    pub inputs: Vec<PathBuf>,
    /// Also take recordings from this history file's captures of the mill's stands
    /// (with --captures).
    #[arg(long, requires = "captures")]
    pub db: Option<PathBuf>,
    /// Which captures (with --db): `LAST:N` (the mill's newest N) or capture ids,
    /// comma-separated (`12,15`); manual captures of stable rolling, or chatter-free
    /// ones (a capture that shows chatter is refused as a CSV is).
    #[arg(long, requires = "db", value_parser = Picked::captures)]
    pub captures: Option<Picked>,
    /// Name of the tandem mill (default: the first one).
    #[arg(long)]
    pub mill: Option<String>,
    /// Margin above the largest stable gain, percent.
    #[arg(long, default_value_t = DEFAULT_MARGIN_PERCENT)]
    pub margin: f64,
    /// A column of the recordings holding the mill's speed (any unit), to report the
    /// speeds the recordings covered.
    #[arg(long)]
    pub speed_column: Option<String>,
    /// Fewest recordings of a product group (by the recordings' `product` column, the
    /// captures' product) for its own thresholds; a group with fewer falls back to the
    /// mill's.
    #[arg(long, default_value_t = DEFAULT_MIN_GROUP_RECORDINGS)]
    pub min_group_recordings: usize,
    /// Output format.
    #[arg(long, value_enum, default_value = "text")]
    pub format: OutputFormat,
}

/// Runs `millgate chatter commission`: returns what it prints.
pub fn run(args: &CommissionArgs) -> anyhow::Result<String> {
    let config = millgate_config::load_uncommissioned(&args.config)?;
    let index = mill_index(&config, args.mill.as_deref(), &args.config)?;
    let mut recordings = args
        .inputs
        .iter()
        .map(|path| stands::read(path, &config, index, args.speed_column.as_deref()))
        .collect::<Result<Vec<_>, _>>()?;
    let mut not_pooled = Vec::new();
    if let (Some(db), Some(selection)) = (&args.db, &args.captures) {
        let (taken, untrusted) = captured(db, &config, index, selection)?;
        recordings.extend(taken);
        not_pooled = untrusted;
    }
    let mut commissioning = commission_by_product(
        &config,
        index,
        &recordings,
        args.margin,
        args.min_group_recordings,
    )?;
    commissioning.not_pooled = not_pooled;
    Ok(match args.format {
        OutputFormat::Json => serde_json::to_string_pretty(&commissioning)? + "\n",
        OutputFormat::Text => text(&commissioning),
    })
}

/// The captures of mill `index` of `config` that `selection` names in the history
/// `db`, oldest first, as recordings of its stands (each named `db#capture ID`), each
/// with the product it carries as its `product` column when its context was valid;
/// and the captures whose context was stale or invalid (no product: not pooled into
/// a product's group). Errors name the file and the capture: one that is not the
/// mill's, lacks a stand, or is a chatter episode (the chatter check of
/// `analysis::chatter::commission` then runs on the rest).
fn captured(
    db: &Path,
    config: &Config,
    index: usize,
    selection: &Picked,
) -> anyhow::Result<(Vec<Recording>, Vec<NotPooled>)> {
    let mill = &config.tandem_mills[index].name;
    let reader = HistoryReader::open(db)?;
    let rows = picked_rows(&reader, db, mill, selection)?;
    let mut recordings = Vec::with_capacity(rows.len());
    let mut not_pooled = Vec::new();
    for row in rows {
        if row.kind == "chatter" {
            // The gateway warned in it: not stable rolling, however far it developed
            // (a slowed-down episode may stay below the chatter factor).
            anyhow::bail!(
                "{}#capture {}: a chatter episode (the gateway warned at {}): commission from \
                 stable rolling only (manual captures of the stands, `command.manual_capture`)",
                db.display(),
                row.id,
                row.started_at
            );
        }
        let capture = reader.capture_of(row)?;
        let name = format!("{}#capture {}", db.display(), capture.row.id);
        let mut recording = stands::from_capture(name, &capture, config, index)?;
        match capture.row.context_status.as_deref() {
            Some("valid") => {
                let samples = recording.len();
                recording.context.product =
                    capture.row.product.map(|code| vec![code as f64; samples]);
            }
            Some(status) => not_pooled.push(NotPooled {
                recording: recording.name.clone(),
                context_status: status.to_owned(),
                context_note: capture.row.context_note.clone(),
            }),
            // No context tags (or a capture from before schema v14): no product.
            None => {}
        }
        recordings.push(recording);
    }
    Ok((recordings, not_pooled))
}

/// The rows of the captures that `selection` names in the history `db` (read by
/// `reader`) of tandem mill `mill`, oldest first; the error names the file and the
/// capture that is missing or not the mill's.
fn picked_rows(
    reader: &HistoryReader,
    db: &Path,
    mill: &str,
    selection: &Picked,
) -> anyhow::Result<Vec<CaptureRow>> {
    let mut rows: Vec<CaptureRow> = Vec::new();
    reader.for_each(
        &Filter::default(),
        |row: CaptureRow| -> anyhow::Result<()> {
            let wanted = match selection {
                Picked::Last(_) => row.subject == mill,
                Picked::Numbers(ids) => ids.contains(&row.id),
            };
            if wanted {
                rows.push(row);
            }
            Ok(())
        },
    )?;
    match selection {
        Picked::Last(n) => {
            if rows.len() < *n as usize {
                anyhow::bail!(
                    "{}: --captures LAST:{n}: tandem mill \"{mill}\" has {} captures",
                    db.display(),
                    rows.len()
                );
            }
            rows.drain(..rows.len() - *n as usize);
        }
        Picked::Numbers(ids) => {
            for id in ids {
                match rows.iter().find(|r| r.id == *id) {
                    None => anyhow::bail!(
                        "{}: --captures: no capture {id} (see `millgate capture list --db {}`)",
                        db.display(),
                        db.display()
                    ),
                    Some(row) if row.subject != mill => anyhow::bail!(
                        "{}: --captures: capture {id} is of \"{}\", not of tandem mill \"{mill}\"",
                        db.display(),
                        row.subject
                    ),
                    Some(_) => {}
                }
            }
        }
    }
    Ok(rows)
}

/// A list of figures as TOML: `[1.187, 1.492]`.
fn toml_list(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:.3}")).collect();
    format!("[{}]", items.join(", "))
}

/// What `commission` prints as text.
fn text(c: &Commissioning) -> String {
    let mut out = String::new();
    recordings_text(c, &mut out);
    speeds_text(c, &mut out);
    stands_text(c, &mut out);
    paste_text(c, &mut out);
    groups_text(c, &mut out);
    not_pooled_text(c, &mut out);
    out
}

/// The captures left out of the product groups: their context was not trusted.
fn not_pooled_text(c: &Commissioning, out: &mut String) {
    if c.not_pooled.is_empty() {
        return;
    }
    let _ = writeln!(
        out,
        "# not pooled into a product group (the capture's context was not valid: its product \
         is not trusted; counted for gain_thresholds above only):"
    );
    for left in &c.not_pooled {
        let why = left
            .context_note
            .as_deref()
            .map_or(String::new(), |note| format!(": {note}"));
        let _ = writeln!(
            out,
            "#   {}: context {}{why}",
            left.recording, left.context_status
        );
    }
}

/// The product groups: each with its recordings, and the entries to paste for those
/// with thresholds.
fn groups_text(c: &Commissioning, out: &mut String) {
    if c.product_groups.is_empty() {
        return;
    }
    let _ = writeln!(
        out,
        "# product groups (recordings grouped by their product column; any other product, \
         or none, falls back to gain_thresholds above):"
    );
    let codes = |g: &GroupCommissioning| {
        let codes: Vec<String> = g.products.iter().map(u32::to_string).collect();
        codes.join(", ")
    };
    for group in &c.product_groups {
        let what = match &group.gain_thresholds {
            Some(_) => format!("{} windows", group.windows),
            None => format!(
                "too few recordings for its own thresholds (need {}): its products fall back \
                 to the mill's",
                group.min_recordings
            ),
        };
        let _ = writeln!(
            out,
            "#   \"{}\" (products {}): {} recording(s), {what}",
            group.name,
            codes(group),
            group.recordings.len()
        );
    }
    for group in &c.product_groups {
        let Some(thresholds) = &group.gain_thresholds else {
            continue;
        };
        let _ = writeln!(out, "[[tandem_mills.product_groups]]");
        // A configured name has no control characters; Debug's quotes and escapes of
        // `"` and `\` are TOML's.
        let _ = writeln!(out, "name = {:?}", group.name);
        let _ = writeln!(out, "products = [{}]", codes(group));
        let _ = writeln!(out, "gain_thresholds = {}", toml_list(thresholds));
    }
}

/// The recordings, each with its windows and the stands it notes.
fn recordings_text(c: &Commissioning, out: &mut String) {
    let _ = writeln!(
        out,
        "tandem mill \"{}\": {} recording(s), {:.1} s, {} windows with a full gain window",
        c.mill,
        c.recordings.len(),
        c.duration_s,
        c.windows
    );
    for r in &c.recordings {
        let speeds = r.speeds.as_ref().map_or(String::new(), |s| {
            format!(", {} {:.2} .. {:.2}", s.column, s.lowest, s.highest)
        });
        let _ = writeln!(
            out,
            "  {}: {:.1} s, {} windows{speeds}",
            r.recording, r.duration_s, r.windows
        );
        for (stand, (&factor, &at_s)) in r
            .largest_over_median
            .iter()
            .zip(&r.largest_at_s)
            .enumerate()
        {
            if factor > NOTE_FACTOR {
                let _ = writeln!(
                    out,
                    "    note: stand {} (`{}`) reaches {factor:.1} times its median gain at t = \
                     {at_s:.2} s (the end of an acceleration, a weld, or the start of chatter: \
                     look at it with `millgate chatter --plot`)",
                    stand + 1,
                    c.stands[stand].channel
                );
            }
        }
    }
}

/// The speeds the recordings covered, or how to have them.
fn speeds_text(c: &Commissioning, out: &mut String) {
    match &c.speeds {
        Some(s) => {
            let _ = writeln!(
                out,
                "speeds covered ({}): {:.2} .. {:.2}; the thresholds hold up to {:.2}: record \
                 stable rolling up to the highest allowed speed",
                s.column, s.lowest, s.highest, s.highest
            );
        }
        None => {
            let _ = writeln!(
                out,
                "speeds covered: not recorded (--speed-column NAME names the recordings' speed \
                 column); the thresholds hold up to the highest speed the recordings reached"
            );
        }
    }
}

/// Per stand, its largest gain, its threshold and its largest band RMS.
fn stands_text(c: &Commissioning, out: &mut String) {
    let _ = writeln!(
        out,
        "{:<16} {:>12} {:>14} {:>16}",
        "stand",
        "largest gain",
        format!("threshold +{}%", c.margin_percent),
        "largest band RMS"
    );
    for (stand, threshold) in c.stands.iter().zip(&c.gain_thresholds) {
        let _ = writeln!(
            out,
            "{:<16} {:>12.3} {:>14.3} {:>16.3}",
            stand.channel, stand.largest_gain, threshold, stand.largest_band_rms
        );
    }
}

/// The lines to paste into the mill's entry, and what the other detectors would take.
fn paste_text(c: &Commissioning, out: &mut String) {
    let _ = writeln!(
        out,
        "# paste into the [[tandem_mills]] entry \"{}\":",
        c.mill
    );
    let _ = writeln!(out, "gain_thresholds = {}", toml_list(&c.gain_thresholds));
    let _ = writeln!(
        out,
        "# the request clears below this (stable rolling stayed below {:.3} of the thresholds \
         in 99% of the windows):",
        c.stable_ratio_p99
    );
    let _ = writeln!(out, "slow_down_release = {:.2}", c.slow_down_release);
    if c.release_cramped {
        let _ = writeln!(
            out,
            "# warning: a release with room below the alarm would be above {RELEASE_CEILING}: \
             with these thresholds the request may never clear in stable rolling; raise \
             --margin (now {}%)",
            c.margin_percent
        );
    }
    let _ = writeln!(
        out,
        "# for detector = \"paper\" (largest K_mean {:.3}, moved {}% of the way to 1):\n\
         # k_max = {:.3}",
        c.largest_k_mean, c.margin_percent, c.k_max
    );
    let _ = writeln!(
        out,
        "# a band-RMS vibration alarm at the largest band RMS + {}%: {}",
        c.margin_percent,
        toml_list(&c.band_rms_thresholds)
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::chatter::commission::commission;
    use crate::analysis::chatter::testing::{example_tandem, lines_recording};
    use crate::history::writer::{connect, insert_run};
    use crate::history::RunInfo;
    use crate::state::captures::{CaptureChannel, CaptureKind, CaptureRecord};
    use crate::state::context::{ContextError, ContextReading, ProcessContext, StaleTags};
    use crate::state::events::HistoryEvent;
    use crate::state::time::UtcTime;
    use crate::testing::capture_without_samples;

    /// A history file at `path` with a manual capture of the example tandem mill's
    /// stands per `(amplitude, context)`: 3 s of [`lines_recording`]'s lines, the
    /// chatter line `amplitude` (gain `2 amplitude`), the context as the gateway kept
    /// it. Capture ids are 1, 2, ... in this order.
    fn history_with_captures(path: &Path, captures: &[(f64, Option<ContextReading>)]) {
        let config = example_tandem();
        let mill = &config.tandem_mills[0];
        let mut connection = connect(path).expect("history");
        let start = UtcTime::parse("2026-11-01T00:00:00Z").expect("time");
        let run = RunInfo {
            version: "test".into(),
            config_name: "tandem".into(),
            config_hash: String::new(),
            drivelines: Vec::new(),
        };
        let run = insert_run(&connection, start, &run).expect("run");
        let transaction = connection.transaction().expect("transaction");
        for (k, &(amplitude, context)) in captures.iter().enumerate() {
            let recording = lines_recording(7_500, |_| amplitude);
            let channels = mill
                .stands
                .iter()
                .zip(&recording.stands)
                .map(|(&channel, samples)| CaptureChannel {
                    samples: samples.clone(),
                    ..CaptureChannel::described(&config.channels[channel])
                })
                .collect();
            let capture = CaptureRecord {
                first_sample_unix_ns: (start.unix_ms() + 60_000 * k as i64) * 1_000_000,
                channels,
                ..capture_without_samples(CaptureKind::Manual, &mill.name, context)
            };
            crate::history::rows::insert(
                &transaction,
                run,
                &HistoryEvent::Capture(Box::new(capture)),
            )
            .expect("capture");
        }
        transaction.commit().expect("commit");
    }

    /// `--db --captures` groups the captures by the product they carry, as the
    /// `product` column groups CSVs; a capture whose context was stale or invalid
    /// counts for the mill's thresholds only, and the output names it.
    #[test]
    fn captures_are_grouped_by_the_product_they_carry_unless_their_context_was_untrusted() {
        let folder = std::env::temp_dir().join(format!(
            "millgate-commission-captures-{}",
            std::process::id()
        ));
        std::fs::create_dir_all(&folder).expect("folder");
        let db = folder.join("history.db");
        let _ = std::fs::remove_file(&db);
        let product = |code| ProcessContext {
            product: Some(code),
            ..ProcessContext::default()
        };
        let valid = |code| ContextReading {
            context: Ok(product(code)),
            stale: StaleTags::default(),
        };
        let mut stale_coil = StaleTags::default();
        stale_coil.insert("coil");
        history_with_captures(
            &db,
            &[
                // Product 7 at gain 1, twice: its own thresholds.
                (0.5, Some(valid(7))),
                (0.5, Some(valid(7))),
                // Product 7 at gain 2 while the coil tag was stale: not pooled.
                (
                    1.0,
                    Some(ContextReading {
                        context: Ok(product(7)),
                        stale: stale_coil,
                    }),
                ),
                // An impossible speed: no product at all.
                (
                    0.75,
                    Some(ContextReading {
                        context: Err(ContextError::Speed(-5.0)),
                        stale: StaleTags::default(),
                    }),
                ),
            ],
        );
        let args = |format| CommissionArgs {
            config: crate::testing::example("tandem-5stand.toml"),
            inputs: Vec::new(),
            db: Some(db.clone()),
            captures: Some(Picked::captures("LAST:4").expect("selection")),
            mill: None,
            margin: 10.0,
            speed_column: None,
            min_group_recordings: 2,
            format,
        };
        let json: serde_json::Value =
            serde_json::from_str(&run(&args(OutputFormat::Json)).expect("commissioned"))
                .expect("json");
        // The mill's thresholds from all four (gain 2 plus 10%), product 7's from its
        // two trusted captures (gain 1 plus 10%).
        let mill = json["gain_thresholds"].as_array().expect("thresholds");
        assert!(
            mill.iter().all(|t| (t.as_f64().unwrap() - 2.2).abs() < 0.1),
            "{json}"
        );
        let groups = json["product_groups"].as_array().expect("groups");
        assert_eq!(groups.len(), 1, "{json}");
        assert_eq!(groups[0]["name"], "product-7");
        let pooled = db.display().to_string();
        assert_eq!(
            groups[0]["recordings"],
            serde_json::json!([format!("{pooled}#capture 1"), format!("{pooled}#capture 2")])
        );
        let own = groups[0]["gain_thresholds"].as_array().expect("its own");
        assert!(
            own.iter().all(|t| (t.as_f64().unwrap() - 1.1).abs() < 0.05),
            "{json}"
        );
        let left: Vec<(&str, &str)> = json["not_pooled"]
            .as_array()
            .expect("not pooled")
            .iter()
            .map(|n| {
                (
                    n["recording"].as_str().unwrap(),
                    n["context_status"].as_str().unwrap(),
                )
            })
            .collect();
        let (three, four) = (format!("{pooled}#capture 3"), format!("{pooled}#capture 4"));
        assert_eq!(
            left,
            [(three.as_str(), "stale"), (four.as_str(), "invalid")]
        );

        let printed = run(&args(OutputFormat::Text)).expect("commissioned");
        assert!(
            printed.contains("#   \"product-7\" (products 7): 2 recording(s)")
                && printed.contains("[[tandem_mills.product_groups]]\nname = \"product-7\"\n"),
            "{printed}"
        );
        assert!(
            printed.contains(&format!(
                "#   {three}: context stale: no fresh value of coil (source stale or tag not \
                 delivered)"
            )) && printed.contains(&format!(
                "#   {four}: context invalid: speed_mpm -5 is not allowed"
            )),
            "{printed}"
        );
        let _ = std::fs::remove_dir_all(&folder);
    }

    #[test]
    fn a_stand_above_three_times_its_median_is_noted_with_the_time() {
        // 20 s steady, then the chatter line grows fourfold over 5 s.
        let milder = |t: f64| 0.5 * (1.0 + 3.5 * ((t - 20.0) / 5.0).clamp(0.0, 1.0));
        let c = commission(
            &example_tandem(),
            0,
            &[lines_recording(62_500, milder)],
            10.0,
        )
        .expect("commissioned");
        let printed = text(&c);
        assert!(
            printed.contains("note: stand 1 (`s1_vib`) reaches"),
            "{printed}"
        );
        assert!(
            printed.contains("gain_thresholds = [") && printed.contains("slow_down_release = "),
            "{printed}"
        );
    }
}
