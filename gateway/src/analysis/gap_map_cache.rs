//! Gap maps on disk, so a restart does not rebuild them.
//!
//! One JSON file per driveline model and settings in the cache folder
//! (`cache_dir` in the configuration, else systemd's `$CACHE_DIRECTORY`, both
//! resolved by the configuration, else [`default_dir`]): `gap-maps-<hash>.json`,
//! where `<hash>` is the FNV-1a 64 hash of the **key**, a text holding everything the
//! maps depend on: the format version, the model as simulated (its TOML with every
//! backlash 0 and the torque channel's sample rate, so comments and a backlash in the
//! file do not matter), the bite detector's and the transient analysis' settings, the
//! simulated idle and record lengths, and the grid. The file stores the key itself
//! beside the maps (`{"key": ..., "maps": ...}`); a file whose key differs (a hash
//! collision, an older format) or that does not parse is rebuilt and overwritten.
//! Writes go to a temporary file renamed into place, so a reader never sees half a
//! file.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::simulated_bite::BiteSimulator;
use crate::state::gap_maps::{fnv1a, GapMapData, GapMapSpec, GapMaps};

/// Version of the file format and of what a map point means; part of the key.
pub(crate) const FORMAT_VERSION: u32 = 1;

/// Why the cache could not be used (never fatal: the maps are then built and kept in
/// memory only).
#[derive(Debug, thiserror::Error)]
pub(crate) enum CacheError {
    /// The cache folder or file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The folder or file.
        path: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is not valid JSON of the expected form.
    #[error("{path}: not a gap map file: {message}")]
    Format {
        /// The file.
        path: String,
        /// What the JSON parser said.
        message: String,
    },
    /// The model could not be written as TOML for the key.
    #[error("cannot key the gap maps: {0}")]
    Model(#[from] millgate_sim::model::ModelError),
}

#[derive(Serialize, Deserialize)]
struct CacheFile {
    key: String,
    maps: GapMapData,
}

/// The key of the maps `simulator` builds over `spec`.
pub(crate) fn key(simulator: &BiteSimulator, spec: &GapMapSpec) -> Result<String, CacheError> {
    let spec = serde_json::to_string(spec).map_err(|error| CacheError::Format {
        path: "<spec>".into(),
        message: error.to_string(),
    })?;
    Ok(format!(
        "millgate gap maps, format {FORMAT_VERSION}\n{}\nspec {spec}\n",
        simulator.describe()?
    ))
}

/// The file holding the maps of `key` in `dir`.
pub(crate) fn path(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("gap-maps-{:016x}.json", fnv1a(key)))
}

/// The cache folder when the configuration names none and systemd set no
/// `$CACHE_DIRECTORY`: `$XDG_CACHE_HOME/millgate`,
/// else `$HOME/.cache/millgate`, else `millgate-cache` in the system's temporary
/// folder.
pub(crate) fn default_dir() -> PathBuf {
    let from_env = |name: &str| std::env::var_os(name).filter(|value| !value.is_empty());
    if let Some(cache) = from_env("XDG_CACHE_HOME") {
        PathBuf::from(cache).join("millgate")
    } else if let Some(home) = from_env("HOME") {
        PathBuf::from(home).join(".cache").join("millgate")
    } else {
        std::env::temp_dir().join("millgate-cache")
    }
}

/// The maps of `key` from `dir`: `Ok(None)` when there is no file or it holds other
/// maps (another key).
pub(crate) fn load(dir: &Path, key: &str) -> Result<Option<GapMaps>, CacheError> {
    let file = path(dir, key);
    let text = match std::fs::read_to_string(&file) {
        Ok(text) => text,
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => {
            return Err(CacheError::Io {
                path: file.display().to_string(),
                source,
            })
        }
    };
    let stored: CacheFile = serde_json::from_str(&text).map_err(|error| CacheError::Format {
        path: file.display().to_string(),
        message: error.to_string(),
    })?;
    Ok((stored.key == key).then(|| GapMaps::new(stored.maps)))
}

/// Stores `maps` under `key` in `dir` (created when missing); returns the file.
pub(crate) fn save(dir: &Path, key: &str, maps: &GapMaps) -> Result<PathBuf, CacheError> {
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |source| CacheError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let file = path(dir, key);
    let text = serde_json::to_string(&CacheFile {
        key: key.to_owned(),
        maps: maps.data().clone(),
    })
    .map_err(|error| CacheError::Format {
        path: file.display().to_string(),
        message: error.to_string(),
    })?;
    // A name of its own per writer: two gateways (or tests) may store the same maps.
    static WRITES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let write = WRITES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let temporary = file.with_extension(format!("json.{}-{write}.tmp", std::process::id()));
    std::fs::write(&temporary, text).map_err(io(&temporary))?;
    std::fs::rename(&temporary, &file).map_err(io(&file))?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_name_hash_is_fnv1a_64() {
        // Reference values of the FNV-1a 64-bit hash (Fowler, Noll, Vo test vectors).
        assert_eq!(fnv1a(""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a("a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a("foobar"), 0x8594_4171_f739_67e8);
        assert_eq!(
            path(Path::new("/c"), "a"),
            PathBuf::from("/c/gap-maps-af63dc4c8601ec8c.json")
        );
    }
}
