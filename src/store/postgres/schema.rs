//! The PostgreSQL schema, created and migrated at start: the SQLite
//! schema's tables and meaning (`store/sqlite/schema.rs`), with readings and
//! estimates partitioned by time (one partition per day, made when the
//! first row of its day is written) so retention drops whole partitions.
//! Several nodes may start at once: migrations run under an advisory lock.

use tokio_postgres::Client;

use crate::store::error::StoreError;

/// Migration `i` takes the database from version `i` to `i + 1`.
const MIGRATIONS: &[&str] = &[
    // 1: what SQLite's migrations 1-4 made.
    "
    CREATE TABLE machines (
        id bigserial PRIMARY KEY,
        -- the protocol id, [A-Za-z0-9_-]{1,64}
        machine text NOT NULL UNIQUE,
        -- the validated MachineSpec as JSON
        spec text NOT NULL
    );
    -- Every accepted reading; `id` its arrival order (one writer per
    -- machine), `body` its data, compact (store/codec.rs).
    CREATE SEQUENCE readings_id_seq AS bigint;
    CREATE TABLE readings (
        id bigint NOT NULL DEFAULT nextval('readings_id_seq'),
        machine_id bigint NOT NULL REFERENCES machines(id),
        t double precision NOT NULL,
        -- SensorKind in protocol order: 0 laser, 1 inclinometer, 2 imu,
        -- 3 magnetometer, 4 level, 5 odometer, 6 advance
        sensor smallint NOT NULL,
        body bytea NOT NULL,
        -- A sensor has one reading per instant: a resent reading is stored once.
        UNIQUE (machine_id, t, sensor)
    ) PARTITION BY RANGE (t);
    -- The readings that arrived after a snapshot.
    CREATE INDEX readings_by_arrival ON readings (machine_id, id);
    -- Engine and stage outputs; `extreme_a`, `extreme_b` the two values
    -- whose extremes downsampling keeps, `codec` the body's version.
    CREATE TABLE estimates (
        machine_id bigint NOT NULL REFERENCES machines(id),
        engine text NOT NULL,
        t double precision NOT NULL,
        extreme_a double precision NOT NULL,
        extreme_b double precision NOT NULL,
        body bytea NOT NULL,
        codec integer NOT NULL,
        PRIMARY KEY (machine_id, engine, t)
    ) PARTITION BY RANGE (t);
    -- Per-bucket extremes of the estimates at a few bucket widths.
    CREATE TABLE estimate_buckets (
        machine_id bigint NOT NULL REFERENCES machines(id),
        engine text NOT NULL,
        width_s bigint NOT NULL,
        bucket bigint NOT NULL,
        min_a double precision NOT NULL, t_min_a double precision NOT NULL,
        max_a double precision NOT NULL, t_max_a double precision NOT NULL,
        min_b double precision NOT NULL, t_min_b double precision NOT NULL,
        max_b double precision NOT NULL, t_max_b double precision NOT NULL,
        PRIMARY KEY (machine_id, engine, width_s, bucket)
    );
    -- The latest state of each machine's engines and reorder buffer, after
    -- every reading up to `last_reading_id` had arrived.
    CREATE TABLE snapshots (
        machine_id bigint PRIMARY KEY REFERENCES machines(id),
        last_reading_id bigint NOT NULL,
        state text NOT NULL
    );
    -- Access tokens, as SHA-256 hashes (never the token itself).
    CREATE TABLE tokens (
        id bigserial PRIMARY KEY,
        name text NOT NULL,
        scope text NOT NULL CHECK (scope IN ('ingest', 'read', 'admin')),
        machine text,
        hash text NOT NULL UNIQUE,
        created_t double precision NOT NULL,
        revoked_t double precision
    );
    -- Alarms, raised, cleared and acknowledged in place (the audit log).
    CREATE TABLE alarms (
        id bigserial PRIMARY KEY,
        machine_id bigint NOT NULL REFERENCES machines(id),
        kind text NOT NULL,
        severity text NOT NULL CHECK (severity IN ('warn', 'alarm')),
        subject text NOT NULL,
        message text NOT NULL,
        raised_t double precision NOT NULL,
        cleared_t double precision,
        acked_t double precision,
        acked_by text,
        UNIQUE (machine_id, kind, severity, subject, raised_t)
    );
    CREATE INDEX alarms_open ON alarms (machine_id, cleared_t);
    ",
    // 2: several nodes on one database (`cluster.rs`).
    "
    -- The server nodes: where each answers, the key its forwarded
    -- requests carry, its last heartbeat.
    CREATE TABLE nodes (
        node text PRIMARY KEY,
        url text NOT NULL,
        key text NOT NULL,
        seen_at timestamptz NOT NULL
    );
    -- Which node fuses which machine, until when; `epoch` counts the
    -- times the machine changed hands.
    CREATE TABLE leases (
        machine_id bigint PRIMARY KEY REFERENCES machines(id),
        node text NOT NULL,
        epoch bigint NOT NULL,
        expires_at timestamptz NOT NULL
    );
    CREATE INDEX leases_by_node ON leases (node);
    ",
    // 3: an office's record of what each site sent (as in SQLite's 5),
    // alarm changes owed to webhooks, tokens for sites.
    "
    -- Per forwarded machine, the last sequence its site sent that is
    -- committed here.
    CREATE TABLE forward_marks (
        machine_id bigint PRIMARY KEY REFERENCES machines(id),
        sequence bigint NOT NULL
    );
    -- Each site's link as last reported.
    CREATE TABLE sites (
        name text PRIMARY KEY,
        last_contact_t double precision NOT NULL,
        backlog_items bigint NOT NULL,
        backlog_readings bigint NOT NULL,
        oldest_unsent_t double precision
    );
    -- Alarm changes owed to a webhook: `kind` the severity, `node` the
    -- node that made them and posts them.
    CREATE TABLE outbox (
        id bigserial PRIMARY KEY,
        node text NOT NULL,
        kind text NOT NULL,
        machine_id bigint NOT NULL REFERENCES machines(id),
        body text NOT NULL,
        created_t double precision NOT NULL
    );
    CREATE INDEX outbox_by_node ON outbox (node, kind, id);
    ALTER TABLE tokens DROP CONSTRAINT tokens_scope_check;
    ALTER TABLE tokens ADD CONSTRAINT tokens_scope_check
        CHECK (scope IN ('ingest', 'read', 'admin', 'site'));
    ",
    // 4: tokens of a fifth scope, `operator` (read, and acknowledge
    // alarms); a node's key is no longer stored, only the SHA-256 of the
    // cluster key it signs with (the keys stored before are wiped).
    "
    ALTER TABLE tokens DROP CONSTRAINT tokens_scope_check;
    ALTER TABLE tokens ADD CONSTRAINT tokens_scope_check
        CHECK (scope IN ('ingest', 'read', 'operator', 'admin', 'site'));
    ALTER TABLE nodes RENAME COLUMN key TO key_sha256;
    UPDATE nodes SET key_sha256 = '';
    ",
    // 5: an office's record of each forwarded sequence it applied, the
    // mark up to which earlier rows are trusted, and the audit log (as in
    // SQLite's 7).
    "
    CREATE TABLE forward_applied (
        machine_id bigint NOT NULL REFERENCES machines(id),
        sequence bigint NOT NULL,
        PRIMARY KEY (machine_id, sequence)
    );
    ALTER TABLE forward_marks ADD COLUMN trusted_to bigint NOT NULL DEFAULT -1;
    UPDATE forward_marks SET trusted_to = sequence;
    CREATE TABLE audit (
        id bigserial PRIMARY KEY,
        t double precision NOT NULL,
        actor text NOT NULL,
        action text NOT NULL,
        subject text NOT NULL,
        detail text NOT NULL
    );
    ",
];

/// The schema version this build writes.
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// Any constant both nodes agree on: the advisory lock migrations hold.
const MIGRATION_LOCK: i64 = 0x7475_6e6e_656c_6e76; // "tunnelnv"

/// Brings the database to [`SCHEMA_VERSION`]; refuses a newer one.
pub async fn migrate(client: &mut Client) -> Result<(), StoreError> {
    client
        .execute("SELECT pg_advisory_lock($1)", &[&MIGRATION_LOCK])
        .await?;
    let result = migrate_locked(client).await;
    client
        .execute("SELECT pg_advisory_unlock($1)", &[&MIGRATION_LOCK])
        .await?;
    result
}

async fn migrate_locked(client: &mut Client) -> Result<(), StoreError> {
    client
        .batch_execute("CREATE TABLE IF NOT EXISTS tunnelnav_schema (version bigint NOT NULL)")
        .await?;
    let version: i64 = match client
        .query_opt("SELECT version FROM tunnelnav_schema", &[])
        .await?
    {
        Some(row) => row.get(0),
        None => {
            client
                .execute("INSERT INTO tunnelnav_schema (version) VALUES (0)", &[])
                .await?;
            0
        }
    };
    if version > SCHEMA_VERSION {
        return Err(StoreError::NewerSchema {
            found: version,
            supported: SCHEMA_VERSION,
        });
    }
    for (from, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
        let tx = client.transaction().await?;
        tx.batch_execute(sql).await?;
        tx.execute(
            "UPDATE tunnelnav_schema SET version = $1",
            &[&(from as i64 + 1)],
        )
        .await?;
        tx.commit().await?;
    }
    Ok(())
}

/// Seconds of time per partition of `readings` and `estimates`.
pub const PARTITION_S: f64 = 86_400.0;

/// The tables partitioned by time.
pub const PARTITIONED: [&str; 2] = ["readings", "estimates"];

/// The partition of `table` holding time `t`: its number (days since
/// 1970) and name.
pub fn partition(table: &str, t: f64) -> (i64, String) {
    let day = (t / PARTITION_S).floor() as i64;
    let name = if day < 0 {
        format!("{table}_before_{}", -day)
    } else {
        format!("{table}_d{day}")
    };
    (day, name)
}

/// Makes the partition of `table` for `day` if no node has made it yet.
pub async fn create_partition(
    client: &impl tokio_postgres::GenericClient,
    table: &str,
    day: i64,
) -> Result<(), StoreError> {
    let (_, name) = partition(table, day as f64 * PARTITION_S);
    let from = day as f64 * PARTITION_S;
    let to = (day + 1) as f64 * PARTITION_S;
    let sql = format!(
        "CREATE TABLE IF NOT EXISTS {name} PARTITION OF {table} FOR VALUES FROM ({from:?}) TO ({to:?})"
    );
    match client.batch_execute(&sql).await {
        Ok(()) => Ok(()),
        // Another node made it between our check and our statement.
        Err(e) if e.code() == Some(&tokio_postgres::error::SqlState::DUPLICATE_TABLE) => Ok(()),
        Err(e) => Err(e.into()),
    }
}

/// The partitions that exist: (table, day).
pub async fn partitions(client: &Client) -> Result<Vec<(String, i64)>, StoreError> {
    let rows = client
        .query(
            "SELECT parent.relname::text, child.relname::text FROM pg_inherits \
             JOIN pg_class parent ON parent.oid = pg_inherits.inhparent \
             JOIN pg_class child ON child.oid = pg_inherits.inhrelid \
             WHERE parent.relname = ANY($1)",
            &[&PARTITIONED.to_vec()],
        )
        .await?;
    let mut found = Vec::new();
    for row in rows {
        let (table, child): (String, String) = (row.get(0), row.get(1));
        let rest = child.strip_prefix(&format!("{table}_")).unwrap_or("");
        let day = if let Some(days) = rest.strip_prefix("before_") {
            days.parse::<i64>().ok().map(|d| -d)
        } else {
            rest.strip_prefix('d').and_then(|d| d.parse::<i64>().ok())
        };
        if let Some(day) = day {
            found.push((table, day));
        }
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_partition_is_named_by_its_day() {
        assert_eq!(partition("readings", 0.0), (0, "readings_d0".into()));
        // 2025-12-05 12:00 UTC is day 20_427.
        assert_eq!(
            partition("estimates", 1_764_936_000.0),
            (20_427, "estimates_d20427".into())
        );
        assert_eq!(
            partition("readings", -1.0),
            (-1, "readings_before_1".into())
        );
    }
}
