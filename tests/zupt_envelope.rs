//! The `zupt` engine on drives drawn from the envelope (issue 33), beside
//! the paper's detector and an oracle fed the true zero-velocity flags.
//!
//! Seeds 1–12 were fixed before any result was looked at (the rules were
//! developed on seeds 1001–1020). Each test asserts only what holds on
//! all of its drives; the bars of the issue that are not met are printed
//! as not met (docs/evaluation.md has the 40-drive figures of
//! `eval zupt --envelope --seeds 40`).

use tunnelnav::eval::zupt_envelope::{evaluate_all, evaluate_envelope, render, summarise};
use tunnelnav::fusion::Params;
use tunnelnav::fusion::zupt::PARAMS;
use tunnelnav::sim::pipejack::SensorGrade;
use tunnelnav::sim::pipejack_envelope::{PipeJackEnvelope, Spectrum, VibrationDraw};

#[test]
fn envelope_drives_seeds_1_to_12() {
    let seeds: Vec<u64> = (1..=12).collect();
    let drives = evaluate_all(&seeds, &Params::defaults(PARAMS), 2).unwrap();
    let summary = summarise(&drives);
    eprintln!("{}", render(&drives, &summary));
    assert_eq!(summary.drives, 12);
    // Issue 33's eleven, and issue 54's two on integrity.
    assert_eq!(summary.bars.len(), 13);
    for d in &drives {
        let oracle = d.run("oracle").unwrap();
        // The oracle's flags are the truth.
        assert_eq!(oracle.precision, 1.0, "seed {}", d.drive.seed);
        assert_eq!(oracle.recall, 1.0, "seed {}", d.drive.seed);
        // Every drive starts standing, so the oracle aligns at once. (The
        // paper's detector may find no rest at all: seed 2.)
        assert!(oracle.estimates > 0, "seed {}: {oracle:?}", d.drive.seed);
    }
}

/// The trolley: pushes of `push_s` at 35–45 mm/s (by seed)
/// carrying a few mg of steady rolling vibration (5–30 Hz) and a little
/// angular jitter, quiet rests of `rest_s`.
fn rolling_trolley(seed: u64, push_s: f64, rest_s: f64) -> PipeJackEnvelope {
    PipeJackEnvelope {
        seed,
        heading_deg: 30.0,
        slope_deg: 0.5,
        latitude_deg: 30.0,
        push_s,
        rest_s,
        speed_mps: [0.035, 0.040, 0.045][(seed % 3) as usize],
        ramp_s: 1.5,
        fluctuation: 0.0,
        push_vibration: Some(VibrationDraw {
            amplitude_mg: 3.0,
            band_hz: (5.0, 30.0),
            spectrum: Spectrum::Tones { count: 3 },
            jitter_dps: 0.005,
            switching_s: None,
        }),
        rest_vibration: None,
        odometer_scale_error: None,
        sensors: SensorGrade::PAPER,
        duration_s: 1900.0,
        ..PipeJackEnvelope::draw(seed)
    }
}

/// The table, first two rows (push/rest 30/30, 20/40, 40/20 and
/// 45/15 s, seeds 1–3 each, fixed before the rest check was run on them):
/// the paper's detector holds, and so does the engine's default, which
/// calls none of the rolling a rest. (First written with distance ≤ 1.5 %,
/// which 40/20 seed 3 breaks for both runs: 2.96 and 2.92 %.)
#[test]
fn a_rolling_trolley_is_never_standing() {
    for (push_s, rest_s) in [(30.0, 30.0), (20.0, 40.0), (40.0, 20.0), (45.0, 15.0)] {
        for seed in 1..=3 {
            let drive = rolling_trolley(seed, push_s, rest_s);
            let d = evaluate_envelope(&drive, &Params::defaults(PARAMS)).unwrap();
            let engine = d.run("engine").unwrap();
            let paper = d.run("paper").unwrap();
            eprintln!(
                "{push_s}/{rest_s} s seed {seed}: engine precision {:.4} recall {:.4} distance {:.2} %; paper precision {:.4} distance {:.2} %",
                engine.precision,
                engine.recall,
                engine.distance_error_pct,
                paper.precision,
                paper.distance_error_pct
            );
            assert!(
                engine.precision >= 0.99,
                "{push_s}/{rest_s} seed {seed}: {engine:?}"
            );
            assert!(
                engine.recall >= 0.90,
                "{push_s}/{rest_s} seed {seed}: {engine:?}"
            );
            // The distance bar is the issue's: never worse than the paper's
            // by more than 0.2 % (with 40 s pushes the INS alone drifts
            // ~3 % on seed 3, for both).
            assert!(
                engine.distance_error_pct <= paper.distance_error_pct + 0.2,
                "{push_s}/{rest_s} seed {seed}: {engine:?}"
            );
            assert!(
                paper.precision >= 0.99,
                "{push_s}/{rest_s} seed {seed}: {paper:?}"
            );
        }
    }
}
