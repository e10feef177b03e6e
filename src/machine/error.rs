//! Why a machine could not be built, restored or reached.

use crate::fusion::{ParamError, SnapshotError};
use crate::store::StoreError;

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
