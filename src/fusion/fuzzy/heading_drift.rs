//! Whose fault is a compass the gate refuses: the gyro's or the field's
//! (docs/engines/fuzzy.md: step 4, heading)?
//!
//! The heading gate refuses a compass that disagrees with the
//! gyro-carried heading by more than two σ, because a disturbance that
//! keeps the field's magnitude and dip shows only that way. But a gyro
//! whose bias has walked further than its filter believes carries the
//! heading away just as surely, and then the gate refuses the one sensor
//! that would bring it back. The two leave different traces in the
//! innovation ν = compass − heading over the last [`WINDOW_S`]:
//! - a **drifting gyro** makes ν a ramp, ν ≈ a + r·t, that starts where the
//!   compass was believed (|a| within the gate) and fits within the
//!   compass's own σ;
//! - a **disturbance** arrives as a step (the sensor passes steel, a
//!   magnet comes near) or, on a moving vehicle, as an error that changes
//!   with the heading: no line fits it.
//!
//! A calibration's residual error changes with the heading too, and on a
//! steady turn that can look like a ramp: only a span over which the
//! heading turned by at most [`MAX_TURN_RAD`] is judged, and only a
//! calibrated compass (an uncalibrated one's error is its hard iron, which
//! every turn sweeps).
//!
//! So the innovations of undisturbed, fresh compass readings are kept and
//! a straight line is fitted to them by least squares; a ramp that fits
//! is evidence of a bias error of about r on the world vertical, which
//! the engine adds to its bias variance, so the bias filter learns it from
//! the compass's pulls and the heading's σ (and with it the gate) grows
//! to the size the data show.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Span of innovations kept, s.
pub const WINDOW_S: f64 = 30.0;
/// The shortest span a ramp is judged on, s.
pub const MIN_SPAN_S: f64 = 10.0;
/// Innovations kept at most (the newest).
const MAX_INNOVATIONS: usize = 1024;
/// The most the heading may turn over a span judged, rad (30°).
pub const MAX_TURN_RAD: f64 = std::f64::consts::FRAC_PI_6;

/// A straight line through the innovations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    /// Its slope, rad/s: the heading's drift against the compass.
    pub rate_rad_per_s: f64,
    /// Its value at the oldest innovation kept, rad.
    pub start_rad: f64,
    /// RMS of the innovations about it, rad.
    pub residual_rad: f64,
    /// Time from the oldest innovation kept to the newest, s.
    pub span_s: f64,
    /// The largest turn of the heading from the oldest reading's, rad.
    pub turned_rad: f64,
}

/// The innovations of the last [`WINDOW_S`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Innovations {
    /// (time, ν, heading) oldest first, s, rad and rad.
    kept: VecDeque<(f64, f64, f64)>,
}

impl Innovations {
    /// Adds the innovation `innovation_rad` of a fresh, undisturbed
    /// compass reading taken at `t`, against the gyro-carried
    /// `heading_rad`; a reading not newer than the newest kept is skipped
    /// (one innovation per compass reading).
    pub fn push(&mut self, t: f64, innovation_rad: f64, heading_rad: f64) {
        if !t.is_finite()
            || !innovation_rad.is_finite()
            || !heading_rad.is_finite()
            || self.kept.back().is_some_and(|(newest, _, _)| t <= *newest)
        {
            return;
        }
        self.kept.push_back((t, innovation_rad, heading_rad));
        while self
            .kept
            .front()
            .is_some_and(|(oldest, _, _)| t - oldest > WINDOW_S)
            || self.kept.len() > MAX_INNOVATIONS
        {
            self.kept.pop_front();
        }
    }

    /// Forgets every innovation (the compass was taken, or disturbed).
    pub fn clear(&mut self) {
        self.kept.clear();
    }

    /// The least-squares line through the innovations kept, once they
    /// span [`MIN_SPAN_S`].
    pub fn ramp(&self) -> Option<Ramp> {
        let (&(t0, _, h0), &(t1, _, _)) = (self.kept.front()?, self.kept.back()?);
        let span_s = t1 - t0;
        if span_s < MIN_SPAN_S || self.kept.len() < 3 {
            return None;
        }
        let n = self.kept.len() as f64;
        let mean_t = self.kept.iter().map(|(t, _, _)| t - t0).sum::<f64>() / n;
        let mean_v = self.kept.iter().map(|(_, v, _)| v).sum::<f64>() / n;
        let turned_rad = self
            .kept
            .iter()
            .map(|(_, _, h)| super::orientation::angle_difference(*h, h0).abs())
            .fold(0.0, f64::max);
        let (mut stt, mut stv) = (0.0, 0.0);
        for (t, v, _) in &self.kept {
            let dt = t - t0 - mean_t;
            stt += dt * dt;
            stv += dt * (v - mean_v);
        }
        if stt <= 0.0 {
            return None;
        }
        let rate = stv / stt;
        let start = mean_v - rate * mean_t;
        let residual = (self
            .kept
            .iter()
            .map(|(t, v, _)| (v - start - rate * (t - t0)).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        Some(Ramp {
            rate_rad_per_s: rate,
            start_rad: start,
            residual_rad: residual,
            span_s,
            turned_rad,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ramp_fits_and_a_step_does_not() {
        // 0.3 °/s from agreement, 10 Hz for 20 s, ±0.5° alternating noise.
        let mut drift = Innovations::default();
        let noise = 0.5_f64.to_radians();
        for k in 0..=200 {
            let t = f64::from(k) * 0.1;
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            drift.push(
                100.0 + t,
                (0.3 * t).to_radians() + sign * noise,
                3.1 + 0.001 * t,
            );
        }
        let ramp = drift.ramp().unwrap();
        assert!(
            (ramp.rate_rad_per_s.to_degrees() - 0.3).abs() < 0.01,
            "{ramp:?}"
        );
        assert!(ramp.start_rad.to_degrees().abs() < 0.2);
        assert!((ramp.residual_rad.to_degrees() - 0.5).abs() < 0.02);
        assert!((ramp.span_s - 20.0).abs() < 1e-9);
        // Across ±180°: 3.1 to 3.12 rad wraps, and turned 0.02 rad.
        assert!((ramp.turned_rad - 0.02).abs() < 1e-9, "{ramp:?}");
        // A 6° step halfway: the line through it misses by about 1.5°
        // (the RMS of ±3° less the line's share).
        let mut step = Innovations::default();
        for k in 0..=200 {
            let t = f64::from(k) * 0.1;
            step.push(t, if t < 10.0 { 0.0 } else { 6f64.to_radians() }, 0.0);
        }
        let line = step.ramp().unwrap();
        assert!(line.residual_rad.to_degrees() > 1.2, "{line:?}");
        // Older than the window: dropped; too short a span: no ramp.
        let mut short = Innovations::default();
        short.push(0.0, 0.0, 0.0);
        short.push(50.0, 0.1, 0.0);
        short.push(55.0, 0.1, 0.0);
        short.push(55.0, 0.2, 0.0);
        assert!(short.ramp().is_none());
        assert_eq!(short.kept.len(), 2);
    }
}
