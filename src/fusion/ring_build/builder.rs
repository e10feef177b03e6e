//! The built lining, tracked ring by ring, and the plan from it.
//!
//! The newest ring's front face is estimated per plane as (offset,
//! direction) against the axis with its covariance. A ring built with a
//! known key moves it by the ring chain (`chain.rs`), and its covariance
//! by F·P·Fᵀ + Q, F = [[1, w], [0, 1]], Q the build's own error
//! ([`BUILD_OFFSET_SIGMA_MM`], [`BUILD_ANGLE_SIGMA_MRAD`]). A measured
//! tail clearance is independent evidence of where the lining is: the
//! ring's centre off the tail's (the fit, `clearance.rs`) plus where the
//! tail is (the machine's rear point, from the newest `dta` estimate),
//! at the tail's end; a Kalman update with H = [1, −Δ] (Δ from the tail's
//! end to the front face) and the two σ added corrects the chain.
//!
//! The machine's track (the front point's deviations by station) tells
//! where the shield will be when its tail gets to a station: where the
//! front was. Ahead of the front, the target (the correction curve, or the
//! axis) plus the front's present offset from it.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::super::steering::Axis;
use super::chain::{self, Face, Ring};
use super::clearance;
use super::plan::{Course, Plan, Situation};
use super::spec::RingSpec;

/// 1σ of where a ring seats against the one before, mm.
pub const BUILD_OFFSET_SIGMA_MM: f64 = 1.0;
/// 1σ of a ring's turn against its taper's, mrad (5 % of a 40 mm taper
/// on 6 m).
pub const BUILD_ANGLE_SIGMA_MRAD: f64 = 0.33;
/// 1σ of the tail's position when the `dta` estimate has none (laser
/// positions), mm.
pub const GUIDANCE_SIGMA_MM: f64 = 3.0;
/// 1σ of a clearance fit's offsets when the fit has too few points to
/// tell, and the least it is taken as, mm.
pub const CLEARANCE_FIT_FLOOR_MM: f64 = 0.5;
/// 1σ of a lining started from the machine (centred in the tail, headed
/// as the machine), mm and mrad.
const START_OFFSET_SIGMA_MM: f64 = 10.0;
const START_ANGLE_SIGMA_MRAD: f64 = 2.0;
/// Points of the machine's track kept (a point per `dta` estimate, thinned
/// to one per 10 cm of station).
const TRACK_LEN: usize = 400;
const TRACK_SPACING_M: f64 = 0.1;
/// Weight of the newest innovation in the running mean of their
/// normalised squares (about the last 20 rings).
const NIS_WEIGHT: f64 = 0.05;
/// Bounds of the build error's scale.
const Q_SCALE: (f64, f64) = (0.05, 20.0);
/// Points round the ring a plan predicts before any clearance is measured.
pub const DEFAULT_POINTS: usize = 8;

/// Where the machine is: its front and rear (the tail's end) against the
/// axis, from a `dta` estimate, at internal stations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MachineAt {
    pub front_station_m: f64,
    pub front_m: [f64; 2],
    pub rear_station_m: f64,
    pub rear_m: [f64; 2],
    /// 1σ of the rear's deviations, mm.
    pub rear_sigma_mm: [f64; 2],
}

/// One plane's estimate of the newest front face: offset (m) and
/// direction (rad) against the axis, with their covariance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct PlaneCovariance {
    p: [[f64; 2]; 2],
}

impl PlaneCovariance {
    fn diagonal(offset_sigma_m: f64, angle_sigma_rad: f64) -> Self {
        PlaneCovariance {
            p: [
                [offset_sigma_m.powi(2), 0.0],
                [0.0, angle_sigma_rad.powi(2)],
            ],
        }
    }

    /// F·P·Fᵀ + `scale`·Q over a ring of width `w`.
    fn built(&mut self, w: f64, scale: f64) {
        let p = self.p;
        let p00 = p[0][0] + w * (p[0][1] + p[1][0]) + w * w * p[1][1];
        let p01 = p[0][1] + w * p[1][1];
        self.p = [
            [p00 + scale * (BUILD_OFFSET_SIGMA_MM / 1000.0).powi(2), p01],
            [
                p01,
                p[1][1] + scale * (BUILD_ANGLE_SIGMA_MRAD / 1000.0).powi(2),
            ],
        ];
    }

    /// A measurement z of offset − Δ·direction with variance `r`:
    /// the state's correction for innovation `y`, and the innovation's
    /// normalised square y²/S.
    fn update(&mut self, delta_m: f64, r: f64, y: f64) -> ([f64; 2], f64) {
        let p = self.p;
        let h = [1.0, -delta_m];
        let ph = [
            p[0][0] * h[0] + p[0][1] * h[1],
            p[1][0] * h[0] + p[1][1] * h[1],
        ];
        let s = h[0] * ph[0] + h[1] * ph[1] + r;
        let k = [ph[0] / s, ph[1] / s];
        for (i, row) in self.p.iter_mut().enumerate() {
            for (j, value) in row.iter_mut().enumerate() {
                *value = p[i][j] - k[i] * ph[j];
            }
        }
        ([k[0] * y, k[1] * y], y * y / s)
    }

    fn offset_sigma_mm(&self) -> f64 {
        self.p[0][0].max(0.0).sqrt() * 1000.0
    }

    /// 1σ of the offset `behind_m` behind the face, mm: √(h·P·hᵀ),
    /// h = [1, −behind].
    fn sigma_behind_mm(&self, behind_m: f64) -> f64 {
        let p = self.p;
        let variance = p[0][0] - behind_m * (p[0][1] + p[1][0]) + behind_m * behind_m * p[1][1];
        variance.max(0.0).sqrt() * 1000.0
    }
}

/// What the builder knows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct RingBuilder {
    /// The newest ring, if the lining is known, and the one before it.
    newest: Option<Ring>,
    previous: Option<Ring>,
    /// Its number and key position (`None` for a ring the lining was
    /// started from).
    newest_ring: Option<u64>,
    newest_key: Option<u32>,
    covariance: Option<[PlaneCovariance; 2]>,
    /// The newest machine position.
    machine: Option<MachineAt>,
    /// The front's track: internal station, offsets (m).
    track: VecDeque<(f64, [f64; 2])>,
    /// The innovations' normalised squares, averaged (per plane, weight
    /// [`NIS_WEIGHT`] for the newest): the build's error Q is scaled by
    /// it, so the lining's σ follows what the measurements show.
    #[serde(default)]
    nis_mean: Option<[f64; 2]>,
    /// The last clearance measured: its centred gap and its points.
    centred_clearance_mm: Option<f64>,
    points: Option<usize>,
}

/// A ring just added to the lining or corrected.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BuiltRing {
    pub ring: Option<u64>,
    pub key: u32,
    /// The ring's centre: internal station and offsets (m).
    pub centre: Face,
    /// 1σ of the centre's offsets, mm.
    pub sigma_mm: [f64; 2],
}

impl RingBuilder {
    /// A machine position (a `dta` estimate's front and rear).
    pub fn machine(&mut self, at: MachineAt) {
        self.machine = Some(at);
        let far_enough = self
            .track
            .back()
            .is_none_or(|(s, _)| (at.front_station_m - s).abs() >= TRACK_SPACING_M);
        if far_enough {
            // A machine never backs: a station behind the track's end
            // starts a new one (a new set-up of the guidance).
            if self
                .track
                .back()
                .is_some_and(|(s, _)| at.front_station_m < *s)
            {
                self.track.clear();
            }
            self.track.push_back((at.front_station_m, at.front_m));
            if self.track.len() > TRACK_LEN {
                self.track.pop_front();
            }
        }
    }

    /// Starts the lining from the machine: the newest ring (straight,
    /// `key`) centred in the tail, headed as the machine, its front face
    /// `ahead_m` ahead of the tail's end. `None` without a machine
    /// position.
    fn start<A: Axis + ?Sized>(
        &mut self,
        axis: &A,
        spec: &RingSpec,
        key: u32,
        ahead_m: f64,
    ) -> Option<()> {
        let m = self.machine?;
        let angle = chain::heading_through(
            axis,
            (m.rear_station_m, m.rear_m),
            (m.front_station_m, m.front_m),
        );
        let tail = Face {
            station_m: m.rear_station_m,
            offset_m: m.rear_m,
            angle_rad: angle,
        };
        // A straight piece of lining to the front face, on the axis's frame.
        let front = chain::along(axis, &tail, ahead_m);
        let back = chain::along(axis, &front, -spec.width_m);
        self.newest = Some(Ring {
            key,
            straight: true,
            back,
            front,
        });
        self.previous = None;
        let start = PlaneCovariance::diagonal(
            START_OFFSET_SIGMA_MM / 1000.0,
            START_ANGLE_SIGMA_MRAD / 1000.0,
        );
        self.covariance = Some([start; 2]);
        Some(())
    }

    /// Ring `ring` completed with `key` (`None`: the key is not known, and
    /// the lining restarts from the machine at the next ring).
    pub fn advance<A: Axis + ?Sized>(
        &mut self,
        axis: &A,
        spec: &RingSpec,
        ring: u64,
        key: Option<u32>,
    ) -> Option<BuiltRing> {
        let Some(key) = key else {
            self.newest = None;
            self.previous = None;
            self.covariance = None;
            self.newest_ring = Some(ring);
            self.newest_key = None;
            return None;
        };
        if self.newest.is_none() {
            // The machine's tail holds the ring just built, before the push.
            self.start(axis, spec, key, spec.overlap_m())?;
        } else {
            let front = self.newest?.front;
            self.previous = self.newest;
            self.newest = Some(chain::build(axis, spec, &front, key));
            let scale = self.nis_mean.unwrap_or([1.0; 2]);
            if let Some(covariance) = self.covariance.as_mut() {
                for (plane, scale) in covariance.iter_mut().zip(scale) {
                    plane.built(spec.width_m, scale.clamp(Q_SCALE.0, Q_SCALE.1));
                }
            }
        }
        self.newest_ring = Some(ring);
        self.newest_key = Some(key);
        self.built(axis, spec)
    }

    /// A tail clearance measured at the tail's end; corrects the lining.
    pub fn clearance<A: Axis + ?Sized>(
        &mut self,
        axis: &A,
        spec: &RingSpec,
        clearances_mm: &[f64],
    ) -> Option<BuiltRing> {
        let fit = clearance::fit(clearances_mm)?;
        self.centred_clearance_mm = Some(fit.mean_mm);
        self.points = Some(clearances_mm.len());
        let machine = self.machine?;
        if self.newest.is_none() {
            // Gauged after a push: the newest ring's front face a ring
            // width nearer the tail's end than when it was built. Its key
            // is not known.
            self.start(axis, spec, 0, spec.overlap_m() - spec.width_m)?;
            self.newest_key = None;
        }
        let newest = self.newest?;
        // The lining at the tail's end, as the chain has it.
        let x = machine.rear_station_m - newest.back.station_m;
        let at_tail = match self.previous {
            _ if (0.0..=spec.width_m).contains(&x) => newest.at(axis, spec, x),
            _ if x > spec.width_m => chain::along(axis, &newest.front, x - spec.width_m),
            Some(previous) if x >= -spec.width_m => previous.at(axis, spec, x + spec.width_m),
            _ => chain::along(axis, &newest.back, x),
        };
        let delta_m = newest.front.station_m - machine.rear_station_m;
        let fit_sigma = fit
            .offset_sigma_mm
            .unwrap_or(CLEARANCE_FIT_FLOOR_MM)
            .max(CLEARANCE_FIT_FLOOR_MM);
        let covariance = self.covariance.as_mut()?;
        let front_station_m = newest.front.station_m;
        let mut shift = [[0.0; 2]; 2];
        let mut nis_mean = self.nis_mean.unwrap_or([1.0; 2]);
        for i in 0..2 {
            let measured = machine.rear_m[i] + fit.offset_mm[i] / 1000.0;
            let r = ((fit_sigma.powi(2) + machine.rear_sigma_mm[i].powi(2)) / 1.0e6).max(1e-12);
            let (correction, nis) =
                covariance[i].update(delta_m, r, measured - at_tail.offset_m[i]);
            shift[i] = correction;
            nis_mean[i] += NIS_WEIGHT * (nis.min(25.0) - nis_mean[i]);
        }
        self.nis_mean = Some(nis_mean);
        // The lining moves as one piece about the front face.
        let moved = |face: &mut Face| {
            let behind_m = front_station_m - face.station_m;
            for (i, [d_offset, d_angle]) in shift.into_iter().enumerate() {
                face.offset_m[i] += d_offset - d_angle * behind_m;
                face.angle_rad[i] += d_angle;
            }
        };
        for ring in [self.newest.as_mut(), self.previous.as_mut()]
            .into_iter()
            .flatten()
        {
            moved(&mut ring.back);
            moved(&mut ring.front);
        }
        self.built(axis, spec)
    }

    /// The newest ring as known now.
    pub fn built<A: Axis + ?Sized>(&self, axis: &A, spec: &RingSpec) -> Option<BuiltRing> {
        let newest = self.newest?;
        let covariance = self.covariance?;
        Some(BuiltRing {
            ring: self.newest_ring,
            key: newest.key,
            centre: newest.centre(axis, spec),
            sigma_mm: covariance.map(|c| c.sigma_behind_mm(spec.width_m / 2.0)),
        })
    }

    /// 2σ of the newest front face's offset, the larger plane's, mm.
    fn margin_mm(&self) -> f64 {
        self.covariance.map_or(0.0, |c| {
            2.0 * c[0].offset_sigma_mm().max(c[1].offset_sigma_mm())
        })
    }

    /// The newest ring's key position, if known.
    pub fn newest_key(&self) -> Option<u32> {
        self.newest_key
    }

    /// The newest ring's number, if any advance was seen.
    pub fn newest_ring(&self) -> Option<u64> {
        self.newest_ring
    }

    /// The plan for the next `look_ahead` rings toward `target` (offsets
    /// from the axis by internal station, m; `None`: the axis itself).
    pub fn plan<A: Axis + ?Sized>(
        &self,
        axis: &A,
        spec: &RingSpec,
        target: Option<&dyn Fn(f64) -> [f64; 2]>,
        look_ahead: usize,
        beam: usize,
    ) -> Option<Plan> {
        self.at_newest(axis, spec, target, |s| s.search(look_ahead, beam))
    }

    /// The key the naive rule builds next (the one that turns most nearly
    /// toward the target), the yardstick of `eval rings`.
    pub fn naive_key<A: Axis + ?Sized>(
        &self,
        axis: &A,
        spec: &RingSpec,
        target: Option<&dyn Fn(f64) -> [f64; 2]>,
    ) -> Option<u32> {
        self.at_newest(axis, spec, target, |s| s.naive())
    }

    /// `decide` on the situation at the newest ring's front face; `None`
    /// before the lining is known.
    fn at_newest<A: Axis + ?Sized, R>(
        &self,
        axis: &A,
        spec: &RingSpec,
        target: Option<&dyn Fn(f64) -> [f64; 2]>,
        decide: impl FnOnce(&Situation<'_, A, TrackCourse<'_>>) -> R,
    ) -> Option<R> {
        let newest = self.newest?;
        let course = TrackCourse {
            track: &self.track,
            target,
        };
        let situation = Situation {
            axis,
            spec,
            course: &course,
            front: newest.front,
            last_key: self.newest_key,
            points: self.points.unwrap_or(DEFAULT_POINTS),
            centred_clearance_mm: self
                .centred_clearance_mm
                .unwrap_or(spec.nominal_clearance_mm),
            margin_mm: self.margin_mm(),
        };
        Some(decide(&situation))
    }
}

/// The course from the machine's track and the target.
struct TrackCourse<'a> {
    track: &'a VecDeque<(f64, [f64; 2])>,
    target: Option<&'a dyn Fn(f64) -> [f64; 2]>,
}

impl Course for TrackCourse<'_> {
    fn target_m(&self, station_m: f64) -> [f64; 2] {
        self.target.map_or([0.0; 2], |target| target(station_m))
    }

    fn shield_m(&self, station_m: f64) -> [f64; 2] {
        let Some(&(last_s, last)) = self.track.back() else {
            return self.target_m(station_m);
        };
        if station_m >= last_s {
            // Ahead of the front: the target, with the front's offset
            // from it held.
            let (here, there) = (self.target_m(last_s), self.target_m(station_m));
            return [0, 1].map(|i| there[i] + last[i] - here[i]);
        }
        // Where the front was: between the two track points around it.
        let after = self.track.partition_point(|(s, _)| *s <= station_m);
        match (
            after.checked_sub(1).map(|i| self.track[i]),
            self.track.get(after),
        ) {
            (Some((s0, o0)), Some(&(s1, o1))) if s1 > s0 => {
                let u = (station_m - s0) / (s1 - s0);
                [0, 1].map(|i| o0[i] + u * (o1[i] - o0[i]))
            }
            (Some((_, o0)), _) => o0,
            (None, _) => self.track.front().map_or(last, |(_, o)| *o),
        }
    }
}
