//! The OPC UA server's stand-in in a millgate built without the `opcua` feature: the
//! names the rest of the gateway uses (the face of `outputs/opcua/mod.rs`), none of
//! whose values can exist. A configuration with `[outputs.opcua]` is refused with a
//! sentence saying how to build the server in; there is never a server to run, count
//! or show on `/metrics`, and the demo has no `--opcua`.

use std::convert::Infallible;
use std::sync::Arc;

use millgate_config::{Config, OpcUaOutput};
use tokio::net::TcpListener;

use crate::exposition::{Exposition, Families};
use crate::shutdown::Shutdown;
use crate::state::board::Board;
use crate::state::commands::CommandSender;

/// Why the OPC UA server cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OpcUaError {
    /// `[outputs.opcua]` in a millgate built without the `opcua` feature.
    #[error(
        "outputs.opcua: this millgate was built without the OPC UA server (build it with \
         cargo build --release -p millgate --features opcua)"
    )]
    NotBuilt,
}

/// The OPC UA output: never made without the feature.
#[derive(Debug)]
pub struct OpcUaOutputTask(Infallible);

impl OpcUaOutputTask {
    /// `None` without `[outputs.opcua]`, [`OpcUaError::NotBuilt`] with it.
    pub fn prepare(
        config: &Config,
        _rod_spans: &[usize],
        _board: Arc<Board>,
        _commands: CommandSender,
        _configs: tokio::sync::watch::Receiver<Arc<Config>>,
    ) -> Result<Option<Self>, OpcUaError> {
        match config.outputs.opcua {
            Some(_) => Err(OpcUaError::NotBuilt),
            None => Ok(None),
        }
    }

    /// The server's counts (none: there is no server).
    pub fn status(&self) -> OpcUaStatus {
        match self.0 {}
    }

    /// Serve on `listener` (never called: there is no server).
    pub async fn run(self, _listener: TcpListener, _shutdown: Shutdown) -> Result<(), String> {
        match self.0 {}
    }
}

/// The counts of a running server: never made without the feature.
#[derive(Debug, Clone)]
pub struct OpcUaStatus(Infallible);

impl Families for OpcUaStatus {
    fn write_families(&self, _page: &mut Exposition) {
        match self.0 {}
    }
}

/// No warning: a configuration with `[outputs.opcua]` is refused.
pub fn exposure_warning(_settings: &OpcUaOutput) -> Option<String> {
    None
}

/// [`OpcUaError::NotBuilt`]: there is no address space to show.
pub fn address_space_table(_config: &Config, _rod_spans: &[usize]) -> Result<String, OpcUaError> {
    Err(OpcUaError::NotBuilt)
}

/// The demo's OPC UA option: none without the feature.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoOption {}

impl DemoOption {
    /// Nothing to turn on.
    pub fn apply(&self, _config: &mut Config, _folder: &std::path::Path) {}
}
