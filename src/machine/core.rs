//! The machine's synchronous core: its engines behind a reorder buffer,
//! the estimates they emit, attributed and serialised once.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::config::MachineSpec;
use crate::fusion::alarms::{AlarmKind, AlarmNow, AlarmRules, AlarmState, Transition};
use crate::fusion::estimate::EstimateWriter;
use crate::fusion::pipeline::{Pipeline, PipelineState};
use crate::fusion::reorder::{Admission, ReorderBuffer};
use crate::fusion::{
    EngineKind, EngineModel, EngineOutput, ParamError, Reading, Signals, SnapshotError, StreamKind,
};
use crate::store::{EstimateRow, StoreError};

/// Most readings the reorder buffer holds per machine.
pub const REORDER_MAX_LEN: usize = 100_000;

/// An estimate as the machine emits it: attributed, serialised once.
#[derive(Debug, Clone)]
pub struct FusedEstimate {
    /// The engine or stage that made it.
    pub engine: StreamKind,
    pub t: f64,
    /// What the alarm rules and the status watch in it.
    pub signals: Signals,
    /// The protocol JSON, one object, no newline.
    pub json: Arc<str>,
}

impl FusedEstimate {
    /// A stored estimate of `machine`'s `engine` as the live stream shows it.
    pub fn stored(
        machine: &str,
        engine: StreamKind,
        output: &EngineOutput,
    ) -> Result<FusedEstimate, StoreError> {
        let json = serde_json::to_string(&output.for_machine(machine))
            .map_err(|e| StoreError::Corrupt(format!("stored estimate: {e}")))?;
        Ok(FusedEstimate {
            engine,
            t: output.t,
            signals: output.values.signals(),
            json: Arc::from(json),
        })
    }
}

/// One engine output in both forms it leaves the machine in: JSON for live
/// clients and the status, a compact row for the store.
#[derive(Debug)]
pub struct Emitted {
    pub live: FusedEstimate,
    pub row: EstimateRow,
}

/// What live clients receive.
pub type LiveEstimate = Arc<FusedEstimate>;

/// A machine's engines, stages and reorder buffer: deterministic, no IO.
/// The same readings in the same arrival order give the same estimates
/// here, in a restored copy, and (for time-ordered input) in `replay`.
pub struct MachineCore {
    pipeline: Pipeline,
    reorder: ReorderBuffer,
    alarms: AlarmRules,
    /// Alarm transitions since [`MachineCore::take_alarms`].
    transitions: Vec<Transition>,
    writer: EstimateWriter,
    ready: Vec<Reading>,
    outputs: Vec<EngineOutput>,
    line: Vec<u8>,
    /// Whether the alarm rules run here: not for a machine an office holds
    /// for a site, whose alarms come from the site.
    own_alarms: bool,
}

#[derive(Serialize, Deserialize)]
struct CoreState {
    #[serde(flatten)]
    pipeline: PipelineState,
    reorder: serde_json::Value,
    /// Absent in snapshots from before the alarms: no alarm active.
    #[serde(default)]
    alarms: AlarmState,
}

impl MachineCore {
    /// Fresh engines and stages for `spec`.
    pub fn new(spec: &MachineSpec) -> Result<MachineCore, ParamError> {
        Ok(Self::assemble(
            spec,
            spec.pipeline()?,
            ReorderBuffer::new(spec.reorder_window_s, REORDER_MAX_LEN),
            AlarmState::default(),
        ))
    }

    /// Engines and stages continuing from a [`MachineCore::snapshot`].
    pub fn restore(spec: &MachineSpec, state: &str) -> Result<MachineCore, SnapshotError> {
        Self::from_snapshot(spec, state, Pipeline::restore)
    }

    /// Like [`MachineCore::restore`], a stage this release added that may
    /// be seeded starting from `newest`, the machine's newest stored
    /// output of each stream ([`Pipeline::restore_seeded`]).
    pub fn restore_seeded(
        spec: &MachineSpec,
        state: &str,
        newest: &[EngineOutput],
    ) -> Result<MachineCore, SnapshotError> {
        Self::from_snapshot(spec, state, |pipeline, declaration| {
            Pipeline::restore_seeded(pipeline, declaration, newest)
        })
    }

    /// The engines of a [`MachineCore::snapshot`] under a declaration that
    /// differs only in what the stages read (the design axis, geometry,
    /// tolerances, start): the engines go on where they stood, a stage the
    /// declaration now calls for starts from here.
    pub fn redeclared(spec: &MachineSpec, state: &str) -> Result<MachineCore, SnapshotError> {
        Self::from_snapshot(spec, state, Pipeline::restore_adding_stages)
    }

    /// The core of a snapshot's `state`, its pipeline restored by `pipeline`.
    fn from_snapshot(
        spec: &MachineSpec,
        state: &str,
        pipeline: impl FnOnce(
            PipelineState,
            &crate::fusion::Declaration,
        ) -> Result<Pipeline, SnapshotError>,
    ) -> Result<MachineCore, SnapshotError> {
        let state: CoreState =
            serde_json::from_str(state).map_err(|e| SnapshotError::Invalid(e.to_string()))?;
        Ok(Self::assemble(
            spec,
            pipeline(state.pipeline, &spec.stage_declaration())?,
            ReorderBuffer::restore(state.reorder)?,
            state.alarms,
        ))
    }

    fn assemble(
        spec: &MachineSpec,
        pipeline: Pipeline,
        reorder: ReorderBuffer,
        alarms: AlarmState,
    ) -> Self {
        MachineCore {
            pipeline,
            reorder,
            alarms: AlarmRules::new(spec.alarms, spec.tolerances, &spec.streams(), alarms),
            transitions: Vec::new(),
            writer: EstimateWriter::new(&spec.id),
            ready: Vec::new(),
            outputs: Vec::new(),
            line: Vec::new(),
            own_alarms: crate::config::forwarded_site(&spec.id).is_none(),
        }
    }

    /// The whole state as JSON.
    pub fn snapshot(&self) -> String {
        let state = CoreState {
            pipeline: self.pipeline.state(),
            reorder: self.reorder.snapshot(),
            alarms: self.alarms.state().clone(),
        };
        serde_json::to_string(&state).unwrap_or_default()
    }

    /// Offers one reading; appends the estimates that became ready to `out`.
    pub fn push(&mut self, reading: Reading, out: &mut Vec<Emitted>) -> Admission {
        let admission = self.reorder.push(reading);
        self.reorder.pop_ready(&mut self.ready);
        for reading in self.ready.drain(..) {
            self.outputs.clear();
            if self.own_alarms {
                self.alarms.reading(&reading, &mut self.transitions);
            }
            self.pipeline.feed(&reading, &mut self.outputs);
            for output in &self.outputs {
                let stream = output.values.stream();
                let signals = output.values.signals();
                if self.own_alarms {
                    self.alarms.signals(
                        output.t,
                        stream,
                        output.integrity,
                        &signals,
                        &mut self.transitions,
                    );
                }
                self.line.clear();
                self.writer.write_line(output, &mut self.line);
                let json = std::str::from_utf8(self.line.trim_ascii_end()).unwrap_or("{}");
                out.push(Emitted {
                    live: FusedEstimate {
                        engine: stream,
                        t: output.t,
                        signals,
                        json: Arc::from(json),
                    },
                    row: EstimateRow::new(output),
                });
            }
        }
        admission
    }

    /// The alarms raised and cleared since the last call.
    pub fn take_alarms(&mut self) -> Vec<Transition> {
        std::mem::take(&mut self.transitions)
    }

    /// What each active alarm's quantity reads now, by kind and subject.
    pub fn alarm_now(&self) -> &BTreeMap<(AlarmKind, String), AlarmNow> {
        self.alarms.now()
    }

    /// The server runs the machine again at `now_t`: its downtime is not
    /// its sensors' silence.
    pub fn resumed(&mut self, now_t: f64) {
        self.alarms.resumed(now_t);
    }

    /// When [`MachineCore::resumed`] last said the server resumed.
    pub fn resumed_t(&self) -> Option<f64> {
        self.alarms.resumed_t()
    }

    /// The server clock at `now_t`: sensors silent too long. Returns the
    /// alarms raised (and any pending from readings).
    pub fn tick(&mut self, now_t: f64) -> Vec<Transition> {
        if self.own_alarms {
            self.alarms.tick(now_t, &mut self.transitions);
        }
        self.take_alarms()
    }

    /// Each engine's model report, if it has one.
    pub fn models(&self) -> BTreeMap<EngineKind, EngineModel> {
        self.pipeline.models()
    }
}
