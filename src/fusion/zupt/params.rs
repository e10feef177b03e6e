//! The `zupt` engine's parameter table, its typed parameters and the
//! configuration in working units (SI, radians) the engine runs with.

use serde::{Deserialize, Serialize};

use super::detectors::{DetectorNoise, Signals};
use super::eskf::ProcessNoise;
use super::rest_check::RestCheckConfig;
use super::strapdown::Site;
use super::zero_velocity::{Adaptation, DetectorKind, PipelineConfig, Thresholds};
use crate::fusion::angles::rad;
use crate::fusion::geometry::normal_gravity_mps2;
use crate::fusion::params::{ParamError, Params, TypedParams, param_table};

/// Standard gravity, for µg and mg parameters.
const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;

param_table! {
    /// The `zupt` engine's parameters. Sensor defaults are the paper's Table 1
    /// FOG IMU (gyro bias stability 0.5 °/h, ARW ≤ 0.05 °/√h, accelerometer
    /// bias 1 mg); detector defaults are the paper's W = L = 100 and 3 s, with
    /// thresholds set on the simulated trolley runs (docs/engines/zupt.md: how to tune).
    pub struct ZuptParams in PARAMS {
        latitude_deg: f64 = real(
            30.0,
            -90.0,
            90.0,
            "deg",
            "site latitude (Earth rate, gravity)",
        ),
        initial_height_m: f64 = real(
            0.0,
            -11_000.0,
            9_000.0,
            "m",
            "ellipsoidal height of the start point (gravity)",
        ),
        initial_yaw_deg: f64 = real(
            0.0,
            -360.0,
            360.0,
            "deg",
            "heading of the machine at the start, clockwise from north",
        ),
        initial_yaw_sigma_deg: f64 = real(
            0.5,
            0.0,
            180.0,
            "deg",
            "uncertainty of initial_yaw_deg",
        ),
        detector: DetectorKind = choice(
            DetectorKind::Tczvd,
            "zero-velocity test: MV ∧ ARE ∧ SHOE, one test alone, or none (pure INS)",
        ),
        detector_signals: Signals = choice(
            Signals::Integrated,
            "what MV, ARE and SHOE test: the velocity and angle each window integrates to (steady machinery vibration hardly counts), or the raw samples (the paper)",
        ),
        window_samples: usize = integer(
            100,
            1,
            10_000,
            "W: samples in each detector window, centred on the sample decided",
        ),
        median_samples: usize = integer(
            100,
            1,
            10_000,
            "L: length of the binary median filter over the test decisions (1: off)",
        ),
        min_zv_s: f64 = real(
            3.0,
            0.0,
            60.0,
            "s",
            "shortest zero-velocity run kept",
        ),
        threshold_adapt: bool = flag(
            true,
            "thresholds follow each statistic's learned rest level (a machine whose pumps run while it stands has a higher floor); false: fixed γ",
        ),
        rest_level_factor: f64 = real(
            4.0,
            1.0,
            1000.0,
            "",
            "κ: a test's threshold is at least κ × its statistic's learned rest level (the level a twentieth of the samples fall below)",
        ),
        threshold_max_factor: f64 = real(
            5.0,
            1.0,
            1000.0,
            "",
            "m: a learned threshold is at most m × its configured γ, so motion that never stops cannot become the rest level",
        ),
        rest_level_rise_s: f64 = real(
            180.0,
            1.0,
            86_400.0,
            "s",
            "τ: while every sample is above it the rest level rises by e in this long (it falls twenty times as fast)",
        ),
        sigma_accel_mps2: f64 = real(
            0.005,
            1.0e-6,
            10.0,
            "m/s²",
            "σ_a normalising MV, SHOE and MAG: accelerometer noise per sample",
        ),
        sigma_gyro_dps: f64 = real(
            0.01,
            1.0e-6,
            10.0,
            "deg/s",
            "σ_g normalising ARE and SHOE: gyro noise per sample",
        ),
        threshold_mv: f64 = real(
            6.0,
            0.0,
            1.0e9,
            "",
            "γ of MV (at rest MV ≈ 3 when σ_a is the true noise)",
        ),
        threshold_are: f64 = real(
            6.0,
            0.0,
            1.0e9,
            "",
            "γ of ARE (at rest ≈ 3 · (true σ / σ_g)²)",
        ),
        threshold_shoe: f64 = real(
            20.0,
            0.0,
            1.0e9,
            "",
            "γ of SHOE (at rest ≈ MV + ARE + (‖f‖ − g)²/σ_a², the last from accelerometer bias)",
        ),
        threshold_mag: f64 = real(
            12.0,
            0.0,
            1.0e9,
            "",
            "γ of MAG (at rest ≈ 1 + (‖f‖ − g)²/σ_a²)",
        ),
        gyro_arw_deg_per_sqrt_h: f64 = real(
            0.05,
            1.0e-6,
            100.0,
            "deg/√h",
            "gyro angle random walk (filter process noise)",
        ),
        gyro_bias_sigma_deg_per_h: f64 = real(
            2.0,
            0.0,
            1.0e5,
            "deg/h",
            "initial uncertainty of each gyro bias (run-to-run, wider than the datasheet's bias stability: a prior too tight makes the rest updates turn the heading instead of learning the bias)",
        ),
        gyro_bias_rw_deg_per_h_per_sqrt_h: f64 = real(
            0.05,
            0.0,
            1.0e5,
            "deg/h/√h",
            "random walk of the gyro biases",
        ),
        accel_vrw_ug_per_sqrt_hz: f64 = real(
            50.0,
            1.0e-3,
            1.0e6,
            "µg/√Hz",
            "accelerometer white noise (velocity random walk)",
        ),
        accel_bias_sigma_mg: f64 = real(
            1.0,
            0.0,
            1.0e4,
            "mg",
            "initial uncertainty of each accelerometer bias",
        ),
        accel_bias_rw_ug_per_sqrt_s: f64 = real(
            1.0,
            0.0,
            1.0e6,
            "µg/√s",
            "random walk of the accelerometer biases",
        ),
        filter_period_s: f64 = real(
            0.1,
            0.001,
            10.0,
            "s",
            "how often the covariance is propagated and the updates are made",
        ),
        zupt_sigma_mps: f64 = real(
            0.002,
            1.0e-6,
            10.0,
            "m/s",
            "noise of the zero-velocity pseudo-measurement",
        ),
        rest_check: bool = flag(
            true,
            "judge each run of rest the detector calls, once at its start, on the velocity the INS integrated since the previous run; veto readings the odometer saw advance, and accept a refused run once the odometer stood for a whole odometer_rest_window_s (rest_check.rs); false: every called rest is a zero-velocity update (the paper)",
        ),
        rest_gate_chi2: f64 = real(
            16.27,
            1.0,
            1.0e6,
            "",
            "a run of rest is refused when the velocity booked at its start is further than this squared Mahalanobis distance from standing (χ², 3 degrees of freedom: 16.27 refuses 0.1 % of true rests)",
        ),
        rest_speed_change: f64 = real(
            0.3,
            0.0,
            10.0,
            "",
            "how much a machine's speed may change unseen within a push, as a share of it, for the rest check's \"still moving\" prediction",
        ),
        rest_motion_evidence: f64 = real(
            3.0,
            0.0,
            1000.0,
            "",
            "after a refused run, the next is refused when the log-likelihood ratio of \"still moving as booked\" over \"standing\" exceeds this (3: twenty to one)",
        ),
        max_speed_mps: f64 = real(
            0.15,
            0.001,
            100.0,
            "m/s",
            "the fastest the machine advances: the rest check books motion only along the machine's axis and up to this speed (a velocity beyond, an INS gone wrong, leaves the call to the detector); a rest no odometer confirms may hide a creep this fast, and the position σ along the axis grows by it; an INS faster than this by 3σ has run away: its estimate is lost (speed_implausible) and its advance joins that σ",
        ),
        odometer_rest_m: f64 = real(
            0.006,
            0.0,
            100.0,
            "m",
            "a called rest is refused while the odometer advanced more than this over odometer_rest_window_s",
        ),
        odometer_rest_window_s: f64 = real(
            10.0,
            1.0,
            600.0,
            "s",
            "the window of odometer_rest_m: a veto counts from the start of the detector's current rest at the earliest; a confirmation needs the whole window",
        ),
        zaru: bool = flag(
            true,
            "zero-angular-rate update at every rest: the gyros read the Earth's rotation there, so their biases (heading drift) are estimated",
        ),
        zaru_sigma_deg_per_h: f64 = real(
            0.05,
            0.0,
            100_000.0,
            "deg/h",
            "rotation a standing machine may still have (settling), added to the noise of each rest's mean rate (the larger of the ARW's and the one estimated from the rates)",
        ),
        smooth_pushes: bool = flag(
            true,
            "smooth each completed push over both of its still ends (Rauch–Tung–Striebel) and publish its track as `smoothed_push`",
        ),
        smooth_max_push_s: f64 = real(
            300.0,
            1.0,
            7200.0,
            "s",
            "longer pushes are not smoothed (the record of a push, kept in the engine's snapshot, grows by about 7 kB a second)",
        ),
        level_sigma_m: f64 = real(
            0.002,
            1.0e-6,
            100.0,
            "m",
            "noise of a level-instrument height",
        ),
        aid_gate_sigma: f64 = real(
            6.0,
            0.0,
            1.0e6,
            "",
            "a level height, odometer count or push scale further than this many σ from the prediction is refused, and an odometer interval counting more or less than the INS advanced by this many σ is a slip (0: no gate)",
        ),
        odometer_aiding: bool = flag(
            true,
            "fuse the odometer: its count since the first after alignment against the estimated scale times the engine's advance (position and velocity), zero speed across its axis, and the scale from each push between two rests it confirms; off: the odometer only vetoes and confirms rests (rest_check) and is shown",
        ),
        odometer_sigma_mps: f64 = real(
            0.005,
            1.0e-6,
            10.0,
            "m/s",
            "noise of the zero speed across the odometer's axis (the machine moves along it)",
        ),
        odometer_distance_sigma_m: f64 = real(
            0.002,
            1.0e-6,
            10.0,
            "m",
            "noise of an odometer's count: each count is compared, times the estimated scale, with the engine's advance since the first count after alignment; an interval counting more than aid_gate_sigma of its σ beyond the INS's advance is a slip, not fused",
        ),
        odometer_scale_sigma_pct: f64 = real(
            5.0,
            0.0,
            50.0,
            "%",
            "1σ of the odometer's scale (calibration) error before the drive: the filter estimates the scale from the zero-velocity-bounded INS (odometer_scale in the estimate) and starts from this",
        ),
        odometer_axis_sigma_deg: f64 = real(
            0.1,
            0.0,
            10.0,
            "deg",
            "1σ of the angles between the odometer's axis (the way the machine moves) and the IMU's x axis, toward its y and z, before the drive: estimated by the filter like the scale",
        ),
        max_imu_gap_s: f64 = real(
            0.5,
            0.001,
            3600.0,
            "s",
            "longer gaps between IMU readings end a stream (no integration across)",
        ),
    }
}

/// The engine's parameters in working units (SI, radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ZuptConfig {
    pub site: Site,
    pub initial_yaw_rad: f64,
    pub initial_yaw_sigma_rad: f64,
    pub pipeline: PipelineConfig,
    pub process_noise: ProcessNoise,
    pub gyro_bias_sigma_rad_per_s: f64,
    pub accel_bias_sigma_mps2: f64,
    pub filter_period_s: f64,
    pub zupt_sigma_mps: f64,
    /// The check of called rests; `None`: off (the paper).
    pub rest_check: Option<RestCheckConfig>,
    /// The odometer's window (`odometer_rest_m` over
    /// `odometer_rest_window_s`), which confirms a rest whether or not
    /// the check is on: the creep bound and the scale's push measurements
    /// need it.
    pub odometer_window: RestCheckConfig,
    /// Zero-angular-rate updates at rest, and the settling rate allowed, rad/s.
    pub zaru: bool,
    pub zaru_sigma_rad_per_s: f64,
    /// Smoothing of completed pushes, and the longest push smoothed, s.
    pub smooth_pushes: bool,
    pub smooth_max_push_s: f64,
    pub level_sigma_m: f64,
    pub aid_gate_sigma: f64,
    pub odometer_aiding: bool,
    pub odometer_sigma_mps: f64,
    pub odometer_distance_sigma_m: f64,
    /// 1σ of the odometer's scale error before the drive, a fraction,
    /// and of its axis's angles to the IMU's x, rad.
    pub odometer_scale_sigma: f64,
    pub odometer_axis_sigma_rad: f64,
    /// The fastest the machine advances, m/s: what a rest no odometer
    /// confirms may hide.
    pub max_speed_mps: f64,
    pub max_imu_gap_s: f64,
}

/// °/h to rad/s.
fn rad_per_s_from_deg_per_h(x: f64) -> f64 {
    rad(x) / 3600.0
}

impl ZuptConfig {
    /// Converts validated parameters; degrees become radians here.
    pub fn from_params(params: &Params) -> Result<ZuptConfig, ParamError> {
        Ok(ZuptConfig::new(&ZuptParams::from_params(params)?))
    }

    /// The working configuration of typed parameters.
    pub fn new(p: &ZuptParams) -> ZuptConfig {
        let site = Site {
            lat_rad: rad(p.latitude_deg),
            height_m: p.initial_height_m,
        };
        let odometer_window = RestCheckConfig {
            gate_chi2: p.rest_gate_chi2,
            odometer_advance_m: p.odometer_rest_m,
            odometer_window_s: p.odometer_rest_window_s,
            speed_change: p.rest_speed_change,
            motion_evidence: p.rest_motion_evidence,
            max_speed_mps: p.max_speed_mps,
            zupt_variance_mps2: p.zupt_sigma_mps.powi(2),
        };
        ZuptConfig {
            site,
            initial_yaw_rad: rad(p.initial_yaw_deg),
            initial_yaw_sigma_rad: rad(p.initial_yaw_sigma_deg),
            pipeline: PipelineConfig {
                detector: p.detector,
                thresholds: Thresholds {
                    mv: p.threshold_mv,
                    are: p.threshold_are,
                    shoe: p.threshold_shoe,
                    mag: p.threshold_mag,
                },
                noise: DetectorNoise {
                    sigma_accel_mps2: p.sigma_accel_mps2,
                    sigma_gyro_rad_per_s: rad(p.sigma_gyro_dps),
                    gravity_mps2: normal_gravity_mps2(site.lat_rad, site.height_m),
                },
                signals: p.detector_signals,
                adaptation: p.threshold_adapt.then_some(Adaptation {
                    rest_level_factor: p.rest_level_factor,
                    max_factor: p.threshold_max_factor,
                    rise_s: p.rest_level_rise_s,
                }),
                window_samples: p.window_samples,
                median_samples: p.median_samples,
                min_run_s: p.min_zv_s,
            },
            process_noise: ProcessNoise {
                // °/√h → rad/√s; µg/√Hz → (m/s²)/√Hz = (m/s)/√s.
                gyro_arw: rad(p.gyro_arw_deg_per_sqrt_h) / 60.0,
                gyro_bias_rw: rad_per_s_from_deg_per_h(p.gyro_bias_rw_deg_per_h_per_sqrt_h) / 60.0,
                accel_vrw: p.accel_vrw_ug_per_sqrt_hz * 1e-6 * STANDARD_GRAVITY_MPS2,
                accel_bias_rw: p.accel_bias_rw_ug_per_sqrt_s * 1e-6 * STANDARD_GRAVITY_MPS2,
            },
            gyro_bias_sigma_rad_per_s: rad_per_s_from_deg_per_h(p.gyro_bias_sigma_deg_per_h),
            accel_bias_sigma_mps2: p.accel_bias_sigma_mg * 1e-3 * STANDARD_GRAVITY_MPS2,
            filter_period_s: p.filter_period_s,
            zupt_sigma_mps: p.zupt_sigma_mps,
            rest_check: p.rest_check.then_some(odometer_window),
            odometer_window,
            zaru: p.zaru,
            zaru_sigma_rad_per_s: rad_per_s_from_deg_per_h(p.zaru_sigma_deg_per_h),
            smooth_pushes: p.smooth_pushes,
            smooth_max_push_s: p.smooth_max_push_s,
            level_sigma_m: p.level_sigma_m,
            aid_gate_sigma: p.aid_gate_sigma,
            odometer_aiding: p.odometer_aiding,
            odometer_sigma_mps: p.odometer_sigma_mps,
            odometer_distance_sigma_m: p.odometer_distance_sigma_m,
            odometer_scale_sigma: p.odometer_scale_sigma_pct / 100.0,
            odometer_axis_sigma_rad: p.odometer_axis_sigma_deg.to_radians(),
            max_speed_mps: p.max_speed_mps,
            max_imu_gap_s: p.max_imu_gap_s,
        }
    }
}
