//! What a machine looks like now: published by its task after every
//! request, and rebuilt from the store at a restart.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::fusion::alarms::{AlarmKind, AlarmNow};
use crate::fusion::{SensorKind, StreamKind};

use super::core::LiveEstimate;

/// Last reading of one sensor.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SensorStatus {
    /// Time of the newest reading received, Unix seconds.
    pub last_t: f64,
    /// Readings received since the server started, less those of writes
    /// that failed (the gateway resends them).
    pub readings: u64,
}

/// What a machine looks like now; published after every request.
#[derive(Debug, Clone, Default)]
pub struct MachineStatus {
    /// Latest estimate of each engine and stage, protocol JSON.
    pub latest: BTreeMap<StreamKind, LiveEstimate>,
    pub sensors: BTreeMap<SensorKind, SensorStatus>,
    /// Readings dropped as older than one of the same sensor already fused
    /// (stored all the same), since the server started, less those of
    /// writes that failed.
    pub late: u64,
    /// What each active alarm's quantity reads now, by kind and subject.
    pub alarm_now: BTreeMap<(AlarmKind, String), AlarmNow>,
}
