//! Standard attitude and heading reference systems, as baselines for the
//! `fuzzy` engine: Madgwick's gradient-descent filter and Mahony's explicit
//! complementary filter, both written from their papers' equations.
//!
//! Conventions (those of the whole project): the attitude is a body-to-NED
//! unit quaternion q (body x forward, y right, z down), so a vector turns
//! from the body into NED as v_n = q ⊗ v_b ⊗ q*, and the NED vector d reads
//! in the body as q* ⊗ d ⊗ q = R(q)ᵀ d. The accelerometer gives specific
//! force, f = −g at rest (a level sensor reads (0, 0, −9.81) m/s²), so the
//! measured direction of "down" in the body is −f/|f|. The gyro is in
//! rad/s, the magnetometer in µT in the body frame. Euler angles from
//! `q.euler_angles()` are (roll, pitch, yaw); yaw is the heading clockwise
//! from magnetic north (both filters take "north" from the field: add the
//! declination for true north).
//!
//! Madgwick (2010), "An efficient orientation filter for inertial and
//! inertial/magnetic sensor arrays": his q = ^S_E q maps an Earth vector
//! into the sensor frame by q* ⊗ d ⊗ q, which is exactly how our body-to-
//! NED quaternion maps a NED vector into the body. With his Earth frame read
//! as NED, his gravity direction (0, 0, 1) is our "down" and his measured
//! acceleration is our −f, so his objective functions f_g (eq. 25) and f_b
//! (eq. 29), Jacobians (eqs. 26, 30) and magnetic-distortion compensation
//! (eqs. 45–46: h = q ⊗ m ⊗ q*, b = (√(h_x² + h_y²), 0, h_z)) hold with q as
//! our quaternion; they are derived here once for a reference (d_x, 0, d_z)
//! covering both. The filter: q̇ = ½ q ⊗ ω − β ∇f/|∇f| (eq. 42, without the
//! optional gyro-drift term ζ). The rate part is integrated exactly
//! (q ⊗ exp(½ ω dt) instead of the paper's Euler step, the same to first
//! order), so β = 0 integrates the gyros exactly.
//!
//! Mahony, Hamel, Pflimlin (2008), "Nonlinear complementary filters on the
//! special orthogonal group", the explicit complementary filter with bias
//! correction (eq. 32): R̂ is the body-to-inertial rotation (ours), each
//! measured body direction v_i against its estimate v̂_i = R̂ᵀ v0_i gives
//! ω_mes = Σ k_i v_i × v̂_i, and Ṙ̂ = R̂ (Ω_y − b̂ + k_P ω_mes)×,
//! ḃ = −k_I ω_mes. The directions (k_i = 1) are "down" from the
//! accelerometer and the field; the field's reference direction is taken
//! from the measurement as in Madgwick's compensation (so neither filter
//! needs the inclination).
//!
//! VQF (Laidig and Seel 2023, "VQF: Highly accurate IMU orientation
//! estimation with bias estimation and magnetic disturbance rejection",
//! Information Fusion 91) through the `vqf-rs` crate, a port of the
//! authors' C++ reference, with all its defaults (rest and motion gyro
//! bias estimation, magnetic disturbance rejection): the best open filter,
//! the yardstick of issue 55. Its earth frame is ENU (x east, y north, z
//! up; the horizontal field laid onto y) and its quaternion turns sensor
//! vectors into it. NED is ENU with x and y swapped and z negated, the
//! half turn about (1, 1, 0)/√2, so our body-to-NED attitude is
//! q_c ⊗ q_VQF with q_c = (0, 1/√2, 1/√2, 0). The sensor axes are any
//! (VQF finds "up" from the specific force), ours included.

use nalgebra::{Quaternion, UnitQuaternion, Vector4};
use vqf_rs::VQF;

use crate::fusion::geometry::{V3, attitude_from_euler, level};

/// Readings with a smaller norm than this carry no direction.
const MIN_NORM: f64 = 1e-9;

/// The unit vector along `v`, or `None` when `v` has no usable norm.
fn direction(v: &V3) -> Option<V3> {
    let n = v.norm();
    (n.is_finite() && n > MIN_NORM).then(|| v / n)
}

/// The Earth-field reference in NED of Madgwick's compensation: the
/// measured body field `m` turned into NED by the estimate, h = q ⊗ m ⊗ q*,
/// with its horizontal part laid onto north: (√(h_x² + h_y²), 0, h_z).
fn field_reference(q: &UnitQuaternion<f64>, m: &V3) -> V3 {
    let h = q * m;
    V3::new(h.x.hypot(h.y), 0.0, h.z)
}

/// Madgwick's objective for the NED reference (d_x, 0, d_z) and the
/// measured body direction `s`: F(q) = R(q)ᵀ d − s, and its gradient
/// Jᵀ F with respect to (w, x, y, z).
///
/// With R(q)ᵀ d = d_x · (row 1 of R) + d_z · (row 3 of R):
///   F₁ = d_x (1 − 2y² − 2z²) + 2 d_z (xz − wy)           − s_x
///   F₂ = 2 d_x (xy − wz)     + 2 d_z (yz + wx)           − s_y
///   F₃ = 2 d_x (xz + wy)     + d_z (1 − 2x² − 2y²)       − s_z
/// and the rows of J (∂/∂w, ∂/∂x, ∂/∂y, ∂/∂z):
///   ∂F₁ = (−2d_z y,          2d_z z,          −4d_x y − 2d_z w,  −4d_x z + 2d_z x)
///   ∂F₂ = (−2d_x z + 2d_z x, 2d_x y + 2d_z w, 2d_x x + 2d_z z,   −2d_x w + 2d_z y)
///   ∂F₃ = (2d_x y,           2d_x z − 4d_z x, 2d_x w − 4d_z y,   2d_x x)
/// (with d = (0, 0, 1) these are Madgwick's eqs. 25–26, with d = b his
/// eqs. 29–30).
fn objective_gradient(q: &UnitQuaternion<f64>, dx: f64, dz: f64, s: &V3) -> (V3, Vector4<f64>) {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    let f = V3::new(
        dx * (1.0 - 2.0 * (y * y + z * z)) + 2.0 * dz * (x * z - w * y) - s.x,
        2.0 * dx * (x * y - w * z) + 2.0 * dz * (y * z + w * x) - s.y,
        2.0 * dx * (x * z + w * y) + dz * (1.0 - 2.0 * (x * x + y * y)) - s.z,
    );
    let j1 = Vector4::new(
        -2.0 * dz * y,
        2.0 * dz * z,
        -4.0 * dx * y - 2.0 * dz * w,
        -4.0 * dx * z + 2.0 * dz * x,
    );
    let j2 = Vector4::new(
        -2.0 * dx * z + 2.0 * dz * x,
        2.0 * dx * y + 2.0 * dz * w,
        2.0 * dx * x + 2.0 * dz * z,
        -2.0 * dx * w + 2.0 * dz * y,
    );
    let j3 = Vector4::new(
        2.0 * dx * y,
        2.0 * dx * z - 4.0 * dz * x,
        2.0 * dx * w - 4.0 * dz * y,
        2.0 * dx * x,
    );
    (f, j1 * f.x + j2 * f.y + j3 * f.z)
}

/// Madgwick's gradient-descent AHRS (IMU and MARG variants).
#[derive(Debug, Clone)]
pub struct Madgwick {
    beta: f64,
    attitude: UnitQuaternion<f64>,
}

impl Madgwick {
    /// beta in rad/s (gyro-error gain); initial attitude given.
    pub fn new(beta: f64, attitude: UnitQuaternion<f64>) -> Madgwick {
        Madgwick { beta, attitude }
    }

    /// One step; magnetometer optional (None → IMU-only update). A reading
    /// of zero norm skips its correction; a step of no time does nothing.
    pub fn update(&mut self, gyro_rad_per_s: &V3, accel_mps2: &V3, mag_ut: Option<&V3>, dt_s: f64) {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return;
        }
        let q = self.attitude;
        let mut gradient = Vector4::zeros();
        if let Some(down) = direction(&-accel_mps2) {
            gradient += objective_gradient(&q, 0.0, 1.0, &down).1;
        }
        if let Some(m) = mag_ut.and_then(direction) {
            let b = field_reference(&q, &m);
            gradient += objective_gradient(&q, b.x, b.z, &m).1;
        }
        let turned = (q * UnitQuaternion::from_scaled_axis(gyro_rad_per_s * dt_s)).into_inner();
        let norm = gradient.norm();
        let stepped = if norm > MIN_NORM && self.beta != 0.0 {
            let g = gradient * (self.beta * dt_s / norm);
            Quaternion::new(
                turned.w - g[0],
                turned.i - g[1],
                turned.j - g[2],
                turned.k - g[3],
            )
        } else {
            turned
        };
        if stepped.norm() > MIN_NORM {
            self.attitude = UnitQuaternion::from_quaternion(stepped);
        }
    }

    /// The estimate: body to NED (magnetic north).
    pub fn attitude(&self) -> UnitQuaternion<f64> {
        self.attitude
    }
}

/// Mahony's explicit complementary filter with gyro-bias estimation.
#[derive(Debug, Clone)]
pub struct Mahony {
    kp: f64,
    ki: f64,
    attitude: UnitQuaternion<f64>,
    bias: V3,
}

impl Mahony {
    /// kp in rad/s (proportional gain), ki in rad/s² (integral gain);
    /// initial attitude given, gyro bias estimate zero.
    pub fn new(kp: f64, ki: f64, attitude: UnitQuaternion<f64>) -> Mahony {
        Mahony {
            kp,
            ki,
            attitude,
            bias: V3::zeros(),
        }
    }

    /// One step; magnetometer optional (None → tilt-only correction). A
    /// reading of zero norm skips its correction; a step of no time does
    /// nothing.
    pub fn update(&mut self, gyro_rad_per_s: &V3, accel_mps2: &V3, mag_ut: Option<&V3>, dt_s: f64) {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return;
        }
        let q = self.attitude;
        let inverse = q.inverse();
        // ω_mes = Σ v_i × v̂_i with v̂_i = R̂ᵀ v0_i.
        let mut correction = V3::zeros();
        if let Some(down) = direction(&-accel_mps2) {
            correction += down.cross(&(inverse * V3::z()));
        }
        if let Some(m) = mag_ut.and_then(direction) {
            let expected = inverse * field_reference(&q, &m);
            correction += m.cross(&expected);
        }
        self.bias -= correction * (self.ki * dt_s);
        let rate = gyro_rad_per_s - self.bias + correction * self.kp;
        self.attitude = q * UnitQuaternion::from_scaled_axis(rate * dt_s);
    }

    /// The estimate: body to NED (magnetic north).
    pub fn attitude(&self) -> UnitQuaternion<f64> {
        self.attitude
    }

    /// The estimated gyro bias (what the gyros read above the true rate).
    pub fn gyro_bias_rad_per_s(&self) -> V3 {
        self.bias
    }
}

/// Initial attitude from a resting accelerometer and (optionally)
/// magnetometer reading (tilt from gravity, heading from the
/// tilt-compensated field). Heading is magnetic and 0 without a usable
/// field; tilt is level without a usable specific force.
pub fn initial_attitude(accel_mps2: &V3, mag_ut: Option<&V3>) -> UnitQuaternion<f64> {
    let (roll, pitch) = if direction(accel_mps2).is_some() {
        level(accel_mps2)
    } else {
        (0.0, 0.0)
    };
    // The field turned into the level frame: h = R_y(θ) R_x(φ) m; heading
    // clockwise from north is atan2(−h_y, h_x).
    let yaw = mag_ut.and_then(direction).map_or(0.0, |m| {
        let h = attitude_from_euler(roll, pitch, 0.0) * m;
        (-h.y).atan2(h.x)
    });
    attitude_from_euler(roll, pitch, yaw)
}

/// VQF, as the module documentation describes.
pub struct Vqf {
    filter: VQF,
}

impl std::fmt::Debug for Vqf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Vqf")
            .field("attitude", &self.attitude())
            .finish()
    }
}

impl Vqf {
    /// A filter for an IMU read every `imu_period_s` and a magnetometer
    /// every `mag_period_s` (its low-pass filters are set for them; the
    /// gyro is integrated over each reading's own spacing).
    pub fn new(imu_period_s: f64, mag_period_s: f64) -> Vqf {
        Vqf {
            filter: VQF::new(imu_period_s, None, Some(mag_period_s), None),
        }
    }

    /// One IMU reading: the rate held over `dt_s` since the reading before
    /// (nothing to integrate at the first), then the specific force.
    pub fn update_imu(&mut self, gyro_rad_per_s: &V3, accel_mps2: &V3, dt_s: f64) {
        if dt_s > 0.0 && dt_s.is_finite() {
            self.filter
                .update_gyr_with_ts([gyro_rad_per_s.x, gyro_rad_per_s.y, gyro_rad_per_s.z], dt_s);
        }
        self.filter
            .update_acc([accel_mps2.x, accel_mps2.y, accel_mps2.z]);
    }

    /// One magnetometer reading, µT in the body frame.
    pub fn update_mag(&mut self, mag_ut: &V3) {
        self.filter.update_mag([mag_ut.x, mag_ut.y, mag_ut.z]);
    }

    /// The body-to-NED attitude (yaw from magnetic north).
    pub fn attitude(&self) -> UnitQuaternion<f64> {
        let q = self.filter.quat_9d();
        let enu = UnitQuaternion::from_quaternion(Quaternion::new(q.0, q.1, q.2, q.3));
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let enu_to_ned = UnitQuaternion::from_quaternion(Quaternion::new(0.0, half, half, 0.0));
        enu_to_ned * enu
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// VQF at rest for a minute at 100 Hz (field 20 µT north, 45 µT down),
    /// level facing north, facing east (north on the body's left: the
    /// field reads (0, −20, 45)) and rolled 30° right (the force
    /// Rₓ(30°)ᵀ(0, 0, −g) = (0, −g sin 30°, −g cos 30°), the field
    /// (20, 45 sin 30°, 45 cos 30°)): it finds each attitude.
    #[test]
    fn vqf_finds_a_resting_attitude_in_ned() {
        let g = 9.81;
        let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
        let cases = [
            (
                V3::new(0.0, 0.0, -g),
                V3::new(20.0, 0.0, 45.0),
                (0.0, 0.0, 0.0),
            ),
            (
                V3::new(0.0, 0.0, -g),
                V3::new(0.0, -20.0, 45.0),
                (0.0, 0.0, 90.0),
            ),
            (
                V3::new(0.0, -g * s, -g * c),
                V3::new(20.0, 45.0 * s, 45.0 * c),
                (30.0, 0.0, 0.0),
            ),
        ];
        for (force, field, (roll, pitch, yaw)) in cases {
            let mut vqf = Vqf::new(0.01, 0.01);
            for _ in 0..6000 {
                vqf.update_imu(&V3::zeros(), &force, 0.01);
                vqf.update_mag(&field);
            }
            let (r, p, y) = vqf.attitude().euler_angles();
            let off =
                |got: f64, want: f64| (got.to_degrees() - want + 180.0).rem_euclid(360.0) - 180.0;
            assert!(
                off(r, roll).abs() < 0.5 && off(p, pitch).abs() < 0.5 && off(y, yaw).abs() < 0.5,
                "want {roll}/{pitch}/{yaw}, got {}/{}/{}",
                r.to_degrees(),
                p.to_degrees(),
                y.to_degrees()
            );
        }
    }

    const G: f64 = 9.81;
    const DT: f64 = 0.01;

    /// A 50 µT field of the given inclination pointing to magnetic north.
    fn earth_field(inclination_deg: f64) -> V3 {
        let i = inclination_deg.to_radians();
        V3::new(50.0 * i.cos(), 0.0, 50.0 * i.sin())
    }

    /// What a perfect still sensor at `truth` reads.
    fn still(truth: &UnitQuaternion<f64>, field_n: &V3) -> (V3, V3) {
        let inverse = truth.inverse();
        (inverse * V3::new(0.0, 0.0, -G), inverse * field_n)
    }

    fn degrees_apart(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
        a.angle_to(b).to_degrees()
    }

    fn tilted() -> UnitQuaternion<f64> {
        attitude_from_euler(
            20f64.to_radians(),
            (-10f64).to_radians(),
            130f64.to_radians(),
        )
    }

    #[test]
    fn the_objective_gradient_is_j_transpose_f() {
        // Central differences of ½|F|² against the hand-derived Jᵀ F.
        let q = UnitQuaternion::from_euler_angles(0.3, -0.4, 2.0);
        let s = V3::new(0.2, -0.5, 0.8).normalize();
        let (dx, dz) = (0.5, 0.866);
        let (_, gradient) = objective_gradient(&q, dx, dz, &s);
        let cost = |c: [f64; 4]| {
            let (w, x, y, z) = (c[0], c[1], c[2], c[3]);
            let f = V3::new(
                dx * (1.0 - 2.0 * (y * y + z * z)) + 2.0 * dz * (x * z - w * y) - s.x,
                2.0 * dx * (x * y - w * z) + 2.0 * dz * (y * z + w * x) - s.y,
                2.0 * dx * (x * z + w * y) + dz * (1.0 - 2.0 * (x * x + y * y)) - s.z,
            );
            0.5 * f.norm_squared()
        };
        let c = [q.w, q.i, q.j, q.k];
        for k in 0..4 {
            let (mut up, mut down) = (c, c);
            up[k] += 1e-6;
            down[k] -= 1e-6;
            let numeric = (cost(up) - cost(down)) / 2e-6;
            assert!((numeric - gradient[k]).abs() < 1e-8, "{k}");
        }
        // And F is R(q)ᵀ d − s.
        let (f, _) = objective_gradient(&q, dx, dz, &s);
        let expected = q.inverse() * V3::new(dx, 0.0, dz) - s;
        assert!((f - expected).norm() < 1e-12);
    }

    #[test]
    fn initial_attitude_from_a_still_reading() {
        let truth = tilted();
        let (f, m) = still(&truth, &earth_field(60.0));
        assert!(degrees_apart(&initial_attitude(&f, Some(&m)), &truth) < 1e-9);
        let (roll, pitch, yaw) = initial_attitude(&f, None).euler_angles();
        assert!((roll.to_degrees() - 20.0).abs() < 1e-9);
        assert!((pitch.to_degrees() + 10.0).abs() < 1e-9);
        assert!(yaw.abs() < 1e-12);
        // Level at rest, facing east: the field's horizontal part points
        // to the body's left (−y).
        let east = attitude_from_euler(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let (f, m) = still(&east, &earth_field(60.0));
        assert!((m.y + 25.0).abs() < 1e-9 && (f.z + G).abs() < 1e-12);
        let yaw = initial_attitude(&f, Some(&m)).euler_angles().2;
        assert!((yaw.to_degrees() - 90.0).abs() < 1e-9);
        // Zero readings leave the identity.
        assert_eq!(
            initial_attitude(&V3::zeros(), Some(&V3::zeros())),
            UnitQuaternion::identity()
        );
    }

    #[test]
    fn a_still_tilted_sensor_converges_from_a_wrong_start() {
        let truth = tilted();
        let (f, m) = still(&truth, &earth_field(60.0));
        // 80° off in heading and 15° off in roll.
        let start = attitude_from_euler(
            35f64.to_radians(),
            (-10f64).to_radians(),
            50f64.to_radians(),
        );
        assert!(degrees_apart(&start, &truth) > 75.0);
        let mut madgwick = Madgwick::new(0.3, start);
        let mut mahony = Mahony::new(2.0, 0.0, start);
        // Mahony's heading error decays at k_P cos² I = 0.5 per s (the
        // field's horizontal part is half of it): 80 s to 1e-6°.
        for _ in 0..8000 {
            madgwick.update(&V3::zeros(), &f, Some(&m), DT);
            mahony.update(&V3::zeros(), &f, Some(&m), DT);
        }
        // Madgwick's fixed step β·dt leaves a limit cycle of about
        // β·dt rad in the quaternion (2β·dt in angle) around the truth.
        let limit = (2.0 * 0.3 * DT).to_degrees();
        assert!(
            degrees_apart(&madgwick.attitude(), &truth) < limit,
            "{}",
            degrees_apart(&madgwick.attitude(), &truth)
        );
        let e = degrees_apart(&mahony.attitude(), &truth);
        assert!(e < 1e-6, "{e} {:?}", mahony.attitude().euler_angles());
        // Without the magnetometer, tilt converges and heading stays put.
        let mut imu = Madgwick::new(0.3, start);
        for _ in 0..3000 {
            imu.update(&V3::zeros(), &f, None, DT);
        }
        let (roll, pitch, _) = imu.attitude().euler_angles();
        assert!((roll.to_degrees() - 20.0).abs() < limit);
        assert!((pitch.to_degrees() + 10.0).abs() < limit);
    }

    #[test]
    fn without_correction_a_constant_rate_integrates_exactly() {
        let rate = V3::new(0.3, -0.2, 0.5);
        let start = tilted();
        let mut madgwick = Madgwick::new(0.0, start);
        let mut mahony = Mahony::new(0.0, 0.0, start);
        // The readings are inconsistent with the motion; no gain, no effect.
        let f = V3::new(1.0, 2.0, -9.0);
        let m = V3::new(10.0, -30.0, 20.0);
        for _ in 0..1000 {
            madgwick.update(&rate, &f, Some(&m), DT);
            mahony.update(&rate, &f, Some(&m), DT);
        }
        // 10 s at a constant body rate: q ⊗ exp(½ ω · 10 s).
        let expected = start * UnitQuaternion::from_scaled_axis(rate * 10.0);
        assert!(degrees_apart(&madgwick.attitude(), &expected) < 1e-9);
        assert!(degrees_apart(&mahony.attitude(), &expected) < 1e-9);
        assert_eq!(mahony.gyro_bias_rad_per_s(), V3::zeros());
    }

    #[test]
    fn mahony_integral_term_converges_to_a_constant_gyro_bias() {
        let truth = tilted();
        let (f, m) = still(&truth, &earth_field(60.0));
        let bias = V3::new(0.01, -0.02, 0.015);
        // Error dynamics s² + k_P s + k_I: roots −0.11 and −0.89 per s.
        let mut mahony = Mahony::new(1.0, 0.1, truth);
        for _ in 0..20_000 {
            mahony.update(&bias, &f, Some(&m), DT);
        }
        let error = mahony.gyro_bias_rad_per_s() - bias;
        assert!(error.norm() < 1e-6, "{error}");
        assert!(degrees_apart(&mahony.attitude(), &truth) < 1e-4);
    }

    #[test]
    fn heading_ignores_a_change_of_the_fields_inclination() {
        // Converged at 60° inclination from 4° off in heading, the field
        // steepens to 75° (its horizontal direction unchanged). b is
        // recomputed from the measurement, so the truth stays the fixed
        // point and the heading does not move (a reference fixed at 60°
        // would disagree with the new field by 15° and pull the estimate).
        let truth = tilted();
        let (f, m) = still(&truth, &earth_field(60.0));
        let (_, steep) = still(&truth, &earth_field(75.0));
        let start = attitude_from_euler(
            20f64.to_radians(),
            (-10f64).to_radians(),
            126f64.to_radians(),
        );
        let beta = 0.05;
        let mut madgwick = Madgwick::new(beta, start);
        let mut mahony = Mahony::new(2.0, 0.0, start);
        for _ in 0..6000 {
            madgwick.update(&V3::zeros(), &f, Some(&m), DT);
            mahony.update(&V3::zeros(), &f, Some(&m), DT);
        }
        // Madgwick's fixed step leaves a limit cycle around the truth: a
        // quaternion step of β·dt is 2β·dt in angle; yaw, read through
        // the tilt, within twice that.
        let limit = (4.0 * beta * DT).to_degrees();
        let heading = |q: UnitQuaternion<f64>| q.euler_angles().2.to_degrees();
        let (mut worst_madgwick, mut worst_mahony) = (0.0_f64, 0.0_f64);
        for _ in 0..6000 {
            madgwick.update(&V3::zeros(), &f, Some(&steep), DT);
            mahony.update(&V3::zeros(), &f, Some(&steep), DT);
            worst_madgwick = worst_madgwick.max((heading(madgwick.attitude()) - 130.0).abs());
            worst_mahony = worst_mahony.max((heading(mahony.attitude()) - 130.0).abs());
        }
        assert!(worst_madgwick < limit, "{worst_madgwick}");
        assert!(worst_mahony < 1e-6, "{worst_mahony}");
        assert!(degrees_apart(&madgwick.attitude(), &truth) < limit);
        assert!(degrees_apart(&mahony.attitude(), &truth) < 1e-6);
        // The compensated reference at the truth is the new field in NED.
        let b = field_reference(&truth, &steep);
        assert!((b - earth_field(75.0)).norm() < 1e-9);
    }

    #[test]
    fn zero_norm_readings_skip_their_correction() {
        let start = tilted();
        let rate = V3::new(0.0, 0.0, 0.1);
        let mut madgwick = Madgwick::new(0.5, start);
        let mut mahony = Mahony::new(2.0, 0.5, start);
        for _ in 0..100 {
            madgwick.update(&rate, &V3::zeros(), Some(&V3::zeros()), DT);
            mahony.update(&rate, &V3::zeros(), None, DT);
        }
        let expected = start * UnitQuaternion::from_scaled_axis(rate * 1.0);
        assert!(degrees_apart(&madgwick.attitude(), &expected) < 1e-9);
        assert!(degrees_apart(&mahony.attitude(), &expected) < 1e-9);
        // A step of no time changes nothing.
        madgwick.update(&rate, &V3::new(0.0, 0.0, -G), None, 0.0);
        assert!(degrees_apart(&madgwick.attitude(), &expected) < 1e-9);
    }
}
