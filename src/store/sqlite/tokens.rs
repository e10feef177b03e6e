//! Access tokens in the SQLite store: made, listed, read in force and
//! revoked (the tokens themselves, their scopes and hashing are
//! [`crate::auth`]'s; PostgreSQL's are in `store/postgres/tokens.rs`).

use rusqlite::{Connection, OptionalExtension, params};

use crate::auth::{Scope, Token, TokenError, check_new, generate};
use crate::store::error::StoreError;

/// Stores a new token; returns its id and the token text (shown once).
pub fn create(
    conn: &Connection,
    name: &str,
    scope: Scope,
    machine: Option<&str>,
    now_t: f64,
) -> Result<(i64, String), StoreError> {
    check_new(scope, machine)?;
    let (token, hash) = generate();
    conn.execute(
        "INSERT INTO tokens (name, scope, machine, hash, created_t) VALUES (?1, ?2, ?3, ?4, ?5)",
        params![name, scope.as_str(), machine, hash, now_t],
    )?;
    Ok((conn.last_insert_rowid(), token))
}

fn row_to_token(row: &rusqlite::Row<'_>) -> rusqlite::Result<Token> {
    let scope: String = row.get(2)?;
    Ok(Token {
        id: row.get(0)?,
        name: row.get(1)?,
        // The table's CHECK constraint admits only the scopes' names.
        scope: Scope::from_name(&scope).unwrap_or(Scope::Read),
        machine: row.get(3)?,
        created_t: row.get(4)?,
        revoked_t: row.get(5)?,
    })
}

/// Every token, revoked ones included, oldest first.
pub fn list(conn: &Connection) -> Result<Vec<Token>, StoreError> {
    let mut stmt = conn
        .prepare("SELECT id, name, scope, machine, created_t, revoked_t FROM tokens ORDER BY id")?;
    let tokens = stmt
        .query_map([], row_to_token)?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(tokens)
}

/// The tokens in force, with their hashes.
pub fn active(conn: &Connection) -> Result<Vec<(String, Token)>, StoreError> {
    let mut stmt = conn.prepare_cached(
        "SELECT id, name, scope, machine, created_t, revoked_t, hash FROM tokens WHERE revoked_t IS NULL",
    )?;
    let tokens = stmt
        .query_map([], |row| Ok((row.get::<_, String>(6)?, row_to_token(row)?)))?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(tokens)
}

/// Revokes a token (at once for new requests; the server rereads within 2 s).
pub fn revoke(conn: &Connection, id: i64, now_t: f64) -> Result<Token, StoreError> {
    conn.execute(
        "UPDATE tokens SET revoked_t = ?2 WHERE id = ?1 AND revoked_t IS NULL",
        params![id, now_t],
    )?;
    conn.query_row(
        "SELECT id, name, scope, machine, created_t, revoked_t FROM tokens WHERE id = ?1",
        [id],
        row_to_token,
    )
    .optional()?
    .ok_or(StoreError::Token(TokenError::NoSuchToken(id)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::auth::hash;

    #[test]
    fn tokens_are_stored_hashed_and_revoked() {
        let mut conn = Connection::open_in_memory().unwrap();
        crate::store::sqlite::schema::migrate(&mut conn).unwrap();
        let (id, token) = create(&conn, "gw", Scope::Ingest, Some("tbm-1"), 1.0).unwrap();
        assert!(token.starts_with("tnv_") && token.len() == 68);
        let stored: String = conn
            .query_row("SELECT hash FROM tokens WHERE id = ?1", [id], |r| r.get(0))
            .unwrap();
        assert_eq!(stored, hash(&token));
        assert!(!stored.contains(&token[4..]));
        assert_eq!(active(&conn).unwrap().len(), 1);
        assert!(matches!(
            create(&conn, "x", Scope::Ingest, None, 1.0),
            Err(StoreError::Token(TokenError::MachineMissing))
        ));
        assert!(matches!(
            create(&conn, "x", Scope::Read, Some("tbm-1"), 1.0),
            Err(StoreError::Token(TokenError::MachineNotAllowed(
                Scope::Read
            )))
        ));
        let revoked = revoke(&conn, id, 2.0).unwrap();
        assert_eq!(revoked.revoked_t, Some(2.0));
        assert!(active(&conn).unwrap().is_empty());
        assert_eq!(list(&conn).unwrap().len(), 1);
        assert!(matches!(
            revoke(&conn, 99, 2.0),
            Err(StoreError::Token(TokenError::NoSuchToken(99)))
        ));
    }
}
