//! History reads: estimates with downsampling, raw readings streamed.

use rusqlite::{OptionalExtension, params};

use super::handle::SqliteStore;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};
use crate::store::codec::{decode_output, decode_reading};
use crate::store::error::StoreError;
use crate::store::history::{EstimatesPage, Extremes, HistorySource, estimates_page};

/// Decodes a `(t, sensor, body)` row of `readings`.
pub(super) fn reading_row(row: &rusqlite::Row) -> Result<Reading, StoreError> {
    let sensor_index: i64 = row.get(1)?;
    let sensor = usize::try_from(sensor_index)
        .ok()
        .and_then(|i| SensorKind::ALL.get(i).copied())
        .ok_or_else(|| StoreError::Corrupt(format!("stored sensor number {sensor_index}")))?;
    let bytes = row.get_ref(2)?.as_blob().map_err(rusqlite::Error::from)?;
    decode_reading(row.get(0)?, sensor, bytes)
}

/// Decodes a `(t, body, codec)` row of `estimates`.
fn output_row(engine: StreamKind, row: &rusqlite::Row) -> Result<EngineOutput, StoreError> {
    let bytes = row.get_ref(1)?.as_blob().map_err(rusqlite::Error::from)?;
    decode_output(engine, row.get(0)?, row.get(2)?, bytes)
}

/// One machine's estimates of one stream in the SQLite store.
struct SqliteHistory<'c> {
    conn: &'c rusqlite::Connection,
    machine_id: i64,
    engine: StreamKind,
}

impl HistorySource for SqliteHistory<'_> {
    fn count_upto(&mut self, from_t: f64, to_t: f64, limit: i64) -> Result<i64, StoreError> {
        Ok(self
            .conn
            .prepare_cached(
                "SELECT count(*) FROM (SELECT 1 FROM estimates \
                 WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t <= ?4 LIMIT ?5)",
            )?
            .query_row(
                params![self.machine_id, self.engine.as_str(), from_t, to_t, limit],
                |row| row.get(0),
            )?)
    }

    fn all(&mut self, from_t: f64, to_t: f64) -> Result<Vec<EngineOutput>, StoreError> {
        let mut stmt = self.conn.prepare_cached(
            "SELECT t, body, codec FROM estimates \
             WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t <= ?4 ORDER BY t",
        )?;
        let mut rows = stmt.query(params![self.machine_id, self.engine.as_str(), from_t, to_t])?;
        let mut out = Vec::new();
        while let Some(row) = rows.next()? {
            out.push(output_row(self.engine, row)?);
        }
        Ok(out)
    }

    fn end(&mut self, from_t: f64, to_t: f64, last: bool) -> Result<f64, StoreError> {
        let order = if last { "DESC" } else { "ASC" };
        Ok(self
            .conn
            .prepare_cached(&format!(
                "SELECT t FROM estimates WHERE machine_id = ?1 AND engine = ?2 \
                 AND t >= ?3 AND t <= ?4 ORDER BY t {order} LIMIT 1"
            ))?
            .query_row(
                params![self.machine_id, self.engine.as_str(), from_t, to_t],
                |row| row.get(0),
            )?)
    }

    fn points(
        &mut self,
        lo: f64,
        hi: f64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError> {
        let mut stmt = self.conn.prepare_cached(
            "SELECT t, extreme_a, extreme_b FROM estimates \
             WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t < ?4",
        )?;
        let mut rows = stmt.query(params![self.machine_id, self.engine.as_str(), lo, hi])?;
        while let Some(row) = rows.next()? {
            out(Extremes::point(row.get(0)?, [row.get(1)?, row.get(2)?]));
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
        let mut stmt = self.conn.prepare_cached(
            "SELECT min_a, t_min_a, max_a, t_max_a, min_b, t_min_b, max_b, t_max_b \
             FROM estimate_buckets WHERE machine_id = ?1 AND engine = ?2 \
             AND width_s = ?3 AND bucket >= ?4 AND bucket < ?5",
        )?;
        let mut rows = stmt.query(params![
            self.machine_id,
            self.engine.as_str(),
            width_s,
            first,
            end
        ])?;
        while let Some(row) = rows.next()? {
            out(Extremes {
                min_a: (row.get(0)?, row.get(1)?),
                max_a: (row.get(2)?, row.get(3)?),
                min_b: (row.get(4)?, row.get(5)?),
                max_b: (row.get(6)?, row.get(7)?),
            });
        }
        Ok(())
    }

    fn at(&mut self, t: f64) -> Result<Option<EngineOutput>, StoreError> {
        let mut stmt = self.conn.prepare_cached(
            "SELECT t, body, codec FROM estimates WHERE machine_id = ?1 AND engine = ?2 AND t = ?3",
        )?;
        let mut rows = stmt.query(params![self.machine_id, self.engine.as_str(), t])?;
        rows.next()?
            .map(|row| output_row(self.engine, row))
            .transpose()
    }
}

impl SqliteStore {
    /// A machine's estimates of one engine in `[from_t, to_t]`, downsampled
    /// above `max_points` (see [`estimates_page`]).
    pub fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        self.read(|conn| {
            let mut source = SqliteHistory {
                conn,
                machine_id,
                engine,
            };
            estimates_page(&mut source, from_t, to_t, max_points)
        })
    }

    /// Calls `f` with each stored reading of the machine in `[from_t, to_t]`
    /// (of one sensor, or all), in time order and, within a time, in the
    /// order they were stored (arrival), one row at a time; stops early
    /// when `f` returns false.
    pub fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT t, sensor, body FROM readings WHERE machine_id = ?1 AND t >= ?2 AND t <= ?3 \
                 AND (?4 IS NULL OR sensor = ?4) ORDER BY t, id",
            )?;
            let mut rows =
                stmt.query(params![machine_id, from_t, to_t, sensor.map(|s| s as i64)])?;
            while let Some(row) = rows.next()? {
                if !f(&reading_row(row)?) {
                    break;
                }
            }
            Ok(())
        })
    }
}

impl SqliteStore {
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
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT t, body, codec FROM estimates \
                 WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t <= ?4 ORDER BY t",
            )?;
            let mut rows = stmt.query(params![machine_id, engine.as_str(), from_t, to_t])?;
            while let Some(row) = rows.next()? {
                if !f(&output_row(engine, row)?) {
                    break;
                }
            }
            Ok(())
        })
    }

    /// The newest stored estimate of an engine.
    pub fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT t, body, codec FROM estimates WHERE machine_id = ?1 AND engine = ?2 \
                 ORDER BY t DESC LIMIT 1",
            )?;
            let mut rows = stmt.query(params![machine_id, engine.as_str()])?;
            rows.next()?.map(|row| output_row(engine, row)).transpose()
        })
    }

    /// Time of the newest stored reading of a sensor.
    pub fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        self.read(|conn| {
            Ok(conn
                .prepare_cached(
                    "SELECT t FROM readings WHERE machine_id = ?1 AND sensor = ?2 \
                     ORDER BY t DESC LIMIT 1",
                )?
                .query_row(params![machine_id, sensor as i64], |row| row.get(0))
                .optional()?)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineDeclaration;
    use crate::fusion::{AttitudeEstimate, EstimateValues};
    use crate::store::Store;
    use crate::store::{EstimateRow, Write};

    /// Stores `n` estimates at 1 Hz with values from `f`; returns the store.
    async fn store_with(
        dir: &std::path::Path,
        n: usize,
        f: impl Fn(usize) -> [f64; 2],
    ) -> (Store, i64) {
        let store = Store::open(dir).unwrap();
        let spec = serde_json::from_value::<MachineDeclaration>(
            serde_json::json!({"engines": {"attitude": {}}}),
        )
        .unwrap()
        .validate("m")
        .unwrap();
        let id = store.put_machine(spec, "{}".into()).await.unwrap();
        for chunk in (0..n).collect::<Vec<_>>().chunks(997) {
            let (reply, answer) = tokio::sync::oneshot::channel();
            let estimates = chunk
                .iter()
                .map(|&i| {
                    let [pitch_deg, roll_deg] = f(i);
                    EstimateRow::new(&EngineOutput {
                        integrity: crate::fusion::Integrity::OK,
                        t: 1.0e9 + i as f64,
                        values: EstimateValues::Attitude(AttitudeEstimate {
                            pitch_deg,
                            roll_deg,
                            pitch_pred_deg: pitch_deg,
                            roll_pred_deg: roll_deg,
                            pred_t: 1.0e9 + i as f64 + 1.0,
                            pitch_sigma_deg: None,
                            roll_sigma_deg: None,
                            pitch_pred_sigma_deg: None,
                            laser_ok: true,
                            pitch_correction_deg: 0.0,
                            laser_age_s: None,
                            model_version: 0,
                            incl_pitch_deg: pitch_deg,
                            incl_roll_deg: roll_deg,
                        }),
                    })
                })
                .collect();
            store
                .write(Write {
                    machine_id: id,
                    alarms: Vec::new(),
                    readings: Vec::new(),
                    estimates,
                    snapshot: None,
                    after_commit: None,
                    reply: Some(reply),
                    lease_epoch: None,
                    forwarded: None,
                })
                .await
                .unwrap();
            answer.await.unwrap().unwrap();
        }
        (store, id)
    }

    fn times(page: &EstimatesPage) -> Vec<f64> {
        page.estimates.iter().map(|e| e.t).collect()
    }

    #[tokio::test]
    async fn downsampling_keeps_every_bucket_extreme_from_stored_buckets_and_raw_edges() {
        let dir = tempfile::tempdir().unwrap();
        let n = 50_000;
        // A slow wave with a few one-sample spikes.
        let value = |i: usize| {
            let x = (i as f64 * 0.001).sin();
            let spike = if i % 9_973 == 5 { 3.0 } else { 0.0 };
            [x + spike, -x - spike * 0.5]
        };
        let (store, id) = store_with(dir.path(), n, value).await;
        let t0 = 1.0e9;
        // Ranges not aligned to any stored bucket, long and short.
        for (from, to, max_points) in [
            (t0 + 3.5, t0 + 49_990.2, 400),
            (t0 - 100.0, t0 + 1e6, 2000),
            (t0 + 1234.0, t0 + 5678.0, 100),
            (t0 + 20.0, t0 + 420.0, 40),
        ] {
            let page = store
                .estimates_page(id, StreamKind::Attitude, from, to, max_points)
                .unwrap();
            assert!(page.downsampled);
            let got = times(&page);
            assert!(got.len() <= max_points, "{} > {max_points}", got.len());
            assert!(got.windows(2).all(|w| w[0] < w[1]));
            assert!(got.iter().all(|&t| t >= from && t <= to));
            // The range's own extremes are always there.
            let inside: Vec<usize> = (0..n)
                .filter(|&i| (from..=to).contains(&(t0 + i as f64)))
                .collect();
            for k in 0..2 {
                let by = |i: &&usize| value(**i)[k];
                let min = inside
                    .iter()
                    .min_by(|a, b| by(a).total_cmp(&by(b)))
                    .unwrap();
                let max = inside
                    .iter()
                    .max_by(|a, b| by(a).total_cmp(&by(b)))
                    .unwrap();
                for i in [min, max] {
                    assert!(
                        got.contains(&(t0 + *i as f64)),
                        "extreme at {i} missing in {from}..{to}"
                    );
                }
            }
        }
        // At or under max_points nothing is dropped.
        let page = store
            .estimates_page(id, StreamKind::Attitude, t0, t0 + 99.0, 100)
            .unwrap();
        assert!(!page.downsampled);
        assert_eq!(times(&page).len(), 100);
    }
}
