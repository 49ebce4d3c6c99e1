//! The millgate namespace: the address space built from the [`AddressSpaceSpec`]
//! and the acknowledge method, guarded like the HMI server's command registers.
//!
//! Layout: `Objects/Millgate` (the root), with `Gateway` (its state, the method
//! `AcknowledgeAlarms`) and one folder per kind of object (`Sources`, `Drivelines`,
//! `TandemMills`, `RodMills`); each object holds its variables, an object with a
//! parent sits in its parent. Node ids are strings of the browse path from the root:
//! `ns=<millgate>;s=Drivelines/F1/taf`.

use std::collections::HashSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_trait::async_trait;
use opcua::nodes::{EventNotifier, MethodBuilder, NodeType, ObjectBuilder, VariableBuilder};
use opcua::server::address_space::{AccessLevel, AddressSpace};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{
    InMemoryNodeManagerImpl, InMemoryNodeManagerImplBuilder,
};
use opcua::server::node_manager::{MethodCall, RequestContext, ServerContext};
use opcua::sync::RwLock;
use opcua::types::{
    DataTypeId, DataValue, EUInformation, ExtensionObject, LocalizedText, NodeClass, NodeId,
    ObjectId, ObjectTypeId, Range, StatusCode, VariableTypeId, Variant,
};

use super::auth;
use super::front::ChannelPeers;
use super::model::{
    object_path, Acknowledgement, AddressSpaceSpec, ObjectKind, Unit, VariableType,
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
/// EUInformation's namespace for UNECE codes (OPC 10000-8, 5.6.3).
const UNECE_NAMESPACE: &str = "http://www.opcfoundation.org/UA/units/un/cefact";

/// What the acknowledge method calls once the guard let a call through.
pub(crate) type Acknowledger = Arc<dyn Fn(Acknowledgement) + Send + Sync>;

/// The node ids of the spec's objects and variables in namespace `ns`.
#[derive(Debug, Clone)]
pub(crate) struct NodeIds {
    pub(crate) objects: Vec<NodeId>,
    pub(crate) variables: Vec<Vec<NodeId>>,
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
        }
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
}

impl Default for Pace {
    fn default() -> Self {
        Self {
            last: None,
            refused: WarnLimit::new(WARN_PERIOD),
            limited: WarnLimit::new(WARN_PERIOD),
        }
    }
}

impl CommandGuard {
    /// The acknowledge call of `context`'s session: done, or refused with
    /// `BadUserAccessDenied`.
    fn acknowledge(&self, context: &RequestContext) -> StatusCode {
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
            return StatusCode::BadUserAccessDenied;
        }
        if pace
            .last
            .is_some_and(|last| now.duration_since(last) < ACKNOWLEDGE_INTERVAL)
        {
            count(&self.counters.acknowledgements_limited);
            if let Some(suppressed) = pace.limited.occurred(now) {
                tracing::warn!(peer = ?peer, user = ?user, suppressed, "OPC UA acknowledge refused: one was carried out less than a second ago");
            }
            return StatusCode::BadTooManyOperations;
        }
        pace.last = Some(now);
        drop(pace);
        count(&self.counters.acknowledgements);
        tracing::info!(peer = ?peer, user = ?user, "alarms acknowledged over OPC UA");
        (self.acknowledge)(Acknowledgement { peer, user });
        StatusCode::Good
    }
}

/// Builds [`MillgateNodes`] when the server starts.
pub(crate) struct MillgateNodesBuilder {
    pub(crate) spec: Arc<AddressSpaceSpec>,
    pub(crate) guard: Arc<CommandGuard>,
}

impl InMemoryNodeManagerImplBuilder for MillgateNodesBuilder {
    type Impl = MillgateNodes;

    fn build(self, context: ServerContext, address_space: &mut AddressSpace) -> Self::Impl {
        let mut type_tree = context.type_tree.write();
        let index = type_tree.namespaces_mut().add_namespace(NAMESPACE_URI);
        // The ConditionId of an event (its ConditionType's NodeId, empty browse path)
        // as a field async-opcua accepts in a select clause: it answers null (there are
        // no condition instances). A select clause async-opcua cannot resolve is left
        // out of the event's fields, which shifts the fields after it for the client
        // (asyncua and UaExpert select ConditionId).
        let condition_type = NodeId::from(ObjectTypeId::ConditionType);
        type_tree.add_type_property(&condition_type, &condition_type, &[], NodeClass::Object);
        drop(type_tree);
        address_space.add_namespace(NAMESPACE_URI, index);
        MillgateNodes {
            namespace: NamespaceMetadata {
                namespace_uri: NAMESPACE_URI.to_owned(),
                namespace_index: index,
                ..Default::default()
            },
            spec: self.spec,
            guard: self.guard,
        }
    }
}

/// The node manager of the millgate namespace.
pub(crate) struct MillgateNodes {
    namespace: NamespaceMetadata,
    spec: Arc<AddressSpaceSpec>,
    guard: Arc<CommandGuard>,
}

#[async_trait]
impl InMemoryNodeManagerImpl for MillgateNodes {
    async fn init(&self, address_space: &mut AddressSpace, _context: ServerContext) {
        let ns = self.namespace.namespace_index;
        match NodeIds::new(&self.spec, ns) {
            Ok(ids) => build(address_space, &self.spec, &ids, ns),
            // The server checked the ids before it started (`NodeIds::new` in `run`).
            Err(error) => tracing::error!(%error, "OPC UA address space not built"),
        }
    }

    fn name(&self) -> &str {
        "millgate"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![self.namespace.clone()]
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
            if *call.method_id() == acknowledge {
                call.set_status(self.guard.acknowledge(context));
            } else {
                call.set_status(StatusCode::BadMethodInvalid);
            }
        }
        Ok(())
    }
}

/// The nodes of `spec` in `address_space`: the root, the folders, the objects and
/// their variables (`Bad_WaitingForInitialData` until the first snapshot), the
/// acknowledge method.
fn build(address_space: &mut AddressSpace, spec: &AddressSpaceSpec, ids: &NodeIds, ns: u16) {
    let root = NodeId::new(ns, ROOT);
    ObjectBuilder::new(&root, ROOT, ROOT)
        .description(format!("millgate gateway: {}", spec.name))
        .has_type_definition(ObjectTypeId::BaseObjectType)
        .organized_by(ObjectId::ObjectsFolder)
        .insert(address_space);
    let mut folders = Vec::new();
    for (index, object) in spec.objects.iter().enumerate() {
        let parent = match (object.parent, object.kind.folder()) {
            (Some(parent), _) => ids.objects[parent].clone(),
            (None, Some(folder)) => {
                let id = NodeId::new(ns, format!("{ROOT}/{folder}"));
                if !folders.contains(&id) {
                    ObjectBuilder::new(&id, folder, folder)
                        .is_folder()
                        .organized_by(root.clone())
                        .insert(address_space);
                    folders.push(id.clone());
                }
                id
            }
            (None, None) => root.clone(),
        };
        let id = &ids.objects[index];
        ObjectBuilder::new(id, object.name.as_str(), object.name.as_str())
            .description(object.description.as_str())
            .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .component_of(parent)
            .insert(address_space);
        for (variable, variable_id) in object.variables.iter().zip(&ids.variables[index]) {
            // A number with a unit or a range is an analog item (OPC 10000-8, 5.3.2).
            let numeric = matches!(
                variable.datatype,
                VariableType::Double | VariableType::UInt32 | VariableType::UInt64
            );
            let analog = numeric && (variable.unit.is_some() || variable.range.is_some());
            let type_definition = if analog {
                VariableTypeId::BaseAnalogType
            } else {
                VariableTypeId::BaseDataVariableType
            };
            let variable_id_path = string_id(variable_id);
            VariableBuilder::new(variable_id, variable.key.as_str(), variable.key.as_str())
                .description(variable.description.as_str())
                .data_type(data_type(variable.datatype))
                .value_rank(-1)
                .access_level(AccessLevel::CURRENT_READ)
                .user_access_level(AccessLevel::CURRENT_READ)
                .has_type_definition(type_definition)
                .component_of(id.clone())
                .insert(address_space);
            if let Some(NodeType::Variable(node)) = address_space.find_mut(variable_id) {
                node.set_data_value(DataValue {
                    value: Some(Variant::Empty),
                    status: Some(StatusCode::BadWaitingForInitialData),
                    ..Default::default()
                });
            }
            let property = |name: &str| {
                let property_id = NodeId::new(ns, format!("{variable_id_path}/{name}"));
                VariableBuilder::new(&property_id, name, name)
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
        }
    }
    if let Some((gateway, method)) = &ids.acknowledge {
        MethodBuilder::new(method, ACKNOWLEDGE_METHOD, ACKNOWLEDGE_METHOD)
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
