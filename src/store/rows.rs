//! What every backend stores and answers: the rows of a [`Write`] and
//! what it stored, a stored machine and its snapshot.

use tokio::sync::oneshot;

use super::error::StoreError;
use super::{alarms, codec, outbox};
use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

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
