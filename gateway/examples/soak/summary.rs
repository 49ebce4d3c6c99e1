//! What one load point measured, and the table of the load points run so far.

use crate::bites::{quantile, quantile_below};

/// What one load point measured.
pub(crate) struct Summary {
    pub(crate) drivelines: usize,
    pub(crate) stands: usize,
    pub(crate) channels: usize,
    pub(crate) samples_per_s: f64,
    pub(crate) cpu_percent: f64,
    pub(crate) rss_max_kib: u64,
    pub(crate) rss_growth_kib: i64,
    pub(crate) fds: (usize, usize),
    pub(crate) missed: f64,
    pub(crate) bites: u64,
    pub(crate) degraded: usize,
    pub(crate) not_in_history: usize,
    pub(crate) not_at_plc: usize,
    pub(crate) answers_failed: usize,
    pub(crate) answers: usize,
    pub(crate) sparkplug_bites: f64,
    /// Sorted, from the delivery of the block that completed the window.
    pub(crate) latencies_ms: Vec<f64>,
    /// Sorted, from the window's last sample (upper bounds).
    pub(crate) from_sample_ms: Vec<f64>,
    pub(crate) unattributed: usize,
}

impl Summary {
    pub(crate) fn passed(&self, p99_limit_ms: f64) -> bool {
        self.missed == 0.0
            && self.not_in_history == 0
            && self.not_at_plc == 0
            && self.answers_failed == 0
            && quantile_below(&self.latencies_ms, 0.99, p99_limit_ms)
    }
}

pub(crate) fn print_table(summaries: &[Summary], p99_limit_ms: f64) {
    println!(
        "{:>3} {:>3} {:>4} {:>7} {:>6} {:>8} {:>8} {:>7} {:>7} {:>6} {:>5} {:>7} {:>7} {:>7} \
         {:>7} {:>6} {:>5} {:>4}",
        "N",
        "M",
        "ch",
        "samp/s",
        "cpu_%",
        "%/ch",
        "rss_kib",
        "rss_+",
        "fds",
        "missed",
        "bites",
        "p50_ms",
        "p99_ms",
        "max_ms",
        "no_hist",
        "no_plc",
        "fails",
        "pass"
    );
    for s in summaries {
        let l = &s.latencies_ms;
        println!(
            "{:>3} {:>3} {:>4} {:>7.0} {:>6.1} {:>8.3} {:>8} {:>7} {:>7} {:>6} {:>5} {:>7.2} \
             {:>7.2} {:>7.2} {:>7} {:>6} {:>5} {:>4}",
            s.drivelines,
            s.stands,
            s.channels,
            s.samples_per_s,
            s.cpu_percent,
            s.cpu_percent / s.channels as f64,
            s.rss_max_kib,
            s.rss_growth_kib,
            format!("{}..{}", s.fds.0, s.fds.1),
            s.missed,
            s.bites,
            quantile(l, 0.5),
            quantile(l, 0.99),
            l.last().copied().unwrap_or(f64::NAN),
            s.not_in_history,
            s.not_at_plc,
            format!("{}/{}", s.answers_failed, s.answers),
            if s.passed(p99_limit_ms) { "yes" } else { "no" },
        );
        println!(
            "    {} bites measured, {} degraded, {} Sparkplug bite DDATAs; from the window's \
             last sample (block and poll wait included) p50 {:.2} ms, p99 {:.2} ms, max {:.2} \
             ms; {} bites not told from their block (measured from the last sample)",
            l.len(),
            s.degraded,
            s.sparkplug_bites,
            quantile(&s.from_sample_ms, 0.5),
            quantile(&s.from_sample_ms, 0.99),
            s.from_sample_ms.last().copied().unwrap_or(f64::NAN),
            s.unattributed,
        );
    }
}
