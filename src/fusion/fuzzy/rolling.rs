//! Motion from events: a vehicle that started rolling is rolling until it
//! has stopped (issue 55).
//!
//! The motion expert (motion.rs) judges each half-second window by its
//! vibration and turning against the noise floors. A vehicle rolling
//! smoothly, or creeping at the end of a long coast, can look as quiet as
//! one at rest; and floors learnt while it rolls rise towards its
//! vibration until rolling looks like rest. So the expert's verdict is
//! latched by events:
//!
//! The static degree this latch takes is the expert's verdict on the
//! shaking alone (the spreads and the norm, not the mean rate's distance
//! from the bias): a gyro whose bias stepped looks turning, and a latch on
//! that would keep a standing vehicle from ever resting to learn it.
//!
//! 1. **Start.** The expert says `moving` (static degree below the
//!    threshold) for `start_s` without a break: the vehicle is rolling. A
//!    shorter burst (a door, a knock) is only what the expert says.
//! 2. **Rolling.** While rolling the motion is `moving` whatever the
//!    expert says, nothing is learnt as at rest (the static degree the
//!    engine uses is 0), and the noise floors are not learnt
//!    (noise_floor.rs): floors come from confirmed rest only.
//! 3. **Stop.** Rolling ends when either
//!    - (a) the expert has been sure of rest (static degree ≥
//!      [`QUIET_DEGREE`]: every input `low`) since t_q and a deceleration
//!      brought it there, or
//!    - (b) the expert has been *calm* (no input fully `high`: static
//!      degree above 0) for `settle_s`: a coast's end decelerates too
//!      gently to tell (0.01–0.05 m/s²: the tilt's own error), and a
//!      vehicle that drifts to a stop is at rest once it has been calm
//!      that long. A roll that ends so while the expert still says
//!      `moving` ended at a rest louder than the one the floors were
//!      learnt at: the engine takes the quietest spreads of the calm as
//!      its floors ([`RollingWatch::ended_louder_than_floors`]), or a
//!      standing vehicle that sways more than it idled would look like
//!      motion for good (floors are not learnt while rolling, beyond a
//!      slow rise: noise_floor.rs).
//!
//! **The deceleration** is read from h, the horizontal specific force
//! (tilt.rs: the window's mean C·f) turned by the heading into the
//! vehicle's level frame, so it is the same for the same push whichever
//! way the vehicle points, and a turn does not move it. (The body frame
//! would spare the filter's own tilt corrections, but a hand-held sensor
//! tilted by tens of degrees reads gravity's share as a push.) A vehicle's
//! speed changes along its own axis (ahead or astern). The **start's
//! direction** u is that of the speed the roll first gained,
//! s = ∫ (h − h₀) dτ from [`START_LEAD_S`] before the first `moving`
//! reading on (h₀ the force then: at rest, before a smooth start shows),
//! once ‖s‖ ≥ `speed_mps` within [`START_SEARCH_S`]:
//!
//! ```text
//! u = s / ‖s‖                                                    (1)
//! ```
//!
//! The **speed lost** before the quiet, against h̄_q, the mean force
//! since the quiet began (at rest it is the tilt's error, so that error
//! cancels; a standing vehicle sways, so not the newest force alone), is
//! the most any stretch [τ₀, t] from t_q − [`BRAKE_LOOKBACK_S`] on took
//! off along u:
//!
//! ```text
//! Δ = max over τ₀ of −u · ∫_{τ₀}^{t} (h(τ) − h̄_q) dτ              (2)
//! ```
//!
//! (a) holds when Δ ≥ `speed_mps`. The end of the start's acceleration
//! gains speed along u and does not count; a braking loses it. A roll
//! that gained no clear speed (no u: a smooth start) counts a change of
//! either sign, ‖∫‖ ≥ `speed_mps`.
//!
//! The horizontal force is sampled every [`SAMPLE_EVERY_S`] (a braking
//! lasts seconds) and kept for [`BRAKE_LOOKBACK_S`] plus the quiet.
//! Before the engine has an attitude there is no h: only (b) stops.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// How far back before the quiet began a deceleration counts, s: a
/// braking ends as the vehicle stops, and the expert's window (half a
/// second) and the tilt window's lag (tilt.rs) delay the quiet by about
/// a second after it; a coast's last metres per second take longer.
pub const BRAKE_LOOKBACK_S: f64 = 10.0;
/// The static degree a rolling vehicle must reach to count as quiet:
/// every input of the expert `low` (motion.rs), not merely over the
/// threshold (what the expert is unsure of is still rolling).
pub const QUIET_DEGREE: f64 = 0.99;
/// How long before the expert's first `moving` the start's h₀ is taken,
/// s: the expert's window and the tilt window's lag (half a window each)
/// see a smooth start late, with the force already the acceleration's.
pub const START_LEAD_S: f64 = 1.0;
/// How long after the first `moving` reading the start's direction is
/// looked for, s: a start gains its 0.25 m/s within seconds.
pub const START_SEARCH_S: f64 = 10.0;
/// Spacing of the kept horizontal forces, s.
pub const SAMPLE_EVERY_S: f64 = 0.1;
/// Longest spacing integrated, s: a gap is not time at that force.
const MAX_STEP_S: f64 = 1.0;

/// The rule's parameters (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RollingConfig {
    /// The static degree below which the expert says `moving`.
    pub static_threshold: f64,
    /// `moving` without a break for this long starts rolling, s.
    pub start_s: f64,
    /// Speed the start must gain to give its direction (1), and a
    /// deceleration must take off (2), m/s.
    pub speed_mps: f64,
    /// Calm this long stops rolling without a deceleration, s.
    pub settle_s: f64,
}

/// The latch of the module documentation.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RollingWatch {
    rolling: bool,
    /// Since when the expert has said `moving` without a break.
    moving_since: Option<f64>,
    /// Since when the expert has been sure of rest without a break.
    quiet_since: Option<f64>,
    /// Since when no input of the expert has been fully `high`.
    #[serde(default)]
    calm_since: Option<f64>,
    /// When the start of (1) was first seen.
    #[serde(default)]
    start_t: Option<f64>,
    /// The roll ended by (b) at this reading with the expert unsure.
    #[serde(default)]
    ended_louder: bool,
    /// (t, horizontal specific force in the level frame turned with the
    /// vehicle, m/s²), oldest first.
    forces: VecDeque<(f64, [f64; 2])>,
    /// h₀ of (1): the force at rest before the first `moving` reading.
    start_base: Option<[f64; 2]>,
    /// s of (1) so far, m/s.
    start_gain: [f64; 2],
    /// u of (1), once the start has gained `speed_mps`.
    start_direction: Option<[f64; 2]>,
}

impl RollingWatch {
    /// True while the vehicle is rolling (step 2).
    pub fn is_rolling(&self) -> bool {
        self.rolling
    }

    /// Takes one reading's static degree from the expert and, when a
    /// sample is due ([`RollingWatch::sample_due`]) and the engine has an
    /// attitude, the horizontal specific force in the vehicle's level
    /// frame, m/s². Returns whether the vehicle is rolling after it.
    pub fn step(
        &mut self,
        config: &RollingConfig,
        t: f64,
        static_degree: f64,
        horizontal_mps2: Option<[f64; 2]>,
    ) -> bool {
        let moving = static_degree < config.static_threshold;
        if moving && self.moving_since.is_none() {
            self.moving_since = Some(t);
            if !self.rolling {
                self.start_from(t);
            }
        }
        if let Some(h) = horizontal_mps2 {
            self.keep(t, h, config.speed_mps);
        }
        if moving {
            if self
                .moving_since
                .is_some_and(|since| t - since >= config.start_s)
            {
                self.rolling = true;
            }
        } else {
            self.moving_since = None;
            if !self.rolling {
                self.start_base = None;
            }
        }
        // Calm: no input of the expert fully `high` (static degree above 0).
        let calm_since = if static_degree <= 0.0 {
            self.calm_since = None;
            None
        } else {
            Some(*self.calm_since.get_or_insert(t))
        };
        // A deceleration counts once the expert is sure of the quiet.
        let quiet = if self.rolling {
            static_degree >= QUIET_DEGREE
        } else {
            !moving
        };
        if !quiet {
            self.quiet_since = None;
        } else {
            self.quiet_since.get_or_insert(t);
        }
        let settled = calm_since.is_some_and(|since| t - since >= config.settle_s);
        let stopped = self.rolling
            && (settled
                || self
                    .quiet_since
                    .is_some_and(|since| self.speed_lost(since) >= config.speed_mps));
        self.ended_louder = stopped && settled && moving;
        if stopped {
            // A roll that starts again counts its own time, from its own
            // start.
            self.calm_since = None;
            self.rolling = false;
            self.moving_since = moving.then_some(t);
            if moving {
                self.start_from(t);
            } else {
                self.start_base = None;
                self.start_direction = None;
            }
        }
        self.rolling
    }

    /// True at the reading a roll ended by (b) while the expert still
    /// said `moving` (no input fully `high`, the degree below the
    /// threshold): a rest louder than the one the floors were learnt at,
    /// whose quietest spreads the engine then takes as its floors (floors
    /// are not learnt while rolling, so without this such a rest would
    /// look like motion for good).
    pub fn ended_louder_than_floors(&self) -> bool {
        self.ended_louder
    }

    /// True when a reading at `t` would be kept: the engine turns the
    /// force into the vehicle's frame only for those.
    pub fn sample_due(&self, t: f64) -> bool {
        self.forces
            .back()
            .is_none_or(|(last, _)| t - last >= SAMPLE_EVERY_S)
    }

    /// A gap in the readings: the kept forces no longer follow on. The
    /// verdict stays: a vehicle rolling before the gap is rolling until
    /// it is seen to stop.
    pub fn interrupted(&mut self) {
        self.forces.clear();
        self.moving_since = None;
        self.quiet_since = None;
        self.calm_since = None;
        self.start_base = None;
    }

    /// Equation (1)'s h₀ and the speed gained since it, for a start
    /// first seen at `t`: the force [`START_LEAD_S`] before (the expert
    /// and the tilt window see a smooth start late; the force then was
    /// the rest's), and the samples after it integrated.
    fn start_from(&mut self, t: f64) {
        self.start_gain = [0.0, 0.0];
        self.start_direction = None;
        self.start_t = Some(t);
        let lead_t = t - START_LEAD_S;
        let Some(base_index) = self
            .forces
            .iter()
            .rposition(|(ti, _)| *ti <= lead_t)
            .or((!self.forces.is_empty()).then_some(0))
        else {
            self.start_base = None;
            return;
        };
        let (mut previous_t, base) = self.forces[base_index];
        self.start_base = Some(base);
        for &(ti, h) in self.forces.iter().skip(base_index + 1) {
            let dt_s = (ti - previous_t).min(MAX_STEP_S);
            previous_t = ti;
            self.start_gain[0] += (h[0] - base[0]) * dt_s;
            self.start_gain[1] += (h[1] - base[1]) * dt_s;
        }
    }

    /// Keeps the force if a sample is due.
    fn keep(&mut self, t: f64, h: [f64; 2], speed_mps: f64) {
        let last_t = self.forces.back().map(|(ti, _)| *ti);
        if last_t.is_some_and(|last| t - last < SAMPLE_EVERY_S) {
            return;
        }
        self.forces.push_back((t, h));
        // Equation (1): the speed the start gains, until it is clear.
        // Only over the start's first seconds: later, a turn's or the
        // tilt's drift would set a direction no braking follows.
        let searching = self
            .start_t
            .is_some_and(|start| t - start <= START_SEARCH_S);
        if self.start_direction.is_none()
            && searching
            && let Some(base) = self.start_base
        {
            let dt_s = last_t.map_or(0.0, |last| (t - last).min(MAX_STEP_S));
            self.start_gain[0] += (h[0] - base[0]) * dt_s;
            self.start_gain[1] += (h[1] - base[1]) * dt_s;
            let gained = self.start_gain[0].hypot(self.start_gain[1]);
            if gained >= speed_mps {
                self.start_direction =
                    Some([self.start_gain[0] / gained, self.start_gain[1] / gained]);
            }
        }
        // While rolling, the look-back before the quiet; at rest, the
        // newest seconds only (a long rest keeps no more).
        let quiet_since = self.quiet_since.filter(|_| self.rolling);
        let keep_from = quiet_since.unwrap_or(t) - BRAKE_LOOKBACK_S;
        while self.forces.front().is_some_and(|(ti, _)| *ti < keep_from) {
            self.forces.pop_front();
        }
    }

    /// Equation (2): the most speed any stretch ending now, from
    /// `quiet_since − BRAKE_LOOKBACK_S` on, took off along the start's
    /// direction (without one: changed in any direction), against the
    /// mean force since the quiet began (a standing vehicle sways), m/s.
    fn speed_lost(&self, quiet_since: f64) -> f64 {
        let Some(now) = self.mean_force_from(quiet_since) else {
            return 0.0;
        };
        let from = quiet_since - BRAKE_LOOKBACK_S;
        let mut change = [0.0, 0.0];
        let mut most = 0.0_f64;
        self.integrate_back(from, now, |step| {
            change[0] += step[0];
            change[1] += step[1];
            let lost = match self.start_direction {
                Some(u) => -(u[0] * change[0] + u[1] * change[1]),
                None => change[0].hypot(change[1]),
            };
            most = most.max(lost);
        });
        most
    }

    /// The mean kept force from `since` on, if any was kept.
    fn mean_force_from(&self, since: f64) -> Option<[f64; 2]> {
        let (sum, n) = self
            .forces
            .iter()
            .rev()
            .take_while(|(ti, _)| *ti >= since)
            .fold(([0.0, 0.0], 0_u32), |(sum, n), (_, h)| {
                ([sum[0] + h[0], sum[1] + h[1]], n + 1)
            });
        (n > 0).then(|| [sum[0] / f64::from(n), sum[1] / f64::from(n)])
    }

    /// Walks the kept forces from the newest back to `from`, handing each
    /// interval's (h − `reference`)·dt, m/s.
    fn integrate_back(&self, from: f64, reference: [f64; 2], mut each: impl FnMut([f64; 2])) {
        let mut later_t: Option<f64> = None;
        for &(ti, h) in self.forces.iter().rev() {
            if ti < from {
                break;
            }
            if let Some(later) = later_t {
                let dt_s = (later - ti).min(MAX_STEP_S);
                each([(h[0] - reference[0]) * dt_s, (h[1] - reference[1]) * dt_s]);
            }
            later_t = Some(ti);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONFIG: RollingConfig = RollingConfig {
        static_threshold: 0.55,
        start_s: 1.0,
        speed_mps: 0.25,
        settle_s: 10.0,
    };

    /// Steps at 100 Hz over [from_s, to_s) with a fixed verdict and force.
    fn run(
        watch: &mut RollingWatch,
        (from_s, to_s): (f64, f64),
        moving: bool,
        h: Option<[f64; 2]>,
    ) -> bool {
        let degree = if moving { 0.0 } else { 1.0 };
        let mut rolling = watch.is_rolling();
        let mut i = 0;
        loop {
            let t = from_s + 0.01 * f64::from(i);
            if t >= to_s - 1e-9 {
                return rolling;
            }
            rolling = watch.step(&CONFIG, t, degree, h);
            i += 1;
        }
    }

    #[test]
    fn a_short_burst_does_not_start_rolling() {
        let mut watch = RollingWatch::default();
        assert!(!run(&mut watch, (0.0, 0.9), true, Some([0.0, 0.0])));
        assert!(!run(&mut watch, (0.9, 2.0), false, Some([0.0, 0.0])));
        assert!(run(&mut watch, (2.0, 3.1), true, Some([0.0, 0.0])));
    }

    #[test]
    fn a_braking_before_the_quiet_stops_at_once_the_end_of_the_start_does_not() {
        let mut watch = RollingWatch::default();
        // The tilt's error: 0.1 m/s² sideways throughout.
        run(&mut watch, (0.0, 5.0), false, Some([0.0, 0.1]));
        // 2 s at 1 m/s² ahead: u = (1, 0) once 0.25 m/s is gained.
        run(&mut watch, (5.0, 7.0), true, Some([1.0, 0.1]));
        assert_eq!(watch.start_direction, Some([1.0, 0.0]));
        assert!(run(&mut watch, (7.0, 9.0), false, Some([0.0, 0.1])));
        run(&mut watch, (9.0, 20.0), true, Some([0.0, 0.1]));
        // Braking at 0.5 m/s² for 3 s (1.5 m/s lost), then quiet: stopped
        // at the first force kept from the quiet.
        run(&mut watch, (20.0, 23.0), true, Some([-0.5, 0.1]));
        assert!(watch.is_rolling());
        assert!(!run(&mut watch, (23.0, 23.2), false, Some([0.0, 0.1])));
    }

    #[test]
    fn a_start_the_expert_sees_late_takes_its_direction_from_before_it() {
        let mut watch = RollingWatch::default();
        run(&mut watch, (0.0, 5.0), false, Some([0.0, 0.0]));
        // Accelerating at 0.5 m/s² ahead from 5 s; the expert sees it at
        // 5.8 s. h₀ is the force at 4.8 s (at rest), not the
        // acceleration's, so the start gains speed ahead.
        run(&mut watch, (5.0, 5.8), false, Some([0.5, 0.0]));
        run(&mut watch, (5.8, 7.0), true, Some([0.5, 0.0]));
        assert_eq!(watch.start_base, Some([0.0, 0.0]));
        assert_eq!(watch.start_direction, Some([1.0, 0.0]));
    }

    /// (b) with the expert unsure: a rest louder than the floors (the
    /// expert's degree 0.3: some input `medium`, none `high`) ends the
    /// roll after `settle_s`, and says so once; a fully `high` input
    /// (degree 0) is no calm.
    #[test]
    fn a_rest_louder_than_the_floors_ends_the_roll_and_says_so() {
        let mut watch = RollingWatch::default();
        run(&mut watch, (0.0, 5.0), true, Some([0.0, 0.0]));
        let step = |watch: &mut RollingWatch, t: f64, degree: f64| {
            let rolling = watch.step(&CONFIG, t, degree, Some([0.0, 0.0]));
            (rolling, watch.ended_louder_than_floors())
        };
        let mut ended = Vec::new();
        for i in 0..1200 {
            let t = 5.0 + f64::from(i) * 0.01;
            let (rolling, louder) = step(&mut watch, t, 0.3);
            if louder {
                ended.push(t);
            }
            // The expert, unsure, says `moving`: rolling again 1 s after
            // (the engine's floors, raised, end that).
            let expected = !(15.0 - 1e-9..16.0 - 1e-9).contains(&t);
            assert_eq!(rolling, expected, "{t}");
        }
        assert_eq!(ended.len(), 1);
        assert!((ended[0] - 15.0).abs() < 0.011, "{ended:?}");
        // Shaking hard (degree 0) restarts the roll after start_s; calm
        // is not counted through it.
        let mut watch = RollingWatch::default();
        for i in 0..3000 {
            let t = f64::from(i) * 0.01;
            let degree = if i % 500 < 100 { 0.0 } else { 0.3 };
            let (rolling, _) = step(&mut watch, t, degree);
            assert!(rolling || t < 1.0, "{t}");
        }
    }

    #[test]
    fn the_speed_lost_is_the_most_any_stretch_ending_now_took_off() {
        let mut watch = RollingWatch {
            start_direction: Some([0.0, 1.0]),
            ..RollingWatch::default()
        };
        // 0.1 s apart: +1 m/s² for 0.3 s, −2 m/s² for 0.2 s, now 0.
        for (i, h) in [0.0, 1.0, 1.0, 1.0, -2.0, -2.0, 0.0].iter().enumerate() {
            watch
                .forces
                .push_back((f64::from(i as u32) * 0.1, [0.0, *h]));
        }
        // Stretches back from now: −2·0.1 = −0.2, then −0.4 (most lost:
        // 0.4), then −0.3, −0.2, −0.1, −0.1.
        assert!((watch.speed_lost(0.6) - 0.4).abs() < 1e-12);
        // Without a direction: the largest change either way, 0.4.
        watch.start_direction = None;
        assert!((watch.speed_lost(0.6) - 0.4).abs() < 1e-12);
    }

    #[test]
    fn a_quiet_without_a_deceleration_stops_after_the_settling_time() {
        let mut watch = RollingWatch::default();
        // A constant horizontal force: the tilt's error, not a braking.
        run(&mut watch, (0.0, 30.0), true, Some([0.15, 0.0]));
        assert!(run(&mut watch, (30.0, 39.9), false, Some([0.15, 0.0])));
        assert!(!run(&mut watch, (39.9, 40.1), false, Some([0.15, 0.0])));
        // Without an attitude, the same.
        let mut watch = RollingWatch::default();
        run(&mut watch, (0.0, 30.0), true, None);
        assert!(run(&mut watch, (30.0, 39.9), false, None));
        assert!(!run(&mut watch, (39.9, 40.1), false, None));
    }

    #[test]
    fn a_braking_long_before_the_quiet_does_not_count() {
        let mut watch = RollingWatch::default();
        run(&mut watch, (0.0, 10.0), true, Some([0.0, -0.8]));
        run(&mut watch, (10.0, 22.0), true, Some([0.0, 0.0]));
        // 12 s of steady force before the quiet: more than the look-back.
        assert!(run(&mut watch, (22.0, 27.0), false, Some([0.0, 0.0])));
        // Moving again restarts the quiet.
        assert!(run(&mut watch, (27.0, 28.0), true, Some([0.0, 0.0])));
        assert!(run(&mut watch, (28.0, 37.9), false, Some([0.0, 0.0])));
        assert!(!run(&mut watch, (37.9, 38.1), false, Some([0.0, 0.0])));
    }
}
