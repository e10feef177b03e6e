use super::*;
use crate::fusion::IntegrityReason;
use crate::fusion::alignment::AlignmentSpec;

/// Due north from (1000, 5000) for 100 m, level at 50 m; the front 4 m
/// ahead of the reference point, the rear 5 m behind.
fn declaration(engines: &[EngineKind]) -> Declaration {
    let axis = r#"{"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
        "horizontal": [{"type": "line", "length_m": 100.0}],
        "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}"#;
    let spec: AlignmentSpec = serde_json::from_str(axis).unwrap();
    Declaration {
        alignment: Some(Arc::new(spec.build().unwrap())),
        geometry: Some(MachineGeometry {
            front_m: [4.0, 0.0, 0.0],
            rear_m: [-5.0, 0.0, 0.0],
        }),
        tolerances: Some(Tolerances {
            horizontal_mm: Limits {
                warn: 50.0,
                alarm: 100.0,
            },
            vertical_mm: Limits {
                warn: 30.0,
                alarm: 60.0,
            },
        }),
        start: Some(ProjectPoint {
            easting_m: 1000.0,
            northing_m: 5000.0,
            height_m: 50.0,
        }),
        steering: None,
        rings: None,
        engines: engines.to_vec(),
    }
}

fn laser(t: f64, yaw_deg: f64, position: ProjectPoint) -> Reading {
    Reading {
        t,
        data: SensorData::Laser {
            pitch_deg: 0.0,
            roll_deg: 0.0,
            yaw_deg: Some(yaw_deg),
            position: Some(position),
        },
    }
}

fn dta(out: &[EngineOutput]) -> &DtaEstimate {
    match &out.last().expect("an estimate").values {
        EstimateValues::Dta(d) => d,
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_pipeline_offers_the_dta_estimates_to_steer_and_rings() {
    use crate::fusion::pipeline::Pipeline;
    use crate::fusion::steering::SteeringSpec;
    let declaration = Declaration {
        steering: Some(SteeringSpec::new(1500.0, 1.5, 6.0)),
        ..declaration(&[EngineKind::Attitude])
    };
    let engines = vec![
        EngineKind::Attitude
            .create(EngineKind::Attitude.params([]).unwrap())
            .unwrap(),
    ];
    let mut pipeline = Pipeline::declared(engines, &declaration);
    assert_eq!(
        pipeline.stages().collect::<Vec<_>>(),
        [StageKind::Dta, StageKind::Steer, StageKind::Rings]
    );
    assert!(pipeline.uses(SensorKind::Advance));
    let mut out = Vec::new();
    // 50 mm right of the axis, square to it: the laser's reading makes
    // the dta estimate from its position, and the curve from that (the
    // attitude engine waits for its inclinometer).
    let at = ProjectPoint {
        easting_m: 1000.05,
        northing_m: 5010.0,
        height_m: 50.0,
    };
    pipeline.feed(&laser(1.772e9, 0.0, at), &mut out);
    let streams: Vec<StreamKind> = out.iter().map(|o| o.values.stream()).collect();
    assert_eq!(streams, [StreamKind::Dta, StreamKind::Steer]);
    let EstimateValues::Steer(steer) = &out[1].values else {
        panic!("{out:?}")
    };
    // d0 = 50 mm, g0 = 0, R 1500 m, 1.5 m steps, a 9 m shield (at
    // least 18 m): the quintic's largest curvature 10/√3·d0/L² is
    // within 1/1500 from L ≥ 20.8 m, so 14 steps (21 m).
    assert_eq!((steer.steps, steer.station_m), (Some(14), 14.0));
    // A ring closed now logs the dta estimate the pipeline made.
    out.clear();
    let ring = Reading {
        t: 1.772e9 + 60.0,
        data: SensorData::Advance {
            ring: 7,
            strokes_mm: None,
            key: None,
        },
    };
    pipeline.feed(&ring, &mut out);
    let [
        EngineOutput {
            values: EstimateValues::Rings(record),
            ..
        },
    ] = out.as_slice()
    else {
        panic!("{out:?}")
    };
    assert_eq!((record.ring, record.dta_t), (7, Some(1.772e9)));
    assert!((record.front_horizontal_mm.unwrap() - 50.0).abs() < 1e-6);
    assert!((record.station_m.unwrap() - 10.0).abs() < 1e-9);
}

#[test]
fn a_snapshot_from_before_the_ring_log_continues_seeded_as_a_replay_would() {
    use crate::fusion::pipeline::Pipeline;
    let declaration = declaration(&[EngineKind::Attitude]);
    let engines = || {
        vec![
            EngineKind::Attitude
                .create(EngineKind::Attitude.params([]).unwrap())
                .unwrap(),
        ]
    };
    let t0 = 1.772e9;
    let at = |east_m: f64| ProjectPoint {
        easting_m: 1000.0 + east_m,
        northing_m: 5010.0,
        height_m: 50.0,
    };
    let inclinometer = |t: f64| Reading {
        t,
        data: SensorData::Inclinometer {
            pitch_deg: 0.01,
            roll_deg: 0.2,
            temp_c: None,
        },
    };
    let mut replayed = Pipeline::declared(engines(), &declaration);
    let mut before = Vec::new();
    for i in 0..20 {
        let t = t0 + f64::from(i);
        replayed.feed(&inclinometer(t), &mut before);
        if i % 5 == 0 {
            replayed.feed(&laser(t + 0.5, 0.0, at(0.001 * f64::from(i))), &mut before);
        }
    }
    // The snapshot as the release before the ring log wrote it, and
    // the newest output of each stream as the store keeps them.
    let mut state = replayed.state();
    assert!(state.stages.remove(&StageKind::Rings).is_some());
    let text = serde_json::to_string(&state).unwrap();
    assert!(matches!(
        Pipeline::restore(serde_json::from_str(&text).unwrap(), &declaration),
        Err(SnapshotError::MissingStage(StageKind::Rings))
    ));
    let newest: Vec<EngineOutput> = [StreamKind::Attitude, StreamKind::Dta]
        .iter()
        .filter_map(|s| {
            before
                .iter()
                .rev()
                .find(|o| o.values.stream() == *s)
                .cloned()
        })
        .collect();
    let mut seeded =
        Pipeline::restore_seeded(serde_json::from_str(&text).unwrap(), &declaration, &newest)
            .unwrap();
    // A ring closed now is logged alike.
    let ring = Reading {
        t: t0 + 30.0,
        data: SensorData::Advance {
            ring: 12,
            strokes_mm: None,
            key: None,
        },
    };
    let (mut a, mut b) = (Vec::new(), Vec::new());
    replayed.feed(&ring, &mut a);
    seeded.feed(&ring, &mut b);
    assert_eq!(a, b);
    let EstimateValues::Rings(record) = &a[0].values else {
        panic!("{a:?}")
    };
    assert_eq!(record.dta_t, Some(t0 + 15.5));
    assert!(record.pitch_deg.is_some());
}

#[test]
fn front_and_rear_by_hand_from_a_laser_position() {
    let mut stage = Dta::create(&declaration(&[EngineKind::Attitude])).unwrap();
    let mut out = Vec::new();
    // 20 mm right (east) of the axis, 29 mm high, square to it.
    let at = ProjectPoint {
        easting_m: 1000.02,
        northing_m: 5010.0,
        height_m: 50.029,
    };
    stage.reading(&laser(1.0, 0.0, at), &mut out);
    let d = dta(&out);
    assert_eq!(d.source, DtaSource::Laser);
    assert!((d.station_m - 10.0).abs() < 1e-9);
    assert!((d.front.station_m - 14.0).abs() < 1e-9 && (d.rear.station_m - 5.0).abs() < 1e-9);
    for p in [d.front, d.rear] {
        assert!((p.horizontal_mm - 20.0).abs() < 1e-6, "{p:?}");
        assert!((p.vertical_mm - 29.0).abs() < 1e-6, "{p:?}");
    }
    assert!(d.tendency_horizontal_mm_per_m.abs() < 1e-6);
    // Within both tolerances (vertical warns beyond 30 mm).
    assert_eq!(d.status, Some(DtaStatus::Ok));

    // An attitude estimate before the engine's first laser sample (its
    // pitch still carries the inclinometer's error) is not used.
    let attitude = |t: f64, pitch_deg: f64, laser_age_s: Option<f64>| EngineOutput {
        integrity: crate::fusion::Integrity::OK,
        t,
        values: EstimateValues::Attitude(crate::fusion::AttitudeEstimate {
            pitch_deg,
            roll_deg: 0.0,
            pitch_pred_deg: pitch_deg,
            roll_pred_deg: 0.0,
            pred_t: t + 1.0,
            pitch_sigma_deg: None,
            roll_sigma_deg: None,
            pitch_pred_sigma_deg: None,
            laser_ok: laser_age_s.is_some(),
            pitch_correction_deg: 0.0,
            laser_age_s,
            model_version: 0,
            incl_pitch_deg: pitch_deg,
            incl_roll_deg: 0.0,
        }),
    };
    stage.estimate(&attitude(1.2, 5.0, None), &mut out);
    stage.reading(&laser(1.5, 0.0, at), &mut out);
    let flat = dta(&out);
    assert!((flat.front.vertical_mm - 29.0).abs() < 1e-6, "{flat:?}");

    // Yawed 1° right and, from the attitude engine, pitched 1° nose up:
    // the front moves 4·sin 1° right and up, the rear 5·sin 1° left and
    // down; the tendency is 1000·tan 1°-ish mm/m both ways.
    let sin1 = 1f64.to_radians().sin();
    let fused = attitude(2.0, 1.0, Some(1.0));
    stage.estimate(&fused, &mut out);
    stage.reading(&laser(3.0, 1.0, at), &mut out);
    let d = dta(&out);
    let cos1 = 1f64.to_radians().cos();
    // Heading 1° east of north and pitched 1° up: the body x axis is
    // (E, N, up) = (cos1·sin1, cos1·cos1, sin1).
    let front_h = 20.0 + 1000.0 * 4.0 * cos1 * sin1;
    let rear_h = 20.0 - 1000.0 * 5.0 * cos1 * sin1;
    assert!((d.front.horizontal_mm - front_h).abs() < 1e-6, "{d:?}");
    assert!((d.rear.horizontal_mm - rear_h).abs() < 1e-6, "{d:?}");
    assert!(
        (d.front.vertical_mm - (29.0 + 4000.0 * sin1)).abs() < 1e-6,
        "{d:?}"
    );
    assert!(
        (d.rear.vertical_mm - (29.0 - 5000.0 * sin1)).abs() < 1e-6,
        "{d:?}"
    );
    assert!((d.tendency_horizontal_mm_per_m - 1000.0 * cos1 * sin1).abs() < 1e-6);
    assert!((d.tendency_vertical_mm_per_m - 1000.0 * sin1).abs() < 1e-6);
    // Front 29 + 69.8 mm high: beyond the 60 mm alarm.
    assert_eq!(d.status, Some(DtaStatus::Alarm));
}

#[test]
fn a_zupt_position_is_relative_to_the_declared_start() {
    let mut stage = Dta::create(&declaration(&[EngineKind::Zupt])).unwrap();
    let mut out = Vec::new();
    let estimate = |position_m: [f64; 3], aligned| {
        let mut output = crate::fusion::estimate::zupt_for_tests(5.0, None);
        if let EstimateValues::Zupt(z) = &mut output.values {
            (z.zv, z.position_m, z.aligned) = (false, position_m, aligned);
            z.position_sigma_m = [0.01; 3];
            z.yaw_sigma_deg = Some(0.1);
            z.attitude_sigma_deg = Some([0.05, 0.05, 0.1]);
        }
        output
    };
    stage.estimate(&estimate([20.0, -0.07, 0.01], false), &mut out);
    assert!(out.is_empty(), "nothing before alignment");
    // 20 m north, 70 mm west (left), 10 mm down.
    stage.estimate(&estimate([20.0, -0.07, 0.01], true), &mut out);
    let d = dta(&out);
    assert_eq!(d.source, DtaSource::Zupt);
    assert!((d.station_m - 20.0).abs() < 1e-9);
    assert!(
        (d.front.horizontal_mm + 70.0).abs() < 1e-6 && (d.front.vertical_mm + 10.0).abs() < 1e-6
    );
    // 70 mm left is beyond the 50 mm warning, but its 2σ band (below)
    // reaches back to 70 − 2·12.2 = 45.6 mm: the status cannot be told.
    assert_eq!(d.status, Some(DtaStatus::Unknown));
    // The INS's σ: 10 mm per coordinate, and the attitude's over the
    // lever (4 m ahead, 5 m behind, level, due north): across the axis
    // the heading's 0.1°, vertically the tilt about east, 0.05°:
    // √(10² + (4000·0.1°)²) = 12.1959 mm, √(10² + (4000·0.05°)²) =
    // 10.5917 mm; the rear's over 5 m 13.2723 and 10.9105 mm.
    let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-3;
    assert!(close(d.front.sigma_horizontal_mm, 12.1959), "{d:?}");
    assert!(close(d.front.sigma_vertical_mm, 10.5917), "{d:?}");
    assert!(close(d.rear.sigma_horizontal_mm, 13.2723), "{d:?}");
    assert!(close(d.rear.sigma_vertical_mm, 10.9105), "{d:?}");
    // Beyond the axis's end: no estimate, counted.
    stage.estimate(&estimate([120.0, 0.0, 0.0], true), &mut out);
    assert_eq!(out.len(), 1);
    assert_eq!(stage.state.outside, 1);
}

#[test]
fn a_deviation_is_graded_only_where_its_two_sigma_band_agrees() {
    let limits = Limits {
        warn: 50.0,
        alarm: 100.0,
    };
    // No σ (a laser position): the value's own grade.
    assert_eq!(grade(49.9, None, limits), DtaStatus::Ok);
    assert_eq!(grade(-50.1, None, limits), DtaStatus::Warn);
    assert_eq!(grade(100.1, None, limits), DtaStatus::Alarm);
    // 30 ± 2·9.9 = 10.2 … 49.8: ok throughout.
    assert_eq!(grade(30.0, Some(9.9), limits), DtaStatus::Ok);
    // 30 ± 2·10.1 reaches 50.2: unknown.
    assert_eq!(grade(30.0, Some(10.1), limits), DtaStatus::Unknown);
    // −75 ± 2·12: 51 … 99, a warning either way.
    assert_eq!(grade(-75.0, Some(12.0), limits), DtaStatus::Warn);
    // 140 ± 2·15: 110 … 170, an alarm either way.
    assert_eq!(grade(140.0, Some(15.0), limits), DtaStatus::Alarm);
    // 90 ± 2·6 crosses the alarm limit.
    assert_eq!(grade(90.0, Some(6.0), limits), DtaStatus::Unknown);
    // The estimate shows a certain alarm over an unknown, an unknown
    // over a certain warning.
    let worst = |a: DtaStatus, b: DtaStatus| [a, b].into_iter().max_by_key(|s| s.rank());
    assert_eq!(
        worst(DtaStatus::Unknown, DtaStatus::Alarm),
        Some(DtaStatus::Alarm)
    );
    assert_eq!(
        worst(DtaStatus::Warn, DtaStatus::Unknown),
        Some(DtaStatus::Unknown)
    );
}

#[test]
fn a_source_that_cannot_vouch_leaves_the_status_unknown_and_is_inherited() {
    let mut stage = Dta::create(&declaration(&[EngineKind::Zupt])).unwrap();
    let mut out = Vec::new();
    let mut output = crate::fusion::estimate::zupt_for_tests(5.0, None);
    if let EstimateValues::Zupt(z) = &mut output.values {
        (z.zv, z.position_m, z.aligned) = (false, [20.0, 0.0, 0.0], true);
    }
    stage.estimate(&output, &mut out);
    assert_eq!(dta(&out).status, Some(DtaStatus::Ok));
    assert_eq!(out[0].integrity, Integrity::OK);
    output.integrity = Integrity::lost(IntegrityReason::TiltDisagrees);
    out.clear();
    stage.estimate(&output, &mut out);
    assert_eq!(dta(&out).status, Some(DtaStatus::Unknown));
    assert_eq!(out[0].integrity, output.integrity);
    output.integrity = Integrity::degraded(IntegrityReason::Innovations);
    out.clear();
    stage.estimate(&output, &mut out);
    assert_eq!(dta(&out).status, Some(DtaStatus::Ok));
    assert_eq!(out[0].integrity, output.integrity);
}

#[test]
fn only_a_declared_axis_and_geometry_make_the_stage() {
    let full = declaration(&[EngineKind::Attitude]);
    assert!(Dta::create(&full).is_some());
    assert!(
        Dta::create(&Declaration {
            alignment: None,
            ..full.clone()
        })
        .is_none()
    );
    assert!(
        Dta::create(&Declaration {
            geometry: None,
            ..full.clone()
        })
        .is_none()
    );
    // A fuzzy machine has no position to locate.
    assert!(Dta::create(&declaration(&[EngineKind::Fuzzy])).is_none());
    // Zupt without a start has none either.
    let zupt = declaration(&[EngineKind::Zupt]);
    assert!(
        Dta::create(&Declaration {
            start: None,
            ..zupt
        })
        .is_none()
    );
}

#[test]
fn an_estimate_stored_before_the_points_sigma_still_reads() {
    // The layout codec 1 stored: points without σ.
    #[derive(Serialize)]
    struct Point(f64, f64, f64);
    #[derive(Serialize)]
    struct V1(DtaSource, f64, Point, Point, f64, f64, Option<DtaStatus>);
    let bytes = postcard::to_allocvec(&V1(
        DtaSource::Laser,
        12.5,
        Point(16.7, 20.0, -3.0),
        Point(7.4, 18.0, -2.0),
        0.215,
        -0.1,
        Some(DtaStatus::Ok),
    ))
    .unwrap();
    let d = DtaEstimate::decode(1, &bytes).unwrap();
    assert_eq!(d.front.horizontal_mm, 20.0);
    assert_eq!(d.rear.vertical_mm, -2.0);
    assert_eq!(d.front.sigma_horizontal_mm, None);
    assert_eq!(d.status, Some(DtaStatus::Ok));
    assert!(DtaEstimate::decode(CODEC_VERSION + 1, &bytes).is_err());
    // This release's form round-trips.
    assert_eq!(DtaEstimate::decode(CODEC_VERSION, &d.encode()).unwrap(), d);
}
