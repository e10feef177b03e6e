//! `tunnelnav serve [--listen ADDR] [--data-dir DIR] [--config FILE]`

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;

use super::CliError;
use crate::clock::Clock;
use crate::server::settings::{ServerConfig, ServerSettings};
use crate::server::{self, AppState, ServerOptions, SharedState};

/// Every flag can also come from the environment variable named in its
/// help (`TUNNELNAV_*`, for containers and systemd units); a flag given on
/// the command line wins.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "TUNNELNAV_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// Directory holding the database (created if missing).
    #[arg(long, env = "TUNNELNAV_DATA_DIR", default_value = "data")]
    pub data_dir: PathBuf,
    /// The PostgreSQL store, `postgres://USER@HOST:PORT/DB`, instead of
    /// SQLite in --data-dir (also the config file's `[store] url`).
    #[arg(long, env = "TUNNELNAV_STORE", value_name = "URL")]
    pub store: Option<String>,
    /// A file whose first line is the store's password (also `[store]
    /// password_file`).
    #[arg(long, env = "TUNNELNAV_STORE_PASSWORD_FILE", value_name = "FILE")]
    pub store_password_file: Option<PathBuf>,
    /// The CA (PEM) the store's certificate is checked against when its URL
    /// asks for TLS (`sslmode=require`; also `[store] ca_file`); default
    /// the system's roots.
    #[arg(long, env = "TUNNELNAV_STORE_CA_FILE", value_name = "FILE")]
    pub store_ca_file: Option<PathBuf>,
    /// This node's name among several serving one PostgreSQL store
    /// (default: the host's name; `NAME-2`, ... if a live server has it).
    #[arg(long, env = "TUNNELNAV_NODE", value_name = "NAME")]
    pub node: Option<String>,
    /// Where the other nodes reach this one, `http://HOST:PORT` (default:
    /// the address listened on, the host's name for 0.0.0.0).
    #[arg(long, env = "TUNNELNAV_ADVERTISE", value_name = "URL")]
    pub advertise: Option<String>,
    /// The cluster key file every node of one PostgreSQL store shares: one
    /// key a line (at least 32 characters), the first signs, any verifies;
    /// reread when it changes (docs/operations.md, "Several nodes").
    #[arg(long, env = "TUNNELNAV_CLUSTER_KEY_FILE", value_name = "FILE")]
    pub cluster_key_file: Option<PathBuf>,
    /// The office this site forwards everything it stores to,
    /// `http://HOST:PORT` (also the config file's `[forward] url`); needs
    /// --site.
    #[arg(long, env = "TUNNELNAV_FORWARD_TO", value_name = "URL")]
    pub forward_to: Option<String>,
    /// This site's name at the office, whose machines it names
    /// `{site}.{machine}` (also `[forward] site`).
    #[arg(long, env = "TUNNELNAV_SITE", value_name = "NAME")]
    pub site: Option<String>,
    /// A file whose first line is the office's `site` token for this site
    /// (also `[forward] token_file`).
    #[arg(long, env = "TUNNELNAV_FORWARD_TOKEN_FILE", value_name = "FILE")]
    pub forward_token_file: Option<PathBuf>,
    /// TOML file declaring machines, webhooks and limits (docs/operations.md).
    #[arg(long, env = "TUNNELNAV_CONFIG")]
    pub config: Option<PathBuf>,
    /// Serve with no access tokens on an address other than loopback:
    /// anyone who can reach the port may read, post and declare machines.
    #[arg(long, env = "TUNNELNAV_ALLOW_NO_AUTH")]
    pub allow_no_auth: bool,
    /// Delete raw readings older than this many days (default: keep all).
    /// Readings the latest engine snapshot does not cover yet are kept.
    #[arg(long, env = "TUNNELNAV_KEEP_READINGS_DAYS", value_name = "DAYS")]
    pub keep_readings_days: Option<f64>,
    /// Thin estimates older than this many days to one a minute (default:
    /// keep all); the per-bucket extremes stay.
    #[arg(long, env = "TUNNELNAV_KEEP_ESTIMATES_DAYS", value_name = "DAYS")]
    pub keep_estimates_days: Option<f64>,
    /// Cap the database file at this many megabytes: beyond, ingest
    /// answers 503 as on a full disk until retention or a larger cap makes
    /// room.
    #[arg(long, env = "TUNNELNAV_MAX_DATABASE_MB", value_name = "MB")]
    pub max_database_mb: Option<f64>,
    /// Seconds between retention passes.
    #[arg(
        long,
        env = "TUNNELNAV_RETENTION_EVERY_S",
        default_value_t = 3600.0,
        value_name = "SECONDS"
    )]
    pub retention_every_s: f64,
    /// The MQTT broker to take readings from and publish to:
    /// `mqtt://[user:password@]host[:port]` or `mqtts://` (TLS), with
    /// optional `?client_id=` (default `tunnelnav`); instead of the config
    /// file's `[mqtt] url`, whose other settings apply. docs/operations.md.
    #[arg(long, env = "TUNNELNAV_MQTT", value_name = "URL")]
    pub mqtt: Option<String>,
    /// Log lines as text or JSON objects.
    #[arg(long, env = "TUNNELNAV_LOG_FORMAT", value_enum, default_value = "text")]
    pub log_format: LogFormat,
}

impl ServeArgs {
    /// The retention policy these arguments ask for.
    fn retention(&self) -> crate::store::retention::Retention {
        let days = |d: Option<f64>| d.map(|d| d * 86_400.0);
        crate::store::retention::Retention {
            keep_readings_s: days(self.keep_readings_days),
            full_estimates_s: days(self.keep_estimates_days),
            every_s: self.retention_every_s,
        }
    }
}

pub fn run(args: ServeArgs) -> Result<(), CliError> {
    init_tracing(args.log_format);
    let settings = match &args.config {
        Some(path) => ServerConfig::load(path)?,
        None => ServerSettings::default(),
    };
    // The config file's limits, then the command line's database cap.
    let mut limits = settings.limits;
    if let Some(mb) = args.max_database_mb {
        limits.max_database_bytes = Some(crate::server::settings::database_cap_bytes(mb)?);
    }
    let mqtt = mqtt_settings(args.mqtt.as_deref(), &settings.mqtt)?;
    let postgres = crate::server::settings::store_location(
        args.store.as_deref(),
        crate::server::settings::StoreFiles {
            password_file: args.store_password_file.as_deref(),
            ca_file: args.store_ca_file.as_deref(),
        },
        &settings.store,
    )?;
    if postgres.is_none()
        && (args.node.is_some() || args.advertise.is_some() || args.cluster_key_file.is_some())
    {
        return Err(CliError::Refused(
            "--node, --advertise and --cluster-key-file are for several nodes on one \
             PostgreSQL store: \
             give --store postgres://... too"
                .into(),
        ));
    }
    let node = NodeArgs {
        node: args.node.clone(),
        advertise: args.advertise.clone(),
        cluster_key_file: args.cluster_key_file.clone(),
    };
    let forward = forward_options(&args, &settings.forward)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let options = ServerOptions {
            data_dir: args.data_dir.clone(),
            postgres,
            machines: settings.machines,
            limits,
            clock: Clock::system(),
            retention: args.retention(),
            webhooks: settings.webhooks,
            cluster: None,
            forward,
            site_backlog_alarm_s: settings.sites.backlog_alarm_s(),
            access_log: tracing::Level::INFO,
        };
        let (state, listener) = start(options, args.listen, args.allow_no_auth, node).await?;
        if let Some(mqtt) = mqtt {
            server::mqtt::spawn(state.clone(), mqtt);
        }
        server::run(listener, state, shutdown_signal()).await?;
        tracing::info!("stopped");
        Ok(())
    })
}

/// Where this site forwards to, if `--forward-to` or `[forward] url` says;
/// the flags win over the file.
fn forward_options(
    args: &ServeArgs,
    config: &crate::server::settings::ForwardConfig,
) -> Result<Option<server::forward::ForwardOptions>, CliError> {
    let office = args.forward_to.clone().or_else(|| config.url.clone());
    let site = args.site.clone().or_else(|| config.site.clone());
    let (office, site) = match (office, site) {
        (None, None) => return Ok(None),
        (Some(office), Some(site)) => (office, site),
        (Some(_), None) => {
            return Err(CliError::Refused(
                "--forward-to needs --site (this site's name at the office)".into(),
            ));
        }
        (None, Some(_)) => {
            return Err(CliError::Refused(
                "--site names this site at an office: give --forward-to URL too".into(),
            ));
        }
    };
    let token = match args
        .forward_token_file
        .as_ref()
        .or(config.token_file.as_ref())
    {
        Some(path) => Some(
            std::fs::read_to_string(path)
                .map_err(|source| CliError::File {
                    context: format!("cannot read the forward token file {}", path.display()),
                    source,
                })?
                .lines()
                .next()
                .unwrap_or_default()
                .trim()
                .to_string(),
        ),
        None => None,
    };
    let options = server::forward::ForwardOptions {
        office,
        site,
        token,
    };
    options
        .validate()
        .map_err(|e| CliError::Refused(e.to_string()))?;
    Ok(Some(options))
}

/// The broker's settings, if `url` (`--mqtt`) or the config file's
/// `[mqtt] url` names one (`serve`, `demo`).
pub fn mqtt_settings(
    url: Option<&str>,
    config: &crate::server::settings::MqttConfig,
) -> Result<Option<server::mqtt::MqttSettings>, CliError> {
    url.or(config.url.as_deref())
        .map(|url| server::mqtt::settings(url, config))
        .transpose()
        .map_err(|e| CliError::Refused(e.to_string()))
}

/// Opens the store, restores the machines, binds `listen` and prints
/// `listening on http://ADDR` as the first line on stdout (for scripts and
/// tests that pass port 0). Shared by `serve` and `demo`.
///
/// Beyond loopback a server needs access tokens: without any it refuses
/// to start unless `allow_no_auth` (and then says so loudly); with
/// `allow_no_auth` off it keeps demanding a token even if every token is
/// later revoked.
pub async fn start(
    mut options: ServerOptions,
    listen: SocketAddr,
    allow_no_auth: bool,
    node: NodeArgs,
) -> Result<(SharedState, tokio::net::TcpListener), CliError> {
    server::metrics::install();
    let data_dir = options.data_dir.clone();
    let where_tokens = match &options.postgres {
        Some(location) => format!("--store {}", location.redacted_url()),
        None => format!("--data-dir {}", data_dir.display()),
    };
    // Bound first: the other nodes are told the address.
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .map_err(|source| CliError::File {
            context: format!("cannot listen on {listen}"),
            source,
        })?;
    let address = listener.local_addr()?;
    if options.postgres.is_some() {
        let host = host_name();
        if let Some(name) = &node.node
            && !valid_node_name(name)
        {
            return Err(CliError::Refused(format!(
                "--node `{name}` is not a node name: use 1 to 64 letters, digits, `.`, `-` or `_`"
            )));
        }
        let keys = server::signing::ClusterKeys::load(node.cluster_key_file.as_deref())?;
        options.cluster = Some(server::cluster::ClusterOptions {
            keys: std::sync::Arc::new(keys),
            node: node.node.unwrap_or_else(|| host.clone()),
            advertise: node
                .advertise
                .map(|url| url.trim_end_matches('/').to_string())
                .unwrap_or_else(|| {
                    if address.ip().is_unspecified() {
                        format!("http://{host}:{}", address.port())
                    } else {
                        format!("http://{address}")
                    }
                }),
        });
    }
    let state = AppState::start(options).await?;
    if !listen.ip().is_loopback() {
        let tokens = state.store.active_tokens().await?;
        if tokens.is_empty() && !allow_no_auth {
            return Err(CliError::Refused(format!(
                "refusing to serve on {listen} without access tokens: anyone who can reach \
                 the port could read, post readings and declare machines. Create tokens \
                 (`tunnelnav token create {where_tokens} --scope admin`, one `--scope ingest \
                 --machine ID` per gateway), serve on 127.0.0.1 behind a reverse proxy, or pass \
                 --allow-no-auth to serve openly anyway"
            )));
        }
        if tokens.is_empty() {
            tracing::warn!(%listen, "SERVING WITHOUT AUTHENTICATION beyond loopback (--allow-no-auth): anyone who can reach the port may read, post readings and declare machines");
            eprintln!(
                "WARNING: serving on {listen} without access tokens (--allow-no-auth): anyone who can reach the port may read, post readings and declare machines"
            );
        }
    }
    if !listen.ip().is_loopback() && !allow_no_auth {
        state.gate.insist();
    }
    tracing::info!(%address, data_dir = %data_dir.display(), store = state.store.backend_name(), "tunnelnav serving");
    println!("listening on http://{address}");
    Ok((state, listener))
}

/// How this server names itself among several nodes (`serve --node`,
/// `--advertise`); unset: the host's name and the address listened on.
#[derive(Debug, Clone, Default)]
pub struct NodeArgs {
    pub node: Option<String>,
    pub advertise: Option<String>,
    pub cluster_key_file: Option<PathBuf>,
}

/// A node name: 1 to 64 letters, digits, `.`, `-` or `_` (it travels in
/// a header).
fn valid_node_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'))
}

/// This host's name (`node` if the kernel does not say).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|name| name.trim().to_string())
        .filter(|name| !name.is_empty())
        .unwrap_or_else(|| "node".to_string())
}

/// Resolves on Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut signal) => {
                signal.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = terminate => {},
    }
}

/// How log lines are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// One human-readable line per event (coloured on a terminal only).
    Text,
    /// One JSON object per line (for journald, Loki, Elasticsearch).
    Json,
}

/// Logs to stderr in `format`; `RUST_LOG` filters (default `info`). Colour
/// only when stderr is a terminal, so files and journald get plain text.
pub fn init_tracing(format: LogFormat) {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = match format {
        LogFormat::Text => builder
            .with_ansi(std::io::stderr().is_terminal())
            .try_init(),
        LogFormat::Json => builder.json().flatten_event(true).try_init(),
    };
}
