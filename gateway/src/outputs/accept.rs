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
    /// What one `accept` gave: the connection (the count of failures starts again),
    /// or `None` after a failure (out of descriptors or memory: warned, with a short
    /// back-off). The error comes back once [`MAX_FAILURES_IN_A_ROW`] failed in a row
    /// (a listener that keeps failing is a fault of the service).
    pub(crate) async fn check<T>(
        &mut self,
        accepted: std::io::Result<T>,
        listener: &str,
    ) -> Result<Option<T>, std::io::Error> {
        match accepted {
            Ok(connection) => {
                self.0 = 0;
                Ok(Some(connection))
            }
            Err(error) => {
                self.0 += 1;
                tracing::warn!(%error, "{listener} accept failed");
                if self.0 >= MAX_FAILURES_IN_A_ROW {
                    return Err(error);
                }
                tokio::time::sleep(BACKOFF).await;
                Ok(None)
            }
        }
    }
}
