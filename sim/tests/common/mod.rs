//! Shared by the sim test files.

use millgate_sim::model::Model;

/// A model shipped in `sim/models/`.
pub(crate) fn load(name: &str) -> anyhow::Result<Model> {
    Ok(Model::load(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("models")
            .join(name),
    )?)
}
