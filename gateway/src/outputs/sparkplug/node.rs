//! The Sparkplug B edge node as a state machine without I/O: which message to send
//! for a session's start (the Will NDEATH, NBIRTH, one DBIRTH per device), for changed
//! values (NDATA/DDATA by alias), for each bite (its own DDATA with a bite id) and for
//! a rebirth command. The task in [`super`] moves the messages to the broker.
//!
//! Devices: each driveline, each tandem mill and each rod mill, named as in the
//! configuration; their metrics are the catalogue's figures, named by their keys, with
//! the catalogue's units ([`crate::state::catalogue`]). A rod mill's per-span metrics
//! are `span<i>/<key>` (i 1-based in rolling order), as many spans as its mill file has
//! (fixed at birth). A driveline's bite DDATA adds `bite_id`. A value the stale rule
//! withholds is sent null.
//! Aliases are unique within the node: the node's metrics first, then each device's in
//! order. `seq` counts 0..=255 over every message of the session but the NDEATH, and
//! starts at 0 with each NBIRTH; `bdSeq` (0..=255) is the session number the NBIRTH
//! and the Will's NDEATH carry (the task persists it in the history file).

use prost::Message as _;

use super::devices::{columns, values, wire, Column, Device, Kind};
use super::payload::{DataType, Metric, MetricValue, Payload, PropertySet};
use crate::state::catalogue::{self, Value};
use crate::state::results::{DrivelineResults, Results};

/// The Sparkplug B topic namespace.
pub const NAMESPACE: &str = "spBv1.0";
/// The node metric a host sets to `true` in an NCMD to ask for the births again.
pub const REBIRTH: &str = "Node Control/Rebirth";

/// One MQTT message to publish.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    /// The topic.
    pub topic: String,
    /// The encoded [`Payload`].
    pub payload: Vec<u8>,
}

/// The bite id metric of a bite's DDATA: the driveline's bite counter after the bite,
/// which the history keeps across restarts, so (device, bite_id) names a bite once.
pub const BITE_ID: &str = "bite_id";

/// The capture metrics of a driveline device, after [`BITE_ID`], and of a tandem mill
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
pub struct CaptureNotice {
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
    fn metrics(notice: Option<&Self>, first_alias: u64, ms: u64, named: bool) -> Vec<Metric> {
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

/// Longest a driveline's changed values wait for the DDATA of the bite that changed
/// them (a bite reaches the history, and from it the broker, within milliseconds; a
/// history that cannot store it must not hold the values back for good).
pub const BITE_HOLD_MS: u64 = 2000;

/// Node metrics: bdSeq (alias 0) and the rebirth command (alias 1).
const NODE_METRICS: u64 = 2;

/// The edge node of one session.
#[derive(Debug)]
pub struct EdgeNode {
    group: String,
    node: String,
    bd_seq: u8,
    seq: u8,
    devices: Vec<Device>,
}

impl EdgeNode {
    /// The node `group`/`node` with these devices, in session `bd_seq`: the
    /// drivelines, the tandem mills, then the rod mills (name, span count), each in
    /// config order.
    pub fn new(
        group: &str,
        node: &str,
        (drivelines, tandem_mills): (&[String], &[String]),
        rod_mills: &[(String, usize)],
        bd_seq: u8,
    ) -> Self {
        let mut devices = Vec::new();
        let mut alias = NODE_METRICS;
        // `extra`: aliases kept after the columns (a driveline's capture metrics).
        let mut add = |name: &str, kind: Kind, columns: Vec<Column>, extra: u64| {
            let width = columns.len() as u64;
            devices.push(Device {
                name: name.to_owned(),
                kind,
                columns,
                first_alias: alias,
                sent: Vec::new(),
                bite_counter: None,
                held_since: None,
            });
            alias += width + extra;
        };
        for (k, name) in drivelines.iter().enumerate() {
            let mut driveline: Vec<Column> = columns(catalogue::DRIVELINE, "").collect();
            driveline.push(Column {
                name: BITE_ID.to_owned(),
                datatype: DataType::UInt64,
                unit: "",
            });
            // The capture metrics' aliases follow (not columns: they are no figures).
            let extra = CAPTURE_METRICS.len() as u64;
            add(name, Kind::Driveline(k), driveline, extra);
        }
        for (k, name) in tandem_mills.iter().enumerate() {
            add(
                name,
                Kind::TandemMill(k),
                columns(catalogue::TANDEM_MILL, "").collect(),
                CAPTURE_METRICS.len() as u64,
            );
        }
        for (k, (name, spans)) in rod_mills.iter().enumerate() {
            let mut rod: Vec<Column> = columns(catalogue::ROD_MILL, "").collect();
            for span in 1..=*spans {
                rod.extend(columns(catalogue::ROD_SPAN, &format!("span{span}/")));
            }
            add(name, Kind::RodMill(k, *spans), rod, 0);
        }
        Self {
            group: group.to_owned(),
            node: node.to_owned(),
            bd_seq,
            seq: 0,
            devices,
        }
    }

    /// This session's bdSeq.
    pub fn bd_seq(&self) -> u8 {
        self.bd_seq
    }

    /// A new MQTT session: the next bdSeq (the caller persists it before connecting).
    pub fn new_session(&mut self, bd_seq: u8) {
        self.bd_seq = bd_seq;
    }

    fn node_topic(&self, kind: &str) -> String {
        format!("{NAMESPACE}/{}/{kind}/{}", self.group, self.node)
    }

    fn device_topic(&self, kind: &str, device: usize) -> String {
        format!(
            "{NAMESPACE}/{}/{kind}/{}/{}",
            self.group, self.node, self.devices[device].name
        )
    }

    /// The NCMD topic the node subscribes to.
    pub fn command_topic(&self) -> String {
        self.node_topic("NCMD")
    }

    fn next_seq(&mut self) -> u64 {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        u64::from(seq)
    }

    /// The bdSeq metric: Int64, as Sparkplug 3.0 asks of the Will's and the NBIRTH's.
    fn bd_seq_metric(&self, now_ms: u64) -> Metric {
        Metric {
            name: Some("bdSeq".to_owned()),
            alias: None,
            timestamp: Some(now_ms),
            datatype: Some(DataType::Int64.code()),
            value: Some(MetricValue::LongValue(u64::from(self.bd_seq))),
            ..Metric::default()
        }
    }

    /// The Will: NDEATH with this session's bdSeq (no seq).
    pub fn death(&self, now_ms: u64) -> Outgoing {
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics: vec![self.bd_seq_metric(now_ms)],
            ..Payload::default()
        };
        Outgoing {
            topic: self.node_topic("NDEATH"),
            payload: payload.encode_to_vec(),
        }
    }

    /// NBIRTH (seq 0) and a DBIRTH per device with every metric: name, alias,
    /// datatype, unit, value; a driveline's and a tandem mill's with its newest capture
    /// (`captures`: the drivelines' in order, then the tandem mills').
    pub fn births(
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

    fn device_message(&mut self, topic: String, metrics: Vec<Metric>, now_ms: u64) -> Outgoing {
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics,
            seq: Some(self.next_seq()),
            ..Payload::default()
        };
        Outgoing {
            topic,
            payload: payload.encode_to_vec(),
        }
    }

    /// A DDATA per device whose values changed since the last birth or data message,
    /// with only the changed metrics, by alias. A driveline whose results show a bite
    /// whose own DDATA has not gone yet waits for it (at most [`BITE_HOLD_MS`]): a host
    /// sees a bite's DDATA before the values it changed, never after.
    pub fn data(&mut self, results: &Results, now_ms: u64) -> Vec<Outgoing> {
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
    pub fn bite(
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

impl EdgeNode {
    /// The DDATA announcing `capture`, one of tandem mill `mill`'s (a chatter episode
    /// or a manual capture of its stands): its capture metrics, timestamped `now_ms`.
    pub fn mill_capture(&mut self, mill: usize, capture: &CaptureNotice, now_ms: u64) -> Outgoing {
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

/// The topic a primary host application publishes its STATE on (Sparkplug 3.0).
pub fn state_topic(host_id: &str) -> String {
    format!("{NAMESPACE}/STATE/{host_id}")
}

/// Whether a STATE payload (`{"online": true, "timestamp": ...}`) says the host is
/// online; `None` when it is not such JSON.
pub fn host_online(payload: &[u8]) -> Option<bool> {
    let state: serde_json::Value = serde_json::from_slice(payload).ok()?;
    state.get("online")?.as_bool()
}

/// Whether an NCMD payload asks for a rebirth (`Node Control/Rebirth` = true, by
/// name or by its alias).
pub fn is_rebirth(payload: &[u8]) -> Result<bool, prost::DecodeError> {
    let payload = Payload::decode(payload)?;
    Ok(payload.metrics.iter().any(|metric| {
        let named = metric.name.as_deref() == Some(REBIRTH) || metric.alias == Some(1);
        named && metric.value == Some(MetricValue::BooleanValue(true))
    }))
}

fn metric(
    name: Option<&str>,
    alias: u64,
    datatype: DataType,
    value: Option<Value>,
    now_ms: u64,
) -> Metric {
    Metric {
        name: name.map(str::to_owned),
        alias: Some(alias),
        timestamp: Some(now_ms),
        datatype: Some(datatype.code()),
        is_null: value.is_none().then_some(true),
        value: value.map(wire),
        ..Metric::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::results::{RodMillResults, RodSpanResults};

    fn decode(out: &Outgoing) -> Payload {
        Payload::decode(out.payload.as_slice()).unwrap()
    }

    fn node_with(rod_mills: &[(String, usize)]) -> EdgeNode {
        EdgeNode::new(
            "plant",
            "stand-f1",
            (&["F1".into(), "F2".into()], &["tandem".into()]),
            rod_mills,
            7,
        )
    }

    fn node() -> EdgeNode {
        node_with(&[])
    }

    /// The alias of driveline `index`'s metric named `name` (`bite_id` after the
    /// figures).
    fn driveline_alias(index: usize, name: &str) -> u64 {
        let width = catalogue::DRIVELINE.len() as u64 + 1 + CAPTURE_METRICS.len() as u64;
        let at = catalogue::DRIVELINE
            .iter()
            .position(|f| f.key == name)
            .map_or(catalogue::DRIVELINE.len(), |at| at) as u64;
        NODE_METRICS + width * index as u64 + at
    }

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

    #[test]
    fn a_rebirth_command_is_recognised_by_name_or_alias() {
        let by_name = Payload {
            metrics: vec![Metric {
                name: Some(REBIRTH.into()),
                datatype: Some(DataType::Boolean.code()),
                value: Some(MetricValue::BooleanValue(true)),
                ..Metric::default()
            }],
            ..Payload::default()
        };
        assert!(is_rebirth(&by_name.encode_to_vec()).unwrap());
        let other = Payload {
            metrics: vec![Metric {
                name: Some("Node Control/Reboot".into()),
                value: Some(MetricValue::BooleanValue(true)),
                ..Metric::default()
            }],
            ..Payload::default()
        };
        assert!(!is_rebirth(&other.encode_to_vec()).unwrap());
        assert!(is_rebirth(b"\xff\xff").is_err());
    }

    #[test]
    fn a_host_state_is_read_from_its_json() {
        assert_eq!(
            host_online(br#"{"online": true, "timestamp": 1}"#),
            Some(true)
        );
        assert_eq!(
            host_online(br#"{"online":false,"timestamp":1}"#),
            Some(false)
        );
        assert_eq!(host_online(b"ONLINE"), None);
        assert_eq!(state_topic("scada"), "spBv1.0/STATE/scada");
    }
}
