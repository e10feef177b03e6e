//! Magnetic disturbances: a magnet or a steel mass near the sensor changes
//! the field's magnitude or its dip (the angle below the horizontal),
//! which the Earth's field at a site does not. While either departs from
//! the site's, the compass is not used and its readings do not enter the
//! calibration (docs/engines/fuzzy.md: magnetic disturbances).
//!
//! With the calibrated field m_c levelled by the current tilt, h = its
//! horizontal magnitude and v its downward part:
//! - dip δ = atan2(v, h);
//! - magnitude ‖m_c‖ (the horizontal h for a planar calibration, whose
//!   vertical is sized from the site's inclination and says nothing).
//!
//! The magnitude reference is the calibration's own field magnitude (the
//! median over the readings it was fitted to, not one noisy reading), the
//! dip's starts from the site's inclination; both then follow undisturbed
//! readings (exponential means over `REFERENCE_TIME_CONSTANT_S`) and the
//! dip's survives a refit. A reading is disturbed when the magnitude
//! departs by more than `magnitude_tolerance` (relative) or the dip by more
//! than `dip_tolerance_rad`. A disturbance ends only after `CALM_S` of
//! undisturbed readings, so an odd reading inside it does not restart its
//! clock. One that lasts (an attached magnet, a new steel structure) is the
//! calibration's to absorb: after `RELEARN_AFTER_S` of it the references
//! start again from the readings. Such a field is [`relearnt`]: it feeds
//! the calibration, but a magnet on the vehicle is as steady as the
//! Earth's field and turns the compass, so it steers the heading only
//! once a new calibration is fitted, its heading changes agree with the
//! gyro's across turns (the engine's `turn_check.rs`), or the calibrated
//! field is back for `CALM_S`.
//!
//! [`relearnt`]: DisturbanceDetector::relearnt

use serde::{Deserialize, Serialize};

/// Time constant of the learned references, s.
const REFERENCE_TIME_CONSTANT_S: f64 = 30.0;
/// A disturbance longer than this is taken as the new field, s.
const RELEARN_AFTER_S: f64 = 120.0;
/// A disturbance is over after this long without a disturbed reading, s.
const CALM_S: f64 = 2.0;

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
    /// Since when the field has been disturbed (kept through `CALM_S`
    /// of undisturbed readings).
    disturbed_since: Option<f64>,
    /// The newest disturbed reading's time.
    #[serde(default)]
    last_disturbed_t: Option<f64>,
    /// Since when every reading has departed (none calm in between).
    #[serde(default)]
    departing_since: Option<f64>,
    /// The references were taken from a lasting disturbance and neither a
    /// calibration nor the gyro has confirmed them yet.
    #[serde(default)]
    relearnt: bool,
    /// The references the newest calibration set (magnitude µT, dip
    /// rad): a relearnt field back at them is the calibrated one again.
    #[serde(default)]
    calibrated: Option<(f64, f64)>,
    /// Since when every reading has agreed with those, while relearnt.
    #[serde(default)]
    back_since: Option<f64>,
    /// The site's inclination, rad: the Earth's field dips by it
    /// whatever the references have learnt.
    site_dip_rad: f64,
}

impl DisturbanceDetector {
    /// Nothing learned; the dip starts at the site's inclination.
    pub fn new(inclination_rad: f64) -> DisturbanceDetector {
        DisturbanceDetector {
            magnitude_ut: None,
            dip_rad: inclination_rad,
            newest_t: None,
            disturbed_since: None,
            last_disturbed_t: None,
            departing_since: None,
            relearnt: false,
            calibrated: None,
            back_since: None,
            site_dip_rad: inclination_rad,
        }
    }

    /// A new calibration: its field magnitude (µT, horizontal for a planar
    /// one; `None` if unknown: the next reading's) becomes the reference,
    /// the learned dip is kept and no disturbance is pending.
    pub fn recalibrated(&mut self, magnitude_ut: Option<f64>) {
        self.magnitude_ut = magnitude_ut.filter(|m| m.is_finite() && *m > 0.0);
        self.relearnt = false;
        self.back_since = None;
        self.calibrated = self.magnitude_ut.map(|m| (m, self.dip_rad));
        self.end_disturbance();
    }

    /// True from a lasting disturbance taken as the field until a new
    /// calibration or [`confirm`](Self::confirm): the field is steady, but
    /// a magnet on the vehicle is steady too, and its heading is wrong.
    pub fn relearnt(&self) -> bool {
        self.relearnt
    }

    /// How far the field the references follow may turn the compass's
    /// heading, rad, judged by its dip against the site's inclination I:
    /// 0 while the reference dip δ is within `tolerance_rad` of I; beyond
    /// it the field is not the Earth's alone (a calibration fitted through
    /// steel, a lasting disturbance relearnt), and the vertical part of
    /// what was added, |v − h·tan I| = h·|tan δ − tan I|, over the
    /// horizontal field h is the scale of the deflection its unseen
    /// horizontal part may cause: atan(|tan δ − tan I|).
    pub fn off_site_deflection_rad(&self, tolerance_rad: f64) -> f64 {
        if (self.dip_rad - self.site_dip_rad).abs() <= tolerance_rad {
            return 0.0;
        }
        (self.dip_rad.tan() - self.site_dip_rad.tan()).abs().atan()
    }

    /// The relearnt field's heading changes agree with the gyro's across
    /// turns: it is the Earth's.
    pub fn confirm(&mut self) {
        self.relearnt = false;
    }

    fn end_disturbance(&mut self) {
        self.disturbed_since = None;
        self.last_disturbed_t = None;
        self.departing_since = None;
    }

    /// How long every reading has departed from the references at `t`, s
    /// (0 after a calm one): the disturbance itself, without its calm tail.
    pub fn departing_for_s(&self, t: f64) -> f64 {
        self.departing_since
            .map_or(0.0, |since| (t - since).max(0.0))
    }

    /// True while a disturbance lasts (until `CALM_S` after its newest
    /// disturbed reading).
    pub fn disturbed(&self) -> bool {
        self.disturbed_since.is_some()
    }

    fn mark_disturbed(&mut self, t: f64) -> f64 {
        self.last_disturbed_t = Some(t);
        self.departing_since.get_or_insert(t);
        *self.disturbed_since.get_or_insert(t)
    }

    /// Takes a calibrated, levelled field (x north-ish, y, z down; µT) at
    /// time `t`; `planar` when only the horizontal magnitude is
    /// meaningful. Returns true while disturbed: the reading departs, or
    /// the disturbance it follows has not been calm for `CALM_S`.
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
        let agrees = |(reference, reference_dip): (f64, f64)| {
            (dip - reference_dip).abs() <= tolerances.dip_rad
                && (magnitude / reference - 1.0).abs() <= tolerances.magnitude
        };
        // Back at the calibrated field for `CALM_S` after a relearnt one
        // (the magnet taken off): the calibrated references again.
        match self.calibrated.filter(|c| self.relearnt && agrees(*c)) {
            Some(calibrated) => {
                let since = *self.back_since.get_or_insert(t);
                if t - since >= CALM_S {
                    (self.magnitude_ut, self.dip_rad) = (Some(calibrated.0), calibrated.1);
                    self.relearnt = false;
                    self.back_since = None;
                    self.end_disturbance();
                }
            }
            None => self.back_since = None,
        }
        let dip_departs = (dip - self.dip_rad).abs() > tolerances.dip_rad;
        let departs = match self.magnitude_ut {
            Some(reference) => {
                dip_departs || (magnitude / reference - 1.0).abs() > tolerances.magnitude
            }
            // No magnitude to compare with, but the dip must be the site's.
            None => dip_departs,
        };
        if departs {
            let since = self.mark_disturbed(t);
            if t - since <= RELEARN_AFTER_S {
                return true;
            }
            // Lasting: the new field is the site's now (for the
            // calibration to absorb; not yet for the heading).
            self.magnitude_ut = Some(magnitude);
            self.dip_rad = dip;
            self.relearnt = self.calibrated.is_none_or(|c| !agrees(c));
            self.end_disturbance();
            return false;
        }
        self.departing_since = None;
        if self.last_disturbed_t.is_some_and(|last| t - last >= CALM_S) {
            self.end_disturbance();
        }
        let gain = (dt_s / REFERENCE_TIME_CONSTANT_S).min(1.0);
        self.magnitude_ut = Some(match self.magnitude_ut {
            Some(reference) => reference + (magnitude - reference) * gain,
            None => magnitude,
        });
        self.dip_rad += (dip - self.dip_rad) * gain;
        self.disturbed()
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
        // Gone again: still disturbed until CALM_S (2 s) have passed.
        assert!(detector.observe(60.1, &earth(0.0, Vector3::zeros()), false, &TOLERANCES));
        assert!(detector.observe(61.9, &earth(0.0, Vector3::zeros()), false, &TOLERANCES));
        assert!(!detector.observe(62.2, &earth(0.0, Vector3::zeros()), false, &TOLERANCES));
        // A dip change of 6° at equal magnitude.
        let tilted = {
            let dip = 66.0_f64.to_radians();
            Vector3::new(50.0 * dip.cos(), 0.0, 50.0 * dip.sin())
        };
        assert!(detector.observe(62.3, &tilted, false, &TOLERANCES));
    }

    #[test]
    fn the_calibration_sets_the_magnitude_and_the_first_reading_does_not() {
        let mut detector = DisturbanceDetector::new(60.0_f64.to_radians());
        // The calibration says 50 µT; a first reading 7 % strong departs.
        detector.recalibrated(Some(50.0));
        assert!(detector.observe(
            0.0,
            &(earth(0.0, Vector3::zeros()) * 1.07),
            false,
            &TOLERANCES
        ));
        // Without a calibrated magnitude the first reading is the reference.
        let mut fresh = DisturbanceDetector::new(60.0_f64.to_radians());
        assert!(!fresh.observe(
            0.0,
            &(earth(0.0, Vector3::zeros()) * 1.07),
            false,
            &TOLERANCES
        ));
        assert!(!fresh.observe(
            0.1,
            &(earth(1.0, Vector3::zeros()) * 1.07),
            false,
            &TOLERANCES
        ));
    }

    #[test]
    fn an_odd_calm_reading_does_not_restart_a_lasting_disturbance() {
        let mut detector = DisturbanceDetector::new(60.0_f64.to_radians());
        detector.recalibrated(Some(50.0));
        let shifted = earth(0.0, Vector3::new(0.0, 0.0, 15.0));
        let mut last = true;
        for i in 0..=1300 {
            let t = f64::from(i) * 0.1;
            // Every 10 s one reading of the old field.
            let field = if i % 100 == 50 {
                earth(0.0, Vector3::zeros())
            } else {
                shifted
            };
            last = detector.observe(t, &field, false, &TOLERANCES);
            if i < 1200 {
                assert!(last, "{i}");
            }
        }
        assert!(!last);
    }

    #[test]
    fn a_magnet_left_on_is_relearnt_and_its_removal_restores_the_calibrated_field() {
        let mut detector = DisturbanceDetector::new(60.0_f64.to_radians());
        detector.recalibrated(Some(50.0));
        let magnet = earth(0.0, Vector3::new(0.0, 0.0, 15.0));
        // Disturbed for RELEARN_AFTER_S (120 s), then taken as the field:
        // steady, but unconfirmed.
        for i in 0..=1210 {
            detector.observe(f64::from(i) * 0.1, &magnet, false, &TOLERANCES);
        }
        assert!(!detector.disturbed());
        assert!(detector.relearnt());
        // Taken off: the calibrated field departs from the relearnt one
        // but is the calibrated one once back for CALM_S (2 s).
        let earth_field = earth(0.0, Vector3::zeros());
        assert!(detector.observe(121.1, &earth_field, false, &TOLERANCES));
        assert!(detector.observe(122.0, &earth_field, false, &TOLERANCES));
        assert!(!detector.observe(123.2, &earth_field, false, &TOLERANCES));
        assert!(!detector.relearnt());
        assert!(!detector.observe(123.3, &earth_field, false, &TOLERANCES));
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
        // Steady, but not yet confirmed: the gyro or a calibration must.
        assert!(detector.relearnt());
        detector.confirm();
        assert!(!detector.relearnt());
    }

    #[test]
    fn a_relearnt_field_whose_dip_is_not_the_sites_may_deflect_the_heading() {
        let mut detector = DisturbanceDetector::new(60.0_f64.to_radians());
        for i in 0..300 {
            let t = f64::from(i) * 0.1;
            detector.observe(t, &earth(t * 0.3, Vector3::zeros()), false, &TOLERANCES);
        }
        // The Earth's field: nothing to add.
        assert_eq!(detector.off_site_deflection_rad(0.07), 0.0);
        // Steel adds a field that dips the total 70° (the same horizontal
        // 25 µT, a vertical of 25·tan 70° = 68.7 µT) for longer than the
        // relearning takes: the references are its now.
        let steel = |t: f64| {
            let level = earth(t * 0.3, Vector3::zeros());
            Vector3::new(level.x, level.y, 25.0 * 70.0_f64.to_radians().tan())
        };
        for i in 0..1300 {
            let t = 30.0 + f64::from(i) * 0.1;
            detector.observe(t, &steel(t), false, &TOLERANCES);
        }
        assert!(detector.relearnt());
        // atan(|tan 70° − tan 60°|) = atan(2.747477 − 1.732051)
        // = atan(1.015426) = 45.44°.
        let deflection = detector.off_site_deflection_rad(0.07).to_degrees();
        assert!((deflection - 45.44).abs() < 0.01, "{deflection}");
        // Within a tolerance wider than the 10° departure: nothing.
        assert_eq!(detector.off_site_deflection_rad(0.2), 0.0);
    }
}
