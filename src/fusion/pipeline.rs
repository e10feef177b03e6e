//! A machine's engines and the stages after them, fed time-ordered
//! readings: what the server's machine actor and `replay` both run, so
//! their outputs are the same.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::estimate::EngineOutput;
use super::params::{ParamError, Params};
use super::reading::Reading;
use super::registry::{EngineKind, EngineModel, StageKind};
use super::{Declaration, Stage};
use super::{Engine, SnapshotError};

/// Engines, then stages.
pub struct Pipeline {
    engines: Vec<Box<dyn Engine>>,
    stages: Vec<Box<dyn Stage>>,
    /// One engine's (or stage's) outputs of the current reading, before
    /// the stages after it.
    scratch: Vec<EngineOutput>,
}

/// What restoring does with a stage the snapshot lacks.
#[derive(Clone, Copy)]
enum Missing<'a> {
    /// Refuse: the machine is rebuilt from its readings.
    Refuse,
    /// Start it afresh (the declaration gained it just now).
    Fresh,
    /// Seed a stage that may be from the newest outputs; refuse others.
    Seed(&'a [EngineOutput]),
}

/// The state of a pipeline, serialisable.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PipelineState {
    pub engines: BTreeMap<EngineKind, serde_json::Value>,
    /// Absent in snapshots from before stages existed.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub stages: BTreeMap<StageKind, serde_json::Value>,
}

impl Pipeline {
    /// Fresh engines with these parameters, and the stages a declaration
    /// of only them calls for.
    pub fn new<'a>(
        engines: impl IntoIterator<Item = (EngineKind, &'a Params)>,
    ) -> Result<Pipeline, ParamError> {
        let engines = engines
            .into_iter()
            .map(|(kind, params)| kind.create(params.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Pipeline::with_engines(engines))
    }

    /// These engines and the stages a declaration of only them calls for.
    pub fn with_engines(engines: Vec<Box<dyn Engine>>) -> Pipeline {
        let declaration = Declaration::of_engines(engines.iter().map(|e| e.kind()));
        Pipeline::declared(engines, &declaration)
    }

    /// These engines and the stages `declaration` (of a machine running
    /// them) calls for.
    pub fn declared(engines: Vec<Box<dyn Engine>>, declaration: &Declaration) -> Pipeline {
        let stages = StageKind::ALL
            .iter()
            .filter_map(|stage| stage.create(declaration))
            .collect();
        Pipeline {
            engines,
            stages,
            scratch: Vec::new(),
        }
    }

    /// Continues from a [`Pipeline::state`]. A stage the engines now call
    /// for and the state lacks (it predates the stage) is refused as
    /// [`SnapshotError::MissingStage`]: rebuild from the readings.
    pub fn restore(
        state: PipelineState,
        declaration: &Declaration,
    ) -> Result<Pipeline, SnapshotError> {
        Pipeline::restore_as(state, declaration, Missing::Refuse)
    }

    /// Like [`Pipeline::restore`], but a stage the state lacks that may be
    /// seeded ([`StageKind::seeded`]) starts from `newest`, the newest
    /// stored output of each of the machine's streams, offered to it in
    /// stream order (what it derives is dropped); any other missing stage
    /// is still [`SnapshotError::MissingStage`].
    pub fn restore_seeded(
        state: PipelineState,
        declaration: &Declaration,
        newest: &[EngineOutput],
    ) -> Result<Pipeline, SnapshotError> {
        Pipeline::restore_as(state, declaration, Missing::Seed(newest))
    }

    /// Like [`Pipeline::restore`], but a stage the state lacks starts
    /// afresh (the machine's declaration gained it just now: it derives
    /// from here on).
    pub fn restore_adding_stages(
        state: PipelineState,
        declaration: &Declaration,
    ) -> Result<Pipeline, SnapshotError> {
        Pipeline::restore_as(state, declaration, Missing::Fresh)
    }

    fn restore_as(
        state: PipelineState,
        declaration: &Declaration,
        missing: Missing<'_>,
    ) -> Result<Pipeline, SnapshotError> {
        let mut engines = Vec::new();
        for (kind, snapshot) in state.engines {
            engines.push(kind.restore(snapshot)?);
        }
        let mut stages = Vec::new();
        let mut snapshots = state.stages;
        for stage in declaration.stages() {
            match (snapshots.remove(&stage), missing) {
                (Some(snapshot), _) => stages.push(stage.restore(declaration, snapshot)?),
                (None, Missing::Fresh) => stages.extend(stage.create(declaration)),
                (None, Missing::Seed(newest)) if stage.seeded() => {
                    let mut fresh = stage
                        .create(declaration)
                        .ok_or(SnapshotError::MissingStage(stage))?;
                    let mut sorted: Vec<&EngineOutput> = newest.iter().collect();
                    sorted.sort_by_key(|o| o.values.stream());
                    let mut dropped = Vec::new();
                    for output in sorted {
                        fresh.estimate(output, &mut dropped);
                        dropped.clear();
                    }
                    stages.push(fresh);
                }
                (None, _) => return Err(SnapshotError::MissingStage(stage)),
            }
        }
        Ok(Pipeline {
            engines,
            stages,
            scratch: Vec::new(),
        })
    }

    /// The whole state.
    pub fn state(&self) -> PipelineState {
        PipelineState {
            engines: self
                .engines
                .iter()
                .map(|e| (e.kind(), e.snapshot()))
                .collect(),
            stages: self
                .stages
                .iter()
                .map(|s| (s.kind(), s.snapshot()))
                .collect(),
        }
    }

    /// Feeds one time-ordered reading to the stages and the engines
    /// that use its sensor; appends every output to `out`, each followed
    /// by what the stages after the one that made it derive from it (in
    /// registry order: `steer` and `rings` see `dta`'s estimates).
    pub fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        let sensor = reading.sensor();
        for i in 0..self.stages.len() {
            let (stage, later) = self.stages[i..].split_at_mut(1);
            stage[0].reading(reading, &mut self.scratch);
            pass_on(&mut self.scratch, later, out);
        }
        for engine in &mut self.engines {
            if !engine.kind().sensors().contains(&sensor) {
                continue;
            }
            if self.stages.is_empty() {
                engine.feed(reading, out);
                continue;
            }
            engine.feed(reading, &mut self.scratch);
            pass_on(&mut self.scratch, &mut self.stages, out);
        }
    }

    /// The input has ended: what the engines still hold, and what the
    /// stages derive from it.
    pub fn flush(&mut self, out: &mut Vec<EngineOutput>) {
        for engine in &mut self.engines {
            engine.flush(&mut self.scratch);
            pass_on(&mut self.scratch, &mut self.stages, out);
        }
    }

    /// Whether a reading of `sensor` feeds any engine or stage.
    pub fn uses(&self, sensor: super::SensorKind) -> bool {
        self.engines
            .iter()
            .any(|e| e.kind().sensors().contains(&sensor))
            || self.stages.iter().any(|s| s.reads(sensor))
    }

    /// The engines.
    pub fn engines(&self) -> &[Box<dyn Engine>] {
        &self.engines
    }

    /// The stages running after them.
    pub fn stages(&self) -> impl Iterator<Item = StageKind> + '_ {
        self.stages.iter().map(|s| s.kind())
    }

    /// Each engine's model report, if it has one.
    pub fn models(&self) -> BTreeMap<EngineKind, EngineModel> {
        self.engines
            .iter()
            .filter_map(|e| e.model().map(|m| (e.kind(), m)))
            .collect()
    }
}

/// Moves `outputs` to `out`, each followed by what the `stages` derive
/// from it.
fn pass_on(
    outputs: &mut Vec<EngineOutput>,
    stages: &mut [Box<dyn Stage>],
    out: &mut Vec<EngineOutput>,
) {
    for output in outputs.drain(..) {
        offer(output, stages, out);
    }
}

/// Appends `output` to `out`, then offers it to each of `stages` in turn:
/// what one derives follows, each offered in turn to the stages after it.
fn offer(output: EngineOutput, stages: &mut [Box<dyn Stage>], out: &mut Vec<EngineOutput>) {
    let at = out.len();
    out.push(output);
    for i in 0..stages.len() {
        let (stage, later) = stages[i..].split_at_mut(1);
        // Most stages derive nothing from most outputs: no allocation then.
        let mut derived = Vec::new();
        stage[0].estimate(&out[at], &mut derived);
        for d in derived {
            offer(d, later, out);
        }
    }
}
