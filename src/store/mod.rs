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
mod rows;
pub mod sqlite;

pub use backend::{Announce, Backend, EachReading, Office};
pub use error::StoreError;
pub use handle::Store;
pub use history::{BUCKET_WIDTHS_S, EstimatesPage, Extremes};
pub use rows::{
    AfterCommit, EstimateRow, ReadingRow, StoredMachine, StoredSnapshot, Write, WriteOutcome,
    stored_machine,
};
pub use sqlite::{DB_FILE, SqliteStore};
