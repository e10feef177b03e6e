//! The Takagi–Sugeno ANFIS that models the inclinometer's pitch error as a
//! function of roll (He et al. 2021, Sec. 3.2, Eq. 20–25), with a
//! temperature term fitted jointly with the consequents and the residuals
//! smoothed along the roll ([`super::residual`]) added:
//!
//! ê(β, T) = Σ ρ̄_i(β) (p_i0 + p_i1 β) + m(β) + c_T (T − T_ref)   (Eq. 24 + m + c_T)
//!
//! Beyond the roll range it was trained on, the model goes on along its
//! tangent at the edge (the slope over the last `min_width_rad` inside it)
//! up to the extrapolation guard, where it is held: the error is a smooth
//! function of roll, and its local slope at the edge is the best evidence
//! of where it goes next. (The Gaussian rules alone would go on along the
//! edge rule's consequent, a line fitted over that rule's whole support,
//! which on a curved error is the wrong slope.)
//!
//! The temperature enters linearly and alike in every rule (a datasheet's
//! temperature coefficient): a second fuzzy input would multiply the rules
//! for a term that is, for an inclinometer, a straight line. T_ref is the
//! training set's weighted mean temperature; without temperatures (or with
//! less than [`MIN_TEMP_SPREAD_C`] of spread) c_T stays 0.
//!
//! Training is the standard hybrid rule on a bounded, recency-weighted set of
//! (roll, pitch error) pairs: weighted least squares for the linear
//! consequents, then a gradient step on centres and widths with an adaptive
//! step length, warm-started from the current model. The set is stratified
//! by roll (each bin keeps its newest pairs), so regions visited long ago are
//! remembered; each rule is shrunk towards the set's global line (which
//! matters where a rule has few pairs). Each laser sample costs `epochs`
//! passes over at most `window` samples, however long the drive.
//!
//! All angles here are radians.

use std::collections::VecDeque;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::residual::{Residual, ResidualTable};
pub use super::training_set::TrainingSample;
use super::training_set::TrainingSet;

/// Most memberships a model may have (the engine's parameter range).
pub const MAX_MEMBERSHIPS: usize = 9;
/// Two consequents per rule and the temperature coefficient.
const MAX_PARAMS: usize = 2 * MAX_MEMBERSHIPS + 1;
/// Firing strengths below this add nothing a double can hold next to the
/// others (e^{−36}: six widths from a centre).
const NEGLIGIBLE_FIRING: f64 = 2.3e-16;
/// The memberships are spread afresh over the seen roll once its span has
/// grown by this factor since they were last spread.
const RESPREAD_GROWTH: f64 = 1.25;
/// Ridge on the temperature coefficient, °C²: where the roll and the
/// temperature moved together in the training pairs, their effects cannot
/// be told apart, and the roll (the documented cause) keeps the error
/// unless the temperature has varied on its own by more than about √ of
/// this. It keeps the roll's slope right for extrapolation.
const TEMP_RIDGE_C2: f64 = 0.25;
/// Weighted spread of the training temperatures, °C, below which the
/// temperature coefficient is not fitted (it would be noise).
pub const MIN_TEMP_SPREAD_C: f64 = 0.3;

/// How the model is shaped and trained.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AnfisConfig {
    /// Number of Gaussian memberships (rules), m₁ in Eq. 20.
    pub memberships: usize,
    /// Most training samples kept; older ones are forgotten.
    pub window: usize,
    /// Width of the roll bins the training set is stratified by.
    pub bin_width_rad: f64,
    /// Most samples kept per roll bin: a new sample replaces the oldest of
    /// its bin, so a roll region visited hours ago is not forgotten just
    /// because the machine has spent the time elsewhere.
    pub per_bin: usize,
    /// Age, in samples, at which a sample's weight has halved.
    pub half_life: f64,
    /// Floor of the recency weight, so the only samples of a roll region
    /// still count.
    pub min_weight: f64,
    /// Hybrid epochs run per new sample.
    pub epochs: usize,
    /// Samples needed before the rules are fitted; until then the output is
    /// the weighted mean error (a constant offset).
    pub min_samples: usize,
    /// Smallest membership width σ; also how far inside the edge of the
    /// trained roll range the tangent beyond it is taken.
    pub min_width_rad: f64,
    /// Smallest roll span the memberships are spread over.
    pub min_span_rad: f64,
    /// How far beyond the trained roll range the correction goes on along
    /// its tangent before it is held (extrapolation guard).
    pub extrapolation_rad: f64,
    /// Ridge weight pulling each consequent towards the global weighted line
    /// through the training set; matters for rules with little data.
    pub ridge: f64,
}

/// One fuzzy rule: a Gaussian membership and a first-order consequent.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rule {
    /// c_i of Eq. 20.
    pub centre_rad: f64,
    /// σ_i of Eq. 20.
    pub width_rad: f64,
    /// p_i0 of Eq. 23.
    pub p0_rad: f64,
    /// p_i1 of Eq. 23 (rad of error per rad of roll).
    pub p1: f64,
}

/// The model and its training set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Anfis {
    config: AnfisConfig,
    samples: TrainingSet,
    /// Empty until `min_samples` pairs have been seen.
    rules: Vec<Rule>,
    /// Recency-weighted mean error: the output before the rules exist.
    mean_error_rad: f64,
    /// Recency-weighted plane error = a + b·roll + c·(T − T_ref) through
    /// the training set: the prior each rule's consequent is shrunk towards.
    global_line: [f64; 3],
    /// c_T, rad of error per °C, and T_ref, °C.
    temp_coefficient: f64,
    temp_ref_c: f64,
    /// True when the training set's temperatures spread enough for c_T.
    temp_fitted: bool,
    /// Roll range of the training set when last trained, for the
    /// extrapolation guard (kept: `output` runs on every reading).
    roll_lo_rad: f64,
    roll_hi_rad: f64,
    /// Current gradient step length on centres and widths (adapted).
    step_rad: f64,
    /// The roll span the memberships were last spread over.
    #[serde(default)]
    spread_span_rad: f64,
    /// RMS residual of the model over the training set.
    fit_rmse_rad: f64,
    /// Generalised cross-validation score of the last training.
    gcv: f64,
    /// Times the model has been trained.
    version: u64,
    /// The rules' residuals smoothed along the roll, when leave-one-out
    /// finds them worth adding.
    residual: Option<ResidualTable>,
    #[serde(skip)]
    cache: FiringCache,
}

/// Normalised firing strengths ρ̄ (Eq. 22) of every rule for every training
/// sample, row-major (sample, rule): computed once per premise and shared by
/// the least squares, the cost and the gradient.
#[derive(Debug, Clone)]
struct Firings {
    rules: usize,
    weights: Vec<f64>,
}

impl Firings {
    fn row(&self, sample: usize) -> &[f64] {
        &self.weights[sample * self.rules..(sample + 1) * self.rules]
    }

    fn rows(&self) -> usize {
        self.weights.len() / self.rules.max(1)
    }
}

/// The firings of the training set under the current premises, kept
/// between trainings so that a new pair costs one row, not a recomputation.
/// It is derived data: never serialised, rebuilt when missing, and ignored
/// when models are compared.
#[derive(Debug, Clone, Default)]
struct FiringCache(Option<Firings>);

impl PartialEq for FiringCache {
    fn eq(&self, _other: &Self) -> bool {
        true
    }
}

/// ê of Eq. 24 for one sample, given its normalised firings.
fn blend(rules: &[Rule], firing: &[f64], x: f64) -> f64 {
    rules
        .iter()
        .zip(firing)
        .map(|(r, w)| w * (r.p0_rad + r.p1 * x)) // Eq. 23
        .sum()
}

impl Anfis {
    /// An untrained model.
    pub fn new(config: AnfisConfig) -> Anfis {
        Anfis {
            config,
            samples: TrainingSet::new(),
            rules: Vec::new(),
            mean_error_rad: 0.0,
            global_line: [0.0, 0.0, 0.0],
            temp_coefficient: 0.0,
            temp_ref_c: 20.0,
            temp_fitted: false,
            roll_lo_rad: 0.0,
            roll_hi_rad: 0.0,
            step_rad: 0.0,
            spread_span_rad: 0.0,
            fit_rmse_rad: 0.0,
            gcv: f64::MAX,
            version: 0,
            residual: None,
            cache: FiringCache::default(),
        }
    }

    /// Takes `config` (rebuilt from validated parameters) after a restore,
    /// refusing state that does not fit it or is not finite.
    pub fn reconfigure(&mut self, config: AnfisConfig) -> Result<(), String> {
        if !self.rules.is_empty() && self.rules.len() != config.memberships {
            return Err(format!(
                "{} ANFIS rules for {} memberships",
                self.rules.len(),
                config.memberships
            ));
        }
        if let Some(r) = self.rules.iter().find(|r| {
            !(r.centre_rad.is_finite()
                && r.width_rad.is_finite()
                && r.width_rad > 0.0
                && r.p0_rad.is_finite()
                && r.p1.is_finite())
        }) {
            return Err(format!("ANFIS rule {r:?} is not usable"));
        }
        if self.samples.len() > config.window {
            return Err(format!(
                "{} training pairs for a window of {}",
                self.samples.len(),
                config.window
            ));
        }
        if self.samples.iter().any(|s| {
            !(s.roll_rad.is_finite()
                && s.error_rad.is_finite()
                && s.temp_c.is_none_or(f64::is_finite))
        }) || !(self.temp_coefficient.is_finite() && self.temp_ref_c.is_finite())
        {
            return Err("a training pair or the temperature term is not finite".to_string());
        }
        let range_ok = self.roll_lo_rad.is_finite()
            && self.roll_hi_rad.is_finite()
            && self.roll_lo_rad <= self.roll_hi_rad;
        if !range_ok {
            return Err(format!(
                "trained roll range {}…{} rad is not usable",
                self.roll_lo_rad, self.roll_hi_rad
            ));
        }
        if self.residual.as_ref().is_some_and(|r| !r.is_valid()) {
            return Err("the smoothed residuals are not usable".to_string());
        }
        self.config = config;
        self.cache = FiringCache::default();
        Ok(())
    }

    /// The training configuration.
    pub fn config(&self) -> &AnfisConfig {
        &self.config
    }

    /// The rules, empty before the model has enough samples.
    pub fn rules(&self) -> &[Rule] {
        &self.rules
    }

    /// The training set, oldest first.
    pub fn samples(&self) -> &VecDeque<TrainingSample> {
        &self.samples
    }

    /// RMS residual over the training set after the last training.
    pub fn fit_rmse_rad(&self) -> f64 {
        self.fit_rmse_rad
    }

    /// Times the model has been trained.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Roll range covered by the training set as it is now (infinite
    /// bounds when it is empty).
    pub fn roll_range_rad(&self) -> (f64, f64) {
        self.samples
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
                (lo.min(s.roll_rad), hi.max(s.roll_rad))
            })
    }

    /// Mean width σ of the memberships, rad (NaN before the rules exist).
    pub fn mean_width_rad(&self) -> f64 {
        self.rules.iter().map(|r| r.width_rad).sum::<f64>() / self.rules.len() as f64
    }

    /// Roll range of the training set when the model was last trained
    /// (what its extrapolation guard holds to), rad.
    pub fn trained_roll_range_rad(&self) -> (f64, f64) {
        (self.roll_lo_rad, self.roll_hi_rad)
    }

    /// Recency-weighted mean error of the training set.
    pub fn mean_error_rad(&self) -> f64 {
        self.mean_error_rad
    }

    /// The temperature coefficient c_T (rad/°C) and T_ref (°C); c_T is 0
    /// until the training temperatures spread.
    pub fn temperature_term(&self) -> (f64, f64) {
        (self.temp_coefficient, self.temp_ref_c)
    }

    /// The modelled pitch error ê_a = f(β, T) (Eq. 17 with the temperature
    /// term). Without a temperature the term is taken at T_ref.
    pub fn output(&self, roll_rad: f64, temp_c: Option<f64>) -> f64 {
        let temp = self.temp_coefficient * self.temp_offset(temp_c);
        if self.rules.is_empty() {
            return self.mean_error_rad + temp;
        }
        let x = self.guard(roll_rad);
        let edge = x.clamp(self.roll_lo_rad, self.roll_hi_rad);
        if x == edge {
            return self.roll_term(x) + temp;
        }
        // Beyond the trained range: along the tangent at the edge.
        let span = self.roll_hi_rad - self.roll_lo_rad;
        let inward = if x > edge { -1.0 } else { 1.0 };
        let inner = edge + inward * self.config.min_width_rad.min(span);
        let at_edge = self.roll_term(edge);
        if inner == edge {
            return at_edge + temp;
        }
        let slope = (at_edge - self.roll_term(inner)) / (edge - inner);
        at_edge + slope * (x - edge) + temp
    }

    /// The rules' blend (Eq. 24) plus the smoothed residual at `x`.
    fn roll_term(&self, x: f64) -> f64 {
        let mut firing = [0.0; MAX_MEMBERSHIPS];
        let firing = &mut firing[..self.rules.len()];
        fire_into(&self.rules, x, firing);
        blend(&self.rules, firing, x) + self.residual.as_ref().map_or(0.0, |r| r.at(x))
    }

    /// T − T_ref, 0 without a temperature (or while c_T is not fitted).
    fn temp_offset(&self, temp_c: Option<f64>) -> f64 {
        match temp_c {
            Some(t) if self.temp_fitted => t - self.temp_ref_c,
            _ => 0.0,
        }
    }

    /// Holds the input within the trained range widened by the guard.
    fn guard(&self, roll_rad: f64) -> f64 {
        let margin = self.config.extrapolation_rad;
        roll_rad.clamp(self.roll_lo_rad - margin, self.roll_hi_rad + margin)
    }

    /// Eq. 20–22 for every training sample.
    fn firings(&self, rules: &[Rule]) -> Firings {
        let m = rules.len();
        let mut weights = vec![0.0; self.samples.len() * m];
        for (s, row) in self.samples.iter().zip(weights.chunks_exact_mut(m.max(1))) {
            fire_into(rules, s.roll_rad, row);
        }
        Firings { rules: m, weights }
    }

    /// Adds a pair to the training set ([`TrainingSet::add`]). Does not train.
    pub fn add_sample(&mut self, sample: TrainingSample) {
        let added = self.samples.add(sample, &self.config);
        // Keep the cached firings in step with the samples.
        let rules = &self.rules;
        if let Some(cache) = self.cache.0.as_mut() {
            if let Some(index) = added.removed {
                cache
                    .weights
                    .drain(index * cache.rules..(index + 1) * cache.rules);
            }
            let start = cache.weights.len();
            cache.weights.resize(start + cache.rules, 0.0);
            fire_into(rules, added.roll_rad, &mut cache.weights[start..]);
        }
    }

    /// Recency weights of the training set, oldest first.
    fn weights(&self) -> Vec<f64> {
        self.samples.weights(&self.config)
    }

    /// Trains on the current set: hybrid epochs warm-started from the
    /// current rules (or the weighted mean until there are enough samples).
    pub fn train(&mut self) {
        if self.samples.is_empty() {
            return;
        }
        let weights = self.weights();
        let total_w: f64 = weights.iter().sum();
        self.mean_error_rad = self
            .samples
            .iter()
            .zip(&weights)
            .map(|(s, w)| w * s.error_rad)
            .sum::<f64>()
            / total_w;
        let (lo, hi) = self.roll_range_rad();
        self.roll_lo_rad = lo;
        self.roll_hi_rad = hi;
        self.set_temperature_reference(&weights);
        self.global_line = self.fit_plane(&weights);
        self.version += 1;
        if self.samples.len() < self.config.min_samples {
            self.temp_coefficient = 0.0;
            self.fit_rmse_rad = self.rmse_of_constant();
            return;
        }
        // Memberships spread over the roll seen, again whenever the roll
        // has gone well beyond where they were spread: gradient steps on
        // the premises move them only slowly.
        if self.rules.is_empty() || self.span_rad() > RESPREAD_GROWTH * self.spread_span_rad {
            self.rules = self.initial_rules();
            self.spread_span_rad = self.span_rad();
            self.step_rad = 0.1 * self.span_rad();
            self.cache = FiringCache::default();
        }
        let mut firings = match self.cache.0.take() {
            Some(cached)
                if cached.rules == self.rules.len() && cached.rows() == self.samples.len() =>
            {
                cached
            }
            _ => self.firings(&self.rules),
        };
        let (mut cost, mut dof) = match self.fit_consequents(&self.rules, &firings, &weights) {
            Some(fit) => {
                self.rules = fit.rules;
                self.temp_coefficient = fit.temp_coefficient;
                (fit.cost, fit.dof)
            }
            None => {
                // The rules may have just been spread afresh: the old
                // table smoothed another model's residuals.
                self.residual = None;
                return;
            }
        };
        for _ in 0..self.config.epochs {
            (firings, cost, dof) = self.premise_step(firings, &weights, cost, dof);
        }
        self.fit_rmse_rad = self.rmse(&firings);
        self.residual = self.smooth_residuals(&firings, &weights);
        // Generalised cross-validation (Golub, Heath & Wahba 1979): the
        // weighted mean squared residual over (1 − df/n)², with df the
        // consequents' degrees of freedom plus the two premise parameters
        // of every rule, and n the weights' effective count.
        let total_w: f64 = weights.iter().sum();
        let n_eff = total_w * total_w / weights.iter().map(|w| w * w).sum::<f64>();
        let df = dof + 2.0 * self.rules.len() as f64;
        self.gcv = if df < n_eff {
            (2.0 * cost / total_w) / (1.0 - df / n_eff).powi(2)
        } else {
            f64::MAX
        };
        self.cache = FiringCache(Some(firings));
    }

    /// The rules' residuals at the training pairs, smoothed along the roll
    /// ([`ResidualTable::fit`]).
    fn smooth_residuals(&self, firings: &Firings, weights: &[f64]) -> Option<ResidualTable> {
        let residuals: Vec<Residual> = self
            .samples
            .iter()
            .zip(weights)
            .enumerate()
            .map(|(j, (s, &weight))| Residual {
                roll_rad: s.roll_rad,
                weight,
                residual_rad: self.rule_target(s) - blend(&self.rules, firings.row(j), s.roll_rad),
            })
            .collect();
        ResidualTable::fit(
            &residuals,
            self.roll_lo_rad,
            self.roll_hi_rad,
            self.mean_width_rad(),
        )
    }

    /// The generalised cross-validation score of the last training
    /// (`f64::MAX` before the rules exist): lower generalises better. It
    /// scores the rules alone, before the smoothed residual is added
    /// (which only lowers the error where leave-one-out finds it does), so
    /// as the model's error it errs on the large side.
    pub fn gcv(&self) -> f64 {
        self.gcv
    }

    /// T_ref = the weighted mean temperature of the pairs that have one;
    /// the temperature term is fitted only if they spread enough.
    fn set_temperature_reference(&mut self, weights: &[f64]) {
        let (mut sw, mut st) = (0.0, 0.0);
        for (s, &w) in self.samples.iter().zip(weights) {
            if let Some(t) = s.temp_c {
                sw += w;
                st += w * t;
            }
        }
        if sw <= 0.0 {
            self.temp_fitted = false;
            return;
        }
        let mean = st / sw;
        let spread = (self
            .samples
            .iter()
            .zip(weights)
            .filter_map(|(s, &w)| s.temp_c.map(|t| w * (t - mean) * (t - mean)))
            .sum::<f64>()
            / sw)
            .sqrt();
        self.temp_ref_c = mean;
        self.temp_fitted = spread >= MIN_TEMP_SPREAD_C;
    }

    fn span_rad(&self) -> f64 {
        (self.roll_hi_rad - self.roll_lo_rad).max(self.config.min_span_rad)
    }

    /// Memberships spread evenly over the seen roll range (at least the
    /// minimum span), neighbours crossing at half height.
    fn initial_rules(&self) -> Vec<Rule> {
        let m = self.config.memberships;
        let span = self.span_rad();
        let mid = 0.5 * (self.roll_lo_rad + self.roll_hi_rad);
        let lo = mid - 0.5 * span;
        let spacing = if m > 1 { span / (m - 1) as f64 } else { span };
        // exp(−(s/2)²/σ²) = ½  ⇒  σ = s / (2 √ln 2)
        let width =
            (spacing / (2.0 * std::f64::consts::LN_2.sqrt())).max(self.config.min_width_rad);
        (0..m)
            .map(|i| Rule {
                centre_rad: if m > 1 { lo + i as f64 * spacing } else { mid },
                width_rad: width,
                p0_rad: self.mean_error_rad,
                p1: 0.0,
            })
            .collect()
    }

    /// Weighted least squares for the consequents and c_T given the
    /// premises (forward half of the hybrid rule), with the cost ½ Σ w r²
    /// (Eq. 25 summed over the set).
    fn fit_consequents(
        &self,
        premises: &[Rule],
        firings: &Firings,
        weights: &[f64],
    ) -> Option<Fit> {
        let m = premises.len();
        let temp_column = self.temp_fitted;
        let n_params = 2 * m + usize::from(temp_column);
        // Normal equations accumulated in a fixed array (upper triangle):
        // this loop is the training's hot spot.
        let mut normal = [[0.0_f64; MAX_PARAMS]; MAX_PARAMS];
        let mut rhs = [0.0_f64; MAX_PARAMS];
        let mut row = [0.0_f64; MAX_PARAMS];
        let mut total_w = 0.0;
        let mut weighted_sq = 0.0;
        // Only the rules a sample fires noticeably enter its products: far
        // from a centre a Gaussian is nothing, and a sample fires a few
        // neighbouring rules, so the cost grows with the rules, not their square.
        let mut live = [0usize; MAX_PARAMS];
        for (j, (s, &w)) in self.samples.iter().zip(weights).enumerate() {
            let firing = firings.row(j);
            let mut n_live = 0;
            for i in 0..m {
                if firing[i] > NEGLIGIBLE_FIRING {
                    row[2 * i] = firing[i];
                    row[2 * i + 1] = firing[i] * s.roll_rad;
                    live[n_live] = 2 * i;
                    live[n_live + 1] = 2 * i + 1;
                    n_live += 2;
                }
            }
            if temp_column {
                row[2 * m] = self.temp_offset(s.temp_c);
                live[n_live] = 2 * m;
                n_live += 1;
            }
            let live = &live[..n_live];
            for (k, &a) in live.iter().enumerate() {
                let wa = w * row[a];
                rhs[a] += wa * s.error_rad;
                for &b in &live[k..] {
                    normal[a][b] += wa * row[b];
                }
            }
            total_w += w;
            weighted_sq += w * s.error_rad * s.error_rad;
        }
        // Kept before the ridge is added: the cost below is of the data alone.
        let (data_normal, data_rhs) = (normal, rhs);
        // Ridge towards the global plane, the slope measured across the
        // span; the temperature coefficient is pulled towards 0 as by
        // TEMP_RIDGE_C2 of extra temperature spread at the reference.
        let lambda = self.config.ridge * total_w;
        let span = self.span_rad();
        let [a, b, _] = self.global_line;
        for i in 0..m {
            normal[2 * i][2 * i] += lambda;
            rhs[2 * i] += lambda * a;
            normal[2 * i + 1][2 * i + 1] += lambda * span * span;
            rhs[2 * i + 1] += lambda * span * span * b;
        }
        if temp_column {
            normal[2 * m][2 * m] += TEMP_RIDGE_C2 * total_w;
        }
        let normal = DMatrix::from_fn(n_params, n_params, |r, c| {
            if r <= c { normal[r][c] } else { normal[c][r] }
        });
        let rhs = DVector::from_column_slice(&rhs[..n_params]);
        let cholesky = normal.cholesky()?;
        let solution = cholesky.solve(&rhs);
        if solution.iter().any(|x| !x.is_finite()) {
            return None;
        }
        // Degrees of freedom of the ridge fit: trace((N + Λ)⁻¹ N).
        let data = DMatrix::from_fn(n_params, n_params, |r, c| {
            if r <= c {
                data_normal[r][c]
            } else {
                data_normal[c][r]
            }
        });
        let dof = cholesky.solve(&data).trace();
        let rules: Vec<Rule> = premises
            .iter()
            .enumerate()
            .map(|(i, r)| Rule {
                p0_rad: solution[2 * i],
                p1: solution[2 * i + 1],
                ..*r
            })
            .collect();
        // Eq. 25 summed with the weights, from the normal equations:
        // ½ Σ w (e − aᵀp)² = ½ (Σ w e² − 2 pᵀ b + pᵀ N p).
        let p = solution.as_slice();
        let mut quadratic = 0.0;
        for a in 0..n_params {
            quadratic += p[a] * p[a] * data_normal[a][a];
            for b in a + 1..n_params {
                quadratic += 2.0 * p[a] * p[b] * data_normal[a][b];
            }
        }
        let linear: f64 = (0..n_params).map(|a| p[a] * data_rhs[a]).sum();
        let cost = (0.5 * (weighted_sq - 2.0 * linear + quadratic)).max(0.0);
        Some(Fit {
            rules,
            temp_coefficient: if temp_column { p[2 * m] } else { 0.0 },
            cost,
            dof,
        })
    }

    /// Weighted least-squares plane error = a + b·roll + c·(T − T_ref)
    /// through the training set; the roll slope is 0 when the roll has not
    /// varied enough to give one, c is 0 without temperature spread.
    fn fit_plane(&self, weights: &[f64]) -> [f64; 3] {
        // Centred sums: x = roll, u = T − T_ref, y = error.
        let (mut sw, mut sx, mut su, mut sy) = (0.0, 0.0, 0.0, 0.0);
        for (s, &w) in self.samples.iter().zip(weights) {
            sw += w;
            sx += w * s.roll_rad;
            su += w * self.temp_offset(s.temp_c);
            sy += w * s.error_rad;
        }
        let (mx, mu, my) = (sx / sw, su / sw, sy / sw);
        let (mut sxx, mut sxu, mut suu, mut sxy, mut suy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (s, &w) in self.samples.iter().zip(weights) {
            let dx = s.roll_rad - mx;
            let du = self.temp_offset(s.temp_c) - mu;
            let dy = s.error_rad - my;
            sxx += w * dx * dx;
            sxu += w * dx * du;
            suu += w * du * du;
            sxy += w * dx * dy;
            suy += w * du * dy;
        }
        // Below a tenth of the minimum span of roll spread, a slope is noise.
        let min_spread = 0.1 * self.config.min_span_rad;
        let roll_ok = sxx > sw * min_spread * min_spread;
        let temp_ok = self.temp_fitted && suu > 0.0;
        // The temperature coefficient carries the same ridge as in
        // `fit_consequents`: only temperature spread the roll does not
        // share can give it.
        let suu = suu + TEMP_RIDGE_C2 * sw;
        let (b, c) = match (roll_ok, temp_ok) {
            (true, true) => {
                let det = sxx * suu - sxu * sxu;
                ((sxy * suu - suy * sxu) / det, (suy * sxx - sxy * sxu) / det)
            }
            (true, false) => (sxy / sxx, 0.0),
            (false, true) => (0.0, suy / suu),
            (false, false) => (0.0, 0.0),
        };
        [my - b * mx - c * mu, b, c]
    }

    /// What the rules must explain for a sample: its error less the
    /// temperature term.
    fn rule_target(&self, s: &TrainingSample) -> f64 {
        s.error_rad - self.temp_coefficient * self.temp_offset(s.temp_c)
    }

    /// The cost summed directly over the samples: the reference that the
    /// normal-equation form in `fit_consequents` is tested against.
    #[cfg(test)]
    fn cost(&self, rules: &[Rule], firings: &Firings, weights: &[f64]) -> f64 {
        self.samples
            .iter()
            .zip(weights)
            .enumerate()
            .map(|(j, (s, w))| {
                let r = blend(rules, firings.row(j), s.roll_rad) - self.rule_target(s);
                0.5 * w * r * r // Eq. 25 per sample, recency-weighted
            })
            .sum()
    }

    /// Backward half of the hybrid rule: one gradient step on centres and
    /// widths with the consequents held, kept only if the cost (with
    /// consequents refitted) drops; the step length grows after a success
    /// and halves after a failure.
    fn premise_step(
        &mut self,
        firings: Firings,
        weights: &[f64],
        cost: f64,
        dof: f64,
    ) -> (Firings, f64, f64) {
        let m = self.rules.len();
        let mut grad_c = vec![0.0; m];
        let mut grad_s = vec![0.0; m];
        for (j, (s, &w)) in self.samples.iter().zip(weights).enumerate() {
            let x = s.roll_rad;
            let firing = firings.row(j);
            let value = blend(&self.rules, firing, x);
            let r = value - self.rule_target(s); // ∂E/∂ê for E of Eq. 25
            for (i, rule) in self.rules.iter().enumerate() {
                let d = x - rule.centre_rad;
                let sigma2 = rule.width_rad * rule.width_rad;
                let y_i = rule.p0_rad + rule.p1 * x;
                // ∂ê/∂μ_i · μ_i = ρ̄_i (y_i − ê); ∂ ln μ_i/∂c_i = 2d/σ², ∂ ln μ_i/∂σ_i = 2d²/σ³
                let common = w * r * firing[i] * (y_i - value);
                grad_c[i] += common * 2.0 * d / sigma2;
                grad_s[i] += common * 2.0 * d * d / (sigma2 * rule.width_rad);
            }
        }
        let norm = grad_c
            .iter()
            .chain(&grad_s)
            .map(|g| g * g)
            .sum::<f64>()
            .sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return (firings, cost, dof);
        }
        let span = self.span_rad();
        let (lo, hi) = (self.roll_lo_rad - 0.5 * span, self.roll_hi_rad + 0.5 * span);
        let max_width = (4.0 * span).max(self.config.min_width_rad);
        let trial: Vec<Rule> = self
            .rules
            .iter()
            .enumerate()
            .map(|(i, r)| Rule {
                centre_rad: (r.centre_rad - self.step_rad * grad_c[i] / norm).clamp(lo, hi),
                width_rad: (r.width_rad - self.step_rad * grad_s[i] / norm)
                    .clamp(self.config.min_width_rad, max_width),
                ..*r
            })
            .collect();
        let trial_firings = self.firings(&trial);
        match self.fit_consequents(&trial, &trial_firings, weights) {
            Some(fit) if fit.cost < cost => {
                self.rules = fit.rules;
                self.temp_coefficient = fit.temp_coefficient;
                self.step_rad = (self.step_rad * 1.2).min(span);
                (trial_firings, fit.cost, fit.dof)
            }
            _ => {
                self.step_rad = (self.step_rad * 0.5).max(1e-6 * span);
                (firings, cost, dof)
            }
        }
    }

    fn rmse(&self, firings: &Firings) -> f64 {
        let n = self.samples.len() as f64;
        let sse: f64 = self
            .samples
            .iter()
            .enumerate()
            .map(|(j, s)| {
                (blend(&self.rules, firings.row(j), s.roll_rad) - self.rule_target(s)).powi(2)
            })
            .sum();
        (sse / n).sqrt()
    }

    fn rmse_of_constant(&self) -> f64 {
        let n = self.samples.len() as f64;
        let sse: f64 = self
            .samples
            .iter()
            .map(|s| (self.mean_error_rad - s.error_rad).powi(2))
            .sum();
        (sse / n).sqrt()
    }
}

/// Consequents and temperature coefficient fitted for given premises.
struct Fit {
    rules: Vec<Rule>,
    temp_coefficient: f64,
    cost: f64,
    /// Degrees of freedom the consequents used.
    dof: f64,
}

/// Eq. 20–22 for one input: the normalised firing strengths ρ̄ into `out`.
/// In log form: Eq. 21 is ρ_i = μ_i with one input, and scaling all ρ_i by
/// exp(−max ln μ) leaves ρ̄_i unchanged while keeping them from underflowing
/// together far from every centre.
fn fire_into(rules: &[Rule], x: f64, out: &mut [f64]) {
    let mut top = f64::NEG_INFINITY;
    for (log, r) in out.iter_mut().zip(rules) {
        *log = log_membership(r, x);
        top = top.max(*log);
    }
    let mut total = 0.0;
    for rho in out.iter_mut() {
        *rho = (*rho - top).exp();
        total += *rho;
    }
    for rho in out.iter_mut() {
        *rho /= total; // Eq. 22
    }
}

/// ln μ_i of Eq. 20: −(x − c_i)² / σ_i².
fn log_membership(rule: &Rule, x: f64) -> f64 {
    let d = x - rule.centre_rad;
    -(d * d) / (rule.width_rad * rule.width_rad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::angles::{deg, rad};

    fn config() -> AnfisConfig {
        AnfisConfig {
            memberships: 3,
            window: 400,
            bin_width_rad: rad(0.25),
            per_bin: 1000,
            half_life: 1.0e9,
            min_weight: 0.0,
            epochs: 1,
            min_samples: 6,
            min_width_rad: rad(0.1),
            min_span_rad: rad(1.0),
            extrapolation_rad: rad(0.5),
            ridge: 1e-6,
        }
    }

    fn rules() -> Vec<Rule> {
        vec![
            Rule {
                centre_rad: -1.0,
                width_rad: 1.0,
                p0_rad: 1.0,
                p1: 0.5,
            },
            Rule {
                centre_rad: 1.0,
                width_rad: 2.0,
                p0_rad: -1.0,
                p1: 2.0,
            },
        ]
    }

    #[test]
    fn output_matches_hand_computed_eq_20_to_24() {
        let mut model = Anfis::new(config());
        model.rules = rules();
        model.roll_lo_rad = -10.0;
        model.roll_hi_rad = 10.0;
        // x = 0: μ₁ = e^{−1}, μ₂ = e^{−1/4}; ρ̄₁ = μ₁/(μ₁+μ₂); y₁ = 1, y₂ = −1.
        let mu1 = (-1.0_f64).exp();
        let mu2 = (-0.25_f64).exp();
        let expected = (mu1 - mu2) / (mu1 + mu2); // y₁ = 1, y₂ = −1
        assert!((model.output(0.0, None) - expected).abs() < 1e-15);
        // x = 2: μ₁ = e^{−9}, μ₂ = e^{−1/4}; y₁ = 2, y₂ = 3.
        let mu1 = (-9.0_f64).exp();
        let expected = (mu1 * 2.0 + mu2 * 3.0) / (mu1 + mu2);
        assert!((model.output(2.0, None) - expected).abs() < 1e-15);
    }

    /// The hand-set [`rules`], trained over a roll range of −1…1 rad.
    fn hand_set_model() -> Anfis {
        let mut model = Anfis::new(config());
        model.rules = rules();
        model.roll_lo_rad = -1.0;
        model.roll_hi_rad = 1.0;
        model
    }

    #[test]
    fn far_inputs_neither_underflow_nor_explode() {
        let model = hand_set_model();
        // Held at the edge of the guarded range, not extrapolated to 1000.
        let edge = model.output(1.0 + model.config.extrapolation_rad, None);
        assert_eq!(model.output(1000.0, None), edge);
        assert!(model.output(-1000.0, None).is_finite());
    }

    #[test]
    fn beyond_the_trained_roll_it_goes_on_along_the_tangent_then_holds() {
        // Hand-set rules over a trained range of −1…1 rad, no residual
        // table: beyond each edge the output is the value at the edge plus
        // the secant slope over the last min_width (0.1° here) inside it
        // times the distance, up to the guard (0.5°), then held.
        let mut model = hand_set_model();
        let w = model.config.min_width_rad;
        let guard = model.config.extrapolation_rad;
        for (edge, outward) in [(1.0, 1.0), (-1.0, -1.0)] {
            let at_edge = model.output(edge, None);
            let slope = (at_edge - model.output(edge - outward * w, None)) / (outward * w);
            for beyond in [0.1 * guard, 0.5 * guard, guard] {
                let x = edge + outward * beyond;
                let expected = at_edge + slope * outward * beyond;
                assert!(
                    (model.output(x, None) - expected).abs() < 1e-12,
                    "{x}: {} against {expected}",
                    model.output(x, None)
                );
            }
            // Continuous at the edge, held past the guard.
            let just_outside = model.output(edge + outward * 1e-9, None);
            assert!((just_outside - at_edge).abs() < 1e-8);
            let at_guard = model.output(edge + outward * guard, None);
            assert_eq!(model.output(edge + outward * (guard + 0.3), None), at_guard);
        }
        // A single trained roll (lo = hi) has no slope: the value is held.
        model.roll_lo_rad = 0.2;
        model.roll_hi_rad = 0.2;
        assert_eq!(model.output(0.25, None), model.output(0.2, None));
        assert_eq!(model.output(0.1, None), model.output(0.2, None));
    }

    #[test]
    fn a_restored_model_with_an_unusable_range_or_table_is_refused() {
        // A ripple three rules cannot follow leaves residuals worth
        // smoothing.
        let mut model = Anfis::new(config());
        for i in 0..300 {
            let roll_deg = -1.5 + 3.0 * i as f64 / 300.0;
            let error_deg = 0.1 * (std::f64::consts::TAU * roll_deg / 2.0).sin();
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: rad(roll_deg),
                error_rad: rad(error_deg),
                temp_c: None,
                seq: 0,
            });
        }
        model.train();
        assert!(model.residual.is_some(), "no residual table");
        let config = model.config;
        assert!(model.clone().reconfigure(config).is_ok());
        let mut reversed = model.clone();
        (reversed.roll_lo_rad, reversed.roll_hi_rad) = (model.roll_hi_rad, model.roll_lo_rad);
        assert!(reversed.reconfigure(config).is_err());
        let mut bad_table = model.clone();
        if let Some(table) = bad_table.residual.as_mut() {
            table.width_rad = -1.0;
        }
        assert!(bad_table.reconfigure(config).is_err());
    }

    #[test]
    fn constant_output_until_enough_samples() {
        let mut model = Anfis::new(config());
        for (i, e) in [0.1, 0.3].into_iter().enumerate() {
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: i as f64,
                error_rad: e,
                temp_c: None,
                seq: 0,
            });
        }
        model.train();
        assert!(model.rules().is_empty());
        // Half-life 1e9 samples: the two weights differ by ~7e-10.
        assert!((model.output(5.0, None) - 0.2).abs() < 1e-9);
    }

    /// A smooth, clearly nonlinear error curve over roll −2°..4°, in degrees.
    fn curve_deg(roll_deg: f64) -> f64 {
        -0.30 + 0.04 * roll_deg - 0.012 * roll_deg * roll_deg + 0.02 * (1.1 * roll_deg).sin()
    }

    #[test]
    fn fits_a_known_nonlinear_curve_on_noise_free_data() {
        let mut model = Anfis::new(AnfisConfig {
            epochs: 1,
            ..config()
        });
        let n = 300;
        for i in 0..n {
            let roll_deg = -2.0 + 6.0 * ((i * 37) % n) as f64 / n as f64;
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: rad(roll_deg),
                error_rad: rad(curve_deg(roll_deg)),
                temp_c: None,
                seq: 0,
            });
        }
        for _ in 0..300 {
            model.train();
        }
        let grid: Vec<f64> = (0..=600).map(|i| -2.0 + 6.0 * i as f64 / 600.0).collect();
        let sse: f64 = grid
            .iter()
            .map(|&r| (deg(model.output(rad(r), None)) - curve_deg(r)).powi(2))
            .sum();
        let rmse_deg = (sse / grid.len() as f64).sqrt();
        assert!(rmse_deg <= 0.002, "ANFIS fit RMSE {rmse_deg}° > 0.002°");
        // And the fit is not trivially a constant or a line.
        let line_rmse = {
            let (a, b) = (curve_deg(-2.0), curve_deg(4.0));
            let sse: f64 = grid
                .iter()
                .map(|&r| (a + (b - a) * (r + 2.0) / 6.0 - curve_deg(r)).powi(2))
                .sum();
            (sse / grid.len() as f64).sqrt()
        };
        assert!(line_rmse > 10.0 * rmse_deg);
    }

    #[test]
    fn training_never_increases_the_cost() {
        let mut model = Anfis::new(config());
        for i in 0..50 {
            let roll_deg = -2.0 + 6.0 * i as f64 / 50.0;
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: rad(roll_deg),
                error_rad: rad(curve_deg(roll_deg)),
                temp_c: None,
                seq: 0,
            });
        }
        model.train();
        let w = model.weights();
        let cost = |m: &Anfis| m.cost(&m.rules, &m.firings(&m.rules), &w);
        let mut last = cost(&model);
        for _ in 0..20 {
            model.train();
            let now = cost(&model);
            assert!(now <= last * (1.0 + 1e-12));
            last = now;
        }
    }

    #[test]
    fn normal_equation_cost_matches_the_direct_sum() {
        let mut model = Anfis::new(AnfisConfig {
            half_life: 7.0,
            ..config()
        });
        for i in 0..60 {
            let roll_deg = -2.0 + 0.1 * i as f64;
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: rad(roll_deg),
                error_rad: rad(curve_deg(roll_deg) + 0.003 * ((i * 7) % 5) as f64),
                temp_c: None,
                seq: 0,
            });
        }
        model.train();
        let w = model.weights();
        let firings = model.firings(&model.rules);
        let fit = model.fit_consequents(&model.rules, &firings, &w).unwrap();
        let (rules, cost) = (fit.rules, fit.cost);
        let direct = model.cost(&rules, &firings, &w);
        assert!(
            (cost - direct).abs() <= 1e-9 * direct.max(1e-30),
            "{cost} vs {direct}"
        );
    }

    #[test]
    fn a_full_window_forgets_from_its_fullest_bin() {
        let mut model = Anfis::new(AnfisConfig {
            window: 20,
            ..config()
        });
        let add = |model: &mut Anfis, roll_deg: f64| {
            model.add_sample(TrainingSample {
                t: 0.0,
                roll_rad: rad(roll_deg),
                error_rad: 0.0,
                temp_c: None,
                seq: 0,
            })
        };
        for _ in 0..5 {
            add(&mut model, -2.0); // a region visited once, early
        }
        for _ in 0..100 {
            add(&mut model, 1.1); // then the machine stays elsewhere
        }
        let early = model
            .samples()
            .iter()
            .filter(|s| s.roll_rad < rad(-1.0))
            .count();
        assert_eq!(model.samples().len(), 20);
        assert_eq!(early, 5);
    }

    #[test]
    fn the_temperature_term_is_fitted_jointly_with_the_rules() {
        // e = curve(β) + 0.004 °/°C (T − 15), roll and temperature both
        // moving (not together): the fit recovers the coefficient and the
        // output follows the temperature at a fixed roll.
        let mut model = Anfis::new(config());
        for i in 0..300 {
            let roll_deg = -2.0 + 6.0 * ((i * 37) % 300) as f64 / 300.0;
            let temp_c = 10.0 + 10.0 * ((i * 53) % 300) as f64 / 300.0;
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: rad(roll_deg),
                error_rad: rad(curve_deg(roll_deg) + 0.004 * (temp_c - 15.0)),
                temp_c: Some(temp_c),
                seq: 0,
            });
        }
        for _ in 0..300 {
            model.train();
        }
        let (c_t, _) = model.temperature_term();
        assert!((deg(c_t) - 0.004).abs() < 2e-4, "c_T {} °/°C", deg(c_t));
        let at = |t: f64| deg(model.output(rad(1.0), Some(t)));
        let swing = at(20.0) - at(10.0);
        assert!((swing - 0.04).abs() < 2e-3, "{swing}");
        assert!((at(15.0) - curve_deg(1.0)).abs() < 3e-3, "{}", at(15.0));
        // Without a temperature the term is taken at T_ref.
        let (_, t_ref) = model.temperature_term();
        assert_eq!(
            model.output(rad(1.0), None),
            model.output(rad(1.0), Some(t_ref))
        );
    }

    #[test]
    fn a_constant_temperature_fits_no_coefficient() {
        let mut model = Anfis::new(config());
        for i in 0..50 {
            let roll_deg = -2.0 + 0.1 * i as f64;
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: rad(roll_deg),
                error_rad: rad(curve_deg(roll_deg)),
                temp_c: Some(18.0 + 0.01 * (i % 3) as f64),
                seq: 0,
            });
        }
        model.train();
        assert_eq!(model.temperature_term().0, 0.0);
    }

    #[test]
    fn window_is_bounded() {
        let mut model = Anfis::new(AnfisConfig {
            window: 20,
            ..config()
        });
        for i in 0..100 {
            model.add_sample(TrainingSample {
                t: i as f64,
                roll_rad: 0.0,
                error_rad: 0.0,
                temp_c: None,
                seq: 0,
            });
        }
        assert_eq!(model.samples().len(), 20);
        assert_eq!(model.samples()[0].t, 80.0);
    }
}
