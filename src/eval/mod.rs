//! Scoring engines against simulated truth and against recorded trials
//! with optical truth (`recording`).

pub mod ahrs;
pub mod attitude;
pub mod dta;
pub mod dta_ins;
pub mod fuzzy;
pub mod fuzzy_envelope;
pub mod integrity;
pub mod kf3;
pub mod recording;
pub mod rings;
pub mod zupt;
pub mod zupt_envelope;

use serde::Serialize;

/// Running error statistics: RMS and largest absolute error.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ErrorStats {
    pub count: u64,
    pub sum_sq: f64,
    pub max_abs: f64,
}

impl ErrorStats {
    /// Adds one error.
    pub fn add(&mut self, error: f64) {
        self.count += 1;
        self.sum_sq += error * error;
        self.max_abs = self.max_abs.max(error.abs());
    }

    /// Root mean square of the errors (0 when there are none).
    pub fn rmse(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            (self.sum_sq / self.count as f64).sqrt()
        }
    }
}

/// The largest absolute error over several error statistics.
pub fn largest_abs(stats: &[&ErrorStats]) -> f64 {
    stats.iter().map(|s| s.max_abs).fold(0.0, f64::max)
}

/// The median of `values` (the upper one of an even count; NaN if empty).
pub fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

/// |estimate − truth| of two headings, degrees, the short way round.
pub fn heading_error_deg(estimate_deg: f64, truth_deg: f64) -> f64 {
    ((estimate_deg - truth_deg + 540.0).rem_euclid(360.0) - 180.0).abs()
}

/// `f` over `items` on up to `threads` threads; results in input order.
pub fn parallel_map<T: Sync, R: Send>(
    items: &[T],
    threads: usize,
    f: impl Fn(&T) -> R + Sync,
) -> Vec<R> {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<R>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, items.len().max(1)) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(i) else {
                        break;
                    };
                    let result = f(item);
                    if let Ok(mut slots) = results.lock() {
                        slots[i] = Some(result);
                    }
                }
            });
        }
    });
    // Every slot is filled: each index is taken by exactly one thread.
    results
        .into_inner()
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .collect()
}

/// One bar of an issue, what was measured and whether it holds: the
/// envelope evaluations print every bar, met or not.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Bar {
    pub bar: String,
    pub measured: String,
    pub met: bool,
}

impl Bar {
    /// `met     bar: measured` or `NOT MET bar: measured`, one line each.
    pub fn render_all(bars: &[Bar], out: &mut String) {
        for b in bars {
            out.push_str(if b.met { "met    " } else { "NOT MET" });
            out.push(' ');
            out.push_str(&b.bar);
            out.push_str(": ");
            out.push_str(&b.measured);
            out.push('\n');
        }
    }
}
