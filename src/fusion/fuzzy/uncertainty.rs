//! The σ of an angle the engine carries on the gyros (tilt, heading)
//! against the σ of the sensor that pulls it back (accelerometer, compass)
//! (docs/engines/fuzzy.md: step 4). With σ the angle's own and σ_ref
//! the sensor's:
//! - the sensor is believed within max(gate, 2·√(σ² + σ_ref²)): two σ of
//!   the innovation, never less than the configured gate;
//! - its pull is multiplied by max(1, σ²/σ_ref²): an angle less sure than
//!   the sensor takes it faster;
//! - a pull by the fraction g leaves σ² ← (1 − g)²σ² + g²σ_ref² (the
//!   variance of (1 − g)·angle + g·sensor).

/// What the estimate reports as its 1σ, rad: the engine's own σ (the
/// gyros' drift against the sensor's white noise, above) and the errors
/// that no averaging of the sensor removes, added in quadrature:
/// √(σ² + Σ σ_sys²), at most [`UNKNOWN_ANGLE_SIGMA_RAD`].
pub fn reported_sigma(sigma_rad: f64, systematic_rad: &[f64]) -> f64 {
    let total = systematic_rad
        .iter()
        .fold(sigma_rad * sigma_rad, |sum, s| sum + s * s);
    total.sqrt().min(UNKNOWN_ANGLE_SIGMA_RAD)
}

/// σ of an angle known only to lie somewhere in a full turn: π/√3 rad
/// (103.9°, a uniform distribution over ±180°).
pub const UNKNOWN_ANGLE_SIGMA_RAD: f64 = 1.813_799_364_234_217_8;

/// The innovation the sensor is believed within, rad.
pub fn widened_gate(gate_rad: f64, sigma_rad: f64, reference_sigma_rad: f64) -> f64 {
    gate_rad.max(2.0 * (sigma_rad.powi(2) + reference_sigma_rad.powi(2)).sqrt())
}

/// What the sensor's pull is multiplied by.
pub fn pull_boost(sigma_rad: f64, reference_sigma_rad: f64) -> f64 {
    (sigma_rad / reference_sigma_rad).powi(2).max(1.0)
}

/// The σ, rad, of a reference that is a mean over a window while the
/// sensor moves: its own `base_sigma_rad` and the acceleration the window
/// shows, added in quadrature. A force mean whose size is not gravity's,
/// or an older half that differs from the newer one, is not gravity's
/// direction alone: their sum over g is the angle it may be off
/// (`norm_error_mps2` = |‖F̄‖ − g₀|, `halves_apart_mps2` = how far the
/// halves' means are apart beyond their scatter,
/// `TiltWindow::halves_apart_mps2`). A sideways acceleration a changes
/// ‖F̄‖ by only a²/2g: what this σ misses, the gate's residual sees.
pub fn moving_reference_sigma(
    base_sigma_rad: f64,
    norm_error_mps2: f64,
    halves_apart_mps2: f64,
    gravity_mps2: f64,
) -> f64 {
    let shown = ((norm_error_mps2.abs() + halves_apart_mps2.abs()) / gravity_mps2.max(1e-9)).atan();
    (base_sigma_rad.powi(2) + shown.powi(2)).sqrt()
}

/// The 1σ, rad, that a window's residual ρ against the carried gravity
/// leaves on the tilt: ρ is the tilt's error plus the angle the vehicle's
/// acceleration turns the force by, and beyond the accelerometer's own
/// noise σ_a nothing tells the two apart, so the tilt may be off by all
/// of the rest: √max(0, ρ² − σ_a²), which two σ cover. σ_a is the σ
/// the engine gives the residual angle itself (its gate is 2σ_a), not a
/// per-axis σ.
pub fn unexplained_residual_sigma(residual_rad: f64, accel_sigma_rad: f64) -> f64 {
    0.5 * (residual_rad.powi(2) - accel_sigma_rad.powi(2))
        .max(0.0)
        .sqrt()
}

/// The angle's σ after a pull by the fraction `gain` towards the sensor, rad.
pub fn sigma_after_pull(sigma_rad: f64, reference_sigma_rad: f64, gain: f64) -> f64 {
    ((1.0 - gain).powi(2) * sigma_rad.powi(2) + gain.powi(2) * reference_sigma_rad.powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gate_widens_the_pull_speeds_up_and_the_sigma_shrinks() {
        // σ = 3, σ_ref = 4: 2·√(9 + 16) = 10 beats a gate of 8, not one of 12.
        assert_eq!(widened_gate(8.0, 3.0, 4.0), 10.0);
        assert_eq!(widened_gate(12.0, 3.0, 4.0), 12.0);
        // Surer than the sensor: no boost; twice as unsure: four times.
        assert_eq!(pull_boost(3.0, 4.0), 1.0);
        assert_eq!(pull_boost(8.0, 4.0), 4.0);
        // g = 0.5: √(0.25·9 + 0.25·16) = 2.5; g = 1 leaves the sensor's σ.
        assert_eq!(sigma_after_pull(3.0, 4.0, 0.5), 2.5);
        assert_eq!(sigma_after_pull(3.0, 4.0, 1.0), 4.0);
        assert_eq!(sigma_after_pull(3.0, 4.0, 0.0), 3.0);
    }

    #[test]
    fn a_moving_reference_is_as_unsure_as_the_acceleration_it_shows() {
        // Nothing shown: the base σ. 0.3 + 0.4 = 0.7 m/s² of 9.8: atan(1/14).
        assert_eq!(moving_reference_sigma(0.02, 0.0, 0.0, 9.8), 0.02);
        let shown = (1.0f64 / 14.0).atan();
        let sigma = moving_reference_sigma(0.02, -0.3, 0.4, 9.8);
        assert!((sigma - (0.0004 + shown * shown).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn a_residual_beyond_the_accelerometers_noise_may_all_be_tilt() {
        // ρ = 5, σ_a = 3: √(25 − 9) = 4, two σ of 2.
        assert_eq!(unexplained_residual_sigma(5.0, 3.0), 2.0);
        // Within the noise: nothing.
        assert_eq!(unexplained_residual_sigma(2.0, 3.0), 0.0);
        assert_eq!(unexplained_residual_sigma(3.0, 3.0), 0.0);
    }

    #[test]
    fn the_reported_sigma_adds_what_averaging_cannot_remove() {
        // √(0.3² + 0.4²) = 0.5; with 1.2 too: √(0.25 + 1.44) = 1.3.
        assert!((reported_sigma(0.3, &[0.4]) - 0.5).abs() < 1e-12);
        assert!((reported_sigma(0.3, &[0.4, 1.2]) - 1.3).abs() < 1e-12);
        // Never more than a uniform angle's: π/√3.
        assert!((UNKNOWN_ANGLE_SIGMA_RAD - std::f64::consts::PI / 3f64.sqrt()).abs() < 1e-15);
        assert_eq!(reported_sigma(10.0, &[]), UNKNOWN_ANGLE_SIGMA_RAD);
    }
}
