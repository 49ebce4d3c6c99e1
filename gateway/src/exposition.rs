//! Prometheus' text exposition format (version 0.0.4): a page of metric families, each
//! its HELP and TYPE lines and then its samples, written by the parts that own the
//! numbers (the field sources, the history, each output) through [`Families`], and
//! served by `outputs::metrics`.
//!
//! The page makes the format's two rules hold by construction: a sample is only ever
//! written as part of the call that writes its family's HELP and TYPE
//! ([`Exposition::family`]), so no sample can stray outside its family; and a family
//! name already on the page is refused, so no family appears twice (a bug in the
//! writer: debug builds panic, release builds leave the second one out and log it).
//! A family without a sample is not written at all: a scraper sees only series.
//!
//! A leaf module: `field` and `history` sit below `outputs` (which imports both), so
//! their families could not be written through `outputs` without an import cycle.

use std::collections::HashSet;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Prometheus' metric type of a family.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Only goes up (or restarts from 0 with the process); its name ends in `_total`.
    Counter,
    /// Goes up and down.
    Gauge,
}

impl Kind {
    /// The name on the TYPE line.
    fn name(self) -> &'static str {
        match self {
            Kind::Counter => "counter",
            Kind::Gauge => "gauge",
        }
    }
}

/// A sample's labels: `(name, value)` pairs; the values are escaped when written.
pub(crate) type Labels<'a> = Vec<(&'static str, &'a str)>;

/// What writes its own families onto the `/metrics` page: a field source's, the
/// history's or an output's counters. The page asks each for its families at every
/// scrape, in the order they were added; a new output implements this beside its
/// code and hands it to the page from its builder, `outputs::metrics` unchanged.
pub trait Families: Send + Sync + std::fmt::Debug {
    /// Write the families, always the same ones in the same order, onto `page`.
    fn write_families(&self, page: &mut Exposition);
}

/// A page of the exposition format being written.
#[derive(Debug, Default)]
pub struct Exposition {
    out: String,
    names: HashSet<String>,
}

impl Exposition {
    /// An empty page.
    pub fn new() -> Self {
        Self::default()
    }

    /// One family: its HELP (escaped) and TYPE lines, then one sample per
    /// `(labels, value)`. A family without samples is left out (no HELP and TYPE
    /// without a series: a gauge with no valid value, a subject the gateway does not
    /// have), as is one of a name already on the page.
    pub fn family<'a>(
        &mut self,
        name: &str,
        kind: Kind,
        help: &str,
        samples: impl IntoIterator<Item = (Labels<'a>, f64)>,
    ) {
        let mut samples = samples.into_iter().peekable();
        if !self.head(name, kind.name(), help, samples.peek().is_some()) {
            return;
        }
        for (labels, value) in samples {
            self.sample(name, &labels, None, value);
        }
    }

    /// A histogram family: its HELP and TYPE lines, then per `(labels, histogram)`
    /// the cumulative `_bucket{le}` counts (the last `le="+Inf"`), `_sum` and
    /// `_count`. Left out, as [`Self::family`] leaves a family out, without a series.
    pub fn histogram<'a>(
        &mut self,
        name: &str,
        help: &str,
        series: impl IntoIterator<Item = (Labels<'a>, HistogramCounts)>,
    ) {
        let mut series = series.into_iter().peekable();
        if !self.head(name, "histogram", help, series.peek().is_some()) {
            return;
        }
        let bucket = format!("{name}_bucket");
        for (labels, counts) in series {
            let mut cumulative = 0;
            for (&bound, &count) in counts.bounds.iter().zip(&counts.buckets) {
                cumulative += count;
                let le = number(bound);
                self.sample(&bucket, &labels, Some(("le", &le)), cumulative as f64);
            }
            self.sample(&bucket, &labels, Some(("le", "+Inf")), counts.count as f64);
            self.sample(&format!("{name}_sum"), &labels, None, counts.sum);
            self.sample(&format!("{name}_count"), &labels, None, counts.count as f64);
        }
    }

    /// The HELP and TYPE lines of family `name` of type `kind`, when it has a
    /// sample (`any`) and its name is not on the page yet; whether they were
    /// written (and so its samples are to be).
    fn head(&mut self, name: &str, kind: &str, help: &str, any: bool) -> bool {
        debug_assert!(
            is_metric_name(name),
            "{name:?} is no Prometheus metric name"
        );
        if !self.names.insert(name.to_owned()) {
            debug_assert!(false, "the /metrics family {name} was written twice");
            tracing::error!(
                family = name,
                "a /metrics family was written twice: the second is left out"
            );
            return false;
        }
        if !any {
            return false;
        }
        let help = help.replace('\\', "\\\\").replace('\n', "\\n");
        let _ = writeln!(self.out, "# HELP {name} {help}");
        let _ = writeln!(self.out, "# TYPE {name} {kind}");
        true
    }

    /// One sample line of `name` with `labels` and, last, `extra` (a histogram's `le`).
    fn sample(
        &mut self,
        name: &str,
        labels: &Labels<'_>,
        extra: Option<(&'static str, &str)>,
        value: f64,
    ) {
        let _ = write!(self.out, "{name}");
        let all: Vec<String> = labels
            .iter()
            .copied()
            .chain(extra)
            .map(|(label, value)| {
                debug_assert!(is_label_name(label), "{label:?} is no label name");
                format!("{label}=\"{}\"", escape(value))
            })
            .collect();
        if !all.is_empty() {
            let _ = write!(self.out, "{{{}}}", all.join(","));
        }
        let _ = writeln!(self.out, " {}", number(value));
    }

    /// A family of one sample without labels.
    pub fn scalar(&mut self, name: &str, kind: Kind, help: &str, value: f64) {
        self.family(name, kind, help, [(Vec::new(), value)]);
    }

    /// A family of one sample without labels per `(name, kind, help, value)`.
    pub(crate) fn scalars<'a>(
        &mut self,
        rows: impl IntoIterator<Item = (&'a str, Kind, &'a str, f64)>,
    ) {
        for (name, kind, help, value) in rows {
            self.scalar(name, kind, help, value);
        }
    }

    /// The page's text.
    pub(crate) fn into_text(self) -> String {
        self.out
    }
}

/// A histogram of durations that any thread observes into: fixed bucket bounds,
/// counts, sum and count in atomics, so an observation is a few relaxed atomic
/// additions and takes no lock (the analysis and the PLC writer observe in their
/// hot paths). Read with [`Self::counts`]; written onto the page by
/// [`Exposition::histogram`].
///
/// Hand-rolled rather than taken from a Prometheus client crate for the reason
/// `outputs::metrics` gives: the page is written here, and a client's registry would
/// be a second one. A scrape between the atomics of one observation may see its
/// bucket and not yet its sum; the next scrape sees both.
#[derive(Debug)]
pub struct Histogram {
    /// Upper bounds of the buckets, seconds, increasing (the `+Inf` bucket is implied).
    bounds: &'static [f64],
    /// Observations per bucket (not cumulative); one more than `bounds`: above the last.
    buckets: Vec<AtomicU64>,
    /// Sum of the observations, nanoseconds.
    sum_ns: AtomicU64,
}

/// A copy of a [`Histogram`]'s counts.
#[derive(Debug, Clone, PartialEq)]
pub struct HistogramCounts {
    /// Upper bounds of the buckets, seconds.
    pub bounds: &'static [f64],
    /// Observations per bucket (not cumulative), one per bound.
    pub buckets: Vec<u64>,
    /// All observations (those above the last bound too).
    pub count: u64,
    /// Sum of the observations, seconds.
    pub sum: f64,
}

impl Histogram {
    /// An empty histogram with buckets up to `bounds` (seconds, increasing).
    pub fn new(bounds: &'static [f64]) -> Self {
        debug_assert!(bounds.windows(2).all(|pair| pair[0] < pair[1]));
        Self {
            bounds,
            buckets: (0..=bounds.len()).map(|_| AtomicU64::new(0)).collect(),
            sum_ns: AtomicU64::new(0),
        }
    }

    /// Count one duration.
    pub fn observe(&self, duration: Duration) {
        let seconds = duration.as_secs_f64();
        let bucket = self
            .bounds
            .iter()
            .position(|&bound| seconds <= bound)
            .unwrap_or(self.bounds.len());
        self.buckets[bucket].fetch_add(1, Ordering::Relaxed);
        let ns = u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX);
        self.sum_ns.fetch_add(ns, Ordering::Relaxed);
    }

    /// The counts now.
    pub fn counts(&self) -> HistogramCounts {
        let all: Vec<u64> = self
            .buckets
            .iter()
            .map(|bucket| bucket.load(Ordering::Relaxed))
            .collect();
        HistogramCounts {
            bounds: self.bounds,
            buckets: all[..self.bounds.len()].to_vec(),
            count: all.iter().sum(),
            sum: self.sum_ns.load(Ordering::Relaxed) as f64 / 1e9,
        }
    }
}

/// A sample value as Prometheus reads it.
fn number(value: f64) -> String {
    if value.is_nan() {
        "NaN".into()
    } else if value.is_infinite() {
        if value > 0.0 { "+Inf" } else { "-Inf" }.into()
    } else if value.fract() == 0.0 && value.abs() < 1e15 {
        format!("{value:.0}")
    } else {
        format!("{value:?}")
    }
}

/// A label value with its backslashes, quotes and line feeds escaped.
fn escape(label: &str) -> String {
    label
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// `[a-zA-Z_:][a-zA-Z0-9_:]*`.
fn is_metric_name(name: &str) -> bool {
    let mut chars = name.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_' || c == ':')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':')
}

/// `[a-zA-Z_][a-zA-Z0-9_]*`, not starting with `__` (reserved).
fn is_label_name(name: &str) -> bool {
    let mut chars = name.chars();
    !name.starts_with("__")
        && chars
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_written_as_prometheus_reads_them() {
        assert_eq!(number(3.0), "3");
        assert_eq!(number(0.25), "0.25");
        assert_eq!(number(1e300), "1e300");
        assert_eq!(number(f64::NAN), "NaN");
        assert_eq!(number(f64::NEG_INFINITY), "-Inf");
    }

    #[test]
    fn a_family_is_its_help_type_and_samples_with_escaped_text() {
        let mut page = Exposition::new();
        page.family(
            "millgate_example_total",
            Kind::Counter,
            "Said \\ twice\nover.",
            [
                (vec![("source", "a \"b\"\\c")], 2.0),
                (vec![("source", "d"), ("reason", "e")], 0.5),
            ],
        );
        page.scalar("millgate_example_state", Kind::Gauge, "State.", 1.0);
        assert_eq!(
            page.into_text(),
            "# HELP millgate_example_total Said \\\\ twice\\nover.\n\
             # TYPE millgate_example_total counter\n\
             millgate_example_total{source=\"a \\\"b\\\"\\\\c\"} 2\n\
             millgate_example_total{source=\"d\",reason=\"e\"} 0.5\n\
             # HELP millgate_example_state State.\n\
             # TYPE millgate_example_state gauge\n\
             millgate_example_state 1\n"
        );
    }

    #[test]
    fn a_family_without_samples_is_left_out() {
        let mut page = Exposition::new();
        page.family("millgate_empty", Kind::Gauge, "No value yet.", []);
        page.scalar("millgate_example_state", Kind::Gauge, "State.", 1.0);
        assert_eq!(
            page.into_text(),
            "# HELP millgate_example_state State.\n\
             # TYPE millgate_example_state gauge\n\
             millgate_example_state 1\n"
        );
    }

    #[test]
    fn a_histogram_is_cumulative_buckets_up_to_inf_its_sum_and_count() {
        static BOUNDS: [f64; 2] = [0.001, 0.01];
        let histogram = Histogram::new(&BOUNDS);
        for us in [500, 1_000, 3_000, 30_000, 40_000] {
            histogram.observe(Duration::from_micros(us));
        }
        let counts = histogram.counts();
        assert_eq!(counts.buckets, [2, 1], "1 ms is in the 1 ms bucket (le)");
        assert_eq!(counts.count, 5);
        assert_eq!(counts.sum, 0.0745);
        let mut page = Exposition::new();
        page.histogram(
            "millgate_example_seconds",
            "Latency.",
            [(vec![("driveline", "F1")], counts)],
        );
        page.histogram(
            "millgate_empty_seconds",
            "No series.",
            std::iter::empty::<(Labels, HistogramCounts)>(),
        );
        assert_eq!(
            page.into_text(),
            "# HELP millgate_example_seconds Latency.\n\
             # TYPE millgate_example_seconds histogram\n\
             millgate_example_seconds_bucket{driveline=\"F1\",le=\"0.001\"} 2\n\
             millgate_example_seconds_bucket{driveline=\"F1\",le=\"0.01\"} 3\n\
             millgate_example_seconds_bucket{driveline=\"F1\",le=\"+Inf\"} 5\n\
             millgate_example_seconds_sum{driveline=\"F1\"} 0.0745\n\
             millgate_example_seconds_count{driveline=\"F1\"} 5\n"
        );
    }

    #[test]
    #[should_panic(expected = "written twice")]
    fn a_family_written_twice_is_refused() {
        let mut page = Exposition::new();
        page.scalar("millgate_twice", Kind::Gauge, "Once.", 1.0);
        page.scalar("millgate_twice", Kind::Gauge, "Twice.", 2.0);
    }

    #[test]
    fn names_are_checked_as_prometheus_reads_them() {
        assert!(is_metric_name("millgate_plc_writes_total"));
        assert!(is_metric_name("process:cpu"));
        assert!(!is_metric_name("0abc"));
        assert!(!is_metric_name("millgate-plc"));
        assert!(!is_metric_name(""));
        assert!(is_label_name("reason"));
        assert!(!is_label_name("__name__"));
        assert!(!is_label_name("rod:mill"));
    }
}
