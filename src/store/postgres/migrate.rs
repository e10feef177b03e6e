//! `tunnelnav migrate`: a site's SQLite store moved into an empty
//! PostgreSQL database, every table, ids kept (readings' arrival order,
//! snapshots' `last_reading_id`, alarm and token ids stay valid).
//!
//! Everything goes in one transaction: rows by `COPY ... BINARY`, then each
//! table is read back inside the transaction and compared with the source
//! by count and by a SHA-256 over its rows in key order; the transaction
//! commits only if every table matches, so a failed or interrupted
//! migration leaves the target as it was.

use std::path::Path;

use rusqlite::Connection;
use sha2::{Digest, Sha256};
use tokio_postgres::Transaction;
use tokio_postgres::binary_copy::BinaryCopyInWriter;
use tokio_postgres::types::{ToSql, Type};

use super::{PgLocation, connect, schema};
use crate::store::error::StoreError;
use crate::store::sqlite::SqliteStore;

/// One table as moved: its rows and their checksum (equal on both sides).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TableReport {
    pub table: &'static str,
    pub rows: u64,
    /// SHA-256 over the rows in key order, hex.
    pub sha256: String,
}

/// A value of a row, for the checksum and the copy.
enum Value {
    Int(i64),
    Real(f64),
    Text(String),
    Bytes(Vec<u8>),
    Null,
}

impl Value {
    fn from_sqlite(value: rusqlite::types::ValueRef<'_>) -> Result<Value, StoreError> {
        use rusqlite::types::ValueRef;
        Ok(match value {
            ValueRef::Null => Value::Null,
            ValueRef::Integer(i) => Value::Int(i),
            ValueRef::Real(r) => Value::Real(r),
            ValueRef::Text(t) => Value::Text(
                String::from_utf8(t.to_vec())
                    .map_err(|e| StoreError::Corrupt(format!("text column: {e}")))?,
            ),
            ValueRef::Blob(b) => Value::Bytes(b.to_vec()),
        })
    }

    /// Feeds the checksum: a tag, then the value (lengths before text).
    fn hash(&self, hasher: &mut Sha256) {
        match self {
            Value::Int(i) => {
                hasher.update([1]);
                hasher.update(i.to_le_bytes());
            }
            Value::Real(r) => {
                hasher.update([2]);
                hasher.update(r.to_bits().to_le_bytes());
            }
            Value::Text(t) => {
                hasher.update([3]);
                hasher.update((t.len() as u64).to_le_bytes());
                hasher.update(t.as_bytes());
            }
            Value::Bytes(b) => {
                hasher.update([4]);
                hasher.update((b.len() as u64).to_le_bytes());
                hasher.update(b);
            }
            Value::Null => hasher.update([0]),
        }
    }
}

/// A column: its name and PostgreSQL type.
type Column = (&'static str, Type);

/// The tables, in the order that satisfies their foreign keys, each with
/// its columns and key order. `REAL` columns of SQLite are `float8`.
fn tables() -> Vec<(&'static str, Vec<Column>, &'static str)> {
    use Type as T;
    vec![
        (
            "machines",
            vec![("id", T::INT8), ("machine", T::TEXT), ("spec", T::TEXT)],
            "id",
        ),
        (
            "readings",
            vec![
                ("id", T::INT8),
                ("machine_id", T::INT8),
                ("t", T::FLOAT8),
                ("sensor", T::INT2),
                ("body", T::BYTEA),
            ],
            "id",
        ),
        (
            "estimates",
            vec![
                ("machine_id", T::INT8),
                ("engine", T::TEXT),
                ("t", T::FLOAT8),
                ("extreme_a", T::FLOAT8),
                ("extreme_b", T::FLOAT8),
                ("body", T::BYTEA),
                ("codec", T::INT4),
            ],
            "machine_id, engine, t",
        ),
        (
            "estimate_buckets",
            vec![
                ("machine_id", T::INT8),
                ("engine", T::TEXT),
                ("width_s", T::INT8),
                ("bucket", T::INT8),
                ("min_a", T::FLOAT8),
                ("t_min_a", T::FLOAT8),
                ("max_a", T::FLOAT8),
                ("t_max_a", T::FLOAT8),
                ("min_b", T::FLOAT8),
                ("t_min_b", T::FLOAT8),
                ("max_b", T::FLOAT8),
                ("t_max_b", T::FLOAT8),
            ],
            "machine_id, engine, width_s, bucket",
        ),
        (
            "snapshots",
            vec![
                ("machine_id", T::INT8),
                ("last_reading_id", T::INT8),
                ("state", T::TEXT),
            ],
            "machine_id",
        ),
        (
            "tokens",
            vec![
                ("id", T::INT8),
                ("name", T::TEXT),
                ("scope", T::TEXT),
                ("machine", T::TEXT),
                ("hash", T::TEXT),
                ("created_t", T::FLOAT8),
                ("revoked_t", T::FLOAT8),
            ],
            "id",
        ),
        (
            "alarms",
            vec![
                ("id", T::INT8),
                ("machine_id", T::INT8),
                ("kind", T::TEXT),
                ("severity", T::TEXT),
                ("subject", T::TEXT),
                ("message", T::TEXT),
                ("raised_t", T::FLOAT8),
                ("cleared_t", T::FLOAT8),
                ("acked_t", T::FLOAT8),
                ("acked_by", T::TEXT),
            ],
            "id",
        ),
        (
            "audit",
            vec![
                ("id", T::INT8),
                ("t", T::FLOAT8),
                ("actor", T::TEXT),
                ("action", T::TEXT),
                ("subject", T::TEXT),
                ("detail", T::TEXT),
            ],
            "id",
        ),
    ]
}

/// Moves the SQLite store in `data_dir` into the empty PostgreSQL database
/// at `target`; what each table holds on both sides. Refuses a target that
/// already holds machines.
pub async fn from_sqlite(
    data_dir: &Path,
    target: &PgLocation,
) -> Result<Vec<TableReport>, StoreError> {
    let database = data_dir.join(crate::store::sqlite::DB_FILE);
    if !database.exists() {
        return Err(StoreError::Location(format!(
            "to migrate: there is no SQLite store at {}",
            database.display()
        )));
    }
    let source = SqliteStore::connect(data_dir)?;
    let endpoint = target.endpoint()?;
    let mut client = connect(&endpoint).await?;
    schema::migrate(&mut client).await?;
    let machines: i64 = client
        .query_one("SELECT count(*) FROM machines", &[])
        .await?
        .get(0);
    if machines > 0 {
        return Err(StoreError::Location(format!(
            "to migrate into holds {machines} machines already: migrate into an empty database"
        )));
    }
    let tx = client.transaction().await?;
    // Every day partition the rows need: each group of whole days (SQLite
    // truncates toward zero) gives the days of its first and last row.
    for table in schema::PARTITIONED {
        let mut groups = source.prepare(&format!(
            "SELECT min(t), max(t) FROM {table} GROUP BY CAST(t / {:?} AS INTEGER)",
            schema::PARTITION_S
        ))?;
        let ends: Vec<(f64, f64)> = groups
            .query_map([], |row| Ok((row.get(0)?, row.get(1)?)))?
            .collect::<Result<_, _>>()?;
        let mut days: Vec<i64> = ends
            .iter()
            .flat_map(|&(first, last)| [first, last])
            .map(|t| schema::partition(table, t).0)
            .collect();
        days.sort_unstable();
        days.dedup();
        for day in days {
            schema::create_partition(&tx, table, day).await?;
        }
    }
    let mut reports = Vec::new();
    for (table, columns, key) in tables() {
        let copied = copy_table(&source, &tx, table, &columns, key).await?;
        let stored = checksum_target(&tx, table, &columns, key).await?;
        if stored != copied {
            return Err(StoreError::Corrupt(format!(
                "{table}: {} rows ({}) read from SQLite, {} rows ({}) in PostgreSQL: nothing committed",
                copied.rows, copied.sha256, stored.rows, stored.sha256
            )));
        }
        reports.push(copied);
    }
    // The sequences go on after the ids moved.
    for (table, sequence) in [
        ("machines", "machines_id_seq"),
        ("readings", "readings_id_seq"),
        ("tokens", "tokens_id_seq"),
        ("alarms", "alarms_id_seq"),
        ("audit", "audit_id_seq"),
    ] {
        tx.execute(
            &format!(
                "SELECT setval('{sequence}', coalesce((SELECT max(id) FROM {table}), 0) + 1, false)"
            ),
            &[],
        )
        .await?;
    }
    tx.commit().await?;
    Ok(reports)
}

/// Copies `table` from SQLite by `COPY ... BINARY`, in key order; its rows
/// and checksum as read.
async fn copy_table(
    source: &Connection,
    tx: &Transaction<'_>,
    table: &'static str,
    columns: &[Column],
    key: &str,
) -> Result<TableReport, StoreError> {
    let names: Vec<&str> = columns.iter().map(|(name, _)| *name).collect();
    let types: Vec<Type> = columns.iter().map(|(_, ty)| ty.clone()).collect();
    let sink = tx
        .copy_in(&format!(
            "COPY {table} ({}) FROM STDIN BINARY",
            names.join(", ")
        ))
        .await?;
    let writer = BinaryCopyInWriter::new(sink, &types);
    let mut writer = std::pin::pin!(writer);
    let mut statement = source.prepare(&format!(
        "SELECT {} FROM {table} ORDER BY {key}",
        names.join(", ")
    ))?;
    let mut rows = statement.query([])?;
    let mut hasher = Sha256::new();
    let mut count = 0;
    while let Some(row) = rows.next()? {
        let mut values = Vec::with_capacity(columns.len());
        for (i, (_, ty)) in columns.iter().enumerate() {
            let value = match (Value::from_sqlite(row.get_ref(i)?)?, ty) {
                // An integral value in a REAL column: the target's float8.
                (Value::Int(i), &Type::FLOAT8) => Value::Real(i as f64),
                (value, _) => value,
            };
            value.hash(&mut hasher);
            values.push(parameter(value, ty)?);
        }
        let refs: Vec<&(dyn ToSql + Sync)> = values
            .iter()
            .map(|v| v.as_ref() as &(dyn ToSql + Sync))
            .collect();
        writer.as_mut().write(&refs).await?;
        count += 1;
    }
    writer.finish().await?;
    Ok(TableReport {
        table,
        rows: count,
        sha256: hex::encode(hasher.finalize()),
    })
}

/// A value as the PostgreSQL column of type `ty` takes it.
fn parameter(value: Value, ty: &Type) -> Result<Box<dyn ToSql + Sync + Send>, StoreError> {
    let mismatch = |what: &str| StoreError::Corrupt(format!("{what} in a {ty} column"));
    Ok(match (value, ty) {
        (Value::Null, _) => match *ty {
            Type::INT8 => Box::new(None::<i64>),
            Type::INT4 => Box::new(None::<i32>),
            Type::INT2 => Box::new(None::<i16>),
            Type::FLOAT8 => Box::new(None::<f64>),
            Type::TEXT => Box::new(None::<String>),
            _ => Box::new(None::<Vec<u8>>),
        },
        (Value::Int(i), &Type::INT8) => Box::new(i),
        (Value::Int(i), &Type::INT4) => {
            Box::new(i32::try_from(i).map_err(|_| mismatch("a large integer"))?)
        }
        (Value::Int(i), &Type::INT2) => {
            Box::new(i16::try_from(i).map_err(|_| mismatch("a large integer"))?)
        }
        (Value::Real(r), &Type::FLOAT8) => Box::new(r),
        (Value::Text(t), &Type::TEXT) => Box::new(t),
        (Value::Bytes(b), &Type::BYTEA) => Box::new(b),
        (Value::Int(_), _) => return Err(mismatch("an integer")),
        (Value::Real(_), _) => return Err(mismatch("a real")),
        (Value::Text(_), _) => return Err(mismatch("text")),
        (Value::Bytes(_), _) => return Err(mismatch("bytes")),
    })
}

/// The rows and checksum of `table` as PostgreSQL holds it (inside `tx`),
/// hashed as SQLite's were: integers as integers, reals as reals.
async fn checksum_target(
    tx: &Transaction<'_>,
    table: &'static str,
    columns: &[Column],
    key: &str,
) -> Result<TableReport, StoreError> {
    use futures_util::StreamExt;
    let names: Vec<&str> = columns.iter().map(|(name, _)| *name).collect();
    let no_parameters: [&(dyn ToSql + Sync); 0] = [];
    let rows = tx
        .query_raw(
            &format!("SELECT {} FROM {table} ORDER BY {key}", names.join(", ")),
            no_parameters,
        )
        .await?;
    let mut rows = std::pin::pin!(rows);
    let mut hasher = Sha256::new();
    let mut count = 0;
    while let Some(row) = rows.next().await {
        let row = row?;
        count += 1;
        for (i, (_, ty)) in columns.iter().enumerate() {
            let value = match *ty {
                Type::INT8 => row.get::<_, Option<i64>>(i).map(Value::Int),
                Type::INT4 => row.get::<_, Option<i32>>(i).map(|v| Value::Int(v.into())),
                Type::INT2 => row.get::<_, Option<i16>>(i).map(|v| Value::Int(v.into())),
                Type::FLOAT8 => row.get::<_, Option<f64>>(i).map(Value::Real),
                Type::TEXT => row.get::<_, Option<String>>(i).map(Value::Text),
                _ => row.get::<_, Option<Vec<u8>>>(i).map(Value::Bytes),
            };
            value.unwrap_or(Value::Null).hash(&mut hasher);
        }
    }
    Ok(TableReport {
        table,
        rows: count,
        sha256: hex::encode(hasher.finalize()),
    })
}
