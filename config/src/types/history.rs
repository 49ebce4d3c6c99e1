//! The event history and its captures.

use std::path::PathBuf;

/// The event history: one SQLite file per gateway holding every bite, wear estimate,
/// alarm, chatter episode, source outage and start and stop, and the state restored
/// at the next start.
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    /// The SQLite file; a relative `path` resolved against `$STATE_DIRECTORY` when
    /// systemd sets it, else against the configuration file's folder; its folder exists.
    pub path: PathBuf,
    /// Events older than this are deleted, 1..=36500 days (default 400).
    pub retention_days: u32,
    /// Largest size of the file's data before the oldest events are deleted,
    /// 1..=1048576 MiB (default 1024).
    pub max_size_mb: u32,
    /// The captures (bite windows, chatter episodes, manual) kept in the file.
    pub captures: CaptureSettings,
    /// When a commit counts as durable (`synchronous`, default `normal`).
    pub synchronous: Synchronous,
}

/// `history.synchronous`: how far a commit is on disk before the PLC sees what it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Synchronous {
    /// `normal`: a commit is in the operating system's write-ahead log file, synced at
    /// each checkpoint: it survives a crash or kill of the gateway, but a power cut may
    /// lose the last commits since the last checkpoint (SQLite's WAL with
    /// `synchronous=NORMAL`).
    #[default]
    Normal,
    /// `full`: every commit is synced to the disk before it counts (`synchronous=FULL`):
    /// a power cut loses nothing committed, at the cost of an `fsync` per commit.
    Full,
}

impl Synchronous {
    /// Both settings.
    pub const ALL: [Self; 2] = [Self::Normal, Self::Full];

    /// The spelling in the file (and SQLite's name of the pragma's value).
    pub fn name(self) -> &'static str {
        match self {
            Self::Normal => "normal",
            Self::Full => "full",
        }
    }
}

/// `[history]`'s capture keys: whether the samples behind each bite are kept, and the
/// budget they are kept within.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureSettings {
    /// Keep captures at all (default true).
    pub enabled: bool,
    /// Largest size of the captures' samples, 1..=`max_size_mb` / 2 MiB (default
    /// `max_size_mb` / 2): past it the oldest ordinary bites' captures go first, those of
    /// warning bites next, the important ones (alarm bites) last.
    pub max_mb: u32,
    /// Ordinary bites' captures older than this are thinned to every
    /// `keep_every`-th bite, 1..=36500 days (default 7).
    pub thin_after_days: u32,
    /// After `thin_after_days`, an ordinary bite's capture is kept when its bite
    /// counter is a multiple of this, 1..=1000 (default 10; 1 keeps all).
    pub keep_every: u32,
}

impl CaptureSettings {
    /// The defaults for a file of `max_size_mb` MiB.
    pub fn defaults(max_size_mb: u32) -> Self {
        Self {
            enabled: true,
            max_mb: (max_size_mb / 2).max(1),
            thin_after_days: 7,
            keep_every: 10,
        }
    }
}
