//! Every engine in the registry (`src/fusion/registry.rs`) holds to what
//! the rest of tunnelnav assumes of it: its parameters round-trip through
//! its typed struct, a snapshot continues exactly, its NDJSON writer
//! equals serde_json, its stored form round-trips, and its page section
//! renders with its script. A new engine is checked here by being listed.

mod common;

use common::{TestServer, declare_machine};
use tunnelnav::fusion::estimate::EstimateWriter;
use tunnelnav::fusion::pipeline::Pipeline;
use tunnelnav::fusion::{
    Declaration, EngineKind, EngineOutput, ParamValue, Params, Reading, StageKind, StreamKind,
};
use tunnelnav::sim::pipejack::{PipeJackDrive, PipeJackScenario};
use tunnelnav::sim::tbm::{TbmDrive, TbmScenario};
use tunnelnav::sim::vehicle::{VehicleDrive, VehicleScenario};

/// A few minutes of the sensors `engine` consumes.
fn drive(engine: EngineKind) -> Vec<Reading> {
    match engine {
        EngineKind::Attitude => TbmDrive::new(TbmScenario {
            seed: 2,
            hours: 0.5,
            laser_period_s: 30.0,
            ..TbmScenario::default()
        })
        .unwrap()
        .map(|event| event.reading)
        .collect(),
        EngineKind::Zupt => PipeJackDrive::new(PipeJackScenario {
            seed: 2,
            ..PipeJackScenario::default()
        })
        .unwrap()
        .take(40_000)
        .map(|event| event.reading)
        .collect(),
        EngineKind::Fuzzy => VehicleDrive::new(VehicleScenario {
            seed: 2,
            duration_s: 300.0,
            ..VehicleScenario::default()
        })
        .unwrap()
        .take(12_000)
        .map(|event| event.reading)
        .collect(),
    }
}

/// Every output of `engine` fed `readings`, flushed at the end.
fn run(engine: &mut dyn tunnelnav::fusion::Engine, readings: &[Reading]) -> Vec<EngineOutput> {
    let mut out = Vec::new();
    for reading in readings {
        engine.feed(reading, &mut out);
    }
    out
}

#[test]
fn parameters_round_trip_through_each_engines_typed_struct() {
    for &kind in EngineKind::ALL {
        let defaults = Params::defaults(kind.specs());
        assert_eq!(kind.read_params(&defaults).unwrap(), defaults, "{kind}");
        // Every value as text, as `--param` gives it.
        let words: Vec<String> = kind
            .specs()
            .iter()
            .map(|spec| format!("{}={}", spec.name, spec.default_value()))
            .collect();
        let parsed = kind
            .params_from_assignments(words.iter().map(String::as_str))
            .unwrap();
        assert_eq!(parsed, defaults, "{kind}");
        // A changed value is read, and written back as given.
        let spec = kind
            .specs()
            .iter()
            .find(|spec| matches!(spec.default_value(), ParamValue::Bool(_)))
            .or_else(|| kind.specs().first())
            .unwrap();
        let changed = match spec.default_value() {
            ParamValue::Bool(b) => ParamValue::Bool(!b),
            other => other,
        };
        let params = kind.params([(spec.name.to_string(), changed)]).unwrap();
        assert_eq!(kind.read_params(&params).unwrap(), params, "{kind}");
        let engine = kind.create(params.clone()).unwrap();
        assert_eq!(engine.params(), &params, "{kind}");
        assert_eq!(engine.kind(), kind);
    }
}

#[test]
fn a_snapshot_continues_exactly_and_estimates_write_and_store_exactly() {
    for &kind in EngineKind::ALL {
        let readings = drive(kind);
        let half = readings.len() / 2;
        let params = Params::defaults(kind.specs());

        let mut whole = kind.create(params.clone()).unwrap();
        let expected = run(whole.as_mut(), &readings);
        assert!(
            expected.len() > readings.len() / 4,
            "{kind}: {}",
            expected.len()
        );

        // Snapshot half way, through its JSON text, and go on.
        let mut first = kind.create(params).unwrap();
        let mut outputs = run(first.as_mut(), &readings[..half]);
        let text = serde_json::to_string(&first.snapshot()).unwrap();
        let mut second = kind.restore(serde_json::from_str(&text).unwrap()).unwrap();
        outputs.extend(run(second.as_mut(), &readings[half..]));
        assert_eq!(
            format!("{outputs:?}"),
            format!("{expected:?}"),
            "{kind}: restored engine diverged"
        );
        assert_eq!(second.params(), whole.params());

        let mut writer = EstimateWriter::new("reg-1");
        let mut told = Vec::new();
        for output in &expected {
            assert_eq!(output.values.stream(), StreamKind::from(kind));
            // It tells only the signals it declares.
            for signal in output.values.signals().kinds() {
                assert!(
                    StreamKind::from(kind).signals().contains(&signal),
                    "{kind} tells {signal:?}"
                );
                told.push(signal);
            }
            // The NDJSON writer is serde_json, byte for byte.
            let mut ours = Vec::new();
            writer.write_line(output, &mut ours);
            let mut serde = serde_json::to_vec(&output.for_machine("reg-1")).unwrap();
            serde.push(b'\n');
            assert_eq!(
                String::from_utf8(ours).unwrap(),
                String::from_utf8(serde).unwrap(),
                "{kind}"
            );
            // The stored form of this release decodes to the same values.
            let bytes = output.values.encode();
            let back = tunnelnav::fusion::EstimateValues::decode(
                kind.into(),
                StreamKind::from(kind).codec_version(),
                &bytes,
            )
            .unwrap();
            assert_eq!(
                format!("{back:?}"),
                format!("{:?}", output.values),
                "{kind}"
            );
        }
        // ... and, on its drive, every signal it declares.
        for signal in StreamKind::from(kind).signals() {
            assert!(told.contains(signal), "{kind} never tells {signal:?}");
        }
        // A model, if the engine has one, serialises.
        if let Some(model) = whole.model() {
            assert!(serde_json::to_value(model).unwrap().is_object(), "{kind}");
        }
    }
}

#[tokio::test]
async fn each_engines_page_section_renders_with_its_script() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    for &kind in EngineKind::ALL {
        let section =
            tunnelnav::server::pages::engine_section(kind, &Params::defaults(kind.specs()))
                .unwrap();
        assert!(section.html.contains(&format!("id=\"{kind}\"")), "{kind}");

        let machine = format!("page-{kind}");
        let body = format!(r#"{{"engines": {{"{kind}": {{}}}}}}"#);
        declare_machine(&client, &base, &machine, &body).await;
        let page = client
            .get(format!("{base}/machines/{machine}"))
            .send()
            .await
            .unwrap();
        assert_eq!(page.status(), 200);
        let html = page.text().await.unwrap();
        let tag = format!("<script src=\"/static/{}\">", section.script);
        assert!(html.contains(&tag), "{kind}: {tag}");
        let script = client
            .get(format!("{base}/static/{}", section.script))
            .send()
            .await
            .unwrap();
        assert_eq!(script.status(), 200, "{kind}");
        let text = script.text().await.unwrap();
        assert!(
            text.contains(&format!("tn.registerEngine('{kind}'")),
            "{kind}: the script registers itself"
        );
        // The fleet page loads every engine's script for its card.
        let fleet = client
            .get(&base)
            .send()
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        assert!(fleet.contains(&tag), "{kind}");
    }
    server.stop().await;
}

/// A machine running `engine` whose declaration calls for `stage`, if
/// there is one to test it with.
fn declaration_for(stage: StageKind, engine: EngineKind) -> Option<Declaration> {
    match stage {
        StageKind::Pushes => {
            (engine == EngineKind::Zupt).then(|| Declaration::of_engines([engine]))
        }
        StageKind::Dta => zupt_on_an_axis(engine),
        // On the axis, 0.1 m off it: a curve back every time.
        StageKind::Steer => zupt_on_an_axis(engine).map(|declaration| Declaration {
            steering: Some(tunnelnav::fusion::steering::SteeringSpec::new(
                300.0, 1.2, 2.0,
            )),
            ..declaration
        }),
        // Rings log the dta estimates of a zupt machine; an attitude
        // machine's without a position.
        StageKind::Rings => match engine {
            EngineKind::Zupt => zupt_on_an_axis(engine),
            _ => Some(Declaration::of_engines([engine])),
        },
        // The lining of a zupt machine on the axis.
        StageKind::RingPlan => zupt_on_an_axis(engine).map(|declaration| Declaration {
            rings: Some(
                serde_json::from_value(serde_json::json!({
                    "taper_mm": 40.0, "diameter_m": 6.0, "width_m": 1.5, "key_positions": 16,
                    "forbidden_keys": [7, 8, 9], "nominal_clearance_mm": 50.0,
                    "min_clearance_mm": 20.0}))
                .unwrap(),
            ),
            ..declaration
        }),
    }
}

/// The `zupt` source: a long straight axis through the start point,
/// along the engine's initial heading (north), with a design grade.
fn zupt_on_an_axis(engine: EngineKind) -> Option<Declaration> {
    {
        (engine == EngineKind::Zupt).then(|| {
            let axis = r#"{"start_station_m": 1000.0,
                "start": {"easting_m": 2000.0, "northing_m": 4900.0, "azimuth_deg": 0.0},
                "horizontal": [{"type": "line", "length_m": 1000.0}],
                "vertical": {"start_height_m": 30.0, "end_grade_pct": 0.5}}"#;
            let spec: tunnelnav::fusion::alignment::AlignmentSpec =
                serde_json::from_str(axis).unwrap();
            Declaration {
                alignment: Some(std::sync::Arc::new(spec.build().unwrap())),
                geometry: Some(tunnelnav::fusion::declaration::MachineGeometry {
                    front_m: [1.5, 0.0, 0.0],
                    rear_m: [-1.5, 0.0, 0.0],
                }),
                start: Some(tunnelnav::fusion::reading::ProjectPoint {
                    easting_m: 2000.0,
                    northing_m: 5000.0,
                    height_m: 30.5,
                }),
                ..Declaration::of_engines([engine])
            }
        })
    }
}

/// `readings` with, for the `rings` and `ring_plan` stages, an `advance`
/// reading every seventh of the way (every other one with strokes; for
/// `ring_plan` with a key, followed by a tail clearance).
fn with_advances(stage: StageKind, mut readings: Vec<Reading>) -> Vec<Reading> {
    if !matches!(stage, StageKind::Rings | StageKind::RingPlan) {
        return readings;
    }
    let keyed = stage == StageKind::RingPlan;
    let every = readings.len() / 7;
    for ring in (1..7u64).rev() {
        let at = ring as usize * every;
        let t = readings[at].t;
        readings.insert(
            at + 1,
            Reading {
                t,
                data: tunnelnav::fusion::SensorData::Advance {
                    ring: 100 + ring,
                    strokes_mm: (ring % 2 == 0).then(|| vec![1500.0 + ring as f64, 1498.25]),
                    key: keyed.then_some((ring as u32 * 5) % 16),
                },
            },
        );
        if keyed {
            readings.insert(
                at + 1,
                Reading {
                    t,
                    data: tunnelnav::fusion::SensorData::TailClearance {
                        clearance_mm: vec![50.0, 48.0 + ring as f64, 47.5, 52.0, 51.0, 49.0],
                    },
                },
            );
        }
    }
    readings
}

#[test]
fn every_stage_runs_after_an_engine_and_writes_stores_and_continues_exactly() {
    for &stage in StageKind::ALL {
        let declared: Vec<(EngineKind, Declaration)> = EngineKind::ALL
            .iter()
            .filter_map(|&engine| Some((engine, declaration_for(stage, engine)?)))
            .collect();
        assert!(!declared.is_empty(), "{stage}: no engine to test it after");
        for (engine, declaration) in declared {
            let readings = with_advances(stage, drive(engine));
            let params = Params::defaults(engine.specs());
            let create = || vec![engine.create(params.clone()).unwrap()];
            let mut whole = Pipeline::declared(create(), &declaration);
            assert!(whole.stages().any(|s| s == stage), "{stage}");
            let mut expected = Vec::new();
            for reading in &readings {
                whole.feed(reading, &mut expected);
            }
            whole.flush(&mut expected);
            let derived: Vec<&EngineOutput> = expected
                .iter()
                .filter(|o| o.values.stream() == StreamKind::from(stage))
                .collect();
            assert!(!derived.is_empty(), "{stage} after {engine}: no output");

            // Through a snapshot half way, the same outputs.
            let half = readings.len() / 2;
            let mut first = Pipeline::declared(create(), &declaration);
            let mut outputs = Vec::new();
            for reading in &readings[..half] {
                first.feed(reading, &mut outputs);
            }
            let text = serde_json::to_string(&first.state()).unwrap();
            let mut second =
                Pipeline::restore(serde_json::from_str(&text).unwrap(), &declaration).unwrap();
            for reading in &readings[half..] {
                second.feed(reading, &mut outputs);
            }
            second.flush(&mut outputs);
            assert_eq!(format!("{outputs:?}"), format!("{expected:?}"), "{stage}");

            let mut writer = EstimateWriter::new("reg-1");
            for output in derived {
                let mut ours = Vec::new();
                writer.write_line(output, &mut ours);
                let mut serde = serde_json::to_vec(&output.for_machine("reg-1")).unwrap();
                serde.push(b'\n');
                assert_eq!(
                    String::from_utf8(ours).unwrap(),
                    String::from_utf8(serde).unwrap()
                );
                let stream = output.values.stream();
                let back = tunnelnav::fusion::EstimateValues::decode(
                    stream,
                    stream.codec_version(),
                    &output.values.encode(),
                )
                .unwrap();
                assert_eq!(format!("{back:?}"), format!("{:?}", output.values));
            }
        }
    }
}
