//! History reads in PostgreSQL: estimates downsampled by
//! [`crate::store::history::estimates_page`], readings and estimates
//! exported in time order.

use super::handle::PgStore;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};
use crate::store::codec;
use crate::store::error::StoreError;
use crate::store::history::{self, EstimatesPage, Extremes, HistorySource};

impl PgStore {
    /// The newest stored estimate of a stream.
    pub fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        self.read(async |client| {
            client
                .query_opt(
                    "SELECT t, body, codec FROM estimates WHERE machine_id = $1 AND engine = $2 \
                     ORDER BY t DESC LIMIT 1",
                    &[&machine_id, &engine.as_str()],
                )
                .await?
                .map(|row| output(engine, &row))
                .transpose()
        })
    }

    /// Time of the newest stored reading of a sensor.
    pub fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query_opt(
                    "SELECT t FROM readings WHERE machine_id = $1 AND sensor = $2 \
                     ORDER BY t DESC LIMIT 1",
                    &[&machine_id, &(sensor as i16)],
                )
                .await?
                .map(|row| row.get(0)))
        })
    }

    /// A machine's estimates of one stream in `[from_t, to_t]`, downsampled
    /// above `max_points` as on SQLite ([`history::estimates_page`]).
    pub fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        let client = self.reader()?;
        let mut source = PgHistory {
            runtime: &self.runtime,
            client: &client,
            machine_id,
            engine,
        };
        history::estimates_page(&mut source, from_t, to_t, max_points)
    }

    /// Calls `f` with each stored reading of the machine in `[from_t, to_t]`
    /// (of one sensor, or all), in time order, a batch read at a time;
    /// stops early when `f` returns false.
    pub fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        let sensor = sensor.map(|s| s as i16);
        // Resume after the last (t, id) sent: within a time, the order
        // the readings were stored in (arrival).
        let mut after: (f64, i64) = (f64::NEG_INFINITY, -1);
        loop {
            // A connection per batch: a slow reader holds none between them.
            let client = self.reader()?;
            let rows = self.runtime.block_on(client.query(
                "SELECT t, sensor, body, id FROM readings WHERE machine_id = $1 AND t >= $2 \
                 AND t <= $3 AND ($4::int2 IS NULL OR sensor = $4) AND t >= $5 AND (t, id) > ($5, $6) \
                 ORDER BY t, id LIMIT $7",
                &[
                    &machine_id,
                    &from_t,
                    &to_t,
                    &sensor,
                    &after.0,
                    &after.1,
                    &EXPORT_BATCH,
                ],
            ))?;
            drop(client);
            for row in &rows {
                after = (row.get(0), row.get(3));
                if !f(&reading(row.get(0), row.get(1), row.get(2))?) {
                    return Ok(());
                }
            }
            if (rows.len() as i64) < EXPORT_BATCH {
                return Ok(());
            }
        }
    }

    /// Every stored estimate of `engine` in `[from_t, to_t]`, in time
    /// order, to `f` until it answers false (blocking).
    pub fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError> {
        let mut after = f64::NEG_INFINITY;
        loop {
            let client = self.reader()?;
            let rows = self.runtime.block_on(client.query(
                "SELECT t, body, codec FROM estimates WHERE machine_id = $1 AND engine = $2 \
                 AND t >= $3 AND t <= $4 AND t > $5 ORDER BY t LIMIT $6",
                &[
                    &machine_id,
                    &engine.as_str(),
                    &from_t,
                    &to_t,
                    &after,
                    &EXPORT_BATCH,
                ],
            ))?;
            drop(client);
            for row in &rows {
                let estimate = output(engine, row)?;
                after = estimate.t;
                if !f(&estimate) {
                    return Ok(());
                }
            }
            if (rows.len() as i64) < EXPORT_BATCH {
                return Ok(());
            }
        }
    }
}

/// Rows an export reads per query.
const EXPORT_BATCH: i64 = 5000;

/// One machine's estimates of one stream in PostgreSQL; each query blocks
/// on the store's runtime (history reads run on blocking threads).
struct PgHistory<'a> {
    runtime: &'a tokio::runtime::Handle,
    client: &'a deadpool_postgres::Client,
    machine_id: i64,
    engine: StreamKind,
}

impl PgHistory<'_> {
    fn query(
        &self,
        sql: &str,
        params: &[&(dyn tokio_postgres::types::ToSql + Sync)],
    ) -> Result<Vec<tokio_postgres::Row>, StoreError> {
        Ok(self.runtime.block_on(self.client.query(sql, params))?)
    }
}

impl HistorySource for PgHistory<'_> {
    fn count_upto(&mut self, from_t: f64, to_t: f64, limit: i64) -> Result<i64, StoreError> {
        let rows = self.query(
            "SELECT count(*) FROM (SELECT 1 FROM estimates \
             WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t <= $4 LIMIT $5) AS upto",
            &[
                &self.machine_id,
                &self.engine.as_str(),
                &from_t,
                &to_t,
                &limit,
            ],
        )?;
        Ok(rows.first().map_or(0, |row| row.get(0)))
    }

    fn all(&mut self, from_t: f64, to_t: f64) -> Result<Vec<EngineOutput>, StoreError> {
        self.query(
            "SELECT t, body, codec FROM estimates \
             WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t <= $4 ORDER BY t",
            &[&self.machine_id, &self.engine.as_str(), &from_t, &to_t],
        )?
        .iter()
        .map(|row| output(self.engine, row))
        .collect()
    }

    fn end(&mut self, from_t: f64, to_t: f64, last: bool) -> Result<f64, StoreError> {
        let order = if last { "DESC" } else { "ASC" };
        let rows = self.query(
            &format!(
                "SELECT t FROM estimates WHERE machine_id = $1 AND engine = $2 \
                 AND t >= $3 AND t <= $4 ORDER BY t {order} LIMIT 1"
            ),
            &[&self.machine_id, &self.engine.as_str(), &from_t, &to_t],
        )?;
        rows.first()
            .map(|row| row.get(0))
            .ok_or_else(|| StoreError::Corrupt("estimates counted but not found".into()))
    }

    fn points(
        &mut self,
        lo: f64,
        hi: f64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError> {
        for row in self.query(
            "SELECT t, extreme_a, extreme_b FROM estimates \
             WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t < $4",
            &[&self.machine_id, &self.engine.as_str(), &lo, &hi],
        )? {
            out(Extremes::point(row.get(0), [row.get(1), row.get(2)]));
        }
        Ok(())
    }

    fn buckets(
        &mut self,
        width_s: i64,
        first: i64,
        end: i64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError> {
        for row in self.query(
            "SELECT min_a, t_min_a, max_a, t_max_a, min_b, t_min_b, max_b, t_max_b \
             FROM estimate_buckets WHERE machine_id = $1 AND engine = $2 \
             AND width_s = $3 AND bucket >= $4 AND bucket < $5",
            &[
                &self.machine_id,
                &self.engine.as_str(),
                &width_s,
                &first,
                &end,
            ],
        )? {
            out(Extremes {
                min_a: (row.get(0), row.get(1)),
                max_a: (row.get(2), row.get(3)),
                min_b: (row.get(4), row.get(5)),
                max_b: (row.get(6), row.get(7)),
            });
        }
        Ok(())
    }

    fn at(&mut self, t: f64) -> Result<Option<EngineOutput>, StoreError> {
        self.query(
            "SELECT t, body, codec FROM estimates WHERE machine_id = $1 AND engine = $2 AND t = $3",
            &[&self.machine_id, &self.engine.as_str(), &t],
        )?
        .first()
        .map(|row| output(self.engine, row))
        .transpose()
    }
}

/// A stored reading's row.
pub(super) fn reading(t: f64, sensor: i16, body: Vec<u8>) -> Result<Reading, StoreError> {
    let sensor = usize::try_from(sensor)
        .ok()
        .and_then(|i| SensorKind::ALL.get(i).copied())
        .ok_or_else(|| StoreError::Corrupt(format!("sensor number {sensor}")))?;
    codec::decode_reading(t, sensor, &body)
}

/// A stored estimate's row (`t`, `body`, `codec`).
fn output(engine: StreamKind, row: &tokio_postgres::Row) -> Result<EngineOutput, StoreError> {
    let body: Vec<u8> = row.get(1);
    let codec: i32 = row.get(2);
    codec::decode_output(engine, row.get(0), codec as u32, &body)
}
