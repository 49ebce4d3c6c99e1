//! What the command line uses of the OPC UA server: the address space as a table
//! (`millgate address-space`) and the demo's `--opcua`.

use millgate_config::{Config, OpcUaOutput};

use super::adapter::CatalogueAdapter;
use super::model::render_markdown;
use super::OpcUaError;

/// `config`'s address space as a Markdown table (every variable: node id, type, unit
/// with its UNECE code, range, description), from the spec the server publishes; its
/// rod mills have `rod_spans` spans. `millgate address-space` prints it.
pub fn address_space_table(config: &Config, rod_spans: &[usize]) -> Result<String, OpcUaError> {
    let (_, spec) = CatalogueAdapter::new(config, rod_spans);
    Ok(render_markdown(&spec))
}

/// The OPC UA option of `millgate demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoOption {
    /// Serve the results over OPC UA on this address (security none, anonymous).
    #[arg(long, value_name = "HOST:PORT")]
    pub opcua: Option<std::net::SocketAddr>,
}

impl DemoOption {
    /// Turn the server on in `config` when asked: anonymous, security none, its
    /// certificate store in `folder`'s `opcua-pki`.
    pub fn apply(&self, config: &mut Config, folder: &std::path::Path) {
        if let Some(bind) = self.opcua {
            let pki_dir = folder.join(OpcUaOutput::DEFAULT_PKI_FOLDER);
            config.outputs.opcua = Some(OpcUaOutput::on(bind, pki_dir));
        }
    }
}
