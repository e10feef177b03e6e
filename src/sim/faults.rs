//! Faults injected into a simulated drive's readings (issue 54, item 7):
//! each a documented category (docs/evaluation.md, "Faults") that the
//! envelopes of every engine run with `eval … --envelope --fault`, and
//! `simulate … --fault` writes. The truth is left as it was: a fault is
//! in what the sensors (or their gateway) say, not in where the machine is.
//!
//! A fault starts at [`FAULT_AT`] of a drive. A step (a power cycle, an
//! odometer slip, a clock step) stays; a frozen sensor, spikes, a wrong
//! prism and steel beside the compass end after their duration.
//! Deterministic: no randomness, the same readings give the same faults.

use serde::Serialize;

use crate::fusion::{EngineKind, Reading, SensorData, SensorKind};

/// Where in a drive its fault starts (share of its length).
pub const FAULT_AT: f64 = 0.4;

/// A fault category.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// The fast attitude sensor is power-cycled and comes up with a new
    /// turn-on bias: the IMU's gyros (`fuzzy`: by the simulator, a bias of
    /// the other sign; `zupt`: +0.5 °/h on each axis, 20× a FOG's bias
    /// stability), the inclinometer's zero (`attitude`: +0.05° pitch and
    /// roll, the inclinometer's whole error budget). It stays.
    PowerCycle,
    /// The fast sensor repeats its last value for 120 s (a gateway that
    /// re-sends a stale register).
    Frozen,
    /// Every 10th reading of the fast sensor for 120 s is a spike, of
    /// alternating sign: the inclinometer ±2°, the IMU ±30 °/s about its
    /// x axis and ±5 m/s² along it (a loose connector, a hammer blow).
    Spikes,
    /// `attitude`: the laser targets a wrong prism for 30 min: its pitch,
    /// roll and yaw +0.2°, its position 50 mm east and north.
    LaserJump,
    /// `zupt`: the odometer wheel slips: it counts 0.5 m more over 5 s,
    /// which stays in its distance.
    OdometerSlip,
    /// `fuzzy`: steel beside the compass for 300 s: its field plus
    /// (30, 0, −20) µT.
    Steel,
    /// The gateway's clock steps 5 s forward: every reading from then on
    /// is stamped 5 s late. It stays.
    ClockStep,
}

/// How long a fault that ends lasts, s.
const FROZEN_S: f64 = 120.0;
const SPIKES_S: f64 = 120.0;
const LASER_JUMP_S: f64 = 1800.0;
const SLIP_S: f64 = 5.0;
const STEEL_S: f64 = 300.0;
/// Magnitudes.
const SPIKE_EVERY: u64 = 10;
const INCLINOMETER_SPIKE_DEG: f64 = 2.0;
const GYRO_SPIKE_DPS: f64 = 30.0;
const ACCEL_SPIKE_MPS2: f64 = 5.0;
const INCLINOMETER_STEP_DEG: f64 = 0.05;
const FOG_BIAS_STEP_DPH: f64 = 0.5;
const LASER_JUMP_DEG: f64 = 0.2;
const LASER_JUMP_M: f64 = 0.05;
const SLIP_M: f64 = 0.5;
const STEEL_UT: [f64; 3] = [30.0, 0.0, -20.0];
const CLOCK_STEP_S: f64 = 5.0;

impl FaultKind {
    /// Every category, in order.
    pub const ALL: [FaultKind; 7] = [
        FaultKind::PowerCycle,
        FaultKind::Frozen,
        FaultKind::Spikes,
        FaultKind::LaserJump,
        FaultKind::OdometerSlip,
        FaultKind::Steel,
        FaultKind::ClockStep,
    ];

    /// The command-line name.
    pub fn as_str(self) -> &'static str {
        match self {
            FaultKind::PowerCycle => "power-cycle",
            FaultKind::Frozen => "frozen",
            FaultKind::Spikes => "spikes",
            FaultKind::LaserJump => "laser-jump",
            FaultKind::OdometerSlip => "odometer-slip",
            FaultKind::Steel => "steel",
            FaultKind::ClockStep => "clock-step",
        }
    }

    /// Whether it means anything for `engine`'s sensors.
    pub fn applies_to(self, engine: EngineKind) -> bool {
        match self {
            FaultKind::PowerCycle
            | FaultKind::Frozen
            | FaultKind::Spikes
            | FaultKind::ClockStep => true,
            FaultKind::LaserJump => engine == EngineKind::Attitude,
            FaultKind::OdometerSlip => engine == EngineKind::Zupt,
            FaultKind::Steel => engine == EngineKind::Fuzzy,
        }
    }

    /// The categories that apply to `engine`.
    pub fn for_engine(engine: EngineKind) -> Vec<FaultKind> {
        FaultKind::ALL
            .into_iter()
            .filter(|f| f.applies_to(engine))
            .collect()
    }

    /// How long it changes the readings from its onset, s (0: a step).
    pub fn duration_s(self) -> f64 {
        match self {
            FaultKind::Frozen => FROZEN_S,
            FaultKind::Spikes => SPIKES_S,
            FaultKind::LaserJump => LASER_JUMP_S,
            FaultKind::OdometerSlip => SLIP_S,
            FaultKind::Steel => STEEL_S,
            FaultKind::PowerCycle | FaultKind::ClockStep => 0.0,
        }
    }
}

/// When a fault acts in a drive: from `from_t` to `to_t` (equal for a
/// step), by the readings' true time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FaultWindow {
    pub kind: FaultKind,
    pub from_t: f64,
    pub to_t: f64,
}

impl FaultWindow {
    /// The window of `kind` in a drive from `start_t` lasting
    /// `duration_s`.
    pub fn in_drive(kind: FaultKind, start_t: f64, duration_s: f64) -> FaultWindow {
        let from_t = start_t + FAULT_AT * duration_s;
        FaultWindow {
            kind,
            from_t,
            to_t: from_t + kind.duration_s(),
        }
    }
}

/// A category that does not apply to an engine.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("fault `{fault}` does not apply to `{engine}` (its faults: {known})")]
pub struct NotApplicable {
    pub fault: &'static str,
    pub engine: &'static str,
    pub known: String,
}

/// Changes the readings of one drive as its fault says.
#[derive(Debug, Clone)]
pub struct FaultInjector {
    window: FaultWindow,
    /// The sensor whose readings a frozen, spiking or power-cycled fault
    /// changes (the engine's fast one).
    fast: SensorKind,
    /// `fuzzy`'s power cycle is the simulator's: not changed here.
    by_simulator: bool,
    frozen: Option<SensorData>,
    seen_in_window: u64,
}

impl FaultInjector {
    /// The injector of `window` for a drive `engine` runs.
    pub fn new(window: FaultWindow, engine: EngineKind) -> Result<FaultInjector, NotApplicable> {
        if !window.kind.applies_to(engine) {
            return Err(NotApplicable {
                fault: window.kind.as_str(),
                engine: engine.as_str(),
                known: FaultKind::for_engine(engine)
                    .iter()
                    .map(|f| f.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
        let fast = if engine == EngineKind::Attitude {
            SensorKind::Inclinometer
        } else {
            SensorKind::Imu
        };
        Ok(FaultInjector {
            window,
            fast,
            by_simulator: engine == EngineKind::Fuzzy && window.kind == FaultKind::PowerCycle,
            frozen: None,
            seen_in_window: 0,
        })
    }

    /// The window it injects.
    pub fn window(&self) -> FaultWindow {
        self.window
    }

    /// Whether the simulator makes the fault itself (`fuzzy`'s power
    /// cycle, a new turn-on bias of its IMU model).
    pub fn by_simulator(&self) -> bool {
        self.by_simulator
    }

    /// `reading` as the faulty sensor or gateway delivers it.
    pub fn apply(&mut self, mut reading: Reading) -> Reading {
        let w = self.window;
        let t = reading.t;
        if t < w.from_t || self.by_simulator {
            return reading;
        }
        let within = t < w.to_t;
        let fast = reading.sensor() == self.fast;
        match (w.kind, &mut reading.data) {
            (FaultKind::PowerCycle, SensorData::Imu { gyro_dps, .. }) => {
                for axis in gyro_dps.iter_mut() {
                    *axis += FOG_BIAS_STEP_DPH / 3600.0;
                }
            }
            (
                FaultKind::PowerCycle,
                SensorData::Inclinometer {
                    pitch_deg,
                    roll_deg,
                    ..
                },
            ) => {
                *pitch_deg += INCLINOMETER_STEP_DEG;
                *roll_deg += INCLINOMETER_STEP_DEG;
            }
            (FaultKind::Frozen, data) if within && fast => match &self.frozen {
                Some(held) => *data = held.clone(),
                None => self.frozen = Some(data.clone()),
            },
            (FaultKind::Spikes, data) if within && fast => {
                self.seen_in_window += 1;
                if self.seen_in_window.is_multiple_of(SPIKE_EVERY) {
                    let sign = if (self.seen_in_window / SPIKE_EVERY).is_multiple_of(2) {
                        1.0
                    } else {
                        -1.0
                    };
                    spike(data, sign);
                }
            }
            (
                FaultKind::LaserJump,
                SensorData::Laser {
                    pitch_deg,
                    roll_deg,
                    yaw_deg,
                    position,
                },
            ) if within => {
                *pitch_deg += LASER_JUMP_DEG;
                *roll_deg += LASER_JUMP_DEG;
                if let Some(yaw) = yaw_deg {
                    *yaw += LASER_JUMP_DEG;
                }
                if let Some(p) = position {
                    p.easting_m += LASER_JUMP_M;
                    p.northing_m += LASER_JUMP_M;
                }
            }
            (FaultKind::OdometerSlip, SensorData::Odometer { distance_m }) => {
                let share = ((t - w.from_t) / SLIP_S).min(1.0);
                *distance_m += SLIP_M * share;
            }
            (FaultKind::Steel, SensorData::Magnetometer { field_ut }) if within => {
                for (axis, add) in field_ut.iter_mut().zip(STEEL_UT) {
                    *axis += add;
                }
            }
            (FaultKind::ClockStep, _) => reading.t += CLOCK_STEP_S,
            _ => {}
        }
        reading
    }
}

/// One spike of `sign` on a fast sensor's reading.
fn spike(data: &mut SensorData, sign: f64) {
    match data {
        SensorData::Inclinometer {
            pitch_deg,
            roll_deg,
            ..
        } => {
            *pitch_deg += sign * INCLINOMETER_SPIKE_DEG;
            *roll_deg -= sign * INCLINOMETER_SPIKE_DEG;
        }
        SensorData::Imu {
            accel_mps2,
            gyro_dps,
        } => {
            gyro_dps[0] += sign * GYRO_SPIKE_DPS;
            accel_mps2[0] += sign * ACCEL_SPIKE_MPS2;
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inclinometer(t: f64, pitch_deg: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg,
                roll_deg: 0.0,
                temp_c: None,
            },
        }
    }

    fn pitch(r: &Reading) -> f64 {
        match r.data {
            SensorData::Inclinometer { pitch_deg, .. } => pitch_deg,
            _ => f64::NAN,
        }
    }

    #[test]
    fn a_fault_starts_at_its_share_of_the_drive_and_lasts_its_duration() {
        let w = FaultWindow::in_drive(FaultKind::Frozen, 100.0, 1000.0);
        assert_eq!((w.from_t, w.to_t), (500.0, 620.0));
        let w = FaultWindow::in_drive(FaultKind::ClockStep, 0.0, 1000.0);
        assert_eq!((w.from_t, w.to_t), (400.0, 400.0));
    }

    #[test]
    fn a_frozen_inclinometer_repeats_its_first_value_in_the_window_only() {
        let w = FaultWindow::in_drive(FaultKind::Frozen, 0.0, 1000.0);
        let mut injector = FaultInjector::new(w, EngineKind::Attitude).unwrap();
        let out: Vec<f64> = [399.0, 400.0, 450.0, 519.0, 520.0]
            .map(|t| pitch(&injector.apply(inclinometer(t, t))))
            .to_vec();
        assert_eq!(out, [399.0, 400.0, 400.0, 400.0, 520.0]);
    }

    #[test]
    fn every_tenth_reading_spikes_with_alternating_sign() {
        let w = FaultWindow::in_drive(FaultKind::Spikes, 0.0, 1000.0);
        let mut injector = FaultInjector::new(w, EngineKind::Attitude).unwrap();
        let out: Vec<f64> = (0..20)
            .map(|i| pitch(&injector.apply(inclinometer(400.0 + f64::from(i), 1.0))))
            .collect();
        // The 10th reading: one spike of −2° (10 / 10 = 1, odd); the 20th: +2°.
        assert_eq!(out[9], -1.0);
        assert_eq!(out[19], 3.0);
        assert_eq!(out.iter().filter(|&&p| p == 1.0).count(), 18);
    }

    #[test]
    fn a_clock_step_stamps_every_later_reading_five_seconds_late() {
        let w = FaultWindow::in_drive(FaultKind::ClockStep, 0.0, 100.0);
        let mut injector = FaultInjector::new(w, EngineKind::Zupt).unwrap();
        assert_eq!(injector.apply(inclinometer(39.0, 0.0)).t, 39.0);
        assert_eq!(injector.apply(inclinometer(40.0, 0.0)).t, 45.0);
        assert_eq!(injector.apply(inclinometer(90.0, 0.0)).t, 95.0);
    }

    #[test]
    fn an_odometer_slip_adds_half_a_metre_over_five_seconds_and_keeps_it() {
        let w = FaultWindow::in_drive(FaultKind::OdometerSlip, 0.0, 100.0);
        let mut injector = FaultInjector::new(w, EngineKind::Zupt).unwrap();
        let distance = |injector: &mut FaultInjector, t: f64| match injector
            .apply(Reading {
                t,
                data: SensorData::Odometer { distance_m: 10.0 },
            })
            .data
        {
            SensorData::Odometer { distance_m } => distance_m,
            _ => f64::NAN,
        };
        assert_eq!(distance(&mut injector, 39.0), 10.0);
        assert!((distance(&mut injector, 42.5) - 10.25).abs() < 1e-12);
        assert_eq!(distance(&mut injector, 80.0), 10.5);
    }

    #[test]
    fn a_category_of_another_engines_sensors_is_refused_by_name() {
        let w = FaultWindow::in_drive(FaultKind::Steel, 0.0, 100.0);
        let err = FaultInjector::new(w, EngineKind::Attitude).unwrap_err();
        assert_eq!(
            err.to_string(),
            "fault `steel` does not apply to `attitude` (its faults: power-cycle, frozen, spikes, laser-jump, clock-step)"
        );
    }
}
