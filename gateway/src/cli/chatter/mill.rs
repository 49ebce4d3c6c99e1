//! The tandem mill `millgate chatter` and `millgate chatter commission` run on: the
//! one `--mill` names in the configuration, or its first.

use std::path::Path;

use anyhow::{bail, Context};
use millgate_config::Config;

/// The index of the tandem mill called `name` in `config` (the first without a
/// name); the error names the file and the mills there are.
pub(super) fn mill_index(
    config: &Config,
    name: Option<&str>,
    config_path: &Path,
) -> anyhow::Result<usize> {
    match name {
        None if config.tandem_mills.is_empty() => {
            bail!("{}: no [[tandem_mills]]", config_path.display())
        }
        None => Ok(0),
        Some(name) => config
            .tandem_mills
            .iter()
            .position(|m| m.name == name)
            .with_context(|| {
                let names: Vec<_> = config
                    .tandem_mills
                    .iter()
                    .map(|m| m.name.as_str())
                    .collect();
                format!(
                    "--mill {name}: no such tandem mill in {} (mills: {})",
                    config_path.display(),
                    names.join(", ")
                )
            }),
    }
}
