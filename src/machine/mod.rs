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

mod actor;
mod core;
mod error;
mod lease;
mod recover;
mod status;
#[cfg(test)]
mod tests;

pub use self::core::{Emitted, FusedEstimate, LiveEstimate, MachineCore, REORDER_MAX_LEN};
pub use actor::{
    AlarmSink, ForwardedPart, LIVE_BUFFER, MachineHandle, SNAPSHOT_EVERY_READINGS, Surroundings,
    spawn,
};
pub use error::MachineError;
pub use lease::LeaseEpoch;
pub use recover::{newest_outputs, recover, stored_status};
pub use status::{MachineStatus, SensorStatus};
