//! Issue 54: the `fuzzy` engine after an IMU power cycle at a stop (the
//! demo's shift boundary): the gyros come up with a new turn-on bias,
//! the engine must not show a wrong tilt as right, and must recover.
//!
//! Seeds 1–6 of the default (gentle) drive were fixed before any result
//! on them was looked at. Each drive is power-cycled at the start of its
//! first stop of at least 5 s after 300 s. Asserted on all of them: no
//! run of estimates shown `ok` whose tilt error exceeds 5σ and 1° lasts
//! longer than 10 s; from 30 s after the cycle on, the tilt of the `ok`
//! estimates is within 2° (the engine re-levelled, no lock-out).
//! The same figures over the whole envelope are
//! `tunnelnav eval fuzzy --envelope --fault power-cycle`.

use tunnelnav::config::MachineDeclaration;
use tunnelnav::eval::integrity::{IntegrityScore, misleading};
use tunnelnav::fusion::alarms::{AlarmKind, Severity};
use tunnelnav::fusion::fuzzy::PARAMS;
use tunnelnav::fusion::{EngineKind, ParamValue, Params};
use tunnelnav::machine::MachineCore;
use tunnelnav::sim::vehicle::{VehicleDrive, VehicleScenario};

/// The start of the first stop of at least 5 s after 300 s, seconds
/// from the start.
fn first_stop_after_300_s(scenario: &VehicleScenario) -> f64 {
    let mut still_since: Option<f64> = None;
    for event in VehicleDrive::new(scenario.clone()).unwrap() {
        let Some(truth) = event.truth else { continue };
        let s = truth.t - scenario.start_t;
        if s < 300.0 || truth.moving {
            still_since = None;
            continue;
        }
        let since = *still_since.get_or_insert(s);
        if s - since >= 5.0 {
            return since;
        }
    }
    panic!("seed {}: no stop of 5 s after 300 s", scenario.seed);
}

#[test]
fn a_power_cycle_at_a_stop_is_never_shown_as_right_and_the_engine_recovers() {
    for seed in 1..=6 {
        let mut scenario = VehicleScenario {
            seed,
            ..VehicleScenario::default()
        };
        let cycle_s = first_stop_after_300_s(&scenario);
        scenario.power_cycles_s = vec![cycle_s];
        let params = Params::defaults(PARAMS)
            .with_overrides(
                PARAMS,
                [
                    ("declination_deg", scenario.declination_deg),
                    ("mag_inclination_deg", scenario.inclination_deg),
                    ("window_samples", 50.0),
                ]
                .map(|(name, value)| (name.to_string(), ParamValue::Number(value))),
            )
            .unwrap();
        let mut engine = EngineKind::Fuzzy.create(params).unwrap();
        let mut score = IntegrityScore::default();
        let mut worst_after_deg: f64 = 0.0;
        let mut out = Vec::new();
        for event in VehicleDrive::new(scenario.clone()).unwrap() {
            out.clear();
            engine.feed(&event.reading, &mut out);
            let (Some(truth), Some(output)) = (event.truth, out.last()) else {
                continue;
            };
            let estimate = output.values.as_fuzzy().unwrap();
            let s = truth.t - scenario.start_t;
            if s < 10.0 {
                continue;
            }
            let pitch_error = estimate.pitch_deg - truth.pitch_deg;
            let roll_error = estimate.roll_deg - truth.roll_deg;
            let wrong = misleading(pitch_error, estimate.pitch_sigma_deg, 1.0)
                || misleading(roll_error, estimate.roll_sigma_deg, 1.0);
            score.add(truth.t, output.integrity, wrong);
            if s >= cycle_s + 30.0 && output.integrity.is_ok() {
                worst_after_deg = worst_after_deg.max(pitch_error.abs().max(roll_error.abs()));
            }
        }
        eprintln!(
            "seed {seed}: cycle at {cycle_s:.1} s, flagged {:.2} %, longest misleading ok run {:.1} s, worst tilt 30 s after {worst_after_deg:.2}°",
            100.0 * score.flagged_share(),
            score.worst_run_s
        );
        assert!(
            score.worst_run_s <= 10.0,
            "seed {seed}: a misleading run of {} s from {:?}",
            score.worst_run_s,
            score.worst_run_from_t
        );
        assert!(
            worst_after_deg <= 2.0,
            "seed {seed}: tilt error {worst_after_deg}° shown ok after the cycle"
        );
    }
}

/// The same fault seen by an operator: a machine running `fuzzy` (seed 1,
/// cycled as above) raises an `integrity` alarm about `fuzzy` within 10 s
/// of the cycle, and clears it once the engine is vouched for again.
#[test]
fn a_power_cycle_raises_an_integrity_alarm_that_clears_on_recovery() {
    let mut scenario = VehicleScenario {
        seed: 1,
        ..VehicleScenario::default()
    };
    let cycle_s = first_stop_after_300_s(&scenario);
    scenario.power_cycles_s = vec![cycle_s];
    let spec = serde_json::from_value::<MachineDeclaration>(serde_json::json!({
        "engines": {"fuzzy": {
            "declination_deg": scenario.declination_deg,
            "mag_inclination_deg": scenario.inclination_deg,
            "window_samples": 50
        }}
    }))
    .unwrap()
    .validate("van")
    .unwrap();
    let mut core = MachineCore::new(&spec).unwrap();
    let mut out = Vec::new();
    let mut transitions = Vec::new();
    for event in VehicleDrive::new(scenario.clone()).unwrap() {
        out.clear();
        core.push(event.reading, &mut out);
        transitions.extend(core.take_alarms());
    }
    let integrity: Vec<_> = transitions
        .iter()
        .filter(|t| t.key.kind == AlarmKind::Integrity)
        .map(|t| {
            (
                t.key.severity,
                t.key.subject.as_str(),
                t.raised,
                t.t - scenario.start_t,
            )
        })
        .collect();
    eprintln!("cycle at {cycle_s:.1} s: {integrity:?}");
    let raised = integrity
        .iter()
        .find(|(severity, _, raised, _)| *severity == Severity::Alarm && *raised)
        .expect("an integrity alarm");
    assert_eq!(raised.1, "fuzzy");
    assert!(
        raised.3 >= cycle_s && raised.3 <= cycle_s + 10.0,
        "raised at {} s, the cycle at {cycle_s} s",
        raised.3
    );
    let last = integrity.iter().rev().find(|e| e.0 == Severity::Alarm);
    assert!(
        last.is_some_and(|e| !e.2),
        "the alarm clears on recovery: {integrity:?}"
    );
}
