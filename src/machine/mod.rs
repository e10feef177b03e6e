//! One machine: its engines behind a reorder buffer ([`MachineCore`], plain
//! synchronous code) and the task that owns them ([`spawn`]), the only
//! bridge from the async server to the fusion core.
//!
//! Per ingest request the task time-orders the batch, pushes it through the
//! reorder buffer into every engine that uses each sensor, and sends the
//! readings, the estimates they produced and now and then a snapshot to the
//! store as one write. The request is answered by the store after the
//! commit; the estimates are broadcast to live clients at the same moment.
//! The task does not wait for the commit, so one machine's requests are
//! pipelined into the store's group commits.

use crate::fusion::{ParamError, SnapshotError};
use crate::store::StoreError;

mod actor;
mod core;
mod lease;
mod recover;
#[cfg(test)]
mod tests;

pub use self::core::{Emitted, FusedEstimate, LiveEstimate, MachineCore, REORDER_MAX_LEN};
pub use actor::{
    AlarmSink, ForwardedPart, MachineHandle, MachineStatus, SensorStatus, Surroundings, spawn,
};
pub use lease::LeaseEpoch;
pub use recover::{newest_outputs, recover, stored_status};

/// A snapshot is stored after this many readings, so a restart re-feeds at
/// most this many.
pub const SNAPSHOT_EVERY_READINGS: u64 = 20_000;
/// Estimates a slow live client may fall behind by before it gets a `gap`.
pub const LIVE_BUFFER: usize = 4096;

/// Why a machine could not be built or restored.
#[derive(Debug, thiserror::Error)]
pub enum MachineError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error(transparent)]
    Snapshot(#[from] SnapshotError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("stored reading is invalid: {0}")]
    StoredReading(String),
    #[error("machine `{0}` has stopped")]
    Stopped(String),
    #[error("machine `{machine}` is busy: {queued} requests are waiting for it")]
    Busy { machine: String, queued: usize },
}
