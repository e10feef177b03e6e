use super::*;

fn incl(t: f64, pitch_deg: f64, roll_deg: f64) -> Reading {
    Reading {
        t,
        data: SensorData::Inclinometer {
            pitch_deg,
            roll_deg,
            temp_c: None,
        },
    }
}

fn laser(t: f64, pitch_deg: f64, roll_deg: f64) -> Reading {
    Reading {
        t,
        data: SensorData::Laser {
            pitch_deg,
            roll_deg,
            yaw_deg: None,
            position: None,
        },
    }
}

fn attitude(out: &[EngineOutput]) -> &AttitudeEstimate {
    let values = &out.last().expect("an estimate").values;
    values.as_attitude().expect("an attitude estimate")
}

fn engine(assignments: &[&str]) -> AttitudeEngine {
    AttitudeEngine::new(Params::from_assignments(PARAMS, assignments.iter().copied()).unwrap())
        .unwrap()
}

const T0: f64 = 1_772_431_200.0;

/// The laser monitor carries the shown roll to the sample's time: a
/// shield rolling steadily at 0.005 °/s, an exact inclinometer every
/// 20 s and an exact laser 10 s after every third reading (the roll
/// 0.05° on from the newest estimate) is vouched for once two samples
/// after the first agree, and never flagged after.
#[test]
fn a_steady_roll_between_an_estimate_and_a_laser_sample_is_no_disagreement() {
    let mut e = engine(&[]);
    let roll_at = |s: f64| 0.005 * s;
    let mut out = Vec::new();
    let mut seen = Vec::new();
    for i in 0..60 {
        let s = 20.0 * f64::from(i);
        out.clear();
        e.feed(&incl(T0 + s, 0.3, roll_at(s)), &mut out);
        seen.push(out.last().expect("an estimate").integrity);
        if i % 3 == 0 {
            e.feed(&laser(T0 + s + 10.0, 0.3, roll_at(s + 10.0)), &mut out);
        }
    }
    assert_eq!(
        seen[0].reason,
        Some(crate::fusion::IntegrityReason::Unverified)
    );
    let vouched = seen.iter().position(|i| i.is_ok()).expect("vouched for");
    assert!(vouched <= 10, "first ok at reading {vouched}");
    assert!(seen[vouched..].iter().all(|i| i.is_ok()), "{seen:?}");
}

/// Issue 54: a new inclinometer zero between laser samples. A 1 Hz
/// inclinometer with ±0.01° of noise on a still shield at pitch 0.3°,
/// the laser every 60 s; at 1,000 s (40 s after a laser sample) the
/// inclinometer's zero moves by 0.05°. Within 20 readings the estimate
/// is `degraded` (`unverified`) and its pitch σ grows by the step's
/// bound (0.05/√3 = 0.029°); the next laser sample takes the flag.
#[test]
fn a_step_in_the_inclinometer_is_flagged_and_widened_until_the_laser_checks() {
    let mut e = engine(&[]);
    let mut out = Vec::new();
    let mut at = Vec::new();
    for i in 0..1030 {
        let s = f64::from(i);
        let noise = if i % 2 == 0 { 0.01 } else { -0.01 };
        let zero = if i >= 1000 { 0.05 } else { 0.0 };
        out.clear();
        e.feed(&incl(T0 + s, 0.3 + noise + zero, 0.2 + noise), &mut out);
        if let Some(o) = out.last() {
            at.push((s, o.integrity, attitude(&out).pitch_sigma_deg.unwrap()));
        }
        if i % 60 == 0 {
            e.feed(&laser(T0 + s + 0.5, 0.3, 0.2), &mut out);
        }
    }
    let before = at.iter().find(|(s, ..)| *s == 999.0).unwrap();
    assert!(before.1.is_ok(), "{before:?}");
    let flagged = at
        .iter()
        .find(|(s, i, _)| *s >= 1000.0 && !i.is_ok())
        .expect("the step is flagged");
    assert!(flagged.0 < 1020.0, "{flagged:?}");
    assert_eq!(
        flagged.1.reason,
        Some(crate::fusion::IntegrityReason::Unverified)
    );
    assert!(flagged.2 >= 0.04 / 3f64.sqrt(), "{flagged:?}");
    // The laser sample at 1,020.5 s checks it (and finds the estimate
    // off: the laser monitor's own flag may follow).
    assert!(!e.step_watch.unverified());
}

#[test]
fn a_laser_that_jumps_while_the_inclinometer_does_not_is_held_out_and_widened() {
    // A still machine, laser every 10 s; from 1,000 s to 1,300 s the
    // laser reads 0.2° more on both axes (a wrong prism).
    let mut e = engine(&[]);
    let mut out = Vec::new();
    let mut at = Vec::new();
    for i in 0..1500 {
        let s = f64::from(i);
        let noise = if i % 2 == 0 { 0.002 } else { -0.002 };
        out.clear();
        e.feed(&incl(T0 + s, 0.3 + noise, 0.2 + noise), &mut out);
        if let Some(o) = out.last() {
            let a = attitude(&out);
            at.push((s, o.integrity, a.pitch_deg, a.pitch_sigma_deg.unwrap()));
        }
        if i % 10 == 0 {
            let jump = if (1000..1300).contains(&i) { 0.2 } else { 0.0 };
            e.feed(&laser(T0 + s + 0.5, 0.3 + jump, 0.2 + jump), &mut out);
        }
    }
    let before = at.iter().find(|(s, ..)| *s == 999.0).unwrap();
    assert!(before.1.is_ok(), "{before:?}");
    for (s, integrity, pitch_deg, sigma_deg) in
        at.iter().filter(|(s, ..)| (1001.0..1300.0).contains(s))
    {
        assert_eq!(
            integrity.reason,
            Some(crate::fusion::IntegrityReason::LaserDisagrees),
            "at {s} s"
        );
        // The estimate keeps the inclinometer's continuity; its σ
        // covers the laser's word (0.2° from the truth, 0.175° from
        // the estimate before, 0.3255° ± 0.0223°).
        assert!(
            (pitch_deg - before.2).abs() < 0.002,
            "at {s} s: {pitch_deg}"
        );
        assert!(*sigma_deg >= 0.17, "at {s} s: {sigma_deg}");
    }
    assert!(e.laser_dispute.disputes >= 1 && e.laser_dispute.held_out >= 29);
    // The laser is back at 1,300.5 s: it agrees, and no one is blamed.
    let after = at.iter().find(|(s, ..)| *s == 1310.0).unwrap();
    assert!(after.1.is_ok(), "{after:?}");
    assert!(!e.laser_dispute.is_open());
}

#[test]
fn before_any_laser_the_estimate_is_the_filtered_inclinometer() {
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    e.feed(&incl(T0, 0.5, 1.0), &mut out);
    let a = attitude(&out);
    assert!((a.pitch_deg - 0.5).abs() < 1e-12);
    assert!((a.roll_deg - 1.0).abs() < 1e-12);
    assert!(!a.laser_ok);
    assert_eq!(a.pitch_correction_deg, 0.0);
    assert_eq!(a.laser_age_s, None);
    assert_eq!(a.pred_t, T0);
}

#[test]
fn the_first_estimate_carries_the_priors_as_its_sigma() {
    // θ = z − b with b ~ N(0, (0.5°)²) and the reading's noise r:
    // σ_pitch = √(0.25 + 0.0001)°, σ_roll = √(0.09 + 0.0001)° (the
    // roll's mounting-offset prior is 0.3°); nothing is unchecked yet.
    let mut e = engine(&["noise=fixed", "r_incl_deg2=0.0001"]);
    let mut out = Vec::new();
    e.feed(&incl(T0, 0.5, 1.0), &mut out);
    let a = attitude(&out);
    let pitch = a.pitch_sigma_deg.unwrap();
    assert!((pitch - 0.2501_f64.sqrt()).abs() < 1e-12, "{pitch}");
    let roll = a.roll_sigma_deg.unwrap();
    assert!((roll - 0.0901_f64.sqrt()).abs() < 1e-12, "{roll}");
    assert_eq!(a.pitch_pred_sigma_deg, a.pitch_sigma_deg);
}

#[test]
fn sigma_grows_as_a_dropout_takes_the_roll_beyond_the_trained_range() {
    // Two hours with the laser every minute, the roll within 0–2° and an
    // error that changes with it; then an hour without the laser while
    // the roll ramps by 4° (from 0.46° to 4.46°), 2.46° past anything the
    // model has seen; then the laser again, there. The angle holds still
    // and the laser has shown it does (a small q_θ̇), so the filter's
    // slope state takes most of the inclinometer's change as the error's:
    // σ grows, and covers the error.
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    let roll_at = |s: f64| {
        if s < 7200.0 {
            1.0 + (s / 600.0).sin()
        } else {
            (1.0 + (12.0_f64).sin()) + 4.0 * ((s - 7200.0) / 3600.0).min(1.0)
        }
    };
    let mut sigma_at = |e: &mut AttitudeEngine, from: u32, to: u32, with_laser: bool| {
        let mut last = (0.0, 0.0);
        for s in from..to {
            let t = T0 + f64::from(s);
            let roll = roll_at(f64::from(s));
            let error = 0.1 * (roll / 2.0).sin();
            if with_laser && s % 60 == 30 {
                e.feed(&laser(t, 0.8, roll), &mut out);
            }
            // A live sensor's last digit (1e−6°): one repeating the same
            // value to the bit is frozen (the inclinometer monitor).
            let dither = 1e-6 * f64::from(s % 5);
            e.feed(&incl(t, 0.8 - error + dither, roll), &mut out);
            let a = attitude(&out);
            last = (a.pitch_sigma_deg.unwrap(), (a.pitch_deg - 0.8).abs());
        }
        last
    };
    let (trained, _) = sigma_at(&mut e, 0, 7200, true);
    let (early, _) = sigma_at(&mut e, 7200, 7320, false);
    let (late, late_error) = sigma_at(&mut e, 7320, 10_800, false);
    let (back, _) = sigma_at(&mut e, 10_800, 11_400, true);
    assert!(trained < 0.01, "{trained}");
    assert!(late > 3.0 * early, "early {early}, late {late}");
    assert!(late_error < 2.0 * late, "late {late}, error {late_error}");
    assert!(back < 0.5 * late, "late {late}, back {back}");
}

#[test]
fn first_laser_update_matches_hand_computation() {
    // noise=fixed, no process noise. The first inclinometer reading
    // starts θ = 0.5°, b = 0 with P = [[vb + r, 0, −vb], [0, ·, 0],
    // [−vb, 0, vb]], vb = (0.5°)². A laser of 0.8° at the same instant:
    // S = vb + r + r_L, θ = 0.5 + 0.3 (vb + r) / S, b = 0.3 · (−vb) / S
    // (the inclinometer reads low: its bias is negative).
    let mut e = engine(&[
        "noise=fixed",
        "r_incl_deg2=0.0001",
        "r_laser_deg2=0.0004",
        "q_pitch_deg2_per_s=0",
        "q_pitch_rate_deg2_per_s3=0",
        "q_bias_deg2_per_s=0",
    ]);
    let mut out = Vec::new();
    e.feed(&incl(T0, 0.5, 1.0), &mut out);
    e.feed(&laser(T0, 0.8, 1.0), &mut out);
    let f = e.pitch.unwrap();
    let (vb, r, r_l) = (0.25, 1e-4, 4e-4);
    let s = vb + r + r_l;
    assert!((deg(f.angle()) - (0.5 + 0.3 * (vb + r) / s)).abs() < 1e-12);
    assert!((deg(f.bias()) + 0.3 * vb / s).abs() < 1e-12);
    // θ + b still reads what the inclinometer said.
    assert!((deg(f.angle() + f.bias()) - (0.5 + 0.3 * r / s)).abs() < 1e-12);
}

#[test]
fn the_laser_reveals_the_inclinometer_error_and_the_model_learns_it() {
    // True pitch 0.8°, the inclinometer reads 0.5° at every roll: the
    // error is a constant 0.3°, learned as the correction.
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    for s in 0..7200 {
        let t = T0 + s as f64;
        let roll = 1.0 + (s as f64 / 900.0).sin();
        if s % 60 == 30 {
            e.feed(&laser(t, 0.8, roll), &mut out);
        }
        e.feed(&incl(t, 0.5, roll), &mut out);
    }
    let a = attitude(&out);
    assert!((a.pitch_deg - 0.8).abs() < 1e-3, "{}", a.pitch_deg);
    assert!(
        (a.pitch_correction_deg - 0.3).abs() < 2e-3,
        "{}",
        a.pitch_correction_deg
    );
    assert!(a.laser_ok);
    assert!(e.anfis().samples().len() > 60);
    // The prediction is for the next reading, one period ahead.
    assert_eq!(a.pred_t, a_t(&out) + 1.0);
    let report = e.model_report(false);
    assert!(report.roll_offset_deg.unwrap().abs() < 1e-3);
    assert!(report.pitch_bias_deg.unwrap().abs() < 2e-3);
}

fn a_t(out: &[EngineOutput]) -> f64 {
    out.last().unwrap().t
}

#[test]
fn prediction_is_the_estimate_plus_rate_times_the_period() {
    // A pitch ramp of 0.001 °/s read every 5 s: once the filter has the
    // rate, the prediction 5 s ahead adds 0.005°.
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    for k in 0..2000 {
        let t = T0 + 5.0 * k as f64;
        let truth = 0.2 + 0.001 * 5.0 * k as f64;
        if k % 24 == 3 {
            e.feed(&laser(t, truth, 0.0), &mut out);
        }
        e.feed(&incl(t, truth - 0.1, 0.0), &mut out);
    }
    let a = attitude(&out);
    assert_eq!(a.pred_t, a_t(&out) + 5.0);
    let step = a.pitch_pred_deg - a.pitch_deg;
    assert!((step - 0.005).abs() < 2e-4, "{step}");
}

#[test]
fn stale_and_duplicate_readings_are_dropped() {
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    e.feed(&incl(T0 + 1.0, 0.5, 1.0), &mut out);
    e.feed(&incl(T0 + 1.0, 0.6, 1.0), &mut out);
    e.feed(&incl(T0, 0.6, 1.0), &mut out);
    assert_eq!(out.len(), 1);
    e.feed(&laser(T0 + 1.0, 0.5, 1.0), &mut out);
    e.feed(&laser(T0 + 1.0, 0.5, 1.0), &mut out);
    e.feed(&laser(T0, 0.5, 1.0), &mut out);
    let s = e.stats();
    assert_eq!(
        (s.inclinometer_dropped, s.laser_used, s.laser_dropped),
        (2, 1, 2)
    );
}

#[test]
fn a_laser_sample_is_paired_once_the_inclinometer_has_passed_it() {
    // Pairing window 60 s: the pair at T0 + 10 is made when the
    // inclinometer reaches T0 + 70, from the readings on both sides.
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    for s in 0..=69 {
        e.feed(&incl(T0 + s as f64, 0.5, 1.0), &mut out);
        if s == 10 {
            e.feed(&laser(T0 + 10.0, 0.9, 1.0), &mut out);
        }
    }
    assert!(e.anfis().samples().is_empty());
    e.feed(&incl(T0 + 70.0, 0.5, 1.0), &mut out);
    assert_eq!(e.anfis().samples().len(), 1);
    let sample = e.anfis().samples()[0];
    assert!((deg(sample.error_rad) - 0.4).abs() < 1e-9);
}

#[test]
fn a_late_laser_sample_still_corrects_the_estimate() {
    // A laser sample 30 s older than the newest inclinometer reading
    // moves the estimate towards it as one on time would.
    let run = |late: bool| {
        let mut e = AttitudeEngine::with_defaults();
        let mut out = Vec::new();
        for s in 0..=100 {
            e.feed(&incl(T0 + s as f64, 0.5, 1.0), &mut out);
            if s == if late { 100 } else { 70 } {
                e.feed(&laser(T0 + 70.0, 0.8, 1.0), &mut out);
            }
        }
        e.feed(&incl(T0 + 101.0, 0.5, 1.0), &mut out);
        attitude(&out).pitch_deg
    };
    let (on_time, late) = (run(false), run(true));
    assert!(on_time > 0.75, "{on_time}");
    assert!((late - on_time).abs() < 0.01, "{late} vs {on_time}");
}

#[test]
fn dropout_is_detected_from_the_laser_age() {
    let mut e = engine(&["laser_period_s=60", "dropout_factor=2"]);
    let mut out = Vec::new();
    for s in 0..=400 {
        let t = T0 + s as f64;
        if s % 60 == 0 && s <= 120 {
            e.feed(&laser(t, 0.8, 1.0), &mut out);
        }
        e.feed(&incl(t, 0.5, 1.0), &mut out);
    }
    let ok: Vec<bool> = out
        .iter()
        .map(|o| o.values.as_attitude().expect("attitude").laser_ok)
        .collect();
    // Held sample at 120 s, period 60 s: ok through 240 s, dropout after.
    assert!(ok[..=240].iter().all(|&b| b));
    assert!(ok[241..].iter().all(|&b| !b));
    assert!(e.model_report(true).frozen);
}

/// The inclinometer's error: a smooth function of roll.
fn error_deg(roll_deg: f64) -> f64 {
    0.3 + 0.06 * roll_deg - 0.02 * roll_deg * roll_deg
}

#[test]
fn a_fast_roll_sweep_is_followed_without_lag() {
    // Roll swings ±2° with a 20-minute period (0.6 °/min at its
    // fastest); true pitch 0.8°, read through the error above. After
    // two hours of learning the laser stops: the estimate must follow
    // the roll through the model alone.
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    let mut worst_with_laser: f64 = 0.0;
    let mut worst_without: f64 = 0.0;
    let mut biggest_step: f64 = 0.0;
    let mut previous: Option<f64> = None;
    for s in 0..4 * 3600 {
        let t = T0 + s as f64;
        let roll = 2.0 * (std::f64::consts::TAU * s as f64 / 1200.0).sin();
        if s % 60 == 30 && s < 2 * 3600 {
            e.feed(&laser(t, 0.8, roll), &mut out);
        }
        out.clear();
        e.feed(&incl(t, 0.8 - error_deg(roll), roll), &mut out);
        let pitch = attitude(&out).pitch_deg;
        if s > 3600 {
            let error = (pitch - 0.8).abs();
            if s < 2 * 3600 {
                worst_with_laser = worst_with_laser.max(error);
                biggest_step = biggest_step.max((pitch - previous.unwrap_or(pitch)).abs());
            } else {
                worst_without = worst_without.max(error);
            }
        }
        previous = Some(pitch);
    }
    // The error moves by up to 0.13 °/° × 0.63 °/min = 0.08 °/min: a
    // correction slewed at 5e-4 °/s (0.03 °/min) would trail it by
    // tenths of a degree.
    assert!(worst_with_laser < 0.015, "{worst_with_laser}");
    assert!(worst_without < 0.015, "{worst_without}");
    // The biggest steps are laser samples correcting what is left.
    assert!(biggest_step < 0.003, "{biggest_step}");
}

#[test]
fn a_retrain_moves_the_correction_not_the_estimate() {
    // The inclinometer reads 0.3° low; the first trainings move the
    // correction from 0 towards 0.3° in large steps. The filter's bias
    // moves with it, so the estimate does not.
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    let mut checked = 0;
    let mut previous: Option<AttitudeEstimate> = None;
    for s in 0..3600 {
        let t = T0 + s as f64;
        if s % 60 == 0 {
            e.feed(&laser(t, 0.8, 1.0), &mut out);
        }
        out.clear();
        e.feed(&incl(t, 0.5, 1.0), &mut out);
        let a = attitude(&out).clone();
        // Roll and readings are constant: the correction moves only
        // when the model is retrained.
        if let Some(p) = &previous {
            let moved = (a.pitch_correction_deg - p.pitch_correction_deg).abs();
            let step = (a.pitch_deg - p.pitch_deg).abs();
            if moved > 0.01 {
                assert!(step < 0.05 * moved, "retrain at {s} s: {step} for {moved}");
                checked += 1;
            }
        }
        previous = Some(a);
    }
    assert!(checked > 0, "no large retrain seen");
}

#[test]
fn the_temperature_term_holds_through_a_dropout() {
    // The error grows by 0.004 °/°C while the shield warms and cools by
    // 16 °C over four hours; the laser stops for the last hour while
    // the temperature swings: the correction must follow it.
    let temp = |s: f64| 15.0 + 8.0 * (std::f64::consts::TAU * s / 14_400.0).sin();
    let run = |correction: &str| {
        let mut e = engine(&[&format!("correction={correction}")]);
        let mut out = Vec::new();
        let mut worst: f64 = 0.0;
        for s in 0..5 * 3600 {
            let t = T0 + s as f64;
            let roll = 1.0 + 0.5 * (s as f64 / 700.0).sin();
            if s % 60 == 30 && s < 4 * 3600 {
                e.feed(&laser(t, 0.8, roll), &mut out);
            }
            let error = error_deg(roll) + 0.004 * (temp(s as f64) - 15.0);
            out.clear();
            e.feed(
                &Reading {
                    t,
                    data: SensorData::Inclinometer {
                        pitch_deg: 0.8 - error,
                        roll_deg: roll,
                        temp_c: Some((temp(s as f64) * 10.0).round() / 10.0),
                    },
                },
                &mut out,
            );
            if s >= 4 * 3600 {
                worst = worst.max((attitude(&out).pitch_deg - 0.8).abs());
            }
        }
        (worst, e)
    };
    let (with_model, e) = run("anfis");
    let (offset, _) = run("offset");
    assert!(with_model < 0.01, "{with_model}");
    assert!(offset > 3.0 * with_model, "{offset} vs {with_model}");
    let report = e.model_report(true);
    assert!(
        (report.temp_coefficient_deg_per_c - 0.004).abs() < 5e-4,
        "{}",
        report.temp_coefficient_deg_per_c
    );
}

#[test]
fn noise_is_measured_per_phase() {
    // 40 minutes cutting at σ 0.03°, 20 standing at 0.006°, repeated;
    // the engine is told neither.
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    for s in 0..6 * 3600 {
        let t = T0 + s as f64;
        let sigma = if s % 3600 < 2400 { 0.03 } else { 0.006 };
        let n: f64 = StandardNormal.sample(&mut rng);
        let m: f64 = StandardNormal.sample(&mut rng);
        if s % 120 == 60 {
            e.feed(&laser(t, 0.5, 1.0), &mut out);
        }
        e.feed(&incl(t, 0.2 + sigma * n, 1.0 + sigma * m), &mut out);
    }
    let noise = e.model_report(false).noise;
    assert!(
        (noise.incl_pitch_vibrating_deg / 0.03 - 1.0).abs() < 0.3,
        "{noise:?}"
    );
    assert!(
        (noise.incl_pitch_quiet_deg / 0.006 - 1.0).abs() < 0.3,
        "{noise:?}"
    );
    assert_eq!(noise.mode, NoiseMode::Adaptive);
}

#[test]
fn snapshot_restore_continues_exactly() {
    let mut a = AttitudeEngine::with_defaults();
    let mut out_a = Vec::new();
    let feed = |e: &mut dyn Engine, s: usize, out: &mut Vec<EngineOutput>| {
        let t = T0 + s as f64;
        let roll = 1.0 + (s as f64 / 300.0).sin();
        if s.is_multiple_of(60) {
            e.feed(&laser(t, 0.3 + 0.01 * roll * roll, roll), out);
        }
        e.feed(&incl(t, 0.1 + 0.001 * (s % 7) as f64, roll + 0.2), out);
    };
    for s in 0..2000 {
        feed(&mut a, s, &mut out_a);
    }
    let snap = a.snapshot();
    let text = serde_json::to_string(&snap).unwrap();
    let mut b = AttitudeEngine::restore(serde_json::from_str(&text).unwrap()).unwrap();
    assert_eq!(a, b);
    let mut out_b = Vec::new();
    out_a.clear();
    for s in 2000..4000 {
        feed(&mut a, s, &mut out_a);
        feed(&mut b, s, &mut out_b);
    }
    assert_eq!(out_a, out_b);
}

#[test]
fn a_reading_trains_the_model_in_use_and_at_most_one_candidate() {
    // A laser sample every 10 s: while young each pair trains every
    // model, so candidates wait in the queue.
    let mut engine = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    let versions = |e: &AttitudeEngine| e.models.iter().map(|m| m.version()).collect::<Vec<_>>();
    let mut queued_seen = false;
    for s in 0..3000u32 {
        let t = T0 + s as f64;
        let roll = 1.0 + (s as f64 / 300.0).sin();
        let mut readings = vec![incl(t, 0.1, roll + 0.2)];
        if s.is_multiple_of(10) {
            readings.insert(0, laser(t, 0.3 + 0.01 * roll * roll, roll));
        }
        for reading in readings {
            let (before, in_use) = (versions(&engine), engine.chosen);
            engine.feed(&reading, &mut out);
            let after = versions(&engine);
            let trained: Vec<usize> = (0..after.len())
                .filter(|&i| after[i] != before[i])
                .collect();
            let candidates = trained.iter().filter(|&&i| i != in_use).count();
            assert!(
                candidates <= 1,
                "second {s}: models {trained:?} trained by one reading"
            );
            assert!(
                after[in_use] - before[in_use] <= 1,
                "second {s}: the model in use trained twice"
            );
            queued_seen |= !engine.candidates_due.is_empty();
        }
    }
    assert!(
        queued_seen,
        "no candidate ever waited: the test shows nothing"
    );
}

#[test]
fn a_snapshot_with_candidates_waiting_continues_exactly() {
    let mut a = AttitudeEngine::with_defaults();
    let mut out_a = Vec::new();
    let feed = |e: &mut dyn Engine, s: usize, out: &mut Vec<EngineOutput>| {
        let t = T0 + s as f64;
        let roll = 1.0 + (s as f64 / 300.0).sin();
        if s.is_multiple_of(10) {
            e.feed(&laser(t, 0.3 + 0.01 * roll * roll, roll), out);
        }
        e.feed(&incl(t, 0.1, roll + 0.2), out);
    };
    let mut s = 0;
    while a.candidates_due.is_empty() {
        feed(&mut a, s, &mut out_a);
        s += 1;
        assert!(s < 3000, "no candidate ever waited");
    }
    let text = serde_json::to_string(&a.snapshot()).unwrap();
    let mut b = AttitudeEngine::restore(serde_json::from_str(&text).unwrap()).unwrap();
    assert_eq!(a, b);
    let mut out_b = Vec::new();
    out_a.clear();
    for s in s..s + 600 {
        feed(&mut a, s, &mut out_a);
        feed(&mut b, s, &mut out_b);
    }
    assert_eq!(out_a, out_b);
}

#[test]
fn corrupt_and_outdated_snapshots_are_refused_not_trusted() {
    let mut e = AttitudeEngine::with_defaults();
    let mut out = Vec::new();
    for s in 0..1200 {
        let t = T0 + s as f64;
        if s % 60 == 0 {
            e.feed(
                &laser(
                    t,
                    0.8 + 0.001 * (s / 60) as f64,
                    1.0 + 0.05 * (s / 60) as f64,
                ),
                &mut out,
            );
        }
        e.feed(&incl(t, 0.5, 1.0 + 0.05 * (s / 60) as f64), &mut out);
    }
    let snap = e.snapshot();
    assert_eq!(snap["models"][0]["rules"].as_array().map(Vec::len), Some(3));
    let mut too_many = snap.clone();
    let rule = too_many["models"][0]["rules"][0].clone();
    for _ in 0..10 {
        too_many["models"][0]["rules"]
            .as_array_mut()
            .unwrap()
            .push(rule.clone());
    }
    assert!(matches!(
        AttitudeEngine::restore(too_many),
        Err(SnapshotError::Invalid(_))
    ));
    let mut flat = snap.clone();
    flat["models"][0]["rules"][1]["width_rad"] = serde_json::json!(0.0);
    assert!(matches!(
        AttitudeEngine::restore(flat),
        Err(SnapshotError::Invalid(_))
    ));
    let mut unbounded = snap.clone();
    unbounded["history"]["capacity"] = serde_json::json!(0);
    let restored = AttitudeEngine::restore(unbounded).unwrap();
    assert_eq!(restored, AttitudeEngine::restore(snap.clone()).unwrap());
    // A snapshot of the engine before the state version existed.
    let mut old = snap;
    old.as_object_mut().unwrap().remove("state_version");
    assert!(matches!(
        AttitudeEngine::restore(old),
        Err(SnapshotError::Outdated {
            found: 1,
            expected: 12,
            ..
        })
    ));
}

#[test]
fn inconsistent_parameters_are_refused() {
    let p = Params::from_assignments(
        PARAMS,
        ["training_window_samples=20", "anfis_min_samples=30"],
    )
    .unwrap();
    assert!(matches!(
        AttitudeEngine::new(p),
        Err(ParamError::Inconsistent(_))
    ));
}
