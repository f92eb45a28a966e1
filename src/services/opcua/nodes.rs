//! The server's node manager for the run's namespace: its nodes live in memory (each frame's
//! changes are written into them, reads and subscriptions read them there), and its methods are
//! called with the session's user — so the log names who commanded the machine.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

use async_trait::async_trait;
use opcua::nodes::NodeSet2Import;
use opcua::server::ContinuationPoint;
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerBuilder, InMemoryNodeManagerImpl};
use opcua::server::node_manager::{HistoryNode, MethodCall, NodeManagerBuilder, RequestContext, ServerContext};
use opcua::sync::RwLock;
use opcua::types::{HistoryData, NodeId, ReadRawModifiedDetails, StatusCode, TimestampsToReturn, Variant};
use tracing::info;

use super::history::{Continuation, History};
use super::methods::{CallRate, command};
use super::space::{Method, NAMESPACE};
use crate::runtime::frame::FrameFeed;
use crate::services::hmi::commands::CommandSink;

/// The node manager of the run's namespace.
pub type PlcNodeManager = InMemoryNodeManager<PlcNodes>;

/// The run's nodes: the namespace, and where its methods' commands go (set once the address
/// space is built).
pub struct PlcNodes {
    namespaces: Vec<NamespaceMetadata>,
    commander: OnceLock<Commander>,
    history: OnceLock<Arc<Mutex<History>>>,
}

/// What the methods need: which node is which method, the newest frame's state, where commands
/// go, the run's programs, the bound on calls.
pub struct Commander {
    /// The methods' nodes.
    pub methods: HashMap<NodeId, Method>,
    /// The frames (the state the methods check).
    pub feed: FrameFeed,
    /// Where commands go.
    pub sink: CommandSink,
    /// The run's programs, numbered from 1 for `Load`.
    pub programs: Vec<String>,
    /// The bound on calls, all sessions together.
    pub rate: Mutex<CallRate>,
}

/// The builder the server is given: registers [`NAMESPACE`] and imports the `companions`
/// (the namespaces and nodes of [`super::companion`]), whose instances live beside the run's.
pub fn builder(companions: Vec<NodeSet2Import>) -> impl NodeManagerBuilder {
    InMemoryNodeManagerBuilder::new(move |context: ServerContext, space: &mut AddressSpace| {
        let mut type_tree = context.type_tree.write();
        // The run's namespace first, so that its index does not depend on the companions.
        let index = type_tree.namespaces_mut().add_namespace(NAMESPACE);
        space.add_namespace(NAMESPACE, index);
        for import in &companions {
            space.import_node_set(import, type_tree.namespaces_mut());
        }
        let mut namespaces: Vec<NamespaceMetadata> = space
            .namespaces()
            .iter()
            .map(|(index, uri)| NamespaceMetadata {
                namespace_uri: uri.clone(),
                namespace_index: *index,
                ..Default::default()
            })
            .collect();
        namespaces.sort_by_key(|n| n.namespace_index);
        PlcNodes {
            namespaces,
            commander: OnceLock::new(),
            history: OnceLock::new(),
        }
    })
}

impl PlcNodes {
    /// Gives the methods their commander; `false` if they had one already (it is given once).
    pub fn set_commander(&self, commander: Commander) -> bool {
        self.commander.set(commander).is_ok()
    }

    /// The methods' commander, once given.
    pub fn commander(&self) -> Option<&Commander> {
        self.commander.get()
    }

    /// Gives the history HistoryRead reads; `false` if it had one already.
    pub fn set_history(&self, history: Arc<Mutex<History>>) -> bool {
        self.history.set(history).is_ok()
    }
}

impl Commander {
    /// Carries out `method` for `user`: logged with the user's name and the outcome.
    pub fn call(&self, method: Method, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        if !self
            .rate
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .allow(Instant::now())
        {
            return Err(StatusCode::BadTooManyOperations);
        }
        let state = self.feed.latest().status.state.clone();
        match command(method, args, &state, &self.programs, &self.sink) {
            Ok(done) => {
                info!("OPC UA: user \"{user}\": {}: {done}", method.name());
                Ok(vec![Variant::from(done)])
            }
            Err((code, why)) => {
                info!("OPC UA: user \"{user}\": {} refused ({code}): {why}", method.name());
                Err(code)
            }
        }
    }
}

#[async_trait]
impl InMemoryNodeManagerImpl for PlcNodes {
    async fn init(&self, _address_space: &mut AddressSpace, _context: ServerContext) {}

    fn name(&self) -> &str {
        "pkm-plc"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        self.namespaces.clone()
    }

    /// Raw values from the history kept in memory (the server has checked that each node may
    /// be read so); modified values there are none of.
    async fn history_read_raw_modified(
        &self,
        _context: &RequestContext,
        details: &ReadRawModifiedDetails,
        nodes: &mut [&mut &mut HistoryNode],
        _timestamps_to_return: TimestampsToReturn,
    ) -> Result<(), StatusCode> {
        if details.is_read_modified {
            return Err(StatusCode::BadHistoryOperationUnsupported);
        }
        let Some(history) = self.history.get() else {
            return Err(StatusCode::BadHistoryOperationUnsupported);
        };
        let history = history.lock().unwrap_or_else(|p| p.into_inner());
        for node in nodes {
            let from = match node.continuation_point() {
                Some(cp) => match cp.get::<Continuation>() {
                    Some(c) => Some(c.clone()),
                    None => {
                        node.set_status(StatusCode::BadContinuationPointInvalid);
                        continue;
                    }
                },
                None => None,
            };
            let count = details.num_values_per_node as usize;
            match history.read_raw(
                node.node_id(),
                details.start_time,
                details.end_time,
                count,
                from.as_ref(),
            ) {
                Ok((values, next)) => {
                    node.set_result(HistoryData {
                        data_values: Some(values),
                    });
                    node.set_next_continuation_point(next.map(|c| ContinuationPoint::new(Box::new(c))));
                    node.set_status(StatusCode::Good);
                }
                Err(refused) => node.set_status(refused.status()),
            }
        }
        Ok(())
    }

    /// The server has checked that the method exists on its object, that the arguments fit its
    /// declaration and that the session's user may execute it (anonymous sessions may not).
    async fn call(
        &self,
        context: &RequestContext,
        _address_space: &RwLock<AddressSpace>,
        methods_to_call: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        let Some(commander) = self.commander.get() else {
            return Err(StatusCode::BadServiceUnsupported);
        };
        let user = &context.user_token().0;
        for call in methods_to_call {
            match commander.methods.get(call.method_id()) {
                Some(&method) => match commander.call(method, call.arguments(), user) {
                    Ok(outputs) => {
                        call.set_outputs(outputs);
                        call.set_status(StatusCode::Good);
                    }
                    Err(code) => call.set_status(code),
                },
                None => call.set_status(StatusCode::BadMethodInvalid),
            }
        }
        Ok(())
    }
}
