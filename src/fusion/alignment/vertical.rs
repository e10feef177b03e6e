//! The vertical profile: grades between points of vertical intersection
//! (PVI), each rounded by a symmetric parabola of its curve length. The
//! first grade runs from the start height at the start station to the first
//! PVI, the last one leaves the last PVI at the end grade.
//!
//! Within a curve of length L about a PVI at station x_v, from its
//! beginning (BVC, x_v − L/2) with the incoming grade g₁ towards the
//! outgoing g₂: z(x) = z_BVC + g₁·(x − x_BVC) + (g₂ − g₁)·(x − x_BVC)²/(2L).

use serde::{Deserialize, Serialize};

/// A point of vertical intersection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Pvi {
    #[schema(minimum = -1.0e7, maximum = 1.0e7)]
    pub station_m: f64,
    #[schema(minimum = -20_000.0, maximum = 20_000.0)]
    pub height_m: f64,
    /// Length of the parabola about it (0: a sharp change of grade).
    #[serde(default)]
    #[schema(minimum = 0.0, maximum = 100_000.0)]
    pub curve_length_m: f64,
}

/// The profile: grades through the PVIs and their curves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    pub start_station_m: f64,
    pub start_height_m: f64,
    pub pvis: Vec<Pvi>,
    /// Grade after the last PVI (or throughout without one), rise over run.
    pub end_grade: f64,
}

/// Why a profile was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    #[error("PVI {index} at station {station_m}: {reason}")]
    Pvi {
        index: usize,
        station_m: f64,
        reason: String,
    },
    #[error("the end grade {0} is not a finite number")]
    EndGrade(f64),
}

impl Profile {
    /// Checks the PVIs: finite, in increasing station after the start,
    /// curves that neither overlap each other nor run before the start.
    pub fn validate(&self) -> Result<(), ProfileError> {
        if !self.end_grade.is_finite() {
            return Err(ProfileError::EndGrade(self.end_grade));
        }
        let mut previous_end = self.start_station_m;
        let mut previous_station = self.start_station_m;
        for (index, pvi) in self.pvis.iter().enumerate() {
            let refuse = |reason: String| ProfileError::Pvi {
                index,
                station_m: pvi.station_m,
                reason,
            };
            let finite = pvi.station_m.is_finite()
                && pvi.height_m.is_finite()
                && pvi.curve_length_m.is_finite();
            if !(finite && pvi.curve_length_m >= 0.0) {
                return Err(refuse(
                    "station, height and curve length must be finite, the length ≥ 0".into(),
                ));
            }
            let begin = pvi.station_m - 0.5 * pvi.curve_length_m;
            if pvi.station_m <= previous_station {
                return Err(refuse(
                    "PVIs must follow the start and each other in station".into(),
                ));
            }
            if begin < previous_end - 1e-9 {
                return Err(refuse(format!(
                    "its curve begins at station {begin}, before the previous curve ends or the profile starts ({previous_end})"
                )));
            }
            previous_end = pvi.station_m + 0.5 * pvi.curve_length_m;
            previous_station = pvi.station_m;
        }
        Ok(())
    }

    /// The grade of the tangent leaving PVI `i` (or the start, for −1).
    fn grade_after(&self, i: Option<usize>) -> f64 {
        let (x0, z0) = match i {
            None => (self.start_station_m, self.start_height_m),
            Some(i) => (self.pvis[i].station_m, self.pvis[i].height_m),
        };
        let next = i.map_or(0, |i| i + 1);
        match self.pvis.get(next) {
            Some(p) => (p.height_m - z0) / (p.station_m - x0),
            None => self.end_grade,
        }
    }

    /// The vertical curve `station_m` lies in: its PVI, the incoming and
    /// outgoing grades and the distance from its beginning (the last such
    /// curve if curves overlap, which validation refuses).
    fn curve_at(&self, station_m: f64) -> Option<(&Pvi, f64, f64, f64)> {
        self.pvis
            .iter()
            .enumerate()
            .rev()
            .find(|(_, pvi)| {
                let half = 0.5 * pvi.curve_length_m;
                half > 0.0 && (station_m - pvi.station_m).abs() < half
            })
            .map(|(i, pvi)| {
                let d = station_m - (pvi.station_m - 0.5 * pvi.curve_length_m);
                (
                    pvi,
                    self.grade_after(i.checked_sub(1)),
                    self.grade_after(Some(i)),
                    d,
                )
            })
    }

    /// The grade (rise over run) at `station_m` and its rate of change
    /// along the station, 1/m: on a tangent its grade and 0, within a
    /// curve about a PVI g₁ + (g₂ − g₁)·d/L and (g₂ − g₁)/L, d from the
    /// curve's beginning (the derivatives of [`Profile::height_at`]). At a
    /// PVI without a curve the grade steps: the one leaving it.
    pub fn grade_at(&self, station_m: f64) -> (f64, f64) {
        match self.curve_at(station_m) {
            Some((pvi, g1, g2, d)) => {
                let rate = (g2 - g1) / pvi.curve_length_m;
                (g1 + rate * d, rate)
            }
            None => {
                let last_before = self.pvis.iter().rposition(|p| p.station_m <= station_m);
                (self.grade_after(last_before), 0.0)
            }
        }
    }

    /// The design height at `station_m` (the profile's tangents continue
    /// beyond its ends).
    pub fn height_at(&self, station_m: f64) -> f64 {
        // Within a curve, the parabola lies off the incoming tangent by
        // (g₂ − g₁)·d²/(2L), d from the curve's beginning.
        if let Some((pvi, g1, g2, d)) = self.curve_at(station_m) {
            let tangent_in = pvi.height_m + g1 * (station_m - pvi.station_m);
            return tangent_in + (g2 - g1) * d * d / (2.0 * pvi.curve_length_m);
        }
        // The tangent the station lies on: after the last PVI at or before it.
        let last_before = self.pvis.iter().rposition(|p| p.station_m <= station_m);
        let (x0, z0) = match last_before {
            None => (self.start_station_m, self.start_height_m),
            Some(i) => (self.pvis[i].station_m, self.pvis[i].height_m),
        };
        z0 + self.grade_after(last_before) * (station_m - x0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// From 50 m at station 0, a PVI at 120 m / 50.6 m (grade +0.5 %)
    /// with a 60 m curve, then −0.5 %.
    fn crest() -> Profile {
        Profile {
            start_station_m: 0.0,
            start_height_m: 50.0,
            pvis: vec![Pvi {
                station_m: 120.0,
                height_m: 50.6,
                curve_length_m: 60.0,
            }],
            end_grade: -0.005,
        }
    }

    #[test]
    fn tangents_and_a_crest_curve_by_hand() {
        let p = crest();
        p.validate().unwrap();
        // On the first tangent: 50 + 0.005·60.
        assert!((p.height_at(60.0) - 50.3).abs() < 1e-12);
        assert!((p.height_at(90.0) - 50.45).abs() < 1e-12);
        // At the PVI the parabola lies (g₂ − g₁)·L/8 = −0.01·60/8 below it.
        assert!((p.height_at(120.0) - (50.6 - 0.075)).abs() < 1e-12);
        // 10 m into the curve: tangent 50.5 − 0.01·100/120 = 50.491667.
        assert!((p.height_at(100.0) - (50.5 - 0.01 * 100.0 / 120.0)).abs() < 1e-12);
        // End of the curve back on the outgoing tangent: 50.6 − 0.005·30.
        assert!((p.height_at(150.0) - 50.45).abs() < 1e-12);
        assert!((p.height_at(200.0) - 50.2).abs() < 1e-12);
        // Continuous and smooth across the curve's ends: the slope just
        // inside equals the tangent's (+0.5 % in, −0.5 % out).
        let h = 1e-3;
        for (x, grade) in [(90.0, 0.005), (150.0, -0.005)] {
            let slope_before = (p.height_at(x) - p.height_at(x - h)) / h;
            let slope_after = (p.height_at(x + h) - p.height_at(x)) / h;
            assert!((slope_before - grade).abs() < 1e-6, "{x}: {slope_before}");
            assert!((slope_after - grade).abs() < 1e-6, "{x}: {slope_after}");
        }
    }

    #[test]
    fn the_grade_and_its_rate_through_a_crest_curve() {
        // The crest: +0.5 % into a 60 m curve about 120 m, −0.5 % out of
        // it: the rate is −0.01/60 = −1.6667e-4 /m from 90 m to 150 m, the
        // grade 0 at the PVI and 0.005 − 1.6667e-4·15 = 0.0025 at 105 m.
        let p = crest();
        for (station_m, expected) in [(50.0, 0.005), (200.0, -0.005)] {
            let (grade, rate) = p.grade_at(station_m);
            assert!(
                (grade - expected).abs() < 1e-12 && rate == 0.0,
                "{station_m}"
            );
        }
        let (grade, rate) = p.grade_at(105.0);
        assert!((grade - 0.0025).abs() < 1e-12 && (rate + 1.666_667e-4).abs() < 1e-9);
        assert!(p.grade_at(120.0).0.abs() < 1e-12);
        // It is the height's derivative.
        let slope = (p.height_at(105.001) - p.height_at(104.999)) / 0.002;
        assert!((slope - grade).abs() < 1e-9, "{slope}");
    }

    #[test]
    fn overlapping_curves_and_disordered_pvis_are_refused() {
        let mut p = crest();
        p.pvis.push(Pvi {
            station_m: 160.0,
            height_m: 50.0,
            curve_length_m: 40.0,
        });
        let err = p.validate().unwrap_err();
        assert!(matches!(err, ProfileError::Pvi { index: 1, .. }), "{err}");
        p.pvis[1].station_m = 100.0;
        assert!(p.validate().is_err());
        let mut p = crest();
        p.pvis[0].curve_length_m = 300.0;
        assert!(p.validate().unwrap_err().to_string().contains("before"));
    }
}
