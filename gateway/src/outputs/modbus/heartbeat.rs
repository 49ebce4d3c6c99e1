//! The heartbeat without a PLC output: the PLC writer moves the heartbeat on every
//! write period; without one, this task does, so an HMI reading the server does not
//! take a live gateway for dead.

use std::sync::Arc;
use std::time::Duration;

use crate::shutdown::Shutdown;
use crate::state::board::Board;

/// Heartbeat period when no PLC output sets it (the server's HMIs still watch it).
pub(crate) const HEARTBEAT_WITHOUT_PLC: Duration = Duration::from_secs(1);

/// Moves the heartbeat every [`HEARTBEAT_WITHOUT_PLC`] until shutdown: without a
/// PLC writer nothing else would, and an HMI would take the gateway for dead.
pub(crate) async fn beat_without_plc(board: Arc<Board>, mut shutdown: Shutdown) {
    let mut ticks = tokio::time::interval(HEARTBEAT_WITHOUT_PLC);
    loop {
        tokio::select! {
            _ = ticks.tick() => board.beat(),
            () = shutdown.recv() => break,
        }
    }
}
