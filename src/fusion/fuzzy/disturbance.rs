//! Magnetic disturbances: a magnet or a steel mass near the sensor changes
//! the field's magnitude or its dip (the angle below the horizontal),
//! which the Earth's field at a site does not. While either departs from
//! the site's, the compass is not used and its readings do not enter the
//! calibration (README: "The fuzzy engine", magnetic disturbances).
//!
//! With the calibrated field m_c levelled by the current tilt, h = its
//! horizontal magnitude and v its downward part:
//! - dip δ = atan2(v, h);
//! - magnitude ‖m_c‖ (the horizontal h for a planar calibration, whose
//!   vertical is sized from the site's inclination and says nothing).
//!
//! The references are learned from undisturbed readings (exponential
//! means over `REFERENCE_TIME_CONSTANT_S`), the dip starting from the
//! site's inclination; a reading is disturbed when the magnitude departs
//! by more than `magnitude_tolerance` (relative) or the dip by more than
//! `dip_tolerance_rad`. A disturbance that lasts (an attached magnet, a new
//! steel structure) is the calibration's to absorb: after
//! `RELEARN_AFTER_S` of it the references start again from the readings.

use serde::{Deserialize, Serialize};

/// Time constant of the learned references, s.
const REFERENCE_TIME_CONSTANT_S: f64 = 30.0;
/// A disturbance longer than this is taken as the new field, s.
const RELEARN_AFTER_S: f64 = 120.0;

/// The tolerances before a reading counts as disturbed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Tolerances {
    /// Relative departure of the magnitude, e.g. 0.06.
    pub magnitude: f64,
    pub dip_rad: f64,
}

/// Learned field magnitude and dip, and whether the newest reading departs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DisturbanceDetector {
    magnitude_ut: Option<f64>,
    dip_rad: f64,
    newest_t: Option<f64>,
    /// Since when the field has been disturbed.
    disturbed_since: Option<f64>,
}

impl DisturbanceDetector {
    /// Nothing learned; the dip starts at the site's inclination.
    pub fn new(inclination_rad: f64) -> DisturbanceDetector {
        DisturbanceDetector {
            magnitude_ut: None,
            dip_rad: inclination_rad,
            newest_t: None,
            disturbed_since: None,
        }
    }

    /// How long the field has been disturbed at `t`, s (0 if it is not).
    pub fn disturbed_for_s(&self, t: f64) -> f64 {
        self.disturbed_since
            .map_or(0.0, |since| (t - since).max(0.0))
    }

    /// True while the newest reading departs from the references.
    pub fn disturbed(&self) -> bool {
        self.disturbed_since.is_some()
    }

    /// Takes a calibrated, levelled field (x north-ish, y, z down; µT) at
    /// time `t`; `planar` when only the horizontal magnitude is
    /// meaningful. Returns true if the reading is disturbed.
    pub fn observe(
        &mut self,
        t: f64,
        level_field_ut: &nalgebra::Vector3<f64>,
        planar: bool,
        tolerances: &Tolerances,
    ) -> bool {
        let horizontal = level_field_ut.xy().norm();
        let magnitude = if planar {
            horizontal
        } else {
            level_field_ut.norm()
        };
        let dip = level_field_ut.z.atan2(horizontal);
        if !magnitude.is_finite() || magnitude <= 0.0 || !dip.is_finite() {
            return self.disturbed();
        }
        let dt_s = self
            .newest_t
            .map_or(0.0, |newest| (t - newest).clamp(0.0, 1.0));
        self.newest_t = Some(t);
        let Some(reference) = self.magnitude_ut else {
            // The first reading has no magnitude to compare with, but its
            // dip must be the site's.
            if (dip - self.dip_rad).abs() > tolerances.dip_rad {
                return true;
            }
            self.magnitude_ut = Some(magnitude);
            return false;
        };
        let departs = (magnitude / reference - 1.0).abs() > tolerances.magnitude
            || (dip - self.dip_rad).abs() > tolerances.dip_rad;
        if departs {
            let since = *self.disturbed_since.get_or_insert(t);
            if t - since <= RELEARN_AFTER_S {
                return true;
            }
            // Lasting: the new field is the site's now.
            self.magnitude_ut = Some(magnitude);
            self.dip_rad = dip;
            self.disturbed_since = None;
            return false;
        }
        self.disturbed_since = None;
        let gain = (dt_s / REFERENCE_TIME_CONSTANT_S).min(1.0);
        self.magnitude_ut = Some(reference + (magnitude - reference) * gain);
        self.dip_rad += (dip - self.dip_rad) * gain;
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    const TOLERANCES: Tolerances = Tolerances {
        magnitude: 0.06,
        dip_rad: 0.07,
    };

    /// A field of 50 µT dipping 60°, turned to `heading` about the vertical.
    fn earth(heading: f64, extra: Vector3<f64>) -> Vector3<f64> {
        let h = 25.0;
        let v = 50.0 * 60.0_f64.to_radians().sin();
        Vector3::new(h * heading.cos(), -h * heading.sin(), v) + extra
    }

    #[test]
    fn a_magnet_is_detected_and_the_earth_is_not() {
        let mut detector = DisturbanceDetector::new(60.0_f64.to_radians());
        for i in 0..600 {
            let t = f64::from(i) * 0.1;
            // Turning: magnitude and dip stay.
            assert!(!detector.observe(t, &earth(t * 0.3, Vector3::zeros()), false, &TOLERANCES));
        }
        // 10 µT along x: magnitude 50 → about 55 at heading 0 (10 %).
        assert!(detector.observe(
            60.0,
            &earth(0.0, Vector3::new(10.0, 0.0, 0.0)),
            false,
            &TOLERANCES
        ));
        assert!(detector.disturbed());
        // Gone again.
        assert!(!detector.observe(60.1, &earth(0.0, Vector3::zeros()), false, &TOLERANCES));
        // A dip change of 6° at equal magnitude.
        let tilted = {
            let dip = 66.0_f64.to_radians();
            Vector3::new(50.0 * dip.cos(), 0.0, 50.0 * dip.sin())
        };
        assert!(detector.observe(60.2, &tilted, false, &TOLERANCES));
    }

    #[test]
    fn a_lasting_disturbance_becomes_the_reference() {
        let mut detector = DisturbanceDetector::new(60.0_f64.to_radians());
        detector.observe(0.0, &earth(0.0, Vector3::zeros()), false, &TOLERANCES);
        let shifted = earth(0.0, Vector3::new(0.0, 0.0, 15.0));
        let mut last = true;
        for i in 1..=1300 {
            last = detector.observe(f64::from(i) * 0.1, &shifted, false, &TOLERANCES);
            if i < 1200 {
                assert!(last, "{i}");
            }
        }
        assert!(!last);
    }
}
