//! Accuracy of the `zupt` engine on simulated pipe-jacking drives with
//! known truth (the bars of issue 6; numbers in the README).
//!
//! - trolley (the paper's 30 s push / 30 s rest, 36.55 m), three seeds:
//!   TCZVD precision ≥ 99.5 %, F0.5 ≥ 96 %, final distance error ≤ 1.5 %
//!   of the distance, pure INS at least 10× worse, and the position error
//!   within 3σ of the filter's own covariance on ≥ 95 % of readings;
//! - varied duty cycles, five seeds: distance error ≤ 2 % in RMS over the
//!   seeds (single seeds spread about it: at the simulated IMU's noise the
//!   filter's own 1σ along-track is about 1 % of the distance);
//! - field (2 mm/s with cutter vibration): no false zero velocity while
//!   advancing, every rest of 2 min or more detected;
//! - issue 17: rests found with machinery running (precision ≥ 0.99,
//!   recall ≥ 0.90, no false zero velocity at 2 mm/s), the trolley's
//!   final heading within 0.1° RMS over five seeds, and its smoothed
//!   pushes within half the live error inside each push.

use tunnelnav::eval::zupt::{DetectorScores, ZuptEvalConfig, evaluate, evaluate_runs};
use tunnelnav::fusion::Params;
use tunnelnav::fusion::zupt::PARAMS;
use tunnelnav::sim::pipejack::{Case, Machinery, MachineryPattern, PipeJackScenario};

fn scenario(case: Case, seed: u64) -> ZuptEvalConfig {
    ZuptEvalConfig::new(PipeJackScenario {
        case,
        seed,
        ..PipeJackScenario::default()
    })
}

fn run<'a>(scores: &'a [DetectorScores], label: &str) -> &'a DetectorScores {
    scores.iter().find(|d| d.detector == label).unwrap()
}

#[test]
fn trolley_runs_clear_the_papers_bars() {
    for seed in 1..=3 {
        let e = evaluate(&scenario(Case::Trolley, seed)).unwrap();
        let tczvd = run(&e.detectors, "tczvd");
        let none = run(&e.detectors, "none");
        eprintln!(
            "seed {seed}: precision {:.4} F0.5 {:.4} distance {:.3} m ({:.2} %), none {:.1} m, within 3σ {:?}",
            tczvd.precision,
            tczvd.f_half,
            tczvd.distance_error_m,
            tczvd.distance_error_pct,
            none.distance_error_m,
            tczvd.within_3_sigma
        );
        assert!(tczvd.precision >= 0.995, "seed {seed}: {tczvd:?}");
        assert!(tczvd.f_half >= 0.96, "seed {seed}: {tczvd:?}");
        assert!(tczvd.distance_error_pct <= 1.5, "seed {seed}: {tczvd:?}");
        assert!(
            none.distance_error_m >= 10.0 * tczvd.distance_error_m.max(0.01),
            "seed {seed}: no ZUPT {none:?}"
        );
        for axis in 0..3 {
            assert!(tczvd.within_3_sigma[axis] >= 0.95, "seed {seed}: {tczvd:?}");
        }
        // The single detectors alone are each fooled somewhere; TCZVD is
        // not (the rest check, which would catch them, off).
        let alone = evaluate(&with_params(
            scenario(Case::Trolley, seed),
            &["rest_check=false"],
        ))
        .unwrap();
        let tczvd_alone = run(&alone.detectors, "tczvd");
        assert!(
            tczvd_alone.precision >= 0.995,
            "seed {seed}: {tczvd_alone:?}"
        );
        for single in ["mv", "are", "mag"] {
            assert!(run(&alone.detectors, single).precision < tczvd_alone.precision);
        }
    }
}

#[test]
fn varied_duty_cycles_stay_within_two_percent() {
    let mut sum_sq = 0.0;
    let seeds = 1..=5;
    for seed in seeds.clone() {
        let e = evaluate_runs(&scenario(Case::Varied, seed), &[("tczvd", "tczvd", false)]).unwrap();
        let d = &e.detectors[0];
        eprintln!(
            "seed {seed}: {:.3} m of {:.2} m ({:.2} %), precision {:.4}",
            d.distance_error_m, e.distance_m, d.distance_error_pct, d.precision
        );
        assert!(d.precision >= 0.995, "seed {seed}: {d:?}");
        assert!(d.distance_error_pct <= 3.0, "seed {seed}: {d:?}");
        sum_sq += d.distance_error_pct.powi(2);
    }
    let rms = (sum_sq / seeds.count() as f64).sqrt();
    assert!(rms <= 2.0, "RMS distance error {rms:.2} %");
}

#[test]
fn field_advance_is_never_taken_for_a_rest_and_every_long_rest_is_found() {
    // The field's odometer is calibrated (0.2 % off), and its 10–20 min
    // pushes let no push measure the scale (issue 58): the site declares
    // its calibration class, 1 %, as it would (with the default 5 % of an
    // uncalibrated wheel the distance ends 1.2 % off: the count is
    // trusted as far as the scale is known).
    let e = evaluate_runs(
        &with_params(scenario(Case::Field, 1), &["odometer_scale_sigma_pct=1"]),
        &[("tczvd", "tczvd", false), ("tczvd+odo", "tczvd", true)],
    )
    .unwrap();
    for d in &e.detectors {
        eprintln!("{d:?}");
        assert_eq!(d.false_zv_s, 0.0, "{d:?}");
        assert!(d.long_rests >= 5);
        assert_eq!(d.long_rests_found, d.long_rests, "{d:?}");
    }
    // With 10–20 min pushes the INS alone drifts; the odometer holds it.
    assert!(
        e.detectors[1].distance_error_pct < 1.0,
        "{:?}",
        e.detectors[1]
    );
}

fn with_params(mut config: ZuptEvalConfig, assignments: &[&str]) -> ZuptEvalConfig {
    config.params = Params::from_assignments(PARAMS, assignments.iter().copied()).unwrap();
    config
}

/// Issue 17: a power pack shaking the standing machine (2–5 mg at 20–60
/// Hz) must not hide the rests, and the 2 mm/s advance must never be taken
/// for one. The paper's detector on the raw samples with fixed thresholds
/// finds almost none of those rests (the test can fail).
#[test]
fn rests_with_machinery_running_are_found_and_the_advance_never_taken_for_one() {
    let drives = [
        (1, Machinery::power_pack(MachineryPattern::Always)),
        (2, Machinery::power_pack(MachineryPattern::Cycling)),
        (
            3,
            Machinery {
                pattern: MachineryPattern::Always,
                amplitude_mg: (5.0, 5.0),
                band_hz: (20.0, 21.0),
            },
        ),
    ];
    for (seed, machinery) in drives {
        let config = ZuptEvalConfig::new(PipeJackScenario {
            case: Case::Field,
            seed,
            machinery: Some(machinery),
            ..PipeJackScenario::default()
        });
        let e = evaluate_runs(&config, &[("tczvd", "tczvd", false)]).unwrap();
        let d = &e.detectors[0];
        eprintln!("seed {seed} {machinery:?}: {d:?}");
        assert!(d.precision >= 0.99, "seed {seed}: {d:?}");
        assert!(d.recall >= 0.90, "seed {seed}: {d:?}");
        assert_eq!(d.false_zv_s, 0.0, "seed {seed}: {d:?}");
        if seed == 3 {
            let paper = with_params(config, &["detector_signals=raw", "threshold_adapt=false"]);
            let e = evaluate_runs(&paper, &[("tczvd", "tczvd", false)]).unwrap();
            let d = &e.detectors[0];
            eprintln!("the paper's detector: {d:?}");
            assert!(d.recall < 0.5, "{d:?}");
        }
    }
}

/// Issue 17: with a zero-angular-rate update at every rest the heading at
/// the end of a trolley run stays within 0.1° (RMS over five seeds);
/// without it, it does not. On the same runs, the smoothed pushes are
/// within half the live estimate's error inside each push.
#[test]
fn the_trolley_heading_holds_and_its_pushes_are_smoothed() {
    let runs = |assignments: &[&str]| -> Vec<DetectorScores> {
        (1..=5)
            .map(|seed| {
                let config = with_params(scenario(Case::Trolley, seed), assignments);
                let e = evaluate_runs(&config, &[("tczvd", "tczvd", false)]).unwrap();
                e.detectors.into_iter().next().unwrap()
            })
            .collect()
    };
    let rms = |runs: &[DetectorScores], f: fn(&DetectorScores) -> f64| {
        (runs.iter().map(|d| f(d).powi(2)).sum::<f64>() / runs.len() as f64).sqrt()
    };
    let with = runs(&[]);
    let without = runs(&["zaru=false", "smooth_pushes=false"]);
    let heading = rms(&with, |d| d.heading_error_deg);
    let heading_without = rms(&without, |d| d.heading_error_deg);
    eprintln!("heading RMS: {heading:.3}° with rest updates, {heading_without:.3}° without");
    assert!(heading <= 0.1, "{heading}");
    assert!(
        heading_without > 2.0 * heading,
        "{heading_without} vs {heading}"
    );

    let live = rms(&with, |d| d.live_track_rms_m);
    let smoothed = rms(&with, |d| d.smoothed_track_rms_m);
    eprintln!("within-push error RMS: live {live:.4} m, smoothed {smoothed:.4} m");
    assert!(with.iter().all(|d| d.track_points > 500), "{with:?}");
    assert!(smoothed <= 0.5 * live, "{smoothed} vs {live}");
    assert!(without.iter().all(|d| d.track_points == 0));
}

/// Issue 17: pushes of 15–60 s with rests of 10–40 s (longer pushes drift
/// more between rests): the final heading stays within 0.15° RMS over five
/// seeds (0.09° measured).
#[test]
fn the_heading_holds_with_pushes_of_up_to_a_minute() {
    let mut sum_sq = 0.0;
    for seed in 1..=5 {
        let config = ZuptEvalConfig::new(PipeJackScenario {
            seed,
            push_s: Some((15.0, 60.0)),
            rest_s: Some((10.0, 40.0)),
            ..PipeJackScenario::default()
        });
        let e = evaluate_runs(&config, &[("tczvd", "tczvd", false)]).unwrap();
        let d = &e.detectors[0];
        eprintln!(
            "seed {seed}: heading error {:.3}°, {d:?}",
            d.heading_error_deg
        );
        assert!(d.precision >= 0.995, "{d:?}");
        sum_sq += d.heading_error_deg.powi(2);
    }
    let rms = (sum_sq / 5.0).sqrt();
    assert!(rms <= 0.15, "{rms}");
}
