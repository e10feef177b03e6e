//! The accelerometer as a tilt reference that does not pull while the
//! vehicle accelerates (docs/engines/fuzzy.md: tilt while moving).
//!
//! For each IMU reading the engine keeps the specific force turned into
//! the world frame, C f (C: its gyro-propagated body-to-world attitude),
//! and the force at rest (0, 0, −g₀) (g₀: the static norm this
//! accelerometer reads). Over the **older half** of the motion window the
//! two means F̄ and F̂ are compared:
//! - in the world frame, so the body may turn under the window: a
//!   body-frame comparison from half a window ago, applied to today's body
//!   axes, would turn the tilt the wrong way at hundreds of °/s;
//! - it is delayed by half a window: the expert's decision covers the whole
//!   window, so when it says "static", the older half has been static for
//!   at least half a window since: an acceleration that has just begun is
//!   in the newer half and not yet in the reference;
//! - the residual ρ = ‖F̄ − F̂‖ is what is not gravity (plus the tilt
//!   error, 0.17 m/s² per degree): while moving, the reference is used
//!   only when ρ is within `gate_mps2` (full weight) to 2·`gate_mps2`
//!   (none), so a vehicle accelerating, braking or cornering keeps its
//!   gyro-propagated tilt, and the static spells correct what that gate
//!   rejects. Whatever the gate, the engine may turn the tilt by a small
//!   fraction of the angle the gyros turned through ([`turn_gain`]): their
//!   scale and axis errors grow with it, and a sensor that never rests
//!   must not drift past the gate for good.
//!
//! The correction turns the attitude about the world axis u = F̄ × F̂ by a
//! fraction of the angle between them ([`correct_world`]); u is
//! horizontal, so heading is unchanged to first order.

use std::collections::VecDeque;

use nalgebra::{Unit, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// Measured and predicted forces over the motion window, with the sums of
/// the older half kept in O(1) per reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TiltWindow {
    capacity: usize,
    /// (measured f, predicted f̂), oldest first.
    pairs: VecDeque<(V3, V3)>,
    /// Sums over the older ⌈capacity/2⌉ pairs once full (all pairs until then).
    older_measured: V3,
    older_predicted: V3,
    older_len: usize,
    /// Sum of the measured force over every pair held, and of its squared norm.
    #[serde(default)]
    all_measured: V3,
    #[serde(default)]
    all_measured_squared: f64,
    pushes_since_refresh: usize,
}

impl TiltWindow {
    /// An empty window of `capacity` readings (at least 2).
    pub fn new(capacity: usize) -> TiltWindow {
        TiltWindow {
            capacity: capacity.max(2),
            pairs: VecDeque::with_capacity(capacity.max(2)),
            older_measured: V3::zeros(),
            older_predicted: V3::zeros(),
            older_len: 0,
            all_measured: V3::zeros(),
            all_measured_squared: 0.0,
            pushes_since_refresh: 0,
        }
    }

    /// Forgets every reading.
    pub fn clear(&mut self) {
        *self = TiltWindow::new(self.capacity);
    }

    fn older_capacity(&self) -> usize {
        self.capacity.div_ceil(2)
    }

    /// Adds a reading's measured and predicted specific force, m/s².
    pub fn push(&mut self, measured: V3, predicted: V3) {
        if self.pairs.len() == self.capacity
            && let Some((f, p)) = self.pairs.pop_front()
        {
            self.older_measured -= f;
            self.older_predicted -= p;
            self.older_len -= 1;
            self.all_measured -= f;
            self.all_measured_squared -= f.norm_squared();
        }
        self.pairs.push_back((measured, predicted));
        self.all_measured += measured;
        self.all_measured_squared += measured.norm_squared();
        // The older half takes readings until it is full; then the reading
        // that crosses from the newer half into it.
        let older = self.older_capacity();
        if self.older_len < older {
            let index = self.older_len;
            if let Some(&(f, p)) = self.pairs.get(index) {
                self.older_measured += f;
                self.older_predicted += p;
                self.older_len += 1;
            }
        }
        self.pushes_since_refresh += 1;
        if self.pushes_since_refresh >= self.capacity {
            self.refresh();
        }
    }

    fn refresh(&mut self) {
        self.pushes_since_refresh = 0;
        self.older_len = self.pairs.len().min(self.older_capacity());
        self.older_measured = V3::zeros();
        self.older_predicted = V3::zeros();
        for (f, p) in self.pairs.iter().take(self.older_len) {
            self.older_measured += f;
            self.older_predicted += p;
        }
        self.all_measured = self.pairs.iter().map(|(f, _)| f).sum();
        self.all_measured_squared = self.pairs.iter().map(|(f, _)| f.norm_squared()).sum();
    }

    /// True once the window is full.
    pub fn is_full(&self) -> bool {
        self.pairs.len() == self.capacity
    }

    /// How far apart the measured force's means over the older and the
    /// newer half are beyond what the readings' own scatter explains, m/s²:
    /// √max(0, ‖F̄_old − F̄_new‖² − v·(1/n_old + 1/n_new)), v the window's
    /// variance of the force about its mean (summed over the axes). White
    /// vibration leaves 0; an acceleration that changes within the window
    /// does not. 0 until both halves hold readings.
    pub fn halves_apart_mps2(&self) -> f64 {
        let n = self.pairs.len();
        let newer = n - self.older_len;
        if newer == 0 || self.older_len == 0 {
            return 0.0;
        }
        let (n_old, n_new) = (self.older_len as f64, newer as f64);
        let mean = self.all_measured / n as f64;
        let variance = (self.all_measured_squared / n as f64 - mean.norm_squared()).max(0.0);
        let old = self.older_measured / n_old;
        let new = (self.all_measured - self.older_measured) / n_new;
        let scatter = variance * (1.0 / n_old + 1.0 / n_new);
        ((old - new).norm_squared() - scatter).max(0.0).sqrt()
    }

    /// Mean of the measured force over every reading held, m/s².
    pub fn mean_measured(&self) -> Option<V3> {
        (!self.pairs.is_empty()).then(|| self.all_measured / self.pairs.len() as f64)
    }

    /// Means of the measured and predicted force over the older half.
    pub fn older_means(&self) -> Option<(V3, V3)> {
        (self.older_len > 0).then(|| {
            let n = self.older_len as f64;
            (self.older_measured / n, self.older_predicted / n)
        })
    }
}

/// Weight of the reference while moving for a residual ρ: 1 up to
/// `gate_mps2`, falling linearly to 0 at twice that.
pub fn moving_weight(residual_mps2: f64, gate_mps2: f64) -> f64 {
    if gate_mps2 <= 0.0 {
        return 0.0;
    }
    (2.0 - residual_mps2 / gate_mps2).clamp(0.0, 1.0)
}

/// The gain that turns `measured` towards `expected` by at most
/// `allowance_rad` (all the way if they are closer).
pub fn turn_gain(measured: &V3, expected: &V3, allowance_rad: f64) -> f64 {
    let angle = measured.angle(expected);
    if angle > 1e-12 {
        (allowance_rad / angle).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Turns `attitude` (body → world) a fraction `gain` ∈ [0, 1] of the way
/// from putting the world-frame force `measured` at `expected`: the turn is
/// about the world axis `measured` × `expected`.
pub fn correct_world(
    attitude: &UnitQuaternion<f64>,
    measured: &V3,
    expected: &V3,
    gain: f64,
) -> UnitQuaternion<f64> {
    let axis = measured.cross(expected);
    let Some(axis) = Unit::try_new(axis, 1e-12) else {
        return *attitude;
    };
    let angle = measured.angle(expected) * gain.clamp(0.0, 1.0);
    UnitQuaternion::from_axis_angle(&axis, angle) * attitude
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::geometry::attitude_from_euler;

    #[test]
    fn the_older_half_is_the_oldest_readings_held() {
        let mut window = TiltWindow::new(5);
        for i in 0..23 {
            let x = f64::from(i);
            window.push(V3::new(x, 0.0, 0.0), V3::new(0.0, 2.0 * x, 0.0));
        }
        // Held: 18..=22; older half (3 of 5): 18, 19, 20.
        let (measured, predicted) = window.older_means().unwrap();
        assert!((measured.x - 19.0).abs() < 1e-12);
        assert!((predicted.y - 38.0).abs() < 1e-12);
        // Older 18, 19, 20 (mean 19), newer 21, 22 (21.5): 2.5 apart; the
        // five have variance 2 about their mean 20, and 2·(1/3 + 1/2) = 5/3
        // of the 6.25 is scatter: √(6.25 − 5/3).
        let apart = window.halves_apart_mps2();
        assert!(
            (apart - (6.25f64 - 5.0 / 3.0).sqrt()).abs() < 1e-9,
            "{apart}"
        );
        // Before it is full the older half fills first.
        let mut young = TiltWindow::new(6);
        young.push(V3::new(1.0, 0.0, 0.0), V3::zeros());
        young.push(V3::new(3.0, 0.0, 0.0), V3::zeros());
        assert!((young.older_means().unwrap().0.x - 2.0).abs() < 1e-12);
        for _ in 0..2 {
            young.push(V3::new(100.0, 0.0, 0.0), V3::zeros());
        }
        // Three older of six: 1, 3, 100.
        assert!((young.older_means().unwrap().0.x - 104.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn a_world_correction_levels_a_tilted_estimate_whatever_the_body_does() {
        let g = 9.81;
        // The estimate is rolled 2° too far; the body points anywhere.
        let truth = attitude_from_euler(0.3, -0.5, 2.0);
        let estimate = UnitQuaternion::from_axis_angle(&V3::x_axis(), 0.035) * truth;
        let force = truth.inverse() * V3::new(0.0, 0.0, -g);
        let measured = estimate * force;
        let expected = V3::new(0.0, 0.0, -g);
        // World x axis, about which the error is: 2° error, all of it back.
        let corrected = correct_world(&estimate, &measured, &expected, 1.0);
        assert!(corrected.angle_to(&truth) < 1e-9);
        // Half the gain, half the angle; the yaw moves by a fraction of the
        // 1° turned (second order: the body is pitched 29°), where a turn
        // about the vertical would move it 1° (0.017 rad).
        let half = correct_world(&estimate, &measured, &expected, 0.5);
        assert!(((half * force).angle(&expected) - 0.0175).abs() < 1e-9);
        let (_, _, yaw) = half.euler_angles();
        assert!((yaw - 2.0).abs() < 5e-3, "{yaw}");
        // A turn of at most 0.5° of the 2°: a quarter of the way.
        let gain = turn_gain(&measured, &expected, 0.5_f64.to_radians());
        assert!((gain - 0.25).abs() < 1e-3, "{gain}");
        assert_eq!(turn_gain(&measured, &expected, 1.0), 1.0);
        assert_eq!(turn_gain(&expected, &expected, 1.0), 0.0);
    }

    #[test]
    fn the_moving_weight_falls_from_one_to_zero_over_the_gate() {
        assert_eq!(moving_weight(0.1, 0.2), 1.0);
        assert_eq!(moving_weight(0.2, 0.2), 1.0);
        assert!((moving_weight(0.3, 0.2) - 0.5).abs() < 1e-12);
        assert_eq!(moving_weight(0.5, 0.2), 0.0);
        assert_eq!(moving_weight(0.1, 0.0), 0.0);
    }
}
