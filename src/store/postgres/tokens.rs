//! Access tokens in PostgreSQL (their scopes and hashing are
//! [`crate::auth`]'s).

use super::handle::PgStore;
use crate::auth::{Scope, Token, TokenError};
use crate::store::error::StoreError;

impl PgStore {
    /// The tokens in force, with their hashes.
    pub async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError> {
        let client = self.pooled().await?;
        let rows = client
            .query(
                "SELECT id, name, scope, machine, created_t, revoked_t, hash FROM tokens \
                 WHERE revoked_t IS NULL",
                &[],
            )
            .await?;
        Ok(rows.iter().map(|row| (row.get(6), token(row))).collect())
    }

    /// Stores a new token; its id and text (shown once), as
    /// [`crate::store::sqlite::tokens::create`] does on SQLite.
    pub async fn create_token(
        &self,
        name: &str,
        scope: Scope,
        machine: Option<&str>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError> {
        crate::auth::check_new(scope, machine)?;
        let (token, hash) = crate::auth::generate();
        let client = self.pooled().await?;
        let id: i64 = client
            .query_one(
                "INSERT INTO tokens (name, scope, machine, hash, created_t) \
                 VALUES ($1, $2, $3, $4, $5) RETURNING id",
                &[&name, &scope.as_str(), &machine, &hash, &now_t],
            )
            .await
            .map_err(StoreError::from)?
            .get(0);
        Ok((id, token))
    }

    /// Every token, revoked ones included, oldest first.
    pub async fn tokens(&self) -> Result<Vec<Token>, StoreError> {
        let client = self.pooled().await?;
        let rows = client
            .query(
                "SELECT id, name, scope, machine, created_t, revoked_t FROM tokens ORDER BY id",
                &[],
            )
            .await?;
        Ok(rows.iter().map(token).collect())
    }

    /// Revokes a token.
    pub async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError> {
        let client = self.pooled().await?;
        client
            .execute(
                "UPDATE tokens SET revoked_t = $2 WHERE id = $1 AND revoked_t IS NULL",
                &[&id, &now_t],
            )
            .await
            .map_err(StoreError::from)?;
        client
            .query_opt(
                "SELECT id, name, scope, machine, created_t, revoked_t FROM tokens WHERE id = $1",
                &[&id],
            )
            .await
            .map_err(StoreError::from)?
            .map(|row| token(&row))
            .ok_or(StoreError::Token(TokenError::NoSuchToken(id)))
    }
}

/// A token from a row of (id, name, scope, machine, created_t, revoked_t).
fn token(row: &tokio_postgres::Row) -> Token {
    let scope: String = row.get(2);
    Token {
        id: row.get(0),
        name: row.get(1),
        // The table's CHECK constraint admits only the three names.
        scope: Scope::from_name(&scope).unwrap_or(Scope::Read),
        machine: row.get(3),
        created_t: row.get(4),
        revoked_t: row.get(5),
    }
}
