use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use super::*;
use crate::fusion::alignment::AlignmentSpec;
use crate::fusion::declaration::{Limits, MachineGeometry};
use crate::fusion::dta::{DtaSource, PointDeviation};

/// An axis from north at the origin: `horizontal` elements, level.
fn axis(horizontal: &str) -> Arc<Alignment> {
    let json = format!(
        r#"{{"start": {{"easting_m": 0.0, "northing_m": 0.0, "azimuth_deg": 0.0}},
            "horizontal": [{horizontal}], "vertical": {{"start_height_m": 0.0, "end_grade_pct": 0.0}}}}"#
    );
    Arc::new(
        serde_json::from_str::<AlignmentSpec>(&json)
            .unwrap()
            .build()
            .unwrap(),
    )
}

/// A stage on `alignment` for a 9 m shield (front 4.5 m ahead of the
/// reference point, rear 4.5 m behind), warn at 50 mm.
fn stage(spec: SteeringSpec, alignment: Arc<Alignment>) -> SteerStage {
    let limits = Limits {
        warn: 50.0,
        alarm: 100.0,
    };
    let declaration = Declaration {
        engines: vec![crate::fusion::EngineKind::Attitude],
        alignment: Some(alignment),
        geometry: Some(MachineGeometry {
            front_m: [4.5, 0.0, 0.0],
            rear_m: [-4.5, 0.0, 0.0],
        }),
        tolerances: Some(Tolerances {
            horizontal_mm: limits,
            vertical_mm: limits,
        }),
        start: None,
        steering: Some(spec),
        rings: None,
    };
    Steer::create(&declaration).unwrap()
}

/// A dta estimate with the front at `station_m`, `front_h_mm` right of
/// the axis with a horizontal tendency.
fn dta(t: f64, station_m: f64, front_h_mm: f64, tendency_h: f64) -> EngineOutput {
    let point = |station_m, horizontal_mm| PointDeviation {
        station_m,
        horizontal_mm,
        vertical_mm: 0.0,
        sigma_horizontal_mm: None,
        sigma_vertical_mm: None,
    };
    EngineOutput {
        integrity: crate::fusion::Integrity::OK,
        t,
        values: EstimateValues::Dta(DtaEstimate {
            source: DtaSource::Laser,
            station_m: station_m - 4.5,
            front: point(station_m, front_h_mm),
            rear: point(station_m - 9.0, front_h_mm - 9.0 * tendency_h),
            tendency_horizontal_mm_per_m: tendency_h,
            tendency_vertical_mm_per_m: 0.0,
            status: None,
        }),
    }
}

fn steer(stage: &mut SteerStage, input: &EngineOutput) -> SteerEstimate {
    let mut out = Vec::new();
    stage.estimate(input, &mut out);
    match out.as_slice() {
        [
            EngineOutput {
                values: EstimateValues::Steer(s),
                ..
            },
        ] => s.clone(),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_curve_is_planned_then_held_while_the_front_follows_it() {
    // 50 mm right of a straight axis, parallel: the quintic of 14 rings
    // (its largest curvature 10/√3·0.05/L² within 1/1500 from 20.8 m),
    // steering left first (κ < 0: the right cylinders extend more).
    let line = axis(r#"{"type": "line", "length_m": 1000.0}"#);
    let mut stage = stage(SteeringSpec::new(1500.0, 1.5, 6.0), line);
    let first = steer(&mut stage, &dta(0.0, 100.0, 50.0, 0.0));
    assert!(first.feasible && first.replanned);
    assert_eq!((first.steps, first.length_m), (Some(14), Some(21.0)));
    let stroke = first.horizontal.stroke_difference_mm.unwrap();
    assert!(stroke < 0.0, "{first:?}");
    assert!(first.words.starts_with("steer left "), "{}", first.words);
    assert!(!first.horizontal.outside_warn);
    // A ring later, 1 mm off where the curve said: held, the same plan,
    // 13 steps left.
    let planned = first.horizontal.next_deviation_mm.unwrap();
    let second = steer(&mut stage, &dta(60.0, 101.5, planned + 1.0, 0.0));
    assert!(!second.replanned, "{second:?}");
    assert_eq!(second.plan, first.plan);
    assert_eq!(second.steps, Some(13));
    // 5 mm off it (beyond the 2 mm margin): a new curve from there.
    let third = steer(&mut stage, &dta(120.0, 103.0, planned + 5.0, 0.0));
    assert!(third.replanned);
    assert_eq!(third.plan.unwrap().start_station_m, 103.0);
}

#[test]
fn a_deviation_no_curve_can_take_back_is_infeasible() {
    // 50 m off with a 1500 m radius: no curve within 500 m.
    let line = axis(r#"{"type": "line", "length_m": 1000.0}"#);
    let mut stage = stage(SteeringSpec::new(1500.0, 1.5, 6.0), line);
    let s = steer(&mut stage, &dta(0.0, 100.0, 50_000.0, 0.0));
    assert!(!s.feasible);
    assert_eq!((s.steps, s.length_m, s.plan), (None, None, None));
    assert!(s.words.starts_with("no curve: "), "{}", s.words);
    assert_eq!(s.signals().steering_feasible, Some(false));
    // Other streams pass by.
    let mut none = Vec::new();
    let other = EngineOutput {
        integrity: crate::fusion::Integrity::OK,
        t: 1.0,
        values: EstimateValues::Steer(s),
    };
    stage.estimate(&other, &mut none);
    assert!(none.is_empty());
}

#[test]
fn a_restored_stage_continues_exactly_and_codec_1_still_reads() {
    let line = axis(r#"{"type": "line", "length_m": 1000.0}"#);
    let spec = SteeringSpec::new(1500.0, 1.5, 6.0);
    let mut live = stage(spec.clone(), line.clone());
    steer(&mut live, &dta(0.0, 100.0, 30.0, 1.0));
    steer(&mut live, &dta(60.0, 101.5, 30.5, 0.5));
    let declaration = Declaration {
        engines: vec![crate::fusion::EngineKind::Attitude],
        alignment: Some(line),
        geometry: Some(MachineGeometry {
            front_m: [4.5, 0.0, 0.0],
            rear_m: [-4.5, 0.0, 0.0],
        }),
        tolerances: live.tolerances,
        start: None,
        steering: Some(spec),
        rings: None,
    };
    let mut restored = Steer::restore(&declaration, live.snapshot()).unwrap();
    let next = dta(120.0, 103.0, 29.0, 0.0);
    assert_eq!(steer(&mut restored, &next), steer(&mut live, &next));
    // A snapshot of the stage that kept nothing (state version 1) is
    // outdated: the machine is rebuilt from its readings.
    assert!(matches!(
        Steer::restore(&declaration, serde_json::json!({"state_version": 1})),
        Err(SnapshotError::Outdated { found: 1, .. })
    ));
    // Codec 1's estimates still decode.
    #[derive(Serialize)]
    struct V1Plane(f64, f64, Option<f64>, Option<f64>);
    #[derive(Serialize)]
    struct V1(f64, bool, Option<u32>, Option<f64>, V1Plane, V1Plane);
    let bytes = postcard::to_allocvec(&V1(
        10.0,
        true,
        Some(3),
        Some(4.5),
        V1Plane(5.0, 0.1, Some(4.0), Some(-1.2)),
        V1Plane(0.0, 0.0, Some(0.0), Some(0.0)),
    ))
    .unwrap();
    let old = SteerEstimate::decode(1, &bytes).unwrap();
    assert_eq!(
        (old.steps, old.horizontal.stroke_difference_mm),
        (Some(3), Some(-1.2))
    );
    assert!(old.plan.is_none());
}

/// The machine a closed loop steers: its front's path in the plane (east,
/// north), and the tangent's azimuth, every 0.1 m; the shield a chord of
/// it, 9 m from the rear to the front.
struct Machine {
    path: Vec<(f64, f64, f64)>,
}

const SHIELD_M: f64 = 9.0;
const PATH_STEP_M: f64 = 0.1;

impl Machine {
    /// Advance `length_m` with curvature `curvature_per_m` (+ right).
    fn advance(&mut self, length_m: f64, curvature_per_m: f64) {
        let n = (length_m / PATH_STEP_M).round() as usize;
        for _ in 0..n {
            let &(e, north, a) = self.path.last().unwrap();
            let mid = a + 0.5 * curvature_per_m * PATH_STEP_M;
            self.path.push((
                e + PATH_STEP_M * mid.sin(),
                north + PATH_STEP_M * mid.cos(),
                a + curvature_per_m * PATH_STEP_M,
            ));
        }
    }

    fn front(&self) -> (f64, f64) {
        let &(e, n, _) = self.path.last().unwrap();
        (e, n)
    }

    fn rear(&self) -> (f64, f64) {
        let back = (SHIELD_M / PATH_STEP_M).round() as usize;
        let &(e, n, _) = &self.path[self.path.len() - 1 - back];
        (e, n)
    }
}

/// Where a point lies against an arc of `radius_m` to the right about
/// (`radius_m`, 0), starting at the origin northward: (station, + right:
/// towards the centre), m. Plane geometry, not the alignment's code.
fn against_arc(radius_m: f64, (e, n): (f64, f64)) -> (f64, f64) {
    let (de, dn) = (e - radius_m, n);
    let r = de.hypot(dn);
    let angle = dn.atan2(-de);
    (radius_m * angle, radius_m - r)
}

/// One closed-loop drive: 50 mm outside (left of) an 800 m right-hand arc,
/// parallel to it; each ring the machine steers the served stroke
/// difference (a constant curvature over the push) with a gain error of
/// 1σ `gain_sigma` drawn once and `stroke_sigma_mm` of noise, and the
/// guidance measures front and rear with `guidance_sigma_mm` of noise; the
/// machine declares those accuracies. The front's true deviation after
/// each of 80 rings.
fn closed_loop(seed: u64, [gain_sigma, guidance_sigma_mm, stroke_sigma_mm]: [f64; 3]) -> Vec<f64> {
    let radius_m = 800.0;
    // The machine declares the accuracies the simulation gives it.
    let spec = SteeringSpec {
        guidance_sigma_mm: guidance_sigma_mm.max(0.01),
        stroke_sigma_mm: stroke_sigma_mm.max(0.01),
        ..SteeringSpec::new(500.0, 1.5, 6.0)
    };
    let arc = axis(r#"{"type": "arc", "length_m": 1000.0, "radius_m": 800.0}"#);
    let mut stage = stage(spec.clone(), arc);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut noise = move |sigma: f64| {
        let n: f64 = StandardNormal.sample(&mut rng);
        sigma * n
    };
    // 50 mm outside: on the circle of 800.05 m, from its own start.
    let offset_radius = radius_m + 0.050;
    let mut machine = Machine {
        path: vec![(radius_m - offset_radius, 0.0, 0.0)],
    };
    machine.advance(60.0, 1.0 / offset_radius);
    let gain = 1.0 + noise(gain_sigma);
    let mut deviations = Vec::new();
    for ring in 0..80 {
        let (station_front, front_mm) = against_arc(radius_m, machine.front());
        let (_, rear_mm) = against_arc(radius_m, machine.rear());
        let (front_mm, rear_mm) = (front_mm * 1000.0, rear_mm * 1000.0);
        let measured_front = front_mm + noise(guidance_sigma_mm);
        let measured_rear = rear_mm + noise(guidance_sigma_mm);
        let tendency = (measured_front - measured_rear) / SHIELD_M;
        let s = steer(
            &mut stage,
            &dta(
                f64::from(ring) * 3600.0,
                station_front,
                measured_front,
                tendency,
            ),
        );
        let stroke_mm = s.horizontal.stroke_difference_mm.expect("a curve");
        let executed = stroke_mm * gain + noise(stroke_sigma_mm);
        machine.advance(
            spec.step_m,
            executed / 1000.0 / spec.cylinder_circle_m / spec.step_m,
        );
        deviations.push(against_arc(radius_m, machine.front()).1 * 1000.0);
    }
    deviations
}

/// The closed loop over seeds 1–20 at `noises`: (worst overshoot, worst
/// |deviation| from ring 40 on, the last ring outside ±3 mm), mm.
fn closed_loops(noises: [f64; 3]) -> (f64, f64, usize) {
    let mut worst = (0.0f64, 0.0f64, 0usize);
    for seed in 1..=20 {
        let d = closed_loop(seed, noises);
        // From the left (−50 mm): an overshoot lies to the right.
        let overshoot = d.iter().fold(0.0f64, |m, &x| m.max(x));
        let after = d[39..].iter().fold(0.0f64, |m, &x| m.max(x.abs()));
        let outside = d.iter().rposition(|x| x.abs() > 3.0).map_or(0, |i| i + 1);
        eprintln!(
            "noise {noises:?} seed {seed}: overshoot {overshoot:.2} mm, |d| from ring 40 {after:.2} mm, last ring outside 3 mm {outside}"
        );
        worst = (
            worst.0.max(overshoot),
            worst.1.max(after),
            worst.2.max(outside),
        );
    }
    eprintln!(
        "noise {noises:?} worst: overshoot {:.2} mm, from ring 40 {:.2} mm, last ring outside 3 mm {}",
        worst.0, worst.1, worst.2
    );
    worst
}

#[test]
fn closed_loop_from_50_mm_off_an_800_m_arc_seeds_1_to_20() {
    // The issue's bar (overshoot ≤ 5 mm, within ±3 mm in ≤ 40 rings) on
    // every seed, for a machine that builds each ring as told within 1 %
    // of gain, 0.2 mm of stroke difference and 0.2 mm of guidance noise.
    let (overshoot, after, outside) = closed_loops([0.01, 0.2, 0.2]);
    assert!(
        overshoot <= 5.0 && after <= 3.0 && outside <= 40,
        "{overshoot} {after} {outside}"
    );
    // With 3 % of gain, 0.5 mm of guidance and 0.5 mm of stroke noise the
    // overshoot bar holds and the ±3 mm one does not: the curve may not be
    // shorter than two shields nor change its curvature at once, so a
    // ring-to-ring scatter of the thrust is taken out over 12 rings or
    // more, and the hold margin lets the front wander 2 mm first
    // (docs/api.md, "Steering"). What holds there, on every seed:
    let (overshoot, after, _) = closed_loops([0.03, 0.5, 0.5]);
    assert!(overshoot <= 5.0 && after <= 6.0, "{overshoot} {after}");
}
