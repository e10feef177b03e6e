//! TBM drives drawn at random from the whole envelope the `attitude`
//! engine's defaults must hold over (issue 16), for `simulate tbm
//! --envelope`, `eval attitude --envelope` and the accuracy tests.
//!
//! Each seed draws one machine and one drive; nothing drawn is told to the
//! engine. The ranges (every draw independent, "log-uniform" where a range
//! spans a decade or more):
//!
//! | quantity | range |
//! |---|---|
//! | inclinometer period | 0.5–30 s, log-uniform; each reading jittered by ±2 % |
//! | laser period | 30–300 s, log-uniform; time stamps jittered by ±0.5 s |
//! | laser noise (pitch, roll) | 0.002–0.005° |
//! | laser samples lost at random | 0–5 % |
//! | inclinometer noise while excavating | log-uniform, so that standing is within 0.003–0.05° |
//! | standing (ring building) noise | excavating ÷ 2–5 |
//! | coloured share of that noise | none on half the machines, else 30–90 % of the variance, τ 1–10 s |
//! | roll | start −1.5…1.5°; a drift of up to 3 °/h while excavating, reversed at random and kept within ±0–2°; one or two oscillations with periods 15 min–6 h and a total amplitude of 0.3–3°; all together at most 0.5 °/min |
//! | pitch error of the inclinometer | a polynomial, a line with a sinusoidal ripple, or a saturating tanh step of roll; offset −0.3…0.3°; within ±0.4° over the roll the drive can reach |
//! | temperature | mean 10–20 °C, a cycle of 8–20 °C peak to peak over 2–8 h, plus 0–3 °C of heating while excavating; coefficient −0.005…0.005 °/°C |
//! | inclinometer roll offset | −0.15…0.15° |
//! | true pitch | a design grade of −1…1° with vertical curves (grade changes of up to ±0.4° over 2–5 m every 3–8 m of advance), one or two oscillations with periods of 30 min–4 h and a total amplitude of 0.05–0.1°, smooth steering (σ 0.01–0.04°: a 30-minute Ornstein–Uhlenbeck process through a 5-minute lag) and rocking (σ 0.001–0.004°, τ 2 min) while excavating |
//! | laser dropouts | one to three, 10–120 min each (log-uniform), the first 1.5–3 h in, 30–150 min apart |
//! | drive | 12 h: excavation strokes of 40–90 min (one 1.5 m ring) and ring building of 15–45 min |
//!
//! The truth is written here from these definitions alone: nothing in it
//! comes from the engine's equations.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::noise::Ou;
use super::tbm::{DEFAULT_START_T, Dropout, Phase, TbmEvent, TbmTruth};
use crate::fusion::{Reading, SensorData};

const HOURS: f64 = 12.0;
const RING_LENGTH_M: f64 = 1.5;
/// Fastest the roll may move, degrees per hour (0.5 °/min).
const MAX_ROLL_RATE_DPH: f64 = 30.0;

/// One sinusoidal component of a motion, in time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Oscillation {
    pub amplitude_deg: f64,
    pub period_h: f64,
    pub phase_rad: f64,
}

impl Oscillation {
    fn value(&self, hours: f64) -> f64 {
        self.amplitude_deg * (std::f64::consts::TAU * hours / self.period_h + self.phase_rad).sin()
    }

    /// Largest rate of change, degrees per hour.
    fn max_rate_dph(&self) -> f64 {
        std::f64::consts::TAU * self.amplitude_deg / self.period_h
    }
}

/// The shape of the inclinometer's pitch error over roll, degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case")]
pub enum ErrorShape {
    /// Σ c_k β^k, k = 0..3.
    Polynomial { coefficients: [f64; 4] },
    /// offset + slope·β + amplitude·sin(2π β / wavelength + phase).
    Ripple {
        offset_deg: f64,
        slope: f64,
        amplitude_deg: f64,
        wavelength_deg: f64,
        phase_rad: f64,
    },
    /// offset + slope·β + amplitude·tanh((β − centre) / width).
    Saturating {
        offset_deg: f64,
        slope: f64,
        amplitude_deg: f64,
        centre_deg: f64,
        width_deg: f64,
    },
}

impl ErrorShape {
    /// The error at `roll_deg`, degrees.
    pub fn value(&self, roll_deg: f64) -> f64 {
        match *self {
            ErrorShape::Polynomial { coefficients: c } => {
                c[0] + roll_deg * (c[1] + roll_deg * (c[2] + roll_deg * c[3]))
            }
            ErrorShape::Ripple {
                offset_deg,
                slope,
                amplitude_deg,
                wavelength_deg,
                phase_rad,
            } => {
                offset_deg
                    + slope * roll_deg
                    + amplitude_deg
                        * (std::f64::consts::TAU * roll_deg / wavelength_deg + phase_rad).sin()
            }
            ErrorShape::Saturating {
                offset_deg,
                slope,
                amplitude_deg,
                centre_deg,
                width_deg,
            } => {
                offset_deg
                    + slope * roll_deg
                    + amplitude_deg * ((roll_deg - centre_deg) / width_deg).tanh()
            }
        }
    }

    /// The same shape scaled by `gain`, offset included.
    fn scaled(self, gain: f64) -> ErrorShape {
        match self {
            ErrorShape::Polynomial { coefficients: c } => ErrorShape::Polynomial {
                coefficients: [c[0] * gain, c[1] * gain, c[2] * gain, c[3] * gain],
            },
            ErrorShape::Ripple {
                offset_deg,
                slope,
                amplitude_deg,
                wavelength_deg,
                phase_rad,
            } => ErrorShape::Ripple {
                offset_deg: offset_deg * gain,
                slope: slope * gain,
                amplitude_deg: amplitude_deg * gain,
                wavelength_deg,
                phase_rad,
            },
            ErrorShape::Saturating {
                offset_deg,
                slope,
                amplitude_deg,
                centre_deg,
                width_deg,
            } => ErrorShape::Saturating {
                offset_deg: offset_deg * gain,
                slope: slope * gain,
                amplitude_deg: amplitude_deg * gain,
                centre_deg,
                width_deg,
            },
        }
    }
}

/// Everything one seed draws: the machine, its sensors and its drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvelopeDrive {
    pub seed: u64,
    pub start_t: f64,
    pub hours: f64,
    pub incl_period_s: f64,
    pub laser_period_s: f64,
    pub laser_noise_deg: f64,
    pub laser_loss: f64,
    /// Per-reading inclinometer noise (pitch and roll alike), white and
    /// coloured together.
    pub incl_noise_excavating_deg: f64,
    pub incl_noise_standing_deg: f64,
    /// Share of that variance that is coloured (0: white).
    pub coloured_share: f64,
    pub coloured_tau_s: f64,
    pub roll_start_deg: f64,
    pub roll_drift_dph: f64,
    pub roll_drift_limit_deg: f64,
    pub roll_oscillations: Vec<Oscillation>,
    /// Roll the drive can reach (the error is scaled within it).
    pub roll_range_deg: (f64, f64),
    pub error: ErrorShape,
    pub temp_coefficient_deg_per_c: f64,
    pub temp_mean_c: f64,
    pub temp_cycle: Oscillation,
    pub temp_heating_c: f64,
    pub incl_roll_offset_deg: f64,
    pub grade_deg: f64,
    pub pitch_oscillations: Vec<Oscillation>,
    pub steering_sigma_deg: f64,
    pub rocking_sigma_deg: f64,
    pub dropouts: Vec<Dropout>,
}

fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (rng.random_range(lo.ln()..hi.ln())).exp()
}

/// Splits `total` into `n` random positive shares.
fn shares(rng: &mut ChaCha8Rng, n: usize, total: f64) -> Vec<f64> {
    let w: Vec<f64> = (0..n).map(|_| rng.random_range(0.3..1.0)).collect();
    let sum: f64 = w.iter().sum();
    w.iter().map(|x| total * x / sum).collect()
}

impl EnvelopeDrive {
    /// Draws a machine and drive from `seed`.
    pub fn draw(seed: u64) -> EnvelopeDrive {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(10);
        let rng = &mut rng;
        let tau = std::f64::consts::TAU;

        let incl_period_s = log_uniform(rng, 0.5, 30.0);
        let laser_period_s = log_uniform(rng, 30.0, 300.0);
        let laser_noise_deg = rng.random_range(0.002..0.005);
        let laser_loss = rng.random_range(0.0..0.05);
        let factor = rng.random_range(2.0..5.0);
        let incl_noise_excavating_deg = log_uniform(rng, 0.003 * factor, 0.05);
        let incl_noise_standing_deg = incl_noise_excavating_deg / factor;
        let (coloured_share, coloured_tau_s) = if rng.random_bool(0.5) {
            (rng.random_range(0.3..0.9), rng.random_range(1.0..10.0))
        } else {
            (0.0, 1.0)
        };

        // Roll: drift plus oscillations, within the rate limit.
        let roll_start_deg = rng.random_range(-1.5..1.5);
        let roll_drift_dph = rng.random_range(0.0..3.0);
        let roll_drift_limit_deg = rng.random_range(0.0..2.0);
        let n_roll = rng.random_range(1..=2);
        let roll_total = rng.random_range(0.3..3.0);
        let budget_dph = MAX_ROLL_RATE_DPH - roll_drift_dph;
        let mut roll_oscillations: Vec<Oscillation> = shares(rng, n_roll, roll_total)
            .into_iter()
            .map(|amplitude_deg| Oscillation {
                amplitude_deg,
                period_h: log_uniform(rng, 0.25, 6.0),
                phase_rad: rng.random_range(0.0..tau),
            })
            .collect();
        let rate: f64 = roll_oscillations
            .iter()
            .map(Oscillation::max_rate_dph)
            .sum();
        if rate > budget_dph {
            for o in &mut roll_oscillations {
                o.amplitude_deg *= budget_dph / rate;
            }
        }
        let reach: f64 = roll_oscillations
            .iter()
            .map(|o| o.amplitude_deg)
            .sum::<f64>()
            + roll_drift_limit_deg
            + 0.05;
        let roll_range_deg = (roll_start_deg - reach, roll_start_deg + reach);

        // The error shape, then scaled to lie within ±0.4° over that roll.
        let offset = rng.random_range(-0.3..0.3);
        let (lo, hi) = roll_range_deg;
        let mid = 0.5 * (lo + hi);
        let half = 0.5 * (hi - lo);
        let raw = match rng.random_range(0..3) {
            0 => {
                // A cubic in the roll about the middle of the range, expanded.
                let (a1, a2, a3) = (
                    rng.random_range(-1.0..1.0) / half,
                    rng.random_range(-1.0..1.0) / (half * half),
                    rng.random_range(-1.0..1.0) / (half * half * half),
                );
                // p(β) = a1 (β − m) + a2 (β − m)² + a3 (β − m)³
                let m = mid;
                ErrorShape::Polynomial {
                    coefficients: [
                        -a1 * m + a2 * m * m - a3 * m * m * m,
                        a1 - 2.0 * a2 * m + 3.0 * a3 * m * m,
                        a2 - 3.0 * a3 * m,
                        a3,
                    ],
                }
            }
            1 => ErrorShape::Ripple {
                offset_deg: 0.0,
                slope: rng.random_range(-1.0..1.0) / half,
                amplitude_deg: rng.random_range(0.2..1.0),
                wavelength_deg: rng.random_range(1.5..6.0),
                phase_rad: rng.random_range(0.0..tau),
            },
            _ => ErrorShape::Saturating {
                offset_deg: 0.0,
                slope: rng.random_range(-0.5..0.5) / half,
                amplitude_deg: if rng.random_bool(0.5) { 1.0 } else { -1.0 },
                centre_deg: rng.random_range(lo + 0.25 * (hi - lo)..hi - 0.25 * (hi - lo)),
                width_deg: rng.random_range(0.5..3.0),
            },
        };
        // Peak-to-peak of the roll-dependent part over the reachable roll.
        let grid: Vec<f64> = (0..=200)
            .map(|i| raw.value(lo + (hi - lo) * i as f64 / 200.0))
            .collect();
        let (g_lo, g_hi) = grid
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let g_mid = 0.5 * (g_lo + g_hi);
        let target_pp = rng.random_range(0.05..0.5);
        let gain = target_pp / (g_hi - g_lo).max(1e-9);
        let mut error = with_offset(raw.scaled(gain), offset - g_mid * gain);
        let worst = (0..=200)
            .map(|i| error.value(lo + (hi - lo) * i as f64 / 200.0).abs())
            .fold(0.0, f64::max);
        if worst > 0.4 {
            error = error.scaled(0.4 / worst);
        }

        let temp_coefficient_deg_per_c = rng.random_range(-0.005..0.005);
        let temp_mean_c = rng.random_range(10.0..20.0);
        let temp_cycle = Oscillation {
            amplitude_deg: 0.5 * rng.random_range(8.0..20.0),
            period_h: rng.random_range(2.0..8.0),
            phase_rad: rng.random_range(0.0..tau),
        };
        let temp_heating_c = rng.random_range(0.0..3.0);
        let incl_roll_offset_deg = rng.random_range(-0.15..0.15);

        let grade_deg = rng.random_range(-1.0..1.0);
        let n_pitch = rng.random_range(1..=2);
        let pitch_total = rng.random_range(0.05..0.1);
        let pitch_oscillations = shares(rng, n_pitch, pitch_total)
            .into_iter()
            .map(|amplitude_deg| Oscillation {
                amplitude_deg,
                period_h: log_uniform(rng, 0.5, 4.0),
                phase_rad: rng.random_range(0.0..tau),
            })
            .collect();
        let steering_sigma_deg = rng.random_range(0.01..0.04);
        let rocking_sigma_deg = rng.random_range(0.001..0.004);

        let mut dropouts = Vec::new();
        let mut start_h = rng.random_range(1.5..3.0);
        for _ in 0..rng.random_range(1..=3) {
            let minutes = log_uniform(rng, 10.0, 120.0);
            if start_h + minutes / 60.0 > HOURS - 0.5 {
                break;
            }
            dropouts.push(Dropout { start_h, minutes });
            start_h += minutes / 60.0 + rng.random_range(0.5..2.5);
        }

        EnvelopeDrive {
            seed,
            start_t: DEFAULT_START_T,
            hours: HOURS,
            incl_period_s,
            laser_period_s,
            laser_noise_deg,
            laser_loss,
            incl_noise_excavating_deg,
            incl_noise_standing_deg,
            coloured_share,
            coloured_tau_s,
            roll_start_deg,
            roll_drift_dph,
            roll_drift_limit_deg,
            roll_oscillations,
            roll_range_deg,
            error,
            temp_coefficient_deg_per_c,
            temp_mean_c,
            temp_cycle,
            temp_heating_c,
            incl_roll_offset_deg,
            grade_deg,
            pitch_oscillations,
            steering_sigma_deg,
            rocking_sigma_deg,
            dropouts,
        }
    }

    /// The inclinometer's noise-free pitch error (true − inclinometer) at
    /// roll β and temperature T, degrees.
    pub fn incl_pitch_error_deg(&self, roll_deg: f64, temp_c: f64) -> f64 {
        self.error.value(roll_deg) + self.temp_coefficient_deg_per_c * (temp_c - 20.0)
    }

    /// Per-reading inclinometer noise in `phase`, degrees.
    pub fn incl_noise_deg(&self, phase: Phase) -> f64 {
        match phase {
            Phase::Excavating => self.incl_noise_excavating_deg,
            Phase::RingBuilding => self.incl_noise_standing_deg,
        }
    }

    /// True if the laser is out at `t`.
    pub fn in_dropout(&self, t: f64) -> bool {
        self.dropouts.iter().any(|d| {
            let start = self.start_t + d.start_h * 3600.0;
            t >= start && t < start + d.minutes * 60.0
        })
    }

    /// The drive's readings with the truth at each.
    pub fn events(&self) -> EnvelopeEvents {
        EnvelopeEvents::new(self.clone())
    }

    /// True when the drive lies in the "easy" corner: inclinometer
    /// noise ≤ 0.03°, period ≤ 5 s, laser period ≤ 120 s.
    pub fn is_easy(&self) -> bool {
        self.incl_noise_excavating_deg <= 0.03
            && self.incl_period_s <= 5.0
            && self.laser_period_s <= 120.0
    }
}

fn with_offset(shape: ErrorShape, add: f64) -> ErrorShape {
    match shape {
        ErrorShape::Polynomial { mut coefficients } => {
            coefficients[0] += add;
            ErrorShape::Polynomial { coefficients }
        }
        ErrorShape::Ripple {
            offset_deg,
            slope,
            amplitude_deg,
            wavelength_deg,
            phase_rad,
        } => ErrorShape::Ripple {
            offset_deg: offset_deg + add,
            slope,
            amplitude_deg,
            wavelength_deg,
            phase_rad,
        },
        ErrorShape::Saturating {
            offset_deg,
            slope,
            amplitude_deg,
            centre_deg,
            width_deg,
        } => ErrorShape::Saturating {
            offset_deg: offset_deg + add,
            slope,
            amplitude_deg,
            centre_deg,
            width_deg,
        },
    }
}

/// The machine's true motion, advanced in time.
#[derive(Debug, Clone)]
struct Motion {
    rng: ChaCha8Rng,
    t: f64,
    phase: Phase,
    phase_end_t: f64,
    speed_mps: f64,
    chainage_m: f64,
    /// Grade at the start of the current vertical element and its change.
    grade_deg: f64,
    curve: (f64, f64, f64),
    drift_deg: f64,
    drift_sign: f64,
    steering: Ou,
    /// The steering as the shield follows it: a first-order lag.
    steering_lagged_deg: f64,
    rocking: Ou,
    wobble: Ou,
    heat_c: f64,
}

impl Motion {
    fn new(d: &EnvelopeDrive) -> Motion {
        let mut rng = ChaCha8Rng::seed_from_u64(d.seed);
        rng.set_stream(11);
        let phase = if rng.random_bool(0.5) {
            Phase::Excavating
        } else {
            Phase::RingBuilding
        };
        let mut m = Motion {
            t: d.start_t,
            phase,
            phase_end_t: d.start_t,
            speed_mps: 0.0,
            chainage_m: 0.0,
            grade_deg: d.grade_deg,
            curve: (0.0, 0.0, 0.0),
            drift_deg: 0.0,
            drift_sign: if rng.random_bool(0.5) { 1.0 } else { -1.0 },
            steering: Ou {
                x: 0.0,
                tau_s: 1800.0,
            },
            steering_lagged_deg: 0.0,
            rocking: Ou {
                x: 0.0,
                tau_s: 120.0,
            },
            wobble: Ou {
                x: 0.0,
                tau_s: 60.0,
            },
            heat_c: 0.0,
            rng,
        };
        m.next_curve();
        // The first phase lasts a random part of its usual length.
        m.phase = match phase {
            Phase::Excavating => Phase::RingBuilding,
            Phase::RingBuilding => Phase::Excavating,
        };
        m.next_phase();
        m.phase_end_t = d.start_t + (m.phase_end_t - d.start_t) * m.rng.random_range(0.2..1.0);
        m
    }

    /// The next vertical element: (start chainage, length, grade change).
    fn next_curve(&mut self) {
        let (start, length, change) = self.curve;
        self.grade_deg += change;
        let gap = self.rng.random_range(3.0..8.0);
        self.curve = (
            start + length + gap,
            self.rng.random_range(2.0..5.0),
            self.rng.random_range(-0.4..0.4),
        );
    }

    fn next_phase(&mut self) {
        let start = self.phase_end_t;
        match self.phase {
            Phase::RingBuilding => {
                self.phase = Phase::Excavating;
                let minutes: f64 = self.rng.random_range(40.0..90.0);
                self.phase_end_t = start + minutes * 60.0;
                self.speed_mps = RING_LENGTH_M / (minutes * 60.0);
                if self.rng.random_bool(0.3) {
                    self.drift_sign = -self.drift_sign;
                }
            }
            Phase::Excavating => {
                self.phase = Phase::RingBuilding;
                let minutes: f64 = self.rng.random_range(15.0..45.0);
                self.phase_end_t = start + minutes * 60.0;
            }
        }
    }

    fn advance_to(&mut self, t: f64, d: &EnvelopeDrive) {
        while self.t < t {
            let seg_end = t.min(self.phase_end_t);
            let dt = seg_end - self.t;
            if dt > 0.0 {
                self.advance(dt, d);
            }
            self.t = seg_end;
            if seg_end >= self.phase_end_t {
                self.next_phase();
            }
        }
    }

    fn advance(&mut self, dt: f64, d: &EnvelopeDrive) {
        let cutting = self.phase == Phase::Excavating;
        if cutting {
            self.chainage_m += self.speed_mps * dt;
            while self.chainage_m > self.curve.0 + self.curve.1 {
                self.next_curve();
            }
            self.steering.step(dt, d.steering_sigma_deg, &mut self.rng);
            self.steering_lagged_deg +=
                (self.steering.x - self.steering_lagged_deg) * (1.0 - (-dt / 300.0).exp());
            self.rocking.step(dt, d.rocking_sigma_deg, &mut self.rng);
            self.wobble.step(dt, 0.005, &mut self.rng);
            let limit = d.roll_drift_limit_deg;
            if self.drift_deg >= limit {
                self.drift_sign = -1.0;
            } else if self.drift_deg <= -limit {
                self.drift_sign = 1.0;
            }
            self.drift_deg += self.drift_sign * d.roll_drift_dph * dt / 3600.0;
            self.heat_c += (d.temp_heating_c - self.heat_c) * (1.0 - (-dt / 2400.0).exp());
        } else {
            self.rocking
                .step(dt, 0.1 * d.rocking_sigma_deg, &mut self.rng);
            self.wobble.step(dt, 0.0005, &mut self.rng);
            self.heat_c *= (-dt / 3600.0).exp();
        }
    }

    /// The design grade at the current chainage (pitch of the axis).
    fn design_deg(&self) -> f64 {
        let (start, length, change) = self.curve;
        let along = ((self.chainage_m - start) / length).clamp(0.0, 1.0);
        self.grade_deg + change * along
    }

    fn truth(&self, d: &EnvelopeDrive) -> TbmTruth {
        let hours = (self.t - d.start_t) / 3600.0;
        let pitch = self.design_deg()
            + d.pitch_oscillations
                .iter()
                .map(|o| o.value(hours))
                .sum::<f64>()
            + self.steering_lagged_deg
            + self.rocking.x;
        let roll = d.roll_start_deg
            + self.drift_deg
            + d.roll_oscillations
                .iter()
                .map(|o| o.value(hours))
                .sum::<f64>()
            + self.wobble.x;
        let temp_c = d.temp_mean_c + d.temp_cycle.value(hours) + self.heat_c;
        TbmTruth {
            t: self.t,
            pitch_deg: pitch,
            roll_deg: roll,
            yaw_deg: 37.5,
            phase: self.phase,
            temp_c,
            chainage_m: self.chainage_m,
            incl_pitch_error_deg: d.incl_pitch_error_deg(roll, temp_c),
        }
    }
}

/// The readings of an [`EnvelopeDrive`] in time order, each with the truth
/// at its time. Memory stays constant however long the drive.
#[derive(Debug, Clone)]
pub struct EnvelopeEvents {
    drive: EnvelopeDrive,
    motion: Motion,
    incl_rng: ChaCha8Rng,
    laser_rng: ChaCha8Rng,
    coloured: [Ou; 2],
    next_incl: u64,
    next_incl_t: f64,
    next_laser: u64,
    next_laser_t: f64,
    last_incl_t: f64,
}

impl EnvelopeEvents {
    fn new(drive: EnvelopeDrive) -> EnvelopeEvents {
        let mut incl_rng = ChaCha8Rng::seed_from_u64(drive.seed);
        incl_rng.set_stream(12);
        let mut laser_rng = ChaCha8Rng::seed_from_u64(drive.seed);
        laser_rng.set_stream(13);
        let ou = Ou {
            x: 0.0,
            tau_s: drive.coloured_tau_s,
        };
        let mut events = EnvelopeEvents {
            motion: Motion::new(&drive),
            incl_rng,
            laser_rng,
            coloured: [ou, ou],
            next_incl: 0,
            next_incl_t: drive.start_t,
            next_laser: 0,
            next_laser_t: 0.0,
            last_incl_t: drive.start_t,
            drive,
        };
        events.next_laser_t = events.laser_time(0);
        events
    }

    fn laser_time(&mut self, j: u64) -> f64 {
        let jitter: f64 = self.laser_rng.random_range(-0.5..0.5);
        self.drive.start_t + 1.0 + j as f64 * self.drive.laser_period_s + jitter
    }

    fn inclinometer(&mut self, t: f64) -> TbmEvent {
        self.motion.advance_to(t, &self.drive);
        let truth = self.motion.truth(&self.drive);
        let dt = (t - self.last_incl_t).max(1e-3);
        self.last_incl_t = t;
        let d = &self.drive;
        let sigma = d.incl_noise_deg(truth.phase);
        let coloured = sigma * d.coloured_share.sqrt();
        let white = sigma * (1.0 - d.coloured_share).sqrt();
        let mut noise = [0.0; 2];
        for (n, ou) in noise.iter_mut().zip(&mut self.coloured) {
            ou.step(dt, coloured, &mut self.incl_rng);
            let w: f64 = self.incl_rng.sample(StandardNormal);
            *n = ou.x + white * w;
        }
        let reading = Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg: truth.pitch_deg - truth.incl_pitch_error_deg + noise[0],
                roll_deg: truth.roll_deg - d.incl_roll_offset_deg + noise[1],
                temp_c: Some((truth.temp_c * 10.0).round() / 10.0),
            },
        };
        TbmEvent { truth, reading }
    }

    fn laser(&mut self, t: f64) -> TbmEvent {
        self.motion.advance_to(t, &self.drive);
        let truth = self.motion.truth(&self.drive);
        let sigma = self.drive.laser_noise_deg;
        let n: [f64; 3] = [
            self.laser_rng.sample(StandardNormal),
            self.laser_rng.sample(StandardNormal),
            self.laser_rng.sample(StandardNormal),
        ];
        let reading = Reading {
            t,
            data: SensorData::Laser {
                pitch_deg: truth.pitch_deg + sigma * n[0],
                roll_deg: truth.roll_deg + sigma * n[1],
                yaw_deg: Some(truth.yaw_deg + 0.005 * n[2]),
                position: None,
            },
        };
        TbmEvent { truth, reading }
    }
}

impl Iterator for EnvelopeEvents {
    type Item = TbmEvent;

    fn next(&mut self) -> Option<TbmEvent> {
        let end = self.drive.start_t + self.drive.hours * 3600.0;
        loop {
            let incl_t = self.next_incl_t;
            if incl_t >= end && self.next_laser_t >= end {
                return None;
            }
            if self.next_laser_t < incl_t {
                let t = self.next_laser_t;
                self.next_laser += 1;
                self.next_laser_t = self.laser_time(self.next_laser);
                // Drawn whether or not it is delivered: a dropout changes
                // no other draw.
                let event = self.laser(t);
                let lost = self.laser_rng.random_bool(self.drive.laser_loss);
                if lost || self.drive.in_dropout(t) {
                    continue;
                }
                return Some(event);
            }
            self.next_incl += 1;
            let period = self.drive.incl_period_s;
            let jitter: f64 = self.incl_rng.random_range(-0.02..0.02);
            self.next_incl_t = self.drive.start_t + (self.next_incl as f64 + jitter) * period;
            return Some(self.inclinometer(incl_t));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::SensorKind;

    #[test]
    fn draws_stay_inside_the_envelope() {
        for seed in 1..=200 {
            let d = EnvelopeDrive::draw(seed);
            assert!((0.5..=30.0).contains(&d.incl_period_s), "{seed}");
            assert!((30.0..=300.0).contains(&d.laser_period_s), "{seed}");
            assert!((0.002..=0.005).contains(&d.laser_noise_deg));
            assert!((0.0..=0.05).contains(&d.laser_loss));
            let ratio = d.incl_noise_excavating_deg / d.incl_noise_standing_deg;
            assert!((2.0..=5.0).contains(&ratio));
            assert!(d.incl_noise_standing_deg >= 0.003 - 1e-12);
            assert!(d.incl_noise_excavating_deg <= 0.05);
            assert!(d.incl_roll_offset_deg.abs() <= 0.15);
            assert!(d.temp_coefficient_deg_per_c.abs() <= 0.005);
            let rate: f64 = d
                .roll_oscillations
                .iter()
                .map(Oscillation::max_rate_dph)
                .sum::<f64>()
                + d.roll_drift_dph;
            assert!(rate <= MAX_ROLL_RATE_DPH + 1e-9, "{seed}: {rate} °/h");
            let amplitude: f64 = d.roll_oscillations.iter().map(|o| o.amplitude_deg).sum();
            assert!(amplitude <= 3.0 + 1e-9);
            let (lo, hi) = d.roll_range_deg;
            for i in 0..=100 {
                let roll = lo + (hi - lo) * i as f64 / 100.0;
                assert!(d.error.value(roll).abs() <= 0.4 + 1e-9, "{seed}");
            }
            assert!(!d.dropouts.is_empty(), "{seed}");
            for w in d.dropouts.windows(2) {
                assert!(w[1].start_h > w[0].start_h + w[0].minutes / 60.0);
            }
            for x in &d.dropouts {
                assert!((10.0..=120.0).contains(&x.minutes));
                assert!(x.start_h >= 1.5 && x.start_h + x.minutes / 60.0 <= d.hours);
            }
        }
    }

    #[test]
    fn error_shapes_by_hand() {
        let p = ErrorShape::Polynomial {
            coefficients: [0.1, 0.02, -0.01, 0.001],
        };
        // 0.1 + 0.04 − 0.04 + 0.008 at β = 2
        assert!((p.value(2.0) - 0.108).abs() < 1e-15);
        let r = ErrorShape::Ripple {
            offset_deg: -0.2,
            slope: 0.05,
            amplitude_deg: 0.03,
            wavelength_deg: 4.0,
            phase_rad: 0.0,
        };
        // sin(2π·1/4) = 1: −0.2 + 0.05 + 0.03
        assert!((r.value(1.0) + 0.12).abs() < 1e-15);
        let s = ErrorShape::Saturating {
            offset_deg: 0.1,
            slope: 0.0,
            amplitude_deg: 0.2,
            centre_deg: 1.0,
            width_deg: 2.0,
        };
        assert!((s.value(1.0) - 0.1).abs() < 1e-15);
        assert!((s.value(3.0) - (0.1 + 0.2 * 1.0_f64.tanh())).abs() < 1e-15);
    }

    #[test]
    fn readings_carry_the_drawn_errors_and_dropouts() {
        let d = EnvelopeDrive::draw(7);
        let (mut incl, mut laser) = (0u64, 0u64);
        let mut last = f64::NEG_INFINITY;
        let mut roll_rate_max = 0.0_f64;
        let mut previous: Option<TbmTruth> = None;
        for e in d.events() {
            assert!(e.reading.t >= last);
            last = e.reading.t;
            e.reading.validate().unwrap();
            match e.reading.data {
                SensorData::Inclinometer { pitch_deg, .. } => {
                    incl += 1;
                    // Noise is at most a few sigma.
                    let clean = e.truth.pitch_deg - e.truth.incl_pitch_error_deg;
                    assert!((pitch_deg - clean).abs() < 6.0 * d.incl_noise_excavating_deg);
                    if let Some(p) = previous
                        && e.truth.t - p.t > 60.0
                    {
                        let rate = (e.truth.roll_deg - p.roll_deg).abs() / (e.truth.t - p.t);
                        roll_rate_max = roll_rate_max.max(rate * 60.0);
                    }
                    if previous.is_none_or(|p| e.truth.t - p.t > 60.0) {
                        previous = Some(e.truth);
                    }
                }
                SensorData::Laser { .. } => {
                    laser += 1;
                    assert!(!d.in_dropout(e.reading.t));
                }
                _ => unreachable!(),
            }
            assert!(matches!(
                e.reading.sensor(),
                SensorKind::Inclinometer | SensorKind::Laser
            ));
        }
        let expected_incl = d.hours * 3600.0 / d.incl_period_s;
        assert!((incl as f64 - expected_incl).abs() <= 2.0, "{incl}");
        let out_minutes: f64 = d.dropouts.iter().map(|x| x.minutes).sum();
        let expected_laser = (d.hours * 60.0 - out_minutes) * 60.0 / d.laser_period_s;
        assert!(
            laser as f64 > 0.9 * expected_laser && laser as f64 <= expected_laser + 2.0,
            "{laser} vs {expected_laser}"
        );
        // Roll stays under 0.5 °/min (wobble aside) over minute-long steps.
        assert!(roll_rate_max < 0.55, "{roll_rate_max} °/min");
    }

    #[test]
    fn the_same_seed_gives_the_same_drive() {
        let a: Vec<_> = EnvelopeDrive::draw(3).events().take(5000).collect();
        let b: Vec<_> = EnvelopeDrive::draw(3).events().take(5000).collect();
        assert!(a == b);
        let c: Vec<_> = EnvelopeDrive::draw(4).events().take(5000).collect();
        assert!(a != c);
    }
}
