//! [`WarnLimit`]: a warning that repeats (a DAQ refusing connections, a PLC
//! unreachable, HMI clients beyond the limit) is logged the first time, then at most
//! once per period with the number of occurrences it stands for, so a peer failing
//! thousands of times a second cannot flood the journal.

use std::time::Duration;

use tokio::time::Instant;

/// Period of the summary lines of a repeating warning.
pub(crate) const WARN_PERIOD: Duration = Duration::from_secs(10);

/// Rate limit of one repeating warning.
#[derive(Debug)]
pub(crate) struct WarnLimit {
    period: Duration,
    last_logged: Option<Instant>,
    suppressed: u64,
}

impl WarnLimit {
    /// A limit of one line per `period` after the first.
    pub(crate) fn new(period: Duration) -> Self {
        Self {
            period,
            last_logged: None,
            suppressed: 0,
        }
    }

    /// One more occurrence at `now`. `Some(n)` when it is to be logged, `n` being the
    /// occurrences since the last logged line that were not (0 for the first);
    /// `None` when it is suppressed.
    pub(crate) fn occurred(&mut self, now: Instant) -> Option<u64> {
        match self.last_logged {
            Some(last) if now.saturating_duration_since(last) < self.period => {
                self.suppressed += 1;
                None
            }
            _ => {
                self.last_logged = Some(now);
                Some(std::mem::take(&mut self.suppressed))
            }
        }
    }

    /// The condition cleared (a good poll, a write that went through): the next
    /// occurrence is logged at once. Returns the occurrences suppressed since the last
    /// logged line, for a closing summary.
    pub(crate) fn clear(&mut self) -> u64 {
        self.last_logged = None;
        std::mem::take(&mut self.suppressed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_is_logged_then_one_summary_per_period() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut limit = WarnLimit::new(Duration::from_secs(10));
        assert_eq!(limit.occurred(t0), Some(0));
        // 6 000 occurrences in the next second: none logged.
        for i in 1..=6000 {
            assert_eq!(limit.occurred(t0 + ms(i / 6)), None);
        }
        assert_eq!(limit.occurred(t0 + ms(10_000)), Some(6000));
        assert_eq!(limit.occurred(t0 + ms(10_001)), None);
        assert_eq!(limit.clear(), 1);
        assert_eq!(
            limit.occurred(t0 + ms(10_002)),
            Some(0),
            "logged at once after clearing"
        );
    }
}
