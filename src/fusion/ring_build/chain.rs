//! The ring chain: where a ring built with a key position puts the lining,
//! from the ring before it.
//!
//! A universal ring's back face lies on the previous ring's front face;
//! its front face is tilted by the taper, δ = `taper_mm`/`diameter_m`
//! rad, away from its widest point. Built with key position k (the widest
//! point at φ = k·2π/K clockwise from the top, looking forward) it turns
//! the lining by
//!
//!   τ = −δ·(sin φ, cos φ)          (right, up)
//!
//! evenly over its width w, as an arc does. Against the design axis, whose
//! direction is Θ(s) per plane, a point x along the ring (0 ≤ x ≤ w) from
//! a face at station s, offset o and direction a (the ring's less the
//! axis's) lies at
//!
//!   offset(x) = o + a·x + τ·x²/(2w) − ∫₀ˣ (Θ(s + u) − Θ(s)) du
//!   angle(x)  = a + τ·x/w − (Θ(s + x) − Θ(s))
//!
//! (the integral by Simpson's rule: exact for an axis whose direction is
//! at most quadratic along the ring). The ring's centre is x = w/2, its
//! front face x = w. Offsets are measured square to the axis and stations
//! along it: on a curve of radius R an offset o shifts the station's
//! scale by o/R, below 10⁻⁴ for any offset a lining tolerates.

use serde::{Deserialize, Serialize};

use super::super::steering::Axis;
use super::spec::RingSpec;

/// The lining at a ring's face, against the design axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Face {
    /// Internal station of the face's centre, m.
    pub station_m: f64,
    /// The face centre's offset from the axis, m: right, up.
    pub offset_m: [f64; 2],
    /// The ring's direction less the axis's, rad: right, up.
    pub angle_rad: [f64; 2],
}

/// A ring built from a face.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Ring {
    pub key: u32,
    /// A piece of lining taken as straight (where the lining was started
    /// from the machine): its key's taper is not applied.
    pub straight: bool,
    /// Where it started (the previous ring's front face).
    pub back: Face,
    /// Its front face: where the next ring starts.
    pub front: Face,
}

impl Ring {
    /// The ring's centre line at `x` metres from its back face: its
    /// station and its offset from the axis, m.
    pub fn at<A: Axis + ?Sized>(&self, axis: &A, spec: &RingSpec, x_m: f64) -> Face {
        let turn = if self.straight {
            [0.0; 2]
        } else {
            turn_rad(spec, self.key)
        };
        point_on_ring(axis, spec.width_m, &self.back, turn, x_m)
    }

    /// The ring's centre (half its width from the back face).
    pub fn centre<A: Axis + ?Sized>(&self, axis: &A, spec: &RingSpec) -> Face {
        self.at(axis, spec, spec.width_m / 2.0)
    }
}

/// τ: how a ring built with `key` turns the lining, rad (right, up).
pub fn turn_rad(spec: &RingSpec, key: u32) -> [f64; 2] {
    let phi = spec.key_angle_rad(key);
    let delta = spec.taper_rad();
    [-delta * phi.sin(), -delta * phi.cos()]
}

/// The ring built with `key` on the face `back`.
pub fn build<A: Axis + ?Sized>(axis: &A, spec: &RingSpec, back: &Face, key: u32) -> Ring {
    let front = point_on_ring(axis, spec.width_m, back, turn_rad(spec, key), spec.width_m);
    Ring {
        key,
        straight: false,
        back: *back,
        front,
    }
}

/// The direction against the axis of the straight line from `from` to
/// `to` (internal station, offsets in m), rad per plane: the offsets'
/// difference plus what the axis bends away between, over the length.
pub fn heading_through<A: Axis + ?Sized>(
    axis: &A,
    from: (f64, [f64; 2]),
    to: (f64, [f64; 2]),
) -> [f64; 2] {
    let (s, length) = (from.0, (to.0 - from.0).max(0.1));
    let half = axis_turn(axis, s, s + length / 2.0);
    let whole = axis_turn(axis, s, s + length);
    [0, 1].map(|i| {
        let axis_bend = length / 6.0 * (4.0 * half[i] + whole[i]);
        (to.1[i] - from.1[i] + axis_bend) / length
    })
}

/// The point `x_m` ahead of `face` (behind, negative) on the straight line
/// along its direction.
pub fn along<A: Axis + ?Sized>(axis: &A, face: &Face, x_m: f64) -> Face {
    point_on_ring(axis, 1.0, face, [0.0; 2], x_m)
}

/// The axis's change of direction from `from_m` to `to_m` per plane, rad
/// (an azimuth taken the short way round).
fn axis_turn<A: Axis + ?Sized>(axis: &A, from_m: f64, to_m: f64) -> [f64; 2] {
    let (a, b) = (axis.angles_rad(from_m), axis.angles_rad(to_m));
    [wrap(b[0] - a[0]), b[1] - a[1]]
}

/// An angle difference in (−π, π].
fn wrap(angle_rad: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let wrapped = angle_rad.rem_euclid(tau);
    if wrapped > std::f64::consts::PI {
        wrapped - tau
    } else {
        wrapped
    }
}

/// The centre line `x_m` along a ring of width `w` and turn `turn` from
/// `back`.
fn point_on_ring<A: Axis + ?Sized>(
    axis: &A,
    w: f64,
    back: &Face,
    turn: [f64; 2],
    x_m: f64,
) -> Face {
    let s = back.station_m;
    let half = axis_turn(axis, s, s + x_m / 2.0);
    let whole = axis_turn(axis, s, s + x_m);
    let mut face = Face {
        station_m: s + x_m,
        offset_m: [0.0; 2],
        angle_rad: [0.0; 2],
    };
    for i in 0..2 {
        // ∫₀ˣ (Θ(s + u) − Θ(s)) du by Simpson's rule.
        let axis_bend = x_m / 6.0 * (4.0 * half[i] + whole[i]);
        face.offset_m[i] =
            back.offset_m[i] + back.angle_rad[i] * x_m + turn[i] * x_m * x_m / (2.0 * w)
                - axis_bend;
        face.angle_rad[i] = back.angle_rad[i] + turn[i] * x_m / w - whole[i];
    }
    face
}
