//! The gyro bias from the pulls while moving: the integral term of a
//! complementary filter (Mahony et al. 2008, the explicit complementary
//! filter's ḃ = −k_I·ω_mes), for a sensor that is never still long enough
//! for the static blocks of `rest_rate.rs` to learn its bias.
//!
//! A bias error δb (the compensated rate too high by δb, body frame) turns
//! the attitude by C·δb·dt per reading (world frame); the accelerometer's
//! and the compass's pulls turn it back along their residual e (world
//! frame, rad: the axis and angle from the estimate to the sensor). A pull
//! by the fraction g per reading is a proportional gain k_P = g/dt; with
//! the integral gain k_I = k_P²/4 the loop is critically damped, and
//!
//!   b ← b − k_I · Cᵀe · dt · (1 − σ)
//!
//! (σ the stillness: at rest the static blocks learn the bias instead),
//! and per axis only as far as the bias filter is unsure of it: the step is
//! weighted by P/(P + R_fb), P the bias filter's variance and R_fb the
//! variance of the bias the residuals can tell, (σ_ref/τ)² with σ_ref the
//! sensor's σ and τ = 1/k_P its pull's time constant. A bias learnt at a
//! rest minutes ago (P small) is barely moved by the residuals a vehicle's
//! accelerations and turns leave; one never learnt (an alignment while
//! moving: P the data sheet's bias²) is learnt from them. A steady bias
//! error leaves a steady residual, which the integral takes into the bias
//! until the residual is gone.

use nalgebra::UnitQuaternion;

use crate::fusion::geometry::V3;

/// The bias change, rad/s, one pull implies: `residual_world_rad` the
/// pull's residual e (world frame), `pull_gain` its fraction g of this
/// reading, `moving` the weight 1 − σ.
/// `bias_variance` P per axis, (rad/s)², and `reference_sigma_rad` the
/// sensor's σ_ref.
pub fn bias_step(
    attitude: &UnitQuaternion<f64>,
    residual_world_rad: &V3,
    pull_gain: f64,
    dt_s: f64,
    moving: f64,
    bias_variance: &V3,
    reference_sigma_rad: f64,
) -> V3 {
    if dt_s <= 0.0 || pull_gain <= 0.0 || !pull_gain.is_finite() {
        return V3::zeros();
    }
    let proportional = pull_gain / dt_s;
    let integral = 0.25 * proportional * proportional;
    let told = (reference_sigma_rad * proportional).powi(2);
    let weight = bias_variance.map(|p| if p > 0.0 { p / (p + told) } else { 0.0 });
    (-(attitude.inverse() * residual_world_rad) * (integral * dt_s * moving.clamp(0.0, 1.0)))
        .component_mul(&weight)
}

/// The settling time of the critically damped loop in pull time
/// constants: what the pulls tell of the bias, they tell once per this.
const LOOP_TIME_CONSTANTS: f64 = 4.0;

/// The bias variance per axis after a pull, (rad/s)²: the pulls measure
/// the bias with the variance R_fb once per loop time 4τ, so a variance
/// far above R_fb (a bias called into doubt, bias_doubt.rs) falls as the
/// loop learns it, dP = −P²/(P + R_fb)·g·(1 − σ)/4·h per reading (about
/// −P·g(1 − σ)/4 while P ≫ R_fb, a continuous Kalman filter's
/// −P²/(R_fb·4τ) once P ≪ R_fb), h = 1 − (C·e_k)_z² how horizontal body
/// axis k lies: the accelerometer's residual is horizontal and tells
/// nothing of a bias about the vertical (the compass's). Arguments as
/// [`bias_step`]'s.
pub fn variance_after(
    attitude: &UnitQuaternion<f64>,
    bias_variance: &V3,
    pull_gain: f64,
    moving: f64,
    reference_sigma_rad: f64,
    dt_s: f64,
) -> V3 {
    if dt_s <= 0.0 || pull_gain <= 0.0 || !pull_gain.is_finite() {
        return *bias_variance;
    }
    let told = (reference_sigma_rad * pull_gain / dt_s).powi(2);
    let rate = (pull_gain * moving.clamp(0.0, 1.0) / LOOP_TIME_CONSTANTS).min(1.0);
    let mut after = *bias_variance;
    for (k, p) in after.iter_mut().enumerate() {
        let vertical = (attitude * V3::ith(k, 1.0)).z;
        let horizontal = (1.0 - vertical * vertical).clamp(0.0, 1.0);
        if *p > 0.0 {
            *p -= *p * *p / (*p + told) * rate * horizontal;
        }
    }
    after
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::geometry::attitude_from_euler;

    #[test]
    fn a_residual_moves_the_bias_against_it_in_the_body_frame() {
        // Level, heading 90°: world x (north) is body −y. A residual of
        // 0.01 rad about north, g = 0.001 per 0.01 s (k_P = 0.1/s,
        // k_I = 0.0025/s²), fully moving: Δb = −0.0025·0.01·(0, −0.01, 0)
        // = (0, 2.5e-7, 0) in the body.
        // A bias never learnt (P ≫ R_fb): the full step.
        let attitude = attitude_from_euler(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let unknown = V3::repeat(1e6);
        let e = V3::new(0.01, 0.0, 0.0);
        let step = bias_step(&attitude, &e, 0.001, 0.01, 1.0, &unknown, 0.02);
        assert!((step - V3::new(0.0, 2.5e-7, 0.0)).norm() < 1e-12, "{step}");
        // At rest nothing; half moving half as much.
        assert_eq!(
            bias_step(&attitude, &e, 0.001, 0.01, 0.0, &unknown, 0.02),
            V3::zeros()
        );
        let half = bias_step(&attitude, &e, 0.001, 0.01, 0.5, &unknown, 0.02);
        assert!((half - step * 0.5).norm() < 1e-15);
        // P = R_fb = (0.02·0.1)² = 4e-6: half the step.
        let known = V3::repeat(4e-6);
        let weighed = bias_step(&attitude, &e, 0.001, 0.01, 1.0, &known, 0.02);
        assert!((weighed - step * 0.5).norm() < 1e-15, "{weighed}");
    }

    #[test]
    fn a_steady_bias_error_is_taken_out_by_the_loop() {
        // One axis: the angle error θ grows by δb·dt and the pull takes
        // g·θ back; the integral takes k_I·θ·dt into the bias. After a
        // few time constants (critically damped: 2/k_P = 20 s) both are gone.
        let (dt, g) = (0.01, 0.001);
        let true_error = 0.01; // rad/s
        let (mut theta, mut bias) = (0.0_f64, 0.0_f64);
        let level = UnitQuaternion::identity();
        for _ in 0..(300.0 / dt) as usize {
            theta += (true_error - bias) * dt;
            // The residual from the estimate to the sensor is −θ.
            bias += bias_step(
                &level,
                &V3::new(-theta, 0.0, 0.0),
                g,
                dt,
                1.0,
                &V3::repeat(1e6),
                0.02,
            )
            .x;
            theta -= g * theta;
        }
        assert!((bias - true_error).abs() < 1e-4, "{bias}");
        assert!(theta.abs() < 1e-3, "{theta}");
    }

    #[test]
    fn a_doubted_variance_falls_as_the_loop_learns_and_a_sure_one_barely_moves() {
        // g = 0.001 per 0.01 s (k_P = 0.1/s), σ_ref 0.02 rad: R_fb =
        // (0.002)² = 4e-6. Level: body x and y horizontal, z vertical.
        // P = 4e-4 ≫ R_fb: dP = −(1.6e-7/4.04e-4)·0.001/4 = −9.90e-8;
        // P = R_fb: −2e-6·0.00025 = −5e-10; z (vertical): unchanged;
        // half moving: half.
        let level = UnitQuaternion::identity();
        let after = variance_after(&level, &V3::new(4e-4, 4e-6, 4e-4), 0.001, 1.0, 0.02, 0.01);
        assert!(
            (after.x - (4e-4 - 1.6e-7 / 4.04e-4 * 0.00025)).abs() < 1e-15,
            "{after}"
        );
        assert!((after.y - (4e-6 - 5e-10)).abs() < 1e-18, "{after}");
        assert_eq!(after.z, 4e-4);
        let half = variance_after(&level, &V3::repeat(4e-6), 0.001, 0.5, 0.02, 0.01);
        assert!((half.x - (4e-6 - 2.5e-10)).abs() < 1e-18);
        // Rolled 90° about x: body y is vertical, z horizontal.
        let rolled = attitude_from_euler(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        let after = variance_after(&rolled, &V3::repeat(4e-6), 0.001, 1.0, 0.02, 0.01);
        assert!((after.y - 4e-6).abs() < 1e-18 && (after.z - (4e-6 - 5e-10)).abs() < 1e-18);
        // At rest or without a pull: unchanged.
        let p = V3::repeat(4e-4);
        assert_eq!(variance_after(&level, &p, 0.0, 1.0, 0.02, 0.01), p);
        assert_eq!(variance_after(&level, &p, 0.001, 0.0, 0.02, 0.01), p);
    }
}
