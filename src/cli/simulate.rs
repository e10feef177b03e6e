//! `tunnelnav simulate ...`

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use clap::{Args, Subcommand};

use super::CliError;
use crate::fusion::{EngineKind, Reading, SensorKind};
use crate::sim::faults::{FaultInjector, FaultKind, FaultWindow};
use crate::sim::pipejack::{
    Case, IMU_RATE_HZ, Machinery, MachineryPattern, PipeJackDrive, PipeJackScenario,
};
use crate::sim::pipejack_envelope::PipeJackEnvelope;
use crate::sim::tbm::{DEFAULT_START_T, Dropout, TbmDrive, TbmEvent, TbmScenario};
use crate::sim::tbm_envelope::EnvelopeDrive;
use crate::sim::vehicle::{
    DriveProfile, ImuErrors, MagnetDisturbance, VehicleDrive, VehicleScenario,
};
use crate::sim::vehicle_envelope::{VehicleCategory, VehicleEnvelope};

#[derive(Debug, Subcommand)]
pub enum Scenario {
    /// A TBM drive: excavation and ring building, laser + inclinometer.
    Tbm(TbmArgs),
    /// A pipe-jacking drive: FOG IMU at 100 Hz, level and odometer at 1 Hz.
    PipeJacking(PipeJackingArgs),
    /// A small tunnel vehicle: MEMS IMU at 100 Hz, magnetometer at 10 Hz.
    Vehicle(VehicleArgs),
}

/// The simulated vehicle drive: shared by `simulate vehicle` and `eval fuzzy`.
#[derive(Debug, Args)]
pub struct VehicleDriveArgs {
    /// Length of the drive, minutes.
    #[arg(long, default_value_t = 20.0)]
    pub minutes: f64,
    /// Heading at the start, degrees clockwise from north.
    #[arg(long, default_value_t = 75.0, allow_negative_numbers = true)]
    pub heading_deg: f64,
    /// The Earth's field at the site: total intensity, µT.
    #[arg(long, default_value_t = 50.0)]
    pub field_ut: f64,
    /// Inclination of the field, degrees, down positive.
    #[arg(long, default_value_t = 60.0, allow_negative_numbers = true)]
    pub inclination_deg: f64,
    /// Magnetic declination, degrees, east positive.
    #[arg(long, default_value_t = 2.5, allow_negative_numbers = true)]
    pub declination_deg: f64,
    /// IMU rate, Hz.
    #[arg(long, default_value_t = 100.0)]
    pub imu_rate_hz: f64,
    /// Magnetometer rate, Hz.
    #[arg(long, default_value_t = 10.0)]
    pub mag_rate_hz: f64,
    /// Random seed: the same seed gives the same drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Unix seconds of the first reading.
    #[arg(long, default_value_t = DEFAULT_START_T)]
    pub start_t: f64,
    /// The harder drive all at once: --profile hard and a hand-held grade
    /// MEMS IMU (gyro bias 1 °/s, drift up to 0.1 °/s per minute, noise
    /// 0.5 °/s and 0.1 m/s², vibration 0.5 m/s² + 0.1 per m/s rolling,
    /// 0.2 m/s² idling). The flags below override single values.
    #[arg(long)]
    pub hard: bool,
    /// gentle: the default drive; hard: accelerations to 3 m/s², turns at
    /// 30–60 °/s, creeping legs, idling stops (manoeuvres only).
    /// Default: hard with --hard, else gentle.
    #[arg(long, value_enum)]
    pub profile: Option<DriveProfile>,
    /// Gyro turn-on bias, °/s (1σ per axis; default 0.3).
    #[arg(long, value_parser = non_negative)]
    pub gyro_bias_dps: Option<f64>,
    /// Largest slope of the drifting gyro bias, °/s per minute (per axis,
    /// a new slope every 1–3 min; default 0).
    #[arg(long, value_parser = non_negative)]
    pub bias_drift_dps_per_min: Option<f64>,
    /// Gyro white noise per sample, °/s (default 0.05).
    #[arg(long, value_parser = non_negative)]
    pub gyro_noise_dps: Option<f64>,
    /// Accelerometer white noise per sample, m/s² (default 0.02).
    #[arg(long, value_parser = non_negative)]
    pub accel_noise_mps2: Option<f64>,
    /// Accelerometer bias, m/s² (1σ per axis; default 0.02).
    #[arg(long, value_parser = non_negative)]
    pub accel_bias_mps2: Option<f64>,
    /// Vibration rolling at walking pace and faster, m/s² (default 0.3).
    #[arg(long, value_parser = non_negative)]
    pub vibration_mps2: Option<f64>,
    /// Extra vibration per m/s of speed, m/s² (default 0).
    #[arg(long, value_parser = non_negative)]
    pub vibration_growth_per_mps: Option<f64>,
    /// Vibration standing with the engine idling, m/s² (default 0.01).
    #[arg(long, value_parser = non_negative)]
    pub idle_vibration_mps2: Option<f64>,
    /// A magnet near the sensor from this many seconds after the start
    /// (with --magnet-for-s and --magnet-ut).
    #[arg(long, value_parser = non_negative, requires_all = ["magnet_for_s", "magnet_ut"])]
    pub magnet_at_s: Option<f64>,
    /// How long the magnet stays, s.
    #[arg(long, value_parser = non_negative, requires = "magnet_at_s")]
    pub magnet_for_s: Option<f64>,
    /// The magnet's field at the sensor, µT, fixed in the body frame.
    #[arg(long, value_parser = non_negative, requires = "magnet_at_s")]
    pub magnet_ut: Option<f64>,
    /// Fault: power-cycle the IMU this many seconds from the start (its
    /// gyros come up with a new turn-on bias); repeatable, and allowed
    /// with --envelope.
    #[arg(long = "power-cycle-at-s", value_name = "S", value_parser = non_negative)]
    pub power_cycle_at_s: Vec<f64>,
    /// With --envelope: draw the drive in this category (issue 55; see
    /// `src/sim/vehicle_envelope.rs`).
    #[arg(long, value_enum, default_value = "ordinary", requires = "envelope")]
    pub category: VehicleCategory,
    /// Draw the vehicle, its sensors, the site and the drive at random
    /// from the envelope the fuzzy engine must hold over (seeded by
    /// --seed). See `src/sim/vehicle_envelope.rs`.
    #[arg(long, conflicts_with_all = [
        "minutes", "heading_deg", "field_ut", "inclination_deg", "declination_deg",
        "imu_rate_hz", "mag_rate_hz", "hard", "profile", "gyro_bias_dps",
        "bias_drift_dps_per_min", "gyro_noise_dps", "accel_noise_mps2", "accel_bias_mps2",
        "vibration_mps2", "vibration_growth_per_mps", "idle_vibration_mps2", "magnet_at_s",
    ])]
    pub envelope: bool,
}

/// A finite number ≥ 0.
fn non_negative(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("`{text}` is not a number ≥ 0")),
    }
}

impl VehicleDriveArgs {
    /// The scenario these arguments describe.
    pub fn scenario(&self) -> VehicleScenario {
        if self.envelope {
            return VehicleScenario {
                start_t: self.start_t,
                power_cycles_s: self.power_cycle_at_s.clone(),
                ..VehicleEnvelope::draw_in(self.seed, self.category).scenario
            };
        }
        let preset = if self.hard {
            VehicleScenario::hard()
        } else {
            VehicleScenario::default()
        };
        let i = preset.imu;
        let imu = ImuErrors {
            gyro_bias_dps: self.gyro_bias_dps.unwrap_or(i.gyro_bias_dps),
            bias_drift_dps_per_min: self
                .bias_drift_dps_per_min
                .unwrap_or(i.bias_drift_dps_per_min),
            gyro_noise_dps: self.gyro_noise_dps.unwrap_or(i.gyro_noise_dps),
            accel_bias_mps2: self.accel_bias_mps2.unwrap_or(i.accel_bias_mps2),
            accel_noise_mps2: self.accel_noise_mps2.unwrap_or(i.accel_noise_mps2),
            vibration_mps2: self.vibration_mps2.unwrap_or(i.vibration_mps2),
            vibration_growth_per_mps: self
                .vibration_growth_per_mps
                .unwrap_or(i.vibration_growth_per_mps),
            idle_vibration_mps2: self.idle_vibration_mps2.unwrap_or(i.idle_vibration_mps2),
        };
        let magnet = match (self.magnet_at_s, self.magnet_for_s, self.magnet_ut) {
            (Some(at_s), Some(for_s), Some(field_ut)) => Some(MagnetDisturbance {
                at_s,
                for_s,
                field_ut,
            }),
            _ => None,
        };
        VehicleScenario {
            seed: self.seed,
            start_t: self.start_t,
            duration_s: self.minutes * 60.0,
            imu_rate_hz: self.imu_rate_hz,
            mag_rate_hz: self.mag_rate_hz,
            initial_heading_deg: self.heading_deg,
            field_ut: self.field_ut,
            inclination_deg: self.inclination_deg,
            declination_deg: self.declination_deg,
            profile: self.profile.unwrap_or(preset.profile),
            imu,
            magnet,
            manoeuvres: None,
            iron: None,
            disturbances: Vec::new(),
            power_cycles_s: self.power_cycle_at_s.clone(),
        }
    }
}

#[derive(Debug, Args)]
pub struct VehicleArgs {
    #[command(flatten)]
    pub drive: VehicleDriveArgs,
    /// Write the truth (one NDJSON line per IMU reading) to this file.
    #[arg(long, value_name = "FILE")]
    pub truth: Option<PathBuf>,
    /// Inject this fault at 40 % of the drive into the readings written
    /// (the truth is left as it was; docs/evaluation.md, "Faults"): the
    /// same injection as `eval … --envelope --fault`.
    #[arg(long, value_enum)]
    pub fault: Option<FaultKind>,
}

/// The simulated pipe-jacking drive: shared by `simulate pipe-jacking` and `eval zupt`.
#[derive(Debug, Args)]
pub struct PipeJackArgs {
    /// trolley: the paper's 30 s push / 30 s rest over 36.55 m; varied:
    /// pushes of 15–45 s, rests of 10–60 s; field: 2 mm/s with cutter vibration.
    #[arg(long, value_enum, default_value_t = Case::Trolley)]
    pub case: Case,
    /// Heading of the drive, degrees clockwise from north.
    #[arg(long, default_value_t = 30.0, allow_negative_numbers = true)]
    pub heading_deg: f64,
    /// Slope of the drive, degrees, positive rising.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub slope_deg: f64,
    /// Site latitude, degrees.
    #[arg(long, default_value_t = 30.0, allow_negative_numbers = true)]
    pub latitude_deg: f64,
    /// Push durations as MIN:MAX seconds (or one value), instead of the case's.
    #[arg(long, value_name = "MIN:MAX", value_parser = parse_range)]
    pub push_s: Option<(f64, f64)>,
    /// Rest durations as MIN:MAX seconds (or one value), instead of the case's.
    #[arg(long, value_name = "MIN:MAX", value_parser = parse_range)]
    pub rest_s: Option<(f64, f64)>,
    /// IMU rate, Hz.
    #[arg(long, default_value_t = IMU_RATE_HZ)]
    pub imu_rate_hz: f64,
    /// Running machinery (a power pack shaking the machine while it
    /// stands): off, always, or cycling on and off every 1–5 min. Default:
    /// always in the field case, off on the trolley.
    #[arg(long, value_enum)]
    pub machinery: Option<MachineryPattern>,
    /// The machinery's vibration amplitude range, mg.
    #[arg(long, value_name = "MIN:MAX", value_parser = parse_range, default_value = "2:5")]
    pub machinery_mg: (f64, f64),
    /// The machinery's frequency band, Hz.
    #[arg(long, value_name = "MIN:MAX", value_parser = parse_range, default_value = "20:60")]
    pub machinery_hz: (f64, f64),
    /// Length of a field drive, hours.
    #[arg(long, default_value_t = 2.0)]
    pub field_hours: f64,
    /// Random seed: the same seed gives the same drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Unix seconds of the first reading.
    #[arg(long, default_value_t = DEFAULT_START_T)]
    pub start_t: f64,
}

/// `MIN:MAX` or one number.
fn parse_range(text: &str) -> Result<(f64, f64), String> {
    let number = |s: &str| {
        s.trim()
            .parse::<f64>()
            .map_err(|_| format!("`{s}` is not a number"))
    };
    let (min, max) = match text.split_once(':') {
        Some((a, b)) => (number(a)?, number(b)?),
        None => (number(text)?, number(text)?),
    };
    if !(min.is_finite() && max.is_finite() && min > 0.0 && max >= min) {
        return Err(format!("`{text}`: expected 0 < MIN ≤ MAX"));
    }
    Ok((min, max))
}

impl PipeJackArgs {
    /// The scenario these arguments describe.
    pub fn scenario(&self) -> PipeJackScenario {
        PipeJackScenario {
            case: self.case,
            seed: self.seed,
            start_t: self.start_t,
            heading_deg: self.heading_deg,
            slope_deg: self.slope_deg,
            latitude_deg: self.latitude_deg,
            push_s: self.push_s,
            rest_s: self.rest_s,
            imu_rate_hz: self.imu_rate_hz,
            field_duration_s: self.field_hours * 3600.0,
            machinery: Some(Machinery {
                pattern: self.machinery.unwrap_or(self.case.machinery_pattern()),
                amplitude_mg: self.machinery_mg,
                band_hz: self.machinery_hz,
            }),
            ..PipeJackScenario::default()
        }
    }
}

#[derive(Debug, Args)]
pub struct PipeJackingArgs {
    #[command(flatten)]
    pub drive: PipeJackArgs,
    /// Draw the machine, its sensors and the drive at random from the
    /// envelope the zupt engine must hold over (seeded by --seed; the draw
    /// goes to stderr as JSON). See `src/sim/pipejack_envelope.rs`.
    #[arg(long, conflicts_with_all = ["case", "push_s", "rest_s", "machinery", "heading_deg", "slope_deg", "latitude_deg"])]
    pub envelope: bool,
    /// Write the truth (one NDJSON line per IMU reading) to this file.
    #[arg(long, value_name = "FILE")]
    pub truth: Option<PathBuf>,
    /// Inject this fault at 40 % of the drive into the readings written
    /// (the truth is left as it was; docs/evaluation.md, "Faults"): the
    /// same injection as `eval … --envelope --fault`.
    #[arg(long, value_enum)]
    pub fault: Option<FaultKind>,
}

/// The simulated drive: shared by `simulate tbm` and `eval attitude`.
#[derive(Debug, Args)]
pub struct DriveArgs {
    /// Length of the drive in hours.
    #[arg(long, default_value_t = 10.0)]
    pub hours: f64,
    /// Inclinometer period in seconds.
    #[arg(long, default_value_t = 1.0)]
    pub incl_period_s: f64,
    /// Laser period in seconds (the paper's system: 120).
    #[arg(long, default_value_t = 120.0)]
    pub laser_period_s: f64,
    /// A laser dropout as START_H:MINUTES (repeatable), e.g. 7:45.
    #[arg(long = "dropout", value_name = "START_H:MINUTES")]
    pub dropouts: Vec<Dropout>,
    /// Random seed: the same seed gives the same drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Unix seconds of the first reading.
    #[arg(long, default_value_t = DEFAULT_START_T)]
    pub start_t: f64,
}

impl DriveArgs {
    /// The scenario these arguments describe.
    pub fn scenario(&self) -> TbmScenario {
        TbmScenario {
            seed: self.seed,
            start_t: self.start_t,
            hours: self.hours,
            incl_period_s: self.incl_period_s,
            laser_period_s: self.laser_period_s,
            dropouts: self.dropouts.clone(),
        }
    }
}

#[derive(Debug, Args)]
pub struct TbmArgs {
    #[command(flatten)]
    pub drive: DriveArgs,
    /// Draw the machine, its sensors and the drive at random from the
    /// envelope the attitude engine must hold over (seeded by --seed; the
    /// draw goes to stderr as JSON). See `src/sim/tbm_envelope.rs`.
    #[arg(long, conflicts_with_all = ["hours", "incl_period_s", "laser_period_s", "dropouts"])]
    pub envelope: bool,
    /// Write the truth (one NDJSON line per inclinometer reading) to this file.
    #[arg(long, value_name = "FILE")]
    pub truth: Option<PathBuf>,
    /// Inject this fault at 40 % of the drive into the readings written
    /// (the truth is left as it was; docs/evaluation.md, "Faults"): the
    /// same injection as `eval … --envelope --fault`.
    #[arg(long, value_enum)]
    pub fault: Option<FaultKind>,
}

pub fn run(scenario: Scenario) -> Result<(), CliError> {
    match scenario {
        Scenario::Tbm(args) => run_tbm(&args),
        Scenario::PipeJacking(args) => run_pipe_jacking(&args),
        Scenario::Vehicle(args) => {
            let mut scenario = args.drive.scenario();
            let mut injector = injector(
                args.fault,
                EngineKind::Fuzzy,
                scenario.start_t,
                scenario.duration_s,
            )?;
            // The IMU's power cycle is the simulator's own (a new turn-on
            // bias of its model).
            if let Some(by_simulator) = injector.take_if(|i| i.by_simulator()) {
                let window = by_simulator.window();
                scenario
                    .power_cycles_s
                    .push(window.from_t - scenario.start_t);
            }
            if args.drive.envelope {
                eprintln!(
                    "{}",
                    serde_json::to_string(&scenario).map_err(io::Error::other)?
                );
            }
            let drive = VehicleDrive::new(scenario).map_err(CliError::Scenario)?;
            let truth = create_truth(&args.truth)?;
            write_events(
                drive.map(|e| (faulty(&mut injector, e.reading), e.truth)),
                truth,
            )
        }
    }
}

fn create_truth(path: &Option<PathBuf>) -> Result<Option<BufWriter<File>>, CliError> {
    match path {
        Some(path) => Ok(Some(BufWriter::new(File::create(path).map_err(
            |source| CliError::File {
                context: format!("cannot create truth file {}", path.display()),
                source,
            },
        )?))),
        None => Ok(None),
    }
}

/// Writes readings to stdout and truths to `truth`; a reader that stops
/// early (`| head`) is not an error.
fn write_events<T: serde::Serialize>(
    events: impl Iterator<Item = (crate::fusion::Reading, Option<T>)>,
    mut truth: Option<BufWriter<File>>,
) -> Result<(), CliError> {
    let stdout = io::stdout();
    let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let result = (|| -> io::Result<()> {
        for (reading, event_truth) in events {
            serde_json::to_writer(&mut out, &reading)?;
            out.write_all(b"\n")?;
            if let (Some(file), Some(event_truth)) = (truth.as_mut(), event_truth) {
                serde_json::to_writer(&mut *file, &event_truth)?;
                file.write_all(b"\n")?;
            }
        }
        out.flush()?;
        if let Some(file) = truth.as_mut() {
            file.flush()?;
        }
        Ok(())
    })();
    match result {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// The injector of `fault` for a drive of `engine` from `start_t` lasting
/// `duration_s`, if one is asked for.
fn injector(
    fault: Option<FaultKind>,
    engine: EngineKind,
    start_t: f64,
    duration_s: f64,
) -> Result<Option<FaultInjector>, CliError> {
    fault
        .map(|kind| {
            FaultInjector::new(FaultWindow::in_drive(kind, start_t, duration_s), engine)
                .map_err(|e| CliError::Scenario(e.to_string()))
        })
        .transpose()
}

/// `reading` as the fault, if any, delivers it.
fn faulty(injector: &mut Option<FaultInjector>, reading: Reading) -> Reading {
    match injector {
        Some(injector) => injector.apply(reading),
        None => reading,
    }
}

fn run_pipe_jacking(args: &PipeJackingArgs) -> Result<(), CliError> {
    let drive = if args.envelope {
        let mut draw = PipeJackEnvelope::draw(args.drive.seed);
        draw.start_t = args.drive.start_t;
        eprintln!(
            "{}",
            serde_json::to_string(&draw).map_err(io::Error::other)?
        );
        draw.drive()
    } else {
        PipeJackDrive::new(args.drive.scenario()).map_err(CliError::Scenario)?
    };
    let mut injector = injector(
        args.fault,
        EngineKind::Zupt,
        drive.scenario().start_t,
        drive.duration_s(),
    )?;
    let truth = create_truth(&args.truth)?;
    write_events(
        drive.map(|e| (faulty(&mut injector, e.reading), e.truth)),
        truth,
    )
}

fn run_tbm(args: &TbmArgs) -> Result<(), CliError> {
    let truth = create_truth(&args.truth)?;
    let (drive, hours): (Box<dyn Iterator<Item = TbmEvent>>, f64) = if args.envelope {
        let mut draw = EnvelopeDrive::draw(args.drive.seed);
        draw.start_t = args.drive.start_t;
        eprintln!(
            "{}",
            serde_json::to_string(&draw).map_err(io::Error::other)?
        );
        let hours = draw.hours;
        (Box::new(draw.events()), hours)
    } else {
        let drive = TbmDrive::new(args.drive.scenario()).map_err(CliError::Scenario)?;
        (Box::new(drive), args.drive.hours)
    };
    let mut injector = injector(
        args.fault,
        EngineKind::Attitude,
        args.drive.start_t,
        hours * 3600.0,
    )?;
    // The truth is written per inclinometer reading.
    write_events(
        drive.map(|e| {
            let truth = (e.reading.sensor() == SensorKind::Inclinometer).then_some(e.truth);
            (faulty(&mut injector, e.reading), truth)
        }),
        truth,
    )
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        drive: VehicleDriveArgs,
    }

    fn scenario(args: &[&str]) -> VehicleScenario {
        Cli::try_parse_from(std::iter::once("test").chain(args.iter().copied()))
            .unwrap()
            .drive
            .scenario()
    }

    #[test]
    fn no_flags_give_the_default_drive() {
        assert_eq!(scenario(&[]), VehicleScenario::default());
    }

    #[test]
    fn hard_sets_everything_and_single_flags_override() {
        assert_eq!(scenario(&["--hard"]), VehicleScenario::hard());
        let s = scenario(&[
            "--hard",
            "--gyro-noise-dps",
            "0.2",
            "--profile",
            "gentle",
            "--magnet-at-s",
            "10",
            "--magnet-for-s",
            "5",
            "--magnet-ut",
            "150",
        ]);
        assert_eq!(s.profile, DriveProfile::Gentle);
        assert_eq!(
            s.imu,
            ImuErrors {
                gyro_noise_dps: 0.2,
                ..ImuErrors::hard()
            }
        );
        assert_eq!(
            s.magnet,
            Some(MagnetDisturbance {
                at_s: 10.0,
                for_s: 5.0,
                field_ut: 150.0
            })
        );
        let s = scenario(&["--profile", "hard", "--idle-vibration-mps2", "0.3"]);
        assert_eq!(s.profile, DriveProfile::Hard);
        assert_eq!(s.imu.idle_vibration_mps2, 0.3);
        assert_eq!(s.imu.gyro_noise_dps, ImuErrors::default().gyro_noise_dps);
        // A magnet needs all three, and levels are not negative.
        let parse =
            |args: &[&str]| Cli::try_parse_from(std::iter::once("t").chain(args.iter().copied()));
        assert!(parse(&["--magnet-at-s", "10"]).is_err());
        assert!(parse(&["--accel-noise-mps2", "-0.1"]).is_err());
    }
}
