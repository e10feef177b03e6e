//! The `attitude` engine: dual-rate Kalman fusion of a laser targeting
//! system and a two-axis inclinometer, with an ANFIS that learns the
//! inclinometer's pitch error as a function of roll (He et al. 2021).
//!
//! Per inclinometer reading (one estimate each):
//! 1. each inclinometer angle runs its scalar Kalman filter ([`kalman`]);
//! 2. roll is corrected by an offset learned against the laser;
//! 3. the ANFIS ([`anfis`]) gives the pitch error ê_a at that roll, which is
//!    added to the inclinometer and filtered with it (Eq. 18–19);
//! 4. pitch and roll are fused with the held laser (Eq. 10/11/19) unless the
//!    laser is in dropout (then k_f1 = k_f2 = 0);
//! 5. the one-step prediction of Eq. 12/13 is made for the next period.
//!
//! Per laser reading: the laser filters are updated and the sample held
//! ([`dual_rate`]); the inclinometer at the laser's instant gives a training
//! pair (Eq. 16) and the roll offset; the model is retrained, warm.
//!
//! Before the first laser sample the estimate is the filtered inclinometer
//! with no correction (`laser_ok: false`, `pitch_correction_deg: 0`): as good
//! as the inclinometer's installation, no better. Inclinometer readings at or
//! before the newest one already used, and laser readings at or before the
//! held one, are dropped and counted (a reorder buffer in front absorbs
//! ordinary disorder). A laser sample may be older than the newest
//! inclinometer reading: it is paired with the inclinometer history at its
//! own time.

pub mod anfis;
pub mod dual_rate;
pub mod kalman;

use serde::{Deserialize, Serialize};

use self::anfis::{Anfis, AnfisConfig, TrainingSample};
use self::dual_rate::{FilterNoise, InclHistory, InclPoint, LaserHold, fuse, predict_one_step};
use self::kalman::ScalarKalman;
use super::angles::{deg, rad, rad2};
use super::estimate::{AttitudeEstimate, EngineOutput, EstimateValues};
use super::params::{ParamError, ParamKind, ParamSpec, Params, integer, real};
use super::reading::{Reading, SensorData};
use super::{Engine, EngineKind, SnapshotError};

/// Filtered inclinometer points kept for pairing with late laser samples.
const HISTORY_POINTS: usize = 512;
/// Laser samples kept waiting for the inclinometer to reach their time.
const MAX_PENDING_LASER: usize = 8;
/// Points on the reported model curve.
const CURVE_POINTS: usize = 61;

/// The `attitude` engine's parameters. Gains and membership count are the
/// paper's; noise defaults are sized for a 1 Hz inclinometer under cutter
/// vibration (σ ≈ 0.005°), a laser system good to ≈ 0.002°, and a shield
/// whose pitch moves by a few hundredths of a degree within minutes.
pub const PARAMS: &[ParamSpec] = &[
    real(
        "fusion_gain_pitch",
        0.02,
        0.0,
        1.0,
        "",
        "k_f1 of Eq. 10/19: weight of the held laser pitch (paper: 0.02)",
    ),
    real(
        "fusion_gain_roll",
        0.0,
        0.0,
        1.0,
        "",
        "k_f2 of Eq. 11: weight of the held laser roll (paper: 0)",
    ),
    real(
        "prediction_gain",
        1.0,
        0.0,
        100.0,
        "",
        "k_p of Eq. 12/13: prediction horizon in inclinometer periods (paper: 1)",
    ),
    real(
        "q_pitch_deg2_per_s",
        1.6e-5,
        1.0e-14,
        1.0,
        "deg²/s",
        "process noise of the pitch random walk (Q of Eq. 4 per second)",
    ),
    real(
        "q_roll_deg2_per_s",
        1.0e-5,
        1.0e-14,
        1.0,
        "deg²/s",
        "process noise of the roll random walk (Q of Eq. 4 per second)",
    ),
    real(
        "r_incl_deg2",
        3.0e-5,
        1.0e-12,
        100.0,
        "deg²",
        "inclinometer measurement noise variance (R of Eq. 5)",
    ),
    real(
        "r_laser_deg2",
        4.0e-6,
        1.0e-12,
        100.0,
        "deg²",
        "laser measurement noise variance (R of Eq. 5)",
    ),
    real(
        "laser_period_s",
        120.0,
        0.1,
        86_400.0,
        "s",
        "laser period assumed until two samples have been seen (paper: 2 min)",
    ),
    real(
        "dropout_factor",
        2.5,
        1.05,
        1000.0,
        "",
        "the laser is in dropout once its sample is older than this many observed periods",
    ),
    ParamSpec {
        name: "correction",
        kind: ParamKind::Choice {
            default: "anfis",
            options: &["anfis", "offset", "none"],
        },
        unit: "",
        doc: "pitch error model: the ANFIS, a recency-weighted constant offset, or nothing (for comparison)",
    },
    integer(
        "anfis_memberships",
        3,
        1,
        9,
        "Gaussian memberships (rules) of the ANFIS (paper: 3, NM/O/PM)",
    ),
    integer(
        "training_window_samples",
        240,
        10,
        5000,
        "most (roll, pitch error) pairs kept for training",
    ),
    real(
        "training_bin_deg",
        0.25,
        0.001,
        10.0,
        "deg",
        "width of the roll bins the training pairs are stratified by",
    ),
    integer(
        "training_per_bin",
        12,
        1,
        5000,
        "most training pairs kept per roll bin (a new pair replaces the oldest of its bin)",
    ),
    real(
        "training_half_life_samples",
        30.0,
        1.0,
        1.0e9,
        "samples",
        "age at which a training pair weighs half as much as the newest",
    ),
    real(
        "training_min_weight",
        0.1,
        0.0,
        1.0,
        "",
        "floor of a training pair's recency weight, so the only pairs of a roll region still count",
    ),
    integer(
        "anfis_epochs",
        1,
        1,
        50,
        "hybrid training epochs run per laser sample",
    ),
    integer(
        "anfis_min_samples",
        10,
        2,
        5000,
        "pairs needed before the rules are fitted (until then: the mean error)",
    ),
    real(
        "anfis_min_width_deg",
        0.3,
        1.0e-3,
        90.0,
        "deg",
        "smallest membership width σ",
    ),
    real(
        "anfis_min_span_deg",
        1.0,
        1.0e-3,
        90.0,
        "deg",
        "smallest roll span the memberships are spread over at first",
    ),
    real(
        "anfis_extrapolation_deg",
        2.0,
        0.0,
        90.0,
        "deg",
        "beyond the trained roll range by more than this, the correction is held",
    ),
    real(
        "anfis_ridge",
        1.0e-3,
        1.0e-6,
        1.0,
        "",
        "weight pulling each rule towards the global line through the training pairs (sets extrapolation)",
    ),
    real(
        "correction_slew_deg_per_s",
        5.0e-4,
        1.0e-7,
        10.0,
        "deg/s",
        "fastest the applied pitch correction may move once established, so a retrained model (e.g. after a dropout) is blended in without a jump",
    ),
    real(
        "roll_offset_gain",
        0.1,
        1.0e-4,
        1.0,
        "",
        "how fast the inclinometer roll offset follows the laser (per laser sample)",
    ),
    real(
        "pair_max_gap_s",
        60.0,
        0.1,
        86_400.0,
        "s",
        "largest inclinometer gap across which a laser instant is interpolated",
    ),
];

/// Which pitch error model corrects the inclinometer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Correction {
    /// The ANFIS of Eq. 20–25.
    Anfis,
    /// A recency-weighted constant offset (the ANFIS's fallback, for comparison).
    Offset,
    /// No correction (for comparison).
    None,
}

/// The engine's parameters in working units (radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AttitudeConfig {
    pub fusion_gain_pitch: f64,
    pub fusion_gain_roll: f64,
    pub prediction_gain: f64,
    pub noise: FilterNoise,
    pub laser_period_s: f64,
    pub dropout_factor: f64,
    pub correction: Correction,
    pub anfis: AnfisConfig,
    pub roll_offset_gain: f64,
    pub pair_max_gap_s: f64,
    /// rad/s
    pub correction_slew_per_s: f64,
}

impl AttitudeConfig {
    /// Converts validated parameters; degrees become radians here.
    pub fn from_params(p: &Params) -> Result<AttitudeConfig, ParamError> {
        let correction = match p.choice("correction")? {
            "offset" => Correction::Offset,
            "none" => Correction::None,
            _ => Correction::Anfis,
        };
        let window = p.integer("training_window_samples")? as usize;
        let min_samples = p.integer("anfis_min_samples")? as usize;
        if min_samples > window {
            return Err(ParamError::Inconsistent(format!(
                "anfis_min_samples ({min_samples}) exceeds training_window_samples ({window})"
            )));
        }
        Ok(AttitudeConfig {
            fusion_gain_pitch: p.real("fusion_gain_pitch")?,
            fusion_gain_roll: p.real("fusion_gain_roll")?,
            prediction_gain: p.real("prediction_gain")?,
            noise: FilterNoise {
                q_pitch_per_s: rad2(p.real("q_pitch_deg2_per_s")?),
                q_roll_per_s: rad2(p.real("q_roll_deg2_per_s")?),
                r_laser: rad2(p.real("r_laser_deg2")?),
                r_incl: rad2(p.real("r_incl_deg2")?),
            },
            laser_period_s: p.real("laser_period_s")?,
            dropout_factor: p.real("dropout_factor")?,
            correction,
            anfis: AnfisConfig {
                memberships: p.integer("anfis_memberships")? as usize,
                window,
                bin_width_rad: rad(p.real("training_bin_deg")?),
                per_bin: p.integer("training_per_bin")? as usize,
                half_life: p.real("training_half_life_samples")?,
                min_weight: p.real("training_min_weight")?,
                epochs: p.integer("anfis_epochs")? as usize,
                min_samples,
                min_width_rad: rad(p.real("anfis_min_width_deg")?),
                min_span_rad: rad(p.real("anfis_min_span_deg")?),
                extrapolation_rad: rad(p.real("anfis_extrapolation_deg")?),
                ridge: p.real("anfis_ridge")?,
            },
            roll_offset_gain: p.real("roll_offset_gain")?,
            pair_max_gap_s: p.real("pair_max_gap_s")?,
            correction_slew_per_s: rad(p.real("correction_slew_deg_per_s")?),
        })
    }
}

/// Counts of what the engine did with its readings.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct AttitudeStats {
    pub inclinometer_used: u64,
    pub laser_used: u64,
    /// Inclinometer readings at or before the newest one used.
    pub inclinometer_dropped: u64,
    /// Laser readings at or before the held one.
    pub laser_dropped: u64,
    /// Laser samples that found no inclinometer around their instant.
    pub laser_unpaired: u64,
}

/// The fused attitude of the previous inclinometer reading (for Eq. 12/13).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Fused {
    t: f64,
    pitch_rad: f64,
    roll_rad: f64,
}

/// The `attitude` engine; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AttitudeEngine {
    params: Params,
    #[serde(skip_serializing, default = "placeholder_config")]
    config: AttitudeConfig,
    /// α_I_f: the inclinometer pitch filter, on the uncorrected reading.
    incl_pitch: ScalarKalman,
    /// β_I_f: the inclinometer roll filter.
    incl_roll: ScalarKalman,
    /// The correction passed through the inclinometer pitch filter's gains.
    /// The filter is linear and its gains do not depend on the data, so
    /// filter(α_I + ê_a) = α_I_f + this: α_Ic_f of Eq. 19, exactly.
    correction_filtered_rad: f64,
    /// The ê_a applied at the newest reading.
    correction_rad: f64,
    /// True once a trained correction has been applied (slew limit active).
    correction_established: bool,
    laser: LaserHold,
    anfis: Anfis,
    /// Learned β_L − β_I_f; `None` until the first pair.
    roll_offset_rad: Option<f64>,
    history: InclHistory,
    /// Laser samples newer than the newest inclinometer point: (t, pitch, roll).
    pending_laser: Vec<(f64, f64, f64)>,
    previous: Option<Fused>,
    stats: AttitudeStats,
}

/// Used only while deserialising; `restore` rebuilds the config from `params`.
fn placeholder_config() -> AttitudeConfig {
    AttitudeConfig::from_params(&Params::defaults(PARAMS)).expect("default parameters are valid")
}

/// The learned pitch-error model as the API reports it (degrees).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelReport {
    pub correction: Correction,
    pub memberships: Vec<MembershipReport>,
    pub consequents: Vec<ConsequentReport>,
    pub curve: Vec<CurvePoint>,
    pub samples: Vec<SampleReport>,
    pub fit_rmse_deg: f64,
    /// True while the laser is in dropout: the model is not being trained.
    pub frozen: bool,
    pub version: u64,
    pub roll_offset_deg: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MembershipReport {
    pub centre_deg: f64,
    pub width_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ConsequentReport {
    /// p_i0 of Eq. 23.
    pub p0_deg: f64,
    /// p_i1 of Eq. 23, degrees of error per degree of roll.
    pub p1_deg_per_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    pub roll_deg: f64,
    pub correction_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SampleReport {
    pub t: f64,
    pub roll_deg: f64,
    pub error_deg: f64,
}

impl AttitudeEngine {
    /// A fresh engine.
    pub fn new(params: Params) -> Result<AttitudeEngine, ParamError> {
        let config = AttitudeConfig::from_params(&params)?;
        Ok(AttitudeEngine {
            params,
            config,
            incl_pitch: ScalarKalman::default(),
            incl_roll: ScalarKalman::default(),
            correction_filtered_rad: 0.0,
            correction_rad: 0.0,
            correction_established: false,
            laser: LaserHold::new(config.laser_period_s),
            anfis: Anfis::new(config.anfis),
            roll_offset_rad: None,
            history: InclHistory::new(HISTORY_POINTS),
            pending_laser: Vec::new(),
            previous: None,
            stats: AttitudeStats::default(),
        })
    }

    /// An engine with every parameter at its default.
    pub fn with_defaults() -> AttitudeEngine {
        AttitudeEngine::new(Params::defaults(PARAMS)).expect("default parameters are valid")
    }

    /// Continues from a snapshot taken by [`Engine::snapshot`].
    pub fn restore(snapshot: serde_json::Value) -> Result<AttitudeEngine, SnapshotError> {
        let mut engine: AttitudeEngine = SnapshotError::parse(EngineKind::Attitude, snapshot)?;
        let params = engine.params.revalidated(PARAMS)?;
        engine.config = AttitudeConfig::from_params(&params)?;
        engine.params = params;
        // What the parameters shape is rebuilt from them, not trusted.
        engine
            .anfis
            .reconfigure(engine.config.anfis)
            .map_err(SnapshotError::Invalid)?;
        engine
            .laser
            .set_nominal_period(engine.config.laser_period_s);
        engine.history.set_capacity(HISTORY_POINTS);
        engine.pending_laser.truncate(MAX_PENDING_LASER);
        Ok(engine)
    }

    /// What the engine has done with its readings.
    pub fn stats(&self) -> AttitudeStats {
        self.stats
    }

    /// The pitch error model.
    pub fn anfis(&self) -> &Anfis {
        &self.anfis
    }

    /// The working configuration.
    pub fn config(&self) -> &AttitudeConfig {
        &self.config
    }

    /// The pitch error ê_a the engine would apply at `roll_rad`.
    fn correction_at(&self, roll_rad: f64) -> f64 {
        match self.config.correction {
            Correction::Anfis => self.anfis.output(roll_rad),
            Correction::Offset => self.anfis.mean_error_rad(),
            Correction::None => 0.0,
        }
    }

    fn on_inclinometer(&mut self, t: f64, pitch_deg: f64, roll_deg: f64) -> Option<EngineOutput> {
        let dt_s = match self.previous {
            Some(prev) if t <= prev.t => {
                self.stats.inclinometer_dropped += 1;
                return None;
            }
            Some(prev) => t - prev.t,
            None => 0.0,
        };
        self.stats.inclinometer_used += 1;
        let noise = self.config.noise;
        // Eq. 1–7 on the inclinometer angles.
        let gain = self
            .incl_pitch
            .step(rad(pitch_deg), noise.q_pitch_per_s * dt_s, noise.r_incl);
        self.incl_roll
            .step(rad(roll_deg), noise.q_roll_per_s * dt_s, noise.r_incl);
        let roll_corrected = self.incl_roll.x + self.roll_offset_rad.unwrap_or(0.0);

        // Eq. 17–18 through the filter: α_Ic_f = α_I_f + filtered ê_a.
        // Once the model has been trained, the applied ê_a moves towards it
        // no faster than the slew limit: a retrain after a dropout is
        // blended in, not jumped to. The first trained value applies at once.
        let target = self.correction_at(roll_corrected);
        if self.correction_established {
            let step = self.config.correction_slew_per_s * dt_s;
            self.correction_rad += (target - self.correction_rad).clamp(-step, step);
        } else {
            self.correction_rad = target;
            self.correction_established = self.anfis.version() > 0;
        }
        self.correction_filtered_rad += gain * (self.correction_rad - self.correction_filtered_rad);
        let pitch_corrected = self.incl_pitch.x + self.correction_filtered_rad;

        // Eq. 19 and 11; during dropout k_f1 = k_f2 = 0 (Sec. 4.3).
        let laser_ok = self.laser.is_ok(t, self.config.dropout_factor);
        let (k_f1, k_f2) = if laser_ok {
            (self.config.fusion_gain_pitch, self.config.fusion_gain_roll)
        } else {
            (0.0, 0.0)
        };
        let pitch = fuse(k_f1, self.laser.pitch.x, pitch_corrected);
        let roll = fuse(k_f2, self.laser.roll.x, roll_corrected);

        // Eq. 12/13, one inclinometer period ahead.
        let k_p = self.config.prediction_gain;
        let (pitch_pred, roll_pred, pred_t) = match self.previous {
            Some(prev) => (
                predict_one_step(pitch, prev.pitch_rad, k_p),
                predict_one_step(roll, prev.roll_rad, k_p),
                t + k_p * dt_s,
            ),
            None => (pitch, roll, t),
        };
        self.previous = Some(Fused {
            t,
            pitch_rad: pitch,
            roll_rad: roll,
        });

        self.history.push(InclPoint {
            t,
            pitch_rad: self.incl_pitch.x,
            roll_rad: self.incl_roll.x,
        });
        self.pair_pending();

        Some(EngineOutput {
            t,
            values: EstimateValues::Attitude(AttitudeEstimate {
                pitch_deg: deg(pitch),
                roll_deg: deg(roll),
                pitch_pred_deg: deg(pitch_pred),
                roll_pred_deg: deg(roll_pred),
                pred_t,
                laser_ok,
                pitch_correction_deg: deg(self.correction_rad),
                laser_age_s: self.laser.age_s(t),
                model_version: self.anfis.version(),
                incl_pitch_deg: pitch_deg,
                incl_roll_deg: roll_deg,
            }),
        })
    }

    fn on_laser(&mut self, t: f64, pitch_deg: f64, roll_deg: f64) {
        let (pitch, roll) = (rad(pitch_deg), rad(roll_deg));
        if self
            .laser
            .accept(t, pitch, roll, &self.config.noise)
            .is_err()
        {
            self.stats.laser_dropped += 1;
            return;
        }
        self.stats.laser_used += 1;
        // Wait for the inclinometer to reach the laser's instant (also when
        // the laser comes first of all).
        match self.history.newest_t() {
            Some(newest) if t <= newest => self.pair(t, pitch, roll),
            _ => {
                if self.pending_laser.len() == MAX_PENDING_LASER {
                    self.pending_laser.remove(0);
                    self.stats.laser_unpaired += 1;
                }
                self.pending_laser.push((t, pitch, roll));
            }
        }
    }

    /// Pairs waiting laser samples the inclinometer has now caught up with.
    fn pair_pending(&mut self) {
        let Some(newest) = self.history.newest_t() else {
            return;
        };
        while let Some(&(t, pitch, roll)) = self.pending_laser.first() {
            if t > newest {
                break;
            }
            self.pending_laser.remove(0);
            self.pair(t, pitch, roll);
        }
    }

    /// Eq. 16: the pitch error at a laser instant, then training.
    fn pair(&mut self, t: f64, laser_pitch: f64, laser_roll: f64) {
        let Some(incl) = self.history.at(t, self.config.pair_max_gap_s) else {
            self.stats.laser_unpaired += 1;
            return;
        };
        // The paper pairs with the raw inclinometer sample; the filtered one
        // is the same sensor's estimate at that instant without the
        // vibration noise, which would otherwise enter every training target.
        let roll_offset = laser_roll - incl.roll_rad;
        self.roll_offset_rad = Some(match self.roll_offset_rad {
            Some(offset) => offset + self.config.roll_offset_gain * (roll_offset - offset),
            None => roll_offset,
        });
        self.anfis.add_sample(TrainingSample {
            t,
            roll_rad: laser_roll,
            error_rad: laser_pitch - incl.pitch_rad,
            seq: 0,
        });
        if self.config.correction != Correction::None {
            self.anfis.train();
        }
    }

    /// The learned model in degrees, as `GET .../model` reports it.
    pub fn model_report(&self, frozen: bool) -> ModelReport {
        let rules = self.anfis.rules();
        // The pairs' roll range as they are now (training, which also
        // records it, does not run with `correction=none`).
        let (lo, hi) = self.anfis.roll_range_rad();
        let curve = if self.anfis.samples().is_empty() {
            Vec::new()
        } else {
            (0..CURVE_POINTS)
                .map(|i| {
                    let roll = lo + (hi - lo) * i as f64 / (CURVE_POINTS - 1) as f64;
                    CurvePoint {
                        roll_deg: deg(roll),
                        correction_deg: deg(self.correction_at(roll)),
                    }
                })
                .collect()
        };
        ModelReport {
            correction: self.config.correction,
            memberships: rules
                .iter()
                .map(|r| MembershipReport {
                    centre_deg: deg(r.centre_rad),
                    width_deg: deg(r.width_rad),
                })
                .collect(),
            consequents: rules
                .iter()
                .map(|r| ConsequentReport {
                    p0_deg: deg(r.p0_rad),
                    p1_deg_per_deg: r.p1,
                })
                .collect(),
            curve,
            samples: self
                .anfis
                .samples()
                .iter()
                .map(|s| SampleReport {
                    t: s.t,
                    roll_deg: deg(s.roll_rad),
                    error_deg: deg(s.error_rad),
                })
                .collect(),
            fit_rmse_deg: deg(self.anfis.fit_rmse_rad()),
            frozen,
            version: self.anfis.version(),
            roll_offset_deg: self.roll_offset_rad.map(deg),
        }
    }

    /// True while the laser is usable as of the newest inclinometer reading.
    pub fn laser_ok(&self) -> bool {
        self.previous
            .is_some_and(|p| self.laser.is_ok(p.t, self.config.dropout_factor))
    }
}

impl Engine for AttitudeEngine {
    fn kind(&self) -> EngineKind {
        EngineKind::Attitude
    }

    fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        match reading.data {
            SensorData::Inclinometer {
                pitch_deg,
                roll_deg,
                ..
            } => out.extend(self.on_inclinometer(reading.t, pitch_deg, roll_deg)),
            SensorData::Laser {
                pitch_deg,
                roll_deg,
                ..
            } => self.on_laser(reading.t, pitch_deg, roll_deg),
            _ => {}
        }
    }

    fn params(&self) -> &Params {
        &self.params
    }

    fn snapshot(&self) -> serde_json::Value {
        // Every field is a plain number, bool, string or list of them, and
        // the engine keeps them finite: serialising cannot fail.
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }

    fn model(&self) -> Option<serde_json::Value> {
        serde_json::to_value(self.model_report(!self.laser_ok())).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn incl(t: f64, pitch_deg: f64, roll_deg: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg,
                roll_deg,
                temp_c: None,
            },
        }
    }

    fn laser(t: f64, pitch_deg: f64, roll_deg: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Laser {
                pitch_deg,
                roll_deg,
                yaw_deg: None,
            },
        }
    }

    fn attitude(out: &[EngineOutput]) -> &AttitudeEstimate {
        let values = &out.last().expect("an estimate").values;
        values.as_attitude().expect("an attitude estimate")
    }

    const T0: f64 = 1_772_431_200.0;

    #[test]
    fn before_any_laser_the_estimate_is_the_filtered_inclinometer() {
        let mut e = AttitudeEngine::with_defaults();
        let mut out = Vec::new();
        e.feed(&incl(T0, 0.5, 1.0), &mut out);
        let a = attitude(&out);
        assert!((a.pitch_deg - 0.5).abs() < 1e-12);
        assert!((a.roll_deg - 1.0).abs() < 1e-12);
        assert!(!a.laser_ok);
        assert_eq!(a.pitch_correction_deg, 0.0);
        assert_eq!(a.laser_age_s, None);
        assert_eq!(a.pred_t, T0);
    }

    #[test]
    fn one_step_matches_hand_computation() {
        // Two inclinometer readings 1 s apart, a laser between them.
        let mut e =
            AttitudeEngine::new(Params::from_assignments(PARAMS, ["anfis_min_samples=2"]).unwrap())
                .unwrap();
        let mut out = Vec::new();
        e.feed(&incl(T0, 0.5, 1.0), &mut out);
        e.feed(&laser(T0, 0.8, 1.1), &mut out);
        // Pair at T0: e_a = 0.8 − 0.5 = 0.3; roll offset = 1.1 − 1.0 = 0.1.
        assert_eq!(e.anfis().samples().len(), 1);
        assert!((deg(e.anfis().samples()[0].error_rad) - 0.3).abs() < 1e-12);
        e.feed(&incl(T0 + 1.0, 0.5, 1.0), &mut out);
        let a = attitude(&out);
        // Filters see the same value twice: α_I_f = 0.5, β_I_f = 1.0.
        // ê_a = 0.3 (one sample: the mean); its filtered value after the
        // first (gain 1) and second steps stays 0.3 because ê was 0 at the
        // first step: c_f = 0 + K (0.3 − 0) with K from Eq. 5.
        let q = e.config().noise.q_pitch_per_s;
        let r = e.config().noise.r_incl;
        let k = (r + q) / (r + q + r);
        let c_f = k * 0.3;
        let pitch = 0.02 * 0.8 + 0.98 * (0.5 + c_f);
        assert!((a.pitch_correction_deg - 0.3).abs() < 1e-12);
        assert!(
            (a.pitch_deg - pitch).abs() < 1e-9,
            "{} vs {pitch}",
            a.pitch_deg
        );
        assert!((a.roll_deg - 1.1).abs() < 1e-12);
        assert!(a.laser_ok);
        assert_eq!(a.laser_age_s, Some(1.0));
        // Eq. 12: previous fused pitch was the plain 0.5 (no laser yet).
        assert!((a.pitch_pred_deg - (pitch + (pitch - 0.5))).abs() < 1e-9);
        assert_eq!(a.pred_t, T0 + 2.0);
    }

    #[test]
    fn stale_and_duplicate_readings_are_dropped() {
        let mut e = AttitudeEngine::with_defaults();
        let mut out = Vec::new();
        e.feed(&incl(T0 + 1.0, 0.5, 1.0), &mut out);
        e.feed(&incl(T0 + 1.0, 0.6, 1.0), &mut out);
        e.feed(&incl(T0, 0.6, 1.0), &mut out);
        assert_eq!(out.len(), 1);
        e.feed(&laser(T0 + 1.0, 0.5, 1.0), &mut out);
        e.feed(&laser(T0 + 1.0, 0.5, 1.0), &mut out);
        e.feed(&laser(T0, 0.5, 1.0), &mut out);
        let s = e.stats();
        assert_eq!(
            (s.inclinometer_dropped, s.laser_used, s.laser_dropped),
            (2, 1, 2)
        );
    }

    #[test]
    fn laser_ahead_of_the_inclinometer_waits_for_it() {
        let mut e = AttitudeEngine::with_defaults();
        let mut out = Vec::new();
        e.feed(&incl(T0, 0.5, 1.0), &mut out);
        e.feed(&laser(T0 + 0.5, 0.9, 1.0), &mut out);
        assert!(e.anfis().samples().is_empty());
        e.feed(&incl(T0 + 1.0, 0.7, 1.0), &mut out);
        assert_eq!(e.anfis().samples().len(), 1);
    }

    #[test]
    fn dropout_is_detected_from_the_laser_age() {
        let mut e = AttitudeEngine::new(
            Params::from_assignments(PARAMS, ["laser_period_s=60", "dropout_factor=2"]).unwrap(),
        )
        .unwrap();
        let mut out = Vec::new();
        for s in 0..=400 {
            let t = T0 + s as f64;
            if s % 60 == 0 && s <= 120 {
                e.feed(&laser(t, 0.8, 1.0), &mut out);
            }
            e.feed(&incl(t, 0.5, 1.0), &mut out);
        }
        let ok: Vec<bool> = out
            .iter()
            .map(|o| o.values.as_attitude().expect("attitude").laser_ok)
            .collect();
        // Held sample at 120 s, period 60 s: ok through 240 s, dropout after.
        assert!(ok[..=240].iter().all(|&b| b));
        assert!(ok[241..].iter().all(|&b| !b));
        assert!(e.model_report(true).frozen);
    }

    #[test]
    fn laser_return_is_blended_in_without_overshoot() {
        // The inclinometer reads a constant 0.5°; the laser says 0.8° for an
        // hour, drops out for 45 min, and comes back saying 0.85°: the
        // inclinometer's error moved by 0.05° while nothing could see it.
        let mut e =
            AttitudeEngine::new(Params::from_assignments(PARAMS, ["laser_period_s=60"]).unwrap())
                .unwrap();
        let mut out = Vec::new();
        let laser_at = |s: usize| s.is_multiple_of(60) && !(3600..6300).contains(&s);
        let mut pitch = Vec::new();
        for s in 0..9000 {
            let t = T0 + s as f64;
            if laser_at(s) {
                let truth = if s < 3600 { 0.8 } else { 0.85 };
                e.feed(&laser(t, truth, 1.0), &mut out);
            }
            out.clear();
            e.feed(&incl(t, 0.5, 1.0), &mut out);
            let a = attitude(&out);
            pitch.push((s, a.pitch_deg, a.laser_ok));
        }
        let before = pitch[3599].1;
        assert!((before - 0.8).abs() < 1e-3, "{before}");
        assert!(!pitch[6000].2, "the dropout is detected");
        assert!(
            (pitch[6000].1 - before).abs() < 1e-9,
            "frozen during dropout"
        );
        // After the return: each step within the slew limit plus the laser
        // weight's share of the change, never past the new truth, and there
        // within twenty minutes (a roll bin holds 12 pairs: the new error is
        // adopted over about 12 laser samples).
        let max_step = 5.0e-4 + 0.02 * 0.05 + 1e-9;
        for w in pitch[6300..].windows(2) {
            assert!(
                (w[1].1 - w[0].1).abs() <= max_step,
                "step {} at {} s",
                w[1].1 - w[0].1,
                w[1].0
            );
            assert!(
                w[1].1 <= 0.85 + 1e-3,
                "overshoot {} at {} s",
                w[1].1,
                w[1].0
            );
        }
        assert!(pitch[6300 + 600].1 > before + 0.03, "{}", pitch[6900].1);
        assert!(
            (pitch[6300 + 1200].1 - 0.85).abs() < 2e-3,
            "{}",
            pitch[7500].1
        );
    }

    #[test]
    fn snapshot_restore_continues_exactly() {
        let mut a = AttitudeEngine::with_defaults();
        let mut out_a = Vec::new();
        let feed = |e: &mut dyn Engine, s: usize, out: &mut Vec<EngineOutput>| {
            let t = T0 + s as f64;
            let roll = 1.0 + (s as f64 / 300.0).sin();
            if s.is_multiple_of(60) {
                e.feed(&laser(t, 0.3 + 0.01 * roll * roll, roll), out);
            }
            e.feed(&incl(t, 0.1 + 0.001 * (s % 7) as f64, roll + 0.2), out);
        };
        for s in 0..2000 {
            feed(&mut a, s, &mut out_a);
        }
        let snap = a.snapshot();
        let text = serde_json::to_string(&snap).unwrap();
        let mut b = AttitudeEngine::restore(serde_json::from_str(&text).unwrap()).unwrap();
        assert_eq!(a, b);
        let mut out_b = Vec::new();
        out_a.clear();
        for s in 2000..4000 {
            feed(&mut a, s, &mut out_a);
            feed(&mut b, s, &mut out_b);
        }
        assert_eq!(out_a, out_b);
    }

    #[test]
    fn corrupt_snapshots_are_refused_not_trusted() {
        let mut e = AttitudeEngine::with_defaults();
        let mut out = Vec::new();
        for s in 0..1200 {
            let t = T0 + s as f64;
            if s % 60 == 0 {
                e.feed(
                    &laser(
                        t,
                        0.8 + 0.001 * (s / 60) as f64,
                        1.0 + 0.05 * (s / 60) as f64,
                    ),
                    &mut out,
                );
            }
            e.feed(&incl(t, 0.5, 1.0 + 0.05 * (s / 60) as f64), &mut out);
        }
        let snap = e.snapshot();
        assert_eq!(snap["anfis"]["rules"].as_array().map(Vec::len), Some(3));
        let mut too_many = snap.clone();
        let rule = too_many["anfis"]["rules"][0].clone();
        for _ in 0..10 {
            too_many["anfis"]["rules"]
                .as_array_mut()
                .unwrap()
                .push(rule.clone());
        }
        assert!(matches!(
            AttitudeEngine::restore(too_many),
            Err(SnapshotError::Invalid(_))
        ));
        let mut flat = snap.clone();
        flat["anfis"]["rules"][1]["width_rad"] = serde_json::json!(0.0);
        assert!(matches!(
            AttitudeEngine::restore(flat),
            Err(SnapshotError::Invalid(_))
        ));
        let mut unbounded = snap.clone();
        unbounded["history"]["capacity"] = serde_json::json!(0);
        let restored = AttitudeEngine::restore(unbounded).unwrap();
        assert_eq!(restored, AttitudeEngine::restore(snap).unwrap());
    }

    #[test]
    fn inconsistent_parameters_are_refused() {
        let p = Params::from_assignments(
            PARAMS,
            ["training_window_samples=20", "anfis_min_samples=30"],
        )
        .unwrap();
        assert!(matches!(
            AttitudeEngine::new(p),
            Err(ParamError::Inconsistent(_))
        ));
    }
}
