//! `millgate address-space --config FILE`: the OPC UA server's address space as a
//! Markdown table (every variable: node id, type, unit with its UNECE code, range,
//! description), from the same spec the server publishes (an error in a millgate built
//! without the `opcua` feature).

use millgate_config::Config;

use crate::analysis::rod_monitor::RodMonitor;
use crate::outputs::opcua::address_space_table;

/// The table of `config`'s address space; an error when a rod mill's file does not
/// load (its spans are variables).
pub fn run(config: &Config) -> anyhow::Result<String> {
    let spans = (0..config.rod_mills.len())
        .map(|index| Ok(RodMonitor::new(config, index)?.span_names().len()))
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(address_space_table(config, &spans)?)
}
