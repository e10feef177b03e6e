//! A request for a machine another node fuses, forwarded to that node
//! signed with the cluster key and naming the caller's token (the
//! middleware and the reverse proxy), and such a request checked where it
//! arrives.

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderName, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use std::time::Duration;

use super::{Cluster, Route, View, moving, whole_body};
use crate::fusion::Reading;
use crate::server::auth::Caller;
use crate::server::error::{ApiError, Refusal};
use crate::server::signing::{Grant, NODE_HEADER, Signable};
use crate::server::state::SharedState;

impl Cluster {
    /// The node and the grant of a request another node signed, or why it
    /// is refused (401): a signature under none of this node's keys, out
    /// of the replay window or replayed, or a node not live in `nodes`.
    pub async fn forwarded(
        &self,
        headers: &HeaderMap,
        (method, target, body): (&str, &str, &[u8]),
    ) -> Result<Grant, ApiError> {
        let request = Signable {
            to: &self.url,
            method,
            target,
            body,
        };
        let (node, grant) = self
            .keys
            .verify(headers, &request, crate::clock::wall_clock_s())?;
        let live = |view: &View| view.nodes.get(&node).is_some_and(|row| row.live);
        let mut known = self.view.read().map(|v| live(&v)).unwrap_or(false);
        if !known {
            self.refresh_if_stale().await;
            known = self.view.read().map(|v| live(&v)).unwrap_or(false);
        }
        if !known {
            return Err(ApiError::Unauthorized(format!(
                "a request signed as node `{node}`, which is not a live node of this store"
            )));
        }
        Ok(grant)
    }

    /// The headers that sign `request` as this node's, for `grant`; an
    /// error without a cluster key.
    pub(super) fn sign(
        &self,
        request: &Signable<'_>,
        grant: &Grant,
    ) -> Result<HeaderMap, ApiError> {
        let signed = self
            .keys
            .sign(request, &self.node, grant, crate::clock::wall_clock_s())
            .ok_or_else(|| ApiError::Unavailable {
                reason: Refusal::MachineMoving,
                message: format!(
                    "node `{}` has no cluster key (serve --cluster-key-file) to reach the node \
                     that fuses this machine with",
                    self.node
                ),
            })?;
        Ok(signed.into_iter().collect())
    }

    /// Sends `readings` of `machine` to the node at `url` (WebSocket and
    /// MQTT ingest for a machine fused elsewhere); its answer, the indices
    /// of what it refused among `readings`.
    pub async fn post_readings(
        &self,
        url: &str,
        machine: &str,
        readings: &[Reading],
    ) -> Result<crate::server::openapi::Ack, ApiError> {
        let mut body = String::new();
        for reading in readings {
            body.push_str(&reading.to_json());
            body.push('\n');
        }
        let target = format!("/api/v1/machines/{machine}/readings");
        let headers = self.sign(
            &Signable {
                to: url,
                method: "POST",
                target: &target,
                body: body.as_bytes(),
            },
            &Grant::Node,
        )?;
        let answer = self
            .http
            .post(format!("{url}{target}"))
            .headers(headers)
            .header("content-type", "application/x-ndjson")
            .body(body)
            .timeout(Duration::from_secs(30))
            .send()
            .await
            .map_err(|e| moving(machine, &format!("its node at {url} did not answer: {e}")))?;
        let status = answer.status();
        let text = answer
            .text()
            .await
            .map_err(|e| moving(machine, &format!("its node at {url} broke off: {e}")))?;
        if status == StatusCode::OK {
            return serde_json::from_str(&text)
                .map_err(|e| ApiError::Internal(format!("node at {url} answered {text}: {e}")));
        }
        let said = serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .and_then(|v| v["error"].as_str().map(str::to_string))
            .unwrap_or(text);
        Err(match status {
            StatusCode::BAD_REQUEST | StatusCode::PAYLOAD_TOO_LARGE => ApiError::BadRequest(said),
            // Its node changed hands, restarted (a new key) or is full:
            // for now.
            _ => moving(machine, &format!("its node answered {status}: {said}")),
        })
    }
}

/// The machine a path is about: `/api/v1/machines/{m}[/...]` or
/// `/machines/{m}`.
fn machine_of(path: &str) -> Option<String> {
    let rest = path
        .strip_prefix("/api/v1/machines/")
        .or_else(|| path.strip_prefix("/machines/"))?;
    let segment = rest.split('/').next()?;
    let machine = percent_decoded(segment)?;
    (!machine.is_empty()).then_some(machine)
}

/// A path segment as the router's `Path` reads it (`%XX` decoded); `None`
/// if it is not UTF-8 once decoded.
fn percent_decoded(segment: &str) -> Option<String> {
    let bytes = segment.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        match (bytes[i], bytes.get(i + 1), bytes.get(i + 2)) {
            (b'%', Some(&h), Some(&l)) if hex(h).is_some() && hex(l).is_some() => {
                out.push((hex(h)? * 16 + hex(l)?) as u8);
                i += 3;
            }
            (b, _, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).ok()
}

/// Headers that belong to one hop, not passed on.
fn hop_by_hop(name: &HeaderName) -> bool {
    matches!(
        name.as_str(),
        "host"
            | "connection"
            | "keep-alive"
            | "proxy-authenticate"
            | "proxy-authorization"
            | "te"
            | "trailer"
            | "transfer-encoding"
            | "upgrade"
            | "content-length"
    )
}

/// The route layer that sends a request for a machine fused by another
/// node to that node (after the caller's token was checked here), and
/// answers 503 while the machine changes hands. WebSocket upgrades stay:
/// their handlers follow a machine wherever it runs.
pub async fn forward(State(state): State<SharedState>, request: Request, next: Next) -> Response {
    let Some(cluster) = state.cluster.clone() else {
        return next.run(request).await;
    };
    let Some(machine) = machine_of(request.uri().path()) else {
        return next.run(request).await;
    };
    if request.headers().contains_key(axum::http::header::UPGRADE)
        || state.machine(&machine).is_ok()
    {
        return next.run(request).await;
    }
    let forwarded = request.headers().contains_key(NODE_HEADER);
    match cluster.route(&machine).await {
        Route::Unknown => next.run(request).await,
        Route::Forward(_) | Route::Moving if forwarded => {
            moving(&machine, "it is not running on the node it was sent to").into_response()
        }
        Route::Moving => moving(&machine, "no node runs it this moment").into_response(),
        Route::Forward(url) => match proxy(&state, &cluster, &url, request).await {
            Ok(response) => response,
            Err(e) => e.into_response(),
        },
    }
}

/// Sends `request` to the node at `url`; its answer, streamed back.
async fn proxy(
    state: &SharedState,
    cluster: &Cluster,
    url: &str,
    request: Request,
) -> Result<Response, ApiError> {
    let (parts, body) = request.into_parts();
    let machine = machine_of(parts.uri.path()).unwrap_or_default();
    let target = format!(
        "{url}{}",
        parts
            .uri
            .path_and_query()
            .map(|p| p.as_str())
            .unwrap_or("/")
    );
    let body = whole_body(body, state.limits.max_body_bytes).await?;
    let mut headers = HeaderMap::new();
    for (name, value) in &parts.headers {
        // A client's own `x-tunnelnav-*` never passes: only this node's.
        // Nor does its token: the signature names it.
        if !hop_by_hop(name)
            && !name.as_str().starts_with("x-tunnelnav-")
            && name != axum::http::header::AUTHORIZATION
            && name != axum::http::header::COOKIE
        {
            headers.append(name.clone(), value.clone());
        }
    }
    // Signed as the URL is sent (its path and query after parsing).
    let sent = reqwest::Url::parse(&target).map_err(|e| ApiError::Internal(e.to_string()))?;
    let sent_target = match sent.query() {
        Some(query) => format!("{}?{query}", sent.path()),
        None => sent.path().to_string(),
    };
    let grant = Grant::of(parts.extensions.get::<Caller>().and_then(|c| c.0.as_ref()));
    headers.extend(cluster.sign(
        &Signable {
            to: url,
            method: parts.method.as_str(),
            target: &sent_target,
            body: &body,
        },
        &grant,
    )?);
    let answer = cluster
        .http
        .request(parts.method.clone(), sent)
        .headers(headers)
        .body(body)
        .send()
        .await
        .map_err(|e| moving(&machine, &format!("its node at {url} did not answer: {e}")))?;
    let mut response = Response::builder().status(answer.status());
    if let Some(out) = response.headers_mut() {
        for (name, value) in answer.headers() {
            if !hop_by_hop(name) {
                out.append(name.clone(), value.clone());
            }
        }
    }
    response
        .body(Body::from_stream(answer.bytes_stream()))
        .map_err(|e| ApiError::Internal(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_machine_of_a_path() {
        let some = |m: &str| Some(m.to_string());
        assert_eq!(machine_of("/api/v1/machines/tbm-1"), some("tbm-1"));
        assert_eq!(machine_of("/api/v1/machines/tbm-1/readings"), some("tbm-1"));
        assert_eq!(machine_of("/machines/tbm-1"), some("tbm-1"));
        assert_eq!(machine_of("/api/v1/machines/m%31/readings"), some("m1"));
        assert_eq!(machine_of("/api/v1/machines/m%3"), some("m%3"));
        assert_eq!(machine_of("/api/v1/machines"), None);
        assert_eq!(machine_of("/api/v1/machines/"), None);
        assert_eq!(machine_of("/api/v1/alarms"), None);
    }
}
