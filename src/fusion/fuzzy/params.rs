//! The `fuzzy` engine's parameter table, its typed parameters and the
//! configuration in working units (SI, radians) the engine runs with.

use serde::{Deserialize, Serialize};

use super::disturbance::Tolerances;
use super::motion::{Breakpoints, MotionConfig};
use super::rolling::RollingConfig;
use crate::fusion::angles::rad;
use crate::fusion::params::{ParamError, Params, Retired, TypedParams, param_table};

param_table! {
    /// The `fuzzy` engine's parameters. No threshold is in sensor units: the
    /// expert's breakpoints are multiples of the noise floor learnt at rest
    /// (docs/engines/fuzzy.md: how to tune).
    pub struct FuzzyParams in PARAMS {
        declination_deg: f64 = real(
            0.0,
            -180.0,
            180.0,
            "deg",
            "magnetic declination, east positive: true heading = magnetic + declination",
        ),
        window_samples: usize = integer(
            50,
            2,
            10_000,
            "IMU readings in the motion expert's trailing window (about half a second)",
        ),
        accel_dev_still_factor: f64 = real(
            1.5,
            0.0,
            1000.0,
            "× floor",
            "|mean ‖f‖ − g| below this many accelerometer floors is fully `low`",
        ),
        accel_dev_moving_factor: f64 = real(
            8.0,
            0.0,
            1000.0,
            "× floor",
            "|mean ‖f‖ − g| above this many accelerometer floors is fully `high`",
        ),
        accel_activity_still_factor: f64 = real(
            2.0,
            0.0,
            1000.0,
            "× floor",
            "specific-force spread below this many accelerometer floors is fully `low`",
        ),
        accel_activity_moving_factor: f64 = real(
            10.0,
            0.0,
            1000.0,
            "× floor",
            "specific-force spread above this many accelerometer floors is fully `high`",
        ),
        gyro_activity_still_factor: f64 = real(
            1.6,
            0.0,
            1000.0,
            "× floor",
            "gyro activity (fast rate spread ⊕ mean rate beyond the bias's tolerance) below this many gyro floors is fully `low`",
        ),
        gyro_activity_moving_factor: f64 = real(
            3.0,
            0.0,
            1000.0,
            "× floor",
            "gyro activity (fast rate spread ⊕ mean rate beyond the bias's tolerance) above this many gyro floors is fully `high`",
        ),
        noise_floor_rise_s: f64 = real(
            300.0,
            1.0,
            1.0e6,
            "s",
            "the learnt noise floors rise e-fold in this time of louder windows (and fall 99× faster)",
        ),
        defuzzification_points: usize = integer(
            201,
            2,
            100_001,
            "centroid discretisation: points over the output range [−0.5, 1.5], ends included",
        ),
        static_threshold: f64 = real(
            0.55,
            0.0,
            1.0,
            "",
            "`motion` is static from this static degree up; bias learning starts above it",
        ),
        rolling_start_s: f64 = real(
            1.0,
            0.1,
            60.0,
            "s",
            "`moving` without a break for this long means the vehicle is rolling until it stops (rolling.rs)",
        ),
        stop_speed_mps: f64 = real(
            0.25,
            0.01,
            10.0,
            "m/s",
            "the speed a roll's start must gain to give its direction, and a deceleration before a quiet must take off along it to stop rolling (rolling.rs)",
        ),
        stop_settle_s: f64 = real(
            10.0,
            1.0,
            600.0,
            "s",
            "no input of the motion expert fully `high` for this long stops rolling without a deceleration (rolling.rs)",
        ),
        top_speed_mps: f64 = real(
            15.0,
            0.1,
            1000.0,
            "m/s",
            "the vehicle's top speed: a mean of its acceleration over a minute tilts the force by at most atan(2·this/(g·60 s)), and a tilt residual that persists beyond that calls the gyro bias into doubt (bias_doubt.rs)",
        ),
        tilt_time_constant_s: f64 = real(
            4.0,
            0.001,
            1.0e6,
            "s",
            "time constant of the pull towards the accelerometer tilt when fully static",
        ),
        tilt_moving_time_constant_s: f64 = real(
            10.0,
            0.001,
            1.0e6,
            "s",
            "time constant of the gated pull towards the accelerometer tilt while moving",
        ),
        tilt_gate_deg: f64 = real(
            3.0,
            0.0,
            90.0,
            "deg",
            "while moving, the accelerometer counts fully when it disagrees with the gyro tilt by less than this (g·sin), not at all beyond twice it",
        ),
        tilt_turn_pull: f64 = real(
            0.005,
            0.0,
            1.0,
            "",
            "while moving, the accelerometer turns the tilt by at least this fraction of the angle the gyros turn through about a horizontal axis (their scale and axis errors grow with it), whatever the gate",
        ),
        heading_time_constant_s: f64 = real(
            2.0,
            0.001,
            1.0e6,
            "s",
            "time constant of the pull towards the compass heading when fully static",
        ),
        heading_moving_time_constant_s: f64 = real(
            30.0,
            0.001,
            1.0e6,
            "s",
            "time constant of the pull towards the compass heading while moving",
        ),
        heading_gate_deg: f64 = real(
            4.0,
            0.0,
            180.0,
            "deg",
            "a compass heading further than this from the gyro-carried one is not used (a disturbance the field's magnitude and dip do not show)",
        ),
        heading_gate_s: f64 = real(
            60.0,
            0.0,
            1.0e6,
            "s",
            "a compass that disagrees beyond the gate for this long is believed again (the heading was wrong, not the compass)",
        ),
        gyro_bias_walk_dps_per_sqrt_s: f64 = real(
            0.005,
            0.0,
            10.0,
            "deg/s/√s",
            "random walk of the gyro bias between stops (its variance grows by the square of this per second) until the engine has learnt it from the bias changes between two long stops",
        ),
        mag_min_coverage_deg: f64 = real(
            300.0,
            10.0,
            360.0,
            "deg",
            "field azimuth that must be seen before the magnetometer is calibrated",
        ),
        mag_inclination_deg: f64 = real(
            60.0,
            -89.0,
            89.0,
            "deg",
            "inclination of the Earth's field at the site, down positive (sizes the vertical of a planar calibration; first dip reference)",
        ),
        mag_level_tolerance_deg: f64 = real(
            1.5,
            0.0,
            90.0,
            "deg",
            "magnetometer readings tilted less than this count as level (a planar calibration uses only those when they cover enough directions, otherwise every reading levelled by its tilt)",
        ),
        mag_refit_every: usize = integer(
            50,
            1,
            1_000_000,
            "refit the calibration every this many magnetometer readings",
        ),
        mag_disturbance_magnitude: f64 = real(
            0.06,
            0.0,
            10.0,
            "",
            "a calibrated field whose magnitude departs from the site's by more than this fraction is disturbed",
        ),
        mag_disturbance_dip_deg: f64 = real(
            4.0,
            0.0,
            90.0,
            "deg",
            "a calibrated field whose dip departs from the site's by more than this is disturbed",
        ),
        max_mag_age_s: f64 = real(
            1.0,
            0.0,
            3600.0,
            "s",
            "an older magnetometer reading gives no heading",
        ),
        align_without_rest_s: f64 = real(
            2.0,
            0.0,
            1.0e6,
            "s",
            "with no quiet window this long after the first reading, the engine aligns while moving: tilt from the mean force in the first reading's frame (held still by the gyros), heading from the compass, gyro bias unknown (σ gyro_bias_prior_dps) until a rest",
        ),
        gyro_bias_prior_dps: f64 = real(
            1.0,
            0.0,
            100.0,
            "deg/s",
            "the gyro's turn-on bias (1σ per axis, its data sheet's): the bias σ of an alignment made while moving",
        ),
        accel_bias_sigma_mps2: f64 = real(
            0.05,
            0.0,
            10.0,
            "m/s²",
            "the accelerometer's bias (1σ per axis, its data sheet's turn-on bias): levelling at rest cannot see it, so the tilt may be off by about this over g; only the reported σ carries it",
        ),
        max_imu_gap_s: f64 = real(
            0.5,
            0.001,
            3600.0,
            "s",
            "longer gaps between IMU readings are not integrated across; the window starts afresh",
        ),
    }
}

/// Parameters of earlier releases: a stored machine that has them loads
/// without them; a new declaration that names one is refused saying why.
pub const RETIRED: &[Retired] = &[
    Retired {
        name: "accel_dev_still_mps2",
        reason: "thresholds are now multiples of the noise floor learnt at rest: use accel_dev_still_factor",
    },
    Retired {
        name: "accel_dev_moving_mps2",
        reason: "thresholds are now multiples of the noise floor learnt at rest: use accel_dev_moving_factor",
    },
    Retired {
        name: "accel_activity_still_mps2",
        reason: "thresholds are now multiples of the noise floor learnt at rest: use accel_activity_still_factor",
    },
    Retired {
        name: "accel_activity_moving_mps2",
        reason: "thresholds are now multiples of the noise floor learnt at rest: use accel_activity_moving_factor",
    },
    Retired {
        name: "gyro_activity_still_dps",
        reason: "thresholds are now multiples of the noise floor learnt at rest: use gyro_activity_still_factor",
    },
    Retired {
        name: "gyro_activity_moving_dps",
        reason: "thresholds are now multiples of the noise floor learnt at rest: use gyro_activity_moving_factor",
    },
    Retired {
        name: "bias_time_constant_s",
        reason: "the gyro bias is now a Kalman filter of a random walk: use gyro_bias_walk_dps_per_sqrt_s",
    },
];

/// g, m/s²: what an accelerometer bias is compared with.
const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;

/// The engine's parameters in working units (SI, radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FuzzyConfig {
    pub declination_rad: f64,
    pub window_samples: usize,
    /// Breakpoints as multiples of the noise floors.
    pub motion: MotionConfig,
    pub floor_rise_s: f64,
    pub static_threshold: f64,
    /// Motion from events (rolling.rs).
    pub rolling: RollingConfig,
    pub tilt_time_constant_s: f64,
    pub tilt_moving_time_constant_s: f64,
    /// Fraction of the gyros' turn the tilt may always be pulled by while moving.
    pub tilt_turn_pull: f64,
    /// `tilt_gate_deg`, rad.
    pub tilt_gate_rad: f64,
    /// `top_speed_mps`, m/s (bias_doubt.rs: v_max).
    pub top_speed_mps: f64,
    pub heading_time_constant_s: f64,
    pub heading_moving_time_constant_s: f64,
    pub heading_gate_rad: f64,
    pub heading_gate_s: f64,
    /// q of the bias random walk, rad²/s³.
    pub bias_walk_density: f64,
    pub mag_min_coverage_deg: f64,
    pub mag_inclination_rad: f64,
    pub mag_level_tolerance_rad: f64,
    pub mag_refit_every: u32,
    pub mag_disturbance: Tolerances,
    pub max_mag_age_s: f64,
    /// The tilt an unseen accelerometer bias leaves, rad (1σ): bias / g.
    pub accel_bias_tilt_rad: f64,
    pub align_without_rest_s: f64,
    /// `gyro_bias_prior_dps`, rad/s.
    pub gyro_bias_prior_rad_per_s: f64,
    pub max_imu_gap_s: f64,
}

/// The breakpoints of one expert input, the `moving` one above `still`.
fn breakpoints(
    (still, still_value): (&str, f64),
    (moving, moving_value): (&str, f64),
) -> Result<Breakpoints, ParamError> {
    if still_value >= moving_value {
        return Err(ParamError::Inconsistent(format!(
            "{moving} ({moving_value}) must be above {still} ({still_value})"
        )));
    }
    Ok(Breakpoints {
        still: still_value,
        moving: moving_value,
    })
}

impl FuzzyConfig {
    /// Converts validated parameters; degrees become radians here.
    pub fn from_params(params: &Params) -> Result<FuzzyConfig, ParamError> {
        FuzzyConfig::new(&FuzzyParams::from_params(params)?)
    }

    /// The working configuration of typed parameters.
    pub fn new(p: &FuzzyParams) -> Result<FuzzyConfig, ParamError> {
        let walk = rad(p.gyro_bias_walk_dps_per_sqrt_s);
        Ok(FuzzyConfig {
            declination_rad: rad(p.declination_deg),
            window_samples: p.window_samples,
            motion: MotionConfig {
                accel_dev: breakpoints(
                    ("accel_dev_still_factor", p.accel_dev_still_factor),
                    ("accel_dev_moving_factor", p.accel_dev_moving_factor),
                )?,
                accel_activity: breakpoints(
                    ("accel_activity_still_factor", p.accel_activity_still_factor),
                    (
                        "accel_activity_moving_factor",
                        p.accel_activity_moving_factor,
                    ),
                )?,
                gyro_activity: breakpoints(
                    ("gyro_activity_still_factor", p.gyro_activity_still_factor),
                    ("gyro_activity_moving_factor", p.gyro_activity_moving_factor),
                )?,
                resolution: p.defuzzification_points,
            },
            floor_rise_s: p.noise_floor_rise_s,
            static_threshold: p.static_threshold,
            rolling: RollingConfig {
                static_threshold: p.static_threshold,
                start_s: p.rolling_start_s,
                speed_mps: p.stop_speed_mps,
                settle_s: p.stop_settle_s,
            },
            tilt_time_constant_s: p.tilt_time_constant_s,
            tilt_moving_time_constant_s: p.tilt_moving_time_constant_s,
            tilt_turn_pull: p.tilt_turn_pull,
            tilt_gate_rad: rad(p.tilt_gate_deg),
            top_speed_mps: p.top_speed_mps,
            heading_time_constant_s: p.heading_time_constant_s,
            heading_moving_time_constant_s: p.heading_moving_time_constant_s,
            heading_gate_rad: rad(p.heading_gate_deg),
            heading_gate_s: p.heading_gate_s,
            bias_walk_density: walk * walk,
            mag_min_coverage_deg: p.mag_min_coverage_deg,
            mag_inclination_rad: rad(p.mag_inclination_deg),
            mag_level_tolerance_rad: rad(p.mag_level_tolerance_deg),
            mag_refit_every: p.mag_refit_every as u32,
            mag_disturbance: Tolerances {
                magnitude: p.mag_disturbance_magnitude,
                dip_rad: rad(p.mag_disturbance_dip_deg),
            },
            max_mag_age_s: p.max_mag_age_s,
            accel_bias_tilt_rad: (p.accel_bias_sigma_mps2 / STANDARD_GRAVITY_MPS2).atan(),
            align_without_rest_s: p.align_without_rest_s,
            gyro_bias_prior_rad_per_s: rad(p.gyro_bias_prior_dps),
            max_imu_gap_s: p.max_imu_gap_s,
        })
    }
}
