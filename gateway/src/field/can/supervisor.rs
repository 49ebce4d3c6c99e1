//! The supervisor of one CAN source: keeps its [`CanReader`] open across interface
//! failures.

use std::sync::Arc;

use millgate_config::{ChannelSource, Config};
use tokio::sync::mpsc;

use super::error::CanError;
use super::reader::CanReader;
use crate::field::acquired::Acquired;
use crate::field::backoff::Backoff;
use crate::field::counters::{CanCounters, ChannelCounters};
use crate::field::source_health::SourceHealth;
use crate::shutdown::Shutdown;

/// Keep CAN source `index` read until shutdown: open its interface, read it, and on
/// any failure (interface absent, down, removed) mark the gap on its channels and
/// reopen with capped backoff, so an interface that goes down and comes back is
/// survived. The readers count into `counters` (the source's) and `channel_counters`
/// (indexed like `config.channels`).
pub(crate) async fn supervise_can(
    config: Arc<Config>,
    index: usize,
    health: Arc<SourceHealth>,
    (counters, channel_counters): (Arc<CanCounters>, Vec<Arc<ChannelCounters>>),
    samples: mpsc::Sender<Acquired>,
    mut shutdown: Shutdown,
) {
    let name = &config.can_sources[index].name;
    let channels: Vec<usize> = config
        .channels
        .iter()
        .enumerate()
        .filter(|(_, c)| matches!(c.source, ChannelSource::Can { source, .. } if source == index))
        .map(|(channel, _)| channel)
        .collect();
    let mut backoff = Backoff::new();
    let mut read_before = false;
    while !shutdown.is_shutdown() {
        let error = match CanReader::open(&config, index) {
            Ok(reader) => {
                health.set_connected(true);
                backoff.reset();
                if read_before {
                    // Frames sent while the interface was away are lost: no silent join.
                    for &channel in &channels {
                        let gap = Acquired::Gap {
                            channel,
                            missed_samples: None,
                        };
                        if samples.send(gap).await.is_err() {
                            return;
                        }
                    }
                }
                read_before = true;
                let result = reader
                    .with_health(Arc::clone(&health))
                    .with_counters(Arc::clone(&counters))
                    .with_channel_counters(channel_counters.clone())
                    .run(samples.clone(), shutdown.receiver())
                    .await;
                health.set_connected(false);
                match result {
                    Ok(()) => return,
                    Err(CanError::SamplesClosed { .. }) => return,
                    Err(error) => error,
                }
            }
            Err(error) => error,
        };
        let delay = backoff.next_delay();
        tracing::warn!(source = %name, %error, retry_in = ?delay, "CAN source failed");
        tokio::select! {
            () = tokio::time::sleep(delay) => {}
            () = shutdown.recv() => return,
        }
    }
}
