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
//!
//! Here: the devices and their aliases, the session's bdSeq and seq, the topics, the
//! Will. `births.rs` the NBIRTH and DBIRTHs; `data.rs` changed values and bites;
//! `captures.rs` the capture notices; `host.rs` what comes from the host application
//! (its STATE, a rebirth command).

mod births;
mod captures;
mod data;
mod host;

pub(crate) use captures::CaptureNotice;
pub use captures::CAPTURE_METRICS;
pub use data::BITE_HOLD_MS;
pub(crate) use host::{host_online, is_rebirth, state_topic, REBIRTH};

use prost::Message as _;

use super::devices::{columns, wire, Column, Device, Kind};
use super::payload::{DataType, Metric, MetricValue, Payload};
use crate::state::catalogue::{self, Value};

/// The Sparkplug B topic namespace.
pub(crate) const NAMESPACE: &str = "spBv1.0";

/// One MQTT message to publish.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Outgoing {
    /// The topic.
    pub topic: String,
    /// The encoded [`Payload`].
    pub payload: Vec<u8>,
}

/// The bite id metric of a bite's DDATA: the driveline's bite counter after the bite,
/// which the history keeps across restarts, so (device, bite_id) names a bite once.
pub const BITE_ID: &str = "bite_id";

/// Node metrics: bdSeq (alias 0) and the rebirth command (alias 1).
const NODE_METRICS: u64 = 2;

/// bdSeq's alias.
const BD_SEQ_ALIAS: u64 = 0;

/// The edge node of one session.
#[derive(Debug)]
pub(crate) struct EdgeNode {
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
    pub(crate) fn new(
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

    /// A new MQTT session: the next bdSeq (the caller persists it before connecting).
    pub(crate) fn new_session(&mut self, bd_seq: u8) {
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
    pub(crate) fn command_topic(&self) -> String {
        self.node_topic("NCMD")
    }

    fn next_seq(&mut self) -> u64 {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        u64::from(seq)
    }

    /// The bdSeq metric: Int64, as Sparkplug 3.0 asks of the Will's and the NBIRTH's,
    /// with its name and its alias ([`BD_SEQ_ALIAS`]) as every other metric of the
    /// births (a host that maps aliases finds it in the NBIRTH's map too).
    fn bd_seq_metric(&self, now_ms: u64) -> Metric {
        Metric {
            name: Some("bdSeq".to_owned()),
            alias: Some(BD_SEQ_ALIAS),
            timestamp: Some(now_ms),
            datatype: Some(DataType::Int64.code()),
            value: Some(MetricValue::LongValue(u64::from(self.bd_seq))),
            ..Metric::default()
        }
    }

    /// The Will: NDEATH with this session's bdSeq (no seq).
    pub(crate) fn death(&self, now_ms: u64) -> Outgoing {
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
}

/// A device metric by `alias` (named in a birth), `None` sent as null.
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

/// What the tests of the node's files share: a node of two drivelines and a tandem
/// mill, decoding, the drivelines' aliases.
#[cfg(test)]
mod testing {
    use super::*;

    pub(super) fn decode(out: &Outgoing) -> Payload {
        <Payload as prost::Message>::decode(out.payload.as_slice()).unwrap()
    }

    pub(super) fn node_with(rod_mills: &[(String, usize)]) -> EdgeNode {
        EdgeNode::new(
            "plant",
            "stand-f1",
            (&["F1".into(), "F2".into()], &["tandem".into()]),
            rod_mills,
            7,
        )
    }

    pub(super) fn node() -> EdgeNode {
        node_with(&[])
    }

    /// The alias of driveline `index`'s metric named `name` (`bite_id` after the
    /// figures).
    pub(super) fn driveline_alias(index: usize, name: &str) -> u64 {
        let width = catalogue::DRIVELINE.len() as u64 + 1 + CAPTURE_METRICS.len() as u64;
        let at = catalogue::DRIVELINE
            .iter()
            .position(|f| f.key == name)
            .map_or(catalogue::DRIVELINE.len(), |at| at) as u64;
        NODE_METRICS + width * index as u64 + at
    }
}
