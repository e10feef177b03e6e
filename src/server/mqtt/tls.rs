//! TLS to the broker (`mqtts://`): rustls with ring, the broker's
//! certificate checked against `[mqtt] ca_file` (a site's own CA) or the
//! system's root certificates, and a client certificate when given.

use std::path::Path;
use std::sync::Arc;

use rumqttc::{TlsConfiguration, Transport};
use rustls::pki_types::PrivateKeyDer;
use rustls::pki_types::pem::PemObject;

use crate::tls::TlsSetupError;

use super::MqttError;
use crate::server::settings::MqttConfig;

/// The TLS transport `config` asks for.
pub(super) fn transport(config: &MqttConfig) -> Result<Transport, MqttError> {
    let builder = crate::tls::builder()
        .map_err(mqtt_error)?
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
fn roots(ca_file: Option<&Path>) -> Result<rustls::RootCertStore, MqttError> {
    crate::tls::roots(ca_file).map_err(mqtt_error)
}

/// Every certificate of a PEM file; at least one.
fn certificates(
    what: &'static str,
    path: &Path,
) -> Result<Vec<rustls::pki_types::CertificateDer<'static>>, MqttError> {
    crate::tls::certificates(what, path).map_err(mqtt_error)
}

/// A TLS set-up error as the MQTT settings name it.
fn mqtt_error(e: TlsSetupError) -> MqttError {
    match e {
        TlsSetupError::File { what, path, reason } => MqttError::File { what, path, reason },
        TlsSetupError::NoRoots(why) => MqttError::Settings(format!(
            "TLS: no root certificate found on this system ({why}); \
             name the broker's CA in mqtt.ca_file"
        )),
        TlsSetupError::Config(why) => MqttError::Settings(format!("TLS: {why}")),
    }
}
