//! Vehicle drives drawn at random from the whole envelope the `fuzzy`
//! engine's defaults must hold over (issue 34), for `simulate vehicle
//! --envelope`, `eval fuzzy --envelope` and the accuracy tests.
//!
//! Each seed draws one vehicle, its sensors, its site and one drive;
//! nothing drawn is told to the engine except what an installer would set
//! (the site's declination and inclination, and the window at half a
//! second of readings). Every draw is independent; "log-uniform" where a
//! range spans a decade or more.
//!
//! | quantity | range |
//! |---|---|
//! | drive | 10–25 min |
//! | IMU and magnetometer rates | 50, 100 or 200 Hz; 5, 10 or 25 Hz (at most the IMU's) |
//! | start | parked 5–60 s, or (one drive in four) rolling from the first reading: never still at the start |
//! | calibration circle | on half the drives: 370° at walking pace, 5–30 °/s, after the parked start (or after the first leg); none on the others |
//! | legs | top speed log-uniform between a slowest of 0.3–1 m/s and a fastest of 1.5–12 m/s (walking pace to fast driving); peak acceleration and braking within 0.3–3 m/s²; a share 0–50 % of the stops reached by coasting (0.05–0.2 m/s²); 5–120 s between acceleration and braking |
//! | turns | 0–4 per leg, 15–180°, peak rate up to 5–60 °/s (capped at 4 m/s² sideways) |
//! | grade, bank, bumps | within ±0–10° and ±0–4°; bumps of 0.2–3° every 2–15 s |
//! | stops | log-uniform in 2 s – 10 min, around a typical length drawn log-uniform in that range (each 0.5–2 × it) |
//! | sway while standing | on half the drives, slow: an amplitude of 0.05–0.5° at 0.1–1 Hz, in pitch and in roll each 0.5–1 × that amplitude and 0.8–1.25 × that frequency (an idling chassis, a person standing: the truth, not motion) |
//! | gyro | turn-on bias 0–0.6 °/s (1σ per axis: biases up to about 1 °/s), warm-up drift 0.05 °/s, a drifting bias on two drives in three (new slope every 1–3 min, up to 0–0.1 °/s per minute), white noise 0.01–0.5 °/s log-uniform |
//! | accelerometer | bias 0.005–0.08 m/s² (1σ per axis), white noise 0.005–0.1 m/s² log-uniform |
//! | vibration | rolling 0.05–0.8 m/s² log-uniform plus 0–0.1 m/s² per m/s; idling 0.003–0.3 m/s² log-uniform |
//! | site | field 25–65 µT, inclination 0–75° (south of the magnetic equator on one drive in four), declination −20…20°, start heading 0…360° |
//! | hard iron | up to 2 × the horizontal field, any direction |
//! | soft iron | symmetric, diagonal 1 ± 0–15 %, off-diagonal ± 0–8 % |
//! | disturbances | 0–4 per drive, each 2–200 µT log-uniform for 1 s – 3 min log-uniform, any direction, fixed on the vehicle (a tool, a magnet) or in the tunnel (steel passed by) |
//!
//! The motion truth is the simulator's: rolling or turning is moving;
//! swaying while standing is not.
//!
//! **Categories** (issue 55; [`VehicleCategory`]): a drive of a category
//! is the ordinary draw of its seed with a few quantities drawn again, from
//! a stream of their own, within the category's ranges:
//!
//! | category | redrawn |
//! |---|---|
//! | `ordinary` | nothing |
//! | `site` | a slow site vehicle: top speeds 1–6 m/s (slowest 1 m/s), no calibration circle, 2–4 pieces of steel fixed in the world (10–80 µT, 10–120 s) |
//! | `cruising` | smooth cruising: top speeds 6–14 m/s, cruises of 30–120 s, rolling vibration 0.05–0.15 m/s² (growth ≤ 0.01 per m/s), bumps 0.2–0.5° |
//! | `never-still` | rolling from the first reading, stops of 0.05–0.3 s reached by braking (none by coasting), no calibration circle: the truth stands at most about 2 s at a time (the ends of the raised-cosine speed changes under 1 cm/s) until its last leg |

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::tbm::DEFAULT_START_T;
use super::vehicle::{
    DisturbanceFrame, DriveProfile, FieldDisturbance, ImuErrors, Iron, Manoeuvres, VehicleScenario,
};

/// Uniform in [lo, hi).
fn uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    rng.random_range(lo..hi)
}

/// Log-uniform in [lo, hi).
fn log_uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    rng.random_range(lo.ln()..hi.ln()).exp()
}

/// A direction drawn uniformly on the sphere.
fn direction(rng: &mut ChaCha8Rng) -> [f64; 3] {
    let z: f64 = rng.random_range(-1.0..1.0);
    let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let r = (1.0 - z * z).sqrt();
    [r * phi.cos(), r * phi.sin(), z]
}

/// A category of drives (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum VehicleCategory {
    #[default]
    Ordinary,
    /// A slow site vehicle without a calibration circle, steel nearby.
    Site,
    /// Smooth cruising at 6–14 m/s.
    Cruising,
    /// Rolling from the first reading, standing at most about 2 s at a
    /// time.
    NeverStill,
}

impl VehicleCategory {
    /// The command-line name.
    pub fn as_str(self) -> &'static str {
        match self {
            VehicleCategory::Ordinary => "ordinary",
            VehicleCategory::Site => "site",
            VehicleCategory::Cruising => "cruising",
            VehicleCategory::NeverStill => "never-still",
        }
    }
}

/// One drive drawn from the envelope (module documentation): the scenario
/// the simulator runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VehicleEnvelope {
    pub seed: u64,
    pub scenario: VehicleScenario,
}

impl VehicleEnvelope {
    /// The drive of `seed` in `category`: the ordinary draw with the
    /// category's quantities drawn again from their own stream.
    pub fn draw_in(seed: u64, category: VehicleCategory) -> VehicleEnvelope {
        let mut drive = VehicleEnvelope::draw(seed);
        let mut rng = ChaCha8Rng::seed_from_u64(
            seed.wrapping_mul(0x9e37_79b9)
                .wrapping_add(55 + category as u64),
        );
        let scenario = &mut drive.scenario;
        let Some(m) = scenario.manoeuvres.as_mut() else {
            return drive;
        };
        match category {
            VehicleCategory::Ordinary => {}
            VehicleCategory::Site => {
                m.speed_mps = (1.0, uniform(&mut rng, (1.5, 6.0)));
                m.calibration_circle_dps = None;
                let duration_s = scenario.duration_s;
                for _ in 0..rng.random_range(2..=4) {
                    let size = uniform(&mut rng, (10.0, 80.0));
                    scenario.disturbances.push(FieldDisturbance {
                        at_s: uniform(&mut rng, (0.0, duration_s)),
                        for_s: uniform(&mut rng, (10.0, 120.0)),
                        field_ut: direction(&mut rng).map(|x| x * size),
                        frame: DisturbanceFrame::World,
                    });
                }
            }
            VehicleCategory::Cruising => {
                m.speed_mps = (6.0, uniform(&mut rng, (8.0, 14.0)));
                m.cruise_s = (30.0, 120.0);
                m.bump_deg = (0.2, uniform(&mut rng, (0.2, 0.5)));
                scenario.imu.vibration_mps2 = uniform(&mut rng, (0.05, 0.15));
                scenario.imu.vibration_growth_per_mps = uniform(&mut rng, (0.0, 0.01));
            }
            VehicleCategory::NeverStill => {
                m.parked_start_s = 0.0;
                m.stop_s = (0.05, 0.3);
                m.coast_share = 0.0;
                m.calibration_circle_dps = None;
            }
        }
        drive
    }

    /// The drive of `seed`.
    pub fn draw(seed: u64) -> VehicleEnvelope {
        // Its own stream: the simulator seeds its noise from `seed` too.
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9e37_79b9).wrapping_add(34));
        let duration_s = uniform(&mut rng, (600.0, 1500.0)).round();
        let imu_rate_hz: f64 = [50.0, 100.0, 200.0][rng.random_range(0..3)];
        let mag_rate_hz: f64 = [5.0, 10.0, 25.0][rng.random_range(0..3)];

        let parked_start_s = if rng.random_bool(0.25) {
            0.0
        } else {
            uniform(&mut rng, (5.0, 60.0)).round()
        };
        let calibration_circle_dps = rng.random_bool(0.5).then(|| uniform(&mut rng, (5.0, 30.0)));
        let slowest = uniform(&mut rng, (0.3, 1.0));
        let fastest = log_uniform(&mut rng, (1.5, 12.0));
        let accel_high = uniform(&mut rng, (0.5, 3.0));
        let accel_low = uniform(&mut rng, (0.3, accel_high));
        let typical_stop = log_uniform(&mut rng, (2.0, 600.0));
        let stop_s = (
            (0.5 * typical_stop).max(2.0),
            (2.0 * typical_stop).min(600.0),
        );
        let sway = rng.random_bool(0.5).then(|| {
            (
                uniform(&mut rng, (0.05, 0.5)),
                uniform(&mut rng, (0.1, 1.0)),
            )
        });
        let bump_low = uniform(&mut rng, (0.2, 1.5));
        let manoeuvres = Manoeuvres {
            parked_start_s,
            calibration_circle_dps,
            speed_mps: (slowest, fastest),
            accel_mps2: (accel_low, accel_high),
            coast_share: uniform(&mut rng, (0.0, 0.5)),
            cruise_s: (5.0, 120.0),
            turns_per_leg: (0, 4),
            turn_deg: (15.0, 180.0),
            turn_rate_dps: (5.0, uniform(&mut rng, (5.0, 60.0))),
            grade_deg: uniform(&mut rng, (0.0, 10.0)),
            bank_deg: uniform(&mut rng, (0.0, 4.0)),
            bump_deg: (bump_low, uniform(&mut rng, (bump_low, 3.0))),
            bump_every_s: (2.0, uniform(&mut rng, (4.0, 15.0))),
            stop_s,
            sway,
        };

        let imu = ImuErrors {
            gyro_bias_dps: uniform(&mut rng, (0.0, 0.6)),
            bias_drift_dps_per_min: if rng.random_bool(2.0 / 3.0) {
                uniform(&mut rng, (0.0, 0.1))
            } else {
                0.0
            },
            gyro_noise_dps: log_uniform(&mut rng, (0.01, 0.5)),
            accel_bias_mps2: uniform(&mut rng, (0.005, 0.08)),
            accel_noise_mps2: log_uniform(&mut rng, (0.005, 0.1)),
            vibration_mps2: log_uniform(&mut rng, (0.05, 0.8)),
            vibration_growth_per_mps: uniform(&mut rng, (0.0, 0.1)),
            idle_vibration_mps2: log_uniform(&mut rng, (0.003, 0.3)),
        };

        let field_ut = uniform(&mut rng, (25.0, 65.0));
        let inclination_deg =
            uniform(&mut rng, (0.0, 75.0)) * if rng.random_bool(0.25) { -1.0 } else { 1.0 };
        let declination_deg = uniform(&mut rng, (-20.0, 20.0));
        let initial_heading_deg = uniform(&mut rng, (0.0, 360.0));
        let horizontal_ut = field_ut * inclination_deg.to_radians().cos();
        let hard = uniform(&mut rng, (0.0, 2.0)) * horizontal_ut;
        let hard_direction = direction(&mut rng);
        let (diagonal, off) = (
            uniform(&mut rng, (0.0, 0.15)),
            uniform(&mut rng, (0.0, 0.08)),
        );
        let d: [f64; 3] = std::array::from_fn(|_| 1.0 + uniform(&mut rng, (-diagonal, diagonal)));
        let o: [f64; 3] = std::array::from_fn(|_| uniform(&mut rng, (-off, off)));
        let iron = Iron {
            hard_iron_ut: hard_direction.map(|x| x * hard),
            soft_iron: [[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]],
        };
        let disturbances = (0..rng.random_range(0..=4))
            .map(|_| {
                let size = log_uniform(&mut rng, (2.0, 200.0));
                FieldDisturbance {
                    at_s: uniform(&mut rng, (0.0, duration_s)),
                    for_s: log_uniform(&mut rng, (1.0, 180.0)),
                    field_ut: direction(&mut rng).map(|x| x * size),
                    frame: if rng.random_bool(0.5) {
                        DisturbanceFrame::Body
                    } else {
                        DisturbanceFrame::World
                    },
                }
            })
            .collect();

        VehicleEnvelope {
            seed,
            scenario: VehicleScenario {
                seed,
                start_t: DEFAULT_START_T,
                duration_s,
                imu_rate_hz,
                mag_rate_hz: mag_rate_hz.min(imu_rate_hz),
                initial_heading_deg,
                field_ut,
                inclination_deg,
                declination_deg,
                profile: DriveProfile::Gentle,
                imu,
                magnet: None,
                manoeuvres: Some(manoeuvres),
                iron: Some(iron),
                disturbances,
                power_cycles_s: Vec::new(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::SensorData;
    use crate::fusion::angles::{deg, rad};
    use crate::fusion::geometry::{V3, attitude_from_euler};
    use crate::sim::vehicle::{VehicleDrive, VehicleTruth};
    use nalgebra::UnitQuaternion;

    fn truths(seed: u64) -> (VehicleScenario, Vec<VehicleTruth>) {
        truths_in(seed, VehicleCategory::Ordinary)
    }

    fn truths_in(seed: u64, category: VehicleCategory) -> (VehicleScenario, Vec<VehicleTruth>) {
        let scenario = VehicleEnvelope::draw_in(seed, category).scenario;
        let truths = VehicleDrive::new(scenario.clone())
            .unwrap()
            .filter_map(|e| e.truth)
            .collect();
        (scenario, truths)
    }

    #[test]
    fn the_same_seed_draws_the_same_drive_and_others_differ() {
        assert_eq!(VehicleEnvelope::draw(7), VehicleEnvelope::draw(7));
        assert_ne!(VehicleEnvelope::draw(7), VehicleEnvelope::draw(8));
    }

    #[test]
    fn the_draws_stay_within_the_documented_ranges() {
        let (mut rolling, mut circles, mut swaying) = (0, 0, 0);
        for seed in 1..=200 {
            let s = VehicleEnvelope::draw(seed).scenario;
            let m = s.manoeuvres.unwrap();
            assert!((600.0..=1500.0).contains(&s.duration_s));
            assert!(s.mag_rate_hz <= s.imu_rate_hz);
            assert!(s.inclination_deg.abs() <= 75.0);
            assert!(s.imu.gyro_bias_dps <= 0.6 && s.imu.bias_drift_dps_per_min <= 0.1);
            assert!((0.01..=0.5).contains(&s.imu.gyro_noise_dps));
            let iron = s.iron.unwrap();
            let horizontal = s.field_ut * rad(s.inclination_deg).cos();
            assert!(V3::from(iron.hard_iron_ut).norm() <= 2.0 * horizontal + 1e-9);
            for i in 0..3 {
                assert!((iron.soft_iron[i][i] - 1.0).abs() <= 0.15);
                for j in 0..3 {
                    assert_eq!(iron.soft_iron[i][j], iron.soft_iron[j][i]);
                }
            }
            assert!(s.disturbances.len() <= 4);
            for d in &s.disturbances {
                let size = V3::from(d.field_ut).norm();
                assert!((2.0..=200.0).contains(&size) && (1.0..=180.0).contains(&d.for_s));
            }
            assert!(m.stop_s.0 >= 2.0 && m.stop_s.1 <= 600.0 && m.stop_s.0 <= m.stop_s.1);
            rolling += usize::from(m.parked_start_s == 0.0);
            circles += usize::from(m.calibration_circle_dps.is_some());
            swaying += usize::from(m.sway.is_some());
        }
        // A quarter, a half and a half of 200, within what chance allows.
        assert!((30..=70).contains(&rolling), "{rolling}");
        assert!((75..=125).contains(&circles), "{circles}");
        assert!((75..=125).contains(&swaying), "{swaying}");
    }

    #[test]
    fn a_category_redraws_only_its_own_quantities_within_its_ranges() {
        for seed in 1..=40 {
            let ordinary = VehicleEnvelope::draw(seed).scenario;
            assert_eq!(
                VehicleEnvelope::draw_in(seed, VehicleCategory::Ordinary).scenario,
                ordinary
            );
            let site = VehicleEnvelope::draw_in(seed, VehicleCategory::Site).scenario;
            let m = site.manoeuvres.unwrap();
            assert!(m.calibration_circle_dps.is_none());
            assert!(m.speed_mps.0 == 1.0 && (1.5..6.0).contains(&m.speed_mps.1));
            let steel = site.disturbances.len() - ordinary.disturbances.len();
            assert!((2..=4).contains(&steel), "{steel}");
            assert_eq!(site.iron, ordinary.iron);
            assert_eq!(site.imu, ordinary.imu);
            let cruising = VehicleEnvelope::draw_in(seed, VehicleCategory::Cruising).scenario;
            let m = cruising.manoeuvres.unwrap();
            assert!(m.speed_mps.0 == 6.0 && (8.0..14.0).contains(&m.speed_mps.1));
            assert!(cruising.imu.vibration_mps2 < 0.15);
            assert_eq!(cruising.disturbances, ordinary.disturbances);
            let never = VehicleEnvelope::draw_in(seed, VehicleCategory::NeverStill).scenario;
            let m = never.manoeuvres.unwrap();
            assert_eq!(m.parked_start_s, 0.0);
            assert!(m.stop_s.1 <= 0.3 && m.calibration_circle_dps.is_none());
        }
    }

    #[test]
    fn a_never_still_drive_never_stands_long() {
        for seed in 1..=10 {
            let (scenario, truths) = truths_in(seed, VehicleCategory::NeverStill);
            let step_s = 1.0 / scenario.imu_rate_hz;
            let mut standing_s: f64 = 0.0;
            let mut longest: f64 = 0.0;
            // After its last leg a drive stands until its end.
            let last_moving = truths.iter().rposition(|t| t.moving).unwrap();
            for truth in &truths[..last_moving] {
                standing_s = if truth.moving {
                    0.0
                } else {
                    standing_s + step_s
                };
                longest = longest.max(standing_s);
            }
            assert!(longest < 2.5, "seed {seed}: stood {longest} s");
        }
    }

    #[test]
    fn a_drive_rolling_from_the_start_is_never_still_at_the_start() {
        let seed = (1..)
            .find(|&s| {
                VehicleEnvelope::draw(s)
                    .scenario
                    .manoeuvres
                    .unwrap()
                    .parked_start_s
                    == 0.0
            })
            .unwrap();
        let (scenario, truths) = truths(seed);
        let slowest = scenario.manoeuvres.unwrap().speed_mps.0;
        assert!(truths[0].moving && truths[0].speed_mps >= slowest * 0.99);
    }

    #[test]
    fn drives_stop_and_stay_within_their_speeds() {
        for seed in 1..=6 {
            let (scenario, truths) = truths(seed);
            let m = scenario.manoeuvres.unwrap();
            let stops = truths
                .windows(2)
                .filter(|w| w[0].moving && !w[1].moving)
                .count();
            assert!(stops >= 1, "seed {seed}");
            let top = truths.iter().map(|t| t.speed_mps).fold(0.0, f64::max);
            assert!(top <= m.speed_mps.1 * (1.0 + 1e-9), "seed {seed}: {top}");
            assert!(truths.iter().any(|t| t.moving) && truths.iter().any(|t| !t.moving));
        }
    }

    /// The gyros minus the true bias, without noise, integrate to the
    /// truth (sway and bumps included): the readings are derivatives of it.
    #[test]
    fn the_gyros_integrate_to_the_true_attitude() {
        for seed in 1..=3 {
            let mut scenario = VehicleEnvelope::draw(seed).scenario;
            scenario.imu.gyro_noise_dps = 0.0;
            let dt = 1.0 / scenario.imu_rate_hz;
            let mut q: Option<UnitQuaternion<f64>> = None;
            let mut previous: Option<V3> = None;
            let mut worst = 0.0_f64;
            for event in VehicleDrive::new(scenario).unwrap() {
                let (Some(truth), SensorData::Imu { gyro_dps, .. }) =
                    (event.truth, &event.reading.data)
                else {
                    continue;
                };
                let truth_q = attitude_from_euler(
                    rad(truth.roll_deg),
                    rad(truth.pitch_deg),
                    rad(truth.heading_deg),
                );
                let rate = (V3::from(*gyro_dps) - V3::from(truth.gyro_bias_dps)).map(rad);
                let estimate = q.get_or_insert(truth_q);
                if let Some(p) = previous {
                    *estimate *= UnitQuaternion::from_scaled_axis((p + rate) * (0.5 * dt));
                }
                previous = Some(rate);
                worst = worst.max(deg(estimate.angle_to(&truth_q)));
            }
            assert!(worst < 0.2, "seed {seed}: {worst}°");
        }
    }
}
