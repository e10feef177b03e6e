//! A simulated ring build, for `eval rings` and the tests: a TBM driving a
//! random design axis with a wandering path, building universal tapered
//! rings with the keys it is given (as planned, or as an operator
//! overrides), its tail clearance gauged with noise after each push.
//!
//! The truth does not reuse the planner's geometry. The design axis is
//! placed by the simulator's own integration (`axis_drive.rs`); rings are
//! built in three dimensions, each an exact circular arc of its true
//! taper's turn (the taper a little off its nominal, and each ring seated
//! a little off the one before); the clearance is the gap between two
//! circles in the shield's cross-section at the tail's end, not its first
//! order; a ring's deviation is its centre's projection on the axis.

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::fusion::alignment::{AlignmentSpec, ElementSpec, ProfileSpec, Pvi, StartPose};
use crate::fusion::ring_build::{MachineAt, RingSpec};

use super::axis_drive::OwnAxis;

/// A ring build drive, drawn from its seed.
#[derive(Debug, Clone)]
pub struct RingDriveScenario {
    pub seed: u64,
    pub alignment: AlignmentSpec,
    pub spec: RingSpec,
    /// Rings built.
    pub rings: usize,
    /// From the tail's end to the front point, m.
    pub shield_m: f64,
    /// Station of the tail's end at the start.
    pub start_station_m: f64,
    /// The machine's path off the axis: per plane, sines of these
    /// amplitudes (mm), wavelengths (m) and phases.
    pub wander: [[(f64, f64, f64); 2]; 2],
    /// The true gap of a centred ring, mm.
    pub centred_clearance_mm: f64,
    /// 1σ of each gauged gap, mm.
    pub gauge_sigma_mm: f64,
    /// Points gauged round the ring.
    pub points: usize,
    /// 1σ of the guidance's deviations of front and rear, mm.
    pub guidance_sigma_mm: f64,
    /// 1σ of a ring's true taper against its nominal, relative.
    pub taper_error: f64,
    /// 1σ of where a ring seats against the one before, mm, and of its
    /// turn besides its taper's, mrad.
    pub seat_sigma_mm: f64,
    pub seat_sigma_mrad: f64,
    /// How often the operator builds another key than the one asked.
    pub override_probability: f64,
}

impl RingDriveScenario {
    /// The drive of `seed`: a line, a transition into an arc of
    /// ±300…1200 m (straight in one drive of four), a grade of ±2 % with a
    /// vertical curve; the machine wandering up to 5–25 mm off the axis
    /// over 40–160 m; 60 rings of the kind (taper 40 mm, Ø 6 m,
    /// 1.5 m, 16 keys, 3 forbidden at the invert); a gauge of 8 points to
    /// 1.5 mm; guidance to 2 mm; one ring in ten overridden by a key one or
    /// two positions off.
    pub fn draw(seed: u64) -> RingDriveScenario {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(60);
        let straight = rng.random_bool(0.25);
        let radius =
            if rng.random_bool(0.5) { 1.0 } else { -1.0 } * rng.random_range(300.0..1200.0);
        let mut horizontal = vec![ElementSpec::Line { length_m: 20.0 }];
        if straight {
            horizontal.push(ElementSpec::Line { length_m: 120.0 });
        } else {
            horizontal.push(ElementSpec::Spiral {
                length_m: 20.0,
                radius_start_m: None,
                radius_end_m: Some(radius),
            });
            horizontal.push(ElementSpec::Arc {
                length_m: 100.0,
                radius_m: radius,
            });
        }
        let start_height_m = 50.0;
        let grade = rng.random_range(-0.02..0.02);
        let alignment = AlignmentSpec {
            name: format!("ring build axis {seed}"),
            start_station_m: 0.0,
            start: StartPose {
                easting_m: rng.random_range(1000.0..9000.0),
                northing_m: rng.random_range(1000.0..9000.0),
                azimuth_deg: rng.random_range(0.0..360.0),
            },
            horizontal,
            vertical: ProfileSpec {
                start_height_m,
                pvis: vec![Pvi {
                    station_m: 70.0,
                    height_m: start_height_m + grade * 70.0,
                    curve_length_m: 40.0,
                }],
                end_grade_pct: rng.random_range(-2.0..2.0),
            },
            station_equations: Vec::new(),
        };
        let peak_mm: f64 = rng.random_range(5.0..25.0);
        let mut plane = || {
            let share: f64 = rng.random_range(0.5..0.8);
            let tau = std::f64::consts::TAU;
            [
                (
                    peak_mm * share,
                    rng.random_range(80.0..160.0),
                    rng.random_range(0.0..tau),
                ),
                (
                    peak_mm * (1.0 - share),
                    rng.random_range(40.0..80.0),
                    rng.random_range(0.0..tau),
                ),
            ]
        };
        let wander = [plane(), plane()];
        let spec = RingSpec {
            taper_mm: 40.0,
            diameter_m: 6.0,
            width_m: 1.5,
            key_positions: 16,
            forbidden_keys: vec![7, 8, 9],
            nominal_clearance_mm: 50.0,
            min_clearance_mm: 20.0,
            overlap_m: Some(3.0),
            clearance_weight: 1.0,
        };
        RingDriveScenario {
            seed,
            alignment,
            spec,
            rings: 60,
            shield_m: rng.random_range(8.0..11.0),
            start_station_m: 12.0,
            wander,
            centred_clearance_mm: 50.0 + rng.random_range(-3.0..3.0),
            gauge_sigma_mm: 1.5,
            points: 8,
            guidance_sigma_mm: 2.0,
            taper_error: 0.03,
            seat_sigma_mm: 0.5,
            seat_sigma_mrad: 0.1,
            override_probability: 0.1,
        }
    }

    /// The machine path's offset from the axis at `station_m`, m (right,
    /// up).
    fn wander_m(&self, station_m: f64) -> [f64; 2] {
        self.wander.map(|sines| {
            sines
                .iter()
                .map(|&(amplitude_mm, wavelength_m, phase)| {
                    amplitude_mm * (std::f64::consts::TAU * station_m / wavelength_m + phase).sin()
                })
                .sum::<f64>()
                / 1000.0
        })
    }
}

/// A ring as built: its back face's centre, its direction there, the way
/// it turns (a unit vector square to the direction) and by how much.
#[derive(Debug, Clone, Copy)]
struct TrueRing {
    back: Vector3<f64>,
    direction: Vector3<f64>,
    bend: Vector3<f64>,
    turn_rad: f64,
    width_m: f64,
}

impl TrueRing {
    /// The centre line `x` metres along the arc, and its direction.
    fn at(&self, x_m: f64) -> (Vector3<f64>, Vector3<f64>) {
        let angle = self.turn_rad * x_m / self.width_m;
        if self.turn_rad.abs() < 1e-12 {
            return (self.back + self.direction * x_m, self.direction);
        }
        let radius = self.width_m / self.turn_rad;
        let point = self.back
            + self.direction * (radius * angle.sin())
            + self.bend * (radius * (1.0 - angle.cos()));
        let direction = self.direction * angle.cos() + self.bend * angle.sin();
        (point, direction)
    }
}

/// Up, east-north-up.
fn up() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, 1.0)
}

/// The unit vector square to `direction` toward the top, and to the right.
fn frame(direction: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let top = (up() - direction * up().dot(direction)).normalize();
    let right = direction.cross(&top);
    (top, right)
}

/// A ring build under way.
pub struct RingDrive {
    scenario: RingDriveScenario,
    axis: OwnAxis,
    rng: ChaCha8Rng,
    rings: Vec<TrueRing>,
    /// Station of the tail's end on the axis.
    tail_station_m: f64,
}

impl RingDrive {
    /// The drive's start: one ring built, centred in the tail, and the
    /// push after it made (the gauge reads after a push).
    pub fn new(scenario: RingDriveScenario) -> Result<RingDrive, String> {
        let axis = OwnAxis::new(&scenario.alignment)?;
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        rng.set_stream(61);
        let tail_station_m = scenario.start_station_m;
        let mut drive = RingDrive {
            scenario,
            axis,
            rng,
            rings: Vec::new(),
            tail_station_m,
        };
        let (rear, front) = drive.machine_points();
        let direction = (front - rear).normalize();
        let spec = &drive.scenario.spec;
        let face = rear + direction * (spec.overlap_m() - spec.width_m);
        let (top, _) = frame(&direction);
        drive.rings.push(TrueRing {
            back: face - direction * spec.width_m,
            direction,
            bend: top,
            turn_rad: 0.0,
            width_m: spec.width_m,
        });
        Ok(drive)
    }

    pub fn scenario(&self) -> &RingDriveScenario {
        &self.scenario
    }

    /// The design axis at `station_m`: its point, its horizontal right and
    /// its tangent.
    fn axis_frame(&self, station_m: f64) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let (east, north, azimuth) = self.axis.plan(station_m);
        let height = self.axis.height(station_m);
        let delta = 0.01;
        let grade = (self.axis.height(station_m + delta) - self.axis.height(station_m - delta))
            / (2.0 * delta);
        let right = Vector3::new(azimuth.cos(), -azimuth.sin(), 0.0);
        let tangent = Vector3::new(azimuth.sin(), azimuth.cos(), grade).normalize();
        (Vector3::new(east, north, height), right, tangent)
    }

    /// The point `offset_m` (right, up) off the axis at `station_m`.
    fn off_axis(&self, station_m: f64, offset_m: [f64; 2]) -> Vector3<f64> {
        let (point, right, _) = self.axis_frame(station_m);
        point + right * offset_m[0] + up() * offset_m[1]
    }

    /// The tail's end and the front point, on the machine's path.
    fn machine_points(&self) -> (Vector3<f64>, Vector3<f64>) {
        let s = &self.scenario;
        let rear = self.tail_station_m;
        let front = rear + s.shield_m;
        (
            self.off_axis(rear, s.wander_m(rear)),
            self.off_axis(front, s.wander_m(front)),
        )
    }

    /// Where a point lies against the design axis: its station (by
    /// bisection of the tangent's dot product) and its offsets, m.
    pub fn deviation(&self, point: &Vector3<f64>, near_m: f64) -> (f64, [f64; 2]) {
        let along = |s: f64| {
            let (p, _, t) = self.axis_frame(s);
            (point - p).dot(&t)
        };
        let (mut lo, mut hi) = (near_m - 5.0, near_m + 5.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if along(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let station = 0.5 * (lo + hi);
        let (p, right, _) = self.axis_frame(station);
        let d = point - p;
        (
            station,
            [d.dot(&right), point.z - self.axis.height(station)],
        )
    }

    /// What the guidance tells of the machine now, with its noise.
    pub fn machine_measured(&mut self) -> MachineAt {
        let s = &self.scenario;
        let rear = self.tail_station_m;
        let front = rear + s.shield_m;
        let sigma = s.guidance_sigma_mm;
        let (w_rear, w_front) = (s.wander_m(rear), s.wander_m(front));
        let mut noisy = |truth: [f64; 2]| {
            truth.map(|x| x + sigma / 1000.0 * self.rng.sample::<f64, _>(StandardNormal))
        };
        MachineAt {
            front_station_m: front,
            front_m: noisy(w_front),
            rear_station_m: rear,
            rear_m: noisy(w_rear),
            rear_sigma_mm: [sigma; 2],
        }
    }

    /// The true gaps at the tail's end, clockwise from the top.
    pub fn clearance_truth(&self) -> Vec<f64> {
        let (rear, front) = self.machine_points();
        let axis = (front - rear).normalize();
        let (top, right) = frame(&axis);
        // The ring whose centre line crosses the tail's section, newest
        // first; its crossing by Newton's method.
        let crossing = self
            .rings
            .iter()
            .rev()
            .map(|ring| {
                let mut x = (rear - ring.back).dot(&ring.direction);
                for _ in 0..4 {
                    let (p, d) = ring.at(x);
                    x -= (p - rear).dot(&axis) / d.dot(&axis);
                }
                (x, ring)
            })
            .find(|(x, ring)| (-1e-6..=ring.width_m + 1e-6).contains(x))
            .map(|(x, ring)| ring.at(x).0);
        let centre = crossing.unwrap_or_else(|| self.rings[self.rings.len() - 1].at(0.0).0);
        let e = centre - rear;
        let e = [e.dot(&right), e.dot(&top)];
        let spec = &self.scenario.spec;
        let ring_radius = spec.diameter_m / 2.0;
        let skin_radius = ring_radius + self.scenario.centred_clearance_mm / 1000.0;
        (0..self.scenario.points)
            .map(|i| {
                let phi = i as f64 * std::f64::consts::TAU / self.scenario.points as f64;
                let u = [phi.sin(), phi.cos()];
                // The ring's outer circle, centred at e, along the ray u
                // from the skin's centre: e·u + √(r² − (e×u)²).
                let along = e[0] * u[0] + e[1] * u[1];
                let across = e[0] * u[1] - e[1] * u[0];
                let reach = along + (ring_radius.powi(2) - across.powi(2)).sqrt();
                (skin_radius - reach) * 1000.0
            })
            .collect()
    }

    /// The gauge's reading of the gaps: the truth with its noise.
    pub fn clearance_measured(&mut self, truth: &[f64]) -> Vec<f64> {
        let sigma = self.scenario.gauge_sigma_mm;
        truth
            .iter()
            .map(|c| c + sigma * self.rng.sample::<f64, _>(StandardNormal))
            .collect()
    }

    /// Whether the operator overrides the next ring, and with which key:
    /// one or two positions either side of the one asked (a segment at
    /// hand, a joint he prefers), allowed, not the previous one's.
    pub fn operator(&mut self, asked: u32, previous: u32) -> u32 {
        if !self.rng.random_bool(self.scenario.override_probability) {
            return asked;
        }
        let positions = self.scenario.spec.key_positions;
        let near = |k: u32| {
            let d = (k + positions - asked) % positions;
            d.min(positions - d)
        };
        let choices: Vec<u32> = self
            .scenario
            .spec
            .allowed_keys()
            .filter(|&k| (1..=2).contains(&near(k)) && k != previous)
            .collect();
        choices
            .get(self.rng.random_range(0..choices.len().max(1)))
            .copied()
            .unwrap_or(asked)
    }

    /// Builds the next ring with `key`, as rings are: its taper a little
    /// off, seated a little off.
    pub fn build(&mut self, key: u32) {
        let spec = self.scenario.spec.clone();
        let last = self.rings[self.rings.len() - 1];
        let (face, direction) = last.at(last.width_m);
        let (top, right) = frame(&direction);
        let phi = spec.key_angle_rad(key);
        let widest = top * phi.cos() + right * phi.sin();
        let taper = spec.taper_rad()
            * (1.0 + self.scenario.taper_error * self.rng.sample::<f64, _>(StandardNormal));
        let n = |rng: &mut ChaCha8Rng| rng.sample::<f64, _>(StandardNormal);
        let seat = (top * n(&mut self.rng) + right * n(&mut self.rng))
            * (self.scenario.seat_sigma_mm / 1000.0);
        let tilt = (top * n(&mut self.rng) + right * n(&mut self.rng))
            * (self.scenario.seat_sigma_mrad / 1000.0);
        let direction = (direction + tilt).normalize();
        let (top, right) = frame(&direction);
        // The widest point's side, square to the tilted direction.
        let widest = (top * widest.dot(&top) + right * widest.dot(&right)).normalize();
        self.rings.push(TrueRing {
            back: face + seat,
            direction,
            bend: -widest,
            turn_rad: taper,
            width_m: spec.width_m,
        });
    }

    /// The machine pushes one ring width.
    pub fn push(&mut self) {
        self.tail_station_m += self.scenario.spec.width_m;
    }

    /// The newest ring's centre against the design axis: station and
    /// offsets, mm.
    pub fn newest_centre(&self) -> (f64, [f64; 2]) {
        let ring = self.rings[self.rings.len() - 1];
        let (centre, _) = ring.at(ring.width_m / 2.0);
        let near = self.tail_station_m + self.scenario.spec.overlap_m() - ring.width_m / 2.0;
        let (station, offset) = self.deviation(&centre, near);
        (station, offset.map(|o| o * 1000.0))
    }

    /// Rings built since the start.
    pub fn rings_built(&self) -> usize {
        self.rings.len() - 1
    }
}
