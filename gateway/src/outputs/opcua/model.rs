//! The OPC UA server's own vocabulary, independent of the results types: what the
//! address space holds ([`AddressSpaceSpec`]), what changes in it ([`Snapshot`] of
//! [`VariableUpdate`]s) and the alarms it sends as events ([`AlarmEventSpec`]). A
//! mapping from the gateway's catalogue builds these (`super::adapter`); the
//! server knows nothing else.

use std::fmt::Write as _;
use std::time::SystemTime;

/// Everything the server publishes: objects with their variables, in a fixed order
/// that [`Snapshot`]s follow.
#[derive(Debug, Clone, PartialEq)]
pub struct AddressSpaceSpec {
    /// The plant or mill name (the root object's description).
    pub name: String,
    /// The objects; an object's `parent` comes before it.
    pub objects: Vec<ObjectSpec>,
    /// The items of the Machinery companion model (`Objects/Machines`, OPC 40001-1),
    /// in the order of [`Snapshot::machines`].
    pub machines: Vec<MachineSpec>,
}

/// A Machinery item (OPC 40001-1): the gateway, a driveline or a mill, with its
/// identification, its MachineryItemState and its NE 107 DeviceHealth (OPC
/// 10000-100).
#[derive(Debug, Clone, PartialEq)]
pub struct MachineSpec {
    /// The object it stands for (index into [`AddressSpaceSpec::objects`]); its
    /// browse name is the object's.
    pub object: usize,
    /// Identification: `(browse name in the DI namespace, value)`, the ones known
    /// (the gateway's `Manufacturer`, `Model`, `SoftwareRevision`, and what the
    /// configuration's `identification` tables give).
    pub identification: Vec<(&'static str, NameplateValue)>,
}

/// A value of an `Identification` property, of the data type DI's nameplate gives it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NameplateValue {
    /// `LocalizedText` (`Manufacturer`, `Model`), in English.
    LocalizedText(String),
    /// `String` (`SerialNumber`, `ProductInstanceUri`, `SoftwareRevision`, ...).
    String(String),
    /// `UInt16` (`YearOfConstruction`).
    UInt16(u16),
}

/// A Machinery item's state (OPC 40001-1 `MachineryItemState_StateMachineType`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MachineState {
    /// Its state is not known (its source is stale or lost).
    NotAvailable,
    /// Not working: waiting for its first bite or window, or stopped.
    NotExecuting,
    /// Working.
    Executing,
}

impl MachineState {
    /// The state's browse name, as `CurrentState` shows it.
    pub fn name(self) -> &'static str {
        match self {
            MachineState::NotAvailable => "NotAvailable",
            MachineState::NotExecuting => "NotExecuting",
            MachineState::Executing => "Executing",
        }
    }
}

/// NE 107 device health (OPC 10000-100 `DeviceHealthEnumeration`: its values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceHealth {
    /// 0: working, no condition.
    Normal = 0,
    /// 1: its output is not valid (a stopped gateway, a lost or stale source).
    Failure = 1,
    /// 2: its output is temporarily not valid (the gateway starting).
    CheckFunction = 2,
    /// 3: working outside its specification (a source stale for the gateway, a
    /// degraded bite for a driveline).
    OffSpec = 3,
    /// 4: working, maintenance is needed (a latched alarm or a gap warning).
    MaintenanceRequired = 4,
}

impl DeviceHealth {
    /// The names of the values, from 0 (`DeviceHealthEnumeration`'s).
    pub const NAMES: [&'static str; 5] = [
        "NORMAL",
        "FAILURE",
        "CHECK_FUNCTION",
        "OFF_SPEC",
        "MAINTENANCE_REQUIRED",
    ];
}

/// What an object stands for; objects without a parent are grouped by kind under
/// the root (`Gateway` itself, `Sources/`, `Drivelines/`, `TandemMills/`, `RodMills/`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectKind {
    /// The gateway's own state.
    Gateway,
    /// A field source (a Modbus DAQ or PLC, a CAN interface).
    Source,
    /// A hot-mill driveline analysed at each bite.
    Driveline,
    /// A tandem mill watched for chatter.
    TandemMill,
    /// A rod mill checked against the Mathieu tongues.
    RodMill,
    /// One span of a rod mill (its parent).
    RodSpan,
}

impl ObjectKind {
    /// The folder under the root for objects of this kind without a parent; `None`:
    /// directly under the root.
    pub fn folder(self) -> Option<&'static str> {
        match self {
            ObjectKind::Gateway => None,
            ObjectKind::Source => Some("Sources"),
            ObjectKind::Driveline => Some("Drivelines"),
            ObjectKind::TandemMill => Some("TandemMills"),
            ObjectKind::RodMill => Some("RodMills"),
            ObjectKind::RodSpan => Some("RodSpans"),
        }
    }
}

/// One object: a driveline, a mill, the gateway, a source.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectSpec {
    /// Its browse name, as in the configuration (`F1`, `daq1`) or `span1`.
    pub name: String,
    /// What it stands for.
    pub kind: ObjectKind,
    /// The object it belongs to (index into [`AddressSpaceSpec::objects`]), e.g. a
    /// rod mill for its spans.
    pub parent: Option<usize>,
    /// One sentence.
    pub description: String,
    /// Its variables, in the order of [`Snapshot::objects`]' updates.
    pub variables: Vec<VariableSpec>,
    /// The alarms it raises: a condition instance each (OPC 10000-9), whose events
    /// are the [`AlarmEventSpec`]s of this object and kind.
    pub conditions: Vec<ConditionSpec>,
}

/// An alarm an object raises: a condition instance of `AlarmConditionType`.
#[derive(Debug, Clone, PartialEq)]
pub struct ConditionSpec {
    /// Its key (`taf_alarm`, `source_lost`): the ConditionName, the instance's browse
    /// name and the `kind` of its [`AlarmEventSpec`]s.
    pub kind: String,
    /// One sentence.
    pub description: String,
    /// Whether it latches until the PLC's acknowledge (`AcknowledgeAlarms`, a
    /// condition's `Acknowledge`) clears it in every output; other conditions are
    /// acknowledged on the OPC UA server only (a warning that follows the analysis).
    pub latched: bool,
}

/// One published figure.
#[derive(Debug, Clone, PartialEq)]
pub struct VariableSpec {
    /// Its key and browse name (`taf`, `gap_mrad`).
    pub key: String,
    /// One sentence.
    pub description: String,
    /// Engineering unit, `None` for counts, flags and ratios.
    pub unit: Option<Unit>,
    /// The OPC UA data type of its value.
    pub datatype: VariableType,
    /// Its normal range `(low, high)` (EURange), where one exists.
    pub range: Option<(f64, f64)>,
    /// For a state: the name of each value, from 0 (a `MultiStateDiscreteType` with
    /// `EnumStrings`); empty for other figures.
    pub states: Vec<String>,
}

/// OPC UA data types of the published figures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VariableType {
    /// 64-bit float.
    Double,
    /// true / false.
    Boolean,
    /// Unsigned 32-bit integer.
    UInt32,
    /// Unsigned 64-bit integer.
    UInt64,
    /// UTC time.
    DateTime,
}

impl VariableType {
    /// The OPC UA type name.
    pub fn name(self) -> &'static str {
        match self {
            VariableType::Double => "Double",
            VariableType::Boolean => "Boolean",
            VariableType::UInt32 => "UInt32",
            VariableType::UInt64 => "UInt64",
            VariableType::DateTime => "DateTime",
        }
    }
}

/// An engineering unit by its UNECE Recommendation 20 common code, as OPC UA's
/// EUInformation carries it (OPC 10000-8, 5.6.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Unit {
    /// The UNECE common code (`B48`).
    pub unece_code: &'static str,
    /// The symbol shown to people (`kN·m`).
    pub symbol: &'static str,
    /// The unit's name (`kilonewton metre`).
    pub name: &'static str,
}

impl Unit {
    /// kN·m, torque.
    pub(crate) const KILONEWTON_METRE: Unit = Unit::new("B48", "kN·m", "kilonewton metre");
    /// Hz.
    pub(crate) const HERTZ: Unit = Unit::new("HTZ", "Hz", "hertz");
    /// s.
    pub(crate) const SECOND: Unit = Unit::new("SEC", "s", "second");
    /// mrad, the driveline gap.
    pub(crate) const MILLIRADIAN: Unit = Unit::new("C25", "mrad", "milliradian");
    /// m/s, the rod speed.
    pub(crate) const METRE_PER_SECOND: Unit = Unit::new("MTS", "m/s", "metre per second");
    /// 1/s, growth exponents.
    pub(crate) const RECIPROCAL_SECOND: Unit = Unit::new("C97", "s⁻¹", "reciprocal second");
    /// °C, the rod temperature.
    pub(crate) const DEGREE_CELSIUS: Unit = Unit::new("CEL", "°C", "degree Celsius");
    /// d, calendar days of a forecast.
    pub(crate) const DAY: Unit = Unit::new("DAY", "d", "day");
    /// mrad/d, the gap's growth: UNECE Recommendation 20 has no code for it, so its
    /// `unitId` is -1 ("not available", OPC 10000-8, 5.6.3) and the symbol says it.
    pub(crate) const MILLIRADIAN_PER_DAY: Unit = Unit::new("", "mrad/d", "milliradian per day");
    /// 1/d, the share of a fatigue life used per day: like mrad/d, `unitId` -1 with the
    /// symbol saying it.
    pub(crate) const RECIPROCAL_DAY: Unit = Unit::new("", "d⁻¹", "reciprocal day");

    const fn new(unece_code: &'static str, symbol: &'static str, name: &'static str) -> Self {
        Self {
            unece_code,
            symbol,
            name,
        }
    }

    /// EUInformation's `unitId`: the common code's characters, big-endian, one byte
    /// each (OPC 10000-8, 5.6.3: `B48` is 0x423438); -1 without a code.
    pub fn unit_id(self) -> i32 {
        if self.unece_code.is_empty() {
            return -1;
        }
        self.unece_code
            .bytes()
            .fold(0i32, |id, byte| (id << 8) | i32::from(byte))
    }
}

/// A value of a variable; its kind must match the variable's [`VariableType`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// For [`VariableType::Double`].
    Double(f64),
    /// For [`VariableType::Boolean`].
    Boolean(bool),
    /// For [`VariableType::UInt32`].
    UInt32(u32),
    /// For [`VariableType::UInt64`].
    UInt64(u64),
    /// For [`VariableType::DateTime`].
    DateTime(SystemTime),
}

impl Value {
    /// The data type this value is of.
    pub fn datatype(self) -> VariableType {
        match self {
            Value::Double(_) => VariableType::Double,
            Value::Boolean(_) => VariableType::Boolean,
            Value::UInt32(_) => VariableType::UInt32,
            Value::UInt64(_) => VariableType::UInt64,
            Value::DateTime(_) => VariableType::DateTime,
        }
    }
}

/// How far a variable's value can be trusted; the server publishes it as the value's
/// OPC UA status code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quality {
    /// A value computed from fresh, clean input: `Good`.
    Good,
    /// The source is stale or lost and the figure keeps its last value, which is
    /// still the last usable one (a counter, a latched flag):
    /// `Uncertain_LastUsableValue`.
    UncertainLastUsableValue,
    /// Never computed yet (no bite, no window, no model maps yet):
    /// `Bad_WaitingForInitialData`, no value.
    BadWaitingForInitialData,
    /// Withdrawn because its source is stale or lost: `Bad_NoCommunication`, no value
    /// (never a frozen value shown as good).
    BadNoCommunication,
    /// Withdrawn because its input data were not clean (gaps, saturated or non-finite
    /// samples in the bite's window): `Bad_DeviceFailure`, no value.
    BadDeviceFailure,
    /// Not computed because an input was out of its range (a rod mill's refused
    /// inputs): `Bad_OutOfRange`, no value.
    BadOutOfRange,
    /// The last computation gave no value for this figure from clean input (a fit
    /// that did not converge, a span without a band edge in the speed range):
    /// `Bad_NoData`, no value.
    BadNoData,
}

impl Quality {
    /// Whether a value goes with this quality (only good and uncertain ones carry one).
    pub(crate) fn carries_value(self) -> bool {
        matches!(self, Quality::Good | Quality::UncertainLastUsableValue)
    }
}

/// A variable's state at one moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VariableUpdate {
    /// The value; `None` with a bad quality (a value given with a bad quality is not
    /// published).
    pub value: Option<Value>,
    /// How far it can be trusted.
    pub quality: Quality,
    /// When the value was measured (the bite, the window); `None`: when the server
    /// received it.
    pub source_time: Option<SystemTime>,
}

impl VariableUpdate {
    /// A good value measured at `source_time`.
    pub fn good(value: Value, source_time: Option<SystemTime>) -> Self {
        Self {
            value: Some(value),
            quality: Quality::Good,
            source_time,
        }
    }

    /// No value, with `quality` saying why.
    pub fn missing(quality: Quality) -> Self {
        Self {
            value: None,
            quality,
            source_time: None,
        }
    }
}

/// Every variable's state, aligned with the spec: `objects[i][j]` is variable `j` of
/// object `i`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Snapshot {
    /// Per object, per variable.
    pub objects: Vec<Vec<VariableUpdate>>,
    /// Per Machinery item ([`AddressSpaceSpec::machines`]): its state and health.
    pub machines: Vec<(MachineState, DeviceHealth)>,
}

/// An alarm or warning that was raised, cleared or acknowledged, sent to clients as an
/// event from its object.
#[derive(Debug, Clone, PartialEq)]
pub struct AlarmEventSpec {
    /// The object it is about (index into [`AddressSpaceSpec::objects`]).
    pub object: usize,
    /// Which alarm, a key (`taf_alarm`, `gap_warning`): the event's ConditionName.
    pub kind: String,
    /// Urgency 1..=1000 (OPC UA: 801..=1000 high, 401..=600 medium).
    pub severity: u16,
    /// One sentence for operators.
    pub message: String,
    /// Whether the condition holds now (raised) or not any more (cleared,
    /// acknowledged).
    pub active: bool,
    /// Whether it waits for an acknowledgement (a latched alarm still set).
    pub unacknowledged: bool,
    /// When it happened (the bite, the window).
    pub time: SystemTime,
}

/// Who asked to acknowledge the latched alarms through the server's method.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Acknowledgement {
    /// The client's address, when the connection is known.
    pub peer: Option<std::net::SocketAddr>,
    /// The user signed in, `None` for an anonymous session.
    pub user: Option<String>,
}

/// The address space as a Markdown table: one row per variable with its path below
/// the root (its node id's string is `Millgate/` and the path), type, unit (UNECE
/// code), range and description.
pub(crate) fn render_markdown(spec: &AddressSpaceSpec) -> String {
    let mut text = String::from(
        "| variable (below `Millgate/`) | type | unit (UNECE code) | range | description |\n\
         |---|---|---|---|---|\n",
    );
    for (index, object) in spec.objects.iter().enumerate() {
        let path = object_path(spec, index);
        for variable in &object.variables {
            let unit = variable.unit.map_or(String::new(), |u| match u.unece_code {
                "" => format!("{} (no code, unitId -1)", u.symbol),
                code => format!("{} ({code})", u.symbol),
            });
            let range = variable
                .range
                .map_or(String::new(), |(low, high)| format!("{low}..{high}"));
            let _ = writeln!(
                text,
                "| `{path}/{}` | {} | {unit} | {range} | {} |",
                variable.key,
                variable.datatype.name(),
                variable.description.replace('|', "\\|")
            );
        }
    }
    text
}

/// An object's path from the root: its folder (or its parent's path) and its name,
/// `/`-separated (`Drivelines/F1`, `RodMills/R1/span1`, `Gateway`); the string
/// identifier of its node id.
pub(crate) fn object_path(spec: &AddressSpaceSpec, index: usize) -> String {
    let object = &spec.objects[index];
    match (object.parent, object.kind.folder()) {
        (Some(parent), _) if parent < index => {
            format!("{}/{}", object_path(spec, parent), object.name)
        }
        (_, Some(folder)) => format!("{folder}/{}", object.name),
        _ => object.name.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_ids_follow_opc_10000_8() {
        // OPC 10000-8 5.6.3's worked example: "°C" is CEL, unitId 4408652 (0x43454C).
        assert_eq!(Unit::DEGREE_CELSIUS.unit_id(), 4_408_652);
        assert_eq!(Unit::KILONEWTON_METRE.unit_id(), 0x42_34_38);
    }

    #[test]
    fn paths_nest_under_parents_and_folders() {
        let object = |name: &str, kind, parent| ObjectSpec {
            name: name.into(),
            kind,
            parent,
            description: String::new(),
            variables: vec![VariableSpec {
                key: "flag".into(),
                description: "a | b".into(),
                unit: None,
                datatype: VariableType::Boolean,
                range: None,
                states: Vec::new(),
            }],
            conditions: Vec::new(),
        };
        let spec = AddressSpaceSpec {
            name: "plant".into(),
            objects: vec![
                object("Gateway", ObjectKind::Gateway, None),
                object("R1", ObjectKind::RodMill, None),
                object("span1", ObjectKind::RodSpan, Some(1)),
            ],
            machines: Vec::new(),
        };
        let paths: Vec<_> = (0..3).map(|i| object_path(&spec, i)).collect();
        assert_eq!(paths, ["Gateway", "RodMills/R1", "RodMills/R1/span1"]);
        let table = render_markdown(&spec);
        assert!(table.contains("| `RodMills/R1/span1/flag` | Boolean |  |  | a \\| b |"));
    }
}
