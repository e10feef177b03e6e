use super::plan as plan_curve;
use super::*;
use crate::fusion::alignment::AlignmentSpec;
use crate::fusion::declaration::Limits;

/// A machine with 1.5 m rings and thrust cylinders on a 6.0 m circle,
/// steering no tighter than `min_radius_m`.
fn rings(min_radius_m: f64) -> SteeringSpec {
    SteeringSpec::new(min_radius_m, 1.5, 6.0)
}

/// An axis from its declaration: `horizontal` elements after a start at
/// the origin heading north, `vertical` the profile.
fn axis(horizontal: &str, vertical: &str) -> Alignment {
    let json = format!(
        r#"{{"start_station_m": 0.0, "start": {{"easting_m": 0.0, "northing_m": 0.0, "azimuth_deg": 0.0}},
            "horizontal": [{horizontal}], "vertical": {vertical}}}"#
    );
    serde_json::from_str::<AlignmentSpec>(&json)
        .unwrap()
        .build()
        .unwrap()
}

const LEVEL: &str = r#"{"start_height_m": 0.0, "end_grade_pct": 0.0}"#;

/// A straight, level axis 2 km long.
fn straight() -> Alignment {
    axis(r#"{"type": "line", "length_m": 2000.0}"#, LEVEL)
}

/// A 500 m arc to the right, 1 km long.
fn right_arc(radius_m: f64) -> Alignment {
    axis(
        &format!(r#"{{"type": "arc", "length_m": 1000.0, "radius_m": {radius_m}}}"#),
        LEVEL,
    )
}

/// A crest: +2 % into a 40 m vertical curve about station 100, −2 % out
/// (the pitch bends down by 0.04/40 = 1·10⁻³ per metre: radius 1000 m).
fn crest() -> Alignment {
    axis(
        r#"{"type": "line", "length_m": 1000.0}"#,
        r#"{"start_height_m": 0.0, "pvis": [{"station_m": 100.0, "height_m": 2.0, "curve_length_m": 40.0}], "end_grade_pct": -2.0}"#,
    )
}

fn start(station_m: f64, h: (f64, f64, f64), v: (f64, f64, f64)) -> Start {
    let plane = |(deviation_mm, tendency_mm_per_m, curvature_per_m)| PlaneStart {
        deviation_mm,
        tendency_mm_per_m,
        curvature_per_m,
    };
    Start {
        station_m,
        horizontal: plane(h),
        vertical: plane(v),
    }
}

fn front_of(s: &Start) -> Front {
    Front {
        internal_station_m: s.station_m,
        station_m: s.station_m,
        horizontal_mm: s.horizontal.deviation_mm,
        vertical_mm: s.vertical.deviation_mm,
        tendency_horizontal_mm_per_m: s.horizontal.tendency_mm_per_m,
        tendency_vertical_mm_per_m: s.vertical.tendency_mm_per_m,
    }
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance
}

#[test]
fn the_quintic_ends_on_the_axis_with_its_curvature() {
    // From rest 50 mm off over 30 m: d0·(1 − 10u³ + 15u⁴ − 6u⁵), so
    // d(15) = 50·(1 − 1.25 + 0.9375 − 0.1875) = 25 mm; its curvature
    // d0/L²·(−60u + 180u² − 120u³) is largest at u = 1/2 ∓ √3/6 with
    // 10/√3·d0/L² = 3.2075e-4 /m.
    let rest = PlaneStart {
        deviation_mm: 50.0,
        tendency_mm_per_m: 0.0,
        curvature_per_m: 0.0,
    };
    let q = Quintic::new(&rest, 30.0);
    assert!(close(q.at(15.0).0, 0.025, 1e-15));
    let u = 0.5 - 3f64.sqrt() / 6.0;
    assert!(
        close(q.at(u * 30.0).2, -3.207_501e-4, 1e-9),
        "{:?}",
        q.at(u * 30.0)
    );
    assert_eq!(q.at(30.0), (0.0, 0.0, 0.0));
    // From a tendency and a curvature: the start's three and the end's
    // three conditions (the end approached from inside).
    let moving = PlaneStart {
        deviation_mm: -20.0,
        tendency_mm_per_m: 3.0,
        curvature_per_m: -2e-4,
    };
    let q = Quintic::new(&moving, 24.0);
    let (d, g, c) = q.at(0.0);
    assert!(close(d, -0.020, 1e-15) && close(g, 0.003, 1e-15) && close(c, -2e-4, 1e-15));
    let (d, g, c) = q.at(24.0 - 1e-9);
    assert!(
        d.abs() < 1e-12 && g.abs() < 1e-9 && c.abs() < 1e-8,
        "{d} {g} {c}"
    );
}

#[test]
fn on_a_500_m_arc_the_machine_steers_the_arc() {
    // On the axis of a 500 m right-hand arc: every ring turns
    // 1.5/500 rad, so 6.0 m × 1.5 m / 500 m = +18.0 mm of stroke (left
    // extends more) and curvature 1/500, along the shortest curve (two
    // shield lengths of 9 m: 12 rings).
    let arc = right_arc(500.0);
    let on_axis = start(100.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0));
    let plan = plan_curve(&rings(300.0), &arc, &on_axis, 18.0).unwrap();
    assert_eq!((plan.steps, plan.length_m), (12, 18.0));
    let c = expand(
        &rings(300.0),
        &arc,
        &plan,
        &front_of(&on_axis),
        None,
        [0.0; 2],
    );
    assert_eq!(c.horizontal.points.len(), 13);
    for p in &c.horizontal.points {
        assert!(close(p.stroke_difference_mm, 18.0, 1e-9), "{p:?}");
        assert!(close(p.curvature_per_m, 1.0 / 500.0, 1e-15), "{p:?}");
        assert_eq!(p.deviation_mm, 0.0);
    }
    assert!(
        c.vertical
            .points
            .iter()
            .all(|p| p.stroke_difference_mm == 0.0)
    );
    // A machine whose tightest curve is 600 m cannot drive it.
    let refused = plan_or_why(&rings(600.0), &arc, &on_axis);
    assert!(
        matches!(refused, Err(Infeasible::AxisTooTight { radius_m, .. }) if close(radius_m, 500.0, 1e-6)),
        "{refused:?}"
    );
}

fn plan_or_why(spec: &SteeringSpec, axis: &Alignment, s: &Start) -> Result<Plan, Infeasible> {
    plan(spec, axis, s, 18.0)
}

/// The path's curvature of both planes together, checked every 10 cm
/// along the whole curve (not only at its points): within `limit`.
fn within_everywhere(_spec: &SteeringSpec, axis: &Alignment, plan: &Plan) -> f64 {
    let path = Path::new(axis, plan);
    (0..=(plan.length_m * 10.0) as usize)
        .map(|i| {
            let [h, v] = path.curvatures_per_m(i as f64 / 10.0);
            h.hypot(v)
        })
        .fold(0.0, f64::max)
}

#[test]
fn forty_mm_off_the_arc_the_path_keeps_the_radius_and_ends_on_the_axis() {
    // 40 mm outside a 500 m right-hand arc, parallel to it, with a
    // machine of 400 m: back to the left (the path straightens below
    // 1/500), then onto the arc's curvature. The path may reach 1/400:
    // the correction's curvature at most 1/400 − 1/500 = 5e-4 to the
    // right, 10/√3·0.040/L² ≤ 5e-4 from L ≥ 21.5 m: 15 rings.
    let arc = right_arc(500.0);
    let spec = rings(400.0);
    let off = start(100.0, (40.0, 0.0, 0.0), (0.0, 0.0, 0.0));
    let plan = plan_curve(&spec, &arc, &off, 18.0).unwrap();
    assert_eq!(plan.steps, 15);
    assert!(within_everywhere(&spec, &arc, &plan) <= 1.0 / 400.0 * (1.0 + 1e-9));
    let c = expand(&spec, &arc, &plan, &front_of(&off), None, [0.0; 2]);
    let last = c.horizontal.points.last().unwrap();
    assert!(close(last.deviation_mm, 0.0, 1e-9) && close(last.curvature_per_m, 1.0 / 500.0, 1e-12));
    assert!(
        c.horizontal
            .points
            .iter()
            .all(|p| p.curvature_per_m <= 1.0 / 400.0 + 1e-12)
    );
    // It does not overshoot: every point between the start and the axis.
    assert!(
        c.horizontal
            .points
            .iter()
            .all(|p| p.deviation_mm >= -1e-9 && p.deviation_mm <= 40.0)
    );
    // The stroke differences are the turns over each step: their sum is
    // the whole turn, the arc's 22.5/500 rad (the correction's slope
    // is 0 at both ends) on the 6 m circle.
    let total: f64 = c.horizontal.points[..15]
        .iter()
        .map(|p| p.stroke_difference_mm)
        .sum();
    assert!(close(total, 6.0 * 22.5 / 500.0 * 1000.0, 1e-9), "{total}");
}

#[test]
fn on_a_crest_the_same_in_the_vertical() {
    // On the axis inside the crest (radius 1000 m, from station 80 to
    // 120): every step within it turns down 1.5/1000 rad, −9.0 mm (the
    // top extends more); beyond the crest 0. A 1200 m machine cannot;
    // 40 mm above the crest with a 600 m machine the path keeps 1/600.
    let crest = crest();
    // From 106 m: nine steps in the crest, the rest beyond it.
    let on_axis = start(106.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0));
    let spec = rings(600.0);
    let plan = plan_curve(&spec, &crest, &on_axis, 18.0).unwrap();
    let c = expand(&spec, &crest, &plan, &front_of(&on_axis), None, [0.0; 2]);
    let (mut inside, mut beyond) = (0, 0);
    for p in &c.vertical.points {
        // atan of the grade: the pitch bends by 1/(1 + g²) of the grade's
        // change, within 0.04 % here.
        if p.station_m + 1.5 <= 120.0 {
            assert!(close(p.stroke_difference_mm, -9.0, 0.01), "{p:?}");
            inside += 1;
        } else if p.station_m >= 120.0 {
            assert!(close(p.stroke_difference_mm, 0.0, 1e-9), "{p:?}");
            beyond += 1;
        }
    }
    assert!(inside >= 5 && beyond >= 3, "{inside} {beyond}");
    assert!(matches!(
        plan_or_why(&rings(1200.0), &crest, &on_axis),
        Err(Infeasible::AxisTooTight { .. })
    ));
    let above = start(106.0, (0.0, 0.0, 0.0), (40.0, 0.0, 0.0));
    let plan = plan_curve(&spec, &crest, &above, 18.0).unwrap();
    assert!(within_everywhere(&spec, &crest, &plan) <= 1.0 / 600.0 * (1.0 + 1e-9));
    let c = expand(&spec, &crest, &plan, &front_of(&above), None, [0.0; 2]);
    assert!(close(
        c.vertical.points.last().unwrap().deviation_mm,
        0.0,
        1e-9
    ));
}

#[test]
fn the_stroke_difference_is_the_turn_over_the_step() {
    // On a spiral from straight to a 300 m radius over 60 m the curvature
    // grows by 1/300/60 per metre: over the step from 30 m to 31.5 m the
    // axis turns by (30 + 31.5)/2/300/60·1.5 = 2.5625e-3 rad, 15.375 mm
    // on the 6 m circle. The curvature at the step's start (1/600) would
    // say 15.0 mm.
    let spiral = axis(
        r#"{"type": "spiral", "length_m": 60.0, "radius_start_m": null, "radius_end_m": 300.0},
           {"type": "arc", "length_m": 500.0, "radius_m": 300.0}"#,
        LEVEL,
    );
    let on_axis = start(30.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0));
    let spec = rings(250.0);
    let plan = plan_curve(&spec, &spiral, &on_axis, 18.0).unwrap();
    let c = expand(&spec, &spiral, &plan, &front_of(&on_axis), None, [0.0; 2]);
    let first = c.horizontal.points[0];
    assert!(close(first.stroke_difference_mm, 15.375, 1e-9), "{first:?}");
    assert!(
        close(first.curvature_per_m, 1.0 / 600.0, 1e-15),
        "{first:?}"
    );
}

#[test]
fn a_small_offset_is_taken_out_over_two_shield_lengths_without_overshoot() {
    // 1 mm off a straight axis: not within 2 rings at the limit but over
    // the shortest curve allowed (two shield lengths, 18 m: 12 rings),
    // arriving with no curvature.
    let line = straight();
    let off = start(10.0, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0));
    let plan = plan_curve(&rings(1500.0), &line, &off, 18.0).unwrap();
    assert_eq!(plan.steps, 12);
    let c = expand(
        &rings(1500.0),
        &line,
        &plan,
        &front_of(&off),
        None,
        [0.0; 2],
    );
    let points = &c.horizontal.points;
    assert!(points.iter().all(|p| (0.0..=1.0).contains(&p.deviation_mm)));
    assert_eq!(points.last().unwrap().curvature_per_m, 0.0);
    // The stroke differences sum to nothing: it ends parallel as it
    // started.
    let total: f64 = points.iter().map(|p| p.stroke_difference_mm).sum();
    assert!(total.abs() < 1e-12, "{total}");
}

#[test]
fn the_stroke_change_per_ring_lengthens_the_curve() {
    // 50 mm off a straight axis with a 1500 m machine: the radius alone
    // allows 10/√3·0.05/L² ≤ 1/1500 from L ≥ 20.8 m (14 rings); the
    // stroke difference then changes by up to about 3 mm a ring. Held to
    // 1 mm a ring the curve is longer and every change within 1 mm, from
    // the machine's present 0 to the axis's 0 after the end.
    let line = straight();
    let off = start(10.0, (50.0, 0.0, 0.0), (0.0, 0.0, 0.0));
    let free = plan_curve(&rings(1500.0), &line, &off, 18.0).unwrap();
    assert_eq!(free.steps, 14);
    let spec = SteeringSpec {
        max_stroke_change_mm: Some(1.0),
        ..rings(1500.0)
    };
    let held = plan_curve(&spec, &line, &off, 18.0).unwrap();
    assert!(held.steps > free.steps, "{held:?}");
    let c = expand(&spec, &line, &held, &front_of(&off), None, [0.0; 2]);
    let strokes: Vec<f64> = c
        .horizontal
        .points
        .iter()
        .map(|p| p.stroke_difference_mm)
        .collect();
    let mut previous = 0.0;
    for s in strokes.iter().chain([&0.0]) {
        assert!((s - previous).abs() <= 1.0 + 1e-6, "{strokes:?}");
        previous = *s;
    }
}

#[test]
fn both_planes_share_the_radius_and_a_lost_machine_is_told_so() {
    let line = straight();
    let spec = rings(1500.0);
    let one = plan_curve(
        &spec,
        &line,
        &start(0.0, (50.0, 2.0, 0.0), (0.0, 0.0, 0.0)),
        18.0,
    )
    .unwrap();
    let both = plan_curve(
        &spec,
        &line,
        &start(0.0, (50.0, 2.0, 0.0), (50.0, 2.0, 0.0)),
        18.0,
    )
    .unwrap();
    assert!(both.steps > one.steps, "{one:?} {both:?}");
    assert!(within_everywhere(&spec, &line, &both) <= 1.0 / 1500.0 * (1.0 + 1e-9));
    // 3 m off and heading away at 10 %: no curve within 500 m.
    let lost = start(0.0, (3000.0, 100.0, 0.0), (0.0, 0.0, 0.0));
    assert!(matches!(
        plan_curve(&spec, &line, &lost, 18.0),
        Err(Infeasible::TooFar { .. })
    ));
}

#[test]
fn points_beyond_the_warn_limit_are_flagged() {
    // 45 mm off and heading away at 2 mm/m: the curve runs out beyond
    // the 50 mm warn limit before it turns back.
    let line = straight();
    let spec = rings(1500.0);
    let off = start(0.0, (45.0, 2.0, 0.0), (0.0, 0.0, 0.0));
    let plan = plan_curve(&spec, &line, &off, 18.0).unwrap();
    let limits = Limits {
        warn: 50.0,
        alarm: 75.0,
    };
    let tolerances = Tolerances {
        horizontal_mm: limits,
        vertical_mm: limits,
    };
    let c = expand(
        &spec,
        &line,
        &plan,
        &front_of(&off),
        Some(&tolerances),
        [0.0; 2],
    );
    let flagged: Vec<_> = c
        .horizontal
        .points
        .iter()
        .filter(|p| p.outside_warn)
        .collect();
    assert!(!flagged.is_empty());
    assert!(flagged.iter().all(|p| p.deviation_mm > 50.0));
    assert!(
        c.horizontal
            .points
            .iter()
            .filter(|p| !p.outside_warn)
            .all(|p| p.deviation_mm <= 50.0)
    );
}

#[test]
fn groups_take_their_share_and_the_step_is_said_in_words() {
    // Right 18 mm, down 4 mm: the left group extends 9 mm more than the
    // mean, the right 9 mm less; the top 2 mm more, the bottom 2 mm less.
    let group = |name: &str, angle_deg: f64, cylinders: Vec<usize>| CylinderGroup {
        name: name.into(),
        angle_deg,
        cylinders,
    };
    let spec = SteeringSpec {
        cylinder_groups: vec![
            group("top", 0.0, vec![0, 1]),
            group("right", 90.0, vec![2]),
            group("bottom", 180.0, vec![3]),
            group("left", 270.0, vec![4, 5]),
        ],
        ..rings(500.0)
    };
    assert!(spec.check().is_ok());
    let strokes = [1500.0, 1502.0, 1490.0, 1510.0, 1505.0, 1507.0];
    let targets = group_targets(&spec, [18.0, -4.0], Some(&strokes));
    let got: Vec<(f64, f64)> = targets
        .iter()
        .map(|t| (t.extension_difference_mm, t.target_stroke_mm.unwrap()))
        .collect();
    let expected = [(2.0, 1503.0), (-9.0, 1481.0), (-2.0, 1508.0), (9.0, 1515.0)];
    for (g, e) in got.iter().zip(expected) {
        assert!(close(g.0, e.0, 1e-12) && close(g.1, e.1, 1e-9), "{got:?}");
    }
    assert_eq!(
        words(&spec, [18.0, -4.0], &targets),
        "steer right 18 mm, down 4 mm over the next ring; extend more: left +9 mm, top +2 mm"
    );
    assert_eq!(
        words(&rings(500.0), [-0.2, 0.3], &[]),
        "hold the line over the next ring"
    );
    assert!(
        group_targets(&spec, [18.0, -4.0], None)[0]
            .target_stroke_mm
            .is_none()
    );
    // A pipe-jacking head with an articulation 2 m + 4 m about its joint:
    // 18 mm over the 6 m circle is a turn of 3e-3 rad in 1.5 m, a
    // curvature of 2e-3 /m: the joint bends 2e-3·3 m = 0.3438°.
    let head = SteeringSpec {
        articulation: Some(Articulation {
            front_m: 2.0,
            rear_m: 4.0,
        }),
        step_name: StepName::Pipe,
        ..rings(500.0)
    };
    let [h, v] = articulation_deg(&head, [18.0, 0.0]).unwrap();
    assert!(close(h, 0.006f64.to_degrees(), 1e-12) && v == 0.0);
    assert_eq!(
        words(&head, [18.0, 0.0], &[]),
        "steer right 0.34° over the next pipe"
    );
}

#[test]
fn a_declaration_that_cannot_steer_is_refused() {
    let spec = rings(1500.0);
    assert!(spec.check().is_ok());
    for bad in [
        SteeringSpec {
            step_m: 0.0,
            ..spec.clone()
        },
        SteeringSpec {
            hold_margin_mm: 0.0,
            ..spec.clone()
        },
        SteeringSpec {
            max_stroke_change_mm: Some(-1.0),
            ..spec.clone()
        },
        SteeringSpec {
            cylinder_groups: vec![
                CylinderGroup {
                    name: "A".into(),
                    angle_deg: 0.0,
                    cylinders: vec![0],
                },
                CylinderGroup {
                    name: "B".into(),
                    angle_deg: 90.0,
                    cylinders: vec![0],
                },
            ],
            ..spec.clone()
        },
        SteeringSpec {
            cylinder_groups: vec![CylinderGroup {
                name: "A".into(),
                angle_deg: 400.0,
                cylinders: vec![0],
            }],
            ..spec.clone()
        },
        SteeringSpec {
            articulation: Some(Articulation {
                front_m: 0.0,
                rear_m: 1.0,
            }),
            ..spec.clone()
        },
    ] {
        assert!(bad.check().is_err(), "{bad:?}");
    }
    // A declaration from before issue 56 still reads, with the defaults.
    let old: SteeringSpec =
        serde_json::from_str(r#"{"min_radius_m": 1500, "step_m": 1.5, "cylinder_circle_m": 6.0}"#)
            .unwrap();
    assert_eq!(old, spec);
}
