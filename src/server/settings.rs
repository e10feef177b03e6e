//! The server's settings: its limits, the MQTT broker and the alarm
//! webhooks, as the config file (`serve --config`) sets them, and the file
//! itself, which also declares machines ([`crate::config`]).
//!
//! Every number of `[limits]`, `[mqtt]` and `[webhooks]` is one row of
//! [`SETTINGS`]: its section and name in the file, unit, default and range.
//! The defaults of [`Limits`], [`MqttConfig`] and [`WebhookConfig`] are
//! taken from it, every value read is checked against it, and
//! docs/operations.md shows it (a test checks the copy).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use crate::config::{ConfigError, MachineDeclaration, MachineSpec};

/// Which values of a setting's range are allowed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bounds {
    /// Any real number within [min, max].
    Closed,
    /// Any real number above min, at most max.
    AboveMin,
    /// A whole number within [min, max].
    Whole,
}

/// One number of the config file's server sections.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setting {
    /// `[section]` of the file.
    pub section: &'static str,
    /// Its key within the section.
    pub name: &'static str,
    /// Unit of the value in the file (`MB`, `s`, `Hz`, or empty for a count).
    pub unit: &'static str,
    /// The value when the file does not set it; `None`: no limit.
    pub default: Option<f64>,
    /// Smallest and largest value allowed (see `bounds`).
    pub min: f64,
    pub max: f64,
    pub bounds: Bounds,
}

/// A setting refused, naming it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SettingsError {
    /// A number outside its range.
    #[error("{section}.{name} must be {rule}, not {value}")]
    Range {
        section: &'static str,
        name: &'static str,
        /// What is allowed, as [`Setting::rule`] says it.
        rule: String,
        value: f64,
    },
    /// A webhook URL this build cannot post to.
    #[error("webhooks.{severity}: `{url}` is not an http:// URL ({reason})")]
    Url {
        severity: &'static str,
        url: String,
        reason: String,
    },
}

impl Setting {
    /// What is allowed, in words (`between 1 and 15 s`).
    pub fn rule(&self) -> String {
        let (min, max) = (self.min, self.max);
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        match self.bounds {
            Bounds::Closed => format!("between {min} and {max}{unit}"),
            Bounds::AboveMin => format!("above {min} and at most {max}{unit}"),
            Bounds::Whole => format!("a whole number between {min} and {max}"),
        }
    }

    /// `value` if it is allowed, else why not.
    pub fn check(&self, value: f64) -> Result<f64, SettingsError> {
        let allowed = value.is_finite()
            && value <= self.max
            && match self.bounds {
                Bounds::Closed => value >= self.min,
                Bounds::AboveMin => value > self.min,
                Bounds::Whole => value >= self.min && value.fract() == 0.0,
            };
        if allowed {
            return Ok(value);
        }
        Err(SettingsError::Range {
            section: self.section,
            name: self.name,
            rule: self.rule(),
            value,
        })
    }

    /// The default of a setting that has one (a table row without one is
    /// a programming error, caught by the defaults' unit test).
    const fn fixed(&self) -> f64 {
        match self.default {
            Some(v) => v,
            None => panic!("a setting without a default"),
        }
    }
}

const fn setting(
    section: &'static str,
    name: &'static str,
    unit: &'static str,
    default: Option<f64>,
    (min, max): (f64, f64),
    bounds: Bounds,
) -> Setting {
    Setting {
        section,
        name,
        unit,
        default,
        min,
        max,
        bounds,
    }
}

use Bounds::{AboveMin, Closed, Whole};

/// 16 MiB, in MB.
const MAX_BODY_MB: Setting = setting(
    "limits",
    "max_body_mb",
    "MB",
    Some(16.777216),
    (0.001, 4096.0),
    Closed,
);
const MAX_READINGS_PER_REQUEST: Setting = setting(
    "limits",
    "max_readings_per_request",
    "",
    Some(100_000.0),
    (1.0, 1e7),
    Whole,
);
/// 4 MiB, in MB.
const MAX_FRAME_MB: Setting = setting(
    "limits",
    "max_frame_mb",
    "MB",
    Some(4.194304),
    (0.001, 1024.0),
    Closed,
);
const MAX_POINTS_LIMIT: Setting = setting(
    "limits",
    "max_points_limit",
    "",
    Some(100_000.0),
    (1.0, 1e7),
    Whole,
);
const LIVE_PING_INTERVAL_S: Setting = setting(
    "limits",
    "live_ping_interval_s",
    "s",
    Some(10.0),
    (1.0, 15.0),
    Closed,
);
const MAX_FUTURE_S: Setting = setting(
    "limits",
    "max_future_s",
    "s",
    Some(600.0),
    (0.0, 86_400.0),
    Closed,
);
const MACHINE_QUEUE: Setting = setting(
    "limits",
    "machine_queue",
    "",
    Some(64.0),
    (1.0, 100_000.0),
    Whole,
);
const MAX_LIVE_CLIENTS_PER_MACHINE: Setting = setting(
    "limits",
    "max_live_clients_per_machine",
    "",
    Some(100.0),
    (1.0, 100_000.0),
    Whole,
);
const MAX_REPORT_ROWS: Setting = setting(
    "limits",
    "max_report_rows",
    "",
    Some(100_000.0),
    (1.0, 1e7),
    Whole,
);
const MAX_PRINTED_REPORT_ROWS: Setting = setting(
    "limits",
    "max_printed_report_rows",
    "",
    Some(10_000.0),
    (1.0, 1e6),
    Whole,
);
const REPORTS_AT_ONCE: Setting = setting(
    "limits",
    "reports_at_once",
    "",
    Some(2.0),
    (1.0, 64.0),
    Whole,
);
const MAX_ALARM_CLIENTS: Setting = setting(
    "limits",
    "max_alarm_clients",
    "",
    Some(1000.0),
    (1.0, 100_000.0),
    Whole,
);
const REQUEST_TIMEOUT_S: Setting = setting(
    "limits",
    "request_timeout_s",
    "s",
    Some(30.0),
    (1.0, 3600.0),
    Closed,
);
/// No default: the disk's size.
const MAX_DATABASE_MB: Setting =
    setting("limits", "max_database_mb", "MB", None, (1.0, 1e9), Closed);
const ESTIMATES_HZ: Setting = setting(
    "mqtt",
    "estimates_hz",
    "Hz",
    Some(10.0),
    (0.01, 1000.0),
    Closed,
);
const ATTEMPTS: Setting = setting("webhooks", "attempts", "", Some(8.0), (1.0, 100.0), Whole);
const FIRST_RETRY_S: Setting = setting(
    "webhooks",
    "first_retry_s",
    "s",
    Some(1.0),
    (0.0, 3600.0),
    AboveMin,
);
const MAX_RETRY_S: Setting = setting(
    "webhooks",
    "max_retry_s",
    "s",
    Some(60.0),
    (0.0, 3600.0),
    AboveMin,
);
const TIMEOUT_S: Setting = setting(
    "webhooks",
    "timeout_s",
    "s",
    Some(10.0),
    (0.0, 3600.0),
    AboveMin,
);
const BACKLOG_ALARM_S: Setting = setting(
    "sites",
    "backlog_alarm_s",
    "s",
    Some(300.0),
    (10.0, 604_800.0),
    Closed,
);

/// Every number of the config file's `[limits]`, `[mqtt]`, `[webhooks]`
/// and `[sites]`.
pub const SETTINGS: [Setting; 20] = [
    MAX_BODY_MB,
    MAX_READINGS_PER_REQUEST,
    MAX_FRAME_MB,
    MAX_POINTS_LIMIT,
    MAX_REPORT_ROWS,
    MAX_PRINTED_REPORT_ROWS,
    REPORTS_AT_ONCE,
    LIVE_PING_INTERVAL_S,
    MAX_FUTURE_S,
    MACHINE_QUEUE,
    MAX_LIVE_CLIENTS_PER_MACHINE,
    MAX_ALARM_CLIENTS,
    REQUEST_TIMEOUT_S,
    MAX_DATABASE_MB,
    ESTIMATES_HZ,
    ATTEMPTS,
    FIRST_RETRY_S,
    MAX_RETRY_S,
    TIMEOUT_S,
    BACKLOG_ALARM_S,
];

fn megabytes(mb: f64) -> usize {
    (mb * 1e6) as usize
}

fn database_bytes(mb: f64) -> u64 {
    (mb * 1e6) as u64
}

/// `--max-database-mb`: the cap in bytes, checked as `limits.max_database_mb` is.
pub fn database_cap_bytes(mb: f64) -> Result<u64, SettingsError> {
    MAX_DATABASE_MB.check(mb).map(database_bytes)
}

/// Limits on what clients may send.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Largest request body (413 beyond).
    pub max_body_bytes: usize,
    /// Most readings in one request or WebSocket frame (413 beyond).
    pub max_readings_per_request: usize,
    /// Largest WebSocket message.
    pub max_frame_bytes: usize,
    /// Most points a history query returns.
    pub max_points_limit: usize,
    /// Most rows (rings, pushes, alarms, laser dropouts) a report as JSON
    /// or CSV holds (413 beyond, naming the limit).
    pub max_report_rows: usize,
    /// Most rows a report as a page or PDF holds (413 beyond).
    pub max_printed_report_rows: usize,
    /// Reports read and drawn at once (each holds its rows in memory);
    /// more wait their turn.
    pub reports_at_once: usize,
    /// Interval between `ping` events on live sockets (at most 15 s).
    pub live_ping_interval: Duration,
    /// How far ahead of the server clock a reading's time may be.
    pub max_future_s: f64,
    /// Ingest requests waiting for one machine; beyond, 503 with
    /// `Retry-After` instead of buffering.
    pub machine_queue: usize,
    /// Live sockets per machine (503 beyond).
    pub max_live_clients_per_machine: usize,
    /// Fleet alarm sockets (every dashboard page opens one; 503 beyond).
    pub max_alarm_clients: usize,
    /// Longest a request may take to be answered (beyond: 408 if its body
    /// had not arrived, else 503); streamed
    /// bodies and open WebSockets are not cut.
    pub request_timeout: Duration,
    /// Cap on the database file (a small card on a site computer): beyond
    /// it ingest answers 503 as on a full disk. `None`: the disk's size.
    pub max_database_bytes: Option<u64>,
}

impl Default for Limits {
    /// The defaults of [`SETTINGS`] (each within its range: a unit test
    /// checks every row).
    fn default() -> Self {
        LimitsConfig::default()
            .limits()
            .expect("the defaults of SETTINGS are within their ranges")
    }
}

/// `[limits]` of the config file: what clients may send and how long the
/// server waits; each absent one keeps its default ([`SETTINGS`]; the
/// counts are read as numbers and must be whole).
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsConfig {
    pub max_body_mb: Option<f64>,
    pub max_readings_per_request: Option<f64>,
    pub max_frame_mb: Option<f64>,
    pub max_points_limit: Option<f64>,
    pub max_report_rows: Option<f64>,
    pub max_printed_report_rows: Option<f64>,
    pub reports_at_once: Option<f64>,
    pub live_ping_interval_s: Option<f64>,
    pub max_future_s: Option<f64>,
    pub machine_queue: Option<f64>,
    pub max_live_clients_per_machine: Option<f64>,
    pub max_alarm_clients: Option<f64>,
    pub request_timeout_s: Option<f64>,
    pub max_database_mb: Option<f64>,
}

impl LimitsConfig {
    /// The defaults with each limit the file sets, checked.
    pub fn limits(&self) -> Result<Limits, SettingsError> {
        // The value the file sets, or the setting's default, checked.
        let value =
            |set: Option<f64>, setting: Setting| setting.check(set.unwrap_or(setting.fixed()));
        let count = |set: Option<f64>, setting: Setting| value(set, setting).map(|v| v as usize);
        let seconds =
            |set: Option<f64>, setting: Setting| value(set, setting).map(Duration::from_secs_f64);
        Ok(Limits {
            max_body_bytes: megabytes(value(self.max_body_mb, MAX_BODY_MB)?),
            max_readings_per_request: count(
                self.max_readings_per_request,
                MAX_READINGS_PER_REQUEST,
            )?,
            max_frame_bytes: megabytes(value(self.max_frame_mb, MAX_FRAME_MB)?),
            max_points_limit: count(self.max_points_limit, MAX_POINTS_LIMIT)?,
            max_report_rows: count(self.max_report_rows, MAX_REPORT_ROWS)?,
            max_printed_report_rows: count(self.max_printed_report_rows, MAX_PRINTED_REPORT_ROWS)?,
            reports_at_once: count(self.reports_at_once, REPORTS_AT_ONCE)?,
            live_ping_interval: seconds(self.live_ping_interval_s, LIVE_PING_INTERVAL_S)?,
            max_future_s: value(self.max_future_s, MAX_FUTURE_S)?,
            machine_queue: count(self.machine_queue, MACHINE_QUEUE)?,
            max_live_clients_per_machine: count(
                self.max_live_clients_per_machine,
                MAX_LIVE_CLIENTS_PER_MACHINE,
            )?,
            max_alarm_clients: count(self.max_alarm_clients, MAX_ALARM_CLIENTS)?,
            request_timeout: seconds(self.request_timeout_s, REQUEST_TIMEOUT_S)?,
            // No default: the disk's size.
            max_database_bytes: self.max_database_mb.map(database_cap_bytes).transpose()?,
        })
    }
}

/// `[store]` of the config file: the PostgreSQL store instead of SQLite in
/// the data dir (docs/operations.md, "PostgreSQL"). `serve --store URL`
/// (`TUNNELNAV_STORE`) names it instead of `url`.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoreConfig {
    /// `postgres://USER@HOST:PORT/DB`.
    pub url: Option<String>,
    /// A file holding the password (its first line), kept out of the URL
    /// and the process list.
    pub password_file: Option<PathBuf>,
    /// The CA (PEM) the server's certificate is checked against when the
    /// URL asks for TLS (`sslmode=require`); default the system's roots.
    pub ca_file: Option<PathBuf>,
}

/// How to reach a PostgreSQL store besides its URL (flags that win over
/// the config file's `[store]`).
#[derive(Debug, Clone, Copy, Default)]
pub struct StoreFiles<'a> {
    pub password_file: Option<&'a Path>,
    pub ca_file: Option<&'a Path>,
}

/// Where the store is: PostgreSQL if `url` (a flag, else the config
/// file's `[store] url`) names it, else `None` (SQLite in the data dir).
pub fn store_location(
    url: Option<&str>,
    files: StoreFiles<'_>,
    config: &StoreConfig,
) -> Result<Option<crate::store::postgres::PgLocation>, crate::store::StoreError> {
    let Some(url) = url.or(config.url.as_deref()) else {
        return Ok(None);
    };
    if !(url.starts_with("postgres://") || url.starts_with("postgresql://")) {
        return Err(crate::store::StoreError::Location(format!(
            "`{}` is not PostgreSQL's: expected postgres://USER@HOST:PORT/DB (SQLite, the default, needs no URL: it lives in --data-dir)",
            crate::store::postgres::redacted(url)
        )));
    }
    Ok(Some(crate::store::postgres::PgLocation {
        url: url.to_string(),
        password_file: files
            .password_file
            .map(Path::to_path_buf)
            .or_else(|| config.password_file.clone()),
        ca_file: files
            .ca_file
            .map(Path::to_path_buf)
            .or_else(|| config.ca_file.clone()),
    }))
}

/// `[mqtt]` of the config file: the broker and how to reach it
/// (docs/operations.md, "MQTT"). `serve --mqtt URL` (`TUNNELNAV_MQTT`)
/// names the broker instead of `url`; the rest applies either way.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MqttConfig {
    /// `mqtt://[user:password@]host[:port]` or `mqtts://` (TLS).
    pub url: Option<String>,
    /// The user to sign in as, when the URL names none.
    pub username: Option<String>,
    /// A file holding the password (its first line), kept out of the URL
    /// and the process list.
    pub password_file: Option<PathBuf>,
    /// PEM certificates of the CA that signed the broker's certificate
    /// (a site's own CA); without it, the system's root certificates.
    pub ca_file: Option<PathBuf>,
    /// PEM certificate (chain) tunnelnav presents, for a broker that
    /// requires client certificates; with `client_key_file`.
    pub client_cert_file: Option<PathBuf>,
    /// PEM private key of `client_cert_file`.
    pub client_key_file: Option<PathBuf>,
    /// The newest estimate of each stream is published this many times a
    /// second at most ([`SETTINGS`]: 10 by default).
    pub estimates_hz: Option<f64>,
}

impl MqttConfig {
    /// How often the newest estimate of a stream is published.
    pub fn estimates_every(&self) -> Result<Duration, SettingsError> {
        let hz = ESTIMATES_HZ.check(self.estimates_hz.unwrap_or(ESTIMATES_HZ.fixed()))?;
        Ok(Duration::from_secs_f64(1.0 / hz))
    }
}

/// Webhooks, one URL per severity (`[webhooks]` in the server config).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WebhookConfig {
    /// Receives the changes of `warn` alarms.
    pub warn: Option<String>,
    /// Receives the changes of `alarm` alarms.
    pub alarm: Option<String>,
    /// Attempts per change before it is given up (logged).
    pub attempts: u32,
    /// Wait before the first retry; doubled after each failure.
    pub first_retry_s: f64,
    /// Longest wait between attempts.
    pub max_retry_s: f64,
    /// How long one attempt may take.
    pub timeout_s: f64,
}

impl Default for WebhookConfig {
    fn default() -> Self {
        WebhookConfig {
            warn: None,
            alarm: None,
            attempts: ATTEMPTS.fixed() as u32,
            first_retry_s: FIRST_RETRY_S.fixed(),
            max_retry_s: MAX_RETRY_S.fixed(),
            timeout_s: TIMEOUT_S.fixed(),
        }
    }
}

impl WebhookConfig {
    /// Checks the URLs (plain `http://`: this build has no TLS client; put
    /// a relay or the proxy in front for `https`) and the timings.
    pub fn validate(&self) -> Result<(), SettingsError> {
        for (severity, url) in [("warn", &self.warn), ("alarm", &self.alarm)] {
            let Some(url) = url else { continue };
            let parsed = reqwest::Url::parse(url).map_err(|e| SettingsError::Url {
                severity,
                url: url.clone(),
                reason: e.to_string(),
            })?;
            if parsed.scheme() != "http" || parsed.host_str().is_none() {
                return Err(SettingsError::Url {
                    severity,
                    url: url.clone(),
                    reason: "only http:// with a host is supported".into(),
                });
            }
        }
        ATTEMPTS.check(f64::from(self.attempts))?;
        FIRST_RETRY_S.check(self.first_retry_s)?;
        MAX_RETRY_S.check(self.max_retry_s)?;
        TIMEOUT_S.check(self.timeout_s)?;
        Ok(())
    }

    /// The wait after failed attempt `attempt` (1-based): doubling from
    /// `first_retry_s`, at most `max_retry_s`.
    pub fn backoff(&self, attempt: u32) -> Duration {
        let doubled = self.first_retry_s * 2f64.powi(attempt.saturating_sub(1).min(30) as i32);
        Duration::from_secs_f64(doubled.min(self.max_retry_s))
    }
}

/// The server's config file.
///
/// ```toml
/// [machines.tbm-1]
/// name = "TBM 1, north drive"
/// [machines.tbm-1.engines.attitude]
/// fusion_gain_pitch = 0.4
/// ```
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServerConfig {
    /// Machine id → declaration.
    #[serde(default)]
    pub machines: BTreeMap<String, MachineDeclaration>,
    /// Where alarm changes are posted (`[webhooks]`: `warn`, `alarm`).
    #[serde(default)]
    pub webhooks: WebhookConfig,
    /// The server's limits (`[limits]`), each optional.
    #[serde(default)]
    pub limits: LimitsConfig,
    /// The MQTT broker (`[mqtt]`), if any.
    #[serde(default)]
    pub mqtt: MqttConfig,
    /// The PostgreSQL store (`[store]`), if any.
    #[serde(default)]
    pub store: StoreConfig,
    /// The office this site forwards to (`[forward]`), if any.
    #[serde(default)]
    pub forward: ForwardConfig,
    /// What an office allows its sites (`[sites]`).
    #[serde(default)]
    pub sites: SitesConfig,
}

/// `[forward]` of the config file: the office a site forwards to
/// (docs/operations.md, "Sites and the office"). `serve --forward-to`,
/// `--site` and `--forward-token-file` win over it.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForwardConfig {
    /// The office, `http://HOST:PORT`.
    pub url: Option<String>,
    /// This site's name.
    pub site: Option<String>,
    /// A file whose first line is the office's `site` token for this site.
    pub token_file: Option<PathBuf>,
}

/// `[sites]` of the config file: an office's allowance for its sites.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SitesConfig {
    /// A site whose oldest unsent row is older than this (s), or that has
    /// been silent this long, raises `site_link` on its machines.
    pub backlog_alarm_s: Option<f64>,
}

impl SitesConfig {
    /// `backlog_alarm_s`, checked, or its default.
    pub fn checked_backlog_alarm_s(&self) -> Result<f64, SettingsError> {
        BACKLOG_ALARM_S.check(self.backlog_alarm_s.unwrap_or(BACKLOG_ALARM_S.fixed()))
    }

    /// `backlog_alarm_s` or its default (call after [`ServerConfig::parse`]
    /// has checked it).
    pub fn backlog_alarm_s(&self) -> f64 {
        self.checked_backlog_alarm_s()
            .unwrap_or(BACKLOG_ALARM_S.fixed())
    }
}

/// A config file, validated.
#[derive(Debug, Clone, Default)]
pub struct ServerSettings {
    pub machines: Vec<MachineSpec>,
    pub webhooks: WebhookConfig,
    /// The server's limits: the defaults with `[limits]` applied.
    pub limits: Limits,
    /// `[mqtt]`, its rate checked; the rest is checked when the broker's
    /// connection is set up (`server::mqtt::settings`).
    pub mqtt: MqttConfig,
    /// `[store]`.
    pub store: StoreConfig,
    /// `[forward]`.
    pub forward: ForwardConfig,
    /// `[sites]`, checked.
    pub sites: SitesConfig,
}

impl ServerConfig {
    /// Reads and validates a config file.
    pub fn load(path: &Path) -> Result<ServerSettings, ConfigError> {
        let file_error = |reason: String| ConfigError::File {
            path: path.display().to_string(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| file_error(e.to_string()))?;
        Self::parse(&text).map_err(|e| match e {
            ConfigError::File { reason, .. } => file_error(reason),
            other => file_error(other.to_string()),
        })
    }

    /// Parses and validates config text.
    pub fn parse(text: &str) -> Result<ServerSettings, ConfigError> {
        let file_error = |reason: String| ConfigError::File {
            path: String::new(),
            reason,
        };
        let config: ServerConfig = toml::from_str(text).map_err(|e| file_error(e.to_string()))?;
        config
            .webhooks
            .validate()
            .map_err(|e| file_error(e.to_string()))?;
        let limits = config
            .limits
            .limits()
            .map_err(|e| file_error(e.to_string()))?;
        config
            .mqtt
            .estimates_every()
            .map_err(|e| file_error(e.to_string()))?;
        config
            .sites
            .checked_backlog_alarm_s()
            .map_err(|e| file_error(e.to_string()))?;
        Ok(ServerSettings {
            machines: config
                .machines
                .into_iter()
                .map(|(id, declaration)| declaration.validate(&id))
                .collect::<Result<_, _>>()?,
            webhooks: config.webhooks,
            limits,
            mqtt: config.mqtt,
            store: config.store,
            forward: config.forward,
            sites: config.sites,
        })
    }
}

#[cfg(test)]
mod tests;
