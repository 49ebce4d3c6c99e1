//! A driveline whose process context comes from a second PLC over Modbus TCP (the
//! demo's configuration plus a `process_plc` source), and the check of a capture's
//! exports by pyarrow: what the bite-gating and text-coil end-to-end tests share.

use std::path::{Path, PathBuf};

use millgate::cli::capture::{ExportArgs, Selection};
use millgate::history::capture_files::ExportFormat;

use super::peers::peer;

/// The models folder of `millgate-sim`.
pub const MODELS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sim/models");

/// The demo's configuration (`config/examples/demo.toml`) with a Modbus source
/// `process_plc` (polled every 100 ms; its address to be set), the `channels` TOML
/// read from it, the driveline's `driveline` keys (its `context`, ...), `/metrics` on
/// a free port and the history at `history`; `name` is the file name in errors.
pub fn context_config(
    name: &str,
    channels: &str,
    driveline: &str,
    history: &Path,
) -> anyhow::Result<millgate_config::Config> {
    let demo = std::fs::read_to_string(format!(
        "{}/../config/examples/demo.toml",
        env!("CARGO_MANIFEST_DIR")
    ))?;
    let text = demo.replacen(
        "[[drivelines]]",
        &format!(
            "[[sources.modbus]]\nname = \"process_plc\"\naddress = \"127.0.0.1:1\"\n\
             poll_period_ms = 100\ntimeout_ms = 500\n\n{channels}[[drivelines]]\n{driveline}"
        ),
        1,
    ) + &format!(
        "\n[outputs.metrics]\nbind = \"127.0.0.1:0\"\n\n[history]\npath = {:?}\n",
        history.display().to_string()
    );
    millgate_config::from_toml_str(&text, name, Path::new(MODELS))
        .map_err(|error| anyhow::anyhow!("{error}"))
}

/// Export capture `id` of `selection` as CSV and Parquet into `out`, and have
/// pyarrow check both, the context (`MILLGATE_CONTEXT`, a JSON object) included.
pub fn pyarrow_checks_export(
    selection: &Selection,
    id: i64,
    out: PathBuf,
    context: &str,
) -> anyhow::Result<()> {
    let export = |format| {
        millgate::cli::capture::export(&ExportArgs {
            selection: selection.clone(),
            bite: None,
            id: Some(id),
            format,
            out: out.clone(),
        })
    };
    let csv = export(ExportFormat::Csv)?;
    let parquet = export(ExportFormat::Parquet)?;
    let checked = std::process::Command::new("python3")
        .arg(peer("capture_parquet.py"))
        .arg(&csv[0])
        .arg(&parquet[0])
        .env("MILLGATE_CONTEXT", context)
        .output()?;
    anyhow::ensure!(
        checked.status.success(),
        "{}{}",
        String::from_utf8_lossy(&checked.stdout),
        String::from_utf8_lossy(&checked.stderr)
    );
    Ok(())
}
