//! Liveness of acquisition sources ([`SourceHealth`]): when each last answered and
//! whether it is connected, from which its [`SourceStatus`] (ok, stale, lost) follows.
//! Readers report into it; the register map, the board and `/metrics` read it. Its
//! times are tokio's clock (the system's monotonic clock, or a test's paused one).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use tokio::time::Instant;

/// What the gateway knows of a source right now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceStatus {
    /// Connected and answering.
    Ok,
    /// Connected, or reconnecting, but no good answer for longer than its stale time.
    Stale,
    /// Never answered, or not connected for longer than its lost time.
    Lost,
}

impl SourceStatus {
    /// Register encoding: 0 ok, 1 stale, 2 lost.
    pub fn code(self) -> u16 {
        match self {
            SourceStatus::Ok => 0,
            SourceStatus::Stale => 1,
            SourceStatus::Lost => 2,
        }
    }

    /// Lower-case name for logs and metrics.
    pub fn name(self) -> &'static str {
        match self {
            SourceStatus::Ok => "ok",
            SourceStatus::Stale => "stale",
            SourceStatus::Lost => "lost",
        }
    }
}

/// Liveness of one source: when it last answered, whether it is connected.
#[derive(Debug)]
pub struct SourceHealth {
    epoch: Instant,
    /// Milliseconds after `epoch` of the last good answer; 0 = never.
    last_good_ms: AtomicU64,
    connected: AtomicBool,
    connects: AtomicU64,
    stale_after: Duration,
    lost_after: Duration,
}

impl SourceHealth {
    /// A source that is stale after `stale_after` without a good answer and lost
    /// after `lost_after` (>= `stale_after`) or while it has never answered.
    pub fn new(stale_after: Duration, lost_after: Duration) -> Self {
        Self {
            epoch: Instant::now(),
            last_good_ms: AtomicU64::new(0),
            connected: AtomicBool::new(false),
            connects: AtomicU64::new(0),
            stale_after,
            lost_after: lost_after.max(stale_after),
        }
    }

    pub(crate) fn answered(&self) {
        let ms = self.epoch.elapsed().as_millis().max(1) as u64;
        self.last_good_ms.store(ms, Ordering::Relaxed);
    }

    pub(crate) fn set_connected(&self, connected: bool) {
        if connected {
            self.connects.fetch_add(1, Ordering::Relaxed);
        }
        self.connected.store(connected, Ordering::Relaxed);
    }

    /// Successful connections so far (reconnects show as > 1).
    pub fn connects(&self) -> u64 {
        self.connects.load(Ordering::Relaxed)
    }

    /// Status at `now`.
    pub(crate) fn status_at(&self, now: Instant) -> SourceStatus {
        let last_good_ms = self.last_good_ms.load(Ordering::Relaxed);
        if last_good_ms == 0 {
            return SourceStatus::Lost;
        }
        let last_good = self.epoch + Duration::from_millis(last_good_ms);
        let silent = now.saturating_duration_since(last_good);
        if silent > self.lost_after {
            SourceStatus::Lost
        } else if silent > self.stale_after || !self.connected.load(Ordering::Relaxed) {
            SourceStatus::Stale
        } else {
            SourceStatus::Ok
        }
    }

    /// Status now.
    pub fn status(&self) -> SourceStatus {
        self.status_at(Instant::now())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_goes_ok_stale_lost() {
        let health = SourceHealth::new(Duration::from_millis(100), Duration::from_secs(1));
        assert_eq!(health.status(), SourceStatus::Lost, "never answered");
        health.set_connected(true);
        health.answered();
        let now = Instant::now();
        assert_eq!(health.status_at(now), SourceStatus::Ok);
        assert_eq!(
            health.status_at(now + Duration::from_millis(300)),
            SourceStatus::Stale
        );
        assert_eq!(
            health.status_at(now + Duration::from_secs(2)),
            SourceStatus::Lost
        );
        health.set_connected(false);
        assert_eq!(health.status_at(now), SourceStatus::Stale, "disconnected");
        assert_eq!(health.connects(), 1);
    }
}
