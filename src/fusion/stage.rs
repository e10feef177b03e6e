//! Stages after the engines: each derives a stream of its own from a
//! machine's declaration, the readings its engines are fed and the
//! estimates they emit (the jacking log from `zupt`'s pushes; the
//! deviation from the design axis from positions and attitude). Pure like
//! the engines: the server's machine actor and `replay` run the same
//! [`Pipeline`](super::pipeline::Pipeline) and get the same outputs.

use std::sync::Arc;

use super::alignment::Alignment;
use super::dta::{MachineGeometry, Tolerances};
use super::estimate::EngineOutput;
use super::reading::{ProjectPoint, Reading, SensorKind};
use super::registry::{EngineKind, StageKind};
use super::steering::SteeringSpec;

/// The part of a machine's declaration stages read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Declaration {
    /// The engines the machine runs.
    pub engines: Vec<EngineKind>,
    /// The designed tunnel axis of its drive.
    pub alignment: Option<Arc<Alignment>>,
    /// Where its front and rear are on it.
    pub geometry: Option<MachineGeometry>,
    pub tolerances: Option<Tolerances>,
    /// Project coordinates of its reference point at the first reading
    /// (for engines whose position is relative to their start).
    pub start: Option<ProjectPoint>,
    /// How the machine may be steered (the `steer` stage's curve).
    pub steering: Option<SteeringSpec>,
}

impl Declaration {
    /// A declaration of these engines.
    pub fn of_engines(engines: impl IntoIterator<Item = EngineKind>) -> Declaration {
        Declaration {
            engines: engines.into_iter().collect(),
            ..Declaration::default()
        }
    }

    /// Whether the machine runs `engine`.
    pub fn runs(&self, engine: EngineKind) -> bool {
        self.engines.contains(&engine)
    }

    /// The stages this declaration calls for, in registry order.
    pub fn stages(&self) -> Vec<StageKind> {
        StageKind::ALL
            .iter()
            .copied()
            .filter(|stage| stage.create(self).is_some())
            .collect()
    }
}

/// A stage after the engines.
pub trait Stage: Send {
    /// Which stage this is.
    fn kind(&self) -> StageKind;

    /// Whether the stage reads readings of `sensor` (a reading no engine
    /// and no stage reads is not fed at all).
    fn reads(&self, _sensor: SensorKind) -> bool {
        false
    }

    /// A reading as the engines are fed it (in time order, after the
    /// reorder buffer); appends what it derives to `out`. Most stages
    /// need only estimates.
    fn reading(&mut self, _reading: &Reading, _out: &mut Vec<EngineOutput>) {}

    /// An engine's estimate, or an earlier stage's output, in the order
    /// they are emitted; appends what it derives to `out` (offered in
    /// turn to the stages after this one).
    fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<EngineOutput>);

    /// The whole state, serialisable: [`StageKind::restore`] continues
    /// from it exactly.
    fn snapshot(&self) -> serde_json::Value;
}
