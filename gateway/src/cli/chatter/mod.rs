//! `millgate chatter`: a tandem mill's recorded stand vibrations through the service's
//! own chatter monitor, offline, window by window ([`windows`]); and
//! `millgate chatter commission`: the mill's alarm thresholds from stable recordings
//! ([`commission`]). Both read a [`Recording`] of the mill's stands and choose the
//! mill with `--mill` (`mill`).
//!
//! [`Recording`]: crate::analysis::chatter::Recording

pub mod commission;
mod mill;
pub mod windows;

use anyhow::bail;

pub use commission::CommissionArgs;
pub use windows::WindowsArgs;

/// Arguments of `millgate chatter`: a subcommand, or the per-window report's.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct ChatterArgs {
    /// `commission`: thresholds from stable recordings.
    #[command(subcommand)]
    pub command: Option<ChatterCommand>,
    /// The per-window report (without a subcommand).
    #[command(flatten)]
    pub windows: Option<WindowsArgs>,
}

/// What `millgate chatter` can do besides the per-window report.
#[derive(Debug, clap::Subcommand)]
pub enum ChatterCommand {
    /// Per-stand gain thresholds from stable recordings, as a line to paste into the
    /// mill's `[[tandem_mills]]` entry.
    Commission(CommissionArgs),
}

/// Runs `millgate chatter`: returns what it prints.
pub fn run(args: &ChatterArgs) -> anyhow::Result<String> {
    match (&args.command, &args.windows) {
        (Some(ChatterCommand::Commission(commission)), _) => commission::run(commission),
        (None, Some(windows)) => windows::run(windows),
        (None, None) => {
            bail!("--input and --config are required (or `millgate chatter commission`)")
        }
    }
}
