//! Alarms as OPC UA events: [`AlarmEventSpec`] to an event of `AlarmConditionType`
//! (a subtype of `BaseEventType`, so a client selecting only the base fields gets
//! Severity, Message, SourceNode, SourceName and Time).
//!
//! The fields filled: the base event's (EventId, EventType, SourceNode, SourceName,
//! Time, ReceiveTime, Message, Severity), ConditionName (the alarm's key),
//! ConditionClassId/Name (process), Retain (active or unacknowledged),
//! EnabledState/Id, ActiveState/Id, AckedState/Id. There are no condition instances
//! in the address space: ConditionRefresh and the condition's own Acknowledge method
//! are not offered; alarms are acknowledged with `Gateway/AcknowledgeAlarms`.

use std::time::{SystemTime, UNIX_EPOCH};

use opcua::core_namespace::events::AlarmConditionType;
use opcua::nodes::NamespaceMap;
use opcua::types::{ByteString, DateTime, LocalizedText, NodeId, ObjectTypeId, UAString};

use super::model::AlarmEventSpec;

/// OPC UA ticks (100 ns since 1601-01-01) at the Unix epoch.
const UNIX_EPOCH_TICKS: i64 = 116_444_736_000_000_000;

/// `time` as an OPC UA DateTime (times before 1970 as 1970).
pub(crate) fn ua_time(time: SystemTime) -> DateTime {
    let since_epoch = time.duration_since(UNIX_EPOCH).unwrap_or_default();
    let ticks = i64::try_from(since_epoch.as_nanos() / 100).unwrap_or(i64::MAX - UNIX_EPOCH_TICKS);
    DateTime::from(UNIX_EPOCH_TICKS + ticks)
}

/// The event of `alarm`, raised by `source` (its node) called `source_name`; `id`
/// makes the EventId unique.
pub(crate) fn alarm_event(
    alarm: &AlarmEventSpec,
    source: &NodeId,
    source_name: &str,
    id: [u8; 16],
) -> AlarmConditionType {
    let time = ua_time(alarm.time);
    let mut event = AlarmConditionType::new_event(
        ObjectTypeId::AlarmConditionType.into(),
        ByteString::from(id.to_vec()),
        LocalizedText::new("en", &alarm.message),
        &NamespaceMap::new(),
        time,
    );
    let acknowledgeable = &mut event.base;
    acknowledgeable.acked_state.id = !alarm.unacknowledged;
    acknowledgeable.acked_state.base.value = LocalizedText::new(
        "en",
        if alarm.unacknowledged {
            "Unacknowledged"
        } else {
            "Acknowledged"
        },
    );
    let condition = &mut acknowledgeable.base;
    condition.condition_name = UAString::from(alarm.kind.as_str());
    condition.condition_class_id = ObjectTypeId::ProcessConditionClassType.into();
    condition.condition_class_name = LocalizedText::new("en", "Process");
    condition.retain = alarm.active || alarm.unacknowledged;
    condition.enabled_state.id = true;
    condition.enabled_state.base.value = LocalizedText::new("en", "Enabled");
    let base = &mut condition.base;
    base.source_node = source.clone();
    base.source_name = UAString::from(source_name);
    base.severity = alarm.severity.clamp(1, 1000);
    base.receive_time = DateTime::now();
    event.active_state.id = alarm.active;
    event.active_state.base.value =
        LocalizedText::new("en", if alarm.active { "Active" } else { "Inactive" });
    event
}

#[cfg(test)]
mod tests {
    use super::*;
    use opcua::nodes::Event;
    use opcua::types::{AttributeId, NumericRange, QualifiedName, Variant};

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
    fn clients_read_the_base_and_alarm_fields() {
        let alarm = AlarmEventSpec {
            object: 0,
            kind: "taf_alarm".into(),
            severity: 800,
            message: "F1: TAF alarm".into(),
            active: true,
            unacknowledged: true,
            time: UNIX_EPOCH + std::time::Duration::from_secs(1_700_000_000),
        };
        let source = NodeId::new(2, "Millgate/Drivelines/F1");
        let event = alarm_event(&alarm, &source, "F1", [7; 16]);
        let field = |type_id: ObjectTypeId, path: &[&str]| {
            let path: Vec<QualifiedName> = path.iter().map(|p| QualifiedName::new(0, *p)).collect();
            event.get_field(
                &type_id.into(),
                AttributeId::Value,
                &NumericRange::None,
                &path,
            )
        };
        assert_eq!(
            field(ObjectTypeId::BaseEventType, &["Severity"]),
            Variant::UInt16(800)
        );
        assert_eq!(
            field(ObjectTypeId::BaseEventType, &["SourceNode"]),
            Variant::from(source.clone())
        );
        assert_eq!(
            field(ObjectTypeId::BaseEventType, &["ConditionName"]),
            Variant::from("taf_alarm")
        );
        assert_eq!(
            field(ObjectTypeId::AlarmConditionType, &["ActiveState", "Id"]),
            Variant::Boolean(true)
        );
        assert_eq!(
            field(ObjectTypeId::BaseEventType, &["AckedState", "Id"]),
            Variant::Boolean(false)
        );
        assert_eq!(
            field(ObjectTypeId::BaseEventType, &["Retain"]),
            Variant::Boolean(true)
        );
    }
}
