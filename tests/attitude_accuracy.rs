//! Accuracy of the `attitude` engine on simulated TBM drives with known
//! truth, scored after one hour of learning.
//!
//! On the paper's fixed scenario (`sim::tbm`), eight seeds each, two
//! scenarios:
//! - *learned*: a 10-hour drive with a 45-minute laser dropout at 7 h, once
//!   the roll has swept its range: the case the paper's dropout claim is about;
//! - *unseen roll*: a 6-hour drive with the dropout at 2.5 h, during which
//!   the roll moves up to 1.5° beyond anything the model has seen, so the
//!   correction must extrapolate.
//!
//! The engine's defaults are no longer tuned on this simulator (issue 16:
//! it measures its noise); `tests/attitude_envelope.rs` scores it over
//! drives drawn from the whole envelope.

use tunnelnav::eval::attitude::{
    AttitudeEvalConfig, AttitudeEvaluation, ENGINE_NONE, ENGINE_OFFSET, LASER_HOLD,
    RAW_INCLINOMETER, evaluate,
};
use tunnelnav::fusion::Params;
use tunnelnav::fusion::attitude::PARAMS;
use tunnelnav::sim::tbm::{Dropout, TbmScenario};

const SEEDS: std::ops::RangeInclusive<u64> = 1..=8;

fn drive(seed: u64, hours: f64, dropout_h: f64, extra: &[&str]) -> AttitudeEvaluation {
    let scenario = TbmScenario {
        seed,
        hours,
        dropouts: vec![Dropout {
            start_h: dropout_h,
            minutes: 45.0,
        }],
        ..TbmScenario::default()
    };
    let mut config = AttitudeEvalConfig::new(scenario);
    config.params = Params::from_assignments(PARAMS, extra.iter().copied()).unwrap();
    evaluate(&config).unwrap()
}

fn learned(seed: u64, extra: &[&str]) -> AttitudeEvaluation {
    drive(seed, 10.0, 7.0, extra)
}

fn unseen_roll(seed: u64) -> AttitudeEvaluation {
    drive(seed, 6.0, 2.5, &[])
}

fn best_baseline(
    e: &AttitudeEvaluation,
    metric: impl Fn(&tunnelnav::eval::attitude::MethodScores) -> f64,
) -> f64 {
    e.baselines().map(metric).fold(f64::MAX, f64::min)
}

/// The bars of issue 3 on the learned scenario, in full.
fn bars(e: &AttitudeEvaluation) -> Result<(), String> {
    let best = best_baseline(e, |m| m.pitch.rmse());
    let rmse = e.engine().pitch.rmse();
    if 5.0 * rmse > best {
        return Err(format!(
            "pitch RMSE {rmse:.4}° not 5× under the best baseline's {best:.4}°"
        ));
    }
    core_bars(e)
}

/// The bars of issue 3 but the ratio to the best baseline.
fn core_bars(e: &AttitudeEvaluation) -> Result<(), String> {
    let engine = e.engine();
    let rmse = engine.pitch.rmse();
    if rmse > 0.01 {
        return Err(format!("pitch RMSE {rmse:.4}° (bar 0.01°)"));
    }
    let dropout = engine.pitch_in_dropout[0];
    if dropout.count < 2000 || dropout.max_abs > 0.03 {
        return Err(format!(
            "max error {:.4}° through the dropout (bar 0.03°)",
            dropout.max_abs
        ));
    }
    let prediction = engine.pitch_pred_at_laser.rmse();
    if prediction > 0.01 {
        return Err(format!(
            "prediction RMS at laser instants {prediction:.4}° > 0.01°"
        ));
    }
    Ok(())
}

#[test]
fn learned_drive_meets_the_rmse_dropout_and_prediction_bars() {
    for seed in SEEDS {
        if let Err(why) = core_bars(&learned(seed, &[])) {
            panic!("seed {seed}: {why}");
        }
    }
}

#[test]
fn the_bars_fail_without_the_anfis_correction() {
    for seed in SEEDS {
        for correction in ["correction=offset", "correction=none"] {
            assert!(
                bars(&learned(seed, &[correction])).is_err(),
                "seed {seed}: bars met with {correction}: the ANFIS is not what makes the difference"
            );
        }
    }
    // Since issue 16 the filter's bias state follows what the laser shows
    // even without a model, so the ablations are far better than they were
    // (0.32° → 0.012° without a correction) and the margin narrower: over
    // the eight drives the model still halves the error, and never loses.
    let mut sums = [0.0; 3];
    for seed in SEEDS {
        let e = learned(seed, &[]);
        let anfis = e.engine().pitch.rmse();
        sums[0] += anfis * anfis;
        for (i, ablation) in [ENGINE_OFFSET, ENGINE_NONE].into_iter().enumerate() {
            let other = e.method(ablation).unwrap().pitch.rmse();
            assert!(
                other > anfis,
                "seed {seed} {ablation}: {other:.4} vs {anfis:.4}"
            );
            sums[i + 1] += other * other;
        }
    }
    for (i, ablation) in [ENGINE_OFFSET, ENGINE_NONE].into_iter().enumerate() {
        let ratio = (sums[i + 1] / sums[0]).sqrt();
        assert!(
            ratio > 1.8,
            "{ablation}: pooled RMSE {ratio:.2}× the engine's"
        );
    }
}

#[test]
fn unseen_roll_bounds_the_extrapolation() {
    for seed in SEEDS {
        let e = unseen_roll(seed);
        let rmse = e.engine().pitch.rmse();
        let hold_rmse = e.method(LASER_HOLD).unwrap().pitch.rmse();
        assert!(
            rmse < hold_rmse,
            "seed {seed}: pitch RMSE {rmse:.4}° vs the laser hold's {hold_rmse:.4}°"
        );
        let dropout = e.engine().pitch_in_dropout[0].max_abs;
        let hold = e.method(LASER_HOLD).unwrap().pitch_in_dropout[0].max_abs;
        assert!(
            hold > dropout,
            "seed {seed}: laser hold {hold:.4}° vs {dropout:.4}°"
        );
    }
}

/// Issue 3's bars on the unseen-roll drive: RMSE ≤ 0.01° and under 0.06°
/// through the dropout. Since issue 16 (noise measured, not tuned to this
/// simulator) met on seeds 2–8 (0.0043–0.0087°, 0.015–0.039°) but not on
/// seed 1 (after issue 35: 0.0103°, 0.058°; the engine before issue 16:
/// 0.0091°, 0.055°), whose roll runs 1.5° below anything seen during the
/// dropout: the model extrapolates. Run with `--ignored`.
#[test]
#[ignore = "issue 3 unseen-roll bars: seed 1 misses them since issue 16 (docs/evaluation.md)"]
fn unseen_roll_keeps_rmse_under_the_bars() {
    let mut failures = Vec::new();
    for seed in SEEDS {
        let e = unseen_roll(seed);
        let rmse = e.engine().pitch.rmse();
        let dropout = e.engine().pitch_in_dropout[0].max_abs;
        if rmse > 0.01 || dropout >= 0.06 {
            failures.push(format!(
                "seed {seed}: {rmse:.4}°, {dropout:.4}° in the dropout"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Issue 3's RMSE bar in full: at least 5× under the best simple baseline.
/// Since issue 16 missed on seeds 3 and 5 by 1–2 % (4.8× and 4.9×; the
/// engine before issue 16, whose noise was tuned on this simulator, met
/// it), and since issue 35's laser bound on the angle's walk on seed 7 too
/// (0.0042 → 0.0051°, 4.4×: docs/evaluation.md). Run with `--ignored`.
#[test]
#[ignore = "issue 3 RMSE ratio: seeds 3, 5 and 7 at 4.4–4.9× (docs/evaluation.md)"]
fn pitch_rmse_five_times_under_the_best_baseline() {
    let mut failures = Vec::new();
    for seed in SEEDS {
        if let Err(why) = bars(&learned(seed, &[])) {
            failures.push(format!("seed {seed}: {why}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn roll_follows_the_laser_after_offset_correction() {
    for seed in SEEDS {
        let e = learned(seed, &[]);
        let roll = e.engine().roll.rmse();
        let raw = e.method(RAW_INCLINOMETER).unwrap().roll.rmse();
        assert!(roll < 0.005, "seed {seed}: roll RMSE {roll:.4}°");
        assert!(
            raw > 10.0 * roll,
            "seed {seed}: raw roll {raw:.4}° vs {roll:.4}°"
        );
    }
}

/// The dropout bar in full: max error through the dropout at least
/// 5× under the *best* baseline. Not met: on seeds whose roll during the
/// dropout sits near its value in the calibration hour, the constant-offset
/// inclinometer's systematic error is as small as the filter noise both
/// share (0.016–0.03°), and nothing can be 5× under that; against the laser
/// hold alone the margin is 4.1–11×. Run with `--ignored`.
#[test]
#[ignore = "issue 3 dropout bar vs the constant-offset baseline: not met (see the comment above)"]
fn dropout_max_error_five_times_under_the_best_baseline() {
    let mut failures = Vec::new();
    for seed in SEEDS {
        let e = learned(seed, &[]);
        let engine = e.engine().pitch_in_dropout[0].max_abs;
        let best = best_baseline(&e, |m| m.pitch_in_dropout[0].max_abs);
        if 5.0 * engine > best {
            failures.push(format!(
                "seed {seed}: {engine:.4}° vs best baseline {best:.4}°"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
