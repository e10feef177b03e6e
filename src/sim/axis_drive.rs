//! A simulated TBM drive along a designed tunnel axis with known
//! deviations, for `simulate axis`, `eval dta`, the demo and the tests.
//!
//! The driven path is the axis displaced by a horizontal and a vertical
//! deviation that are smooth functions of station (two sines each: the
//! machine drifts towards a tolerance and the driver steers it back),
//! reaching `peak_fraction` of the warn tolerance at most. The cutterhead
//! (front) advances along the path, 1.5 m per excavation stroke of
//! `stroke_min` minutes, standing still while a ring is built; the shield
//! tail (rear) is on the path the machine length behind, so the machine's
//! yaw and pitch are those of the chord from rear to front. Roll drifts
//! slowly (cutterhead torque, reversed at ±2.5°).
//!
//! Sensors:
//! - inclinometer (the TBM simulator's error model: roll- and
//!   temperature-dependent pitch error, 0.12° roll offset, vibration noise);
//! - laser: pitch and roll to 0.002°, yaw to 0.005°, and the position of
//!   the navigation reference point (the laser target, off the machine's
//!   axis by the declared offsets) to `position_sigma_mm` per axis.
//!
//! The truth does not reuse the engine's geometry: the simulator places
//! the axis with its own composite Simpson integration of the heading and
//! its own profile, and turns the body offsets with its own rotation. A
//! point built as axis(s) + h·normal(s) + v·up has its perpendicular foot
//! at s, so the deviations of front and rear are h and v at their
//! stations by construction.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::tbm::{DEFAULT_START_T, incl_pitch_error_deg};
use crate::fusion::alignment::{AlignmentSpec, ElementSpec, ProfileSpec, Pvi, StartPose};
use crate::fusion::declaration::{MachineGeometry, Tolerances};
use crate::fusion::reading::ProjectPoint;
use crate::fusion::{Reading, SensorData};

const RING_LENGTH_M: f64 = 1.5;
/// Inclinometer roll offset (reads this much low), as in the TBM simulator.
const INCL_ROLL_OFFSET_DEG: f64 = 0.12;
/// Simpson panels per metre when placing the axis.
const PANELS_PER_M: f64 = 4.0;

/// What to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisDriveScenario {
    pub seed: u64,
    /// Unix seconds of the first reading.
    pub start_t: f64,
    pub hours: f64,
    pub alignment: AlignmentSpec,
    pub geometry: MachineGeometry,
    pub tolerances: Tolerances,
    /// Station of the cutterhead at the start (the tail must be on the axis).
    pub start_station_m: f64,
    /// Largest deviation of the path as a fraction of the warn tolerance.
    pub peak_fraction: f64,
    /// Wavelengths of the deviation's two sines, m of station.
    pub drift_wavelength_m: (f64, f64),
    /// Minutes per 1.5 m excavation stroke, and per ring build.
    pub stroke_min: (f64, f64),
    pub ring_build_min: (f64, f64),
    pub incl_period_s: f64,
    pub laser_period_s: f64,
    /// 1σ of each coordinate of the laser's position, mm.
    pub position_sigma_mm: f64,
}

impl AxisDriveScenario {
    /// A drive on `alignment` from the protocol's example machine: a
    /// 9.3 m shield whose laser target sits 0.4 m left and 1.1 m above its
    /// axis (so roll matters), ±50/100 mm horizontal and ±30/60 mm
    /// vertical tolerances, starting 15 m into the axis.
    pub fn on(alignment: AlignmentSpec, seed: u64) -> AxisDriveScenario {
        let start_station_m = alignment.start_station_m + 15.0;
        AxisDriveScenario {
            seed,
            start_t: DEFAULT_START_T,
            hours: 6.0,
            alignment,
            geometry: MachineGeometry {
                front_m: [4.2, 0.4, 1.1],
                rear_m: [-5.1, 0.4, 1.1],
            },
            tolerances: Tolerances {
                horizontal_mm: crate::fusion::declaration::Limits {
                    warn: 50.0,
                    alarm: 100.0,
                },
                vertical_mm: crate::fusion::declaration::Limits {
                    warn: 30.0,
                    alarm: 60.0,
                },
            },
            start_station_m,
            peak_fraction: 1.2,
            drift_wavelength_m: (60.0, 25.0),
            stroke_min: (50.0, 70.0),
            ring_build_min: (20.0, 35.0),
            incl_period_s: 1.0,
            laser_period_s: 30.0,
            position_sigma_mm: 1.0,
        }
    }

    /// A drive drawn from the envelope `eval dta` scores over: a random
    /// axis (line, transition spiral into an arc of ±250…1500 m either way,
    /// a spiral between two arcs of different radius, spiral out, line;
    /// two PVIs with ±2 % grades and 40–120 m parabolas; anywhere on the
    /// grid at any azimuth), a random shield (6–12 m, laser target up to
    /// 0.6 m aside and 1.5 m off its axis), a start anywhere the drive fits,
    /// deviations peaking at 0.5–1.5 × the warn tolerance, 8 hours.
    pub fn draw(seed: u64) -> AxisDriveScenario {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(7);
        let sign = |rng: &mut ChaCha8Rng| if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let r1: f64 = sign(&mut rng) * rng.random_range(250.0..1500.0);
        let r2 = r1.signum() * rng.random_range(250.0..1500.0);
        let mut horizontal = vec![
            ElementSpec::Line {
                length_m: rng.random_range(30.0..80.0),
            },
            ElementSpec::Spiral {
                length_m: rng.random_range(20.0..60.0),
                radius_start_m: None,
                radius_end_m: Some(r1),
            },
            ElementSpec::Arc {
                length_m: rng.random_range(40.0..150.0),
                radius_m: r1,
            },
        ];
        if (r1 - r2).abs() > 1.0 {
            horizontal.push(ElementSpec::Spiral {
                length_m: rng.random_range(20.0..40.0),
                radius_start_m: Some(r1),
                radius_end_m: Some(r2),
            });
            horizontal.push(ElementSpec::Arc {
                length_m: rng.random_range(40.0..100.0),
                radius_m: r2,
            });
        }
        let last_radius = if (r1 - r2).abs() > 1.0 { r2 } else { r1 };
        horizontal.push(ElementSpec::Spiral {
            length_m: rng.random_range(20.0..60.0),
            radius_start_m: Some(last_radius),
            radius_end_m: None,
        });
        horizontal.push(ElementSpec::Line {
            length_m: rng.random_range(30.0..80.0),
        });
        let length_m: f64 = horizontal
            .iter()
            .map(|e| match *e {
                ElementSpec::Line { length_m }
                | ElementSpec::Arc { length_m, .. }
                | ElementSpec::Spiral { length_m, .. } => length_m,
            })
            .sum();
        let start_station_m = rng.random_range(0.0..2000.0_f64).round();
        let start_height_m = rng.random_range(-30.0..200.0);
        let mut height = start_height_m;
        let mut pvis = Vec::new();
        for fraction in [0.35, 0.7] {
            let station_m = start_station_m + fraction * length_m;
            let previous = pvis.last().map_or(start_station_m, |p: &Pvi| p.station_m);
            height += rng.random_range(-0.02..0.02) * (station_m - previous);
            pvis.push(Pvi {
                station_m,
                height_m: height,
                curve_length_m: rng.random_range(40.0..120.0_f64).min(0.3 * length_m),
            });
        }
        let alignment = AlignmentSpec {
            name: format!("envelope axis {seed}"),
            start_station_m,
            start: StartPose {
                easting_m: rng.random_range(100_000.0..900_000.0),
                northing_m: rng.random_range(1_000_000.0..6_000_000.0),
                azimuth_deg: rng.random_range(0.0..360.0),
            },
            horizontal,
            vertical: ProfileSpec {
                start_height_m,
                pvis,
                end_grade_pct: rng.random_range(-2.0..2.0),
            },
            station_equations: Vec::new(),
        };
        let shield_m = rng.random_range(6.0..12.0);
        let front_x = rng.random_range(0.3..0.7) * shield_m;
        let (y, z) = (rng.random_range(-0.6..0.6), rng.random_range(-1.5..0.5));
        let hours = 8.0;
        // Up to ~1.5 m per hour of drive: start where eight hours fit.
        let first = start_station_m + shield_m + 2.0;
        let last = start_station_m + length_m - 1.5 * hours * 1.2 - 2.0;
        AxisDriveScenario {
            hours,
            geometry: MachineGeometry {
                front_m: [front_x, y, z],
                rear_m: [front_x - shield_m, y, z],
            },
            start_station_m: rng.random_range(first..last.max(first + 1.0)),
            peak_fraction: rng.random_range(0.5..1.5),
            ..AxisDriveScenario::on(alignment, seed)
        }
    }

    /// Checks the scenario can be simulated.
    pub fn validate(&self) -> Result<(), String> {
        let g = &self.geometry;
        if g.front_m[1] != g.rear_m[1] || g.front_m[2] != g.rear_m[2] || g.front_m[0] <= g.rear_m[0]
        {
            return Err(
                "the simulator puts front and rear on the machine's axis: they must differ only in x, front ahead".into(),
            );
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(positive(self.hours)
            && positive(self.incl_period_s)
            && self.laser_period_s >= 1.0
            && self.position_sigma_mm >= 0.0
            && self.peak_fraction >= 0.0
            && positive(self.drift_wavelength_m.0)
            && positive(self.drift_wavelength_m.1))
        {
            return Err(
                "hours, periods (laser ≥ 1 s), wavelengths must be positive; σ and peak ≥ 0".into(),
            );
        }
        let ranges = [self.stroke_min, self.ring_build_min];
        if ranges.iter().any(|&(a, b)| !(positive(a) && b >= a)) {
            return Err("stroke and ring-build minutes must be positive ranges".into());
        }
        let axis = OwnAxis::new(&self.alignment)?;
        let length = g.front_m[0] - g.rear_m[0];
        if self.start_station_m - length < axis.start_station_m() + 1.0 {
            return Err(format!(
                "the tail must start on the axis: start station at least {:.1}",
                axis.start_station_m() + length + 1.0
            ));
        }
        if self.start_station_m >= axis.end_station_m() {
            return Err("the start station is beyond the axis".into());
        }
        Ok(())
    }
}

/// One point's true deviation from the axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PointTruth {
    pub station_m: f64,
    pub horizontal_mm: f64,
    pub vertical_mm: f64,
}

/// The truth at a laser reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisTruth {
    pub t: f64,
    pub front: PointTruth,
    pub rear: PointTruth,
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
}

/// One simulated reading, with the truth when it is a laser reading.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisEvent {
    pub reading: Reading,
    pub truth: Option<AxisTruth>,
}

/// One horizontal element as the simulator places it.
#[derive(Debug, Clone, Copy)]
struct OwnElement {
    start_station_m: f64,
    length_m: f64,
    east_m: f64,
    north_m: f64,
    /// Azimuth at the start, rad clockwise from north.
    azimuth_rad: f64,
    curvature_per_m: f64,
    curvature_rate_per_m2: f64,
}

impl OwnElement {
    fn azimuth_at(&self, l: f64) -> f64 {
        self.azimuth_rad + self.curvature_per_m * l + 0.5 * self.curvature_rate_per_m2 * l * l
    }

    /// East, north and azimuth `l` metres in: ∫ (sin, cos) of the azimuth
    /// by composite Simpson.
    fn at(&self, l: f64) -> (f64, f64, f64) {
        let panels = ((l * PANELS_PER_M).ceil() as usize).max(1) * 2;
        let h = l / panels as f64;
        let (mut e, mut n) = (0.0, 0.0);
        for i in 0..=panels {
            let w = if i == 0 || i == panels {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let a = self.azimuth_at(i as f64 * h);
            e += w * a.sin();
            n += w * a.cos();
        }
        (
            self.east_m + e * h / 3.0,
            self.north_m + n * h / 3.0,
            self.azimuth_at(l),
        )
    }
}

/// The design axis, placed by the simulator's own integration.
#[derive(Debug, Clone)]
pub(super) struct OwnAxis {
    elements: Vec<OwnElement>,
    /// (station, height) of the start, each PVI with its curve length, and
    /// the end grade.
    pvis: Vec<(f64, f64, f64)>,
    end_grade: f64,
}

impl OwnAxis {
    pub(super) fn new(spec: &AlignmentSpec) -> Result<OwnAxis, String> {
        let mut elements = Vec::new();
        let (mut station, mut e, mut n) = (
            spec.start_station_m,
            spec.start.easting_m,
            spec.start.northing_m,
        );
        let mut azimuth = spec.start.azimuth_deg.to_radians();
        let k = |r: Option<f64>| r.map_or(0.0, |r| 1.0 / r);
        for element in &spec.horizontal {
            let (length_m, k0, k1) = match *element {
                ElementSpec::Line { length_m } => (length_m, 0.0, 0.0),
                ElementSpec::Arc { length_m, radius_m } => {
                    (length_m, 1.0 / radius_m, 1.0 / radius_m)
                }
                ElementSpec::Spiral {
                    length_m,
                    radius_start_m,
                    radius_end_m,
                } => (length_m, k(radius_start_m), k(radius_end_m)),
            };
            if !(length_m.is_finite() && length_m > 0.0) {
                return Err(format!("element length {length_m} is not positive"));
            }
            let placed = OwnElement {
                start_station_m: station,
                length_m,
                east_m: e,
                north_m: n,
                azimuth_rad: azimuth,
                curvature_per_m: k0,
                curvature_rate_per_m2: (k1 - k0) / length_m,
            };
            (e, n, azimuth) = placed.at(length_m);
            station += length_m;
            elements.push(placed);
        }
        if elements.is_empty() {
            return Err("the alignment has no horizontal element".into());
        }
        let v = &spec.vertical;
        let mut pvis = vec![(spec.start_station_m, v.start_height_m, 0.0)];
        pvis.extend(
            v.pvis
                .iter()
                .map(|p| (p.station_m, p.height_m, p.curve_length_m)),
        );
        Ok(OwnAxis {
            elements,
            pvis,
            end_grade: v.end_grade_pct / 100.0,
        })
    }

    pub(super) fn start_station_m(&self) -> f64 {
        self.elements[0].start_station_m
    }

    pub(super) fn end_station_m(&self) -> f64 {
        let last = self.elements[self.elements.len() - 1];
        last.start_station_m + last.length_m
    }

    /// East, north, azimuth at `station_m` (clamped to the axis).
    pub(super) fn plan(&self, station_m: f64) -> (f64, f64, f64) {
        let element = self
            .elements
            .iter()
            .rev()
            .find(|e| station_m >= e.start_station_m)
            .unwrap_or(&self.elements[0]);
        element.at((station_m - element.start_station_m).clamp(0.0, element.length_m))
    }

    /// Grade leaving PVI `i` (the last one leaves at the end grade).
    fn grade_after(&self, i: usize) -> f64 {
        match self.pvis.get(i + 1) {
            Some(&(s, h, _)) => (h - self.pvis[i].1) / (s - self.pvis[i].0),
            None => self.end_grade,
        }
    }

    /// Design height at `station_m`: tangents through the PVIs, each
    /// rounded by z = z_BVC + g₁x + (g₂ − g₁)x²/(2L) within L/2 of it.
    pub(super) fn height(&self, station_m: f64) -> f64 {
        for i in 1..self.pvis.len() {
            let (s, h, l) = self.pvis[i];
            let (g1, g2) = (self.grade_after(i - 1), self.grade_after(i));
            if l > 0.0 && (station_m - s).abs() <= l / 2.0 {
                let x = station_m - (s - l / 2.0);
                return h - g1 * l / 2.0 + g1 * x + (g2 - g1) * x * x / (2.0 * l);
            }
        }
        let i = self
            .pvis
            .iter()
            .rposition(|&(s, _, _)| station_m >= s)
            .unwrap_or(0);
        self.pvis[i].1 + self.grade_after(i) * (station_m - self.pvis[i].0)
    }
}

/// A deviation that is a smooth function of station: two sines.
#[derive(Debug, Clone, Copy, Serialize)]
struct Drift {
    amplitude_mm: [f64; 2],
    wavenumber_per_m: [f64; 2],
    phase_rad: [f64; 2],
}

impl Drift {
    fn new(rng: &mut ChaCha8Rng, peak_mm: f64, wavelengths_m: (f64, f64)) -> Drift {
        let share: f64 = rng.random_range(0.6..0.85);
        let tau = std::f64::consts::TAU;
        Drift {
            amplitude_mm: [peak_mm * share, peak_mm * (1.0 - share)],
            wavenumber_per_m: [
                tau / (wavelengths_m.0 * rng.random_range(0.8..1.25)),
                tau / (wavelengths_m.1 * rng.random_range(0.8..1.25)),
            ],
            phase_rad: [rng.random_range(0.0..tau), rng.random_range(0.0..tau)],
        }
    }

    fn at_mm(&self, station_m: f64) -> f64 {
        (0..2)
            .map(|i| {
                self.amplitude_mm[i]
                    * (self.wavenumber_per_m[i] * station_m + self.phase_rad[i]).sin()
            })
            .sum()
    }
}

/// The simulated drive: readings in time order.
#[derive(Debug, Clone)]
pub struct AxisDrive {
    scenario: AxisDriveScenario,
    axis: OwnAxis,
    horizontal: Drift,
    vertical: Drift,
    /// Excavation strokes: (start t, end t, station at start).
    strokes: Vec<(f64, f64, f64)>,
    roll_phase: f64,
    roll_period_s: f64,
    roll_mean_deg: f64,
    incl_rng: ChaCha8Rng,
    laser_rng: ChaCha8Rng,
    next_incl: u64,
    next_laser: u64,
}

impl AxisDrive {
    /// Starts a drive; the scenario must be valid.
    pub fn new(scenario: AxisDriveScenario) -> Result<AxisDrive, String> {
        scenario.validate()?;
        let axis = OwnAxis::new(&scenario.alignment)?;
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        let t = &scenario.tolerances;
        let horizontal = Drift::new(
            &mut rng,
            scenario.peak_fraction * t.horizontal_mm.warn,
            scenario.drift_wavelength_m,
        );
        let vertical = Drift::new(
            &mut rng,
            scenario.peak_fraction * t.vertical_mm.warn,
            scenario.drift_wavelength_m,
        );
        // The strokes: ring building first, then 1.5 m per stroke, until
        // the drive's end or the axis's.
        let mut strokes = Vec::new();
        let (mut time, mut station) = (scenario.start_t, scenario.start_station_m);
        let end_t = scenario.start_t + scenario.hours * 3600.0;
        let end_station = axis.end_station_m() - 1.0;
        let draw = |rng: &mut ChaCha8Rng, (a, b): (f64, f64)| {
            if b > a { rng.random_range(a..b) } else { a }
        };
        while time < end_t && station < end_station {
            time += draw(&mut rng, scenario.ring_build_min) * 60.0;
            let minutes = draw(&mut rng, scenario.stroke_min);
            strokes.push((time, time + minutes * 60.0, station));
            time += minutes * 60.0;
            station = (station + RING_LENGTH_M).min(end_station);
        }
        let roll_period_s = rng.random_range(4.0..8.0) * 3600.0;
        let roll_phase = rng.random_range(0.0..std::f64::consts::TAU);
        let roll_mean_deg = rng.random_range(-0.5..1.0);
        let mut incl_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        incl_rng.set_stream(1);
        let mut laser_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        laser_rng.set_stream(2);
        Ok(AxisDrive {
            scenario,
            axis,
            horizontal,
            vertical,
            strokes,
            roll_phase,
            roll_period_s,
            roll_mean_deg,
            incl_rng,
            laser_rng,
            next_incl: 0,
            next_laser: 0,
        })
    }

    /// The scenario being simulated.
    pub fn scenario(&self) -> &AxisDriveScenario {
        &self.scenario
    }

    /// When each ring is complete: the end of the ring build before each
    /// excavation stroke (its start), in time order.
    pub fn rings_complete_t(&self) -> impl Iterator<Item = f64> + '_ {
        self.strokes.iter().map(|stroke| stroke.0)
    }

    /// When the last excavation stroke ends (the drive's end or the
    /// axis's, whichever comes first).
    pub fn last_stroke_end_t(&self) -> f64 {
        self.strokes.last().map_or(self.scenario.start_t, |s| s.1)
    }

    /// The cutterhead's station at `t`, and whether it is cutting.
    fn front_station(&self, t: f64) -> (f64, bool) {
        let mut station = self.scenario.start_station_m;
        for &(start, end, at) in &self.strokes {
            if t < start {
                return (at, false);
            }
            if t < end {
                let reached = (at + RING_LENGTH_M * (t - start) / (end - start))
                    .min(self.axis.end_station_m() - 1.0);
                return (reached, true);
            }
            station = (at + RING_LENGTH_M).min(self.axis.end_station_m() - 1.0);
        }
        (station, false)
    }

    /// The driven path at `station_m`: east, north, height.
    fn path(&self, station_m: f64) -> [f64; 3] {
        let (e, n, azimuth) = self.axis.plan(station_m);
        let h = self.horizontal.at_mm(station_m) / 1000.0;
        let v = self.vertical.at_mm(station_m) / 1000.0;
        // Right of the direction (sin a, cos a) is (cos a, −sin a).
        [
            e + h * azimuth.cos(),
            n - h * azimuth.sin(),
            self.axis.height(station_m) + v,
        ]
    }

    fn point_truth(&self, station_m: f64) -> PointTruth {
        PointTruth {
            station_m,
            horizontal_mm: self.horizontal.at_mm(station_m),
            vertical_mm: self.vertical.at_mm(station_m),
        }
    }

    fn roll_deg(&self, t: f64) -> f64 {
        let x = std::f64::consts::TAU * (t - self.scenario.start_t) / self.roll_period_s
            + self.roll_phase;
        self.roll_mean_deg + 1.8 * x.sin()
    }

    /// The machine at `t`: truth and the laser target's position.
    fn machine(&self, t: f64) -> (AxisTruth, [f64; 3], bool) {
        let g = &self.scenario.geometry;
        let length = g.front_m[0] - g.rear_m[0];
        let (front_station, cutting) = self.front_station(t);
        let front = self.path(front_station);
        // The tail: on the path, the machine length behind (secant steps).
        let mut rear_station = front_station - length;
        let mut rear = self.path(rear_station);
        for _ in 0..6 {
            let d = distance(front, rear);
            rear_station -= length - d;
            rear = self.path(rear_station);
        }
        let u = [0, 1, 2].map(|i| (front[i] - rear[i]) / distance(front, rear));
        let yaw = u[0].atan2(u[1]);
        let pitch = u[2].asin();
        let roll = self.roll_deg(t).to_radians();
        // The body axes in (east, north, up): x along the chord, y right,
        // z down, turned by roll about x.
        let x = u;
        let level_right = [yaw.cos(), -yaw.sin(), 0.0];
        let level_down = cross(x, level_right);
        let (sr, cr) = roll.sin_cos();
        let y = [0, 1, 2].map(|i| cr * level_right[i] + sr * level_down[i]);
        let z = [0, 1, 2].map(|i| -sr * level_right[i] + cr * level_down[i]);
        let offset =
            [0, 1, 2].map(|i| g.front_m[0] * x[i] + g.front_m[1] * y[i] + g.front_m[2] * z[i]);
        let target = [0, 1, 2].map(|i| front[i] - offset[i]);
        let truth = AxisTruth {
            t,
            front: self.point_truth(front_station),
            rear: self.point_truth(rear_station),
            yaw_deg: yaw.to_degrees().rem_euclid(360.0),
            pitch_deg: pitch.to_degrees(),
            roll_deg: roll.to_degrees(),
        };
        (truth, target, cutting)
    }

    fn inclinometer(&mut self, t: f64) -> AxisEvent {
        let (truth, _, cutting) = self.machine(t);
        let temp_c = 20.0 + if cutting { 2.0 } else { 0.5 };
        let white = if cutting { 0.005 } else { 0.001 };
        let n: [f64; 2] = [
            self.incl_rng.sample(StandardNormal),
            self.incl_rng.sample(StandardNormal),
        ];
        AxisEvent {
            reading: Reading {
                t,
                data: SensorData::Inclinometer {
                    pitch_deg: truth.pitch_deg - incl_pitch_error_deg(truth.roll_deg, temp_c)
                        + white * n[0],
                    roll_deg: truth.roll_deg - INCL_ROLL_OFFSET_DEG + white * n[1],
                    temp_c: Some(temp_c),
                },
            },
            truth: None,
        }
    }

    fn laser(&mut self, t: f64) -> AxisEvent {
        let (truth, target, _) = self.machine(t);
        let mut n = || -> f64 { self.laser_rng.sample(StandardNormal) };
        let sigma_m = self.scenario.position_sigma_mm / 1000.0;
        let (np, nr, ny) = (n(), n(), n());
        let position = ProjectPoint {
            easting_m: target[0] + sigma_m * n(),
            northing_m: target[1] + sigma_m * n(),
            height_m: target[2] + sigma_m * n(),
        };
        AxisEvent {
            reading: Reading {
                t,
                data: SensorData::Laser {
                    pitch_deg: truth.pitch_deg + 0.002 * np,
                    roll_deg: truth.roll_deg + 0.002 * nr,
                    yaw_deg: Some((truth.yaw_deg + 0.005 * ny).rem_euclid(360.0)),
                    position: Some(position),
                },
            },
            truth: Some(truth),
        }
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl Iterator for AxisDrive {
    type Item = AxisEvent;

    fn next(&mut self) -> Option<AxisEvent> {
        let s = &self.scenario;
        let end = s.start_t + s.hours * 3600.0;
        let incl_t = s.start_t + self.next_incl as f64 * s.incl_period_s;
        // The first laser sample half a second after the first inclinometer reading.
        let laser_t = s.start_t + 0.5 + self.next_laser as f64 * s.laser_period_s;
        if incl_t >= end && laser_t >= end {
            return None;
        }
        if laser_t < incl_t {
            self.next_laser += 1;
            return Some(self.laser(laser_t));
        }
        self.next_incl += 1;
        Some(self.inclinometer(incl_t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::SensorKind;

    fn protocol_axis() -> AlignmentSpec {
        serde_json::from_str(include_str!("../../tests/fixtures/alignment/s1.json")).unwrap()
    }

    #[test]
    fn the_own_axis_matches_hand_computed_points() {
        let axis = OwnAxis::new(&protocol_axis()).unwrap();
        // 20 m along the first line at 30°.
        let (e, n, a) = axis.plan(20.0);
        assert!((e - 1010.0).abs() < 1e-9 && (n - 5_017.320_508_075_689).abs() < 1e-9);
        assert!((a - 30f64.to_radians()).abs() < 1e-12);
        // A quarter circle of 100 m radius to the right, from north: ends
        // 100 m east and 100 m north of its start, heading east.
        let quarter = AlignmentSpec {
            horizontal: vec![ElementSpec::Arc {
                length_m: 50.0 * std::f64::consts::PI,
                radius_m: 100.0,
            }],
            start: StartPose {
                easting_m: 0.0,
                northing_m: 0.0,
                azimuth_deg: 0.0,
            },
            ..protocol_axis()
        };
        let (e, n, a) = OwnAxis::new(&quarter)
            .unwrap()
            .plan(50.0 * std::f64::consts::PI);
        assert!(
            (e - 100.0).abs() < 1e-7 && (n - 100.0).abs() < 1e-7,
            "{e} {n}"
        );
        assert!((a - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // The profile: 0.5 % up to the PVI at 120 m (50.6 m), −0.5 % after;
        // the 60 m parabola sags the PVI by (g₂ − g₁)L/8 = 0.075 m.
        assert!((axis.height(30.0) - 50.15).abs() < 1e-12);
        assert!((axis.height(120.0) - 50.525).abs() < 1e-12);
        assert!((axis.height(200.0) - 50.2).abs() < 1e-12);
    }

    #[test]
    fn the_machine_spans_its_length_on_the_path_and_the_laser_sees_its_target() {
        let scenario = AxisDriveScenario {
            hours: 3.0,
            position_sigma_mm: 0.0,
            ..AxisDriveScenario::on(protocol_axis(), 3)
        };
        let drive = AxisDrive::new(scenario.clone()).unwrap();
        let length = scenario.geometry.front_m[0] - scenario.geometry.rear_m[0];
        let mut last = f64::NEG_INFINITY;
        let (mut lasers, mut inclinometers) = (0, 0);
        for event in drive.clone() {
            assert!(event.reading.t >= last);
            last = event.reading.t;
            event.reading.validate().unwrap();
            match event.reading.sensor() {
                SensorKind::Laser => lasers += 1,
                SensorKind::Inclinometer => inclinometers += 1,
                other => panic!("unexpected {other}"),
            }
            let Some(truth) = event.truth else { continue };
            let front = drive.path(truth.front.station_m);
            let rear = drive.path(truth.rear.station_m);
            assert!((distance(front, rear) - length).abs() < 1e-9);
            let peak = scenario.peak_fraction * scenario.tolerances.horizontal_mm.warn;
            assert!(truth.front.horizontal_mm.abs() <= peak + 1e-9);
            // The target is the front turned back by the body offset: its
            // distance from the front is the offset's length.
            let SensorData::Laser {
                position: Some(p), ..
            } = event.reading.data
            else {
                panic!("a laser reading without a position");
            };
            let offset = scenario.geometry.front_m;
            let norm = (offset[0].powi(2) + offset[1].powi(2) + offset[2].powi(2)).sqrt();
            let d = distance(front, [p.easting_m, p.northing_m, p.height_m]);
            assert!((d - norm).abs() < 1e-9, "{d} {norm}");
        }
        assert_eq!(inclinometers, 3 * 3600);
        assert_eq!(lasers, 3 * 120);
    }

    #[test]
    fn envelope_drives_are_valid_and_advance() {
        for seed in 1..20 {
            let scenario = AxisDriveScenario::draw(seed);
            scenario.validate().unwrap();
            let drive = AxisDrive::new(scenario.clone()).unwrap();
            // About a ring per 70–105 min over the 8 hours.
            let end = scenario.start_t + scenario.hours * 3600.0;
            let advanced = drive.front_station(end).0 - scenario.start_station_m;
            assert!(
                (6.0..=10.5).contains(&advanced),
                "seed {seed}: {advanced} m"
            );
        }
    }
}
