//! The checkpointer thread: copies the write-ahead log into the database file off the
//! writer thread, so no commit (and no bite the PLC waits for) pays for a checkpoint.
//!
//! SQLite checkpoints a WAL file on the connection whose commit made it pass
//! `wal_autocheckpoint` pages: on the writer, that commit then also waited for the
//! WAL's sync, the copy into the database file and the database file's sync. Here a
//! connection of its own runs `PRAGMA wal_checkpoint(PASSIVE)` every
//! [`CHECKPOINT_PERIOD`]: a passive checkpoint never waits for the writer, and the
//! writer appends to the WAL while it runs. The writer keeps its own automatic
//! checkpoint at [`FALLBACK_CHECKPOINT_PAGES`], far above what the WAL reaches between
//! two of these, so the WAL stays bounded should this thread fail.
//!
//! A checkpoint that fails (a full disk: the database file cannot grow, while the
//! commits may still fit in the WAL's room) makes the history's state failing, with
//! the reason, until one succeeds again.

use std::path::PathBuf;
use std::sync::mpsc::{sync_channel, RecvTimeoutError, SyncSender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use rusqlite::{Connection, OpenFlags};

use super::error::explain;
use super::schema::APPLICATION_ID;
use crate::state::history::{Counters, HistoryState};

/// Time between two checkpoints.
pub(super) const CHECKPOINT_PERIOD: Duration = Duration::from_millis(500);
/// WAL pages past which the writer's own commit checkpoints (the fallback should this
/// thread not keep up): 40 MiB at 4 KiB pages.
pub(super) const FALLBACK_CHECKPOINT_PAGES: i64 = 10_000;

/// The device and inode of the file at `path`, `None` when there is none: the writer
/// and the checkpointer notice a file deleted or replaced by it.
pub(super) fn file_identity(path: &std::path::Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path)
        .ok()
        .map(|metadata| (metadata.dev(), metadata.ino()))
}

/// The running checkpointer; dropping it stops the thread and waits for it.
#[derive(Debug)]
pub(super) struct Checkpointer {
    stop: Option<SyncSender<()>>,
    thread: Option<JoinHandle<()>>,
}

impl Checkpointer {
    /// Start checkpointing the file at `path` (a file that does not exist yet is
    /// opened once it does). `None` when the thread cannot be started: the writer's
    /// automatic checkpoint then does the work.
    pub(super) fn start(path: PathBuf, counters: Arc<Counters>) -> Option<Self> {
        let (stop, stopped) = sync_channel::<()>(0);
        let thread = std::thread::Builder::new()
            .name("HistoryCheckpointer".into())
            .spawn(move || {
                let mut open: Option<(Connection, Option<(u64, u64)>)> = None;
                while let Err(RecvTimeoutError::Timeout) = stopped.recv_timeout(CHECKPOINT_PERIOD) {
                    checkpoint(&path, &mut open, &counters);
                }
            });
        match thread {
            Ok(thread) => Some(Self {
                stop: Some(stop),
                thread: Some(thread),
            }),
            Err(error) => {
                tracing::warn!(%error, "cannot start the history checkpointer thread: the writer checkpoints");
                None
            }
        }
    }
}

impl Drop for Checkpointer {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(thread) = self.thread.take() {
            if thread.join().is_err() {
                tracing::error!("the history checkpointer thread panicked");
            }
        }
    }
}

/// One passive checkpoint of the file at `path`, on the connection in `open`
/// (opened again when the file at the path is another one than it has open); its
/// failure or success again on `counters` and in the log. A file that is not (or not
/// yet) a millgate history is left alone: the writer refuses another application's
/// file, and its WAL is not this thread's to copy.
fn checkpoint(
    path: &std::path::Path,
    open: &mut Option<(Connection, Option<(u64, u64)>)>,
    counters: &Counters,
) {
    let identity = file_identity(path);
    if identity.is_none() {
        *open = None;
        return;
    }
    if open.as_ref().is_none_or(|(_, opened)| *opened != identity) {
        // Never creates the file: the writer does, with its schema.
        *open = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .ok()
        .filter(|connection| {
            connection
                .query_row("PRAGMA application_id", [], |row| row.get::<_, i64>(0))
                .is_ok_and(|id| id == APPLICATION_ID)
        })
        .map(|connection| (connection, identity));
    }
    let Some((connection, _)) = open.as_ref() else {
        return;
    };
    // (busy, WAL frames, frames checkpointed); a busy checkpoint is tried again next time.
    let done = connection.query_row("PRAGMA wal_checkpoint(PASSIVE)", [], |row| {
        row.get::<_, i64>(0)
    });
    match done {
        Ok(_) => {
            if counters.checkpointed(None) {
                counters.set_state(HistoryState::Ok);
                tracing::info!(path = %path.display(), "history stored again (checkpoints succeed again)");
            }
        }
        Err(error) => {
            let message = format!(
                "history {}: checkpoint failed (the last commits stay in the WAL): {}",
                path.display(),
                explain(&error)
            );
            if counters.checkpointed(Some(message.clone())) {
                tracing::error!(
                    error = message,
                    "history checkpoints fail; tried again every 0.5 s"
                );
            }
            *open = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A WAL-mode file whose last rows are still in its WAL (no automatic
    /// checkpoint), with `application_id` `id`; the connection keeps the WAL.
    fn file_with_wal(path: &std::path::Path, id: i64) -> Connection {
        let db = Connection::open(path).unwrap();
        db.pragma_update(None, "journal_mode", "wal").unwrap();
        db.pragma_update(None, "wal_autocheckpoint", 0).unwrap();
        db.pragma_update(None, "application_id", id).unwrap();
        db.execute_batch("CREATE TABLE t (x BLOB); PRAGMA wal_checkpoint(TRUNCATE);")
            .unwrap();
        for _ in 0..50 {
            db.execute("INSERT INTO t VALUES (zeroblob(4000))", [])
                .unwrap();
        }
        db
    }

    #[test]
    fn another_applications_file_is_not_checkpointed_a_history_is() {
        let folder =
            std::env::temp_dir().join(format!("millgate-checkpoint-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&folder);
        std::fs::create_dir_all(&folder).unwrap();
        let counters = Counters::default();
        let mut open = None;

        let foreign = folder.join("foreign.db");
        let _keep = file_with_wal(&foreign, 0x1234_5678);
        let size = std::fs::metadata(&foreign).unwrap().len();
        checkpoint(&foreign, &mut open, &counters);
        assert!(
            open.is_none(),
            "another application's file is not kept open"
        );
        assert_eq!(
            std::fs::metadata(&foreign).unwrap().len(),
            size,
            "its WAL was not copied into it"
        );

        let ours = folder.join("history.db");
        let _keep = file_with_wal(&ours, APPLICATION_ID);
        let size = std::fs::metadata(&ours).unwrap().len();
        checkpoint(&ours, &mut open, &counters);
        assert!(open.is_some());
        assert!(
            std::fs::metadata(&ours).unwrap().len() > size + 100_000,
            "a history's WAL is copied into it"
        );
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
