//! Magnetometer calibration from the data itself: hard iron (an offset
//! `b`) and soft iron (a symmetric matrix), so that the calibrated field
//! `m_c = S (m − b)` lies on a sphere whatever the body's orientation.
//!
//! Samples are kept one per direction bin (the newest wins, so the fit
//! follows slow changes): 36 azimuth bins of 10° of the field's body x–y
//! direction about the current centre, times 9 elevation bands of 20°.
//! Before the first fit the centre is only the middle of the extremes
//! seen and moves as they grow, so samples are not replaced then: one is
//! appended whenever the bin changes, and the kept samples are binned
//! again when the centre moves. From the first fit on, the newest sample
//! of a bin replaces the others there. At most 512 samples are kept (the
//! oldest go first).
//! - **ellipsoid**: once the samples span enough of the sphere (azimuths
//!   over `min_coverage_deg` and at least 5 elevation bands), the general
//!   quadric mᵀQm + 2uᵀm = 1 is fitted by linear least squares (9
//!   unknowns); b = −Q⁻¹u, and S = (Q / (1 + bᵀQb))^½ scaled to det S = 1.
//! - **planar** (`planar_fit.rs`): a ground vehicle turns about its z
//!   axis and barely tilts, so the vertical soft iron is unobservable.
//!   With azimuths over `min_coverage_deg` among the samples taken level
//!   (tilt within `level_tolerance`), the conic [x² y² 2xy 2x 2y]·p = 1
//!   is fitted to them in the body x–y plane: 2-D hard and soft iron
//!   (det 1). The z axis keeps unit scale; its offset is set so that the
//!   level samples' mean vertical field is R·tan I, R the corrected
//!   horizontal radius and I the site's inclination: the vertical then
//!   has the size the tilt compensation needs. Level samples come first:
//!   their heading does not rest on the tilt estimate. Without enough of
//!   them (a graded road, issue 34) every sample is levelled by the roll
//!   and pitch it was taken at and fitted in the level frame
//!   ([`fit_levelled`]); the gates then judge the levelled field.
//!
//! Level and tilted samples are kept apart (a tilted sample never
//! replaces a level one), and a level sample gives way only to one at
//! most 0.1° more tilted, so a vehicle that later drives on grades keeps
//! the most level samples it has seen.
//!
//! A candidate fit is accepted only if it passes every gate (issue 18:
//! a still sensor once "covered" 360° of noise and fitted a sphere to it):
//! - **coverage measured honestly**: a sample is binned only when it lies
//!   at least `MIN_RADIUS_UT` from the centre, so the noise of a still
//!   sensor around the middle of its own extremes covers nothing;
//! - **plausible field**: the corrected field's mean magnitude (horizontal
//!   for a planar fit, at most 70 µT) lies in the range of the Earth's field;
//! - **directions really spread**: the corrected directions span at least
//!   90° (360° less the widest gap between their azimuths in the body x–y
//!   plane for a planar fit; about each of the three principal axes of
//!   their second moment for a full one), so a fit over a narrow arc,
//!   band or cap of directions is refused, however dense;
//! - **residual**: RMS of the relative radius error over the fitted
//!   samples ≤ 10 %;
//! - **held-back samples**: every `HOLDOUT_EVERY`-th reading is kept out of
//!   the fit, the newest per direction bin (at most `HOLDOUT_SAMPLES`);
//!   they must span 90° through the candidate, and the candidate's
//!   relative radius spread on them must be at most `IMPROVEMENT` of the
//!   current correction's (the raw field's before the first fit): a new
//!   calibration is never worse than the previous one on recent data, and
//!   a refit that only fits the noise differently changes nothing.
//!
//! When no candidate beats the raw field and the raw field itself passes
//! the gates with a spread of at most `MAX_RAW_RMS`, the raw field is the
//! calibration (`raw`: a factory-calibrated magnetometer is used as it is
//! rather than refitted to its own noise).
//!
//! **A calibration is checked on every reading afterwards** (issue 34):
//! only undisturbed readings reach the fit, and a wrong ellipsoid (fitted
//! early in fast motion, or before a magnet was attached) makes every
//! reading look disturbed, so it would never be refitted. [`check`]
//! keeps the newest readings, one per 0.1 s, disturbed or not; once their
//! raw directions span 90° (not judged through the ellipsoid: a hard iron as
//! large as the field would bunch them up), the ellipsoid's relative
//! radius spread on them is compared with the raw field's. A calibration more
//! than `CHECK_WORSE_THAN_RAW` (2) times worse than no calibration, and
//! worse than `MAX_RAW_RMS`, is dropped, with its samples: the raw field becomes the
//! calibration if its own spread is within `MAX_RAW_RMS`, otherwise the
//! fit starts again from the readings that follow. A steady disturbance
//! near the sensor bends the raw and the calibrated field alike and
//! refutes nothing. Planar calibrations are not checked: their vertical
//! is set, not measured.
//!
//! [`check`]: MagCalibration::check

use std::collections::VecDeque;

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::arc_fit::{ArcCalibration, GyroHeading};
use super::planar_fit::{fit_levelled, fit_planar};
use crate::fusion::geometry::{V3, attitude_from_euler};

const AZIMUTH_BINS: usize = 36;
const ELEVATION_BANDS: usize = 9;
/// Elevation bands needed for a full ellipsoid fit.
const MIN_ELEVATION_BANDS: usize = 5;
/// A fit worse than this (RMS of the relative radius error) is refused.
const MAX_FIT_RMS: f64 = 0.1;
/// A level sample is replaced in its bin only by one tilted at most this
/// much more (0.1°), so the level set gets more level over time.
const LEVEL_SLACK_RAD: f64 = 0.001_745;
/// Samples kept for the fit.
const MAX_SAMPLES: usize = 512;
/// A sample nearer the binning centre than this says nothing of a
/// direction (the noise of a still sensor around the middle of its own
/// extremes), µT: ten times a MEMS magnetometer's noise, a third of the
/// weakest horizontal Earth's field at tunnelling latitudes.
const MIN_RADIUS_UT: f64 = 5.0;
/// The Earth's field is 22–67 µT everywhere; a fit whose corrected field
/// is far outside that (a tiny sphere around noise, a huge one from a
/// degenerate quadric) is refused. The horizontal part can be small near
/// the magnetic poles, hence the lower bound.
const PLAUSIBLE_FIELD_UT: (f64, f64) = (5.0, 150.0);
/// The Earth's field is at most about 67 µT, and so is its horizontal
/// part: a planar fit whose levelled horizontal radius is above this has
/// fitted a disturbance (a calibration circle next to steel).
const MAX_HORIZONTAL_UT: f64 = 70.0;
/// Field directions a fit must span, degrees (module documentation).
const MIN_SPAN_DEG: f64 = 90.0;
/// Every this many readings one is held back from the fit to check it.
const HOLDOUT_EVERY: u64 = 4;
/// A reading whose corrected radius is off by less than this (relative)
/// is never an outlier of a fit.
const MIN_OUTLIER_RADIUS_ERROR: f64 = 0.03;
/// Rounds of refitting without outliers.
const OUTLIER_ROUNDS: usize = 3;
/// Held-back readings kept (the newest).
const HOLDOUT_SAMPLES: usize = 128;
/// A candidate replaces the current correction (the raw field before the
/// first) only if its held-back spread is at most this fraction of the
/// current one's: a refit that merely fits the noise differently changes
/// nothing.
const IMPROVEMENT: f64 = 0.7;
/// The raw field is taken as calibrated when no fit improves on it and
/// its relative radius spread is at most this (3 %).
const MAX_RAW_RMS: f64 = 0.03;
/// The check keeps one reading per this many seconds, disturbed or not.
const CHECK_SPACING_S: f64 = 0.1;
/// Readings the check keeps (the newest).
const CHECK_READINGS: usize = 128;
/// The check judges once it holds this many readings.
const CHECK_MIN_READINGS: usize = 64;
/// The check judges every this many new readings.
const CHECK_EVERY: u32 = 16;
/// A calibration whose radius spread on the newest readings is more than
/// this many times the raw field's is dropped (chosen on BROAD's odd
/// trials between 1/`IMPROVEMENT` and 2; docs/engines/fuzzy.md).
const CHECK_WORSE_THAN_RAW: f64 = 2.0;

/// How far the calibration has come.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum CalibrationState {
    /// Not enough directions seen: heading from the magnetometer is not used.
    Collecting,
    /// Hard and soft iron in the body x–y plane (ground vehicle).
    Planar,
    /// Full 3-D hard and soft iron.
    Ellipsoid,
    /// Fitted to a partial arc with the gyros' heading (arc_fit.rs), until
    /// the directions seen allow a planar or full fit.
    Arc,
    /// No fit improves on the raw field, which is consistent over the
    /// directions seen (a factory-calibrated magnetometer): used as it is.
    Raw,
}

impl CalibrationState {
    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            CalibrationState::Collecting => "collecting",
            CalibrationState::Planar => "planar",
            CalibrationState::Ellipsoid => "ellipsoid",
            CalibrationState::Arc => "arc",
            CalibrationState::Raw => "raw",
        }
    }
}

/// A fitted correction `m_c = soft_iron (m − hard_iron_ut)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Correction {
    pub hard_iron_ut: V3,
    pub soft_iron: Matrix3<f64>,
    /// RMS of the relative radius error over the samples fitted.
    pub fit_rms: f64,
}

impl Correction {
    /// The raw field taken as it is, with its relative radius spread over
    /// `samples` (horizontal if `planar`) as its residual.
    fn raw(samples: &[Tilted], planar: bool) -> Correction {
        Correction {
            hard_iron_ut: V3::zeros(),
            soft_iron: Matrix3::identity(),
            fit_rms: radius_rms(samples, |r| magnitude(r, None, planar)),
        }
    }

    /// The calibrated field, µT.
    pub fn apply(&self, field_ut: &V3) -> V3 {
        self.soft_iron * (field_ut - self.hard_iron_ut)
    }
}

/// A raw reading with the rotation that levels it: the filter's roll and
/// pitch when it was taken, undone (heading kept). A planar calibration
/// is fitted and judged in that level frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tilted {
    pub field_ut: V3,
    pub levelling: UnitQuaternion<f64>,
}

impl Tilted {
    /// A reading whose tilt does not matter to the fit (a full one).
    fn untilted(field_ut: V3) -> Tilted {
        Tilted {
            field_ut,
            levelling: UnitQuaternion::identity(),
        }
    }

    /// The field as a fit of this kind sees it: corrected (raw without a
    /// correction), and levelled if planar.
    pub(super) fn seen(&self, correction: Option<&Correction>, planar: bool) -> V3 {
        let field = correction.map_or(self.field_ut, |c| c.apply(&self.field_ut));
        if planar {
            self.levelling * field
        } else {
            field
        }
    }
}

/// Online calibration; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MagCalibration {
    min_coverage_deg: f64,
    inclination_rad: f64,
    level_tolerance_rad: f64,
    refit_every: u32,
    /// Samples kept, oldest first, each with its (azimuth, elevation) bin.
    samples: VecDeque<Sample>,
    /// Componentwise extremes of every sample, for the centre before a fit.
    min_ut: Option<V3>,
    max_ut: Option<V3>,
    state: CalibrationState,
    correction: Option<Correction>,
    /// The centre the bins were made around.
    binned_centre: V3,
    /// Samples binned since the last fit.
    since_fit: u32,
    /// Readings held back from the fit to check candidates, newest last.
    #[serde(default)]
    holdout: VecDeque<Sample>,
    /// Readings offered, for choosing the held-back ones.
    #[serde(default)]
    offered: u64,
    /// Candidate fits refused by a gate.
    #[serde(default)]
    refused: u64,
    /// The newest readings for the check, one per `CHECK_SPACING_S`.
    #[serde(default)]
    checked: VecDeque<V3>,
    /// When the newest of them was taken, s.
    #[serde(default)]
    checked_t: Option<f64>,
    /// Readings kept since the check last judged.
    #[serde(default)]
    since_check: u32,
    /// The planar correction was fitted to levelled readings
    /// ([`fit_levelled`]), not to level ones alone.
    #[serde(default)]
    levelled: bool,
    /// The gyro-aided partial-arc calibration, used until this one fits.
    #[serde(default)]
    arc: ArcCalibration,
}

impl MagCalibration {
    /// Fits once azimuths over `min_coverage_deg` are seen, refitting every
    /// `refit_every` samples. A sample tilted by at most
    /// `level_tolerance_rad` counts as level; `inclination_rad` is the
    /// site's field inclination (down positive), which sizes the vertical
    /// of a planar calibration.
    pub fn new(
        min_coverage_deg: f64,
        inclination_rad: f64,
        level_tolerance_rad: f64,
        refit_every: u32,
    ) -> MagCalibration {
        MagCalibration {
            min_coverage_deg,
            inclination_rad,
            level_tolerance_rad,
            refit_every: refit_every.max(1),
            samples: VecDeque::new(),
            min_ut: None,
            max_ut: None,
            state: CalibrationState::Collecting,
            correction: None,
            binned_centre: V3::zeros(),
            since_fit: 0,
            holdout: VecDeque::new(),
            offered: 0,
            refused: 0,
            checked: VecDeque::new(),
            checked_t: None,
            since_check: 0,
            levelled: false,
            arc: ArcCalibration::default(),
        }
    }

    /// Checks the calibration against the raw field on the newest
    /// readings (module documentation); `field_ut` is a raw reading at
    /// `t`, disturbed or not. Returns true when the calibration was
    /// dropped (replaced by the raw field, or by none).
    pub fn check(&mut self, t: f64, field_ut: V3) -> bool {
        if !field_ut.iter().all(|x| x.is_finite())
            || self
                .checked_t
                .is_some_and(|last| t >= last && t - last < CHECK_SPACING_S)
        {
            return false;
        }
        self.checked_t = Some(t);
        self.checked.push_back(field_ut);
        while self.checked.len() > CHECK_READINGS {
            self.checked.pop_front();
        }
        self.since_check += 1;
        if self.state != CalibrationState::Ellipsoid
            || self.checked.len() < CHECK_MIN_READINGS
            || self.since_check < CHECK_EVERY
        {
            return false;
        }
        self.since_check = 0;
        let Some(current) = self.correction else {
            return false;
        };
        let recent: Vec<Tilted> = self.checked.iter().copied().map(Tilted::untilted).collect();
        let raw_field = Correction::raw(&recent, false);
        // The directions are judged raw: a calibration wrong by a hard
        // iron as large as the field would bunch them up through itself.
        if direction_span_deg(&raw_field, &recent, false) < MIN_SPAN_DEG {
            return false;
        }
        let calibrated = radius_rms(&recent, |r| magnitude(r, Some(&current), false));
        let raw = raw_field.fit_rms;
        if calibrated <= MAX_RAW_RMS || calibrated <= raw * CHECK_WORSE_THAN_RAW {
            return false;
        }
        let checked = std::mem::take(&mut self.checked);
        *self = MagCalibration {
            checked,
            refused: self.refused,
            ..MagCalibration::new(
                self.min_coverage_deg,
                self.inclination_rad,
                self.level_tolerance_rad,
                self.refit_every,
            )
        };
        self.checked_t = Some(t);
        // The raw field passes the gates a fit to it would have to.
        if raw <= MAX_RAW_RMS && plausible_field(&raw_field, &recent, false) {
            self.correction = Some(raw_field);
            self.state = CalibrationState::Raw;
        }
        true
    }

    /// Candidate fits refused by a gate (module documentation), the
    /// partial arcs' included.
    pub fn refused_fits(&self) -> u64 {
        self.refused + self.arc.refused_fits()
    }

    /// The state reached.
    pub fn state(&self) -> CalibrationState {
        if self.correction.is_none() && self.arc.correction().is_some() {
            CalibrationState::Arc
        } else {
            self.state
        }
    }

    /// The current correction, once fitted: the planar or full fit's, or
    /// before it the partial arc's.
    pub fn correction(&self) -> Option<&Correction> {
        self.correction.as_ref().or(self.arc.correction())
    }

    /// The gyro heading restarted: the partial arc's samples are of no use.
    pub fn restart_arc(&mut self) {
        self.arc.restart();
    }

    /// The calibrated field's magnitude (µT; horizontal for a planar
    /// calibration): the median over the readings kept, `None` before a
    /// calibration.
    pub fn field_magnitude_ut(&self) -> Option<f64> {
        let Some(c) = self.correction.as_ref() else {
            return self.arc.field_magnitude_ut();
        };
        let planar = self.state == CalibrationState::Planar;
        let mut magnitudes: Vec<f64> = fields(&self.samples, planar && !self.levelled)
            .iter()
            .map(|r| magnitude(r, Some(c), planar))
            .collect();
        if magnitudes.is_empty() {
            return None;
        }
        magnitudes.sort_by(f64::total_cmp);
        Some(magnitudes[magnitudes.len() / 2])
    }

    /// Degrees of azimuth seen (10° per occupied azimuth bin).
    pub fn coverage_deg(&self) -> f64 {
        self.azimuth_coverage_deg(false)
    }

    /// Degrees of azimuth seen by the samples (the level ones alone if
    /// `level_only`).
    fn azimuth_coverage_deg(&self, level_only: bool) -> f64 {
        self.azimuths_seen(level_only) as f64 * (360.0 / AZIMUTH_BINS as f64)
    }

    fn azimuths_seen(&self, level_only: bool) -> usize {
        // One bit per azimuth bin (every estimate asks, over up to
        // `MAX_SAMPLES` samples: a mask is the cheapest pass).
        const _: () = assert!(AZIMUTH_BINS <= 64);
        let mut seen = 0u64;
        for sample in self.samples.iter().filter(|s| s.level || !level_only) {
            seen |= 1 << (sample.bin % AZIMUTH_BINS);
        }
        seen.count_ones() as usize
    }

    fn elevations_seen(&self) -> usize {
        let mut seen = [false; ELEVATION_BANDS];
        for sample in &self.samples {
            seen[sample.bin / AZIMUTH_BINS] = true;
        }
        seen.iter().filter(|&&s| s).count()
    }

    /// Where samples are binned around: the fitted centre, or the middle of
    /// the extremes seen.
    fn centre(&self) -> V3 {
        match (&self.correction, self.min_ut, self.max_ut) {
            (Some(c), _, _) => c.hard_iron_ut,
            (None, Some(lo), Some(hi)) => (lo + hi) * 0.5,
            _ => V3::zeros(),
        }
    }

    /// Adds a raw reading (µT) taken at the filter's roll and pitch
    /// (rad) and, once aligned, with the engine's gyro heading; refits
    /// when due. Returns true when the correction changed.
    pub fn add(
        &mut self,
        field_ut: V3,
        roll_rad: f64,
        pitch_rad: f64,
        gyro: Option<GyroHeading>,
    ) -> bool {
        if !field_ut.iter().all(|x| x.is_finite()) {
            return false;
        }
        // Until a planar or full fit, the partial arc's (every reading: it
        // keeps its own samples).
        let arc_changed = match gyro {
            Some(gyro) if self.correction.is_none() => {
                self.arc
                    .add(field_ut, (roll_rad, pitch_rad), gyro, self.inclination_rad)
            }
            _ => false,
        };
        let had_fit = self.correction.is_some();
        let changed = self.add_binned(field_ut, roll_rad, pitch_rad);
        if !had_fit && self.correction.is_some() {
            // The planar or full fit takes over: the arc's samples would
            // only weigh on every snapshot.
            self.arc.restart();
        }
        changed || arc_changed
    }

    /// [`add`](Self::add) for the planar and full fits.
    fn add_binned(&mut self, field_ut: V3, roll_rad: f64, pitch_rad: f64) -> bool {
        self.offered += 1;
        if self.offered.is_multiple_of(HOLDOUT_EVERY) {
            // Held back one per direction bin (the newest), so the ring
            // spans the directions seen rather than the last seconds.
            if let Some(bin) = direction_bin(&self.binned_centre, &field_ut) {
                let sample = Sample::new(
                    field_ut,
                    bin,
                    (roll_rad, pitch_rad),
                    self.level_tolerance_rad,
                );
                self.holdout
                    .retain(|s| s.bin != bin || s.level != sample.level);
                push_newest(&mut self.holdout, sample, HOLDOUT_SAMPLES);
            }
            return false;
        }
        self.min_ut = Some(self.min_ut.map_or(field_ut, |m| m.inf(&field_ut)));
        self.max_ut = Some(self.max_ut.map_or(field_ut, |m| m.sup(&field_ut)));
        // The centre moves while the extremes grow (and with each fit):
        // the samples kept are binned again around the new one.
        let centre = self.centre();
        if let (Some(lo), Some(hi)) = (self.min_ut, self.max_ut)
            && (centre - self.binned_centre).norm() > 0.02 * (hi - lo).norm()
        {
            self.binned_centre = centre;
            for sample in self.samples.iter_mut().chain(self.holdout.iter_mut()) {
                if let Some(bin) = direction_bin(&centre, &sample.field_ut) {
                    sample.bin = bin;
                }
            }
        }
        let Some(bin) = direction_bin(&self.binned_centre, &field_ut) else {
            return false;
        };
        let sample = Sample::new(
            field_ut,
            bin,
            (roll_rad, pitch_rad),
            self.level_tolerance_rad,
        );
        let (level, tilt_rad) = (sample.level, sample.tilt_rad());
        let same = |s: &Sample| s.bin == bin && s.level == level;
        if self.correction.is_some() {
            // A level sample gives way only to one about as level or more.
            if level
                && self
                    .samples
                    .iter()
                    .any(|s| same(s) && s.tilt_rad() + LEVEL_SLACK_RAD < tilt_rad)
            {
                return false;
            }
            self.samples.retain(|s| !same(s));
        } else if self.samples.back().is_some_and(same) {
            return false;
        }
        push_newest(&mut self.samples, sample, MAX_SAMPLES);
        self.since_fit += 1;
        if self.since_fit < self.refit_every && self.state != CalibrationState::Collecting {
            return false;
        }
        self.refit()
    }

    /// Fits from the binned samples if they cover enough directions.
    fn refit(&mut self) -> bool {
        self.since_fit = 0;
        if self.coverage_deg() < self.min_coverage_deg {
            return false;
        }
        let inclination = self.inclination_rad;
        // Level readings first: their heading does not rest on the tilt
        // estimate, whose error in a turn (0.3–1°) would tip the field's
        // large vertical into the horizontal; the levelled fit where they
        // do not cover enough directions (a graded road).
        let (state, levelled) = if self.elevations_seen() >= MIN_ELEVATION_BANDS {
            (CalibrationState::Ellipsoid, false)
        } else {
            (
                CalibrationState::Planar,
                self.azimuth_coverage_deg(true) < self.min_coverage_deg,
            )
        };
        let planar = state == CalibrationState::Planar;
        let level_only = planar && !levelled;
        let fitted = fields(&self.samples, level_only);
        let held = fields(&self.holdout, level_only);
        let fit = if !planar {
            refit_without_outliers(&fitted, false, |s| fit_ellipsoid(&raw_fields(s)))
        } else if levelled {
            // Its own rounds judge the vertical too.
            fit_levelled(&fitted, inclination)
        } else {
            refit_without_outliers(&fitted, true, |s| fit_planar(&raw_fields(s), inclination))
        };
        let passes_gates = |c: &Correction| {
            c.fit_rms <= MAX_FIT_RMS
                && plausible_field(c, &fitted, planar)
                && direction_span_deg(c, &fitted, planar) >= MIN_SPAN_DEG
        };
        let current = held_spread(&held, self.correction.as_ref(), planar);
        // A candidate is judged on held-back readings that span enough
        // directions through it; without them it waits.
        let accepted = fit.filter(|candidate| {
            passes_gates(candidate)
                && direction_span_deg(candidate, &held, planar) >= MIN_SPAN_DEG
                && match (held_spread(&held, Some(candidate), planar), current) {
                    (Some(new), Some(old)) => new <= IMPROVEMENT * old,
                    _ => false,
                }
        });
        if let Some(correction) = accepted {
            self.correction = Some(correction);
            self.state = state;
            self.levelled = levelled;
            return true;
        }
        self.refused += 1;
        // No fit beats the raw field clearly: if the raw field is already
        // consistent over directions that span enough, it is the
        // calibration (a factory-calibrated magnetometer).
        if self.correction.is_none() {
            let raw = Correction::raw(&fitted, planar);
            if passes_gates(&raw) && raw.fit_rms <= MAX_RAW_RMS {
                self.correction = Some(raw);
                self.state = CalibrationState::Raw;
                self.levelled = false;
                return true;
            }
        }
        false
    }
}

/// The readings a fit takes: every one with its levelling, or (`level_only`)
/// the level ones as if untilted.
fn fields(samples: &VecDeque<Sample>, level_only: bool) -> Vec<Tilted> {
    samples
        .iter()
        .filter(|s| s.level || !level_only)
        .map(|s| {
            if level_only {
                Tilted::untilted(s.field_ut)
            } else {
                s.tilted()
            }
        })
        .collect()
}

/// The raw fields of readings.
fn raw_fields(readings: &[Tilted]) -> Vec<V3> {
    readings.iter().map(|r| r.field_ut).collect()
}

/// A reading's magnitude through a correction (raw without one) as a fit
/// of this kind sees it: the levelled horizontal one if planar.
pub(super) fn magnitude(reading: &Tilted, correction: Option<&Correction>, planar: bool) -> f64 {
    let field = reading.seen(correction, planar);
    if planar {
        field.xy().norm()
    } else {
        field.norm()
    }
}

/// The relative radius spread of held-back readings through a correction
/// (`None`: the raw field); `None` when too few are held to judge by.
fn held_spread(held: &[Tilted], correction: Option<&Correction>, planar: bool) -> Option<f64> {
    (held.len() >= 8).then(|| radius_rms(held, |r| magnitude(r, correction, planar)))
}

/// Appends `sample`, dropping the oldest beyond `capacity`.
fn push_newest(queue: &mut VecDeque<Sample>, sample: Sample, capacity: usize) {
    queue.push_back(sample);
    if queue.len() > capacity {
        queue.pop_front();
    }
}

/// A field's direction bin around `centre`: 36 azimuths × 9 elevation
/// bands; `None` within `MIN_RADIUS_UT` of it.
fn direction_bin(centre: &V3, field_ut: &V3) -> Option<usize> {
    let d = field_ut - centre;
    let norm = d.norm();
    if norm < MIN_RADIUS_UT {
        return None;
    }
    let azimuth = d.y.atan2(d.x).rem_euclid(std::f64::consts::TAU);
    let elevation = (d.z / norm).clamp(-1.0, 1.0).asin() + std::f64::consts::FRAC_PI_2;
    let a = ((azimuth / std::f64::consts::TAU) * AZIMUTH_BINS as f64) as usize;
    let e = ((elevation / std::f64::consts::PI) * ELEVATION_BANDS as f64) as usize;
    Some(e.min(ELEVATION_BANDS - 1) * AZIMUTH_BINS + a.min(AZIMUTH_BINS - 1))
}

/// True when the corrected field's mean magnitude (horizontal if planar)
/// is one the Earth can have.
fn plausible_field(c: &Correction, samples: &[Tilted], planar: bool) -> bool {
    if samples.is_empty() {
        return false;
    }
    let mean = samples
        .iter()
        .map(|r| magnitude(r, Some(c), planar))
        .sum::<f64>()
        / samples.len() as f64;
    let upper = if planar {
        MAX_HORIZONTAL_UT
    } else {
        PLAUSIBLE_FIELD_UT.1
    };
    (PLAUSIBLE_FIELD_UT.0..=upper).contains(&mean)
}

/// The angle the corrected field directions span, degrees: in the level
/// frame's x–y plane if planar (360° less the widest azimuth gap); for a full
/// fit the least such span about the three principal axes of the
/// directions' second moment, so a narrow band or cap of directions,
/// however densely sampled, spans little.
pub fn direction_span_deg(c: &Correction, samples: &[Tilted], planar: bool) -> f64 {
    let directions: Vec<V3> = samples
        .iter()
        .filter_map(|r| {
            let mut v = r.seen(Some(c), planar);
            if planar {
                v.z = 0.0;
            }
            nalgebra::Unit::try_new(v, 1e-12).map(|u| u.into_inner())
        })
        .collect();
    if directions.is_empty() {
        return 0.0;
    }
    if planar {
        return azimuth_span_deg(directions.iter().map(|u| (u.x, u.y)));
    }
    let moment = directions
        .iter()
        .fold(Matrix3::zeros(), |m, u| m + u * u.transpose());
    let axes = nalgebra::SymmetricEigen::new(moment).eigenvectors;
    (0..3)
        .map(|k| {
            let axis: V3 = axes.column(k).into_owned();
            let e1 = axis
                .cross(&if axis.x.abs() < 0.9 { V3::x() } else { V3::y() })
                .normalize();
            let e2 = axis.cross(&e1);
            // Directions nearly along the axis have no azimuth about it.
            azimuth_span_deg(
                directions
                    .iter()
                    .filter(|u| u.dot(&axis).abs() < 0.95)
                    .map(|u| (u.dot(&e1), u.dot(&e2))),
            )
        })
        .fold(f64::INFINITY, f64::min)
}

/// 360° less the widest gap between the azimuths of 2-D vectors, degrees.
pub(super) fn azimuth_span_deg(vectors: impl Iterator<Item = (f64, f64)>) -> f64 {
    let mut azimuths: Vec<f64> = vectors.map(|(x, y)| y.atan2(x).to_degrees()).collect();
    if azimuths.len() < 2 {
        return 0.0;
    }
    azimuths.sort_by(f64::total_cmp);
    let wrap = azimuths[0] + 360.0 - azimuths[azimuths.len() - 1];
    let widest = azimuths
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(wrap, f64::max);
    360.0 - widest
}

/// A kept reading: the raw field, its direction bin, the filter's roll
/// and pitch when it was taken, and whether that was level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Sample {
    field_ut: V3,
    bin: usize,
    level: bool,
    roll_rad: f64,
    pitch_rad: f64,
}

impl Sample {
    /// A reading in direction bin `bin` taken at `(roll, pitch)`; level
    /// when both are within `level_tolerance_rad`.
    fn new(
        field_ut: V3,
        bin: usize,
        (roll_rad, pitch_rad): (f64, f64),
        level_tolerance_rad: f64,
    ) -> Sample {
        let mut sample = Sample {
            field_ut,
            bin,
            level: false,
            roll_rad,
            pitch_rad,
        };
        sample.level = sample.tilt_rad() <= level_tolerance_rad;
        sample
    }

    /// The larger of |roll| and |pitch|, rad.
    fn tilt_rad(&self) -> f64 {
        self.roll_rad.abs().max(self.pitch_rad.abs())
    }

    fn tilted(&self) -> Tilted {
        Tilted {
            field_ut: self.field_ut,
            levelling: attitude_from_euler(self.roll_rad, self.pitch_rad, 0.0),
        }
    }
}

/// Centre and scale for conditioning: the samples' mean and RMS spread.
pub(super) fn normaliser(samples: &[V3]) -> (V3, f64) {
    let n = samples.len().max(1) as f64;
    let mean = samples.iter().sum::<V3>() / n;
    let spread = (samples
        .iter()
        .map(|s| (s - mean).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    (mean, if spread > 0.0 { spread } else { 1.0 })
}

/// The symmetric square root of a positive-definite 3×3 matrix, or `None`.
fn sqrt_spd3(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let eigen = nalgebra::SymmetricEigen::new(*m);
    if eigen
        .eigenvalues
        .iter()
        .any(|&l| l <= 0.0 || !l.is_finite())
    {
        return None;
    }
    let root = eigen.eigenvalues.map(f64::sqrt);
    Some(eigen.eigenvectors * Matrix3::from_diagonal(&root) * eigen.eigenvectors.transpose())
}

pub(super) fn sqrt_spd2(m: &Matrix2<f64>) -> Option<Matrix2<f64>> {
    let eigen = nalgebra::SymmetricEigen::new(*m);
    if eigen
        .eigenvalues
        .iter()
        .any(|&l| l <= 0.0 || !l.is_finite())
    {
        return None;
    }
    let root = eigen.eigenvalues.map(f64::sqrt);
    Some(eigen.eigenvectors * Matrix2::from_diagonal(&root) * eigen.eigenvectors.transpose())
}

/// Each sample's corrected radius over the samples' mean, less one;
/// `None` when the mean is not positive.
fn relative_radius_errors<T>(samples: &[T], radius: impl Fn(&T) -> f64) -> Option<Vec<f64>> {
    let radii: Vec<f64> = samples.iter().map(radius).collect();
    let mean = radii.iter().sum::<f64>() / radii.len().max(1) as f64;
    if mean <= 0.0 {
        return None;
    }
    Some(radii.iter().map(|r| r / mean - 1.0).collect())
}

/// RMS of ‖S(m − b)‖ / mean − 1 over the samples, on the chosen axes.
pub(super) fn radius_rms<T>(samples: &[T], correct: impl Fn(&T) -> f64) -> f64 {
    let n = samples.len().max(1) as f64;
    match relative_radius_errors(samples, correct) {
        Some(errors) => (errors.iter().map(|e| e.powi(2)).sum::<f64>() / n).sqrt(),
        None => f64::INFINITY,
    }
}

/// Fits, then fits again without the readings whose corrected radius is
/// off by more than three times the fit's RMS (at least
/// `MIN_OUTLIER_RADIUS_ERROR`), up to `OUTLIER_ROUNDS` times: readings
/// taken next to a magnet or a steel mass must not bend the calibration
/// of every other direction. At least half the readings are kept.
fn refit_without_outliers(
    samples: &[Tilted],
    planar: bool,
    fit: impl Fn(&[Tilted]) -> Option<Correction>,
) -> Option<Correction> {
    let mut current = fit(samples)?;
    let mut kept = samples.len();
    for _ in 0..OUTLIER_ROUNDS {
        let Some(errors) =
            relative_radius_errors(samples, |r| magnitude(r, Some(&current), planar))
        else {
            break;
        };
        let limit = (3.0 * current.fit_rms).max(MIN_OUTLIER_RADIUS_ERROR);
        let inliers: Vec<Tilted> = samples
            .iter()
            .zip(&errors)
            .filter(|(_, e)| e.abs() <= limit)
            .map(|(r, _)| *r)
            .collect();
        if inliers.len() == kept || inliers.len() < samples.len() / 2 {
            break;
        }
        kept = inliers.len();
        match fit(&inliers) {
            Some(better) => current = better,
            None => break,
        }
    }
    Some(current)
}

/// Least-squares quadric fit; see the module documentation.
pub fn fit_ellipsoid(samples: &[V3]) -> Option<Correction> {
    if samples.len() < 9 {
        return None;
    }
    let (mean, scale) = normaliser(samples);
    let mut normal = SMatrix::<f64, 9, 9>::zeros();
    let mut rhs = SVector::<f64, 9>::zeros();
    for s in samples {
        let p = (s - mean) / scale;
        let row = SVector::<f64, 9>::from([
            p.x * p.x,
            p.y * p.y,
            p.z * p.z,
            2.0 * p.x * p.y,
            2.0 * p.x * p.z,
            2.0 * p.y * p.z,
            2.0 * p.x,
            2.0 * p.y,
            2.0 * p.z,
        ]);
        normal += row * row.transpose();
        rhs += row;
    }
    let v = normal.cholesky()?.solve(&rhs);
    let q = Matrix3::new(v[0], v[3], v[4], v[3], v[1], v[5], v[4], v[5], v[2]);
    let u = V3::new(v[6], v[7], v[8]);
    let centre = -(q.try_inverse()? * u);
    let k = 1.0 + centre.dot(&(q * centre));
    if k <= 0.0 {
        return None;
    }
    let root = sqrt_spd3(&(q / k))?;
    // det 1: keep the field's magnitude in µT on average.
    let det = root.determinant();
    if det <= 0.0 {
        return None;
    }
    let soft_iron = root / det.cbrt();
    let hard_iron_ut = mean + centre * scale;
    let fit_rms = radius_rms(samples, |m| (soft_iron * (m - hard_iron_ut)).norm());
    Some(Correction {
        hard_iron_ut,
        soft_iron,
        fit_rms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn distortion() -> (Matrix3<f64>, V3) {
        let a = Matrix3::new(1.08, 0.04, -0.02, 0.04, 0.93, 0.03, -0.02, 0.03, 1.01);
        (a, V3::new(18.0, -11.0, 6.0))
    }

    /// The calibrated field's direction error after correcting `raw`.
    fn direction_error_deg(c: &Correction, truth: &V3, raw: &V3) -> f64 {
        c.apply(raw).angle(truth).to_degrees()
    }

    #[test]
    fn ellipsoid_fit_recovers_hard_and_soft_iron_from_all_directions() {
        let (a, b) = distortion();
        let earth = V3::new(20.0, 1.0, 44.0);
        let mut calibration = MagCalibration::new(300.0, 1.0, 0.03, 10);
        let mut cases = Vec::new();
        for i in 0..2000 {
            let t = f64::from(i);
            let attitude = UnitQuaternion::from_euler_angles(
                1.3 * (t * 0.011).sin(),
                0.9 * (t * 0.007).cos(),
                t * 0.05,
            );
            let body = attitude.inverse() * earth;
            let raw = a * body + b;
            calibration.add(raw, 0.5, 0.0, None);
            cases.push((body, raw));
        }
        assert_eq!(calibration.state(), CalibrationState::Ellipsoid);
        let c = calibration.correction().unwrap();
        assert!((c.hard_iron_ut - b).norm() < 1e-6, "{:?}", c.hard_iron_ut);
        for (body, raw) in &cases {
            assert!(direction_error_deg(c, body, raw) < 1e-4);
        }
    }

    #[test]
    fn readings_next_to_a_magnet_do_not_bend_the_fit() {
        let (a, b) = distortion();
        let earth = V3::new(20.0, 1.0, 44.0);
        let mut samples = Vec::new();
        for i in 0..400 {
            let t = f64::from(i);
            let attitude = UnitQuaternion::from_euler_angles(
                1.3 * (t * 0.11).sin(),
                0.9 * (t * 0.07).cos(),
                t * 0.5,
            );
            let mut raw = a * (attitude.inverse() * earth) + b;
            // One reading in ten passes a magnet: 25 µT more along x.
            if i % 10 == 0 {
                raw.x += 25.0;
            }
            samples.push(raw);
        }
        let plain = fit_ellipsoid(&samples).unwrap();
        let readings: Vec<Tilted> = samples.iter().copied().map(Tilted::untilted).collect();
        let robust =
            refit_without_outliers(&readings, false, |r| fit_ellipsoid(&raw_fields(r))).unwrap();
        // The plain fit's centre is pulled by the magnet; without the
        // outliers it is within a fraction of a µT (a reading the magnet
        // moved along the sphere, radius within 3 %, cannot be told).
        let plain_error = (plain.hard_iron_ut - b).norm();
        let robust_error = (robust.hard_iron_ut - b).norm();
        assert!(plain_error > 1.0, "{:?}", plain.hard_iron_ut);
        assert!(robust_error < 0.3, "{:?}", robust.hard_iron_ut);
        assert!(robust.fit_rms < 0.01, "{}", robust.fit_rms);
    }

    #[test]
    fn planar_fit_levels_the_horizontal_circle_of_a_turning_vehicle() {
        let (a, b) = distortion();
        let earth = V3::new(20.0, 1.0, 44.0);
        let mut calibration =
            MagCalibration::new(300.0, earth.z.atan2(earth.xy().norm()), 0.03, 10);
        // A calibration turn of a little over a full circle.
        for i in 0..=380 {
            let attitude = UnitQuaternion::from_euler_angles(0.0, 0.0, f64::from(i).to_radians());
            calibration.add(a * (attitude.inverse() * earth) + b, 0.0, 0.0, None);
            if i < 290 {
                assert_eq!(calibration.state(), CalibrationState::Collecting, "{i}");
            }
        }
        assert_eq!(calibration.state(), CalibrationState::Planar);
        let c = *calibration.correction().unwrap();
        // Level: the corrected horizontal field is a circle, so heading
        // from it is right to the accuracy the soft iron's z coupling allows.
        for i in 0..72 {
            let yaw = f64::from(i * 5).to_radians();
            let attitude = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
            let corrected = c.apply(&(a * (attitude.inverse() * earth) + b));
            let heading = (-corrected.y).atan2(corrected.x) + earth.y.atan2(earth.x);
            let error = (heading - yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(
                error.to_degrees().abs() < 0.5,
                "{i}: {}",
                error.to_degrees()
            );
        }
        // Tilted, the vertical sized from the inclination makes the tilt
        // compensation right too (to the soft iron's z coupling).
        for i in 0..72 {
            let yaw = f64::from(i * 5).to_radians();
            let (roll, pitch) = (2.0_f64.to_radians(), -4.0_f64.to_radians());
            let attitude = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
            let corrected = c.apply(&(a * (attitude.inverse() * earth) + b));
            let heading =
                crate::fusion::fuzzy::orientation::magnetic_heading(&corrected, roll, pitch)
                    + earth.y.atan2(earth.x);
            let error = crate::fusion::fuzzy::orientation::angle_difference(heading, yaw);
            assert!(
                error.to_degrees().abs() < 0.6,
                "{i}: {}",
                error.to_degrees()
            );
        }
    }

    /// The worst heading error over a full turn at `(roll, pitch)` of a
    /// field corrected by `c`, degrees.
    fn worst_heading_error_deg(c: &Correction, (roll, pitch): (f64, f64)) -> f64 {
        let (a, b) = distortion();
        let earth = V3::new(20.0, 1.0, 44.0);
        (0..72)
            .map(|i| {
                let yaw = f64::from(i * 5).to_radians();
                let attitude = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
                let corrected = c.apply(&(a * (attitude.inverse() * earth) + b));
                let heading =
                    crate::fusion::fuzzy::orientation::magnetic_heading(&corrected, roll, pitch)
                        + earth.y.atan2(earth.x);
                crate::fusion::fuzzy::orientation::angle_difference(heading, yaw)
                    .to_degrees()
                    .abs()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_calibration_turn_on_a_grade_is_levelled_by_the_tilt() {
        let (a, b) = distortion();
        let earth = V3::new(20.0, 1.0, 44.0);
        let inclination = earth.z.atan2(earth.xy().norm());
        // A turn on a 5° slope, banked 2°: no reading is level.
        let (roll, pitch) = (2.0_f64.to_radians(), 5.0_f64.to_radians());
        let turn = |told: (f64, f64)| {
            let mut calibration = MagCalibration::new(300.0, inclination, 0.03, 10);
            for i in 0..=380 {
                let yaw = f64::from(i).to_radians();
                let attitude = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
                calibration.add(a * (attitude.inverse() * earth) + b, told.0, told.1, None);
            }
            calibration
        };
        let levelled = turn((roll, pitch));
        assert_eq!(levelled.state(), CalibrationState::Planar);
        assert!(levelled.levelled);
        let c = levelled.correction().unwrap();
        // Right on the slope and level, to the soft iron's z coupling.
        for tilt in [(roll, pitch), (0.0, 0.0), (-roll, -pitch)] {
            let error = worst_heading_error_deg(c, tilt);
            assert!(error < 0.8, "{tilt:?}: {error}");
        }
        // Told it was level, the same readings fit a circle whose centre
        // holds the vertical field's share, sin 5° × 44 µT ≈ 3.8 µT of
        // hard iron that is not there: heading off by degrees.
        let pretended = turn((0.0, 0.0));
        assert!(!pretended.levelled);
        let wrong = pretended.correction().unwrap();
        assert!(worst_heading_error_deg(wrong, (roll, pitch)) > 3.0);
    }

    #[test]
    fn a_fit_over_less_than_90_degrees_of_directions_is_refused() {
        let (a, b) = distortion();
        let earth = V3::new(20.0, 1.0, 44.0);
        // Coverage asked of the bins: only 10°, so the gates must refuse.
        let mut calibration = MagCalibration::new(10.0, 1.1, 0.03, 5);
        for i in 0..2000 {
            // A slow swing over 80° of heading, back and forth.
            let yaw = (40.0 * (f64::from(i) * 0.01).sin()).to_radians();
            let attitude = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
            calibration.add(a * (attitude.inverse() * earth) + b, 0.0, 0.0, None);
        }
        assert_eq!(calibration.state(), CalibrationState::Collecting);
        assert!(calibration.refused_fits() > 0);
        // The same swing over 120° passes the direction gate.
        let mut wide = MagCalibration::new(10.0, 1.1, 0.03, 5);
        for i in 0..2000 {
            let yaw = (60.0 * (f64::from(i) * 0.01).sin()).to_radians();
            let attitude = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
            wide.add(a * (attitude.inverse() * earth) + b, 0.0, 0.0, None);
        }
        assert_eq!(wide.state(), CalibrationState::Planar);
    }

    #[test]
    fn a_still_sensor_covers_nothing_whatever_its_noise() {
        let mut calibration = MagCalibration::new(300.0, 1.0, 0.03, 10);
        let mut x = 0.3_f64;
        for _ in 0..5000 {
            let mut noise = || {
                x = (x * 997.0 + 0.123_456_7).fract();
                2.0 * (x - 0.5)
            };
            // ±1 µT of noise on each axis (a noisy MEMS magnetometer).
            let field = V3::new(20.0 + noise(), 1.0 + noise(), 44.0 + noise());
            calibration.add(field, 0.0, 0.0, None);
        }
        assert_eq!(calibration.coverage_deg(), 0.0);
        assert_eq!(calibration.state(), CalibrationState::Collecting);
    }

    #[test]
    fn too_few_directions_or_bad_data_give_no_calibration() {
        let mut calibration = MagCalibration::new(300.0, 1.0, 0.03, 10);
        for i in 0..200 {
            calibration.add(
                V3::new(20.0 + f64::from(i % 7) * 0.01, 1.0, 44.0),
                0.0,
                0.0,
                None,
            );
        }
        calibration.add(V3::new(f64::NAN, 0.0, 0.0), 0.0, 0.0, None);
        assert_eq!(calibration.state(), CalibrationState::Collecting);
        assert!(calibration.correction().is_none());
        assert!(fit_ellipsoid(&[V3::zeros(); 20]).is_none());
    }

    /// A field of 50 µT from 200 directions spread over the sphere, plus
    /// `hard_iron`, one every 0.1 s.
    fn sphere_readings(hard_iron: V3) -> Vec<(f64, V3)> {
        (0..200)
            .map(|k| {
                let k = f64::from(k);
                let azimuth = k * 0.7;
                let elevation = (k * 0.37).sin() * 1.2;
                let direction = V3::new(
                    elevation.cos() * azimuth.cos(),
                    elevation.cos() * azimuth.sin(),
                    elevation.sin(),
                );
                (k * 0.1, direction * 50.0 + hard_iron)
            })
            .collect()
    }

    fn ellipsoid_with_hard_iron(hard_iron_ut: V3) -> MagCalibration {
        let mut calibration = MagCalibration::new(300.0, 1.0, 0.03, 16);
        calibration.state = CalibrationState::Ellipsoid;
        calibration.correction = Some(Correction {
            hard_iron_ut,
            soft_iron: Matrix3::identity(),
            fit_rms: 0.01,
        });
        calibration
    }

    #[test]
    fn a_calibration_worse_than_the_raw_field_is_dropped_for_it() {
        // The raw field is a clean sphere; the calibration removes 20 µT
        // of hard iron that is not there: its radius spread is about 28 %.
        let mut calibration = ellipsoid_with_hard_iron(V3::new(20.0, 0.0, 0.0));
        let dropped: Vec<bool> = sphere_readings(V3::zeros())
            .into_iter()
            .map(|(t, m)| calibration.check(t, m))
            .collect();
        // Not before 64 readings are held.
        assert!(!dropped[..63].iter().any(|d| *d));
        assert_eq!(dropped.iter().filter(|d| **d).count(), 1);
        assert_eq!(calibration.state(), CalibrationState::Raw);
        let raw = calibration.correction().unwrap();
        assert_eq!(raw.hard_iron_ut, V3::zeros());
        assert!(raw.fit_rms < 1e-9);
        // Readings closer than 0.1 s apart count once: every 7th of 1/64 s
        // (0.109 s), 0, 7, …, 196: 29 of 200.
        let mut spaced = ellipsoid_with_hard_iron(V3::new(20.0, 0.0, 0.0));
        for k in 0..200 {
            assert!(!spaced.check(f64::from(k) / 64.0, V3::new(50.0, 0.0, 0.0)));
        }
        assert_eq!(spaced.checked.len(), 29);
    }

    #[test]
    fn a_right_calibration_stays_and_a_wrong_one_over_a_bad_raw_field_starts_again() {
        // The calibration removes the 8 µT the raw field carries (a radius
        // spread of about 11 %, beyond the raw field's 3 %): kept.
        let hard_iron = V3::new(0.0, 8.0, 0.0);
        let mut right = ellipsoid_with_hard_iron(hard_iron);
        for (t, m) in sphere_readings(hard_iron) {
            assert!(!right.check(t, m));
        }
        assert_eq!(right.state(), CalibrationState::Ellipsoid);
        // Both wrong, the calibration by 30 µT more than twice as badly
        // (the hard iron moved, a magnet attached): the fit starts again,
        // with no correction meanwhile.
        let mut wrong = ellipsoid_with_hard_iron(V3::new(-30.0, 0.0, 0.0));
        let dropped = sphere_readings(hard_iron)
            .into_iter()
            .filter(|(t, m)| wrong.check(*t, *m))
            .count();
        assert_eq!(dropped, 1);
        assert_eq!(wrong.state(), CalibrationState::Collecting);
        assert!(wrong.correction().is_none());
        assert!(wrong.samples.is_empty());
    }
}
