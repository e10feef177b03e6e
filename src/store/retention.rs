//! Retention: raw readings kept for a number of days, estimates at full
//! rate for a number of days and then thinned to one a minute (the
//! per-bucket extremes stay, so history over old ranges still shows every
//! spike).
//!
//! A pass is planned on a read connection ([`plan`]) and done step by
//! step on the writer's connection between its group commits
//! ([`Step::apply`] through `Store::maintain`): each step a short
//! transaction of at most `batch` rows or one thinning window, so ingest
//! waits for a few milliseconds at a time and nothing else writes.
//! A reading is deleted only if its machine's latest snapshot already
//! covers it: restart re-feeds the readings after the snapshot, and those
//! are never pruned. A gateway resending a pruned reading gets it stored
//! again, as a late reading (stored, not fused).

use rusqlite::{Connection, params};

use super::StoreError;
use crate::fusion::StreamKind;

/// What to keep, and how often the server applies it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Retention {
    /// Raw readings older than this (s, against reading time) are deleted.
    pub keep_readings_s: Option<f64>,
    /// Estimates older than this (s) are thinned to one per minute.
    pub full_estimates_s: Option<f64>,
    /// Seconds between passes.
    pub every_s: f64,
}

impl Default for Retention {
    /// Keep everything; a pass an hour once a policy is set.
    fn default() -> Self {
        Retention {
            keep_readings_s: None,
            full_estimates_s: None,
            every_s: 3600.0,
        }
    }
}

impl Retention {
    /// True when the policy deletes nothing.
    pub fn keeps_everything(&self) -> bool {
        self.keep_readings_s.is_none() && self.full_estimates_s.is_none()
    }
}

/// What a pass deleted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Pruned {
    pub readings: u64,
    pub estimates: u64,
}

/// Width of the windows estimates are thinned in, s.
const THIN_WINDOW_S: f64 = 600.0;
/// One estimate kept per this many seconds.
pub(super) const THIN_TO_S: f64 = 60.0;

/// One unit of a pass, its own short transaction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// Delete up to `batch` readings older than `cut` that their
    /// machine's snapshot covers; again while a full batch went
    /// ([`Step::again`]).
    Readings { cut: f64, batch: usize },
    /// Thin one machine's estimates of one stream in `[from, to)`.
    Thin {
        machine: i64,
        stream: StreamKind,
        from: f64,
        to: f64,
    },
}

/// The steps of a pass of `policy` at `now_t`.
pub fn plan(
    conn: &Connection,
    now_t: f64,
    policy: &Retention,
    batch: usize,
) -> Result<Vec<Step>, StoreError> {
    let machines: Vec<i64> = conn
        .prepare("SELECT id FROM machines")?
        .query_map([], |row| row.get(0))?
        .collect::<Result<_, _>>()?;
    plan_steps(now_t, policy, batch, &machines, |machine, stream| {
        Ok(conn.query_row(
            "SELECT MIN(t) FROM estimates WHERE machine_id = ?1 AND engine = ?2",
            params![machine, stream.as_str()],
            |row| row.get(0),
        )?)
    })
}

/// The steps of a pass of `policy` at `now_t` over `machines`, `oldest`
/// answering the time of a machine's oldest estimate of a stream.
pub(super) fn plan_steps(
    now_t: f64,
    policy: &Retention,
    batch: usize,
    machines: &[i64],
    mut oldest: impl FnMut(i64, StreamKind) -> Result<Option<f64>, StoreError>,
) -> Result<Vec<Step>, StoreError> {
    let mut steps = Vec::new();
    if let Some(keep_s) = policy.keep_readings_s {
        steps.push(Step::Readings {
            cut: now_t - keep_s,
            batch,
        });
    }
    if let Some(full_s) = policy.full_estimates_s {
        let cut = now_t - full_s;
        for &machine in machines {
            for &stream in StreamKind::ALL {
                let Some(oldest) = oldest(machine, stream)? else {
                    continue;
                };
                let mut from = (oldest / THIN_WINDOW_S).floor() * THIN_WINDOW_S;
                while from < cut {
                    let to = (from + THIN_WINDOW_S).min(cut);
                    steps.push(Step::Thin {
                        machine,
                        stream,
                        from,
                        to,
                    });
                    from = to;
                }
            }
        }
    }
    Ok(steps)
}

impl Step {
    /// Does the step; what it deleted.
    pub fn apply(&self, conn: &Connection) -> Result<Pruned, StoreError> {
        match *self {
            Step::Readings { cut, batch } => {
                let readings = conn.execute(
                    "DELETE FROM readings WHERE id IN (
                         SELECT r.id FROM readings r JOIN snapshots s ON s.machine_id = r.machine_id
                         WHERE r.t < ?1 AND r.id <= s.last_reading_id
                         AND NOT EXISTS (SELECT 1 FROM outbox o WHERE o.destination = 'office'
                             AND o.kind = 'readings' AND o.machine_id = r.machine_id
                             AND o.first_reading_id <= r.id)
                         LIMIT ?2)",
                    params![cut, batch as i64],
                )? as u64;
                Ok(Pruned {
                    readings,
                    estimates: 0,
                })
            }
            Step::Thin {
                machine,
                stream,
                from,
                to,
            } => {
                let estimates = conn.execute(
                    "DELETE FROM estimates WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t < ?4
                       AND t NOT IN (
                         SELECT MIN(t) FROM estimates
                         WHERE machine_id = ?1 AND engine = ?2 AND t >= ?3 AND t < ?4
                         GROUP BY CAST(t / ?5 AS INTEGER))",
                    params![machine, stream.as_str(), from, to, THIN_TO_S],
                )? as u64;
                Ok(Pruned {
                    readings: 0,
                    estimates,
                })
            }
        }
    }
}

impl Step {
    /// Whether the step has more to do after deleting `pruned`.
    pub fn again(&self, pruned: &Pruned) -> bool {
        matches!(*self, Step::Readings { batch, .. } if pruned.readings >= batch as u64)
    }
}

/// A whole pass of the policy at `now_t` on one connection (the steps of
/// [`plan`], each applied as often as it has more to do).
pub fn prune(
    conn: &Connection,
    now_t: f64,
    policy: &Retention,
    batch: usize,
) -> Result<Pruned, StoreError> {
    let mut pruned = Pruned::default();
    for step in plan(conn, now_t, policy, batch)? {
        loop {
            let done = step.apply(conn)?;
            pruned.add(done);
            if !step.again(&done) {
                break;
            }
        }
    }
    Ok(pruned)
}

impl Pruned {
    /// Adds what another step deleted.
    pub fn add(&mut self, other: Pruned) {
        self.readings += other.readings;
        self.estimates += other.estimates;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn database() -> Connection {
        let mut conn = Connection::open_in_memory().unwrap();
        super::super::schema::migrate(&mut conn).unwrap();
        conn.execute(
            "INSERT INTO machines (id, machine, spec) VALUES (1, 'm', '{}')",
            [],
        )
        .unwrap();
        // Three hours of 1 Hz readings and estimates from t = 0.
        for i in 0..10_800 {
            let t = f64::from(i);
            conn.execute(
                "INSERT INTO readings (id, machine_id, t, sensor, body) VALUES (?1, 1, ?2, 1, x'00')",
                params![i + 1, t],
            )
            .unwrap();
            conn.execute(
                "INSERT INTO estimates (machine_id, engine, t, extreme_a, extreme_b, body) VALUES (1, 'attitude', ?1, 0, 0, x'00')",
                [t],
            )
            .unwrap();
        }
        conn
    }

    #[test]
    fn readings_go_only_where_the_snapshot_covers_them() {
        let conn = database();
        // The snapshot covers the first hour only.
        conn.execute(
            "INSERT INTO snapshots (machine_id, last_reading_id, state) VALUES (1, 3600, '{}')",
            [],
        )
        .unwrap();
        let policy = Retention {
            keep_readings_s: Some(3600.0),
            ..Retention::default()
        };
        // At t = 3 h, keep 1 h: readings before 2 h may go, but only those
        // the snapshot covers (the first hour).
        let pruned = prune(&conn, 10_800.0, &policy, 1000).unwrap();
        assert_eq!(pruned.readings, 3600);
        let oldest: f64 = conn
            .query_row("SELECT MIN(t) FROM readings", [], |r| r.get(0))
            .unwrap();
        assert_eq!(oldest, 3600.0);
        // Once the snapshot moves on, the second hour goes too.
        conn.execute("UPDATE snapshots SET last_reading_id = 10800", [])
            .unwrap();
        assert_eq!(
            prune(&conn, 10_800.0, &policy, 1000).unwrap().readings,
            3600
        );
        assert_eq!(prune(&conn, 10_800.0, &policy, 1000).unwrap().readings, 0);
    }

    #[test]
    fn old_estimates_are_thinned_to_one_a_minute() {
        let conn = database();
        let policy = Retention {
            full_estimates_s: Some(3600.0),
            ..Retention::default()
        };
        let pruned = prune(&conn, 10_800.0, &policy, 1000).unwrap();
        // Before 2 h: 120 minutes, one estimate each; after: all 3600.
        assert_eq!(pruned.estimates, 7200 - 120);
        let count = |sql: &str| -> i64 { conn.query_row(sql, [], |r| r.get(0)).unwrap() };
        assert_eq!(count("SELECT COUNT(*) FROM estimates WHERE t < 7200"), 120);
        assert_eq!(
            count("SELECT COUNT(*) FROM estimates WHERE t >= 7200"),
            3600
        );
        // A second pass changes nothing.
        assert_eq!(prune(&conn, 10_800.0, &policy, 1000).unwrap().estimates, 0);
    }
}
