//! Access tokens: what a token may do, how tokens are made, stored and
//! checked. Plain logic: the tokens table is the store's
//! (`store::tokens` on SQLite, `store::postgres` on PostgreSQL), the HTTP
//! side is `server::auth`.
//!
//! A token is `tnv_` followed by 64 hex digits (256 random bits from the
//! operating system's generator). Only its SHA-256 is stored; the token
//! itself is printed once, when created. Scopes:
//! - `ingest` for one named machine: post its readings, use its ingest
//!   WebSocket (a field gateway);
//! - `read`: the dashboard, history, exports, live sockets, metrics;
//!   it changes nothing;
//! - `operator`: what `read` may, and acknowledge alarms (the driver's
//!   and the control room's token);
//! - `admin`: everything, including declaring machines;
//! - `site` for one named site: forward that site's machines to this
//!   office and report its link (a site server's token at its office).

use serde::Serialize;
use sha2::{Digest, Sha256};

/// What a token may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scope {
    Ingest,
    Read,
    Operator,
    Admin,
    Site,
}

impl Scope {
    /// The stored and command-line name.
    pub fn as_str(self) -> &'static str {
        match self {
            Scope::Ingest => "ingest",
            Scope::Read => "read",
            Scope::Operator => "operator",
            Scope::Admin => "admin",
            Scope::Site => "site",
        }
    }

    /// Parses a name.
    pub fn from_name(name: &str) -> Option<Scope> {
        [
            Scope::Ingest,
            Scope::Read,
            Scope::Operator,
            Scope::Admin,
            Scope::Site,
        ]
        .into_iter()
        .find(|s| s.as_str() == name)
    }
}

/// What a request needs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Need {
    /// Nothing: liveness, static assets, the login page.
    Nothing,
    /// Reading anything.
    Read,
    /// Acknowledging alarms.
    Acknowledge,
    /// Sending readings of this machine.
    Ingest(String),
    /// Declaring machines.
    Admin,
    /// Forwarding this site's machines to this office.
    Site(String),
}

/// A stored token (without its hash).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Token {
    pub id: i64,
    pub name: String,
    pub scope: Scope,
    /// The machine an `ingest` token is for; the site a `site` token is for.
    pub machine: Option<String>,
    pub created_t: f64,
    pub revoked_t: Option<f64>,
}

impl Token {
    /// Whether this token grants `need`.
    pub fn allows(&self, need: &Need) -> bool {
        match (self.scope, need) {
            (_, Need::Nothing) | (Scope::Admin, _) => true,
            (Scope::Read | Scope::Operator, Need::Read) => true,
            (Scope::Operator, Need::Acknowledge) => true,
            (Scope::Ingest, Need::Ingest(machine)) => self.machine.as_deref() == Some(machine),
            (Scope::Site, Need::Site(site)) => self.machine.as_deref() == Some(site),
            _ => false,
        }
    }
}

/// A new token and the hash to store.
pub fn generate() -> (String, String) {
    let bytes: [u8; 32] = rand::random();
    let token = format!("tnv_{}", hex::encode(bytes));
    let hash = hash(&token);
    (token, hash)
}

/// The stored form of a token.
pub fn hash(token: &str) -> String {
    hex::encode(Sha256::digest(token.as_bytes()))
}

/// Why a token command failed.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("an `ingest` token needs --machine (the machine its gateway feeds)")]
    MachineMissing,
    #[error("a `site` token needs --site (the site that forwards with it)")]
    SiteMissing,
    #[error("only `ingest` tokens are for one machine and `site` tokens for one site; `{}` tokens are for neither", .0.as_str())]
    MachineNotAllowed(Scope),
    #[error("machine id `{0}` is not valid (letters, digits, _ and -, at most 64)")]
    MachineId(String),
    #[error("no token with id {0}")]
    NoSuchToken(i64),
}

/// Whether a token of `scope` for `machine` may be made: an ingest token
/// names one machine, the others none.
pub fn check_new(scope: Scope, machine: Option<&str>) -> Result<(), TokenError> {
    match (scope, machine) {
        (Scope::Ingest, None) => Err(TokenError::MachineMissing),
        (Scope::Site, None) => Err(TokenError::SiteMissing),
        (Scope::Read | Scope::Operator | Scope::Admin, Some(_)) => {
            Err(TokenError::MachineNotAllowed(scope))
        }
        (_, Some(m)) if !crate::config::valid_machine_id(m) => {
            Err(TokenError::MachineId(m.to_string()))
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scopes_grant_what_they_say() {
        let token = |scope, machine: Option<&str>| Token {
            id: 1,
            name: "t".into(),
            scope,
            machine: machine.map(str::to_string),
            created_t: 0.0,
            revoked_t: None,
        };
        let gateway = token(Scope::Ingest, Some("tbm-1"));
        assert!(gateway.allows(&Need::Ingest("tbm-1".into())));
        assert!(!gateway.allows(&Need::Ingest("tbm-2".into())));
        assert!(!gateway.allows(&Need::Read));
        assert!(!gateway.allows(&Need::Admin));
        let reader = token(Scope::Read, None);
        assert!(reader.allows(&Need::Read));
        assert!(!reader.allows(&Need::Acknowledge));
        assert!(!reader.allows(&Need::Ingest("tbm-1".into())));
        assert!(!reader.allows(&Need::Admin));
        let operator = token(Scope::Operator, None);
        assert!(operator.allows(&Need::Read));
        assert!(operator.allows(&Need::Acknowledge));
        assert!(!operator.allows(&Need::Admin));
        assert!(!operator.allows(&Need::Ingest("tbm-1".into())));
        let admin = token(Scope::Admin, None);
        for need in [
            Need::Read,
            Need::Acknowledge,
            Need::Admin,
            Need::Ingest("x".into()),
        ] {
            assert!(admin.allows(&need));
        }
    }
}
