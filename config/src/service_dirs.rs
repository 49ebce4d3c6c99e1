//! The folders a service manager hands the gateway: systemd's `StateDirectory=`,
//! `CacheDirectory=` and `LoadCredential=` (`$STATE_DIRECTORY`, `$CACHE_DIRECTORY`,
//! `$CREDENTIALS_DIRECTORY`).

use std::ffi::OsString;
use std::path::PathBuf;

/// Folders systemd sets up for the unit, each `None` when its variable is not set
/// (outside systemd, or a unit without the setting).
///
/// What they change (see `config/README.md`, "Under systemd"):
/// - a relative `history.path` is resolved against `state` rather than the
///   configuration file's folder;
/// - `cache_dir` defaults to `cache`, and a relative one is resolved against it;
/// - `outputs.mqtt.password_credential` names a file in `credentials`.
///
/// ```
/// use millgate_config::ServiceDirs;
/// let dirs = ServiceDirs::from_vars(|name| match name {
///     "STATE_DIRECTORY" => Some("/var/lib/millgate:/var/lib/other".into()),
///     _ => None,
/// });
/// assert_eq!(dirs.state, Some("/var/lib/millgate".into()));
/// assert_eq!(dirs.cache, None);
/// ```
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ServiceDirs {
    /// `$STATE_DIRECTORY` (`StateDirectory=`): where the history file goes.
    pub state: Option<PathBuf>,
    /// `$CACHE_DIRECTORY` (`CacheDirectory=`): where the gap maps are cached.
    pub cache: Option<PathBuf>,
    /// `$CREDENTIALS_DIRECTORY` (`LoadCredential=`): the unit's secrets, one file each.
    pub credentials: Option<PathBuf>,
}

/// The variable systemd sets for `StateDirectory=`.
pub const STATE_DIRECTORY: &str = "STATE_DIRECTORY";
/// The variable systemd sets for `CacheDirectory=`.
pub const CACHE_DIRECTORY: &str = "CACHE_DIRECTORY";
/// The variable systemd sets for `LoadCredential=`.
pub const CREDENTIALS_DIRECTORY: &str = "CREDENTIALS_DIRECTORY";

impl ServiceDirs {
    /// The folders from this process's environment.
    pub(crate) fn from_env() -> Self {
        Self::from_vars(|name| std::env::var_os(name))
    }

    /// The folders from `lookup` (an environment by variable name). systemd joins
    /// several folders of one setting with `:`; the first is taken. An empty
    /// variable counts as not set.
    pub fn from_vars(lookup: impl Fn(&str) -> Option<OsString>) -> Self {
        let folder = |name: &str| {
            let value = lookup(name)?;
            let first = value.to_str().map_or_else(
                || PathBuf::from(&value),
                |text| PathBuf::from(text.split(':').next().unwrap_or_default()),
            );
            (!first.as_os_str().is_empty()).then_some(first)
        };
        ServiceDirs {
            state: folder(STATE_DIRECTORY),
            cache: folder(CACHE_DIRECTORY),
            credentials: folder(CREDENTIALS_DIRECTORY),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn takes_the_first_folder_and_ignores_empty_variables() {
        let dirs = ServiceDirs::from_vars(|name| match name {
            "STATE_DIRECTORY" => Some("".into()),
            "CACHE_DIRECTORY" => Some("/var/cache/millgate:/var/cache/b".into()),
            "CREDENTIALS_DIRECTORY" => Some("/run/credentials/millgate.service".into()),
            _ => None,
        });
        assert_eq!(
            dirs,
            ServiceDirs {
                state: None,
                cache: Some("/var/cache/millgate".into()),
                credentials: Some("/run/credentials/millgate.service".into()),
            }
        );
        assert_eq!(ServiceDirs::from_vars(|_| None), ServiceDirs::default());
    }
}
