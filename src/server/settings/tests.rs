use super::*;
use crate::fusion::EngineKind;

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
    let settings =
        ServerConfig::parse("[webhooks]\nalarm = \"http://127.0.0.1:9000/alarm\"\nattempts = 3\n")
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
fn back_off_doubles_up_to_its_cap() {
    let config = WebhookConfig {
        first_retry_s: 0.5,
        max_retry_s: 3.0,
        ..WebhookConfig::default()
    };
    let waits: Vec<f64> = (1..=5).map(|a| config.backoff(a).as_secs_f64()).collect();
    assert_eq!(waits, [0.5, 1.0, 2.0, 3.0, 3.0]);
}

#[test]
fn webhook_urls_and_timings_are_checked() {
    let ok = WebhookConfig {
        alarm: Some("http://127.0.0.1:9000/hook".into()),
        ..WebhookConfig::default()
    };
    assert_eq!(ok.validate(), Ok(()));
    let https = WebhookConfig {
        warn: Some("https://example.org/hook".into()),
        ..WebhookConfig::default()
    };
    assert!(matches!(
        https.validate(),
        Err(SettingsError::Url {
            severity: "warn",
            ..
        })
    ));
    let nonsense = WebhookConfig {
        alarm: Some("not a url".into()),
        ..WebhookConfig::default()
    };
    assert!(nonsense.validate().is_err());
    let zero = WebhookConfig {
        attempts: 0,
        ..WebhookConfig::default()
    };
    assert!(matches!(
        zero.validate(),
        Err(SettingsError::Range {
            name: "attempts",
            ..
        })
    ));
    let negative = WebhookConfig {
        timeout_s: -1.0,
        ..WebhookConfig::default()
    };
    assert!(negative.validate().is_err());
}
#[test]
fn the_defaults_are_what_they_were() {
    // The values each default had before the table (hand-written).
    let l = Limits::default();
    assert_eq!(l.max_body_bytes, 16 * 1024 * 1024);
    assert_eq!(l.max_frame_bytes, 4 * 1024 * 1024);
    assert_eq!(
        (l.max_readings_per_request, l.max_points_limit),
        (100_000, 100_000)
    );
    assert_eq!(l.live_ping_interval, Duration::from_secs(10));
    assert_eq!(l.max_future_s, 600.0);
    assert_eq!(
        (
            l.machine_queue,
            l.max_live_clients_per_machine,
            l.max_alarm_clients
        ),
        (64, 100, 1000)
    );
    assert_eq!(l.request_timeout, Duration::from_secs(30));
    assert_eq!(l.max_database_bytes, None);
    let w = WebhookConfig::default();
    assert_eq!(
        (w.attempts, w.first_retry_s, w.max_retry_s, w.timeout_s),
        (8, 1.0, 60.0, 10.0)
    );
    assert_eq!(
        MqttConfig::default().estimates_every(),
        Ok(Duration::from_millis(100))
    );
    // Every default is within its own range.
    for s in SETTINGS {
        if let Some(v) = s.default {
            assert_eq!(s.check(v), Ok(v), "{}.{}", s.section, s.name);
        }
    }
}

#[test]
fn every_row_is_a_key_of_its_section() {
    // Each row set alone to its default (or its minimum) parses and
    // validates: the table names nothing the file would refuse.
    for s in SETTINGS {
        let value = s.default.unwrap_or(s.min.max(1.0));
        let text = format!("[{}]\n{} = {value}\n", s.section, s.name);
        assert!(ServerConfig::parse(&text).is_ok(), "{text}");
    }
}

#[test]
fn ranges_are_checked_and_named() {
    assert_eq!(MACHINE_QUEUE.check(8.0), Ok(8.0));
    for refused in [0.0, 8.5, 100_001.0, f64::NAN] {
        let err = MACHINE_QUEUE.check(refused).unwrap_err().to_string();
        assert!(
            err.starts_with("limits.machine_queue must be a whole number between 1 and 100000"),
            "{err}"
        );
    }
    assert!(TIMEOUT_S.check(0.0).is_err());
    assert_eq!(TIMEOUT_S.check(3600.0), Ok(3600.0));
    assert_eq!(MAX_FUTURE_S.check(0.0), Ok(0.0));
    assert!(LIVE_PING_INTERVAL_S.check(15.5).is_err());
}

#[test]
fn the_operations_guide_shows_the_table() {
    // docs/operations.md, "Settings", is this table as markdown.
    let rows: Vec<String> = SETTINGS
        .iter()
        .map(|s| {
            let default = s.default.map_or("none".to_string(), |v| v.to_string());
            let unit = if s.unit.is_empty() { "–" } else { s.unit };
            format!(
                "| `[{}]` | `{}` | {unit} | {default} | {} |",
                s.section,
                s.name,
                s.rule()
            )
        })
        .collect();
    let guide = include_str!("../../../docs/operations.md");
    let table = rows.join("\n");
    assert!(
        guide.contains(&table),
        "docs/operations.md does not show the settings as they are:\n{table}"
    );
}
