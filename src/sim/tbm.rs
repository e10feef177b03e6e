//! A simulated TBM drive with known truth, for `simulate tbm`, `eval
//! attitude`, the accuracy tests and the benchmarks.
//!
//! The machine alternates excavation strokes (50–70 min, one 1.5 m ring)
//! with ring building (20–35 min, standing still). While excavating it
//! follows a vertical alignment (pitch changes with chainage), the driver's
//! steering adds a slow deviation, thrust changes rock the shield by a few
//! hundredths of a degree over a minute or two, and the cutterhead torque
//! rolls the machine at 1–2.5 °/h until the driver reverses the cutterhead
//! (roll stays within about −1°…3°). The shield warms while cutting.
//!
//! Sensors:
//! - inclinometer: reads the true pitch minus an error that is a smooth
//!   nonlinear function of roll ([`incl_pitch_error_deg`]: mounting offset,
//!   cross-axis coupling, curvature, ripple) plus 0.002 °/°C × (T − 20 °C);
//!   roll offset 0.12°; vibration noise 0.005° white + 0.002° coloured
//!   (τ 4 s) while cutting, 0.001° standing;
//! - laser: pitch and roll to 0.002°, yaw to 0.005°, timestamps jittered by
//!   ±0.5 s, 2 % of samples lost at random, nothing during the dropouts asked for.
//!
//! Truth, inclinometer noise and the laser draw from separate random
//! streams, so asking for a dropout changes nothing else.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::noise::Ou;
use crate::fusion::{Reading, SensorData};

/// 2026-03-02T06:00:00Z: the default start of a simulated drive.
pub const DEFAULT_START_T: f64 = 1_772_431_200.0;

/// A laser outage: from `start_h` hours into the drive, for `minutes`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Dropout {
    pub start_h: f64,
    pub minutes: f64,
}

impl std::str::FromStr for Dropout {
    type Err = String;

    /// Parses `START_H:MINUTES`, e.g. `2.5:45`.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let (start, minutes) = text
            .split_once(':')
            .ok_or_else(|| format!("dropout `{text}`: expected START_H:MINUTES, e.g. 2.5:45"))?;
        let start_h: f64 = start
            .trim()
            .parse()
            .map_err(|_| format!("dropout `{text}`: start `{start}` is not a number of hours"))?;
        let minutes: f64 = minutes
            .trim()
            .parse()
            .map_err(|_| format!("dropout `{text}`: `{minutes}` is not a number of minutes"))?;
        if !(start_h.is_finite() && start_h >= 0.0 && minutes.is_finite() && minutes > 0.0) {
            return Err(format!(
                "dropout `{text}`: start must be ≥ 0 h and length > 0 min"
            ));
        }
        Ok(Dropout { start_h, minutes })
    }
}

/// What to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TbmScenario {
    pub seed: u64,
    /// Unix seconds of the first reading.
    pub start_t: f64,
    pub hours: f64,
    pub incl_period_s: f64,
    pub laser_period_s: f64,
    pub dropouts: Vec<Dropout>,
}

impl Default for TbmScenario {
    fn default() -> Self {
        TbmScenario {
            seed: 1,
            start_t: DEFAULT_START_T,
            hours: 6.0,
            incl_period_s: 1.0,
            laser_period_s: 120.0,
            dropouts: Vec::new(),
        }
    }
}

impl TbmScenario {
    /// Checks the scenario can be simulated.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.hours.is_finite() && self.hours > 0.0) {
            return Err("hours must be > 0".into());
        }
        if !(self.incl_period_s.is_finite() && self.incl_period_s >= 0.01) {
            return Err("inclinometer period must be ≥ 0.01 s".into());
        }
        if !(self.laser_period_s.is_finite() && self.laser_period_s >= 1.0) {
            return Err("laser period must be ≥ 1 s (timestamps are jittered by ±0.5 s)".into());
        }
        Ok(())
    }

    /// True if the laser is out at `t`.
    pub fn in_dropout(&self, t: f64) -> bool {
        self.dropouts.iter().any(|d| {
            let start = self.start_t + d.start_h * 3600.0;
            t >= start && t < start + d.minutes * 60.0
        })
    }

    /// Time the drive ends.
    pub fn end_t(&self) -> f64 {
        self.start_t + self.hours * 3600.0
    }
}

/// What the machine is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    Excavating,
    RingBuilding,
}

/// The true state of the machine at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TbmTruth {
    pub t: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    pub yaw_deg: f64,
    pub phase: Phase,
    pub temp_c: f64,
    pub chainage_m: f64,
    /// What must be added to the inclinometer pitch to get the true pitch
    /// (noise aside): the error the ANFIS should learn.
    pub incl_pitch_error_deg: f64,
}

/// One simulated reading and the truth at its time.
#[derive(Debug, Clone, PartialEq)]
pub struct TbmEvent {
    pub truth: TbmTruth,
    pub reading: Reading,
}

/// The inclinometer's noise-free pitch error at roll β and temperature T:
/// true pitch − inclinometer pitch.
pub fn incl_pitch_error_deg(roll_deg: f64, temp_c: f64) -> f64 {
    // Mounting offset, cross-axis coupling (linear in roll), a curvature
    // from the sensor and the shield deforming under cutterhead torque (which
    // is what rolls the machine), and a small structural ripple.
    0.30 + 0.05 * roll_deg - 0.008 * roll_deg * roll_deg
        + 0.008 * (1.7 * roll_deg).sin()
        + 0.002 * (temp_c - 20.0)
}

/// Inclinometer roll offset (reads this much low).
const INCL_ROLL_OFFSET_DEG: f64 = 0.12;
const RING_LENGTH_M: f64 = 1.5;

/// The machine's true motion.
#[derive(Debug, Clone)]
struct Machine {
    rng: ChaCha8Rng,
    t: f64,
    phase: Phase,
    phase_end_t: f64,
    speed_mps: f64,
    chainage_m: f64,
    design_grade_deg: f64,
    design_phase: f64,
    steering: Ou,
    rocking: Ou,
    roll_deg: f64,
    roll_rate_dps: f64,
    roll_wobble: Ou,
    yaw: Ou,
    heat_c: f64,
    day_phase: f64,
}

impl Machine {
    fn new(seed: u64, start_t: f64) -> Machine {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(0);
        let mut m = Machine {
            t: start_t,
            phase: Phase::RingBuilding,
            phase_end_t: start_t,
            speed_mps: 0.0,
            chainage_m: 0.0,
            design_grade_deg: rng.random_range(-0.5..0.5),
            design_phase: rng.random_range(0.0..std::f64::consts::TAU),
            steering: Ou {
                x: 0.0,
                tau_s: 600.0,
            },
            rocking: Ou {
                x: 0.0,
                tau_s: 120.0,
            },
            roll_deg: rng.random_range(0.0..1.5),
            roll_rate_dps: 0.0,
            roll_wobble: Ou {
                x: 0.0,
                tau_s: 60.0,
            },
            yaw: Ou {
                x: 0.0,
                tau_s: 1800.0,
            },
            heat_c: 0.0,
            day_phase: rng.random_range(0.0..std::f64::consts::TAU),
            rng,
        };
        m.next_phase();
        m
    }

    fn next_phase(&mut self) {
        let start = self.phase_end_t;
        match self.phase {
            Phase::RingBuilding => {
                self.phase = Phase::Excavating;
                let minutes: f64 = self.rng.random_range(50.0..70.0);
                self.phase_end_t = start + minutes * 60.0;
                self.speed_mps = RING_LENGTH_M / (minutes * 60.0);
                let rate_dph: f64 = self.rng.random_range(1.0..2.5);
                // The driver reverses the cutterhead now and then, and always
                // when the roll nears its limits.
                let mut direction = self.roll_rate_dps.signum();
                if direction == 0.0 || self.rng.random_bool(0.3) {
                    direction = if self.rng.random_bool(0.5) { 1.0 } else { -1.0 };
                }
                self.roll_rate_dps = direction * rate_dph / 3600.0;
            }
            Phase::Excavating => {
                self.phase = Phase::RingBuilding;
                let minutes: f64 = self.rng.random_range(20.0..35.0);
                self.phase_end_t = start + minutes * 60.0;
            }
        }
    }

    fn advance_to(&mut self, t: f64) {
        while self.t < t {
            let seg_end = t.min(self.phase_end_t);
            let dt = seg_end - self.t;
            if dt > 0.0 {
                self.advance(dt);
            }
            self.t = seg_end;
            if seg_end >= self.phase_end_t {
                self.next_phase();
            }
        }
    }

    fn advance(&mut self, dt: f64) {
        let cutting = self.phase == Phase::Excavating;
        if cutting {
            self.chainage_m += self.speed_mps * dt;
            // Steering deviation evolves with the machine's advance.
            self.steering.step(dt, 0.05, &mut self.rng);
            if self.roll_deg > 2.5 {
                self.roll_rate_dps = -self.roll_rate_dps.abs();
            } else if self.roll_deg < -1.0 {
                self.roll_rate_dps = self.roll_rate_dps.abs();
            }
            self.roll_deg += self.roll_rate_dps * dt;
            self.heat_c += (2.5 - self.heat_c) * (1.0 - (-dt / 2400.0).exp());
        } else {
            self.heat_c *= (-dt / 3600.0).exp();
        }
        let (rock, wobble) = if cutting {
            (0.015, 0.01)
        } else {
            (0.001, 0.001)
        };
        self.rocking.step(dt, rock, &mut self.rng);
        self.roll_wobble.step(dt, wobble, &mut self.rng);
        self.yaw.step(dt, 0.05, &mut self.rng);
    }

    fn truth(&self, start_t: f64) -> TbmTruth {
        let s = self.chainage_m;
        let design = self.design_grade_deg
            + 0.35 * (std::f64::consts::TAU * s / 45.0 + self.design_phase).sin();
        let roll = self.roll_deg + self.roll_wobble.x;
        let temp_c = 19.0
            + 1.0 * (std::f64::consts::TAU * (self.t - start_t) / 86_400.0 + self.day_phase).sin()
            + self.heat_c;
        TbmTruth {
            t: self.t,
            pitch_deg: design + self.steering.x + self.rocking.x,
            roll_deg: roll,
            yaw_deg: 37.5 + self.yaw.x,
            phase: self.phase,
            temp_c,
            chainage_m: s,
            incl_pitch_error_deg: incl_pitch_error_deg(roll, temp_c),
        }
    }
}

/// The simulated drive: an iterator of readings in time order, each with
/// the truth at its time. Memory stays constant however long the drive.
#[derive(Debug, Clone)]
pub struct TbmDrive {
    scenario: TbmScenario,
    machine: Machine,
    incl_rng: ChaCha8Rng,
    laser_rng: ChaCha8Rng,
    vibration: Ou,
    next_incl: u64,
    next_laser: u64,
    next_laser_t: f64,
    last_incl_t: f64,
}

impl TbmDrive {
    /// Starts a drive; the scenario must be valid.
    pub fn new(scenario: TbmScenario) -> Result<TbmDrive, String> {
        scenario.validate()?;
        let mut incl_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        incl_rng.set_stream(1);
        let mut laser_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        laser_rng.set_stream(2);
        let mut drive = TbmDrive {
            machine: Machine::new(scenario.seed, scenario.start_t),
            incl_rng,
            laser_rng,
            vibration: Ou { x: 0.0, tau_s: 4.0 },
            next_incl: 0,
            next_laser: 0,
            next_laser_t: 0.0,
            last_incl_t: scenario.start_t,
            scenario,
        };
        drive.next_laser_t = drive.laser_time(0);
        Ok(drive)
    }

    /// The scenario being simulated.
    pub fn scenario(&self) -> &TbmScenario {
        &self.scenario
    }

    fn laser_time(&mut self, j: u64) -> f64 {
        let jitter: f64 = self.laser_rng.random_range(-0.5..0.5);
        // A second in, so the first sample follows the first inclinometer reading.
        self.scenario.start_t + 1.0 + j as f64 * self.scenario.laser_period_s + jitter
    }

    fn inclinometer(&mut self, t: f64) -> TbmEvent {
        self.machine.advance_to(t);
        let truth = self.machine.truth(self.scenario.start_t);
        let dt = (t - self.last_incl_t).max(0.0);
        self.last_incl_t = t;
        let cutting = truth.phase == Phase::Excavating;
        let (white, coloured) = if cutting {
            (0.005, 0.002)
        } else {
            (0.001, 0.0)
        };
        self.vibration
            .step(dt.max(1e-3), coloured, &mut self.incl_rng);
        let n_pitch: f64 = self.incl_rng.sample(StandardNormal);
        let n_roll: f64 = self.incl_rng.sample(StandardNormal);
        let reading = Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg: truth.pitch_deg - truth.incl_pitch_error_deg
                    + white * n_pitch
                    + self.vibration.x,
                roll_deg: truth.roll_deg - INCL_ROLL_OFFSET_DEG + white * n_roll,
                temp_c: Some((truth.temp_c * 10.0).round() / 10.0),
            },
        };
        TbmEvent { truth, reading }
    }

    fn laser(&mut self, t: f64) -> TbmEvent {
        self.machine.advance_to(t);
        let truth = self.machine.truth(self.scenario.start_t);
        let n: [f64; 3] = [
            self.laser_rng.sample(StandardNormal),
            self.laser_rng.sample(StandardNormal),
            self.laser_rng.sample(StandardNormal),
        ];
        let reading = Reading {
            t,
            data: SensorData::Laser {
                pitch_deg: truth.pitch_deg + 0.002 * n[0],
                roll_deg: truth.roll_deg + 0.002 * n[1],
                yaw_deg: Some(truth.yaw_deg + 0.005 * n[2]),
                position: None,
            },
        };
        TbmEvent { truth, reading }
    }
}

impl Iterator for TbmDrive {
    type Item = TbmEvent;

    fn next(&mut self) -> Option<TbmEvent> {
        let end = self.scenario.end_t();
        loop {
            let incl_t =
                self.scenario.start_t + self.next_incl as f64 * self.scenario.incl_period_s;
            if incl_t >= end && self.next_laser_t >= end {
                return None;
            }
            if self.next_laser_t < incl_t {
                let t = self.next_laser_t;
                self.next_laser += 1;
                self.next_laser_t = self.laser_time(self.next_laser);
                // Drawn whether or not it is delivered, so that a dropout
                // changes no other draw.
                let event = self.laser(t);
                let lost = self.laser_rng.random_bool(0.02);
                if lost || self.scenario.in_dropout(t) {
                    continue;
                }
                return Some(event);
            }
            self.next_incl += 1;
            return Some(self.inclinometer(incl_t));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::SensorKind;

    #[test]
    fn dropout_parsing() {
        assert_eq!(
            "2.5:45".parse::<Dropout>().unwrap(),
            Dropout {
                start_h: 2.5,
                minutes: 45.0
            }
        );
        assert!("2.5".parse::<Dropout>().is_err());
        assert!("x:45".parse::<Dropout>().is_err());
        assert!("1:-3".parse::<Dropout>().is_err());
    }

    #[test]
    fn readings_are_time_ordered_and_valid() {
        let drive = TbmDrive::new(TbmScenario {
            hours: 2.0,
            ..TbmScenario::default()
        })
        .unwrap();
        let mut last = f64::NEG_INFINITY;
        let (mut incl, mut laser) = (0, 0);
        for event in drive {
            assert!(event.reading.t >= last);
            last = event.reading.t;
            event.reading.validate().unwrap();
            match event.reading.sensor() {
                SensorKind::Inclinometer => incl += 1,
                SensorKind::Laser => laser += 1,
                other => panic!("unexpected {other}"),
            }
        }
        assert_eq!(incl, 7200);
        assert!((55..=60).contains(&laser), "{laser}");
    }

    #[test]
    fn dropouts_remove_only_laser_samples() {
        let base = TbmScenario {
            hours: 2.0,
            ..TbmScenario::default()
        };
        let with = TbmScenario {
            dropouts: vec![Dropout {
                start_h: 0.5,
                minutes: 30.0,
            }],
            ..base.clone()
        };
        let a: Vec<_> = TbmDrive::new(base).unwrap().collect();
        let b: Vec<_> = TbmDrive::new(with.clone()).unwrap().collect();
        let keep: Vec<_> = a
            .iter()
            .filter(|e| !(e.reading.sensor() == SensorKind::Laser && with.in_dropout(e.reading.t)))
            .cloned()
            .collect();
        assert!(
            keep == b,
            "a dropout changed more than the laser samples in it"
        );
        assert!(keep.len() < a.len());
    }

    #[test]
    fn the_drive_moves_like_a_tbm() {
        let events: Vec<_> = TbmDrive::new(TbmScenario {
            hours: 10.0,
            ..TbmScenario::default()
        })
        .unwrap()
        .collect();
        let roll: Vec<f64> = events.iter().map(|e| e.truth.roll_deg).collect();
        let (lo, hi) = roll
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &r| (a.min(r), b.max(r)));
        assert!(hi - lo > 1.5 && lo > -1.5 && hi < 3.0, "roll {lo}..{hi}");
        let last = events.last().unwrap().truth;
        assert!(
            last.chainage_m > 9.0 && last.chainage_m < 14.0,
            "{}",
            last.chainage_m
        );
        assert!(events.iter().any(|e| e.truth.phase == Phase::RingBuilding));
    }
}
