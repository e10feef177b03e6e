//! A simulated drive of a small tunnel vehicle (a service vehicle or a
//! segment carrier) with known truth, for `simulate vehicle`, `eval fuzzy`,
//! the accuracy tests and the benchmarks.
//!
//! The drive (`duration_s`, 20 min by default): parked for 30 s with the
//! engine idling; a slow calibration turn (380° at about 5 °/s at walking
//! pace) and a 20 s stop; then legs until a minute before the end, each an
//! acceleration to 2–6 m/s, 20–90 s of driving with turns of 30–120°,
//! changes of grade (within ±5°) and bank (within ±2°), and bumps (a 0.5–
//! 1.5° pitch or roll kick of 0.4–1 s every 3–15 s), a braking to rest, and
//! a stop of 10–40 s; parked to the end. Every manoeuvre is a raised-cosine
//! pulse of a rate, so the truth is smooth and the IMU readings are the
//! exact derivatives of it. While rolling, the chassis also wobbles (tones
//! of 0.02–0.06° at 4–12 Hz in pitch and roll, part of the truth) and
//! shakes (0.3 m/s² translational vibration per axis, not part of it).
//!
//! Sensors (a MEMS IMU of the kind Wang 2005 uses):
//! - IMU at 100 Hz: gyro bias 0.3 °/s (1σ per axis) plus a warm-up drift
//!   of 0.05 °/s (1σ, time constant 400 s) and a 3·10⁻⁴ °/s/√s random
//!   walk, white noise 0.05 °/s per sample; accelerometer bias 0.02 m/s²
//!   (1σ), white noise 0.02 m/s² per sample, engine vibration 0.01 m/s²
//!   parked and 0.3 m/s² rolling (AR(1), ρ = 0.7);
//! - magnetometer at 10 Hz: the Earth's field (`field_ut`, `inclination_deg`,
//!   `declination_deg`) through soft iron (I + symmetric, diagonal 8 %,
//!   off-diagonal 4 %, 1σ) and hard iron (15 µT in x and y, 5 µT in z,
//!   1σ), white noise 0.3 µT.
//!
//! Harder drives (all off by default, so the default drive is unchanged
//! reading for reading):
//! - [`DriveProfile::Hard`] manoeuvres: legs at 2–7 m/s, or (three in ten)
//!   creeping at walking pace (0.5–1.5 m/s); accelerations and brakings
//!   peaking at 1.5–3 m/s²; one to three tight turns per leg of 45–180° at
//!   a peak rate of 30–60 °/s (capped at a 4 m/s² lateral acceleration);
//!   grade within ±8°, bank within ±3°; bumps of 1–3° every 2–8 s; idling
//!   stops of 5–60 s. The parking and the calibration turn are as gentle.
//! - [`ImuErrors`]: the gyro bias (1σ per axis), a bias drift that keeps
//!   changing (per axis, piecewise linear: a new slope drawn uniformly in
//!   ±`bias_drift_dps_per_min` every 60–180 s, so the bias differs from one
//!   stop to the next), white noise of both sensors, the accelerometer
//!   bias, the rolling vibration (reached at walking pace, growing by
//!   `vibration_growth_per_mps` per m/s above nothing) and the vibration
//!   standing with the engine idling. [`ImuErrors::hard`] is a hand-held
//!   grade MEMS: bias 1 °/s, drift up to 0.1 °/s per minute, noise
//!   0.5 °/s and 0.1 m/s², accelerometer bias 0.05 m/s², vibration
//!   0.5 m/s² + 0.1 m/s² per m/s rolling and 0.2 m/s² idling.
//!   [`VehicleScenario::hard`] is both at once (`--hard`).
//! - [`MagnetDisturbance`]: a magnet near the sensor, a field fixed in the
//!   body frame (along [`MAGNET_DIRECTION`]) added to the magnetometer's
//!   readings over [at, at + for] seconds from the start; the truth marks
//!   its IMU readings (`magnet_near`).

use nalgebra::{Matrix3, UnitQuaternion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::fusion::angles::{deg, rad};
use crate::fusion::geometry::{V3, attitude_from_euler};
use crate::fusion::{Reading, SensorData};

use super::tbm::DEFAULT_START_T;

/// Standard gravity used by the simulated accelerometer, m/s².
const GRAVITY_MPS2: f64 = 9.806_65;
/// Rolling speed at which the wobble and vibration are fully developed.
const FULL_SHAKE_SPEED_MPS: f64 = 0.5;

/// How the vehicle is driven (see the module doc).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DriveProfile {
    /// The default drive: 2–6 m/s, turns of 30–120° over 6–15 s.
    #[default]
    Gentle,
    /// Hard accelerations, tight turns, creeping legs, idling stops.
    Hard,
}

/// The IMU's errors. The default is the module doc's MEMS IMU.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ImuErrors {
    /// Gyro turn-on bias, °/s (1σ per axis).
    pub gyro_bias_dps: f64,
    /// Largest slope of the drifting gyro bias, °/s per minute (0: none).
    pub bias_drift_dps_per_min: f64,
    /// Gyro white noise per sample, °/s (1σ).
    pub gyro_noise_dps: f64,
    /// Accelerometer bias, m/s² (1σ per axis).
    pub accel_bias_mps2: f64,
    /// Accelerometer white noise per sample, m/s² (1σ).
    pub accel_noise_mps2: f64,
    /// Vibration while rolling at walking pace and faster, m/s² (1σ).
    pub vibration_mps2: f64,
    /// Extra vibration per m/s of speed, m/s² (1σ).
    pub vibration_growth_per_mps: f64,
    /// Vibration standing with the engine idling, m/s² (1σ).
    pub idle_vibration_mps2: f64,
}

impl Default for ImuErrors {
    fn default() -> Self {
        ImuErrors {
            gyro_bias_dps: 0.3,
            bias_drift_dps_per_min: 0.0,
            gyro_noise_dps: 0.05,
            accel_bias_mps2: 0.02,
            accel_noise_mps2: 0.02,
            vibration_mps2: 0.3,
            vibration_growth_per_mps: 0.0,
            idle_vibration_mps2: 0.01,
        }
    }
}

impl ImuErrors {
    /// A hand-held grade MEMS IMU on a rough machine (module doc).
    pub fn hard() -> ImuErrors {
        ImuErrors {
            gyro_bias_dps: 1.0,
            bias_drift_dps_per_min: 0.1,
            gyro_noise_dps: 0.5,
            accel_bias_mps2: 0.05,
            accel_noise_mps2: 0.1,
            vibration_mps2: 0.5,
            vibration_growth_per_mps: 0.1,
            idle_vibration_mps2: 0.2,
        }
    }

    fn is_valid(&self) -> bool {
        [
            self.gyro_bias_dps,
            self.bias_drift_dps_per_min,
            self.gyro_noise_dps,
            self.accel_bias_mps2,
            self.accel_noise_mps2,
            self.vibration_mps2,
            self.vibration_growth_per_mps,
            self.idle_vibration_mps2,
        ]
        .iter()
        .all(|x| x.is_finite() && *x >= 0.0)
    }
}

/// The body-frame direction of a [`MagnetDisturbance`]'s field: from the
/// front, right and below (a unit vector).
pub const MAGNET_DIRECTION: [f64; 3] = [0.6, 0.64, 0.48];

/// A magnet brought near the sensor: `field_ut` along [`MAGNET_DIRECTION`]
/// in the body frame over [`at_s`, `at_s + for_s`] from the start.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MagnetDisturbance {
    pub at_s: f64,
    pub for_s: f64,
    pub field_ut: f64,
}

impl MagnetDisturbance {
    /// True while the magnet is near, `s` seconds from the start.
    pub fn is_near(&self, s: f64) -> bool {
        s >= self.at_s && s <= self.at_s + self.for_s
    }
}

/// What to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VehicleScenario {
    pub seed: u64,
    /// Unix seconds of the first reading.
    pub start_t: f64,
    pub duration_s: f64,
    pub imu_rate_hz: f64,
    pub mag_rate_hz: f64,
    /// Heading at the start, clockwise from north.
    pub initial_heading_deg: f64,
    /// The Earth's field at the site: total intensity, inclination (down
    /// positive), declination (east positive).
    pub field_ut: f64,
    pub inclination_deg: f64,
    pub declination_deg: f64,
    /// How the vehicle is driven.
    #[serde(default)]
    pub profile: DriveProfile,
    /// The IMU's errors.
    #[serde(default)]
    pub imu: ImuErrors,
    /// A magnet near the sensor for a while.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub magnet: Option<MagnetDisturbance>,
    /// Manoeuvre ranges an envelope drive is planned from
    /// ([`super::vehicle_envelope`]); `None`: the `profile`'s plan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub manoeuvres: Option<Manoeuvres>,
    /// The magnetometer's hard and soft iron; `None`: drawn from the seed
    /// (module doc).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iron: Option<Iron>,
    /// Further changes of the field at the sensor.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disturbances: Vec<FieldDisturbance>,
    /// Fault: the IMU is power-cycled at these seconds from the start;
    /// each time its gyros come up with a new turn-on bias, drawn like
    /// the first (`imu.gyro_bias_dps`, 1σ per axis), and warm up again.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub power_cycles_s: Vec<f64>,
}

/// The magnetometer's errors: m = S·(Earth's field in the body frame) + b.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Iron {
    /// b, µT.
    pub hard_iron_ut: [f64; 3],
    /// S, rows (symmetric).
    pub soft_iron: [[f64; 3]; 3],
}

/// Where a [`FieldDisturbance`]'s field is fixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DisturbanceFrame {
    /// On the vehicle (a tool, a magnet): turns with it.
    Body,
    /// In the tunnel (steel passed by), north-east-down.
    World,
}

/// `field_ut` added to the magnetometer's readings over [`at_s`,
/// `at_s + for_s`] from the start, fixed in `frame`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FieldDisturbance {
    pub at_s: f64,
    pub for_s: f64,
    pub field_ut: [f64; 3],
    pub frame: DisturbanceFrame,
}

impl FieldDisturbance {
    /// True while the disturbance acts, `s` seconds from the start.
    pub fn is_on(&self, s: f64) -> bool {
        s >= self.at_s && s <= self.at_s + self.for_s
    }
}

/// The ranges an envelope drive's legs are drawn from (uniformly unless
/// said otherwise); see [`super::vehicle_envelope`] for the envelope.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Manoeuvres {
    /// Parked at the start, s; 0: rolling at the first reading.
    pub parked_start_s: f64,
    /// A calibration circle (370° at walking pace) after the parked start
    /// (or after the first leg when rolling from the start): its peak
    /// rate, °/s; `None`: no circle.
    pub calibration_circle_dps: Option<f64>,
    /// Top speed of a leg, m/s (log-uniform between).
    pub speed_mps: (f64, f64),
    /// Peak acceleration and braking, m/s².
    pub accel_mps2: (f64, f64),
    /// Share of the stops reached by coasting (a peak deceleration of
    /// 0.05–0.2 m/s²) rather than braking.
    pub coast_share: f64,
    /// Driving between acceleration and braking, s.
    pub cruise_s: (f64, f64),
    /// Turns per leg (the largest included).
    pub turns_per_leg: (u32, u32),
    /// A turn's angle, degrees, and its peak rate, °/s (capped at a
    /// lateral acceleration of 4 m/s²).
    pub turn_deg: (f64, f64),
    pub turn_rate_dps: (f64, f64),
    /// Grade and bank of a leg within ± these, degrees.
    pub grade_deg: f64,
    pub bank_deg: f64,
    /// Bumps (pitch or roll kicks of 0.3–1 s): size, degrees, and the
    /// time between them, s.
    pub bump_deg: (f64, f64),
    pub bump_every_s: (f64, f64),
    /// A stop's length, s (log-uniform between).
    pub stop_s: (f64, f64),
    /// Standing, the body sways (part of the truth, not motion): amplitude,
    /// degrees, and frequency, Hz, in pitch and in roll; `None`: no sway.
    pub sway: Option<(f64, f64)>,
}

impl Default for VehicleScenario {
    fn default() -> Self {
        VehicleScenario {
            seed: 1,
            start_t: DEFAULT_START_T,
            duration_s: 1200.0,
            imu_rate_hz: 100.0,
            mag_rate_hz: 10.0,
            initial_heading_deg: 75.0,
            field_ut: 50.0,
            inclination_deg: 60.0,
            declination_deg: 2.5,
            profile: DriveProfile::Gentle,
            imu: ImuErrors::default(),
            magnet: None,
            manoeuvres: None,
            iron: None,
            disturbances: Vec::new(),
            power_cycles_s: Vec::new(),
        }
    }
}

impl VehicleScenario {
    /// The harder drive: [`DriveProfile::Hard`] with [`ImuErrors::hard`].
    pub fn hard() -> VehicleScenario {
        VehicleScenario {
            profile: DriveProfile::Hard,
            imu: ImuErrors::hard(),
            ..VehicleScenario::default()
        }
    }
}

/// The true state at one IMU reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VehicleTruth {
    pub t: f64,
    /// True while the vehicle rolls or turns.
    pub moving: bool,
    pub speed_mps: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    /// Clockwise from true north, [0, 360).
    pub heading_deg: f64,
    /// The gyro bias at this instant.
    pub gyro_bias_dps: [f64; 3],
    /// True while a magnet disturbs the magnetometer.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub magnet_near: bool,
}

/// One simulated reading, and the truth if it is an IMU reading.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleEvent {
    pub reading: Reading,
    pub truth: Option<VehicleTruth>,
}

/// What a manoeuvre changes.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Channel {
    Speed,
    Heading,
    Grade,
    Bank,
    BumpPitch,
    BumpRoll,
}

/// A raised-cosine pulse of a rate: the channel changes by `change` over
/// `[start, start + duration]` (a bump's change is its peak, and it returns).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pulse {
    channel: Channel,
    start: f64,
    duration: f64,
    change: f64,
}

impl Pulse {
    /// The channel's rate at `t`.
    fn rate(&self, t: f64) -> f64 {
        let x = (t - self.start) / self.duration;
        if !(0.0..=1.0).contains(&x) {
            return 0.0;
        }
        let w = std::f64::consts::TAU / self.duration;
        match self.channel {
            // Out and back: angle = change·(1 − cos 2πx)/2.
            Channel::BumpPitch | Channel::BumpRoll => {
                self.change * 0.5 * w * (w * (t - self.start)).sin()
            }
            _ => self.change / self.duration * (1.0 - (w * (t - self.start)).cos()),
        }
    }

    /// The channel's value change from the pulse's start to `t`.
    fn integral(&self, t: f64) -> f64 {
        let x = ((t - self.start) / self.duration).clamp(0.0, 1.0);
        let phase = std::f64::consts::TAU * x;
        match self.channel {
            Channel::BumpPitch | Channel::BumpRoll => self.change * 0.5 * (1.0 - phase.cos()),
            _ => self.change * (x - phase.sin() / std::f64::consts::TAU),
        }
    }
}

/// A wobble tone: amplitude (rad), angular frequency (rad/s), phase.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tone {
    amplitude: f64,
    omega: f64,
    phase: f64,
}

/// The simulated drive; iterate it for the readings in time order.
pub struct VehicleDrive {
    scenario: VehicleScenario,
    pulses: Vec<Pulse>,
    pitch_tones: Vec<Tone>,
    roll_tones: Vec<Tone>,
    /// Sway while standing (empty: none).
    pitch_sway: Vec<Tone>,
    roll_sway: Vec<Tone>,
    earth_field_n: V3,
    soft_iron: Matrix3<f64>,
    hard_iron_ut: V3,
    gyro_bias0: V3,
    gyro_warmup: V3,
    /// Per power cycle, from its time on: the new turn-on bias and the
    /// start of its warm-up.
    power_cycles: Vec<(f64, V3)>,
    gyro_walk: V3,
    drift: BiasDrift,
    accel_bias: V3,
    vibration: V3,
    imu_rng: ChaCha8Rng,
    mag_rng: ChaCha8Rng,
    sample: u64,
    next_mag: u64,
    queued: Option<Reading>,
    /// Pulses started and not yet ended; the first not started; and, per
    /// channel, the total change of the pulses that have ended.
    active: Vec<usize>,
    next_pulse: usize,
    settled: [f64; 6],
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

fn normal3(rng: &mut ChaCha8Rng, sigma: f64) -> V3 {
    V3::new(normal(rng), normal(rng), normal(rng)) * sigma
}

/// The drifting part of the gyro bias: per axis piecewise linear, a new
/// slope (uniform within ±the scenario's drift rate) every 60–180 s, from
/// its own generator (so the rest of the drive does not depend on it).
struct BiasDrift {
    rng: ChaCha8Rng,
    /// Largest slope, rad/s per s.
    max_slope: f64,
    /// The drift at `since`, the slopes from then, and when they change.
    offset: V3,
    slope: V3,
    since: f64,
    next_change: f64,
}

impl BiasDrift {
    fn new(seed: u64, dps_per_min: f64) -> BiasDrift {
        let mut drift = BiasDrift {
            rng: ChaCha8Rng::seed_from_u64(seed.wrapping_mul(41).wrapping_add(13)),
            max_slope: rad(dps_per_min) / 60.0,
            offset: V3::zeros(),
            slope: V3::zeros(),
            since: 0.0,
            next_change: 0.0,
        };
        if drift.max_slope > 0.0 {
            drift.redraw();
        }
        drift
    }

    fn redraw(&mut self) {
        let m = self.max_slope;
        self.slope = V3::new(
            self.rng.random_range(-m..=m),
            self.rng.random_range(-m..=m),
            self.rng.random_range(-m..=m),
        );
        self.next_change = self.since + self.rng.random_range(60.0..180.0);
    }

    /// The drift at `s` (which only grows), rad/s.
    fn at(&mut self, s: f64) -> V3 {
        if self.max_slope == 0.0 {
            return V3::zeros();
        }
        while s >= self.next_change {
            self.offset += self.slope * (self.next_change - self.since);
            self.since = self.next_change;
            self.redraw();
        }
        self.offset + self.slope * (s - self.since)
    }
}

/// The drive's manoeuvres.
fn plan(scenario: &VehicleScenario, rng: &mut ChaCha8Rng) -> Vec<Pulse> {
    if let Some(m) = &scenario.manoeuvres {
        return plan_envelope(m, scenario.duration_s, rng);
    }
    match scenario.profile {
        DriveProfile::Gentle => plan_gentle(scenario, rng),
        DriveProfile::Hard => plan_hard(scenario, rng),
    }
}

/// The parking and the calibration turn that start every drive; returns
/// when the legs may start.
fn plan_start(pulses: &mut Vec<Pulse>, rng: &mut ChaCha8Rng) -> f64 {
    let mut push = |channel, start, duration, change| {
        pulses.push(Pulse {
            channel,
            start,
            duration,
            change,
        })
    };
    // Parked 30 s, then the calibration turn at walking pace.
    let mut t = 30.0;
    push(Channel::Speed, t, 4.0, 1.0);
    let direction = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    push(Channel::Heading, t + 4.0, 80.0, rad(380.0) * direction);
    t += 84.0;
    push(Channel::Speed, t, 4.0, -1.0);
    t + 4.0 + 20.0
}

/// A sign drawn at random.
fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random_bool(0.5) { 1.0 } else { -1.0 }
}

/// The hard profile's manoeuvres (module doc).
fn plan_hard(scenario: &VehicleScenario, rng: &mut ChaCha8Rng) -> Vec<Pulse> {
    /// Largest centripetal acceleration a turn may reach, m/s².
    const MAX_LATERAL_MPS2: f64 = 4.0;
    let mut pulses = Vec::new();
    let mut t = plan_start(&mut pulses, rng);
    let mut push = |channel, start, duration, change| {
        pulses.push(Pulse {
            channel,
            start,
            duration,
            change,
        })
    };
    let (mut grade, mut bank) = (0.0_f64, 0.0_f64);
    let end = scenario.duration_s - 60.0;
    loop {
        let creep = rng.random_bool(0.3);
        let speed = if creep {
            rng.random_range(0.5..1.5)
        } else {
            rng.random_range(2.0..7.0)
        };
        // A raised-cosine change of Δv over T peaks at 2Δv/T.
        let accelerate = 2.0 * speed / rng.random_range(1.5..3.0);
        let cruise = rng.random_range(20.0..90.0);
        let brake = 2.0 * speed / rng.random_range(1.5..3.0);
        if t + accelerate + cruise + brake > end {
            break;
        }
        push(Channel::Speed, t, accelerate, speed);
        let (cruise_start, cruise_end) = (t + accelerate, t + accelerate + cruise);
        let mut turn_t = cruise_start + rng.random_range(2.0..8.0);
        for _ in 0..rng.random_range(1..4) {
            let angle = rad(rng.random_range(45.0..180.0));
            let peak = rad(rng.random_range(30.0..60.0)).min(MAX_LATERAL_MPS2 / speed);
            let duration = 2.0 * angle / peak;
            if turn_t + duration > cruise_end {
                break;
            }
            push(Channel::Heading, turn_t, duration, angle * sign(rng));
            turn_t += duration + rng.random_range(2.0..10.0);
        }
        let duration = rng.random_range(4.0_f64..10.0).min(cruise);
        let target = rad(rng.random_range(-8.0..8.0));
        push(Channel::Grade, cruise_start, duration, target - grade);
        grade = target;
        let target = rad(rng.random_range(-3.0..3.0));
        push(Channel::Bank, cruise_start + 1.0, duration, target - bank);
        bank = target;
        let mut bump_t = cruise_start + rng.random_range(2.0..8.0);
        while bump_t + 1.0 < cruise_end {
            let channel = if rng.random_bool(0.5) {
                Channel::BumpPitch
            } else {
                Channel::BumpRoll
            };
            let size = rad(rng.random_range(1.0..3.0)) * sign(rng);
            push(channel, bump_t, rng.random_range(0.3..0.8), size);
            bump_t += rng.random_range(2.0..8.0);
        }
        push(Channel::Speed, cruise_end, brake, -speed);
        t = cruise_end + brake + rng.random_range(5.0..60.0);
    }
    pulses.sort_by(|a, b| a.start.total_cmp(&b.start));
    pulses
}

/// Uniform in a range given as (low, high); the low end when it is empty.
fn within(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

/// Log-uniform in a range of positive values given as (low, high).
fn log_within(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    within(rng, (lo.ln(), hi.ln())).exp()
}

/// An envelope drive's manoeuvres from its ranges ([`Manoeuvres`]).
fn plan_envelope(m: &Manoeuvres, duration_s: f64, rng: &mut ChaCha8Rng) -> Vec<Pulse> {
    /// Largest centripetal acceleration a turn may reach, m/s².
    const MAX_LATERAL_MPS2: f64 = 4.0;
    /// Walking pace, m/s: the calibration circle's speed.
    const WALKING_MPS: f64 = 1.0;
    let mut pulses = Vec::new();
    let mut push = |channel, start, duration, change| {
        pulses.push(Pulse {
            channel,
            start,
            duration,
            change,
        })
    };
    let circle = |push: &mut dyn FnMut(Channel, f64, f64, f64), t: f64, rng: &mut ChaCha8Rng| {
        let peak_dps = m.calibration_circle_dps.unwrap_or(10.0);
        let angle = rad(370.0) * sign(rng);
        let duration = 2.0 * angle.abs() / rad(peak_dps);
        push(Channel::Speed, t, 4.0, WALKING_MPS);
        push(Channel::Heading, t + 4.0, duration, angle);
        push(Channel::Speed, t + 4.0 + duration, 4.0, -WALKING_MPS);
        t + 8.0 + duration + within(rng, (5.0, 20.0))
    };
    let end = duration_s - 30.0;
    let mut t = m.parked_start_s;
    let mut circle_due = m.calibration_circle_dps.is_some();
    if circle_due && t > 0.0 {
        t = circle(&mut push, t, rng);
        circle_due = false;
    }
    let (mut grade, mut bank) = (0.0_f64, 0.0_f64);
    let mut first = true;
    loop {
        let speed = log_within(rng, m.speed_mps);
        // A raised-cosine change of Δv over T peaks at 2Δv/T.
        let accelerate = 2.0 * speed / within(rng, m.accel_mps2);
        let cruise = within(rng, m.cruise_s);
        let brake = if rng.random_bool(m.coast_share.clamp(0.0, 1.0)) {
            2.0 * speed / within(rng, (0.05, 0.2))
        } else {
            2.0 * speed / within(rng, m.accel_mps2)
        };
        let stop = log_within(rng, m.stop_s);
        // Rolling from the first reading: the first acceleration has
        // ended by then.
        let start = if first && t == 0.0 { -accelerate } else { t };
        first = false;
        if start + accelerate + cruise + brake > end {
            break;
        }
        push(Channel::Speed, start, accelerate, speed);
        let (cruise_start, cruise_end) = (start + accelerate, start + accelerate + cruise);
        let mut turn_t = cruise_start + within(rng, (1.0, 8.0));
        let turns = rng.random_range(m.turns_per_leg.0..=m.turns_per_leg.1.max(m.turns_per_leg.0));
        for _ in 0..turns {
            let angle = rad(within(rng, m.turn_deg));
            let peak = rad(within(rng, m.turn_rate_dps)).min(MAX_LATERAL_MPS2 / speed);
            let duration = 2.0 * angle / peak;
            if turn_t + duration > cruise_end {
                break;
            }
            push(Channel::Heading, turn_t, duration, angle * sign(rng));
            turn_t += duration + within(rng, (2.0, 10.0));
        }
        let duration = within(rng, (4.0, 15.0)).min(cruise);
        let target = rad(within(rng, (-m.grade_deg, m.grade_deg)));
        push(Channel::Grade, cruise_start, duration, target - grade);
        grade = target;
        let target = rad(within(rng, (-m.bank_deg, m.bank_deg)));
        push(Channel::Bank, cruise_start + 0.5, duration, target - bank);
        bank = target;
        let mut bump_t = cruise_start + within(rng, m.bump_every_s);
        while bump_t + 1.0 < cruise_end {
            let channel = if rng.random_bool(0.5) {
                Channel::BumpPitch
            } else {
                Channel::BumpRoll
            };
            let size = rad(within(rng, m.bump_deg)) * sign(rng);
            push(channel, bump_t, within(rng, (0.3, 1.0)), size);
            bump_t += within(rng, m.bump_every_s);
        }
        push(Channel::Speed, cruise_end, brake, -speed);
        t = cruise_end + brake + stop;
        if circle_due {
            t = circle(
                &mut push,
                cruise_end + brake + within(rng, (2.0, 10.0)),
                rng,
            );
            circle_due = false;
        }
    }
    pulses.sort_by(|a, b| a.start.total_cmp(&b.start));
    pulses
}

/// The default drive's manoeuvres.
fn plan_gentle(scenario: &VehicleScenario, rng: &mut ChaCha8Rng) -> Vec<Pulse> {
    let mut pulses = Vec::new();
    let mut t = plan_start(&mut pulses, rng);
    let mut push = |channel, start, duration, change| {
        pulses.push(Pulse {
            channel,
            start,
            duration,
            change,
        })
    };
    let (mut grade, mut bank) = (0.0_f64, 0.0_f64);
    let end = scenario.duration_s - 60.0;
    loop {
        let speed = rng.random_range(2.0..6.0);
        let accelerate = rng.random_range(4.0..8.0);
        let cruise = rng.random_range(20.0..90.0);
        let brake = rng.random_range(3.0..6.0);
        if t + accelerate + cruise + brake > end {
            break;
        }
        push(Channel::Speed, t, accelerate, speed);
        let (cruise_start, cruise_end) = (t + accelerate, t + accelerate + cruise);
        // Turns, one after another.
        let mut turn_t = cruise_start + rng.random_range(2.0..10.0);
        for _ in 0..rng.random_range(0..3) {
            let duration = rng.random_range(6.0..15.0);
            if turn_t + duration > cruise_end {
                break;
            }
            let angle =
                rng.random_range(30.0..120.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            push(Channel::Heading, turn_t, duration, rad(angle));
            turn_t += duration + rng.random_range(3.0..20.0);
        }
        // A change of grade and of bank.
        let duration = rng.random_range(8.0_f64..15.0).min(cruise);
        let target = rad(rng.random_range(-5.0..5.0));
        push(Channel::Grade, cruise_start, duration, target - grade);
        grade = target;
        let target = rad(rng.random_range(-2.0..2.0));
        push(Channel::Bank, cruise_start + 1.0, duration, target - bank);
        bank = target;
        // Bumps.
        let mut bump_t = cruise_start + rng.random_range(3.0..15.0);
        while bump_t + 1.0 < cruise_end {
            let channel = if rng.random_bool(0.5) {
                Channel::BumpPitch
            } else {
                Channel::BumpRoll
            };
            let size =
                rad(rng.random_range(0.5..1.5)) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            push(channel, bump_t, rng.random_range(0.4..1.0), size);
            bump_t += rng.random_range(3.0..15.0);
        }
        push(Channel::Speed, cruise_end, brake, -speed);
        t = cruise_end + brake + rng.random_range(10.0..40.0);
    }
    // `state` reads the pulses that have started, in order.
    pulses.sort_by(|a, b| a.start.total_cmp(&b.start));
    pulses
}

fn tones(rng: &mut ChaCha8Rng) -> Vec<Tone> {
    (0..3)
        .map(|_| Tone {
            amplitude: rad(rng.random_range(0.02..0.06)),
            omega: std::f64::consts::TAU * rng.random_range(4.0..12.0),
            phase: rng.random_range(0.0..std::f64::consts::TAU),
        })
        .collect()
}

/// The kinematic state at one instant.
struct State {
    speed: f64,
    speed_rate: f64,
    heading: f64,
    heading_rate: f64,
    grade: f64,
    grade_rate: f64,
    roll: f64,
    roll_rate: f64,
    pitch: f64,
    pitch_rate: f64,
    moving: bool,
}

impl VehicleDrive {
    /// Generates the drive.
    pub fn new(scenario: VehicleScenario) -> Result<VehicleDrive, String> {
        if !(scenario.duration_s >= 300.0
            && scenario.duration_s <= 86_400.0
            && scenario.imu_rate_hz >= 20.0
            && scenario.imu_rate_hz <= 1000.0
            && scenario.mag_rate_hz > 0.0
            && scenario.mag_rate_hz <= scenario.imu_rate_hz
            && scenario.field_ut > 0.0
            && scenario.inclination_deg.abs() < 90.0
            && scenario.start_t.is_finite())
        {
            return Err("duration must be 300 s–24 h, IMU rate 20–1000 Hz, magnetometer rate up to the IMU's, field positive, inclination within ±90°".into());
        }
        if !scenario.imu.is_valid() {
            return Err("the IMU's error levels must be finite and not negative".into());
        }
        if let Some(m) = scenario.magnet
            && !(m.at_s.is_finite()
                && m.at_s >= 0.0
                && m.for_s.is_finite()
                && m.for_s > 0.0
                && m.field_ut.is_finite()
                && m.field_ut >= 0.0)
        {
            return Err(
                "the magnet needs a start ≥ 0 s, a duration > 0 s and a field ≥ 0 µT".into(),
            );
        }
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        let pulses = plan(&scenario, &mut rng);
        let pitch_tones = tones(&mut rng);
        let roll_tones = tones(&mut rng);
        let (inclination, declination) =
            (rad(scenario.inclination_deg), rad(scenario.declination_deg));
        let horizontal = scenario.field_ut * inclination.cos();
        let earth_field_n = V3::new(
            horizontal * declination.cos(),
            horizontal * declination.sin(),
            scenario.field_ut * inclination.sin(),
        );
        let d = normal3(&mut rng, 0.08);
        let o = normal3(&mut rng, 0.04);
        let soft_iron = Matrix3::new(
            1.0 + d.x,
            o.x,
            o.y,
            o.x,
            1.0 + d.y,
            o.z,
            o.y,
            o.z,
            1.0 + d.z,
        );
        let hard_iron_ut = V3::new(
            15.0 * normal(&mut rng),
            15.0 * normal(&mut rng),
            5.0 * normal(&mut rng),
        );
        let (soft_iron, hard_iron_ut) = match &scenario.iron {
            Some(iron) => (
                Matrix3::from_fn(|i, j| iron.soft_iron[i][j]),
                V3::from(iron.hard_iron_ut),
            ),
            None => (soft_iron, hard_iron_ut),
        };
        // Drawn from their own generator: the rest of the drive does not
        // depend on them.
        let (pitch_sway, roll_sway) = match scenario.manoeuvres.and_then(|m| m.sway) {
            Some((amplitude_deg, frequency_hz)) => {
                let mut sway_rng =
                    ChaCha8Rng::seed_from_u64(scenario.seed.wrapping_mul(43).wrapping_add(17));
                let tone = |rng: &mut ChaCha8Rng| Tone {
                    amplitude: rad(amplitude_deg) * rng.random_range(0.5..1.0),
                    omega: std::f64::consts::TAU * frequency_hz * rng.random_range(0.8..1.25),
                    phase: rng.random_range(0.0..std::f64::consts::TAU),
                };
                (vec![tone(&mut sway_rng)], vec![tone(&mut sway_rng)])
            }
            None => (Vec::new(), Vec::new()),
        };
        let imu = scenario.imu;
        let gyro_bias0 = normal3(&mut rng, rad(imu.gyro_bias_dps));
        let gyro_warmup = normal3(&mut rng, rad(0.05));
        let accel_bias = normal3(&mut rng, imu.accel_bias_mps2);
        let drift = BiasDrift::new(scenario.seed, imu.bias_drift_dps_per_min);
        // The power cycles' biases from a stream of their own: a drive
        // without them is the drive it always was.
        let mut cycle_rng =
            ChaCha8Rng::seed_from_u64(scenario.seed.wrapping_mul(47).wrapping_add(23));
        let mut cycle_times = scenario.power_cycles_s.clone();
        cycle_times.sort_by(f64::total_cmp);
        let power_cycles = cycle_times
            .into_iter()
            .map(|at_s| (at_s, normal3(&mut cycle_rng, rad(imu.gyro_bias_dps))))
            .collect();
        let imu_rng = ChaCha8Rng::seed_from_u64(scenario.seed.wrapping_mul(31).wrapping_add(7));
        let mag_rng = ChaCha8Rng::seed_from_u64(scenario.seed.wrapping_mul(37).wrapping_add(11));
        Ok(VehicleDrive {
            scenario,
            pulses,
            pitch_tones,
            roll_tones,
            pitch_sway,
            roll_sway,
            earth_field_n,
            soft_iron,
            hard_iron_ut,
            gyro_bias0,
            gyro_warmup,
            power_cycles,
            gyro_walk: V3::zeros(),
            drift,
            accel_bias,
            vibration: V3::zeros(),
            imu_rng,
            mag_rng,
            sample: 0,
            next_mag: 0,
            queued: None,
            active: Vec::new(),
            next_pulse: 0,
            settled: [0.0; 6],
        })
    }

    /// The scenario.
    pub fn scenario(&self) -> &VehicleScenario {
        &self.scenario
    }

    /// The magnetometer's hard iron, µT (for reports).
    pub fn hard_iron_ut(&self) -> V3 {
        self.hard_iron_ut
    }

    /// The magnetometer's hard and soft iron, as drawn or given.
    pub fn iron(&self) -> Iron {
        Iron {
            hard_iron_ut: self.hard_iron_ut.into(),
            soft_iron: std::array::from_fn(|i| std::array::from_fn(|j| self.soft_iron[(i, j)])),
        }
    }

    /// Moves the pulses that have started by `s` into the active set and
    /// the ones that have ended out of it, into the settled totals. `s`
    /// only grows.
    fn advance_to(&mut self, s: f64) {
        while let Some(p) = self.pulses.get(self.next_pulse)
            && p.start <= s
        {
            self.active.push(self.next_pulse);
            self.next_pulse += 1;
        }
        let (pulses, settled) = (&self.pulses, &mut self.settled);
        self.active.retain(|&i| {
            let p = &pulses[i];
            let ended = s > p.start + p.duration;
            if ended {
                settled[p.channel as usize] += p.integral(p.start + p.duration);
            }
            !ended
        });
    }

    /// The kinematic state at `s`, once [`VehicleDrive::advance_to`] `s`.
    fn state(&self, s: f64) -> State {
        let settled = |c: Channel| self.settled[c as usize];
        let mut speed = settled(Channel::Speed);
        let mut speed_rate = 0.0;
        let mut heading = rad(self.scenario.initial_heading_deg) + settled(Channel::Heading);
        let mut heading_rate = 0.0;
        let (mut grade, mut grade_rate) = (settled(Channel::Grade), 0.0);
        let (mut bank, mut bank_rate) = (settled(Channel::Bank), 0.0);
        let (mut bump_pitch, mut bump_pitch_rate) = (settled(Channel::BumpPitch), 0.0);
        let (mut bump_roll, mut bump_roll_rate) = (settled(Channel::BumpRoll), 0.0);
        let mut active = false;
        for p in self.active.iter().map(|&i| &self.pulses[i]) {
            let value = p.integral(s);
            let rate = p.rate(s);
            let running = s <= p.start + p.duration;
            match p.channel {
                Channel::Speed => {
                    speed += value;
                    speed_rate += rate;
                }
                Channel::Heading => {
                    heading += value;
                    heading_rate += rate;
                    active |= running;
                }
                Channel::Grade => {
                    grade += value;
                    grade_rate += rate;
                }
                Channel::Bank => {
                    bank += value;
                    bank_rate += rate;
                }
                Channel::BumpPitch => {
                    bump_pitch += value;
                    bump_pitch_rate += rate;
                }
                Channel::BumpRoll => {
                    bump_roll += value;
                    bump_roll_rate += rate;
                }
            }
        }
        let speed = speed.max(0.0);
        // Wobble grows with speed: envelope e = min(1, v / v_full).
        let (envelope, envelope_rate) = if speed < FULL_SHAKE_SPEED_MPS {
            (
                speed / FULL_SHAKE_SPEED_MPS,
                speed_rate / FULL_SHAKE_SPEED_MPS,
            )
        } else {
            (1.0, 0.0)
        };
        let wobble = |tones: &[Tone]| -> (f64, f64) {
            tones.iter().fold((0.0, 0.0), |(a, r), tone| {
                let x = tone.omega * s + tone.phase;
                (
                    a + envelope * tone.amplitude * x.sin(),
                    r + envelope_rate * tone.amplitude * x.sin()
                        + envelope * tone.amplitude * tone.omega * x.cos(),
                )
            })
        };
        let (pitch_wobble, pitch_wobble_rate) = wobble(&self.pitch_tones);
        let (roll_wobble, roll_wobble_rate) = wobble(&self.roll_tones);
        // Sway while standing: the wobble's complement, 1 − e.
        let sway = |tones: &[Tone]| -> (f64, f64) {
            tones.iter().fold((0.0, 0.0), |(a, r), tone| {
                let x = tone.omega * s + tone.phase;
                (
                    a + (1.0 - envelope) * tone.amplitude * x.sin(),
                    r - envelope_rate * tone.amplitude * x.sin()
                        + (1.0 - envelope) * tone.amplitude * tone.omega * x.cos(),
                )
            })
        };
        let (pitch_sway, pitch_sway_rate) = sway(&self.pitch_sway);
        let (roll_sway, roll_sway_rate) = sway(&self.roll_sway);
        let (pitch_wobble, pitch_wobble_rate) = (
            pitch_wobble + pitch_sway,
            pitch_wobble_rate + pitch_sway_rate,
        );
        let (roll_wobble, roll_wobble_rate) =
            (roll_wobble + roll_sway, roll_wobble_rate + roll_sway_rate);
        State {
            speed,
            speed_rate,
            heading,
            heading_rate,
            grade,
            grade_rate,
            roll: bank + bump_roll + roll_wobble,
            roll_rate: bank_rate + bump_roll_rate + roll_wobble_rate,
            pitch: grade + bump_pitch + pitch_wobble,
            pitch_rate: grade_rate + bump_pitch_rate + pitch_wobble_rate,
            moving: speed > 0.01 || active,
        }
    }

    /// Gyro bias at `s` seconds (`s` only grows).
    fn gyro_bias(&mut self, s: f64) -> V3 {
        let (turned_on_s, turn_on) = self
            .power_cycles
            .iter()
            .rev()
            .find(|(at_s, _)| *at_s <= s)
            .map_or((0.0, self.gyro_bias0), |&(at_s, bias)| (at_s, bias));
        turn_on
            + self.gyro_warmup * (1.0 - (-(s - turned_on_s) / 400.0).exp())
            + self.gyro_walk
            + self.drift.at(s)
    }

    fn imu_event(&mut self) -> VehicleEvent {
        let dt = 1.0 / self.scenario.imu_rate_hz;
        let s = self.sample as f64 * dt;
        self.sample += 1;
        self.advance_to(s);
        let st = self.state(s);
        let attitude: UnitQuaternion<f64> = attitude_from_euler(st.roll, st.pitch, st.heading);
        // Body rates from Euler rates (Z-Y-X).
        let (sr, cr) = st.roll.sin_cos();
        let (sp, cp) = st.pitch.sin_cos();
        let rate_b = V3::new(
            st.roll_rate - st.heading_rate * sp,
            st.pitch_rate * cr + st.heading_rate * sr * cp,
            -st.pitch_rate * sr + st.heading_rate * cr * cp,
        );
        // Acceleration along the path (heading, grade): a = v̇ t̂ + v dt̂/dt.
        let (sg, cg) = st.grade.sin_cos();
        let (sh, ch) = st.heading.sin_cos();
        let tangent = V3::new(cg * ch, cg * sh, -sg);
        let tangent_rate = V3::new(
            -sg * st.grade_rate * ch - cg * sh * st.heading_rate,
            -sg * st.grade_rate * sh + cg * ch * st.heading_rate,
            -cg * st.grade_rate,
        );
        let accel_n = tangent * st.speed_rate + tangent_rate * st.speed;
        let force_true = attitude.inverse() * (accel_n - V3::new(0.0, 0.0, GRAVITY_MPS2));

        let imu = self.scenario.imu;
        let (idle, rolling) = (imu.idle_vibration_mps2, imu.vibration_mps2);
        let shake = if st.speed < FULL_SHAKE_SPEED_MPS {
            idle + (rolling - idle) * st.speed / FULL_SHAKE_SPEED_MPS
        } else {
            rolling
        } + imu.vibration_growth_per_mps * st.speed;
        let rho = 0.7_f64;
        let innovation = normal3(&mut self.imu_rng, shake * (1.0 - rho * rho).sqrt());
        self.vibration = self.vibration * rho + innovation;
        self.gyro_walk += normal3(&mut self.imu_rng, rad(3e-4) * dt.sqrt());
        let bias = self.gyro_bias(s);
        let gyro = rate_b + bias + normal3(&mut self.imu_rng, rad(imu.gyro_noise_dps));
        let accel = force_true
            + self.accel_bias
            + self.vibration
            + normal3(&mut self.imu_rng, imu.accel_noise_mps2);
        let t = self.scenario.start_t + s;
        VehicleEvent {
            reading: Reading {
                t,
                data: SensorData::Imu {
                    accel_mps2: [accel.x, accel.y, accel.z],
                    gyro_dps: [deg(gyro.x), deg(gyro.y), deg(gyro.z)],
                },
            },
            truth: Some(VehicleTruth {
                t,
                moving: st.moving,
                speed_mps: st.speed,
                pitch_deg: deg(st.pitch),
                roll_deg: deg(st.roll),
                heading_deg: deg(st.heading).rem_euclid(360.0),
                gyro_bias_dps: [deg(bias.x), deg(bias.y), deg(bias.z)],
                magnet_near: self.scenario.magnet.is_some_and(|m| m.is_near(s))
                    || self.scenario.disturbances.iter().any(|d| d.is_on(s)),
            }),
        }
    }

    fn mag_reading(&mut self, s: f64) -> Reading {
        let st = self.state(s);
        let attitude = attitude_from_euler(st.roll, st.pitch, st.heading);
        let body = attitude.inverse() * self.earth_field_n;
        let mut field = self.soft_iron * body + self.hard_iron_ut + normal3(&mut self.mag_rng, 0.3);
        if let Some(m) = self.scenario.magnet
            && m.is_near(s)
        {
            field += V3::from(MAGNET_DIRECTION) * m.field_ut;
        }
        for d in self.scenario.disturbances.iter().filter(|d| d.is_on(s)) {
            field += match d.frame {
                DisturbanceFrame::Body => V3::from(d.field_ut),
                DisturbanceFrame::World => attitude.inverse() * V3::from(d.field_ut),
            };
        }
        Reading {
            t: self.scenario.start_t + s,
            data: SensorData::Magnetometer {
                field_ut: [field.x, field.y, field.z],
            },
        }
    }
}

impl Iterator for VehicleDrive {
    type Item = VehicleEvent;

    fn next(&mut self) -> Option<VehicleEvent> {
        if let Some(reading) = self.queued.take() {
            return Some(VehicleEvent {
                reading,
                truth: None,
            });
        }
        let dt = 1.0 / self.scenario.imu_rate_hz;
        let s = self.sample as f64 * dt;
        if s > self.scenario.duration_s {
            return None;
        }
        let mag_s = self.next_mag as f64 / self.scenario.mag_rate_hz;
        let event = self.imu_event();
        // A magnetometer reading follows the IMU one of its instant (or the
        // first after it, when the rates do not divide): it is taken then.
        if mag_s <= s + 1e-9 {
            self.next_mag += 1;
            self.queued = Some(self.mag_reading(s));
        }
        Some(event)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pulses_integrate_their_rates() {
        for channel in [Channel::Heading, Channel::BumpRoll] {
            let p = Pulse {
                channel,
                start: 3.0,
                duration: 2.0,
                change: 0.7,
            };
            let mut integral = 0.0;
            let step = 1e-4;
            let mut t = 2.0;
            while t < 6.0 {
                integral += p.rate(t + step / 2.0) * step;
                t += step;
                assert!((integral - p.integral(t)).abs() < 1e-6, "{channel:?} {t}");
            }
        }
    }

    #[test]
    fn the_drive_has_stops_turns_and_a_calibration_turn() {
        let drive = VehicleDrive::new(VehicleScenario::default()).unwrap();
        let truths: Vec<VehicleTruth> = drive.filter_map(|e| e.truth).collect();
        assert_eq!(truths.len(), 120_001);
        let moving = truths.iter().filter(|t| t.moving).count() as f64 / truths.len() as f64;
        assert!((0.4..0.9).contains(&moving), "{moving}");
        let stops = truths
            .windows(2)
            .filter(|w| w[0].moving && !w[1].moving)
            .count();
        assert!(stops >= 8, "{stops}");
        assert!(!truths[2000].moving && truths[6000].moving);
        let max_speed = truths.iter().map(|t| t.speed_mps).fold(0.0, f64::max);
        assert!((2.0..6.0).contains(&max_speed));
    }

    #[test]
    fn the_gyros_integrate_to_the_true_attitude() {
        // The readings minus the true bias, integrated, follow the truth
        // to within what the white noise random-walks to.
        let worst = gyro_integration_error(VehicleScenario::default());
        assert!(worst < 0.5, "{worst}");
    }

    #[test]
    fn the_hard_drives_gyros_integrate_to_the_true_attitude() {
        // Tight turns and big bumps, the drifting bias taken out with the
        // truth's, the white noise (0.5 °/s would random-walk to about a
        // degree) left out.
        let scenario = VehicleScenario {
            imu: ImuErrors {
                gyro_noise_dps: 0.0,
                ..ImuErrors::hard()
            },
            ..VehicleScenario::hard()
        };
        let worst = gyro_integration_error(scenario);
        assert!(worst < 0.1, "{worst}");
    }

    /// The largest angle, degrees, between the truth and the gyros minus
    /// the true bias integrated over the first 10 minutes.
    fn gyro_integration_error(scenario: VehicleScenario) -> f64 {
        let dt = 1.0 / scenario.imu_rate_hz;
        let mut drive = VehicleDrive::new(scenario).unwrap();
        let mut attitude: Option<UnitQuaternion<f64>> = None;
        let mut previous: Option<V3> = None;
        let mut worst = 0.0_f64;
        for event in drive.by_ref() {
            let (Some(truth), SensorData::Imu { gyro_dps, .. }) =
                (event.truth, &event.reading.data)
            else {
                continue;
            };
            let rate = (V3::from(*gyro_dps) - V3::from(truth.gyro_bias_dps)).map(rad);
            let q = attitude.get_or_insert_with(|| {
                attitude_from_euler(
                    rad(truth.roll_deg),
                    rad(truth.pitch_deg),
                    rad(truth.heading_deg),
                )
            });
            if let Some(p) = previous {
                *q *= UnitQuaternion::from_scaled_axis((p + rate) * (0.5 * dt));
            }
            previous = Some(rate);
            let truth_q = attitude_from_euler(
                rad(truth.roll_deg),
                rad(truth.pitch_deg),
                rad(truth.heading_deg),
            );
            worst = worst.max(deg(q.angle_to(&truth_q)));
            if truth.t - DEFAULT_START_T > 600.0 {
                break;
            }
        }
        worst
    }

    #[test]
    fn the_hard_drive_accelerates_turns_creeps_and_idles() {
        let scenario = VehicleScenario::hard();
        let dt = 1.0 / scenario.imu_rate_hz;
        let truths: Vec<VehicleTruth> = VehicleDrive::new(scenario)
            .unwrap()
            .filter_map(|e| e.truth)
            .collect();
        let mut max_accel = 0.0_f64;
        let mut max_turn = 0.0_f64;
        for w in truths.windows(2) {
            max_accel = max_accel.max((w[1].speed_mps - w[0].speed_mps).abs() / dt);
            let turn = (w[1].heading_deg - w[0].heading_deg + 180.0).rem_euclid(360.0) - 180.0;
            max_turn = max_turn.max(turn.abs() / dt);
        }
        assert!((2.5..=3.01).contains(&max_accel), "{max_accel}");
        assert!((30.0..=60.5).contains(&max_turn), "{max_turn}");
        // Legs between stops (after the calibration turn): their top speeds.
        let mut legs = Vec::new();
        let mut top = 0.0_f64;
        for t in truths.iter().filter(|t| t.t - DEFAULT_START_T > 140.0) {
            if t.moving {
                top = top.max(t.speed_mps);
            } else if top > 0.0 {
                legs.push(top);
                top = 0.0;
            }
        }
        assert!(legs.len() >= 8, "{legs:?}");
        assert!(legs.iter().any(|&v| v < 1.5), "no creeping leg: {legs:?}");
        assert!(legs.iter().any(|&v| v > 4.0), "{legs:?}");
    }

    #[test]
    fn the_bias_drift_is_piecewise_linear_within_its_rate() {
        let mut drift = BiasDrift::new(5, 0.1);
        let max_slope = rad(0.1) / 60.0;
        let mut previous = drift.at(0.0);
        assert_eq!(previous, V3::zeros());
        let mut slopes = Vec::new();
        for k in 1..=1200 {
            let now = drift.at(f64::from(k));
            let slope = now - previous;
            assert!(slope.amax() <= max_slope * (1.0 + 1e-9), "{k}");
            slopes.push(slope.x);
            previous = now;
        }
        // A new slope every 1–3 minutes, 6 to 20 over 20 minutes; each
        // shows twice in the one-second steps (the step across it blends).
        let changes = slopes
            .windows(2)
            .filter(|w| (w[1] - w[0]).abs() > 1e-12)
            .count();
        assert!((12..=40).contains(&changes), "{changes}");
        // None without a drift rate.
        assert_eq!(BiasDrift::new(5, 0.0).at(500.0), V3::zeros());
    }

    #[test]
    fn a_magnet_adds_its_field_in_the_body_frame_while_near() {
        let magnet = MagnetDisturbance {
            at_s: 300.0,
            for_s: 60.0,
            field_ut: 200.0,
        };
        let plain = VehicleDrive::new(VehicleScenario::default()).unwrap();
        let disturbed = VehicleDrive::new(VehicleScenario {
            magnet: Some(magnet),
            ..VehicleScenario::default()
        })
        .unwrap();
        let (mut near, mut near_truths) = (0, 0);
        for (a, b) in plain.zip(disturbed) {
            let s = a.reading.t - DEFAULT_START_T;
            if let Some(truth) = b.truth {
                assert_eq!(truth.magnet_near, magnet.is_near(s));
                near_truths += usize::from(truth.magnet_near);
            }
            match (&a.reading.data, &b.reading.data) {
                (
                    SensorData::Magnetometer { field_ut: x },
                    SensorData::Magnetometer { field_ut: y },
                ) => {
                    let extra = V3::from(*y) - V3::from(*x);
                    if magnet.is_near(s) {
                        near += 1;
                        let expected = V3::from(MAGNET_DIRECTION) * 200.0;
                        assert!((extra - expected).norm() < 1e-9, "{s}");
                    } else {
                        assert_eq!(extra, V3::zeros(), "{s}");
                    }
                }
                _ => assert_eq!(a.reading, b.reading),
            }
        }
        assert_eq!(near, 601);
        assert_eq!(near_truths, 6001);
        assert!((V3::from(MAGNET_DIRECTION).norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn steel_in_the_tunnel_adds_a_field_fixed_in_the_world() {
        let steel = FieldDisturbance {
            at_s: 200.0,
            for_s: 30.0,
            field_ut: [5.0, -12.0, 8.0],
            frame: DisturbanceFrame::World,
        };
        let plain = VehicleDrive::new(VehicleScenario::default()).unwrap();
        let disturbed = VehicleDrive::new(VehicleScenario {
            disturbances: vec![steel],
            ..VehicleScenario::default()
        })
        .unwrap();
        let mut attitude = UnitQuaternion::identity();
        let mut near = 0;
        for (a, b) in plain.zip(disturbed) {
            let s = a.reading.t - DEFAULT_START_T;
            if let Some(truth) = b.truth {
                assert_eq!(truth.magnet_near, steel.is_on(s));
                attitude = attitude_from_euler(
                    rad(truth.roll_deg),
                    rad(truth.pitch_deg),
                    rad(truth.heading_deg),
                );
            }
            if let (
                SensorData::Magnetometer { field_ut: x },
                SensorData::Magnetometer { field_ut: y },
            ) = (&a.reading.data, &b.reading.data)
            {
                let extra = V3::from(*y) - V3::from(*x);
                // Taken at the IMU reading just before: the world field
                // turned into that reading's body frame.
                let expected = if steel.is_on(s) {
                    near += 1;
                    attitude.inverse() * V3::from(steel.field_ut)
                } else {
                    V3::zeros()
                };
                assert!((extra - expected).norm() < 1e-9, "{s}");
            }
        }
        assert_eq!(near, 301);
    }

    #[test]
    fn a_scenario_without_the_new_fields_reads_as_the_default_drive() {
        let mut value = serde_json::to_value(VehicleScenario::default()).unwrap();
        for key in ["profile", "imu", "magnet"] {
            value.as_object_mut().unwrap().remove(key);
        }
        let scenario: VehicleScenario = serde_json::from_value(value).unwrap();
        assert_eq!(scenario, VehicleScenario::default());
        let hard: VehicleScenario =
            serde_json::from_value(serde_json::to_value(VehicleScenario::hard()).unwrap()).unwrap();
        assert_eq!(hard, VehicleScenario::hard());
    }

    #[test]
    fn a_still_imu_reads_gravity_and_its_bias() {
        let mut drive = VehicleDrive::new(VehicleScenario::default()).unwrap();
        let first = drive.next().unwrap();
        let truth = first.truth.unwrap();
        let SensorData::Imu { accel_mps2, .. } = first.reading.data else {
            panic!("the first reading is the IMU's");
        };
        let norm = V3::from(accel_mps2).norm();
        assert!((norm - GRAVITY_MPS2).abs() < 0.2, "{norm}");
        assert!(!truth.moving && truth.speed_mps == 0.0);
        assert_eq!(
            drive.next().unwrap().reading.sensor().as_str(),
            "magnetometer"
        );
    }
}
