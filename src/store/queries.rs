//! History reads: estimates with downsampling, raw readings streamed.

use rusqlite::{OptionalExtension, params};

use super::{Store, StoreError};
use crate::fusion::{EngineKind, SensorKind};

/// Estimates of a time range, possibly downsampled.
#[derive(Debug, Clone, Default)]
pub struct EstimatesPage {
    pub downsampled: bool,
    /// Protocol JSON of each estimate, in time order.
    pub bodies: Vec<String>,
}

/// Per bucket, the times of the estimates holding each extreme.
#[derive(Clone, Copy)]
struct Bucket {
    min_a: (f64, f64),
    max_a: (f64, f64),
    min_b: (f64, f64),
    max_b: (f64, f64),
}

impl Bucket {
    fn new(t: f64, a: f64, b: f64) -> Bucket {
        Bucket {
            min_a: (a, t),
            max_a: (a, t),
            min_b: (b, t),
            max_b: (b, t),
        }
    }

    fn add(&mut self, t: f64, a: f64, b: f64) {
        if a < self.min_a.0 {
            self.min_a = (a, t);
        }
        if a > self.max_a.0 {
            self.max_a = (a, t);
        }
        if b < self.min_b.0 {
            self.min_b = (b, t);
        }
        if b > self.max_b.0 {
            self.max_b = (b, t);
        }
    }

    fn times(&self) -> [f64; 4] {
        [self.min_a.1, self.max_a.1, self.min_b.1, self.max_b.1]
    }
}

/// Estimates a bucket contributes at most: the estimates holding the
/// minimum and maximum of each of the two kept quantities.
pub const POINTS_PER_BUCKET: usize = 4;

impl Store {
    /// A machine's estimates of one engine in `[from_t, to_t]`. Above
    /// `max_points` the range is cut into `max_points / 4` equal buckets and
    /// each keeps the estimates holding its extremes, so spikes stay visible.
    pub fn estimates_page(
        &self,
        machine_id: i64,
        engine: EngineKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        self.read(|conn| {
            let range = params![machine_id, engine.as_str(), from_t, to_t];
            let (count, first_t, last_t): (i64, Option<f64>, Option<f64>) = conn
                .prepare_cached(
                    "SELECT count(*), min(t), max(t) FROM estimates \
                     WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t <= ?4",
                )?
                .query_row(range, |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)))?;
            let mut page = EstimatesPage::default();
            if count <= max_points as i64 {
                let mut stmt = conn.prepare_cached(
                    "SELECT body FROM estimates \
                     WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t <= ?4 ORDER BY t",
                )?;
                let rows = stmt.query_map(range, |row| row.get(0))?;
                for body in rows {
                    page.bodies.push(body?);
                }
                return Ok(page);
            }
            page.downsampled = true;
            let (first_t, last_t) = (first_t.unwrap_or(from_t), last_t.unwrap_or(to_t));
            let buckets = (max_points / POINTS_PER_BUCKET).max(1);
            let width = ((last_t - first_t) / buckets as f64).max(f64::MIN_POSITIVE);
            let mut stmt = conn.prepare_cached(
                "SELECT t, extreme_a, extreme_b FROM estimates \
                 WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t <= ?4 ORDER BY t",
            )?;
            let mut rows = stmt.query(range)?;
            let mut current: Option<(usize, Bucket)> = None;
            let mut keep: Vec<f64> = Vec::with_capacity(max_points);
            while let Some(row) = rows.next()? {
                let (t, a, b): (f64, f64, f64) = (row.get(0)?, row.get(1)?, row.get(2)?);
                let index = (((t - first_t) / width) as usize).min(buckets - 1);
                match &mut current {
                    Some((i, bucket)) if *i == index => bucket.add(t, a, b),
                    _ => {
                        if let Some((_, bucket)) = current.take() {
                            keep.extend(bucket.times());
                        }
                        current = Some((index, Bucket::new(t, a, b)));
                    }
                }
            }
            if let Some((_, bucket)) = current {
                keep.extend(bucket.times());
            }
            keep.sort_by(f64::total_cmp);
            keep.dedup();
            let mut stmt = conn.prepare_cached(
                "SELECT body FROM estimates WHERE machine_id = ?1 AND engine = ?2 AND t = ?3",
            )?;
            for t in keep {
                page.bodies.push(
                    stmt.query_row(params![machine_id, engine.as_str(), t], |row| row.get(0))?,
                );
            }
            Ok(page)
        })
    }

    /// Calls `f` with each stored reading of the machine in `[from_t, to_t]`
    /// (of one sensor, or all), in time order, one row at a time; stops
    /// early when `f` returns false.
    pub fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&str) -> bool,
    ) -> Result<(), StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT body FROM readings WHERE machine_id = ?1 AND t >= ?2 AND t <= ?3 \
                 AND (?4 IS NULL OR sensor = ?4) ORDER BY t, sensor",
            )?;
            let mut rows =
                stmt.query(params![machine_id, from_t, to_t, sensor.map(|s| s as i64)])?;
            while let Some(row) = rows.next()? {
                let body = row.get_ref(0)?.as_str().map_err(rusqlite::Error::from)?;
                if !f(body) {
                    break;
                }
            }
            Ok(())
        })
    }
}

impl Store {
    /// The newest stored estimate of an engine: its time and JSON.
    pub fn latest_estimate(
        &self,
        machine_id: i64,
        engine: EngineKind,
    ) -> Result<Option<String>, StoreError> {
        self.read(|conn| {
            Ok(conn
                .prepare_cached(
                    "SELECT body FROM estimates WHERE machine_id = ?1 AND engine = ?2 \
                     ORDER BY t DESC LIMIT 1",
                )?
                .query_row(params![machine_id, engine.as_str()], |row| row.get(0))
                .optional()?)
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
