//! Zero-velocity test statistics over a window of W IMU samples. The
//! extracted paper (Zhang et al. 2024, Sec. 3) lost the formulas; these are
//! the standard forms it cites (Skog et al. 2010), as NOTES.md gives them.
//! Each is stationary where T < γ.
//!
//! FOG gyros at rest read the Earth's rotation. ARE and SHOE here subtract
//! it, projected into the body frame (`earth_rate_b`), before squaring: we
//! implement the first of NOTES.md's two options, so σ_g can stay at the
//! gyro's own noise.
//!
//! Each test is a plain function over a slice (the reference, used in the
//! tests); [`WindowSums`] gives the same four values in O(1) per sample
//! from running sums, which is what the engine runs.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::strapdown::V3;

/// The four statistics of one window, and its mean specific force.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Statistics {
    pub mv: f64,
    pub are: f64,
    pub shoe: f64,
    pub mag: f64,
    /// ȳ_a, m/s² (used to level the platform at alignment).
    pub mean_accel_mps2: V3,
}

/// Noise levels that normalise the statistics and the gravity they test
/// against.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DetectorNoise {
    /// σ_a: accelerometer noise per sample, m/s².
    pub sigma_accel_mps2: f64,
    /// σ_g: gyro noise per sample, rad/s.
    pub sigma_gyro_rad_per_s: f64,
    /// g: local gravity magnitude, m/s².
    pub gravity_mps2: f64,
}

fn mean(samples: &[V3]) -> V3 {
    samples.iter().sum::<V3>() / samples.len().max(1) as f64
}

/// MV, moving variance: T = (1/(σa²·W)) Σ ‖y_a,k − ȳ_a‖².
pub fn mv(accel: &[V3], noise: &DetectorNoise) -> f64 {
    let m = mean(accel);
    let sum: f64 = accel.iter().map(|a| (a - m).norm_squared()).sum();
    sum / (noise.sigma_accel_mps2.powi(2) * accel.len() as f64)
}

/// ARE, angular-rate energy: T = (1/(σg²·W)) Σ ‖y_ω,k − ω_ieᵇ‖².
pub fn are(gyro: &[V3], earth_rate_b: &V3, noise: &DetectorNoise) -> f64 {
    let sum: f64 = gyro.iter().map(|w| (w - earth_rate_b).norm_squared()).sum();
    sum / (noise.sigma_gyro_rad_per_s.powi(2) * gyro.len() as f64)
}

/// SHOE (the paper's GLRT): T = (1/W) Σ [‖y_a,k − g·ȳ_a/‖ȳ_a‖‖²/σa² +
/// ‖y_ω,k − ω_ieᵇ‖²/σg²].
pub fn shoe(accel: &[V3], gyro: &[V3], earth_rate_b: &V3, noise: &DetectorNoise) -> f64 {
    let m = mean(accel);
    let up = m / m.norm().max(f64::MIN_POSITIVE) * noise.gravity_mps2;
    let accel_part: f64 =
        accel.iter().map(|a| (a - up).norm_squared()).sum::<f64>() / noise.sigma_accel_mps2.powi(2);
    let gyro_part: f64 = gyro
        .iter()
        .map(|w| (w - earth_rate_b).norm_squared())
        .sum::<f64>()
        / noise.sigma_gyro_rad_per_s.powi(2);
    (accel_part + gyro_part) / accel.len() as f64
}

/// MAG, acceleration magnitude: T = (1/(σa²·W)) Σ (‖y_a,k‖ − g)².
pub fn mag(accel: &[V3], noise: &DetectorNoise) -> f64 {
    let sum: f64 = accel
        .iter()
        .map(|a| (a.norm() - noise.gravity_mps2).powi(2))
        .sum();
    sum / (noise.sigma_accel_mps2.powi(2) * accel.len() as f64)
}

/// Running sums over the newest W samples, from which all four statistics
/// follow (expanding the squares):
/// - Σ‖a − ā‖² = Σ‖a‖² − W‖ā‖²
/// - Σ‖ω − e‖² = Σ‖ω‖² − 2e·Σω + W‖e‖²
/// - Σ‖a − g·ā/‖ā‖‖² = Σ‖a‖² − 2gW‖ā‖ + Wg²
/// - Σ(‖a‖ − g)² = Σ‖a‖² − 2gΣ‖a‖ + Wg²
///
/// The sums are recomputed from the held samples every W pushes, so
/// rounding cannot accumulate over a months-long stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowSums {
    capacity: usize,
    samples: VecDeque<(V3, V3)>,
    sum_accel: V3,
    sum_accel_sq: f64,
    sum_accel_norm: f64,
    sum_gyro: V3,
    sum_gyro_sq: f64,
    pushes_since_refresh: usize,
}

impl WindowSums {
    /// Empty sums over windows of up to `capacity` samples.
    pub fn new(capacity: usize) -> WindowSums {
        WindowSums {
            capacity: capacity.max(1),
            samples: VecDeque::with_capacity(capacity.max(1)),
            sum_accel: V3::zeros(),
            sum_accel_sq: 0.0,
            sum_accel_norm: 0.0,
            sum_gyro: V3::zeros(),
            sum_gyro_sq: 0.0,
            pushes_since_refresh: 0,
        }
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// True when no sample is held.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Forgets every sample.
    pub fn clear(&mut self) {
        *self = WindowSums::new(self.capacity);
    }

    /// Adds the newest sample (accel m/s², gyro rad/s), dropping the oldest
    /// once `capacity` are held.
    pub fn push(&mut self, accel: V3, gyro: V3) {
        if self.samples.len() == self.capacity {
            self.pop_oldest();
        }
        self.samples.push_back((accel, gyro));
        self.sum_accel += accel;
        self.sum_accel_sq += accel.norm_squared();
        self.sum_accel_norm += accel.norm();
        self.sum_gyro += gyro;
        self.sum_gyro_sq += gyro.norm_squared();
        self.pushes_since_refresh += 1;
        if self.pushes_since_refresh >= self.capacity {
            self.refresh();
        }
    }

    /// Drops the oldest sample (the window's trailing edge moves on).
    pub fn pop_oldest(&mut self) {
        if let Some((accel, gyro)) = self.samples.pop_front() {
            self.sum_accel -= accel;
            self.sum_accel_sq -= accel.norm_squared();
            self.sum_accel_norm -= accel.norm();
            self.sum_gyro -= gyro;
            self.sum_gyro_sq -= gyro.norm_squared();
        }
    }

    fn refresh(&mut self) {
        self.sum_accel = V3::zeros();
        self.sum_accel_sq = 0.0;
        self.sum_accel_norm = 0.0;
        self.sum_gyro = V3::zeros();
        self.sum_gyro_sq = 0.0;
        for (accel, gyro) in &self.samples {
            self.sum_accel += accel;
            self.sum_accel_sq += accel.norm_squared();
            self.sum_accel_norm += accel.norm();
            self.sum_gyro += gyro;
            self.sum_gyro_sq += gyro.norm_squared();
        }
        self.pushes_since_refresh = 0;
    }

    /// The statistics of the held samples; `None` when there are none.
    pub fn statistics(&self, earth_rate_b: &V3, noise: &DetectorNoise) -> Option<Statistics> {
        if self.samples.is_empty() {
            return None;
        }
        let w = self.samples.len() as f64;
        let g = noise.gravity_mps2;
        let var_a = noise.sigma_accel_mps2.powi(2);
        let var_g = noise.sigma_gyro_rad_per_s.powi(2);
        let mean_accel = self.sum_accel / w;
        let mean_norm = mean_accel.norm();
        // Rounding can make a sum of squares a hair negative: clamp at 0.
        let spread = (self.sum_accel_sq - w * mean_norm * mean_norm).max(0.0);
        let gyro_energy = (self.sum_gyro_sq - 2.0 * earth_rate_b.dot(&self.sum_gyro)
            + w * earth_rate_b.norm_squared())
        .max(0.0);
        let off_gravity = (self.sum_accel_sq - 2.0 * g * w * mean_norm + w * g * g).max(0.0);
        let off_magnitude =
            (self.sum_accel_sq - 2.0 * g * self.sum_accel_norm + w * g * g).max(0.0);
        Some(Statistics {
            mv: spread / (var_a * w),
            are: gyro_energy / (var_g * w),
            shoe: (off_gravity / var_a + gyro_energy / var_g) / w,
            mag: off_magnitude / (var_a * w),
            mean_accel_mps2: mean_accel,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NOISE: DetectorNoise = DetectorNoise {
        sigma_accel_mps2: 0.01,
        sigma_gyro_rad_per_s: 0.001,
        gravity_mps2: 9.8,
    };

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn a_still_window_scores_zero_on_every_test() {
        let accel = vec![V3::new(0.0, 0.0, -9.8); 10];
        let earth = V3::new(5e-5, 0.0, -4e-5);
        let gyro = vec![earth; 10];
        assert!(mv(&accel, &NOISE) < 1e-20);
        assert!(are(&gyro, &earth, &NOISE) < 1e-20);
        assert!(shoe(&accel, &gyro, &earth, &NOISE) < 1e-20);
        assert!(mag(&accel, &NOISE) < 1e-20);
    }

    #[test]
    fn hand_computed_windows() {
        // Two samples ±0.01 m/s² about the mean along x: each deviates by
        // one σ, so MV = (1 + 1)/(1·2) = 1.
        let g = V3::new(0.0, 0.0, -9.8);
        let accel = [g + V3::new(0.01, 0.0, 0.0), g - V3::new(0.01, 0.0, 0.0)];
        assert!(close(mv(&accel, &NOISE), 1.0));
        // Gyro 2σ on one axis, 0 on the other sample: (4 + 0)/2 = 2.
        let gyro = [V3::new(0.0, 0.002, 0.0), V3::zeros()];
        assert!(close(are(&gyro, &V3::zeros(), &NOISE), 2.0));
        // The Earth rate is removed before squaring.
        let earth = V3::new(0.0, 0.002, 0.0);
        assert!(close(are(&[earth, earth], &earth, &NOISE), 0.0));
        // MAG: |a| = 9.83 against g = 9.8 is 3σ: 9 per sample.
        let heavy = [V3::new(0.0, 0.0, -9.83); 4];
        assert!(close(mag(&heavy, &NOISE), 9.0));
        // SHOE sees the same 3σ magnitude error plus the gyro term.
        let gyro4 = [V3::new(0.001, 0.0, 0.0); 4];
        assert!(close(shoe(&heavy, &gyro4, &V3::zeros(), &NOISE), 9.0 + 1.0));
        // A tilted but still platform: MV, MAG and SHOE stay at 0.
        let tilted = [V3::new(9.8 * 0.1_f64.sin(), 0.0, -9.8 * 0.1_f64.cos()); 3];
        assert!(mv(&tilted, &NOISE) < 1e-12);
        assert!(mag(&tilted, &NOISE) < 1e-12);
        assert!(shoe(&tilted, &[V3::zeros(); 3], &V3::zeros(), &NOISE) < 1e-12);
    }

    #[test]
    fn constant_velocity_fools_mv_and_mag_but_not_a_vibrating_gyro() {
        // Gliding at constant speed: the specific force is gravity alone.
        let accel = vec![V3::new(0.0, 0.0, -9.8); 50];
        let gyro: Vec<V3> = (0..50)
            .map(|k| V3::new(0.0, 0.01 * (k as f64 * 0.7).sin(), 0.0))
            .collect();
        assert!(mv(&accel, &NOISE) < 1.0);
        assert!(mag(&accel, &NOISE) < 1.0);
        assert!(are(&gyro, &V3::zeros(), &NOISE) > 10.0);
        assert!(shoe(&accel, &gyro, &V3::zeros(), &NOISE) > 10.0);
    }

    #[test]
    fn running_sums_match_the_slice_functions() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let earth = V3::new(6e-5, 0.0, -3e-5);
        let mut sums = WindowSums::new(25);
        let mut all: Vec<(V3, V3)> = Vec::new();
        for k in 0..400 {
            let scale = if (k / 60) % 2 == 0 { 0.01 } else { 1.0 };
            let accel = V3::new(next() * scale, next() * scale, -9.8 + next() * scale);
            let gyro = V3::new(next(), next(), next()) * scale * 0.01;
            sums.push(accel, gyro);
            all.push((accel, gyro));
            let window = &all[all.len().saturating_sub(25)..];
            let a: Vec<V3> = window.iter().map(|s| s.0).collect();
            let w: Vec<V3> = window.iter().map(|s| s.1).collect();
            let s = sums.statistics(&earth, &NOISE).unwrap();
            assert!(close(s.mv, mv(&a, &NOISE)) || (s.mv - mv(&a, &NOISE)).abs() < 1e-4);
            assert!(close(s.are, are(&w, &earth, &NOISE)));
            let reference = shoe(&a, &w, &earth, &NOISE);
            assert!((s.shoe - reference).abs() < 1e-6 * (1.0 + reference), "{k}");
            let reference = mag(&a, &NOISE);
            assert!((s.mag - reference).abs() < 1e-6 * (1.0 + reference), "{k}");
        }
        // The trailing edge can also be moved by hand (end of a stream).
        sums.pop_oldest();
        assert_eq!(sums.len(), 24);
    }
}
