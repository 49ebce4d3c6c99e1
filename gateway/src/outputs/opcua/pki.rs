//! The server's certificate store in `pki_dir`: the folders, and the application
//! instance certificate and key, created at the first start and kept after.
//!
//! Layout (async-opcua's): `own/cert.der` (the server's certificate, DER),
//! `private/private.pem` (its RSA key, PKCS#8, mode 0600), `trusted/` (client
//! certificates accepted), `rejected/` (client certificates refused: a certificate
//! moved from here to `trusted/` is accepted at its next connection).

use std::path::{Path, PathBuf};

use opcua::crypto::{CertificateStore, X509Data};

use super::error::OpcUaError;

/// RSA key size of the server's certificate, bits (Basic256Sha256 allows 2048..=4096).
const KEY_BITS: u32 = 2048;
/// Validity of a created certificate, days (five years).
const CERTIFICATE_DAYS: u32 = 5 * 365;

/// What [`prepare`] found or did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Prepared {
    /// The certificate and key were there.
    Found,
    /// A new certificate and key were created (its file).
    Created(PathBuf),
}

/// Make the store's folders and, when there is none yet, the server's certificate
/// (for `application_uri`, the endpoint `host`, `localhost` and the machine's name) and
/// its key. An existing certificate is kept (clients trust it); one that names another
/// application URI or has expired is logged.
pub(crate) fn prepare(
    pki_dir: &Path,
    application_uri: &str,
    host: &str,
) -> Result<Prepared, OpcUaError> {
    let failure = |why: String| OpcUaError::Pki {
        path: pki_dir.to_path_buf(),
        why,
    };
    let store = CertificateStore::new(pki_dir);
    store.ensure_pki_path().map_err(failure)?;
    let (cert_path, key_path) = (store.own_certificate_path(), store.own_private_key_path());
    match (cert_path.exists(), key_path.exists()) {
        (true, true) => {
            let cert = store.read_own_cert().map_err(failure)?;
            store.read_own_pkey().map_err(failure)?;
            if cert.is_application_uri_valid(application_uri).is_err() {
                tracing::warn!(
                    certificate = %cert_path.display(),
                    application_uri,
                    "the OPC UA server certificate names another application URI (the \
                     configuration's name or host changed): clients may refuse it; remove \
                     own/cert.der and private/private.pem to create a new one"
                );
            }
            if cert
                .is_time_valid(&opcua::types::DateTime::now().as_chrono())
                .is_err()
            {
                tracing::warn!(certificate = %cert_path.display(), "the OPC UA server certificate is not valid now (expired?): remove own/cert.der and private/private.pem to create a new one");
            }
            Ok(Prepared::Found)
        }
        (false, false) => {
            let data = X509Data {
                key_size: KEY_BITS,
                common_name: format!("millgate {host}"),
                organization: "millgate".into(),
                organizational_unit: String::new(),
                country: String::new(),
                state: String::new(),
                alt_host_names: X509Data::alt_host_names(
                    application_uri,
                    Some(vec![host.to_owned()]),
                    true,
                    true,
                    false,
                ),
                certificate_duration_days: CERTIFICATE_DAYS,
            };
            store
                .create_and_store_application_instance_cert(&data, false)
                .map_err(failure)?;
            restrict(&key_path).map_err(|error| failure(error.to_string()))?;
            tracing::info!(certificate = %cert_path.display(), "created the OPC UA server certificate");
            Ok(Prepared::Created(cert_path))
        }
        (cert, _) => {
            let (present, missing) = if cert {
                (&cert_path, &key_path)
            } else {
                (&key_path, &cert_path)
            };
            Err(failure(format!(
                "{} exists but {} does not: restore it, or remove both to create a new \
                 certificate (clients must then trust the new one)",
                present.display(),
                missing.display()
            )))
        }
    }
}

/// The key readable by its owner only, its folder too.
fn restrict(key_path: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(key_path, std::fs::Permissions::from_mode(0o600))?;
    if let Some(folder) = key_path.parent() {
        std::fs::set_permissions(folder, std::fs::Permissions::from_mode(0o700))?;
    }
    Ok(())
}

/// Refused client certificates kept in `rejected/` (the newest; about 1 kB each):
/// any client can add one, with no credentials (round-4 audit, finding 6).
pub(crate) const MAX_REJECTED: usize = 64;

/// Remove the oldest files of `pki_dir/rejected/` (by modification time, then name)
/// beyond `keep`; the number removed.
pub(crate) fn trim_rejected(pki_dir: &Path, keep: usize) -> std::io::Result<usize> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(pki_dir.join("rejected"))? {
        let entry = entry?;
        let metadata = entry.metadata()?;
        if metadata.is_file() {
            files.push((metadata.modified()?, entry.path()));
        }
    }
    if files.len() <= keep {
        return Ok(0);
    }
    files.sort();
    let extra = files.len() - keep;
    for (_, path) in &files[..extra] {
        std::fs::remove_file(path)?;
    }
    Ok(extra)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trimming_keeps_the_newest_rejected() {
        let folder = std::env::temp_dir().join(format!("millgate-trim-{}", std::process::id()));
        let rejected = folder.join("rejected");
        std::fs::create_dir_all(&rejected).unwrap();
        let start = std::time::SystemTime::now() - std::time::Duration::from_secs(100);
        for i in 0..10u64 {
            let path = rejected.join(format!("client {i}.der"));
            std::fs::write(&path, [0u8; 8]).unwrap();
            let file = std::fs::File::options().write(true).open(&path).unwrap();
            file.set_modified(start + std::time::Duration::from_secs(i))
                .unwrap();
        }
        assert_eq!(trim_rejected(&folder, 4).unwrap(), 6);
        let mut left: Vec<_> = std::fs::read_dir(&rejected)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        assert_eq!(
            left,
            [
                "client 6.der",
                "client 7.der",
                "client 8.der",
                "client 9.der"
            ]
        );
        assert_eq!(trim_rejected(&folder, 4).unwrap(), 0);
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
