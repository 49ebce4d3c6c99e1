//! TLS to the broker: a rustls client configuration from `[outputs.mqtt.tls]`, with
//! the `ring` crypto provider (rustls' default, aws-lc-rs, needs cmake and builds
//! slowly; rumqttc is built without a provider chosen).

use std::sync::Arc;

use millgate_config::{MqttTls, TlsFileError};
use rustls::{ClientConfig, RootCertStore};

/// Why the TLS configuration cannot be built; names the key and the file.
#[derive(Debug, thiserror::Error)]
pub enum TlsSetupError {
    /// A file cannot be read or is not PEM.
    #[error(transparent)]
    File(#[from] TlsFileError),
    /// A certificate of `ca_file` is not one rustls accepts as a trust anchor.
    #[error("{key}.ca_file: {path}: not a usable CA certificate: {source}")]
    Ca {
        /// The table's key (`outputs.mqtt.tls`, `outputs.mqtt.brokers[1].tls`).
        key: String,
        /// The file.
        path: String,
        /// Why (boxed: the error stays small).
        source: Box<rustls::Error>,
    },
    /// The ring provider refuses the default protocol versions (not expected).
    #[error("the TLS provider (ring): {0}")]
    Provider(rustls::Error),
    /// The client certificate and key are not usable together (for example the key
    /// is not the certificate's).
    #[error("{table}.key_file: {key} with cert_file {cert}: {source}")]
    ClientAuth {
        /// The table's key (`outputs.mqtt.tls`, `outputs.mqtt.brokers[1].tls`).
        table: String,
        /// The certificate file.
        cert: String,
        /// The key file.
        key: String,
        /// Why (boxed: the error stays small).
        source: Box<rustls::Error>,
    },
}

/// The client configuration of `tls`: the broker is checked against `ca_file` (and
/// its name or IP address against the broker address); with `cert_file`/`key_file`,
/// the gateway also presents its certificate.
pub(crate) fn client_config(tls: &MqttTls) -> Result<Arc<ClientConfig>, TlsSetupError> {
    let material = tls.read()?;
    let mut roots = RootCertStore::empty();
    for certificate in material.ca {
        roots.add(certificate).map_err(|source| TlsSetupError::Ca {
            key: tls.key.clone(),
            path: tls.ca_file.display().to_string(),
            source: Box::new(source),
        })?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(TlsSetupError::Provider)?
        .with_root_certificates(roots);
    let config = match (material.client, &tls.client) {
        (Some((chain, key)), Some((cert_file, key_file))) => builder
            .with_client_auth_cert(chain, key)
            .map_err(|source| TlsSetupError::ClientAuth {
                table: tls.key.clone(),
                cert: cert_file.display().to_string(),
                key: key_file.display().to_string(),
                source: Box::new(source),
            })?,
        _ => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}
