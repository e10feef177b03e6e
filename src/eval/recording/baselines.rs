//! The estimators the engine is compared with: gyro only, accelerometer +
//! compass per sample, and Madgwick's β grid.

use super::*;

/// `attitude` turned by the body rate `rate_rad_per_s` held over `dt_s`
/// (the engine's own integration step: this is a baseline of it).
pub use crate::fusion::fuzzy::orientation::integrate as integrate_rate;

/// Attitude from one sample's specific force and field alone (body-to-NED,
/// yaw from the field's north): roll = atan2(−f_y, −f_z), pitch =
/// atan2(f_x, √(f_y² + f_z²)), yaw = atan2(−h_y, h_x) with h the field
/// turned level by that roll and pitch.
pub fn accel_compass_attitude(force_mps2: &V3, field_ut: &V3) -> UnitQuaternion<f64> {
    let f = force_mps2;
    let roll = (-f.y).atan2(-f.z);
    let pitch = f.x.atan2(f.y.hypot(f.z));
    let level = UnitQuaternion::from_euler_angles(roll, pitch, 0.0) * field_ut;
    UnitQuaternion::from_euler_angles(roll, pitch, (-level.y).atan2(level.x))
}

/// Gyro-only integration from a first attitude, with a fixed bias removed.
#[derive(Debug, Clone)]
pub(super) struct GyroOnly {
    bias: V3,
    state: Option<(f64, V3, UnitQuaternion<f64>)>,
}

impl GyroOnly {
    pub(super) fn new(bias: V3) -> GyroOnly {
        GyroOnly { bias, state: None }
    }

    /// The attitude at `sample`, starting from its truth at the first
    /// sample that has one.
    pub(super) fn step(&mut self, sample: &Sample) -> Option<UnitQuaternion<f64>> {
        let rate = sample.gyro_rad_per_s - self.bias;
        let next = match (self.state, sample.truth) {
            (Some((t, previous, q)), _) => {
                integrate_rate(&q, &((previous + rate) * 0.5), sample.t_s - t)
            }
            (None, Some(truth)) => truth,
            (None, None) => return None,
        };
        self.state = Some((sample.t_s, rate, next));
        Some(next)
    }
}

/// Madgwick's β tried, rad/s; the common default first.
pub const MADGWICK_BETAS: [f64; 12] = [
    0.041, 0.005, 0.01, 0.02, 0.03, 0.06, 0.08, 0.1, 0.12, 0.15, 0.2, 0.3,
];
/// The β commonly used as a default, rad/s.
pub const MADGWICK_DEFAULT_BETA: f64 = 0.041;
