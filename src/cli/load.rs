//! `tunnelnav load`: drives a server over loopback with many concurrent
//! gateways and reports throughput and post-to-live-estimate latency.
//!
//! Without `--url` it starts `tunnelnav serve` itself (this binary, port 0,
//! a fresh data dir under the system temp dir, removed afterwards), so one
//! command reproduces a number.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};
use futures_util::StreamExt;

use super::CliError;
use crate::sim::tbm::{TbmDrive, TbmScenario};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LoadMode {
    /// Each gateway posts batches of `--batch` readings.
    Batch,
    /// Each gateway posts one reading per request.
    Single,
    /// Paced single posts at `--rate` readings/s in all, a live socket per
    /// machine; latency from post to the estimate on the socket.
    Live,
    /// Stores `--estimates` estimates for one machine (1 Hz inclinometer),
    /// then times 2000-point history queries over ranges of it.
    History,
    /// `batch` over HTTP, then the same through the MQTT broker `--mqtt`
    /// (one gateway per machine publishing `--batch` readings a message at
    /// QoS 1, until every reading is answered on the acks topics): both
    /// rates, in one run.
    Mqtt,
}

#[derive(Debug, Args)]
pub struct LoadArgs {
    /// What to measure.
    #[arg(long, value_enum, default_value = "batch")]
    pub mode: LoadMode,
    /// A running server; without it one is started for the run.
    #[arg(long)]
    pub url: Option<String>,
    /// An admin token for that server (it declares machines and posts
    /// readings); sent as `Authorization: Bearer`.
    #[arg(long, env = "TUNNELNAV_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Machines (one gateway each, several for `single`).
    #[arg(long, default_value_t = 50)]
    pub machines: usize,
    /// Concurrent connections posting (`batch`, `single`).
    #[arg(long, default_value_t = 64)]
    pub concurrency: usize,
    /// Readings per request (`batch`).
    #[arg(long, default_value_t = 1000)]
    pub batch: usize,
    /// Readings per machine to post (`batch`, `single`).
    #[arg(long, default_value_t = 20_000)]
    pub readings: usize,
    /// Total readings/s across machines (`live`).
    #[arg(long, default_value_t = 1000.0)]
    pub rate: f64,
    /// Seconds to run (`live`).
    #[arg(long, default_value_t = 20.0)]
    pub seconds: f64,
    /// Estimates to store before querying (`history`).
    #[arg(long, default_value_t = 10_000_000)]
    pub estimates: usize,
    /// The MQTT broker (`mqtt`): `mqtt://host:port`; a server started for
    /// the run is given it too.
    #[arg(long, value_name = "URL")]
    pub mqtt: Option<String>,
    /// `batch` on a server started for the run: afterwards, stop it, time
    /// a plain SQLite insert loop of the rows it stored (a fresh database
    /// of the same schema, one transaction per `--batch` readings), and
    /// print the ratio of the two rates.
    #[arg(long)]
    pub against_raw_sqlite: bool,
}

/// A `serve` child process started for the run.
struct SpawnedServer {
    child: Child,
    data_dir: PathBuf,
    url: String,
}

impl SpawnedServer {
    fn start(mqtt: Option<&str>) -> Result<SpawnedServer, CliError> {
        let data_dir = std::env::temp_dir().join(format!("tunnelnav-load-{}", std::process::id()));
        let exe = std::env::current_exe()?;
        let mut child = Command::new(exe)
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(&data_dir)
            .args(mqtt.map(|url| ["--mqtt", url]).into_iter().flatten())
            .env("RUST_LOG", "error")
            .stdout(Stdio::piped())
            .spawn()?;
        let mut line = String::new();
        if let Some(stdout) = child.stdout.take() {
            BufReader::new(stdout).read_line(&mut line)?;
        }
        let url = line
            .trim()
            .strip_prefix("listening on ")
            .ok_or_else(|| CliError::Scenario(format!("server did not start: {line:?}")))?
            .to_string();
        Ok(SpawnedServer {
            child,
            data_dir,
            url,
        })
    }
}

impl Drop for SpawnedServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.data_dir);
    }
}

/// Percentile of sorted durations, in milliseconds.
fn percentile_ms(sorted: &[Duration], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i].as_secs_f64() * 1e3
}

/// Posts an NDJSON body; the answer's bytes, or what went wrong.
pub(super) async fn post_ndjson(
    client: &reqwest::Client,
    endpoint: &str,
    body: String,
) -> Result<bytes::Bytes, String> {
    let response = client
        .post(endpoint)
        .header("content-type", "application/x-ndjson")
        .body(body)
        .send()
        .await
        .map_err(|e| e.to_string())?;
    let status = response.status();
    let bytes = response.bytes().await.map_err(|e| e.to_string())?;
    if !status.is_success() {
        return Err(format!("{status}: {}", String::from_utf8_lossy(&bytes)));
    }
    Ok(bytes)
}

/// One machine's readings as NDJSON lines, starting `offset_s` into the drive.
fn readings(machine: usize, count: usize) -> Vec<String> {
    let hours = count as f64 / 3600.0 * 1.02 + 0.01;
    TbmDrive::new(TbmScenario {
        seed: machine as u64 + 1,
        hours,
        ..TbmScenario::default()
    })
    .map(|drive| drive.take(count).map(|e| e.reading.to_json()).collect())
    .unwrap_or_default()
}

pub fn run(args: LoadArgs) -> Result<(), CliError> {
    if args.against_raw_sqlite && (args.mode != LoadMode::Batch || args.url.is_some()) {
        return Err(CliError::Scenario(
            "--against-raw-sqlite needs --mode batch on a server the run starts (no --url)".into(),
        ));
    }
    let mut spawned = match &args.url {
        Some(_) => None,
        None => Some(SpawnedServer::start(args.mqtt.as_deref())?),
    };
    let url = args
        .url
        .clone()
        .or_else(|| spawned.as_ref().map(|s| s.url.clone()))
        .unwrap_or_default();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let result = runtime.block_on(async {
        // The token's header, for every request and the live sockets.
        let mut headers = reqwest::header::HeaderMap::new();
        if let Some(token) = &args.token {
            let mut bearer = reqwest::header::HeaderValue::from_str(&format!("Bearer {token}"))
                .map_err(|_| {
                    CliError::Scenario("--token holds characters a header cannot".into())
                })?;
            bearer.set_sensitive(true);
            headers.insert(reqwest::header::AUTHORIZATION, bearer);
        }
        let client = reqwest::Client::builder()
            .pool_max_idle_per_host(args.concurrency.max(args.machines))
            .default_headers(headers.clone())
            .build()
            .map_err(|e| CliError::Scenario(e.to_string()))?;
        let run_id = std::process::id();
        let machine_count = if args.mode == LoadMode::History {
            1
        } else {
            args.machines
        };
        let mut machines: Vec<String> = (0..machine_count)
            .map(|i| format!("load-{run_id}-{i}"))
            .collect();
        // The broker's gateways feed machines of their own.
        if args.mode == LoadMode::Mqtt {
            machines.extend((0..machine_count).map(|i| format!("load-{run_id}-mqtt-{i}")));
        }
        for machine in &machines {
            let response = client
                .put(format!("{url}/api/v1/machines/{machine}"))
                .body(r#"{"engines":{"attitude":{}}}"#)
                .send()
                .await
                .map_err(|e| CliError::Scenario(format!("declaring {machine}: {e}")))?;
            if !response.status().is_success() {
                return Err(CliError::Scenario(format!(
                    "declaring {machine}: {}",
                    response.status()
                )));
            }
        }
        match args.mode {
            LoadMode::Batch | LoadMode::Single => {
                throughput(&args, &client, &url, &machines).await.map(Some)
            }
            LoadMode::Mqtt => {
                let (http, broker) = machines.split_at(machine_count);
                throughput(&args, &client, &url, http).await?;
                through_broker(&args, broker).await.map(|()| None)
            }
            LoadMode::Live => live(&args, &client, &headers, &url, &machines)
                .await
                .map(|()| None),
            LoadMode::History => history(&args, &client, &url, &machines[0])
                .await
                .map(|()| None),
        }
    });
    let ingest_readings_per_s = result?;
    if let (true, Some(server), Some(ingest)) = (
        args.against_raw_sqlite,
        spawned.as_mut(),
        ingest_readings_per_s,
    ) {
        // Stopped as a crash would: what it acknowledged is committed.
        server.child.kill()?;
        server.child.wait()?;
        let raw = raw_sqlite_loop(&server.data_dir, args.batch.max(1))?;
        println!("{raw}");
        println!(
            "batched ingest / raw insert loop: {:.2}× ({ingest:.0} against {:.0} readings/s)",
            ingest / raw.readings_per_s(),
            raw.readings_per_s()
        );
    }
    drop(spawned);
    Ok(())
}

/// What [`raw_sqlite_loop`] did.
struct RawRun {
    readings: usize,
    estimates: usize,
    transactions: usize,
    seconds: f64,
    /// The same rows in one transaction.
    seconds_in_one: f64,
}

impl RawRun {
    fn readings_per_s(&self) -> f64 {
        self.readings as f64 / self.seconds.max(1e-9)
    }
}

impl std::fmt::Display for RawRun {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "raw SQLite insert loop: {} readings and {} estimates in {} transactions over {:.2} s: {:.0} readings/s \
             (in one transaction: {:.2} s, {:.0} readings/s)",
            self.readings,
            self.estimates,
            self.transactions,
            self.seconds,
            self.readings_per_s(),
            self.seconds_in_one,
            self.readings as f64 / self.seconds_in_one.max(1e-9)
        )
    }
}

type Row = Vec<rusqlite::types::Value>;

/// A table's rows as stored, with the statement that inserts one.
struct TableRows {
    insert: String,
    columns: Vec<String>,
    rows: Vec<Row>,
}

impl TableRows {
    fn read(conn: &rusqlite::Connection, table: &str, order: &str) -> rusqlite::Result<TableRows> {
        let mut statement = conn.prepare(&format!("SELECT * FROM {table} {order}"))?;
        let columns: Vec<String> = statement
            .column_names()
            .iter()
            .map(|c| c.to_string())
            .collect();
        let count = columns.len();
        let rows = statement
            .query_map([], |row| (0..count).map(|i| row.get(i)).collect())?
            .collect::<rusqlite::Result<Vec<Row>>>()?;
        let places: Vec<String> = (1..=count).map(|i| format!("?{i}")).collect();
        Ok(TableRows {
            insert: format!(
                "INSERT INTO {table} ({}) VALUES ({})",
                columns.join(", "),
                places.join(", ")
            ),
            columns,
            rows,
        })
    }

    /// Where `name` is in a row.
    fn column(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }
}

/// The yardstick for batched ingest: the readings and estimates a server
/// stored in `data_dir`, every column, inserted again into a fresh
/// database of the same schema and settings (the store's migrations and
/// page size, WAL, `synchronous=FULL`, foreign keys, the writer's page
/// cache, no checkpoints during the loop) by a loop of prepared
/// `INSERT`s, one transaction per `batch` readings in the order they
/// arrived, each with the estimates made at those readings' times: a
/// gateway's requests committed one after another. No HTTP, no parsing,
/// no fusion, no bucket extremes, no group commit: only the rows. Only the
/// loop is timed; it runs again with every row in one transaction, for
/// the fastest a plain loop can go.
fn raw_sqlite_loop(data_dir: &std::path::Path, batch: usize) -> Result<RawRun, CliError> {
    let sql_error = |e: rusqlite::Error| CliError::Scenario(format!("raw SQLite loop: {e}"));
    let stored = rusqlite::Connection::open_with_flags(
        data_dir.join(crate::store::DB_FILE),
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
    )
    .map_err(sql_error)?;
    let machines = TableRows::read(&stored, "machines", "").map_err(sql_error)?;
    let readings = TableRows::read(&stored, "readings", "ORDER BY id").map_err(sql_error)?;
    let estimates = TableRows::read(&stored, "estimates", "").map_err(sql_error)?;
    drop(stored);
    let missing = |table: &str| {
        CliError::Scenario(format!("raw SQLite loop: {table} has no machine_id or t"))
    };
    let (r_machine, r_t) = readings
        .column("machine_id")
        .zip(readings.column("t"))
        .ok_or_else(|| missing("readings"))?;
    let (e_machine, e_t) = estimates
        .column("machine_id")
        .zip(estimates.column("t"))
        .ok_or_else(|| missing("estimates"))?;
    let key = |row: &Row, machine: usize, t: usize| match (&row[machine], &row[t]) {
        (rusqlite::types::Value::Integer(m), rusqlite::types::Value::Real(t)) => {
            Some((*m, t.to_bits()))
        }
        _ => None,
    };
    // The estimates each reading made: those of its machine at its time.
    let mut made: HashMap<(i64, u64), Vec<&Row>> = HashMap::new();
    for row in &estimates.rows {
        if let Some(k) = key(row, e_machine, e_t) {
            made.entry(k).or_default().push(row);
        }
    }
    // Per transaction: its readings' rows and their estimates' rows.
    let mut transactions: Vec<(Vec<&Row>, Vec<&Row>)> = readings
        .rows
        .chunks(batch)
        .map(|chunk| {
            let made_here = chunk
                .iter()
                .filter_map(|r| key(r, r_machine, r_t))
                .filter_map(|k| made.remove(&k))
                .flatten()
                .collect();
            (chunk.iter().collect(), made_here)
        })
        .collect();
    // Estimates at no reading's time (an engine's last, flushed) go last.
    if let Some(last) = transactions.last_mut() {
        last.1.extend(made.into_values().flatten());
    }
    let seconds = insert_loop(data_dir, &machines, &readings, &estimates, &transactions)?;
    let all: Vec<(Vec<&Row>, Vec<&Row>)> = vec![(
        readings.rows.iter().collect(),
        transactions
            .iter()
            .flat_map(|(_, e)| e.iter().copied())
            .collect(),
    )];
    let seconds_in_one = insert_loop(data_dir, &machines, &readings, &estimates, &all)?;
    Ok(RawRun {
        readings: readings.rows.len(),
        estimates: estimates.rows.len(),
        transactions: transactions.len(),
        seconds,
        seconds_in_one,
    })
}

/// Inserts `transactions` (readings' rows, estimates' rows) into a fresh
/// database under `data_dir`, one transaction each; the seconds taken.
fn insert_loop(
    data_dir: &std::path::Path,
    machines: &TableRows,
    readings: &TableRows,
    estimates: &TableRows,
    transactions: &[(Vec<&Row>, Vec<&Row>)],
) -> Result<f64, CliError> {
    let fresh_dir = data_dir.join("raw-insert-loop");
    let _ = std::fs::remove_dir_all(&fresh_dir);
    let fresh = crate::store::SqliteStore::connect(&fresh_dir)
        .map_err(|e| CliError::Scenario(format!("raw SQLite loop: {e}")))?;
    let seconds = time_inserts(fresh, machines, readings, estimates, transactions)
        .map_err(|e| CliError::Scenario(format!("raw SQLite loop: {e}")));
    let _ = std::fs::remove_dir_all(&fresh_dir);
    seconds
}

/// [`insert_loop`]'s work on the fresh connection.
fn time_inserts(
    mut fresh: rusqlite::Connection,
    machines: &TableRows,
    readings: &TableRows,
    estimates: &TableRows,
    transactions: &[(Vec<&Row>, Vec<&Row>)],
) -> rusqlite::Result<f64> {
    // As the store's writer connection has it.
    fresh.pragma_update(None, "foreign_keys", true)?;
    fresh.pragma_update(None, "cache_size", -65_536)?;
    fresh.pragma_update(None, "wal_autocheckpoint", 0)?;
    for machine in &machines.rows {
        fresh.execute(&machines.insert, rusqlite::params_from_iter(machine))?;
    }
    let started = Instant::now();
    for (reading_rows, estimate_rows) in transactions {
        let tx = fresh.transaction()?;
        {
            let mut insert_reading = tx.prepare_cached(&readings.insert)?;
            for row in reading_rows {
                insert_reading.execute(rusqlite::params_from_iter(row.iter()))?;
            }
            let mut insert_estimate = tx.prepare_cached(&estimates.insert)?;
            for row in estimate_rows {
                insert_estimate.execute(rusqlite::params_from_iter(row.iter()))?;
            }
        }
        tx.commit()?;
    }
    Ok(started.elapsed().as_secs_f64())
}

/// Posts every machine's readings; returns the readings accepted per second.
async fn throughput(
    args: &LoadArgs,
    client: &reqwest::Client,
    url: &str,
    machines: &[String],
) -> Result<f64, CliError> {
    let batch = if args.mode == LoadMode::Single {
        1
    } else {
        args.batch.max(1)
    };
    eprintln!(
        "preparing {} readings for {} machines...",
        args.readings * machines.len(),
        machines.len()
    );
    // Requests per machine, in order; a machine's requests go one after
    // another (a gateway), machines are spread over the connections.
    let mut queues: Vec<(String, Vec<String>)> = Vec::new();
    for (i, machine) in machines.iter().enumerate() {
        let lines = readings(i, args.readings);
        let bodies = lines.chunks(batch).map(|c| c.join("\n")).collect();
        queues.push((machine.clone(), bodies));
    }
    let queues = Arc::new(Mutex::new(queues));
    let started = Instant::now();
    let mut workers = Vec::new();
    for _ in 0..args.concurrency.max(1) {
        let (client, url, queues) = (client.clone(), url.to_string(), queues.clone());
        workers.push(tokio::spawn(async move {
            let mut accepted = 0u64;
            let mut requests = 0u64;
            let mut latencies = Vec::new();
            // Take a machine's whole queue: its requests stay in order.
            while let Some((machine, bodies)) = queues.lock().ok().and_then(|mut q| q.pop()) {
                let endpoint = format!("{url}/api/v1/machines/{machine}/readings");
                for body in bodies {
                    let sent = Instant::now();
                    let bytes = post_ndjson(&client, &endpoint, body).await?;
                    let ack: serde_json::Value =
                        serde_json::from_slice(&bytes).map_err(|e| e.to_string())?;
                    accepted += ack["accepted"].as_u64().unwrap_or(0);
                    requests += 1;
                    latencies.push(sent.elapsed());
                }
            }
            Ok::<_, String>((accepted, requests, latencies))
        }));
    }
    let (mut accepted, mut requests, mut latencies) = (0, 0, Vec::new());
    for worker in workers {
        let (a, r, l) = worker
            .await
            .map_err(|e| CliError::Scenario(e.to_string()))?
            .map_err(CliError::Scenario)?;
        accepted += a;
        requests += r;
        latencies.extend(l);
    }
    let elapsed = started.elapsed().as_secs_f64();
    latencies.sort();
    println!(
        "mode {:?}: {accepted} readings in {requests} requests over {elapsed:.2} s: \
         {:.0} readings/s, {:.0} requests/s accepted, fused and committed; \
         request latency p50 {:.2} ms, p99 {:.2} ms ({} machines, {} connections, {batch} per request)",
        if args.mode == LoadMode::Mqtt {
            LoadMode::Batch
        } else {
            args.mode
        },
        accepted as f64 / elapsed,
        requests as f64 / elapsed,
        percentile_ms(&latencies, 0.5),
        percentile_ms(&latencies, 0.99),
        machines.len(),
        args.concurrency,
    );
    Ok(accepted as f64 / elapsed)
}

async fn live(
    args: &LoadArgs,
    client: &reqwest::Client,
    headers: &reqwest::header::HeaderMap,
    url: &str,
    machines: &[String],
) -> Result<(), CliError> {
    let per_machine_rate = args.rate / machines.len() as f64;
    let count = (per_machine_rate * args.seconds).ceil() as usize + 1;
    // Inclinometer readings only: each gives exactly one estimate.
    let sent: Arc<Mutex<HashMap<(usize, u64), Instant>>> = Arc::default();
    let latencies: Arc<Mutex<Vec<Duration>>> = Arc::default();
    let ws_base = url.replacen("http://", "ws://", 1);
    let mut readers = Vec::new();
    for (i, machine) in machines.iter().enumerate() {
        use tokio_tungstenite::tungstenite::client::IntoClientRequest;
        let mut request = format!("{ws_base}/api/v1/machines/{machine}/live")
            .into_client_request()
            .map_err(|e| CliError::Scenario(format!("live socket: {e}")))?;
        request.headers_mut().extend(headers.clone());
        let (socket, _) = tokio_tungstenite::connect_async(request)
            .await
            .map_err(|e| CliError::Scenario(format!("live socket: {e}")))?;
        let (sent, latencies) = (sent.clone(), latencies.clone());
        readers.push(tokio::spawn(async move {
            let mut socket = socket;
            let mut received = 0usize;
            while received < count {
                let Some(Ok(message)) = socket.next().await else {
                    break;
                };
                let tokio_tungstenite::tungstenite::Message::Text(text) = message else {
                    continue;
                };
                let arrived = Instant::now();
                let Ok(frame) = serde_json::from_str::<serde_json::Value>(&text) else {
                    continue;
                };
                let Some(t) = frame["t"].as_f64() else {
                    continue;
                };
                if let Some(at) = sent
                    .lock()
                    .ok()
                    .and_then(|mut s| s.remove(&(i, t.to_bits())))
                {
                    if let Ok(mut l) = latencies.lock() {
                        l.push(arrived - at);
                    }
                    received += 1;
                }
            }
        }));
    }
    let started = Instant::now();
    let mut posters = Vec::new();
    for (i, machine) in machines.iter().enumerate() {
        let lines: Vec<String> = readings(i, count * 2)
            .into_iter()
            .filter(|l| l.contains("\"inclinometer\""))
            .take(count)
            .collect();
        let (client, sent) = (client.clone(), sent.clone());
        let endpoint = format!("{url}/api/v1/machines/{machine}/readings");
        let period = Duration::from_secs_f64(1.0 / per_machine_rate);
        // Spread the machines' phases over one period.
        let phase = period.mul_f64(i as f64 / machines.len() as f64);
        posters.push(tokio::spawn(async move {
            let mut ticks = tokio::time::interval_at(tokio::time::Instant::now() + phase, period);
            ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
            for line in lines {
                ticks.tick().await;
                let t = serde_json::from_str::<serde_json::Value>(&line)
                    .ok()
                    .and_then(|v| v["t"].as_f64())
                    .unwrap_or(0.0);
                if let Ok(mut s) = sent.lock() {
                    s.insert((i, t.to_bits()), Instant::now());
                }
                let response = client.post(&endpoint).body(line).send().await;
                match response {
                    Ok(r) if r.status().is_success() => {
                        let _ = r.bytes().await;
                    }
                    Ok(r) => return Err(format!("post: {}", r.status())),
                    Err(e) => return Err(format!("post: {e}")),
                }
            }
            Ok(())
        }));
    }
    for poster in posters {
        poster
            .await
            .map_err(|e| CliError::Scenario(e.to_string()))?
            .map_err(CliError::Scenario)?;
    }
    let posting = started.elapsed().as_secs_f64();
    for reader in readers {
        let _ = tokio::time::timeout(Duration::from_secs(10), reader).await;
    }
    let mut latencies = latencies.lock().map(|l| l.clone()).unwrap_or_default();
    latencies.sort();
    let missing = sent.lock().map(|s| s.len()).unwrap_or(0);
    println!(
        "mode live: {} readings over {posting:.1} s ({:.0} readings/s, {} machines, single posts); \
         post to live estimate p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms; {missing} estimates not seen",
        latencies.len(),
        latencies.len() as f64 / posting,
        machines.len(),
        percentile_ms(&latencies, 0.5),
        percentile_ms(&latencies, 0.99),
        percentile_ms(&latencies, 1.0),
    );
    Ok(())
}

async fn history(
    args: &LoadArgs,
    client: &reqwest::Client,
    url: &str,
    machine: &str,
) -> Result<(), CliError> {
    const BATCH: usize = 5000;
    let t0 = crate::sim::tbm::DEFAULT_START_T;
    let endpoint = format!("{url}/api/v1/machines/{machine}/readings");
    let started = Instant::now();
    // Synthetic 1 Hz inclinometer readings, generated batch by batch; a few
    // connections keep the machine's queue full.
    let next = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let batches = args.estimates.div_ceil(BATCH);
    let mut posters = Vec::new();
    for _ in 0..4 {
        let (client, endpoint, next) = (client.clone(), endpoint.clone(), next.clone());
        let total = args.estimates;
        posters.push(tokio::spawn(async move {
            loop {
                let b = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if b >= batches {
                    return Ok(());
                }
                let mut body = String::with_capacity(BATCH * 100);
                for i in b * BATCH..((b + 1) * BATCH).min(total) {
                    let x = i as f64;
                    body.push_str(&format!(
                        "{{\"t\":{},\"sensor\":\"inclinometer\",\"pitch_deg\":{:.5},\"roll_deg\":{:.5}}}\n",
                        t0 + x,
                        0.3 * (x / 5000.0).sin(),
                        1.5 + (x / 20000.0).cos()
                    ));
                }
                post_ndjson(&client, &endpoint, body).await?;
            }
        }));
    }
    for poster in posters {
        poster
            .await
            .map_err(|e| CliError::Scenario(e.to_string()))?
            .map_err(CliError::Scenario)?;
    }
    let stored_s = started.elapsed().as_secs_f64();
    println!(
        "stored {} readings and their estimates in {stored_s:.1} s ({:.0}/s)",
        args.estimates,
        args.estimates as f64 / stored_s
    );
    let span_s = args.estimates as f64;
    for (label, from, to) in [
        ("whole history", t0, t0 + span_s),
        ("last 7 days", t0 + span_s - 7.0 * 86400.0, t0 + span_s),
        ("last 12 h", t0 + span_s - 12.0 * 3600.0, t0 + span_s),
        ("last 15 min", t0 + span_s - 900.0, t0 + span_s),
    ] {
        let query = format!(
            "{url}/api/v1/machines/{machine}/estimates?from={}&to={}&max_points=2000",
            from.max(t0),
            to
        );
        let mut times = Vec::new();
        let mut points = 0;
        for _ in 0..10 {
            let sent = Instant::now();
            let response = client
                .get(&query)
                .send()
                .await
                .map_err(|e| CliError::Scenario(e.to_string()))?;
            let body = response
                .bytes()
                .await
                .map_err(|e| CliError::Scenario(e.to_string()))?;
            times.push(sent.elapsed());
            let page: serde_json::Value = serde_json::from_slice(&body)
                .map_err(|e| CliError::Scenario(format!("history answer: {e}")))?;
            points = page["estimates"].as_array().map_or(0, Vec::len);
        }
        times.sort();
        println!(
            "history {label}: {points} points, p50 {:.1} ms, max {:.1} ms over 10 queries",
            percentile_ms(&times, 0.5),
            percentile_ms(&times, 1.0)
        );
    }
    Ok(())
}

/// `mqtt`: one gateway per machine publishes its readings, `--batch` a
/// message, at QoS 1 through the broker; the run ends when the acks topics
/// have answered for every reading.
async fn through_broker(args: &LoadArgs, machines: &[String]) -> Result<(), CliError> {
    use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
    let broker = args
        .mqtt
        .as_deref()
        .ok_or_else(|| CliError::Scenario("--mode mqtt needs --mqtt URL (the broker)".into()))?;
    let options = |id: String| -> Result<MqttOptions, CliError> {
        let separator = if broker.contains('?') { '&' } else { '?' };
        let mut options = MqttOptions::parse_url(format!("{broker}{separator}client_id={id}"))
            .map_err(|e| CliError::Scenario(format!("--mqtt {broker}: {e}")))?;
        options.set_max_packet_size(64 << 20, 64 << 20);
        Ok(options)
    };
    let batch = args.batch.max(1);
    let expected = (args.readings * machines.len()) as u64;
    eprintln!(
        "preparing {expected} readings for {} machines...",
        machines.len()
    );
    let bodies: Vec<Vec<String>> = (0..machines.len())
        .map(|i| {
            readings(i, args.readings)
                .chunks(batch)
                .map(|c| c.join("\n"))
                .collect()
        })
        .collect();
    let messages: usize = bodies.iter().map(Vec::len).sum();

    // The answers: every machine's acks topic.
    let (listener, mut answers) =
        AsyncClient::new(options(format!("load-acks-{}", std::process::id()))?, 64);
    listener
        .subscribe("tunnelnav/v1/+/acks", QoS::AtLeastOnce)
        .await
        .map_err(|e| CliError::Scenario(e.to_string()))?;
    let (done, mut finished) = tokio::sync::oneshot::channel::<Result<u64, String>>();
    let counter = tokio::spawn(async move {
        let mut accepted = 0u64;
        loop {
            match answers.poll().await {
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let ack: serde_json::Value =
                        serde_json::from_slice(&p.payload).unwrap_or_default();
                    if let Some(error) = ack["error"].as_str() {
                        let _ = done.send(Err(format!("{}: {error}", p.topic)));
                        return;
                    }
                    accepted += ack["accepted"].as_u64().unwrap_or(0);
                    if accepted >= expected {
                        let _ = done.send(Ok(accepted));
                        return;
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    let _ = done.send(Err(format!("acks subscription: {e}")));
                    return;
                }
            }
        }
    });
    // Give the subscription a moment to be in place at the broker.
    tokio::time::sleep(Duration::from_millis(300)).await;

    let started = Instant::now();
    let mut gateways = Vec::new();
    for (machine, bodies) in machines.iter().zip(bodies) {
        let (client, mut eventloop) = AsyncClient::new(options(format!("load-gw-{machine}"))?, 64);
        let poller = tokio::spawn(async move {
            loop {
                if eventloop.poll().await.is_err() {
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            }
        });
        let topic = format!("tunnelnav/v1/{machine}/readings");
        gateways.push((
            poller,
            tokio::spawn(async move {
                for body in bodies {
                    client
                        .publish(topic.as_str(), QoS::AtLeastOnce, false, body.into_bytes())
                        .await
                        .map_err(|e| e.to_string())?;
                }
                Ok::<_, String>(client)
            }),
        ));
    }
    let answered = tokio::time::timeout(Duration::from_secs(600), &mut finished)
        .await
        .map_err(|_| CliError::Scenario("not every reading answered within 600 s".into()))?
        .map_err(|_| CliError::Scenario("the acks subscription ended".into()))?
        .map_err(CliError::Scenario)?;
    let elapsed = started.elapsed().as_secs_f64();
    counter.abort();
    for (poller, publisher) in gateways {
        let _ = publisher.await;
        poller.abort();
    }
    println!(
        "mode Mqtt: {answered} readings in {messages} messages over {elapsed:.2} s: \
         {:.0} readings/s, {:.0} messages/s through the broker, committed and answered \
         ({} machines, one gateway each, {batch} per message, QoS 1)",
        answered as f64 / elapsed,
        messages as f64 / elapsed,
        machines.len(),
    );
    Ok(())
}
