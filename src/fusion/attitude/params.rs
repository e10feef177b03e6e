//! The `attitude` engine's parameter table, its typed parameters and the
//! configuration in working units (radians) the engine runs with.

use serde::{Deserialize, Serialize};

use super::anfis::{self, AnfisConfig};
use super::kalman::ProcessNoise;
use crate::fusion::angles::{rad, rad2};
use crate::fusion::params::{ParamError, Params, Retired, TypedParams, choice_enum, param_table};

param_table! {
    /// The `attitude` engine's parameters. The noise values are priors: the
    /// engine measures the real ones from the data (`noise=adaptive`) and
    /// uses these only until it has (or always, with `noise=fixed`).
    pub struct AttitudeParams in PARAMS {
        fusion_gain_pitch: f64 = real(
            0.0,
            0.0,
            1.0,
            "",
            "k_f1 of Eq. 10/19: weight of the held laser pitch blended into the estimate (paper: 0.02; the filter's update already fuses every laser sample)",
        ),
        fusion_gain_roll: f64 = real(
            0.0,
            0.0,
            1.0,
            "",
            "k_f2 of Eq. 11: weight of the held laser roll blended into the estimate (paper: 0)",
        ),
        prediction_gain: f64 = real(
            1.0,
            0.0,
            100.0,
            "",
            "k_p of Eq. 12/13: prediction horizon in inclinometer periods (paper: 1)",
        ),
        noise: NoiseMode = choice(
            NoiseMode::Adaptive,
            "adaptive: measurement and process noise estimated from the data, the values below as priors; fixed: the values below throughout",
        ),
        r_incl_deg2: f64 = real(
            1.0e-4,
            1.0e-12,
            100.0,
            "deg²",
            "inclinometer measurement noise variance, per reading (R of Eq. 5)",
        ),
        r_laser_deg2: f64 = real(
            1.0e-5,
            1.0e-12,
            100.0,
            "deg²",
            "laser measurement noise variance (R of Eq. 5)",
        ),
        q_pitch_deg2_per_s: f64 = real(
            0.0,
            0.0,
            1.0,
            "deg²/s",
            "white steps of the pitch (Q of Eq. 4, per second)",
        ),
        q_pitch_rate_deg2_per_s3: f64 = real(
            1.0e-10,
            0.0,
            1.0,
            "deg²/s³",
            "random walk of the pitch rate: how fast the shield's pitch can change its trend",
        ),
        q_bias_deg2_per_s: f64 = real(
            1.0e-10,
            0.0,
            1.0,
            "deg²/s",
            "how far the pitch bias left after the error model may move between laser samples, per second",
        ),
        q_bias_per_roll: f64 = real(
            1.0e-5,
            0.0,
            1.0,
            "deg²/deg²",
            "how far the pitch bias left after the error model may move between laser samples, per squared degree the roll moved",
        ),
        q_roll_deg2_per_s: f64 = real(
            1.0e-9,
            0.0,
            1.0,
            "deg²/s",
            "white steps of the roll (Q of Eq. 4, per second)",
        ),
        q_roll_rate_deg2_per_s3: f64 = real(
            1.0e-7,
            0.0,
            1.0,
            "deg²/s³",
            "random walk of the roll rate (cutterhead torque rolls the shield at up to 0.5 °/min)",
        ),
        laser_period_s: f64 = real(
            120.0,
            0.1,
            86_400.0,
            "s",
            "laser period assumed until two samples have been seen (paper: 2 min)",
        ),
        dropout_factor: f64 = real(
            2.5,
            1.05,
            1000.0,
            "",
            "the laser is in dropout once its sample is older than this many observed periods",
        ),
        laser_dispute_max_s: f64 = real(
            3600.0,
            0.0,
            86_400.0,
            "s",
            "longest a laser that jumped away from the inclinometer's continuity is held out before it is believed again (0: never held out)",
        ),
        correction: Correction = choice(
            Correction::Anfis,
            "pitch error model: the ANFIS, a recency-weighted constant offset, or nothing (for comparison)",
        ),
        anfis_memberships: usize = integer(
            3,
            1,
            9,
            "Gaussian memberships (rules) of the ANFIS (paper: 3, NM/O/PM); with anfis_select=gcv the fewest tried",
        ),
        anfis_select: AnfisSelect = choice(
            AnfisSelect::Gcv,
            "gcv: models with anfis_memberships, +2 and +4 rules are trained side by side and the one generalised cross-validation prefers corrects; fixed: anfis_memberships only",
        ),
        training_window_samples: usize = integer(
            240,
            10,
            5000,
            "most (roll, temperature, pitch error) pairs kept for training",
        ),
        training_bin_deg: f64 = real(
            0.25,
            0.001,
            10.0,
            "deg",
            "width of the roll bins the training pairs are stratified by",
        ),
        training_per_bin: usize = integer(
            12,
            1,
            5000,
            "most training pairs kept per roll bin (a new pair replaces the oldest of its bin)",
        ),
        training_half_life_samples: f64 = real(
            200.0,
            1.0,
            1.0e9,
            "samples",
            "age at which a training pair weighs half as much as the newest",
        ),
        training_min_weight: f64 = real(
            0.1,
            0.0,
            1.0,
            "",
            "floor of a training pair's recency weight, so the only pairs of a roll region still count",
        ),
        anfis_epochs: usize = integer(
            1,
            1,
            50,
            "hybrid training epochs run per laser sample",
        ),
        anfis_min_samples: usize = integer(
            10,
            2,
            5000,
            "pairs needed before the rules are fitted (until then: the mean error)",
        ),
        anfis_min_width_deg: f64 = real(
            0.3,
            1.0e-3,
            90.0,
            "deg",
            "smallest membership width σ; also how far inside the edge of the seen roll the tangent beyond it is taken",
        ),
        anfis_min_span_deg: f64 = real(
            1.0,
            1.0e-3,
            90.0,
            "deg",
            "smallest roll span the memberships are spread over at first",
        ),
        anfis_extrapolation_deg: f64 = real(
            2.0,
            0.0,
            90.0,
            "deg",
            "beyond the trained roll range the correction goes on along its tangent at the edge; beyond it by more than this, it is held",
        ),
        anfis_ridge: f64 = real(
            1.0e-3,
            1.0e-6,
            1.0,
            "",
            "weight pulling each rule towards the global plane through the training pairs",
        ),
        pair_window_s: f64 = real(
            60.0,
            1.0,
            3600.0,
            "s",
            "longest half-width of the inclinometer window a laser sample is compared with (the window follows the filter's averaging length, at least two inclinometer periods)",
        ),
        pair_max_gap_s: f64 = real(
            60.0,
            0.1,
            86_400.0,
            "s",
            "largest inclinometer gap across which a laser instant is still paired",
        ),
    }
}

/// Parameters of earlier releases that no longer exist: a stored machine
/// that has them loads without them; a new declaration that names one is
/// refused with the reason.
pub const RETIRED: &[Retired] = &[
    Retired {
        name: "correction_slew_deg_per_s",
        reason: "a retrain now moves the filter's bias with the correction, so a true change is not slowed and no slew limit is needed",
    },
    Retired {
        name: "roll_offset_gain",
        reason: "the inclinometer's roll offset is now a state of the roll filter, learned from every laser sample",
    },
];

choice_enum! {
    /// Which pitch error model corrects the inclinometer.
    pub enum Correction {
        /// The ANFIS of Eq. 20–25 with the temperature term.
        Anfis = "anfis",
        /// A recency-weighted constant offset (the ANFIS's fallback, for comparison).
        Offset = "offset",
        /// No correction (for comparison): the filter's bias state alone.
        None = "none",
    }
}

choice_enum! {
    /// How many pitch error models are trained.
    pub enum AnfisSelect {
        /// `anfis_memberships`, +2 and +4 side by side; generalised
        /// cross-validation picks the one that corrects.
        Gcv = "gcv",
        /// `anfis_memberships` only.
        Fixed = "fixed",
    }
}

choice_enum! {
    /// Where the filters' noise comes from.
    pub enum NoiseMode {
        /// Estimated from the data ([`super::noise`]), the parameters as priors.
        Adaptive = "adaptive",
        /// The parameters throughout.
        Fixed = "fixed",
    }
}

/// How far the pitch bias may move between two laser samples:
/// `per_s`·Δt + `per_roll2`·Δβ² (rad², rad²/s, dimensionless).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BiasMotion {
    pub per_s: f64,
    pub per_roll2: f64,
}

/// The noise parameters in working units (rad², per second where a rate).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoisePriors {
    pub r_incl: f64,
    pub r_laser: f64,
    pub pitch: ProcessNoise,
    pub roll: ProcessNoise,
    pub bias: BiasMotion,
}

/// The engine's parameters in working units (radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AttitudeConfig {
    pub fusion_gain_pitch: f64,
    pub fusion_gain_roll: f64,
    pub prediction_gain: f64,
    pub noise_mode: NoiseMode,
    pub priors: NoisePriors,
    pub laser_period_s: f64,
    pub dropout_factor: f64,
    pub laser_dispute_max_s: f64,
    pub correction: Correction,
    pub anfis: AnfisConfig,
    /// Membership counts of the candidate models (one with `anfis_select=fixed`).
    pub candidates: [usize; 3],
    pub candidate_count: usize,
    pub pair_window_s: f64,
    pub pair_max_gap_s: f64,
}

impl AttitudeConfig {
    /// The configurations of the candidate models.
    pub fn model_configs(&self) -> impl Iterator<Item = AnfisConfig> + '_ {
        self.candidates[..self.candidate_count]
            .iter()
            .map(|&memberships| AnfisConfig {
                memberships,
                ..self.anfis
            })
    }

    /// Converts validated parameters; degrees become radians here.
    pub fn from_params(params: &Params) -> Result<AttitudeConfig, ParamError> {
        AttitudeConfig::new(&AttitudeParams::from_params(params)?)
    }

    /// The working configuration of typed parameters.
    pub fn new(p: &AttitudeParams) -> Result<AttitudeConfig, ParamError> {
        let correction = p.correction;
        let noise_mode = p.noise;
        let select_gcv = p.anfis_select == AnfisSelect::Gcv;
        let fewest = p.anfis_memberships;
        let mut candidates = [fewest; 3];
        let mut candidate_count = 1;
        if select_gcv {
            for more in [fewest + 2, fewest + 4] {
                if more <= anfis::MAX_MEMBERSHIPS {
                    candidates[candidate_count] = more;
                    candidate_count += 1;
                }
            }
        }
        let window = p.training_window_samples;
        let min_samples = p.anfis_min_samples;
        if min_samples > window {
            return Err(ParamError::Inconsistent(format!(
                "anfis_min_samples ({min_samples}) exceeds training_window_samples ({window})"
            )));
        }
        Ok(AttitudeConfig {
            fusion_gain_pitch: p.fusion_gain_pitch,
            fusion_gain_roll: p.fusion_gain_roll,
            prediction_gain: p.prediction_gain,
            noise_mode,
            priors: NoisePriors {
                r_incl: rad2(p.r_incl_deg2),
                r_laser: rad2(p.r_laser_deg2),
                pitch: ProcessNoise {
                    angle: rad2(p.q_pitch_deg2_per_s),
                    rate: rad2(p.q_pitch_rate_deg2_per_s3),
                },
                // The roll's bias, the mounting offset, does not move.
                roll: ProcessNoise {
                    angle: rad2(p.q_roll_deg2_per_s),
                    rate: rad2(p.q_roll_rate_deg2_per_s3),
                },
                bias: BiasMotion {
                    per_s: rad2(p.q_bias_deg2_per_s),
                    per_roll2: p.q_bias_per_roll,
                },
            },
            laser_period_s: p.laser_period_s,
            dropout_factor: p.dropout_factor,
            laser_dispute_max_s: p.laser_dispute_max_s,
            correction,
            anfis: AnfisConfig {
                memberships: fewest,
                window,
                bin_width_rad: rad(p.training_bin_deg),
                per_bin: p.training_per_bin,
                half_life: p.training_half_life_samples,
                min_weight: p.training_min_weight,
                epochs: p.anfis_epochs,
                min_samples,
                min_width_rad: rad(p.anfis_min_width_deg),
                min_span_rad: rad(p.anfis_min_span_deg),
                extrapolation_rad: rad(p.anfis_extrapolation_deg),
                ridge: p.anfis_ridge,
            },
            candidates,
            candidate_count,
            pair_window_s: p.pair_window_s,
            pair_max_gap_s: p.pair_max_gap_s,
        })
    }
}
