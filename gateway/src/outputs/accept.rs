//! What a listener's accept loop does when `accept` fails, shared by the HMI Modbus
//! server and the maintenance page.

use std::time::Duration;

/// Accept failures in a row after which the listener gives up.
const MAX_FAILURES_IN_A_ROW: u32 = 100;
/// Pause after a failed accept.
const BACKOFF: Duration = Duration::from_millis(100);

/// Failed accepts in a row of one listener.
#[derive(Debug, Default)]
pub(crate) struct AcceptFailures(u32);

impl AcceptFailures {
    /// A connection was accepted: the count starts again.
    pub(crate) fn accepted(&mut self) {
        self.0 = 0;
    }

    /// `accept` failed (out of descriptors or memory): warn, back off a little, and
    /// give the error back once [`MAX_FAILURES_IN_A_ROW`] failed in a row (a listener
    /// that keeps failing is a fault of the service).
    pub(crate) async fn failed(
        &mut self,
        error: std::io::Error,
        listener: &str,
    ) -> Result<(), std::io::Error> {
        self.0 += 1;
        tracing::warn!(%error, "{listener} accept failed");
        if self.0 >= MAX_FAILURES_IN_A_ROW {
            return Err(error);
        }
        tokio::time::sleep(BACKOFF).await;
        Ok(())
    }
}
