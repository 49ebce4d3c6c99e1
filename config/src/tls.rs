//! The PEM files of `[outputs.mqtt.tls]`: read at configuration load (so a bad file
//! is reported with the other problems) and again when the edge node starts.

use std::fmt;
use std::path::{Path, PathBuf};

use rustls_pki_types::pem::{self, PemObject};
use rustls_pki_types::{CertificateDer, PrivateKeyDer};

use crate::MqttTls;

/// The certificates and key of [`MqttTls`], decoded from PEM.
#[derive(Debug)]
pub struct TlsMaterial {
    /// The certificate authorities trusted for the broker (at least one).
    pub ca: Vec<CertificateDer<'static>>,
    /// The client certificate chain (at least one) and its private key.
    pub client: Option<(Vec<CertificateDer<'static>>, PrivateKeyDer<'static>)>,
}

/// A TLS file that cannot be used: its key (`ca_file`, `cert_file` or `key_file`),
/// its path and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFileError {
    /// The key under `[outputs.mqtt.tls]`.
    pub(crate) key: &'static str,
    /// The file, as resolved against the configuration file's folder.
    pub(crate) path: PathBuf,
    /// Why, one line.
    pub(crate) why: String,
}

impl fmt::Display for TlsFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "outputs.mqtt.tls.{}: {}: {}",
            self.key,
            self.path.display(),
            self.why
        )
    }
}

impl std::error::Error for TlsFileError {}

impl MqttTls {
    /// Reads and decodes the files.
    pub fn read(&self) -> Result<TlsMaterial, TlsFileError> {
        let ca = certificates("ca_file", &self.ca_file)?;
        let client = match &self.client {
            Some((cert, key)) => Some((certificates("cert_file", cert)?, private_key(key)?)),
            None => None,
        };
        Ok(TlsMaterial { ca, client })
    }
}

/// Every `CERTIFICATE` section of the PEM file at `path` (at least one).
fn certificates(
    key: &'static str,
    path: &Path,
) -> Result<Vec<CertificateDer<'static>>, TlsFileError> {
    let error = |why: String| TlsFileError {
        key,
        path: path.to_path_buf(),
        why,
    };
    let certificates = CertificateDer::pem_file_iter(path)
        .map_err(|e| error(why(&e)))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| error(why(&e)))?;
    if certificates.is_empty() {
        return Err(error(
            "no certificate in the file (must be PEM with -----BEGIN CERTIFICATE-----)".into(),
        ));
    }
    Ok(certificates)
}

/// The first private key of the PEM file at `path`.
fn private_key(path: &Path) -> Result<PrivateKeyDer<'static>, TlsFileError> {
    PrivateKeyDer::from_pem_file(path).map_err(|e| TlsFileError {
        key: "key_file",
        path: path.to_path_buf(),
        why: match e {
            pem::Error::NoItemsFound => "no private key in the file (must be PEM: \
                 -----BEGIN PRIVATE KEY-----, RSA PRIVATE KEY or EC PRIVATE KEY)"
                .into(),
            other => why(&other),
        },
    })
}

/// One line for a PEM reading error.
fn why(error: &pem::Error) -> String {
    match error {
        pem::Error::Io(io) => format!("cannot read: {io}"),
        pem::Error::NoItemsFound => "nothing found".into(),
        other => format!("not a valid PEM file ({other})"),
    }
}
