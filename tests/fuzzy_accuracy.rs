//! Accuracy of the `fuzzy` engine on simulated 20-minute vehicle drives
//! with known truth (the bars of issue 7; numbers in the README), five
//! seeds:
//! - motion status right on ≥ 97 % of the readings;
//! - pitch and roll RMSE ≤ 0.5°, heading RMSE ≤ 2° after calibration;
//! - each at least 3× better than the best single-sensor baseline
//!   (gyro-only, accelerometer-only tilt, raw compass);
//! - drift-free: over the five drives, the RMS of the last 5 minutes'
//!   error is no larger than that of the first 5 minutes after
//!   calibration, for each angle. A single drive is not enough to say so:
//!   without drift, which of the two windows is worse is a matter of the
//!   terrain driven in it, so per drive the comparison goes either way.
//!   The gyro-only baseline, which does drift, fails the same comparison:
//!   the test can tell.

use tunnelnav::eval::fuzzy::{FuzzyEvalConfig, FuzzyEvaluation, evaluate};
use tunnelnav::sim::vehicle::VehicleScenario;

fn drive(seed: u64) -> FuzzyEvaluation {
    evaluate(&FuzzyEvalConfig::new(VehicleScenario {
        seed,
        ..VehicleScenario::default()
    }))
    .unwrap()
}

/// √(mean x²) over the drives.
fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0.0), |(s, n), x| (s + x * x, n + 1.0));
    (sum / n).sqrt()
}

#[test]
fn vehicle_drives_clear_the_bars() {
    let drives: Vec<FuzzyEvaluation> = (1..=5).map(drive).collect();
    for e in &drives {
        let seed = e.scenario.seed;
        let best = e.best_baseline();
        eprintln!(
            "seed {seed}: motion {:.4}, engine {:?}, best baseline {best:?}, first 5 min {:?}, last 5 min {:?}",
            e.motion_accuracy, e.engine, e.first_5_min, e.last_5_min
        );
        assert!(
            e.calibrated_after_s.is_some_and(|s| s < 150.0),
            "seed {seed}: {e:?}"
        );
        assert!(e.motion_accuracy >= 0.97, "seed {seed}: {e:?}");
        assert!(e.engine.pitch_deg <= 0.5, "seed {seed}: {e:?}");
        assert!(e.engine.roll_deg <= 0.5, "seed {seed}: {e:?}");
        assert!(e.engine.heading_deg <= 2.0, "seed {seed}: {e:?}");
        assert!(
            best.pitch_deg >= 3.0 * e.engine.pitch_deg,
            "seed {seed}: {e:?}"
        );
        assert!(
            best.roll_deg >= 3.0 * e.engine.roll_deg,
            "seed {seed}: {e:?}"
        );
        assert!(
            best.heading_deg >= 3.0 * e.engine.heading_deg,
            "seed {seed}: {e:?}"
        );
        // The bias is a random walk in a Kalman filter (issue 18): at rest
        // its steady state trades noise (σ about 0.005 °/s per axis on this
        // IMU) for following a bias that drifts between stops; the largest
        // error over the 30 000 readings of 5 minutes, driving included, is
        // 0.025–0.031 °/s on these seeds (the previous exponential mean:
        // 0.006–0.016, but blind to a bias that warms between stops).
        assert!(e.final_bias_error_dps < 0.04, "seed {seed}: {e:?}");
    }
    let first = |f: fn(&FuzzyEvaluation) -> f64| rms(drives.iter().map(f));
    for (angle, early, late) in [
        (
            "pitch",
            first(|e| e.first_5_min.pitch_deg),
            first(|e| e.last_5_min.pitch_deg),
        ),
        (
            "roll",
            first(|e| e.first_5_min.roll_deg),
            first(|e| e.last_5_min.roll_deg),
        ),
        (
            "heading",
            first(|e| e.first_5_min.heading_deg),
            first(|e| e.last_5_min.heading_deg),
        ),
    ] {
        eprintln!("{angle}: first 5 min {early:.3}°, last 5 min {late:.3}° (RMS over 5 drives)");
        assert!(late <= early, "{angle} drifts: {early} → {late}");
    }
    // The same comparison catches the gyros' drift.
    let gyro_early = first(|e| e.gyro_only_first_5_min.heading_deg);
    let gyro_late = first(|e| e.gyro_only_last_5_min.heading_deg);
    assert!(
        gyro_late > gyro_early,
        "gyro only: {gyro_early} → {gyro_late}"
    );
}
