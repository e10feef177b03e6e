//! Helpers shared by the server tests: a server in this process on an
//! ephemeral port, the real binary as a child process, simulated drives.

#![allow(dead_code)]

pub mod postgres;

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};

use tokio::sync::oneshot;
use tunnelnav::clock::Clock;
use tunnelnav::server::settings::Limits;
use tunnelnav::server::{self, AppState, ServerOptions, SharedState};
use tunnelnav::sim::tbm::{Dropout, TbmDrive, TbmScenario};

/// A server running in this process.
pub struct TestServer {
    pub address: SocketAddr,
    pub state: SharedState,
    stop: Option<oneshot::Sender<()>>,
    task: Option<tokio::task::JoinHandle<()>>,
}

impl TestServer {
    pub async fn start(data_dir: &Path) -> TestServer {
        Self::start_with(data_dir, Limits::default()).await
    }

    pub async fn start_with(data_dir: &Path, limits: Limits) -> TestServer {
        Self::start_configured(data_dir, limits, Default::default()).await
    }

    /// A server posting alarm changes to `webhooks`.
    pub async fn start_configured(
        data_dir: &Path,
        limits: Limits,
        webhooks: tunnelnav::server::settings::WebhookConfig,
    ) -> TestServer {
        let any_port = "127.0.0.1:0".parse().unwrap();
        Self::launch(data_dir, limits, webhooks, any_port, None).await
    }

    /// A site server forwarding to `forward`'s office.
    pub async fn start_site(
        data_dir: &Path,
        forward: tunnelnav::server::forward::ForwardOptions,
    ) -> TestServer {
        let any_port = "127.0.0.1:0".parse().unwrap();
        Self::launch(
            data_dir,
            Limits::default(),
            Default::default(),
            any_port,
            Some(forward),
        )
        .await
    }

    /// A server on `address` (the one a stopped server had, say).
    pub async fn start_at(data_dir: &Path, address: std::net::SocketAddr) -> TestServer {
        Self::launch(
            data_dir,
            Limits::default(),
            Default::default(),
            address,
            None,
        )
        .await
    }

    async fn launch(
        data_dir: &Path,
        limits: Limits,
        webhooks: tunnelnav::server::settings::WebhookConfig,
        address: std::net::SocketAddr,
        forward: Option<tunnelnav::server::forward::ForwardOptions>,
    ) -> TestServer {
        server::metrics::install();
        let state = AppState::start(ServerOptions {
            postgres: None,
            data_dir: data_dir.to_path_buf(),
            machines: Vec::new(),
            limits,
            clock: Clock::system(),
            retention: tunnelnav::store::retention::Retention::default(),
            webhooks,
            cluster: None,
            forward,
            site_backlog_alarm_s: tunnelnav::server::settings::SitesConfig::default()
                .backlog_alarm_s(),
            access_log: tracing::Level::INFO,
        })
        .await
        .expect("server starts");
        let listener = tokio::net::TcpListener::bind(address).await.unwrap();
        let address = listener.local_addr().unwrap();
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(server::run(listener, state.clone(), async move {
            let _ = stopped.await;
        }));
        TestServer {
            address,
            state,
            stop: Some(stop),
            task: Some(tokio::spawn(async move {
                task.await.unwrap().unwrap();
            })),
        }
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.address)
    }

    pub fn ws_url(&self, path: &str) -> String {
        format!("ws://{}{path}", self.address)
    }

    /// Graceful stop: live sockets closed, machines snapshotted.
    pub async fn stop(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(task) = self.task.take() {
            task.await.unwrap();
        }
    }
}

/// The real binary serving `data_dir` on an ephemeral port.
pub struct ServerProcess {
    pub child: Child,
    pub address: SocketAddr,
}

impl ServerProcess {
    pub fn start(data_dir: &Path) -> ServerProcess {
        Self::start_with_args(data_dir, &[])
    }

    /// `serve` with more arguments.
    pub fn start_with_args(data_dir: &Path, args: &[&str]) -> ServerProcess {
        let mut child = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(data_dir)
            .args(args)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("tunnelnav runs");
        let stdout = child.stdout.take().unwrap();
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line).unwrap();
        let address = line
            .trim()
            .strip_prefix("listening on http://")
            .unwrap_or_else(|| panic!("unexpected first line: {line:?}"))
            .parse()
            .unwrap();
        ServerProcess { child, address }
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.address)
    }

    pub fn kill(mut self) {
        self.child.kill().unwrap(); // SIGKILL
        self.child.wait().unwrap();
    }

    /// SIGTERM, then waits for a clean exit.
    pub fn terminate(mut self) -> std::process::ExitStatus {
        let pid = self.child.id().to_string();
        Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        self.child.wait().unwrap()
    }
}

impl Drop for ServerProcess {
    /// A failed test must not leave a server behind.
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A simulated drive as NDJSON lines (readings only).
pub fn drive(hours: f64, seed: u64, dropouts: Vec<Dropout>) -> Vec<String> {
    TbmDrive::new(TbmScenario {
        seed,
        hours,
        dropouts,
        ..TbmScenario::default()
    })
    .unwrap()
    .map(|event| event.reading.to_json())
    .collect()
}

pub async fn put_machine(client: &reqwest::Client, base: &str, machine: &str) {
    declare_machine(
        client,
        base,
        machine,
        r#"{"name": "Test TBM", "engines": {"attitude": {}}}"#,
    )
    .await;
}

/// `PUT`s a machine declaration; asserts it was accepted.
pub async fn declare_machine(client: &reqwest::Client, base: &str, machine: &str, body: &str) {
    let response = client
        .put(format!("{base}/api/v1/machines/{machine}"))
        .body(body.to_string())
        .send()
        .await
        .unwrap();
    assert!(
        response.status().is_success(),
        "{:?}",
        response.text().await
    );
}

/// A server in `data_dir` with one declared `attitude` machine, a client
/// and the server's base URL.
pub async fn server_with_machine(
    data_dir: &Path,
    machine: &str,
) -> (TestServer, reqwest::Client, String) {
    let server = TestServer::start(data_dir).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    put_machine(&client, &base, machine).await;
    (server, client, base)
}

/// Sends NDJSON lines as one ingest request, whatever the answer.
pub async fn send_ndjson(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
    lines: &[String],
) -> reqwest::Result<reqwest::Response> {
    let mut body = lines.join("\n");
    body.push('\n');
    client
        .post(format!("{base}/api/v1/machines/{machine}/readings"))
        .header("content-type", "application/x-ndjson")
        .body(body)
        .send()
        .await
}

/// Posts NDJSON lines as one request; asserts a 200 and returns the ack.
pub async fn post_ndjson(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
    lines: &[String],
) -> serde_json::Value {
    let response = send_ndjson(client, base, machine, lines).await.unwrap();
    assert_eq!(response.status(), 200);
    serde_json::from_slice(&response.bytes().await.unwrap()).unwrap()
}

/// The key of a reading line: its time (bits) and sensor.
pub fn reading_key(line: &str) -> (u64, String) {
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    (
        v["t"].as_f64().unwrap().to_bits(),
        v["sensor"].as_str().unwrap().to_string(),
    )
}

/// Every stored reading of a machine, as the NDJSON export's lines.
pub async fn exported_readings(client: &reqwest::Client, base: &str, machine: &str) -> Vec<String> {
    let response = client
        .get(format!("{base}/api/v1/machines/{machine}/readings"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let text = response.text().await.unwrap();
    text.lines().map(str::to_string).collect()
}

/// Every stored estimate of a machine, not downsampled.
pub async fn all_estimates(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
) -> Vec<serde_json::Value> {
    stream_estimates(client, base, machine, "").await
}

/// Every stored estimate of a machine's `stream` (an engine or stage
/// name; empty: the machine's one engine), not downsampled.
pub async fn stream_estimates(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
    stream: &str,
) -> Vec<serde_json::Value> {
    let engine = if stream.is_empty() {
        String::new()
    } else {
        format!("&engine={stream}")
    };
    let response = client
        .get(format!(
            "{base}/api/v1/machines/{machine}/estimates?max_points=100000{engine}"
        ))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let body: serde_json::Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    assert_eq!(body["downsampled"], false);
    body["estimates"].as_array().unwrap().clone()
}

/// Runs `tunnelnav replay` over the lines; its estimates.
pub fn replay(machine: &str, lines: &[String]) -> Vec<serde_json::Value> {
    replay_engine(machine, "attitude", &[], lines)
}

/// Runs `tunnelnav replay --engine ENGINE --param ...` over the lines;
/// the engine's estimates (without those of the stages after it).
pub fn replay_engine(
    machine: &str,
    engine: &str,
    params: &[&str],
    lines: &[String],
) -> Vec<serde_json::Value> {
    replay_streams(machine, engine, params, lines)
        .into_iter()
        .filter(|e| e["engine"] == engine)
        .collect()
}

/// Every estimate `tunnelnav replay --engine ENGINE --param ...` writes:
/// the engine's and its stages'.
pub fn replay_streams(
    machine: &str,
    engine: &str,
    params: &[&str],
    lines: &[String],
) -> Vec<serde_json::Value> {
    use std::io::Write;
    let mut args = vec!["replay", "--engine", engine, "--machine", machine];
    for param in params {
        args.extend(["--param", param]);
    }
    args.push("-");
    let mut child = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args(&args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Feed stdin from another thread while stdout is drained.
    let mut stdin = child.stdin.take().unwrap();
    let input = lines.join("\n");
    let feeder = std::thread::spawn(move || {
        stdin.write_all(input.as_bytes()).unwrap();
        stdin.write_all(b"\n").unwrap();
    });
    let output = child.wait_with_output().unwrap();
    feeder.join().unwrap();
    assert!(output.status.success());
    String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// `GET base + path` answered 200 with JSON: the value.
/// The body of `GET {base}{path}` as text.
pub async fn get_text(client: &reqwest::Client, base: &str, path: &str) -> String {
    client
        .get(format!("{base}{path}"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap()
}

pub async fn get_json(client: &reqwest::Client, base: &str, path: &str) -> serde_json::Value {
    let response = client.get(format!("{base}{path}")).send().await.unwrap();
    assert_eq!(response.status(), 200, "{path}");
    serde_json::from_slice(&response.bytes().await.unwrap()).unwrap()
}

/// `PUT`s `body` (of `content_type`, if given) to `url`; asserts a 400
/// with a JSON error and returns the error's text.
pub async fn put_refused(
    client: &reqwest::Client,
    url: &str,
    content_type: Option<&str>,
    body: String,
) -> String {
    let mut request = client.put(url).body(body);
    if let Some(content_type) = content_type {
        request = request.header("content-type", content_type);
    }
    let response = request.send().await.unwrap();
    assert_eq!(response.status(), 400);
    let body: serde_json::Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    body["error"].as_str().unwrap().to_string()
}

/// Runs `promtool` with `args` in `dir`, `input` on its stdin; `None` (and
/// says so) when it is not installed, unless `TUNNELNAV_PROMTOOL_TEST=required`
/// (CI), where that fails the test.
pub fn promtool(args: &[&str], dir: &Path, input: Option<&str>) -> Option<std::process::Output> {
    use std::io::Write;
    let spawned = Command::new("promtool")
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match spawned {
        Ok(child) => child,
        Err(e) => {
            assert!(
                std::env::var("TUNNELNAV_PROMTOOL_TEST").as_deref() != Ok("required"),
                "TUNNELNAV_PROMTOOL_TEST=required but promtool does not run ({e}); \
                 apt-get install prometheus"
            );
            eprintln!("SKIPPED: promtool not found ({e}); apt-get install prometheus");
            return None;
        }
    };
    let mut stdin = child.stdin.take().unwrap();
    if let Some(input) = input {
        stdin.write_all(input.as_bytes()).unwrap();
    }
    drop(stdin);
    Some(child.wait_with_output().unwrap())
}

/// Spawns a prepared `tunnelnav serve` (stdout piped here) and returns it
/// with its base URL, read from its first line (`listening on URL`).
pub fn spawn_serving(command: &mut Command) -> (Child, String) {
    let mut child = command
        .stdout(Stdio::piped())
        .spawn()
        .expect("tunnelnav runs");
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    let base = first
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {first:?}"))
        .to_string();
    (child, base)
}

/// A read token named `name` in the store of `dir`, created now, as
/// `tunnelnav token create` makes one; a running server takes it up within
/// its token refresh (2 s).
pub fn read_token(dir: &Path, name: &str) -> String {
    token_of(dir, name, tunnelnav::auth::Scope::Read)
}

/// Creates an `operator` token named `name` (read, and acknowledge
/// alarms) in the SQLite store in `dir`.
pub fn operator_token(dir: &Path, name: &str) -> String {
    token_of(dir, name, tunnelnav::auth::Scope::Operator)
}

/// Creates a token of `scope` (for no machine) in the SQLite store in `dir`.
fn token_of(dir: &Path, name: &str, scope: tunnelnav::auth::Scope) -> String {
    let conn = tunnelnav::store::Store::connect(dir).unwrap();
    tunnelnav::store::sqlite::tokens::create(
        &conn,
        name,
        scope,
        None,
        tunnelnav::clock::wall_clock_s(),
    )
    .unwrap()
    .1
}

/// An attitude machine on a straight axis due north from (1000, 5000),
/// ±50/100 mm horizontal tolerances .
pub fn on_an_axis(name: &str) -> serde_json::Value {
    serde_json::json!({
        "name": name,
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.0, 0.0, 0.0], "rear_m": [-5.0, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "alignment": {"name": "straight",
                      "start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
                      "horizontal": [{"type": "line", "length_m": 100.0}],
                      "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}
    })
}

/// Laser readings every 2 s from `from_t`, `count` of them, `east_m` east
/// of the axis, each followed by an inclinometer reading a second later.
pub fn laser_pairs(from_t: f64, count: u32, east_m: f64) -> Vec<String> {
    (0..count)
        .flat_map(|i| {
            let t = from_t + 2.0 * f64::from(i);
            [
                serde_json::json!({"t": t, "sensor": "laser", "pitch_deg": 0.0, "roll_deg": 0.0,
                                   "yaw_deg": 0.0, "easting_m": 1000.0 + east_m,
                                   "northing_m": 5020.0, "height_m": 50.0}),
                serde_json::json!({"t": t + 1.0, "sensor": "inclinometer",
                                   "pitch_deg": 0.0, "roll_deg": 0.0}),
            ]
        })
        .map(|reading| reading.to_string())
        .collect()
}

/// One CSV line's cells, unquoted (quoted cells with doubled quotes).
pub fn csv_cells(line: &str) -> Vec<String> {
    let (mut cells, mut cell, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => cells.push(std::mem::take(&mut cell)),
            _ => cell.push(c),
        }
    }
    cells.push(cell);
    cells
}
