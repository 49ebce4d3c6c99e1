//! The Sparkplug B edge node as a state machine without I/O: which message to send
//! for a session's start (the Will NDEATH, NBIRTH, one DBIRTH per device), for changed
//! values (NDATA/DDATA by alias), for each bite (its own DDATA with a bite id) and for
//! a rebirth command. The task in [`super`] moves the messages to the broker.
//!
//! Devices: each driveline and each tandem mill, named as in the configuration.
//! Aliases are unique within the node: the node's metrics first, then each device's in
//! order. `seq` counts 0..=255 over every message of the session but the NDEATH, and
//! starts at 0 with each NBIRTH; `bdSeq` (0..=255) is the session number the NBIRTH
//! and the Will's NDEATH carry (the task persists it in the history file).

use prost::Message as _;

use super::payload::{DataType, Metric, MetricValue, Payload, PropertySet};
use crate::outputs::results::{DrivelineResults, MillResults, Results};

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

/// A metric's value as millgate has it; `None` is published as `is_null`.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Value {
    U32(u32),
    U64(u64),
    F64(f64),
    Bool(bool),
    /// ms since the Unix epoch.
    Time(u64),
}

impl Value {
    fn datatype(self) -> DataType {
        match self {
            Value::U32(_) => DataType::UInt32,
            Value::U64(_) => DataType::UInt64,
            Value::F64(_) => DataType::Double,
            Value::Bool(_) => DataType::Boolean,
            Value::Time(_) => DataType::DateTime,
        }
    }

    fn wire(self) -> MetricValue {
        match self {
            Value::U32(v) => MetricValue::IntValue(v),
            Value::U64(v) | Value::Time(v) => MetricValue::LongValue(v),
            Value::F64(v) => MetricValue::DoubleValue(v),
            Value::Bool(v) => MetricValue::BooleanValue(v),
        }
    }
}

/// A device metric: name, datatype, unit and how to read it from the results.
struct Def<R> {
    name: &'static str,
    datatype: DataType,
    unit: &'static str,
    read: fn(&R) -> Option<Value>,
}

/// A driveline's metrics (the register map's driveline block, with units).
const DRIVELINE: &[Def<DrivelineResults>] = &[
    Def {
        name: "bite_counter",
        datatype: DataType::UInt32,
        unit: "",
        read: |r| Some(Value::U32(r.bite_counter)),
    },
    Def {
        name: "last_bite_time",
        datatype: DataType::DateTime,
        unit: "",
        read: |r| r.last_bite_unix_s.map(|s| Value::Time(u64::from(s) * 1000)),
    },
    Def {
        name: "static_torque",
        datatype: DataType::Double,
        unit: "kN*m",
        read: |r| r.static_torque_knm.map(Value::F64),
    },
    Def {
        name: "peak_torque",
        datatype: DataType::Double,
        unit: "kN*m",
        read: |r| r.peak_torque_knm.map(Value::F64),
    },
    Def {
        name: "taf",
        datatype: DataType::Double,
        unit: "",
        read: |r| r.taf.map(Value::F64),
    },
    Def {
        name: "first_period_shift",
        datatype: DataType::Double,
        unit: "s",
        read: |r| r.first_period_shift_s.map(Value::F64),
    },
    Def {
        name: "beta1",
        datatype: DataType::Double,
        unit: "Hz",
        read: |r| r.beta1_hz.map(Value::F64),
    },
    Def {
        name: "beta2",
        datatype: DataType::Double,
        unit: "Hz",
        read: |r| r.beta2_hz.map(Value::F64),
    },
    Def {
        name: "wear_index",
        datatype: DataType::Double,
        unit: "",
        read: |r| r.wear_index.map(Value::F64),
    },
    Def {
        name: "wear_trend",
        datatype: DataType::Double,
        unit: "",
        read: |r| r.wear_trend.map(Value::F64),
    },
    Def {
        name: "degraded",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.last_bite_degraded)),
    },
    Def {
        name: "warning",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.warning)),
    },
    Def {
        name: "alarm",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.alarm)),
    },
    Def {
        name: "source_stale",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.source_stale)),
    },
    Def {
        name: "restored",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.restored)),
    },
    Def {
        name: "gap",
        datatype: DataType::Double,
        unit: "mrad",
        read: |r| r.gap.as_ref().map(|g| Value::F64(g.gap_mrad)),
    },
    Def {
        name: "gap_low",
        datatype: DataType::Double,
        unit: "mrad",
        read: |r| r.gap.as_ref().map(|g| Value::F64(g.low_mrad)),
    },
    Def {
        name: "gap_high",
        datatype: DataType::Double,
        unit: "mrad",
        read: |r| r.gap.as_ref().map(|g| Value::F64(g.high_mrad)),
    },
    Def {
        // Model index, 0 = motor side; null while undetermined.
        name: "gap_coupling",
        datatype: DataType::UInt32,
        unit: "",
        read: |r| {
            let coupling = r.gap.as_ref()?.coupling?;
            u32::try_from(coupling).ok().map(Value::U32)
        },
    },
    Def {
        name: "bites_pooled",
        datatype: DataType::UInt32,
        unit: "",
        read: |r| {
            let pooled = r.gap.as_ref()?.bites_pooled;
            Some(Value::U32(u32::try_from(pooled).unwrap_or(u32::MAX)))
        },
    },
    Def {
        name: "gap_warning",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.gap_warning)),
    },
    Def {
        name: "gap_alarm",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.gap_alarm)),
    },
];

/// A tandem mill's chatter metrics.
const MILL: &[Def<MillResults>] = &[
    Def {
        name: "evaluations",
        datatype: DataType::UInt64,
        unit: "",
        read: |r| Some(Value::U64(r.evaluations)),
    },
    Def {
        name: "sigma_n",
        datatype: DataType::Double,
        unit: "Hz",
        read: |r| r.sigma_n_hz.map(Value::F64),
    },
    Def {
        name: "k_mean",
        datatype: DataType::Double,
        unit: "",
        read: |r| r.k_mean.map(Value::F64),
    },
    Def {
        name: "chatter_frequency",
        datatype: DataType::Double,
        unit: "Hz",
        read: |r| r.chatter_frequency_hz.map(Value::F64),
    },
    Def {
        name: "warning",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.warning)),
    },
    Def {
        name: "alarm",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.alarm)),
    },
    Def {
        name: "source_stale",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.source_stale)),
    },
    Def {
        name: "chatter_gain",
        datatype: DataType::Double,
        unit: "",
        read: |r| r.chatter_gain.map(Value::F64),
    },
    Def {
        name: "gain_ratio",
        datatype: DataType::Double,
        unit: "",
        read: |r| r.gain_ratio.map(Value::F64),
    },
    Def {
        name: "band_rms_max",
        datatype: DataType::Double,
        // In the stand channels' own unit.
        unit: "",
        read: |r| r.band_rms_max.map(Value::F64),
    },
    Def {
        name: "worst_stand",
        datatype: DataType::UInt32,
        unit: "",
        // 1-based, as the register.
        read: |r| {
            r.worst_stand
                .map(|stand| Value::U32(u32::try_from(stand + 1).unwrap_or(u32::MAX)))
        },
    },
    Def {
        name: "slow_down_request",
        datatype: DataType::Boolean,
        unit: "",
        read: |r| Some(Value::Bool(r.slow_down_request)),
    },
];

/// Driveline metrics a bite's history row does not keep (flags of the moment): a
/// replayed bite's DDATA leaves them out rather than claim a value.
pub const NOT_RECORDED: &[&str] = &[
    "warning",
    "alarm",
    "source_stale",
    "restored",
    "gap_warning",
    "gap_alarm",
];

/// The bite id metric of a bite's DDATA: the driveline's bite counter after the bite,
/// which the history keeps across restarts, so (device, bite_id) names a bite once.
pub const BITE_ID: &str = "bite_id";

/// Node metrics: bdSeq (alias 0) and the rebirth command (alias 1).
const NODE_METRICS: u64 = 2;

/// The edge node of one session.
#[derive(Debug)]
pub struct EdgeNode {
    group: String,
    node: String,
    drivelines: Vec<String>,
    mills: Vec<String>,
    bd_seq: u8,
    seq: u8,
    /// What the last birth or data message said, per device and metric.
    sent_drivelines: Vec<Vec<Option<Value>>>,
    sent_mills: Vec<Vec<Option<Value>>>,
}

impl EdgeNode {
    /// The node `group`/`node` with these devices, in session `bd_seq`.
    pub fn new(
        group: &str,
        node: &str,
        drivelines: &[String],
        mills: &[String],
        bd_seq: u8,
    ) -> Self {
        Self {
            group: group.to_owned(),
            node: node.to_owned(),
            drivelines: drivelines.to_vec(),
            mills: mills.to_vec(),
            bd_seq,
            seq: 0,
            sent_drivelines: vec![Vec::new(); drivelines.len()],
            sent_mills: vec![Vec::new(); mills.len()],
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

    fn device_topic(&self, kind: &str, device: &str) -> String {
        format!("{NAMESPACE}/{}/{kind}/{}/{device}", self.group, self.node)
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

    fn bd_seq_metric(&self, named: bool) -> Metric {
        Metric {
            name: named.then(|| "bdSeq".to_owned()),
            alias: None,
            datatype: Some(DataType::UInt64.code()),
            value: Some(MetricValue::LongValue(u64::from(self.bd_seq))),
            ..Metric::default()
        }
    }

    /// The Will: NDEATH with this session's bdSeq (no seq).
    pub fn death(&self, now_ms: u64) -> Outgoing {
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics: vec![self.bd_seq_metric(true)],
            ..Payload::default()
        };
        Outgoing {
            topic: self.node_topic("NDEATH"),
            payload: payload.encode_to_vec(),
        }
    }

    /// NBIRTH (seq 0) and a DBIRTH per device with every metric: name, alias,
    /// datatype, unit, value.
    pub fn births(&mut self, results: &Results, now_ms: u64) -> Vec<Outgoing> {
        self.seq = 0;
        let mut node_metrics = vec![self.bd_seq_metric(true)];
        node_metrics.push(Metric {
            name: Some(REBIRTH.to_owned()),
            alias: Some(1),
            datatype: Some(DataType::Boolean.code()),
            value: Some(MetricValue::BooleanValue(false)),
            ..Metric::default()
        });
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
        for index in 0..self.drivelines.len() {
            let values = read_all(DRIVELINE, results.drivelines.get(index));
            let metrics = birth_metrics(
                DRIVELINE,
                self.driveline_alias(index, 0),
                &values,
                now_ms,
                true,
            );
            self.sent_drivelines[index] = values;
            let topic = self.device_topic("DBIRTH", &self.drivelines[index]);
            out.push(self.device_message(topic, metrics, now_ms));
        }
        for index in 0..self.mills.len() {
            let values = read_all(MILL, results.mills.get(index));
            let metrics = birth_metrics(MILL, self.mill_alias(index, 0), &values, now_ms, false);
            self.sent_mills[index] = values;
            let topic = self.device_topic("DBIRTH", &self.mills[index]);
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

    /// Alias of driveline `index`'s metric `metric` (the bite id after the others).
    fn driveline_alias(&self, index: usize, metric: usize) -> u64 {
        NODE_METRICS + (index * (DRIVELINE.len() + 1) + metric) as u64
    }

    fn mill_alias(&self, index: usize, metric: usize) -> u64 {
        let drivelines = self.drivelines.len() * (DRIVELINE.len() + 1);
        NODE_METRICS + (drivelines + index * MILL.len() + metric) as u64
    }

    /// A DDATA per device whose values changed since the last birth or data message,
    /// with only the changed metrics, by alias.
    pub fn data(&mut self, results: &Results, now_ms: u64) -> Vec<Outgoing> {
        let mut out = Vec::new();
        for index in 0..self.drivelines.len() {
            let values = read_all(DRIVELINE, results.drivelines.get(index));
            let base = self.driveline_alias(index, 0);
            let metrics = changed(
                DRIVELINE,
                base,
                &self.sent_drivelines[index],
                &values,
                now_ms,
            );
            if !metrics.is_empty() {
                self.sent_drivelines[index] = values;
                let topic = self.device_topic("DDATA", &self.drivelines[index]);
                out.push(self.device_message(topic, metrics, now_ms));
            }
        }
        for index in 0..self.mills.len() {
            let values = read_all(MILL, results.mills.get(index));
            let base = self.mill_alias(index, 0);
            let metrics = changed(MILL, base, &self.sent_mills[index], &values, now_ms);
            if !metrics.is_empty() {
                self.sent_mills[index] = values;
                let topic = self.device_topic("DDATA", &self.mills[index]);
                out.push(self.device_message(topic, metrics, now_ms));
            }
        }
        out
    }

    /// A bite of driveline `index`: its own DDATA with every driveline metric and the
    /// bite id, timestamped with the bite's time; `historical` flags a value sent
    /// after the fact (a bite replayed from the history), which carries only what the
    /// history keeps (not [`NOT_RECORDED`]).
    pub fn bite(
        &mut self,
        index: usize,
        after: &DrivelineResults,
        bite_ms: u64,
        historical: bool,
    ) -> Outgoing {
        let values = read_all(DRIVELINE, Some(after));
        let base = self.driveline_alias(index, 0);
        let mut metrics: Vec<Metric> = values
            .iter()
            .enumerate()
            .filter(|(at, _)| !historical || !NOT_RECORDED.contains(&DRIVELINE[*at].name))
            .map(|(at, value)| {
                metric(
                    None,
                    base + at as u64,
                    DRIVELINE[at].datatype,
                    *value,
                    bite_ms,
                )
            })
            .collect();
        metrics.push(metric(
            None,
            base + DRIVELINE.len() as u64,
            DataType::UInt64,
            Some(Value::U64(u64::from(after.bite_counter))),
            bite_ms,
        ));
        if historical {
            for metric in &mut metrics {
                metric.is_historical = Some(true);
            }
        } else {
            self.sent_drivelines[index] = values;
        }
        let topic = self.device_topic("DDATA", &self.drivelines[index]);
        self.device_message(topic, metrics, bite_ms)
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

fn read_all<R: Default>(defs: &[Def<R>], results: Option<&R>) -> Vec<Option<Value>> {
    let fallback = R::default();
    let results = results.unwrap_or(&fallback);
    defs.iter().map(|def| (def.read)(results)).collect()
}

fn metric(
    name: Option<&str>,
    alias: u64,
    datatype: DataType,
    value: Option<Value>,
    now_ms: u64,
) -> Metric {
    debug_assert!(value.is_none_or(|v| v.datatype() == datatype));
    Metric {
        name: name.map(str::to_owned),
        alias: Some(alias),
        timestamp: Some(now_ms),
        datatype: Some(datatype.code()),
        is_null: value.is_none().then_some(true),
        value: value.map(Value::wire),
        ..Metric::default()
    }
}

/// Every metric of a device's birth, then the bite id when `bite_id` (drivelines).
fn birth_metrics<R>(
    defs: &[Def<R>],
    base: u64,
    values: &[Option<Value>],
    now_ms: u64,
    bite_id: bool,
) -> Vec<Metric> {
    let mut metrics: Vec<Metric> = defs
        .iter()
        .zip(values)
        .enumerate()
        .map(|(at, (def, value))| {
            let mut metric = metric(
                Some(def.name),
                base + at as u64,
                def.datatype,
                *value,
                now_ms,
            );
            if !def.unit.is_empty() {
                metric.properties = Some(PropertySet::unit(def.unit));
            }
            metric
        })
        .collect();
    if bite_id {
        metrics.push(metric(
            Some(BITE_ID),
            base + defs.len() as u64,
            DataType::UInt64,
            None,
            now_ms,
        ));
    }
    metrics
}

fn changed<R>(
    defs: &[Def<R>],
    base: u64,
    sent: &[Option<Value>],
    values: &[Option<Value>],
    now_ms: u64,
) -> Vec<Metric> {
    defs.iter()
        .enumerate()
        .filter(|(at, _)| sent.get(*at) != values.get(*at))
        .map(|(at, def)| metric(None, base + at as u64, def.datatype, values[at], now_ms))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(out: &Outgoing) -> Payload {
        Payload::decode(out.payload.as_slice()).unwrap()
    }

    fn node() -> EdgeNode {
        EdgeNode::new(
            "plant",
            "stand-f1",
            &["F1".into(), "F2".into()],
            &["tandem".into()],
            7,
        )
    }

    #[test]
    fn births_come_in_order_with_seq_from_0_and_unique_aliases() {
        let mut node = node();
        let results = Results::new(1, 2, 1);
        let births = node.births(&results, 1000);
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
        node.births(&results, 1000);
        assert!(node.data(&results, 1100).is_empty(), "nothing changed");
        results.drivelines[1].alarm = true;
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
            let bite = node.bite(0, &results.drivelines[0], 5000, false);
            let seq = decode(&bite).seq.unwrap();
            assert_eq!(seq, u64::from((5 + n) % 256));
        }
    }

    #[test]
    fn a_historical_bite_is_flagged_and_leaves_out_what_the_history_lacks() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        node.births(&results, 1000);
        results.drivelines[1].bite_counter = 9;
        results.drivelines[1].taf = Some(1.3);
        let payload = decode(&node.bite(1, &results.drivelines[1], 777, true));
        assert_eq!(payload.timestamp, Some(777));
        assert!(payload
            .metrics
            .iter()
            .all(|m| m.is_historical == Some(true) && m.timestamp == Some(777)));
        assert_eq!(
            payload.metrics.len(),
            DRIVELINE.len() - NOT_RECORDED.len() + 1
        );
        let bite_id = node.driveline_alias(1, DRIVELINE.len());
        let id = payload.metrics.iter().find(|m| m.alias == Some(bite_id));
        assert_eq!(id.unwrap().value, Some(MetricValue::LongValue(9)));
        // A historical bite does not change what DDATA compares with.
        assert!(node.data(&results, 1100).len() == 1);
    }

    #[test]
    fn a_tandem_mill_publishes_its_early_warning_and_slow_down_request() {
        let mut node = node();
        let mut results = Results::new(1, 2, 1);
        node.births(&results, 1000);
        let mill = &mut results.mills[0];
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
        // 1-based, as the register.
        assert!(values.contains(&Some(MetricValue::IntValue(4))));
        assert!(values.contains(&Some(MetricValue::BooleanValue(true))));
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
