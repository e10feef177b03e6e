//! A simulated pipe-jacking drive with known truth, for `simulate
//! pipe-jacking`, `eval zupt`, the accuracy tests and the benchmarks.
//!
//! Cases:
//! - `trolley`: the paper's experiment (Zhang et al. 2024, Sec. 5): a
//!   trolley pushed along a straight line, 30 s push / 30 s rest, 32 pushes
//!   covering 36.55 m in about 32 min (≈ 4 cm/s while pushed);
//! - `varied`: the same trolley with pushes of 15–45 s and rests of
//!   10–60 s, until the same distance is covered (the paper's Table 3
//!   does not give its durations; these are ours);
//! - `field`: a jacking machine advancing at a steady 2 mm/s for 10–20 min
//!   with its cutter running, then resting 2–6 min for the next pipe, for
//!   two hours (`field_duration_s`).
//!
//! Motion: the machine moves along a straight line at `heading_deg` and
//! `slope_deg`. Each push's speed rises and falls smoothly (sin² ramps);
//! while moving, the trolley's wheels or the machine's cutter shake it:
//! small vertical and sideways oscillations (a few hundredths of m/s²) and
//! attitude wobble (a few hundredths of °/s), proportional to the speed
//! ramp. On the trolley, a third of the pushes cross a 4–10 s stretch where
//! the wheels run quietly (the accelerations drop to a tenth) and a third
//! one where the trolley does not wobble (the angular rates drop to a
//! tenth): each fools the single-signal detectors, which is what the
//! three-condition detector is for. No push has both at once: there no
//! inertial detector could tell motion from rest, the three-condition one
//! included, and the simulation says so rather than pretend. Every
//! quantity is analytic, so the IMU readings are exact derivatives of the
//! true trajectory.
//!
//! Running machinery (`machinery`): a hydraulic power pack, slurry pumps
//! or a motor that keeps running while the machine stands shakes it with a
//! steady vibration: two tones in `band_hz` (20–60 Hz by default) whose
//! accelerations total `amplitude_mg` (2–5 mg, drawn per drive), mostly
//! vertical, with an angular jitter of 0.002–0.01 °/s. `always`: the whole
//! drive (the field case's default); `cycling`: on and off for 1–5 min at a
//! time, independent of the pushes. Like the shaking it is analytic (the
//! readings stay exact derivatives of the truth) and it does not move the
//! machine: the truth's zero velocity is the advance's. Tones above half
//! the IMU rate alias, as they would in an IMU without an anti-alias filter.
//!
//! Sensors (the paper's Table 1 FOG IMU):
//! - IMU at 100 Hz (`imu_rate_hz`): gyro bias 0.5 °/h (1σ per axis) plus a 0.05 °/h/√h
//!   random walk, angle random walk 0.05 °/√h; accelerometer bias 1 mg (1σ
//!   per axis), white noise 50 µg/√Hz; both sense the Earth's rotation
//!   and WGS84 normal gravity at `latitude_deg`;
//! - level at 1 Hz: height to 0.5 mm;
//! - odometer at 1 Hz: distance with a 0.2 % scale error, to 1 mm.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::fusion::angles::{deg, rad};
use crate::fusion::geometry::{V3, attitude_from_euler, earth_rate_n};
use crate::fusion::zupt::strapdown::Site;
use crate::fusion::{Reading, SensorData};

use super::tbm::DEFAULT_START_T;

/// The IMU's usual rate, Hz (the paper's FOG-INS).
pub const IMU_RATE_HZ: f64 = 100.0;
/// Trolley: the paper's distance and push count.
const TROLLEY_DISTANCE_M: f64 = 36.55;
const TROLLEY_PUSHES: usize = 32;

/// Which drive to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Case {
    /// 30 s push / 30 s rest, 36.55 m (the paper's Table 2).
    Trolley,
    /// Pushes of 15–45 s, rests of 10–60 s (the paper's Table 3).
    Varied,
    /// A steady 2 mm/s advance with cutter vibration, rests of 2–6 min.
    Field,
}

impl Case {
    /// When machinery runs unless told: in the field always, on the trolley never.
    pub fn machinery_pattern(self) -> MachineryPattern {
        match self {
            Case::Field => MachineryPattern::Always,
            Case::Trolley | Case::Varied => MachineryPattern::Off,
        }
    }
}

/// When the machinery runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum MachineryPattern {
    /// Never: the machine is silent while it stands.
    Off,
    /// The whole drive, pushes and rests.
    Always,
    /// On and off for 1–5 min at a time, whatever the machine does.
    Cycling,
}

/// Running machinery: see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Machinery {
    pub pattern: MachineryPattern,
    /// Range the drive's total vibration amplitude is drawn from, mg.
    pub amplitude_mg: (f64, f64),
    /// Range the tones' frequencies are drawn from, Hz.
    pub band_hz: (f64, f64),
}

impl Machinery {
    /// A power pack of 2–5 mg at 20–60 Hz running as `pattern` says.
    pub fn power_pack(pattern: MachineryPattern) -> Machinery {
        Machinery {
            pattern,
            amplitude_mg: (2.0, 5.0),
            band_hz: (20.0, 60.0),
        }
    }
}

/// The IMU's error model (1σ per axis where a spread).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorGrade {
    /// Turn-on gyro bias, °/h, and its random walk, °/h/√h.
    pub gyro_bias_deg_per_h: f64,
    pub gyro_bias_rw_deg_per_h_per_sqrt_h: f64,
    /// Angle random walk, °/√h.
    pub gyro_arw_deg_per_sqrt_h: f64,
    /// Turn-on accelerometer bias, mg, and white noise, µg/√Hz.
    pub accel_bias_mg: f64,
    pub accel_vrw_ug_per_sqrt_hz: f64,
}

impl SensorGrade {
    /// The paper's Table 1 FOG IMU (the accelerometer noise is ours).
    pub const PAPER: SensorGrade = SensorGrade {
        gyro_bias_deg_per_h: 0.5,
        gyro_bias_rw_deg_per_h_per_sqrt_h: 0.05,
        gyro_arw_deg_per_sqrt_h: 0.05,
        accel_bias_mg: 1.0,
        accel_vrw_ug_per_sqrt_hz: 50.0,
    };
}

/// What to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipeJackScenario {
    pub case: Case,
    pub seed: u64,
    /// Unix seconds of the first reading.
    pub start_t: f64,
    /// Heading of the drive, clockwise from north.
    pub heading_deg: f64,
    /// Slope of the drive, positive rising.
    pub slope_deg: f64,
    pub latitude_deg: f64,
    /// Push and rest durations, s, drawn uniformly from (min, max); `None`
    /// takes the case's (trolley 30/30, varied 15–45/10–60, field
    /// 600–1200/120–360).
    pub push_s: Option<(f64, f64)>,
    pub rest_s: Option<(f64, f64)>,
    /// IMU rate, Hz; the shaking stays below a quarter of it.
    pub imu_rate_hz: f64,
    /// Length of a field drive, s (the trolley cases end with their distance).
    pub field_duration_s: f64,
    /// What the level reads at the start point, m, and the odometer, m (a
    /// drive continued after a stop starts where the last one ended).
    pub start_height_m: f64,
    pub start_odometer_m: f64,
    /// Running machinery; `None` takes the case's (field: a power pack
    /// running always; trolley and varied: off).
    pub machinery: Option<Machinery>,
}

impl PipeJackScenario {
    /// The machinery that runs in this drive.
    pub fn machinery(&self) -> Machinery {
        self.machinery
            .unwrap_or(Machinery::power_pack(self.case.machinery_pattern()))
    }

    /// Push durations (min, max), s.
    pub fn push_range_s(&self) -> (f64, f64) {
        self.push_s.unwrap_or(match self.case {
            Case::Trolley => (30.0, 30.0),
            Case::Varied => (15.0, 45.0),
            Case::Field => (600.0, 1200.0),
        })
    }

    /// Time between IMU readings, s.
    pub fn imu_period_s(&self) -> f64 {
        1.0 / self.imu_rate_hz
    }

    /// Rest durations (min, max), s.
    pub fn rest_range_s(&self) -> (f64, f64) {
        self.rest_s.unwrap_or(match self.case {
            Case::Trolley => (30.0, 30.0),
            Case::Varied => (10.0, 60.0),
            Case::Field => (120.0, 360.0),
        })
    }
}

impl Default for PipeJackScenario {
    fn default() -> Self {
        PipeJackScenario {
            case: Case::Trolley,
            seed: 1,
            start_t: DEFAULT_START_T,
            heading_deg: 30.0,
            slope_deg: 0.5,
            latitude_deg: 30.0,
            push_s: None,
            rest_s: None,
            imu_rate_hz: IMU_RATE_HZ,
            field_duration_s: 7200.0,
            start_height_m: 12.0,
            start_odometer_m: 0.0,
            machinery: None,
        }
    }
}

/// The true state at one IMU reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PipeJackTruth {
    pub t: f64,
    /// True when the machine is not moving at all.
    pub zv: bool,
    /// North, east, down of the start point.
    pub position_m: [f64; 3],
    pub velocity_mps: [f64; 3],
    /// Distance along the line travelled.
    pub distance_m: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    pub yaw_deg: f64,
}

/// One simulated reading, and the truth if it is an IMU reading.
#[derive(Debug, Clone, PartialEq)]
pub struct PipeJackEvent {
    pub reading: Reading,
    pub truth: Option<PipeJackTruth>,
}

/// A smooth 0 → 1 → 0 window: sin² rise over `rise_s` from `start`, 1,
/// sin² fall over `fall_s` to `end`; value and two time derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Window {
    pub start: f64,
    pub end: f64,
    pub rise_s: f64,
    pub fall_s: f64,
}

impl Window {
    fn at(&self, t: f64) -> [f64; 3] {
        use std::f64::consts::PI;
        if t <= self.start || t >= self.end {
            return [0.0; 3];
        }
        let from_start = t - self.start;
        let to_end = self.end - t;
        if from_start < self.rise_s {
            let k = PI / self.rise_s;
            let x = k * from_start;
            [
                (x / 2.0).sin().powi(2),
                k / 2.0 * x.sin(),
                k * k / 2.0 * x.cos(),
            ]
        } else if to_end < self.fall_s {
            let k = PI / self.fall_s;
            let x = k * to_end;
            [
                (x / 2.0).sin().powi(2),
                -k / 2.0 * x.sin(),
                k * k / 2.0 * x.cos(),
            ]
        } else {
            [1.0, 0.0, 0.0]
        }
    }

    /// ∫ from start to t of the window.
    pub(super) fn integral(&self, t: f64) -> f64 {
        use std::f64::consts::PI;
        let t = t.clamp(self.start, self.end);
        let ramp = |x: f64, len: f64| x / 2.0 - len / (2.0 * PI) * (PI * x / len).sin();
        let from_start = t - self.start;
        let rise = ramp(from_start.min(self.rise_s), self.rise_s);
        let plateau_end = self.end - self.fall_s;
        let plateau = (t.min(plateau_end) - (self.start + self.rise_s)).max(0.0);
        let fall = if t > plateau_end {
            let full = ramp(self.fall_s, self.fall_s);
            full - ramp(self.end - t, self.fall_s)
        } else {
            0.0
        };
        rise + plateau + fall
    }
}

/// Product rule for (value, d1, d2) triples.
fn product(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[0] * b[0],
        a[1] * b[0] + a[0] * b[1],
        a[2] * b[0] + 2.0 * a[1] * b[1] + a[0] * b[2],
    ]
}

/// A sum of sinusoids: value and two derivatives.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Tones(pub Vec<(f64, f64, f64)>);

impl Tones {
    /// `count` tones of `frequency_hz` range and the given amplitude of
    /// their `derivative`-th derivative (0: displacement, 1: rate, 2: acceleration).
    pub(super) fn random(
        rng: &mut ChaCha8Rng,
        count: usize,
        frequency_hz: (f64, f64),
        amplitude: f64,
        derivative: i32,
    ) -> Tones {
        Tones(
            (0..count)
                .map(|_| {
                    let omega =
                        std::f64::consts::TAU * rng.random_range(frequency_hz.0..frequency_hz.1);
                    let share = rng.random_range(0.5..1.0) / (count as f64).sqrt();
                    let phase = rng.random_range(0.0..std::f64::consts::TAU);
                    (amplitude * share / omega.powi(derivative), omega, phase)
                })
                .collect(),
        )
    }

    fn at(&self, t: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        for &(amplitude, omega, phase) in &self.0 {
            let (s, c) = (omega * t + phase).sin_cos();
            out[0] += amplitude * s;
            out[1] += amplitude * omega * c;
            out[2] -= amplitude * omega * omega * s;
        }
        out
    }
}

/// One push: speed window, peak speed, shaking.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Push {
    /// The advance: speed = `speed_mps` × window.
    pub window: Window,
    /// When the machine shakes: the trolley while it rolls; the cutter
    /// from 10 s before the advance until 5 s after it.
    pub shake: Window,
    pub speed_mps: f64,
    /// Distance travelled before this push.
    pub distance_before_m: f64,
    /// Stretches where the accelerations / the wobble drop to a tenth.
    pub quiet_accel: Option<Window>,
    pub quiet_wobble: Option<Window>,
    /// Along-track displacement tones (m) that make the speed fluctuate,
    /// weighted by the square of the speed window so they vanish at rest.
    pub fluctuation: Option<Tones>,
}

impl Push {
    fn distance_m(&self) -> f64 {
        self.speed_mps * self.window.integral(self.window.end)
    }

    /// Envelope of the shaking, with a quiet stretch taken out.
    fn shaking(&self, t: f64, quiet: &Option<Window>) -> [f64; 3] {
        let moving = self.shake.at(t);
        match quiet {
            Some(q) => {
                let [q0, q1, q2] = q.at(t);
                product(moving, [1.0 - 0.9 * q0, -0.9 * q1, -0.9 * q2])
            }
            None => moving,
        }
    }
}

/// The shaking of a moving machine, per unit of envelope.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Shaking {
    pub vertical: Tones,
    pub sideways: Tones,
    pub roll: Tones,
    pub pitch: Tones,
    pub yaw: Tones,
}

impl Shaking {
    /// No shaking at all.
    pub fn none() -> Shaking {
        let none = || Tones(Vec::new());
        Shaking {
            vertical: none(),
            sideways: none(),
            roll: none(),
            pitch: none(),
            yaw: none(),
        }
    }
}

/// A vibration: tones (linear along the NED axes, m/s² amplitudes, and
/// angular on roll, pitch, yaw) and when it runs.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Vibration {
    pub linear: [Tones; 3],
    pub angular: [Tones; 3],
    pub gate: Gate,
}

/// When a vibration runs: inside any of `during` (`None`: always), times
/// inside any of `switching` (`None`: always on).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Gate {
    pub during: Option<Vec<Window>>,
    pub switching: Option<Vec<Window>>,
}

impl Gate {
    /// The envelope at `s`: value and two derivatives.
    fn at(&self, s: f64) -> [f64; 3] {
        let inside = |windows: &Option<Vec<Window>>| match windows {
            None => [1.0, 0.0, 0.0],
            Some(windows) => {
                // Windows are in order and do not overlap.
                let at = windows.partition_point(|w| w.end <= s);
                windows
                    .get(at)
                    .filter(|w| s > w.start)
                    .map_or([0.0; 3], |w| w.at(s))
            }
        };
        let during = inside(&self.during);
        if during == [0.0; 3] {
            return during;
        }
        product(during, inside(&self.switching))
    }
}

impl Vibration {
    fn new(machinery: &Machinery, end_s: f64, rng: &mut ChaCha8Rng) -> Result<Vibration, String> {
        let (lo, hi) = machinery.amplitude_mg;
        let (f_lo, f_hi) = machinery.band_hz;
        if !(lo >= 0.0 && hi >= lo && hi <= 1000.0) {
            return Err("machinery amplitude must be 0 to 1000 mg, min ≤ max".into());
        }
        if !(f_lo >= 0.1 && f_hi >= f_lo && f_hi <= 1000.0) {
            return Err("machinery band must be 0.1 to 1000 Hz, min ≤ max".into());
        }
        let mut draw = |(a, b): (f64, f64)| if b > a { rng.random_range(a..b) } else { a };
        let amplitude = draw((lo, hi)) * 1e-3 * 9.806_65;
        let jitter = rad(draw((0.002, 0.01)));
        let band = (f_lo, f_hi.max(f_lo * 1.000_001));
        // Mostly vertical: the pack sits on the machine's floor.
        let linear = [0.4, 0.5, 1.0].map(|share| Tones::random(rng, 2, band, share * amplitude, 2));
        let angular = [1.0, 0.7, 0.5].map(|share| Tones::random(rng, 2, band, share * jitter, 1));
        let mut on = Vec::new();
        if machinery.pattern == MachineryPattern::Cycling {
            let mut t = rng.random_range(0.0..120.0);
            while t < end_s {
                let length = rng.random_range(60.0..300.0);
                on.push(Window {
                    start: t,
                    end: t + length,
                    rise_s: 2.0,
                    fall_s: 2.0,
                });
                t += length + rng.random_range(60.0..300.0);
            }
        }
        let gate = match machinery.pattern {
            MachineryPattern::Always => Gate {
                during: None,
                switching: None,
            },
            MachineryPattern::Off | MachineryPattern::Cycling => Gate {
                during: Some(on),
                switching: None,
            },
        };
        Ok(Vibration {
            linear,
            angular,
            gate,
        })
    }

    /// Adds the vibration at `s` to the motion.
    fn shake(&self, s: f64, k: &mut Kinematics) {
        let envelope = self.gate.at(s);
        if envelope == [0.0; 3] {
            return;
        }
        for axis in 0..3 {
            let [x, v, a] = product(envelope, self.linear[axis].at(s));
            k.position_m[axis] += x;
            k.velocity_mps[axis] += v;
            k.accel_mps2[axis] += a;
            let [angle, rate, _] = product(envelope, self.angular[axis].at(s));
            k.angles[axis] += angle;
            k.rates[axis] += rate;
        }
    }
}

/// What a drive is made of (the cases' and the envelope's).
pub(super) struct Parts {
    pub scenario: PipeJackScenario,
    pub pushes: Vec<Push>,
    pub shaking: Shaking,
    pub vibrations: Vec<Vibration>,
    /// Length of the drive, s.
    pub end_t: f64,
    pub roll0_rad: f64,
    pub sensors: SensorGrade,
    pub odometer_scale: Option<f64>,
    /// Where the odometer's wheel slips (none in the cases).
    pub odometer_slips: Vec<OdometerSlip>,
    /// Whether a level instrument reads the height (always in the cases).
    pub level: bool,
}

/// A slip of the odometer's wheel: from `at_s` (drive seconds) for
/// `for_s` it counts `excess_m` more than the machine advanced, evenly;
/// the counter keeps the excess after.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometerSlip {
    pub at_s: f64,
    pub for_s: f64,
    pub excess_m: f64,
}

impl OdometerSlip {
    /// What the slip has added to the counter by drive second `s`, m.
    pub fn counted_m(&self, s: f64) -> f64 {
        self.excess_m * ((s - self.at_s) / self.for_s).clamp(0.0, 1.0)
    }
}

/// The drive: schedule, shaking and sensor errors, generated from the seed.
#[derive(Debug, Clone)]
pub struct PipeJackDrive {
    scenario: PipeJackScenario,
    pushes: Vec<Push>,
    shaking: Shaking,
    /// Vibrations that do not move the machine (machinery, rolling).
    vibrations: Vec<Vibration>,
    end_t: f64,
    sensors: SensorGrade,
    /// The odometer's scale error (1.002: reads 0.2 % long); `None`: no odometer.
    odometer_scale: Option<f64>,
    odometer_slips: Vec<OdometerSlip>,
    level: bool,
    site: Site,
    heading_rad: f64,
    slope_rad: f64,
    roll0_rad: f64,
    gyro_bias_rad_per_s: V3,
    accel_bias_mps2: V3,
    imu_rng: ChaCha8Rng,
    aid_rng: ChaCha8Rng,
    /// Next IMU sample index, and next 1 Hz aid second.
    sample: u64,
    next_aid_s: u64,
    /// Push index the clock is in or before.
    push: usize,
    /// Aid readings waiting to be emitted before the next IMU one.
    queued: Vec<Reading>,
}

impl PipeJackDrive {
    /// Generates the drive.
    pub fn new(scenario: PipeJackScenario) -> Result<PipeJackDrive, String> {
        if !(scenario.start_t.is_finite()
            && scenario.heading_deg.is_finite()
            && scenario.slope_deg.abs() <= 30.0
            && scenario.latitude_deg.abs() <= 89.0)
        {
            return Err("slope must be within ±30°, latitude within ±89°".into());
        }
        let (push, rest) = (scenario.push_range_s(), scenario.rest_range_s());
        if !(scenario.imu_rate_hz >= 10.0 && scenario.imu_rate_hz <= 2000.0) {
            return Err("the IMU rate must be 10 to 2000 Hz".into());
        }
        if !(scenario.field_duration_s >= 60.0 && scenario.field_duration_s <= 400.0 * 86_400.0) {
            return Err("a field drive lasts 1 min to 400 days".into());
        }
        if !(push.0 >= 5.0 && push.1 >= push.0 && push.1 <= 7200.0) {
            return Err("pushes must last 5 s to 2 h, min ≤ max".into());
        }
        if !(rest.0 >= 1.0 && rest.1 >= rest.0 && rest.1 <= 7200.0) {
            return Err("rests must last 1 s to 2 h, min ≤ max".into());
        }
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        rng.set_stream(0);
        let pushes = schedule(&scenario, &mut rng);
        let last = pushes.last().map_or(0.0, |p| p.window.end);
        let final_rest_s = if scenario.case == Case::Field {
            180.0
        } else {
            30.0
        };
        // Shaking stays below a quarter of the IMU rate, so it is sampled.
        let top = scenario.imu_rate_hz / 4.0;
        let band = |lo: f64, hi: f64| (lo.min(top * 0.5), hi.min(top));
        let shaking = match scenario.case {
            // Wheels on rails: the trolley at ≈ 4 cm/s.
            Case::Trolley | Case::Varied => Shaking {
                vertical: Tones::random(&mut rng, 3, band(3.0, 15.0), 0.05, 2),
                sideways: Tones::random(&mut rng, 3, band(2.0, 10.0), 0.03, 2),
                roll: Tones::random(&mut rng, 2, band(1.0, 6.0), rad(0.08), 1),
                pitch: Tones::random(&mut rng, 2, band(1.0, 6.0), rad(0.08), 1),
                yaw: Tones::random(&mut rng, 2, band(0.5, 3.0), rad(0.05), 1),
            },
            // A cutter grinding: stronger, faster.
            Case::Field => Shaking {
                vertical: Tones::random(&mut rng, 4, band(8.0, 25.0), 0.15, 2),
                sideways: Tones::random(&mut rng, 4, band(8.0, 25.0), 0.10, 2),
                roll: Tones::random(&mut rng, 3, band(2.0, 12.0), rad(0.1), 1),
                pitch: Tones::random(&mut rng, 3, band(2.0, 12.0), rad(0.06), 1),
                yaw: Tones::random(&mut rng, 3, band(2.0, 12.0), rad(0.06), 1),
            },
        };
        // Its own stream: switching the machinery leaves the rest alike.
        let mut vibration_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        vibration_rng.set_stream(3);
        let vibration = Vibration::new(
            &scenario.machinery(),
            last + final_rest_s,
            &mut vibration_rng,
        )?;
        let roll0_rad = rad(rng.random_range(-1.0..1.0));
        Ok(PipeJackDrive::from_parts(Parts {
            end_t: last + final_rest_s,
            scenario,
            pushes,
            shaking,
            vibrations: vec![vibration],
            roll0_rad,
            sensors: SensorGrade::PAPER,
            odometer_scale: Some(1.002),
            odometer_slips: Vec::new(),
            level: true,
        }))
    }

    /// The drive made of `parts`; the sensors' errors are drawn from the
    /// scenario's seed.
    pub(super) fn from_parts(parts: Parts) -> PipeJackDrive {
        let Parts {
            scenario,
            pushes,
            shaking,
            vibrations,
            end_t,
            roll0_rad,
            sensors,
            odometer_scale,
            odometer_slips,
            level,
        } = parts;
        let mut imu_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        imu_rng.set_stream(1);
        let mut aid_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        aid_rng.set_stream(2);
        let gyro_bias_sigma = rad(sensors.gyro_bias_deg_per_h) / 3600.0;
        let gyro_bias_rad_per_s = V3::from_fn(|_, _| gyro_bias_sigma * normal(&mut imu_rng));
        let accel_bias_mps2 =
            V3::from_fn(|_, _| sensors.accel_bias_mg * 1e-3 * 9.806_65 * normal(&mut imu_rng));
        PipeJackDrive {
            site: Site {
                lat_rad: rad(scenario.latitude_deg),
                height_m: scenario.start_height_m,
            },
            heading_rad: rad(scenario.heading_deg),
            slope_rad: rad(scenario.slope_deg),
            roll0_rad,
            end_t,
            scenario,
            pushes,
            shaking,
            vibrations,
            sensors,
            odometer_scale,
            odometer_slips,
            level,
            gyro_bias_rad_per_s,
            accel_bias_mps2,
            imu_rng,
            aid_rng,
            sample: 0,
            next_aid_s: 0,
            push: 0,
            queued: Vec::new(),
        }
    }

    /// Length of the drive, s.
    pub fn duration_s(&self) -> f64 {
        self.end_t
    }

    /// Distance covered by the whole drive, m.
    pub fn total_distance_m(&self) -> f64 {
        self.pushes
            .last()
            .map_or(0.0, |p| p.distance_before_m + p.distance_m())
    }

    /// The rests (start, end), s from the start, in order.
    pub fn rests_s(&self) -> Vec<(f64, f64)> {
        let mut rests = Vec::new();
        let mut from = 0.0;
        for push in &self.pushes {
            rests.push((from, push.window.start));
            from = push.window.end;
        }
        rests.push((from, self.end_t));
        rests
    }

    /// The scenario.
    pub fn scenario(&self) -> &PipeJackScenario {
        &self.scenario
    }

    /// The true state at `s` seconds from the start: position, velocity,
    /// acceleration (NED), attitude angles and their rates, distance, and
    /// whether the machine stands still.
    fn truth_at(&mut self, s: f64) -> Kinematics {
        let mut k = self.motion_at(s);
        for vibration in &self.vibrations {
            vibration.shake(s, &mut k);
        }
        k
    }

    /// The motion without the machinery's vibration.
    fn motion_at(&mut self, s: f64) -> Kinematics {
        while self.push + 1 < self.pushes.len() && s >= self.pushes[self.push].shake.end {
            self.push += 1;
        }
        let direction = V3::new(
            self.slope_rad.cos() * self.heading_rad.cos(),
            self.slope_rad.cos() * self.heading_rad.sin(),
            -self.slope_rad.sin(),
        );
        let across = V3::new(-self.heading_rad.sin(), self.heading_rad.cos(), 0.0);
        let mut k = Kinematics {
            angles: [self.roll0_rad, self.slope_rad, self.heading_rad],
            ..Kinematics::default()
        };
        let Some(push) = self.pushes.get(self.push) else {
            return k;
        };
        if s < push.shake.start || s >= push.shake.end {
            k.distance_m = push.distance_before_m + push.speed_mps * push.window.integral(s);
            k.position_m = direction * k.distance_m;
            k.still = true;
            return k;
        }
        k.still = s <= push.window.start || s >= push.window.end;
        let ramp = push.window.at(s);
        k.distance_m = push.distance_before_m + push.speed_mps * push.window.integral(s);
        let mut speed = push.speed_mps * ramp[0];
        let mut accel = push.speed_mps * ramp[1];
        if let Some(tones) = &push.fluctuation {
            let [d, v, a] = product(product(ramp, ramp), tones.at(s));
            k.distance_m += d;
            speed += v;
            accel += a;
        }
        let shake_a = push.shaking(s, &push.quiet_accel);
        let shake_g = push.shaking(s, &push.quiet_wobble);
        let vertical = product(shake_a, self.shaking.vertical.at(s));
        let sideways = product(shake_a, self.shaking.sideways.at(s));
        let down = V3::new(0.0, 0.0, 1.0);
        k.position_m = direction * k.distance_m + down * vertical[0] + across * sideways[0];
        k.velocity_mps = direction * speed + down * vertical[1] + across * sideways[1];
        k.accel_mps2 = direction * accel + down * vertical[2] + across * sideways[2];
        for (axis, tones) in [&self.shaking.roll, &self.shaking.pitch, &self.shaking.yaw]
            .into_iter()
            .enumerate()
        {
            let wobble = product(shake_g, tones.at(s));
            k.angles[axis] += wobble[0];
            k.rates[axis] = wobble[1];
        }
        k
    }

    fn imu_event(&mut self) -> PipeJackEvent {
        let s = self.sample as f64 * self.scenario.imu_period_s();
        self.sample += 1;
        let k = self.truth_at(s);
        let [roll, pitch, yaw] = k.angles;
        let [roll_rate, pitch_rate, yaw_rate] = k.rates;
        let attitude = attitude_from_euler(roll, pitch, yaw);
        let (lat, height) = self.site.at(&k.position_m);
        let earth = earth_rate_n(lat);
        let transport = self.site.transport_rate_n(&k.position_m, &k.velocity_mps);
        let gravity = V3::new(
            0.0,
            0.0,
            crate::fusion::geometry::normal_gravity_mps2(lat, height),
        );
        // f = Cᵀ(a + (2ω_ie + ω_en) × v − g).
        let force_n = k.accel_mps2 + (2.0 * earth + transport).cross(&k.velocity_mps) - gravity;
        let force_b = attitude.inverse() * force_n;
        // ω_ib = ω_nb (from the Euler rates) + Cᵀ ω_in.
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let body_rate = V3::new(
            roll_rate - yaw_rate * sp,
            pitch_rate * cr + yaw_rate * cp * sr,
            -pitch_rate * sr + yaw_rate * cp * cr,
        );
        let rate_b = body_rate + attitude.inverse() * (earth + transport);
        // Sensor errors.
        let dt = self.scenario.imu_period_s();
        let grade = self.sensors;
        let bias_rw = rad(grade.gyro_bias_rw_deg_per_h_per_sqrt_h) / 3600.0 / 60.0 * dt.sqrt();
        let rng = &mut self.imu_rng;
        self.gyro_bias_rad_per_s += V3::from_fn(|_, _| bias_rw * normal(rng));
        let arw = rad(grade.gyro_arw_deg_per_sqrt_h) / 60.0 / dt.sqrt();
        let accel_noise = grade.accel_vrw_ug_per_sqrt_hz * 1e-6 * 9.806_65 / dt.sqrt();
        let gyro = rate_b + self.gyro_bias_rad_per_s + V3::from_fn(|_, _| arw * normal(rng));
        let accel = force_b + self.accel_bias_mps2 + V3::from_fn(|_, _| accel_noise * normal(rng));
        let t = self.scenario.start_t + s;
        PipeJackEvent {
            reading: Reading {
                t,
                data: SensorData::Imu {
                    accel_mps2: [accel.x, accel.y, accel.z],
                    gyro_dps: [deg(gyro.x), deg(gyro.y), deg(gyro.z)],
                },
            },
            truth: Some(PipeJackTruth {
                t,
                zv: k.still,
                position_m: [k.position_m.x, k.position_m.y, k.position_m.z],
                velocity_mps: [k.velocity_mps.x, k.velocity_mps.y, k.velocity_mps.z],
                distance_m: k.distance_m,
                pitch_deg: deg(pitch),
                roll_deg: deg(roll),
                yaw_deg: deg(yaw).rem_euclid(360.0),
            }),
        }
    }

    fn aid_readings(&mut self, s: f64) {
        let k = self.truth_at(s);
        let t = self.scenario.start_t + s;
        let height_m =
            self.scenario.start_height_m - k.position_m.z + 0.0005 * normal(&mut self.aid_rng);
        // Drawn whether or not there is an odometer, so that the draws
        // after it do not depend on whether the drive has one.
        let odometer_noise_m = 0.001 * normal(&mut self.aid_rng);
        if let Some(scale) = self.odometer_scale {
            let slipped_m: f64 = self.odometer_slips.iter().map(|x| x.counted_m(s)).sum();
            let distance_m = self.scenario.start_odometer_m
                + k.distance_m * scale
                + slipped_m
                + odometer_noise_m;
            self.queued.push(Reading {
                t,
                data: SensorData::Odometer {
                    distance_m: (distance_m * 1e4).round() / 1e4,
                },
            });
        }
        if self.level {
            self.queued.push(Reading {
                t,
                data: SensorData::Level {
                    height_m: (height_m * 1e4).round() / 1e4,
                },
            });
        }
    }
}

/// The true motion at one instant.
#[derive(Debug, Clone, Copy, Default)]
struct Kinematics {
    position_m: V3,
    velocity_mps: V3,
    accel_mps2: V3,
    /// Roll, pitch, yaw and their rates, rad and rad/s.
    angles: [f64; 3],
    rates: [f64; 3],
    distance_m: f64,
    still: bool,
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// The pushes of a case: when, how fast, and where the ride is quiet.
fn schedule(scenario: &PipeJackScenario, rng: &mut ChaCha8Rng) -> Vec<Push> {
    let case = scenario.case;
    let (push_range, rest_range) = (scenario.push_range_s(), scenario.rest_range_s());
    let draw = |(min, max): (f64, f64), rng: &mut ChaCha8Rng| {
        if max > min {
            rng.random_range(min..max)
        } else {
            min
        }
    };
    let mut pushes = Vec::new();
    let mut t = 30.0; // every drive starts standing still (alignment)
    let mut distance = 0.0;
    let trolley_speed =
        |window: &Window| TROLLEY_DISTANCE_M / TROLLEY_PUSHES as f64 / window.integral(window.end);
    loop {
        let push_s = draw(push_range, rng);
        let rest_s = draw(rest_range, rng);
        let (rise_s, fall_s) = match case {
            Case::Field => (5.0, 5.0),
            _ => (1.0, 1.5),
        };
        let window = Window {
            start: t,
            end: t + push_s,
            rise_s,
            fall_s,
        };
        let speed_mps = match case {
            Case::Field => 0.002,
            Case::Trolley => trolley_speed(&window) * rng.random_range(0.9..1.1),
            Case::Varied => {
                let reference = Window {
                    start: 0.0,
                    end: 30.0,
                    rise_s,
                    fall_s,
                };
                trolley_speed(&reference) * rng.random_range(0.9..1.1)
            }
        };
        let quiet = |rng: &mut ChaCha8Rng| {
            if case == Case::Field {
                return None;
            }
            let length = rng.random_range(4.0..10.0_f64).min(push_s - 4.0);
            if length < 2.0 {
                return None;
            }
            let start = t + rng.random_range(2.0..(push_s - length - 2.0).max(2.001));
            Some(Window {
                start,
                end: start + length,
                rise_s: 0.5,
                fall_s: 0.5,
            })
        };
        // At most one quiet stretch per push: quiet wheels, or no wobble.
        let (quiet_accel, quiet_wobble) = match rng.random_range(0..3) {
            0 => (quiet(rng), None),
            1 => (None, quiet(rng)),
            _ => (None, None),
        };
        let shake = match case {
            Case::Field => Window {
                start: window.start - 10.0,
                end: window.end + 5.0,
                rise_s: 3.0,
                fall_s: 3.0,
            },
            _ => window,
        };
        let push = Push {
            window,
            shake,
            speed_mps,
            distance_before_m: distance,
            quiet_accel,
            quiet_wobble,
            fluctuation: None,
        };
        distance += push.distance_m();
        pushes.push(push);
        t += push_s + rest_s;
        let done = match case {
            Case::Trolley => pushes.len() == TROLLEY_PUSHES,
            Case::Varied => distance >= TROLLEY_DISTANCE_M,
            Case::Field => t >= scenario.field_duration_s,
        };
        if done {
            break;
        }
    }
    pushes
}

impl Iterator for PipeJackDrive {
    type Item = PipeJackEvent;

    fn next(&mut self) -> Option<PipeJackEvent> {
        if let Some(reading) = self.queued.pop() {
            return Some(PipeJackEvent {
                reading,
                truth: None,
            });
        }
        let s = self.sample as f64 * self.scenario.imu_period_s();
        if s > self.end_t {
            return None;
        }
        // Level and odometer once a second, just before the IMU reading of
        // the same instant.
        if self.next_aid_s as f64 <= s + 1e-9 {
            let aid_s = self.next_aid_s as f64;
            self.next_aid_s += 1;
            self.aid_readings(aid_s);
            // Queued in reverse: pop() emits level, then odometer.
            return self.next();
        }
        Some(self.imu_event())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_derivatives_and_integral_are_consistent() {
        let w = Window {
            start: 2.0,
            end: 12.0,
            rise_s: 1.0,
            fall_s: 1.5,
        };
        let h = 1e-5;
        let mut integral = 0.0;
        let mut t = 2.0;
        while t < 12.0 {
            let [v, d1, d2] = w.at(t + 0.0005);
            let numeric_d1 = (w.at(t + 0.0005 + h)[0] - w.at(t + 0.0005 - h)[0]) / (2.0 * h);
            let numeric_d2 = (w.at(t + 0.0005 + h)[1] - w.at(t + 0.0005 - h)[1]) / (2.0 * h);
            assert!((d1 - numeric_d1).abs() < 1e-5, "{t}");
            assert!((d2 - numeric_d2).abs() < 1e-4, "{t}");
            integral += v * 0.001;
            t += 0.001;
        }
        assert!((integral - w.integral(12.0)).abs() < 1e-6);
        assert!((w.integral(12.0) - (10.0 - 0.5 - 0.75)).abs() < 1e-12);
        assert!((w.integral(5.0) - (3.0 - 0.5)).abs() < 1e-12);
    }

    #[test]
    fn the_trolley_matches_the_paper() {
        let drive = PipeJackDrive::new(PipeJackScenario::default()).unwrap();
        assert!((drive.total_distance_m() - 36.55).abs() < 1.0);
        assert!((1900.0..2000.0).contains(&drive.duration_s()));
        assert_eq!(drive.rests_s().len(), 33);
    }

    #[test]
    fn the_truth_integrates_to_itself() {
        // The velocity is the derivative of the position: integrating it
        // over a push lands on the next position.
        let mut drive = PipeJackDrive::new(PipeJackScenario::default()).unwrap();
        let mut position = drive.truth_at(0.0).position_m;
        let mut velocity = drive.truth_at(0.0).velocity_mps;
        let dt = 0.0005;
        let mut s = 0.0;
        while s < 100.0 {
            let next = drive.truth_at(s + dt);
            position += (velocity + next.velocity_mps) * (dt / 2.0);
            velocity = next.velocity_mps;
            s += dt;
        }
        let truth = drive.truth_at(s).position_m;
        assert!(
            (position - truth).norm() < 1e-6,
            "{position:?} vs {truth:?}"
        );
    }

    #[test]
    fn readings_are_time_ordered_and_complete() {
        let drive = PipeJackDrive::new(PipeJackScenario {
            case: Case::Varied,
            ..PipeJackScenario::default()
        })
        .unwrap();
        let duration = drive.duration_s();
        let mut last_t = f64::MIN;
        let (mut imu, mut aids) = (0, 0);
        for event in drive {
            assert!(event.reading.t >= last_t);
            last_t = event.reading.t;
            event.reading.validate().unwrap();
            match event.truth {
                Some(_) => imu += 1,
                None => aids += 1,
            }
        }
        assert_eq!(imu, (duration * IMU_RATE_HZ).floor() as usize + 1);
        assert_eq!(aids, 2 * (duration.floor() as usize + 1));
    }
}
