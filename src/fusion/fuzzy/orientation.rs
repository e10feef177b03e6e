//! Attitude as a body-to-NED unit quaternion: gyro integration while
//! moving, and the static references it is pulled towards (accelerometer
//! tilt, tilt-compensated compass heading) in proportion to the static
//! degree.

use nalgebra::UnitQuaternion;

use crate::fusion::geometry::{V3, attitude_from_euler};

/// Roll and pitch (rad) from a specific force at rest: f = −g in the body
/// frame, so pitch = atan2(f_x, √(f_y² + f_z²)), roll = atan2(−f_y, −f_z).
pub fn tilt_from_accel(force_mps2: &V3) -> (f64, f64) {
    crate::fusion::geometry::level(force_mps2)
}

/// Magnetic heading (rad, clockwise from magnetic north) of a body whose
/// roll and pitch are known, from the calibrated body-frame field: the
/// field is rotated into the level frame, h = R_y(θ) R_x(φ) m, and the
/// heading is atan2(−h_y, h_x).
pub fn magnetic_heading(field_ut: &V3, roll_rad: f64, pitch_rad: f64) -> f64 {
    let level = attitude_from_euler(roll_rad, pitch_rad, 0.0) * field_ut;
    (-level.y).atan2(level.x)
}

/// Advances the attitude by the bias-compensated rate over `dt_s`:
/// q ← q ⊗ exp(½ ω dt), the rotation vector ω·dt taken whole (exact for a
/// rate constant over the step).
pub fn integrate(
    attitude: &UnitQuaternion<f64>,
    rate_rad_per_s: &V3,
    dt_s: f64,
) -> UnitQuaternion<f64> {
    attitude * UnitQuaternion::from_scaled_axis(rate_rad_per_s * dt_s)
}

/// The smallest signed angle from `from` to `to`, rad, in (−π, π].
pub fn angle_difference(to: f64, from: f64) -> f64 {
    let d = (to - from).rem_euclid(std::f64::consts::TAU);
    if d > std::f64::consts::PI {
        d - std::f64::consts::TAU
    } else {
        d
    }
}

/// Moves the attitude's roll and pitch a fraction `gain` ∈ [0, 1] of the
/// way to the reference, keeping its yaw: a spherical interpolation to the
/// attitude with the reference tilt and the current yaw.
pub fn pull_tilt(
    attitude: &UnitQuaternion<f64>,
    roll_rad: f64,
    pitch_rad: f64,
    gain: f64,
) -> UnitQuaternion<f64> {
    let (_, _, yaw) = attitude.euler_angles();
    let target = attitude_from_euler(roll_rad, pitch_rad, yaw);
    attitude.slerp(&target, gain.clamp(0.0, 1.0))
}

/// Turns the attitude about the vertical a fraction `gain` of the way to
/// the reference heading (rad), keeping roll and pitch.
pub fn pull_heading(
    attitude: &UnitQuaternion<f64>,
    yaw_rad: f64,
    gain: f64,
) -> UnitQuaternion<f64> {
    let (_, _, yaw) = attitude.euler_angles();
    let turn = angle_difference(yaw_rad, yaw) * gain.clamp(0.0, 1.0);
    UnitQuaternion::from_axis_angle(&V3::z_axis(), turn) * attitude
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accelerometer_tilt_follows_the_protocol_signs() {
        let g = 9.81;
        let nose_up = attitude_from_euler(0.0, 0.1, 0.7);
        let (roll, pitch) = tilt_from_accel(&(nose_up.inverse() * V3::new(0.0, 0.0, -g)));
        assert!((pitch - 0.1).abs() < 1e-12 && roll.abs() < 1e-12);
        let right_down = attitude_from_euler(0.2, -0.05, 2.0);
        let (roll, pitch) = tilt_from_accel(&(right_down.inverse() * V3::new(0.0, 0.0, -g)));
        assert!((roll - 0.2).abs() < 1e-12 && (pitch + 0.05).abs() < 1e-12);
    }

    #[test]
    fn compass_heading_is_right_when_tilted() {
        let earth = V3::new(20.0, 0.0, 44.0); // magnetic north, dipping down
        for yaw_deg in [0.0, 45.0, 135.0, 250.0, 359.0_f64] {
            let yaw = yaw_deg.to_radians();
            let body = attitude_from_euler(0.08, -0.12, yaw);
            let field = body.inverse() * earth;
            let heading = magnetic_heading(&field, 0.08, -0.12);
            assert!(angle_difference(heading, yaw).abs() < 1e-12, "{yaw_deg}");
        }
    }

    #[test]
    fn integrating_a_constant_rate_turns_by_rate_times_time() {
        let mut q = attitude_from_euler(0.0, 0.0, 0.0);
        for _ in 0..1000 {
            q = integrate(&q, &V3::new(0.0, 0.0, 0.01), 0.01);
        }
        let (roll, pitch, yaw) = q.euler_angles();
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12);
        assert!((yaw - 0.1).abs() < 1e-12);
    }

    #[test]
    fn pulls_move_only_what_they_correct() {
        let q = attitude_from_euler(0.1, 0.05, 1.0);
        let tilted = pull_tilt(&q, 0.0, 0.0, 1.0);
        let (roll, pitch, yaw) = tilted.euler_angles();
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12 && (yaw - 1.0).abs() < 1e-12);
        let turned = pull_heading(&q, -3.0, 0.5);
        let (roll, pitch, yaw) = turned.euler_angles();
        assert!((roll - 0.1).abs() < 1e-12 && (pitch - 0.05).abs() < 1e-12);
        // Half of the short way from 1.0 to −3.0 (through ±π): 2.283 rad.
        let expected = 1.0 + 0.5 * angle_difference(-3.0, 1.0);
        assert!(angle_difference(yaw, expected).abs() < 1e-12);
    }
}
