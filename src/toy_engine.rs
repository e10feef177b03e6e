//! A toy engine, compiled into the unit tests only, that proves what adding
//! an engine touches (docs/development.md, "Adding an engine or a stage").
//!
//! It was added as a new engine would be: this module (its descriptor,
//! parameters, estimate and model report), one `#[cfg(test)]` line in the
//! `registry!` list, and its arms in `src/server/pages.rs` (its section and
//! script, here inline instead of files in `templates/` and `static/`).
//! Nothing else names it but `lib.rs`, which declares the module, and
//! `tests/layering.rs`, which lets this test module name every layer. The tests below find it wherever the service
//! lists engines: names and parameters, the machine core, NDJSON, the
//! stored codec, the OpenAPI schemas, the model report, the alarm rules,
//! the laser report and the page section. A list that skips it, or a
//! `match` without its arm, fails here or does not compile.

use askama::Template;
use serde::{Deserialize, Serialize};

use crate::fusion::descriptor::{EngineDescriptor, LaserSignal, SignalKind, Signals, StreamValues};
use crate::fusion::json_fields::JsonFields;
use crate::fusion::params::{ParamError, Params, Retired, TypedParams, param_table};
use crate::fusion::reading::{Reading, SensorData, SensorKind};
use crate::fusion::{Engine, EngineKind, EngineModel, EngineOutput, EstimateValues, SnapshotError};

param_table! {
    /// The toy's one parameter.
    pub struct ToyParams in PARAMS {
        sigma_deg: f64 = real(0.2, 0.0, 10.0, "deg", "the pitch 1σ the toy claims"),
    }
}

/// The toy's descriptor.
pub struct Toy;

impl EngineDescriptor for Toy {
    const SUMMARY: &'static str = "a toy: the laser's pitch, as read";
    const SENSORS: &'static [SensorKind] = &[SensorKind::Laser];
    const RETIRED: &'static [Retired] = &[];
    type Params = ToyParams;
    type Engine = ToyEngine;
    type Estimate = ToyEstimate;
    type Model = ToyModel;

    fn create(params: Params) -> Result<ToyEngine, ParamError> {
        ToyParams::from_params(&params)?;
        Ok(ToyEngine {
            params,
            readings: 0,
        })
    }
    fn restore(snapshot: serde_json::Value) -> Result<ToyEngine, SnapshotError> {
        SnapshotError::parse(EngineKind::Toy, snapshot)
    }
}

/// The toy: one estimate per laser reading.
#[derive(Debug, Serialize, Deserialize)]
pub struct ToyEngine {
    params: Params,
    readings: u64,
}

impl Engine for ToyEngine {
    fn kind(&self) -> EngineKind {
        EngineKind::Toy
    }
    fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        if let SensorData::Laser { pitch_deg, .. } = reading.data {
            self.readings += 1;
            let sigma_deg = ToyParams::from_params(&self.params).map_or(0.0, |p| p.sigma_deg);
            out.push(EngineOutput {
                integrity: crate::fusion::Integrity::OK,
                t: reading.t,
                values: EstimateValues::Toy(ToyEstimate {
                    pitch_deg,
                    pitch_sigma_deg: sigma_deg,
                    readings: self.readings,
                }),
            });
        }
    }
    fn params(&self) -> &Params {
        &self.params
    }
    fn snapshot(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
    fn model(&self) -> Option<EngineModel> {
        Some(EngineModel::Toy(ToyModel {
            readings: self.readings,
        }))
    }
}

/// What the toy estimates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ToyEstimate {
    pub pitch_deg: f64,
    pub pitch_sigma_deg: f64,
    pub readings: u64,
}

impl StreamValues for ToyEstimate {
    const CODEC_VERSION: u32 = 1;
    const SIGNALS: &'static [SignalKind] = &[SignalKind::Laser, SignalKind::PitchSigma];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.number("pitch_deg", self.pitch_deg);
        w.number("pitch_sigma_deg", self.pitch_sigma_deg);
        w.integer("readings", self.readings);
    }
    fn decode(version: u32, bytes: &[u8]) -> Result<ToyEstimate, postcard::Error> {
        match version {
            1 => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
        }
    }
    fn extremes(&self) -> [f64; 2] {
        [self.pitch_deg, self.pitch_sigma_deg]
    }
    /// It reads the laser at every estimate, and claims its σ.
    fn signals(&self) -> Signals {
        Signals {
            laser: Some(LaserSignal {
                ok: true,
                age_s: Some(0.0),
            }),
            pitch_sigma_deg: Some(self.pitch_sigma_deg),
            ..Signals::default()
        }
    }
}

/// The toy's model report.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct ToyModel {
    pub readings: u64,
}

/// The toy's section of a machine page.
#[derive(Template)]
#[template(
    source = r#"<div id="toy"><span data-field="pitch_deg"></span></div>"#,
    ext = "html"
)]
pub struct ToySection;

/// The toy's script.
pub(crate) const TOY_SCRIPT: crate::server::pages::Asset = crate::server::pages::Asset {
    path: "toy.js",
    content_type: "text/javascript; charset=utf-8",
    bytes: b"tn.registerEngine('toy', {card: (e) => [['pitch', e.pitch_deg]]});",
};

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use clap::ValueEnum;
    use utoipa::ToSchema;

    use super::*;
    use crate::config::{MachineDeclaration, MachineSpec};
    use crate::fusion::alarms::AlarmKind;
    use crate::fusion::{Estimate, StreamKind};
    use crate::machine::{LiveEstimate, MachineCore};

    fn spec() -> MachineSpec {
        serde_json::from_value::<MachineDeclaration>(serde_json::json!({
            "engines": {"toy": {"sigma_deg": 0.25}}
        }))
        .unwrap()
        .validate("toy-1")
        .unwrap()
    }

    fn laser(t: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Laser {
                pitch_deg: 0.5 + t / 1000.0,
                roll_deg: 0.0,
                yaw_deg: None,
                position: None,
            },
        }
    }

    #[test]
    fn the_toy_is_known_by_its_name_everywhere() {
        assert_eq!("toy".parse::<EngineKind>().unwrap(), EngineKind::Toy);
        assert_eq!("toy".parse::<StreamKind>().unwrap(), StreamKind::Toy);
        assert_eq!(
            StreamKind::from(EngineKind::Toy).engine(),
            Some(EngineKind::Toy)
        );
        assert!(EngineKind::value_variants().contains(&EngineKind::Toy));
        assert!(EngineKind::names().ends_with("fuzzy, toy"));
        assert!(StreamKind::names().contains("toy"));
        assert_eq!(EngineKind::Toy.sensors(), &[SensorKind::Laser]);
        let params = EngineKind::Toy
            .params_from_assignments(["sigma_deg=0.3"])
            .unwrap();
        assert_eq!(EngineKind::Toy.read_params(&params).unwrap(), params);
        assert!(
            EngineKind::Toy
                .params_from_assignments(["sigma_deg=11"])
                .is_err()
        );
    }

    #[test]
    fn a_toy_machine_runs_through_the_machine_core_and_continues_from_its_snapshot() {
        let spec = spec();
        let mut core = MachineCore::new(&spec).unwrap();
        let mut emitted = Vec::new();
        for i in 0..60 {
            core.push(laser(f64::from(i)), &mut emitted);
        }
        // The reorder window holds the newest readings back.
        assert!(emitted.len() > 40, "{}", emitted.len());
        for e in &emitted {
            let estimate: Estimate = serde_json::from_str(&e.live.json).unwrap();
            assert!(matches!(estimate.values, EstimateValues::Toy(_)));
            assert_eq!(estimate.machine, "toy-1");
            assert_eq!(e.live.signals, estimate.values.signals());
            // NDJSON as serde_json writes it.
            assert_eq!(*e.live.json, serde_json::to_string(&estimate).unwrap());
        }

        // Its σ (0.25°) is over the pitch alarm (0.1°) for the minimum
        // time: the rules read its signals.
        let alarms = core.take_alarms();
        assert!(
            alarms
                .iter()
                .any(|a| a.raised && a.key.kind == AlarmKind::AttitudeUncertainty),
            "{alarms:?}"
        );
        let model = serde_json::to_value(&core.models()[&EngineKind::Toy]).unwrap();
        assert_eq!(model["readings"], emitted.len() as u64);

        // The same from here on, restored or not.
        let mut restored = MachineCore::restore(&spec, &core.snapshot()).unwrap();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for i in 60..80 {
            core.push(laser(f64::from(i)), &mut a);
            restored.push(laser(f64::from(i)), &mut b);
        }
        assert!(!a.is_empty());
        let json = |v: &[crate::machine::Emitted]| -> Vec<String> {
            v.iter().map(|e| e.live.json.to_string()).collect()
        };
        assert_eq!(json(&a), json(&b));

        // The status's laser report is the toy's.
        let latest: BTreeMap<StreamKind, LiveEstimate> = a
            .into_iter()
            .map(|e| (e.live.engine, std::sync::Arc::new(e.live)))
            .collect();
        let report = crate::server::machines::laser_report(&latest).unwrap();
        assert!(report.ok && !report.dropout);
        assert_eq!(report.age_s, Some(0.0));
    }

    #[test]
    fn beside_attitude_the_toy_is_not_watched_for_what_attitude_tells() {
        use crate::fusion::alarms::{AlarmConfig, AlarmRules, AlarmState};
        let toy = ToyEstimate {
            pitch_deg: 0.0,
            pitch_sigma_deg: 5.0,
            readings: 1,
        };
        let raised = |streams: &[StreamKind]| {
            let mut rules =
                AlarmRules::new(AlarmConfig::default(), None, streams, AlarmState::default());
            let mut out = Vec::new();
            for i in 0..60 {
                rules.signals(
                    f64::from(i),
                    StreamKind::Toy,
                    crate::fusion::Integrity::OK,
                    &toy.signals(),
                    &mut out,
                );
            }
            out.iter().any(|t| t.raised)
        };
        assert!(raised(&[StreamKind::Toy]));
        assert!(!raised(&[StreamKind::Toy, StreamKind::Attitude]));
    }

    #[test]
    fn the_toy_is_stored_and_described() {
        let values = EstimateValues::Toy(ToyEstimate {
            pitch_deg: 1.25,
            pitch_sigma_deg: 0.5,
            readings: 7,
        });
        let version = StreamKind::Toy.codec_version();
        assert_eq!(version, 1);
        let back = EstimateValues::decode(StreamKind::Toy, version, &values.encode()).unwrap();
        assert_eq!(back, values);
        assert!(EstimateValues::decode(StreamKind::Toy, 2, &values.encode()).is_err());
        assert_eq!(values.extremes(), [1.25, 0.5]);

        let mut schemas = Vec::new();
        crate::server::openapi::EstimateValues::schemas(&mut schemas);
        assert!(schemas.iter().any(|(name, _)| name == "ToyEstimate"));
        let mut models = Vec::new();
        crate::server::openapi::EngineModelReport::schemas(&mut models);
        assert!(models.iter().any(|(name, _)| name == "ToyModel"));
        let union = serde_json::to_value(
            <crate::server::openapi::EstimateValues as utoipa::PartialSchema>::schema(),
        )
        .unwrap()
        .to_string();
        assert!(union.contains("\"toy\"") && union.contains("ToyEstimate"));
    }

    #[test]
    fn the_toy_has_its_page_section() {
        let params = EngineKind::Toy.params([]).unwrap();
        let section = crate::server::pages::engine_section(EngineKind::Toy, &params).unwrap();
        assert!(section.html.contains(r#"<div id="toy">"#));
        assert_eq!(section.script, "toy.js");
    }
}
