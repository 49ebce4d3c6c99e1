//! The millgate namespace: the address space built from the [`AddressSpaceSpec`],
//! the acknowledge method, guarded like the HMI server's command registers, and the
//! methods of the condition instances (`Acknowledge`, `ConditionRefresh`,
//! `ConditionRefresh2`).
//!
//! Layout: `Objects/Millgate` (the root), with `Gateway` (its state, the method
//! `AcknowledgeAlarms`) and one folder per kind of object (`Sources`, `Drivelines`,
//! `TandemMills`, `RodMills`); each object holds its variables, an object with a
//! parent sits in its parent, an object that raises alarms has a `Conditions` folder
//! with a condition instance per alarm (`AlarmConditionType`, referenced from the
//! object by `HasCondition`, with its `Acknowledge` method). Node ids are strings of
//! the browse path from the root: `ns=<millgate>;s=Millgate/Drivelines/F1/taf`;
//! browse names are in the millgate namespace (the standard properties', such as
//! `EngineeringUnits`, and the condition's `Acknowledge` in namespace 0), children
//! in the order they were added.

use std::collections::HashSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_trait::async_trait;
use opcua::nodes::{Event, EventNotifier, MethodBuilder, NodeType, ObjectBuilder, VariableBuilder};
use opcua::server::address_space::{AccessLevel, AddressSpace};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{
    InMemoryNodeManagerImpl, InMemoryNodeManagerImplBuilder,
};
use opcua::server::node_manager::{MethodCall, RequestContext, ServerContext};
use opcua::sync::RwLock;
use opcua::types::{
    Argument, DataTypeId, DataValue, EUInformation, ExtensionObject, LocalizedText, MethodId,
    NodeClass, NodeId, ObjectId, ObjectTypeId, QualifiedName, Range, ReferenceTypeId, StatusCode,
    VariableTypeId, Variant,
};

use super::auth;
use super::conditions::Conditions;
use super::events;
use super::front::ChannelPeers;
use super::model::{
    object_path, Acknowledgement, AddressSpaceSpec, DeviceHealth, NameplateValue, ObjectKind,
    ObjectSpec, Unit, VariableSpec, VariableType,
};
use super::status::{count, OpcUaCounters};
use crate::warn_limit::{WarnLimit, WARN_PERIOD};
use tokio::time::Instant;

/// The millgate namespace's URI.
pub(crate) const NAMESPACE_URI: &str = "urn:millgate:results";
/// The root object's browse name and node id.
pub(crate) const ROOT: &str = "Millgate";
/// The acknowledge method's browse name (a component of the gateway object).
pub(crate) const ACKNOWLEDGE_METHOD: &str = "AcknowledgeAlarms";
/// The folder of an object's condition instances.
pub(crate) const CONDITIONS: &str = "Conditions";
/// A condition's acknowledge method's browse name (namespace 0, as the type's).
const CONDITION_ACKNOWLEDGE: &str = "Acknowledge";
/// The Machinery companion specification's namespace (OPC 40001-1).
pub(crate) const MACHINERY_URI: &str = "http://opcfoundation.org/UA/Machinery/";
/// The Devices companion specification's namespace (OPC 10000-100, DI).
pub(crate) const DI_URI: &str = "http://opcfoundation.org/UA/DI/";
/// The folder of the Machinery items under Objects (its browse name Machinery's).
pub(crate) const MACHINES: &str = "Machines";
/// EUInformation's namespace for UNECE codes (OPC 10000-8, 5.6.3).
const UNECE_NAMESPACE: &str = "http://www.opcfoundation.org/UA/units/un/cefact";

/// What the acknowledge method calls once the guard let a call through.
pub(crate) type Acknowledger = Arc<dyn Fn(Acknowledgement) + Send + Sync>;

/// The node ids of the spec's objects and variables in namespace `ns`.
#[derive(Debug, Clone)]
pub(crate) struct NodeIds {
    pub(crate) objects: Vec<NodeId>,
    pub(crate) variables: Vec<Vec<NodeId>>,
    /// Per object, its condition instances (as [`ObjectSpec::conditions`]).
    ///
    /// [`ObjectSpec::conditions`]: super::model::ObjectSpec::conditions
    pub(crate) conditions: Vec<Vec<NodeId>>,
    /// Per Machinery item: its node, its `CurrentState` and its `DeviceHealth`.
    pub(crate) machines: Vec<[NodeId; 3]>,
    pub(crate) acknowledge: Option<(NodeId, NodeId)>,
}

impl NodeIds {
    /// The ids of `spec` in namespace `ns`; an error naming two objects or variables
    /// whose paths coincide.
    pub(crate) fn new(spec: &AddressSpaceSpec, ns: u16) -> Result<Self, String> {
        let mut seen = HashSet::new();
        let mut unique = |path: String| {
            if seen.insert(path.clone()) {
                Ok(NodeId::new(ns, path))
            } else {
                Err(format!(
                    "two nodes of the OPC UA address space would be {path} (names of one \
                     kind must differ, and must not make the same path with '/')"
                ))
            }
        };
        let mut objects = Vec::new();
        let mut variables = Vec::new();
        let mut conditions = Vec::new();
        for (index, object) in spec.objects.iter().enumerate() {
            let path = format!("{ROOT}/{}", object_path(spec, index));
            objects.push(unique(path.clone())?);
            variables.push(
                object
                    .variables
                    .iter()
                    .map(|v| unique(format!("{path}/{}", v.key)))
                    .collect::<Result<_, _>>()?,
            );
            if !object.conditions.is_empty() {
                unique(format!("{path}/{CONDITIONS}"))?;
            }
            conditions.push(
                object
                    .conditions
                    .iter()
                    .map(|c| unique(format!("{path}/{CONDITIONS}/{}", c.kind)))
                    .collect::<Result<_, _>>()?,
            );
        }
        let machines = spec
            .machines
            .iter()
            .map(|machine| {
                let item = format!("{MACHINES}/{}", object_path(spec, machine.object));
                Ok([
                    unique(item.clone())?,
                    unique(format!("{item}/MachineryItemState/CurrentState"))?,
                    unique(format!("{item}/DeviceHealth"))?,
                ])
            })
            .collect::<Result<_, String>>()?;
        let acknowledge = spec
            .objects
            .iter()
            .position(|o| o.kind == ObjectKind::Gateway)
            .map(|gateway| {
                let method = NodeId::new(ns, format!("{ROOT}/Gateway/{ACKNOWLEDGE_METHOD}"));
                (objects[gateway].clone(), method)
            });
        Ok(Self {
            objects,
            variables,
            conditions,
            machines,
            acknowledge,
        })
    }
}

/// Least time between two acknowledges carried out: each one writes the PLC's HMI
/// registers (round-4 audit, finding 7: 2 300 writes a second from one client).
pub(crate) const ACKNOWLEDGE_INTERVAL: Duration = Duration::from_secs(1);

/// Who may acknowledge: a client on this host, or, with `allow_remote`, a signed-in
/// user anywhere; at most one acknowledge per [`ACKNOWLEDGE_INTERVAL`].
pub(crate) struct CommandGuard {
    pub(crate) allow_remote: bool,
    pub(crate) peers: Arc<ChannelPeers>,
    pub(crate) acknowledge: Acknowledger,
    pub(crate) counters: Arc<OpcUaCounters>,
    pub(crate) pace: Mutex<Pace>,
}

/// When the last acknowledge was carried out, and the rate limits of the lines that
/// refusals log.
pub(crate) struct Pace {
    last: Option<Instant>,
    refused: WarnLimit,
    limited: WarnLimit,
    condition_refused: WarnLimit,
}

impl Default for Pace {
    fn default() -> Self {
        Self {
            last: None,
            refused: WarnLimit::new(WARN_PERIOD),
            limited: WarnLimit::new(WARN_PERIOD),
            condition_refused: WarnLimit::new(WARN_PERIOD),
        }
    }
}

impl CommandGuard {
    /// Whether `context`'s session may acknowledge now: who it is, or the refusal
    /// (`Bad_UserAccessDenied`, `Bad_TooManyOperations`), counted and logged.
    fn permit(&self, context: &RequestContext) -> Result<Acknowledgement, StatusCode> {
        let who = self.authorise(context)?;
        self.pace(who)
    }

    /// Whether `context`'s session may acknowledge at all: who it is, or
    /// `Bad_UserAccessDenied`, counted and logged.
    fn authorise(&self, context: &RequestContext) -> Result<Acknowledgement, StatusCode> {
        let channel = context.session.read().secure_channel_id();
        let peer = self.peers.peer(channel);
        let user = auth::user_name(&context.token).map(str::to_owned);
        // A channel the front door did not open came through the server's loopback
        // listener: a process on this host.
        let local = peer.is_none_or(|peer| peer.ip().is_loopback());
        let now = Instant::now();
        let mut pace = crate::lock(&self.pace);
        if !(local || (self.allow_remote && user.is_some())) {
            count(&self.counters.acknowledgements_refused);
            if let Some(suppressed) = pace.refused.occurred(now) {
                tracing::warn!(
                    peer = ?peer,
                    user = ?user,
                    allow_remote_commands = self.allow_remote,
                    suppressed,
                    "OPC UA acknowledge refused: a client on another host needs \
                     outputs.opcua.allow_remote_commands = true and a user of users_file"
                );
            }
            return Err(StatusCode::BadUserAccessDenied);
        }
        Ok(Acknowledgement { peer, user })
    }

    /// Whether `who` may acknowledge now (one a second): counted as carried out, or
    /// `Bad_TooManyOperations`, counted and logged.
    fn pace(&self, who: Acknowledgement) -> Result<Acknowledgement, StatusCode> {
        let Acknowledgement { peer, user } = &who;
        let now = Instant::now();
        let mut pace = crate::lock(&self.pace);
        if pace
            .last
            .is_some_and(|last| now.duration_since(last) < ACKNOWLEDGE_INTERVAL)
        {
            count(&self.counters.acknowledgements_limited);
            if let Some(suppressed) = pace.limited.occurred(now) {
                tracing::warn!(peer = ?peer, user = ?user, suppressed, "OPC UA acknowledge refused: one was carried out less than a second ago");
            }
            return Err(StatusCode::BadTooManyOperations);
        }
        pace.last = Some(now);
        count(&self.counters.acknowledgements);
        Ok(who)
    }

    /// The acknowledge call of `context`'s session: the latched alarms cleared as the
    /// PLC's acknowledge does, or refused.
    fn acknowledge(&self, context: &RequestContext) -> StatusCode {
        match self.permit(context) {
            Ok(who) => {
                tracing::info!(peer = ?who.peer, user = ?who.user, "alarms acknowledged over OPC UA");
                (self.acknowledge)(who);
                StatusCode::Good
            }
            Err(status) => status,
        }
    }

    /// A call of a condition's method refused for what it asked: counted, logged
    /// (rate-limited), its status.
    fn refuse(&self, method: &str, status: StatusCode) -> StatusCode {
        count(&self.counters.condition_calls_refused);
        let mut pace = crate::lock(&self.pace);
        if let Some(suppressed) = pace.condition_refused.occurred(Instant::now()) {
            tracing::warn!(method, %status, suppressed, "OPC UA condition method call refused");
        }
        status
    }
}

/// Builds [`MillgateNodes`] when the server starts.
pub(crate) struct MillgateNodesBuilder {
    pub(crate) spec: Arc<AddressSpaceSpec>,
    pub(crate) guard: Arc<CommandGuard>,
    /// Filled with the spec's condition instances once the namespace is known.
    pub(crate) conditions: Arc<Mutex<Conditions>>,
}

impl InMemoryNodeManagerImplBuilder for MillgateNodesBuilder {
    type Impl = MillgateNodes;

    fn build(self, context: ServerContext, address_space: &mut AddressSpace) -> Self::Impl {
        let mut type_tree = context.type_tree.write();
        let index = type_tree.namespaces_mut().add_namespace(NAMESPACE_URI);
        let machinery = type_tree.namespaces_mut().add_namespace(MACHINERY_URI);
        let di = type_tree.namespaces_mut().add_namespace(DI_URI);
        // The ConditionId of an event (its ConditionType's NodeId, empty browse path)
        // as a field async-opcua accepts in a select clause (the event answers it,
        // `events::ConditionEvent`). A select clause async-opcua cannot resolve is
        // left out of the event's fields, which shifts the fields after it for the
        // client (asyncua, node-opcua and UaExpert select ConditionId).
        let condition_type = NodeId::from(ObjectTypeId::ConditionType);
        type_tree.add_type_property(&condition_type, &condition_type, &[], NodeClass::Object);
        drop(type_tree);
        address_space.add_namespace(NAMESPACE_URI, index);
        address_space.add_namespace(MACHINERY_URI, machinery);
        address_space.add_namespace(DI_URI, di);
        match NodeIds::new(&self.spec, index) {
            Ok(ids) => {
                *crate::lock(&self.conditions) =
                    Conditions::new(&self.spec, &ids.objects, &ids.conditions);
            }
            // The server checked the ids before it started (`NodeIds::new` in `run`).
            Err(error) => tracing::error!(%error, "OPC UA conditions not made"),
        }
        let namespace = |uri: &str, index| NamespaceMetadata {
            namespace_uri: uri.to_owned(),
            namespace_index: index,
            ..Default::default()
        };
        MillgateNodes {
            namespace: namespace(NAMESPACE_URI, index),
            companions: Companions {
                machinery: namespace(MACHINERY_URI, machinery),
                di: namespace(DI_URI, di),
            },
            spec: self.spec,
            guard: self.guard,
            conditions: self.conditions,
        }
    }
}

/// The companion specifications' namespaces, whose browse names the Machinery items
/// use (their nodes are the millgate namespace's).
#[derive(Debug, Clone)]
struct Companions {
    machinery: NamespaceMetadata,
    di: NamespaceMetadata,
}

/// The node manager of the millgate namespace.
pub(crate) struct MillgateNodes {
    namespace: NamespaceMetadata,
    companions: Companions,
    spec: Arc<AddressSpaceSpec>,
    guard: Arc<CommandGuard>,
    conditions: Arc<Mutex<Conditions>>,
}

/// The methods of ConditionType and AcknowledgeableConditionType (namespace 0) that a
/// client calls on a condition instance or on ConditionType, which async-opcua's
/// core namespace does not carry out: the kept patch routes them here.
const CONDITION_METHODS: [MethodId; 3] = [
    MethodId::AcknowledgeableConditionType_Acknowledge,
    MethodId::ConditionType_ConditionRefresh,
    MethodId::ConditionType_ConditionRefresh2,
];

impl MillgateNodes {
    /// A condition's `Acknowledge(EventId, Comment)` on `call`'s object: the PLC's
    /// acknowledge for a latched alarm, this server's for another; refused with the
    /// status OPC 10000-9 5.7.3 names when the EventId is not the condition's last.
    fn acknowledge_condition(&self, context: &RequestContext, call: &MethodCall) -> StatusCode {
        let refuse = |status| self.guard.refuse("Acknowledge", status);
        let (event_id, comment) = match call.arguments() {
            [Variant::ByteString(event_id), comment] => match comment {
                Variant::LocalizedText(text) => (event_id, text.text.to_string()),
                Variant::String(text) => (event_id, text.to_string()),
                Variant::Empty => (event_id, String::new()),
                _ => return refuse(StatusCode::BadTypeMismatch),
            },
            [_, _] => return refuse(StatusCode::BadTypeMismatch),
            arguments if arguments.len() < 2 => return refuse(StatusCode::BadArgumentsMissing),
            _ => return refuse(StatusCode::BadTooManyArguments),
        };
        // Rights first: a client without them learns nothing of the EventIds.
        let who = match self.guard.authorise(context) {
            Ok(who) => who,
            Err(status) => return status,
        };
        let mut conditions = crate::lock(&self.conditions);
        let to_acknowledge = match conditions.check_acknowledge(call.object_id(), event_id) {
            Ok(to_acknowledge) => to_acknowledge,
            Err(refused) => return refuse(refused.status()),
        };
        let who = match self.guard.pace(who) {
            Ok(who) => who,
            Err(status) => return status,
        };
        let name = who
            .user
            .clone()
            .or_else(|| who.peer.map(|peer| peer.to_string()))
            .unwrap_or_default();
        tracing::info!(condition = %call.object_id(), peer = ?who.peer, user = ?who.user, comment, "OPC UA condition acknowledged");
        if to_acknowledge.latched {
            (self.guard.acknowledge)(who);
        }
        if let Some((event, source)) = conditions.acknowledged(to_acknowledge, &comment, &name) {
            context
                .subscriptions
                .notify_events([(&event as &dyn Event, &source)].into_iter());
            count(&self.guard.counters.events);
        }
        StatusCode::Good
    }

    /// ConditionRefresh (`monitored_item` none) or ConditionRefresh2 of `call`: the
    /// retained conditions' last events between RefreshStart and RefreshEnd, to the
    /// session's subscription (OPC 10000-9 5.5.7).
    fn refresh(&self, context: &RequestContext, call: &MethodCall, two: bool) -> StatusCode {
        let method = if two {
            "ConditionRefresh2"
        } else {
            "ConditionRefresh"
        };
        let refuse = |status| self.guard.refuse(method, status);
        let (subscription, monitored_item) = match (call.arguments(), two) {
            ([Variant::UInt32(subscription)], false) => (*subscription, None),
            ([Variant::UInt32(subscription), Variant::UInt32(item)], true) => {
                (*subscription, Some(*item))
            }
            (arguments, _) if arguments.len() < 1 + usize::from(two) => {
                return refuse(StatusCode::BadArgumentsMissing)
            }
            (arguments, _) if arguments.len() > 1 + usize::from(two) => {
                return refuse(StatusCode::BadTooManyArguments)
            }
            _ => return refuse(StatusCode::BadTypeMismatch),
        };
        // Held while the events are queued: an alarm that changes meanwhile comes
        // after RefreshEnd, as the specification asks.
        let mut conditions = crate::lock(&self.conditions);
        let start = events::refresh_event(true, conditions.next_event_id());
        let end = events::refresh_event(false, conditions.next_event_id());
        let retained = conditions.retained();
        let mut sent: Vec<(&dyn Event, Option<&NodeId>)> = vec![(&*start, None)];
        sent.extend(
            retained
                .iter()
                .map(|(event, source)| (event as &dyn Event, Some(source))),
        );
        sent.push((&*end, None));
        let session = context.session_id;
        match context.subscriptions.notify_events_to_subscription(
            session,
            subscription,
            monitored_item,
            &sent,
        ) {
            Ok(()) => {
                count(&self.guard.counters.condition_refreshes);
                tracing::debug!(subscription, retained = retained.len(), "OPC UA {method}");
                StatusCode::Good
            }
            Err(status) => refuse(status),
        }
    }
}

#[async_trait]
impl InMemoryNodeManagerImpl for MillgateNodes {
    async fn init(&self, address_space: &mut AddressSpace, _context: ServerContext) {
        let ns = self.namespace.namespace_index;
        match NodeIds::new(&self.spec, ns) {
            Ok(ids) => {
                build(address_space, &self.spec, &ids, ns);
                let companions = (
                    self.companions.machinery.namespace_index,
                    self.companions.di.namespace_index,
                );
                add_machines(address_space, &self.spec, &ids, ns, companions);
            }
            // The server checked the ids before it started (`NodeIds::new` in `run`).
            Err(error) => tracing::error!(%error, "OPC UA address space not built"),
        }
    }

    fn name(&self) -> &str {
        "millgate"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![
            self.namespace.clone(),
            self.companions.machinery.clone(),
            self.companions.di.clone(),
        ]
    }

    fn takes_method_call(&self, object_id: &NodeId, method_id: &NodeId) -> bool {
        let Ok(method) = method_id.as_method_id() else {
            return false;
        };
        match method {
            MethodId::AcknowledgeableConditionType_Acknowledge => {
                object_id.namespace == self.namespace.namespace_index
            }
            _ => CONDITION_METHODS.contains(&method),
        }
    }

    async fn call(
        &self,
        context: &RequestContext,
        _address_space: &RwLock<AddressSpace>,
        methods_to_call: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        let acknowledge = NodeId::new(
            self.namespace.namespace_index,
            format!("{ROOT}/Gateway/{ACKNOWLEDGE_METHOD}"),
        );
        for call in methods_to_call {
            let method = call.method_id();
            let status = if *method == acknowledge {
                self.guard.acknowledge(context)
            } else if is_condition_acknowledge(method) {
                self.acknowledge_condition(context, call)
            } else {
                match method.as_method_id() {
                    Ok(MethodId::AcknowledgeableConditionType_Acknowledge) => {
                        self.acknowledge_condition(context, call)
                    }
                    Ok(MethodId::ConditionType_ConditionRefresh) => {
                        self.refresh(context, call, false)
                    }
                    Ok(MethodId::ConditionType_ConditionRefresh2) => {
                        self.refresh(context, call, true)
                    }
                    _ => StatusCode::BadMethodInvalid,
                }
            };
            call.set_status(status);
        }
        Ok(())
    }
}

/// Whether `method` is a condition instance's own `Acknowledge` (its node id
/// `<condition>/Acknowledge`; the call's object is the condition).
fn is_condition_acknowledge(method: &NodeId) -> bool {
    string_id(method)
        .rsplit_once('/')
        .is_some_and(|(condition, name)| {
            name == CONDITION_ACKNOWLEDGE && condition.contains(&format!("/{CONDITIONS}/"))
        })
}

/// A browse name in namespace `ns`.
fn name(ns: u16, name: &str) -> QualifiedName {
    QualifiedName::new(ns, name)
}

/// The nodes of `spec` in `address_space`: the root, the folders, the objects and
/// their variables (`Bad_WaitingForInitialData` until the first snapshot), the
/// condition instances, the acknowledge method. Nodes already there are kept as
/// they are: on a grown spec (drivelines added live) only the new objects are added.
pub(crate) fn build(
    address_space: &mut AddressSpace,
    spec: &AddressSpaceSpec,
    ids: &NodeIds,
    ns: u16,
) {
    let root = NodeId::new(ns, ROOT);
    if !address_space.node_exists(&root) {
        ObjectBuilder::new(&root, name(ns, ROOT), ROOT)
            .description(format!("millgate gateway: {}", spec.name))
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .organized_by(ObjectId::ObjectsFolder)
            .insert(address_space);
    }
    for (index, object) in spec.objects.iter().enumerate() {
        let id = &ids.objects[index];
        if address_space.node_exists(id) {
            continue;
        }
        let parent = match (object.parent, object.kind.folder()) {
            (Some(parent), _) => ids.objects[parent].clone(),
            (None, Some(folder)) => {
                let id = NodeId::new(ns, format!("{ROOT}/{folder}"));
                if !address_space.node_exists(&id) {
                    ObjectBuilder::new(&id, name(ns, folder), folder)
                        .is_folder()
                        .organized_by(root.clone())
                        .insert(address_space);
                }
                id
            }
            (None, None) => root.clone(),
        };
        ObjectBuilder::new(id, name(ns, &object.name), object.name.as_str())
            .description(object.description.as_str())
            .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .component_of(parent)
            .insert(address_space);
        for (variable, variable_id) in object.variables.iter().zip(&ids.variables[index]) {
            add_variable(address_space, variable, variable_id, id, ns);
        }
        add_conditions(address_space, object, id, &ids.conditions[index], ns);
    }
    if let Some((gateway, method)) = ids
        .acknowledge
        .as_ref()
        .filter(|(_, method)| !address_space.node_exists(method))
    {
        MethodBuilder::new(method, name(ns, ACKNOWLEDGE_METHOD), ACKNOWLEDGE_METHOD)
            .description(
                "Clear the latched alarms (TAF, gap and chatter alarms), as the PLC's \
                 acknowledge command does; from a client on this host, or with \
                 outputs.opcua.allow_remote_commands a signed-in user",
            )
            .executable(true)
            .user_executable(true)
            .component_of(gateway.clone())
            .insert(address_space);
    }
}

/// `variable` (node `variable_id`) of `object`: its value, unit and range.
fn add_variable(
    address_space: &mut AddressSpace,
    variable: &VariableSpec,
    variable_id: &NodeId,
    object: &NodeId,
    ns: u16,
) {
    // A number with a unit or a range is an analog item (OPC 10000-8, 5.3.2).
    let numeric = matches!(
        variable.datatype,
        VariableType::Double | VariableType::UInt32 | VariableType::UInt64
    );
    let analog = numeric && (variable.unit.is_some() || variable.range.is_some());
    // A state is a number whose values have names (OPC 10000-8, 5.3.3.3: the type
    // of unsigned integers with EnumStrings; its value stays a UInt32).
    let type_definition = if !variable.states.is_empty() {
        VariableTypeId::MultiStateDiscreteType
    } else if analog {
        VariableTypeId::BaseAnalogType
    } else {
        VariableTypeId::BaseDataVariableType
    };
    let variable_id_path = string_id(variable_id);
    VariableBuilder::new(variable_id, name(ns, &variable.key), variable.key.as_str())
        .description(variable.description.as_str())
        .data_type(data_type(variable.datatype))
        .value_rank(-1)
        .access_level(AccessLevel::CURRENT_READ)
        .user_access_level(AccessLevel::CURRENT_READ)
        // Values are written as they change (exception-based), not sampled.
        .minimum_sampling_interval(0.0)
        .has_type_definition(type_definition)
        .component_of(object.clone())
        .insert(address_space);
    if let Some(NodeType::Variable(node)) = address_space.find_mut(variable_id) {
        node.set_data_value(DataValue {
            value: Some(Variant::Empty),
            status: Some(StatusCode::BadWaitingForInitialData),
            ..Default::default()
        });
    }
    // The standard properties' browse names are namespace 0's.
    let property = |property: &str| {
        let property_id = NodeId::new(ns, format!("{variable_id_path}/{property}"));
        VariableBuilder::new(&property_id, property, property)
            .value_rank(-1)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(VariableTypeId::PropertyType)
            .property_of(variable_id.clone())
    };
    if let Some(unit) = variable.unit {
        property("EngineeringUnits")
            .data_type(DataTypeId::EUInformation)
            .value(ExtensionObject::from_message(eu_information(unit)))
            .insert(address_space);
    }
    if let Some((low, high)) = variable.range {
        property("EURange")
            .data_type(DataTypeId::Range)
            .value(ExtensionObject::from_message(Range { low, high }))
            .insert(address_space);
    }
    if !variable.states.is_empty() {
        let id = NodeId::new(ns, format!("{variable_id_path}/EnumStrings"));
        let names = variable.states.iter().map(String::as_str);
        add_enum_strings(address_space, &id, variable_id, names);
    }
}

/// The `Conditions` folder of `object` (node `object_id`) with its condition
/// instances (`ids`), each referenced from the object by `HasCondition` and with its
/// `Acknowledge(EventId, Comment)` method.
fn add_conditions(
    address_space: &mut AddressSpace,
    object: &ObjectSpec,
    object_id: &NodeId,
    ids: &[NodeId],
    ns: u16,
) {
    if object.conditions.is_empty() {
        return;
    }
    let folder = NodeId::new(ns, format!("{}/{CONDITIONS}", string_id(object_id)));
    ObjectBuilder::new(&folder, name(ns, CONDITIONS), CONDITIONS)
        .description("The alarms of this object as condition instances (OPC 10000-9)")
        .is_folder()
        .organized_by(object_id.clone())
        .insert(address_space);
    for (condition, id) in object.conditions.iter().zip(ids) {
        ObjectBuilder::new(id, name(ns, &condition.kind), condition.kind.as_str())
            .description(condition.description.as_str())
            .has_type_definition(ObjectTypeId::AlarmConditionType)
            .organized_by(folder.clone())
            .insert(address_space);
        address_space.insert_reference(object_id, id, ReferenceTypeId::HasCondition);
        let method = NodeId::new(ns, format!("{}/{CONDITION_ACKNOWLEDGE}", string_id(id)));
        let arguments = [
            argument(
                "EventId",
                DataTypeId::ByteString,
                "The EventId of the event acknowledged",
            ),
            argument(
                "Comment",
                DataTypeId::LocalizedText,
                "A comment kept with the condition",
            ),
        ];
        let arguments_id = NodeId::new(ns, format!("{}/InputArguments", string_id(&method)));
        MethodBuilder::new(&method, CONDITION_ACKNOWLEDGE, CONDITION_ACKNOWLEDGE)
            .description(if condition.latched {
                "Acknowledge the alarm: the latched alarms are cleared as the PLC's \
                 acknowledge command does (AcknowledgeAlarms' rights and pace)"
            } else {
                "Acknowledge the condition on this server (AcknowledgeAlarms' rights \
                 and pace)"
            })
            .executable(true)
            .user_executable(true)
            .component_of(id.clone())
            .input_args(address_space, &arguments_id, &arguments)
            .insert(address_space);
    }
}

/// The Machinery items (OPC 40001-1) of `spec` under `Objects/Machines`: each with
/// its `Identification` (DI's nameplate names), its `MachineryItemState` with
/// `CurrentState`, and its NE 107 `DeviceHealth` (DI), and organizing the object it
/// stands for. Typed by the base types: the DI and Machinery nodesets are not loaded
/// (docs/opcua.md). Items already there are kept as they are (as in [`build`]).
pub(crate) fn add_machines(
    address_space: &mut AddressSpace,
    spec: &AddressSpaceSpec,
    ids: &NodeIds,
    ns: u16,
    (machinery, di): (u16, u16),
) {
    if spec.machines.is_empty() {
        return;
    }
    let folder = NodeId::new(ns, MACHINES);
    if !address_space.node_exists(&folder) {
        ObjectBuilder::new(&folder, name(machinery, MACHINES), MACHINES)
            .description(
                "The machines of OPC 40001-1 (Machinery): the gateway, its drivelines and mills",
            )
            .is_folder()
            .organized_by(ObjectId::ObjectsFolder)
            .insert(address_space);
    }
    let property = |id: &NodeId, browse: QualifiedName, display: &str| {
        VariableBuilder::new(id, browse, display)
            .value_rank(-1)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
    };
    for (machine, [item, current_state, health]) in spec.machines.iter().zip(&ids.machines) {
        if address_space.node_exists(item) {
            continue;
        }
        let object = &spec.objects[machine.object];
        let path = string_id(item);
        ObjectBuilder::new(item, name(ns, &object.name), object.name.as_str())
            .description(object.description.as_str())
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .organized_by(folder.clone())
            .insert(address_space);
        address_space.insert_reference(
            item,
            &ids.objects[machine.object],
            ReferenceTypeId::Organizes,
        );
        let identification = NodeId::new(ns, format!("{path}/Identification"));
        ObjectBuilder::new(
            &identification,
            name(di, "Identification"),
            "Identification",
        )
        .has_type_definition(ObjectTypeId::BaseObjectType)
        .component_of(item.clone())
        .insert(address_space);
        for (key, value) in &machine.identification {
            let id = NodeId::new(ns, format!("{path}/Identification/{key}"));
            let builder = property(&id, name(di, key), key)
                .has_type_definition(VariableTypeId::PropertyType)
                .property_of(identification.clone());
            match value {
                NameplateValue::LocalizedText(text) => builder
                    .data_type(DataTypeId::LocalizedText)
                    .value(LocalizedText::new("en", text)),
                NameplateValue::String(text) => {
                    builder.data_type(DataTypeId::String).value(text.as_str())
                }
                NameplateValue::UInt16(number) => {
                    builder.data_type(DataTypeId::UInt16).value(*number)
                }
            }
            .insert(address_space);
        }
        let state = NodeId::new(ns, format!("{path}/MachineryItemState"));
        ObjectBuilder::new(
            &state,
            name(machinery, "MachineryItemState"),
            "MachineryItemState",
        )
        .description("NotAvailable, NotExecuting or Executing (OPC 40001-1)")
        .has_type_definition(ObjectTypeId::BaseObjectType)
        .component_of(item.clone())
        .insert(address_space);
        property(
            current_state,
            QualifiedName::new(0, "CurrentState"),
            "CurrentState",
        )
        .data_type(DataTypeId::LocalizedText)
        .has_type_definition(VariableTypeId::BaseDataVariableType)
        .minimum_sampling_interval(0.0)
        .component_of(state.clone())
        .insert(address_space);
        property(health, name(di, "DeviceHealth"), "DeviceHealth")
            .description("NE 107 device health: the values of DI's DeviceHealthEnumeration")
            .data_type(DataTypeId::UInt32)
            .has_type_definition(VariableTypeId::MultiStateDiscreteType)
            .minimum_sampling_interval(0.0)
            .component_of(item.clone())
            .insert(address_space);
        let id = NodeId::new(ns, format!("{path}/DeviceHealth/EnumStrings"));
        add_enum_strings(address_space, &id, health, DeviceHealth::NAMES);
    }
}

/// The `EnumStrings` property (node `id`) of `variable`: the names of its values,
/// from 0 (OPC 10000-8, 5.3.3.3).
fn add_enum_strings<'a>(
    address_space: &mut AddressSpace,
    id: &NodeId,
    variable: &NodeId,
    names: impl IntoIterator<Item = &'a str>,
) {
    let names: Vec<LocalizedText> = names
        .into_iter()
        .map(|name| LocalizedText::new("en", name))
        .collect();
    VariableBuilder::new(id, "EnumStrings", "EnumStrings")
        .data_type(DataTypeId::LocalizedText)
        .value_rank(1)
        .access_level(AccessLevel::CURRENT_READ)
        .user_access_level(AccessLevel::CURRENT_READ)
        .value(names)
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(variable.clone())
        .insert(address_space);
}

/// A method argument.
fn argument(name: &str, data_type: DataTypeId, description: &str) -> Argument {
    Argument {
        name: name.into(),
        data_type: data_type.into(),
        value_rank: -1,
        array_dimensions: None,
        description: LocalizedText::new("en", description),
    }
}

/// The string identifier of a node id of this namespace.
fn string_id(id: &NodeId) -> String {
    match &id.identifier {
        opcua::types::Identifier::String(path) => path.as_ref().to_owned(),
        other => other.to_string(),
    }
}

/// The OPC UA data type of `datatype`.
fn data_type(datatype: VariableType) -> DataTypeId {
    match datatype {
        VariableType::Double => DataTypeId::Double,
        VariableType::Boolean => DataTypeId::Boolean,
        VariableType::UInt32 => DataTypeId::UInt32,
        VariableType::UInt64 => DataTypeId::UInt64,
        VariableType::DateTime => DataTypeId::DateTime,
    }
}

/// `unit` as EUInformation.
pub(crate) fn eu_information(unit: Unit) -> EUInformation {
    EUInformation {
        namespace_uri: UNECE_NAMESPACE.into(),
        unit_id: unit.unit_id(),
        display_name: LocalizedText::new("en", unit.symbol),
        description: LocalizedText::new("en", unit.name),
    }
}
