//! The store: machines, readings, estimates, engine snapshots, alarms,
//! tokens and what the server owes others, behind one [`Backend`] trait.
//!
//! - [`Store`] is the cheap, cloneable handle the rest of tunnelnav uses.
//!   Writes are typed requests answered after their commit (group commit:
//!   a backend commits every request waiting in its queue in one
//!   transaction); reads are blocking calls (async callers run them with
//!   `spawn_blocking`).
//! - [`sqlite`]: one SQLite file (WAL) in the data dir (one site).
//! - [`postgres`]: a PostgreSQL database (an office; several nodes).
//! - This folder's own files hold what every backend shares: the rows
//!   written ([`Write`]), the alarm, outbox and retention types, history
//!   downsampling ([`history`]) and the codecs.
//!
//! A new backend is a folder implementing [`Backend`] (docs/development.md
//! lists what it implements); `tests/store_conformance.rs` runs every
//! backend, and a test-only one kept in memory, through the same suite.

pub mod alarms;
mod backend;
pub mod codec;
mod error;
mod handle;
pub mod history;
pub mod outbox;
pub mod postgres;
mod queue;
pub mod retention;
pub mod sqlite;

pub use backend::{Backend, Office};
pub use error::StoreError;
pub use handle::Store;
pub use history::{BUCKET_WIDTHS_S, EstimatesPage, Extremes};
pub use sqlite::{DB_FILE, SqliteStore};

use tokio::sync::oneshot;

use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

/// Most requests committed in one transaction.
pub(crate) const MAX_GROUP: usize = 512;
/// Requests waiting for the writer before senders wait (backpressure).
pub(crate) const QUEUE_LEN: usize = 1024;

/// A reading to store: its time, sensor and data.
#[derive(Debug, Clone)]
pub struct ReadingRow {
    pub t: f64,
    pub sensor: SensorKind,
    /// The data, encoded by [`codec::encode_reading`].
    pub data: Vec<u8>,
}

impl ReadingRow {
    /// The row that stores `reading`.
    pub fn new(reading: &Reading) -> ReadingRow {
        ReadingRow {
            t: reading.t,
            sensor: reading.sensor(),
            data: codec::encode_reading(&reading.data),
        }
    }
}

/// An estimate to store.
#[derive(Debug, Clone)]
pub struct EstimateRow {
    pub engine: StreamKind,
    pub t: f64,
    /// The two values whose extremes downsampling keeps.
    pub extremes: [f64; 2],
    /// The integrity and values, encoded by [`codec::encode_output`]; `codec`
    /// is the values' codec version with [`codec::WITH_INTEGRITY`].
    pub values: Vec<u8>,
    pub codec: u32,
}

impl EstimateRow {
    /// The row that stores `output`.
    pub fn new(output: &EngineOutput) -> EstimateRow {
        let (values, codec) = codec::encode_output(output);
        EstimateRow {
            engine: output.values.stream(),
            t: output.t,
            extremes: output.values.extremes(),
            values,
            codec,
        }
    }
}

/// Called once the write it belongs to is committed — with the alarms it
/// changed — or has failed (`None`).
pub type AfterCommit = Box<dyn FnOnce(Option<Vec<alarms::AlarmChange>>) + Send + Sync>;

/// One machine's readings and the estimates and snapshot they led to,
/// committed together.
pub struct Write {
    pub machine_id: i64,
    pub readings: Vec<ReadingRow>,
    pub estimates: Vec<EstimateRow>,
    /// Alarms these readings raised or cleared.
    pub alarms: Vec<alarms::AlarmRow>,
    /// A snapshot of the machine's state after every reading written so far
    /// (including these) arrived.
    pub snapshot: Option<String>,
    /// Runs on the writer thread right after the commit (live broadcast).
    pub after_commit: Option<AfterCommit>,
    pub reply: Option<oneshot::Sender<Result<WriteOutcome, StoreError>>>,
    /// The lease epoch the machine's node runs it under (several nodes on
    /// PostgreSQL): the commit fails unless the node still holds the lease
    /// with this epoch. `None` with one server.
    pub lease_epoch: Option<i64>,
    /// An office: the site's sequence this write of a forwarded machine
    /// brings it to (stored with it), and the acknowledgements in it.
    pub forwarded: Option<Box<outbox::Forwarded>>,
}

/// What a committed [`Write`] stored.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriteOutcome {
    /// Readings newly stored.
    pub stored: usize,
    /// Readings already stored (same machine, sensor and time): kept once.
    pub duplicates: usize,
}

/// A stored machine.
#[derive(Debug, Clone)]
pub struct StoredMachine {
    pub db_id: i64,
    pub spec: MachineSpec,
}

/// A machine's latest snapshot.
#[derive(Debug, Clone)]
pub struct StoredSnapshot {
    pub last_reading_id: i64,
    pub state: String,
}

/// A stored machine from its row: the spec parsed and made current.
pub fn stored_machine(db_id: i64, spec: String) -> Result<StoredMachine, StoreError> {
    let spec: MachineSpec = serde_json::from_str(&spec)
        .map_err(|e| StoreError::Corrupt(format!("machine {db_id} spec: {e}")))?;
    let spec = spec
        .upgraded()
        .map_err(|e| StoreError::Corrupt(format!("machine {db_id} spec: {e}")))?;
    Ok(StoredMachine { db_id, spec })
}
