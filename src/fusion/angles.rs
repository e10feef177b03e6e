//! Degrees at the edges, radians inside the math: the one place where
//! tunnelnav converts between them.

/// Degrees to radians.
#[inline]
pub fn rad(deg: f64) -> f64 {
    deg.to_radians()
}

/// Radians to degrees.
#[inline]
pub fn deg(rad: f64) -> f64 {
    rad.to_degrees()
}

/// A variance in deg² to rad².
#[inline]
pub fn rad2(deg2: f64) -> f64 {
    let k = 1.0_f64.to_radians();
    deg2 * k * k
}
