//! MQTT against a real broker: Debian's `mosquitto`, started on a free
//! port for each test, and the real binary (`serve --mqtt`). Skipped
//! (saying so) where mosquitto is not installed, unless
//! `TUNNELNAV_MQTT_TEST=required` (set by `.ci/run`): then it fails.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{ServerProcess, all_estimates, drive, put_machine, replay};
use rumqttc::{AsyncClient, Event, EventLoop, MqttOptions, Packet, QoS};
use serde_json::Value;

/// mosquitto's program, or `None` (saying so) where it is missing and not
/// required.
fn mosquitto_program() -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    let found = std::env::split_paths(&path)
        .chain([PathBuf::from("/usr/sbin")])
        .map(|dir| dir.join("mosquitto"))
        .find(|p| p.is_file());
    if found.is_none() {
        assert!(
            std::env::var("TUNNELNAV_MQTT_TEST").as_deref() != Ok("required"),
            "TUNNELNAV_MQTT_TEST=required but mosquitto is not installed (apt-get install mosquitto)"
        );
        eprintln!("SKIPPED: the MQTT tests need mosquitto (apt-get install mosquitto)");
    }
    found
}

/// A mosquitto on a free local port, persisting its sessions in `dir`;
/// killed when dropped.
struct Broker {
    child: Child,
    port: u16,
}

impl Broker {
    fn start(program: &Path, dir: &Path, port: u16) -> Broker {
        let config = format!(
            "listener {port} 127.0.0.1\nallow_anonymous true\npersistence true\n\
             persistence_location {}/\nmax_queued_messages 0\n",
            dir.display()
        );
        Broker::with_config(program, dir, port, &config)
    }

    /// A mosquitto with `config` (and its errors on stderr).
    fn with_config(program: &Path, dir: &Path, port: u16, config: &str) -> Broker {
        // Started as root, mosquitto runs as its own user: it must be able
        // to write its sessions here.
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777)).unwrap();
        let path = dir.join("mosquitto.conf");
        std::fs::write(
            &path,
            format!("{config}\nlog_dest stderr\nlog_type error\n"),
        )
        .unwrap();
        let config = path;
        let child = Command::new(program)
            .arg("-c")
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("mosquitto starts");
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "mosquitto does not listen");
            std::thread::sleep(Duration::from_millis(50));
        }
        Broker { child, port }
    }

    fn url(&self, client_id: &str) -> String {
        format!("mqtt://127.0.0.1:{}?client_id={client_id}", self.port)
    }
}

impl Broker {
    /// Stops the broker as its service manager would (SIGTERM: it saves
    /// its sessions first).
    fn stop(mut self) {
        let pid = self.child.id().to_string();
        Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        self.child.wait().unwrap();
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A test's own broker on a free port, its sessions in a temporary
/// directory, with mosquitto's program (to start it again); `None` where
/// mosquitto is missing and not required.
fn own_broker() -> Option<(PathBuf, tempfile::TempDir, Broker)> {
    let program = mosquitto_program()?;
    let dir = tempfile::tempdir().unwrap();
    let broker = Broker::start(&program, dir.path(), free_port());
    Some((program, dir, broker))
}

/// `serve ARGS` on `data`, once it has connected to its broker: the
/// server, an HTTP client and the server's base URL.
async fn serve_connected(data: &Path, args: &[&str]) -> (ServerProcess, reqwest::Client, String) {
    let server = ServerProcess::start_with_args(data, args);
    let client = reqwest::Client::new();
    let base = server.url("");
    wait_for_metric(&client, &base, "tunnelnav_mqtt_connected 1").await;
    (server, client, base)
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A client of the broker: its handle and its event loop, polled by a task
/// that forwards what arrives on its subscriptions.
struct Peer {
    client: AsyncClient,
    received: tokio::sync::mpsc::UnboundedReceiver<(String, Vec<u8>)>,
    puback: tokio::sync::mpsc::UnboundedReceiver<u16>,
}

impl Peer {
    async fn connect(port: u16, id: &str, subscriptions: &[&str]) -> Peer {
        Peer::connect_as(port, id, None, subscriptions).await
    }

    /// As [`Peer::connect`], signed in as `login` (user, password).
    async fn connect_as(
        port: u16,
        id: &str,
        login: Option<(&str, &str)>,
        subscriptions: &[&str],
    ) -> Peer {
        let mut options = MqttOptions::new(id, "127.0.0.1", port);
        if let Some((user, password)) = login {
            options.set_credentials(user, password);
        }
        options.set_keep_alive(Duration::from_secs(5));
        options.set_max_packet_size(16 << 20, 16 << 20);
        let (client, eventloop) = AsyncClient::new(options, 1024);
        for topic in subscriptions {
            client.subscribe(*topic, QoS::AtLeastOnce).await.unwrap();
        }
        let (sender, received) = tokio::sync::mpsc::unbounded_channel();
        let (acked, puback) = tokio::sync::mpsc::unbounded_channel();
        tokio::spawn(poll(eventloop, sender, acked));
        Peer {
            client,
            received,
            puback,
        }
    }

    /// Publishes `body` at QoS 1 and waits for the broker's PUBACK.
    async fn publish(&mut self, topic: &str, body: Vec<u8>) {
        self.client
            .publish(topic, QoS::AtLeastOnce, false, body)
            .await
            .unwrap();
        tokio::time::timeout(Duration::from_secs(10), self.puback.recv())
            .await
            .expect("the broker acknowledges")
            .unwrap();
    }

    /// Publishes `body` to `machine`'s readings topic and returns what its
    /// answer (the next message, on that machine's acks topic, to which
    /// this peer subscribes) accepted.
    async fn readings_accepted(&mut self, machine: &str, body: String) -> Option<u64> {
        self.publish(
            &format!("tunnelnav/v1/{machine}/readings"),
            body.into_bytes(),
        )
        .await;
        let (topic, ack) = self.next().await;
        assert_eq!(topic, format!("tunnelnav/v1/{machine}/acks"), "{ack}");
        ack["accepted"].as_u64()
    }

    /// The next message on a subscription as it came, within 20 s.
    async fn next_raw(&mut self) -> (String, Vec<u8>) {
        tokio::time::timeout(Duration::from_secs(20), self.received.recv())
            .await
            .expect("a message within 20 s")
            .unwrap()
    }

    /// The next message on a subscription, JSON, within 20 s.
    async fn next(&mut self) -> (String, Value) {
        let (topic, body) = self.next_raw().await;
        let value = serde_json::from_slice(&body).unwrap_or_else(|e| {
            panic!(
                "{topic}: not JSON ({e}): {}",
                String::from_utf8_lossy(&body)
            )
        });
        (topic, value)
    }
}

async fn poll(
    mut eventloop: EventLoop,
    received: tokio::sync::mpsc::UnboundedSender<(String, Vec<u8>)>,
    acked: tokio::sync::mpsc::UnboundedSender<u16>,
) {
    loop {
        match eventloop.poll().await {
            Ok(Event::Incoming(Packet::Publish(p))) => {
                let _ = received.send((p.topic.clone(), p.payload.to_vec()));
            }
            Ok(Event::Incoming(Packet::PubAck(ack))) => {
                let _ = acked.send(ack.pkid);
            }
            Ok(_) => {}
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_published_through_the_broker_are_stored_fused_and_acknowledged() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let (_server, client, base) =
        serve_connected(data.path(), &["--mqtt", &broker.url("tn-e2e")]).await;
    put_machine(&client, &base, "tbm-mqtt").await;

    let mut control = Peer::connect(broker.port, "control-room", &["tunnelnav/v1/+/acks"]).await;
    let mut gateway = Peer::connect(broker.port, "gateway-1", &[]).await;
    let lines = drive(0.5, 7, Vec::new());
    assert!(lines.len() > 1000, "{}", lines.len());
    // NDJSON batches of 100 readings, and one array.
    for chunk in lines[..lines.len() - 3].chunks(100) {
        gateway
            .publish(
                "tunnelnav/v1/tbm-mqtt/readings",
                chunk.join("\n").into_bytes(),
            )
            .await;
    }
    let array = format!("[{}]", lines[lines.len() - 3..].join(","));
    let messages = lines[..lines.len() - 3].chunks(100).count() + 1;
    gateway
        .publish("tunnelnav/v1/tbm-mqtt/readings", array.into_bytes())
        .await;
    let mut accepted = 0;
    while accepted < lines.len() {
        let (topic, ack) = control.next().await;
        assert_eq!(topic, "tunnelnav/v1/tbm-mqtt/acks");
        assert_eq!(ack["rejected"], serde_json::json!([]), "{ack}");
        accepted += ack["accepted"].as_u64().unwrap() as usize;
    }
    assert_eq!(accepted, lines.len());
    // The estimates are the replay's, exactly.
    let estimates = all_estimates(&client, &base, "tbm-mqtt").await;
    assert!(estimates.len() > 1000, "{}", estimates.len());
    eprintln!(
        "{} readings in {messages} messages: {} estimates",
        lines.len(),
        estimates.len()
    );
    assert_eq!(estimates, replay("tbm-mqtt", &lines));

    // A body that is not readings, and an unknown machine: answered with
    // the error and acknowledged (not redelivered).
    gateway
        .publish("tunnelnav/v1/tbm-mqtt/readings", b"not json".to_vec())
        .await;
    let (_, ack) = control.next().await;
    assert_eq!(ack["status"], 400, "{ack}");
    assert!(ack["error"].as_str().unwrap().contains("JSON"), "{ack}");
    gateway
        .publish(
            "tunnelnav/v1/no-such/readings",
            lines[0].clone().into_bytes(),
        )
        .await;
    let (topic, ack) = control.next().await;
    assert_eq!(topic, "tunnelnav/v1/no-such/acks");
    assert_eq!(ack["status"], 404, "{ack}");
    assert_eq!(ack["machine"], "no-such");
    wait_for_metric(
        &client,
        &base,
        &format!("tunnelnav_mqtt_messages_total{{outcome=\"acknowledged\"}} {messages}"),
    )
    .await;
    wait_for_metric(
        &client,
        &base,
        "tunnelnav_mqtt_messages_total{outcome=\"rejected\"} 2",
    )
    .await;
}

/// Polls `/metrics` until it holds `line`.
async fn wait_for_metric(client: &reqwest::Client, base: &str, line: &str) {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let text = common::get_text(client, base, "/metrics").await;
        if text.lines().any(|l| l == line) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "no `{line}` in /metrics:\n{}",
            text.lines()
                .filter(|l| l.contains("mqtt"))
                .collect::<Vec<_>>()
                .join("\n")
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Inclinometer readings `first..first + count` of a gateway, 0.1 s apart
/// from `t0`, as NDJSON.
fn inclinometer_lines(t0: f64, first: usize, count: usize) -> String {
    (first..first + count)
        .map(|k| {
            serde_json::json!({"t": t0 + 0.1 * k as f64, "sensor": "inclinometer",
                               "pitch_deg": 0.5 + 1e-4 * k as f64, "roll_deg": -0.2})
            .to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_reading_is_stored_once_though_the_server_is_killed_ten_times() {
    const MACHINES: [&str; 3] = ["tbm-a", "tbm-b", "tbm-c"];
    const MESSAGES: usize = 150;
    const PER_MESSAGE: usize = 100;
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let url = broker.url("tn-crash");
    let mut server = ServerProcess::start_with_args(data.path(), &["--mqtt", &url]);
    let client = reqwest::Client::new();
    for machine in MACHINES {
        put_machine(&client, &server.url(""), machine).await;
    }
    wait_for_metric(&client, &server.url(""), "tunnelnav_mqtt_connected 1").await;

    // Three gateways publish at QoS 1, each message acknowledged by the
    // broker, whatever the server is doing.
    let t0 = (tunnelnav::clock::wall_clock_s() - 3600.0).floor();
    let mut gateways = Vec::new();
    for (g, machine) in MACHINES.into_iter().enumerate() {
        let port = broker.port;
        gateways.push(tokio::spawn(async move {
            let mut gateway = Peer::connect(port, &format!("gateway-{g}"), &[]).await;
            let topic = format!("tunnelnav/v1/{machine}/readings");
            for m in 0..MESSAGES {
                let body = inclinometer_lines(t0, m * PER_MESSAGE, PER_MESSAGE);
                gateway.publish(&topic, body.into_bytes()).await;
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }));
    }
    // Killed (SIGKILL) and restarted ten times while they publish.
    for _ in 0..10 {
        tokio::time::sleep(Duration::from_millis(450)).await;
        server.kill();
        server = ServerProcess::start_with_args(data.path(), &["--mqtt", &url]);
    }
    for gateway in gateways {
        gateway.await.unwrap();
    }
    // Every reading stored, once.
    let base = server.url("");
    let expected = MESSAGES * PER_MESSAGE;
    let deadline = Instant::now() + Duration::from_secs(60);
    for machine in MACHINES {
        loop {
            let stored = common::exported_readings(&client, &base, machine).await;
            if stored.len() == expected {
                let times: Vec<f64> = stored
                    .iter()
                    .map(|line| {
                        serde_json::from_str::<Value>(line).unwrap()["t"]
                            .as_f64()
                            .unwrap()
                    })
                    .collect();
                for (k, t) in times.iter().enumerate() {
                    assert!(
                        (t - (t0 + 0.1 * k as f64)).abs() < 1e-6,
                        "{machine}: reading {k} at {t}"
                    );
                }
                break;
            }
            assert!(
                stored.len() < expected && Instant::now() < deadline,
                "{machine}: {} of {expected} readings stored",
                stored.len()
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
    let metrics = common::get_text(&client, &base, "/metrics").await;
    eprintln!(
        "{}",
        metrics
            .lines()
            .filter(|l| l.starts_with("tunnelnav_mqtt"))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_reconnects_after_a_broker_restart_and_loses_nothing() {
    let Some((program, dir, broker)) = own_broker() else {
        return;
    };
    let port = broker.port;
    let data = tempfile::tempdir().unwrap();
    let (_server, client, base) =
        serve_connected(data.path(), &["--mqtt", &broker.url("tn-restart")]).await;
    put_machine(&client, &base, "tbm-r").await;
    let t0 = (tunnelnav::clock::wall_clock_s() - 3600.0).floor();
    let topic = "tunnelnav/v1/tbm-r/readings";
    let mut gateway = Peer::connect(port, "gateway-r", &[]).await;
    gateway
        .publish(topic, inclinometer_lines(t0, 0, 50).into_bytes())
        .await;
    wait_for_metric(
        &client,
        &base,
        "tunnelnav_mqtt_messages_total{outcome=\"acknowledged\"} 1",
    )
    .await;

    broker.stop();
    wait_for_metric(&client, &base, "tunnelnav_mqtt_connected 0").await;
    let broker = Broker::start(&program, dir.path(), port);
    // The gateway's client reconnects by itself and sends on; so does the
    // server, whose session (and subscription) the broker kept.
    for m in 1..5 {
        gateway
            .publish(topic, inclinometer_lines(t0, 50 * m, 50).into_bytes())
            .await;
    }
    wait_for_metric(&client, &base, "tunnelnav_mqtt_connected 1").await;
    wait_for_metric(
        &client,
        &base,
        "tunnelnav_mqtt_messages_total{outcome=\"acknowledged\"} 5",
    )
    .await;
    let stored = common::exported_readings(&client, &base, "tbm-r").await;
    assert_eq!(stored.len(), 250);
    let metrics = common::get_text(&client, &base, "/metrics").await;
    let reconnects: f64 = metrics
        .lines()
        .find_map(|l| l.strip_prefix("tunnelnav_mqtt_reconnects_total "))
        .unwrap()
        .parse()
        .unwrap();
    assert!(reconnects >= 1.0, "{reconnects}");
    drop(broker);
}

/// A mosquitto password file at `path` for `users` (name, password),
/// made by Debian's `mosquitto_passwd`.
fn password_file(path: &Path, users: &[(&str, &str)]) -> PathBuf {
    for (i, (user, password)) in users.iter().enumerate() {
        let mut command = Command::new("mosquitto_passwd");
        if i == 0 {
            command.arg("-c");
        }
        let status = command
            .arg("-b")
            .arg(path)
            .args([user, password])
            .status()
            .expect("mosquitto_passwd runs");
        assert!(status.success());
    }
    // mosquitto, started as root, reads it as its own user.
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o644)).unwrap();
    path.to_path_buf()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_broker_configuration_keeps_each_gateway_to_its_own_machine() {
    let Some(program) = mosquitto_program() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    // The users, as docs/operations.md has them created.
    let passwords = password_file(
        &dir.path().join("tunnelnav.passwd"),
        &[
            ("tunnelnav", "tn-secret"),
            ("scada", "sc-secret"),
            ("tbm-1", "g1"),
            ("tbm-2", "g2"),
        ],
    );
    let acl = dir.path().join("tunnelnav.acl");
    std::fs::copy("deploy/mosquitto/tunnelnav.acl", &acl).unwrap();
    let shipped = std::fs::read_to_string("deploy/mosquitto/tunnelnav.conf").unwrap();
    let mut config = shipped.clone();
    for (from, to) in [
        ("listener 1883", format!("listener {port} 127.0.0.1")),
        (
            "/etc/mosquitto/tunnelnav.passwd",
            passwords.display().to_string(),
        ),
        ("/etc/mosquitto/tunnelnav.acl", acl.display().to_string()),
        ("/var/lib/mosquitto/", format!("{}/", dir.path().display())),
    ] {
        assert!(
            config.contains(from),
            "the shipped configuration has `{from}`"
        );
        config = config.replace(from, &to);
    }
    let _broker = Broker::with_config(&program, dir.path(), port, &config);

    let data = tempfile::tempdir().unwrap();
    let url = format!("mqtt://tunnelnav:tn-secret@127.0.0.1:{port}?client_id=tn-acl");
    let (_server, client, base) = serve_connected(data.path(), &["--mqtt", &url]).await;
    put_machine(&client, &base, "tbm-1").await;
    put_machine(&client, &base, "tbm-2").await;

    let mut scada = Peer::connect_as(
        port,
        "scada-1",
        Some(("scada", "sc-secret")),
        &["tunnelnav/v1/+/acks"],
    )
    .await;
    let mut gateway = Peer::connect_as(
        port,
        "gateway-1",
        Some(("tbm-1", "g1")),
        &["tunnelnav/v1/tbm-1/acks", "tunnelnav/v1/tbm-2/acks"],
    )
    .await;
    let t0 = (tunnelnav::clock::wall_clock_s() - 3600.0).floor();
    // Its own machine's readings: stored, answered to it and to SCADA.
    assert_eq!(
        gateway
            .readings_accepted("tbm-1", inclinometer_lines(t0, 0, 5))
            .await,
        Some(5)
    );
    let (topic, _) = scada.next().await;
    assert_eq!(topic, "tunnelnav/v1/tbm-1/acks");
    // Another machine's: the broker denies them (mosquitto 2.0.11 then
    // answers a PUBACK with a reason code an MQTT 3.1.1 client cannot
    // read, and the connection drops: a second connection tries it).
    let intruder = Peer::connect_as(port, "gateway-1b", Some(("tbm-1", "g1")), &[]).await;
    intruder
        .client
        .publish(
            "tunnelnav/v1/tbm-2/readings",
            QoS::AtLeastOnce,
            false,
            inclinometer_lines(t0, 0, 5).into_bytes(),
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    drop(intruder);
    assert_eq!(
        gateway
            .readings_accepted("tbm-1", inclinometer_lines(t0, 5, 5))
            .await,
        Some(5)
    );
    assert_eq!(
        common::exported_readings(&client, &base, "tbm-1")
            .await
            .len(),
        10
    );
    assert!(
        common::exported_readings(&client, &base, "tbm-2")
            .await
            .is_empty()
    );

    // Nobody gets in without a password.
    let (_anonymous, mut eventloop) =
        AsyncClient::new(MqttOptions::new("anonymous", "127.0.0.1", port), 10);
    let refused = loop {
        match eventloop.poll().await {
            Ok(Event::Incoming(Packet::ConnAck(ack))) => break format!("{:?}", ack.code),
            Ok(_) => continue,
            Err(e) => break e.to_string(),
        }
    };
    assert!(
        refused.contains("NotAuthorized") || refused.contains("ot authorized"),
        "{refused}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn estimates_status_and_alarms_are_published() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let (_server, client, base) =
        serve_connected(data.path(), &["--mqtt", &broker.url("tn-pub")]).await;
    common::declare_machine(
        &client,
        &base,
        "tbm-pub",
        &common::on_an_axis("TBM published").to_string(),
    )
    .await;
    let mut scada = Peer::connect(
        broker.port,
        "scada",
        &[
            "tunnelnav/v1/tbm-pub/estimates/+",
            "tunnelnav/v1/tbm-pub/status",
        ],
    )
    .await;
    // Its status first: the machine is being published.
    while !scada.next().await.0.ends_with("/status") {}

    // 42 s off the axis (70 mm: a deviation warning), ending 24 s ago, in
    // one request: a burst of estimates.
    let from_t = (tunnelnav::clock::wall_clock_s() - 66.0).floor();
    common::post_ndjson(
        &client,
        &base,
        "tbm-pub",
        &common::laser_pairs(from_t, 21, 0.07),
    )
    .await;
    let started = Instant::now();
    let mut published: BTreeMap<String, Vec<Value>> = BTreeMap::new();
    while started.elapsed() < Duration::from_secs(2) {
        if let Ok(Some((topic, body))) =
            tokio::time::timeout(Duration::from_millis(200), scada.received.recv()).await
            && topic.contains("/estimates/")
        {
            published
                .entry(topic)
                .or_default()
                .push(serde_json::from_slice(&body).unwrap());
        }
    }
    // Each stream: at most one estimate per 100 ms, and the newest last.
    for stream in ["attitude", "dta"] {
        let topic = format!("tunnelnav/v1/tbm-pub/estimates/{stream}");
        let estimates = published
            .get(&topic)
            .unwrap_or_else(|| panic!("none on {topic}"));
        let stored = common::stream_estimates(&client, &base, "tbm-pub", stream).await;
        assert!(stored.len() >= 20, "{stream}: {}", stored.len());
        assert!(
            estimates.len() < stored.len() / 2,
            "{stream}: {} published",
            estimates.len()
        );
        assert_eq!(estimates.last(), stored.last(), "{stream}");
    }

    // A late subscriber finds the alarm and the status retained.
    let mut late = Peer::connect(
        broker.port,
        "late",
        &[
            "tunnelnav/v1/tbm-pub/alarms/+",
            "tunnelnav/v1/tbm-pub/status",
        ],
    )
    .await;
    let mut alarm_topic = None;
    let mut status = None;
    while alarm_topic.is_none() || status.is_none() {
        let (topic, body) = late.next().await;
        if topic.ends_with("/status") {
            // The one retained before the readings, then one with them
            // within 5 s.
            if body["latest"]["attitude"].is_object() {
                status = Some(body);
            }
        } else if body["kind"] == "deviation" {
            // (The inclinometer, silent since, has its own: stale_sensor.)
            assert_eq!(body["transition"], "raised", "{body}");
            alarm_topic = Some((topic, body["id"].as_i64().unwrap()));
        }
    }
    let status = status.unwrap();
    assert_eq!(status["machine"], "tbm-pub");
    assert!(status["latest"]["attitude"].is_object(), "{status}");
    let (alarm_topic, id) = alarm_topic.unwrap();
    assert_eq!(alarm_topic, format!("tunnelnav/v1/tbm-pub/alarms/{id}"));

    // Acknowledged: the retained message says so.
    let response = client
        .post(format!("{base}/api/v1/alarms/{id}/ack"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    loop {
        let (topic, body) = late.next().await;
        if topic == alarm_topic {
            assert_eq!(body["transition"], "acknowledged", "{body}");
            break;
        }
    }
    // Back on the axis for 24 s: cleared (10 s back, and a minute after
    // its onset, the deviation alarm's hold), then the retained message
    // gone.
    common::post_ndjson(
        &client,
        &base,
        "tbm-pub",
        &common::laser_pairs(from_t + 42.0, 12, 0.0),
    )
    .await;
    loop {
        let (topic, body) = late.next_raw().await;
        if topic == alarm_topic {
            let body: Value = serde_json::from_slice(&body).unwrap();
            assert_eq!(body["transition"], "cleared", "{body}");
            break;
        }
    }
    loop {
        let (topic, body) = late.next_raw().await;
        if topic == alarm_topic {
            assert!(body.is_empty(), "the retained alarm is removed");
            break;
        }
    }
    let mut later = Peer::connect(broker.port, "later", &["tunnelnav/v1/tbm-pub/alarms/+"]).await;
    assert!(
        tokio::time::timeout(Duration::from_millis(500), later.received.recv())
            .await
            .is_err(),
        "no alarm is retained once cleared"
    );
}

/// `load --mode mqtt` reports both paths of one run (the numbers are the
/// benchmark's, docs/operations.md "Load"; here only that it runs).
#[test]
fn the_load_generator_measures_the_broker_path_beside_http() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let output = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args(["load", "--mode", "mqtt", "--mqtt"])
        .arg(format!("mqtt://127.0.0.1:{}", broker.port))
        .args([
            "--machines",
            "2",
            "--readings",
            "500",
            "--batch",
            "100",
            "--concurrency",
            "2",
        ])
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{report}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        report.contains("mode Batch: 1000 readings in 10 requests"),
        "{report}"
    );
    assert!(
        report.contains("mode Mqtt: 1000 readings in 10 messages"),
        "{report}"
    );
}

/// `demo --mqtt`: the first TBM's gateway publishes through the broker and
/// its readings are stored (the demo's data dir, read by `serve` after).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_sends_one_gateway_through_the_broker() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args([
            "demo",
            "--listen",
            "127.0.0.1:0",
            "--rate",
            "300",
            "--seconds",
            "6",
        ])
        .arg("--mqtt")
        .arg(broker.url("tn-demo"))
        .arg("--data-dir")
        .arg(data.path())
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(!stderr.contains("will retry"), "{stderr}");
    drop(broker);
    let server = ServerProcess::start(data.path());
    let client = reqwest::Client::new();
    // 6 s at 300× is 30 simulated minutes of inclinometer readings.
    let stored = common::exported_readings(&client, &server.url(""), "tbm-north").await;
    assert!(stored.len() > 500, "{}", stored.len());
}

/// A CA, and certificates it signed for the broker (`localhost`,
/// 127.0.0.1) and for tunnelnav as a client, as PEM files in `dir`:
/// `{name}-ca.pem`, `{name}-broker.pem`/`.key`, `{name}-client.pem`/`.key`.
fn site_certificates(dir: &Path, name: &str) {
    use rcgen::{
        BasicConstraints, CertificateParams, CertifiedIssuer, DnType, ExtendedKeyUsagePurpose,
        IsCa, KeyPair, KeyUsagePurpose,
    };
    let mut ca = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca.distinguished_name
        .push(DnType::CommonName, format!("{name} site CA"));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    let ca = CertifiedIssuer::self_signed(ca, KeyPair::generate().unwrap()).unwrap();
    let write = |file: String, text: String| {
        use std::os::unix::fs::PermissionsExt;
        let path = dir.join(file);
        std::fs::write(&path, text).unwrap();
        // mosquitto, started as root, reads them as its own user.
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
    };
    write(format!("{name}-ca.pem"), ca.pem());
    for (role, names, usage) in [
        (
            "broker",
            vec!["localhost".to_string(), "127.0.0.1".to_string()],
            ExtendedKeyUsagePurpose::ServerAuth,
        ),
        (
            "client",
            vec!["tunnelnav".to_string()],
            ExtendedKeyUsagePurpose::ClientAuth,
        ),
    ] {
        let key = KeyPair::generate().unwrap();
        let mut params = CertificateParams::new(names).unwrap();
        params
            .distinguished_name
            .push(DnType::CommonName, format!("{name} {role}"));
        params.extended_key_usages = vec![usage];
        let certificate = params.signed_by(&key, &ca).unwrap();
        write(format!("{name}-{role}.pem"), certificate.pem());
        write(format!("{name}-{role}.key"), key.serialize_pem());
    }
}

/// TLS to a broker whose certificate the site's own CA signed and which
/// requires a client certificate and a password: `[mqtt]` names the CA,
/// tunnelnav's certificate and key and a password file, and readings a
/// gateway publishes on the broker's plain listener are stored. With
/// another CA's file, tunnelnav never connects; settings that do not fit
/// are refused at start, naming what is wrong.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_to_a_broker_of_the_sites_own_ca_with_a_client_certificate() {
    let Some(program) = mosquitto_program() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    site_certificates(dir.path(), "site");
    site_certificates(dir.path(), "other");
    let passwords = password_file(
        &dir.path().join("passwd"),
        &[("tunnelnav", "tn-secret"), ("gw", "gw-secret")],
    );
    let (plain, tls) = (free_port(), free_port());
    let d = dir.path().display();
    let broker_config = format!(
        "per_listener_settings false\nallow_anonymous false\npassword_file {}\n\
         persistence true\npersistence_location {d}/\n\
         listener {plain} 127.0.0.1\n\
         listener {tls} 127.0.0.1\ncafile {d}/site-ca.pem\ncertfile {d}/site-broker.pem\n\
         keyfile {d}/site-broker.key\nrequire_certificate true\n",
        passwords.display()
    );
    let _broker = Broker::with_config(&program, dir.path(), plain, &broker_config);
    let deadline = Instant::now() + Duration::from_secs(10);
    while std::net::TcpStream::connect(("127.0.0.1", tls)).is_err() {
        assert!(
            Instant::now() < deadline,
            "mosquitto does not listen on TLS"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let secret = dir.path().join("tunnelnav-mqtt-password");
    std::fs::write(&secret, "tn-secret\n").unwrap();
    let config_file = |name: &str, ca: &str, client_id: &str| {
        let path = dir.path().join(name);
        std::fs::write(
            &path,
            format!(
                "[mqtt]\nurl = \"mqtts://localhost:{tls}?client_id={client_id}\"\n\
                 username = \"tunnelnav\"\npassword_file = \"{}\"\n\
                 ca_file = \"{d}/{ca}-ca.pem\"\n\
                 client_cert_file = \"{d}/site-client.pem\"\n\
                 client_key_file = \"{d}/site-client.key\"\n",
                secret.display()
            ),
        )
        .unwrap();
        path
    };

    let data = tempfile::tempdir().unwrap();
    let site = config_file("site.toml", "site", "tn-tls");
    let (server, client, base) =
        serve_connected(data.path(), &["--config", site.to_str().unwrap()]).await;
    put_machine(&client, &base, "tbm-tls").await;
    let mut gateway = Peer::connect_as(
        plain,
        "gw-tls",
        Some(("gw", "gw-secret")),
        &["tunnelnav/v1/tbm-tls/acks"],
    )
    .await;
    let t0 = (tunnelnav::clock::wall_clock_s() - 3600.0).floor();
    assert_eq!(
        gateway
            .readings_accepted("tbm-tls", inclinometer_lines(t0, 0, 5))
            .await,
        Some(5)
    );
    assert_eq!(
        common::exported_readings(&client, &base, "tbm-tls")
            .await
            .len(),
        5
    );
    server.kill();

    // Another CA's file: the broker's certificate is not trusted.
    let other = config_file("other.toml", "other", "tn-other");
    let data = tempfile::tempdir().unwrap();
    let server =
        ServerProcess::start_with_args(data.path(), &["--config", other.to_str().unwrap()]);
    let base = server.url("");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let metrics = common::get_text(&client, &base, "/metrics").await;
        let reconnects: f64 = metrics
            .lines()
            .find_map(|l| l.strip_prefix("tunnelnav_mqtt_reconnects_total "))
            .unwrap()
            .parse()
            .unwrap();
        assert!(
            metrics.lines().any(|l| l == "tunnelnav_mqtt_connected 0"),
            "connected to a broker whose CA it was not given"
        );
        if reconnects >= 2.0 {
            break;
        }
        assert!(Instant::now() < deadline, "no failed connection counted");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    server.kill();

    // Settings that do not fit: refused at start, naming the culprit.
    for (config, expected) in [
        (
            format!("[mqtt]\nurl = \"mqtt://127.0.0.1:{plain}\"\nca_file = \"{d}/site-ca.pem\"\n"),
            "mqtt.ca_file is for TLS",
        ),
        (
            format!("[mqtt]\nurl = \"mqtts://127.0.0.1:{tls}\"\nca_file = \"{d}/absent.pem\"\n"),
            "absent.pem",
        ),
        (
            format!("[mqtt]\nurl = \"mqtt://127.0.0.1:{plain}\"\nestimates_hz = 0\n"),
            "mqtt.estimates_hz",
        ),
    ] {
        let path = dir.path().join("bad.toml");
        std::fs::write(&path, config).unwrap();
        let data = tempfile::tempdir().unwrap();
        let output = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(data.path())
            .arg("--config")
            .arg(&path)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{expected}: started");
        assert!(stderr.contains(expected), "{expected}: {stderr}");
    }
}

/// Back-pressure: a full store (the database capped at 1 MB) refuses the
/// readings of a message; tunnelnav neither acknowledges nor answers it,
/// and tries again. When space returns (a larger cap after a restart), the
/// broker delivers what was not acknowledged: every reading stored once,
/// in order, and the estimates are the replay's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_message_is_kept_by_the_broker_until_it_can_be_stored() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let url = broker.url("tn-full");
    let (server, client, base) =
        serve_connected(data.path(), &["--mqtt", &url, "--max-database-mb", "1"]).await;
    put_machine(&client, &base, "full").await;

    let lines = drive(6.0, 9, Vec::new());
    let mut acks = Peer::connect(broker.port, "acks-full", &["tunnelnav/v1/full/acks"]).await;
    let mut gateway = Peer::connect(broker.port, "gateway-full", &[]).await;
    let chunks: Vec<&[String]> = lines.chunks(500).collect();
    for chunk in &chunks {
        gateway
            .publish("tunnelnav/v1/full/readings", chunk.join("\n").into_bytes())
            .await;
    }
    // The store fills up: refusals counted, and the answers stop short.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let metrics = common::get_text(&client, &base, "/metrics").await;
        let refused = metrics
            .lines()
            .find_map(|l| l.strip_prefix("tunnelnav_mqtt_messages_total{outcome=\"refused\"} "))
            .and_then(|n| n.parse::<f64>().ok())
            .unwrap_or(0.0);
        if refused >= 2.0 {
            break;
        }
        assert!(Instant::now() < deadline, "no refusal counted:\n{metrics}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut answered = 0;
    while let Ok(Some((_, body))) =
        tokio::time::timeout(Duration::from_millis(500), acks.received.recv()).await
    {
        let ack: Value = serde_json::from_slice(&body).unwrap();
        assert!(ack.get("error").is_none(), "a refusal was answered: {ack}");
        answered += 1;
    }
    assert!(
        0 < answered && answered < chunks.len(),
        "{answered} of {} messages answered before the store filled",
        chunks.len()
    );
    assert!(
        common::exported_readings(&client, &base, "full")
            .await
            .len()
            < lines.len(),
        "all stored under the cap"
    );
    assert_eq!(server.terminate().code(), Some(0));

    // Space returns: the broker delivers the rest.
    let server =
        ServerProcess::start_with_args(data.path(), &["--mqtt", &url, "--max-database-mb", "100"]);
    let base = server.url("");
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let stored = common::exported_readings(&client, &base, "full").await;
        if stored.len() >= lines.len() {
            assert_eq!(stored, lines, "every reading once, in order");
            break;
        }
        assert!(
            Instant::now() < deadline,
            "{} of {} readings stored",
            stored.len(),
            lines.len()
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert_eq!(
        all_estimates(&client, &base, "full").await,
        replay("full", &lines)
    );
    eprintln!(
        "{answered} of {} messages in before the store filled; all {} readings after",
        chunks.len(),
        lines.len()
    );
}

/// Node-RED's program: `TUNNELNAV_NODE_RED` (`.ci/run` installs it from
/// npm) or `node-red` on the PATH; `None` (saying so) where there is
/// neither, unless `TUNNELNAV_NODE_RED_TEST=required`.
fn node_red_program() -> Option<PathBuf> {
    let found = std::env::var_os("TUNNELNAV_NODE_RED")
        .map(PathBuf::from)
        .or_else(|| {
            let path = std::env::var_os("PATH").unwrap_or_default();
            std::env::split_paths(&path)
                .map(|dir| dir.join("node-red"))
                .find(|p| p.is_file())
        })
        .filter(|p| p.is_file());
    if found.is_none() {
        assert!(
            std::env::var("TUNNELNAV_NODE_RED_TEST").as_deref() != Ok("required"),
            "TUNNELNAV_NODE_RED_TEST=required but there is no Node-RED \
             (npm install node-red; TUNNELNAV_NODE_RED=.../node_modules/.bin/node-red)"
        );
        eprintln!("SKIPPED: the Node-RED example needs node-red (TUNNELNAV_NODE_RED)");
    }
    found
}

/// A network link to the broker that can be cut and restored, as a
/// tunnel's link to the surface is: a TCP relay on a port of its own.
struct Link {
    port: u16,
    up: tokio::sync::watch::Sender<bool>,
}

impl Link {
    async fn to(upstream: u16) -> Link {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let port = listener.local_addr().unwrap().port();
        let (up, watch) = tokio::sync::watch::channel(true);
        tokio::spawn(async move {
            while let Ok((mut inside, _)) = listener.accept().await {
                let mut state = watch.clone();
                if !*state.borrow() {
                    continue; // down: the connection is dropped at once
                }
                tokio::spawn(async move {
                    let Ok(mut outside) =
                        tokio::net::TcpStream::connect(("127.0.0.1", upstream)).await
                    else {
                        return;
                    };
                    tokio::select! {
                        _ = tokio::io::copy_bidirectional(&mut inside, &mut outside) => {}
                        _ = state.wait_for(|up| !*up) => {}
                    }
                });
            }
        });
        Link { port, up }
    }

    fn cut(&self) {
        self.up.send_replace(false);
    }

    fn restore(&self) {
        self.up.send_replace(true);
    }
}

/// A child process killed when dropped.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Waits until `log` (a file) has a line containing `text`.
async fn wait_for_log(log: &Path, text: &str) {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let written = std::fs::read_to_string(log).unwrap_or_default();
        if written.contains(text) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "no `{text}` in the log:\n{written}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The stored readings' times, sorted.
async fn stored_times(client: &reqwest::Client, base: &str, machine: &str) -> Vec<f64> {
    let mut times: Vec<f64> = common::exported_readings(client, base, machine)
        .await
        .iter()
        .map(|line| {
            let reading: Value = serde_json::from_str(line).unwrap();
            assert_eq!(reading["sensor"], "inclinometer", "{line}");
            assert_eq!(reading["pitch_deg"], 0.42, "{line}");
            reading["t"].as_f64().unwrap()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_node_red_example_flow_sends_every_reading_through_a_link_that_drops() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let Some(node_red) = node_red_program() else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let (_server, client, base) =
        serve_connected(data.path(), &["--mqtt", &broker.url("tn-red")]).await;

    // The shipped flow, as a site imports it, with the broker it names
    // through the environment.
    let link = Link::to(broker.port).await;
    let user_dir = tempfile::tempdir().unwrap();
    std::fs::copy(
        "deploy/node-red/gateway-flow.json",
        user_dir.path().join("flows.json"),
    )
    .unwrap();
    std::fs::write(
        user_dir.path().join("settings.js"),
        format!(
            "module.exports = {{ uiHost: \"127.0.0.1\", uiPort: {}, flowFile: \"flows.json\", \
             credentialSecret: false, mqttReconnectTime: 1000 }};\n",
            free_port()
        ),
    )
    .unwrap();
    let log = user_dir.path().join("node-red.log");
    let _gateway = Killed(
        Command::new(&node_red)
            .arg("--userDir")
            .arg(user_dir.path())
            .env("MQTT_BROKER", format!("mqtt://127.0.0.1:{}", link.port))
            .env("GATEWAY_CLIENT_ID", "gw-tbm-north")
            .stdout(std::fs::File::create(&log).unwrap())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("node-red starts"),
    );

    // Before the machine is declared, tunnelnav's answer (an error) comes
    // back to the flow, which logs it.
    wait_for_log(
        &log,
        "tunnelnav refused a message: unknown machine `tbm-north`",
    )
    .await;
    put_machine(&client, &base, "tbm-north").await;
    let deadline = Instant::now() + Duration::from_secs(30);
    while stored_times(&client, &base, "tbm-north").await.len() < 20 {
        assert!(Instant::now() < deadline, "no readings from Node-RED");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }

    // The link drops for 3 s: the flow holds its readings, and sends them
    // when it is back.
    let cut_s = tunnelnav::clock::wall_clock_s();
    link.cut();
    wait_for_log(&log, "Disconnected from broker").await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let restored_s = tunnelnav::clock::wall_clock_s();
    link.restore();
    let deadline = Instant::now() + Duration::from_secs(30);
    let times = loop {
        let times = stored_times(&client, &base, "tbm-north").await;
        if times.last().is_some_and(|&t| t > restored_s + 2.0) {
            break times;
        }
        assert!(Instant::now() < deadline, "nothing after the link is back");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert!(times[0] < cut_s - 1.0, "{} {cut_s}", times[0]);
    // One reading every 0.1 s, none missing across the drop (duplicates
    // would be absorbed by the store).
    let widest = times
        .windows(2)
        .map(|pair| pair[1] - pair[0])
        .fold(0.0, f64::max);
    assert!(
        widest < 0.5,
        "a gap of {widest:.2} s in {} readings",
        times.len()
    );
    let written = std::fs::read_to_string(&log).unwrap();
    assert!(
        !written.contains("tunnelnav rejected reading") && !written.contains("dropped"),
        "{written}"
    );
    eprintln!(
        "{} readings from Node-RED, widest gap {widest:.3} s across a 3 s drop",
        times.len()
    );
}

/// While tunnelnav cannot reach the broker, nothing is queued for it: when
/// it is back, the newest estimate of each stream is published, not every
/// one made while it was away.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn estimates_made_while_the_broker_is_away_are_not_sent_stale() {
    let Some((_program, _dir, broker)) = own_broker() else {
        return;
    };
    let link = Link::to(broker.port).await;
    let data = tempfile::tempdir().unwrap();
    let url = format!("mqtt://127.0.0.1:{}?client_id=tn-away", link.port);
    let (_server, client, base) = serve_connected(data.path(), &["--mqtt", &url]).await;
    put_machine(&client, &base, "tbm-away").await;
    let mut scada = Peer::connect(
        broker.port,
        "scada-away",
        &["tunnelnav/v1/tbm-away/estimates/attitude"],
    )
    .await;
    let t0 = (tunnelnav::clock::wall_clock_s() - 600.0).floor();
    // Readings `first..first + 10`, posted over HTTP.
    let post = async |first: usize| {
        let lines: Vec<String> = inclinometer_lines(t0, first, 10)
            .lines()
            .map(str::to_string)
            .collect();
        common::post_ndjson(&client, &base, "tbm-away", &lines).await
    };
    post(0).await;
    let (_, first) = scada.next().await;
    assert!(first["t"].as_f64().is_some(), "{first}");

    link.cut();
    wait_for_metric(&client, &base, "tunnelnav_mqtt_connected 0").await;
    // Eight batches, each a new newest estimate, over 2 s (20 ticks of the
    // 10 Hz publisher).
    for batch in 1..=8 {
        post(10 * batch).await;
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    let newest = t0 + 0.1 * 89.0;
    while scada.received.try_recv().is_ok() {}
    link.restore();
    wait_for_metric(&client, &base, "tunnelnav_mqtt_connected 1").await;
    let (_, estimate) = scada.next().await;
    assert!(
        (estimate["t"].as_f64().unwrap() - newest).abs() < 1e-6,
        "{estimate}"
    );
    tokio::time::sleep(Duration::from_secs(1)).await;
    let mut more = Vec::new();
    while let Ok((_, body)) = scada.received.try_recv() {
        more.push(String::from_utf8_lossy(&body).into_owned());
    }
    assert!(
        more.is_empty(),
        "stale estimates after the newest: {more:?}"
    );
}
