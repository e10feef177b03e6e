//! Ingest: `POST .../readings` (one object, an array, or NDJSON) and the
//! ingest WebSocket (one object or an array per text frame). Both answer
//! `{"accepted", "duplicates", "rejected": [{"index", "error"}]}` after the
//! accepted readings are committed.

use std::time::Instant;

use axum::Json;
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::Response;
use serde_json::value::RawValue;

use super::error::{ApiError, Rejected};
use super::metrics;
pub use super::openapi::Ack;
use super::openapi::{MachinePath, ReadingsBody};
use super::settings::Limits;
use super::state::{AppState, SharedState};
use crate::clock::Clock;
use crate::fusion::{Reading, SensorKind, parse_reading};

/// The readings of one request, valid ones and refused ones.
#[derive(Debug, Default)]
pub struct ParsedBatch {
    pub readings: Vec<Reading>,
    pub rejected: Vec<Rejected>,
}

/// What the readings of a request must meet beyond the protocol's checks.
#[derive(Debug, Clone, Copy)]
pub struct BatchRules {
    /// Most readings in one request or frame.
    pub max_readings: usize,
    /// The server clock now, Unix seconds.
    pub now_s: f64,
    /// How far a reading's `t` may be ahead of `now_s` (gateway clock skew).
    pub max_future_s: f64,
}

impl BatchRules {
    /// The rules of `limits` at `clock`'s present.
    pub fn now(limits: &Limits, clock: &Clock) -> BatchRules {
        BatchRules {
            max_readings: limits.max_readings_per_request,
            now_s: clock.now_s(),
            max_future_s: limits.max_future_s,
        }
    }

    fn check(&self, reading: &Reading) -> Result<(), String> {
        let ahead_s = reading.t - self.now_s;
        if ahead_s > self.max_future_s {
            return Err(format!(
                "`t` = {} is {ahead_s:.0} s ahead of the server clock (at most {} s allowed): check the gateway's clock",
                reading.t, self.max_future_s
            ));
        }
        Ok(())
    }
}

/// Splits a body into readings: a JSON object, a JSON array of objects, or
/// (`ndjson`) one object per line. Each invalid reading is named by its
/// index; a body that is not JSON at all is a [`ApiError::BadRequest`].
pub fn parse_batch(body: &[u8], ndjson: bool, rules: &BatchRules) -> Result<ParsedBatch, ApiError> {
    let max_readings = rules.max_readings;
    let mut batch = ParsedBatch::default();
    let text = body.trim_ascii();
    if text.is_empty() {
        return Err(ApiError::BadRequest(
            "empty body: expected a reading, an array of readings or NDJSON".into(),
        ));
    }
    let too_many = || {
        ApiError::TooLarge(format!(
            "more than {max_readings} readings in one request; split the batch"
        ))
    };
    let mut take = |index: usize, bytes: &[u8]| match parse_reading(bytes)
        .map_err(|e| e.to_string())
        .and_then(|reading| {
            rules.check(&reading)?;
            Ok(reading)
        }) {
        Ok(reading) => batch.readings.push(reading),
        Err(error) => batch.rejected.push(Rejected {
            index,
            error,
            sensor: claimed_sensor(bytes),
        }),
    };
    if ndjson {
        for (index, line) in text
            .split(|&b| b == b'\n')
            .map(<[u8]>::trim_ascii)
            .filter(|l| !l.is_empty())
            .enumerate()
        {
            if index >= max_readings {
                return Err(too_many());
            }
            take(index, line);
        }
    } else if text.first() == Some(&b'[') {
        let items: Vec<&RawValue> = serde_json::from_slice(text).map_err(|e| {
            ApiError::BadRequest(format!("body is not a JSON array of readings: {e}"))
        })?;
        if items.len() > max_readings {
            return Err(too_many());
        }
        for (index, item) in items.into_iter().enumerate() {
            take(index, item.get().as_bytes());
        }
    } else if text.first() == Some(&b'{') {
        // Several lines of objects sent as plain JSON: say what to send.
        let lines = text
            .split(|&b| b == b'\n')
            .map(<[u8]>::trim_ascii)
            .filter(|l| !l.is_empty())
            .count();
        if lines > 1 && parse_reading(text).is_err() {
            return Err(ApiError::BadRequest(format!(
                "the body looks like NDJSON ({lines} lines of JSON objects) but was not sent as \
                 such: send it with Content-Type: application/x-ndjson, or as one JSON array"
            )));
        }
        take(0, text);
    } else {
        return Err(ApiError::BadRequest(
            "body is not JSON: expected a reading object, an array of readings, or NDJSON with Content-Type: application/x-ndjson".into(),
        ));
    }
    Ok(batch)
}

/// The `sensor` a refused reading named, if it names a known one.
fn claimed_sensor(bytes: &[u8]) -> Option<SensorKind> {
    #[derive(serde::Deserialize)]
    struct Probe<'a> {
        #[serde(borrow)]
        sensor: Option<&'a str>,
    }
    let probe: Probe = serde_json::from_slice(bytes).ok()?;
    SensorKind::from_name(probe.sensor?)
}

/// Stores and fuses a parsed batch in machine `id`, answering after the
/// commit (by the machine's successor if it is redeclared meanwhile).
pub(super) async fn ingest(
    state: &AppState,
    id: &str,
    batch: ParsedBatch,
) -> Result<Ack, ApiError> {
    let started = Instant::now();
    if let Some(site) = crate::config::forwarded_site(id) {
        return Err(ApiError::Conflict(format!(
            "machine `{id}` is site `{site}`'s: its readings come from the site's forwarding, \
             not from gateways"
        )));
    }
    metrics::rejected(id, &batch.rejected);
    if batch.readings.is_empty() {
        if batch.rejected.is_empty() {
            return Ok(Ack {
                accepted: 0,
                duplicates: 0,
                rejected: Vec::new(),
            });
        }
        return Err(ApiError::NoValidReading {
            rejected: batch.rejected,
        });
    }
    if state.machine(id).is_err()
        && let Some(cluster) = &state.cluster
    {
        return match cluster.route(id).await {
            super::cluster::Route::Forward(url) => {
                let ack = cluster.post_readings(&url, id, &batch.readings).await?;
                Ok(merge_forwarded(batch.rejected, ack))
            }
            super::cluster::Route::Unknown => Err(ApiError::UnknownMachine(id.to_string())),
            _ => Err(super::cluster::moving(id, "no node runs it this moment")),
        };
    }
    let counts = metrics::count_by_sensor(&batch.readings);
    let accepted = batch.readings.len();
    let outcome = state
        .on_machine(id, |machine| {
            let readings = batch.readings.clone();
            async move { machine.ingest(readings).await }
        })
        .await?;
    metrics::accepted(id, &counts, started.elapsed());
    Ok(Ack {
        accepted,
        duplicates: outcome.duplicates,
        rejected: batch.rejected,
    })
}

/// The answer to a batch whose valid readings (those not in `rejected`)
/// went on to another node: what that node refused, by its index among
/// them, is put back at its index in the batch.
fn merge_forwarded(rejected: Vec<Rejected>, forwarded: Ack) -> Ack {
    let refused_here: std::collections::BTreeSet<usize> =
        rejected.iter().map(|r| r.index).collect();
    let mut positions = (0..).filter(|i| !refused_here.contains(i));
    let mut there: Vec<(usize, Rejected)> = forwarded
        .rejected
        .into_iter()
        .map(|r| (r.index, r))
        .collect();
    there.sort_by_key(|(i, _)| *i);
    let mut next = 0;
    let mut all = rejected;
    for (index, mut refused) in there {
        // The `index`-th valid reading's place in the batch.
        let mut place = None;
        while next <= index {
            place = positions.next();
            next += 1;
        }
        if let Some(place) = place {
            refused.index = place;
            all.push(refused);
        }
    }
    all.sort_by_key(|r| r.index);
    Ack {
        accepted: forwarded.accepted,
        duplicates: forwarded.duplicates,
        rejected: all,
    }
}

/// Send readings.
///
/// `POST /api/v1/machines/{machine}/readings`.
#[utoipa::path(post, path = "/api/v1/machines/{machine}/readings", operation_id = "post_readings", tag = "readings",
    params(MachinePath),
    request_body(description = "One reading, an array of readings, or NDJSON (one reading per line, `Content-Type: application/x-ndjson`)",
        content((ReadingsBody = "application/json"), (String = "application/x-ndjson"))),
    responses(
        (status = OK, description = "The valid readings are stored (duplicates included) and fused; the invalid ones are listed by index", body = Ack),
        (status = BAD_REQUEST, description = "The body is not readings, or none of them is valid (then with `accepted: 0` and `rejected`)", body = super::error::ErrorBody)))]
pub async fn post_readings(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<Ack>, ApiError> {
    state.machine(&machine)?;
    let body = body.map_err(|rejection| {
        if rejection.status() == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::TooLarge(format!(
                "body larger than {} bytes; split the batch",
                state.limits.max_body_bytes
            ))
        } else {
            ApiError::BadRequest(format!("could not read the body: {rejection}"))
        }
    })?;
    let ndjson = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/x-ndjson"));
    let batch = parse_batch(&body, ndjson, &BatchRules::now(&state.limits, &state.clock))?;
    Ok(Json(ingest(&state, &machine, batch).await?))
}

/// Send readings (WebSocket).
///
/// `GET /api/v1/machines/{machine}/ingest`: WebSocket ingest.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/ingest", operation_id = "ingest_socket", tag = "readings",
    params(MachinePath),
    description = "WebSocket: each text frame holds one reading or an array; each is answered with an `Ack` (docs/protocol.md, \"Ingest WebSocket\").",
    responses(
        (status = SWITCHING_PROTOCOLS, description = "The socket is open"),
        (status = BAD_REQUEST, description = "Not a WebSocket upgrade request", body = super::error::ErrorBody)))]
pub async fn websocket(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    if !state.knows(&machine).await {
        return Err(ApiError::UnknownMachine(machine));
    }
    let upgrade = upgrade.map_err(ApiError::from)?;
    Ok(upgrade
        .max_message_size(state.limits.max_frame_bytes)
        .on_upgrade(move |socket| serve_ingest(socket, state, machine)))
}

/// Answers each frame; the machine is looked up per frame, so a socket
/// outlives a redeclaration of its machine.
async fn serve_ingest(mut socket: WebSocket, state: SharedState, machine: String) {
    let (limits, clock) = (state.limits, state.clock);
    while let Some(Ok(message)) = socket.recv().await {
        let answer = match message {
            Message::Text(text) => {
                match parse_batch(text.as_bytes(), false, &BatchRules::now(&limits, &clock)) {
                    Ok(batch) => ingest(&state, &machine, batch).await,
                    Err(e) => Err(e),
                }
            }
            Message::Binary(_) => Err(ApiError::BadRequest(
                "binary frames are not readings: send JSON text frames".into(),
            )),
            Message::Close(_) => break,
            Message::Ping(_) | Message::Pong(_) => continue,
        };
        let json = match answer {
            Ok(ack) => serde_json::to_string(&ack),
            Err(e) => {
                let mut body = e.body();
                body.status = Some(e.status().as_u16());
                serde_json::to_string(&body)
            }
        };
        let Ok(json) = json else { break };
        if socket.send(Message::Text(json.into())).await.is_err() {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(index: usize) -> Rejected {
        Rejected {
            index,
            error: format!("#{index}"),
            sensor: None,
        }
    }

    #[test]
    fn what_another_node_refused_keeps_its_place_in_the_batch() {
        // Of six readings, 1 and 4 refused here; the other node refused
        // the 0th and 2nd of the four it got: batch places 0 and 3.
        let ack = merge_forwarded(
            vec![refused(1), refused(4)],
            Ack {
                accepted: 2,
                duplicates: 0,
                rejected: vec![refused(2), refused(0)],
            },
        );
        let places: Vec<usize> = ack.rejected.iter().map(|r| r.index).collect();
        assert_eq!(places, [0, 1, 3, 4]);
        assert_eq!(ack.accepted, 2);
    }

    const GOOD: &str = r#"{"t":1772431200,"sensor":"inclinometer","pitch_deg":0.5,"roll_deg":1}"#;

    /// Rules at 2026-03-02T06:00:00Z, ten minutes of lead allowed.
    fn rules(max_readings: usize) -> BatchRules {
        BatchRules {
            max_readings,
            now_s: 1_772_431_200.0,
            max_future_s: 600.0,
        }
    }

    #[test]
    fn readings_ahead_of_the_server_clock_are_refused_by_index() {
        let body = r#"[{"t":1772431800,"sensor":"level","height_m":1},{"t":1772431801,"sensor":"level","height_m":1}]"#;
        let batch = parse_batch(body.as_bytes(), false, &rules(10)).unwrap();
        assert_eq!(batch.readings.len(), 1);
        assert_eq!(batch.rejected[0].index, 1);
        assert!(
            batch.rejected[0]
                .error
                .contains("ahead of the server clock"),
            "{}",
            batch.rejected[0].error
        );
        assert_eq!(batch.rejected[0].sensor, Some(SensorKind::Level));
    }

    #[test]
    fn arrays_name_each_bad_reading_by_index() {
        let body = format!(r#"[{GOOD},{{"t":1772431201,"sensor":"sonar"}},{GOOD},3]"#);
        let batch = parse_batch(body.as_bytes(), false, &rules(10)).unwrap();
        assert_eq!(batch.readings.len(), 2);
        let indices: Vec<usize> = batch.rejected.iter().map(|r| r.index).collect();
        assert_eq!(indices, vec![1, 3]);
        assert!(batch.rejected[0].error.contains("unknown sensor `sonar`"));
    }

    #[test]
    fn ndjson_counts_non_blank_lines() {
        let body = format!("{GOOD}\n\n{{\"t\":1}}\n{GOOD}\n");
        let batch = parse_batch(body.as_bytes(), true, &rules(10)).unwrap();
        assert_eq!(batch.readings.len(), 2);
        assert_eq!(batch.rejected[0].index, 1);
    }

    #[test]
    fn malformed_and_oversized_bodies_are_refused_whole() {
        assert!(matches!(
            parse_batch(b"[1,", false, &rules(10)),
            Err(ApiError::BadRequest(_))
        ));
        assert!(matches!(
            parse_batch(b"hello", false, &rules(10)),
            Err(ApiError::BadRequest(_))
        ));
        assert!(matches!(
            parse_batch(b"  ", false, &rules(10)),
            Err(ApiError::BadRequest(_))
        ));
        let body = format!("[{GOOD},{GOOD},{GOOD}]");
        assert!(matches!(
            parse_batch(body.as_bytes(), false, &rules(2)),
            Err(ApiError::TooLarge(_))
        ));
    }
}
