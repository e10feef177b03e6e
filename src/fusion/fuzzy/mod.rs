//! The `fuzzy` engine (Wang 2005): low-cost MEMS accelerometers and gyros
//! plus a magnetometer, fused according to a fuzzy expert's decision of
//! the motion status. Only the paper's abstract survives, so the design is
//! ours, in its spirit (docs/engines/fuzzy.md).
//!
//! Per IMU reading:
//! 1. the reading enters a short trailing window ([`motion::MotionWindow`]);
//!    the window's spreads teach the sensors' noise floor
//!    ([`noise_floor`]); the expert's three signals, each divided by its
//!    floor, go through the Mamdani rule base ([`motion::motion_expert`],
//!    [`mamdani`]) to a static degree s ∈ [0, 1]; `motion` is `static`
//!    when s ≥ `static_threshold`. No threshold is in sensor units;
//! 2. the attitude quaternion integrates the bias-compensated gyro
//!    ([`orientation::integrate`]), always; the bias's variance grows as
//!    a random walk whose density is learnt from the bias changes
//!    between static spells ([`gyro_bias`]);
//! 3. with the stillness σ = (s − `static_threshold`)/(1 − `static_threshold`)
//!    clamped to [0, 1] (the `uncertain` rule alone, s = 0.5, is motion),
//!    roll and pitch are corrected towards the accelerometer over the
//!    older half of the window ([`tilt`]) with gain
//!    σ·dt/`tilt_time_constant_s` + (1 − σ)·w·dt/`tilt_moving_time_constant_s`,
//!    w the gate that refuses a force that is not gravity (widened, and
//!    the moving pull sped up, while the tilt's σ exceeds the
//!    accelerometer's), but by at least `tilt_turn_pull` of the angle the
//!    gyros turn about a horizontal axis while moving;
//!    heading is pulled towards the tilt-compensated compass likewise
//!    (time constants `heading_time_constant_s` and
//!    `heading_moving_time_constant_s`, faster while the heading's σ
//!    exceeds the compass's) unless the field is disturbed
//!    ([`disturbance`]) or the compass disagrees with the gyro heading
//!    beyond a gate of `heading_gate_deg` widened by that σ;
//! 4. the reading updates the gyro bias's Kalman filter with weight σ,
//!    and the accelerometer's static norm follows it.
//!
//! The first full window that is quiet against the floor (and plausible
//! for a sensor at rest) aligns the engine: tilt from its mean force,
//! gyro bias from its mean rate, heading from the compass. Magnetometer
//! readings feed the calibration ([`magcal::MagCalibration`]); the newest
//! is used for heading while it is younger than `max_mag_age_s`. Until the
//! calibration exists, heading is the uncalibrated compass at alignment
//! carried on by the gyros, and held by the raw compass while the raw
//! field keeps the magnitude and dip it had then.
//!
//! The Earth's rotation (≤ 0.0042 °/s) is below a MEMS gyro's noise and is
//! absorbed into the estimated bias while static.

pub mod arc_fit;
pub mod bias_doubt;
pub mod bias_feedback;
pub mod disturbance;
pub mod estimate;
pub mod fast_spread;
pub mod gyro_bias;
pub mod heading_drift;
pub mod magcal;
pub mod mamdani;
pub mod motion;
pub mod noise_floor;
pub mod orientation;
pub mod params;
pub mod planar_fit;
pub mod rest_rate;
pub mod rolling;
pub mod start_frame;
pub mod tilt;
pub mod tilt_monitor;
pub mod turn_check;
pub mod uncertainty;

use nalgebra::UnitQuaternion;
use serde::{Deserialize, Serialize};

use self::arc_fit::GyroHeading;
use self::bias_doubt::BiasDoubt;
use self::disturbance::{DisturbanceDetector, Tolerances};
use self::estimate::{CompassState, FuzzyEstimate, Motion};
use self::gyro_bias::{GyroBias, WalkLearner};
use self::heading_drift::Innovations;
use self::magcal::{CalibrationState, MagCalibration};
use self::mamdani::{Mamdani, Scratch};
use self::motion::{MotionSignals, MotionWindow};
use self::noise_floor::NoiseFloor;
use self::orientation::{integrate, magnetic_heading, pull_heading, tilt_from_accel};
pub use self::params::{FuzzyConfig, FuzzyParams, PARAMS, RETIRED};
use self::rest_rate::RestRate;
use self::rolling::RollingWatch;
use self::start_frame::StartFrame;
use self::tilt::TiltWindow;
use self::tilt_monitor::TiltMonitor;
use self::turn_check::TurnCheck;
use super::angles::{deg, rad};
use super::descriptor::EngineDescriptor;
use super::estimate::{EngineOutput, EstimateValues};
use super::frozen::FrozenWatch;
use super::integrity::{Integrity, IntegrityReason};
use super::params::{ParamError, Params, Retired};
use super::reading::{Reading, SensorData, SensorKind};
use super::registry::EngineModel;
use super::{Engine, EngineKind, SnapshotError};
use crate::fusion::geometry::{V3, attitude_from_euler};

/// Version of the engine's snapshot; a snapshot of another is outdated
/// and the server rebuilds the engine from the stored readings.
/// 3: the tilt window holds world-frame forces (issue 18, second step);
/// 4: the bias learns from static blocks (issue 34);
/// 5: alignment while moving in the first reading's frame, the
/// calibration's check and the compass's innovations (issue 34);
/// 6: samples with roll and pitch (the levelled planar fit), relearnt
/// fields, the turns (issue 34);
/// 7: the motion window's time moments of the rates (fast_spread.rs);
/// 8: the IMU watched for a frozen sensor (issue 54);
/// 9: an undone re-take of the heading and the deflection carried from
/// fields not the Earth's (their σ), and a restore carries every part of
/// the state (issue 54);
/// 10: the accelerometer residual's share of the tilt σ (issue 54).
pub const STATE_VERSION: u32 = 10;

/// Plausibility caps for alignment, whatever the floor says: a MEMS
/// sensor at rest shows less spread and less mean rate than this (a
/// sensor that moved from its first reading on has a high "floor" too).
const ALIGN_MAX_ACCEL_SPREAD_MPS2: f64 = 0.5;
const ALIGN_MAX_RATE_SPREAD_RAD_PER_S: f64 = 0.035; // 2 °/s
const ALIGN_MAX_MEAN_RATE_RAD_PER_S: f64 = 0.087; // 5 °/s: no MEMS bias is larger
const ALIGN_MAX_GRAVITY_ERROR_MPS2: f64 = 1.0;
/// Aligning while moving: the tilt's σ is at least this (1°).
const MIN_MOVING_TILT_SIGMA_RAD: f64 = 0.017;
/// g, m/s²: the static norm an alignment while moving starts from.
const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;
/// Time constant of the static ‖f‖ learnt while static, s: it changes
/// only with temperature.
const GRAVITY_TIME_CONSTANT_S: f64 = 5.0;
/// The first calibration re-takes the heading at once; if its field turns
/// out disturbed within this time, s, the fit was wrong and the turn is
/// undone (the heading goes back to what it was, carried by the gyros).
const REHEAD_WATCH_S: f64 = 3.0;
/// ... a disturbance lasting this long, s (not one odd reading).
const REHEAD_UNDO_AFTER_S: f64 = 0.15;
/// A partial arc's calibration is provisional (arc_fit.rs): if its field
/// departs within this time of the fit, s, the arc may have been fitted to
/// a field that was not the Earth's alone, and the heading's σ is the
/// unknown calibration's until a compass steers again. The heading itself
/// is kept (a steel pass right after a good arc is as likely a cause).
const ARC_WATCH_S: f64 = 60.0;
/// How far the uncalibrated compass at alignment may be off (1σ), rad.
const UNCALIBRATED_HEADING_SIGMA_RAD: f64 = 0.17;
/// A reading this still (stillness) is part of a static spell for
/// learning the bias's random walk.
const SPELL_STILLNESS: f64 = 0.9;
/// The smallest floor used as a divisor (far below any sensor's noise).
const MIN_FLOOR: f64 = 1e-9;
/// While the vehicle rolls the noise floors only rise, this many times
/// slower than at rest (noise_floor.rs, rolling.rs).
const ROLLING_FLOOR_RISE_FACTOR: f64 = 100.0;

/// What the engine has done with its readings.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FuzzyStats {
    pub imu_used: u64,
    /// IMU readings at or before the newest one.
    pub imu_dropped: u64,
    /// Gaps longer than `max_imu_gap_s`.
    pub imu_gaps: u64,
    pub mag_used: u64,
    /// Calibration fits accepted.
    pub mag_fits: u64,
    /// Magnetometer readings found disturbed (not used).
    pub mag_disturbed: u64,
    /// Calibrations dropped because the raw field was more consistent on
    /// the newest readings (magcal.rs: the check).
    #[serde(default)]
    pub mag_refuted: u64,
    /// Times a refused compass showed the gyro's heading drifting
    /// (heading_drift.rs) and was taken again.
    #[serde(default)]
    pub heading_drifts: u64,
    /// Times a tilt residual that persisted while moving called the gyro
    /// bias into doubt (bias_doubt.rs).
    #[serde(default)]
    pub bias_doubts: u64,
    /// Times the attitude became non-finite and alignment started again.
    pub resets: u64,
    /// IMU readings taken for a frozen sensor's (not used).
    #[serde(default)]
    pub imu_frozen: u64,
}

/// The attitude solution once aligned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Solution {
    attitude: UnitQuaternion<f64>,
    gyro_bias: GyroBias,
    /// ‖f‖ at rest as this accelerometer reads it, m/s².
    static_gravity_mps2: f64,
    /// The previous bias-compensated rate (trapezoidal integration).
    previous_rate_rad_per_s: Option<V3>,
    /// Measured and expected world-frame forces over the window.
    tilt_window: TiltWindow,
    /// How far the heading may be off (1σ), rad: grows with the gyros'
    /// bias σ and their turn, shrinks with each compass pull.
    #[serde(default)]
    heading_sigma_rad: f64,
    /// How far roll and pitch may be off (1σ), rad: grows like the
    /// heading's, shrinks with each accelerometer pull.
    #[serde(default)]
    tilt_sigma_rad: f64,
    /// The bias's random walk as the data show it.
    #[serde(default)]
    bias_walk: WalkLearner,
    /// Static blocks' mean rates and their wander (rest_rate.rs).
    #[serde(default)]
    rest_rate: RestRate,
    /// The bias-compensated rate about the world vertical, integrated
    /// (no compass in it; unwrapped), rad.
    #[serde(default)]
    gyro_yaw_rad: f64,
    /// The bias estimate subtracted from that rate, integrated likewise,
    /// rad (arc_fit.rs corrects older gyro headings with it).
    #[serde(default)]
    bias_yaw_rad: f64,
    /// What the tilt window's older half (its accelerometer mean against
    /// the carried gravity) says the tilt may be off by,
    /// 1σ, rad (uncertainty.rs, `unexplained_residual_sigma`): reported
    /// in the tilt's σ, not in the carried one the pulls and the monitor
    /// work with.
    #[serde(default)]
    residual_sigma_rad: f64,
    /// The persisting tilt residual's evidence against the bias while
    /// moving (bias_doubt.rs).
    #[serde(default)]
    bias_doubt: BiasDoubt,
}

/// How many σ of the bias and of the wander of the mean rate at rest the
/// window's mean rate may be off the bias before it counts as a turn.
const RATE_TOLERANCE_SIGMAS: f64 = 3.0;

/// The `fuzzy` engine; see the module documentation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FuzzyEngine {
    /// [`STATE_VERSION`] when the snapshot was taken.
    state_version: u32,
    params: Params,
    #[serde(skip_serializing, default = "placeholder_config")]
    config: FuzzyConfig,
    #[serde(skip_serializing, default = "placeholder_expert")]
    expert: Mamdani,
    window: MotionWindow,
    floor: NoiseFloor,
    newest_imu_t: Option<f64>,
    /// The IMU's readings (forces, rates as sent) watched for a frozen
    /// sensor: a frozen reading is not used ([`crate::fusion::frozen`]).
    imu_frozen: FrozenWatch<[f64; 6]>,
    /// Before alignment: the forces in the first reading's frame
    /// (start_frame.rs), for an alignment while moving.
    #[serde(default)]
    start_frame: StartFrame,
    solution: Option<Solution>,
    calibration: MagCalibration,
    disturbance: DisturbanceDetector,
    /// Before a calibration: whether the raw field still has the magnitude
    /// and dip it had when first seen aligned (a sensor that has not
    /// turned, or needs no calibration), so its compass may hold the heading.
    #[serde(default)]
    raw_disturbance: Option<DisturbanceDetector>,
    /// The newest magnetometer reading: time and raw field, µT.
    magnetometer: Option<(f64, V3)>,
    /// True heading (rad) from the newest magnetometer reading, calibrated
    /// and tilt-compensated with the tilt at its time; `None` before the
    /// calibration and while the field is disturbed.
    compass: Option<(f64, f64)>,
    stats: FuzzyStats,
    /// Set by the first calibration: take the heading from the compass.
    reheading: bool,
    /// Since when the compass has disagreed with the heading beyond the gate.
    compass_gated_since: Option<f64>,
    /// The compass's recent innovations (heading_drift.rs).
    #[serde(default)]
    innovations: Innovations,
    /// The calibrated compass against the gyro across turns (turn_check.rs).
    #[serde(default)]
    turns: TurnCheck,
    /// The same for a relearnt field's compass (disturbance.rs), which
    /// steers once its turns agree with the gyro.
    #[serde(default)]
    relearnt_turns: TurnCheck,
    /// A calibrated compass was believed again against the gyro: its
    /// residual says the heading was wrong, not the bias, until it is
    /// back within the gate.
    #[serde(default)]
    reacquired: bool,
    /// The first calibration's re-take of the heading (undone if its
    /// field proves disturbed at once).
    rehead_turn: Option<Rehead>,
    /// The heading rests on no calibration: a first calibration's re-take
    /// was undone. Its σ is the unknown hard iron's until a compass steers.
    #[serde(default)]
    heading_uncalibrated: bool,
    /// Until when a new partial arc's calibration is watched
    /// ([`ARC_WATCH_S`]).
    #[serde(default)]
    arc_watch_until: Option<f64>,
    /// The deflection the heading took from compasses whose field's dip
    /// was not the site's (disturbance.rs), rad: the pulls' weighted
    /// mean of it, which pulls by an Earth's field wear off. Reported in
    /// the heading's σ, after the field is the Earth's again too.
    #[serde(default)]
    carried_deflection_rad: f64,
    /// The newest static degree (the dip check allows for the tilt error
    /// of a moving sensor).
    static_degree: f64,
    /// Motion from events: rolling until stopped (rolling.rs).
    #[serde(default)]
    rolling: RollingWatch,
    /// The quietest accelerometer and gyro spreads of the calm a roll may
    /// end in ([`FuzzyEngine::watch_calm_spreads`]).
    #[serde(default)]
    calm_spreads: Option<[f64; 2]>,
    /// Whether the compass steers the heading, and since when.
    #[serde(default)]
    compass_state: Option<(CompassState, f64)>,
    /// The accelerometer's tilt at rest against the carried tilt
    /// (tilt_monitor.rs).
    #[serde(default)]
    tilt_monitor: TiltMonitor,
    #[serde(skip)]
    scratch: Scratch,
}

/// The first calibration's re-take of the heading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Rehead {
    t: f64,
    /// How far it turned the heading, rad.
    turn_rad: f64,
}

/// Used only while deserialising; `restore` rebuilds it from `params`.
fn placeholder_config() -> FuzzyConfig {
    FuzzyConfig::from_params(&Params::defaults(PARAMS)).expect("default parameters are valid")
}

fn placeholder_expert() -> Mamdani {
    motion::motion_expert(&placeholder_config().motion).expect("the default rule base is valid")
}

impl FuzzyEngine {
    /// A fresh engine.
    pub fn new(params: Params) -> Result<FuzzyEngine, ParamError> {
        let config = FuzzyConfig::from_params(&params)?;
        let expert = motion::motion_expert(&config.motion)
            .map_err(|e| ParamError::Inconsistent(format!("motion rule base: {e}")))?;
        Ok(FuzzyEngine {
            state_version: STATE_VERSION,
            params,
            config,
            expert,
            window: MotionWindow::new(config.window_samples),
            floor: NoiseFloor::default(),
            newest_imu_t: None,
            start_frame: StartFrame::default(),
            solution: None,
            calibration: MagCalibration::new(
                config.mag_min_coverage_deg,
                config.mag_inclination_rad,
                config.mag_level_tolerance_rad,
                config.mag_refit_every,
            ),
            disturbance: DisturbanceDetector::new(config.mag_inclination_rad),
            raw_disturbance: None,
            magnetometer: None,
            compass: None,
            stats: FuzzyStats::default(),
            reheading: false,
            compass_gated_since: None,
            innovations: Innovations::default(),
            turns: TurnCheck::default(),
            relearnt_turns: TurnCheck::default(),
            reacquired: false,
            rehead_turn: None,
            arc_watch_until: None,
            heading_uncalibrated: false,
            carried_deflection_rad: 0.0,
            static_degree: 0.0,
            rolling: RollingWatch::default(),
            calm_spreads: None,
            compass_state: None,
            tilt_monitor: TiltMonitor::default(),
            imu_frozen: FrozenWatch::default(),
            scratch: Scratch::default(),
        })
    }

    /// An engine with every parameter at its default.
    pub fn with_defaults() -> FuzzyEngine {
        FuzzyEngine::new(Params::defaults(PARAMS)).expect("default parameters are valid")
    }

    /// Continues from a snapshot taken by [`Engine::snapshot`]. A snapshot
    /// of another [`STATE_VERSION`] is refused as outdated.
    pub fn restore(snapshot: serde_json::Value) -> Result<FuzzyEngine, SnapshotError> {
        SnapshotError::check_version(EngineKind::Fuzzy, &snapshot, STATE_VERSION)?;
        let engine: FuzzyEngine = SnapshotError::parse(EngineKind::Fuzzy, snapshot)?;
        let params = engine.params.upgraded(PARAMS, RETIRED)?;
        let fresh = FuzzyEngine::new(params)?;
        if engine.window.capacity() != fresh.config.window_samples {
            return Err(SnapshotError::Invalid(
                "motion window does not match the parameters".into(),
            ));
        }
        // Every part of the state from the snapshot; what the parameters
        // make, from them.
        Ok(FuzzyEngine {
            params: fresh.params,
            config: fresh.config,
            expert: fresh.expert,
            window: engine.window.prepared(),
            scratch: Scratch::default(),
            ..engine
        })
    }

    /// The working configuration.
    pub fn config(&self) -> &FuzzyConfig {
        &self.config
    }

    /// What the engine has done with its readings.
    pub fn stats(&self) -> FuzzyStats {
        self.stats
    }

    /// The magnetometer calibration.
    pub fn calibration(&self) -> &MagCalibration {
        &self.calibration
    }

    /// The learnt noise floors: accelerometer spread (m/s²) and gyro fast
    /// spread (rad/s, fast_spread.rs) at rest, once seen.
    pub fn noise_floors(&self) -> (Option<f64>, Option<f64>) {
        (self.floor.accel.level(), self.floor.gyro.level())
    }

    /// Roll and pitch (rad) as best known now.
    fn current_tilt(&self) -> (f64, f64) {
        match &self.solution {
            Some(s) => {
                let (roll, pitch, _) = s.attitude.euler_angles();
                (roll, pitch)
            }
            None => tilt_from_accel(&self.window.mean_force()),
        }
    }

    fn feed_magnetometer(&mut self, t: f64, field_ut: V3) {
        self.stats.mag_used += 1;
        let (roll, pitch) = self.current_tilt();
        // A disturbed reading neither steers nor calibrates.
        // Moving, the tilt (and so the dip) is less sure: up to three times
        // the dip tolerance.
        let tolerances = Tolerances {
            dip_rad: self.config.mag_disturbance.dip_rad * (3.0 - 2.0 * self.static_degree),
            ..self.config.mag_disturbance
        };
        let level = attitude_from_euler(roll, pitch, 0.0);
        // A calibration worse than none on the newest readings is dropped
        // (magcal.rs): the disturbance check starts again from the new
        // field, and the compass's heading is taken at the next IMU reading.
        if self.calibration.check(t, field_ut) {
            self.disturbance
                .recalibrated(self.calibration.field_magnitude_ut());
            self.reheading = self.calibration.correction().is_some();
            self.stats.mag_refuted += 1;
            self.innovations.clear();
            self.turns.clear();
        }
        let disturbed = self.calibration.correction().is_some_and(|c| {
            self.disturbance.observe(
                t,
                &(level * c.apply(&field_ut)),
                self.calibration.state() == CalibrationState::Planar,
                &tolerances,
            )
        });
        // Uncalibrated, the raw compass counts only while the field is as
        // it was: it holds the heading taken from it at alignment.
        let raw_usable = self.calibration.correction().is_none()
            && self.solution.is_some()
            && !self
                .raw_disturbance
                .get_or_insert_with(|| DisturbanceDetector::new(self.config.mag_inclination_rad))
                .observe(t, &(level * field_ut), false, &tolerances);
        if self
            .rehead_turn
            .is_some_and(|rehead| t - rehead.t > REHEAD_WATCH_S)
        {
            self.rehead_turn = None;
        }
        if disturbed {
            self.stats.mag_disturbed += 1;
            self.innovations.clear();
            // Not one odd reading: the field has departed for a while.
            let departed = self.disturbance.departing_for_s(t) >= REHEAD_UNDO_AFTER_S;
            if departed
                && let (Some(rehead), Some(solution)) =
                    (self.rehead_turn.take(), &mut self.solution)
            {
                // The heading as it was, resting again on no calibration
                // (or a refuted one): its σ the unknown hard iron's until
                // a compass steers it.
                solution.attitude =
                    UnitQuaternion::from_axis_angle(&V3::z_axis(), -rehead.turn_rad)
                        * solution.attitude;
                self.heading_uncalibrated = true;
            }
            if departed && self.arc_watch_until.take().is_some_and(|until| t <= until) {
                self.heading_uncalibrated = true;
            }
        }
        // A partial arc's calibration is provisional: a reading it calls
        // disturbed still reaches the planar and full fits (and the arc's
        // own refits), or a wrong arc would keep them from ever fitting.
        if !disturbed || self.calibration.state() == CalibrationState::Arc {
            let was_calibrated = self.calibration.correction().is_some()
                && self.calibration.state() != CalibrationState::Arc;
            let gyro = self.solution.as_ref().map(|s| GyroHeading {
                t,
                yaw_rad: s.gyro_yaw_rad,
                bias_integral_rad: s.bias_yaw_rad,
                bias_rad_per_s: (s.attitude * s.gyro_bias.bias_rad_per_s).z,
                // The bias's σ about the world vertical: its per-axis σ
                // through the attitude's vertical row.
                bias_sigma_rad_per_s: s
                    .attitude
                    .to_rotation_matrix()
                    .matrix()
                    .row(2)
                    .transpose()
                    .component_mul(&s.gyro_bias.sigma_rad_per_s())
                    .norm(),
                tilt_sigma_rad: self.carried_tilt_sigma(s).hypot(s.residual_sigma_rad),
            });
            if self.calibration.add(field_ut, roll, pitch, gyro) {
                self.stats.mag_fits += 1;
                self.arc_watch_until =
                    (self.calibration.state() == CalibrationState::Arc).then_some(t + ARC_WATCH_S);
                // A new calibration moves the compass in one step.
                self.innovations.clear();
                self.turns.clear();
                // The heading so far rests on the raw compass at alignment
                // (or a partial arc): the first calibration replaces it at
                // the next IMU reading.
                if !was_calibrated {
                    self.reheading = true;
                }
                self.disturbance
                    .recalibrated(self.calibration.field_magnitude_ut());
            }
        }
        if self.magnetometer.is_none_or(|(newest, _)| t >= newest) {
            self.magnetometer = Some((t, field_ut));
            let corrected = match self.calibration.correction() {
                Some(c) => Some(c.apply(&field_ut)),
                None => raw_usable.then_some(field_ut),
            };
            self.compass = corrected.filter(|_| !disturbed).map(|field| {
                (
                    t,
                    magnetic_heading(&field, roll, pitch) + self.config.declination_rad,
                )
            });
            if let (Some((_, heading)), Some(solution), Some(_)) =
                (self.compass, &self.solution, self.calibration.correction())
            {
                if self.disturbance.relearnt() {
                    // A relearnt field is the Earth's if its heading
                    // changes are the gyro's (a magnet on the vehicle
                    // bends them as hard iron does).
                    self.relearnt_turns.push(t, heading, solution.gyro_yaw_rad);
                    if self
                        .relearnt_turns
                        .sigma_rad()
                        .is_some_and(|sigma| sigma <= 0.5 * self.config.heading_gate_rad)
                    {
                        self.disturbance.confirm();
                    }
                } else {
                    self.turns.push(t, heading, solution.gyro_yaw_rad);
                }
            }
            if !self.disturbance.relearnt() {
                self.relearnt_turns.clear();
            }
        }
    }

    /// The compass heading (rad) if its reading is young enough at `t`.
    fn fresh_compass(&self, t: f64) -> Option<f64> {
        self.compass
            .filter(|(mag_t, _)| (t - mag_t).abs() <= self.config.max_mag_age_s)
            .map(|(_, heading)| heading)
    }

    /// True heading (rad) at `t` from the newest magnetometer reading, for
    /// this tilt, calibrated if the calibration exists and raw if not: the
    /// best there is at alignment.
    fn any_compass_heading(&self, t: f64, roll: f64, pitch: f64) -> Option<f64> {
        let (_, field) = self
            .magnetometer
            .filter(|(mag_t, _)| (t - mag_t).abs() <= self.config.max_mag_age_s)?;
        let corrected = match self.calibration.correction() {
            Some(c) => c.apply(&field),
            None => field,
        };
        Some(magnetic_heading(&corrected, roll, pitch) + self.config.declination_rad)
    }

    /// The expert's inputs as multiples of the floors (the floor of a
    /// signal not yet seen is the signal itself: ratio 1).
    fn relative_signals(&self, signals: &MotionSignals) -> MotionSignals {
        let accel = self
            .floor
            .accel
            .level()
            .unwrap_or(signals.accel_activity_mps2)
            .max(MIN_FLOOR);
        let gyro = self
            .floor
            .gyro
            .level()
            .unwrap_or_else(|| self.window.fast_rate_spread())
            .max(MIN_FLOOR);
        MotionSignals {
            accel_dev_mps2: signals.accel_dev_mps2 / accel,
            accel_activity_mps2: signals.accel_activity_mps2 / accel,
            gyro_activity_rad_per_s: signals.gyro_activity_rad_per_s / gyro,
        }
    }

    /// The quietest spreads of the calm a roll may end in (rolling.rs:
    /// no input fully `high`): what a rest louder than the floors shows.
    /// `now` is the window's [accelerometer, gyro fast] spreads.
    fn watch_calm_spreads(&mut self, now: [f64; 2], shaking_degree: f64, rolling: bool) {
        if !rolling || shaking_degree <= 0.0 || !self.window.is_full() {
            self.calm_spreads = None;
            return;
        }
        let quietest = self.calm_spreads.get_or_insert(now);
        quietest[0] = quietest[0].min(now[0]);
        quietest[1] = quietest[1].min(now[1]);
    }

    /// A roll ended in a calm the expert still called `moving`: at rest by
    /// events, louder than the rests before. The calm's quietest spreads
    /// become the floors, and the force's norm now the norm at rest (an
    /// alignment while moving may have left it off).
    fn take_louder_rest(&mut self) {
        if let Some([accel, gyro]) = self.calm_spreads.take() {
            self.floor.accel.raise_to(accel);
            self.floor.gyro.raise_to(gyro);
        }
        if let Some(solution) = &mut self.solution
            && self.window.is_full()
        {
            solution.static_gravity_mps2 = self.window.mean_force_norm();
        }
    }

    /// The expert's static degree for signals relative to the floors; 0
    /// for a window no sensor at rest shows.
    fn expert_degree(&mut self, relative: &MotionSignals, plausible_at_rest: bool) -> f64 {
        if !plausible_at_rest {
            return 0.0;
        }
        motion::decided_by_breakpoints(&self.config.motion, relative)
            .or_else(|| motion::static_degree(&self.expert, relative, &mut self.scratch))
            .unwrap_or(0.0)
    }

    fn feed_imu(&mut self, t: f64, force: V3, rate: V3, out: &mut Vec<EngineOutput>) {
        let dt_s = match self.newest_imu_t {
            Some(newest) if t <= newest => {
                self.stats.imu_dropped += 1;
                return;
            }
            Some(newest) => t - newest,
            None => f64::INFINITY,
        };
        let raw = [force.x, force.y, force.z, rate.x, rate.y, rate.z];
        let was_frozen = self.imu_frozen.frozen_since_t().is_some();
        if self.imu_frozen.is_frozen(t, raw) {
            // Not used: the attitude is held, `lost` (`sensor_frozen`);
            // the time until the IMU is live again is a gap.
            self.stats.imu_frozen += 1;
            let signals = self.window_signals();
            let mut held = self.estimate(t, self.static_degree, &signals);
            held.integrity = Integrity::lost(IntegrityReason::SensorFrozen);
            out.push(held);
            return;
        }
        if was_frozen {
            // Live again after a frozen stretch: what the attitude did
            // meanwhile is unknown. The tilt until a quiet window agrees
            // (`lost`, `recovering`); the heading until the compass gives
            // it again (the vehicle may have turned any way).
            self.tilt_monitor.unverified();
            if let Some(solution) = &mut self.solution {
                solution.heading_sigma_rad = uncertainty::UNKNOWN_ANGLE_SIGMA_RAD;
            }
        }
        self.newest_imu_t = Some(t);
        self.stats.imu_used += 1;
        let continuous = dt_s <= self.config.max_imu_gap_s;
        if !continuous {
            if dt_s.is_finite() {
                self.stats.imu_gaps += 1;
            }
            self.window.clear();
            self.start_frame.clear();
            self.innovations.clear();
            self.turns.clear();
            self.relearnt_turns.clear();
            self.rolling.interrupted();
            if let Some(solution) = &mut self.solution {
                solution.previous_rate_rad_per_s = None;
                solution.tilt_window.clear();
                solution.rest_rate.interrupted();
            }
        }
        self.window.push(force, rate);
        // The window's spreads, once per reading: the floors, the latch's
        // shaking and its calm read them.
        let (accel_spread, fast_spread) =
            (self.window.force_spread(), self.window.fast_rate_spread());
        // Floors from rest (rolling.rs); while rolling they only rise,
        // a hundred times slower (noise_floor.rs).
        if self.window.is_full() {
            let rise = self.config.floor_rise_s;
            let (accel, gyro) = (accel_spread, fast_spread);
            if self.rolling.is_rolling() {
                let slow = ROLLING_FLOOR_RISE_FACTOR * rise;
                self.floor.accel.observe_rising(t, accel, slow);
                self.floor.gyro.observe_rising(t, gyro, slow);
            } else {
                self.floor.accel.observe(t, accel, rise);
                self.floor.gyro.observe(t, gyro, rise);
            }
        }

        if self.solution.is_none() {
            let dt = if continuous { dt_s } else { 0.0 };
            // The span starts again after at most 30 s, or twice the wait
            // for an alignment while moving if that is longer.
            let longest_s = start_frame::MAX_SPAN_S.max(2.0 * self.config.align_without_rest_s);
            self.start_frame.push(t, &force, &rate, dt, longest_s);
            self.try_align(t);
            if self.solution.is_some() {
                self.start_frame.clear();
            }
        }
        let signals = self.window_signals();
        let bias = self
            .solution
            .as_ref()
            .map_or(V3::zeros(), |s| s.gyro_bias.bias_rad_per_s);
        let relative = self.relative_signals(&signals);
        // The floors are the quietest windows seen; a sensor never still
        // has learnt them while moving, and everything looks "low" against
        // them. A window no MEMS sensor at rest shows (the alignment's
        // caps on the spreads, and a mean rate more than 5 °/s off the
        // bias) is motion, whatever the floors and the bias's σ say.
        let plausible_at_rest = signals.accel_activity_mps2 <= ALIGN_MAX_ACCEL_SPREAD_MPS2
            && self.window.rate_spread() <= ALIGN_MAX_RATE_SPREAD_RAD_PER_S
            && (self.window.mean_rate() - bias).norm() <= ALIGN_MAX_MEAN_RATE_RAD_PER_S;
        let static_degree = self.expert_degree(&relative, plausible_at_rest);
        // The latch reads the shaking and the acceleration, not the mean
        // rate's distance from the bias: a gyro whose bias stepped (a power
        // cycle) looks turning, and a latch on that would keep it from
        // ever resting to learn the new bias (rolling.rs).
        let shaking_degree = if signals.gyro_activity_rad_per_s > fast_spread {
            let shaking = self.relative_signals(&MotionSignals {
                gyro_activity_rad_per_s: fast_spread,
                ..signals
            });
            self.expert_degree(&shaking, plausible_at_rest)
        } else {
            static_degree
        };
        // The horizontal force in the level frame turned with the vehicle.
        let horizontal = self
            .solution
            .as_ref()
            .filter(|_| self.rolling.sample_due(t))
            .and_then(|s| {
                let f = s.tilt_window.mean_measured()?;
                let (sin, cos) = s.attitude.euler_angles().2.sin_cos();
                Some([cos * f.x + sin * f.y, cos * f.y - sin * f.x])
            });
        let rolling = self
            .rolling
            .step(&self.config.rolling, t, shaking_degree, horizontal);
        self.watch_calm_spreads([accel_spread, fast_spread], shaking_degree, rolling);
        if self.rolling.ended_louder_than_floors() {
            self.take_louder_rest();
        }
        let static_degree = if rolling { 0.0 } else { static_degree };

        self.static_degree = static_degree;
        if continuous && let Some(solution) = self.solution.take() {
            let doubts_before = solution.bias_doubt.doubts;
            let mut updated = self.advance(solution, t, dt_s, force, rate, static_degree);
            self.stats.bias_doubts += updated.bias_doubt.doubts - doubts_before;
            self.steer_heading(&mut updated, t, dt_s, static_degree);
            let finite = updated.attitude.coords.iter().all(|x| x.is_finite())
                && updated
                    .gyro_bias
                    .bias_rad_per_s
                    .iter()
                    .all(|x| x.is_finite())
                && updated.gyro_bias.variance.iter().all(|x| x.is_finite());
            if finite {
                self.solution = Some(updated);
            } else {
                self.stats.resets += 1;
                self.window.clear();
            }
        }
        self.monitor_tilt(t);
        let state = self.compass_now(t);
        if self
            .compass_state
            .is_none_or(|(previous, _)| previous != state)
        {
            self.compass_state = Some((state, t));
        }
        out.push(self.estimate(t, static_degree, &signals));
    }

    /// The motion signals of the window, against the solution's gravity
    /// and gyro bias (before alignment: the window's own gravity, no bias).
    fn window_signals(&self) -> MotionSignals {
        let (bias, gravity, tolerance) = match &self.solution {
            Some(s) => (
                s.gyro_bias.bias_rad_per_s,
                s.static_gravity_mps2,
                RATE_TOLERANCE_SIGMAS
                    * (s.gyro_bias.variance.sum() + 3.0 * s.rest_rate.wander_variance())
                        .max(0.0)
                        .sqrt(),
            ),
            None => (V3::zeros(), self.window.mean_force_norm(), 0.0),
        };
        self.window.signals(gravity, &bias, tolerance)
    }

    /// True while the compass disagrees with the gyro heading beyond the
    /// gate and has not yet for `heading_gate_s` (after that it steers).
    fn gated_now(&self, t: f64) -> bool {
        // The first calibration's heading waits for a relearnt field.
        (self.reheading && self.disturbance.relearnt())
            || self.compass_gated_since.is_some_and(|since| {
                t - since < self.config.heading_gate_s || self.disturbance.relearnt()
            })
    }

    /// Whether the compass steers the heading at `t`, and if not, why.
    fn compass_now(&self, t: f64) -> CompassState {
        let fresh = self
            .magnetometer
            .is_some_and(|(mag_t, _)| (t - mag_t).abs() <= self.config.max_mag_age_s);
        if !fresh {
            CompassState::Absent
        } else if self.disturbance.disturbed() && self.calibration.correction().is_some() {
            CompassState::Disturbed
        } else if self.gated_now(t) {
            CompassState::Gated
        } else if self.calibration.correction().is_some() {
            CompassState::Believed
        } else if self.fresh_compass(t).is_some() {
            CompassState::Raw
        } else {
            CompassState::Collecting
        }
    }

    /// The spreads of a full window the alignment accepts: quiet against
    /// the learnt floors and plausible for a MEMS sensor at rest (the
    /// accelerometer's, the gyros' fast one); `None` for any other window.
    fn quiet_window(&self) -> Option<(f64, f64)> {
        if !self.window.is_full() {
            return None;
        }
        let m = &self.config.motion;
        let spread = self.window.force_spread();
        let rate_spread = self.window.rate_spread();
        let mean_rate = self.window.mean_rate();
        let accel_floor = self.floor.accel.level()?;
        let gyro_floor = self.floor.gyro.level()?;
        let fast_rate_spread = self.window.fast_rate_spread();
        let quiet = spread <= m.accel_activity.still * accel_floor
            && fast_rate_spread <= m.gyro_activity.still * gyro_floor;
        let plausible = spread <= ALIGN_MAX_ACCEL_SPREAD_MPS2
            && rate_spread <= ALIGN_MAX_RATE_SPREAD_RAD_PER_S
            && mean_rate.norm() <= ALIGN_MAX_MEAN_RATE_RAD_PER_S
            && (self.window.mean_force_norm() - 9.81).abs() <= ALIGN_MAX_GRAVITY_ERROR_MPS2;
        (quiet && plausible).then_some((spread, fast_rate_spread))
    }

    /// Tests the carried tilt against a quiet window's (tilt_monitor.rs),
    /// and aligns again from the window when they disagree for long
    /// enough. The heading is the compass's if it gives one, else the
    /// carried one, its σ grown by what the bias's change turns it by
    /// since the tilt last agreed.
    fn monitor_tilt(&mut self, t: f64) {
        let Some(solution) = &self.solution else {
            return;
        };
        if self.quiet_window().is_none() {
            self.tilt_monitor.moving();
            return;
        }
        let down = solution.attitude.inverse_transform_vector(&V3::z());
        // The σ the gyros carry the tilt with: the test asks whether the
        // tilt is as good as that says (the σ the estimate reports adds
        // the residual this window shows, which at rest is the very
        // error under test).
        let tilt_sigma_rad = self.carried_tilt_sigma(solution);
        let bias_departed = tilt_monitor::bias_departs(
            &self.window.mean_rate(),
            &solution.gyro_bias.bias_rad_per_s,
            &solution.gyro_bias.variance,
            self.window.rate_spread(),
            self.window.len(),
        );
        let window = tilt_monitor::QuietWindow {
            mean_force: self.window.mean_force(),
            spread_mps2: self.window.force_spread(),
            samples: self.window.len(),
            bias_departed,
        };
        let verdict = self.tilt_monitor.test(t, &down, &window, tilt_sigma_rad);
        if verdict != tilt_monitor::Verdict::Realign {
            return;
        }
        let Some(old) = self.solution.take() else {
            return;
        };
        let since_agreed_s = self.tilt_monitor.since_agreed_s(t);
        self.try_align(t);
        self.tilt_monitor.realigned(t);
        let Some((roll, pitch, _)) = self.solution.as_ref().map(|s| s.attitude.euler_angles())
        else {
            self.solution = Some(old);
            return;
        };
        // With a compass, `try_align` took the heading from it; without,
        // the old heading stays, with what it carried.
        let compass = self.any_compass_heading(t, roll, pitch);
        if let (None, Some(new)) = (compass, &mut self.solution) {
            let (_, _, old_yaw) = old.attitude.euler_angles();
            new.attitude = attitude_from_euler(roll, pitch, old_yaw);
            let bias_change = (new.gyro_bias.bias_rad_per_s - old.gyro_bias.bias_rad_per_s).norm();
            let turned = since_agreed_s.map_or(std::f64::consts::PI, |s| bias_change * s);
            new.heading_sigma_rad = old.heading_sigma_rad.hypot(turned);
            new.gyro_yaw_rad = old.gyro_yaw_rad;
            new.bias_yaw_rad = old.bias_yaw_rad;
        }
    }

    /// Aligns on a quiet, plausible full window.
    fn try_align(&mut self, t: f64) {
        if !self.window.is_full() {
            return;
        }
        let Some((spread, fast_rate_spread)) = self.quiet_window() else {
            if self.floor.accel.level().is_some() && self.floor.gyro.level().is_some() {
                self.align_while_moving(t);
            }
            return;
        };
        let rate_spread = self.window.rate_spread();
        let mean_rate = self.window.mean_rate();
        let (roll, pitch) = tilt_from_accel(&self.window.mean_force());
        let compass = self.any_compass_heading(t, roll, pitch);
        if compass.is_some() {
            self.heading_taken_from_compass();
        }
        let yaw_known = compass.is_some();
        let yaw = compass.unwrap_or(0.0);
        // This window is quiet: the floors are at most its spreads.
        self.floor.accel.lower_to(spread);
        self.floor.gyro.lower_to(fast_rate_spread);
        // The mean of the window's rates, each with the per-axis noise
        // variance (spread²/3): variance spread²/(3N); and one window
        // cannot tell a bias from a slow sway or a gentle turn of that
        // size: the mean itself is added (per axis, ‖ω̄‖²/3), for the
        // static blocks that follow to settle.
        let n = self.window.len() as f64;
        let bias_variance = (rate_spread * rate_spread / 3.0 / n + mean_rate.norm_squared() / 3.0)
            .max(MIN_FLOOR * MIN_FLOOR);
        self.turns.clear();
        self.relearnt_turns.clear();
        // The gyro heading starts again from zero.
        self.calibration.restart_arc();
        self.solution = Some(Solution {
            attitude: attitude_from_euler(roll, pitch, yaw),
            gyro_bias: GyroBias::new(mean_rate, bias_variance),
            static_gravity_mps2: self.window.mean_force_norm(),
            previous_rate_rad_per_s: None,
            tilt_window: TiltWindow::new(self.config.window_samples),
            tilt_sigma_rad: 0.0,
            bias_walk: WalkLearner::default(),
            rest_rate: RestRate::default(),
            gyro_yaw_rad: 0.0,
            bias_yaw_rad: 0.0,
            residual_sigma_rad: 0.0,
            bias_doubt: BiasDoubt::default(),
            heading_sigma_rad: if yaw_known {
                UNCALIBRATED_HEADING_SIGMA_RAD
            } else {
                std::f64::consts::PI
            },
        });
    }

    /// Aligns without a rest once `align_without_rest_s` has passed since
    /// the first reading with no quiet window (a sensor that is never
    /// still): tilt from the mean force in the first reading's frame, held
    /// still by the gyros (start_frame.rs, with its σ from the data),
    /// heading from the compass, the gyro bias unknown: 0 with σ
    /// `gyro_bias_prior_dps`, learnt at the first rest (and from the pulls
    /// while moving, bias_feedback.rs). Only while that mean force has
    /// gravity's size (within 1 m/s²).
    fn align_while_moving(&mut self, t: f64) {
        let prior = self.config.gyro_bias_prior_rad_per_s;
        if self.start_frame.span_s(t) < self.config.align_without_rest_s {
            return;
        }
        let Some(found) = self.start_frame.alignment(t, STANDARD_GRAVITY_MPS2, prior) else {
            return;
        };
        if found.gravity_error_mps2 > ALIGN_MAX_GRAVITY_ERROR_MPS2 {
            return;
        }
        let (roll, pitch, _) = found.attitude.euler_angles();
        let compass = self.any_compass_heading(t, roll, pitch);
        if compass.is_some() {
            self.heading_taken_from_compass();
        }
        self.turns.clear();
        self.relearnt_turns.clear();
        // The gyro heading starts again from zero.
        self.calibration.restart_arc();
        self.solution = Some(Solution {
            attitude: attitude_from_euler(roll, pitch, compass.unwrap_or(0.0)),
            gyro_bias: GyroBias::new(V3::zeros(), (prior * prior).max(MIN_FLOOR * MIN_FLOOR)),
            static_gravity_mps2: STANDARD_GRAVITY_MPS2,
            previous_rate_rad_per_s: None,
            tilt_window: TiltWindow::new(self.config.window_samples),
            tilt_sigma_rad: found.tilt_sigma_rad.max(MIN_MOVING_TILT_SIGMA_RAD),
            bias_walk: WalkLearner::default(),
            rest_rate: RestRate::default(),
            gyro_yaw_rad: 0.0,
            bias_yaw_rad: 0.0,
            residual_sigma_rad: 0.0,
            bias_doubt: BiasDoubt::default(),
            heading_sigma_rad: if compass.is_some() {
                UNCALIBRATED_HEADING_SIGMA_RAD
            } else {
                std::f64::consts::PI
            },
        });
    }

    /// One step of the module documentation's steps 2–4.
    fn advance(
        &self,
        mut solution: Solution,
        t: f64,
        dt_s: f64,
        force: V3,
        rate: V3,
        static_degree: f64,
    ) -> Solution {
        let c = &self.config;
        let walk_density = solution.bias_walk.density(c.bias_walk_density);
        solution.gyro_bias.predict(dt_s, walk_density);
        let compensated = rate - solution.gyro_bias.bias_rad_per_s;
        let mean_rate = match solution.previous_rate_rad_per_s {
            Some(previous) => (previous + compensated) * 0.5,
            None => compensated,
        };
        solution.attitude = integrate(&solution.attitude, &mean_rate, dt_s);
        solution.gyro_yaw_rad += (solution.attitude * mean_rate).z * dt_s;
        solution.bias_yaw_rad += (solution.attitude * solution.gyro_bias.bias_rad_per_s).z * dt_s;
        solution.previous_rate_rad_per_s = Some(compensated);
        // Linear growth: the gyro errors are correlated over a turn.
        let bias_sigma = solution.gyro_bias.sigma_rad_per_s().norm();
        let drift_rad = (bias_sigma + c.tilt_turn_pull * mean_rate.norm()) * dt_s;
        solution.heading_sigma_rad =
            (solution.heading_sigma_rad + drift_rad).min(std::f64::consts::PI);
        solution.tilt_sigma_rad =
            (solution.tilt_sigma_rad + bias_sigma * dt_s).min(std::f64::consts::FRAC_PI_2);

        // World frame (tilt.rs): the body turns under the window.
        let at_rest = V3::new(0.0, 0.0, -solution.static_gravity_mps2);
        solution
            .tilt_window
            .push(solution.attitude * force, at_rest);
        if solution.tilt_window.is_full()
            && let Some((measured, predicted)) = solution.tilt_window.older_means()
        {
            let residual = (measured - predicted).norm();
            let residual_rad = measured.angle(&predicted);
            // The accelerometer's own σ while moving: half the gate. A
            // tilt less sure than that widens the gate (two σ of the
            // residual) and takes the accelerometer faster.
            let accel_sigma = 0.5 * c.tilt_gate_rad;
            // The residual is the tilt's error plus what the vehicle's
            // acceleration turns the force by; beyond the accelerometer's
            // own noise, nothing tells the two apart (uncertainty.rs).
            solution.residual_sigma_rad =
                uncertainty::unexplained_residual_sigma(residual_rad, accel_sigma);
            // The reference's σ adds the acceleration the window shows
            // (uncertainty.rs); it sets how fast the tilt takes it and how
            // sure that leaves the tilt, not the gate (a steady
            // acceleration shows in neither, only in the residual).
            let reference_sigma = uncertainty::moving_reference_sigma(
                accel_sigma,
                measured.norm() - solution.static_gravity_mps2,
                solution.tilt_window.halves_apart_mps2(),
                solution.static_gravity_mps2,
            );
            let gate_rad =
                uncertainty::widened_gate(c.tilt_gate_rad, solution.tilt_sigma_rad, accel_sigma);
            let gate_mps2 =
                solution.static_gravity_mps2 * gate_rad.min(std::f64::consts::FRAC_PI_2).sin();
            let moving_weight = tilt::moving_weight(residual, gate_mps2);
            let boost = uncertainty::pull_boost(solution.tilt_sigma_rad, reference_sigma);
            let still = self.stillness(static_degree);
            let gain = still * dt_s / c.tilt_time_constant_s
                + ((1.0 - still) * moving_weight * dt_s / c.tilt_moving_time_constant_s * boost)
                    .min(1.0);
            // Only turns about a horizontal axis tilt the estimate (a
            // scale error in a turn about the vertical is heading's).
            let tilting_rate = (solution.attitude * mean_rate).xy().norm();
            let turn_gain = tilt::turn_gain(
                &measured,
                &predicted,
                c.tilt_turn_pull * tilting_rate * dt_s,
            );
            let gain = gain.max((1.0 - still) * turn_gain).min(1.0);
            // While moving, a residual the pull keeps taking out is the
            // gyro bias's (bias_feedback.rs); one that persists beyond
            // what a vehicle's acceleration explains calls the bias into
            // doubt (bias_doubt.rs).
            if let Some(axis) = nalgebra::Unit::try_new(measured.cross(&predicted), 1e-12) {
                let residual = axis.into_inner() * residual_rad;
                let pull_gain = moving_weight * dt_s / c.tilt_moving_time_constant_s;
                // Linear in the acceleration (the bound is on its mean):
                // the horizontal force over g, not the residual's angle.
                let horizontal = V3::new(measured.x, measured.y, 0.0)
                    / solution.static_gravity_mps2.max(f64::EPSILON);
                if let Some(doubt) = solution.bias_doubt.observe(
                    &horizontal,
                    1.0 - still,
                    dt_s,
                    c.top_speed_mps,
                    c.tilt_moving_time_constant_s,
                    &solution.gyro_bias.variance,
                ) {
                    solution.gyro_bias.variance = solution
                        .gyro_bias
                        .variance
                        .map(|p| p.max(doubt.bias_variance));
                    solution.tilt_sigma_rad = solution
                        .tilt_sigma_rad
                        .max(doubt.tilt_off_rad)
                        .min(std::f64::consts::FRAC_PI_2);
                }
                // In doubt, the loop's integral follows the boosted pull
                // (critically damped with it): a bias learnt within
                // seconds, not minutes. The residual comes most of a
                // window late, so the loop's time constant is kept at four
                // windows or more (or the unboosted pull's, if shorter).
                let loop_gain = if solution.bias_doubt.doubted() {
                    (pull_gain * boost).min(pull_gain.max(0.25 / c.window_samples as f64))
                } else {
                    pull_gain
                };
                solution.gyro_bias.bias_rad_per_s += bias_feedback::bias_step(
                    &solution.attitude,
                    &residual,
                    loop_gain,
                    dt_s,
                    1.0 - still,
                    &solution.gyro_bias.variance,
                    accel_sigma,
                );
                // Once in doubt, what the pulls learn of the bias makes it
                // surer again (before, P is the rest's and left alone).
                if solution.bias_doubt.doubted() {
                    solution.gyro_bias.variance = bias_feedback::variance_after(
                        &solution.attitude,
                        &solution.gyro_bias.variance,
                        pull_gain,
                        1.0 - still,
                        accel_sigma,
                        dt_s,
                    );
                }
            }
            solution.tilt_sigma_rad =
                uncertainty::sigma_after_pull(solution.tilt_sigma_rad, reference_sigma, gain);
            solution.attitude =
                tilt::correct_world(&solution.attitude, &measured, &predicted, gain);
        }

        let weight = self.stillness(static_degree);
        let gyro_floor = self.floor.gyro.level().unwrap_or(0.0);
        // Per-axis noise variance: the floor is a norm over three axes.
        let white_variance = (gyro_floor * gyro_floor / 3.0).max(MIN_FLOOR * MIN_FLOOR);
        if let Some(block) =
            solution
                .rest_rate
                .push(&rate, weight, c.window_samples, white_variance)
        {
            solution
                .gyro_bias
                .update(&block.rate_rad_per_s, block.noise_variance, 1.0);
            // The rest has the bias: what the road said of it is old.
            solution.bias_doubt.restart();
        }
        if weight > 0.0 {
            let gain = (weight * dt_s / GRAVITY_TIME_CONSTANT_S).min(1.0);
            solution.static_gravity_mps2 += (force.norm() - solution.static_gravity_mps2) * gain;
        }
        solution
            .bias_walk
            .observe(t, weight >= SPELL_STILLNESS, &solution.gyro_bias);
        solution
    }

    /// How static a reading counts for the references and the bias: 0 up
    /// to `static_threshold` (the `uncertain` rule alone gives 0.5, below
    /// it: what the expert is unsure of is treated as motion), rising to 1
    /// at a static degree of 1.
    fn stillness(&self, static_degree: f64) -> f64 {
        let threshold = self.config.static_threshold;
        if threshold < 1.0 {
            ((static_degree - threshold) / (1.0 - threshold)).clamp(0.0, 1.0)
        } else if static_degree >= 1.0 {
            1.0
        } else {
            0.0
        }
    }

    /// Pulls the heading towards a fresh, undisturbed compass whose
    /// heading is within the gate of the gyro-carried one (or has been
    /// outside it for `heading_gate_s`); the first calibration takes the
    /// compass whole.
    fn steer_heading(&mut self, solution: &mut Solution, t: f64, dt_s: f64, static_degree: f64) {
        let c = &self.config;
        let Some(heading) = self.fresh_compass(t) else {
            return;
        };
        // The compass's own σ: half the gate.
        let compass_sigma = 0.5 * c.heading_gate_rad;
        // The first calibration's heading is not taken from a field not
        // yet confirmed (disturbance.rs: relearnt).
        if self.reheading && self.disturbance.relearnt() {
            return;
        }
        let gain = if self.reheading {
            self.reheading = false;
            self.compass_gated_since = None;
            self.innovations.clear();
            let (_, _, yaw) = solution.attitude.euler_angles();
            self.rehead_turn = Some(Rehead {
                t,
                turn_rad: orientation::angle_difference(heading, yaw),
            });
            1.0
        } else {
            let (_, _, yaw) = solution.attitude.euler_angles();
            let signed_innovation = orientation::angle_difference(heading, yaw);
            let innovation = signed_innovation.abs();
            // Two σ of the innovation, at least the gate.
            let gate = |sigma_rad: f64| {
                uncertainty::widened_gate(c.heading_gate_rad, sigma_rad, compass_sigma)
            };
            // Once per compass reading (this runs at the IMU's rate).
            if let Some((compass_t, _)) = self.compass {
                self.innovations.push(compass_t, signed_innovation, yaw);
            }
            // Refused, but the disagreement grew from agreement along a
            // line the compass's own noise fits: the gyro's bias has
            // walked (heading_drift.rs). Its rate r on the world vertical
            // joins the bias variance, and the heading error it carried
            // over the span the heading's σ.
            let calibrated = self.calibration.correction().is_some();
            if innovation > gate(solution.heading_sigma_rad)
                && calibrated
                && let Some(ramp) = self.innovations.ramp()
                && ramp.turned_rad <= heading_drift::MAX_TURN_RAD
                && ramp.residual_rad <= compass_sigma
                && ramp.start_rad.abs() <= gate(solution.heading_sigma_rad)
                && (ramp.rate_rad_per_s * ramp.span_s).abs() >= c.heading_gate_rad
            {
                let vertical = solution.attitude.inverse() * V3::z();
                solution.gyro_bias.variance +=
                    vertical.component_mul(&vertical) * ramp.rate_rad_per_s.powi(2);
                solution.heading_sigma_rad = solution
                    .heading_sigma_rad
                    .hypot(ramp.rate_rad_per_s * ramp.span_s)
                    .min(std::f64::consts::PI);
                self.stats.heading_drifts += 1;
                self.innovations.clear();
            }
            let gate = gate(solution.heading_sigma_rad);
            let within_gate = innovation <= gate;
            if within_gate {
                self.compass_gated_since = None;
            } else {
                self.compass_gated_since.get_or_insert(t);
                // Gated for `heading_gate_s`, and for good while the field
                // is a relearnt one not yet confirmed (a magnet left on
                // the vehicle never wins against the gyro).
                if self.gated_now(t) {
                    return;
                }
                // A calibrated compass believed again against the gyro:
                // either was wrong by the innovation (an uncalibrated
                // one's σ is the unknown hard iron's already).
                if calibrated {
                    solution.heading_sigma_rad = solution.heading_sigma_rad.max(0.5 * innovation);
                    self.reacquired = true;
                }
            }
            let still = self.stillness(static_degree);
            let gain = still * dt_s / c.heading_time_constant_s
                + (1.0 - still) * dt_s / c.heading_moving_time_constant_s;
            // A heading less sure than the compass is pulled harder.
            let gain = (gain * uncertainty::pull_boost(solution.heading_sigma_rad, compass_sigma))
                .min(1.0);
            // While moving, a heading residual the pull keeps taking out is
            // the vertical gyro bias's (bias_feedback.rs): only from a
            // calibrated compass within the gate (an uncalibrated one's
            // heading is off by its unknown hard iron, and one believed
            // again after disagreeing says the heading was wrong, not the
            // bias).
            if innovation <= c.heading_gate_rad {
                self.reacquired = false;
            }
            let moving = if calibrated && within_gate && !self.reacquired {
                1.0 - still
            } else {
                0.0
            };
            let residual = V3::new(0.0, 0.0, signed_innovation);
            solution.gyro_bias.bias_rad_per_s += bias_feedback::bias_step(
                &solution.attitude,
                &residual,
                dt_s / c.heading_moving_time_constant_s,
                dt_s,
                moving,
                &solution.gyro_bias.variance,
                compass_sigma,
            );
            gain
        };
        solution.heading_sigma_rad =
            uncertainty::sigma_after_pull(solution.heading_sigma_rad, compass_sigma, gain);
        solution.attitude = pull_heading(&solution.attitude, heading, gain);
        self.carried_deflection_rad =
            (1.0 - gain) * self.carried_deflection_rad + gain * self.off_site_deflection_rad();
        self.heading_uncalibrated &= gain <= 0.0;
    }

    /// An alignment took the heading from the compass: it rests on the
    /// calibration and carries the deflection the field may cause now.
    fn heading_taken_from_compass(&mut self) {
        self.carried_deflection_rad = self.off_site_deflection_rad();
        self.heading_uncalibrated = false;
    }

    /// How far the compass's field may deflect its heading now, rad
    /// (disturbance.rs: its dip against the site's).
    fn off_site_deflection_rad(&self) -> f64 {
        self.disturbance
            .off_site_deflection_rad(self.config.mag_disturbance.dip_rad)
    }

    /// The tilt's 1σ as the gyros carry it, rad: its own σ and the
    /// accelerometer bias levelling cannot see, without the accelerometer
    /// residual's share (the rest monitor tests the carried tilt against
    /// the accelerometer at rest, that very residual).
    fn carried_tilt_sigma(&self, s: &Solution) -> f64 {
        uncertainty::reported_sigma(s.tilt_sigma_rad, &[self.config.accel_bias_tilt_rad])
    }

    /// The tilt's and the heading's reported 1σ, rad (uncertainty.rs):
    /// the engine's own σ and what no averaging removes: for tilt, the
    /// carried σ and what the accelerometer residual leaves unexplained
    /// (`residual_sigma_rad`); for heading, the calibration's residual
    /// (its relative radius RMS, `fit_rms`, is about the heading error it
    /// leaves, in rad; before a calibration the compass's hard iron is
    /// unknown and so is the heading) and the tilt's error turned into
    /// heading by the tilt compensation, |tan I|·σ_tilt.
    fn reported_sigmas(&self, s: &Solution, fit_rms: Option<f64>) -> (f64, f64) {
        let tilt = self
            .carried_tilt_sigma(s)
            .hypot(s.residual_sigma_rad)
            .min(uncertainty::UNKNOWN_ANGLE_SIGMA_RAD);
        // A calibration is as sure as its residual, or as the turns show
        // (turn_check.rs) if they show it worse.
        let calibration = fit_rms
            .filter(|_| !self.heading_uncalibrated)
            .map_or(uncertainty::UNKNOWN_ANGLE_SIGMA_RAD, |rms| {
                self.turns.sigma_rad().map_or(rms, |turns| turns.max(rms))
            });
        // What compasses whose field was not the Earth's alone turned the
        // heading by (`carried_deflection_rad`).
        let off_site = self.carried_deflection_rad;
        let through_tilt = self.config.mag_inclination_rad.tan().abs() * tilt;
        let heading = uncertainty::reported_sigma(
            s.heading_sigma_rad,
            &[calibration, through_tilt, off_site],
        );
        (tilt, heading)
    }

    fn estimate(&self, t: f64, static_degree: f64, signals: &MotionSignals) -> EngineOutput {
        let (attitude, bias, sigma, aligned) = match &self.solution {
            Some(s) => (
                s.attitude,
                s.gyro_bias.bias_rad_per_s,
                Some(s.gyro_bias.sigma_rad_per_s()),
                Some(s),
            ),
            None => {
                let (roll, pitch) = tilt_from_accel(&self.window.mean_force());
                let yaw = self.any_compass_heading(t, roll, pitch).unwrap_or(0.0);
                (
                    attitude_from_euler(roll, pitch, yaw),
                    V3::zeros(),
                    None,
                    None,
                )
            }
        };
        let correction = self.calibration.correction();
        let (tilt_sigma_deg, heading_sigma_deg) = match aligned {
            Some(s) => {
                let (tilt, heading) = self.reported_sigmas(s, correction.map(|c| c.fit_rms));
                (Some(deg(tilt)), Some(deg(heading)))
            }
            None => (None, None),
        };
        let aligned = aligned.is_some();
        let (roll, pitch, yaw) = attitude.euler_angles();
        EngineOutput {
            t,
            values: EstimateValues::Fuzzy(FuzzyEstimate {
                motion: if static_degree >= self.config.static_threshold {
                    Motion::Static
                } else {
                    Motion::Moving
                },
                static_degree,
                pitch_deg: deg(pitch),
                roll_deg: deg(roll),
                heading_deg: deg(yaw).rem_euclid(360.0),
                pitch_sigma_deg: tilt_sigma_deg,
                roll_sigma_deg: tilt_sigma_deg,
                heading_sigma_deg,
                gyro_bias_dps: [deg(bias.x), deg(bias.y), deg(bias.z)],
                aligned,
                mag_calibration: self.calibration.state(),
                mag_coverage_deg: self.calibration.coverage_deg(),
                mag_fit_rms: correction.map(|c| c.fit_rms),
                mag_heading_deg: self.fresh_compass(t).map(|h| deg(h).rem_euclid(360.0)),
                accel_dev_mps2: signals.accel_dev_mps2,
                accel_activity_mps2: signals.accel_activity_mps2,
                gyro_activity_dps: deg(signals.gyro_activity_rad_per_s),
                gyro_bias_sigma_dps: sigma.map(|s| [deg(s.x), deg(s.y), deg(s.z)]),
                mag_disturbed: self.disturbance.disturbed() || self.gated_now(t),
                compass: self.compass_state.map(|(state, _)| state),
                compass_since: self.compass_state.map(|(_, since)| since),
            }),
            integrity: if !aligned {
                Integrity::lost(IntegrityReason::Unaligned)
            } else if self.tilt_monitor.disagrees() {
                Integrity::lost(IntegrityReason::TiltDisagrees)
            } else if self.tilt_monitor.unwatched() {
                Integrity::lost(IntegrityReason::Recovering)
            } else if self.tilt_monitor.recovering() {
                Integrity::degraded(IntegrityReason::Recovering)
            } else {
                Integrity::OK
            },
        }
    }
}

/// The magnetometer calibration and the learnt noise floors, as the model
/// endpoint reports them.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct FuzzyModelReport {
    /// Always `fuzzy`: tells this report from the `attitude` one.
    pub engine: super::EngineKind,
    pub mag_calibration: CalibrationState,
    /// Azimuth of the field seen so far, degrees (of 360).
    pub mag_coverage_deg: f64,
    /// The hard-iron offset subtracted from every reading, µT; `null`
    /// before a calibration.
    pub hard_iron_ut: Option<[f64; 3]>,
    /// The soft-iron matrix applied after it, rows.
    pub soft_iron: Option<[[f64; 3]; 3]>,
    /// RMS relative radius error of the calibration fit.
    pub fit_rms: Option<f64>,
    /// Fits refused by the plausibility gates.
    pub mag_fits_refused: u64,
    /// The noise floors learnt at rest: accelerometer m/s² (its spread),
    /// gyro °/s (its fast spread, fast_spread.rs).
    pub accel_noise_floor_mps2: Option<f64>,
    pub gyro_noise_floor_dps: Option<f64>,
    pub stats: FuzzyStats,
}

/// The `fuzzy` engine as the registry lists it.
pub struct Fuzzy;

impl EngineDescriptor for Fuzzy {
    const SUMMARY: &'static str = "MEMS IMU + compass: a fuzzy expert decides static or moving; tilt and compass while static, the gyro while moving";
    const SENSORS: &'static [SensorKind] = &[SensorKind::Imu, SensorKind::Magnetometer];
    const RETIRED: &'static [Retired] = RETIRED;
    type Params = FuzzyParams;
    type Engine = FuzzyEngine;
    type Estimate = FuzzyEstimate;
    type Model = FuzzyModelReport;

    fn create(params: Params) -> Result<FuzzyEngine, ParamError> {
        FuzzyEngine::new(params)
    }
    fn restore(snapshot: serde_json::Value) -> Result<FuzzyEngine, SnapshotError> {
        FuzzyEngine::restore(snapshot)
    }
}

impl Engine for FuzzyEngine {
    fn kind(&self) -> EngineKind {
        EngineKind::Fuzzy
    }

    fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        match &reading.data {
            SensorData::Imu {
                accel_mps2,
                gyro_dps,
            } => {
                let force = V3::from(*accel_mps2);
                let rate = V3::new(rad(gyro_dps[0]), rad(gyro_dps[1]), rad(gyro_dps[2]));
                self.feed_imu(reading.t, force, rate, out);
            }
            SensorData::Magnetometer { field_ut } => {
                self.feed_magnetometer(reading.t, V3::from(*field_ut));
            }
            _ => {}
        }
    }

    fn params(&self) -> &Params {
        &self.params
    }

    fn snapshot(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }

    fn model(&self) -> Option<EngineModel> {
        let correction = self.calibration.correction();
        let (accel_floor, gyro_floor) = self.noise_floors();
        Some(EngineModel::Fuzzy(FuzzyModelReport {
            engine: super::EngineKind::Fuzzy,
            mag_calibration: self.calibration.state(),
            mag_coverage_deg: self.calibration.coverage_deg(),
            hard_iron_ut: correction
                .map(|c| [c.hard_iron_ut.x, c.hard_iron_ut.y, c.hard_iron_ut.z]),
            soft_iron: correction.map(|c| {
                [0, 1, 2].map(|i| {
                    [
                        c.soft_iron[(i, 0)],
                        c.soft_iron[(i, 1)],
                        c.soft_iron[(i, 2)],
                    ]
                })
            }),
            fit_rms: correction.map(|c| c.fit_rms),
            mag_fits_refused: self.calibration.refused_fits(),
            accel_noise_floor_mps2: accel_floor,
            gyro_noise_floor_dps: gyro_floor.map(deg),
            stats: self.stats,
        }))
    }
}

#[cfg(test)]
mod tests;
