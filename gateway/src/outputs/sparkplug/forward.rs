//! Store-and-forward: every bite goes to the broker from the history file, in
//! `bites.id` order, and the file keeps how far the broker has confirmed.
//!
//! - **Cursor.** `sparkplug_node.replay_cursor` is the last `bites.id` such that every
//!   bite up to it was acknowledged by the broker ([`load_cursor`], [`store_cursor`]).
//!   A node new to the file starts at the file's last bite: what was recorded before
//!   the node existed is not its backlog.
//! - **Confirmation.** Bite DDATAs go at QoS 1, and the broker's PUBACK confirms one
//!   ([`Confirmations`]). Sparkplug asks for QoS 0 on DDATA; this is a deliberate
//!   deviation. With QoS 0 the only in-band sign that the broker has read a publish
//!   is the answer to a PINGREQ sent after it on the same stream, but rumqttc 0.25
//!   sends its own keep-alive PINGREQ on a timer the client cannot reset and treats a
//!   second PINGREQ before the PINGRESP as a connection error, so extra PINGREQs would
//!   end sessions at random; and a cursor confirmed only by keep-alive pings would lag
//!   by up to `keep_alive_s`. Births, NDATA and the other DDATA stay QoS 0.
//! - **Replay.** At each session's births, the bites after the cursor up to the file's
//!   last one are the backlog: they go as DDATA flagged `is_historical`, with their
//!   own time and bite id, `replay_batch` per `replay_period`; bites recorded
//!   meanwhile follow, live, in order. A session lost before a bite's PUBACK replays
//!   it (flagged historical) in the next one: a host sees each bite once live or
//!   flagged historical, and drops duplicates by (device, bite_id).

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::path::Path;

use crate::history::writer::connect;
use crate::history::HistoryError;
use crate::state::time::UtcTime;

fn sqlite(path: &Path) -> impl FnOnce(rusqlite::Error) -> HistoryError + '_ {
    move |source| HistoryError::Sqlite {
        path: path.to_path_buf(),
        source,
    }
}

/// The replay cursor of `node` (`group_id/node_id`, whose row [`super::next_bd_seq`]
/// made): the last `bites.id` the broker confirmed. Unset, or beyond the file's last
/// bite (the bites were deleted), it is set to the file's last bite first.
pub fn load_cursor(path: &Path, node: &str) -> Result<i64, HistoryError> {
    let connection = connect(path)?;
    connection
        .query_row(
            "UPDATE sparkplug_node SET replay_cursor = last.id
             FROM (SELECT coalesce(max(id), 0) AS id FROM bites) AS last
             WHERE node = ?1 AND (replay_cursor IS NULL OR replay_cursor > last.id)
             RETURNING replay_cursor",
            [node],
            |row| row.get::<_, i64>(0),
        )
        .or_else(|error| match error {
            rusqlite::Error::QueryReturnedNoRows => connection.query_row(
                "SELECT coalesce(replay_cursor, 0) FROM sparkplug_node WHERE node = ?1",
                [node],
                |row| row.get(0),
            ),
            error => Err(error),
        })
        .map_err(sqlite(path))
}

/// Store `cursor` as `node`'s replay cursor.
pub fn store_cursor(path: &Path, node: &str, cursor: i64) -> Result<(), HistoryError> {
    let connection = connect(path)?;
    connection
        .execute(
            "UPDATE sparkplug_node SET replay_cursor = ?2, updated_at = ?3 WHERE node = ?1",
            rusqlite::params![node, cursor, UtcTime::now().to_string()],
        )
        .map_err(sqlite(path))?;
    Ok(())
}

/// Which bites the broker has confirmed, from the MQTT client's events: every publish
/// handed to the client is noted in order ([`Self::queued`]); the client's outgoing
/// PUBLISH events, in the same order, give each bite its packet id
/// ([`Self::written`]); a PUBACK confirms it ([`Self::acknowledged`]).
#[derive(Debug, Clone, Default)]
pub struct Confirmations {
    /// Publishes handed to the client and not yet written: the bite's row id, `None`
    /// for another message.
    queued: VecDeque<Option<i64>>,
    /// Written bites waiting for their PUBACK, by packet id.
    written: HashMap<u16, i64>,
    /// Row ids of the bites handed over and not yet acknowledged.
    outstanding: BTreeSet<i64>,
    /// Every row up to this id was read and either acknowledged or skipped.
    read: i64,
    /// Every bite up to this row id is confirmed.
    confirmed: i64,
}

impl Confirmations {
    /// Starting at `cursor` (the stored one): every bite up to it is confirmed.
    pub fn new(cursor: i64) -> Self {
        Self {
            read: cursor,
            confirmed: cursor,
            ..Self::default()
        }
    }

    /// Every bite up to this row id is confirmed.
    pub fn confirmed(&self) -> i64 {
        self.confirmed
    }

    /// The last row read: the next read starts after it.
    pub fn read(&self) -> i64 {
        self.read
    }

    /// Bites handed to the client and not yet acknowledged.
    pub(crate) fn outstanding(&self) -> usize {
        self.outstanding.len()
    }

    /// A publish was handed to the client: bite row `row`, or another message.
    pub fn queued(&mut self, row: Option<i64>) {
        if let Some(row) = row {
            self.outstanding.insert(row);
        }
        self.queued.push_back(row);
    }

    /// Rows up to `row` were read and handed over or skipped (another driveline).
    pub(crate) fn read_up_to(&mut self, row: i64) {
        self.read = self.read.max(row);
        self.update();
    }

    /// The client wrote the next publish with packet id `pkid` (0 for QoS 0).
    pub fn written(&mut self, pkid: u16) {
        if let Some(Some(row)) = self.queued.pop_front() {
            self.written.insert(pkid, row);
        }
    }

    /// The broker acknowledged packet `pkid`.
    pub fn acknowledged(&mut self, pkid: u16) {
        if let Some(row) = self.written.remove(&pkid) {
            self.outstanding.remove(&row);
            self.update();
        }
    }

    fn update(&mut self) {
        self.confirmed = match self.outstanding.first() {
            Some(first) => first - 1,
            None => self.read,
        };
    }

    /// The session is gone: what it did not confirm is read again in the next one.
    pub(crate) fn session_lost(&mut self) {
        self.queued.clear();
        self.written.clear();
        self.outstanding.clear();
        self.read = self.confirmed;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bite_is_confirmed_by_its_puback_and_the_cursor_waits_for_the_oldest() {
        let mut confirmations = Confirmations::new(10);
        // NBIRTH (QoS 0), then bites 11, 12, 14 (13 is another node's driveline).
        confirmations.queued(None);
        for row in [11, 12, 14] {
            confirmations.queued(Some(row));
        }
        confirmations.read_up_to(14);
        assert_eq!(
            (confirmations.confirmed(), confirmations.outstanding()),
            (10, 3)
        );
        confirmations.written(0);
        confirmations.written(1);
        confirmations.written(2);
        confirmations.written(3);
        // The second bite's PUBACK first: the first is still open.
        confirmations.acknowledged(2);
        assert_eq!(confirmations.confirmed(), 10);
        confirmations.acknowledged(1);
        // 13 was skipped: everything up to 14 is done.
        assert_eq!(confirmations.confirmed(), 13);
        // An unknown packet id (the NDEATH's) changes nothing.
        confirmations.acknowledged(9);
        assert_eq!(confirmations.confirmed(), 13);
        // The session ends before 14's PUBACK: the next one reads after 13.
        confirmations.session_lost();
        assert_eq!((confirmations.read(), confirmations.outstanding()), (13, 0));
        confirmations.acknowledged(3);
        assert_eq!(confirmations.confirmed(), 13, "a stale PUBACK is ignored");
        confirmations.queued(Some(14));
        confirmations.read_up_to(14);
        confirmations.written(1);
        confirmations.acknowledged(1);
        assert_eq!(confirmations.confirmed(), 14);
    }

    #[test]
    fn the_cursor_starts_at_the_last_bite_and_is_kept_in_the_file() {
        let folder = std::env::temp_dir().join(format!("millgate-cursor-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&folder);
        std::fs::create_dir_all(&folder).unwrap();
        let path = folder.join("history.db");
        let connection = connect(&path).unwrap();
        connection
            .execute_batch(
                "INSERT INTO gateway_runs (id, started_at, version, config_name) VALUES (1, 't', 'v', 'c');
                 INSERT INTO bites (id, run_id, driveline, time, bite_counter, channel,
                     static_torque_knm, peak_torque_knm, quality, degraded)
                 VALUES (5, 1, 'F1', 't', 1, 'c', 1, 1, 'good', 0),
                        (9, 1, 'F1', 't', 2, 'c', 1, 1, 'good', 0);",
            )
            .unwrap();
        super::super::next_bd_seq(&path, "plant/f1").unwrap();
        // A node new to the file: what came before it is not its backlog.
        assert_eq!(load_cursor(&path, "plant/f1").unwrap(), 9);
        store_cursor(&path, "plant/f1", 5).unwrap();
        assert_eq!(load_cursor(&path, "plant/f1").unwrap(), 5, "kept");
        // Beyond the file's last bite (the bites were deleted): back to the last.
        store_cursor(&path, "plant/f1", 40).unwrap();
        assert_eq!(load_cursor(&path, "plant/f1").unwrap(), 9);
        drop(connection);
        let _ = std::fs::remove_dir_all(&folder);
    }
}
