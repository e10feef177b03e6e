//! Retention in memory: the shared plan ([`plan_steps`]) and its steps
//! done on the rows.

use tunnelnav::fusion::StreamKind;
use tunnelnav::store::StoreError;
use tunnelnav::store::retention::{Pruned, Retention, Step, THIN_TO_S, plan_steps};

use super::rows::{Rows, Time};

/// The steps of a pass of `policy` at `now_t`.
pub fn plan(
    rows: &Rows,
    now_t: f64,
    policy: &Retention,
    batch: usize,
) -> Result<Vec<Step>, StoreError> {
    let machines: Vec<i64> = rows.machines.values().map(|m| m.id).collect();
    plan_steps(now_t, policy, batch, &machines, |machine, stream| {
        Ok(rows
            .estimates
            .get(&(machine, stream.as_str()))
            .and_then(|s| s.first_key_value())
            .map(|(t, _)| t.0))
    })
}

/// Does `step`; what it deleted.
pub fn apply(rows: &mut Rows, step: &Step) -> Pruned {
    match *step {
        Step::Readings { cut, batch } => {
            // Older than the cut and covered by the machine's snapshot,
            // the oldest arrivals first.
            let covered: Vec<i64> = rows
                .readings
                .iter()
                .filter(|&(&id, r)| {
                    r.t < cut
                        && rows
                            .machines
                            .values()
                            .any(|m| m.id == r.machine_id && id <= m.snapshot.last_reading_id)
                })
                .map(|(&id, _)| id)
                .take(batch)
                .collect();
            for &id in &covered {
                rows.delete_reading(id);
            }
            Pruned {
                readings: covered.len() as u64,
                estimates: 0,
            }
        }
        Step::Thin {
            machine,
            stream,
            from,
            to,
        } => Pruned {
            readings: 0,
            estimates: thin(rows, machine, stream, from, to),
        },
    }
}

/// Keeps the first estimate of each [`THIN_TO_S`] in `[from, to)`; how
/// many were deleted.
fn thin(rows: &mut Rows, machine: i64, stream: StreamKind, from: f64, to: f64) -> u64 {
    let Some(estimates) = rows.estimates.get_mut(&(machine, stream.as_str())) else {
        return 0;
    };
    if from >= to {
        return 0;
    }
    let mut kept_slot = None;
    let mut doomed = Vec::new();
    for (t, _) in estimates.range(Time::of(from)..Time::of(to)) {
        // SQLite's CAST(t / 60 AS INTEGER): toward zero.
        let slot = (t.0 / THIN_TO_S).trunc() as i64;
        if kept_slot == Some(slot) {
            doomed.push(*t);
        } else {
            kept_slot = Some(slot);
        }
    }
    for t in &doomed {
        estimates.remove(t);
    }
    doomed.len() as u64
}
