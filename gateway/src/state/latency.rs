//! The gateway's own latencies, as histograms on `/metrics`: how long a block waits
//! between its reader and the analysis, how long a bite takes from the block that
//! completed its window to the PLC write that carried its counter, and where that
//! time goes (the bite's stages). The readers stamp each block when they hand it
//! over (`Acquired::Samples::handed`), the analysis observes the wait when it takes
//! the block up and gives each bite its block's stamp (`BiteReport::window_complete`);
//! the board keeps the stamps of the bites published and not yet written
//! (`Latencies::published`, under the results' lock, with the time of the
//! publication), the PLC writer takes them with the results it encodes (the time it
//! took them), and observes them once the PLC acknowledged the write
//! ([`Latencies::written`], with the time the write was sent).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::exposition::{Exposition, Families, Histogram};

/// Bucket bounds of the latency histograms, seconds: 0.1 ms to 100 ms in 1-2-5 steps
/// (the bench's bite -> PLC p99 ran from 3 to 20 ms; the goals are 5 and 10 ms).
pub const LATENCY_BOUNDS_S: [f64; 10] = [
    0.0001, 0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1,
];

/// Most bites that wait for a PLC write with their stamps: while the PLC is
/// unreachable bites go on, and those past this many are not observed (at 256
/// drivelines biting every 2 s, half a minute of them).
pub const MAX_WAITING_BITES: usize = 4096;

/// The stages of a bite's way to the PLC, in order: the label values of
/// `millgate_bite_stage_seconds`, and what each covers. A bite's stages add up to its
/// `millgate_bite_to_plc_seconds`.
pub const BITE_STAGES: [(&str, &str); 4] = [
    (
        "analysis",
        "the block's hand-over to the bite's publication: the block's wait for the analysis, \
         the wait for the driveline's earlier share and for a pool thread, and the bite's analysis",
    ),
    (
        "to_writer",
        "the publication to the PLC writer taking the bite with the results it writes \
         (a write under way, or a failed one, ends first)",
    ),
    (
        "history",
        "the writer taking it to sending the write: the wait for the history's commit of \
         what the write shows, and the encoding of the register map",
    ),
    (
        "write",
        "the write sent to the PLC's acknowledgement: every FC 16 request of the write, one \
         after the other",
    ),
];

/// A published bite's stamps on its way to the PLC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiteStamps {
    /// When the block that completed its window was handed over.
    pub handed: Instant,
    /// When it was published (its results on the board).
    pub published: Instant,
    /// When a PLC writer first took it with the results it writes (`None` before).
    pub taken: Option<Instant>,
}

/// The latency histograms and the stamps of the bites waiting for the PLC.
#[derive(Debug)]
pub struct Latencies {
    block_wait: Histogram,
    bite_to_plc: Histogram,
    /// A bite's stages, in the order of [`BITE_STAGES`].
    stages: [Histogram; 4],
    /// The stamps of the bites published and not yet written to the PLC; kept only
    /// while a PLC writer runs.
    waiting: Mutex<Vec<BiteStamps>>,
    /// PLC writers running (a reload starts the new one before the old one ends).
    plc_writers: AtomicUsize,
}

impl Default for Latencies {
    fn default() -> Self {
        Self {
            block_wait: Histogram::new(&LATENCY_BOUNDS_S),
            bite_to_plc: Histogram::new(&LATENCY_BOUNDS_S),
            stages: std::array::from_fn(|_| Histogram::new(&LATENCY_BOUNDS_S)),
            waiting: Mutex::new(Vec::new()),
            plc_writers: AtomicUsize::new(0),
        }
    }
}

impl Latencies {
    /// A block handed over `waited` ago was taken up by the analysis now.
    pub fn block_taken(&self, waited: Duration) {
        self.block_wait.observe(waited);
    }

    /// A bite whose window a block handed over at `handed` completed was published.
    /// Called under the board's results lock (`Board::update_bite`), so the PLC
    /// writer takes its stamp with the results that hold it, never before.
    pub(crate) fn published(&self, handed: Instant) {
        if self.plc_writers.load(Ordering::Relaxed) == 0 {
            return;
        }
        let published = Instant::now();
        let mut waiting = crate::lock(&self.waiting);
        if waiting.len() < MAX_WAITING_BITES {
            waiting.push(BiteStamps {
                handed,
                published,
                taken: None,
            });
        }
    }

    /// The stamps of the bites published so far, taken now by a PLC writer (called
    /// under the board's results lock, with the copy of the results to write).
    pub(crate) fn take_waiting(&self) -> Vec<BiteStamps> {
        let taken = Instant::now();
        let mut stamps = std::mem::take(&mut *crate::lock(&self.waiting));
        for stamp in &mut stamps {
            stamp.taken.get_or_insert(taken);
        }
        stamps
    }

    /// The PLC acknowledged the write, sent at `sent`, of the results that held the
    /// bites of `stamps`: each one's latency and stages are observed.
    pub fn written(&self, stamps: &[BiteStamps], sent: Instant) {
        let now = Instant::now();
        for stamp in stamps {
            let taken = stamp.taken.unwrap_or(sent);
            self.bite_to_plc
                .observe(now.saturating_duration_since(stamp.handed));
            let [analysis, to_writer, history, write] = &self.stages;
            analysis.observe(stamp.published.saturating_duration_since(stamp.handed));
            to_writer.observe(taken.saturating_duration_since(stamp.published));
            history.observe(sent.saturating_duration_since(taken));
            write.observe(now.saturating_duration_since(sent));
        }
    }

    /// The write of the bites of `stamps` failed: they wait for the next one (the
    /// latency a plant sees includes the retry, in their `to_writer` stage).
    pub fn not_written(&self, stamps: Vec<BiteStamps>) {
        if stamps.is_empty() {
            return;
        }
        let mut waiting = crate::lock(&self.waiting);
        let room = MAX_WAITING_BITES.saturating_sub(waiting.len());
        waiting.splice(0..0, stamps.into_iter().take(room));
    }

    /// A PLC writer runs until the guard is dropped: while one does, bites' stamps
    /// are kept for it.
    pub fn plc_writer(self: &Arc<Self>) -> PlcWriterGuard {
        self.plc_writers.fetch_add(1, Ordering::Relaxed);
        PlcWriterGuard(Arc::clone(self))
    }
}

/// A PLC writer running ([`Latencies::plc_writer`]); the last one's drop lets the
/// stamps go.
#[derive(Debug)]
pub struct PlcWriterGuard(Arc<Latencies>);

impl Drop for PlcWriterGuard {
    fn drop(&mut self) {
        if self.0.plc_writers.fetch_sub(1, Ordering::Relaxed) == 1 {
            crate::lock(&self.0.waiting).clear();
        }
    }
}

impl Families for Latencies {
    /// The histograms (a family or a stage without an observation is left out).
    fn write_families(&self, page: &mut Exposition) {
        for (name, histogram, help) in [
            (
                "millgate_block_wait_seconds",
                &self.block_wait,
                "From a reader handing over a block of samples (a Modbus DAQ's block when its \
                 read returned, a CAN batch when it was read) to the analysis taking it up.",
            ),
            (
                "millgate_bite_to_plc_seconds",
                &self.bite_to_plc,
                "From a reader handing over the block that completed a bite's window to the PLC \
                 acknowledging the write (FC 16) that carried the bite's counter: the wait for \
                 the analysis, the analysis of the bites before it, its own, the history's \
                 commit and the write.",
            ),
        ] {
            let counts = histogram.counts();
            page.histogram(name, help, (counts.count > 0).then(|| (Vec::new(), counts)));
        }
        let stages: Vec<_> = BITE_STAGES
            .iter()
            .zip(&self.stages)
            .map(|(&(stage, _), histogram)| (vec![("stage", stage)], histogram.counts()))
            .filter(|(_, counts)| counts.count > 0)
            .collect();
        let help = BITE_STAGES
            .iter()
            .map(|(stage, covers)| format!("{stage} ({covers})"))
            .collect::<Vec<_>>()
            .join("; ");
        page.histogram(
            "millgate_bite_stage_seconds",
            &format!(
                "Where a bite's time to the PLC goes, per stage (millgate_bite_to_plc_seconds \
                 is their sum): {help}."
            ),
            stages,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_are_kept_only_while_a_plc_writer_runs_and_a_failed_write_keeps_them() {
        let latencies = Arc::new(Latencies::default());
        let t0 = Instant::now();
        latencies.published(t0);
        assert!(latencies.take_waiting().is_empty(), "no writer, no stamp");
        let writer = latencies.plc_writer();
        latencies.published(t0);
        latencies.published(t0 + Duration::from_millis(1));
        let taken = latencies.take_waiting();
        assert_eq!(taken.len(), 2);
        let taken_first: Vec<_> = taken.iter().map(|s| s.taken).collect();
        latencies.published(t0 + Duration::from_millis(2));
        latencies.not_written(taken);
        let again = latencies.take_waiting();
        let handed: Vec<_> = again.iter().map(|stamp| stamp.handed).collect();
        assert_eq!(
            handed,
            [
                t0,
                t0 + Duration::from_millis(1),
                t0 + Duration::from_millis(2)
            ],
            "the failed write's bites first"
        );
        assert_eq!(
            again[..2].iter().map(|s| s.taken).collect::<Vec<_>>(),
            taken_first,
            "a retried bite keeps the time it was first taken"
        );
        assert!(again.iter().all(|s| s.taken >= Some(s.published)));
        latencies.published(t0);
        drop(writer);
        assert!(latencies.take_waiting().is_empty(), "the last writer gone");
    }

    #[test]
    fn the_waiting_bites_are_bounded() {
        let latencies = Arc::new(Latencies::default());
        let _writer = latencies.plc_writer();
        let t0 = Instant::now();
        for _ in 0..MAX_WAITING_BITES + 10 {
            latencies.published(t0);
        }
        let taken = latencies.take_waiting();
        assert_eq!(taken.len(), MAX_WAITING_BITES);
        latencies.published(t0);
        latencies.not_written(taken);
        assert_eq!(latencies.take_waiting().len(), MAX_WAITING_BITES);
    }

    #[test]
    fn a_written_bite_is_observed_in_its_bucket_and_its_stages_add_up() {
        let latencies = Arc::new(Latencies::default());
        let _writer = latencies.plc_writer();
        let now = Instant::now();
        let ms = Duration::from_millis;
        // Handed 30 ms ago, published 20 ms ago, taken 12 ms ago, sent 5 ms ago.
        let stamp = BiteStamps {
            handed: now - ms(30),
            published: now - ms(20),
            taken: Some(now - ms(12)),
        };
        latencies.written(&[stamp], now - ms(5));
        let counts = latencies.bite_to_plc.counts();
        assert_eq!(counts.count, 1);
        // 30 ms and some: in no bucket up to 20 ms.
        let up_to_20_ms = LATENCY_BOUNDS_S.iter().filter(|&&b| b <= 0.02).count();
        assert_eq!(up_to_20_ms, 8);
        assert!(
            counts.buckets[..up_to_20_ms].iter().all(|&n| n == 0),
            "{counts:?}"
        );
        assert!(counts.sum >= 0.03, "{counts:?}");
        let stages: Vec<f64> = latencies.stages.iter().map(|h| h.counts().sum).collect();
        // analysis 10 ms, to the writer 8 ms, history 7 ms, write 5 ms and what
        // passed since `now` (the same in the total).
        for (got, want) in stages.iter().zip([0.010, 0.008, 0.007, 0.005]) {
            assert!((got - want).abs() < 0.002, "{stages:?}");
        }
        assert!(
            (stages.iter().sum::<f64>() - counts.sum).abs() < 1e-6,
            "the stages add up to the total: {stages:?} against {}",
            counts.sum
        );
        let mut page = Exposition::new();
        latencies.write_families(&mut page);
        let text = page.into_text();
        for (stage, _) in BITE_STAGES {
            assert!(
                text.contains(&format!(
                    "millgate_bite_stage_seconds_count{{stage=\"{stage}\"}} 1"
                )),
                "{text}"
            );
        }
    }
}
