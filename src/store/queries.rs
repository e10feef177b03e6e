//! History reads: estimates with downsampling, raw readings streamed.

use rusqlite::{OptionalExtension, params};

use super::codec::{decode_output, decode_reading};
use super::{SqliteStore, StoreError};
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

/// Estimates of a time range, possibly downsampled.
#[derive(Debug, Clone, Default)]
pub struct EstimatesPage {
    pub downsampled: bool,
    /// The estimates, in time order.
    pub estimates: Vec<EngineOutput>,
}

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

/// Widths of the stored extreme buckets (`estimate_buckets`), seconds.
/// A query uses the widest one no wider than its own buckets.
pub const BUCKET_WIDTHS_S: [i64; 3] = [60, 900, 14400];

/// Estimates a bucket contributes at most: the estimates holding the
/// minimum and maximum of each of the two kept quantities.
pub const POINTS_PER_BUCKET: usize = 4;

/// The extremes of one bucket: (value, time) of min and max of `a` and `b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extremes {
    pub min_a: (f64, f64),
    pub max_a: (f64, f64),
    pub min_b: (f64, f64),
    pub max_b: (f64, f64),
}

impl Extremes {
    /// One estimate's values at `t`.
    pub fn point(t: f64, [a, b]: [f64; 2]) -> Extremes {
        Extremes {
            min_a: (a, t),
            max_a: (a, t),
            min_b: (b, t),
            max_b: (b, t),
        }
    }

    /// No estimate yet: every extreme unset (time NaN).
    const EMPTY: Extremes = Extremes {
        min_a: (f64::INFINITY, f64::NAN),
        max_a: (f64::NEG_INFINITY, f64::NAN),
        min_b: (f64::INFINITY, f64::NAN),
        max_b: (f64::NEG_INFINITY, f64::NAN),
    };

    /// Folds another bucket's extremes in (ties keep the earlier).
    pub fn merge(&mut self, other: &Extremes) {
        self.min_a = lower(self.min_a, other.min_a);
        self.max_a = higher(self.max_a, other.max_a);
        self.min_b = lower(self.min_b, other.min_b);
        self.max_b = higher(self.max_b, other.max_b);
    }

    fn times(&self) -> [f64; 4] {
        [self.min_a.1, self.max_a.1, self.min_b.1, self.max_b.1]
    }
}

/// The lower of two (value, time) pairs; the first on a tie.
fn lower(x: (f64, f64), y: (f64, f64)) -> (f64, f64) {
    if y.0 < x.0 { y } else { x }
}

/// The higher of two (value, time) pairs; the first on a tie.
fn higher(x: (f64, f64), y: (f64, f64)) -> (f64, f64) {
    if y.0 > x.0 { y } else { x }
}

/// The output buckets of a downsampled query.
struct Downsample {
    first_t: f64,
    width_s: f64,
    buckets: Vec<Option<Extremes>>,
}

impl Downsample {
    /// Files each extreme under the output bucket its own time falls in.
    fn offer(&mut self, extremes: &Extremes) {
        let last = self.buckets.len() - 1;
        let index = |t: f64| (((t - self.first_t) / self.width_s).max(0.0) as usize).min(last);
        type Fold = fn(&mut Extremes, (f64, f64));
        let parts: [((f64, f64), Fold); 4] = [
            (extremes.min_a, |b: &mut Extremes, x| {
                b.min_a = lower(b.min_a, x)
            }),
            (extremes.max_a, |b: &mut Extremes, x| {
                b.max_a = higher(b.max_a, x)
            }),
            (extremes.min_b, |b: &mut Extremes, x| {
                b.min_b = lower(b.min_b, x)
            }),
            (extremes.max_b, |b: &mut Extremes, x| {
                b.max_b = higher(b.max_b, x)
            }),
        ];
        for (extreme, fold) in parts {
            let bucket = self.buckets[index(extreme.1)].get_or_insert(Extremes::EMPTY);
            fold(bucket, extreme);
        }
    }

    /// The times to return: every bucket's extremes, in order, once each.
    fn times(&self) -> Vec<f64> {
        let mut keep: Vec<f64> = self
            .buckets
            .iter()
            .flatten()
            .flat_map(|b| b.times())
            .filter(|t| !t.is_nan())
            .collect();
        keep.sort_by(f64::total_cmp);
        keep.dedup();
        keep
    }
}

/// What [`estimates_page`] reads, of one machine's estimates of one stream
/// (each store answers in its own SQL).
pub(super) trait HistorySource {
    /// How many estimates in `[from_t, to_t]`, counting no further than `limit`.
    fn count_upto(&mut self, from_t: f64, to_t: f64, limit: i64) -> Result<i64, StoreError>;
    /// Every estimate in `[from_t, to_t]`, in time order.
    fn all(&mut self, from_t: f64, to_t: f64) -> Result<Vec<EngineOutput>, StoreError>;
    /// The first (or last) estimate's time in `[from_t, to_t]`.
    fn end(&mut self, from_t: f64, to_t: f64, last: bool) -> Result<f64, StoreError>;
    /// Each estimate's kept quantities in `[lo, hi)`, as points.
    fn points(&mut self, lo: f64, hi: f64, out: &mut dyn FnMut(Extremes))
    -> Result<(), StoreError>;
    /// The stored extreme buckets of width `width_s`, `first..end`.
    fn buckets(
        &mut self,
        width_s: i64,
        first: i64,
        end: i64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError>;
    /// The estimate at `t`.
    fn at(&mut self, t: f64) -> Result<Option<EngineOutput>, StoreError>;
}

/// A machine's estimates of one stream in `[from_t, to_t]`. Above
/// `max_points` the range is cut into `max_points / 4` equal buckets and
/// each keeps the estimates holding the minimum and maximum of the
/// engine's two kept quantities (attitude: pitch, roll), so spikes stay
/// visible. Long ranges read the stored extreme buckets
/// ([`BUCKET_WIDTHS_S`]) instead of every estimate; an extreme is then
/// filed under the output bucket of its own time, so a stored bucket
/// straddling two output buckets can hide the lesser extreme of one of
/// them, never the range's own extremes.
pub(super) fn estimates_page(
    source: &mut impl HistorySource,
    from_t: f64,
    to_t: f64,
    max_points: usize,
) -> Result<EstimatesPage, StoreError> {
    let mut page = EstimatesPage::default();
    // Count no further than needed to know whether to downsample.
    if source.count_upto(from_t, to_t, max_points as i64 + 1)? <= max_points as i64 {
        page.estimates = source.all(from_t, to_t)?;
        return Ok(page);
    }
    page.downsampled = true;
    let (first_t, last_t) = (
        source.end(from_t, to_t, false)?,
        source.end(from_t, to_t, true)?,
    );
    let buckets = (max_points / POINTS_PER_BUCKET).max(1);
    let width_s = ((last_t - first_t) / buckets as f64).max(f64::MIN_POSITIVE);
    let mut out = Downsample {
        first_t,
        width_s,
        buckets: vec![None; buckets],
    };
    let stored_width = BUCKET_WIDTHS_S
        .iter()
        .rev()
        .copied()
        .find(|&w| w as f64 <= width_s);
    let after_last = f64::from_bits(last_t.to_bits() + 1);
    let mut offer = |e: Extremes| out.offer(&e);
    match stored_width {
        None => source.points(first_t, after_last, &mut offer)?,
        Some(w) => {
            // Whole stored buckets inside the range; raw at the edges.
            let first_bucket = (first_t / w as f64).ceil() as i64;
            let end_bucket = (after_last / w as f64).floor() as i64;
            if first_bucket >= end_bucket {
                source.points(first_t, after_last, &mut offer)?;
            } else {
                source.points(first_t, (first_bucket * w) as f64, &mut offer)?;
                source.buckets(w, first_bucket, end_bucket, &mut offer)?;
                source.points((end_bucket * w) as f64, after_last, &mut offer)?;
            }
        }
    }
    for t in out.times() {
        let estimate = source.at(t)?.ok_or_else(|| {
            StoreError::Corrupt(format!("bucket extreme at t = {t} has no estimate"))
        })?;
        page.estimates.push(estimate);
    }
    Ok(page)
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
