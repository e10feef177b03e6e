//! Property tests: no finite reading sequence makes the engine panic or
//! produce a non-finite estimate, and a snapshot taken anywhere continues
//! exactly.

use proptest::prelude::*;
use tunnelnav::fusion::{Engine, EngineKind, EngineOutput, Params, Reading, SensorData};

const T0: f64 = 1_772_431_200.0;

/// A reading at a time offset that may go backwards, repeat or jump.
fn reading() -> impl Strategy<Value = (f64, Reading)> {
    let angle = prop_oneof![-90.0..90.0f64, -1.0..1.0f64, Just(0.0), Just(89.999)];
    let roll = prop_oneof![-180.0..180.0f64, -3.0..3.0f64, Just(0.0)];
    let step = prop_oneof![
        0.0..2.0f64,
        Just(0.0),
        -5.0..0.0f64,
        100.0..100_000.0f64,
        1e-9..1e-6f64
    ];
    (
        step,
        any::<bool>(),
        angle,
        roll,
        proptest::option::of(-40.0..80.0f64),
    )
        .prop_map(|(step, is_laser, pitch_deg, roll_deg, temp_c)| {
            let data = if is_laser {
                SensorData::Laser {
                    pitch_deg,
                    roll_deg,
                    yaw_deg: None,
                    position: None,
                }
            } else {
                SensorData::Inclinometer {
                    pitch_deg,
                    roll_deg,
                    temp_c,
                }
            };
            (step, Reading { t: 0.0, data })
        })
}

fn all_finite(outputs: &[EngineOutput]) -> bool {
    outputs.iter().all(|o| {
        let a = o.values.as_attitude().expect("attitude estimates");
        [
            o.t,
            a.pitch_deg,
            a.roll_deg,
            a.pitch_pred_deg,
            a.roll_pred_deg,
            a.pred_t,
            a.pitch_correction_deg,
        ]
        .iter()
        .all(|x| x.is_finite())
            && a.laser_age_s.is_none_or(f64::is_finite)
    })
}

fn engine(params: &[&str]) -> Box<dyn Engine> {
    let kind = EngineKind::Attitude;
    kind.create(Params::from_assignments(kind.specs(), params.iter().copied()).unwrap())
        .unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn finite_readings_give_finite_estimates(
        steps in proptest::collection::vec(reading(), 1..400),
        memberships in 1..6usize,
    ) {
        let memberships = format!("anfis_memberships={memberships}");
        let mut e = engine(&["anfis_min_samples=2", &memberships]);
        let mut t = T0;
        let mut out = Vec::new();
        for (step, mut r) in steps {
            t = (t + step).max(T0);
            r.t = t;
            e.feed(&r, &mut out);
        }
        prop_assert!(all_finite(&out));
        let model = e.model().unwrap();
        prop_assert!(serde_json::to_string(&model).is_ok());
    }

    #[test]
    fn snapshot_anywhere_continues_exactly(
        steps in proptest::collection::vec(reading(), 2..200),
        cut in 0usize..200,
    ) {
        let mut a = engine(&["anfis_min_samples=2"]);
        let mut t = T0;
        let mut timed = Vec::new();
        for (step, mut r) in steps {
            t = (t + step).max(T0);
            r.t = t;
            timed.push(r);
        }
        let cut = cut.min(timed.len());
        let mut out_a = Vec::new();
        for r in &timed[..cut] {
            a.feed(r, &mut out_a);
        }
        let text = serde_json::to_string(&a.snapshot()).unwrap();
        let mut b = EngineKind::Attitude.restore(serde_json::from_str(&text).unwrap()).unwrap();
        let (mut rest_a, mut rest_b) = (Vec::new(), Vec::new());
        for r in &timed[cut..] {
            a.feed(r, &mut rest_a);
            b.feed(r, &mut rest_b);
        }
        prop_assert_eq!(rest_a, rest_b);
    }
}
