//! Why the OPC UA server could not start or stopped.

use std::path::PathBuf;

/// Why the OPC UA server could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum OpcUaError {
    /// The certificate store cannot be made or read.
    #[error("outputs.opcua.pki_dir: {}: {why}", path.display())]
    Pki {
        /// The store's folder.
        path: PathBuf,
        /// Why.
        why: String,
    },
    /// async-opcua refused the settings, or its server ended.
    #[error("the OPC UA server: {0}")]
    Server(String),
    /// Two nodes of the address space would have one id.
    #[error("outputs.opcua: {0}")]
    AddressSpace(String),
    /// A listener failed.
    #[error("the OPC UA server's listener: {0}")]
    Io(#[from] std::io::Error),
}
