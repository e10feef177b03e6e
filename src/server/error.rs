//! The HTTP edge's error: every failure is a status code and a JSON body
//! `{"error": "...", ...}` naming what was wrong.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;

use crate::config::ConfigError;
use crate::machine::MachineError;
use crate::store::StoreError;

/// One reading refused, by its position in the request.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq, utoipa::ToSchema)]
pub struct Rejected {
    /// 0-based position in the array, or among the non-blank NDJSON lines.
    pub index: usize,
    pub error: String,
    /// The sensor the reading claimed, when that much was readable (metrics).
    #[serde(skip)]
    pub sensor: Option<crate::fusion::SensorKind>,
}

/// Why the server refused a request it could not serve now (503, counted
/// in `tunnelnav_refusals_total{reason}`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// The server is shutting down.
    ShuttingDown,
    /// The store cannot write now (disk or database cap full, I/O error).
    StoreUnavailable,
    /// The machine is being redeclared or restarted.
    MachineRestarting,
    /// The machine's ingest queue is full.
    MachineBusy,
    /// As many live sockets as allowed are open.
    TooManyClients,
    /// The request was not answered in time though it had arrived whole.
    Stalled,
    /// The machine is changing hands between server nodes.
    MachineMoving,
}

impl Refusal {
    /// Every reason, for registering the counter's series.
    pub const ALL: [Refusal; 7] = [
        Refusal::ShuttingDown,
        Refusal::StoreUnavailable,
        Refusal::MachineRestarting,
        Refusal::MachineBusy,
        Refusal::TooManyClients,
        Refusal::Stalled,
        Refusal::MachineMoving,
    ];

    /// The metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Refusal::ShuttingDown => "shutting_down",
            Refusal::StoreUnavailable => "store_unavailable",
            Refusal::MachineRestarting => "machine_restarting",
            Refusal::MachineBusy => "machine_busy",
            Refusal::TooManyClients => "too_many_clients",
            Refusal::Stalled => "stalled",
            Refusal::MachineMoving => "machine_moving",
        }
    }
}

/// Why a request failed.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    #[error("unknown machine `{0}`")]
    UnknownMachine(String),
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    BadRequest(String),
    #[error("method {method} is not allowed here")]
    MethodNotAllowed { method: String },
    #[error("no valid reading in the request")]
    NoValidReading { rejected: Vec<Rejected> },
    #[error("{0}")]
    TooLarge(String),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{message}")]
    Unavailable { reason: Refusal, message: String },
    #[error("internal error")]
    Internal(String),
    #[error("{0}")]
    Timeout(String),
    #[error("{0}")]
    Unauthorized(String),
    #[error("{0}")]
    Forbidden(String),
    /// The request conflicts with where a thing belongs (a site's machine
    /// changed at the office).
    #[error("{0}")]
    Conflict(String),
}

impl From<axum::extract::ws::rejection::WebSocketUpgradeRejection> for ApiError {
    fn from(rejection: axum::extract::ws::rejection::WebSocketUpgradeRejection) -> Self {
        ApiError::BadRequest(format!(
            "this endpoint is a WebSocket: {}",
            rejection.body_text()
        ))
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::Closed => ApiError::Unavailable {
                reason: Refusal::ShuttingDown,
                message: "the store is shutting down".into(),
            },
            e if e.is_transient() => ApiError::Unavailable {
                reason: Refusal::StoreUnavailable,
                message: format!(
                    "the store cannot write now ({e}); nothing of this request was stored, retry"
                ),
            },
            not_held @ StoreError::NotHeld { .. } => ApiError::Conflict(not_held.to_string()),
            other => ApiError::Internal(other.to_string()),
        }
    }
}

impl From<MachineError> for ApiError {
    fn from(e: MachineError) -> Self {
        match e {
            MachineError::Stopped(machine) => ApiError::Unavailable {
                reason: Refusal::MachineRestarting,
                message: format!(
                    "machine `{machine}` is restarting or the server is shutting down; retry"
                ),
            },
            MachineError::Store(e) => e.into(),
            busy @ MachineError::Busy { .. } => ApiError::Unavailable {
                reason: Refusal::MachineBusy,
                message: format!("{busy}; retry"),
            },
            other => ApiError::Internal(other.to_string()),
        }
    }
}

impl ApiError {
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::UnknownMachine(_) | ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::BadRequest(_) | ApiError::NoValidReading { .. } | ApiError::Config(_) => {
                StatusCode::BAD_REQUEST
            }
            ApiError::MethodNotAllowed { .. } => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::Unavailable { .. } => StatusCode::SERVICE_UNAVAILABLE,
            ApiError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
            ApiError::Timeout(_) => StatusCode::REQUEST_TIMEOUT,
            ApiError::Unauthorized(_) => StatusCode::UNAUTHORIZED,
            ApiError::Forbidden(_) => StatusCode::FORBIDDEN,
            ApiError::Conflict(_) => StatusCode::CONFLICT,
        }
    }

    /// The JSON body.
    pub fn body(&self) -> ErrorBody<'_> {
        let mut body = ErrorBody {
            error: self.to_string(),
            machine: None,
            accepted: None,
            rejected: None,
            status: None,
        };
        match self {
            ApiError::UnknownMachine(machine) => body.machine = Some(machine),
            ApiError::NoValidReading { rejected } => {
                body.accepted = Some(0);
                body.rejected = Some(rejected);
            }
            _ => {}
        }
        body
    }
}

/// Every error's JSON: what was wrong, and what it is about.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct ErrorBody<'a> {
    /// What was wrong, for a person.
    pub error: String,
    /// The unknown machine.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub machine: Option<&'a str>,
    /// With `rejected`: a request none of whose readings was valid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accepted: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Vec<Rejected>>)]
    pub rejected: Option<&'a [Rejected]>,
    /// The HTTP status, where the answer has none of its own (a socket).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub status: Option<u16>,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        if let ApiError::Internal(detail) = &self {
            // Details go to the log, not to the client.
            tracing::error!(%detail, "internal error");
        }
        let status = self.status();
        let mut response = (status, Json(self.body())).into_response();
        // Counted by the response middleware (`metrics::count_responses`).
        if let ApiError::Unavailable { reason, .. } = &self {
            response.extensions_mut().insert(*reason);
        }
        if status == StatusCode::SERVICE_UNAVAILABLE {
            response.headers_mut().insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from_static("1"),
            );
        }
        response
    }
}
