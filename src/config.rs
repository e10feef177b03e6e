//! Machine definitions (the body of `PUT /api/v1/machines/{machine}`) and
//! the server's TOML configuration file, which declares machines the same way.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use std::sync::Arc;

use crate::fusion::alarms::AlarmConfig;
use crate::fusion::alignment::{Alignment, AlignmentError, AlignmentSpec};
use crate::fusion::dta::{MachineGeometry, Tolerances};
use crate::fusion::pipeline::Pipeline;
use crate::fusion::reading::ProjectPoint;
use crate::fusion::{
    Declaration, EngineKind, ParamError, ParamValue, Params, StreamKind, UnknownEngine,
};
pub use crate::server::notify::WebhookConfig;

/// Longest machine display name, in characters.
pub const MAX_NAME_CHARS: usize = 200;
/// Longest reorder window a machine may ask for: readings are held in memory
/// for this long, and estimates come out this much later.
pub const MAX_REORDER_WINDOW_S: f64 = 600.0;

/// A machine as declared by an operator, before validation: what `PUT`
/// bodies and the config file contain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MachineDeclaration {
    /// Display name; the id when absent.
    #[serde(default)]
    pub name: Option<String>,
    /// Engine name → parameter overrides (docs/engines/ lists each
    /// engine's parameters).
    #[schema(schema_with = engines_schema)]
    pub engines: BTreeMap<String, BTreeMap<String, ParamValue>>,
    /// How long readings are held to restore time order, seconds of reading
    /// time (tunnelnav extension, default 0: fused on arrival; docs/api.md).
    #[serde(default)]
    pub reorder_window_s: Option<f64>,
    /// Where the machine's front and rear are (protocol, "Design axis and
    /// deviation"); with an alignment, the `dta` stream.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<MachineGeometry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerances: Option<Tolerances>,
    /// Project coordinates of the reference point at the first reading.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<ProjectPoint>,
    /// The design axis of the machine's drive.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alignment: Option<AlignmentSpec>,
    /// The alarm rules' settings (defaults when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alarms: Option<AlarmConfig>,
}

/// A validated machine: id, name, engines with complete parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MachineSpec {
    pub id: String,
    pub name: String,
    pub engines: BTreeMap<EngineKind, Params>,
    pub reorder_window_s: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<MachineGeometry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerances: Option<Tolerances>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<ProjectPoint>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alignment: Option<AlignmentSpec>,
    /// The alarm rules' settings.
    #[serde(default)]
    pub alarms: AlarmConfig,
    /// `alignment` built (when validated or loaded).
    #[serde(skip)]
    pub built_alignment: Option<Arc<Alignment>>,
}

/// Why a machine declaration or the config file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("machine id `{0}` is not valid: use 1 to 64 letters, digits, `-` or `_`")]
    MachineId(String),
    #[error("machine `{machine}`: {source}")]
    Engine {
        machine: String,
        source: UnknownEngine,
    },
    #[error("machine `{machine}`, engine `{engine}`: {source}")]
    Params {
        machine: String,
        engine: EngineKind,
        source: ParamError,
    },
    #[error("machine `{machine}` declares no engine (known: {known})")]
    NoEngine { machine: String, known: String },
    #[error("machine `{machine}`: {reason}")]
    Invalid { machine: String, reason: String },
    #[error("config file {path}: {reason}")]
    File { path: String, reason: String },
}

/// True for ids matching `[A-Za-z0-9_-]{1,64}` (protocol, "HTTP API").
pub fn valid_machine_id(id: &str) -> bool {
    (1..=64).contains(&id.len())
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

/// The schema of a declaration's `engines`, from the engines' parameter
/// tables (what [`MachineDeclaration::validate`] checks them against):
/// at least one engine, each with only its own parameters, in range.
fn engines_schema() -> utoipa::openapi::schema::Schema {
    use crate::fusion::ParamKind;
    use utoipa::openapi::schema::{ObjectBuilder, Type};
    let mut engines = ObjectBuilder::new()
        .schema_type(Type::Object)
        .description(Some(
            "Engine name → its parameter overrides (docs/engines/); the others keep their defaults",
        ))
        .min_properties(Some(1))
        .additional_properties(Some(
            utoipa::openapi::schema::AdditionalProperties::FreeForm(false),
        ));
    for &engine in crate::fusion::EngineKind::ALL {
        let mut params = ObjectBuilder::new()
            .schema_type(Type::Object)
            .additional_properties(Some(
                utoipa::openapi::schema::AdditionalProperties::FreeForm(false),
            ));
        for spec in engine.specs() {
            let unit = if spec.unit.is_empty() {
                String::new()
            } else {
                format!(" ({})", spec.unit)
            };
            let value = match spec.kind {
                ParamKind::Real { default, min, max } => ObjectBuilder::new()
                    .schema_type(Type::Number)
                    .minimum(Some(min))
                    .maximum(Some(max))
                    .default(Some(default.into())),
                ParamKind::Integer { default, min, max } => ObjectBuilder::new()
                    .schema_type(Type::Integer)
                    .minimum(Some(min as f64))
                    .maximum(Some(max as f64))
                    .default(Some(default.into())),
                ParamKind::Bool { default } => ObjectBuilder::new()
                    .schema_type(Type::Boolean)
                    .default(Some(default.into())),
                ParamKind::Choice { default, options } => ObjectBuilder::new()
                    .schema_type(Type::String)
                    .enum_values(Some(options.iter().copied()))
                    .default(Some(default.into())),
            };
            params = params.property(
                spec.name,
                value.description(Some(format!("{}{unit}", spec.doc))),
            );
        }
        engines = engines.property(engine.as_str(), params);
    }
    engines.into()
}

impl MachineDeclaration {
    /// Checks everything an engine would refuse later, naming the culprit.
    pub fn validate(self, id: &str) -> Result<MachineSpec, ConfigError> {
        if !valid_machine_id(id) {
            return Err(ConfigError::MachineId(id.to_string()));
        }
        let invalid = |reason: String| ConfigError::Invalid {
            machine: id.to_string(),
            reason,
        };
        let name = self.name.unwrap_or_else(|| id.to_string());
        if name.chars().count() > MAX_NAME_CHARS || name.chars().any(char::is_control) {
            return Err(invalid(format!(
                "`name` must be at most {MAX_NAME_CHARS} printable characters"
            )));
        }
        let reorder_window_s = self.reorder_window_s.unwrap_or(0.0);
        if !(0.0..=MAX_REORDER_WINDOW_S).contains(&reorder_window_s) {
            return Err(invalid(format!(
                "`reorder_window_s` = {reorder_window_s} is outside [0, {MAX_REORDER_WINDOW_S}]"
            )));
        }
        if self.engines.is_empty() {
            return Err(ConfigError::NoEngine {
                machine: id.to_string(),
                known: EngineKind::names(),
            });
        }
        let mut engines = BTreeMap::new();
        for (engine_name, overrides) in self.engines {
            let engine: EngineKind = engine_name.parse().map_err(|source| ConfigError::Engine {
                machine: id.to_string(),
                source,
            })?;
            let params_error = |source| ConfigError::Params {
                machine: id.to_string(),
                engine,
                source,
            };
            let params = engine.params(overrides).map_err(params_error)?;
            // Creating the engine runs its cross-parameter checks.
            engine.create(params.clone()).map_err(params_error)?;
            engines.insert(engine, params);
        }
        let finite = |xs: &[f64]| xs.iter().all(|x| x.is_finite());
        if let Some(g) = &self.geometry
            && !finite(&[g.front_m, g.rear_m].concat())
        {
            return Err(invalid(
                "`geometry`: front_m and rear_m must be finite numbers".into(),
            ));
        }
        if let Some(t) = &self.tolerances {
            for (what, limits) in [
                ("horizontal_mm", t.horizontal_mm),
                ("vertical_mm", t.vertical_mm),
            ] {
                if !(finite(&[limits.warn, limits.alarm])
                    && 0.0 < limits.warn
                    && limits.warn <= limits.alarm)
                {
                    return Err(invalid(format!(
                        "`tolerances.{what}`: warn must be above 0 and at most alarm"
                    )));
                }
            }
        }
        if let Some(p) = &self.start
            && !finite(&[p.easting_m, p.northing_m, p.height_m])
        {
            return Err(invalid(
                "`start`: easting, northing and height must be finite".into(),
            ));
        }
        // Only a new declaration is held to scale (an axis stored by an
        // earlier release still opens: see `upgraded`).
        if let Some(alignment) = &self.alignment {
            alignment
                .check_scale()
                .map_err(|e| invalid(format!("`alignment`: {e}")))?;
        }
        let built_alignment =
            built(self.alignment.as_ref()).map_err(|e| invalid(format!("`alignment`: {e}")))?;
        let alarms = self.alarms.unwrap_or_default();
        alarms.validate().map_err(invalid)?;
        Ok(MachineSpec {
            id: id.to_string(),
            name,
            engines,
            reorder_window_s,
            geometry: self.geometry,
            tolerances: self.tolerances,
            start: self.start,
            alignment: self.alignment,
            alarms,
            built_alignment,
        })
    }
}

/// A declared alignment, built.
fn built(alignment: Option<&AlignmentSpec>) -> Result<Option<Arc<Alignment>>, AlignmentError> {
    alignment.map(|a| a.build().map(Arc::new)).transpose()
}

impl MachineSpec {
    /// Fresh engines with the declared parameters and the stages the
    /// declaration calls for: what a machine runs, served or replayed.
    pub fn pipeline(&self) -> Result<Pipeline, ParamError> {
        let engines = self
            .engines
            .iter()
            .map(|(kind, params)| kind.create(params.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Pipeline::declared(engines, &self.stage_declaration()))
    }

    /// What the stages read of this declaration.
    pub fn stage_declaration(&self) -> Declaration {
        Declaration {
            alignment: self.built_alignment.clone(),
            geometry: self.geometry,
            tolerances: self.tolerances,
            start: self.start,
            ..Declaration::of_engines(self.engines.keys().copied())
        }
    }

    /// Every stream of estimates the machine has: its engines', then its
    /// stages' (registry order).
    pub fn streams(&self) -> Vec<StreamKind> {
        self.engines
            .keys()
            .map(|&engine| StreamKind::from(engine))
            .chain(
                self.stage_declaration()
                    .stages()
                    .into_iter()
                    .map(StreamKind::from),
            )
            .collect()
    }

    /// A machine stored by an earlier release made current: retired
    /// parameters dropped, new ones at their defaults (see
    /// [`Params::upgraded`]).
    pub fn upgraded(mut self) -> Result<MachineSpec, ConfigError> {
        for (kind, params) in self.engines.iter_mut() {
            *params = params
                .upgraded(kind.specs(), kind.retired())
                .map_err(|source| ConfigError::Params {
                    machine: self.id.clone(),
                    engine: *kind,
                    source,
                })?;
        }
        self.built_alignment =
            built(self.alignment.as_ref()).map_err(|e| ConfigError::Invalid {
                machine: self.id.clone(),
                reason: format!("stored `alignment`: {e}"),
            })?;
        Ok(self)
    }

    /// The declaration that reproduces this machine, with every parameter
    /// spelled out (what `GET` shows).
    pub fn declaration(&self) -> MachineDeclaration {
        MachineDeclaration {
            name: Some(self.name.clone()),
            engines: self
                .engines
                .iter()
                .map(|(engine, params)| (engine.as_str().to_string(), params.values().clone()))
                .collect(),
            reorder_window_s: Some(self.reorder_window_s),
            geometry: self.geometry,
            tolerances: self.tolerances,
            start: self.start,
            alignment: self.alignment.clone(),
            alarms: (self.alarms != AlarmConfig::default()).then_some(self.alarms),
        }
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
}

/// A config file, validated.
#[derive(Debug, Clone, Default)]
pub struct ServerSettings {
    pub machines: Vec<MachineSpec>,
    pub webhooks: WebhookConfig,
    /// The server's limits: the defaults with `[limits]` applied.
    pub limits: crate::server::Limits,
    /// `[mqtt]`, its rate checked; the rest is checked when the broker's
    /// connection is set up (`server::mqtt::settings`).
    pub mqtt: MqttConfig,
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
    /// second at most (default 10).
    pub estimates_hz: Option<f64>,
}

impl MqttConfig {
    /// Default of `estimates_hz`.
    pub const DEFAULT_ESTIMATES_HZ: f64 = 10.0;
    /// Bounds of `estimates_hz`.
    pub const ESTIMATES_HZ_RANGE: (f64, f64) = (0.01, 1000.0);

    /// How often the newest estimate of a stream is published.
    pub fn estimates_every(&self) -> Result<std::time::Duration, String> {
        let hz = self.estimates_hz.unwrap_or(Self::DEFAULT_ESTIMATES_HZ);
        let (min, max) = Self::ESTIMATES_HZ_RANGE;
        if hz.is_finite() && (min..=max).contains(&hz) {
            Ok(std::time::Duration::from_secs_f64(1.0 / hz))
        } else {
            Err(format!(
                "mqtt.estimates_hz must be between {min} and {max}, not {hz}"
            ))
        }
    }
}

/// `[limits]` of the config file: what clients may send and how long the
/// server waits; each absent one keeps its default (docs/operations.md).
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsConfig {
    pub max_body_mb: Option<f64>,
    pub max_readings_per_request: Option<usize>,
    pub max_frame_mb: Option<f64>,
    pub max_points_limit: Option<usize>,
    pub live_ping_interval_s: Option<f64>,
    pub max_future_s: Option<f64>,
    pub machine_queue: Option<usize>,
    pub max_live_clients_per_machine: Option<usize>,
    pub max_alarm_clients: Option<usize>,
    pub request_timeout_s: Option<f64>,
    pub max_database_mb: Option<f64>,
}

impl LimitsConfig {
    /// `defaults` with these limits applied; an out-of-range value is
    /// refused naming it.
    pub fn apply(&self, defaults: crate::server::Limits) -> Result<crate::server::Limits, String> {
        use std::time::Duration;
        fn real(name: &str, value: Option<f64>, min: f64, max: f64) -> Result<Option<f64>, String> {
            match value {
                Some(v) if !(v.is_finite() && v >= min && v <= max) => Err(format!(
                    "limits.{name} must be between {min} and {max}, not {v}"
                )),
                other => Ok(other),
            }
        }
        fn count(name: &str, value: Option<usize>, max: usize) -> Result<Option<usize>, String> {
            match value {
                Some(v) if v == 0 || v > max => Err(format!(
                    "limits.{name} must be between 1 and {max}, not {v}"
                )),
                other => Ok(other),
            }
        }
        let mb = |v: f64| (v * 1e6) as usize;
        let mut limits = defaults;
        if let Some(v) = real("max_body_mb", self.max_body_mb, 0.001, 4096.0)? {
            limits.max_body_bytes = mb(v);
        }
        if let Some(v) = count(
            "max_readings_per_request",
            self.max_readings_per_request,
            10_000_000,
        )? {
            limits.max_readings_per_request = v;
        }
        if let Some(v) = real("max_frame_mb", self.max_frame_mb, 0.001, 1024.0)? {
            limits.max_frame_bytes = mb(v);
        }
        if let Some(v) = count("max_points_limit", self.max_points_limit, 10_000_000)? {
            limits.max_points_limit = v;
        }
        if let Some(v) = real("live_ping_interval_s", self.live_ping_interval_s, 1.0, 15.0)? {
            limits.live_ping_interval = Duration::from_secs_f64(v);
        }
        if let Some(v) = real("max_future_s", self.max_future_s, 0.0, 86_400.0)? {
            limits.max_future_s = v;
        }
        if let Some(v) = count("machine_queue", self.machine_queue, 100_000)? {
            limits.machine_queue = v;
        }
        if let Some(v) = count(
            "max_live_clients_per_machine",
            self.max_live_clients_per_machine,
            100_000,
        )? {
            limits.max_live_clients_per_machine = v;
        }
        if let Some(v) = count("max_alarm_clients", self.max_alarm_clients, 100_000)? {
            limits.max_alarm_clients = v;
        }
        if let Some(v) = real("request_timeout_s", self.request_timeout_s, 1.0, 3600.0)? {
            limits.request_timeout = Duration::from_secs_f64(v);
        }
        if let Some(v) = real("max_database_mb", self.max_database_mb, 1.0, 1e9)? {
            limits.max_database_bytes = Some((v * 1e6) as u64);
        }
        Ok(limits)
    }
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
        let config: ServerConfig = toml::from_str(text).map_err(|e| ConfigError::File {
            path: String::new(),
            reason: e.to_string(),
        })?;
        config.webhooks.validate().map_err(|e| ConfigError::File {
            path: String::new(),
            reason: e.to_string(),
        })?;
        let limits = config
            .limits
            .apply(crate::server::Limits::default())
            .map_err(|reason| ConfigError::File {
                path: String::new(),
                reason,
            })?;
        config
            .mqtt
            .estimates_every()
            .map_err(|reason| ConfigError::File {
                path: String::new(),
                reason,
            })?;
        Ok(ServerSettings {
            machines: config
                .machines
                .into_iter()
                .map(|(id, declaration)| declaration.validate(&id))
                .collect::<Result<_, _>>()?,
            webhooks: config.webhooks,
            limits,
            mqtt: config.mqtt,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn machine_ids_follow_the_protocol() {
        assert!(valid_machine_id("tbm-1_A"));
        assert!(valid_machine_id(&"a".repeat(64)));
        assert!(!valid_machine_id(&"a".repeat(65)));
        assert!(!valid_machine_id(""));
        assert!(!valid_machine_id("tbm 1"));
        assert!(!valid_machine_id("tbm/1"));
    }

    #[test]
    fn a_config_file_sets_limits_and_refuses_bad_ones() {
        let settings = ServerConfig::parse(
            "[limits]\nmax_body_mb = 2\nmachine_queue = 8\nrequest_timeout_s = 5\n",
        )
        .unwrap();
        let limits = settings.limits;
        assert_eq!(limits.max_body_bytes, 2_000_000);
        assert_eq!(limits.machine_queue, 8);
        assert_eq!(limits.request_timeout, std::time::Duration::from_secs(5));
        // Untouched ones keep their defaults.
        assert_eq!(limits.max_readings_per_request, 100_000);
        let err = ServerConfig::parse("[limits]\nmachine_queue = 0\n").unwrap_err();
        assert!(err.to_string().contains("limits.machine_queue"), "{err}");
        let err = ServerConfig::parse("[limits]\nlive_ping_interval_s = 60\n").unwrap_err();
        assert!(err.to_string().contains("live_ping_interval_s"), "{err}");
        let err = ServerConfig::parse("[limits]\nmax_bodies = 1\n").unwrap_err();
        assert!(err.to_string().contains("max_bodies"), "{err}");
    }

    #[test]
    fn a_config_file_names_the_broker_and_refuses_a_bad_rate() {
        let settings = ServerConfig::parse(
            "[mqtt]\nurl = \"mqtts://broker.site\"\nusername = \"tunnelnav\"\n\
             password_file = \"/run/credentials/mqtt\"\nestimates_hz = 2\n",
        )
        .unwrap();
        assert_eq!(settings.mqtt.url.as_deref(), Some("mqtts://broker.site"));
        assert_eq!(
            settings.mqtt.estimates_every(),
            Ok(std::time::Duration::from_millis(500))
        );
        // Absent: 10 a second.
        assert_eq!(
            MqttConfig::default().estimates_every(),
            Ok(std::time::Duration::from_millis(100))
        );
        let err = ServerConfig::parse("[mqtt]\nestimates_hz = 0\n").unwrap_err();
        assert!(err.to_string().contains("mqtt.estimates_hz"), "{err}");
        let err = ServerConfig::parse("[mqtt]\npassword = \"x\"\n").unwrap_err();
        assert!(err.to_string().contains("password"), "{err}");
    }

    #[test]
    fn a_config_file_names_webhooks_and_refuses_bad_ones() {
        let settings = ServerConfig::parse(
            "[webhooks]\nalarm = \"http://127.0.0.1:9000/alarm\"\nattempts = 3\n",
        )
        .unwrap();
        assert_eq!(
            settings.webhooks.alarm.as_deref(),
            Some("http://127.0.0.1:9000/alarm")
        );
        assert_eq!(
            (settings.webhooks.warn, settings.webhooks.attempts),
            (None, 3)
        );
        let err = ServerConfig::parse("[webhooks]\nwarn = \"ftp://x/\"\n").unwrap_err();
        assert!(err.to_string().contains("webhooks.warn"), "{err}");
        let err = ServerConfig::parse("[webhooks]\nwarm = \"http://x/\"\n").unwrap_err();
        assert!(err.to_string().contains("warm"), "{err}");
    }

    #[test]
    fn a_config_file_declares_machines_with_parameters() {
        let specs = ServerConfig::parse(
            r#"
            [machines.tbm-1]
            name = "TBM 1"
            [machines.tbm-1.engines.attitude]
            fusion_gain_pitch = 0.4
            [machines.tbm-2.engines.attitude]
            "#,
        )
        .unwrap()
        .machines;
        assert_eq!(specs.len(), 2);
        assert_eq!(specs[0].name, "TBM 1");
        assert_eq!(specs[1].name, "tbm-2");
        let params = &specs[0].engines[&EngineKind::Attitude];
        assert_eq!(params.real("fusion_gain_pitch").unwrap(), 0.4);
    }

    #[test]
    fn errors_name_the_machine_engine_and_parameter() {
        let err = ServerConfig::parse("[machines.m.engines.attitude]\nfusion_gain_pitch = 7\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("machine `m`, engine `attitude`"), "{err}");
        assert!(err.contains("fusion_gain_pitch"), "{err}");
        let err = ServerConfig::parse("[machines.m.engines.gps]\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("unknown engine `gps`"), "{err}");
        let err = ServerConfig::parse("[machines.\"a b\".engines.attitude]\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("`a b` is not valid"), "{err}");
        let err = ServerConfig::parse("[machines.m]\nengines = {}\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("declares no engine"), "{err}");
        let err = ServerConfig::parse("[machines.m]\nengine = {}\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("unknown field `engine`"), "{err}");
    }

    #[test]
    fn alarm_settings_are_optional_validated_and_named() {
        let declare = |alarms: serde_json::Value| {
            serde_json::from_value::<MachineDeclaration>(serde_json::json!({
                "engines": {"attitude": {}}, "alarms": alarms
            }))
            .map_err(|e| e.to_string())
            .and_then(|d| d.validate("m").map_err(|e| e.to_string()))
        };
        let spec = declare(serde_json::json!({"laser_dropout_warn_s": 120})).unwrap();
        assert_eq!(spec.alarms.laser_dropout_warn_s, 120.0);
        assert_eq!(
            spec.alarms.stale_periods,
            AlarmConfig::default().stale_periods
        );
        assert_eq!(spec.declaration().alarms, Some(spec.alarms));
        let err = declare(serde_json::json!({"min_duration_s": -1})).unwrap_err();
        assert!(err.contains("alarms.min_duration_s"), "{err}");
        let err = declare(serde_json::json!({"ring_the_bell": true})).unwrap_err();
        assert!(err.contains("ring_the_bell"), "{err}");
        let plain = serde_json::from_value::<MachineDeclaration>(
            serde_json::json!({"engines": {"attitude": {}}}),
        )
        .unwrap()
        .validate("m")
        .unwrap();
        assert_eq!(plain.alarms, AlarmConfig::default());
        assert_eq!(plain.declaration().alarms, None);
    }
}
