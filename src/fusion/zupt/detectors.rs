//! Zero-velocity test statistics over a window of W IMU samples. The
//! extracted paper (Zhang et al. 2024, Sec. 3) lost the formulas; these are
//! the standard forms it cites (Skog et al. 2010; docs/papers.md).
//! Each is stationary where T < γ.
//!
//! FOG gyros at rest read the Earth's rotation. ARE and SHOE here subtract
//! it, projected into the body frame (`earth_rate_b`), before squaring: we
//! take the first of the two ways out (docs/papers.md), so σ_g can stay at the
//! gyro's own noise.
//!
//! Each test is a plain function over a slice (the reference, used in the
//! tests); [`WindowSums`] gives the same four values in O(1) per sample
//! from running sums, which is what the engine runs.
//!
//! **Integrated signals** ([`Signals::Integrated`], the default). Running
//! machinery shakes a standing machine with a steady vibration of a few mg
//! at tens of Hz: zero-mean, so the velocity it causes is a fraction of a
//! millimetre per second, yet MV and ARE see its acceleration and rate at
//! full strength. Tested on what the window integrates to instead, a
//! steady tone of frequency f counts 3/(W sin²(π f Δt)) times what it
//! counts in the raw forms (Δt the sample period): a twentieth at 30 Hz, a
//! twelfth at 20 Hz with W = 100 at 100 Hz. Motion, which changes velocity
//! and angle over the window, counts in full:
//! - MVᵥ = 12 Σₖ ‖Vₖ − V̄‖² / (σa² W²), Vₖ = Σ_{j≤k} (y_a,j − ȳ_a), the
//!   velocity change within the window over Δt (de-meaned, so gravity and
//!   the accelerometer bias drop out);
//! - AREθ = 12 Σₖ ‖Θₖ − Θ̄‖² / (σg² W²) + ‖ȳ_ω − ω_ieᵇ‖²/σg², Θₖ =
//!   Σ_{j≤k} (y_ω,j − ȳ_ω), the angle the window's rate fluctuations turn
//!   it through over Δt, plus the mean rate as the raw ARE counts it (the
//!   raw Σ‖y_ω − ω_ieᵇ‖² splits into the two): a steady turn counts as in
//!   ARE, and a steady error in the Earth rate subtracted (a heading not
//!   yet known) no more than there, where integrating it would make it
//!   count W/2 times as much;
//! - SHOEᵥ = MVᵥ + AREθ; MAG stays as it is.
//!
//! Their normalisers make white noise of σa and σg score 3 at rest, as MV
//! and ARE do: the de-meaned sums V and Θ are discrete Brownian bridges,
//! with E Σₖ ‖Vₖ − V̄‖² = 3σa²(W² − 1)/12 ≈ 3σa²W²/12 (the mean-rate term
//! adds 3/W). Both are computed from the held window in O(W).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

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

crate::fusion::params::choice_enum! {
    /// What the statistics are computed on (the `detector_signals` parameter).
    pub enum Signals {
        /// What the window integrates them to (module doc): steady vibration
        /// at rest hardly counts.
        Integrated = "integrated",
        /// The samples themselves: the paper's MV, ARE, SHOE, MAG.
        Raw = "raw",
    }
}

/// Σₖ ‖Sₖ − S̄‖² for the running sums Sₖ = Σ_{j≤k} xⱼ.
fn running_sum_spread(xs: impl Iterator<Item = V3>) -> f64 {
    let mut running = V3::zeros();
    let sums: Vec<V3> = xs
        .map(|x| {
            running += x;
            running
        })
        .collect();
    let centre = mean(&sums);
    sums.iter().map(|v| (v - centre).norm_squared()).sum()
}

/// MVᵥ over a window (module doc).
pub fn mv_integrated(accel: &[V3], noise: &DetectorNoise) -> f64 {
    let m = mean(accel);
    let w = accel.len() as f64;
    12.0 * running_sum_spread(accel.iter().map(|a| a - m))
        / (noise.sigma_accel_mps2.powi(2) * w * w)
}

/// AREθ over a window (module doc).
pub fn are_integrated(gyro: &[V3], earth_rate_b: &V3, noise: &DetectorNoise) -> f64 {
    let m = mean(gyro);
    let w = gyro.len() as f64;
    let var_g = noise.sigma_gyro_rad_per_s.powi(2);
    12.0 * running_sum_spread(gyro.iter().map(|g| g - m)) / (var_g * w * w)
        + (m - earth_rate_b).norm_squared() / var_g
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

    /// The statistics of the held samples on `signals`; `None` when there
    /// are none.
    pub fn statistics(
        &self,
        earth_rate_b: &V3,
        noise: &DetectorNoise,
        signals: Signals,
    ) -> Option<Statistics> {
        let mut statistics = self.raw_statistics(earth_rate_b, noise)?;
        if signals == Signals::Integrated {
            let (mv, are) = self.integrated(earth_rate_b, noise, &statistics.mean_accel_mps2);
            statistics.mv = mv;
            statistics.are = are;
            statistics.shoe = mv + are;
        }
        Some(statistics)
    }

    /// MVᵥ and AREθ of the held samples, one pass: the running sums V, Θ
    /// and their first and second moments.
    fn integrated(&self, earth_rate_b: &V3, noise: &DetectorNoise, mean_accel: &V3) -> (f64, f64) {
        let w = self.samples.len() as f64;
        let mean_gyro = self.sum_gyro / w;
        let (mut v, mut theta) = (V3::zeros(), V3::zeros());
        let (mut sum_v, mut sum_theta) = (V3::zeros(), V3::zeros());
        let (mut sq_v, mut sq_theta) = (0.0, 0.0);
        for (accel, gyro) in &self.samples {
            v += accel - mean_accel;
            theta += gyro - mean_gyro;
            sum_v += v;
            sum_theta += theta;
            sq_v += v.norm_squared();
            sq_theta += theta.norm_squared();
        }
        let spread_v = (sq_v - sum_v.norm_squared() / w).max(0.0);
        let spread_theta = (sq_theta - sum_theta.norm_squared() / w).max(0.0);
        let var_g = noise.sigma_gyro_rad_per_s.powi(2);
        (
            12.0 * spread_v / (noise.sigma_accel_mps2.powi(2) * w * w),
            12.0 * spread_theta / (var_g * w * w)
                + (mean_gyro - earth_rate_b).norm_squared() / var_g,
        )
    }

    /// The paper's statistics of the held samples.
    fn raw_statistics(&self, earth_rate_b: &V3, noise: &DetectorNoise) -> Option<Statistics> {
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

    /// Uniform on [−0.5, 0.5) from a seeded xorshift (independent of
    /// the code under test).
    fn centred_uniform(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

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
        let mut next = centred_uniform(0x9e37_79b9_7f4a_7c15);
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
            let s = sums.statistics(&earth, &NOISE, Signals::Raw).unwrap();
            assert!(close(s.mv, mv(&a, &NOISE)) || (s.mv - mv(&a, &NOISE)).abs() < 1e-4);
            assert!(close(s.are, are(&w, &earth, &NOISE)));
            let reference = shoe(&a, &w, &earth, &NOISE);
            assert!((s.shoe - reference).abs() < 1e-6 * (1.0 + reference), "{k}");
            let reference = mag(&a, &NOISE);
            assert!((s.mag - reference).abs() < 1e-6 * (1.0 + reference), "{k}");
            let i = sums
                .statistics(&earth, &NOISE, Signals::Integrated)
                .unwrap();
            let reference = mv_integrated(&a, &NOISE);
            assert!((i.mv - reference).abs() < 1e-6 * (1.0 + reference), "{k}");
            let reference = are_integrated(&w, &earth, &NOISE);
            assert!((i.are - reference).abs() < 1e-6 * (1.0 + reference), "{k}");
            assert_eq!(i.shoe, i.mv + i.are);
        }
        // The trailing edge can also be moved by hand (end of a stream).
        sums.pop_oldest();
        assert_eq!(sums.len(), 24);
    }

    #[test]
    fn integrated_statistics_by_hand() {
        // Accelerations +d, −d, +d, −d about the mean along x: the running
        // sums V are d, 0, d, 0 (mean d/2), Σ(V − V̄)² = 4·(d/2)² = d²;
        // MVᵥ = 12 d² / (σ² · 16) = 0.75 at d = σ.
        let g = V3::new(0.0, 0.0, -9.8);
        let d = V3::new(NOISE.sigma_accel_mps2, 0.0, 0.0);
        let accel = [g + d, g - d, g + d, g - d];
        assert!(close(mv_integrated(&accel, &NOISE), 0.75));
        // A steady turn at r = σ about z: no fluctuation, the mean rate
        // counts r²/σ² = 1, as in the raw ARE.
        let earth = V3::new(1e-5, 0.0, 2e-5);
        let r = V3::new(0.0, 0.0, NOISE.sigma_gyro_rad_per_s);
        let gyro = [earth + r; 4];
        assert!(close(are_integrated(&gyro, &earth, &NOISE), 1.0));
        assert!(close(are(&gyro, &earth, &NOISE), 1.0));
        // Rates +σ, −σ, +σ, −σ about the Earth's: Θ = σ, 0, σ, 0, spread
        // σ², AREθ = 12σ²/(σ²·16) = 0.75, the mean term 0.
        let gyro = [earth + r, earth - r, earth + r, earth - r];
        assert!(close(are_integrated(&gyro, &earth, &NOISE), 0.75));
    }

    #[test]
    fn steady_vibration_hardly_counts_once_integrated() {
        // 5 mg at 30 Hz vertically, sampled at 100 Hz, W = 100, no noise,
        // σ = 0.005 m/s²: raw MV = (A²/2)/σ² = 48. The running sum of the
        // tone has amplitude A/(2 sin(π·0.3)), so MVᵥ = 12/W · A²/(8
        // sin²(0.3π)) / σ² = 3/(W sin²(0.3π)) × raw = 0.0458 × raw.
        let noise = DetectorNoise {
            sigma_accel_mps2: 0.005,
            ..NOISE
        };
        let amplitude = 5e-3 * 9.80665;
        let omega = std::f64::consts::TAU * 30.0;
        let accel: Vec<V3> = (0..100)
            .map(|k| V3::new(0.0, 0.0, -9.8 + amplitude * (omega * k as f64 * 0.01).sin()))
            .collect();
        let raw = mv(&accel, &noise);
        let integrated = mv_integrated(&accel, &noise);
        assert!(
            (raw - (amplitude * amplitude / 2.0) / 0.005_f64.powi(2)).abs() < 1.0,
            "{raw}"
        );
        let expected = 3.0 / (100.0 * (0.3 * std::f64::consts::PI).sin().powi(2)) * raw;
        assert!(
            (integrated - expected).abs() < 0.05 * expected,
            "{integrated} vs {expected}"
        );
        assert!(integrated < 3.0);
        // Streaming gives the same.
        let mut sums = WindowSums::new(100);
        for a in &accel {
            sums.push(*a, V3::zeros());
        }
        let s = sums
            .statistics(&V3::zeros(), &noise, Signals::Integrated)
            .unwrap();
        assert!((s.mv - integrated).abs() < 1e-9 * (1.0 + integrated));
        assert!((s.shoe - s.mv - s.are).abs() < 1e-12);
    }

    #[test]
    fn integrated_white_noise_scores_about_three() {
        // Uniform noise of variance σ² on every axis (σ = 0.01 / 0.001):
        // the normalisers make the mean of both statistics ≈ 3.
        // Uniform on ±√3: variance 1.
        let mut uniform = centred_uniform(0x2545_f491_4f6c_dd1d);
        let mut next = move || uniform() * 2.0 * 3f64.sqrt();
        let (mut sum_mv, mut sum_are, windows) = (0.0, 0.0, 2000);
        for _ in 0..windows {
            let accel: Vec<V3> = (0..100)
                .map(|_| V3::new(next(), next(), next()) * 0.01 + V3::new(0.0, 0.0, -9.8))
                .collect();
            let gyro: Vec<V3> = (0..100)
                .map(|_| V3::new(next(), next(), next()) * 0.001)
                .collect();
            sum_mv += mv_integrated(&accel, &NOISE);
            sum_are += are_integrated(&gyro, &V3::zeros(), &NOISE);
        }
        let (mean_mv, mean_are) = (sum_mv / windows as f64, sum_are / windows as f64);
        assert!((mean_mv - 3.0).abs() < 0.15, "{mean_mv}");
        assert!((mean_are - 3.0).abs() < 0.15, "{mean_are}");
    }
}
