//! What a machine declares that its engines and stages read: the engines
//! it runs, its design axis, where its front and rear are on it, the
//! tolerances its deviations are held to, where it starts and how it may
//! be steered.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::alignment::Alignment;
use super::reading::ProjectPoint;
use super::registry::{EngineKind, StageKind};
use super::ring_build::RingSpec;
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
    /// Its universal tapered rings (the `ring_plan` stage).
    pub rings: Option<RingSpec>,
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

/// Where the machine's front and rear points are on it: metres from the
/// navigation reference point in the body frame (x forward, y right, z
/// down).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MachineGeometry {
    pub front_m: [f64; 3],
    pub rear_m: [f64; 3],
}

/// Warn and alarm limits of one deviation, mm (of its magnitude).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    pub warn: f64,
    pub alarm: f64,
}

/// The tolerances the deviations are held to.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Tolerances {
    pub horizontal_mm: Limits,
    pub vertical_mm: Limits,
}
