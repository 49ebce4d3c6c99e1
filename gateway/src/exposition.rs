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

/// Prometheus' metric type of a family.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Only goes up (or restarts from 0 with the process); its name ends in `_total`.
    Counter,
    /// Goes up and down.
    Gauge,
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
            return;
        }
        let mut samples = samples.into_iter().peekable();
        if samples.peek().is_none() {
            return;
        }
        let kind = match kind {
            Kind::Counter => "counter",
            Kind::Gauge => "gauge",
        };
        let help = help.replace('\\', "\\\\").replace('\n', "\\n");
        let _ = writeln!(self.out, "# HELP {name} {help}");
        let _ = writeln!(self.out, "# TYPE {name} {kind}");
        for (labels, value) in samples {
            let _ = write!(self.out, "{name}");
            if !labels.is_empty() {
                let labels: Vec<String> = labels
                    .iter()
                    .map(|(label, value)| {
                        debug_assert!(is_label_name(label), "{label:?} is no label name");
                        format!("{label}=\"{}\"", escape(value))
                    })
                    .collect();
                let _ = write!(self.out, "{{{}}}", labels.join(","));
            }
            let _ = writeln!(self.out, " {}", number(value));
        }
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
