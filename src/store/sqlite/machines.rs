//! Machines, their snapshots and their readings in arrival order, as the
//! SQLite store keeps them.

use rusqlite::{OptionalExtension, params};

use super::handle::SqliteStore;
use crate::fusion::Reading;
use crate::store::error::StoreError;
use crate::store::rows::StoredMachine;
use crate::store::rows::StoredSnapshot;
use crate::store::rows::stored_machine;

impl SqliteStore {
    /// Every stored machine, its parameters made current (a machine
    /// declared by an earlier release loads with its retired parameters
    /// dropped and new ones at their defaults).
    pub fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached("SELECT id, spec FROM machines ORDER BY machine")?;
            let rows = stmt.query_map([], |row| {
                Ok((row.get::<_, i64>(0)?, row.get::<_, String>(1)?))
            })?;
            let mut machines = Vec::new();
            for row in rows {
                let (db_id, spec) = row?;
                machines.push(stored_machine(db_id, spec)?);
            }
            Ok(machines)
        })
    }

    /// A machine's latest snapshot.
    pub fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        self.read(|conn| {
            Ok(conn
                .prepare_cached(
                    "SELECT last_reading_id, state FROM snapshots WHERE machine_id = ?1",
                )?
                .query_row([machine_id], |row| {
                    Ok(StoredSnapshot {
                        last_reading_id: row.get(0)?,
                        state: row.get(1)?,
                    })
                })
                .optional()?)
        })
    }

    /// Calls `f` with each reading of the machine that arrived after
    /// `after_id`, in arrival order, without holding them all in memory.
    pub fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        mut f: impl FnMut(Reading) -> Result<(), StoreError>,
    ) -> Result<u64, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT t, sensor, body FROM readings WHERE machine_id = ?1 AND id > ?2 ORDER BY id",
            )?;
            let mut rows = stmt.query(params![machine_id, after_id])?;
            let mut count = 0;
            while let Some(row) = rows.next()? {
                f(super::history::reading_row(row)?)?;
                count += 1;
            }
            Ok(count)
        })
    }
}
