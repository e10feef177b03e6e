//! Machines, their snapshots and their readings in arrival order, as the
//! PostgreSQL store keeps them.

use tokio::sync::oneshot;

use super::handle::PgStore;
use super::history::reading;
use crate::config::MachineSpec;
use crate::fusion::Reading;
use crate::store::error::StoreError;
use crate::store::queue::{Queued, Request};
use crate::store::rows::StoredMachine;
use crate::store::rows::StoredSnapshot;

impl PgStore {
    /// Creates or replaces a machine with a fresh engine snapshot; returns
    /// its id.
    pub async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.writers[0]
            .send(Queued::Request(Request::PutMachine {
                spec: Box::new(spec),
                snapshot,
                forwarded,
                reply,
            }))
            .await
            .map_err(|_| StoreError::Closed)?;
        answer.await.map_err(|_| StoreError::Closed)?
    }

    /// Every stored machine, its parameters made current.
    pub fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.read(async |client| {
            let rows = client
                .query("SELECT id, spec FROM machines ORDER BY machine", &[])
                .await?;
            rows.iter()
                .map(|row| crate::store::rows::stored_machine(row.get(0), row.get(1)))
                .collect()
        })
    }

    /// A machine's latest snapshot.
    pub fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query_opt(
                    "SELECT last_reading_id, state FROM snapshots WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .map(|row| StoredSnapshot {
                    last_reading_id: row.get(0),
                    state: row.get(1),
                }))
        })
    }

    /// Calls `f` with each reading of the machine that arrived after
    /// `after_id`, in arrival order, a batch at a time.
    pub fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        mut f: impl FnMut(Reading) -> Result<(), StoreError>,
    ) -> Result<u64, StoreError> {
        const BATCH: i64 = 10_000;
        let mut after = after_id;
        let mut count = 0;
        loop {
            let rows = self.read(async |client| {
                Ok(client
                    .query(
                        "SELECT id, t, sensor, body FROM readings WHERE machine_id = $1 AND id > $2 \
                         ORDER BY id LIMIT $3",
                        &[&machine_id, &after, &BATCH],
                    )
                    .await?)
            })?;
            for row in &rows {
                after = row.get(0);
                f(reading(row.get(1), row.get(2), row.get(3))?)?;
                count += 1;
            }
            if (rows.len() as i64) < BATCH {
                return Ok(count);
            }
        }
    }
}
