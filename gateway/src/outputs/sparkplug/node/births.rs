//! NBIRTH and the DBIRTHs: a session's start, every metric named with its datatype
//! and unit, each driveline's and tandem mill's newest capture.

use prost::Message as _;

use super::{metric, CaptureNotice, EdgeNode, Outgoing, REBIRTH};
use crate::outputs::sparkplug::devices::Kind;
use crate::outputs::sparkplug::payload::{DataType, Metric, MetricValue, Payload, PropertySet};
use crate::state::results::Results;

impl EdgeNode {
    /// NBIRTH (seq 0) and a DBIRTH per device with every metric: name, alias,
    /// datatype, unit, value; a driveline's and a tandem mill's with its newest capture
    /// (`captures`: the drivelines' in order, then the tandem mills').
    pub(crate) fn births(
        &mut self,
        results: &Results,
        captures: &[Option<CaptureNotice>],
        now_ms: u64,
    ) -> Vec<Outgoing> {
        self.seq = 0;
        let node_metrics = vec![
            self.bd_seq_metric(now_ms),
            Metric {
                name: Some(REBIRTH.to_owned()),
                alias: Some(1),
                timestamp: Some(now_ms),
                datatype: Some(DataType::Boolean.code()),
                value: Some(MetricValue::BooleanValue(false)),
                ..Metric::default()
            },
        ];
        let nbirth = Payload {
            timestamp: Some(now_ms),
            metrics: node_metrics,
            seq: Some(self.next_seq()),
            ..Payload::default()
        };
        let mut out = vec![Outgoing {
            topic: self.node_topic("NBIRTH"),
            payload: nbirth.encode_to_vec(),
        }];
        for index in 0..self.devices.len() {
            let device = &self.devices[index];
            let mut values = device.values(results);
            // The bite id is born null: it is only sent with a bite.
            values.resize(device.columns.len(), None);
            let mut metrics: Vec<Metric> = device
                .columns
                .iter()
                .zip(&values)
                .enumerate()
                .map(|(at, (column, value))| {
                    let alias = device.first_alias + at as u64;
                    let mut metric =
                        metric(Some(&column.name), alias, column.datatype, *value, now_ms);
                    if !column.unit.is_empty() {
                        metric.properties = Some(PropertySet::unit(column.unit));
                    }
                    metric
                })
                .collect();
            let captured = match device.kind {
                Kind::Driveline(k) => Some(k),
                Kind::TandemMill(k) => Some(results.drivelines.len() + k),
                Kind::RodMill(..) => None,
            };
            if let Some(at) = captured {
                let capture = captures.get(at).and_then(Option::as_ref);
                let first = device.first_alias + device.columns.len() as u64;
                metrics.extend(CaptureNotice::metrics(capture, first, now_ms, true));
            }
            self.devices[index].sent = values;
            if let Kind::Driveline(k) = self.devices[index].kind {
                self.devices[index].bite_counter =
                    results.drivelines.get(k).map(|d| d.bite_counter);
                self.devices[index].held_since = None;
            }
            let topic = self.device_topic("DBIRTH", index);
            out.push(self.device_message(topic, metrics, now_ms));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{decode, node, node_with};
    use super::*;
    use crate::outputs::sparkplug::node::{BITE_ID, CAPTURE_METRICS};
    use crate::state::catalogue;
    use crate::state::results::{RodMillResults, RodSpanResults};

    #[test]
    fn births_come_in_order_with_seq_from_0_and_unique_aliases() {
        let mut node = node();
        let results = Results::new(1, 2, 1);
        let births = node.births(&results, &[], 1000);
        let topics: Vec<&str> = births.iter().map(|m| m.topic.as_str()).collect();
        assert_eq!(
            topics,
            [
                "spBv1.0/plant/NBIRTH/stand-f1",
                "spBv1.0/plant/DBIRTH/stand-f1/F1",
                "spBv1.0/plant/DBIRTH/stand-f1/F2",
                "spBv1.0/plant/DBIRTH/stand-f1/tandem"
            ]
        );
        let payloads: Vec<Payload> = births.iter().map(decode).collect();
        let seqs: Vec<Option<u64>> = payloads.iter().map(|p| p.seq).collect();
        assert_eq!(seqs, [Some(0), Some(1), Some(2), Some(3)]);
        assert_eq!(payloads[0].metrics[0].name.as_deref(), Some("bdSeq"));
        assert_eq!(payloads[0].metrics[0].alias, Some(0), "bdSeq's alias");
        assert_eq!(
            payloads[0].metrics[0].value,
            Some(MetricValue::LongValue(7))
        );
        // bdSeq is Int64 (Sparkplug 3.0); the node's metrics carry the birth's time.
        assert_eq!(
            payloads[0].metrics[0].datatype,
            Some(DataType::Int64.code())
        );
        assert!(payloads[0]
            .metrics
            .iter()
            .all(|m| m.timestamp == Some(1000)));
        // A device's metrics are the catalogue's figures by key (and the bite id and
        // the capture metrics).
        let names: Vec<&str> = payloads[1]
            .metrics
            .iter()
            .map(|m| m.name.as_deref().unwrap())
            .collect();
        let keys: Vec<&str> = catalogue::DRIVELINE.iter().map(|f| f.key).collect();
        assert_eq!(names[..keys.len()], keys[..]);
        let after: Vec<&str> = std::iter::once(BITE_ID)
            .chain(CAPTURE_METRICS.iter().map(|(name, ..)| *name))
            .collect();
        assert_eq!(names[keys.len()..], after[..]);
        let mut aliases: Vec<u64> = payloads
            .iter()
            .flat_map(|p| p.metrics.iter().filter_map(|m| m.alias))
            .collect();
        let count = aliases.len();
        aliases.sort_unstable();
        aliases.dedup();
        assert_eq!(aliases.len(), count, "aliases unique within the node");
        assert!(payloads[1..]
            .iter()
            .flat_map(|p| &p.metrics)
            .all(|m| m.name.is_some() && m.datatype.is_some()));
        // The death carries the same bdSeq and no seq.
        let death = decode(&node.death(2000));
        assert_eq!(death.seq, None);
        assert_eq!(death.metrics[0].value, Some(MetricValue::LongValue(7)));
    }

    #[test]
    fn a_rod_mill_publishes_its_worst_span_and_one_set_of_metrics_per_span() {
        let mut node = node_with(&[("RSM".into(), 3)]);
        let mut results = Results::new(1, 2, 1);
        results.rod_mills = vec![RodMillResults::default()];
        let births: Vec<Payload> = node
            .births(&results, &[], 1000)
            .iter()
            .map(decode)
            .collect();
        assert_eq!(births.len(), 5, "NBIRTH, F1, F2, tandem, RSM");
        let rod = &births[4];
        let names: Vec<&str> = rod
            .metrics
            .iter()
            .map(|m| m.name.as_deref().unwrap())
            .collect();
        assert_eq!(
            names.len(),
            catalogue::ROD_MILL.len() + 3 * catalogue::ROD_SPAN.len()
        );
        assert!(names.contains(&"worst_margin_m_s") && names.contains(&"span3/speed_margin_m_s"));
        assert!(!names.iter().any(|n| n.starts_with("span4/")), "{names:?}");
        let by_name = |payload: &Payload, name: &str| {
            payload
                .metrics
                .iter()
                .find(|m| m.name.as_deref() == Some(name))
                .unwrap()
                .clone()
        };
        let unit = by_name(rod, "span2/worst_exponent_per_s")
            .properties
            .unwrap();
        assert_eq!(unit, PropertySet::unit("1/s"));
        // Not evaluated yet: the worst span and the span values are null.
        assert_eq!(by_name(rod, "worst_span").is_null, Some(true));
        assert_eq!(by_name(rod, "span1/speed_margin_m_s").is_null, Some(true));
        assert_eq!(
            by_name(rod, "span1/invalid").value,
            Some(MetricValue::BooleanValue(true))
        );
        // Aliases continue after the tandem mill's, unique over the node.
        let mut aliases: Vec<u64> = births
            .iter()
            .flat_map(|p| p.metrics.iter().filter_map(|m| m.alias))
            .collect();
        let count = aliases.len();
        aliases.sort_unstable();
        aliases.dedup();
        assert_eq!(aliases.len(), count);
        let alias = |name: &str| by_name(rod, name).alias.unwrap();

        // Span 2 unstable at -0.2 m/s; span 3 has a smaller margin but is not valid
        // (it does not count); span 1 stable.
        let span = |margin: f64, valid: bool| RodSpanResults {
            valid,
            unstable: margin < 0.0,
            near_tongue: false,
            speed_margin_m_s: Some(margin),
            worst_exponent_per_s: Some(margin * -3.0),
            configuration: Some(1),
        };
        results.rod_mills[0] = RodMillResults {
            evaluations: 1,
            configuration: Some(1),
            pass: Some(4),
            finishing_speed_m_s: Some(60.0),
            temperature_c: Some(950.0),
            spans: vec![span(0.5, true), span(-0.2, true), span(-1.0, false)],
            ..RodMillResults::default()
        };
        let data = node.data(&results, 1100);
        let rod = data.iter().find(|m| m.topic.ends_with("/RSM")).unwrap();
        assert_eq!(rod.topic, "spBv1.0/plant/DDATA/stand-f1/RSM");
        let rod = decode(rod);
        assert!(rod.metrics.iter().all(|m| m.name.is_none()));
        let value = |payload: &Payload, name: &str| {
            payload
                .metrics
                .iter()
                .find(|m| m.alias == Some(alias(name)))
                .map(|m| m.value.clone())
        };
        assert_eq!(
            value(&rod, "worst_margin_m_s"),
            Some(Some(MetricValue::DoubleValue(-0.2)))
        );
        assert_eq!(
            value(&rod, "worst_span"),
            Some(Some(MetricValue::LongValue(2)))
        );
        assert_eq!(
            value(&rod, "unstable"),
            Some(Some(MetricValue::BooleanValue(true)))
        );
        assert_eq!(
            value(&rod, "span2/speed_margin_m_s"),
            Some(Some(MetricValue::DoubleValue(-0.2)))
        );
        assert_eq!(
            value(&rod, "span1/invalid"),
            Some(Some(MetricValue::BooleanValue(false)))
        );
        // Span 3 stays as born: invalid, its margin null (unchanged, so not sent).
        assert_eq!(value(&rod, "span3/invalid"), None);
        assert_eq!(value(&rod, "span3/speed_margin_m_s"), None);

        // A stale input: the operating point, the flags and the spans go null/invalid.
        results.rod_mills[0].source_stale = true;
        let stale = decode(&node.data(&results, 1200)[0]);
        assert_eq!(value(&stale, "worst_margin_m_s"), Some(None));
        assert_eq!(value(&stale, "pass"), Some(None));
        assert_eq!(
            value(&stale, "span2/invalid"),
            Some(Some(MetricValue::BooleanValue(true)))
        );
        assert_eq!(value(&stale, "span2/speed_margin_m_s"), Some(None));
        assert_eq!(
            value(&stale, "source_stale"),
            Some(Some(MetricValue::BooleanValue(true)))
        );
    }
}
