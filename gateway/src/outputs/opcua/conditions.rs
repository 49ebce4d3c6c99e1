//! Alarms & Conditions (OPC 10000-9): a condition instance per alarm an object
//! raises ([`ConditionSpec`](super::model::ConditionSpec)), its state as the alarm
//! stream changes it, the EventIds a client acknowledges with, and what a
//! ConditionRefresh sends.
//!
//! A condition becomes active and unacknowledged when its alarm is raised. A
//! latched one (TAF, gap and chatter alarms) is acknowledged by the PLC's
//! acknowledge, wherever it comes from (the PLC, the HMI, `AcknowledgeAlarms`, a
//! condition's `Acknowledge`): the alarm stream's `acknowledged` event clears it. The
//! others (warnings and outages that follow the analysis) have nothing to clear in
//! the other outputs: a client's `Acknowledge` acknowledges them on this server.
//! `Retain` while active or unacknowledged.

use std::collections::HashMap;

use opcua::types::{ByteString, DateTime, NodeId, StatusCode};

use super::events::{ConditionEvent, ConditionState};
use super::model::{object_path, AddressSpaceSpec, AlarmEventSpec};

/// One condition instance: where it is, what it is, its state (none before its
/// first event).
#[derive(Debug, Clone)]
struct Condition {
    id: NodeId,
    source: NodeId,
    source_name: String,
    kind: String,
    latched: bool,
    state: Option<ConditionState>,
}

/// Every condition instance of the address space.
#[derive(Debug, Default)]
pub(crate) struct Conditions {
    list: Vec<Condition>,
    /// By (object, kind).
    by_kind: HashMap<(usize, String), usize>,
    /// By ConditionId.
    by_id: HashMap<NodeId, usize>,
    /// The last EventId's sequence number.
    sequence: u64,
}

/// Why an acknowledge of a condition is refused before the guard looks at it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum AcknowledgeRefused {
    /// No condition has this ConditionId: `Bad_NodeIdUnknown`.
    UnknownCondition,
    /// The EventId is not the condition's last (stale, another condition's, made
    /// up): `Bad_EventIdUnknown`.
    UnknownEvent,
    /// Acknowledged already: `Bad_ConditionBranchAlreadyAcked`.
    AlreadyAcked,
}

impl AcknowledgeRefused {
    /// The OPC UA status of the refusal.
    pub(crate) fn status(self) -> StatusCode {
        match self {
            AcknowledgeRefused::UnknownCondition => StatusCode::BadNodeIdUnknown,
            AcknowledgeRefused::UnknownEvent => StatusCode::BadEventIdUnknown,
            AcknowledgeRefused::AlreadyAcked => StatusCode::BadConditionBranchAlreadyAcked,
        }
    }
}

/// A condition to acknowledge: which, and whether the PLC's acknowledge does it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ToAcknowledge {
    index: usize,
    /// A latched alarm: the PLC's acknowledge clears it in every output.
    pub(crate) latched: bool,
}

impl Conditions {
    /// The conditions of `spec`: its objects' nodes `objects`, per object its
    /// conditions' nodes `ids` (as [`super::model::ObjectSpec::conditions`]).
    pub(crate) fn new(spec: &AddressSpaceSpec, objects: &[NodeId], ids: &[Vec<NodeId>]) -> Self {
        let mut conditions = Self {
            list: Vec::new(),
            by_kind: HashMap::new(),
            by_id: HashMap::new(),
            sequence: 0,
        };
        for (object, (object_spec, condition_ids)) in spec.objects.iter().zip(ids).enumerate() {
            for (condition, id) in object_spec.conditions.iter().zip(condition_ids) {
                let index = conditions.list.len();
                conditions
                    .by_kind
                    .insert((object, condition.kind.clone()), index);
                conditions.by_id.insert(id.clone(), index);
                conditions.list.push(Condition {
                    id: id.clone(),
                    source: objects[object].clone(),
                    source_name: object_path(spec, object),
                    kind: condition.kind.clone(),
                    latched: condition.latched,
                    state: None,
                });
            }
        }
        conditions
    }

    /// The conditions of `spec` grown from these (drivelines added live): each one
    /// already here keeps its state (by its node), the EventIds go on.
    pub(crate) fn grown(
        &mut self,
        spec: &AddressSpaceSpec,
        objects: &[NodeId],
        ids: &[Vec<NodeId>],
    ) {
        let mut grown = Self::new(spec, objects, ids);
        for condition in &mut grown.list {
            if let Some(&index) = self.by_id.get(&condition.id) {
                condition.state = self.list[index].state.take();
            }
        }
        grown.sequence = self.sequence;
        *self = grown;
    }

    /// A new EventId: unique for the server's life (a sequence) and across starts
    /// (the time).
    pub(crate) fn next_event_id(&mut self) -> ByteString {
        self.sequence += 1;
        let mut id = [0u8; 16];
        id[..8].copy_from_slice(&self.sequence.to_be_bytes());
        id[8..].copy_from_slice(&DateTime::now().ticks().to_be_bytes());
        ByteString::from(id.to_vec())
    }

    /// The alarm stream's `alarm` applied to its condition; the event to send and its
    /// source node, `None` for an alarm of no condition.
    pub(crate) fn update(&mut self, alarm: &AlarmEventSpec) -> Option<(ConditionEvent, NodeId)> {
        let index = *self.by_kind.get(&(alarm.object, alarm.kind.clone()))?;
        let event_id = self.next_event_id();
        let condition = &mut self.list[index];
        let time = super::events::ua_time(alarm.time);
        let before = condition.state.take();
        let was_active = before.as_ref().is_some_and(|s| s.active);
        let acked = if condition.latched {
            !alarm.unacknowledged
        } else if alarm.active && !was_active {
            false
        } else {
            before.as_ref().is_none_or(|s| s.acked)
        };
        let changed = |now: bool, then: Option<bool>, since: Option<DateTime>| match since {
            Some(since) if then == Some(now) => since,
            _ => time,
        };
        let state = ConditionState {
            event_id,
            active: alarm.active,
            acked,
            severity: alarm.severity,
            last_severity: before.as_ref().map_or(alarm.severity, |s| s.severity),
            message: alarm.message.clone(),
            time,
            active_since: changed(
                alarm.active,
                before.as_ref().map(|s| s.active),
                before.as_ref().map(|s| s.active_since),
            ),
            acked_since: changed(
                acked,
                before.as_ref().map(|s| s.acked),
                before.as_ref().map(|s| s.acked_since),
            ),
            comment: before.as_ref().map_or(String::new(), |s| s.comment.clone()),
            client_user_id: before.map_or(String::new(), |s| s.client_user_id),
        };
        condition.state = Some(state);
        Some(self.event(index))
    }

    /// The event of condition `index` in its present state.
    fn event(&self, index: usize) -> (ConditionEvent, NodeId) {
        let condition = &self.list[index];
        let state = condition.state.as_ref().expect("a condition with a state");
        let source = (&condition.source, condition.source_name.as_str());
        let event = ConditionEvent::new(&condition.id, source, &condition.kind, state);
        (event, condition.source.clone())
    }

    /// The events of the retained conditions (active or unacknowledged), as last
    /// sent (their EventIds too), for a ConditionRefresh.
    pub(crate) fn retained(&self) -> Vec<(ConditionEvent, NodeId)> {
        (0..self.list.len())
            .filter(|&index| {
                self.list[index]
                    .state
                    .as_ref()
                    .is_some_and(ConditionState::retain)
            })
            .map(|index| self.event(index))
            .collect()
    }

    /// Whether `condition` may be acknowledged with `event_id`: its last event's id,
    /// and not acknowledged yet.
    pub(crate) fn check_acknowledge(
        &self,
        condition: &NodeId,
        event_id: &ByteString,
    ) -> Result<ToAcknowledge, AcknowledgeRefused> {
        let index = *self
            .by_id
            .get(condition)
            .ok_or(AcknowledgeRefused::UnknownCondition)?;
        let entry = &self.list[index];
        let state = entry
            .state
            .as_ref()
            .ok_or(AcknowledgeRefused::UnknownEvent)?;
        if state.event_id != *event_id {
            return Err(AcknowledgeRefused::UnknownEvent);
        }
        if state.acked {
            return Err(AcknowledgeRefused::AlreadyAcked);
        }
        Ok(ToAcknowledge {
            index,
            latched: entry.latched,
        })
    }

    /// Keep the comment and who acknowledged `condition`; for one that is not
    /// latched, acknowledge it here: its event (a latched one's comes with the
    /// alarm stream's `acknowledged`).
    pub(crate) fn acknowledged(
        &mut self,
        condition: ToAcknowledge,
        comment: &str,
        who: &str,
    ) -> Option<(ConditionEvent, NodeId)> {
        let event_id = self.next_event_id();
        let entry = &mut self.list[condition.index];
        let state = entry.state.as_mut()?;
        state.comment = comment.to_owned();
        state.client_user_id = who.to_owned();
        if condition.latched {
            return None;
        }
        let now = DateTime::now();
        state.event_id = event_id;
        state.acked = true;
        state.acked_since = now;
        state.time = now;
        state.last_severity = state.severity;
        state.message = format!("{}: {} acknowledged", entry.source_name, entry.kind);
        Some(self.event(condition.index))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::outputs::opcua::model::{ConditionSpec, ObjectKind, ObjectSpec};
    use std::time::{Duration, UNIX_EPOCH};

    fn spec() -> AddressSpaceSpec {
        let condition = |kind: &str, latched| ConditionSpec {
            kind: kind.into(),
            description: String::new(),
            latched,
        };
        AddressSpaceSpec {
            name: "plant".into(),
            objects: vec![ObjectSpec {
                name: "F1".into(),
                kind: ObjectKind::Driveline,
                parent: None,
                description: String::new(),
                variables: Vec::new(),
                conditions: vec![
                    condition("taf_warning", false),
                    condition("taf_alarm", true),
                ],
            }],
            machines: Vec::new(),
        }
    }

    fn alarm(kind: &str, active: bool, unacknowledged: bool, s: u64) -> AlarmEventSpec {
        AlarmEventSpec {
            object: 0,
            kind: kind.into(),
            severity: 800,
            message: format!("{kind} {active}"),
            active,
            unacknowledged,
            time: UNIX_EPOCH + Duration::from_secs(1_700_000_000 + s),
        }
    }

    /// The conditions of [`spec`] and their ids (`taf_warning`, `taf_alarm`).
    fn conditions() -> (Conditions, Vec<NodeId>) {
        let object = "Millgate/Drivelines/F1";
        let ids: Vec<NodeId> = ["taf_warning", "taf_alarm"]
            .iter()
            .map(|kind| NodeId::new(2, format!("{object}/Conditions/{kind}")))
            .collect();
        let conditions = Conditions::new(
            &spec(),
            &[NodeId::new(2, object)],
            std::slice::from_ref(&ids),
        );
        (conditions, ids)
    }

    fn event_id(conditions: &Conditions, kind: &str) -> ByteString {
        let index = conditions.by_kind[&(0, kind.to_owned())];
        conditions.list[index]
            .state
            .as_ref()
            .unwrap()
            .event_id
            .clone()
    }

    #[test]
    fn a_latched_alarm_waits_for_the_plc_acknowledge_and_stale_event_ids_are_refused() {
        let (mut conditions, ids) = conditions();
        let alarm_id = ids[1].clone();
        assert_eq!(
            conditions.check_acknowledge(&alarm_id, &ByteString::from(vec![1])),
            Err(AcknowledgeRefused::UnknownEvent),
            "no event yet"
        );
        conditions
            .update(&alarm("taf_alarm", true, true, 0))
            .unwrap();
        let first = event_id(&conditions, "taf_alarm");
        assert_eq!(conditions.retained().len(), 1);
        conditions
            .update(&alarm("taf_alarm", true, true, 1))
            .unwrap();
        let second = event_id(&conditions, "taf_alarm");
        assert_ne!(first, second, "each event has its id");
        assert_eq!(
            conditions.check_acknowledge(&alarm_id, &first),
            Err(AcknowledgeRefused::UnknownEvent),
            "a stale EventId"
        );
        conditions
            .update(&alarm("taf_warning", true, false, 1))
            .unwrap();
        let warning = event_id(&conditions, "taf_warning");
        assert_eq!(
            conditions.check_acknowledge(&alarm_id, &warning),
            Err(AcknowledgeRefused::UnknownEvent),
            "another condition's EventId"
        );
        let unknown = NodeId::new(2, "Millgate/Drivelines/F2/Conditions/taf_alarm");
        assert_eq!(
            conditions.check_acknowledge(&unknown, &second),
            Err(AcknowledgeRefused::UnknownCondition)
        );
        let to_ack = conditions.check_acknowledge(&alarm_id, &second).unwrap();
        assert!(to_ack.latched);
        // Latched: nothing changes here until the alarm stream says acknowledged.
        assert!(conditions
            .acknowledged(to_ack, "seen", "operator")
            .is_none());
        assert_eq!(event_id(&conditions, "taf_alarm"), second);
        conditions
            .update(&alarm("taf_alarm", false, false, 2))
            .unwrap();
        let third = event_id(&conditions, "taf_alarm");
        assert_eq!(
            conditions.check_acknowledge(&alarm_id, &third),
            Err(AcknowledgeRefused::AlreadyAcked)
        );
        // The warning is retained (active, unacknowledged), the alarm not any more.
        assert_eq!(conditions.retained().len(), 1);
    }

    #[test]
    fn a_warning_is_acknowledged_here_and_retained_until_then() {
        let (mut conditions, ids) = conditions();
        let warning_id = ids[0].clone();
        conditions
            .update(&alarm("taf_warning", true, false, 0))
            .unwrap();
        conditions
            .update(&alarm("taf_warning", false, false, 1))
            .unwrap();
        assert_eq!(conditions.retained().len(), 1, "cleared, not acknowledged");
        let id = event_id(&conditions, "taf_warning");
        let to_ack = conditions.check_acknowledge(&warning_id, &id).unwrap();
        assert!(!to_ack.latched);
        assert!(conditions.acknowledged(to_ack, "ok", "operator").is_some());
        assert_ne!(event_id(&conditions, "taf_warning"), id);
        assert!(conditions.retained().is_empty());
        // Raised again: unacknowledged again.
        conditions
            .update(&alarm("taf_warning", true, false, 2))
            .unwrap();
        assert_eq!(conditions.retained().len(), 1);
    }
}
