//! The edge node's state in the history file: its session number (bdSeq), the bites
//! it publishes (read on a blocking thread), and the replay cursor kept as the broker
//! confirms them ([`super::forward`] says what the cursor means).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use super::forward;
use super::status::SparkplugStatus;
use crate::history::query::HistoryReader;
use crate::history::writer::connect;
use crate::history::HistoryError;

/// How often the replay cursor is stored (when it moved) and the backlog counted.
const CURSOR_PERIOD: Duration = Duration::from_millis(250);

/// The next session number of `node` (`group_id/node_id`) in the history file at
/// `path`: the last one plus one, modulo 256 (0 for a new node); stored before it is
/// returned, so the Will and the NBIRTH of the next session always carry a new one.
pub fn next_bd_seq(path: &Path, node: &str) -> Result<u8, HistoryError> {
    let connection = connect(path)?;
    let bd_seq: i64 = connection
        .query_row(
            "INSERT INTO sparkplug_node (node, bd_seq, updated_at) VALUES (?1, 0, ?2)
             ON CONFLICT (node) DO UPDATE SET bd_seq = (bd_seq + 1) % 256,
                 updated_at = excluded.updated_at
             RETURNING bd_seq",
            rusqlite::params![node, crate::state::time::UtcTime::now().to_string()],
            |row| row.get(0),
        )
        .map_err(|source| HistoryError::Sqlite {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(u8::try_from(bd_seq).unwrap_or(0))
}

/// The history file's bites, read on a blocking thread with one read-only
/// connection, opened when first needed and again after a failure.
#[derive(Debug)]
pub(super) struct BiteSource {
    path: PathBuf,
    reader: Option<HistoryReader>,
    failing: bool,
}

impl BiteSource {
    pub(super) fn new(path: PathBuf) -> Self {
        Self {
            path,
            reader: None,
            failing: false,
        }
    }

    /// `read`'s answer; `None` when the file cannot be read (logged once per failure).
    pub(super) async fn read<T: Send + 'static>(
        &mut self,
        read: impl FnOnce(&HistoryReader) -> Result<T, HistoryError> + Send + 'static,
    ) -> Option<T> {
        let (path, taken) = (self.path.clone(), self.reader.take());
        let joined = tokio::task::spawn_blocking(move || {
            let reader = match taken {
                Some(reader) => reader,
                None => HistoryReader::open(&path)?,
            };
            let value = read(&reader)?;
            Ok::<_, HistoryError>((reader, value))
        })
        .await;
        match joined {
            Ok(Ok((reader, value))) => {
                self.reader = Some(reader);
                self.failing = false;
                Some(value)
            }
            Ok(Err(error)) => {
                if !self.failing {
                    tracing::error!(%error, "Sparkplug: the history's bites cannot be read");
                }
                self.failing = true;
                None
            }
            Err(error) => {
                tracing::error!(%error, "Sparkplug history task failed");
                None
            }
        }
    }
}

/// Every [`CURSOR_PERIOD`] until `stop` (and once more then): store the replay cursor
/// `confirmed` of `node` in the history file `history` when it moved, and count the
/// backlog after it into `status`.
pub(super) async fn keep_cursor(
    history: PathBuf,
    node: String,
    status: Arc<SparkplugStatus>,
    confirmed: Arc<AtomicI64>,
    mut stop: tokio::sync::oneshot::Receiver<()>,
) {
    let mut bites = BiteSource::new(history.clone());
    let mut stored = confirmed.load(Ordering::Relaxed);
    let mut period = tokio::time::interval(CURSOR_PERIOD);
    loop {
        let stopping = tokio::select! {
            _ = &mut stop => true,
            _ = period.tick() => false,
        };
        let cursor = confirmed.load(Ordering::Relaxed);
        if cursor != stored {
            let (path, key) = (history.clone(), node.clone());
            let done =
                tokio::task::spawn_blocking(move || forward::store_cursor(&path, &key, cursor))
                    .await;
            match done {
                Ok(Ok(())) => stored = cursor,
                Ok(Err(error)) => tracing::warn!(%error, "Sparkplug replay cursor not stored"),
                Err(error) => tracing::error!(%error, "Sparkplug cursor task failed"),
            }
        }
        if let Some(backlog) = bites.read(move |reader| reader.bites_after(cursor)).await {
            status.backlog.store(backlog, Ordering::Relaxed);
        }
        if stopping {
            break;
        }
    }
}
