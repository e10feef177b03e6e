//! History in memory: [`HistorySource`]'s questions answered from the
//! rows, the downsampling left to the store's shared
//! [`tunnelnav::store::history::estimates_page`].

use tunnelnav::fusion::{EngineOutput, StreamKind};
use tunnelnav::store::codec::decode_output;
use tunnelnav::store::history::HistorySource;
use tunnelnav::store::{Extremes, StoreError};

use super::rows::{Rows, StoredEstimate, Time};

/// One machine's estimates of one stream.
pub struct MemoryHistory<'r> {
    pub rows: &'r Rows,
    pub machine_id: i64,
    pub engine: StreamKind,
}

impl MemoryHistory<'_> {
    /// The stream's estimates with `lo <= t` and `t < hi` (or `t <= hi`
    /// with `inclusive`), in time order.
    fn range(
        &self,
        lo: f64,
        hi: f64,
        inclusive: bool,
    ) -> impl Iterator<Item = (f64, &StoredEstimate)> {
        self.rows
            .estimates
            .get(&(self.machine_id, self.engine.as_str()))
            .into_iter()
            .flat_map(move |stream| {
                let end = if inclusive {
                    std::ops::Bound::Included(Time::of(hi))
                } else {
                    std::ops::Bound::Excluded(Time::of(hi))
                };
                // An empty range for lo > hi (BTreeMap::range panics on it).
                let (lo, end) = if lo > hi {
                    (Time::of(hi), std::ops::Bound::Excluded(Time::of(hi)))
                } else {
                    (Time::of(lo), end)
                };
                stream.range((std::ops::Bound::Included(lo), end))
            })
            .map(|(t, e)| (t.0, e))
    }

    fn decode(&self, t: f64, estimate: &StoredEstimate) -> Result<EngineOutput, StoreError> {
        decode_output(self.engine, t, estimate.codec, &estimate.values)
    }
}

impl HistorySource for MemoryHistory<'_> {
    fn count_upto(&mut self, from_t: f64, to_t: f64, limit: i64) -> Result<i64, StoreError> {
        let limit = usize::try_from(limit).unwrap_or(0);
        Ok(self.range(from_t, to_t, true).take(limit).count() as i64)
    }

    fn all(&mut self, from_t: f64, to_t: f64) -> Result<Vec<EngineOutput>, StoreError> {
        self.range(from_t, to_t, true)
            .map(|(t, e)| self.decode(t, e))
            .collect()
    }

    fn end(&mut self, from_t: f64, to_t: f64, last: bool) -> Result<f64, StoreError> {
        let mut times = self.range(from_t, to_t, true).map(|(t, _)| t);
        let found = if last { times.last() } else { times.next() };
        found.ok_or_else(|| StoreError::Corrupt(format!("no estimate in [{from_t}, {to_t}]")))
    }

    fn points(
        &mut self,
        lo: f64,
        hi: f64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError> {
        for (t, e) in self.range(lo, hi, false) {
            out(Extremes::point(t, e.extremes));
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
        if first >= end {
            return Ok(());
        }
        let engine = self.engine.as_str();
        let lo = (self.machine_id, engine, width_s, first);
        let hi = (self.machine_id, engine, width_s, end);
        for extremes in self.rows.buckets.range(lo..hi).map(|(_, e)| e) {
            out(*extremes);
        }
        Ok(())
    }

    fn at(&mut self, t: f64) -> Result<Option<EngineOutput>, StoreError> {
        self.range(t, t, true)
            .next()
            .map(|(t, e)| self.decode(t, e))
            .transpose()
    }
}
