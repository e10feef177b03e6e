//! Tail clearance: the gap between the shield's tail skin and the ring in
//! it, measured at N points evenly round the ring, clockwise from the top,
//! looking forward (φᵢ = i·2π/N).
//!
//! A ring whose centre lies e = (right, up) off the tail's centre has, to
//! first order in e, the gap
//!
//!   cᵢ = m − e_right·sin φᵢ − e_up·cos φᵢ
//!
//! where m is the gap of a centred ring (the skin's radius less the
//! ring's). With N ≥ 4 points evenly round, the sines and cosines are
//! orthogonal, so the least-squares fit is
//!
//!   m = Σcᵢ/N,  e_right = −(2/N)·Σcᵢ·sin φᵢ,  e_up = −(2/N)·Σcᵢ·cos φᵢ,
//!
//! and what it leaves (an oval ring, a gauge's error) is the residual,
//! whose spread tells how well the fit places the ring.

/// The fewest points a clearance measurement has.
pub const MIN_POINTS: usize = 4;
/// The most.
pub const MAX_POINTS: usize = 64;

/// A measured clearance, fitted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClearanceFit {
    /// The gap of a centred ring, mm.
    pub mean_mm: f64,
    /// The ring's centre off the tail's centre, mm: right, up.
    pub offset_mm: [f64; 2],
    /// The standard error of each offset, mm, from the residual's spread
    /// (`None` with 4 points or fewer degrees of freedom than 1).
    pub offset_sigma_mm: Option<f64>,
}

/// The angle of point `i` of `points`, rad clockwise from the top.
pub fn point_angle_rad(i: usize, points: usize) -> f64 {
    i as f64 * std::f64::consts::TAU / points as f64
}

/// Fits `clearances_mm` (N ≥ 4 points evenly round); `None` with fewer.
pub fn fit(clearances_mm: &[f64]) -> Option<ClearanceFit> {
    let n = clearances_mm.len();
    if n < MIN_POINTS {
        return None;
    }
    let nf = n as f64;
    let mean_mm = clearances_mm.iter().sum::<f64>() / nf;
    let (mut sin_sum, mut cos_sum) = (0.0, 0.0);
    for (i, c) in clearances_mm.iter().enumerate() {
        let phi = point_angle_rad(i, n);
        sin_sum += c * phi.sin();
        cos_sum += c * phi.cos();
    }
    let offset_mm = [-2.0 / nf * sin_sum, -2.0 / nf * cos_sum];
    let residual_sq: f64 = clearances_mm
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let predicted = predict_one(mean_mm, offset_mm, point_angle_rad(i, n));
            (c - predicted).powi(2)
        })
        .sum();
    // Three values fitted: N − 3 degrees of freedom; each offset's
    // variance is σ²·2/N.
    let offset_sigma_mm = (n > 3).then(|| (residual_sq / (nf - 3.0) * 2.0 / nf).sqrt());
    Some(ClearanceFit {
        mean_mm,
        offset_mm,
        offset_sigma_mm,
    })
}

/// The gap at angle `phi_rad` of a ring `offset_mm` off the tail's centre.
pub fn predict_one(mean_mm: f64, offset_mm: [f64; 2], phi_rad: f64) -> f64 {
    mean_mm - offset_mm[0] * phi_rad.sin() - offset_mm[1] * phi_rad.cos()
}

/// The gaps at `points` evenly round of a ring `offset_mm` off the tail's
/// centre.
pub fn predict(mean_mm: f64, offset_mm: [f64; 2], points: usize) -> Vec<f64> {
    (0..points)
        .map(|i| predict_one(mean_mm, offset_mm, point_angle_rad(i, points)))
        .collect()
}
