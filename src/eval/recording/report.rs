//! The table `eval recording` prints.

use super::*;

/// The evaluation as text: pooled errors per group and estimator, then
/// one line per trial with the engine's diagnostics.
pub fn render_table(e: &RecordingEvaluation) -> String {
    let mut text = String::new();
    let param = |name: &str| {
        e.params
            .values()
            .get(name)
            .map_or("?".to_string(), |v| v.to_string())
    };
    text.push_str(&format!(
        "{} trials in {}; engine window_samples={}, mag_inclination_deg={}; Madgwick tuned with truth: β={}\n",
        e.trials.len(),
        e.dir.display(),
        param("window_samples"),
        param("mag_inclination_deg"),
        e.madgwick_tuned_beta,
    ));
    text.push_str(
        "RMSE over the movement phases, degrees, pooled as BROAD does (mean over trials; \
         last column: RMS over trials); heading and total after removing each trial's mean \
         heading offset, raw: without\n",
    );
    let cell = |x: f64| {
        if x.is_finite() {
            format!("{x:8.2}")
        } else {
            "       —".to_string()
        }
    };
    text.push_str(&format!(
        "{:<24} {:<27} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}\n",
        "group (trials)", "estimator", "tilt", "heading", "total", "head.raw", "tot.raw", "rms tot"
    ));
    for g in &e.groups {
        for (k, m) in e.methods.iter().enumerate() {
            let Some(r) = g.mean.get(m) else { continue };
            let rms_total = g.rms.get(m).map_or(f64::NAN, |r| r.total_deg);
            let label = if k == 0 {
                format!("{} ({})", g.group, g.trials)
            } else {
                String::new()
            };
            text.push_str(&format!(
                "{label:<24} {m:<27} {} {} {} {} {} {}\n",
                cell(r.tilt_deg),
                cell(r.heading_deg),
                cell(r.total_deg),
                cell(r.heading_raw_deg),
                cell(r.total_raw_deg),
                cell(rms_total),
            ));
        }
    }
    text.push_str("\nper trial: total RMSE per estimator; the engine's tilt, heading (offset) and what it did\n");
    text.push_str(&format!("{:<46}", "trial"));
    for m in &e.methods {
        text.push_str(&format!(" {:>8}", abbreviate(m)));
    }
    text.push_str(&format!(
        " {:>6} {:>15} {:>7} {:>17} {:>13} {:>17} {:>17}\n",
        "tilt",
        "heading(offset)",
        "aligned",
        "calibrated(cover)",
        "compass e/raw",
        "rest act/gyr/st",
        "moving act/gyr/st"
    ));
    for t in &e.trials {
        text.push_str(&format!("{:<46}", t.name));
        for m in &e.methods {
            text.push_str(&format!(
                " {}",
                cell(t.errors.get(m).map_or(f64::NAN, |r| r.total_deg))
            ));
        }
        let d = &t.engine;
        let ours = t.errors.get(ENGINE).copied().unwrap_or_default();
        let seconds = |s: Option<f64>| s.map_or("never".to_string(), |s| format!("{s:.1} s"));
        text.push_str(&format!(
            " {:6.2} {:>15} {:>7} {:>17} {:>13} {:>17} {:>17}\n",
            ours.tilt_deg,
            format!(
                "{:.2} ({:+.1})",
                ours.heading_deg,
                ours.heading_offset_deg.unwrap_or(f64::NAN)
            ),
            seconds(d.aligned_after_s),
            format!(
                "{} {} ({:.0})",
                short_state(&d.final_calibration),
                seconds(d.calibrated_after_s),
                d.coverage_at_calibration_deg.unwrap_or(f64::NAN)
            ),
            format!(
                "{:.0}/{:.0}",
                d.engine_compass_rmse_deg.unwrap_or(f64::NAN),
                d.raw_compass_true_tilt_rmse_deg.unwrap_or(f64::NAN)
            ),
            expert(&d.rest),
            expert(&d.moving),
        ));
    }
    text
}

fn abbreviate(method: &str) -> String {
    match method {
        ENGINE => "engine".into(),
        GYRO_RAW => "gyro raw".into(),
        GYRO_REST_BIAS => "gyro bias".into(),
        ACCEL_COMPASS => "acc+mag".into(),
        MADGWICK_DEFAULT => "mw 0.041".into(),
        MADGWICK_TUNED => "mw tuned".into(),
        VQF_DEFAULT => "vqf".into(),
        other => other.chars().take(8).collect(),
    }
}

fn short_state(state: &str) -> &str {
    match state {
        "collecting" => "coll",
        "planar" => "plan",
        "ellipsoid" => "ell",
        other => other,
    }
}

fn expert(e: &ExpertInputs) -> String {
    if e.samples == 0 {
        "—".to_string()
    } else {
        format!(
            "{:.3}/{:.2}/{:.0}%",
            e.accel_activity_mps2,
            e.gyro_activity_dps,
            100.0 * e.static_share
        )
    }
}
