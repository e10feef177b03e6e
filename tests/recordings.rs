//! Recorded trials (BROAD): the loader's frame conventions checked against
//! the optical truth on a committed 9 s excerpt (`tests/fixtures/broad/`).
//! A whole converted directory is evaluated by the command line, not here:
//! `tunnelnav eval recording --dir DIR [--param name=value] [--json]`.

use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use tunnelnav::eval::recording::{
    Sample, evaluate_recording, installer_params, integrate_rate, load_csv, recording_rate_hz,
    render_table, tilt_error,
};

type V3 = Vector3<f64>;

const G: f64 = 9.81;

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/broad")
}

fn fixture() -> Vec<Sample> {
    let samples = load_csv(&fixture_dir().join("02_undisturbed_slow_rotation_B_excerpt.csv"))
        .expect("the fixture loads");
    assert_eq!(samples.len(), 2571);
    assert!(samples.iter().all(|s| s.truth.is_some()));
    samples
}

/// The first sample of BROAD's movement phase in the excerpt.
const MOVEMENT_START: usize = 714;

/// The angle, degrees, between "down" measured by the accelerometer
/// (−f/|f|) and "down" in the body according to the truth (q⁻¹ (0, 0, 1)).
fn accel_vs_truth_deg(s: &Sample) -> f64 {
    let measured = -s.accel_mps2.normalize();
    let truth = s.truth.expect("truth").inverse() * V3::z();
    measured.angle(&truth).to_degrees()
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

#[test]
fn at_rest_the_accelerometer_tilt_matches_the_truth() {
    let samples = fixture();
    // The hand starts moving a little before BROAD's movement phase.
    let rest = &samples[..600];
    let mean_force = rest.iter().map(|s| s.accel_mps2).sum::<V3>() / rest.len() as f64;
    // z down: a nearly level sensor reads about −g on z.
    assert!((mean_force.z + G).abs() < 0.1, "{mean_force}");
    let roll = (-mean_force.y).atan2(-mean_force.z);
    let pitch = mean_force.x.atan2(mean_force.y.hypot(mean_force.z));
    let (true_roll, true_pitch, _) = rest[rest.len() / 2].truth.expect("truth").euler_angles();
    let (dr, dp) = (
        (roll - true_roll).to_degrees(),
        (pitch - true_pitch).to_degrees(),
    );
    println!("rest: accelerometer − truth roll {dr:.3}°, pitch {dp:.3}°");
    assert!(dr.abs() < 1.0 && dp.abs() < 1.0, "roll {dr}°, pitch {dp}°");
    // Per sample: accelerometer noise of ~0.07 m/s² is ~0.4° of tilt.
    let mut errors: Vec<f64> = rest.iter().map(accel_vs_truth_deg).collect();
    errors.sort_by(f64::total_cmp);
    let p95 = errors[errors.len() * 95 / 100];
    assert!(p95 < 1.5, "{p95}°");
}

#[test]
fn while_rotating_slowly_the_accelerometer_follows_the_truth_through_large_tilts() {
    // Rest alone is nearly level and cannot tell a sign from its absence:
    // the rotations take the sensor through 100° and more of tilt.
    let samples = fixture();
    let quasi_static: Vec<&Sample> = samples[MOVEMENT_START..]
        .iter()
        .filter(|s| (s.accel_mps2.norm() - G).abs() < 0.15 && s.gyro_rad_per_s.norm() < 1.0)
        .collect();
    assert!(quasi_static.len() > 150, "{}", quasi_static.len());
    let largest_tilt = quasi_static
        .iter()
        .map(|s| tilt_error(&s.truth.expect("truth")).to_degrees())
        .fold(0.0, f64::max);
    let errors: Vec<f64> = quasi_static.iter().map(|s| accel_vs_truth_deg(s)).collect();
    let m = median(errors);
    println!(
        "quasi-static while rotating: {} samples, tilt up to {largest_tilt:.0}°, median accelerometer error {m:.2}°",
        quasi_static.len()
    );
    assert!(largest_tilt > 100.0, "{largest_tilt}");
    assert!(m < 3.0, "{m}°");
}

#[test]
fn the_field_seen_through_the_truth_points_north_and_down() {
    // BROAD's reference frame is aligned to magnetic north: the body field
    // turned into NED by the truth is (H, ~0, Z) with Z > 0 (Berlin: ~68°).
    let samples = fixture();
    let mut azimuths = Vec::new();
    let mut inclinations = Vec::new();
    for s in &samples {
        let m = s.truth.expect("truth") * s.field_ut;
        azimuths.push(m.y.atan2(m.x).to_degrees());
        inclinations.push(m.z.atan2(m.x.hypot(m.y)).to_degrees());
    }
    let (azimuth, inclination) = (median(azimuths.clone()), median(inclinations));
    let spread = median(azimuths.iter().map(|a| (a - azimuth).abs()).collect());
    println!(
        "field in NED: azimuth {azimuth:.2}° (median spread {spread:.2}°), inclination {inclination:.2}°"
    );
    assert!(azimuth.abs() < 3.0, "{azimuth}");
    assert!(spread < 3.0, "{spread}");
    assert!((64.0..74.0).contains(&inclination), "{inclination}");
}

#[test]
fn integrated_gyros_turn_as_the_truth_does() {
    let samples = fixture();
    let rest = &samples[..MOVEMENT_START];
    let bias = rest.iter().map(|s| s.gyro_rad_per_s).sum::<V3>() / rest.len() as f64;
    // rad/s: a MEMS bias of a few tenths of a degree per second.
    assert!(bias.norm().to_degrees() < 1.0, "{bias}");
    let span = 857; // 3 s
    for start in [MOVEMENT_START, MOVEMENT_START + span] {
        let window = &samples[start..=start + span];
        let first = window[0].truth.expect("truth");
        let mut q: UnitQuaternion<f64> = first;
        for pair in window.windows(2) {
            let rate = (pair[0].gyro_rad_per_s + pair[1].gyro_rad_per_s) * 0.5 - bias;
            q = integrate_rate(&q, &rate, pair[1].t_s - pair[0].t_s);
        }
        let last = window[span].truth.expect("truth");
        let turned = first.angle_to(&last).to_degrees();
        let error = q.angle_to(&last).to_degrees();
        println!(
            "gyros over 3 s from sample {start}: truth turned {turned:.1}°, integration off by {error:.2}°"
        );
        assert!(turned > 20.0, "{turned}");
        assert!(error < 2.0, "{error}");
    }
}

#[test]
fn the_fixture_evaluates() {
    let dir = fixture_dir();
    let rate = recording_rate_hz(&dir).expect("rate");
    assert!((rate - 2000.0 / 7.0).abs() < 1e-9);
    let params = installer_params(rate, &[]).expect("params");
    let e = evaluate_recording(&dir, &params).expect("evaluation");
    println!("{}", render_table(&e));
    assert_eq!(e.trials.len(), 1);
    let trial = &e.trials[0];
    assert_eq!(trial.scored, 2571 - MOVEMENT_START as u64);
    // The gyro baseline checks the loader, not the engine: 6.5 s from the
    // true attitude with the rest bias removed stays within a few degrees.
    let gyro = trial.errors["gyro only, rest bias"];
    assert!(gyro.total_deg < 3.0, "{gyro:?}");
    serde_json::to_string(&e).expect("the evaluation serialises");
}
