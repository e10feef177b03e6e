//! Retention in the SQLite store ([`crate::store::retention`] says what it
//! keeps).
//!
//! A pass is planned on a read connection ([`plan`]) and done step by
//! step on the writer's connection between its group commits
//! ([`apply`] through `SqliteStore::maintain`): each step a short
//! transaction of at most `batch` rows or one thinning window, so ingest
//! waits for a few milliseconds at a time and nothing else writes.
//! A reading is deleted only if its machine's latest snapshot already
//! covers it: restart re-feeds the readings after the snapshot, and those
//! are never pruned. A gateway resending a pruned reading gets it stored
//! again, as a late reading (stored, not fused).

use rusqlite::{Connection, params};

use crate::store::error::StoreError;
use crate::store::retention::{Pruned, Retention, Step, THIN_TO_S, plan_steps};

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

/// Does `step`; what it deleted.
pub fn apply(conn: &Connection, step: &Step) -> Result<Pruned, StoreError> {
    match *step {
        Step::Readings { cut, batch } => {
            let readings = conn.execute(
                "DELETE FROM readings WHERE id IN (
                         SELECT r.id FROM readings r JOIN snapshots s ON s.machine_id = r.machine_id
                         WHERE r.t < ?1 AND r.id <= s.last_reading_id
                         AND r.id < (SELECT max(id) FROM readings)
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
            let done = apply(conn, &step)?;
            pruned.add(done);
            if !step.again(&done) {
                break;
            }
        }
    }
    Ok(pruned)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn database() -> Connection {
        let mut conn = Connection::open_in_memory().unwrap();
        crate::store::sqlite::schema::migrate(&mut conn).unwrap();
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
    fn the_newest_reading_id_stays_so_ids_never_go_back() {
        // Every reading old and covered: all but the newest go. Without
        // it SQLite would give the next reading the id after the highest
        // left, at or below the snapshot's, and a restart would not
        // re-feed it.
        let conn = database();
        conn.execute(
            "INSERT INTO snapshots (machine_id, last_reading_id, state) VALUES (1, 10800, '{}')",
            [],
        )
        .unwrap();
        let policy = Retention {
            keep_readings_s: Some(60.0),
            ..Retention::default()
        };
        let pruned = prune(&conn, 1.0e6, &policy, 100_000).unwrap();
        assert_eq!(pruned.readings, 10_799);
        conn.execute(
            "INSERT INTO readings (machine_id, t, sensor, body) VALUES (1, 2.0e6, 1, x'00')",
            [],
        )
        .unwrap();
        let newest: i64 = conn
            .query_row("SELECT max(id) FROM readings", [], |r| r.get(0))
            .unwrap();
        assert_eq!(newest, 10_801);
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
