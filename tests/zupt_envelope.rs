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
    assert_eq!(summary.bars.len(), 11);
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

/// The trolley: pushes of about 30 s at 35–45 mm/s carrying a few
/// mg of steady rolling vibration (5–30 Hz) and a little angular jitter,
/// quiet rests of 30 s.
fn rolling_trolley(seed: u64) -> PipeJackEnvelope {
    PipeJackEnvelope {
        seed,
        heading_deg: 30.0,
        slope_deg: 0.5,
        latitude_deg: 30.0,
        push_s: 30.0,
        rest_s: 30.0,
        speed_mps: 0.04,
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

/// The table, first row: the paper's detector holds (precision
/// 1.000 there); the engine's default does not yet, and says so.
#[test]
fn a_rolling_trolley() {
    for seed in 1..=3 {
        let d = evaluate_envelope(&rolling_trolley(seed), &Params::defaults(PARAMS)).unwrap();
        let engine = d.run("engine").unwrap();
        let paper = d.run("paper").unwrap();
        eprintln!(
            "seed {seed}: engine precision {:.4} distance {:.2} %; paper precision {:.4} distance {:.2} %",
            engine.precision, engine.distance_error_pct, paper.precision, paper.distance_error_pct
        );
        if engine.precision < 0.99 {
            eprintln!("seed {seed}: NOT MET: engine precision ≥ 0.99 on the rolling trolley");
        }
        assert!(paper.precision >= 0.99, "seed {seed}: {paper:?}");
        assert!(paper.distance_error_pct <= 1.5, "seed {seed}: {paper:?}");
    }
}
