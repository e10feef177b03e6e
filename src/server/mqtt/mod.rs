//! MQTT: tunnelnav as a client of the site's broker (`serve --mqtt URL`).
//!
//! Field gateways publish readings to `tunnelnav/v1/{machine}/readings` at
//! QoS 1; a message's body is what `POST .../readings` takes (an object, an
//! array or NDJSON). tunnelnav subscribes with a persistent session and
//! acknowledges (PUBACK) a message only once its readings are committed, so
//! a message it had not stored when it crashed is delivered again by the
//! broker; a redelivered one is absorbed as a duplicate, as over HTTP. The
//! answer of `POST` (accepted, duplicates, rejected by index; or the
//! error) is published to `tunnelnav/v1/{machine}/acks`. An unknown
//! machine or a body that is not readings is answered there and
//! acknowledged (a broker redelivering it would loop); a refusal to retry
//! (the machine's queue or the store full: the 503s of HTTP) is retried
//! here and acknowledged when it succeeds, never dropped.
//!
//! Each machine's messages are handled in order by a task of its own
//! (`readings`), so a busy machine does not hold up the others. Out
//! (`publish`): each machine's estimates (at most 10 a second per stream),
//! its status (retained) and its alarms (retained while raised).
//! docs/operations.md ("MQTT").

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use rumqttc::{AsyncClient, Event, EventLoop, MqttOptions, Packet, Publish, QoS};
use tokio::sync::mpsc;

use super::metrics;
use crate::server::settings::MqttConfig;
use crate::server::state::SharedState;

mod publish;
mod readings;
mod tls;

use readings::{machine_of, serve_machine};

/// Readings in: `tunnelnav/v1/{machine}/readings`.
pub const READINGS_TOPICS: &str = "tunnelnav/v1/+/readings";
/// The client id when the URL names none: one per server, so that its
/// session (and what it has not acknowledged) outlives a restart.
pub const DEFAULT_CLIENT_ID: &str = "tunnelnav";
/// Messages waiting for one machine's task before the broker's connection
/// is made to wait (the broker's in-flight window is far smaller).
const MACHINE_INBOX: usize = 1024;
/// The longest wait between attempts to reach the broker.
const MAX_RECONNECT_WAIT: Duration = Duration::from_secs(30);

/// Why the MQTT settings cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum MqttError {
    #[error("MQTT broker URL `{url}`: {reason}")]
    Url { url: String, reason: String },
    #[error("MQTT: {what} {path}: {reason}")]
    File {
        what: &'static str,
        path: String,
        reason: String,
    },
    #[error("MQTT: {0}")]
    Settings(String),
}

/// How tunnelnav reaches the broker, and what it publishes how often.
#[derive(Clone)]
pub struct MqttSettings {
    /// The connection: address, session, credentials, TLS.
    pub options: MqttOptions,
    /// The newest estimate of each stream is published this often.
    pub estimates_every: Duration,
}

/// The settings for broker `url` (`mqtt://[user:password@]host[:port]`, or
/// `mqtts://` for TLS; optional `?client_id=` (default `tunnelnav`),
/// `keep_alive_secs=` and `clean_session=` (default false: a persistent
/// session)), with what `[mqtt]` adds: a user and password file, the CA
/// of a site's own broker certificate, a client certificate, the rate.
pub fn settings(url: &str, config: &MqttConfig) -> Result<MqttSettings, MqttError> {
    let refuse = |reason: String| MqttError::Url {
        url: redacted(url),
        reason,
    };
    let mut parsed = url::Url::parse(url).map_err(|e| refuse(e.to_string()))?;
    let tls = match parsed.scheme() {
        "mqtt" | "tcp" => false,
        "mqtts" | "ssl" => true,
        other => {
            return Err(refuse(format!(
                "scheme `{other}`: use mqtt:// or mqtts:// (TLS)"
            )));
        }
    };
    if !tls {
        for (given, key) in [
            (&config.ca_file, "ca_file"),
            (&config.client_cert_file, "client_cert_file"),
            (&config.client_key_file, "client_key_file"),
        ] {
            if given.is_some() {
                return Err(refuse(format!(
                    "mqtt.{key} is for TLS: use mqtts:// (or drop mqtt.{key})"
                )));
            }
        }
    }
    if !parsed.username().is_empty() && config.username.is_some() {
        return Err(refuse(
            "a user in the URL and mqtt.username: name it once".into(),
        ));
    }
    if parsed.password().is_some() && config.password_file.is_some() {
        return Err(refuse(
            "a password in the URL and mqtt.password_file: give it once".into(),
        ));
    }
    let has = |key: &str| parsed.query_pairs().any(|(k, _)| k == key);
    let (client_id, clean_session) = (has("client_id"), has("clean_session"));
    {
        let mut query = parsed.query_pairs_mut();
        if !client_id {
            query.append_pair("client_id", DEFAULT_CLIENT_ID);
        }
        if !clean_session {
            query.append_pair("clean_session", "false");
        }
    }
    // The transport is set below: rumqttc's own TLS default panics on a
    // machine without readable root certificates.
    if tls {
        parsed
            .set_scheme("mqtt")
            .map_err(|()| refuse("cannot read the scheme".into()))?;
        if parsed.port().is_none() {
            let _ = parsed.set_port(Some(8883));
        }
    }
    let mut options = MqttOptions::parse_url(parsed.as_str()).map_err(|e| refuse(e.to_string()))?;
    options.set_manual_acks(true);
    if let Some(user) = &config.username {
        let password = match &config.password_file {
            Some(path) => password(path)?,
            None => String::new(),
        };
        options.set_credentials(user.clone(), password);
    } else if let Some(path) = &config.password_file {
        let user = parsed.username();
        if user.is_empty() {
            return Err(refuse(
                "mqtt.password_file without a user: set mqtt.username".into(),
            ));
        }
        options.set_credentials(user.to_string(), password(path)?);
    }
    if tls {
        options.set_transport(tls::transport(config)?);
    }
    let estimates_every = config
        .estimates_every()
        .map_err(|e| MqttError::Settings(e.to_string()))?;
    Ok(MqttSettings {
        options,
        estimates_every,
    })
}

/// The first line of a password file.
fn password(path: &std::path::Path) -> Result<String, MqttError> {
    let text = std::fs::read_to_string(path).map_err(|e| MqttError::File {
        what: "password_file",
        path: path.display().to_string(),
        reason: e.to_string(),
    })?;
    Ok(text.lines().next().unwrap_or_default().to_string())
}

/// `url` without its password, for messages and logs.
pub fn redacted(url: &str) -> String {
    match url::Url::parse(url) {
        Ok(mut parsed) if parsed.password().is_some() => {
            let _ = parsed.set_password(Some("***"));
            parsed.to_string()
        }
        _ => url.to_string(),
    }
}

/// Connects to the broker and serves it until the server stops: a task
/// that reconnects for ever (waiting up to 30 s between attempts).
pub fn spawn(state: SharedState, settings: MqttSettings) -> tokio::task::JoinHandle<()> {
    let MqttSettings {
        mut options,
        estimates_every,
    } = settings;
    // A message may be as large as a request body; an answer listing
    // many refused readings may be large too.
    options.set_max_packet_size(state.limits.max_body_bytes, state.limits.max_body_bytes);
    let (client, eventloop) = AsyncClient::new(options, 4096);
    let connected = Connected::default();
    tokio::spawn(publish::machines(
        state.clone(),
        client.clone(),
        connected.clone(),
        estimates_every,
    ));
    tokio::spawn(publish::alarms(state.clone(), client.clone()));
    tokio::spawn(serve(state, client, eventloop, connected))
}

/// Whether the broker is connected now: estimates and status are not
/// queued for it while it is away (they would go stale in the queue).
#[derive(Clone, Default)]
pub(super) struct Connected(Arc<AtomicBool>);

impl Connected {
    fn set(&self, connected: bool) {
        self.0.store(connected, Ordering::Relaxed);
        metrics::mqtt_connected(connected);
    }

    /// The broker is connected.
    pub(super) fn now(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

async fn serve(
    state: SharedState,
    client: AsyncClient,
    mut eventloop: EventLoop,
    connected: Connected,
) {
    let mut shutdown = state.shutdown_signal();
    let mut machines: HashMap<String, mpsc::Sender<Publish>> = HashMap::new();
    let mut wait = Duration::from_millis(500);
    loop {
        let event = tokio::select! {
            event = eventloop.poll() => event,
            _ = shutdown.changed() => break,
        };
        match event {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                tracing::info!("MQTT: connected to the broker");
                connected.set(true);
                wait = Duration::from_millis(500);
                // Kept by a persistent session, but a new one has none.
                if let Err(e) = client.try_subscribe(READINGS_TOPICS, QoS::AtLeastOnce) {
                    tracing::error!(error = %e, "MQTT: cannot subscribe");
                }
            }
            Ok(Event::Incoming(Packet::Publish(publish))) => {
                metrics::mqtt_message("received");
                let Some(machine) = machine_of(&publish.topic) else {
                    // Only the subscribed filter arrives; ack anything else.
                    let _ = client.try_ack(&publish);
                    continue;
                };
                let machine = machine.to_string();
                let mut publish = publish;
                // A machine's task that has ended (its acknowledgement
                // failed) is replaced, and takes the message.
                while !*shutdown.borrow() {
                    let inbox = machines.entry(machine.clone()).or_insert_with(|| {
                        let (sender, inbox) = mpsc::channel(MACHINE_INBOX);
                        tokio::spawn(serve_machine(
                            state.clone(),
                            client.clone(),
                            machine.clone(),
                            inbox,
                        ));
                        sender
                    });
                    // Full: the broker waits (its connection is not read).
                    match inbox.send(publish).await {
                        Ok(()) => break,
                        Err(mpsc::error::SendError(back)) => {
                            machines.remove(&machine);
                            publish = back;
                        }
                    }
                }
            }
            Ok(_) => {}
            Err(e) => {
                connected.set(false);
                metrics::mqtt_reconnect();
                tracing::warn!(error = %e, retry_in_s = wait.as_secs_f64(), "MQTT: broker unreachable");
                tokio::select! {
                    _ = tokio::time::sleep(wait) => {}
                    _ = shutdown.changed() => break,
                }
                wait = (wait * 2).min(MAX_RECONNECT_WAIT);
            }
        }
    }
    connected.set(false);
    // What was not acknowledged stays with the broker for the next start.
    let _ = client.try_disconnect();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(url: &str) -> Result<MqttOptions, MqttError> {
        settings(url, &MqttConfig::default()).map(|s| s.options)
    }

    #[test]
    fn a_url_gets_a_persistent_session_and_manual_acks() {
        let site = options("mqtt://gw:secret@broker.site:1884").unwrap();
        assert_eq!(site.broker_address(), ("broker.site".to_string(), 1884));
        assert_eq!(site.client_id(), "tunnelnav");
        assert!(!site.clean_session());
        assert!(site.manual_acks());
        let login = site.credentials().unwrap();
        assert_eq!(
            (login.username.as_str(), login.password.as_str()),
            ("gw", "secret")
        );
        let named = options("mqtt://broker?client_id=tn-north&clean_session=true").unwrap();
        assert_eq!(named.client_id(), "tn-north");
        assert!(named.clean_session());
        let error = options("http://gw:secret@broker").unwrap_err().to_string();
        assert!(error.contains("use mqtt:// or mqtts://"), "{error}");
        assert!(!error.contains("secret"), "{error}");
        let error = options("mqtt://broker?colour=red").unwrap_err().to_string();
        assert!(error.contains("colour"), "{error}");
    }

    #[test]
    fn the_config_file_adds_a_user_a_password_file_and_a_rate() {
        let dir = tempfile::tempdir().unwrap();
        let secret = dir.path().join("mqtt-password");
        std::fs::write(&secret, "s3cret\n").unwrap();
        let config = MqttConfig {
            username: Some("tunnelnav".into()),
            password_file: Some(secret.clone()),
            estimates_hz: Some(4.0),
            ..MqttConfig::default()
        };
        let site = settings("mqtt://broker.site", &config).unwrap();
        let login = site.options.credentials().unwrap();
        assert_eq!(
            (login.username.as_str(), login.password.as_str()),
            ("tunnelnav", "s3cret")
        );
        assert_eq!(site.estimates_every, Duration::from_millis(250));
        assert_eq!(site.options.broker_address().1, 1883);
        // The URL's user with the file's password.
        let file_only = MqttConfig {
            password_file: Some(secret.clone()),
            ..MqttConfig::default()
        };
        let login = settings_login("mqtt://gw@broker", &file_only);
        assert_eq!(login, ("gw".to_string(), "s3cret".to_string()));
        // Given twice, or a file without a user: refused, naming why.
        let error =
            |url: &str, config: &MqttConfig| settings(url, config).err().unwrap().to_string();
        assert!(error("mqtt://gw@broker", &config).contains("name it once"));
        assert!(error("mqtt://broker", &file_only).contains("mqtt.username"));
        let missing = MqttConfig {
            username: Some("tunnelnav".into()),
            password_file: Some(dir.path().join("absent")),
            ..MqttConfig::default()
        };
        let message = error("mqtt://broker", &missing);
        assert!(
            message.contains("password_file") && message.contains("absent"),
            "{message}"
        );
    }

    fn settings_login(url: &str, config: &MqttConfig) -> (String, String) {
        let login = settings(url, config)
            .unwrap()
            .options
            .credentials()
            .unwrap();
        (login.username, login.password)
    }

    #[test]
    fn tls_takes_a_site_ca_and_refuses_what_does_not_fit() {
        let dir = tempfile::tempdir().unwrap();
        let error =
            |url: &str, config: &MqttConfig| settings(url, config).err().unwrap().to_string();
        // Certificates are for mqtts:// only.
        let with_ca = |path: std::path::PathBuf| MqttConfig {
            ca_file: Some(path),
            ..MqttConfig::default()
        };
        let message = error("mqtt://broker", &with_ca(dir.path().join("ca.pem")));
        assert!(message.contains("use mqtts://"), "{message}");
        // A CA file that is missing, or holds no certificate.
        let message = error("mqtts://broker", &with_ca(dir.path().join("ca.pem")));
        assert!(
            message.contains("ca_file") && message.contains("ca.pem"),
            "{message}"
        );
        let empty = dir.path().join("empty.pem");
        std::fs::write(&empty, "not a certificate\n").unwrap();
        let message = error("mqtts://broker", &with_ca(empty));
        assert!(message.contains("no PEM certificate"), "{message}");
        // A client certificate without its key.
        let half = MqttConfig {
            client_cert_file: Some(dir.path().join("client.pem")),
            ..MqttConfig::default()
        };
        let message = error("mqtts://broker", &half);
        assert!(message.contains("go together"), "{message}");
    }
}
