//! What comes from the host application: its STATE (online or not), and the NCMD
//! that asks for a rebirth.

use prost::Message as _;

use crate::outputs::sparkplug::payload::{MetricValue, Payload};

use super::NAMESPACE;

/// The node metric a host sets to `true` in an NCMD to ask for the births again.
pub(crate) const REBIRTH: &str = "Node Control/Rebirth";

/// The topic a primary host application publishes its STATE on (Sparkplug 3.0).
pub(crate) fn state_topic(host_id: &str) -> String {
    format!("{NAMESPACE}/STATE/{host_id}")
}

/// Whether a STATE payload (`{"online": true, "timestamp": ...}`) says the host is
/// online; `None` when it is not such JSON.
pub(crate) fn host_online(payload: &[u8]) -> Option<bool> {
    let state: serde_json::Value = serde_json::from_slice(payload).ok()?;
    state.get("online")?.as_bool()
}

/// Whether an NCMD payload asks for a rebirth (`Node Control/Rebirth` = true, by
/// name or by its alias).
pub(crate) fn is_rebirth(payload: &[u8]) -> Result<bool, prost::DecodeError> {
    let payload = Payload::decode(payload)?;
    Ok(payload.metrics.iter().any(|metric| {
        let named = metric.name.as_deref() == Some(REBIRTH) || metric.alias == Some(1);
        named && metric.value == Some(MetricValue::BooleanValue(true))
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::outputs::sparkplug::payload::{DataType, Metric};

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
