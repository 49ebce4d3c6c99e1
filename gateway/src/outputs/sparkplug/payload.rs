//! The Sparkplug B payload (Eclipse Tahu `sparkplug_b.proto`, package
//! `org.eclipse.tahu.protobuf`, proto2) as `prost` messages written by hand, so no
//! `protoc` is needed at build time. Only what an edge node sends and the commands it
//! reads are here: `Payload`, `Metric` with scalar values and its `PropertySet`. The
//! field numbers are the specification's; the tests decode what this encodes with the
//! Python `protobuf` runtime and the `sparkplug_b_pb2` module that `pysparkplug` ships.
//!
//! `DataSet`, `Template`, `MetaData` and extensions are not declared: prost skips
//! unknown fields when decoding, so a command that carries them still decodes.

/// A Sparkplug B payload: every NBIRTH, DBIRTH, NDATA, DDATA, NDEATH and NCMD.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// Time the payload was made, ms since the Unix epoch (UTC).
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    /// The metrics.
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    /// Sequence number 0..=255 (absent in NDEATH and STATE).
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    /// Optional UUID of the payload's content.
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    /// Optional opaque body.
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// One metric: name (in births), alias, datatype, value.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Metric {
    /// The metric's name; births carry it, data messages only the alias.
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    /// The alias the births announce, unique within the edge node.
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    /// Time of the value, ms since the Unix epoch (UTC).
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    /// [`DataType`] code.
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    /// The value was stored while the host could not be reached and sent later.
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    /// Not to be stored by the host.
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    /// The metric has no value now.
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    /// Properties (the engineering unit).
    #[prost(message, optional, tag = "9")]
    pub properties: Option<PropertySet>,
    /// The value.
    #[prost(oneof = "MetricValue", tags = "10, 11, 12, 13, 14, 15, 16")]
    pub value: Option<MetricValue>,
}

/// A metric's value (the scalar members of the `value` oneof).
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum MetricValue {
    /// Int8, Int16, Int32 (two's complement), UInt8, UInt16, UInt32.
    #[prost(uint32, tag = "10")]
    IntValue(u32),
    /// Int64 (two's complement), UInt64, DateTime.
    #[prost(uint64, tag = "11")]
    LongValue(u64),
    /// Float.
    #[prost(float, tag = "12")]
    FloatValue(f32),
    /// Double.
    #[prost(double, tag = "13")]
    DoubleValue(f64),
    /// Boolean.
    #[prost(bool, tag = "14")]
    BooleanValue(bool),
    /// String, Text, UUID.
    #[prost(string, tag = "15")]
    StringValue(String),
    /// Bytes, File.
    #[prost(bytes = "vec", tag = "16")]
    BytesValue(Vec<u8>),
}

/// A metric's properties: parallel lists of keys and values.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertySet {
    /// Property names.
    #[prost(string, repeated, tag = "1")]
    pub keys: Vec<String>,
    /// Property values, one per key.
    #[prost(message, repeated, tag = "2")]
    pub values: Vec<PropertyValue>,
}

/// One property's value (scalar members only).
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertyValue {
    /// [`DataType`] code.
    #[prost(uint32, optional, tag = "1")]
    pub r#type: Option<u32>,
    /// No value.
    #[prost(bool, optional, tag = "2")]
    pub is_null: Option<bool>,
    /// The value.
    #[prost(oneof = "PropertyValueKind", tags = "3, 4, 5, 6, 7, 8")]
    pub value: Option<PropertyValueKind>,
}

/// A property's value.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum PropertyValueKind {
    /// 32-bit and smaller integers.
    #[prost(uint32, tag = "3")]
    IntValue(u32),
    /// 64-bit integers, DateTime.
    #[prost(uint64, tag = "4")]
    LongValue(u64),
    /// Float.
    #[prost(float, tag = "5")]
    FloatValue(f32),
    /// Double.
    #[prost(double, tag = "6")]
    DoubleValue(f64),
    /// Boolean.
    #[prost(bool, tag = "7")]
    BooleanValue(bool),
    /// String.
    #[prost(string, tag = "8")]
    StringValue(String),
}

/// Sparkplug B datatype codes (the specification's `DataType` enum), the ones
/// millgate sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum DataType {
    /// Signed 64-bit integer (two's complement) in `long_value`: bdSeq, as the
    /// Sparkplug 3.0 conformance statements ask.
    Int64 = 4,
    /// Unsigned 32-bit integer in `int_value`.
    UInt32 = 7,
    /// Unsigned 64-bit integer in `long_value`.
    UInt64 = 8,
    /// IEEE double in `double_value`.
    Double = 10,
    /// Boolean in `boolean_value`.
    Boolean = 11,
    /// UTF-8 string in `string_value`.
    String = 12,
    /// ms since the Unix epoch in `long_value`.
    DateTime = 13,
}

impl DataType {
    /// The code on the wire.
    pub fn code(self) -> u32 {
        self as u32
    }
}

impl PropertySet {
    /// The engineering unit as the `engUnit` string property (the key Ignition and
    /// other hosts show).
    pub fn unit(unit: &str) -> Self {
        Self {
            keys: vec!["engUnit".to_owned()],
            values: vec![PropertyValue {
                r#type: Some(DataType::String.code()),
                is_null: None,
                value: Some(PropertyValueKind::StringValue(unit.to_owned())),
            }],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    #[test]
    fn a_payload_round_trips_and_its_bytes_follow_the_field_numbers() {
        let payload = Payload {
            timestamp: Some(1_700_000_000_000),
            metrics: vec![Metric {
                name: Some("bdSeq".into()),
                alias: Some(1),
                datatype: Some(DataType::UInt64.code()),
                value: Some(MetricValue::LongValue(7)),
                ..Metric::default()
            }],
            seq: Some(0),
            ..Payload::default()
        };
        let bytes = payload.encode_to_vec();
        // Field 1 varint (tag 0x08), then field 2 length-delimited (0x12).
        assert_eq!(bytes[0], 0x08);
        assert!(bytes.contains(&0x12));
        // The metric: name (0x0a "bdSeq"), alias (0x10 1), datatype (0x20 8), long
        // value (field 11 varint: 0x58 7).
        let metric = &payload.metrics[0].encode_to_vec();
        assert_eq!(
            metric,
            &[0x0a, 5, b'b', b'd', b'S', b'e', b'q', 0x10, 1, 0x20, 8, 0x58, 7]
        );
        assert_eq!(Payload::decode(bytes.as_slice()).unwrap(), payload);
    }
}
