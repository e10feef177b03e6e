//! Geometry every engine shares: vectors, the Euler-angle convention,
//! levelling, WGS84 normal gravity and the Earth's rotation. Body frame:
//! x forward, y right, z down; navigation frame: north, east, down.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// A 3-vector of f64.
pub type V3 = Vector3<f64>;

/// WGS84 Earth rotation rate, rad/s.
pub const EARTH_RATE_RAD_PER_S: f64 = 7.292_115e-5;
/// WGS84 semi-major axis, m.
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// WGS84 first eccentricity squared.
pub const WGS84_E2: f64 = 6.694_379_990_14e-3;
/// Normal gravity at the equator, m/s².
const GAMMA_EQUATOR_MPS2: f64 = 9.780_325_335_9;
/// Somigliana's constant k = (b·γ_p)/(a·γ_e) − 1.
const SOMIGLIANA_K: f64 = 1.931_852_652_41e-3;
/// m = ω²a²b/GM.
const WGS84_M: f64 = 3.449_786_506_84e-3;

/// WGS84 normal gravity at geodetic latitude `lat_rad` and `height_m` above
/// the ellipsoid: Somigliana's formula with the second-order free-air term.
pub fn normal_gravity_mps2(lat_rad: f64, height_m: f64) -> f64 {
    let s2 = lat_rad.sin().powi(2);
    let gamma0 = GAMMA_EQUATOR_MPS2 * (1.0 + SOMIGLIANA_K * s2) / (1.0 - WGS84_E2 * s2).sqrt();
    let h = height_m / WGS84_A_M;
    gamma0 * (1.0 - 2.0 * h * (1.0 + WGS84_F + WGS84_M - 2.0 * WGS84_F * s2) + 3.0 * h * h)
}

/// Meridian (north–south) and transverse (east–west) radii of curvature, m.
pub fn radii_m(lat_rad: f64) -> (f64, f64) {
    let d = 1.0 - WGS84_E2 * lat_rad.sin().powi(2);
    let transverse = WGS84_A_M / d.sqrt();
    let meridian = WGS84_A_M * (1.0 - WGS84_E2) / (d * d.sqrt());
    (meridian, transverse)
}

/// The Earth's rotation in the NED frame at `lat_rad`, rad/s.
pub fn earth_rate_n(lat_rad: f64) -> V3 {
    V3::new(
        EARTH_RATE_RAD_PER_S * lat_rad.cos(),
        0.0,
        -EARTH_RATE_RAD_PER_S * lat_rad.sin(),
    )
}

/// Skew-symmetric (cross-product) matrix: `skew(a) * b == a.cross(&b)`.
pub fn skew(a: &V3) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// Roll and pitch (rad) of a body at rest from its mean specific force
/// (static coarse alignment, levelling): at rest f_b = C_nᵇ·[0, 0, −g], so
/// f_x = g·sin θ, f_y = −g·sin φ·cos θ, f_z = −g·cos φ·cos θ.
pub fn level(mean_accel_mps2: &V3) -> (f64, f64) {
    let f = mean_accel_mps2;
    let pitch = f.x.atan2((f.y * f.y + f.z * f.z).sqrt());
    let roll = (-f.y).atan2(-f.z);
    (roll, pitch)
}

/// Body-to-NED attitude from roll, pitch, yaw (rad), aerospace Z-Y-X order.
pub fn attitude_from_euler(roll: f64, pitch: f64, yaw: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(roll, pitch, yaw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_gravity_matches_published_values() {
        // WGS84 normal gravity at the equator and the pole.
        assert!((normal_gravity_mps2(0.0, 0.0) - 9.780_325_3).abs() < 1e-6);
        let pole = normal_gravity_mps2(std::f64::consts::FRAC_PI_2, 0.0);
        assert!((pole - 9.832_184_9).abs() < 1e-6, "{pole}");
        // Free-air gradient ≈ −3.086e-6 s⁻² near the surface.
        let g0 = normal_gravity_mps2(0.8, 0.0);
        let g100 = normal_gravity_mps2(0.8, 100.0);
        assert!(((g100 - g0) / 100.0 + 3.086e-6).abs() < 0.01e-6);
    }

    #[test]
    fn levelling_recovers_roll_and_pitch() {
        for (roll_deg, pitch_deg) in [(0.0, 0.0), (3.0, -2.0), (-10.0, 25.0), (170.0, 5.0)] {
            let (roll, pitch) = (f64::to_radians(roll_deg), f64::to_radians(pitch_deg));
            let c = attitude_from_euler(roll, pitch, 1.0);
            let f_b = c.inverse() * V3::new(0.0, 0.0, -9.8);
            let (r, p) = level(&f_b);
            assert!((r - roll).abs() < 1e-12 && (p - pitch).abs() < 1e-12);
        }
        // Nose up reads a positive x specific force (protocol).
        let c = attitude_from_euler(0.0, 0.1, 0.0);
        assert!((c.inverse() * V3::new(0.0, 0.0, -9.8)).x > 0.0);
    }
}
