//! The noise processes the simulators share.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// An Ornstein–Uhlenbeck process (exponentially correlated noise of
/// stationary standard deviation σ and time constant τ), stepped exactly
/// over any interval: x ← a·x + σ·√(1 − a²)·n, a = e^(−Δt/τ), n ~ N(0, 1).
#[derive(Debug, Clone, Copy)]
pub(super) struct Ou {
    pub x: f64,
    pub tau_s: f64,
}

impl Ou {
    /// Moves the process on by `dt_s` with stationary deviation `sigma`.
    pub fn step(&mut self, dt_s: f64, sigma: f64, rng: &mut ChaCha8Rng) {
        let a = (-dt_s / self.tau_s).exp();
        let n: f64 = rng.sample(StandardNormal);
        self.x = self.x * a + sigma * (1.0 - a * a).sqrt() * n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_step_is_exact_and_keeps_the_stationary_deviation() {
        // With n fixed by the seed, one step of Δt = τ·ln 2 (a = 1/2) from
        // x = 1 with σ = 2 lands on 0.5 + 2·√0.75·n.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n: f64 = ChaCha8Rng::seed_from_u64(7).sample(StandardNormal);
        let mut ou = Ou {
            x: 1.0,
            tau_s: 10.0,
        };
        ou.step(10.0 * std::f64::consts::LN_2, 2.0, &mut rng);
        assert!((ou.x - (0.5 + 2.0 * 0.75_f64.sqrt() * n)).abs() < 1e-12);
        // Over many steps of any size the spread is σ.
        let mut ou = Ou { x: 0.0, tau_s: 5.0 };
        let (mut sum_sq, steps) = (0.0, 200_000);
        for i in 0..steps {
            ou.step(0.5 + f64::from(i % 7), 3.0, &mut rng);
            sum_sq += ou.x * ou.x;
        }
        let sd = (sum_sq / f64::from(steps)).sqrt();
        assert!((sd - 3.0).abs() < 0.05, "{sd}");
    }
}
