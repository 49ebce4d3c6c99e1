//! What a service manager needs to trust the gateway: readiness (every listener bound
//! and the first PLC write attempted, [`crate::service::RunningService::ready`]) and
//! liveness: a watchdog ping that is sent only while the analysis loop turns and the
//! published heartbeat moves ([`watchdog`]), so a stuck analysis or a stuck output
//! stops the pings and the manager restarts the service.
//!
//! `millgate run` sends both to systemd (`sd_notify`: `READY=1`, `WATCHDOG=1`,
//! `STOPPING=1`); the unit file is `deploy/millgate.service`.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use crate::shutdown::Shutdown;
use crate::state::board::Board;

/// Longest time the analysis loop waits for samples before it turns anyway (and
/// counts the turn), so an idle analysis is seen alive.
pub const ANALYSIS_TICK: Duration = Duration::from_millis(100);

/// Turns of the analysis loop: one per message handled and one per idle tick.
#[derive(Debug, Default)]
pub struct Liveness {
    analysis_turns: AtomicU64,
}

impl Liveness {
    pub(crate) fn analysis_turned(&self) {
        self.analysis_turns.fetch_add(1, Ordering::Relaxed);
    }

    /// Turns of the analysis loop so far.
    pub(crate) fn analysis_turns(&self) -> u64 {
        self.analysis_turns.load(Ordering::Relaxed)
    }
}

/// Why the watchdog cannot be kept with this configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "the watchdog period {watchdog:?} (WatchdogSec) is too short for the heartbeat, which \
     moves every {heartbeat:?} (outputs.plc.write_period_ms, or 1 s without a PLC output): \
     it must be at least 4 times the heartbeat period"
)]
pub struct WatchdogTooShort {
    /// The watchdog period asked for.
    pub watchdog: Duration,
    /// The heartbeat period.
    pub heartbeat: Duration,
}

/// Whether a watchdog of period `watchdog` can be kept while the heartbeat moves every
/// `heartbeat`: progress is checked every quarter period and must be seen within half
/// of it.
pub fn check_watchdog(watchdog: Duration, heartbeat: Duration) -> Result<(), WatchdogTooShort> {
    if watchdog >= heartbeat * 4 {
        Ok(())
    } else {
        Err(WatchdogTooShort {
            watchdog,
            heartbeat,
        })
    }
}

/// Calls `ping` every quarter of `watchdog` while both the analysis loop (`liveness`)
/// and the published heartbeat (`board`) moved within the last half period; stops
/// pinging as soon as either stands still, and returns at shutdown.
pub async fn watchdog(
    liveness: Arc<Liveness>,
    board: Arc<Board>,
    watchdog: Duration,
    mut ping: impl FnMut(),
    mut shutdown: Shutdown,
) {
    let check = watchdog / 4;
    let fresh_within = watchdog / 2;
    let heartbeat = || board.results().heartbeat;
    let (mut turns, mut beat) = (liveness.analysis_turns(), heartbeat());
    let (mut turned_at, mut beat_at) = (Instant::now(), Instant::now());
    let mut ticks = tokio::time::interval(check);
    loop {
        tokio::select! {
            _ = ticks.tick() => {}
            () = shutdown.recv() => return,
        }
        let now = Instant::now();
        let (turns_now, beat_now) = (liveness.analysis_turns(), heartbeat());
        if turns_now != turns {
            (turns, turned_at) = (turns_now, now);
        }
        if beat_now != beat {
            (beat, beat_at) = (beat_now, now);
        }
        let analysis_alive = now - turned_at < fresh_within;
        let outputs_alive = now - beat_at < fresh_within;
        if analysis_alive && outputs_alive {
            ping();
        } else {
            tracing::error!(
                analysis_alive,
                outputs_alive,
                "no progress: watchdog not pinged"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn board() -> Arc<Board> {
        let config = millgate_config::from_toml_str(
            include_str!("../../config/examples/demo.toml"),
            "demo.toml",
            // The demo's driveline model is named relative to the examples folder.
            std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples")),
        )
        .unwrap();
        Arc::new(Board::new(&config, Vec::new()))
    }

    #[tokio::test(start_paused = true)]
    async fn pings_only_while_analysis_and_heartbeat_move() {
        let liveness = Arc::new(Liveness::default());
        let board = board();
        let pings = Arc::new(AtomicU64::new(0));
        let (stop, shutdown) = crate::shutdown::channel();
        let counted = Arc::clone(&pings);
        let task = tokio::spawn(watchdog(
            Arc::clone(&liveness),
            Arc::clone(&board),
            Duration::from_secs(4),
            move || {
                counted.fetch_add(1, Ordering::Relaxed);
            },
            shutdown,
        ));
        let pinged = || pings.load(Ordering::Relaxed);
        // Both move every 100 ms for 10 s: a ping every second.
        for _ in 0..100 {
            liveness.analysis_turned();
            board.beat();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let while_alive = pinged();
        assert!(
            (9..=11).contains(&while_alive),
            "{while_alive} pings in 10 s"
        );
        // The analysis is stuck (no turn) while the heartbeat goes on: pings stop
        // within half the period.
        for _ in 0..50 {
            board.beat();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let stuck = pinged() - while_alive;
        assert!(stuck <= 2, "{stuck} pings with the analysis stuck for 5 s");
        // Back alive, then the outputs stall.
        for _ in 0..30 {
            liveness.analysis_turned();
            board.beat();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let back = pinged();
        assert!(back > while_alive + stuck, "pings again");
        for _ in 0..50 {
            liveness.analysis_turned();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert!(pinged() - back <= 2, "no pings with the heartbeat stuck");
        stop.trigger();
        task.await.unwrap();
    }

    #[test]
    fn the_watchdog_must_be_four_heartbeats() {
        let second = Duration::from_secs(1);
        assert!(check_watchdog(4 * second, second).is_ok());
        let error = check_watchdog(3 * second, second).unwrap_err();
        assert!(error.to_string().contains("at least 4 times"), "{error}");
    }
}
