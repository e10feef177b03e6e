//! What can go wrong in the store.

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error(transparent)]
    Token(#[from] crate::auth::TokenError),
    #[error("PostgreSQL: {0}")]
    Postgres(#[from] tokio_postgres::Error),
    #[error("the database {0}")]
    Location(String),
    #[error("no database connection: {0}")]
    Unavailable(String),
    #[error("cannot create data dir {path}: {source}")]
    DataDir {
        path: String,
        source: std::io::Error,
    },
    #[error("database schema version {found} is newer than this build supports ({supported})")]
    NewerSchema { found: i64, supported: i64 },
    /// What this backend does not keep (an office's records in a store
    /// kept in memory).
    #[error("the {backend} store does not keep {what}")]
    Unsupported {
        backend: &'static str,
        what: &'static str,
    },
    #[error("the store has shut down")]
    Closed,
    #[error("stored data is corrupt: {0}")]
    Corrupt(String),
    #[error("the machine's engines could not be rebuilt after a failed write ({0})")]
    Unrebuilt(String),
    /// An office: a site's row at or below the machine's mark that this
    /// office does not hold (nothing of the request is applied).
    #[error(
        "forwarded row {sequence} lies at or below the mark {mark}, but this office does not hold it"
    )]
    NotHeld { sequence: i64, mark: i64 },
}

/// A PostgreSQL failure that may pass: the connection lost or refused,
/// the server shutting down or out of room, a conflict to retry.
fn postgres_transient(e: &tokio_postgres::Error) -> bool {
    use tokio_postgres::error::SqlState;
    let Some(code) = e.code() else {
        // No SQLSTATE: the connection closed, or an I/O failure reaching
        // the server (refused, reset, timed out); not a client-side error
        // (a type that does not convert, a row count) that would fail again.
        return e.is_closed()
            || std::error::Error::source(e).is_some_and(|s| s.is::<std::io::Error>());
    };
    let class = &code.code()[..2];
    // 08: connection exception; 53: insufficient resources (disk full,
    // out of memory, too many connections); 57P: operator intervention
    // (shutdown); 40: a serialization failure or deadlock to retry.
    matches!(class, "08" | "53" | "40")
        || [
            SqlState::ADMIN_SHUTDOWN,
            SqlState::CRASH_SHUTDOWN,
            SqlState::CANNOT_CONNECT_NOW,
        ]
        .contains(code)
}

impl StoreError {
    /// A failure that may pass: the database busy or locked by another
    /// process, the disk full, an I/O error. The server answers 503 for
    /// these and the client retries.
    pub fn is_transient(&self) -> bool {
        use rusqlite::ErrorCode;
        match self {
            StoreError::Sqlite(rusqlite::Error::SqliteFailure(e, _)) => matches!(
                e.code,
                ErrorCode::DatabaseBusy
                    | ErrorCode::DatabaseLocked
                    | ErrorCode::DiskFull
                    | ErrorCode::SystemIoFailure
                    | ErrorCode::CannotOpen
            ),
            StoreError::Unrebuilt(_) | StoreError::Unavailable(_) => true,
            StoreError::Postgres(e) => postgres_transient(e),
            _ => false,
        }
    }
}
