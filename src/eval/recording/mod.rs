//! `eval recording`: the `fuzzy` engine on recorded trials with optical
//! truth, in the shape of BROAD (Berlin Robust Orientation estimation
//! Assessment Dataset, Laidig et al. 2021, CC BY 4.0): a hand-held MEMS IMU
//! and magnetometer at 2000/7 ≈ 285.7 Hz, optical motion capture as truth.
//!
//! # Input
//! A directory made by `tools/broad_to_csv.py`: one CSV per trial with the
//! header `t_s,ax,ay,az,gx,gy,gz,mx,my,mz,qw,qx,qy,qz` (seconds; m/s², rad/s,
//! µT in the sensor's frame; truth quaternion `nan` where the cameras saw
//! nothing) and a `manifest.json` naming the trials with their rate and
//! the sample ranges BROAD scores (`movement`). Without a manifest every
//! `*.csv` is a trial, scored wherever it has truth.
//!
//! # Frames (verified on the data: `tests/recordings.rs`)
//! BROAD's sensor frame has z up (a flat sensor reads +9.8 m/s² on z) and
//! its truth is the sensor-to-ENU rotation, the ENU frame aligned to
//! magnetic north. Ours: body x forward, y right, z down; attitude
//! body-to-NED. So every sensor vector maps (x, y, z) → (x, −y, −z) (a half
//! turn about x, [`SENSOR_FROM_BODY`]), and the truth becomes
//! q_NED←body = q_NED←ENU ⊗ q_ENU←sensor ⊗ q_sensor←body, q_NED←ENU being
//! the half turn about (1, 1, 0)/√2 that swaps east and north and flips up.
//!
//! # Scores (over the `movement` samples that have truth)
//! With the error in the Earth frame, q_e = q_est ⊗ q_true⁻¹ (BROAD's
//! `calculateErrorQuatEarth`):
//! - tilt ("inclination") error: the angle between the true and the
//!   estimated direction of gravity in the body, 2 acos √(w² + z²);
//! - heading error: q_e's turn about the vertical, 2 atan2(z, w), after
//!   removing the trial's constant heading offset δ between the reference
//!   frame and the estimator's north, δ the circular mean of that turn over
//!   the scored samples (the reference turned by δ about the vertical).
//!   BROAD's own code removes nothing (its reference is already aligned to
//!   magnetic north); that variant is kept as `heading_raw_deg`;
//! - total error: the whole angle of q_e, 2 acos |w|, after (and, `raw`,
//!   before) the same offset removal.
//!
//! Each trial gives RMSEs; pooled figures are their mean over trials
//! (BROAD's averaging, and the independent evaluation's) and their RMS
//! over trials.
//!
//! # Estimators
//! - the `fuzzy` engine, fed each sample's magnetometer reading and then
//!   its IMU reading (t = [`EPOCH_T_S`] + t_s), attitude rebuilt from the
//!   estimate's roll, pitch and heading;
//! - gyro only: the gyros integrated (q ← q ⊗ exp(ω̄ dt), ω̄ the mean of
//!   the step's two samples) from the true attitude at the first sample
//!   with truth, raw and with the mean rate of the initial rest (before the
//!   first movement sample) subtracted;
//! - accelerometer + compass per sample, no memory: tilt from the specific
//!   force, heading from the raw (uncalibrated: BROAD's field is already
//!   calibrated) magnetometer levelled with that tilt. What a static
//!   solution gives while the sensor moves;
//! - Madgwick's MARG filter ([`crate::eval::ahrs::Madgwick`]) started, as
//!   BROAD starts it, from the first sample's accelerometer and
//!   magnetometer, over a grid of β ([`MADGWICK_BETAS`]): reported at the
//!   common default β = 0.041 rad/s and at the β with the lowest mean raw
//!   total error over the trials (BROAD's criterion for its "TAGP"; tuned
//!   with the truth: a bound, not a setting a user could know).
//! - VQF ([`crate::eval::ahrs::Vqf`], issue 55) with its defaults, its
//!   filters set for the trial's rate, from the first sample: the best
//!   open filter.

mod baselines;
mod evaluate;
mod frames;
mod load;
mod report;
mod score;

pub use baselines::*;
pub use evaluate::*;
pub use frames::*;
pub use load::*;
pub use report::*;
pub use score::*;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::ErrorStats;
use super::ahrs::{Madgwick, Vqf, initial_attitude};
use crate::fusion::angles::{deg, rad};
use crate::fusion::fuzzy::{FuzzyEngine, FuzzyParams};
use crate::fusion::params::TypedParams;
use crate::fusion::{
    Engine, EngineKind, EngineOutput, FuzzyEstimate, Motion, ParamError, Params, Reading,
    SensorData,
};

type V3 = Vector3<f64>;

/// Readings carry t = `EPOCH_T_S` + the trial's seconds (2020-09-13), so
/// they are valid protocol times.
pub const EPOCH_T_S: f64 = 1_600_000_000.0;
/// Inclination of the Earth's field in Berlin (WMM: about 68°, down).
pub const BERLIN_INCLINATION_DEG: f64 = 68.0;
/// The motion expert's window, seconds (docs/engines/fuzzy.md: "keep the window at about
/// half a second").
pub const WINDOW_S: f64 = 0.5;
/// The CSV header.
pub const COLUMNS: [&str; 14] = [
    "t_s", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "qw", "qx", "qy", "qz",
];
/// A truth quaternion whose norm is further than this from 1 is refused.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "t_s,ax,ay,az,gx,gy,gz,mx,my,mz,qw,qx,qy,qz";

    fn parse(text: &str) -> Result<Vec<Sample>, RecordingError> {
        parse_csv(Path::new("trial.csv"), text)
    }

    #[test]
    fn a_flat_sensor_reads_our_level_body() {
        let text = format!(
            "{HEADER}\n0,0,0,9.81,0.1,0.2,0.3,20,0,-44,1,0,0,0\n0.01,0,0,9.81,0,0,0,20,0,-44,nan,nan,nan,nan\n"
        );
        let samples = parse(&text).unwrap();
        assert_eq!(samples.len(), 2);
        let s = samples[0];
        assert_eq!(s.accel_mps2, V3::new(0.0, 0.0, -9.81));
        assert_eq!(s.gyro_rad_per_s, V3::new(0.1, -0.2, -0.3));
        assert_eq!(s.field_ut, V3::new(20.0, 0.0, 44.0));
        // Flat, x east in ENU: in NED the body points east (yaw 90°), level.
        let (roll, pitch, yaw) = s.truth.unwrap().euler_angles();
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12, "{roll} {pitch}");
        assert!((deg(yaw) - 90.0).abs() < 1e-9, "{}", deg(yaw));
        assert!(samples[1].truth.is_none());
    }

    #[test]
    fn truth_and_sensors_agree_for_any_attitude() {
        // A sensor at attitude q (sensor-to-ENU) reads the ENU "up" as
        // specific force and the ENU field in its own frame; mapped, both
        // must match our body-to-NED truth.
        let q_enu = UnitQuaternion::from_euler_angles(0.3, -0.7, 2.1);
        let up_sensor = q_enu.inverse() * V3::new(0.0, 0.0, 9.81);
        let field_enu = V3::new(0.5, 18.0, -42.0);
        let field_sensor = q_enu.inverse() * field_enu;
        let q = ned_attitude_from_broad(&q_enu);
        let force = body_from_sensor(&up_sensor);
        assert!((q * force - V3::new(0.0, 0.0, -9.81)).norm() < 1e-9);
        let field_ned = q * body_from_sensor(&field_sensor);
        assert!((field_ned - V3::new(18.0, 0.5, 42.0)).norm() < 1e-9);
    }

    #[test]
    fn accelerometer_and_compass_recover_an_attitude() {
        let q = UnitQuaternion::from_euler_angles(-0.4, 0.9, -2.5);
        let force = q.inverse() * V3::new(0.0, 0.0, -9.81);
        let field = q.inverse() * V3::new(18.0, 0.0, 42.0);
        assert!(accel_compass_attitude(&force, &field).angle_to(&q) < 1e-9);
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let bad_number = format!(
            "{HEADER}\n0,0,0,9.81,0,0,0,20,0,-44,1,0,0,0\n0.1,0,x,9.81,0,0,0,20,0,-44,1,0,0,0\n"
        );
        let message = parse(&bad_number).unwrap_err().to_string();
        assert_eq!(
            message,
            "trial.csv, line 3, column `ay`: `x` is not a number"
        );
        let short = format!("{HEADER}\n0,0,0,9.81,0,0,0,20,0,-44,1,0\n");
        let message = parse(&short).unwrap_err().to_string();
        assert!(
            message.contains("line 2") && message.contains("12 fields"),
            "{message}"
        );
        let nan_sensor = format!("{HEADER}\n0,0,0,9.81,nan,0,0,20,0,-44,1,0,0,0\n");
        let message = parse(&nan_sensor).unwrap_err().to_string();
        assert!(message.contains("column `gx`"), "{message}");
        let half_truth = format!("{HEADER}\n0,0,0,9.81,0,0,0,20,0,-44,1,0,nan,0\n");
        let message = parse(&half_truth).unwrap_err().to_string();
        assert!(message.contains("column `qy`"), "{message}");
        let backwards = format!(
            "{HEADER}\n1,0,0,9.81,0,0,0,20,0,-44,1,0,0,0\n0.5,0,0,9.81,0,0,0,20,0,-44,1,0,0,0\n"
        );
        let message = parse(&backwards).unwrap_err().to_string();
        assert!(message.contains("line 3, column `t_s`"), "{message}");
        let header = "t,ax\n0,1\n";
        let message = parse(header).unwrap_err().to_string();
        assert!(message.contains("line 1, column `header`"), "{message}");
        assert!(parse("").is_err());
        assert!(parse(&format!("{HEADER}\n")).is_err());
    }

    #[test]
    fn heading_offset_is_removed_and_tilt_kept() {
        // Estimates off by a constant 10° of heading plus a 2° tilt on half
        // the samples: heading error 0 once the offset goes, tilt 2° RMS √½.
        let mut series = ErrorSeries::default();
        for k in 0..100 {
            let truth = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.03 * f64::from(k));
            let tilt = if k % 2 == 0 { rad(2.0) } else { 0.0 };
            // Tilted about the Earth's north axis, turned about its vertical.
            let estimate = UnitQuaternion::from_axis_angle(&V3::z_axis(), rad(10.0))
                * UnitQuaternion::from_axis_angle(&V3::x_axis(), tilt)
                * truth;
            series.add(&estimate, &truth);
        }
        let e = series.summary();
        assert!((e.heading_offset_deg.unwrap() - 10.0).abs() < 1e-9, "{e:?}");
        assert!((e.tilt_deg - 2.0 / 2f64.sqrt()).abs() < 1e-9, "{e:?}");
        assert!(e.heading_deg < 1e-9, "{e:?}");
        assert!((e.total_deg - 2.0 / 2f64.sqrt()).abs() < 1e-9, "{e:?}");
        assert!((e.heading_raw_deg - 10.0).abs() < 1e-9, "{e:?}");
    }

    #[test]
    fn installer_parameters_follow_the_rate() {
        let p = installer_params(2000.0 / 7.0, &["tilt_time_constant_s=8"]).unwrap();
        assert_eq!(p.real("window_samples").unwrap(), 143.0);
        assert_eq!(p.real("mag_inclination_deg").unwrap(), 68.0);
        assert_eq!(p.real("tilt_time_constant_s").unwrap(), 8.0);
        let p = installer_params(100.0, &["window_samples=20"]).unwrap();
        assert_eq!(p.real("window_samples").unwrap(), 20.0);
        assert!(installer_params(100.0, &["no_such=1"]).is_err());
    }
}
