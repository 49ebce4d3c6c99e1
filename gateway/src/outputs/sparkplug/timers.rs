//! The edge node's timing decisions, apart from its I/O so a paused clock tests them:
//! rebirths on command at most one per [`REBIRTH_INTERVAL`] ([`Rebirths`]), and the
//! wait before the next connection ([`Reconnect`]). The node's real-time runs against
//! mosquitto and a Python host are `gateway/tests/sparkplug.rs`.

use std::time::Duration;

use tokio::time::Instant;

/// Shortest time between two rebirths on command.
pub const REBIRTH_INTERVAL: Duration = Duration::from_secs(5);
/// Wait before connecting again after a failed connection.
pub(super) const RECONNECT_DELAY: Duration = Duration::from_secs(1);
/// Longest wait before connecting again after sessions ended by oversized packets.
const MAX_OVERSIZE_DELAY: Duration = Duration::from_secs(60);

/// Rebirths on command: every Rebirth NCMD since the last births is answered by one
/// rebirth, at most one per [`REBIRTH_INTERVAL`] (requests meanwhile wait for its end).
#[derive(Debug)]
pub(super) struct Rebirths {
    /// A Rebirth NCMD came since the last births.
    wanted: bool,
    last_births: Instant,
}

impl Rebirths {
    pub(super) fn new() -> Self {
        Self {
            wanted: false,
            last_births: Instant::now(),
        }
    }

    /// Births went out now (a session's first, or a rebirth).
    pub(super) fn born(&mut self) {
        self.wanted = false;
        self.last_births = Instant::now();
    }

    /// A new session: the last session's requests are forgotten.
    pub(super) fn forget(&mut self) {
        self.wanted = false;
    }

    /// A Rebirth NCMD came.
    pub(super) fn requested(&mut self) {
        self.wanted = true;
    }

    /// Whether a rebirth waits.
    pub(super) fn wanted(&self) -> bool {
        self.wanted
    }

    /// When the waiting rebirth is due: [`REBIRTH_INTERVAL`] after the last births
    /// (already passed when they are older).
    pub(super) fn due(&self) -> Instant {
        self.last_births + REBIRTH_INTERVAL
    }
}

/// The wait before connecting again: [`RECONNECT_DELAY`] after a failed connection or
/// session; after sessions that packets over the size limit ended (a retained NCMD the
/// broker sends at every subscription), twice the last such wait, up to
/// [`MAX_OVERSIZE_DELAY`].
#[derive(Debug)]
pub(super) struct Reconnect {
    /// The wait after the next oversized packet.
    oversize: Duration,
}

impl Reconnect {
    pub(super) fn new() -> Self {
        Self {
            oversize: RECONNECT_DELAY,
        }
    }

    /// The wait after a connection or session that ended, by a packet over the size
    /// limit (`oversize`) or otherwise.
    pub(super) fn delay(&mut self, oversize: bool) -> Duration {
        if oversize {
            let delay = self.oversize;
            self.oversize = (delay * 2).min(MAX_OVERSIZE_DELAY);
            delay
        } else {
            self.oversize = RECONNECT_DELAY;
            RECONNECT_DELAY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The node's rebirth arm in a loop of its own: Rebirth NCMDs at `requests`
    /// (after the first births at the start), births when due; the rebirths' times,
    /// seconds from the start, up to `until_s`.
    async fn rebirths_for(requests: &[f64], until_s: f64) -> Vec<f64> {
        let start = Instant::now();
        let at = |s: f64| start + Duration::from_secs_f64(s);
        let mut rebirths = Rebirths::new();
        rebirths.born();
        let mut requests = requests.iter().map(|&s| at(s)).peekable();
        let mut answered = Vec::new();
        let end = tokio::time::sleep_until(at(until_s));
        tokio::pin!(end);
        loop {
            let next_request = requests.peek().copied();
            tokio::select! {
                () = &mut end => break,
                () = tokio::time::sleep_until(next_request.unwrap_or(at(until_s))), if next_request.is_some() => {
                    requests.next();
                    rebirths.requested();
                }
                () = tokio::time::sleep_until(rebirths.due()), if rebirths.wanted() => {
                    rebirths.born();
                    answered.push((Instant::now() - start).as_secs_f64());
                }
            }
        }
        answered
    }

    #[tokio::test(start_paused = true)]
    async fn a_flood_of_rebirth_requests_gets_one_rebirth_per_interval() {
        // A request every 10 ms from 1 s to 16 s: 1 500 of them.
        let flood: Vec<f64> = (100..1600).map(|k| f64::from(k) / 100.0).collect();
        assert_eq!(
            rebirths_for(&flood, 30.0).await,
            [5.0, 10.0, 15.0, 20.0],
            "each interval's requests answered at its end, one rebirth each"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_request_after_a_quiet_interval_is_answered_at_once() {
        // The births are 7 s old at the first request: a rebirth at once; the second
        // request waits for the interval from that rebirth.
        assert_eq!(rebirths_for(&[7.0, 8.0], 20.0).await, [7.0, 12.0]);
    }

    #[tokio::test(start_paused = true)]
    async fn a_new_session_forgets_the_last_ones_requests() {
        let mut rebirths = Rebirths::new();
        rebirths.born();
        rebirths.requested();
        rebirths.forget();
        assert!(!rebirths.wanted());
        tokio::time::advance(REBIRTH_INTERVAL * 2).await;
        assert!(!rebirths.wanted(), "nothing due");
    }

    #[tokio::test(start_paused = true)]
    async fn sessions_ended_by_oversized_packets_come_ever_further_apart_up_to_a_minute() {
        // A session at each connection, ended by an oversized packet (a retained NCMD
        // the old code never cleared): the waits between them, then a session ended
        // otherwise and one oversized again.
        let start = Instant::now();
        let mut reconnect = Reconnect::new();
        let mut sessions = vec![0];
        for oversize in [true, true, true, true, true, true, true, true, false, true] {
            tokio::time::sleep(reconnect.delay(oversize)).await;
            sessions.push((Instant::now() - start).as_secs());
        }
        assert_eq!(
            sessions,
            [0, 1, 3, 7, 15, 31, 63, 123, 183, 184, 185],
            "1, 2, 4 ... 60 s apart; back to 1 s after a session ended otherwise"
        );
    }
}
