//! The one change signal every output waits on: a versioned watch of what moved, the
//! results on the board ([`Version::results`], bumped by every change the analysis or a
//! command makes) and the events the history has settled ([`Version::settled`],
//! committed to the file or known dropped, in queue order). An output holds a
//! [`Changes`] and wakes when the part it publishes moved: the PLC writer, OPC UA and
//! the web page on the results, the Sparkplug node (which reads its bites from the
//! file) on the history. No output polls.
//!
//! Changes that come faster than an output takes them are coalesced (a watch holds
//! the latest version): an output always sees the newest state, never a queue of old
//! ones.

use std::sync::Arc;

use tokio::sync::watch;

/// What has changed so far: counters that only grow.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Version {
    /// Changes of the results on the board.
    pub results: u64,
    /// Events the history has settled (committed or dropped), in queue order.
    pub settled: u64,
}

/// The sending side, shared by the board and the history's writer.
#[derive(Debug, Clone)]
pub struct Signal(Arc<watch::Sender<Version>>);

impl Default for Signal {
    fn default() -> Self {
        Self(Arc::new(watch::channel(Version::default()).0))
    }
}

impl Signal {
    /// The results changed.
    pub(crate) fn results_changed(&self) {
        self.0
            .send_modify(|version| version.results = version.results.wrapping_add(1));
    }

    /// The history has settled its first `events` events.
    pub(crate) fn settled(&self, events: u64) {
        self.0.send_if_modified(|version| {
            let moved = version.settled != events;
            version.settled = events;
            moved
        });
    }

    /// The version now.
    pub fn now(&self) -> Version {
        *self.0.borrow()
    }

    /// A waiter that has seen everything up to now.
    pub fn subscribe(&self) -> Changes {
        let mut receiver = self.0.subscribe();
        let seen = *receiver.borrow_and_update();
        Changes { receiver, seen }
    }
}

/// One output's view of the signal: what it has seen.
#[derive(Debug)]
pub struct Changes {
    receiver: watch::Receiver<Version>,
    seen: Version,
}

impl Changes {
    /// Wait until `part` of the version moved past what this waiter has seen, and see
    /// it (returns at once when it moved since the last wait).
    async fn moved(&mut self, part: fn(&Version) -> u64) -> Version {
        let seen = part(&self.seen);
        // The sender lives as long as the board; gone, nothing changes any more.
        let moved = self
            .receiver
            .wait_for(|version| part(version) != seen)
            .await
            .map(|version| *version);
        match moved {
            Ok(version) => self.seen = version,
            Err(_) => std::future::pending::<()>().await,
        }
        self.seen
    }

    /// Wait until the results changed since the last wait.
    pub async fn results(&mut self) -> Version {
        self.moved(|version| version.results).await
    }

    /// Count the results up to `version` (a [`Signal::now`]'s) as seen: a waiter that
    /// has taken results at least that new is not woken for them again.
    pub(crate) fn saw_results(&mut self, version: u64) {
        self.seen.results = version;
    }

    /// Wait until the history settled more events since the last wait.
    pub async fn settled(&mut self) -> Version {
        self.moved(|version| version.settled).await
    }

    /// Wait until the history has settled its first `through` events.
    pub(crate) async fn settled_through(&mut self, through: u64) {
        let reached = self
            .receiver
            .wait_for(|version| version.settled >= through)
            .await
            .is_ok();
        if !reached {
            std::future::pending::<()>().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test(start_paused = true)]
    async fn a_waiter_wakes_for_its_part_and_changes_coalesce() {
        let signal = Signal::default();
        let mut results = signal.subscribe();
        let mut settled = signal.subscribe();
        let nothing = tokio::time::timeout(Duration::from_secs(1), results.results()).await;
        assert!(nothing.is_err(), "nothing changed yet");
        signal.results_changed();
        signal.results_changed();
        signal.results_changed();
        assert_eq!(
            results.results().await.results,
            3,
            "three changes, one wake"
        );
        let again = tokio::time::timeout(Duration::from_secs(1), results.results()).await;
        assert!(again.is_err(), "seen");
        let untouched = tokio::time::timeout(Duration::from_secs(1), settled.settled()).await;
        assert!(untouched.is_err(), "the results are not the history");
        signal.settled(4);
        assert_eq!(settled.settled().await.settled, 4);
        signal.settled(4);
        let same = tokio::time::timeout(Duration::from_secs(1), settled.settled()).await;
        assert!(same.is_err(), "the same count is no change");
        tokio::time::timeout(Duration::from_secs(1), settled.settled_through(4))
            .await
            .expect("reached");
    }
}
