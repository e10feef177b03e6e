//! Where the office database is and how to reach it: the location (URL,
//! password file, CA), TLS, the read pool and the connections.

use std::path::Path;
use std::str::FromStr;

use deadpool_postgres::{Manager, ManagerConfig, Pool, RecyclingMethod};
use tokio_postgres_rustls::MakeRustlsConnect;

use crate::store::error::StoreError;

/// Connections the read pool keeps.
const READERS: usize = 4;

/// Where the office database is: a `postgres://USER@HOST:PORT/DB` URL and,
/// if the password is not in it, the file holding it.
#[derive(Debug, Clone, PartialEq)]
pub struct PgLocation {
    pub url: String,
    pub password_file: Option<std::path::PathBuf>,
    /// The CA the server's certificate is checked against (TLS), if not
    /// the system's roots.
    pub ca_file: Option<std::path::PathBuf>,
}

/// Where and how to connect: the driver's configuration and the TLS
/// connector (used when the URL's `sslmode` is `require` or `prefer`, or
/// a CA file is named).
#[derive(Clone)]
pub(crate) struct Endpoint {
    pub(super) config: tokio_postgres::Config,
    pub(super) tls: MakeRustlsConnect,
}

impl PgLocation {
    /// The URL without its password, for messages.
    pub fn redacted_url(&self) -> String {
        redacted(&self.url)
    }

    /// The URL parsed, the password read, TLS as asked: `sslmode=require`
    /// (or a CA file) checks the server's certificate against the CA file
    /// or the system's roots and its name against the URL's host.
    pub(super) fn endpoint(&self) -> Result<Endpoint, StoreError> {
        use tokio_postgres::config::SslMode;
        let mut config = self.config()?;
        let asked = ["disable", "prefer", "require"]
            .into_iter()
            .find(|mode| self.url.contains(&format!("sslmode={mode}")));
        let wanted = match (asked, &self.ca_file) {
            (Some("prefer"), _) => {
                return Err(StoreError::Location(
                    "sslmode=prefer is not supported (a connection that may fall back to plain \
                     text is not checked): use sslmode=require, or leave sslmode out for plain"
                        .into(),
                ));
            }
            (Some("disable"), Some(_)) => {
                return Err(StoreError::Location(
                    "a CA file with sslmode=disable: drop one of the two".into(),
                ));
            }
            (Some("require"), _) | (None, Some(_)) => true,
            _ => false,
        };
        if wanted {
            config.ssl_mode(SslMode::Require);
        }
        let roots = if wanted {
            crate::tls::roots(self.ca_file.as_deref())
                .map_err(|e| StoreError::Location(format!("TLS to PostgreSQL: {e}")))?
        } else {
            // Never used: the connection is plain.
            config.ssl_mode(SslMode::Disable);
            rustls::RootCertStore::empty()
        };
        let tls = crate::tls::builder()
            .map_err(|e| StoreError::Location(e.to_string()))?
            .with_root_certificates(roots)
            .with_no_client_auth();
        Ok(Endpoint {
            config,
            tls: MakeRustlsConnect::new(tls),
        })
    }

    /// The driver's configuration: the URL parsed, the password read.
    fn config(&self) -> Result<tokio_postgres::Config, StoreError> {
        let mut config = tokio_postgres::Config::from_str(&self.url)
            .map_err(|e| StoreError::Location(format!("{}: {e}", redacted(&self.url))))?;
        if let Some(file) = &self.password_file {
            config.password(read_password(file)?);
        }
        config.application_name("tunnelnav");
        // A host that drops packets is given up on, not waited for.
        config.connect_timeout(std::time::Duration::from_secs(10));
        config.keepalives_idle(std::time::Duration::from_secs(30));
        config.tcp_user_timeout(std::time::Duration::from_secs(30));
        Ok(config)
    }
}

/// The URL without its password, for messages (also a URL that does not
/// parse: whatever stands between `user:` and `@` is hidden).
pub fn redacted(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    match rest.rsplit_once('@') {
        Some((userinfo, host)) => match userinfo.split_once(':') {
            Some((user, _)) => format!("{scheme}://{user}:***@{host}"),
            None => url.to_string(),
        },
        None => url.to_string(),
    }
}

/// The first line of `file`, the password.
fn read_password(file: &Path) -> Result<String, StoreError> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| StoreError::Location(format!("password file {}: {e}", file.display())))?;
    Ok(text.lines().next().unwrap_or("").to_string())
}

/// The pool of reading connections.
pub(super) fn pool(endpoint: &Endpoint) -> Result<Pool, StoreError> {
    let manager = Manager::from_config(
        endpoint.config.clone(),
        endpoint.tls.clone(),
        ManagerConfig {
            recycling_method: RecyclingMethod::Fast,
        },
    );
    Pool::builder(manager)
        .max_size(READERS)
        .runtime(deadpool_postgres::Runtime::Tokio1)
        .wait_timeout(Some(std::time::Duration::from_secs(10)))
        .create_timeout(Some(std::time::Duration::from_secs(10)))
        .build()
        .map_err(|e| StoreError::Location(e.to_string()))
}

/// A connection, its driver task spawned on the current runtime. Not
/// reaching the server (refused, timed out) is [`StoreError::Unavailable`];
/// what the server answers (a wrong password, no such database) is its error.
pub(super) async fn connect(endpoint: &Endpoint) -> Result<tokio_postgres::Client, StoreError> {
    let (client, connection) = endpoint
        .config
        .connect(endpoint.tls.clone())
        .await
        .map_err(|e| {
            if e.code().is_some() {
                StoreError::Postgres(e)
            } else {
                StoreError::Unavailable(format!("cannot reach PostgreSQL: {}", with_causes(&e)))
            }
        })?;
    tokio::spawn(async move {
        if let Err(e) = connection.await {
            tracing::warn!(error = %e, "PostgreSQL connection ended");
        }
    });
    Ok(client)
}

/// An error with what caused it (a TLS handshake's reason, say).
pub(crate) fn with_causes(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(inner) = cause {
        text.push_str(": ");
        text.push_str(&inner.to_string());
        cause = inner.source();
    }
    text
}

/// A writing connection: [`connect`], and a transaction left idle for
/// 10 s (its host paused) is ended, so the leases it checked are not held
/// for ever.
pub(super) async fn connect_writer(
    endpoint: &Endpoint,
) -> Result<tokio_postgres::Client, StoreError> {
    let client = connect(endpoint).await?;
    client
        .batch_execute("SET idle_in_transaction_session_timeout = '10s'")
        .await?;
    Ok(client)
}
