//! Which key position to build next: a look-ahead over the next rings.
//!
//! Each ring of a candidate sequence costs (mm², the trade-off declared as
//! `clearance_weight`)
//!
//!   cost = |centre − target|² + clearance_weight·mean((cᵢ − m)²)
//!          + SHORTFALL_COST·(max(0, min_clearance + margin − min cᵢ))²
//!
//! with the ring's centre against the target curve (the correction curve
//! the machine follows, or the axis) and cᵢ its clearance when the tail's
//! end passes the ring's centre and its front face, predicted from where
//! the shield will be then; the margin is 2σ of where the lining is
//! known to be, so a gap counts as short before it is.
//! A forbidden key is never built, and no ring repeats the key of the ring
//! before it (their longitudinal joints would line up). A sequence's cost
//! is the sum of its rings'. The search keeps the `BEAM` cheapest partial
//! sequences at each depth (an exhaustive search with an unbounded
//! beam); the first ring of the cheapest sequence is built, and the
//! search runs again at the next ring.

use super::super::steering::Axis;
use super::chain::{self, Face, Ring};
use super::clearance;
use super::spec::RingSpec;

/// Partial sequences kept at each depth of the look-ahead.
pub const BEAM: usize = 256;
/// Rings looked ahead by default.
pub const LOOK_AHEAD: usize = 4;
/// Cost per mm² of clearance below the least allowed: far above any
/// deviation, so a sequence keeps the least clearance wherever one can.
pub const SHORTFALL_COST: f64 = 1.0e4;

/// Where the lining should go, and where the shield will be.
pub trait Course {
    /// Where the lining should be at internal station `station_m`: its
    /// offset from the axis, m (right, up).
    fn target_m(&self, station_m: f64) -> [f64; 2];
    /// Where the shield's axis will be at `station_m` when its tail's end
    /// gets there, m off the design axis (right, up).
    fn shield_m(&self, station_m: f64) -> [f64; 2];
}

/// Where the plan starts.
pub struct Situation<'a, A: Axis + ?Sized, C: Course + ?Sized> {
    pub axis: &'a A,
    pub spec: &'a RingSpec,
    pub course: &'a C,
    /// The newest ring's front face.
    pub front: Face,
    /// The newest ring's key position, if known.
    pub last_key: Option<u32>,
    /// Points round the ring the clearance is predicted at.
    pub points: usize,
    /// The gap of a centred ring, mm (the last measured mean, or nominal).
    pub centred_clearance_mm: f64,
    /// How far a predicted gap may be wrong, mm (2σ of where the lining
    /// is): a gap is short when it is within this of the least allowed.
    pub margin_mm: f64,
}

/// One ring of a plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedRing {
    pub ring: Ring,
    /// The ring's centre off the target, mm (right, up).
    pub off_target_mm: [f64; 2],
    /// The ring's clearance at each point when the tail's end passes its
    /// centre, mm, clockwise from the top.
    pub predicted_clearance_mm: Vec<f64>,
    /// This ring's part of the cost, mm².
    pub cost: f64,
}

/// A plan: the rings to build, next first, and their total cost.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    pub rings: Vec<PlannedRing>,
    pub cost: f64,
}

impl<A: Axis + ?Sized, C: Course + ?Sized> Situation<'_, A, C> {
    /// The ring built with `key` on `back`, priced.
    pub fn price(&self, back: &Face, key: u32) -> PlannedRing {
        let spec = self.spec;
        let ring = chain::build(self.axis, spec, back, key);
        let centre = ring.centre(self.axis, spec);
        let target = self.course.target_m(centre.station_m);
        let off_target_mm = [0, 1].map(|i| (centre.offset_m[i] - target[i]) * 1000.0);
        let m = self.centred_clearance_mm;
        // The gaps as the tail's end passes the centre, then the front face.
        let gaps = |face: &Face| {
            let shield = self.course.shield_m(face.station_m);
            let off_shield_mm = [0, 1].map(|i| (face.offset_m[i] - shield[i]) * 1000.0);
            clearance::predict(m, off_shield_mm, self.points)
        };
        let mut cost = off_target_mm[0].powi(2) + off_target_mm[1].powi(2);
        let predicted = gaps(&centre);
        for gaps in [&predicted, &gaps(&ring.front)] {
            let spread = gaps.iter().map(|c| (c - m).powi(2)).sum::<f64>() / gaps.len() as f64;
            let least = gaps.iter().copied().fold(f64::INFINITY, f64::min);
            let shortfall = (spec.min_clearance_mm + self.margin_mm - least).max(0.0);
            cost += (spec.clearance_weight * spread + SHORTFALL_COST * shortfall * shortfall) / 2.0;
        }
        PlannedRing {
            ring,
            off_target_mm,
            predicted_clearance_mm: predicted,
            cost,
        }
    }

    /// Keys that may follow `last`: allowed, and not `last` itself.
    fn next_keys(&self, last: Option<u32>) -> impl Iterator<Item = u32> + '_ {
        self.spec
            .allowed_keys()
            .filter(move |&k| last.is_none_or(|last| !RingSpec::joints_aligned(last, k)))
    }

    /// The cheapest sequence of `depth` rings the search finds keeping
    /// `beam` partial sequences per depth (`usize::MAX`: all of them).
    pub fn search(&self, depth: usize, beam: usize) -> Plan {
        struct Partial {
            cost: f64,
            front: Face,
            keys: Vec<u32>,
        }
        let mut partials = vec![Partial {
            cost: 0.0,
            front: self.front,
            keys: Vec::new(),
        }];
        for _ in 0..depth.max(1) {
            let mut next = Vec::with_capacity(partials.len() * self.spec.key_positions as usize);
            for partial in &partials {
                let last = partial.keys.last().copied().or(self.last_key);
                for key in self.next_keys(last) {
                    let priced = self.price(&partial.front, key);
                    let mut keys = partial.keys.clone();
                    keys.push(key);
                    next.push(Partial {
                        cost: partial.cost + priced.cost,
                        front: priced.ring.front,
                        keys,
                    });
                }
            }
            next.sort_by(|a, b| a.cost.total_cmp(&b.cost).then_with(|| a.keys.cmp(&b.keys)));
            next.truncate(beam);
            partials = next;
        }
        let keys = partials.first().map(|p| p.keys.clone()).unwrap_or_default();
        self.sequence(&keys)
    }

    /// The plan of building `keys` in turn.
    pub fn sequence(&self, keys: &[u32]) -> Plan {
        let mut rings = Vec::with_capacity(keys.len());
        let mut front = self.front;
        for &key in keys {
            let priced = self.price(&front, key);
            front = priced.ring.front;
            rings.push(priced);
        }
        let cost = rings.iter().map(|r| r.cost).sum();
        Plan { rings, cost }
    }

    /// The naive rule: the allowed key (not the last one) whose turn
    /// points most nearly from the newest ring's front toward the target.
    pub fn naive(&self) -> u32 {
        let target = self.course.target_m(self.front.station_m);
        let toward = [0, 1].map(|i| target[i] - self.front.offset_m[i]);
        self.next_keys(self.last_key)
            .max_by(|&a, &b| {
                let score = |k| {
                    let t = chain::turn_rad(self.spec, k);
                    t[0] * toward[0] + t[1] * toward[1]
                };
                score(a).total_cmp(&score(b)).then(b.cmp(&a))
            })
            .unwrap_or(0)
    }
}
