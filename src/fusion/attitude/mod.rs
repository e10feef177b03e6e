//! The `attitude` engine: laser + inclinometer fusion for a TBM's pitch
//! and roll, with an ANFIS that learns the inclinometer's pitch error from
//! roll and temperature (after He et al. 2021).
//!
//! Per axis a Kalman filter ([`kalman`]) carries the angle, its rate, the
//! inclinometer's residual bias and, for pitch beyond the roll the model
//! was trained on, by how much the error's slope there differs from the
//! model's tangent. Per inclinometer reading (one
//! estimate each, at any period):
//! 1. the motion phase is read from the vibration, and the noise of each
//!    axis and the process noise are taken from the self-tuning
//!    ([`noise`]) — or from the parameters with `noise=fixed`;
//! 2. the roll filter takes the inclinometer roll; its bias is the
//!    mounting offset the laser reveals;
//! 3. the ANFIS ([`anfis`]) gives the pitch error ê_a at that roll and
//!    temperature, added to the inclinometer (Eq. 17–18); the pitch filter
//!    takes the sum, its bias state tracking what the model misses;
//! 4. the estimate is the filtered angle (with the held laser blended in by
//!    k_f1, k_f2 of Eq. 10/11/19 if they are set; the filter's laser update
//!    already fuses each sample), and the prediction one inclinometer
//!    period ahead is the angle plus the filtered rate times that period
//!    (Eq. 12/13 with the filter's rate in place of a difference of two
//!    noisy outputs).
//!
//! Per laser reading: the pitch bias's variance first grows by what time
//! and the roll's travel since the previous sample allow (q_b Δt + q_β Δβ²,
//! priors) and by the excess of the recent normalised laser innovations
//! ν²/S over 1 (covariance matching: what the allowance missed); then both
//! filters take it (Eq. 5–7 with H = [1, 0, 0, 0]);
//! once the inclinometer has passed its instant by the pairing window, the
//! inclinometer around it gives a training pair (Eq. 16) and the model is
//! retrained, warm. A retrain moves the correction under the filter; the
//! filter's bias moves with it (b ← b + Δê at the current roll), so the
//! estimate does not jump, and a genuine roll sweep is followed at once.
//!
//! Before the first laser sample the estimate is the filtered inclinometer
//! with no correction (`laser_ok: false`, `pitch_correction_deg: 0`): as good
//! as the inclinometer's installation, no better. Inclinometer readings at or
//! before the newest one already used, and laser readings at or before the
//! held one, are dropped and counted (a reorder buffer in front absorbs
//! ordinary disorder). A laser sample older than the newest inclinometer
//! reading updates the filter through its motion model (y = θ − θ̇·Δ, the
//! noise grown by the process noise over Δ) and is paired with the
//! inclinometer history at its own time.

pub mod anfis;
pub mod dual_rate;
pub mod estimate;
pub mod inclinometer_monitor;
pub mod kalman;
pub mod lag_watch;
pub mod laser_dispute;
pub mod laser_monitor;
pub mod loud_readings;
pub mod noise;
pub mod params;
pub mod residual;
pub mod step_watch;
pub mod training_set;

use serde::{Deserialize, Serialize};

use self::anfis::{Anfis, AnfisConfig, TrainingSample};
use self::dual_rate::{InclHistory, InclPoint, LaserHold, Period, fuse, local_line};
use self::estimate::AttitudeEstimate;
use self::inclinometer_monitor::{InclinometerMonitor, Screened};
use self::kalman::{H_INCLINOMETER, H_LASER, N, ProcessNoise, TiltFilter, inclinometer_row};
use self::lag_watch::LagWatch;
use self::laser_dispute::{LaserDispute, LaserVerdict};
use self::laser_monitor::LaserMonitor;
use self::loud_readings::LoudReadings;
use self::noise::{LaserCurvature, NoiseFit, Phase, PhaseDetector, Variogram};
pub use self::params::{
    AnfisSelect, AttitudeConfig, AttitudeParams, BiasMotion, Correction, NoiseMode, NoisePriors,
    PARAMS, RETIRED,
};
use self::step_watch::StepWatch;
use super::angles::{deg, rad, rad2};
use super::descriptor::EngineDescriptor;
use super::estimate::{EngineOutput, EstimateValues};
use super::params::{ParamError, Params, Retired};
use super::reading::{Reading, SensorData, SensorKind};
use super::registry::EngineModel;
use super::{Engine, EngineKind, SnapshotError};
use crate::fusion::{Integrity, IntegrityReason};

/// Version of the engine's snapshot. A snapshot of another version is
/// refused as [`SnapshotError::Outdated`]; the machine is then rebuilt from
/// its stored readings.
/// 3: the laser innovations' means and the model's range, for the σ (issue 35).
/// 4: the model's smoothed residuals ([`residual`]).
/// 5: the pitch filter's slope state beyond the trained roll ([`kalman`]).
/// 6: the laser's excess errors weighted by their precision (issue 54).
/// 7: the inclinometer monitor (spikes, a frozen sensor; issue 54).
/// 8: the step watch (a new inclinometer zero; issue 54).
/// 9: the laser dispute (a wrong prism) and the lag watch (issue 54).
/// 10: loud readings ([`loud_readings`]; issue 54).
/// 11: the step watch keeps the readings its extrapolated test needs.
/// 12: the step watch keeps places (both axes at one time) for the laser
/// dispute.
pub const STATE_VERSION: u32 = 12;
/// Inclinometer readings kept for pairing with laser samples.
const HISTORY_POINTS: usize = 512;
/// Laser samples kept waiting for the inclinometer to pass their time.
const MAX_PENDING_LASER: usize = 8;
/// Points on the reported model curve.
const CURVE_POINTS: usize = 61;
/// Prior standard deviations at the first reading: the inclinometer's pitch
/// bias (mounting and error together, within ±0.5°), the pitch rate, the
/// roll rate.
const PRIOR_PITCH_BIAS_DEG: f64 = 0.5;
const PRIOR_ROLL_OFFSET_DEG: f64 = 0.3;
const PRIOR_PITCH_RATE_DEG_PER_S: f64 = 1e-3;
const PRIOR_ROLL_RATE_DEG_PER_S: f64 = 1e-2;
/// The noise is re-estimated this often: it changes over minutes, and each
/// fit costs microseconds.
const RETUNE_EVERY_S: f64 = 120.0;
/// Without a surprise, the model is retrained after this long of laser
/// samples (each training costs tens of microseconds; a pair every 30 s
/// need not each pay it).
const TRAIN_EVERY_S: f64 = 300.0;
/// The pairing window is this many times the filter's averaging length.
const PAIR_WINDOW_AVERAGES: f64 = 4.0;
/// The candidate models not in use are trained every this many trainings.
const CANDIDATES_EVERY: u64 = 4;
/// Candidate models not in use trained per reading, at most: a training
/// costs tens of microseconds, so a reading pays for at most this many
/// beside the model in use's one ([`AttitudeEngine::train_due_candidate`]).
const CANDIDATE_TRAININGS_PER_READING: usize = 1;
/// Another candidate model takes over when its cross-validation score is
/// below this share of the current one's.
const GCV_SWITCH: f64 = 0.95;
/// A pair off the model by more than this many times its fit RMS is a
/// surprise and trains at once.
const SURPRISE_FIT_RMS: f64 = 2.5;
/// Bounds on the self-tuned variances: no estimate is trusted below a
/// tenth of a thousandth of a degree or above a degree.
const MIN_SIGMA_DEG: f64 = 1e-4;
const MAX_SIGMA_DEG: f64 = 1.0;

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

/// The noise the filters run with now (rad², per second for rates).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TunedNoise {
    /// Per-reading inclinometer variance of pitch and roll, per phase
    /// (quiet, vibrating).
    pub r_pitch: [f64; 2],
    pub r_roll: [f64; 2],
    pub r_laser: f64,
    pub pitch: ProcessNoise,
    pub roll: ProcessNoise,
    pub bias: BiasMotion,
    /// The pitch noise's fit (N2), once there is one.
    pub pitch_fit: Option<NoiseFit>,
}

impl TunedNoise {
    fn from_priors(p: &NoisePriors) -> TunedNoise {
        TunedNoise {
            r_pitch: [p.r_incl; 2],
            r_roll: [p.r_incl; 2],
            r_laser: p.r_laser,
            pitch: p.pitch,
            roll: p.roll,
            bias: p.bias,
            pitch_fit: None,
        }
    }
}

/// The self-tuning's estimators.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SelfTuning {
    phase: PhaseDetector,
    pitch: Variogram,
    roll: Variogram,
    curvature: LaserCurvature,
}

/// The least rate random walk the self-tuning will set, deg²/s³: a rate
/// that wanders by about 0.07 °/h in an hour. A filter told the angle
/// cannot change would put every change into the bias.
const MIN_Q_RATE_DEG2_PER_S3: f64 = 1e-13;

impl SelfTuning {
    fn new() -> SelfTuning {
        SelfTuning {
            phase: PhaseDetector::default(),
            pitch: Variogram::default(),
            roll: Variogram::default(),
            curvature: LaserCurvature::default(),
        }
    }

    /// The noise to use now: each estimate where it has data, else the
    /// prior. `period_s` is the inclinometer's.
    fn tuned(&self, priors: &NoisePriors, period_s: f64) -> TunedNoise {
        let clamp = |v: f64| v.clamp(rad2(MIN_SIGMA_DEG.powi(2)), rad2(MAX_SIGMA_DEG.powi(2)));
        let level = self.phase.level();
        let floor = rad2(MIN_Q_RATE_DEG2_PER_S3);
        let laser = self.curvature.rate_noise(priors.r_laser);
        let walk_max = self.curvature.angle_walk_max(priors.r_laser);
        let axis =
            |variogram: &Variogram, q_a: Option<f64>, q_w_max: Option<f64>, prior: ProcessNoise| {
                let rate = q_a.map_or(prior.rate, |q| q.max(floor));
                let mut fit = variogram.fit(rate);
                // N3b: no more walk than the laser's second differences allow.
                if let (Some(fit), Some(max)) = (fit.as_mut(), q_w_max) {
                    fit.q_w = fit.q_w.min(max);
                }
                // N2b: the noise over as many readings as the filter averages,
                // in proportion to each phase's own one-lag level.
                let r = [Phase::Quiet, Phase::Vibrating].map(|p| {
                    let one_lag = variogram.one_lag(p).or(level);
                    clamp(match (one_lag, fit) {
                        (Some(v), Some(fit)) if fit.one_lag > 0.0 => {
                            let n = fit.readings_averaged(rate, period_s);
                            v * fit.effective(n, period_s) / fit.one_lag
                        }
                        (Some(v), _) => v,
                        (None, _) => priors.r_incl,
                    })
                });
                let q = ProcessNoise {
                    angle: fit.map_or(prior.angle, |f| f.q_w),
                    rate,
                };
                (r, q, fit)
            };
        let (r_pitch, pitch, pitch_fit) = axis(
            &self.pitch,
            laser.map(|l| l.0),
            walk_max.map(|w| w.0),
            priors.pitch,
        );
        let (r_roll, roll, _) = axis(
            &self.roll,
            laser.map(|l| l.1),
            walk_max.map(|w| w.1),
            priors.roll,
        );
        TunedNoise {
            r_pitch,
            r_roll,
            r_laser: priors.r_laser,
            pitch,
            roll,
            bias: priors.bias,
            pitch_fit,
        }
    }
}

/// The model in use's trained roll range, beyond which the pitch filter's
/// slope state takes part ([`AttitudeEngine::beyond_rad`]), and how much
/// the model bends over it, kept with the model they were computed from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Extrapolation {
    /// The model: its index among the candidates and its version.
    chosen: usize,
    version: u64,
    lo_rad: f64,
    hi_rad: f64,
    /// The prior variance of the slope state s: the variance of the
    /// model's slope over the range.
    slope_var: f64,
    /// RMS second derivative of the correction over the range, rad⁻¹.
    curvature_rms: f64,
    /// How far the correction spans over the range (largest − smallest),
    /// rad: no bend takes the error further from a line than that.
    span_rad: f64,
    /// Beyond the range by more than this the model holds its correction
    /// (`anfis_extrapolation_deg`), rad; the slope of its tangent below
    /// and above the range, which the error may keep where the model stops.
    guard_rad: f64,
    edge_slopes: [f64; 2],
    /// The side of the range (−1 below, +1 above, 0 none yet) the slope
    /// state has learned on since the model changed: a slope learned above
    /// says nothing below.
    side: f64,
}

/// The fused attitude of the newest inclinometer reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Newest {
    t: f64,
    roll_rad: f64,
    temp_c: Option<f64>,
    phase: Phase,
}

/// What an estimate shows: pitch and roll with their variances (rad,
/// rad²), the predicted pitch's variance, the filters' rates (rad/s), the
/// prediction's horizon (s) and whether the laser is in.
struct Shown {
    pitch: (f64, f64),
    roll: (f64, f64),
    pitch_pred_variance: f64,
    rates: (f64, f64),
    ahead_s: f64,
    laser_ok: bool,
}

/// The `attitude` engine; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AttitudeEngine {
    /// [`STATE_VERSION`] when the snapshot was taken.
    state_version: u32,
    params: Params,
    #[serde(skip_serializing, default = "placeholder_config")]
    config: AttitudeConfig,
    /// Pitch filter on the corrected inclinometer; `None` before the first reading.
    pitch: Option<TiltFilter>,
    roll: Option<TiltFilter>,
    /// The ê_a applied at the newest reading.
    correction_rad: f64,
    laser: LaserHold,
    incl_period: Period,
    /// The candidate error models, fewest rules first, and the one in use.
    models: Vec<Anfis>,
    chosen: usize,
    history: InclHistory,
    /// Laser samples waiting for the inclinometer: (t, pitch, roll).
    pending_laser: Vec<(f64, f64, f64)>,
    tuning: SelfTuning,
    noise: TunedNoise,
    /// Time and filtered roll at the previous laser sample.
    last_laser_roll: Option<(f64, f64)>,
    /// Normalised laser innovations ν²/S, averaged over the last few.
    laser_nis: noise::RecentMean,
    /// The pitch's and the roll's laser innovations beyond what the filter
    /// expected of them, ν² − S, averaged over the last few, each weighted
    /// by its precision 1/S² (a sample the prior dominated says little):
    /// the error the laser finds that the filter's variance misses (rad²).
    pitch_laser_error: noise::PrecisionMean,
    roll_laser_error: noise::PrecisionMean,
    /// The time of the newest estimate and the pitch and roll it showed
    /// with their variances (rad, rad²), for the laser monitor.
    shown: Option<(f64, [(f64, f64); 2])>,
    /// Each laser sample against the pitch shown before it (integrity).
    laser_monitor: LaserMonitor,
    /// A laser sample that jumped from the inclinometer's continuity is
    /// held out while later ones keep the jump (integrity).
    laser_dispute: LaserDispute,
    /// The inclinometer innovations' recent mean: a filter lagging the
    /// shield widens the σ (integrity).
    lag_watch: LagWatch,
    /// What readings as loud as an excavation, fused with a quiet
    /// phase's noise, left in the angles (integrity).
    #[serde(default)]
    loud_readings: LoudReadings,
    /// Each inclinometer reading against the prediction and the one
    /// before it: spikes and a frozen sensor are not fused (integrity).
    #[serde(default)]
    inclinometer_monitor: InclinometerMonitor,
    /// The inclinometer's readings watched for a step (a new zero) until
    /// a laser sample checks the estimate (integrity).
    #[serde(default)]
    step_watch: StepWatch,
    /// What the model in use knows of its roll range, for the σ beyond it.
    extrapolation: Option<Extrapolation>,
    /// Training pairs added since the model was last trained.
    pairs_untrained: u32,
    /// Trainings so far.
    trainings: u64,
    /// Candidate models (not in use) due to train, in order; one trains
    /// per reading, and the choice among the models waits for the last.
    #[serde(default)]
    candidates_due: Vec<usize>,
    /// When the noise was last re-estimated.
    retuned_t: Option<f64>,
    newest: Option<Newest>,
    stats: AttitudeStats,
}

/// Used only while deserialising; `restore` rebuilds the config from `params`.
fn placeholder_config() -> AttitudeConfig {
    AttitudeConfig::from_params(&Params::defaults(PARAMS)).expect("default parameters are valid")
}

/// The learned pitch-error model and the self-tuned noise as the API
/// reports them (degrees).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[schema(as = AttitudeModelReport)]
pub struct ModelReport {
    pub correction: Correction,
    pub memberships: Vec<MembershipReport>,
    pub consequents: Vec<ConsequentReport>,
    /// ê over the seen roll range, at the reference temperature.
    pub curve: Vec<CurvePoint>,
    pub samples: Vec<SampleReport>,
    pub fit_rmse_deg: f64,
    /// c_T: degrees of pitch error per °C, and T_ref.
    pub temp_coefficient_deg_per_c: f64,
    pub temp_reference_c: f64,
    /// True while the laser is in dropout: the model is not being trained.
    pub frozen: bool,
    pub version: u64,
    /// The roll offset (what is added to the inclinometer roll), once a
    /// laser sample has been seen.
    pub roll_offset_deg: Option<f64>,
    /// What the model misses now, ± its σ: the pitch filter's bias, and
    /// beyond the trained roll its slope state's share (b + s·d).
    pub pitch_bias_deg: Option<f64>,
    pub pitch_bias_sigma_deg: Option<f64>,
    pub noise: NoiseReport,
}

/// The noise the filters run with, as standard deviations and intensities.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct NoiseReport {
    pub mode: NoiseMode,
    /// The motion phase of the newest reading.
    pub phase: Phase,
    /// Per-reading inclinometer noise (σ, degrees) while quiet and vibrating.
    pub incl_pitch_quiet_deg: f64,
    pub incl_pitch_vibrating_deg: f64,
    pub incl_roll_quiet_deg: f64,
    pub incl_roll_vibrating_deg: f64,
    pub laser_deg: f64,
    /// Process noise intensities.
    pub q_pitch_deg2_per_s: f64,
    pub q_pitch_rate_deg2_per_s3: f64,
    pub q_bias_deg2_per_s: f64,
    pub q_bias_per_roll: f64,
    pub q_roll_deg2_per_s: f64,
    pub q_roll_rate_deg2_per_s3: f64,
    /// The time constant of the pitch noise's coloured part (0: white).
    pub colour_tau_s: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct MembershipReport {
    pub centre_deg: f64,
    pub width_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ConsequentReport {
    /// p_i0 of Eq. 23.
    pub p0_deg: f64,
    /// p_i1 of Eq. 23, degrees of error per degree of roll.
    pub p1_deg_per_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CurvePoint {
    pub roll_deg: f64,
    pub correction_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SampleReport {
    pub t: f64,
    pub roll_deg: f64,
    pub error_deg: f64,
    pub temp_c: Option<f64>,
}

impl AttitudeEngine {
    /// A fresh engine.
    pub fn new(params: Params) -> Result<AttitudeEngine, ParamError> {
        let config = AttitudeConfig::from_params(&params)?;
        Ok(AttitudeEngine {
            state_version: STATE_VERSION,
            params,
            config,
            pitch: None,
            roll: None,
            correction_rad: 0.0,
            laser: LaserHold::new(config.laser_period_s),
            incl_period: Period::new(0.0),
            models: config.model_configs().map(Anfis::new).collect(),
            chosen: 0,
            history: InclHistory::new(HISTORY_POINTS),
            pending_laser: Vec::new(),
            tuning: SelfTuning::new(),
            noise: TunedNoise::from_priors(&config.priors),
            last_laser_roll: None,
            laser_nis: noise::RecentMean::default(),
            pitch_laser_error: noise::PrecisionMean::default(),
            roll_laser_error: noise::PrecisionMean::default(),
            shown: None,
            laser_monitor: LaserMonitor::default(),
            laser_dispute: LaserDispute::default(),
            lag_watch: LagWatch::default(),
            loud_readings: LoudReadings::default(),
            inclinometer_monitor: InclinometerMonitor::default(),
            step_watch: StepWatch::default(),
            extrapolation: None,
            pairs_untrained: 0,
            trainings: 0,
            candidates_due: Vec::new(),
            retuned_t: None,
            newest: None,
            stats: AttitudeStats::default(),
        })
    }

    /// An engine with every parameter at its default.
    pub fn with_defaults() -> AttitudeEngine {
        AttitudeEngine::new(Params::defaults(PARAMS)).expect("default parameters are valid")
    }

    /// Continues from a snapshot taken by [`Engine::snapshot`]. A snapshot
    /// of another [`STATE_VERSION`] is refused as outdated.
    pub fn restore(snapshot: serde_json::Value) -> Result<AttitudeEngine, SnapshotError> {
        SnapshotError::check_version(EngineKind::Attitude, &snapshot, STATE_VERSION)?;
        let mut engine: AttitudeEngine = SnapshotError::parse(EngineKind::Attitude, snapshot)?;
        let params = engine.params.upgraded(PARAMS, RETIRED)?;
        engine.config = AttitudeConfig::from_params(&params)?;
        engine.params = params;
        // What the parameters shape is rebuilt from them, not trusted.
        let configs: Vec<AnfisConfig> = engine.config.model_configs().collect();
        if engine.models.len() != configs.len() || engine.chosen >= configs.len() {
            return Err(SnapshotError::Invalid(format!(
                "{} error models (model {} chosen) for {} candidates",
                engine.models.len(),
                engine.chosen,
                configs.len()
            )));
        }
        for (model, config) in engine.models.iter_mut().zip(configs) {
            model.reconfigure(config).map_err(SnapshotError::Invalid)?;
        }
        // Only candidates other than the model in use wait, each once.
        let (models, chosen) = (engine.models.len(), engine.chosen);
        let mut seen = Vec::new();
        engine.candidates_due.retain(|&i| {
            let keep = i < models && i != chosen && !seen.contains(&i);
            seen.push(i);
            keep
        });
        engine
            .laser
            .set_nominal_period(engine.config.laser_period_s);
        engine.history.set_capacity(HISTORY_POINTS);
        engine.pending_laser.truncate(MAX_PENDING_LASER);
        let finite = |f: &Option<TiltFilter>| {
            f.is_none_or(|f| {
                f.x.iter()
                    .chain(f.p.iter().flatten())
                    .all(|v| v.is_finite())
            })
        };
        if !(finite(&engine.pitch) && finite(&engine.roll)) {
            return Err(SnapshotError::Invalid(
                "a filter state is not finite".into(),
            ));
        }
        Ok(engine)
    }

    /// What the engine has done with its readings.
    pub fn stats(&self) -> AttitudeStats {
        self.stats
    }

    /// The pitch error model.
    pub fn anfis(&self) -> &Anfis {
        &self.models[self.chosen]
    }

    /// The working configuration.
    pub fn config(&self) -> &AttitudeConfig {
        &self.config
    }

    /// The pitch error ê_a the engine would apply at `roll_rad` and `temp_c`.
    fn correction_at(&self, roll_rad: f64, temp_c: Option<f64>) -> f64 {
        match self.config.correction {
            Correction::Anfis => self.anfis().output(roll_rad, temp_c),
            Correction::Offset => self.anfis().mean_error_rad(),
            Correction::None => 0.0,
        }
    }

    fn retune(&mut self) {
        if self.config.noise_mode == NoiseMode::Adaptive {
            self.noise = self
                .tuning
                .tuned(&self.config.priors, self.incl_period.get());
        }
    }

    fn on_inclinometer(
        &mut self,
        t: f64,
        pitch_deg: f64,
        roll_deg: f64,
        temp_c: Option<f64>,
    ) -> Option<EngineOutput> {
        if self.newest.is_some_and(|newest| t <= newest.t) {
            self.stats.inclinometer_dropped += 1;
            return None;
        }
        let innovations = self.inclinometer_innovations(t, rad(pitch_deg), rad(roll_deg));
        match self
            .inclinometer_monitor
            .screen(t, pitch_deg, roll_deg, innovations)
        {
            Screened::Fuse => {}
            // A spike moves no TBM: no estimate of its own.
            Screened::Spike => return None,
            Screened::Frozen => return self.coasted(t, pitch_deg, roll_deg),
        }
        if let Some(newest) = self.newest {
            self.incl_period.add(t - newest.t);
        }
        self.stats.inclinometer_used += 1;
        let (pitch_raw, roll_raw) = (rad(pitch_deg), rad(roll_deg));
        let temp_c = temp_c.or(self.newest.and_then(|n| n.temp_c));
        let phase = self.tuning.phase.observe(t, pitch_raw, roll_raw);
        let at = phase.index();
        let loud = self.tuning.phase.noise_phase().index();
        let noise = self.noise;
        // The raw readings: the model's correction changes at a retraining.
        let tested = self.step_watch.observe(
            t,
            pitch_raw,
            roll_raw,
            [noise.r_pitch[at], noise.r_roll[at]],
        );
        if let Some(axes) = innovations {
            let monitor = &self.inclinometer_monitor;
            let innovations = [0, 1].map(|k| (axes[k].0, monitor.sigma(k, axes[k].1)));
            self.lag_watch.observe(innovations);
            // Readings too far apart for a window: each innovation is the
            // step since the one before.
            if !tested {
                self.step_watch.record(t, innovations);
            }
        }

        // Roll: the inclinometer roll and its offset (the bias state).
        let roll = match self.roll.as_mut() {
            Some(f) => {
                f.predict_to(t, &noise.roll);
                let gain = f.angle_gain(H_INCLINOMETER, noise.r_roll[at]);
                self.loud_readings
                    .fused(1, gain, noise.r_roll[loud] - noise.r_roll[at]);
                f.update(H_INCLINOMETER, roll_raw, noise.r_roll[at]);
                *f
            }
            None => *self.roll.insert(TiltFilter::start(
                t,
                roll_raw,
                noise.r_roll[at],
                rad(PRIOR_ROLL_OFFSET_DEG),
                rad(PRIOR_ROLL_RATE_DEG_PER_S),
            )),
        };
        let roll_rad = roll.angle();

        // Eq. 17–18: the corrected inclinometer, filtered with its bias
        // (and, beyond the trained roll, how the error's slope leaves the
        // model's tangent).
        self.correction_rad = self.correction_at(roll_rad, temp_c);
        let z = pitch_raw + self.correction_rad;
        self.refresh_extrapolation(roll_rad);
        let beyond = self.beyond_rad(roll_rad);
        self.keep_slope_to_its_side(beyond);
        let pitch = match self.pitch.as_mut() {
            Some(f) => {
                f.predict_to(t, &noise.pitch);
                let gain = f.angle_gain(inclinometer_row(beyond), noise.r_pitch[at]);
                self.loud_readings
                    .fused(0, gain, noise.r_pitch[loud] - noise.r_pitch[at]);
                f.update(inclinometer_row(beyond), z, noise.r_pitch[at]);
                *f
            }
            None => *self.pitch.insert(TiltFilter::start(
                t,
                z,
                noise.r_pitch[at],
                rad(PRIOR_PITCH_BIAS_DEG),
                rad(PRIOR_PITCH_RATE_DEG_PER_S),
            )),
        };
        self.tuning.pitch.observe(t, z, phase);
        self.tuning.roll.observe(t, roll_raw, phase);
        if self.retuned_t.is_none_or(|last| t - last >= RETUNE_EVERY_S) {
            self.retuned_t = Some(t);
            self.retune();
        }

        // Eq. 19 and 11; during dropout k_f1 = k_f2 = 0 (Sec. 4.3).
        let laser_ok = self.laser.is_ok(t, self.config.dropout_factor);
        let (k_f1, k_f2) = if laser_ok && !self.laser_dispute.is_open() {
            (self.config.fusion_gain_pitch, self.config.fusion_gain_roll)
        } else {
            (0.0, 0.0)
        };
        let (laser_pitch, laser_roll) = self.laser.last.map_or((0.0, 0.0), |(_, p, r)| (p, r));
        let pitch_out = fuse(k_f1, laser_pitch, pitch.angle());
        let roll_out = fuse(k_f2, laser_roll, roll_rad);

        // Eq. 12/13 with the filtered rate, one inclinometer period ahead.
        let ahead_s = self.config.prediction_gain * self.incl_period.get();
        self.newest = Some(Newest {
            t,
            roll_rad,
            temp_c,
            phase,
        });
        self.history.push(InclPoint {
            t,
            pitch_rad: pitch_raw,
            roll_rad,
            temp_c,
        });
        self.pair_pending();
        // A retrain just now: the σ below is for the new model.
        self.refresh_extrapolation(roll_rad);

        // σ: what the laser has not checked since its last sample adds to
        // the pitch filter's own variance (the bias's allowance, applied to
        // the filter only at the next laser sample).
        let unchecked = self.unchecked_bias_variance(t, roll_rad);
        // With the held laser blended in by k (Eq. 10/11/19; 0 by
        // default): (1 − k)² of the filter's part, k² of the held sample's
        // (its noise and the angle's motion since).
        let laser_age = self.laser.age_s(t).unwrap_or(0.0);
        let held = |q: &ProcessNoise| noise.r_laser + q.angle * laser_age;
        let [step_pitch, step_roll] = self.step_watch.unverified_variance();
        let [lag_pitch, lag_roll] = self.lag_watch.variance();
        let [loud_pitch, loud_roll] = self.loud_readings.variance();
        let own = pitch.p[0][0]
            + self.pitch_laser_error.mean.max(0.0)
            + unchecked
            + step_pitch
            + lag_pitch
            + loud_pitch;
        let pitch_variance = (1.0 - k_f1).powi(2) * own + k_f1 * k_f1 * held(&noise.pitch);
        // The prediction adds rate·a to the blend: [1 − k, a, 0, 0] P [1 − k, a, 0, 0]ᵀ
        // and the angle's motion over a.
        let pitch_pred_variance = pitch.predicted_angle_variance(1.0 - k_f1, ahead_s, &noise.pitch)
            + (1.0 - k_f1).powi(2) * (own - pitch.p[0][0])
            + k_f1 * k_f1 * held(&noise.pitch);
        let roll_own =
            roll.p[0][0] + self.roll_laser_error.mean.max(0.0) + step_roll + lag_roll + loud_roll;
        let roll_variance = (1.0 - k_f2).powi(2) * roll_own + k_f2 * k_f2 * held(&noise.roll);
        self.shown = Some((t, [(pitch_out, pitch_variance), (roll_out, roll_variance)]));

        Some(self.output(
            t,
            Shown {
                pitch: (pitch_out, pitch_variance),
                roll: (roll_out, roll_variance),
                pitch_pred_variance,
                rates: (pitch.rate(), roll.rate()),
                ahead_s,
                laser_ok,
            },
            (pitch_deg, roll_deg),
        ))
    }

    /// The estimate at `t` of what is `shown`, beside the inclinometer's
    /// `incl_deg` (pitch, roll as sent).
    fn output(&self, t: f64, shown: Shown, incl_deg: (f64, f64)) -> EngineOutput {
        let sigma = |variance: f64| Some(deg(variance.max(0.0).sqrt()));
        // An open laser dispute: the case that the laser was right.
        let [pitch_disputed, roll_disputed] = self.laser_dispute.variance();
        let ((pitch, pitch_variance), (roll, roll_variance)) = (shown.pitch, shown.roll);
        let (pitch_variance, roll_variance) = (
            pitch_variance + pitch_disputed,
            roll_variance + roll_disputed,
        );
        EngineOutput {
            t,
            values: EstimateValues::Attitude(AttitudeEstimate {
                pitch_deg: deg(pitch),
                roll_deg: deg(roll),
                pitch_pred_deg: deg(pitch + shown.rates.0 * shown.ahead_s),
                roll_pred_deg: deg(roll + shown.rates.1 * shown.ahead_s),
                pred_t: t + shown.ahead_s,
                pitch_sigma_deg: sigma(pitch_variance),
                roll_sigma_deg: sigma(roll_variance),
                pitch_pred_sigma_deg: sigma(shown.pitch_pred_variance + pitch_disputed),
                laser_ok: shown.laser_ok,
                pitch_correction_deg: deg(self.correction_rad),
                laser_age_s: self.laser.age_s(t),
                model_version: self.anfis().version(),
                incl_pitch_deg: incl_deg.0,
                incl_roll_deg: incl_deg.1,
            }),
            integrity: self.integrity(),
        }
    }

    /// The integrity of an estimate: the worst of the monitors'.
    fn integrity(&self) -> Integrity {
        let step = if self.step_watch.unverified() {
            Integrity::degraded(IntegrityReason::Unverified)
        } else {
            Integrity::OK
        };
        self.laser_monitor
            .integrity()
            .worst(self.inclinometer_monitor.integrity())
            .worst(step)
    }

    /// How far an inclinometer reading at `t` lies from the filters'
    /// prediction: (ν, √S) of pitch and roll, with the larger of the two
    /// phases' noise (`None` before the filters start).
    fn inclinometer_innovations(
        &self,
        t: f64,
        pitch_raw: f64,
        roll_raw: f64,
    ) -> Option<[(f64, f64); 2]> {
        let (Some(pitch), Some(roll)) = (self.pitch, self.roll) else {
            return None;
        };
        let noise = &self.noise;
        let r = |r: [f64; 2]| r[0].max(r[1]);
        let mut roll_probe = roll;
        roll_probe.predict_to(t, &noise.roll);
        let roll_i = roll_probe.innovation(H_INCLINOMETER, roll_raw, r(noise.r_roll));
        let mut pitch_probe = pitch;
        pitch_probe.predict_to(t, &noise.pitch);
        let beyond = self.beyond_rad(roll_probe.angle());
        let z = pitch_raw + self.correction_rad;
        let pitch_i = pitch_probe.innovation(inclinometer_row(beyond), z, r(noise.r_pitch));
        let pair = |i: kalman::Innovation| (i.value, i.variance.max(0.0).sqrt());
        Some([pair(pitch_i), pair(roll_i)])
    }

    /// The estimate at `t` while the inclinometer is frozen (it sent
    /// `pitch_deg`, `roll_deg` again): the last one shown carried by the
    /// filters' rates, its variance grown as the prediction's.
    fn coasted(&self, t: f64, pitch_deg: f64, roll_deg: f64) -> Option<EngineOutput> {
        let (shown_t, shown) = self.shown?;
        let (pitch, roll) = (self.pitch.as_ref()?, self.roll.as_ref()?);
        let noise = &self.noise;
        let ahead_s = self.config.prediction_gain * self.incl_period.get();
        let dt = t - shown_t;
        let (pitch_rad, pitch_variance) = pitch.carry(shown[0], dt, &noise.pitch);
        let (roll_rad, roll_variance) = roll.carry(shown[1], dt, &noise.roll);
        let (_, pitch_pred_variance) = pitch.carry(shown[0], dt + ahead_s, &noise.pitch);
        Some(self.output(
            t,
            Shown {
                pitch: (pitch_rad, pitch_variance),
                roll: (roll_rad, roll_variance),
                pitch_pred_variance,
                rates: (pitch.rate(), roll.rate()),
                ahead_s,
                laser_ok: self.laser.is_ok(t, self.config.dropout_factor),
            },
            (pitch_deg, roll_deg),
        ))
    }

    /// How far the bias may have moved since the previous laser sample,
    /// rad², at `t` with the roll at `roll_rad`: as much as the time and
    /// the roll's travel allow (q_b Δt + q_β Δβ²). `None` before a laser
    /// sample.
    fn bias_allowance(&self, t: f64, roll_rad: f64) -> Option<f64> {
        let (t0, roll_0) = self.last_laser_roll?;
        let dr = roll_rad - roll_0;
        Some(self.noise.bias.per_s * (t - t0).abs() + self.noise.bias.per_roll2 * dr * dr)
    }

    /// What the bias's variance would grow by if a laser sample came at
    /// `t` with the roll at `roll_rad` (the allowance of [`Self::on_laser`],
    /// or the model's own error if larger), rad²: the part of the
    /// correction no laser has checked yet.
    fn unchecked_bias_variance(&self, t: f64, roll_rad: f64) -> f64 {
        let (Some(allowance), Some((_, roll_0))) =
            (self.bias_allowance(t, roll_rad), self.last_laser_roll)
        else {
            return 0.0;
        };
        allowance.max(self.model_variance(roll_rad - roll_0)) + self.bend_variance(roll_0, roll_rad)
    }

    /// What the error's bend beyond the trained roll adds, rad². The
    /// filter follows the error there along a line (the model's tangent
    /// and its slope state s) through where the laser last checked it,
    /// `anchor_rad` (or the edge, if that was on the other side); a bend
    /// of the model's RMS curvature κ leaves that line by κ·Δd²/2 at
    /// `roll_rad` (at most the model's own span over its range), Δd the
    /// roll's travel beyond the range since. Past the guard the model holds
    /// its correction while the error may go on along the tangent: that
    /// adds the tangent's slope times the travel past the guard.
    fn bend_variance(&self, anchor_rad: f64, roll_rad: f64) -> f64 {
        let Some(e) = self.extrapolation else {
            return 0.0;
        };
        let (d, d0) = (self.beyond_rad(roll_rad), self.beyond_rad(anchor_rad));
        let d0 = if d * d0 < 0.0 { 0.0 } else { d0 };
        let bend = (0.5 * e.curvature_rms * (d - d0).powi(2)).min(e.span_rad);
        let past_guard = |x: f64| (x.abs() - e.guard_rad).max(0.0);
        let edge_slope = e.edge_slopes[usize::from(d > 0.0)];
        let held = edge_slope * (past_guard(d) - past_guard(d0));
        bend * bend + held * held
    }

    /// Signed distance of `roll_rad` beyond the model's trained roll range
    /// (+ above, − below, 0 within), rad.
    fn beyond_rad(&self, roll_rad: f64) -> f64 {
        self.extrapolation.map_or(0.0, |e| {
            (roll_rad - e.hi_rad).max(0.0) - (e.lo_rad - roll_rad).max(0.0)
        })
    }

    /// When the model in use changed (at `roll_rad`): its trained roll
    /// range and how the error may leave it, with the pitch filter's slope
    /// state restarted ([`TiltFilter::restart_slope`]). Beyond the range
    /// the error's slope may differ from the model's tangent by about as
    /// much as the model's own slope varies over the range: s ~ N(0, σ_s²),
    /// σ_s the standard deviation of the model's slope over 16 equal steps
    /// across it (a straight error keeps its tangent; a curved or rippled
    /// one leaves the inclinometer free to move s). How it bends is not
    /// estimated (with d² leverage a curvature state takes the angle's own
    /// motion for it) but counts in σ: κ, the RMS of the model's second
    /// derivative over the same steps ([`Self::unchecked_bias_variance`]).
    fn refresh_extrapolation(&mut self, roll_rad: f64) {
        let beyond = self.beyond_rad(roll_rad);
        if self.config.correction != Correction::Anfis || self.anfis().rules().is_empty() {
            if self.extrapolation.take().is_some()
                && let Some(f) = self.pitch.as_mut()
            {
                f.restart_slope(beyond, 0.0);
            }
            return;
        }
        let (chosen, version) = (self.chosen, self.anfis().version());
        if self
            .extrapolation
            .is_some_and(|e| (e.chosen, e.version) == (chosen, version))
        {
            return;
        }
        let model = self.anfis();
        let (lo, hi) = model.trained_roll_range_rad();
        const STEPS: usize = 16;
        let (slope_var, curvature_rms, span_rad) = if hi > lo {
            let h = (hi - lo) / STEPS as f64;
            let at: [f64; STEPS + 1] =
                std::array::from_fn(|i| model.output(lo + h * i as f64, None));
            let slopes = at.windows(2).map(|w| (w[1] - w[0]) / h);
            let mean = slopes.clone().sum::<f64>() / STEPS as f64;
            let slope_var = slopes.map(|s| (s - mean).powi(2)).sum::<f64>() / STEPS as f64;
            let curvature_var = at
                .windows(3)
                .map(|w| ((w[2] - 2.0 * w[1] + w[0]) / (h * h)).powi(2))
                .sum::<f64>()
                / (STEPS - 1) as f64;
            let (min, max) = at
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            (slope_var, curvature_var.sqrt(), max - min)
        } else {
            (0.0, 0.0, 0.0)
        };
        let guard_rad = model.config().extrapolation_rad;
        // The tangent beyond each edge, read off the model between the
        // edge and the guard, where it runs straight.
        let edge_slopes = if guard_rad > 0.0 {
            [
                (model.output(lo, None) - model.output(lo - guard_rad, None)) / guard_rad,
                (model.output(hi + guard_rad, None) - model.output(hi, None)) / guard_rad,
            ]
        } else {
            [0.0; 2]
        };
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        let slope_var = finite(slope_var);
        if let Some(f) = self.pitch.as_mut() {
            f.restart_slope(beyond, slope_var);
        }
        self.extrapolation = Some(Extrapolation {
            chosen,
            version,
            lo_rad: lo,
            hi_rad: hi,
            slope_var,
            curvature_rms: finite(curvature_rms),
            span_rad: finite(span_rad),
            guard_rad,
            edge_slopes: edge_slopes.map(finite),
            side: 0.0,
        });
    }

    /// The roll `beyond_rad` past the trained range on the other side from
    /// where the slope state learned: it starts again from its prior
    /// (nothing to hand to the bias: the roll has crossed the range, where
    /// s does not act).
    fn keep_slope_to_its_side(&mut self, beyond_rad: f64) {
        let Some(e) = self.extrapolation.as_mut() else {
            return;
        };
        if beyond_rad == 0.0 {
            return;
        }
        let side = beyond_rad.signum();
        if e.side * side < 0.0
            && let Some(f) = self.pitch.as_mut()
        {
            f.restart_slope(0.0, e.slope_var);
        }
        e.side = side;
    }

    /// What the model's own error adds to the correction after the roll
    /// has travelled `roll_travel_rad` from where the laser last checked
    /// it, rad²: the difference of two residuals of the model, each of the
    /// variance its cross-validation expects (GCV), and independent once
    /// the roll has moved by a membership's width.
    fn model_variance(&self, roll_travel_rad: f64) -> f64 {
        if self.config.correction != Correction::Anfis {
            return 0.0;
        }
        let model = self.anfis();
        let gcv = model.gcv();
        let rules = model.rules();
        if rules.is_empty() || !gcv.is_finite() || gcv >= f64::MAX {
            return 0.0;
        }
        let width = model.mean_width_rad();
        let decorrelated = (roll_travel_rad / width.max(1e-9)).powi(2).min(1.0);
        2.0 * gcv * decorrelated
    }

    fn on_laser(&mut self, t: f64, pitch_deg: f64, roll_deg: f64) {
        let (pitch, roll) = (rad(pitch_deg), rad(roll_deg));
        // Whether the inclinometer vouches for the estimate the sample
        // meets: the check before passed and no step since.
        let continuity = self.laser_monitor.agreeing() && !self.step_watch.unverified();
        if self.laser.accept(t, pitch, roll).is_err() {
            self.stats.laser_dropped += 1;
            return;
        }
        self.stats.laser_used += 1;
        let noise = self.noise;
        // The laser against what was shown, carried to the sample's time
        // by the filters' rates (the shown value may be an inclinometer
        // period old), its variance grown as the prediction's.
        if let (Some((shown_t, shown)), Some(pitch_filter), Some(roll_filter)) =
            (self.shown, self.pitch.as_ref(), self.roll.as_ref())
        {
            let dt = t - shown_t;
            let against = |laser: f64, shown: (f64, f64), f: &TiltFilter, q| {
                let (predicted, variance) = f.carry(shown, dt, q);
                (laser - predicted, variance)
            };
            let (pitch_offset, pitch_variance) =
                against(pitch, shown[0], pitch_filter, &noise.pitch);
            let (roll_offset, roll_variance) = against(roll, shown[1], roll_filter, &noise.roll);
            let verdict = self.laser_dispute.judge(
                t,
                [pitch_offset, roll_offset],
                [pitch_variance, roll_variance],
                noise.r_laser,
                continuity
                    && self.laser_monitor.checks() >= 3 * self.config.anfis.min_samples
                    && !self.step_watch.explains([pitch_offset, roll_offset]),
                self.config.laser_dispute_max_s,
            );
            if verdict == LaserVerdict::LaserBack {
                self.laser_monitor.forgive();
            }
            let z = |offset: f64, variance: f64| offset.abs() / (variance + noise.r_laser).sqrt();
            self.laser_monitor
                .check(z(pitch_offset, pitch_variance).max(z(roll_offset, roll_variance)));
            if verdict == LaserVerdict::HoldOut {
                return;
            }
        }
        self.step_watch.laser_checked();
        let roll_now = self.roll.map(|f| f.angle());
        let unchecked = roll_now.map_or(0.0, |roll| self.unchecked_bias_variance(t, roll));
        let allowance = roll_now.and_then(|roll| self.bias_allowance(t, roll));
        if let Some(f) = self.pitch.as_mut() {
            // The bias may have moved since the previous laser sample.
            if let Some(allowance) = allowance {
                f.inflate_bias(allowance);
            }
            let (h, r) = laser_row(f, t, &noise.pitch, noise.r_laser);
            // Laser samples further off than the filter allows, on average
            // over the last few, show what the bias allowance missed: the
            // excess goes to the bias's variance (innovation-based
            // covariance matching of Q_b, Mehra 1972).
            let innovation = f.innovation(h, pitch, r);
            // Beyond S and what the estimate's σ already counted as
            // unchecked (the drift since the previous sample, which the
            // laser row does not see: it has no bias entry).
            let expected = innovation.variance + unchecked;
            self.pitch_laser_error
                .add(innovation.value.powi(2) - expected, expected.powi(-2));
            let nis = innovation.value.powi(2) / innovation.variance;
            self.laser_nis.add(nis);
            let excess = self.laser_nis.mean - 1.0;
            if excess > 0.0 {
                f.inflate_bias(excess * innovation.variance);
            }
            f.update(h, pitch, r);
        }
        self.last_laser_roll = roll_now.map(|r| (t, r));
        if let Some(f) = self.roll.as_mut() {
            let (h, r) = laser_row(f, t, &noise.roll, noise.r_laser);
            let innovation = f.update(h, roll, r);
            self.roll_laser_error.add(
                innovation.value.powi(2) - innovation.variance,
                innovation.variance.powi(-2),
            );
        }
        self.tuning
            .curvature
            .observe(t, pitch, roll, self.laser.period_s());
        self.pending_laser.push((t, pitch, roll));
        if self.pending_laser.len() > MAX_PENDING_LASER {
            self.pending_laser.remove(0);
            self.stats.laser_unpaired += 1;
        }
        self.pair_pending();
        if let Some(roll) = roll_now {
            self.refresh_extrapolation(roll);
        }
    }

    /// The half-width of the inclinometer window a laser sample is paired
    /// over: [`PAIR_WINDOW_AVERAGES`] times as long as the filter averages
    /// (short where the shield moves fast against the noise, long where the
    /// inclinometer is noisy and the motion smooth), at least two periods
    /// and at most `pair_window_s`.
    fn pair_window_s(&self) -> f64 {
        let period = self.incl_period.get();
        let averaged = self.noise.pitch_fit.map_or(f64::INFINITY, |f| {
            f.readings_averaged(self.noise.pitch.rate, period)
        });
        (PAIR_WINDOW_AVERAGES * averaged * period)
            .min(self.config.pair_window_s)
            .max(2.0 * period)
    }

    /// Pairs waiting laser samples the inclinometer has now passed by the
    /// pairing window.
    fn pair_pending(&mut self) {
        let Some(newest) = self.history.newest_t() else {
            return;
        };
        if self.pending_laser.is_empty() {
            return;
        }
        let window = self.pair_window_s();
        // Whether a pair made training due, and whether one found the model young.
        let mut due: Option<bool> = None;
        while let Some(&(t, pitch, _)) = self.pending_laser.first() {
            if t + window > newest {
                break;
            }
            self.pending_laser.remove(0);
            if let Some(young) = self.pair(t, pitch, window) {
                due = Some(due.unwrap_or(false) || young);
            }
        }
        if let Some(young) = due {
            self.train(young);
        }
    }

    /// Trains the model in use once on the pairs added (however many this
    /// reading paired, `young` if one found the model young); queues the
    /// other candidates when they are due too.
    fn train(&mut self, young: bool) {
        // The model in use trains every time, the other candidates every
        // [`CANDIDATES_EVERY`]th time (warm, they stay close in between),
        // and while young.
        self.trainings += 1;
        // Every pair this reading made is in the training, those after
        // the one that made it due too.
        self.pairs_untrained = 0;
        let chosen = self.chosen;
        if self.trainings.is_multiple_of(CANDIDATES_EVERY) || young {
            for i in (0..self.models.len()).filter(|&i| i != chosen) {
                if !self.candidates_due.contains(&i) {
                    self.candidates_due.push(i);
                }
            }
        }
        // One shift of the bias for the retrain and, with no candidate
        // waiting, the choice that follows it.
        self.keeping_the_estimate(|engine| {
            engine.models[chosen].train();
            if engine.candidates_due.is_empty() {
                engine.choose_model();
            }
        });
    }

    /// Trains the next candidate model due, at most
    /// [`CANDIDATE_TRAININGS_PER_READING`] per reading; once none is left,
    /// chooses among the models.
    fn train_due_candidate(&mut self) {
        if self.candidates_due.is_empty() {
            return;
        }
        let take = CANDIDATE_TRAININGS_PER_READING.min(self.candidates_due.len());
        for i in self.candidates_due.drain(..take) {
            // A queued candidate is not the model in use (the choice waits
            // for the queue), so its training leaves the estimate alone.
            if let Some(model) = self.models.get_mut(i) {
                model.train();
            }
        }
        if self.candidates_due.is_empty() {
            let before = self.chosen;
            self.keeping_the_estimate(Self::choose_model);
            // What the slope state knows of the model in use's range is
            // made again for a new model, as after a laser sample's pairs.
            if self.chosen != before
                && let Some(roll) = self.roll.map(|f| f.angle())
            {
                self.refresh_extrapolation(roll);
            }
        }
    }

    /// The candidate generalised cross-validation prefers takes over,
    /// by a clear margin (no flapping between near equals).
    fn choose_model(&mut self) {
        let best = (0..self.models.len())
            .min_by(|&a, &b| self.models[a].gcv().total_cmp(&self.models[b].gcv()))
            .unwrap_or(0);
        if self.models[best].gcv() < GCV_SWITCH * self.models[self.chosen].gcv() {
            self.chosen = best;
        }
    }

    /// Runs `change` on the models; the filter's bias moves with the
    /// correction at the current roll and temperature, so the estimate
    /// does not jump at a retrain or a change of model.
    fn keeping_the_estimate(&mut self, change: impl FnOnce(&mut Self)) {
        let now = self.newest.map(|n| (n.roll_rad, n.temp_c));
        let before = now.map(|(r, tc)| self.correction_at(r, tc));
        change(self);
        let after = now.map(|(r, tc)| self.correction_at(r, tc));
        if let (Some(before), Some(after), Some(f)) = (before, after, self.pitch.as_mut()) {
            f.shift_bias(after - before);
        }
    }

    /// Eq. 16: the pitch error at a laser instant, from the inclinometer
    /// around it, added to the training sets. `Some` when training is due,
    /// holding whether the model in use is young (every candidate trains).
    fn pair(&mut self, t: f64, laser_pitch: f64, window: f64) -> Option<bool> {
        // The inclinometer at t: a line through the window of readings. The
        // roll moves over the window, and with it the inclinometer's error:
        // a line through a curved error sits (q₋ + q₊ − 2q₀)/6 off it at the
        // middle (for a quadratic over a symmetric window), which the
        // current model's curvature between the window's ends supplies.
        let points = || self.history.around(t, window);
        let continuous = points()
            .zip(points().skip(1))
            .all(|(a, b)| b.t - a.t <= self.config.pair_max_gap_s);
        let pitch = local_line(t, points().map(|p| (p.t, p.pitch_rad)));
        let roll = local_line(t, points().map(|p| (p.t, p.roll_rad)));
        let ends = points().next().zip(points().last());
        let (Some(pitch), Some(roll), Some((first, last)), true) = (pitch, roll, ends, continuous)
        else {
            self.stats.laser_unpaired += 1;
            return None;
        };
        let (first, last) = (*first, *last);
        let temp_c = self.history.nearest(t).and_then(|p| p.temp_c);
        let middle = self.correction_at(roll, temp_c);
        let curvature = (self.correction_at(first.roll_rad, first.temp_c)
            + self.correction_at(last.roll_rad, last.temp_c)
            - 2.0 * middle)
            / 6.0;
        let incl_pitch = pitch + curvature;
        let error = laser_pitch - incl_pitch;
        let (lo, hi) = self.anfis().roll_range_rad();
        let fit_rmse = self.anfis().fit_rmse_rad();
        for model in &mut self.models {
            model.add_sample(TrainingSample {
                t,
                roll_rad: roll,
                error_rad: error,
                temp_c,
                seq: 0,
            });
        }
        self.pairs_untrained += 1;
        if self.config.correction == Correction::None {
            return None;
        }
        // Retrain when the model has something to learn: while it is young,
        // when the pair is a surprise (beyond the roll it was trained on, or
        // far off it), and otherwise every few laser samples.
        let young = self.anfis().samples().len() < 3 * self.config.anfis.min_samples;
        let outside = !(lo..=hi).contains(&roll);
        let surprise = (error - middle).abs() > SURPRISE_FIT_RMS * fit_rmse.max(rad(1e-3));
        let due = self.pairs_untrained as f64 * self.laser.period_s() >= TRAIN_EVERY_S;
        if !(young || outside || surprise || due) {
            return None;
        }
        Some(young)
    }

    /// The learned model and the noise in degrees, as `GET .../model` reports it.
    pub fn model_report(&self, frozen: bool) -> ModelReport {
        let model = self.anfis();
        let rules = model.rules();
        // The pairs' roll range as they are now (training, which also
        // records it, does not run with `correction=none`).
        let (lo, hi) = model.roll_range_rad();
        let (temp_coefficient, temp_ref) = model.temperature_term();
        let curve = if model.samples().is_empty() {
            Vec::new()
        } else {
            (0..CURVE_POINTS)
                .map(|i| {
                    let roll = lo + (hi - lo) * i as f64 / (CURVE_POINTS - 1) as f64;
                    CurvePoint {
                        roll_deg: deg(roll),
                        correction_deg: deg(self.correction_at(roll, Some(temp_ref))),
                    }
                })
                .collect()
        };
        let laser_seen = self.laser.last.is_some();
        // What the model misses at the newest roll: b, and beyond the
        // trained range s·d with it.
        let beyond = self.newest.map_or(0.0, |n| self.beyond_rad(n.roll_rad));
        let missed = self.pitch.filter(|_| laser_seen).map(|f| {
            let mut h = inclinometer_row(beyond);
            h[0] = 0.0;
            f.combination(h)
        });
        let n = &self.noise;
        let sd = |v: f64| deg(v.sqrt());
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
            samples: model
                .samples()
                .iter()
                .map(|s| SampleReport {
                    t: s.t,
                    roll_deg: deg(s.roll_rad),
                    error_deg: deg(s.error_rad),
                    temp_c: s.temp_c,
                })
                .collect(),
            fit_rmse_deg: deg(model.fit_rmse_rad()),
            temp_coefficient_deg_per_c: deg(temp_coefficient),
            temp_reference_c: temp_ref,
            frozen,
            version: model.version(),
            roll_offset_deg: self.roll.filter(|_| laser_seen).map(|f| -deg(f.bias())),
            pitch_bias_deg: missed.map(|(b, _)| deg(b)),
            pitch_bias_sigma_deg: missed.map(|(_, var)| sd(var)),
            noise: NoiseReport {
                mode: self.config.noise_mode,
                phase: self.newest.map_or(Phase::Vibrating, |n| n.phase),
                incl_pitch_quiet_deg: sd(n.r_pitch[0]),
                incl_pitch_vibrating_deg: sd(n.r_pitch[1]),
                incl_roll_quiet_deg: sd(n.r_roll[0]),
                incl_roll_vibrating_deg: sd(n.r_roll[1]),
                laser_deg: sd(n.r_laser),
                q_pitch_deg2_per_s: deg(deg(n.pitch.angle)),
                q_pitch_rate_deg2_per_s3: deg(deg(n.pitch.rate)),
                q_bias_deg2_per_s: deg(deg(n.bias.per_s)),
                q_bias_per_roll: n.bias.per_roll2,
                q_roll_deg2_per_s: deg(deg(n.roll.angle)),
                q_roll_rate_deg2_per_s3: deg(deg(n.roll.rate)),
                colour_tau_s: n.pitch_fit.map(|f| f.tau_s),
            },
        }
    }

    /// True while the laser is usable as of the newest inclinometer reading.
    pub fn laser_ok(&self) -> bool {
        self.newest
            .is_some_and(|n| self.laser.is_ok(n.t, self.config.dropout_factor))
    }
}

/// The laser's measurement row and variance at `t` for filter `f`: at or
/// after the filter's time, H = [1, 0, 0, 0] after predicting to `t`; before
/// it (a late sample), y = θ − θ̇·Δ with the noise grown by the process
/// noise over Δ.
fn laser_row(f: &mut TiltFilter, t: f64, q: &ProcessNoise, r: f64) -> ([f64; N], f64) {
    let lag = f.t.map_or(0.0, |ft| ft - t);
    if lag <= 0.0 {
        f.predict_to(t, q);
        return (H_LASER, r);
    }
    (
        [1.0, -lag, 0.0, 0.0],
        r + q.angle * lag + q.rate * lag * lag * lag / 3.0,
    )
}

/// The `attitude` engine as the registry lists it.
pub struct Attitude;

impl EngineDescriptor for Attitude {
    const SUMMARY: &'static str =
        "laser + inclinometer: pitch and roll, the inclinometer's pitch error learnt by an ANFIS";
    const SENSORS: &'static [SensorKind] = &[SensorKind::Laser, SensorKind::Inclinometer];
    const RETIRED: &'static [Retired] = RETIRED;
    type Params = AttitudeParams;
    type Engine = AttitudeEngine;
    type Estimate = AttitudeEstimate;
    type Model = ModelReport;

    fn create(params: Params) -> Result<AttitudeEngine, ParamError> {
        AttitudeEngine::new(params)
    }
    fn restore(snapshot: serde_json::Value) -> Result<AttitudeEngine, SnapshotError> {
        AttitudeEngine::restore(snapshot)
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
                temp_c,
            } => out.extend(self.on_inclinometer(reading.t, pitch_deg, roll_deg, temp_c)),
            SensorData::Laser {
                pitch_deg,
                roll_deg,
                ..
            } => self.on_laser(reading.t, pitch_deg, roll_deg),
            _ => return,
        }
        // After the reading: its estimate is out, and a change of model
        // is in place (extrapolation included) before the next one.
        self.train_due_candidate();
    }

    fn params(&self) -> &Params {
        &self.params
    }

    fn snapshot(&self) -> serde_json::Value {
        // Every field is a plain number, bool, string or list of them, and
        // the engine keeps them finite: serialising cannot fail.
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }

    fn model(&self) -> Option<EngineModel> {
        Some(EngineModel::Attitude(self.model_report(!self.laser_ok())))
    }
}

#[cfg(test)]
mod tests;
