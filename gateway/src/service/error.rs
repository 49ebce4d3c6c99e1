//! Why the service could not start, or a task of it failed.

use crate::analysis::AnalysisError;
use crate::outputs::modbus::register_map::MapTooLarge;

/// Why the service could not start, or its task failed.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// A driveline or tandem mill the analysis cannot be built for.
    #[error(transparent)]
    Analysis(#[from] AnalysisError),
    /// A listening output (the HMI Modbus server, the metrics endpoint) could not bind.
    #[error("cannot bind the {output} to {address}: {source}")]
    Bind {
        /// Which output: "Modbus server", "metrics endpoint", "maintenance page" or
        /// "OPC UA server".
        output: &'static str,
        /// The configured address.
        address: std::net::SocketAddr,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Drivelines that name a model the wear diagnosis cannot use (the model does not
    /// load, or its `wear` settings do not fit it): one `<key path>: <problem>` each,
    /// naming the model file.
    #[error("{}", .0.join("\n"))]
    Wear(Vec<String>),
    /// The register map does not fit a Modbus table.
    #[error("drivelines, tandem_mills: {0}")]
    MapTooLarge(#[from] MapTooLarge),
    /// The register map written at `outputs.plc.register_base` runs past register 65535.
    #[error(
        "outputs.plc.register_base: {base} is not allowed: the register map spans {span} \
         registers and would end at register {end}, past 65535 (must be 0..={max})"
    )]
    RegisterBase {
        /// The configured base.
        base: u16,
        /// Registers the map spans.
        span: u16,
        /// Last register the map would reach.
        end: u32,
        /// Highest base that fits.
        max: u32,
    },
    /// An output task ended while the service ran: its listener failed for good, or it
    /// panicked.
    #[error("the {output} stopped: {reason}")]
    Output {
        /// Which output.
        output: &'static str,
        /// What ended it.
        reason: String,
    },
    /// The Sparkplug B edge node's TLS files cannot be used.
    #[error("the Sparkplug B edge node cannot start: {0}")]
    SparkplugTls(#[from] crate::outputs::sparkplug::tls::TlsSetupError),
    /// The OPC UA server cannot be built or started (or, built without the `opcua`
    /// feature, `[outputs.opcua]` is configured).
    #[error(transparent)]
    OpcUa(#[from] crate::outputs::opcua::OpcUaError),
    /// The service's task panicked or was cancelled.
    #[error("the service task failed: {0}")]
    Task(#[from] tokio::task::JoinError),
    /// The service ended without being asked to stop.
    #[error("the service ended without being asked to stop")]
    Ended,
}
