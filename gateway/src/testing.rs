//! What the unit tests of several rooms share: the example configurations.

use std::path::PathBuf;

use millgate_config::Config;

/// The path of `config/examples/<name>`.
pub(crate) fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../config/examples")
        .join(name)
}

/// The example configuration `config/examples/<name>`, loaded.
pub(crate) fn example_config(name: &str) -> Config {
    millgate_config::load(&example(name)).expect("the example loads")
}
