//! The odometer's scale from whole pushes (issue 58).
//!
//! Between two rests the odometer confirms (it stood still over a whole
//! `odometer_rest_window_s` while the detector called still), the INS's
//! own advance is compared with the odometer's count. "Own": from the
//! filter's state at the first rest, a strapdown and an error-state
//! filter of their own ([`InsPush`]) carry on through the push with the
//! zero-velocity updates of its still readings and nothing else. No
//! correction the odometer makes reaches them: an odometer update that
//! tilts the filter's platform to fit a wrong scale would otherwise make
//! the push agree with that scale. Zero velocity at both ends bounds the
//! INS; the push filter's covariance says how well, tilt and gyro drift
//! included (its bridge is the error model's, not a line).
//!
//! Each push so measured is one observation of the scale k: advance =
//! count ÷ k + the INS's error, linearised about the filter's scale, so
//! that a push weighs by its count and the push filter's σ, never by the
//! advance it measured ([`MeasuredPush::scale`]); it updates the filter's
//! scale state directly. Every other update only
//! considers the scale (Schmidt–Kalman,
//! [`super::eskf::ErrorStateFilter::update`]): the running odometer
//! fusion would otherwise learn the scale from the INS's velocity within
//! a push, which vibration shakes by millimetres per second. A push is
//! measured only where the odometer confirmed both ends: a rest the
//! detector calls in the middle of a push would cut it short, and the
//! rest check refuses the readings the odometer saw advance. For the same
//! reason a push is not measured when the odometer counted an advance
//! over epochs the push took all for still ([`InsPush::counted`]), nor
//! when its INS advance is known to worse than [`MAX_RELATIVE_SIGMA`].

use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

use super::eskf::{Dynamics, ErrorStateFilter, POS, feed_back, zupt_matrix};
use super::strapdown::{Increment, NavState, Site};
use crate::fusion::geometry::V3;

/// A push whose INS advance is known to worse than this share of it is
/// not measured: it says little about a scale of a few per cent, and over
/// such long bridges between zero-velocity updates an error the push
/// filter does not model (a bias the odometer's fusion pulled before the
/// anchor) is not averaged out but repeated push after push.
const MAX_RELATIVE_SIGMA: f64 = 0.1;
/// The 1σ a push's displacement starts from (it is measured from there), m.
const ANCHOR_SIGMA_M: f64 = 1e-6;

/// The INS's own motion since a rest the odometer confirmed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InsPush {
    /// The odometer's count at the anchor (slips taken out), m, and the
    /// push strapdown's position there, NED m.
    counted_m: f64,
    origin_m: V3,
    state: NavState,
    filter: ErrorStateFilter,
    accel_bias_mps2: V3,
    gyro_bias_rad_per_s: V3,
    /// Time, ∫fⁿ dt since the last epoch, and whether every reading in
    /// it was still.
    interval_s: f64,
    force_integral: V3,
    interval_still: bool,
    moved: bool,
    /// Whether every epoch since the newest odometer reading was still,
    /// and whether the odometer counted an advance over epochs all still
    /// (a rest called while the machine moved: the push's zero-velocity
    /// updates cut its advance short, so it is not measured).
    still_since_count: bool,
    contradicted: bool,
    /// Epochs since the newest odometer reading judged, and what the
    /// readings since then counted, m (readings faster than the epochs
    /// are judged together at the first with an epoch behind it).
    epochs_since_count: u32,
    counted_since_m: f64,
}

/// One push measured: the INS's advance along the machine's axis, its
/// 1σ, and the odometer's count over the push (slips taken out), m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredPush {
    pub advance_m: f64,
    pub advance_sigma_m: f64,
    pub counted_m: f64,
}

impl MeasuredPush {
    /// The scale this push says and its 1σ, linearised about the filter's
    /// `prior_scale`, with `count_sigma_m` the noise of one count (two
    /// enter the push's); `None` when the INS's advance is known to worse
    /// than [`MAX_RELATIVE_SIGMA`] of the advance the count implies.
    ///
    /// The model is advance = count ÷ k + the INS's error: the weight of a
    /// push comes from its count, the prior and the push filter's σ, never
    /// from the advance the INS measured. (Taken as k = count ÷ advance,
    /// a push the INS measured long would weigh more and say a smaller
    /// scale: the scale came out biased low by about 4σ² of a push's
    /// relative error, and the distance long.)
    pub fn scale(&self, prior_scale: f64, count_sigma_m: f64) -> Option<(f64, f64)> {
        let expected_m = self.counted_m / prior_scale;
        // d(count ÷ k)/dk, its magnitude.
        let slope_m = self.counted_m / (prior_scale * prior_scale);
        let sigma_m =
            (self.advance_sigma_m.powi(2) + 2.0 * (count_sigma_m / prior_scale).powi(2)).sqrt();
        (sigma_m <= MAX_RELATIVE_SIGMA * expected_m).then(|| {
            (
                prior_scale + (expected_m - self.advance_m) / slope_m,
                sigma_m / slope_m,
            )
        })
    }
}

impl InsPush {
    /// A push anchored at a confirmed rest, the count then `counted_m`,
    /// from the filter's `state` (its velocity taken as zero), covariance
    /// and biases; its displacement is measured from here.
    pub fn anchored(
        counted_m: f64,
        state: &NavState,
        filter: &ErrorStateFilter,
        accel_bias_mps2: &V3,
        gyro_bias_rad_per_s: &V3,
    ) -> InsPush {
        let mut filter = filter.clone();
        filter.p.fixed_rows_mut::<3>(POS).fill(0.0);
        filter.p.fixed_columns_mut::<3>(POS).fill(0.0);
        for axis in 0..3 {
            filter.p[(POS + axis, POS + axis)] = ANCHOR_SIGMA_M * ANCHOR_SIGMA_M;
        }
        InsPush {
            counted_m,
            origin_m: state.position_m,
            state: NavState {
                velocity_mps: V3::zeros(),
                ..*state
            },
            filter,
            accel_bias_mps2: *accel_bias_mps2,
            gyro_bias_rad_per_s: *gyro_bias_rad_per_s,
            interval_s: 0.0,
            force_integral: V3::zeros(),
            interval_still: true,
            moved: false,
            still_since_count: true,
            contradicted: false,
            epochs_since_count: 0,
            counted_since_m: 0.0,
        }
    }

    /// Whether the machine moved since the anchor.
    pub fn moved(&self) -> bool {
        self.moved
    }

    /// One IMU interval: the readings' mean specific force and rate over
    /// it (raw) through the push's strapdown, and whether the reading was
    /// taken for still.
    pub fn advance(
        &mut self,
        site: &Site,
        accel_mps2: &V3,
        gyro_rad_per_s: &V3,
        dt_s: f64,
        still: bool,
    ) {
        let force_n = self.state.advance(
            site,
            &Increment {
                accel_mps2: accel_mps2 - self.accel_bias_mps2,
                gyro_rad_per_s: gyro_rad_per_s - self.gyro_bias_rad_per_s,
                dt_s,
            },
        );
        self.interval_s += dt_s;
        self.force_integral += force_n * dt_s;
        self.interval_still &= still;
        self.moved |= !still;
    }

    /// A filter epoch, as the engine's (`dynamics` its, with this push's
    /// specific force and attitude): the covariance propagated, and a
    /// zero-velocity update (noise `zupt_sigma_mps`) if every reading
    /// since the last epoch was still, fed back into the push's state.
    pub fn epoch(&mut self, dynamics: &Dynamics, zupt_sigma_mps: f64) {
        if self.interval_s <= 0.0 {
            return;
        }
        let own = Dynamics {
            specific_force_n: self.force_integral / self.interval_s,
            c_bn: self.state.attitude.to_rotation_matrix().into_inner(),
            ..*dynamics
        };
        self.filter.propagate(&own, self.interval_s);
        let still = self.interval_still;
        self.still_since_count &= still;
        self.epochs_since_count += 1;
        self.interval_s = 0.0;
        self.force_integral = V3::zeros();
        self.interval_still = true;
        if !still {
            return;
        }
        let r = SMatrix::<f64, 3, 3>::identity() * zupt_sigma_mps.powi(2);
        let Ok(dx) = self
            .filter
            .update(&zupt_matrix(), &self.state.velocity_mps, &r, None)
        else {
            return;
        };
        feed_back(
            &dx,
            &mut self.state,
            &mut self.accel_bias_mps2,
            &mut self.gyro_bias_rad_per_s,
        );
    }

    /// An odometer reading that counted `advance_m` since the one before.
    /// Judged at the first reading with an epoch behind it (with the
    /// readings since the last judged): a count beyond `moved_m` over
    /// epochs that were all still contradicts the push (its rests were
    /// not all rests), which will not be measured.
    pub fn counted(&mut self, advance_m: f64, moved_m: f64) {
        self.counted_since_m += advance_m;
        if self.epochs_since_count == 0 {
            return;
        }
        if self.still_since_count && self.counted_since_m.abs() > moved_m {
            self.contradicted = true;
        }
        self.still_since_count = true;
        self.epochs_since_count = 0;
        self.counted_since_m = 0.0;
    }

    /// The push measured at a confirmed rest (the count then `counted_m`,
    /// `forward` the machine's axis, NED); `None` when it did not move,
    /// the odometer counted none of it or contradicted its rests.
    pub fn measure(&self, counted_m: f64, forward: &V3) -> Option<MeasuredPush> {
        let counted_m = counted_m - self.counted_m;
        if !self.moved || self.contradicted || counted_m <= 0.0 {
            return None;
        }
        let advance_m = forward.dot(&(self.state.position_m - self.origin_m));
        let advance_sigma_m = self.filter.variance_along(POS, forward).sqrt();
        Some(MeasuredPush {
            advance_m,
            advance_sigma_m,
            counted_m,
        })
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::UnitQuaternion;

    use super::*;
    use crate::fusion::geometry::normal_gravity_mps2;
    use crate::fusion::zupt::eskf::ProcessNoise;

    /// Level on the equator, heading north.
    fn level_dynamics() -> Dynamics {
        Dynamics {
            specific_force_n: V3::new(0.0, 0.0, -normal_gravity_mps2(0.0, 0.0)),
            c_bn: nalgebra::Matrix3::identity(),
            earth_rate_n: V3::new(7.292_115e-5, 0.0, 0.0),
            transport_rate_n: V3::zeros(),
            gravity_gradient: 3e-6,
        }
    }

    /// On the equator, level, heading north: 20 s still, a push of 30 s
    /// at 40 mm/s (1 s ramps of 0.04 m/s²: 29 × 0.04 = 1.16 m), 20 s
    /// still, every 0.01 s, an epoch every 0.1 s; the accelerometer reads
    /// `bias_mps2` too much forward, which the push does not know.
    fn push(bias_mps2: f64) -> (InsPush, f64) {
        let site = Site {
            lat_rad: 0.0,
            height_m: 0.0,
        };
        let g = normal_gravity_mps2(0.0, 0.0);
        let earth_rate = 7.292_115e-5;
        let noise = ProcessNoise {
            accel_vrw: 4.9e-4,
            gyro_arw: 1.5e-5,
            accel_bias_rw: 1e-7,
            gyro_bias_rw: 1e-9,
        };
        let filter = ErrorStateFilter::new(
            [
                V3::repeat(1e-3),
                V3::repeat(1e-3),
                V3::new(1e-4, 1e-4, 1e-3),
                V3::repeat(1e-3),
                V3::repeat(1e-7),
                V3::repeat(1e-9),
            ],
            noise,
        );
        let state = NavState::at_rest(UnitQuaternion::identity());
        let mut p = InsPush::anchored(100.0, &state, &filter, &V3::zeros(), &V3::zeros());
        let accel_at = |t: f64| -> f64 {
            match t - 20.0 {
                x if (0.0..1.0).contains(&x) => 0.04,
                x if (29.0..30.0).contains(&x) => -0.04,
                _ => 0.0,
            }
        };
        let dynamics = level_dynamics();
        let dt = 0.01;
        for k in 0..7000 {
            let t = k as f64 * dt;
            let accel = V3::new(accel_at(t + 0.5 * dt) + bias_mps2, 0.0, -g);
            let gyro = V3::new(earth_rate, 0.0, 0.0);
            // Still: no motion this step or the one before.
            let still = !(19.99..50.01).contains(&t);
            p.advance(&site, &accel, &gyro, dt, still);
            if k % 10 == 9 {
                p.epoch(&dynamics, 0.002);
            }
        }
        (p, 70.0)
    }

    #[test]
    fn a_push_between_two_rests_is_measured_with_its_drift_taken_out() {
        let (p, _) = push(0.0);
        let measured = p.measure(101.2064, &V3::x()).unwrap();
        assert!((measured.advance_m - 1.16).abs() < 0.002, "{measured:?}");
        assert!((measured.counted_m - 1.2064).abs() < 1e-9);
        // Linearised about a prior of 1: the count implies 1.2064 m, the
        // slope d(c/k)/dk is 1.2064 m, so the push says 1 + (1.2064 −
        // 1.16) / 1.2064 = 1.0385 (the first step toward 1.2064 / 1.16 =
        // 1.04), σ = √(σ_a² + 2·(1 mm)²) / 1.2064.
        let (scale, sigma) = measured.scale(1.0, 0.001).unwrap();
        assert!((scale - 1.0385).abs() < 0.002, "{scale}");
        let expected = (measured.advance_sigma_m.powi(2) + 2e-6).sqrt() / 1.2064;
        assert!((sigma - expected).abs() < 1e-12, "{sigma}");
        // About the true scale, the step is to it: 1.04 + (1.16 − a) / (1.2064 / 1.04²).
        let (at_truth, _) = measured.scale(1.04, 0.001).unwrap();
        let hand = 1.04 + (1.16 - measured.advance_m) * 1.04 * 1.04 / 1.2064;
        assert!((at_truth - hand).abs() < 1e-12, "{at_truth} {hand}");
        assert!((at_truth - 1.04).abs() < 0.002, "{at_truth}");
        // The weight comes from the count and the prior, not the advance:
        // a push the INS measured 5 % long says the same σ.
        let long = MeasuredPush {
            advance_m: measured.advance_m * 1.05,
            ..measured
        };
        assert_eq!(long.scale(1.0, 0.001).unwrap().1, sigma);
        // A push whose INS advance is known to worse than 10 % is not
        // measured.
        let vague = MeasuredPush {
            advance_sigma_m: 0.11 * 1.2064,
            ..measured
        };
        assert!(vague.scale(1.0, 0.0).is_none());
        let clear_enough = MeasuredPush {
            advance_sigma_m: 0.09 * 1.2064,
            ..measured
        };
        assert!(clear_enough.scale(1.0, 0.0).is_some());
        // A bias of 1e-4 m/s² drifts the bare strapdown by 1e-4 × 70²/2
        // = 0.245 m; the zero-velocity updates at both ends take it out
        // to within the push's own σ.
        let (biased, _) = push(1e-4);
        let measured = biased.measure(101.2064, &V3::x()).unwrap();
        assert!(
            (measured.advance_m - 1.16).abs() < 0.01_f64.max(3.0 * measured.advance_sigma_m),
            "{measured:?}"
        );
        // The velocity random walk over the push and its ends: about
        // 4.9e-4 × √(50³/12) = 5 cm.
        assert!(
            (0.02..0.06).contains(&measured.advance_sigma_m),
            "{measured:?}"
        );
    }

    /// The odometer's readings against the push's still epochs: a count
    /// that advanced 10 mm over epochs all still contradicts the push; 3 mm
    /// (within the 6 mm that still counts as standing) or 10 mm over an
    /// interval with an epoch in motion does not. Readings faster than the
    /// epochs are judged together: 4 mm with no epoch behind it, then a
    /// still epoch and 4 mm more, is 8 mm over still epochs.
    #[test]
    fn a_rest_the_odometer_saw_move_leaves_the_push_unmeasured() {
        // Each reading's count, m, after an epoch (still or not) or none.
        let measured = |readings: &[(f64, Option<bool>)]| {
            let (mut p, _) = push(0.0);
            // The reading before: the push's own motion is behind it.
            p.counted(0.0, 0.006);
            for &(advance_m, epoch) in readings {
                if let Some(still) = epoch {
                    p.interval_s = 0.1;
                    p.interval_still = still;
                    p.epoch(&level_dynamics(), 0.002);
                }
                p.counted(advance_m, 0.006);
            }
            p.measure(101.2064, &V3::x())
        };
        assert!(measured(&[]).is_some());
        assert!(measured(&[(0.003, Some(true))]).is_some());
        assert!(measured(&[(0.010, Some(false))]).is_some());
        assert!(measured(&[(0.010, Some(true))]).is_none());
        assert!(measured(&[(0.010, Some(false)), (0.0, Some(true))]).is_some());
        assert!(measured(&[(0.004, Some(true)), (0.004, Some(true))]).is_some());
        assert!(measured(&[(0.004, None), (0.004, Some(true))]).is_none());
        assert!(measured(&[(0.004, Some(true)), (0.004, None), (0.004, Some(true))]).is_none());
    }

    #[test]
    fn no_motion_measures_nothing() {
        let level = NavState::at_rest(UnitQuaternion::identity());
        let filter = ErrorStateFilter::new(
            [V3::repeat(1e-3); 6],
            ProcessNoise {
                accel_vrw: 4.9e-4,
                gyro_arw: 1.5e-5,
                accel_bias_rw: 1e-7,
                gyro_bias_rw: 1e-9,
            },
        );
        let p = InsPush::anchored(100.0, &level, &filter, &V3::zeros(), &V3::zeros());
        assert!(!p.moved());
        assert!(p.measure(100.0, &V3::x()).is_none());
    }
}
