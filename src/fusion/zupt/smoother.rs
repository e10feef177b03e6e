//! Fixed-interval smoothing of a completed push (Rauch, Tung & Striebel
//! 1965), in the closed-loop error-state form the filter runs in.
//!
//! A push runs from the last filter epoch decided still before it (the
//! anchor) to the first one after it: the velocity is known to be zero at
//! both ends. While it runs, a [`PushRecord`] keeps, at every epoch with an
//! update and at least once a second, a point j: the nominal state after
//! feedback and its covariance P⁺ⱼ; and for the step from the point before,
//! the transition Φⱼ₋₁ (chained over the epochs between), the covariance
//! before the updates P⁻ⱼ and the error fed back there, dxⱼ. The filter's
//! own error estimate after feedback is zero at every point, so the
//! backward pass (RTS, per step) is
//!
//! - Cⱼ = P⁺ⱼ Φⱼᵀ (P⁻ⱼ₊₁)⁻¹
//! - εⱼ = Cⱼ (εⱼ₊₁ + dxⱼ₊₁), ε at the closing point = 0
//! - Pˢⱼ = P⁺ⱼ + Cⱼ (Pˢⱼ₊₁ − P⁻ⱼ₊₁) Cⱼᵀ
//!
//! where εⱼ₊₁ + dxⱼ₊₁ is the smoothed error of the nominal state *before*
//! the updates at j+1 (what Φ predicts to), and εⱼ that of the one kept at
//! j, corrected as the filter corrects: p̂ˢ = p̂⁺ − δp. At the closing point
//! the smoothed estimate is the filter's: smoothing improves the track
//! inside the push, not its end.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::eskf::{Covariance, ErrorState, POS};
use crate::fusion::estimate::TrackPoint;
use crate::fusion::geometry::V3;

/// A point is kept at least this often during a push, s.
pub const POINT_EVERY_S: f64 = 1.0;

/// The filter's state at one point of a push.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub t: f64,
    pub position_m: V3,
    pub distance_m: f64,
    /// The body's forward axis in the navigation frame (for the distance).
    pub forward: V3,
    /// P⁺: after the updates.
    pub p_post: Covariance,
}

/// The step to a point from the one before.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Step {
    /// Φ from the previous point to this one.
    phi: Covariance,
    /// P⁻ here: propagated, before the updates.
    p_prior: Covariance,
    /// The error fed back here by the updates.
    dx: ErrorState,
    point: Point,
}

/// What a push leaves behind while it runs (module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PushRecord {
    anchor: Point,
    steps: Vec<Step>,
    /// Φ chained since the newest point.
    pending_phi: Covariance,
    /// P⁻ and the fed-back error of the epoch in progress.
    pending_prior: Option<Covariance>,
    pending_dx: ErrorState,
}

impl PushRecord {
    /// A record anchored at a still epoch.
    pub fn anchored(anchor: Point) -> PushRecord {
        PushRecord {
            anchor,
            steps: Vec::new(),
            pending_phi: Covariance::identity(),
            pending_prior: None,
            pending_dx: ErrorState::zeros(),
        }
    }

    /// True once a point after the anchor has been kept (the machine moved).
    pub fn has_moved(&self) -> bool {
        !self.steps.is_empty()
    }

    /// The time span recorded so far, s.
    pub fn span_s(&self) -> f64 {
        self.steps.last().map_or(0.0, |s| s.point.t - self.anchor.t)
    }

    /// An epoch's propagation: its Φ and the covariance before its updates.
    pub fn propagated(&mut self, phi: &Covariance, p_prior: &Covariance) {
        self.pending_phi = phi * self.pending_phi;
        self.pending_prior = Some(*p_prior);
        self.pending_dx = ErrorState::zeros();
    }

    /// An update of the epoch in progress fed back `dx`.
    pub fn fed_back(&mut self, dx: &ErrorState) {
        self.pending_dx += dx;
    }

    /// Ends the epoch in progress; `point` is kept if `keep` (an update was
    /// made, a second has passed, or the push ends here).
    pub fn end_epoch(&mut self, point: Point, keep: bool) {
        let newest_t = self.steps.last().map_or(self.anchor.t, |s| s.point.t);
        let due = point.t - newest_t >= POINT_EVERY_S - 1e-9;
        let Some(p_prior) = self.pending_prior.take() else {
            return;
        };
        if keep || due || self.pending_dx != ErrorState::zeros() {
            self.steps.push(Step {
                phi: self.pending_phi,
                p_prior,
                dx: self.pending_dx,
                point,
            });
            self.pending_phi = Covariance::identity();
        }
        self.pending_dx = ErrorState::zeros();
    }

    /// The backward pass over the recorded push: its points, smoothed,
    /// anchor first. `None` if a P⁻ cannot be inverted.
    pub fn smooth(&self) -> Option<Vec<TrackPoint>> {
        let last = self.steps.last()?;
        let mut points = Vec::with_capacity(self.steps.len() + 1);
        let mut error = ErrorState::zeros();
        let mut p_smoothed = last.point.p_post;
        points.push(track_point(&last.point, &error, &p_smoothed));
        // Step i leads from point i (the anchor for i = 0) to point i + 1.
        for i in (0..self.steps.len()).rev() {
            let next = &self.steps[i];
            let here = if i == 0 {
                &self.anchor
            } else {
                &self.steps[i - 1].point
            };
            let prior_inverse = next.p_prior.cholesky()?.inverse();
            let gain = here.p_post * next.phi.transpose() * prior_inverse;
            error = gain * (error + next.dx);
            p_smoothed = here.p_post + gain * (p_smoothed - next.p_prior) * gain.transpose();
            points.push(track_point(here, &error, &p_smoothed));
        }
        points.reverse();
        Some(points)
    }
}

/// A point corrected by its smoothed error.
fn track_point(point: &Point, error: &ErrorState, p_smoothed: &Covariance) -> TrackPoint {
    let correction = -Vector3::new(error[POS], error[POS + 1], error[POS + 2]);
    let position = point.position_m + correction;
    let sigma = |axis: usize| p_smoothed[(POS + axis, POS + axis)].max(0.0).sqrt();
    TrackPoint {
        t: point.t,
        position_m: [position.x, position.y, position.z],
        distance_m: point.distance_m + point.forward.dot(&correction),
        position_sigma_m: [sigma(0), sigma(1), sigma(2)],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scalar random walk seen at both ends, in the 15-state shapes:
    /// x = position error only, P⁺ = 0 at the anchor, each step adds q,
    /// the closing point measured exactly. By hand: with n steps the RTS
    /// estimate at step k is (k/n) of the closing correction, and its
    /// variance q·k(n − k)/n (a Brownian bridge).
    #[test]
    fn a_random_walk_pinned_at_both_ends_is_a_bridge() {
        let q = 0.01;
        let n = 4;
        let point = |t: f64, p: f64, north: f64| {
            let mut p_post = Covariance::identity() * 1e-12;
            p_post[(POS, POS)] = p;
            Point {
                t,
                position_m: V3::new(north, 0.0, 0.0),
                distance_m: 0.0,
                forward: V3::x(),
                p_post,
            }
        };
        let mut record = PushRecord::anchored(point(0.0, 0.0, 0.0));
        let mut p = 0.0;
        for k in 1..=n {
            p += q;
            let mut p_prior = Covariance::identity() * 1e-12;
            p_prior[(POS, POS)] = p;
            record.propagated(&Covariance::identity(), &p_prior);
            if k == n {
                // The end is measured exactly: the position was 0.2 off,
                // the filter moves it to −0.2 and P⁺ = 0.
                let mut dx = ErrorState::zeros();
                dx[POS] = 0.2;
                record.fed_back(&dx);
                record.end_epoch(point(k as f64, 0.0, -0.2), true);
            } else {
                record.end_epoch(point(k as f64, p, 0.0), true);
            }
        }
        let track = record.smooth().unwrap();
        assert_eq!(track.len(), n + 1);
        for (k, point) in track.iter().enumerate() {
            let share = k as f64 / n as f64;
            // The filter's positions were 0 until the end; the smoother
            // moves point k to −0.2·k/n (p̂ˢ = p̂ − δp, δp = 0.2·k/n).
            assert!(
                (point.position_m[0] + 0.2 * share).abs() < 1e-9,
                "{k}: {point:?}"
            );
            let variance = q * (k * (n - k)) as f64 / n as f64;
            assert!(
                (point.position_sigma_m[0].powi(2) - variance).abs() < 1e-9,
                "{k}: {point:?}"
            );
        }
    }
}
