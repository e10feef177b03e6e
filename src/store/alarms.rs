//! Alarms as stored: one row per raised alarm, cleared and acknowledged in
//! place, so the table is also the audit log (who acknowledged what, when).
//! Rows are written in the same transaction as the readings that raised or
//! cleared them; a transition recomputed after a restart (the same machine,
//! kind, severity, subject and time) is stored once.

use serde::Serialize;

use crate::fusion::alarms::Transition;

/// A raised or cleared alarm to write with its machine's readings.
#[derive(Debug, Clone, PartialEq)]
pub struct AlarmRow {
    pub kind: &'static str,
    pub severity: &'static str,
    pub subject: String,
    pub raised: bool,
    pub t: f64,
    pub message: String,
}

impl AlarmRow {
    /// The row of a transition.
    pub fn new(transition: &Transition) -> AlarmRow {
        AlarmRow {
            kind: transition.key.kind.as_str(),
            severity: transition.key.severity.as_str(),
            subject: transition.key.subject.clone(),
            raised: transition.raised,
            t: transition.t,
            message: transition.message.clone(),
        }
    }
}

/// An office: the rows that bring a forwarded machine's alarms to where a
/// change its site made left them (the raise, stored once, before a clear
/// or an acknowledgement, so the office holds the alarm even if it missed
/// the raise), and the acknowledgement; `None` for a kind or severity this
/// release does not know, or an office's own `site_link` or
/// `forward_refused`.
pub fn forwarded_rows(
    change: &AlarmChange,
) -> Option<(Vec<AlarmRow>, Option<super::outbox::ForwardedAck>)> {
    use crate::fusion::alarms::{AlarmKind, Severity};
    let alarm = &change.alarm;
    // `site_link` and `forward_refused` are an office's own: no site
    // raises them.
    let kind = AlarmKind::from_name(&alarm.kind)
        .filter(|kind| !matches!(kind, AlarmKind::SiteLink | AlarmKind::ForwardRefused))?
        .as_str();
    let severity = Severity::from_name(&alarm.severity)?.as_str();
    let row = |raised: bool, t: f64| AlarmRow {
        kind,
        severity,
        subject: alarm.subject.clone(),
        raised,
        t,
        message: alarm.message.clone(),
    };
    let mut rows = vec![row(true, alarm.raised_t)];
    if let Some(cleared_t) = alarm.cleared_t {
        rows.push(row(false, cleared_t));
    }
    let ack = match (change.transition, alarm.acked_t, &alarm.acked_by) {
        (Change::Acknowledged, Some(acked_t), Some(by)) => Some(super::outbox::ForwardedAck {
            kind: kind.to_string(),
            severity: severity.to_string(),
            subject: alarm.subject.clone(),
            raised_t: alarm.raised_t,
            acked_t,
            by: by.clone(),
        }),
        _ => None,
    };
    Some((rows, ack))
}

/// A stored alarm, as the API lists it.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct StoredAlarm {
    pub id: i64,
    pub machine: String,
    #[schema(value_type = crate::fusion::alarms::AlarmKind)]
    pub kind: String,
    #[schema(value_type = crate::fusion::alarms::Severity)]
    pub severity: String,
    /// What it concerns (a sensor for `stale_sensor`), or empty.
    pub subject: String,
    pub message: String,
    pub raised_t: f64,
    pub cleared_t: Option<f64>,
    pub acked_t: Option<f64>,
    /// The name of the token that acknowledged it.
    pub acked_by: Option<String>,
    /// An active alarm of a machine running on this node: what its
    /// quantity reads now (the message keeps the value at the raise).
    /// Not stored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub now: Option<crate::fusion::alarms::AlarmNow>,
}

/// What happened to a stored alarm: the live event's `transition`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Change {
    Raised,
    Cleared,
    Acknowledged,
}

/// A stored alarm as one transition left it (for live clients and
/// webhooks).
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct AlarmChange {
    pub transition: Change,
    #[serde(flatten)]
    pub alarm: StoredAlarm,
}

/// Which alarms to list.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AlarmFilter {
    /// One machine's (its protocol id), or every machine's.
    pub machine: Option<String>,
    /// Only those not cleared yet.
    pub active_only: bool,
    /// Only those active at some time of [`from`, `to`]: raised at or
    /// before `to` and not cleared before `from`.
    pub during: Option<(f64, f64)>,
    /// At most this many (the newest).
    pub limit: Option<usize>,
}
