//! TLS to the broker (`mqtts://`): rustls with ring, the broker's
//! certificate checked against `[mqtt] ca_file` (a site's own CA) or the
//! system's root certificates, and a client certificate when given.

use std::path::Path;
use std::sync::Arc;

use rumqttc::{TlsConfiguration, Transport};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{ClientConfig, RootCertStore};

use super::MqttError;
use crate::server::settings::MqttConfig;

/// The TLS transport `config` asks for.
pub(super) fn transport(config: &MqttConfig) -> Result<Transport, MqttError> {
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| MqttError::Settings(format!("TLS: {e}")))?
        .with_root_certificates(roots(config.ca_file.as_deref())?);
    let client = match (&config.client_cert_file, &config.client_key_file) {
        (Some(cert), Some(key)) => {
            let key_file = |reason: String| MqttError::File {
                what: "client_key_file",
                path: key.display().to_string(),
                reason,
            };
            let key = PrivateKeyDer::from_pem_file(key).map_err(|e| key_file(e.to_string()))?;
            builder
                .with_client_auth_cert(certificates("client_cert_file", cert)?, key)
                .map_err(|e| key_file(e.to_string()))?
        }
        (None, None) => builder.with_no_client_auth(),
        _ => {
            return Err(MqttError::Settings(
                "mqtt.client_cert_file and mqtt.client_key_file go together".into(),
            ));
        }
    };
    Ok(Transport::tls_with_config(TlsConfiguration::Rustls(
        Arc::new(client),
    )))
}

/// The certificates the broker's is checked against.
fn roots(ca_file: Option<&Path>) -> Result<RootCertStore, MqttError> {
    let mut roots = RootCertStore::empty();
    match ca_file {
        Some(path) => {
            for certificate in certificates("ca_file", path)? {
                roots.add(certificate).map_err(|e| MqttError::File {
                    what: "ca_file",
                    path: path.display().to_string(),
                    reason: e.to_string(),
                })?;
            }
        }
        None => {
            let found = rustls_native_certs::load_native_certs();
            let (added, _) = roots.add_parsable_certificates(found.certs);
            if added == 0 {
                let errors: Vec<String> = found.errors.iter().map(|e| e.to_string()).collect();
                return Err(MqttError::Settings(format!(
                    "TLS: no root certificate found on this system ({}); \
                     name the broker's CA in mqtt.ca_file",
                    if errors.is_empty() {
                        "none installed".to_string()
                    } else {
                        errors.join("; ")
                    }
                )));
            }
        }
    }
    Ok(roots)
}

/// Every certificate of a PEM file; at least one.
fn certificates(
    what: &'static str,
    path: &Path,
) -> Result<Vec<CertificateDer<'static>>, MqttError> {
    let file_error = |reason: String| MqttError::File {
        what,
        path: path.display().to_string(),
        reason,
    };
    let certificates = CertificateDer::pem_file_iter(path)
        .map_err(|e| file_error(e.to_string()))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| file_error(e.to_string()))?;
    if certificates.is_empty() {
        return Err(file_error("no PEM certificate in it".into()));
    }
    Ok(certificates)
}
