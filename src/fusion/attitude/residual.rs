//! What the ANFIS leaves over, smoothed along the roll: a kernel
//! (Nadaraya–Watson) smoother of the training pairs' residuals, added to
//! the model's output (a second, local stage after the global fit).
//!
//! A few Gaussian rules spread over the whole seen roll cannot follow an
//! error that turns faster than they are wide (a ripple, the edge of the
//! range where few pairs are), and the filter's bias then carries that
//! miss as if it held at every roll — through a dropout it does not. The
//! residuals near a roll say what the model misses there:
//!
//! m(β) = Σ w_i K((β − β_i)/h) r_i / (Σ w_i K((β − β_i)/h) + 1)
//!
//! with w_i the pairs' recency weights, K a Gaussian, and the 1 a prior of
//! one fresh pair at zero residual (a lone pair does not set the local
//! correction by itself). The width h is chosen from the data: among a
//! quarter, a half and one of the model's mean membership width — or no
//! smoothing at all — the one with the least weighted leave-one-out error
//! wins. For speed the pairs are binned on a grid of h/4 and the kernel is
//! a convolution over the bins (a pair sits at most h/8 from its bin's
//! centre); the table holds m at every bin and is read by linear
//! interpolation, held at its ends.
//!
//! All angles are radians.

use serde::{Deserialize, Serialize};

/// Grid bins per kernel width.
const BINS_PER_WIDTH: f64 = 4.0;
/// The kernel is cut four widths from its centre (e^{−8}).
const KERNEL_WIDTHS: f64 = 4.0;
/// Candidate kernel widths, as shares of the model's mean membership width.
const WIDTH_SHARES: [f64; 3] = [0.25, 0.5, 1.0];
/// Most bins a table may hold (a bound on the cost and the snapshot).
const MAX_BINS: usize = 4096;
/// The prior's weight: one fresh pair at zero residual.
const PRIOR_WEIGHT: f64 = 1.0;

/// One residual of the model at a training pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Residual {
    pub roll_rad: f64,
    /// Recency weight of the pair.
    pub weight: f64,
    /// The pair's error less the model's output there.
    pub residual_rad: f64,
}

/// The smoothed residual m(β) on a grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualTable {
    /// Roll of the first bin's centre.
    pub lo_rad: f64,
    /// Spacing of the bins.
    pub step_rad: f64,
    /// The kernel width chosen.
    pub width_rad: f64,
    /// m at each bin's centre.
    pub values_rad: Vec<f64>,
}

impl ResidualTable {
    /// The smoother for `residuals` over `[lo_rad, hi_rad]` (their roll
    /// range), or `None` when leave-one-out prefers no smoothing at all,
    /// for fewer than two residuals, or when no candidate width's grid
    /// fits in [`MAX_BINS`]. `mean_width_rad` is the model's mean
    /// membership width.
    pub fn fit(
        residuals: &[Residual],
        lo_rad: f64,
        hi_rad: f64,
        mean_width_rad: f64,
    ) -> Option<ResidualTable> {
        let usable = mean_width_rad > 0.0 && hi_rad >= lo_rad;
        if residuals.len() < 2 || !usable {
            return None;
        }
        let unsmoothed: f64 = residuals
            .iter()
            .map(|r| r.weight * r.residual_rad * r.residual_rad)
            .sum();
        let mut best: Option<(f64, ResidualTable)> = None;
        for share in WIDTH_SHARES {
            let width = share * mean_width_rad;
            let Some(grid) = Grid::binned(residuals, lo_rad, hi_rad, width) else {
                continue;
            };
            let score = grid.leave_one_out(residuals);
            if score < unsmoothed && best.as_ref().is_none_or(|(s, _)| score < *s) {
                best = Some((score, grid.table()));
            }
        }
        best.map(|(_, table)| table)
    }

    /// m(β): linear between bin centres, held beyond the ends.
    pub fn at(&self, roll_rad: f64) -> f64 {
        let n = self.values_rad.len();
        if n == 0 {
            return 0.0;
        }
        let spaced = self.step_rad > 0.0;
        if n == 1 || !spaced {
            return self.values_rad[0];
        }
        let u = ((roll_rad - self.lo_rad) / self.step_rad).clamp(0.0, (n - 1) as f64);
        let i = (u.floor() as usize).min(n - 2);
        let f = u - i as f64;
        self.values_rad[i] * (1.0 - f) + self.values_rad[i + 1] * f
    }

    /// True when every number in the table is usable (a restored snapshot
    /// is checked with it).
    pub fn is_valid(&self) -> bool {
        self.lo_rad.is_finite()
            && self.step_rad.is_finite()
            && self.step_rad > 0.0
            && self.width_rad.is_finite()
            && self.width_rad > 0.0
            && !self.values_rad.is_empty()
            && self.values_rad.len() <= MAX_BINS
            && self.values_rad.iter().all(|v| v.is_finite())
    }
}

/// The binned sums and their convolution with the kernel, for one width.
struct Grid {
    lo_rad: f64,
    step_rad: f64,
    width_rad: f64,
    /// Σ w K and Σ w K r at each bin's centre.
    weight: Vec<f64>,
    weighted_rad: Vec<f64>,
}

impl Grid {
    fn binned(residuals: &[Residual], lo_rad: f64, hi_rad: f64, width_rad: f64) -> Option<Grid> {
        let step = width_rad / BINS_PER_WIDTH;
        let spaced = step > 0.0 && (hi_rad - lo_rad) / step < (MAX_BINS - 1) as f64;
        if !spaced {
            return None;
        }
        let bins = ((hi_rad - lo_rad) / step).round() as usize + 1;
        let mut weight = vec![0.0; bins];
        let mut weighted_rad = vec![0.0; bins];
        for r in residuals {
            let i = Self::bin(lo_rad, step, bins, r.roll_rad);
            weight[i] += r.weight;
            weighted_rad[i] += r.weight * r.residual_rad;
        }
        let reach = (KERNEL_WIDTHS * BINS_PER_WIDTH) as usize;
        let kernel: Vec<f64> = (0..=reach)
            .map(|k| (-0.5 * (k as f64 / BINS_PER_WIDTH).powi(2)).exp())
            .collect();
        let convolve = |sums: &[f64]| -> Vec<f64> {
            (0..bins)
                .map(|i| {
                    let from = i.saturating_sub(reach);
                    let to = (i + reach).min(bins - 1);
                    (from..=to).map(|j| kernel[i.abs_diff(j)] * sums[j]).sum()
                })
                .collect()
        };
        Some(Grid {
            lo_rad,
            step_rad: step,
            width_rad,
            weight: convolve(&weight),
            weighted_rad: convolve(&weighted_rad),
        })
    }

    fn bin(lo_rad: f64, step_rad: f64, bins: usize, roll_rad: f64) -> usize {
        (((roll_rad - lo_rad) / step_rad).round().max(0.0) as usize).min(bins - 1)
    }

    /// Σ w_i (r_i − m₋ᵢ(β_i))², m₋ᵢ the smoother without pair i.
    fn leave_one_out(&self, residuals: &[Residual]) -> f64 {
        let bins = self.weight.len();
        residuals
            .iter()
            .map(|r| {
                let i = Self::bin(self.lo_rad, self.step_rad, bins, r.roll_rad);
                let others = self.weighted_rad[i] - r.weight * r.residual_rad;
                let others_weight = (self.weight[i] - r.weight).max(0.0);
                let m = others / (others_weight + PRIOR_WEIGHT);
                r.weight * (r.residual_rad - m).powi(2)
            })
            .sum()
    }

    fn table(&self) -> ResidualTable {
        ResidualTable {
            lo_rad: self.lo_rad,
            step_rad: self.step_rad,
            width_rad: self.width_rad,
            values_rad: self
                .weighted_rad
                .iter()
                .zip(&self.weight)
                .map(|(r, w)| r / (w + PRIOR_WEIGHT))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn residual(roll_rad: f64, residual_rad: f64) -> Residual {
        Residual {
            roll_rad,
            weight: 1.0,
            residual_rad,
        }
    }

    #[test]
    fn the_table_by_hand() {
        // Two pairs four bins apart (one kernel width, h = 1, step 0.25):
        // at each, Σ w K r = r_own + e^{-1/2} r_other and
        // Σ w K = 1 + e^{-1/2}.
        let grid =
            Grid::binned(&[residual(0.0, 1.0), residual(1.0, 3.0)], 0.0, 1.0, 1.0).expect("grid");
        let table = grid.table();
        let k = (-0.5f64).exp();
        assert_eq!(table.values_rad.len(), 5);
        assert!((table.at(0.0) - (1.0 + 3.0 * k) / (1.0 + k + 1.0)).abs() < 1e-12);
        assert!((table.at(1.0) - (3.0 + k) / (1.0 + k + 1.0)).abs() < 1e-12);
        // Midway, bin 2 at 0.5 is e^{-1/8} from both.
        let k_half = (-0.125f64).exp();
        let mid = 4.0 * k_half / (2.0 * k_half + 1.0);
        assert!((table.at(0.5) - mid).abs() < 1e-12);
        // Linear between bins, held beyond the ends.
        let quarter = (table.values_rad[0] + table.values_rad[1]) / 2.0;
        assert!((table.at(0.125) - quarter).abs() < 1e-12);
        assert_eq!(table.at(-5.0), table.at(0.0));
        assert_eq!(table.at(5.0), table.at(1.0));
        // Leaving pair 0 out leaves e^{-1/2}·3 over e^{-1/2} + 1 at its bin.
        let loo = grid.leave_one_out(&[residual(0.0, 1.0)]);
        assert!((loo - (1.0 - 3.0 * k / (k + 1.0)).powi(2)).abs() < 1e-12);
    }

    #[test]
    fn white_residuals_are_left_alone() {
        // Alternating ±1 from pair to pair (two to four pairs per bin): any
        // smoothing predicts a pair worse than zero does.
        let residuals: Vec<Residual> = (0..200)
            .map(|i| residual(i as f64 * 0.01, if i % 2 == 0 { 1.0 } else { -1.0 }))
            .collect();
        assert_eq!(ResidualTable::fit(&residuals, 0.0, 1.99, 0.4), None);
    }

    #[test]
    fn a_ripple_the_rules_missed_is_followed() {
        // A ripple of wavelength 1 over [0, 4] with 0.1 of alternating
        // noise, behind rules 0.2 wide: a width of 0.05 keeps 95 % of the
        // ripple (e^{−(2π·0.05)²/2}), the prior about 93 % of that (12.5
        // pairs' weight under the kernel against 1), and leave-one-out
        // picks a narrow width.
        let ripple = |x: f64| 0.5 * (std::f64::consts::TAU * x).sin();
        let residuals: Vec<Residual> = (0..400)
            .map(|i| {
                let x = i as f64 * 0.01;
                residual(x, ripple(x) + if i % 2 == 0 { 0.1 } else { -0.1 })
            })
            .collect();
        let table = ResidualTable::fit(&residuals, 0.0, 3.99, 0.2).expect("smoothed");
        assert!(table.width_rad <= 0.1 + 1e-12, "width {}", table.width_rad);
        for x in [0.25, 1.1, 2.75, 3.3] {
            assert!(
                (table.at(x) - ripple(x)).abs() < 0.08,
                "{x}: {}",
                table.at(x)
            );
        }
    }

    #[test]
    fn too_fine_a_grid_is_refused() {
        let residuals = [residual(0.0, 1.0), residual(100.0, 1.0)];
        assert!(Grid::binned(&residuals, 0.0, 100.0, 0.01).is_none());
    }
}
