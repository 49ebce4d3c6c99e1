//! The command-line tools apart from the service (`millgate run`): each command is a
//! module with its arguments (a clap `Args` struct) and a `run` returning what to print;
//! `main` parses the command line and prints.
//!
//! - `millgate check --config FILE [--format text|json]`: [`check`]
//! - `millgate registers --config FILE --format md|csv|json`: [`registers`]
//! - `millgate figures --format md|csv|json`: [`figures`]
//! - `millgate address-space --config FILE`: `address_space` (the OPC UA server's
//!   variables as a Markdown table; with the `opcua` feature)
//! - `millgate analyze --input FILE.csv [--channel NAME] [--window START,END] [--format text|json]`:
//!   [`analyze`] (the CSV read by [`crate::records::csv`])
//! - `millgate stiffness --inertia Q1,Q2,Q3 (--freq B1,B2 | --stiffness C12,C23)
//!   [--drawing C12,C23] [--format text|json]`: [`stiffness`]
//! - `millgate chatter --input STANDS.csv --config MILL.toml [--mill NAME]
//!   [--format text|json] [--plot FILE.svg]`: [`chatter`] (the chatter monitor offline,
//!   per window, each stand's band RMS and gain)
//! - `millgate chatter commission --config MILL.toml --input STABLE.csv [--input ...]
//!   [--mill NAME] [--margin PCT] [--speed-column NAME] [--format text|json]`: the
//!   mill's `gain_thresholds` from stable recordings ([`chatter::commission`])
//! - `millgate discrepancy --measured FILE.csv --model MODEL.toml [--channel NAME]
//!   [--report DIR] [--format text|json]`: `discrepancy`
//! - `millgate sim transient|modes|wear-map ...`: `sim`
//! - `millgate rod check|mathieu|floquet ...`: `rod` (rod mills, parametric stability)
//! - `millgate wear --input FILE.csv --model MODEL.toml [--channel NAME] [--pool N]
//!   [--format text|json] [--plot FILE.svg]`: [`wear`] (the gap diagnosis on a record;
//!   `--plot` with `sim-tools`)
//! - `millgate fatigue (--input FILE.csv [--channel NAME] | --db FILE --driveline NAME)
//!   --m M --ref-cycles N --ref-range-knm S [--endurance-knm E] [--gate-knm G]
//!   [--format text|json]`: [`fatigue`] (rainflow count and Miner's damage)
//! - `millgate demo [--duration S] [--history FILE] [--mqtt HOST:PORT]`: `demo`
//! - `millgate history --db FILE [--kind K] [--driveline NAME] [--since T] [--until T]
//!   --format csv|json|md`: [`history`]
//! - `millgate report --db FILE --out DIR [--since T] [--until T]`: `report`
//! - `millgate capture list|export --db FILE [--driveline NAME] [--since T] [--until T]
//!   ...`: [`capture`] (the captures a history keeps; CSV and Parquet)
//! - `millgate completions SHELL`, `millgate man [--out DIR]`: [`shell`] (and the
//!   exit status of every command)
//!
//! `discrepancy`, `sim`, `rod` and `demo` come with the default `sim-tools` feature (they
//! need the simulator's virtual devices or plots); `report` with `plot` (part of
//! `sim-tools`).

pub mod address_space;
pub mod analyze;
pub mod capture;
pub mod chatter;
pub mod check;
#[cfg(feature = "sim-tools")]
pub mod demo;
#[cfg(feature = "sim-tools")]
pub mod discrepancy;
pub mod fatigue;
#[cfg(feature = "sim-tools")]
pub mod fatigue_gap;
pub mod figures;
pub mod history;
pub(crate) mod progress;
pub mod registers;
pub mod reload;
#[cfg(feature = "plot")]
pub mod report;
#[cfg(feature = "sim-tools")]
pub mod rod;
pub mod shell;
#[cfg(feature = "sim-tools")]
pub mod sim;
pub mod stiffness;
pub mod wear;

/// Output format of the offline commands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum OutputFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON document.
    Json,
}
