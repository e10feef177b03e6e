//! `GET .../live`: every new estimate of a machine as a text frame, plus
//! control objects with an `event` field:
//! - `hello` on connect: the machine, its engines and the latest estimate
//!   of each (`latest`), so a page has something to show at once;
//! - `ping` every 10 s (`Limits::live_ping_interval`), so proxies and
//!   clients see a live socket;
//! - `gap` when this client fell more than [`crate::machine::LIVE_BUFFER`]
//!   estimates behind:
//!   `missed` estimates between `from_t` and `to_t` (exclusive) were not
//!   sent; fetch them from the history API. Ingest and other clients never
//!   wait for a slow client;
//! - `alarm` when one of the machine's alarms was raised, cleared or
//!   acknowledged: the stored alarm with its `transition`;
//! - `alarm_gap` when this client fell more than
//!   [`super::notify::ALARM_BUFFER`] alarm changes behind: fetch
//!   `GET /api/v1/alarms` again.
//!
//! `GET /api/v1/alarms/live` is the fleet's alarm socket: `hello` with the
//! active alarms of every machine, then `alarm`, `alarm_gap` and `ping`.

use std::sync::Arc;
use std::time::Duration;

use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, State};
use axum::response::Response;
use std::collections::BTreeMap;

use serde::Serialize;
use serde_json::value::RawValue;
use tokio::sync::broadcast;
use tokio::sync::broadcast::error::RecvError;

use super::error::{ApiError, Refusal};
use super::feeds::Followed;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::clock::Clock;
use crate::fusion::{EngineKind, StreamKind};
use crate::machine::LiveEstimate;
use crate::store::alarms::{AlarmChange, AlarmFilter, StoredAlarm};

/// Follow a machine (WebSocket).
///
/// `GET /api/v1/machines/{machine}/live`.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/live", operation_id = "live_socket", tag = "estimates",
    params(MachinePath),
    description = "WebSocket: a `hello` with the newest estimates and active alarms, then every estimate as it is made, `alarm` events and `ping`s (docs/protocol.md, \"Live stream\").",
    responses(
        (status = SWITCHING_PROTOCOLS, description = "The socket is open"),
        (status = BAD_REQUEST, description = "Not a WebSocket upgrade request", body = super::error::ErrorBody)))]
pub async fn websocket(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    let followed = follow(&state, &machine).await?;
    let upgrade = upgrade.map_err(ApiError::from)?;
    let (channels, active) = Channels::open(&state, Some(machine)).await?;
    let guard = state.live_socket();
    Ok(upgrade.on_upgrade(move |socket| async move {
        serve_live(socket, followed, active, channels).await;
        drop(guard);
    }))
}

/// The machine's estimates as they are made: from its task here, or (a
/// machine another node fuses) from the store as that node commits them.
async fn follow(state: &SharedState, id: &str) -> Result<Followed, ApiError> {
    let most = state.limits.max_live_clients_per_machine;
    let too_many = || ApiError::Unavailable {
        reason: Refusal::TooManyClients,
        message: format!("machine `{id}` already has {most} live clients, the most allowed"),
    };
    let remote = match (state.machine(id), &state.cluster) {
        (Ok(machine), _) => {
            if machine.live_clients() >= most {
                return Err(too_many());
            }
            // Subscribed before the latest is read, so nothing falls
            // between the two (an estimate may come twice; `t` tells).
            let estimates = machine.subscribe();
            return Ok(Followed {
                spec: machine.spec.clone(),
                estimates,
                latest: (*machine.status()).clone(),
            });
        }
        (Err(e), None) => return Err(e),
        (Err(e), Some(cluster)) => {
            let store = state.store.clone();
            let stored = tokio::task::spawn_blocking(move || store.machines())
                .await
                .map_err(|e| ApiError::Internal(e.to_string()))??;
            let Some(stored) = stored.into_iter().find(|m| m.spec.id == id) else {
                return Err(e);
            };
            (cluster.clone(), stored)
        }
    };
    let (cluster, stored) = remote;
    if cluster.feeds.clients(stored.db_id) >= most {
        return Err(too_many());
    }
    cluster
        .feeds
        .follow(&state.store, stored.spec, stored.db_id)
        .await
}

/// Follow every machine's alarms (WebSocket).
///
/// `GET /api/v1/alarms/live`: every machine's alarm changes.
#[utoipa::path(get, path = "/api/v1/alarms/live", operation_id = "alarms_socket", tag = "alarms",
    description = "WebSocket: a `hello` with the active alarms, then an `alarm` event for each raise, clear and acknowledgement, `alarm_gap` when some were missed, and `ping`s (docs/protocol.md).",
    responses(
        (status = SWITCHING_PROTOCOLS, description = "The socket is open"),
        (status = BAD_REQUEST, description = "Not a WebSocket upgrade request", body = super::error::ErrorBody)))]
pub async fn alarms_websocket(
    State(state): State<SharedState>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    let upgrade = upgrade.map_err(ApiError::from)?;
    let Some(counted) = state.alarm_socket() else {
        return Err(ApiError::Unavailable {
            reason: Refusal::TooManyClients,
            message: format!(
                "the fleet's alarm socket already has {} clients, the most allowed",
                state.limits.max_alarm_clients
            ),
        });
    };
    let (channels, active) = Channels::open(&state, None).await?;
    let guard = state.live_socket();
    Ok(upgrade.on_upgrade(move |socket| async move {
        serve_alarms(socket, active, channels).await;
        drop((guard, counted));
    }))
}

/// What a live socket listens to besides estimates.
struct Channels {
    alarm_changes: broadcast::Receiver<Arc<AlarmChange>>,
    ping_every: Duration,
    clock: Clock,
    shutdown: tokio::sync::watch::Receiver<bool>,
}

impl Channels {
    /// The channels of a new socket and the active alarms (of `machine`,
    /// or all), read after subscribing so that none falls between.
    async fn open(
        state: &SharedState,
        machine: Option<String>,
    ) -> Result<(Channels, Vec<StoredAlarm>), ApiError> {
        let alarm_changes = state.alarms.subscribe();
        let filter = AlarmFilter {
            machine,
            active_only: true,
            ..Default::default()
        };
        let active = super::alarms::stored(state, filter).await?;
        let channels = Channels {
            alarm_changes,
            ping_every: state.limits.live_ping_interval,
            clock: state.clock,
            shutdown: state.shutdown_signal(),
        };
        Ok((channels, active))
    }
}

/// What the live socket sends besides estimates, tagged by `event`.
#[derive(Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
enum Event<'a> {
    /// First: the machine, its engines, the newest estimate of each
    /// stream, and the clock.
    Hello {
        machine: &'a str,
        name: &'a str,
        engines: Vec<EngineKind>,
        latest: BTreeMap<StreamKind, Box<RawValue>>,
        /// The machine's active alarms, newest first.
        alarms: Vec<StoredAlarm>,
        server_t: f64,
        clock_rate: f64,
    },
    /// First on the fleet's alarm socket: every active alarm, newest first.
    #[serde(rename = "hello")]
    AlarmsHello {
        alarms: Vec<StoredAlarm>,
        server_t: f64,
        clock_rate: f64,
    },
    /// An alarm raised, cleared or acknowledged.
    Alarm {
        #[serde(flatten)]
        change: &'a AlarmChange,
    },
    /// `missed` alarm changes were not sent: fetch the list again.
    AlarmGap { missed: u64 },
    /// The client fell behind and `missed` estimates between the two
    /// times were dropped: fetch them from the history.
    Gap {
        missed: u64,
        from_t: Option<f64>,
        to_t: Option<f64>,
    },
    /// Keeps idle connections open; carries the clock.
    Ping { server_t: f64 },
}

fn text(event: Event<'_>) -> Message {
    // A tagged struct of plain fields always serialises.
    Message::Text(serde_json::to_string(&event).unwrap_or_default().into())
}

async fn serve_live(
    socket: WebSocket,
    followed: Followed,
    alarms: Vec<StoredAlarm>,
    channels: Channels,
) {
    let Followed {
        spec,
        estimates,
        latest: status,
    } = followed;
    let hello = text(Event::Hello {
        machine: &spec.id,
        name: &spec.name,
        engines: spec.engines.keys().copied().collect(),
        latest: status
            .latest
            .iter()
            .filter_map(|(&stream, e)| {
                Some((stream, RawValue::from_string(e.json.to_string()).ok()?))
            })
            .collect(),
        alarms,
        server_t: channels.clock.now_s(),
        clock_rate: channels.clock.rate(),
    });
    serve(socket, hello, Some((&spec.id, estimates)), channels).await;
}

async fn serve_alarms(socket: WebSocket, alarms: Vec<StoredAlarm>, channels: Channels) {
    let hello = text(Event::AlarmsHello {
        alarms,
        server_t: channels.clock.now_s(),
        clock_rate: channels.clock.rate(),
    });
    serve(socket, hello, None, channels).await;
}

/// Sends `hello`, then until either side closes: the machine's estimates
/// and its alarm changes (with `machine`), or every alarm change (the
/// fleet's socket), and pings.
async fn serve(
    mut socket: WebSocket,
    hello: Message,
    machine: Option<(&str, broadcast::Receiver<LiveEstimate>)>,
    channels: Channels,
) {
    let Channels {
        mut alarm_changes,
        ping_every,
        clock,
        mut shutdown,
    } = channels;
    let (only, mut estimates) = match machine {
        Some((id, estimates)) => (Some(id), Some(estimates)),
        None => (None, None),
    };
    if socket.send(hello).await.is_err() {
        return;
    }
    let mut ping = tokio::time::interval(ping_every);
    ping.tick().await;
    let mut last_t: Option<f64> = None;
    loop {
        tokio::select! {
            received = next_estimate(&mut estimates) => match received {
                Ok(estimate) => {
                    last_t = Some(estimate.t);
                    let frame = Message::Text(Utf8Bytes::from(estimate.json.to_string()));
                    if socket.send(frame).await.is_err() {
                        return;
                    }
                }
                Err(RecvError::Lagged(missed)) => {
                    // The next estimate still buffered bounds the gap.
                    let next = next_estimate(&mut estimates).await;
                    let to_t = next.as_ref().ok().map(|e| e.t);
                    let gap = Event::Gap { missed, from_t: last_t, to_t };
                    if socket.send(text(gap)).await.is_err() {
                        return;
                    }
                    if let Ok(estimate) = next {
                        last_t = Some(estimate.t);
                        let frame = Message::Text(Utf8Bytes::from(estimate.json.to_string()));
                        if socket.send(frame).await.is_err() {
                            return;
                        }
                    }
                }
                Err(RecvError::Closed) => {
                    close(socket, "machine reconfigured or stopped; reconnect").await;
                    return;
                }
            },
            changed = alarm_changes.recv() => {
                let event = match &changed {
                    Ok(change) if only.is_some_and(|id| change.alarm.machine != id) => continue,
                    Ok(change) => Event::Alarm { change },
                    Err(RecvError::Lagged(missed)) => Event::AlarmGap { missed: *missed },
                    // The server keeps the sender as long as it runs.
                    Err(RecvError::Closed) => return,
                };
                if socket.send(text(event)).await.is_err() {
                    return;
                }
            }
            _ = ping.tick() => {
                if socket.send(text(Event::Ping { server_t: clock.now_s() })).await.is_err() {
                    return;
                }
            }
            incoming = socket.recv() => match incoming {
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return,
                // Clients have nothing to say; anything else is ignored.
                Some(Ok(_)) => {}
            },
            () = stopping(&mut shutdown) => {
                close(socket, "server shutting down").await;
                return;
            }
        }
    }
}

/// The next estimate, or never (the fleet's alarm socket has none).
async fn next_estimate(
    estimates: &mut Option<broadcast::Receiver<LiveEstimate>>,
) -> Result<LiveEstimate, RecvError> {
    match estimates {
        Some(receiver) => receiver.recv().await,
        None => std::future::pending().await,
    }
}

/// Resolves when the server starts shutting down.
async fn stopping(shutdown: &mut tokio::sync::watch::Receiver<bool>) {
    let _ = shutdown.wait_for(|stopping| *stopping).await;
}

async fn close(mut socket: WebSocket, reason: &'static str) {
    let _ = socket
        .send(Message::Close(Some(CloseFrame {
            code: axum::extract::ws::close_code::AWAY,
            reason: reason.into(),
        })))
        .await;
}
