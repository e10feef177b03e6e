//! The SQLite schema, created and migrated at start, stepped by
//! `PRAGMA user_version`.

use rusqlite::Connection;

/// Migration `i` takes the database from version `i` to `i + 1`.
const MIGRATIONS: &[&str] = &[
    // 1: machines, readings, estimates and their buckets, snapshots.
    "
    CREATE TABLE machines (
        id INTEGER PRIMARY KEY,
        -- the protocol id, [A-Za-z0-9_-]{1,64}
        machine TEXT NOT NULL UNIQUE,
        -- the validated MachineSpec as JSON
        spec TEXT NOT NULL
    );
    -- Every accepted reading, in arrival order (id); `body` its data,
    -- compact (store/codec.rs).
    CREATE TABLE readings (
        id INTEGER PRIMARY KEY,
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        t REAL NOT NULL,
        -- SensorKind in protocol order: 0 laser, 1 inclinometer, 2 imu,
        -- 3 magnetometer, 4 level, 5 odometer, 6 advance
        sensor INTEGER NOT NULL,
        body BLOB NOT NULL
    );
    -- A sensor has one reading per instant: a resent reading is stored once.
    -- Also serves time-range exports.
    CREATE UNIQUE INDEX readings_by_time ON readings(machine_id, t, sensor);
    -- (machine_id, id): the readings that arrived after a snapshot.
    CREATE INDEX readings_by_arrival ON readings(machine_id);
    -- Engine outputs. `extreme_a`, `extreme_b` are the two quantities whose
    -- extremes history downsampling keeps (attitude: pitch_deg, roll_deg);
    -- `body` the engine's values, compact (store/codec.rs).
    CREATE TABLE estimates (
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        engine TEXT NOT NULL,
        t REAL NOT NULL,
        extreme_a REAL NOT NULL,
        extreme_b REAL NOT NULL,
        body BLOB NOT NULL,
        PRIMARY KEY (machine_id, engine, t)
    ) WITHOUT ROWID;
    -- Per-bucket extremes of the estimates, at a few bucket widths, so a
    -- history query over months reads thousands of rows, not millions.
    -- `bucket` = floor(t / width_s); each extreme with the time it holds.
    CREATE TABLE estimate_buckets (
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        engine TEXT NOT NULL,
        width_s INTEGER NOT NULL,
        bucket INTEGER NOT NULL,
        min_a REAL NOT NULL, t_min_a REAL NOT NULL,
        max_a REAL NOT NULL, t_max_a REAL NOT NULL,
        min_b REAL NOT NULL, t_min_b REAL NOT NULL,
        max_b REAL NOT NULL, t_max_b REAL NOT NULL,
        PRIMARY KEY (machine_id, engine, width_s, bucket)
    ) WITHOUT ROWID;
    -- The latest state of each machine's engines and reorder buffer, after
    -- every reading up to `last_reading_id` had arrived.
    CREATE TABLE snapshots (
        machine_id INTEGER PRIMARY KEY REFERENCES machines(id),
        last_reading_id INTEGER NOT NULL,
        state TEXT NOT NULL
    );
    ",
    // 2: access tokens, stored as SHA-256 hashes (never the token itself).
    "
    CREATE TABLE tokens (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL,
        scope TEXT NOT NULL CHECK (scope IN ('ingest', 'read', 'admin')),
        machine TEXT,
        hash TEXT NOT NULL UNIQUE,
        created_t REAL NOT NULL,
        revoked_t REAL
    );
    ",
    // 3: each estimate row carries the codec version of its body (the
    // engine's `CODEC_VERSION`); rows stored before carry 0, which each
    // engine decodes as the forms it stored until then.
    "
    ALTER TABLE estimates ADD COLUMN codec INTEGER NOT NULL DEFAULT 0;
    ",
    // 4: alarms, raised, cleared and acknowledged in place (the audit log);
    // a raise recomputed after a restart is stored once.
    "
    CREATE TABLE alarms (
        id INTEGER PRIMARY KEY,
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        -- deviation, laser_dropout, stale_sensor, ins_uncertainty, engine_reset
        kind TEXT NOT NULL,
        severity TEXT NOT NULL CHECK (severity IN ('warn', 'alarm')),
        -- what it concerns (a sensor), or ''
        subject TEXT NOT NULL,
        message TEXT NOT NULL,
        raised_t REAL NOT NULL,
        cleared_t REAL,
        acked_t REAL,
        -- the acknowledging token's name
        acked_by TEXT,
        UNIQUE (machine_id, kind, severity, subject, raised_t)
    );
    CREATE INDEX alarms_open ON alarms(machine_id, cleared_t);
    ",
    // 5: the outbox (what a site still owes its office, alarm changes
    // still owed to the webhooks), which machines the office has been told
    // of, an office's record of what each site sent, and tokens for sites.
    "
    -- One row per committed reading batch, declaration or alarm change
    -- still to be sent; deleted once the receiver has committed it. The
    -- id is the sequence of the idempotency key (site, machine, sequence).
    -- AUTOINCREMENT: an id is never used twice, even once its row and
    -- every later one are gone.
    CREATE TABLE outbox (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        -- 'office' (a site forwarding) or 'webhook'
        destination TEXT NOT NULL CHECK (destination IN ('office', 'webhook')),
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        -- office: 'machine', 'readings' or 'alarm'; webhook: the severity
        kind TEXT NOT NULL,
        -- readings: the ids of the batch's readings (with no gap) and
        -- their count
        first_reading_id INTEGER,
        last_reading_id INTEGER,
        readings INTEGER NOT NULL DEFAULT 0,
        -- machine: the declaration and its engines' state; alarm and
        -- webhook: the change; JSON
        body TEXT,
        -- Unix seconds, when committed
        created_t REAL NOT NULL
    );
    CREATE INDEX outbox_by_machine ON outbox(destination, machine_id, id);
    CREATE INDEX outbox_by_kind ON outbox(destination, kind, id);
    -- A site: the machines whose declaration has gone into the outbox,
    -- and the last sequence of each the office has answered committed.
    CREATE TABLE forwarding (
        machine_id INTEGER PRIMARY KEY REFERENCES machines(id),
        acked INTEGER
    );
    -- A site: the office and the name it forwards to and as (another
    -- means declaring every machine afresh).
    CREATE TABLE forward_target (
        id INTEGER PRIMARY KEY CHECK (id = 1),
        office TEXT NOT NULL,
        site TEXT NOT NULL
    );
    -- An office: per forwarded machine, the last sequence its site sent
    -- that is committed here.
    CREATE TABLE forward_marks (
        machine_id INTEGER PRIMARY KEY REFERENCES machines(id),
        sequence INTEGER NOT NULL
    );
    -- An office: each site's link as last reported.
    CREATE TABLE sites (
        name TEXT PRIMARY KEY,
        last_contact_t REAL NOT NULL,
        backlog_items INTEGER NOT NULL,
        backlog_readings INTEGER NOT NULL,
        oldest_unsent_t REAL
    );
    -- Tokens: a fourth scope, `site` (a site forwarding to this office;
    -- `machine` holds the site's name).
    CREATE TABLE tokens_v5 (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL,
        scope TEXT NOT NULL CHECK (scope IN ('ingest', 'read', 'admin', 'site')),
        machine TEXT,
        hash TEXT NOT NULL UNIQUE,
        created_t REAL NOT NULL,
        revoked_t REAL
    );
    INSERT INTO tokens_v5 SELECT id, name, scope, machine, hash, created_t, revoked_t FROM tokens;
    DROP TABLE tokens;
    ALTER TABLE tokens_v5 RENAME TO tokens;
    ",
    // 6: tokens of a fifth scope, `operator` (read, and acknowledge
    // alarms; issue 57).
    "
    CREATE TABLE tokens_v6 (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL,
        scope TEXT NOT NULL CHECK (scope IN ('ingest', 'read', 'operator', 'admin', 'site')),
        machine TEXT,
        hash TEXT NOT NULL UNIQUE,
        created_t REAL NOT NULL,
        revoked_t REAL
    );
    INSERT INTO tokens_v6 SELECT id, name, scope, machine, hash, created_t, revoked_t FROM tokens;
    DROP TABLE tokens;
    ALTER TABLE tokens_v6 RENAME TO tokens;
    ",
    // 7: an office's record of each sequence of a forwarded machine it
    // applied (a skipped row is claimed only if it holds it), kept until
    // the site confirms it, and the mark up to which rows applied before
    // this record existed are trusted; the audit log of what an admin
    // changed by hand (issue 57).
    "
    CREATE TABLE forward_applied (
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        sequence INTEGER NOT NULL,
        PRIMARY KEY (machine_id, sequence)
    );
    ALTER TABLE forward_marks ADD COLUMN trusted_to INTEGER NOT NULL DEFAULT -1;
    UPDATE forward_marks SET trusted_to = sequence;
    CREATE TABLE audit (
        id INTEGER PRIMARY KEY,
        t REAL NOT NULL,
        actor TEXT NOT NULL,
        action TEXT NOT NULL,
        subject TEXT NOT NULL,
        detail TEXT NOT NULL
    );
    ",
];

/// The schema version this build writes.
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// Brings the database to [`SCHEMA_VERSION`]; refuses a newer one.
pub fn migrate(conn: &mut Connection) -> Result<(), crate::store::error::StoreError> {
    let version: i64 = conn.query_row("PRAGMA user_version", [], |row| row.get(0))?;
    if version > SCHEMA_VERSION {
        return Err(crate::store::error::StoreError::NewerSchema {
            found: version,
            supported: SCHEMA_VERSION,
        });
    }
    for (from, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
        let tx = conn.transaction()?;
        tx.execute_batch(sql)?;
        tx.pragma_update(None, "user_version", from as i64 + 1)?;
        tx.commit()?;
    }
    Ok(())
}
