//! The office's side of forwarding: what sites send it and what it knows
//! of their links.
//!
//! - `POST /api/v1/machines/{site}.{machine}/forward`: a site's outbox
//!   rows for one machine, in order, each with its sequence. Declarations
//!   restart the machine from the site's engine state; readings are fused
//!   here in the site's order (so the estimates equal the site's); alarm
//!   changes are stored as the site made them. Each is applied once: the
//!   machine's mark (the last sequence committed here) is stored with
//!   what it brings, and the answer comes after that commit.
//! - `PUT /api/v1/sites/{site}`: the site's report of its backlog (every
//!   few seconds, also while it has nothing to send): the link's
//!   heartbeat.
//! - `GET /api/v1/sites`: each site's link, backlog and last contact.
//!
//! A site whose backlog is older than `[sites] backlog_alarm_s` (or that
//! has not been heard from for that long) raises `site_link` on each of
//! its machines here.

use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Path, State};
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;

use super::error::ApiError;
pub use super::forward::{ForwardAnswer, SiteReport};
pub use super::site_links::{SiteLinks, SiteStatus};
use super::state::SharedState;
use crate::config::{MachineSpec, forwarded_site, valid_machine_id};
use crate::fusion::alarms::AlarmKind;
use crate::fusion::reading::parse_reading;
use crate::machine::{ForwardedPart, MachineError};
use crate::store::StoreError;
use crate::store::alarms::{AlarmChange, AlarmRow, forwarded_rows};
use crate::store::outbox::Declared;

/// How far beyond this office's clock a site's sequence may be, seconds.
/// A site numbers its rows from its wall clock in microseconds when it
/// starts forwarding, then one a row: a day covers any clock's error and
/// more rows than a site writes in years.
pub const SEQUENCE_AHEAD_S: f64 = 86_400.0;

/// The highest sequence a site can have issued by `now_s` (this office's
/// clock): [`SEQUENCE_AHEAD_S`] beyond it, in microseconds.
pub fn highest_possible_sequence(now_s: f64) -> i64 {
    ((now_s + SEQUENCE_AHEAD_S) * 1e6) as i64
}

/// One outbox row of a site, as sent: its sequence and exactly one of
/// `machine`, `readings`, `alarm`.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ForwardItem {
    /// The site's outbox sequence: increasing, the idempotency key with
    /// the site and the machine.
    pub sequence: i64,
    /// The machine was (re)declared: its stored declaration and the state
    /// its engines go on from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub machine: Option<Declared>,
    /// Readings committed together, in the order the site stored them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Vec<Object>>)]
    pub readings: Option<Vec<Box<RawValue>>>,
    /// An alarm change the site made (as its live stream tells it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub alarm: Option<AlarmChange>,
}

/// What a site forwards for one machine.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ForwardBody {
    /// The sending site (the part of the machine's id before the dot).
    pub site: String,
    /// The last sequence of this machine the office answered committed,
    /// as the site recorded it (`null` before the first): an office whose
    /// own record is behind it has lost rows (restored from an old
    /// backup) and refuses, rather than leave a hole.
    #[serde(default)]
    pub after: Option<i64>,
    /// The rows, in sequence order.
    pub items: Vec<ForwardItem>,
}

/// `GET /api/v1/sites`.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SiteList {
    pub sites: Vec<SiteStatus>,
    /// The office's `[sites] backlog_alarm_s`.
    pub backlog_alarm_s: f64,
}

/// The path parameter naming a site.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct SitePath {
    /// The site's name: 1 to 64 ASCII letters, digits, `-` or `_`.
    #[param(pattern = r"^[A-Za-z0-9_-]{1,64}$", example = "north")]
    pub site: String,
}

/// Forward a site's outbox rows.
///
/// `POST /api/v1/machines/{site}.{machine}/forward`: what a site owes this
/// office for one machine (docs/protocol.md, "Sites and the office").
#[utoipa::path(post, path = "/api/v1/machines/{machine}/forward", operation_id = "forward", tag = "sites",
    params(super::openapi::MachinePath),
    request_body(content = ForwardBody, description = "The site's outbox rows for this machine, in sequence order"),
    responses(
        (status = OK, description = "Every row up to `applied` is committed here (rows committed before are not applied again)", body = ForwardAnswer),
        (status = BAD_REQUEST, description = "Not a site's machine, or a row is malformed", body = super::error::ErrorBody),
        (status = NOT_FOUND, description = "Rows of a machine whose declaration has not come first", body = super::error::ErrorBody)))]
pub async fn forward(
    State(state): State<SharedState>,
    Path(super::openapi::MachinePath { machine }): Path<super::openapi::MachinePath>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<ForwardAnswer>, ApiError> {
    let Some((site, own_id)) = machine.split_once('.') else {
        return Err(ApiError::BadRequest(format!(
            "`{machine}` is not a site's machine: forwarded machines are named `{{site}}.{{machine}}`"
        )));
    };
    if !(valid_machine_id(site) && valid_machine_id(own_id)) {
        return Err(ApiError::BadRequest(format!(
            "`{machine}` is not a site's machine: site and machine are each 1 to 64 letters, digits, `-` or `_`"
        )));
    }
    let body = body.map_err(|e| ApiError::BadRequest(format!("could not read the body: {e}")))?;
    let body: ForwardBody = serde_json::from_slice(&body)
        .map_err(|e| ApiError::BadRequest(format!("body is not a site's forwarding: {e}")))?;
    if body.site != site {
        return Err(ApiError::BadRequest(format!(
            "site `{}` sent rows of `{machine}`, which belongs to site `{site}`",
            body.site
        )));
    }
    note_contact(&state, site, None).await;
    let serial = state.sites.forwarding(site);
    let _serial = serial.lock().await;
    let committed = state.forward_mark(&machine).await?;
    if let Some(after) = body.after
        && committed.is_none_or(|mark| mark < after)
    {
        return Err(ApiError::Conflict(format!(
            "`{machine}`: this office holds its rows up to sequence {committed:?}, but the site \
             had them committed up to {after}: the office lost rows (restored from an older \
             backup?); declare the machine afresh at the site"
        )));
    }
    // Every row checked and read before any is applied.
    let highest = highest_possible_sequence(crate::clock::wall_clock_s());
    let rows = read_rows(body.items, highest)?;
    let applied = rows.last().map_or(0, |(sequence, _)| *sequence);
    let mut parts = Vec::new();
    for (sequence, row) in rows {
        match row {
            Row::Declared(declared) => {
                apply_parts(
                    &state,
                    (&machine, site),
                    std::mem::take(&mut parts),
                    body.after,
                )
                .await?;
                declaration_held(&state, (&machine, site), sequence, body.after).await?;
                let spec = forwarded_spec(&machine, declared.spec)?;
                state
                    .declare_forwarded(spec, declared.snapshot, sequence)
                    .await?;
            }
            Row::Part(part) => parts.push((sequence, part)),
        }
    }
    apply_parts(&state, (&machine, site), parts, body.after).await?;
    // What is committed now (each part answered after its commit): a row
    // whose write failed behind an earlier answer is not claimed.
    let committed = state.forward_mark(&machine).await?.unwrap_or(0);
    Ok(Json(ForwardAnswer {
        machine,
        applied: committed.min(applied),
    }))
}

/// The longest alarm message a site may forward (this release's own are
/// under 200 characters; reports print every one).
pub const MAX_ALARM_MESSAGE_CHARS: usize = 1000;

/// A forwarded alarm's texts within bounds, as any declared name is:
/// `message` at most [`MAX_ALARM_MESSAGE_CHARS`], the others at most
/// [`crate::config::MAX_NAME_CHARS`].
fn bounded_alarm_texts(
    sequence: i64,
    alarm: &crate::store::alarms::StoredAlarm,
) -> Result<(), ApiError> {
    let name = crate::config::MAX_NAME_CHARS;
    let texts = [
        ("machine", alarm.machine.as_str(), name),
        ("kind", alarm.kind.as_str(), name),
        ("severity", alarm.severity.as_str(), name),
        ("subject", alarm.subject.as_str(), name),
        ("message", alarm.message.as_str(), MAX_ALARM_MESSAGE_CHARS),
        ("acked_by", alarm.acked_by.as_deref().unwrap_or(""), name),
    ];
    for (field, text, most) in texts {
        let chars = text.chars().count();
        if chars > most {
            return Err(ApiError::BadRequest(format!(
                "sequence {sequence}: the alarm's `{field}` has {chars} characters; at most {most}"
            )));
        }
    }
    Ok(())
}

/// A forwarded row, read.
enum Row {
    Declared(Declared),
    Part(ForwardedPart),
}

/// The site's rows checked (sequences increasing and within `highest`,
/// one thing each, no office alarm, texts within bounds) and read.
fn read_rows(items: Vec<ForwardItem>, highest: i64) -> Result<Vec<(i64, Row)>, ApiError> {
    let mut rows = Vec::with_capacity(items.len());
    let mut before = 0;
    for item in items {
        let sequence = item.sequence;
        if sequence <= before {
            return Err(ApiError::BadRequest(format!(
                "sequence {sequence} is not above the one before it ({before})"
            )));
        }
        if sequence > highest {
            return Err(ApiError::BadRequest(format!(
                "sequence {sequence} is beyond any a site can have issued by now (at most \
                 {highest}: sites number their rows from their clock in microseconds, and this \
                 office allows a day ahead of its own)"
            )));
        }
        before = sequence;
        let row = match (item.machine, item.readings, item.alarm) {
            (Some(declared), None, None) => Row::Declared(declared),
            (None, Some(raw), None) => {
                let mut readings = Vec::with_capacity(raw.len());
                for (index, raw) in raw.iter().enumerate() {
                    readings.push(parse_reading(raw.get().as_bytes()).map_err(|e| {
                        ApiError::BadRequest(format!("sequence {sequence}, reading {index}: {e}"))
                    })?);
                }
                Row::Part(ForwardedPart::Readings(readings))
            }
            (None, None, Some(change)) => {
                let own = [AlarmKind::SiteLink, AlarmKind::ForwardRefused];
                if own.iter().any(|kind| change.alarm.kind == kind.as_str()) {
                    return Err(ApiError::BadRequest(format!(
                        "sequence {sequence}: `{}` is the office's own alarm",
                        change.alarm.kind
                    )));
                }
                bounded_alarm_texts(sequence, &change.alarm)?;
                // The rows that bring the stored alarm to where the site's
                // change left it; a kind or severity this release does not
                // know is applied as nothing (its sequence still counts).
                let (rows, ack) = forwarded_rows(&change).unwrap_or_else(|| {
                    tracing::warn!(
                        sequence, kind = %change.alarm.kind,
                        "a forwarded alarm of a kind or severity this release does not know: not stored"
                    );
                    (Vec::new(), None)
                });
                Row::Part(ForwardedPart::Alarm {
                    rows,
                    ack: ack.map(Box::new),
                })
            }
            _ => {
                return Err(ApiError::BadRequest(format!(
                    "sequence {sequence}: a row holds exactly one of `machine`, `readings`, `alarm`"
                )));
            }
        };
        rows.push((sequence, row));
    }
    Ok(rows)
}

/// Fuses and stores a run of readings and alarm changes in the machine;
/// refused with `forward_refused` if a part at or below its mark is not
/// a row this office holds (the machine's task checks, against the mark it
/// goes on from).
async fn apply_parts(
    state: &SharedState,
    (machine, site): (&str, &str),
    parts: Vec<(i64, ForwardedPart)>,
    confirmed: Option<i64>,
) -> Result<(), ApiError> {
    if parts.is_empty() {
        return Ok(());
    }
    let not_held = state
        .on_machine(machine, |handle| {
            let parts = parts.clone();
            async move {
                match handle.forwarded(parts, confirmed).await {
                    Ok(_) => Ok(None),
                    Err(MachineError::Store(StoreError::NotHeld { sequence, mark })) => {
                        Ok(Some((sequence, mark)))
                    }
                    Err(e) => Err(e),
                }
            }
        })
        .await?;
    match not_held {
        None => Ok(()),
        Some((sequence, mark)) => {
            Err(refuse_not_held(state, (machine, site), (sequence, mark), confirmed).await)
        }
    }
}

/// A redeclaration at or below the machine's mark is skipped as applied
/// only if this office holds it; else refused as [`apply_parts`] does.
async fn declaration_held(
    state: &SharedState,
    (machine, site): (&str, &str),
    sequence: i64,
    confirmed: Option<i64>,
) -> Result<(), ApiError> {
    let Some(mark) = state.forward_mark(machine).await? else {
        return Ok(());
    };
    if sequence > mark || confirmed.is_some_and(|c| sequence <= c) {
        return Ok(());
    }
    let db_id = state.machine(machine)?.db_id;
    let store = state.store.clone();
    let held = tokio::task::spawn_blocking(move || store.forward_held(db_id))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))??;
    if held.holds(sequence) {
        return Ok(());
    }
    Err(refuse_not_held(state, (machine, site), (sequence, mark), confirmed).await)
}

/// A `forward_refused` row of `site`'s machine: raised (or cleared) at `t`.
fn forward_refused(site: &str, raised: bool, t: f64, message: String) -> AlarmRow {
    AlarmRow {
        kind: AlarmKind::ForwardRefused.as_str(),
        severity: crate::fusion::alarms::Severity::Alarm.as_str(),
        subject: site.to_string(),
        raised,
        t,
        message,
    }
}

/// The 409 of a site's row at or below the machine's `mark` that this
/// office does not hold, with `forward_refused` raised: the mark moved past
/// rows this office never had (a forged or foreign sequence), and claiming
/// them applied would have the site delete them.
async fn refuse_not_held(
    state: &SharedState,
    (machine, site): (&str, &str),
    (sequence, mark): (i64, i64),
    confirmed: Option<i64>,
) -> ApiError {
    let back_to = confirmed.unwrap_or(0);
    let message = format!(
        "site `{site}` forwarded rows of `{machine}` from sequence {sequence}, at or below this \
         office's mark {mark}, which it does not hold (a forged or foreign sequence moved the \
         mark?): they are refused and stay at the site. Once checked, an admin sets the mark \
         back to the site's last confirmed sequence (not lower): PUT \
         /api/v1/machines/{machine}/forward-mark {{\"sequence\": {back_to}}}"
    );
    tracing::warn!(%machine, %site, sequence, mark, "forwarded rows below the mark not held here: refused");
    let row = forward_refused(site, true, state.clock.now_s(), message.clone());
    match state.machine(machine) {
        Ok(handle) => {
            if let Err(e) = handle.alarms(vec![row]).await {
                tracing::warn!(%machine, error = %e, "forward_refused not stored");
            }
        }
        Err(e) => tracing::warn!(%machine, error = %e, "forward_refused not stored"),
    }
    ApiError::Conflict(message)
}

/// A forwarded machine's mark, set back.
#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MarkReset {
    /// The sequence the office's mark goes back to: the site's last
    /// confirmed one (the `forward_refused` alarm names it); never
    /// forward.
    pub sequence: i64,
}

/// The mark as set back.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct MarkAnswer {
    pub machine: String,
    /// The mark now.
    pub sequence: i64,
    /// The mark before.
    pub was: i64,
}

/// Set a site's machine's mark back.
///
/// `PUT /api/v1/machines/{site}.{machine}/forward-mark`: after a
/// `forward_refused` alarm, the office's mark of the machine goes back to
/// the sequence given (never forward), recorded in the audit log with the
/// admin's token name; the alarm clears and the site's refused rows apply
/// at its next try (rows the office already holds are not applied twice).
#[utoipa::path(put, path = "/api/v1/machines/{machine}/forward-mark", operation_id = "reset_forward_mark", tag = "sites",
    params(super::openapi::MachinePath),
    request_body(content = MarkReset, description = "The sequence the mark goes back to"),
    responses(
        (status = OK, description = "The mark set back (audited)", body = MarkAnswer),
        (status = BAD_REQUEST, description = "Not a site's machine, or a sequence above the mark or below 0", body = super::error::ErrorBody),
        (status = NOT_FOUND, description = "No such machine", body = super::error::ErrorBody),
        (status = CONFLICT, description = "The machine has no mark yet: nothing forwarded", body = super::error::ErrorBody)))]
pub async fn reset_mark(
    State(state): State<SharedState>,
    Path(super::openapi::MachinePath { machine }): Path<super::openapi::MachinePath>,
    caller: Option<axum::Extension<super::auth::Caller>>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<MarkAnswer>, ApiError> {
    let Some((site, _)) = machine.split_once('.') else {
        return Err(ApiError::BadRequest(format!(
            "`{machine}` is not a site's machine: forwarded machines are named `{{site}}.{{machine}}`"
        )));
    };
    let body = body.map_err(|e| ApiError::BadRequest(format!("could not read the body: {e}")))?;
    let reset: MarkReset = serde_json::from_slice(&body)
        .map_err(|e| ApiError::BadRequest(format!("body is not {{\"sequence\": N}}: {e}")))?;
    let handle = state.machine(&machine)?;
    let Some(mark) = state.forward_mark(&machine).await? else {
        return Err(ApiError::Conflict(format!(
            "`{machine}` has no mark: nothing was forwarded for it"
        )));
    };
    if !(0..=mark).contains(&reset.sequence) {
        return Err(ApiError::BadRequest(format!(
            "`{machine}`'s mark is {mark}: it goes back to a sequence from 0 to {mark}, not {}",
            reset.sequence
        )));
    }
    let actor =
        super::auth::Caller::recorded(caller.as_ref().map(|axum::Extension(caller)| caller));
    let now_t = state.clock.now_s();
    let was = state
        .store
        .reset_forward_mark(machine.clone(), reset.sequence, actor.clone(), now_t)
        .await?
        .unwrap_or(mark);
    handle
        .set_forward_mark(reset.sequence)
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    tracing::warn!(%machine, %actor, was, sequence = reset.sequence, "forward mark set back");
    let cleared = forward_refused(
        site,
        false,
        now_t,
        format!("mark set back from {was} to {} by {actor}", reset.sequence),
    );
    if let Err(e) = handle.alarms(vec![cleared]).await {
        tracing::warn!(%machine, error = %e, "forward_refused not cleared");
    }
    Ok(Json(MarkAnswer {
        machine,
        sequence: reset.sequence,
        was,
    }))
}

/// The site's stored declaration as this office's machine `id`
/// (`{site}.{machine}`), checked as a declaration made here would be.
fn forwarded_spec(id: &str, spec: serde_json::Value) -> Result<MachineSpec, ApiError> {
    let spec: MachineSpec = serde_json::from_value(spec).map_err(|e| {
        ApiError::BadRequest(format!(
            "machine `{id}`: the site's declaration is not one this release reads: {e}"
        ))
    })?;
    let own = id.split_once('.').map_or(id, |(_, own)| own);
    let mut spec = spec
        .upgraded()?
        .declaration()
        .validate(own)
        .map_err(ApiError::from)?;
    spec.id = id.to_string();
    Ok(spec)
}

/// Records that `site` was heard from (and what it reported).
async fn note_contact(state: &SharedState, site: &str, report: Option<&SiteReport>) {
    let now_t = state.clock.now_s();
    if let Some(record) = state.sites.contact(site, now_t, report)
        && let Err(e) = state.store.put_site(record).await
    {
        tracing::warn!(%site, error = %e, "site's contact not stored");
    }
}

/// Report a site's backlog.
///
/// `PUT /api/v1/sites/{site}`: the site's heartbeat, with what it has not
/// sent yet.
#[utoipa::path(put, path = "/api/v1/sites/{site}", operation_id = "report_site", tag = "sites",
    params(SitePath),
    request_body(content = SiteReport, description = "What the site has not sent yet"),
    responses((status = OK, description = "Noted; the site's link as the office now sees it", body = SiteStatus)))]
pub async fn report(
    State(state): State<SharedState>,
    Path(SitePath { site }): Path<SitePath>,
    body: Result<Json<SiteReport>, axum::extract::rejection::JsonRejection>,
) -> Result<Json<SiteStatus>, ApiError> {
    if !valid_machine_id(&site) {
        return Err(ApiError::BadRequest(format!(
            "site `{site}` is not a site name: 1 to 64 letters, digits, `-` or `_`"
        )));
    }
    let Json(report) =
        body.map_err(|e| ApiError::BadRequest(format!("body is not a site report: {e}")))?;
    if [report.backlog_items, report.backlog_readings]
        .iter()
        .any(|&n| i64::try_from(n).is_err())
    {
        return Err(ApiError::BadRequest(
            "`backlog_items` and `backlog_readings` must be at most 2^63 - 1".into(),
        ));
    }
    if !report.oldest_unsent_s.is_finite() {
        return Err(ApiError::BadRequest(
            "`oldest_unsent_s` must be a number of seconds".into(),
        ));
    }
    note_contact(&state, &site, Some(&report)).await;
    statuses(&state)
        .into_iter()
        .find(|s| s.site == site)
        .map(Json)
        .ok_or_else(|| ApiError::Internal(format!("site `{site}` not recorded")))
}

/// The sites' links.
///
/// `GET /api/v1/sites`: each site this office has heard from.
#[utoipa::path(get, path = "/api/v1/sites", operation_id = "list_sites", tag = "sites",
    responses((status = OK, description = "Each site's link, backlog and last contact", body = SiteList)))]
pub async fn list(State(state): State<SharedState>) -> Json<SiteList> {
    Json(SiteList {
        sites: statuses(&state),
        backlog_alarm_s: state.site_backlog_alarm_s,
    })
}

/// Every site's status now.
fn statuses(state: &SharedState) -> Vec<SiteStatus> {
    let machines: Vec<String> = state
        .all_machines()
        .iter()
        .map(|m| m.spec.id.clone())
        .collect();
    state
        .sites
        .statuses(state.clock.now_s(), &machines, state.site_backlog_alarm_s)
}

/// Every second: the sites' gauges, and `site_link` raised or cleared on
/// each machine of a site whose backlog crossed the limit.
pub async fn watch(state: SharedState) {
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut stopping = state.shutdown_signal();
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stopping.changed() => return,
        }
        let now_t = state.clock.now_s();
        let limit_s = state.site_backlog_alarm_s;
        if state.cluster.is_some() {
            // Sites may report to any node.
            let store = state.store.clone();
            match tokio::task::spawn_blocking(move || store.sites()).await {
                Ok(Ok(records)) => state.sites.merge(records),
                Ok(Err(e)) => tracing::warn!(error = %e, "sites not read"),
                Err(e) => tracing::warn!(error = %e, "sites not read"),
            }
        }
        for status in statuses(&state) {
            super::metrics::forward_link(
                &status.site,
                status.connected,
                status.backlog_readings,
                status.oldest_unsent_s,
            );
        }
        for (site, raise, since_t, message) in state.sites.alarm_changes(now_t, limit_s) {
            let row = AlarmRow {
                kind: crate::fusion::alarms::AlarmKind::SiteLink.as_str(),
                severity: crate::fusion::alarms::Severity::Alarm.as_str(),
                subject: site.clone(),
                raised: raise,
                t: if raise { since_t } else { now_t },
                message,
            };
            let mut stored = true;
            for machine in state.all_machines() {
                if forwarded_site(&machine.spec.id) != Some(site.as_str()) {
                    continue;
                }
                if let Err(e) = machine.alarms(vec![row.clone()]).await {
                    tracing::warn!(machine = %machine.spec.id, error = %e, "site_link not stored; tried again");
                    stored = false;
                }
            }
            if stored {
                state.sites.alarm_stored(&site, raise);
            }
        }
    }
}
