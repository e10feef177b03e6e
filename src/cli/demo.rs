//! `tunnelnav demo [--listen ADDR] [--data-dir DIR] [--rate R] [--seconds S]`
//!
//! The server, three simulated laser-guided machines (two TBMs, one pipe
//! jack), a pipe-jacking machine guided by a FOG INS, a service vehicle
//! with a MEMS IMU and a magnetometer, and their field gateways, at an
//! accelerated clock: the gateways post the simulator's readings over real
//! HTTP (NDJSON) and WebSocket as the clock reaches their time, so a
//! 1-minute laser period shows up every few seconds. Each machine drives
//! its declared design axis (curves with spirals, a compound curve,
//! vertical curves): the laser-guided ones with a deviation that drifts
//! towards the warn limit (tbm-south's past it, often) and is
//! steered back, the INS machine along its straight axis, so its
//! deviation is the INS's own error. One machine's laser is blocked for
//! 20 minutes of every hour; the INS machine advances at 2 mm/s and stops
//! for each pipe. The server runs with the same clock, so ages and its
//! future check agree with the gateways.
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
use crate::clock::{Clock, wall_clock_s};
use crate::config::MachineSpec;
use crate::fusion::{Reading, SensorData, SensorKind};
use crate::server::settings::{Limits, MqttConfig, ServerConfig};
use crate::server::{self, ServerOptions};
use crate::sim::axis_drive::{AxisDrive, AxisDriveScenario};
use crate::sim::pipejack::{Case, PipeJackDrive, PipeJackScenario};
use crate::sim::vehicle::{Iron, VehicleDrive, VehicleEvent, VehicleScenario};
use crate::store::Store;

/// The demo machines, declared as a config file would; their design
/// axes are added by [`demo_machines`].
const DEMO_MACHINES: &str = r#"
[machines.tbm-north]
name = "TBM North · S-1 drive"
engines = { attitude = {} }
geometry = { front_m = [4.2, 0.4, 1.1], rear_m = [-5.1, 0.4, 1.1] }
tolerances = { horizontal_mm = { warn = 50, alarm = 100 }, vertical_mm = { warn = 30, alarm = 60 } }
steering = { min_radius_m = 250, step_m = 1.5, cylinder_circle_m = 6.0, max_stroke_change_mm = 6.0, cylinder_groups = [{ name = "A top", angle_deg = 0, cylinders = [0, 1] }, { name = "B right", angle_deg = 90, cylinders = [2, 3] }, { name = "C bottom", angle_deg = 180, cylinders = [4, 5] }, { name = "D left", angle_deg = 270, cylinders = [6, 7] }] }

[machines.tbm-south]
name = "TBM South · S-2 drive (WebSocket gateway)"
engines = { attitude = {} }
geometry = { front_m = [4.6, -0.3, 1.2], rear_m = [-5.4, -0.3, 1.2] }
tolerances = { horizontal_mm = { warn = 50, alarm = 100 }, vertical_mm = { warn = 30, alarm = 60 } }
steering = { min_radius_m = 250, step_m = 1.5, cylinder_circle_m = 6.0, max_stroke_change_mm = 6.0, cylinder_groups = [{ name = "A top", angle_deg = 0, cylinders = [0, 1] }, { name = "B right", angle_deg = 90, cylinders = [2, 3] }, { name = "C bottom", angle_deg = 180, cylinders = [4, 5] }, { name = "D left", angle_deg = 270, cylinders = [6, 7] }] }

[machines.pipejack-3]
name = "Pipe jack P-3 · laser blocked 20 min per hour"
engines = { attitude = {} }
geometry = { front_m = [2.1, 0.2, 0.5], rear_m = [-1.4, 0.2, 0.5] }
tolerances = { horizontal_mm = { warn = 30, alarm = 60 }, vertical_mm = { warn = 20, alarm = 40 } }

[machines.pipejack-ins]
name = "Pipe jack P-7 · FOG INS, zero-velocity updates, odometer"
engines = { zupt = { latitude_deg = 30, initial_yaw_deg = 30, window_samples = 25, median_samples = 25, odometer_aiding = true, odometer_scale_sigma_pct = 1 } }
geometry = { front_m = [2.0, 0.0, 0.3], rear_m = [-1.5, 0.0, 0.3] }
tolerances = { horizontal_mm = { warn = 30, alarm = 60 }, vertical_mm = { warn = 20, alarm = 40 } }
start = { easting_m = 1200.0, northing_m = 5600.0, height_m = 12.0 }

[machines.service-van]
name = "Service vehicle V-2 · MEMS IMU + compass, fuzzy motion expert"
engines = { fuzzy = { declination_deg = 2.5, mag_inclination_deg = 60, window_samples = 13 } }
"#;

/// The design axes of the demo's drives (the protocol's JSON): S-1 a
/// right-hand curve between spirals over a crest; S-2 a left-hand
/// compound curve (a spiral between arcs of 450 and 900 m) through a sag
/// and a crest; P-3 a tight microtunnel curve; P-7 straight along the INS
/// machine's simulated course (heading 30°, rising 0.5°), from 5 m behind
/// its declared start and 0.3 m below it (the machine's axis, where its
/// declared front and rear are).
const DEMO_AXES: [(&str, &str); 4] = [
    (
        "tbm-north",
        r#"{"name": "S-1 drive", "start_station_m": 0.0,
        "start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 30.0},
        "horizontal": [
          {"type": "line", "length_m": 40.0},
          {"type": "spiral", "length_m": 30.0, "radius_start_m": null, "radius_end_m": 300.0},
          {"type": "arc", "length_m": 60.0, "radius_m": 300.0},
          {"type": "spiral", "length_m": 30.0, "radius_start_m": 300.0, "radius_end_m": null},
          {"type": "line", "length_m": 140.0}],
        "vertical": {"start_height_m": 50.0,
          "pvis": [{"station_m": 150.0, "height_m": 50.9, "curve_length_m": 80.0}],
          "end_grade_pct": -0.8}}"#,
    ),
    (
        "tbm-south",
        r#"{"name": "S-2 drive", "start_station_m": 1000.0,
        "start": {"easting_m": 1400.0, "northing_m": 4800.0, "azimuth_deg": 200.0},
        "horizontal": [
          {"type": "line", "length_m": 30.0},
          {"type": "spiral", "length_m": 40.0, "radius_start_m": null, "radius_end_m": -450.0},
          {"type": "arc", "length_m": 80.0, "radius_m": -450.0},
          {"type": "spiral", "length_m": 30.0, "radius_start_m": -450.0, "radius_end_m": -900.0},
          {"type": "arc", "length_m": 60.0, "radius_m": -900.0},
          {"type": "spiral", "length_m": 30.0, "radius_start_m": -900.0, "radius_end_m": null},
          {"type": "line", "length_m": 60.0}],
        "vertical": {"start_height_m": 42.0,
          "pvis": [{"station_m": 1100.0, "height_m": 41.2, "curve_length_m": 60.0},
                   {"station_m": 1240.0, "height_m": 41.9, "curve_length_m": 60.0}],
          "end_grade_pct": 0.3}}"#,
    ),
    (
        "pipejack-3",
        r#"{"name": "P-3 microtunnel", "start_station_m": 0.0,
        "start": {"easting_m": 900.0, "northing_m": 5200.0, "azimuth_deg": 95.0},
        "horizontal": [
          {"type": "line", "length_m": 20.0},
          {"type": "spiral", "length_m": 20.0, "radius_start_m": null, "radius_end_m": 250.0},
          {"type": "arc", "length_m": 40.0, "radius_m": 250.0},
          {"type": "spiral", "length_m": 20.0, "radius_start_m": 250.0, "radius_end_m": null},
          {"type": "line", "length_m": 100.0}],
        "vertical": {"start_height_m": 8.0,
          "pvis": [{"station_m": 90.0, "height_m": 8.9, "curve_length_m": 40.0}],
          "end_grade_pct": 0.2}}"#,
    ),
    (
        "pipejack-ins",
        r#"{"name": "P-7 straight", "start_station_m": 0.0,
        "start": {"easting_m": 1197.5, "northing_m": 5595.669872981078, "azimuth_deg": 30.0},
        "horizontal": [{"type": "line", "length_m": 3000.0}],
        "vertical": {"start_height_m": 11.656365661, "end_grade_pct": 0.872686779}}"#,
    ),
];

/// The demo machines with their design axes, validated.
fn demo_machines() -> Result<Vec<crate::config::MachineSpec>, CliError> {
    let mut config: ServerConfig = toml::from_str(DEMO_MACHINES)
        .map_err(|e| CliError::Scenario(format!("demo machines: {e}")))?;
    for (id, axis) in DEMO_AXES {
        let declaration = config.machines.get_mut(id).ok_or_else(|| {
            CliError::Scenario(format!("demo axis for an undeclared machine {id}"))
        })?;
        declaration.alignment = Some(
            serde_json::from_str(axis)
                .map_err(|e| CliError::Scenario(format!("demo axis of {id}: {e}")))?,
        );
    }
    Ok(config
        .machines
        .into_iter()
        .map(|(id, declaration)| declaration.validate(&id))
        .collect::<Result<_, _>>()?)
}

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
    /// Log lines as text or JSON objects.
    #[arg(long, value_enum, default_value = "text")]
    pub log_format: super::serve::LogFormat,
    /// An MQTT broker (`mqtt://host:port`): the server takes readings from
    /// it, and the first TBM's gateway publishes through it instead of
    /// posting over HTTP.
    #[arg(long, value_name = "URL")]
    pub mqtt: Option<String>,
}

pub fn run(args: DemoArgs) -> Result<(), CliError> {
    init_tracing(args.log_format);
    if !(args.rate.is_finite() && args.rate > 0.0 && args.rate <= 10_000.0) {
        return Err(CliError::Scenario(format!(
            "--rate {} is not in (0, 10000]",
            args.rate
        )));
    }
    let machines = demo_machines()?;
    let mqtt = super::serve::mqtt_settings(args.mqtt.as_deref(), &MqttConfig::default())?;
    let axes: Vec<Option<AxisDriveScenario>> = GATEWAYS
        .iter()
        .map(|gateway| axis_scenario(gateway, &machines))
        .collect();
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
            postgres: None,
            data_dir: args.data_dir.clone(),
            machines,
            limits: Limits::default(),
            clock,
            retention: crate::store::retention::Retention::default(),
            webhooks: Default::default(),
            cluster: None,
            forward: None,
            site_backlog_alarm_s: crate::server::settings::SitesConfig::default().backlog_alarm_s(),
            // Its own gateways post dozens a second: the console keeps the
            // URL, the summary, alarms and errors (RUST_LOG=debug shows them).
            access_log: tracing::Level::DEBUG,
        };
        let (state, listener) = start(
            options,
            args.listen,
            args.allow_no_auth,
            super::serve::NodeArgs::default(),
        )
        .await?;
        let address = listener.local_addr()?;
        if let Some(mqtt) = &mqtt {
            server::mqtt::spawn(state.clone(), mqtt.clone());
        }
        println!(
            "tunnelnav demo: open http://{address}/ in a browser. Five simulated machines, \
             server clock ×{} (a 1-minute laser period every {:.0} s), data in {}. Ctrl-C stops.",
            args.rate,
            DEMO_LASER_PERIOD_S / args.rate,
            args.data_dir.display()
        );

        tokio::spawn(summarise(state.clone(), clock));
        let (stop_gateways, stopping) = watch::channel(false);
        let mut gateways = Vec::new();
        for (i, (gateway, axis)) in GATEWAYS.iter().zip(axes).enumerate() {
            // With a broker, the first gateway publishes through it.
            let broker = mqtt
                .as_ref()
                .filter(|_| i == 0)
                .map(|settings| settings.options.clone());
            gateways.push(tokio::spawn(run_gateway(
                gateway,
                axis,
                address,
                broker,
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

/// How often the demo's console says how it goes.
const SUMMARY_EVERY: Duration = Duration::from_secs(10);

/// Every [`SUMMARY_EVERY`], one line: the machines, the readings a second
/// they received, the simulated time, the active alarms.
async fn summarise(state: crate::server::state::SharedState, clock: Clock) {
    let received = |state: &crate::server::state::SharedState| -> u64 {
        state
            .all_machines()
            .iter()
            .map(|m| m.status().sensors.values().map(|s| s.readings).sum::<u64>())
            .sum()
    };
    let mut ticks = tokio::time::interval(SUMMARY_EVERY);
    ticks.tick().await;
    let mut before = received(&state);
    loop {
        ticks.tick().await;
        let now = received(&state);
        let store = state.store.clone();
        let active = tokio::task::spawn_blocking(move || {
            store.alarms(&crate::store::alarms::AlarmFilter {
                machine: None,
                active_only: true,
                ..Default::default()
            })
        })
        .await
        .ok()
        .and_then(Result::ok)
        .map_or(0, |alarms| alarms.len());
        let simulated = chrono::DateTime::<chrono::Utc>::from_timestamp(clock.now_s() as i64, 0)
            .map(|d| d.format("%Y-%m-%d %H:%M").to_string())
            .unwrap_or_default();
        tracing::info!(
            "demo: {} machines, {:.0} readings/s, simulated clock {simulated} UTC, {active} active alarms",
            state.all_machines().len(),
            now.saturating_sub(before) as f64 / SUMMARY_EVERY.as_secs_f64(),
        );
        before = now;
    }
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
                        match &r.data {
                            SensorData::Level { height_m } => resume.aids.0 = Some(*height_m),
                            SensorData::Odometer { distance_m } => {
                                resume.aids.1 = Some(*distance_m)
                            }
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
    axis: Option<AxisDriveScenario>,
    start_t: f64,
    (height_m, odometer_m): (Option<f64>, Option<f64>),
) -> Result<Box<dyn Iterator<Item = Reading> + Send>, String> {
    Ok(match gateway.kind {
        Kind::Tbm => {
            let axis = axis.ok_or("a demo TBM without a design axis")?;
            Box::new(AxisDrives::new(axis, gateway.seed, start_t)?)
        }
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
        Kind::Vehicle => Box::new(VehicleShifts::new(gateway.seed, start_t)?.map(|e| e.reading)),
    })
}

/// The demo's laser period, s.
const DEMO_LASER_PERIOD_S: f64 = 60.0;

/// What a demo TBM drives: its declared axis and geometry, strokes and
/// ring builds quicker than a real TBM's (1.5 m per 12–20 min) so that at
/// the demo's clock the deviation visibly drifts towards the warn limit
/// (tbm-south's past it, often) and is steered back within minutes.
fn axis_scenario(gateway: &Gateway, machines: &[MachineSpec]) -> Option<AxisDriveScenario> {
    if gateway.kind != Kind::Tbm {
        return None;
    }
    let spec = machines.iter().find(|m| m.id == gateway.machine)?;
    let alignment = spec.alignment.clone()?;
    let geometry = spec.geometry?;
    let length_m = geometry.front_m[0] - geometry.rear_m[0];
    Some(AxisDriveScenario {
        geometry,
        tolerances: spec.tolerances?,
        start_station_m: alignment.start_station_m + length_m + 2.0,
        peak_fraction: if gateway.machine == "tbm-south" {
            1.8
        } else {
            1.3
        },
        drift_wavelength_m: (36.0, 14.0),
        stroke_min: (8.0, 13.0),
        ring_build_min: (4.0, 7.0),
        laser_period_s: DEMO_LASER_PERIOD_S,
        hours: 24.0 * 366.0,
        ..AxisDriveScenario::on(alignment, gateway.seed)
    })
}

/// A demo TBM's readings: drives along its axis back to back, each from
/// the axis's start once the last one reached its end (half an hour after
/// its last stroke), with the next seed; an `advance` reading closes each
/// ring as its build ends, numbered from 1 in each drive (a demo started
/// again starts a drive again).
struct AxisDrives {
    scenario: AxisDriveScenario,
    drive: AxisDrive,
    end_t: f64,
    /// When the drive's rings are complete, the next first.
    rings: std::collections::VecDeque<f64>,
    /// The last ring's number.
    ring: u64,
    /// A reading of the drive held back for an advance before it.
    held: Option<Reading>,
}

impl AxisDrives {
    fn new(mut scenario: AxisDriveScenario, seed: u64, start_t: f64) -> Result<AxisDrives, String> {
        scenario.seed = seed;
        scenario.start_t = start_t;
        let drive = AxisDrive::new(scenario.clone())?;
        let end_t = drive.last_stroke_end_t() + 1800.0;
        let rings = drive.rings_complete_t().collect();
        Ok(AxisDrives {
            scenario,
            drive,
            end_t,
            rings,
            ring: 0,
            held: None,
        })
    }
}

impl Iterator for AxisDrives {
    type Item = Reading;

    fn next(&mut self) -> Option<Reading> {
        let reading = match self.held.take() {
            Some(reading) => Some(reading),
            None => self
                .drive
                .next()
                .filter(|e| e.reading.t < self.end_t)
                .map(|e| e.reading),
        };
        let Some(reading) = reading else {
            let next =
                AxisDrives::new(self.scenario.clone(), self.scenario.seed + 1, self.end_t).ok()?;
            *self = next;
            return self.next();
        };
        if let Some(&ring_t) = self.rings.front()
            && ring_t <= reading.t
        {
            self.rings.pop_front();
            self.ring += 1;
            self.held = Some(reading);
            return Some(Reading {
                t: ring_t,
                data: SensorData::Advance {
                    ring: self.ring,
                    strokes_mm: None,
                    key: None,
                },
            });
        }
        Some(reading)
    }
}

/// The demo vehicle's readings with their truth: simulated shifts back to
/// back, each starting where the last one ended (time and heading), each
/// with a new turn-on gyro bias (a power cycle) and a route of its own;
/// the magnetometer's hard and soft iron are the first shift's throughout
/// (the same sensor on the same van).
pub struct VehicleShifts {
    seed: u64,
    drive: VehicleDrive,
    iron: Iron,
    end_t: f64,
    heading_deg: f64,
}

impl VehicleShifts {
    fn shift(
        seed: u64,
        start_t: f64,
        heading_deg: f64,
        iron: Option<Iron>,
    ) -> Result<VehicleDrive, String> {
        VehicleDrive::new(VehicleScenario {
            seed,
            start_t,
            duration_s: DEMO_SHIFT_S,
            imu_rate_hz: DEMO_VEHICLE_IMU_HZ,
            mag_rate_hz: DEMO_VEHICLE_MAG_HZ,
            initial_heading_deg: heading_deg,
            iron,
            ..VehicleScenario::default()
        })
    }

    /// The shifts of the vehicle of seed `seed` from `start_t`.
    pub fn new(seed: u64, start_t: f64) -> Result<VehicleShifts, String> {
        let heading_deg = VehicleScenario::default().initial_heading_deg;
        let drive = Self::shift(seed, start_t, heading_deg, None)?;
        Ok(VehicleShifts {
            seed,
            iron: drive.iron(),
            drive,
            end_t: start_t,
            heading_deg,
        })
    }

    /// The demo's service vehicle (its machine and seed), from `start_t`.
    pub fn demo_vehicle(start_t: f64) -> Result<(&'static str, VehicleShifts), String> {
        let gateway = GATEWAYS
            .iter()
            .find(|g| matches!(g.kind, Kind::Vehicle))
            .ok_or("the demo has no vehicle")?;
        Ok((gateway.machine, VehicleShifts::new(gateway.seed, start_t)?))
    }
}

impl Iterator for VehicleShifts {
    type Item = VehicleEvent;

    fn next(&mut self) -> Option<VehicleEvent> {
        loop {
            if let Some(event) = self.drive.next() {
                self.end_t = event.reading.t;
                if let Some(truth) = &event.truth {
                    self.heading_deg = truth.heading_deg;
                }
                return Some(event);
            }
            self.seed += 1;
            let start_t = self.end_t + 1.0 / DEMO_VEHICLE_IMU_HZ;
            self.drive = Self::shift(self.seed, start_t, self.heading_deg, Some(self.iron)).ok()?;
        }
    }
}

/// One field gateway: sends the simulator's readings as the clock reaches
/// them, keeping what could not be delivered for the next send.
async fn run_gateway(
    gateway: &'static Gateway,
    axis: Option<AxisDriveScenario>,
    address: SocketAddr,
    broker: Option<rumqttc::MqttOptions>,
    clock: Clock,
    aids: (Option<f64>, Option<f64>),
    mut stop: watch::Receiver<bool>,
) {
    let start_t = clock.now_s();
    let mut drive = match readings(gateway, axis, start_t, aids) {
        Ok(drive) => drive.peekable(),
        Err(e) => {
            tracing::error!(machine = gateway.machine, "demo drive: {e}");
            return;
        }
    };
    let mut sender = Sender::new(gateway, address, broker);
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
    /// Publishing through a broker instead, when given one.
    mqtt: Option<BrokerLink>,
}

/// A gateway's MQTT client: its handle and the broker's PUBACKs.
struct BrokerLink {
    client: rumqttc::AsyncClient,
    acknowledged: tokio::sync::mpsc::UnboundedReceiver<()>,
    poller: tokio::task::JoinHandle<()>,
}

impl BrokerLink {
    /// A persistent session of its own (`demo-{machine}`): what the
    /// broker acknowledged it delivers, even across a tunnelnav restart.
    fn connect(machine: &str, mut options: rumqttc::MqttOptions) -> BrokerLink {
        use rumqttc::{Event, Packet};
        options.set_client_id(format!("demo-{machine}"));
        options.set_manual_acks(false);
        let (client, mut eventloop) = rumqttc::AsyncClient::new(options, 64);
        let (acked, acknowledged) = tokio::sync::mpsc::unbounded_channel();
        let poller = tokio::spawn(async move {
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::PubAck(_))) => {
                        let _ = acked.send(());
                    }
                    Ok(_) => {}
                    Err(_) => tokio::time::sleep(Duration::from_secs(1)).await,
                }
            }
        });
        BrokerLink {
            client,
            acknowledged,
            poller,
        }
    }

    /// Publishes NDJSON at QoS 1; `Ok` once the broker has it.
    async fn publish(&mut self, machine: &str, readings: &[Reading]) -> Result<(), String> {
        let body: String = readings.iter().map(|r| r.to_json() + "\n").collect();
        self.client
            .publish(
                format!("tunnelnav/v1/{machine}/readings"),
                rumqttc::QoS::AtLeastOnce,
                false,
                body.into_bytes(),
            )
            .await
            .map_err(|e| e.to_string())?;
        tokio::time::timeout(Duration::from_secs(10), self.acknowledged.recv())
            .await
            .map_err(|_| "the broker did not acknowledge within 10 s".to_string())?
            .ok_or_else(|| "the broker link ended".to_string())
    }
}

impl Drop for BrokerLink {
    fn drop(&mut self) {
        self.poller.abort();
    }
}

impl Sender {
    fn new(
        gateway: &'static Gateway,
        address: SocketAddr,
        broker: Option<rumqttc::MqttOptions>,
    ) -> Sender {
        Sender {
            gateway,
            base: format!("{address}/api/v1/machines/{}", gateway.machine),
            http: reqwest::Client::new(),
            socket: None,
            mqtt: broker.map(|options| BrokerLink::connect(gateway.machine, options)),
        }
    }

    /// Sends the readings; `Ok` once the server acknowledged the batch. A
    /// reading the server rejects is logged, not retried.
    async fn send(&mut self, readings: &[Reading]) -> Result<(), String> {
        // Through the broker: its answers go to the acks topic; what it
        // rejects is in the server's log and metrics.
        if let Some(link) = &mut self.mqtt {
            return link.publish(self.gateway.machine, readings).await;
        }
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
