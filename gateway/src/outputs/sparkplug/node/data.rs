//! DDATA: the values changed since the last message, and each bite as its own DDATA
//! (its bite id, its values, its capture), before the values it changed.

use super::{metric, CaptureNotice, EdgeNode, Outgoing};
use crate::outputs::sparkplug::devices::{values, Kind};
use crate::outputs::sparkplug::payload::{DataType, Metric};
use crate::state::catalogue::{self, Value};
use crate::state::results::{DrivelineResults, Results};

/// Longest a driveline's changed values wait for the DDATA of the bite that changed
/// them (a bite reaches the history, and from it the broker, within milliseconds; a
/// history that cannot store it must not hold the values back for good).
pub const BITE_HOLD_MS: u64 = 2000;

impl EdgeNode {
    /// A DDATA per device whose values changed since the last birth or data message,
    /// with only the changed metrics, by alias. A driveline whose results show a bite
    /// whose own DDATA has not gone yet waits for it (at most [`BITE_HOLD_MS`]): a host
    /// sees a bite's DDATA before the values it changed, never after.
    pub(crate) fn data(&mut self, results: &Results, now_ms: u64) -> Vec<Outgoing> {
        let mut out = Vec::new();
        for index in 0..self.devices.len() {
            if let Kind::Driveline(k) = self.devices[index].kind {
                let now = results.drivelines.get(k).map(|d| d.bite_counter);
                let device = &mut self.devices[index];
                if now == device.bite_counter {
                    device.held_since = None;
                } else {
                    let since = *device.held_since.get_or_insert(now_ms);
                    if now_ms.saturating_sub(since) < BITE_HOLD_MS {
                        continue;
                    }
                }
            }
            let device = &self.devices[index];
            let values = device.values(results);
            let metrics: Vec<Metric> = values
                .iter()
                .enumerate()
                .filter(|(at, value)| device.sent.get(*at) != Some(value))
                .map(|(at, value)| {
                    let alias = device.first_alias + at as u64;
                    metric(None, alias, device.columns[at].datatype, *value, now_ms)
                })
                .collect();
            if !metrics.is_empty() {
                let sent = &mut self.devices[index].sent;
                sent[..values.len()].copy_from_slice(&values);
                let topic = self.device_topic("DDATA", index);
                out.push(self.device_message(topic, metrics, now_ms));
            }
        }
        out
    }

    /// A bite of driveline `index`: its own DDATA with the bite id and every driveline
    /// metric (`only`: just these keys, for a bite read back from the history, which
    /// keeps its values but not the flags of the moment), timestamped with the bite's
    /// time; `historical` flags a bite sent after the fact (replayed). `capture`: the
    /// bite's capture, announced in the same DDATA.
    pub(crate) fn bite(
        &mut self,
        index: usize,
        after: &DrivelineResults,
        bite_ms: u64,
        (only, historical): (Option<&[&str]>, bool),
        capture: Option<&CaptureNotice>,
    ) -> Outgoing {
        let values = values(catalogue::DRIVELINE, after);
        let device = self
            .devices
            .iter()
            .position(|d| d.kind == Kind::Driveline(index))
            .expect("a driveline device per driveline");
        let (first_alias, columns) = (
            self.devices[device].first_alias,
            &self.devices[device].columns,
        );
        let mut metrics: Vec<Metric> = values
            .iter()
            .enumerate()
            .filter(|(at, _)| only.is_none_or(|keys| keys.contains(&catalogue::DRIVELINE[*at].key)))
            .map(|(at, value)| {
                metric(
                    None,
                    first_alias + at as u64,
                    columns[at].datatype,
                    *value,
                    bite_ms,
                )
            })
            .collect();
        metrics.push(metric(
            None,
            first_alias + values.len() as u64,
            DataType::UInt64,
            Some(Value::Count(u64::from(after.bite_counter))),
            bite_ms,
        ));
        if capture.is_some() {
            let first = first_alias + values.len() as u64 + 1;
            metrics.extend(CaptureNotice::metrics(capture, first, bite_ms, false));
        }
        if historical {
            for metric in &mut metrics {
                metric.is_historical = Some(true);
            }
        } else {
            let sent = &mut self.devices[device];
            sent.bite_counter = Some(after.bite_counter);
            sent.held_since = None;
            if only.is_none() {
                sent.sent[..values.len()].copy_from_slice(&values);
            }
        }
        let topic = self.device_topic("DDATA", device);
        self.device_message(topic, metrics, bite_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{decode, driveline_alias, node};
    use super::*;
    use crate::outputs::sparkplug::node::{BITE_ID, CAPTURE_METRICS, NODE_METRICS};
    use crate::outputs::sparkplug::payload::MetricValue;

    #[test]
    fn data_carries_only_changed_metrics_by_alias_and_seq_wraps() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        node.births(&results, &[], 1000);
        assert!(node.data(&results, 1100).is_empty(), "nothing changed");
        results.drivelines[1].taf_alarm = true;
        let data = node.data(&results, 1200);
        assert_eq!(data.len(), 1);
        assert_eq!(data[0].topic, "spBv1.0/plant/DDATA/stand-f1/F2");
        let payload = decode(&data[0]);
        assert_eq!(payload.seq, Some(4));
        assert_eq!(payload.metrics.len(), 1);
        assert_eq!(payload.metrics[0].name, None);
        assert_eq!(
            payload.metrics[0].value,
            Some(MetricValue::BooleanValue(true))
        );
        for n in 0..300u32 {
            results.drivelines[0].bite_counter = n + 1;
            let bite = node.bite(0, &results.drivelines[0], 5000, (None, false), None);
            let seq = decode(&bite).seq.unwrap();
            assert_eq!(seq, u64::from((5 + n) % 256));
        }
    }

    #[test]
    fn a_historical_bite_is_flagged_and_leaves_out_what_the_history_lacks() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        node.births(&results, &[], 1000);
        results.drivelines[1].bite_counter = 9;
        results.drivelines[1].taf = Some(1.3);
        let recorded = ["bite_counter", "taf"];
        let payload = decode(&node.bite(
            1,
            &results.drivelines[1],
            777,
            (Some(&recorded), true),
            None,
        ));
        assert_eq!(payload.timestamp, Some(777));
        assert!(payload
            .metrics
            .iter()
            .all(|m| m.is_historical == Some(true) && m.timestamp == Some(777)));
        assert_eq!(payload.metrics.len(), recorded.len() + 1);
        let taf = payload
            .metrics
            .iter()
            .find(|m| m.alias == Some(driveline_alias(1, "taf")));
        assert_eq!(taf.unwrap().value, Some(MetricValue::DoubleValue(1.3)));
        let bite_id = driveline_alias(1, BITE_ID);
        let id = payload.metrics.iter().find(|m| m.alias == Some(bite_id));
        assert_eq!(id.unwrap().value, Some(MetricValue::LongValue(9)));
        // A historical bite does not change what DDATA compares with, nor count as the
        // live bite the results show: its values go once the hold is over.
        assert!(node.data(&results, 1100).is_empty());
        assert_eq!(node.data(&results, 1100 + BITE_HOLD_MS).len(), 1);
    }

    #[test]
    fn a_tandem_mill_publishes_its_early_warning_and_slow_down_request() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        node.births(&results, &[], 1000);
        let mill = &mut results.tandem_mills[0];
        mill.gain_ratio = Some(1.25);
        mill.worst_stand = Some(3);
        mill.slow_down_request = true;
        let data = node.data(&results, 1100);
        assert_eq!(data.len(), 1);
        assert_eq!(data[0].topic, "spBv1.0/plant/DDATA/stand-f1/tandem");
        let values: Vec<Option<MetricValue>> = decode(&data[0])
            .metrics
            .into_iter()
            .map(|m| m.value)
            .collect();
        assert_eq!(values.len(), 3, "{values:?}");
        assert!(values.contains(&Some(MetricValue::DoubleValue(1.25))));
        // 1-based, as the register; a UInt64 (Tahu's JS codec reads UInt32 as null).
        assert!(values.contains(&Some(MetricValue::LongValue(4))));
        assert!(values.contains(&Some(MetricValue::BooleanValue(true))));
    }

    #[test]
    fn a_bites_changed_values_wait_for_the_bites_own_ddata() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        node.births(&results, &[], 1000);
        // A degraded bite: the results move before the history has the bite.
        results.drivelines[0].bite_counter = 1;
        results.drivelines[0].last_bite_degraded = true;
        assert!(node.data(&results, 1100).is_empty(), "held for the bite");
        let bite = decode(&node.bite(0, &results.drivelines[0], 1150, (None, false), None));
        assert!(bite.metrics.len() > 1);
        assert!(
            node.data(&results, 1200).is_empty(),
            "the bite carried the changed values"
        );
        // A bite the history never gives: its values go after the hold.
        results.drivelines[1].bite_counter = 1;
        results.drivelines[1].taf = Some(1.2);
        assert!(node.data(&results, 2000).is_empty());
        assert!(node.data(&results, 2000 + BITE_HOLD_MS - 1).is_empty());
        let late = node.data(&results, 2000 + BITE_HOLD_MS);
        assert_eq!(late.len(), 1);
        assert!(late[0].topic.ends_with("/F2"));
    }

    #[test]
    fn a_stale_tandem_mill_sends_no_frozen_chatter_figures() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        let mill = &mut results.tandem_mills[0];
        mill.evaluations = 4;
        mill.sigma_n_hz = Some(0.5);
        mill.k_mean = Some(0.9);
        node.births(&results, &[], 1000);
        results.tandem_mills[0].source_stale = true;
        let data = node.data(&results, 1100);
        let payload = decode(&data[0]);
        let sigma_alias = NODE_METRICS
            + 2 * (catalogue::DRIVELINE.len() as u64 + 1 + CAPTURE_METRICS.len() as u64)
            + catalogue::TANDEM_MILL
                .iter()
                .position(|f| f.key == "sigma_n_hz")
                .unwrap() as u64;
        let sigma = payload
            .metrics
            .iter()
            .find(|m| m.alias == Some(sigma_alias))
            .expect("sigma_n sent");
        assert_eq!(sigma.is_null, Some(true), "withdrawn, not frozen");
        assert_eq!(sigma.value, None);
    }
}
