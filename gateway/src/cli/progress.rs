//! Progress of a long command (`history`, `report` on a year of bites) on stderr.
//!
//! Shown only when stderr is a terminal: one line, rewritten in place at most once a
//! second, then a last line with the totals and the time taken. When stderr is a
//! file, a pipe or the journal (cron, CI, a systemd timer), nothing is written: a
//! log would only collect stale percentages, and the command's own output and exit
//! status say how it ended.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// Least time between two updates of the line.
const PERIOD: Duration = Duration::from_secs(1);

/// The progress line of one command.
#[derive(Debug)]
pub(crate) struct Progress {
    shown: bool,
    started: Instant,
    last: Option<Instant>,
}

impl Progress {
    /// Progress on stderr when it is a terminal, nothing otherwise.
    pub(crate) fn on_terminal() -> Self {
        Self {
            shown: std::io::stderr().is_terminal(),
            started: Instant::now(),
            last: None,
        }
    }

    /// Seconds since the command started.
    pub(crate) fn elapsed_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Show the line `status` gives, if a second has passed since the last one shown
    /// (`status` is not called otherwise).
    pub(crate) fn update(&mut self, status: impl FnOnce() -> String) {
        if !self.shown || self.last.is_some_and(|last| last.elapsed() < PERIOD) {
            return;
        }
        self.last = Some(Instant::now());
        let mut stderr = std::io::stderr().lock();
        // \r and clear to the end of the line: the new line replaces the old.
        let _ = write!(stderr, "\r{}\x1b[K", status());
        let _ = stderr.flush();
    }

    /// End the line with `summary` (the totals); nothing when not shown.
    pub(crate) fn finish(&mut self, summary: &str) {
        if self.shown {
            let _ = writeln!(std::io::stderr().lock(), "\r{summary}\x1b[K");
        }
    }
}

/// `part` of `whole` as a percentage, 100 for an empty whole.
pub(crate) fn percent(part: u64, whole: u64) -> f64 {
    if whole == 0 {
        100.0
    } else {
        100.0 * part as f64 / whole as f64
    }
}
