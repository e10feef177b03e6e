//! Running the engine and the baselines over each trial and summarising
//! them per group of trials.

use super::*;

/// The engine's parameters as docs/engines/fuzzy.md tells an installer to set them
/// for this recording: defaults, `window_samples` half a second of samples
/// at `rate_hz`, `mag_inclination_deg` for Berlin (declination left at 0:
/// the heading offset is removed), then `assignments` (`name=value`) on top.
pub fn installer_params(rate_hz: f64, assignments: &[&str]) -> Result<Params, ParamError> {
    let window = (WINDOW_S * rate_hz).round().max(2.0);
    let base = [
        format!("window_samples={window}"),
        format!("mag_inclination_deg={BERLIN_INCLINATION_DEG}"),
    ];
    EngineKind::Fuzzy.params_from_assignments(
        base.iter()
            .map(String::as_str)
            .chain(assignments.iter().copied()),
    )
}

/// The kind of trial, from its name (BROAD's disturbance groups).
pub fn trial_group(name: &str) -> &'static str {
    const GROUPS: [(&str, &str); 7] = [
        ("undisturbed", "undisturbed"),
        ("tapping", "tapping"),
        ("vibration", "vibration"),
        ("stationary_magnet", "stationary magnet"),
        ("attached_magnet", "attached magnet"),
        ("office", "office"),
        ("mixed", "mixed"),
    ];
    GROUPS
        .iter()
        .find(|(key, _)| name.contains(key))
        .map_or("other", |(_, group)| group)
}

/// What the engine did on a trial (the reasons behind its errors).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct EngineDiagnostics {
    /// Seconds from the trial's start to the first aligned estimate.
    pub aligned_after_s: Option<f64>,
    /// Share of the scored samples whose estimate was aligned.
    pub aligned_share: f64,
    /// Seconds to the first magnetometer calibration, and the state at the end.
    pub calibrated_after_s: Option<f64>,
    /// Azimuth coverage and fit residual reported when it first calibrated.
    pub coverage_at_calibration_deg: Option<f64>,
    pub fit_rms_at_calibration: Option<f64>,
    pub final_calibration: String,
    /// Magnetometer calibrations that changed the state's kind (planar ↔
    /// ellipsoid ↔ collecting), a sign of refits on changing data.
    pub calibration_changes: u64,
    pub final_mag_coverage_deg: f64,
    pub final_mag_fit_rms: Option<f64>,
    /// Means of the expert's inputs over the initial rest (before the
    /// first movement sample, after one full window) and over the scored samples.
    pub rest: ExpertInputs,
    pub moving: ExpertInputs,
    /// Largest |engine gyro bias − initial-rest mean rate| at the end, °/s.
    pub final_bias_error_dps: f64,
    /// Heading RMSE, degrees, over the scored samples with the truth's
    /// |pitch| < 60°: of the engine's own compass (`mag_heading_deg`:
    /// its calibration and its tilt), and of the raw field levelled with
    /// the true tilt (the field's own disturbance). Against the reference
    /// as it is (already aligned to magnetic north), no offset removed.
    pub engine_compass_rmse_deg: Option<f64>,
    pub raw_compass_true_tilt_rmse_deg: Option<f64>,
}

/// Mean motion-expert inputs and the share of `static` calls.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ExpertInputs {
    pub samples: u64,
    pub accel_dev_mps2: f64,
    pub accel_activity_mps2: f64,
    pub gyro_activity_dps: f64,
    pub static_share: f64,
}

#[derive(Debug, Clone, Copy, Default)]
struct ExpertSums {
    n: u64,
    dev: f64,
    activity: f64,
    gyro: f64,
    statics: u64,
}

impl ExpertSums {
    fn add(&mut self, e: &FuzzyEstimate) {
        self.n += 1;
        self.dev += e.accel_dev_mps2;
        self.activity += e.accel_activity_mps2;
        self.gyro += e.gyro_activity_dps;
        self.statics += u64::from(e.motion == Motion::Static);
    }

    fn mean(&self) -> ExpertInputs {
        let n = self.n.max(1) as f64;
        ExpertInputs {
            samples: self.n,
            accel_dev_mps2: self.dev / n,
            accel_activity_mps2: self.activity / n,
            gyro_activity_dps: self.gyro / n,
            static_share: self.statics as f64 / n,
        }
    }
}

/// The estimators compared, in table order.
pub const ENGINE: &str = "fuzzy engine";
pub const GYRO_RAW: &str = "gyro only, raw";
pub const GYRO_REST_BIAS: &str = "gyro only, rest bias";
pub const ACCEL_COMPASS: &str = "accel + compass";
pub const MADGWICK_DEFAULT: &str = "Madgwick β=0.041";
pub const MADGWICK_TUNED: &str = "Madgwick, tuned with truth";
/// VQF with its defaults (Laidig and Seel 2023), the best open filter.
pub const VQF_DEFAULT: &str = "VQF, defaults";

/// One trial's scores.
#[derive(Debug, Clone, Serialize)]
pub struct TrialEvaluation {
    pub name: String,
    pub group: String,
    pub source: String,
    pub rate_hz: f64,
    pub samples: u64,
    pub duration_s: f64,
    /// Samples in the movement phase with truth: those scored.
    pub scored: u64,
    /// Errors per estimator (names as in [`RecordingEvaluation::methods`]).
    pub errors: BTreeMap<String, OrientationErrors>,
    /// Madgwick's errors for each β of [`MADGWICK_BETAS`].
    pub madgwick_grid: Vec<(f64, OrientationErrors)>,
    pub engine: EngineDiagnostics,
}

/// Pooled errors of every estimator over a set of trials.
#[derive(Debug, Clone, Serialize)]
pub struct GroupSummary {
    pub group: String,
    pub trials: usize,
    /// Mean over the trials of each RMSE (BROAD's averaging).
    pub mean: BTreeMap<String, OrientationErrors>,
    /// RMS over the trials of each RMSE.
    pub rms: BTreeMap<String, OrientationErrors>,
}

/// The whole evaluation of a directory of recordings.
#[derive(Debug, Clone, Serialize)]
pub struct RecordingEvaluation {
    pub dir: PathBuf,
    pub params: Params,
    /// Estimator names in table order.
    pub methods: Vec<String>,
    /// The β of the "tuned with truth" Madgwick row: lowest mean raw total error.
    pub madgwick_tuned_beta: f64,
    pub trials: Vec<TrialEvaluation>,
    /// "all" first, then each group in the order trials name them.
    pub groups: Vec<GroupSummary>,
}

/// Runs every trial of `dir` through the engine (with `params`, see
/// [`installer_params`]) and the baselines, and scores them.
pub fn evaluate_recording(
    dir: &Path,
    params: &Params,
) -> Result<RecordingEvaluation, RecordingError> {
    let infos = list_trials(dir)?;
    let mut trials = Vec::with_capacity(infos.len());
    for info in &infos {
        let samples = load_csv(&info.file)?;
        trials.push(evaluate_trial(info, &samples, params)?);
    }
    let madgwick_tuned_beta = best_beta(&trials);
    for t in &mut trials {
        let pick = |beta: f64| {
            t.madgwick_grid
                .iter()
                .find(|(b, _)| *b == beta)
                .map(|(_, e)| *e)
        };
        if let (Some(default), Some(tuned)) =
            (pick(MADGWICK_DEFAULT_BETA), pick(madgwick_tuned_beta))
        {
            t.errors.insert(MADGWICK_DEFAULT.to_string(), default);
            t.errors.insert(MADGWICK_TUNED.to_string(), tuned);
        }
    }
    let methods: Vec<String> = [
        ENGINE,
        GYRO_RAW,
        GYRO_REST_BIAS,
        ACCEL_COMPASS,
        MADGWICK_DEFAULT,
        MADGWICK_TUNED,
        VQF_DEFAULT,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let groups = summarise(&trials, &methods);
    Ok(RecordingEvaluation {
        dir: dir.to_path_buf(),
        params: params.clone(),
        methods,
        madgwick_tuned_beta,
        trials,
        groups,
    })
}

/// The β of [`MADGWICK_BETAS`] with the lowest mean raw total error over
/// trials (BROAD's choice of its common parameters).
fn best_beta(trials: &[TrialEvaluation]) -> f64 {
    let mean_total = |beta: f64| {
        let totals: Vec<f64> = trials
            .iter()
            .flat_map(|t| t.madgwick_grid.iter().filter(|(b, _)| *b == beta))
            .map(|(_, e)| e.total_raw_deg)
            .collect();
        totals.iter().sum::<f64>() / totals.len().max(1) as f64
    };
    MADGWICK_BETAS
        .into_iter()
        .min_by(|a, b| mean_total(*a).total_cmp(&mean_total(*b)))
        .unwrap_or(MADGWICK_DEFAULT_BETA)
}

/// Scores one trial's samples.
pub fn evaluate_trial(
    info: &TrialInfo,
    samples: &[Sample],
    params: &Params,
) -> Result<TrialEvaluation, RecordingError> {
    let rate_hz = match info.rate_hz {
        Some(r) => r,
        None => rate_from_times(&info.file, samples)?,
    };
    let scored_mask = movement_mask(info, samples);
    let rest_end = info
        .movement
        .as_ref()
        .and_then(|m| m.first().map(|r| r[0]))
        .unwrap_or(0)
        .min(samples.len());
    let rest_bias = if rest_end > 0 {
        samples[..rest_end]
            .iter()
            .map(|s| s.gyro_rad_per_s)
            .sum::<V3>()
            / rest_end as f64
    } else {
        V3::zeros()
    };

    let mut engine = FuzzyEngine::new(params.clone())?;
    let window = FuzzyParams::from_params(params)?.window_samples;
    let mut out: Vec<EngineOutput> = Vec::with_capacity(4);
    let mut engine_errors = ErrorSeries::default();
    let mut gyro_raw = (GyroOnly::new(V3::zeros()), ErrorSeries::default());
    let mut gyro_rest = (GyroOnly::new(rest_bias), ErrorSeries::default());
    let mut accel_compass = ErrorSeries::default();
    let mut madgwick: Vec<(f64, Option<Madgwick>, ErrorSeries)> = MADGWICK_BETAS
        .iter()
        .map(|b| (*b, None, ErrorSeries::default()))
        .collect();
    let mut vqf = (
        Vqf::new(1.0 / rate_hz, 1.0 / rate_hz),
        ErrorSeries::default(),
    );
    let mut previous_t = None;
    let mut diagnostics = EngineDiagnostics::default();
    let (mut rest_sums, mut moving_sums) = (ExpertSums::default(), ExpertSums::default());
    let mut aligned_scored = 0u64;
    let mut last_calibration = None;
    let (mut engine_compass, mut raw_compass) = (ErrorStats::default(), ErrorStats::default());
    let mut last: Option<FuzzyEstimate> = None;
    let t0 = samples.first().map_or(0.0, |s| s.t_s);

    for (i, sample) in samples.iter().enumerate() {
        out.clear();
        for reading in sample.readings() {
            engine.feed(&reading, &mut out);
        }
        let estimate = out.iter().rev().find_map(|o| o.values.as_fuzzy()).cloned();
        let gyro = [gyro_raw.0.step(sample), gyro_rest.0.step(sample)];
        for (beta, filter, _) in &mut madgwick {
            match (filter.as_mut(), previous_t) {
                (Some(f), Some(t)) => f.update(
                    &sample.gyro_rad_per_s,
                    &sample.accel_mps2,
                    Some(&sample.field_ut),
                    sample.t_s - t,
                ),
                _ => {
                    let start = initial_attitude(&sample.accel_mps2, Some(&sample.field_ut));
                    *filter = Some(Madgwick::new(*beta, start));
                }
            }
        }
        vqf.0.update_imu(
            &sample.gyro_rad_per_s,
            &sample.accel_mps2,
            previous_t.map_or(0.0, |t| sample.t_s - t),
        );
        vqf.0.update_mag(&sample.field_ut);
        previous_t = Some(sample.t_s);
        let Some(estimate) = estimate else { continue };
        let since_start = sample.t_s - t0;
        if estimate.aligned {
            diagnostics.aligned_after_s.get_or_insert(since_start);
        }
        let calibration = estimate.mag_calibration.as_str();
        if calibration != "collecting" && diagnostics.calibrated_after_s.is_none() {
            diagnostics.calibrated_after_s = Some(since_start);
            diagnostics.coverage_at_calibration_deg = Some(estimate.mag_coverage_deg);
            diagnostics.fit_rms_at_calibration = estimate.mag_fit_rms;
        }
        if last_calibration.is_some_and(|c| c != calibration) {
            diagnostics.calibration_changes += 1;
        }
        last_calibration = Some(calibration);
        if i < rest_end && i >= window {
            rest_sums.add(&estimate);
        }
        if scored_mask[i]
            && let Some(truth) = sample.truth
        {
            moving_sums.add(&estimate);
            let (roll, pitch, yaw) = truth.euler_angles();
            if pitch.abs() < rad(60.0) {
                if let Some(h) = estimate.mag_heading_deg {
                    engine_compass.add(deg(wrap(rad(h) - yaw)));
                }
                let level = UnitQuaternion::from_euler_angles(roll, pitch, 0.0) * sample.field_ut;
                raw_compass.add(deg(wrap((-level.y).atan2(level.x) - yaw)));
            }
            aligned_scored += u64::from(estimate.aligned);
            engine_errors.add(&estimated_attitude(&estimate), &truth);
            accel_compass.add(
                &accel_compass_attitude(&sample.accel_mps2, &sample.field_ut),
                &truth,
            );
            for (_, filter, series) in &mut madgwick {
                if let Some(f) = filter {
                    series.add(&f.attitude(), &truth);
                }
            }
            vqf.1.add(&vqf.0.attitude(), &truth);
            for (series, attitude) in [&mut gyro_raw.1, &mut gyro_rest.1].into_iter().zip(gyro) {
                if let Some(q) = attitude {
                    series.add(&q, &truth);
                }
            }
        }
        last = Some(estimate);
    }

    let scored = engine_errors.len() as u64;
    diagnostics.aligned_share = aligned_scored as f64 / scored.max(1) as f64;
    diagnostics.rest = rest_sums.mean();
    diagnostics.moving = moving_sums.mean();
    let rmse = |e: ErrorStats| (e.count > 0).then(|| e.rmse());
    diagnostics.engine_compass_rmse_deg = rmse(engine_compass);
    diagnostics.raw_compass_true_tilt_rmse_deg = rmse(raw_compass);
    if let Some(e) = &last {
        diagnostics.final_calibration = e.mag_calibration.as_str().to_string();
        diagnostics.final_mag_coverage_deg = e.mag_coverage_deg;
        diagnostics.final_mag_fit_rms = e.mag_fit_rms;
        diagnostics.final_bias_error_dps = (0..3)
            .map(|k| (e.gyro_bias_dps[k] - deg(rest_bias[k])).abs())
            .fold(0.0, f64::max);
    }
    let mut errors = BTreeMap::new();
    errors.insert(ENGINE.to_string(), engine_errors.summary());
    errors.insert(GYRO_RAW.to_string(), gyro_raw.1.summary());
    errors.insert(GYRO_REST_BIAS.to_string(), gyro_rest.1.summary());
    errors.insert(ACCEL_COMPASS.to_string(), accel_compass.summary());
    errors.insert(VQF_DEFAULT.to_string(), vqf.1.summary());
    Ok(TrialEvaluation {
        name: info.name.clone(),
        group: trial_group(&info.name).to_string(),
        source: info.source.clone(),
        rate_hz,
        samples: samples.len() as u64,
        duration_s: samples.last().map_or(0.0, |s| s.t_s) - t0,
        scored,
        errors,
        madgwick_grid: madgwick
            .iter()
            .map(|(beta, _, series)| (*beta, series.summary()))
            .collect(),
        engine: diagnostics,
    })
}

/// Which samples are scored: the manifest's movement ranges, or all.
fn movement_mask(info: &TrialInfo, samples: &[Sample]) -> Vec<bool> {
    match &info.movement {
        None => vec![true; samples.len()],
        Some(ranges) => {
            let mut mask = vec![false; samples.len()];
            for [first, end] in ranges {
                let end = (*end).min(samples.len());
                for m in mask.iter_mut().take(end).skip(*first) {
                    *m = true;
                }
            }
            mask
        }
    }
}

/// The engine's attitude rebuilt from its estimate (declination 0, so the
/// heading is the yaw from magnetic north).
pub fn estimated_attitude(e: &FuzzyEstimate) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(rad(e.roll_deg), rad(e.pitch_deg), rad(e.heading_deg))
}

/// Mean and RMS over trials of each estimator's RMSEs, for all trials and
/// per group.
fn summarise(trials: &[TrialEvaluation], methods: &[String]) -> Vec<GroupSummary> {
    let mut names: Vec<String> = vec!["all".to_string()];
    for t in trials {
        if !names.contains(&t.group) {
            names.push(t.group.clone());
        }
    }
    names
        .into_iter()
        .map(|group| {
            let members: Vec<&TrialEvaluation> = trials
                .iter()
                .filter(|t| group == "all" || t.group == group)
                .collect();
            let (mut mean, mut rms) = (BTreeMap::new(), BTreeMap::new());
            for m in methods {
                let per_trial: Vec<OrientationErrors> = members
                    .iter()
                    .filter_map(|t| t.errors.get(m).copied())
                    .collect();
                mean.insert(m.clone(), pool(&per_trial, Pooling::Mean));
                rms.insert(m.clone(), pool(&per_trial, Pooling::Rms));
            }
            GroupSummary {
                group,
                trials: members.len(),
                mean,
                rms,
            }
        })
        .collect()
}
