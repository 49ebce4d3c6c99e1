//! The events the server sends: a condition's state as an event of
//! `AlarmConditionType` ([`ConditionEvent`]), and the `RefreshStartEventType` and
//! `RefreshEndEventType` that frame a ConditionRefresh (OPC 10000-9 5.5.7).
//!
//! A condition event carries the base event's fields (EventId, EventType,
//! SourceNode, SourceName, Time, ReceiveTime, Message, Severity), the condition's
//! (ConditionId: the instance's node, ConditionName, ConditionClassId/Name: process,
//! BranchId null, Retain, EnabledState, Quality, LastSeverity, Comment,
//! ClientUserId), the acknowledgeable condition's (AckedState) and the alarm's
//! (ActiveState), each state with its Id, its text, its TrueState/FalseState texts
//! and its TransitionTime. ConfirmedState is not offered.
//!
//! async-opcua's generated `AlarmConditionType` answers no field for an empty browse
//! path (ConditionId is the NodeId attribute of the event's condition) and types
//! Quality, LastSeverity and Comment as extension objects: [`ConditionEvent`] answers
//! those itself and hands every other field to the generated event.

use std::time::{SystemTime, UNIX_EPOCH};

use opcua::core_namespace::events::{
    AlarmConditionType, RefreshEndEventType, RefreshStartEventType, SystemEventType,
    TwoStateVariableType,
};
use opcua::nodes::{BaseEventType, Event, EventField, NamespaceMap};
use opcua::types::{
    AttributeId, ByteString, DateTime, LocalizedText, NodeId, NumericRange, ObjectId, ObjectTypeId,
    QualifiedName, StatusCode, UAString, Variant,
};

/// OPC UA ticks (100 ns since 1601-01-01) at the Unix epoch.
const UNIX_EPOCH_TICKS: i64 = 116_444_736_000_000_000;

/// `time` as an OPC UA DateTime (times before 1970 as 1970).
pub(crate) fn ua_time(time: SystemTime) -> DateTime {
    let since_epoch = time.duration_since(UNIX_EPOCH).unwrap_or_default();
    let ticks = i64::try_from(since_epoch.as_nanos() / 100).unwrap_or(i64::MAX - UNIX_EPOCH_TICKS);
    DateTime::from(UNIX_EPOCH_TICKS + ticks)
}

/// What a condition event says: the condition's state when it changed.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ConditionState {
    /// This event's id (a ConditionRefresh sends the last one again).
    pub(crate) event_id: ByteString,
    /// Whether the alarm holds.
    pub(crate) active: bool,
    /// Whether it was acknowledged since it last became active.
    pub(crate) acked: bool,
    /// Urgency 1..=1000.
    pub(crate) severity: u16,
    /// The severity of the event before this one (this one's at the first).
    pub(crate) last_severity: u16,
    /// One sentence for operators.
    pub(crate) message: String,
    /// When it happened (the bite, the window, the acknowledge).
    pub(crate) time: DateTime,
    /// When ActiveState last changed.
    pub(crate) active_since: DateTime,
    /// When AckedState last changed.
    pub(crate) acked_since: DateTime,
    /// The last acknowledge's comment and who gave it (the user, or the client's
    /// address for an anonymous session).
    pub(crate) comment: String,
    pub(crate) client_user_id: String,
}

impl ConditionState {
    /// Whether a client that connects now must be told of it (ConditionRefresh).
    pub(crate) fn retain(&self) -> bool {
        self.active || !self.acked
    }
}

/// The condition event of `condition` (its instance's node) of `source` (its node,
/// its path as the source name) called `name`, in `state`.
pub(crate) struct ConditionEvent {
    event: AlarmConditionType,
    condition: NodeId,
    quality: StatusCode,
    last_severity: u16,
    comment: LocalizedText,
}

impl ConditionEvent {
    pub(crate) fn new(
        condition: &NodeId,
        (source, source_name): (&NodeId, &str),
        name: &str,
        state: &ConditionState,
    ) -> Self {
        let mut event = AlarmConditionType::new_event(
            ObjectTypeId::AlarmConditionType.into(),
            state.event_id.clone(),
            LocalizedText::new("en", &state.message),
            &NamespaceMap::new(),
            state.time,
        );
        let acknowledgeable = &mut event.base;
        acknowledgeable.acked_state = two_state(
            state.acked,
            ("Acknowledged", "Unacknowledged"),
            state.acked_since,
        );
        let condition_fields = &mut acknowledgeable.base;
        condition_fields.condition_name = UAString::from(name);
        condition_fields.condition_class_id = ObjectTypeId::ProcessConditionClassType.into();
        condition_fields.condition_class_name = LocalizedText::new("en", "Process");
        condition_fields.retain = state.retain();
        let enabled = || two_state(true, ("Enabled", "Disabled"), state.time);
        condition_fields.enabled_state = enabled();
        condition_fields.client_user_id = UAString::from(state.client_user_id.as_str());
        let base = &mut condition_fields.base;
        base.source_node = source.clone();
        base.source_name = UAString::from(source_name);
        base.severity = state.severity.clamp(1, 1000);
        base.receive_time = DateTime::now();
        event.active_state = two_state(state.active, ("Active", "Inactive"), state.active_since);
        // The generated types repeat EnabledState at each level, and a select clause of
        // BaseEventType (node-opcua's) reaches AlarmConditionType's first.
        event.base.enabled_state = enabled();
        event.enabled_state = enabled();
        Self {
            event,
            condition: condition.clone(),
            quality: StatusCode::Good,
            last_severity: state.last_severity.clamp(1, 1000),
            comment: LocalizedText::new("en", &state.comment),
        }
    }
}

/// A TwoStateVariable's value: its text, its Id, its state names and when it changed.
fn two_state(
    id: bool,
    (true_state, false_state): (&str, &str),
    since: DateTime,
) -> TwoStateVariableType {
    let mut state = TwoStateVariableType {
        id,
        true_state: LocalizedText::new("en", true_state),
        false_state: LocalizedText::new("en", false_state),
        transition_time: since,
        ..Default::default()
    };
    state.base.value = LocalizedText::new("en", if id { true_state } else { false_state });
    state
}

/// The text of a TwoStateVariable (its value).
fn state_text(state: &TwoStateVariableType) -> Variant {
    Variant::from(state.base.value.clone())
}

/// Whether a select clause of `type_definition` may ask a condition's own fields.
fn of_condition(type_definition: &NodeId) -> bool {
    [
        ObjectTypeId::BaseEventType,
        ObjectTypeId::ConditionType,
        ObjectTypeId::AcknowledgeableConditionType,
        ObjectTypeId::AlarmConditionType,
    ]
    .iter()
    .any(|id| type_definition == id)
}

impl EventField for ConditionEvent {
    fn get_value(
        &self,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        self.event.get_value(attribute_id, index_range, browse_path)
    }
}

impl Event for ConditionEvent {
    fn get_field(
        &self,
        type_definition_id: &NodeId,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        if of_condition(type_definition_id) {
            let field = match browse_path {
                [] if attribute_id == AttributeId::NodeId => {
                    Some(Variant::from(self.condition.clone()))
                }
                [name] if name.namespace_index == 0 && attribute_id == AttributeId::Value => {
                    match name.name.as_ref() {
                        "Quality" => Some(Variant::StatusCode(self.quality)),
                        "LastSeverity" => Some(Variant::UInt16(self.last_severity)),
                        "Comment" => Some(Variant::from(self.comment.clone())),
                        // A state variable's own value, its text: the generated types
                        // answer only its fields.
                        "EnabledState" => Some(state_text(&self.event.enabled_state)),
                        "ActiveState" => Some(state_text(&self.event.active_state)),
                        "AckedState" => Some(state_text(&self.event.base.acked_state)),
                        _ => None,
                    }
                }
                _ => None,
            };
            if let Some(field) = field {
                return field;
            }
        }
        self.event
            .get_field(type_definition_id, attribute_id, index_range, browse_path)
    }

    fn time(&self) -> &DateTime {
        self.event.time()
    }

    fn event_type_id(&self) -> &NodeId {
        self.event.event_type_id()
    }
}

/// The RefreshStart (`start`) or RefreshEnd event of a ConditionRefresh, from the
/// Server object.
pub(crate) fn refresh_event(start: bool, event_id: ByteString) -> Box<dyn Event + Send> {
    let (type_id, message) = if start {
        (
            ObjectTypeId::RefreshStartEventType,
            "ConditionRefresh: the retained conditions follow",
        )
    } else {
        (
            ObjectTypeId::RefreshEndEventType,
            "ConditionRefresh: end of the retained conditions",
        )
    };
    let mut base = BaseEventType::new(
        type_id,
        event_id,
        LocalizedText::new("en", message),
        DateTime::now(),
    );
    base.source_node = ObjectId::Server.into();
    base.source_name = UAString::from("Server");
    base.severity = 1;
    let base = SystemEventType { base };
    if start {
        Box::new(RefreshStartEventType { base })
    } else {
        Box::new(RefreshEndEventType { base })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unix_time_converts_to_ticks() {
        assert_eq!(ua_time(UNIX_EPOCH).ticks(), UNIX_EPOCH_TICKS);
        let later = UNIX_EPOCH + std::time::Duration::from_millis(1_700_000_000_123);
        assert_eq!(
            ua_time(later).as_chrono().timestamp_millis(),
            1_700_000_000_123
        );
    }

    #[test]
    fn clients_read_the_base_condition_and_alarm_fields() {
        let time = ua_time(UNIX_EPOCH + std::time::Duration::from_secs(1_700_000_000));
        let state = ConditionState {
            event_id: ByteString::from(vec![7; 16]),
            active: true,
            acked: false,
            severity: 800,
            last_severity: 500,
            message: "F1: taf_alarm raised".into(),
            time,
            active_since: time,
            acked_since: time,
            comment: String::new(),
            client_user_id: String::new(),
        };
        let source = NodeId::new(2, "Millgate/Drivelines/F1");
        let condition = NodeId::new(2, "Millgate/Drivelines/F1/Conditions/taf_alarm");
        let event =
            ConditionEvent::new(&condition, (&source, "Drivelines/F1"), "taf_alarm", &state);
        let field = |type_id: ObjectTypeId, path: &[&str]| {
            let path: Vec<QualifiedName> = path.iter().map(|p| QualifiedName::new(0, *p)).collect();
            let attribute = if path.is_empty() {
                AttributeId::NodeId
            } else {
                AttributeId::Value
            };
            event.get_field(&type_id.into(), attribute, &NumericRange::None, &path)
        };
        let text = |text: &str| Variant::from(LocalizedText::new("en", text));
        for (type_id, path, expected) in [
            (
                ObjectTypeId::BaseEventType,
                &["Severity"][..],
                Variant::UInt16(800),
            ),
            (
                ObjectTypeId::BaseEventType,
                &["SourceNode"],
                Variant::from(source.clone()),
            ),
            (
                ObjectTypeId::BaseEventType,
                &["ConditionName"],
                Variant::from("taf_alarm"),
            ),
            (
                ObjectTypeId::ConditionType,
                &[],
                Variant::from(condition.clone()),
            ),
            (
                ObjectTypeId::ConditionType,
                &["EnabledState", "Id"],
                Variant::Boolean(true),
            ),
            (
                ObjectTypeId::ConditionType,
                &["EnabledState"],
                text("Enabled"),
            ),
            (
                ObjectTypeId::BaseEventType,
                &["EnabledState", "Id"],
                Variant::Boolean(true),
            ),
            (
                ObjectTypeId::BaseEventType,
                &["EnabledState"],
                text("Enabled"),
            ),
            (
                ObjectTypeId::ConditionType,
                &["Retain"],
                Variant::Boolean(true),
            ),
            (
                ObjectTypeId::ConditionType,
                &["Quality"],
                Variant::StatusCode(StatusCode::Good),
            ),
            (
                ObjectTypeId::ConditionType,
                &["LastSeverity"],
                Variant::UInt16(500),
            ),
            (
                ObjectTypeId::AlarmConditionType,
                &["ActiveState", "Id"],
                Variant::Boolean(true),
            ),
            (
                ObjectTypeId::AlarmConditionType,
                &["ActiveState"],
                text("Active"),
            ),
            (
                ObjectTypeId::AlarmConditionType,
                &["ActiveState", "TrueState"],
                text("Active"),
            ),
            (
                ObjectTypeId::BaseEventType,
                &["AckedState", "Id"],
                Variant::Boolean(false),
            ),
            (
                ObjectTypeId::AcknowledgeableConditionType,
                &["AckedState"],
                text("Unacknowledged"),
            ),
        ] {
            assert_eq!(field(type_id, path), expected, "{type_id:?} {path:?}");
        }
    }
}
