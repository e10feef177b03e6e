use super::*;
use crate::config::MachineDeclaration;
use crate::config::MachineSpec;
use crate::fusion::Reading;
use crate::fusion::SensorData;
use crate::fusion::alarms::Transition;
use crate::fusion::alarms::{AlarmKind, Severity};
use crate::fusion::reading::ProjectPoint;

/// An attitude machine on a straight axis due north from (1000, 5000),
/// level at 50 m, with ±50/100 mm horizontal tolerances.
fn spec() -> MachineSpec {
    serde_json::from_value::<MachineDeclaration>(serde_json::json!({
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.0, 0.0, 0.0], "rear_m": [-5.0, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "alignment": {"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
                      "horizontal": [{"type": "line", "length_m": 100.0}],
                      "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}
    }))
    .unwrap()
    .validate("tbm-alarms")
    .unwrap()
}

/// A laser reading at `t` with the machine `right_mm` right of the axis.
fn laser(t: f64, right_mm: f64) -> Reading {
    Reading {
        t,
        data: SensorData::Laser {
            pitch_deg: 0.0,
            roll_deg: 0.0,
            yaw_deg: Some(0.0),
            position: Some(ProjectPoint {
                easting_m: 1000.0 + right_mm / 1000.0,
                northing_m: 5020.0,
                height_m: 50.0,
            }),
        },
    }
}

fn inclinometer(t: f64) -> Reading {
    Reading {
        t,
        data: SensorData::Inclinometer {
            pitch_deg: 0.0,
            roll_deg: 0.0,
            temp_c: None,
        },
    }
}

fn feed(core: &mut MachineCore, readings: impl IntoIterator<Item = Reading>) -> Vec<Transition> {
    let mut out = Vec::new();
    for reading in readings {
        core.push(reading, &mut out);
    }
    core.take_alarms()
}

#[test]
fn the_machine_raises_clears_and_remembers_its_alarms_across_a_snapshot() {
    let spec = spec();
    let mut core = MachineCore::new(&spec).unwrap();
    // 70 mm right from t = 0, every 2 s: warn raised once the 10 s
    // minimum has passed, dated 0.
    let raised = feed(&mut core, (0..=10).map(|i| laser(2.0 * f64::from(i), 70.0)));
    assert_eq!(raised.len(), 1, "{raised:?}");
    assert_eq!(
        (
            raised[0].key.kind,
            raised[0].key.severity,
            raised[0].raised,
            raised[0].t
        ),
        (AlarmKind::Deviation, Severity::Warn, true, 0.0)
    );
    // Restored from a snapshot, it stays raised: no second raise.
    let mut restored = MachineCore::restore(&spec, &core.snapshot()).unwrap();
    assert!(
        feed(
            &mut restored,
            (11..20).map(|i| laser(2.0 * f64::from(i), 70.0))
        )
        .is_empty()
    );
    // Back on the axis from t = 40, an inclinometer reading between
    // each: cleared at t = 60 (gone 10 s, and held a minute from its
    // onset), dated 40.
    let cleared = feed(
        &mut restored,
        (20..=30).flat_map(|i| {
            let t = 2.0 * f64::from(i);
            [laser(t, 0.0), inclinometer(t + 1.0)]
        }),
    );
    assert_eq!(cleared.len(), 1, "{cleared:?}");
    assert!(!cleared[0].raised && cleared[0].t == 40.0);
    // The machine then falls silent: the inclinometer is stale after 5
    // of its 2 s periods, at least 10 s, past its last reading at
    // t = 61 (the laser's silence is a laser dropout's business).
    assert!(restored.tick(70.0).is_empty());
    let stale = restored.tick(72.0);
    assert_eq!(stale.len(), 1, "{stale:?}");
    assert_eq!(
        (stale[0].key.kind, stale[0].key.subject.as_str(), stale[0].t),
        (AlarmKind::StaleSensor, "inclinometer", 71.0)
    );
}

#[test]
fn a_snapshot_from_before_the_alarms_restores_with_none_active() {
    let spec = spec();
    let core = MachineCore::new(&spec).unwrap();
    let mut state: serde_json::Value = serde_json::from_str(&core.snapshot()).unwrap();
    state.as_object_mut().unwrap().remove("alarms");
    let mut restored = MachineCore::restore(&spec, &state.to_string()).unwrap();
    let raised = feed(
        &mut restored,
        (0..=10).map(|i| laser(2.0 * f64::from(i), 70.0)),
    );
    assert_eq!(raised.len(), 1);
}
