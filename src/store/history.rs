//! History downsampling, the same on every backend: a backend answers
//! [`HistorySource`]'s few questions in its own query language and
//! [`estimates_page`] does the rest.

use super::error::StoreError;
use crate::fusion::EngineOutput;

/// Estimates of a time range, possibly downsampled.
#[derive(Debug, Clone, Default)]
pub struct EstimatesPage {
    pub downsampled: bool,
    /// The estimates, in time order.
    pub estimates: Vec<EngineOutput>,
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
pub trait HistorySource {
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
pub fn estimates_page(
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
