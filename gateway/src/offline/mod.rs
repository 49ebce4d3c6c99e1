//! Offline commands: analyse a recorded CSV, adjust driveline stiffness.
//!
//! - `millgate analyze --input FILE.csv [--channel NAME] [--window START,END] [--format text|json]`
//! - `millgate stiffness --inertia Q1,Q2,Q3 (--freq B1,B2 | --stiffness C12,C23)
//!   [--drawing C12,C23] [--format text|json]`
//! - `millgate discrepancy --measured FILE.csv --model MODEL.toml [--channel NAME]
//!   [--report DIR] [--format text|json]`
//!
//! Each command is an `Args` struct plus `run(&Args) -> anyhow::Result<String>`
//! returning the text to print; `main` only prints it.

pub mod analyze;
pub mod csv;
pub mod discrepancy;
pub mod stiffness;

/// Output format of the offline commands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum OutputFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON document.
    Json,
}
