//! Pipe-jacking drives drawn at random from the whole envelope the `zupt`
//! engine's defaults must hold over (issue 33), for `simulate pipe-jacking
//! --envelope`, `eval zupt --envelope` and the accuracy tests.
//!
//! Each seed draws one machine, its sensors and one drive; nothing drawn is
//! told to the engine except what a site would declare (latitude and the
//! surveyed start heading, the latter with an error the evaluation draws).
//! Every draw is independent; "log-uniform" where a range spans a decade
//! or more.
//!
//! | quantity | range |
//! |---|---|
//! | push length | a typical length log-uniform in 5 s – 10 min, each push 0.7–1.3 × it (within 5 s – 10 min) |
//! | rest length | likewise, independently; the first rest 30–120 s |
//! | speed | a typical top speed log-uniform in 1 mm/s – 0.1 m/s, each push 0.8–1.2 × it |
//! | speed profile | sin² ramps of 1–6 s (2–6 s when fluctuating); steady, or (half the drives) fluctuating by 10–30 % through 1–3 tones of 0.1–0.5 Hz |
//! | vibration while pushing | none (a quarter of the drives), else 0.5–50 mg log-uniform, 3–60 Hz, one to four steady tones or broadband (24 tones over a band of 1.5–4 ×), angular jitter on half of them (0.002–0.05 °/s); steady or switching on and off (10–300 s each); rising and falling with the speed |
//! | vibration while standing | drawn the same way, independently; present during rests only |
//! | vibration velocity | every vibration's amplitude capped so that its velocity stays within 5 mm/s (heavy machinery; ISO 10816's upper zones) |
//! | odometer | present on half the drives, scale error 0–8 % either way, 1 mm noise |
//! | odometer slips | on half the drives with an odometer: 1–4 slips of the wheel during pushes, each counting 5–100 mm (log-uniform) too many over 0.2–2 s |
//! | level instrument | on half the drives (a height once a second to 0.5 mm); none on the others |
//! | slope, heading, latitude | −3…3°, 0…360°, −60…60° |
//! | gyro | turn-on bias 0.1–0.5 °/h, bias random walk 0.01–0.05 °/h/√h, ARW 0.01–0.05 °/√h |
//! | accelerometer | turn-on bias 0.2–1 mg, white noise 20–50 µg/√Hz |
//! | drive | 30–60 min of pushes and rests (at least three pushes), ending with a rest of at least 30 s |
//!
//! The sensor grades are within the paper's Table 1 specification (gyro
//! bias stability 0.5 °/h, ARW ≤ 0.05 °/√h, accelerometer bias 1 mg), the
//! grade the engine's defaults declare. Every quantity is analytic (tones
//! and sin² windows), so the IMU readings are exact derivatives of the
//! truth; the truth is written here and in [`super::pipejack`] from these
//! definitions alone, not from the engine's equations. The truth's zero
//! velocity is "not advancing": vibration shakes a standing machine by
//! micrometres to millimetres without moving it.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::pipejack::{
    Case, Gate, OdometerSlip, Parts, PipeJackDrive, PipeJackScenario, Push, SensorGrade, Shaking,
    Tones, Vibration, Window,
};
use super::tbm::DEFAULT_START_T;
use crate::fusion::angles::rad;

const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;
/// Shortest and longest push or rest, s.
const PHASE_RANGE_S: (f64, f64) = (5.0, 600.0);
/// Largest velocity amplitude of a vibration, m/s.
const MAX_VIBRATION_VELOCITY_MPS: f64 = 0.005;
/// The largest odometer scale error drawn (either sign): drawn uniformly
/// within ±this, on the drives that have an odometer.
pub const ODOMETER_SCALE_ERROR_MAX: f64 = 0.08;
/// A slip's excess count, m (log-uniform), and its length, s.
const SLIP_EXCESS_M: (f64, f64) = (0.005, 0.1);
const SLIP_LENGTH_S: (f64, f64) = (0.2, 2.0);

/// What a vibration's spectrum is made of.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Spectrum {
    /// A few steady tones.
    Tones { count: usize },
    /// Many tones spread over the band.
    Broadband,
}

/// One vibration as drawn.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VibrationDraw {
    /// Total acceleration amplitude, mg (after the velocity cap).
    pub amplitude_mg: f64,
    pub band_hz: (f64, f64),
    pub spectrum: Spectrum,
    /// Angular jitter amplitude, °/s (0: none).
    pub jitter_dps: f64,
    /// On and off lengths, s, when it switches; `None`: steady.
    pub switching_s: Option<(f64, f64)>,
}

/// One drive drawn from the envelope; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipeJackEnvelope {
    pub seed: u64,
    /// Unix seconds of the first reading.
    pub start_t: f64,
    pub heading_deg: f64,
    pub slope_deg: f64,
    pub latitude_deg: f64,
    /// Typical push and rest lengths, s.
    pub push_s: f64,
    pub rest_s: f64,
    /// Typical top speed, m/s.
    pub speed_mps: f64,
    /// Ramp length, s, and the speed's fluctuation (share of the speed, 0: steady).
    pub ramp_s: f64,
    pub fluctuation: f64,
    pub push_vibration: Option<VibrationDraw>,
    pub rest_vibration: Option<VibrationDraw>,
    /// The odometer's scale error (0.01: reads 1 % long); `None`: no odometer.
    pub odometer_scale_error: Option<f64>,
    /// Slips of the odometer's wheel (placed on pushes by [`Self::drive`]).
    #[serde(default)]
    pub odometer_slips: usize,
    /// Whether a level instrument reads the height.
    #[serde(default = "level_by_default")]
    pub level: bool,
    pub sensors: SensorGrade,
    /// The drive lasts at least this long, s.
    pub duration_s: f64,
}

/// Drives drawn before the level was drawn had one.
fn level_by_default() -> bool {
    true
}

fn log_uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    (rng.random_range(lo.ln()..hi.ln())).exp()
}

impl VibrationDraw {
    fn draw(rng: &mut ChaCha8Rng) -> Option<VibrationDraw> {
        if rng.random_bool(0.25) {
            return None;
        }
        let amplitude_mg = log_uniform(rng, (0.5, 50.0));
        let spectrum = if rng.random_bool(0.5) {
            Spectrum::Tones {
                count: rng.random_range(1..=4),
            }
        } else {
            Spectrum::Broadband
        };
        let band_hz = match spectrum {
            Spectrum::Tones { .. } => {
                let lo: f64 = rng.random_range(3.0..40.0);
                (lo, (lo * rng.random_range(1.1..2.0)).min(60.0))
            }
            Spectrum::Broadband => {
                let width = rng.random_range(1.5..4.0);
                let lo = rng.random_range(3.0..60.0 / width);
                (lo, lo * width)
            }
        };
        let jitter_dps = if rng.random_bool(0.5) {
            log_uniform(rng, (0.002, 0.05))
        } else {
            0.0
        };
        let switching_s = rng
            .random_bool(0.5)
            .then(|| (rng.random_range(10.0..300.0), rng.random_range(10.0..300.0)));
        // The velocity a tone of amplitude a at f has is a / (2πf): capped.
        let lowest_omega = std::f64::consts::TAU * band_hz.0;
        let cap_mg = MAX_VIBRATION_VELOCITY_MPS * lowest_omega / STANDARD_GRAVITY_MPS2 * 1e3;
        Some(VibrationDraw {
            amplitude_mg: amplitude_mg.min(cap_mg),
            band_hz,
            spectrum,
            jitter_dps,
            switching_s,
        })
    }

    /// The tones of this vibration (linear mostly vertical, as a machine's
    /// floor carries it; angular on roll, pitch, yaw).
    fn vibration(&self, rng: &mut ChaCha8Rng, during: Vec<Window>, end_s: f64) -> Vibration {
        let count = match self.spectrum {
            Spectrum::Tones { count } => count,
            Spectrum::Broadband => 24,
        };
        let amplitude = self.amplitude_mg * 1e-3 * STANDARD_GRAVITY_MPS2;
        let jitter = rad(self.jitter_dps);
        let band = self.band_hz;
        let linear =
            [0.4, 0.5, 1.0].map(|share| Tones::random(rng, count, band, share * amplitude, 2));
        let angular =
            [1.0, 0.7, 0.5].map(|share| Tones::random(rng, count, band, share * jitter, 1));
        let switching = self.switching_s.map(|(on_s, off_s)| {
            let mut windows = Vec::new();
            let mut t = rng.random_range(0.0..off_s);
            while t < end_s {
                windows.push(Window {
                    start: t,
                    end: t + on_s,
                    rise_s: 1.0,
                    fall_s: 1.0,
                });
                t += on_s + off_s;
            }
            windows
        });
        Vibration {
            linear,
            angular,
            gate: Gate {
                during: Some(during),
                switching,
            },
        }
    }
}

impl PipeJackEnvelope {
    /// Draws drive `seed`.
    pub fn draw(seed: u64) -> PipeJackEnvelope {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(10);
        let fluctuation = if rng.random_bool(0.5) {
            rng.random_range(0.1..0.3)
        } else {
            0.0
        };
        let ramp_s = if fluctuation > 0.0 {
            rng.random_range(2.0..6.0)
        } else {
            rng.random_range(1.0..6.0)
        };
        // Issue 58's draws from a stream of their own: the others stay
        // as they were.
        let mut aids = ChaCha8Rng::seed_from_u64(seed);
        aids.set_stream(12);
        let odometer_slips = if aids.random_bool(0.5) {
            aids.random_range(1..=4)
        } else {
            0
        };
        let level = aids.random_bool(0.5);
        PipeJackEnvelope {
            seed,
            start_t: DEFAULT_START_T,
            heading_deg: rng.random_range(0.0..360.0),
            slope_deg: rng.random_range(-3.0..3.0),
            latitude_deg: rng.random_range(-60.0..60.0),
            push_s: log_uniform(&mut rng, PHASE_RANGE_S),
            rest_s: log_uniform(&mut rng, PHASE_RANGE_S),
            speed_mps: log_uniform(&mut rng, (0.001, 0.1)),
            ramp_s,
            fluctuation,
            push_vibration: VibrationDraw::draw(&mut rng),
            rest_vibration: VibrationDraw::draw(&mut rng),
            odometer_scale_error: rng
                .random_bool(0.5)
                .then(|| rng.random_range(-ODOMETER_SCALE_ERROR_MAX..ODOMETER_SCALE_ERROR_MAX)),
            odometer_slips,
            level,
            sensors: SensorGrade {
                gyro_bias_deg_per_h: rng.random_range(0.1..0.5),
                gyro_bias_rw_deg_per_h_per_sqrt_h: rng.random_range(0.01..0.05),
                gyro_arw_deg_per_sqrt_h: rng.random_range(0.01..0.05),
                accel_bias_mg: rng.random_range(0.2..1.0),
                accel_vrw_ug_per_sqrt_hz: rng.random_range(20.0..50.0),
            },
            duration_s: rng.random_range(1800.0..3600.0),
        }
    }

    /// The scenario header the drive runs with (site, heading, seed).
    pub fn scenario(&self) -> PipeJackScenario {
        PipeJackScenario {
            case: Case::Varied,
            seed: self.seed,
            start_t: self.start_t,
            heading_deg: self.heading_deg,
            slope_deg: self.slope_deg,
            latitude_deg: self.latitude_deg,
            push_s: Some(self.phase_range(self.push_s)),
            rest_s: Some(self.phase_range(self.rest_s)),
            ..PipeJackScenario::default()
        }
    }

    fn phase_range(&self, typical_s: f64) -> (f64, f64) {
        let clamp = |x: f64| x.clamp(PHASE_RANGE_S.0, PHASE_RANGE_S.1);
        (clamp(0.7 * typical_s), clamp(1.3 * typical_s))
    }

    /// Whether vibration runs while the machine stands.
    pub fn vibrates_at_rest(&self) -> bool {
        self.rest_vibration.is_some()
    }

    /// The drive.
    pub fn drive(&self) -> PipeJackDrive {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        rng.set_stream(11);
        let scenario = self.scenario();
        let (push_range, rest_range) =
            (self.phase_range(self.push_s), self.phase_range(self.rest_s));
        let draw = |rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)| {
            if hi > lo {
                rng.random_range(lo..hi)
            } else {
                lo
            }
        };
        let mut pushes: Vec<Push> = Vec::new();
        let mut t = rng.random_range(30.0..120.0);
        let mut distance = 0.0;
        let mut rests = Vec::new();
        let mut rest_from = 0.0;
        loop {
            let push_s = draw(&mut rng, push_range);
            let ramp = self.ramp_s.min(push_s / 2.5);
            let window = Window {
                start: t,
                end: t + push_s,
                rise_s: ramp,
                fall_s: ramp,
            };
            let speed_mps = self.speed_mps * rng.random_range(0.8..1.2);
            let fluctuation = (self.fluctuation > 0.0).then(|| {
                let count = rng.random_range(1..=3);
                // Σ Aᵢωᵢ = share × speed: tones of displacement amplitude.
                let tones = Tones::random(&mut rng, count, (0.1, 0.5), 1.0, 1);
                let total: f64 = tones.0.iter().map(|&(a, omega, _)| a * omega).sum();
                let scale = self.fluctuation * speed_mps / total;
                Tones(
                    tones
                        .0
                        .into_iter()
                        .map(|(a, omega, phase)| (a * scale, omega, phase))
                        .collect(),
                )
            });
            let push = Push {
                window,
                shake: window,
                speed_mps,
                distance_before_m: distance,
                quiet_accel: None,
                quiet_wobble: None,
                fluctuation,
            };
            rests.push((rest_from, t));
            distance += speed_mps * window.integral(window.end);
            pushes.push(push);
            let rest_s = draw(&mut rng, rest_range);
            rest_from = t + push_s;
            t = rest_from + rest_s;
            if t >= self.duration_s && pushes.len() >= 3 {
                break;
            }
        }
        let end_t = rest_from + (t - rest_from).max(30.0);
        rests.push((rest_from, end_t));
        let mut vibrations = Vec::new();
        if let Some(v) = &self.push_vibration {
            let during = pushes.iter().map(|p| p.window).collect();
            vibrations.push(v.vibration(&mut rng, during, end_t));
        }
        if let Some(v) = &self.rest_vibration {
            let during = rests
                .iter()
                .filter(|(from, to)| to - from > 2.5)
                .map(|&(from, to)| Window {
                    start: from,
                    end: to,
                    rise_s: 1.0,
                    fall_s: 1.0,
                })
                .collect();
            vibrations.push(v.vibration(&mut rng, during, end_t));
        }
        let odometer_slips = self.slips(&pushes);
        PipeJackDrive::from_parts(Parts {
            scenario,
            pushes,
            shaking: Shaking::none(),
            vibrations,
            end_t,
            roll0_rad: rad(rng.random_range(-1.0..1.0)),
            sensors: self.sensors,
            odometer_scale: self.odometer_scale_error.map(|e| 1.0 + e),
            odometer_slips,
            level: self.level,
        })
    }

    /// The odometer's slips, each in a push drawn at random, within its
    /// steady part; none without an odometer.
    fn slips(&self, pushes: &[Push]) -> Vec<OdometerSlip> {
        if self.odometer_scale_error.is_none() || pushes.is_empty() {
            return Vec::new();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        rng.set_stream(13);
        (0..self.odometer_slips)
            .map(|_| {
                let w = pushes[rng.random_range(0..pushes.len())].window;
                let (from, to) = (w.start + w.rise_s, w.end - w.fall_s);
                let for_s = rng.random_range(SLIP_LENGTH_S.0..SLIP_LENGTH_S.1);
                let at_s = if to - for_s > from {
                    rng.random_range(from..to - for_s)
                } else {
                    from
                };
                OdometerSlip {
                    at_s,
                    for_s,
                    excess_m: log_uniform(&mut rng, SLIP_EXCESS_M),
                }
            })
            .collect()
    }

    /// The drive's categories (issue 58): its odometer, slips and level.
    pub fn categories(&self) -> DriveCategories {
        DriveCategories {
            odometer: match self.odometer_scale_error {
                None => OdometerCategory::None,
                Some(e) if e.abs() < 0.04 => OdometerCategory::Within4Pct,
                Some(_) => OdometerCategory::Beyond4Pct,
            },
            slips: self.odometer_scale_error.is_some() && self.odometer_slips > 0,
            level: self.level,
        }
    }
}

/// How a drive's odometer reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OdometerCategory {
    None,
    /// Its scale error is under 4 %.
    Within4Pct,
    /// 4–8 %.
    Beyond4Pct,
}

/// The categories a drive falls in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DriveCategories {
    pub odometer: OdometerCategory,
    /// An odometer that slips.
    pub slips: bool,
    pub level: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_span_the_envelope_and_drives_are_consistent() {
        let draws: Vec<PipeJackEnvelope> = (1..=200).map(PipeJackEnvelope::draw).collect();
        let share = |f: &dyn Fn(&PipeJackEnvelope) -> bool| {
            draws.iter().filter(|d| f(d)).count() as f64 / draws.len() as f64
        };
        assert!((0.35..0.65).contains(&share(&|d| d.odometer_scale_error.is_some())));
        assert!((0.35..0.65).contains(&share(&|d| d.level)));
        assert!(share(&|d| d.odometer_scale_error.is_some_and(|e| e.abs() > 0.05)) > 0.1);
        assert!(share(&|d| d.categories().slips) > 0.15);
        assert!((0.6..0.9).contains(&share(&|d| d.rest_vibration.is_some())));
        assert!(share(&|d| d.speed_mps < 0.005) > 0.15);
        assert!(share(&|d| d.speed_mps > 0.03) > 0.15);
        assert!(share(&|d| d.push_s < 20.0) > 0.1 && share(&|d| d.push_s > 200.0) > 0.1);
        for d in &draws {
            for v in [d.push_vibration, d.rest_vibration].into_iter().flatten() {
                let velocity = v.amplitude_mg * 1e-3 * STANDARD_GRAVITY_MPS2
                    / (std::f64::consts::TAU * v.band_hz.0);
                assert!(velocity <= MAX_VIBRATION_VELOCITY_MPS * 1.000_001, "{v:?}");
                assert!(v.band_hz.0 >= 3.0 && v.band_hz.1 <= 60.0 + 1e-9, "{v:?}");
            }
        }
        // The same seed, the same drive.
        assert_eq!(PipeJackEnvelope::draw(7), PipeJackEnvelope::draw(7));
    }

    #[test]
    fn a_drive_starts_and_ends_standing_and_moves_only_forward() {
        for seed in 1..=6 {
            let envelope = PipeJackEnvelope::draw(seed);
            let drive = envelope.drive();
            let duration = drive.duration_s();
            assert!(duration >= envelope.duration_s, "{seed}");
            let mut last_distance = f64::MIN;
            let mut first = None;
            let mut last = None;
            for event in drive {
                if let Some(truth) = event.truth {
                    // Fluctuations never run the machine backwards.
                    assert!(truth.distance_m >= last_distance - 1e-9, "{seed}");
                    last_distance = truth.distance_m;
                    first.get_or_insert(truth.zv);
                    last = Some(truth.zv);
                }
                if event.reading.sensor() == crate::fusion::SensorKind::Odometer {
                    assert!(envelope.odometer_scale_error.is_some(), "{seed}");
                }
            }
            assert_eq!((first, last), (Some(true), Some(true)), "{seed}");
        }
    }
}
