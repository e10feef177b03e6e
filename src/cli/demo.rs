//! `tunnelnav demo [--listen ADDR] [--data-dir DIR] [--rate R] [--seconds S]`
//!
//! The server, three simulated TBMs, a pipe-jacking machine guided by a
//! FOG INS, a service vehicle with a MEMS IMU and a magnetometer, and
//! their field gateways, at an accelerated clock: the gateways
//! post the simulator's readings over real HTTP (NDJSON) and WebSocket as
//! the clock reaches their time, so a 2-minute laser period shows up every
//! few seconds. One machine's laser is blocked for 20 minutes of every
//! hour; the INS machine advances at 2 mm/s and stops for each pipe. The server runs with the same
//! clock, so ages and its future check agree with the gateways.
//!
//! A second run on the same data dir resumes: the clock starts after the
//! newest stored reading, and each machine starts a new stretch of drive.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Args;
use futures_util::{SinkExt, StreamExt};
use tokio::sync::watch;
use tokio_tungstenite::tungstenite::Message;

use super::CliError;
use super::load::post_ndjson;
use super::serve::{init_tracing, shutdown_signal, start};
use crate::config::ServerConfig;
use crate::fusion::{Reading, SensorData, SensorKind};
use crate::server::{self, Clock, Limits, ServerOptions, wall_clock_s};
use crate::sim::pipejack::{Case, PipeJackDrive, PipeJackScenario};
use crate::sim::tbm::{TbmDrive, TbmScenario};
use crate::sim::vehicle::{VehicleDrive, VehicleScenario};
use crate::store::Store;

/// The demo machines, declared as a config file would.
const DEMO_MACHINES: &str = r#"
[machines.tbm-north]
name = "TBM North · S-1 drive"
engines = { attitude = {} }

[machines.tbm-south]
name = "TBM South · S-2 drive (WebSocket gateway)"
engines = { attitude = {} }

[machines.pipejack-3]
name = "Pipe jack P-3 · laser blocked 20 min per hour"
engines = { attitude = {} }

[machines.pipejack-ins]
name = "Pipe jack P-7 · FOG INS, zero-velocity updates, odometer"
engines = { zupt = { latitude_deg = 30, initial_yaw_deg = 30, window_samples = 25, median_samples = 25, odometer_aiding = true } }

[machines.service-van]
name = "Service vehicle V-2 · MEMS IMU + compass, fuzzy motion expert"
engines = { fuzzy = { declination_deg = 2.5, mag_inclination_deg = 60, window_samples = 13 } }
"#;

/// The demo INS's IMU rate: a quarter of the field's 100 Hz keeps the
/// accelerated demo's database growth modest (the detector windows are
/// set to the same second of data).
const DEMO_IMU_RATE_HZ: f64 = 25.0;

/// How a gateway reaches the server.
#[derive(Debug, Clone, Copy)]
enum Transport {
    /// `POST .../readings` with an NDJSON body.
    Http,
    /// Frames on `GET .../ingest`.
    WebSocket,
}

/// What a gateway's machine is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// A TBM with laser and inclinometer.
    Tbm,
    /// A pipe-jacking machine with a FOG IMU, level and odometer (the
    /// simulator's field case).
    PipeJack,
    /// A tunnel service vehicle with a MEMS IMU and a magnetometer
    /// (hour-long simulated shifts, one after another).
    Vehicle,
}

struct Gateway {
    machine: &'static str,
    kind: Kind,
    seed: u64,
    transport: Transport,
    /// The laser's line of sight is blocked for minutes 10–30 of every hour.
    laser_blocked: bool,
}

const GATEWAYS: [Gateway; 5] = [
    Gateway {
        machine: "tbm-north",
        kind: Kind::Tbm,
        seed: 11,
        transport: Transport::Http,
        laser_blocked: false,
    },
    Gateway {
        machine: "tbm-south",
        kind: Kind::Tbm,
        seed: 22,
        transport: Transport::WebSocket,
        laser_blocked: false,
    },
    Gateway {
        machine: "pipejack-3",
        kind: Kind::Tbm,
        seed: 33,
        transport: Transport::Http,
        laser_blocked: true,
    },
    Gateway {
        machine: "pipejack-ins",
        kind: Kind::PipeJack,
        seed: 44,
        transport: Transport::Http,
        laser_blocked: false,
    },
    Gateway {
        machine: "service-van",
        kind: Kind::Vehicle,
        seed: 55,
        transport: Transport::WebSocket,
        laser_blocked: false,
    },
];

/// The demo vehicle's IMU and magnetometer rates (a quarter of the
/// simulator's usual; its window is set to the same half second).
const DEMO_VEHICLE_IMU_HZ: f64 = 25.0;
const DEMO_VEHICLE_MAG_HZ: f64 = 5.0;
/// Length of one simulated shift of the demo vehicle.
const DEMO_SHIFT_S: f64 = 3600.0;

/// Real time between a gateway's sends.
const SEND_EVERY: Duration = Duration::from_millis(200);
/// Readings a gateway keeps while the server cannot be reached.
const MAX_PENDING: usize = 100_000;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// Directory holding the demo's database (created if missing; a second
    /// run continues its history).
    #[arg(long, default_value = "tunnelnav-demo")]
    pub data_dir: PathBuf,
    /// Server-clock seconds per real second.
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    /// Stop after this many real seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Serve the demo on an address other than loopback without access
    /// tokens (its simulated gateways send none).
    #[arg(long)]
    pub allow_no_auth: bool,
}

pub fn run(args: DemoArgs) -> Result<(), CliError> {
    init_tracing();
    if !(args.rate.is_finite() && args.rate > 0.0 && args.rate <= 10_000.0) {
        return Err(CliError::Scenario(format!(
            "--rate {} is not in (0, 10000]",
            args.rate
        )));
    }
    let machines = ServerConfig::parse(DEMO_MACHINES)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        // Start after anything an earlier demo stored, so nothing new is older.
        let resume = resume_point(&args.data_dir).await?;
        let start_t = resume
            .newest_t
            .map_or(wall_clock_s(), |t| wall_clock_s().max(t + 1.0));
        let clock = Clock::accelerated(args.rate, start_t).map_err(CliError::Scenario)?;
        let options = ServerOptions {
            data_dir: args.data_dir.clone(),
            machines,
            limits: Limits::default(),
            clock,
            retention: crate::store::retention::Retention::default(),
        };
        let (state, listener) = start(options, args.listen, args.allow_no_auth).await?;
        let address = listener.local_addr()?;
        println!(
            "tunnelnav demo: open http://{address}/ in a browser. Five simulated machines, \
             server clock ×{} (a 2-minute laser period every {:.0} s), data in {}. Ctrl-C stops.",
            args.rate,
            120.0 / args.rate,
            args.data_dir.display()
        );

        let (stop_gateways, stopping) = watch::channel(false);
        let mut gateways = Vec::new();
        for gateway in &GATEWAYS {
            gateways.push(tokio::spawn(run_gateway(
                gateway,
                address,
                clock,
                resume.aids,
                stopping.clone(),
            )));
        }
        let seconds = args.seconds;
        let shutdown = async move {
            match seconds {
                Some(s) => {
                    tokio::select! {
                        _ = shutdown_signal() => {},
                        _ = tokio::time::sleep(Duration::from_secs_f64(s.max(0.0))) => {},
                    }
                }
                None => shutdown_signal().await,
            }
            // Gateways first, so their last sends are answered.
            stop_gateways.send_replace(true);
            for gateway in gateways {
                let _ = gateway.await;
            }
        };
        server::run(listener, state, shutdown).await?;
        tracing::info!("demo stopped");
        Ok(())
    })
}

/// Where an earlier demo in the same data dir stopped.
#[derive(Debug, Clone, Copy, Default)]
struct Resume {
    /// The newest reading of any machine.
    newest_t: Option<f64>,
    /// The INS machine's last level height and odometer distance: its next
    /// stretch of drive starts there, so the engine sees one drive.
    aids: (Option<f64>, Option<f64>),
}

/// What `data_dir` holds from an earlier demo.
async fn resume_point(data_dir: &Path) -> Result<Resume, CliError> {
    let store = Store::open(data_dir)?;
    let resume = {
        let store = store.clone();
        tokio::task::spawn_blocking(move || {
            let mut resume = Resume::default();
            for machine in store.machines()? {
                for sensor in SensorKind::ALL {
                    let Some(t) = store.last_reading_t(machine.db_id, sensor)? else {
                        continue;
                    };
                    resume.newest_t = Some(resume.newest_t.map_or(t, |n| n.max(t)));
                    if machine.spec.id != "pipejack-ins" {
                        continue;
                    }
                    store.export_readings(machine.db_id, Some(sensor), t, t, |r| {
                        match r.data {
                            SensorData::Level { height_m } => resume.aids.0 = Some(height_m),
                            SensorData::Odometer { distance_m } => resume.aids.1 = Some(distance_m),
                            _ => {}
                        }
                        false
                    })?;
                }
            }
            Ok::<_, crate::store::StoreError>(resume)
        })
        .await
        .map_err(std::io::Error::other)??
    };
    store.close().await;
    Ok(resume)
}

fn laser_blocked(gateway: &Gateway, since_start_s: f64) -> bool {
    gateway.laser_blocked && (600.0..1800.0).contains(&since_start_s.rem_euclid(3600.0))
}

/// The simulated readings of a gateway's machine, for a year from `start_t`.
fn readings(
    gateway: &Gateway,
    start_t: f64,
    (height_m, odometer_m): (Option<f64>, Option<f64>),
) -> Result<Box<dyn Iterator<Item = Reading> + Send>, String> {
    Ok(match gateway.kind {
        Kind::Tbm => Box::new(
            TbmDrive::new(TbmScenario {
                seed: gateway.seed,
                start_t,
                hours: 24.0 * 366.0,
                incl_period_s: 1.0,
                laser_period_s: 120.0,
                dropouts: Vec::new(),
            })?
            .map(|e| e.reading),
        ),
        Kind::PipeJack => Box::new(
            PipeJackDrive::new(PipeJackScenario {
                case: Case::Field,
                seed: gateway.seed,
                start_t,
                imu_rate_hz: DEMO_IMU_RATE_HZ,
                field_duration_s: 366.0 * 86_400.0,
                start_height_m: height_m.unwrap_or(12.0),
                start_odometer_m: odometer_m.unwrap_or(0.0),
                ..PipeJackScenario::default()
            })?
            .map(|e| e.reading),
        ),
        Kind::Vehicle => Box::new(VehicleShifts::new(gateway.seed, start_t)?),
    })
}

/// The demo vehicle's readings: simulated shifts back to back, each
/// starting where the last one ended (time and heading).
struct VehicleShifts {
    seed: u64,
    drive: VehicleDrive,
    end_t: f64,
    heading_deg: f64,
}

impl VehicleShifts {
    fn shift(seed: u64, start_t: f64, heading_deg: f64) -> Result<VehicleDrive, String> {
        VehicleDrive::new(VehicleScenario {
            seed,
            start_t,
            duration_s: DEMO_SHIFT_S,
            imu_rate_hz: DEMO_VEHICLE_IMU_HZ,
            mag_rate_hz: DEMO_VEHICLE_MAG_HZ,
            initial_heading_deg: heading_deg,
            ..VehicleScenario::default()
        })
    }

    fn new(seed: u64, start_t: f64) -> Result<VehicleShifts, String> {
        let heading_deg = VehicleScenario::default().initial_heading_deg;
        Ok(VehicleShifts {
            seed,
            drive: Self::shift(seed, start_t, heading_deg)?,
            end_t: start_t,
            heading_deg,
        })
    }
}

impl Iterator for VehicleShifts {
    type Item = Reading;

    fn next(&mut self) -> Option<Reading> {
        loop {
            if let Some(event) = self.drive.next() {
                self.end_t = event.reading.t;
                if let Some(truth) = event.truth {
                    self.heading_deg = truth.heading_deg;
                }
                return Some(event.reading);
            }
            self.seed += 1;
            let start_t = self.end_t + 1.0 / DEMO_VEHICLE_IMU_HZ;
            self.drive = Self::shift(self.seed, start_t, self.heading_deg).ok()?;
        }
    }
}

/// One field gateway: sends the simulator's readings as the clock reaches
/// them, keeping what could not be delivered for the next send.
async fn run_gateway(
    gateway: &'static Gateway,
    address: SocketAddr,
    clock: Clock,
    aids: (Option<f64>, Option<f64>),
    mut stop: watch::Receiver<bool>,
) {
    let start_t = clock.now_s();
    let mut drive = match readings(gateway, start_t, aids) {
        Ok(drive) => drive.peekable(),
        Err(e) => {
            tracing::error!(machine = gateway.machine, "demo drive: {e}");
            return;
        }
    };
    let mut sender = Sender::new(gateway, address);
    let mut pending: Vec<Reading> = Vec::new();
    let mut tick = tokio::time::interval(SEND_EVERY);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stop.changed() => break,
        }
        let now = clock.now_s();
        while let Some(reading) = drive.next_if(|r| r.t <= now) {
            let is_laser = matches!(reading.data, SensorData::Laser { .. });
            if is_laser && laser_blocked(gateway, reading.t - start_t) {
                continue;
            }
            pending.push(reading);
        }
        if pending.is_empty() {
            continue;
        }
        match sender.send(&pending).await {
            Ok(()) => pending.clear(),
            Err(e) => {
                tracing::warn!(machine = gateway.machine, "demo gateway: {e}; will retry");
                if pending.len() > MAX_PENDING {
                    let excess = pending.len() - MAX_PENDING;
                    pending.drain(..excess);
                }
            }
        }
    }
}

/// A gateway's connection to the server.
struct Sender {
    gateway: &'static Gateway,
    base: String,
    http: reqwest::Client,
    socket: Option<
        tokio_tungstenite::WebSocketStream<
            tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
        >,
    >,
}

impl Sender {
    fn new(gateway: &'static Gateway, address: SocketAddr) -> Sender {
        Sender {
            gateway,
            base: format!("{address}/api/v1/machines/{}", gateway.machine),
            http: reqwest::Client::new(),
            socket: None,
        }
    }

    /// Sends the readings; `Ok` once the server acknowledged the batch. A
    /// reading the server rejects is logged, not retried.
    async fn send(&mut self, readings: &[Reading]) -> Result<(), String> {
        let ack = match self.gateway.transport {
            Transport::Http => self.post(readings).await?,
            Transport::WebSocket => {
                let answer = self.frame(readings).await;
                if answer.is_err() {
                    self.socket = None; // reconnect next time
                }
                answer?
            }
        };
        if let Some(rejected) = ack["rejected"].as_array().filter(|r| !r.is_empty()) {
            tracing::warn!(
                machine = self.gateway.machine,
                ?rejected,
                "readings rejected"
            );
        }
        if let Some(error) = ack.get("error") {
            return Err(format!("server answered {error}"));
        }
        Ok(())
    }

    async fn post(&self, readings: &[Reading]) -> Result<serde_json::Value, String> {
        let mut body = String::new();
        for reading in readings {
            body.push_str(&reading.to_json());
            body.push('\n');
        }
        let endpoint = format!("http://{}/readings", self.base);
        let answer = post_ndjson(&self.http, &endpoint, body).await?;
        serde_json::from_slice(&answer).map_err(|e| e.to_string())
    }

    async fn frame(&mut self, readings: &[Reading]) -> Result<serde_json::Value, String> {
        if self.socket.is_none() {
            let (socket, _) =
                tokio_tungstenite::connect_async(format!("ws://{}/ingest", self.base))
                    .await
                    .map_err(|e| e.to_string())?;
            self.socket = Some(socket);
        }
        let Some(socket) = self.socket.as_mut() else {
            return Err("no socket".into());
        };
        let frame = format!(
            "[{}]",
            readings
                .iter()
                .map(Reading::to_json)
                .collect::<Vec<_>>()
                .join(",")
        );
        socket
            .send(Message::Text(frame.into()))
            .await
            .map_err(|e| e.to_string())?;
        loop {
            match socket.next().await {
                Some(Ok(Message::Text(text))) => {
                    return serde_json::from_str(text.as_str()).map_err(|e| e.to_string());
                }
                Some(Ok(Message::Close(_))) | None => return Err("socket closed".into()),
                Some(Ok(_)) => continue,
                Some(Err(e)) => return Err(e.to_string()),
            }
        }
    }
}
