//! BROAD's frames to ours: the sensor's z-up frame to body x forward,
//! y right, z down, and its ENU truth to a body-to-NED attitude.

use super::*;

/// q_sensor←body: a half turn about x, (x, y, z)_body → (x, −y, −z)_sensor.
pub const SENSOR_FROM_BODY: Quaternion<f64> = Quaternion::new(0.0, 1.0, 0.0, 0.0);

/// q_NED←ENU: the half turn about (1, 1, 0)/√2 (east ↔ north, up → −down).
pub fn ned_from_enu() -> UnitQuaternion<f64> {
    let s = std::f64::consts::FRAC_1_SQRT_2;
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, s, s, 0.0))
}

/// A BROAD sensor-frame vector (z up) in our body frame (z down).
pub fn body_from_sensor(v: &V3) -> V3 {
    V3::new(v.x, -v.y, -v.z)
}

/// BROAD's truth (sensor-to-ENU) as our body-to-NED attitude.
pub fn ned_attitude_from_broad(q_enu_sensor: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    ned_from_enu() * q_enu_sensor * UnitQuaternion::new_unchecked(SENSOR_FROM_BODY)
}
