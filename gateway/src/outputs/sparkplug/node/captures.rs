//! Capture notices: which capture the history holds (its id, kind, samples, span,
//! size), as metrics after a driveline's bite id and a tandem mill's figures; a tandem
//! mill's new chatter or manual capture as a DDATA of its own.

use super::{EdgeNode, Outgoing};
use crate::outputs::sparkplug::devices::Kind;
use crate::outputs::sparkplug::payload::{DataType, Metric, MetricValue, PropertySet};

/// The capture metrics of a driveline device, after [`BITE_ID`](super::BITE_ID), and of a tandem mill
/// device, after its figures: name, datatype, unit. A bite's DDATA carries its
/// capture's (when the history holds it), a DDATA of its own each chatter episode's or
/// manual capture of a tandem mill's stands; the birth the device's newest capture's
/// (null without one).
pub const CAPTURE_METRICS: [(&str, DataType, &str); 6] = [
    ("capture/id", DataType::UInt64, ""),
    ("capture/kind", DataType::String, ""),
    ("capture/samples", DataType::UInt64, ""),
    ("capture/first_sample", DataType::DateTime, ""),
    ("capture/span_s", DataType::Double, "s"),
    ("capture/bytes", DataType::UInt64, "B"),
];

/// A capture as the node announces it: which (its id in the history file: fetch it
/// at `/api/captures/{id}`), what kind, its samples per channel, time span and size.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CaptureNotice {
    /// The capture's id in the history file.
    pub id: u64,
    /// `bite`, `chatter` or `manual`.
    pub kind: String,
    /// Samples per channel.
    pub samples: u64,
    /// The first sample, ms since the Unix epoch.
    pub first_sample_ms: u64,
    /// From the first sample to the last, s.
    pub span_s: f64,
    /// Its samples' size in the file, bytes.
    pub bytes: u64,
}

impl CaptureNotice {
    /// The values of [`CAPTURE_METRICS`], in order.
    fn values(&self) -> [MetricValue; 6] {
        [
            MetricValue::LongValue(self.id),
            MetricValue::StringValue(self.kind.clone()),
            MetricValue::LongValue(self.samples),
            MetricValue::LongValue(self.first_sample_ms),
            MetricValue::DoubleValue(self.span_s),
            MetricValue::LongValue(self.bytes),
        ]
    }

    /// Its metrics from alias `first_alias` on (null ones for `None`), timestamped
    /// `ms`, named when `named` (a birth).
    pub(super) fn metrics(
        notice: Option<&Self>,
        first_alias: u64,
        ms: u64,
        named: bool,
    ) -> Vec<Metric> {
        let values = notice.map(Self::values);
        CAPTURE_METRICS
            .iter()
            .enumerate()
            .map(|(at, (name, datatype, unit))| Metric {
                name: named.then(|| (*name).to_owned()),
                alias: Some(first_alias + at as u64),
                timestamp: Some(ms),
                datatype: Some(datatype.code()),
                is_null: values.is_none().then_some(true),
                value: values.as_ref().map(|v| v[at].clone()),
                properties: (named && !unit.is_empty()).then(|| PropertySet::unit(unit)),
                ..Metric::default()
            })
            .collect()
    }
}

impl EdgeNode {
    /// The DDATA announcing `capture`, one of tandem mill `mill`'s (a chatter episode
    /// or a manual capture of its stands): its capture metrics, timestamped `now_ms`.
    pub(crate) fn mill_capture(
        &mut self,
        mill: usize,
        capture: &CaptureNotice,
        now_ms: u64,
    ) -> Outgoing {
        let device = self
            .devices
            .iter()
            .position(|d| d.kind == Kind::TandemMill(mill))
            .expect("a tandem mill device per tandem mill");
        let first = self.devices[device].first_alias + self.devices[device].columns.len() as u64;
        let metrics = CaptureNotice::metrics(Some(capture), first, now_ms, false);
        let topic = self.device_topic("DDATA", device);
        self.device_message(topic, metrics, now_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{decode, driveline_alias, node};
    use super::*;
    use crate::outputs::sparkplug::node::BITE_ID;
    use crate::outputs::sparkplug::payload::Payload;
    use crate::state::results::Results;

    #[test]
    fn a_tandem_mill_is_born_with_its_newest_capture_and_announces_each_new_one() {
        let mut node = node();
        let results = Results::new(1, 2, 1);
        let notice = |id: u64, kind: &str| CaptureNotice {
            id,
            kind: kind.into(),
            samples: 32_620,
            first_sample_ms: 1_700_000_000_000,
            span_s: 13.048,
            bytes: 120_000,
        };
        // The drivelines' newest captures first (none), then the tandem mill's.
        let births: Vec<Payload> = node
            .births(&results, &[None, None, Some(notice(7, "manual"))], 1000)
            .iter()
            .map(decode)
            .collect();
        let tandem = &births[3];
        let named = |payload: &Payload, name: &str| {
            payload
                .metrics
                .iter()
                .find(|m| m.name.as_deref() == Some(name))
                .cloned()
                .unwrap_or_else(|| panic!("no {name}"))
        };
        assert_eq!(
            named(tandem, "capture/id").value,
            Some(MetricValue::LongValue(7))
        );
        let kind_alias = named(tandem, "capture/kind").alias;
        let span_alias = named(tandem, "capture/span_s").alias;
        assert_eq!(
            named(&births[1], "capture/id").is_null,
            Some(true),
            "F1 has none"
        );
        // A chatter episode's capture: a DDATA of its own on the mill's device, by alias.
        let message = node.mill_capture(0, &notice(8, "chatter"), 2000);
        assert_eq!(message.topic, "spBv1.0/plant/DDATA/stand-f1/tandem");
        let data = decode(&message);
        assert_eq!(data.metrics.len(), CAPTURE_METRICS.len());
        let by_alias = |alias| {
            data.metrics
                .iter()
                .find(|m| m.alias == alias)
                .and_then(|m| m.value.clone())
        };
        assert_eq!(
            by_alias(kind_alias),
            Some(MetricValue::StringValue("chatter".into()))
        );
        assert_eq!(by_alias(span_alias), Some(MetricValue::DoubleValue(13.048)));
        assert!(data.metrics.iter().all(|m| m.name.is_none()));
    }

    #[test]
    fn a_capture_is_announced_in_its_bites_ddata_and_the_birth() {
        let mut node = node();
        let results = Results::new(1, 2, 1);
        let notice = CaptureNotice {
            id: 42,
            kind: "bite".to_owned(),
            samples: 1200,
            first_sample_ms: 1_700_000_000_123,
            span_s: 0.5995,
            bytes: 1699,
        };
        let expected = |metrics: &[Metric], index: usize| {
            let value = |name: &str| {
                let at = CAPTURE_METRICS
                    .iter()
                    .position(|(n, ..)| *n == name)
                    .unwrap();
                let alias = driveline_alias(index, BITE_ID) + 1 + at as u64;
                metrics
                    .iter()
                    .find(|m| m.alias == Some(alias))
                    .and_then(|m| m.value.clone())
            };
            assert_eq!(value("capture/id"), Some(MetricValue::LongValue(42)));
            assert_eq!(
                value("capture/kind"),
                Some(MetricValue::StringValue("bite".to_owned()))
            );
            assert_eq!(value("capture/samples"), Some(MetricValue::LongValue(1200)));
            assert_eq!(
                value("capture/first_sample"),
                Some(MetricValue::LongValue(1_700_000_000_123))
            );
            assert_eq!(
                value("capture/span_s"),
                Some(MetricValue::DoubleValue(0.5995))
            );
            assert_eq!(value("capture/bytes"), Some(MetricValue::LongValue(1699)));
        };
        // The birth: the second driveline's newest capture; the first has none (null).
        let births: Vec<Payload> = node
            .births(&results, &[None, Some(notice.clone())], 1000)
            .iter()
            .map(decode)
            .collect();
        expected(&births[2].metrics, 1);
        let first = driveline_alias(0, BITE_ID) + 1;
        let nulls = births[1]
            .metrics
            .iter()
            .filter(|m| m.alias.is_some_and(|a| a >= first && a < first + 6))
            .filter(|m| m.is_null == Some(true) && m.value.is_none())
            .count();
        assert_eq!(nulls, CAPTURE_METRICS.len());
        // A bite's DDATA with its capture, by alias.
        let bite = decode(&node.bite(
            1,
            &results.drivelines[1],
            2000,
            (None, false),
            Some(&notice),
        ));
        expected(&bite.metrics, 1);
        assert!(bite.metrics.iter().all(|m| m.name.is_none()));
    }
}
