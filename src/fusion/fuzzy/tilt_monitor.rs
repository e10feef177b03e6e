//! The integrity monitor of the `fuzzy` engine's tilt: the accelerometer's
//! tilt at rest against the tilt the gyros carry (docs/engines/fuzzy.md,
//! "Integrity").
//!
//! At rest the mean specific force of a quiet window is gravity: its
//! direction in the body frame is the tilt, whatever the gyros say. The
//! test is run on every window the alignment would accept (quiet against
//! the learnt noise floors, plausible for a MEMS sensor at rest); the
//! motion expert is not asked, since a gyro whose bias jumped (a power
//! cycle) makes it call a standing vehicle moving. The residual is the
//! angle between the carried "down" and the window's mean force; the
//! gate is five σ of it: √(σ_tilt² + σ_window²), σ_tilt the tilt σ the
//! gyros carry (the reported σ without the residual's share, which at
//! rest is the very error under test), σ_window = spread/(g·√N), the
//! mean force's direction noise with each axis given the whole spread
//! (vibration makes samples correlated).
//!
//! A residual beyond the gate makes the estimate `lost` (`tilt_disagrees`)
//! at once; held for [`CONFIRM_S`] of quiet windows, the engine aligns
//! again from the window (re-levels, re-learns the bias) and reports
//! `degraded` (`recovering`) until quiet windows have agreed for
//! [`RECOVERED_S`].

use serde::{Deserialize, Serialize};

use super::super::geometry::V3;

/// How long quiet windows must disagree before the engine aligns again, s.
pub const CONFIRM_S: f64 = 1.0;
/// How long quiet windows must agree after a re-alignment before the
/// estimates are `ok` again, s.
pub const RECOVERED_S: f64 = 2.0;
/// The gate in σ.
pub const GATE_SIGMAS: f64 = 5.0;

/// What the monitor makes of one quiet window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// Within the gate.
    Agrees,
    /// Beyond the gate, not yet for [`CONFIRM_S`].
    Disagrees,
    /// Beyond the gate for [`CONFIRM_S`]: align again.
    Realign,
}

/// What the monitor is shown of a quiet window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuietWindow {
    /// The mean specific force, m/s².
    pub mean_force: V3,
    /// Its spread, m/s².
    pub spread_mps2: f64,
    /// Readings in it.
    pub samples: usize,
    /// Its mean rate departs from the bias the gyros run on
    /// ([`bias_departs`]).
    pub bias_departed: bool,
}

/// The monitor's state.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TiltMonitor {
    /// Since when quiet windows have disagreed beyond the gate.
    disagreeing_since: Option<f64>,
    /// After a re-alignment: since when quiet windows have agreed (`None`
    /// while none has yet).
    recovering: Option<Option<f64>>,
    /// Whether the newest estimate's tilt is known to disagree.
    disagrees: bool,
    /// The newest quiet window that agreed (or the re-alignment).
    last_agreed_t: Option<f64>,
    /// The attitude went unwatched (a frozen IMU) and no quiet window has
    /// agreed since.
    #[serde(default)]
    unwatched: bool,
    /// The newest disagreeing window's mean rate departed from the bias
    /// the gyros run on: what could have turned the tilt.
    #[serde(default)]
    bias_departed: bool,
    /// Re-alignments the monitor has asked for.
    pub realignments: u64,
}

impl TiltMonitor {
    /// Tests a quiet `window` at `t` against the carried `down` (unit,
    /// body frame) and the tilt σ the gyros carry (rad).
    pub fn test(
        &mut self,
        t: f64,
        down: &V3,
        window: &QuietWindow,
        tilt_sigma_rad: f64,
    ) -> Verdict {
        let QuietWindow {
            mean_force,
            spread_mps2,
            samples,
            bias_departed,
        } = *window;
        let norm = mean_force.norm();
        if norm <= 0.0 || samples == 0 {
            return Verdict::Agrees;
        }
        // The measured "down" is minus the specific force's direction.
        let measured = -mean_force / norm;
        let residual = down.cross(&measured).norm().atan2(down.dot(&measured));
        let window_sigma = spread_mps2 / (norm * (samples as f64).sqrt());
        let gate = GATE_SIGMAS * (tilt_sigma_rad.powi(2) + window_sigma.powi(2)).sqrt();
        if residual <= gate {
            self.disagreeing_since = None;
            self.disagrees = false;
            self.unwatched = false;
            self.last_agreed_t = Some(t);
            if let Some(agreeing) = &mut self.recovering {
                let since = *agreeing.get_or_insert(t);
                if t - since >= RECOVERED_S {
                    self.recovering = None;
                }
            }
            return Verdict::Agrees;
        }
        self.disagrees = true;
        self.bias_departed = bias_departed;
        if let Some(agreeing) = &mut self.recovering {
            *agreeing = None;
        }
        let since = *self.disagreeing_since.get_or_insert(t);
        if t - since >= CONFIRM_S {
            Verdict::Realign
        } else {
            Verdict::Disagrees
        }
    }

    /// Seconds since a quiet window last agreed; `None` if none has.
    pub fn since_agreed_s(&self, t: f64) -> Option<f64> {
        self.last_agreed_t.map(|agreed| t - agreed)
    }

    /// The engine aligned again on the monitor's word at `t`.
    pub fn realigned(&mut self, t: f64) {
        self.last_agreed_t = Some(t);
        self.disagreeing_since = None;
        self.disagrees = false;
        self.unwatched = false;
        self.recovering = Some(None);
        self.realignments += 1;
    }

    /// The attitude went unwatched (the IMU was frozen): not vouched for
    /// until a quiet window agrees, then recovering until quiet windows
    /// have agreed for [`RECOVERED_S`].
    pub fn unverified(&mut self) {
        self.recovering = Some(None);
        self.unwatched = true;
    }

    /// Whether the attitude went unwatched and no quiet window has agreed
    /// since.
    pub fn unwatched(&self) -> bool {
        self.unwatched
    }

    /// Whether the newest quiet window disagreed.
    pub fn disagrees(&self) -> bool {
        self.disagrees
    }

    /// Whether the engine is recovering from a re-alignment.
    pub fn recovering(&self) -> bool {
        self.recovering.is_some()
    }

    /// A window that is not quiet: the verdict of the last quiet one
    /// stands for the tilt it judged, but a disagreement that is not
    /// seen again is not confirmed across motion. One whose window showed
    /// the gyros' bias as it was is not held either: nothing turned the
    /// tilt, and a window quiet but not still (a creep speeding up) has
    /// a mean force that is not gravity's.
    pub fn moving(&mut self) {
        self.disagreeing_since = None;
        if self.disagrees && !self.bias_departed {
            self.disagrees = false;
        }
    }
}

/// Whether a window's mean rate departs from the bias the gyros run on
/// by more than [`GATE_SIGMAS`] on any axis (rad/s): the bias's variance
/// and the mean's own, `rate_spread`²/(3N), each axis's noise given a
/// third of the spread's square.
pub fn bias_departs(
    mean_rate: &V3,
    bias: &V3,
    bias_variance: &V3,
    rate_spread: f64,
    samples: usize,
) -> bool {
    let mean_variance = rate_spread * rate_spread / (3.0 * samples.max(1) as f64);
    (0..3).any(|k| {
        (mean_rate[k] - bias[k]).abs()
            > GATE_SIGMAS * (bias_variance[k].max(0.0) + mean_variance).sqrt()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const G: f64 = 9.80665;

    fn window(
        mean_force: V3,
        spread_mps2: f64,
        samples: usize,
        bias_departed: bool,
    ) -> QuietWindow {
        QuietWindow {
            mean_force,
            spread_mps2,
            samples,
            bias_departed,
        }
    }

    /// A force of gravity seen by a body tilted `angle_rad` about x.
    fn force(angle_rad: f64) -> V3 {
        V3::new(0.0, -G * angle_rad.sin(), -G * angle_rad.cos())
    }

    #[test]
    fn a_tilt_within_five_sigma_agrees_and_beyond_it_is_confirmed_after_a_second() {
        let down = V3::new(0.0, 0.0, 1.0);
        let mut m = TiltMonitor::default();
        // σ_tilt 0.1°, a noiseless window: the gate is 0.5°.
        let sigma = 0.1_f64.to_radians();
        assert_eq!(
            m.test(
                0.0,
                &down,
                &window(force(0.49_f64.to_radians()), 0.0, 13, true),
                sigma
            ),
            Verdict::Agrees
        );
        assert!(!m.disagrees());
        assert_eq!(
            m.test(
                1.0,
                &down,
                &window(force(0.51_f64.to_radians()), 0.0, 13, true),
                sigma
            ),
            Verdict::Disagrees
        );
        assert!(m.disagrees());
        assert_eq!(
            m.test(
                1.5,
                &down,
                &window(force(3.0_f64.to_radians()), 0.0, 13, true),
                sigma
            ),
            Verdict::Disagrees
        );
        assert_eq!(
            m.test(
                2.0,
                &down,
                &window(force(3.0_f64.to_radians()), 0.0, 13, true),
                sigma
            ),
            Verdict::Realign
        );
        assert_eq!(m.since_agreed_s(2.0), Some(2.0));
        m.realigned(2.0);
        assert!(m.recovering() && !m.disagrees());
        // Agreeing for two seconds ends the recovery.
        for i in 0..=20 {
            assert_eq!(
                m.test(
                    3.0 + 0.1 * i as f64,
                    &down,
                    &window(force(0.0), 0.0, 13, true),
                    sigma
                ),
                Verdict::Agrees
            );
        }
        assert!(!m.recovering());
        assert_eq!(m.realignments, 1);
    }

    #[test]
    fn the_window_noise_widens_the_gate() {
        let down = V3::new(0.0, 0.0, 1.0);
        let mut m = TiltMonitor::default();
        // Spread 0.5 m/s² over 16 samples: σ_window = 0.5/(g·4) = 0.7304°;
        // with σ_tilt 0 the gate is 3.652°.
        assert_eq!(
            m.test(
                0.0,
                &down,
                &window(force(3.6_f64.to_radians()), 0.5, 16, true),
                0.0
            ),
            Verdict::Agrees
        );
        assert_eq!(
            m.test(
                0.1,
                &down,
                &window(force(3.7_f64.to_radians()), 0.5, 16, true),
                0.0
            ),
            Verdict::Disagrees
        );
        // Motion in between: the disagreement starts again.
        m.moving();
        assert_eq!(
            m.test(
                5.0,
                &down,
                &window(force(3.7_f64.to_radians()), 0.5, 16, true),
                0.0
            ),
            Verdict::Disagrees
        );
    }

    #[test]
    fn a_disagreement_the_bias_cannot_explain_is_not_held_through_motion() {
        let down = V3::new(0.0, 0.0, 1.0);
        let sigma = 0.1_f64.to_radians();
        // The gyros' bias as it was: a creep's acceleration, let go.
        let mut m = TiltMonitor::default();
        m.test(
            0.0,
            &down,
            &window(force(1.0_f64.to_radians()), 0.0, 13, false),
            sigma,
        );
        assert!(m.disagrees());
        m.moving();
        assert!(!m.disagrees());
        // A bias that moved (a power cycle): held until a quiet window.
        let mut m = TiltMonitor::default();
        m.test(
            0.0,
            &down,
            &window(force(1.0_f64.to_radians()), 0.0, 13, true),
            sigma,
        );
        m.moving();
        assert!(m.disagrees());
    }

    #[test]
    fn the_bias_departs_beyond_five_sigma_of_its_own_and_the_means() {
        // Spread 0.3 rad/s over 100 samples: the mean's variance
        // 0.09/300 = 3e-4; with the bias's 1e-4, 5σ = 5·0.02 = 0.1 rad/s.
        let bias = V3::new(0.01, 0.0, 0.0);
        let variance = V3::repeat(1e-4);
        let within = V3::new(0.109, -0.09, 0.0);
        let beyond = V3::new(0.0, 0.0, 0.101);
        assert!(!bias_departs(&within, &bias, &variance, 0.3, 100));
        assert!(bias_departs(&beyond, &bias, &variance, 0.3, 100));
    }
}
