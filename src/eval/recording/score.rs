//! The errors scored (tilt, heading, total, in the Earth frame) and how
//! per-trial RMSEs are pooled.

use super::*;

/// RMS errors of one estimator on one trial (or pooled), degrees.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct OrientationErrors {
    /// Angle between the true and estimated gravity directions.
    pub tilt_deg: f64,
    /// Heading error after removing the constant offset.
    pub heading_deg: f64,
    /// Whole rotation error after removing the constant offset.
    pub total_deg: f64,
    /// Heading and total error without removing it (BROAD's definition).
    pub heading_raw_deg: f64,
    pub total_raw_deg: f64,
    /// The removed offset: estimator's north minus the reference's,
    /// clockwise, degrees (`null` when pooled).
    pub heading_offset_deg: Option<f64>,
}

/// Collects the Earth-frame error quaternions of one estimator on one trial.
#[derive(Debug, Clone, Default)]
pub struct ErrorSeries {
    errors: Vec<UnitQuaternion<f64>>,
}

impl ErrorSeries {
    /// Adds one estimate against the truth.
    pub fn add(&mut self, estimate: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>) {
        self.errors.push(estimate * truth.inverse());
    }

    /// Number of samples scored.
    pub fn len(&self) -> usize {
        self.errors.len()
    }

    /// True when nothing was scored.
    pub fn is_empty(&self) -> bool {
        self.errors.is_empty()
    }

    /// The RMS errors, the heading offset removed as the module explains.
    pub fn summary(&self) -> OrientationErrors {
        if self.errors.is_empty() {
            return OrientationErrors {
                tilt_deg: f64::NAN,
                heading_deg: f64::NAN,
                total_deg: f64::NAN,
                heading_raw_deg: f64::NAN,
                total_raw_deg: f64::NAN,
                heading_offset_deg: None,
            };
        }
        let (mut sin, mut cos) = (0.0, 0.0);
        for q in &self.errors {
            let turn = heading_turn(q);
            sin += turn.sin();
            cos += turn.cos();
        }
        let offset = f64::atan2(sin, cos);
        let unturn = UnitQuaternion::from_axis_angle(&V3::z_axis(), -offset);
        let mut sums = [0.0_f64; 5];
        for q in &self.errors {
            let turn = heading_turn(q);
            let corrected = q * unturn;
            let e = [
                tilt_error(q),
                wrap(turn - offset),
                corrected.angle(),
                wrap(turn),
                q.angle(),
            ];
            for (s, x) in sums.iter_mut().zip(e) {
                *s += x * x;
            }
        }
        let rms = |s: f64| deg((s / self.errors.len() as f64).sqrt());
        OrientationErrors {
            tilt_deg: rms(sums[0]),
            heading_deg: rms(sums[1]),
            total_deg: rms(sums[2]),
            heading_raw_deg: rms(sums[3]),
            total_raw_deg: rms(sums[4]),
            heading_offset_deg: Some(deg(offset)),
        }
    }
}

/// The signed turn of an Earth-frame error about the vertical, rad.
pub fn heading_turn(error: &UnitQuaternion<f64>) -> f64 {
    let q = error.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    wrap(2.0 * f64::atan2(s * q.k, s * q.w))
}

/// The angle between the directions of gravity an Earth-frame error
/// relates, rad: 2 acos √(w² + z²).
pub fn tilt_error(error: &UnitQuaternion<f64>) -> f64 {
    let q = error.quaternion();
    2.0 * (q.w * q.w + q.k * q.k).sqrt().min(1.0).acos()
}

pub(super) fn wrap(angle: f64) -> f64 {
    let a = (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU);
    a - std::f64::consts::PI
}

/// How per-trial RMSEs are pooled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pooling {
    Mean,
    Rms,
}

/// Each figure pooled over trials (trials without a figure left out).
pub fn pool(trials: &[OrientationErrors], how: Pooling) -> OrientationErrors {
    let rms = |f: fn(&OrientationErrors) -> f64| {
        let values: Vec<f64> = trials.iter().map(f).filter(|x| x.is_finite()).collect();
        let n = values.len() as f64;
        match how {
            _ if values.is_empty() => f64::NAN,
            Pooling::Mean => values.iter().sum::<f64>() / n,
            Pooling::Rms => (values.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        }
    };
    OrientationErrors {
        tilt_deg: rms(|e| e.tilt_deg),
        heading_deg: rms(|e| e.heading_deg),
        total_deg: rms(|e| e.total_deg),
        heading_raw_deg: rms(|e| e.heading_raw_deg),
        total_raw_deg: rms(|e| e.total_raw_deg),
        heading_offset_deg: None,
    }
}
