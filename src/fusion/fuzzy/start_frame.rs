//! Gravity found in a frame the gyros hold still, for an alignment while
//! moving (docs/engines/fuzzy.md: step 6).
//!
//! A body that turns under a window has no meaningful mean body-frame
//! force: averaged over half a turn, gravity's direction cancels. From the
//! first reading on, the gyros carry the body's turn since then, q (body
//! now → body at the start, integrated like the attitude), and each force
//! is summed in the start's frame, q·f. Over seconds that mean is
//! gravity's direction there: what the body's own acceleration adds
//! averages to Δv/T (a hand that ends where it began adds nothing). The
//! start's tilt follows from it, and today's attitude is that tilt carried
//! by q: the coarse alignment in an inertially held frame of strapdown
//! navigation, with the Earth's rotation (0.004 °/s) left out.
//!
//! Its σ is estimated from the data by batch means: the forces are summed
//! in batches of [`BATCH_S`], and the spread of the batch means over √(the
//! number of batches) is how far their overall mean may be off; a mean
//! whose size is not gravity's adds that difference; an unknown gyro bias
//! turns the frame by up to σ_b·T over the span T, half of it on average.

use nalgebra::UnitQuaternion;
use serde::{Deserialize, Serialize};

use crate::fusion::geometry::{V3, attitude_from_euler};

use super::orientation::{integrate, tilt_from_accel};

/// Length of one batch of forces, s.
pub const BATCH_S: f64 = 0.25;
/// A span longer than this starts again (the unknown bias would turn the
/// frame too far), s; the engine allows twice `align_without_rest_s` if
/// that is longer.
pub const MAX_SPAN_S: f64 = 30.0;

/// The forces since the first reading, summed in its body frame.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct StartFrame {
    /// Time of the first reading, s.
    start_t: Option<f64>,
    /// Body now → body at the start.
    turn: UnitQuaternion<f64>,
    /// Completed batches: (sum of q·f, count).
    batches: Vec<(V3, u32)>,
    /// The batch being filled and when it began.
    current: (V3, u32),
    current_start_t: f64,
}

/// What the span says of the attitude now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// Body → level frame with yaw 0 at the start; tilt as now.
    pub attitude: UnitQuaternion<f64>,
    /// 1σ of the tilt, rad.
    pub tilt_sigma_rad: f64,
    /// How far the mean force's size is from `gravity_mps2`, m/s².
    pub gravity_error_mps2: f64,
    /// The span's length, s.
    pub span_s: f64,
}

impl StartFrame {
    /// Forgets everything (a gap in the readings).
    pub fn clear(&mut self) {
        *self = StartFrame::default();
    }

    /// Seconds since the first reading of the span (0 before it).
    pub fn span_s(&self, t: f64) -> f64 {
        self.start_t.map_or(0.0, |start| t - start)
    }

    /// Adds a reading: `rate_rad_per_s` turned the body over the `dt_s`
    /// before `t`, and `force_mps2` is the specific force at `t`; a span
    /// longer than `longest_s` starts again.
    pub fn push(
        &mut self,
        t: f64,
        force_mps2: &V3,
        rate_rad_per_s: &V3,
        dt_s: f64,
        longest_s: f64,
    ) {
        match self.start_t {
            Some(start) if t - start > longest_s => self.clear(),
            Some(_) => self.turn = integrate(&self.turn, rate_rad_per_s, dt_s),
            None => {}
        }
        if self.start_t.is_none() {
            self.start_t = Some(t);
            self.current_start_t = t;
        }
        if t - self.current_start_t >= BATCH_S && self.current.1 > 0 {
            self.batches.push(self.current);
            self.current = (V3::zeros(), 0);
            self.current_start_t = t;
        }
        self.current.0 += self.turn * force_mps2;
        self.current.1 += 1;
    }

    /// The attitude now from the span's mean force, once it holds at
    /// least two whole batches; `bias_sigma_rad_per_s` is how far the
    /// gyro bias may be off (the integration used none).
    pub fn alignment(
        &self,
        t: f64,
        gravity_mps2: f64,
        bias_sigma_rad_per_s: f64,
    ) -> Option<Alignment> {
        if self.batches.len() < 2 {
            return None;
        }
        let (sum, count) = self
            .batches
            .iter()
            .chain(std::iter::once(&self.current))
            .fold((V3::zeros(), 0u32), |(s, n), (bs, bn)| (s + bs, n + bn));
        let mean = sum / f64::from(count.max(1));
        let batch_means: Vec<V3> = self
            .batches
            .iter()
            .map(|(s, n)| s / f64::from((*n).max(1)))
            .collect();
        let b = batch_means.len() as f64;
        let batch_mean = batch_means.iter().sum::<V3>() / b;
        let spread = (batch_means
            .iter()
            .map(|m| (m - batch_mean).norm_squared())
            .sum::<f64>()
            / (b - 1.0))
            .sqrt();
        let gravity_error = (mean.norm() - gravity_mps2).abs();
        let span_s = self.span_s(t);
        let from_force = ((gravity_error + spread / b.sqrt()) / gravity_mps2.max(1e-9)).atan();
        let from_bias = 0.5 * bias_sigma_rad_per_s * span_s;
        let (roll, pitch) = tilt_from_accel(&mean);
        let start = attitude_from_euler(roll, pitch, 0.0);
        Some(Alignment {
            attitude: start * self.turn,
            tilt_sigma_rad: (from_force.powi(2) + from_bias.powi(2)).sqrt(),
            gravity_error_mps2: gravity_error,
            span_s,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A body spinning at 200 °/s about an axis 17° above its x axis, for
    /// two whole turns, from a start rolled 6° and pitched up 20°: its mean
    /// body-frame force is only the part of gravity along the spin axis
    /// (about 0.5 m/s²), the start frame's is gravity.
    #[test]
    fn a_spinning_body_finds_gravity_in_its_start_frame() {
        let g = 9.81;
        let rate = V3::new(0.3f64.cos(), 0.0, 0.3f64.sin()) * 200f64.to_radians();
        let start = attitude_from_euler(0.1, 0.35, 1.0);
        let dt = 0.005;
        let mut frame = StartFrame::default();
        let mut truth = start;
        let mut body_sum = V3::zeros();
        let steps = 720; // 3.6 s: two turns
        for k in 0..=steps {
            if k > 0 {
                truth *= UnitQuaternion::from_scaled_axis(rate * dt);
            }
            let force = truth.inverse() * V3::new(0.0, 0.0, -g);
            body_sum += force;
            frame.push(f64::from(k) * dt, &force, &rate, dt, MAX_SPAN_S);
        }
        let body_mean = body_sum / f64::from(steps + 1);
        assert!(body_mean.norm() < 0.1 * g, "{}", body_mean.norm());
        let alignment = frame.alignment(3.6, g, 0.0).unwrap();
        // Tilt right: the true body's down axis, as the estimate sees it.
        let down_true = truth.inverse() * V3::z();
        let down_estimated = alignment.attitude.inverse() * V3::z();
        assert!(down_true.angle(&down_estimated) < 1e-6);
        assert!(alignment.gravity_error_mps2 < 1e-9);
        assert!(alignment.tilt_sigma_rad < 1e-6);
        assert!((alignment.span_s - 3.6).abs() < 1e-9);
    }

    #[test]
    fn an_acceleration_that_comes_and_goes_widens_the_sigma() {
        let g = 9.81;
        let mut frame = StartFrame::default();
        let dt = 0.01;
        // Level and still, shaken along x at 1 Hz with 3 m/s² for 2 s.
        for k in 0..=200 {
            let t = f64::from(k) * dt;
            let shake = 3.0 * (std::f64::consts::TAU * t).sin();
            frame.push(t, &V3::new(shake, 0.0, -g), &V3::zeros(), dt, MAX_SPAN_S);
        }
        let alignment = frame.alignment(2.0, g, 0.0).unwrap();
        // Eight batches of a quarter second: their means differ by about
        // ±1.9 m/s², so σ is a few degrees; the mean itself is near level.
        assert!(
            alignment.tilt_sigma_rad > 1f64.to_radians(),
            "{}",
            alignment.tilt_sigma_rad
        );
        assert!(alignment.tilt_sigma_rad < 10f64.to_radians());
        let (roll, pitch, _) = alignment.attitude.euler_angles();
        assert!(roll.hypot(pitch) < 2f64.to_radians());
        // An unknown bias of 1 °/s over 2 s adds half of 2°.
        let biased = frame.alignment(2.0, g, 1f64.to_radians()).unwrap();
        assert!(biased.tilt_sigma_rad > alignment.tilt_sigma_rad);
        assert!(biased.tilt_sigma_rad >= 1f64.to_radians() - 1e-12);
        // Too young: one batch.
        let mut young = StartFrame::default();
        young.push(0.0, &V3::new(0.0, 0.0, -g), &V3::zeros(), dt, MAX_SPAN_S);
        young.push(0.3, &V3::new(0.0, 0.0, -g), &V3::zeros(), dt, MAX_SPAN_S);
        assert!(young.alignment(0.3, g, 0.0).is_none());
    }
}
