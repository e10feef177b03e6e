//! The outbox: what this server still owes a receiver, kept in its own
//! store and written in the same transaction as what it reports, so
//! nothing committed is lost to a crash, a restart or a cut line.
//!
//! - A **site** (`serve --forward-to`) owes its office every committed
//!   reading batch (a row naming the readings' ids, not a copy), machine
//!   declaration (with its engines' state) and alarm change, in order per
//!   machine. The row's id is the sequence of the idempotency key (site,
//!   machine, sequence); the office keeps the last sequence it committed
//!   per machine (its *mark*, in the same transaction as what it stored),
//!   so a batch sent twice is applied once. A row is deleted only once the
//!   office has answered that it committed it.
//! - Every server owes its webhooks each alarm change of a severity with a
//!   URL: posted after a restart too, with the same idempotency key.
//!
//! Readings a pending batch names are kept by retention until it is sent.

use serde::{Deserialize, Serialize};

use super::alarms::AlarmChange;
use super::error::StoreError;
use crate::fusion::Reading;

/// What a store records in its outbox, fixed when it is opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OutboxConfig {
    /// This server is a site: it forwards to an office.
    pub forward: bool,
    /// Alarm changes of `warn` alarms go to a webhook.
    pub webhook_warn: bool,
    /// Alarm changes of `alarm` alarms go to a webhook.
    pub webhook_alarm: bool,
}

impl OutboxConfig {
    /// Whether changes of alarms of `severity` go to a webhook.
    pub(crate) fn webhook(&self, severity: &str) -> bool {
        match severity {
            "alarm" => self.webhook_alarm,
            _ => self.webhook_warn,
        }
    }
}

/// A declaration as a site sends it: the stored spec (JSON) and the state
/// its engines start from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Declared {
    pub spec: serde_json::Value,
    pub snapshot: String,
}

/// One thing a site owes its office.
#[derive(Debug, Clone)]
pub enum OfficeItem {
    /// The machine was (re)declared: its engines go on from `snapshot`.
    Machine(Declared),
    /// Readings committed together, in the order they were stored.
    Readings(Vec<Reading>),
    /// An alarm raised, cleared or acknowledged.
    Alarm(AlarmChange),
}

/// An outbox row to the office.
#[derive(Debug, Clone)]
pub struct OfficeEntry {
    /// The sequence: increasing with every row.
    pub sequence: i64,
    pub item: OfficeItem,
}

/// What a site has not sent yet.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Backlog {
    /// Outbox rows (reading batches, declarations, alarm changes).
    pub items: u64,
    /// Readings in the batches.
    pub readings: u64,
    /// When the oldest row was committed (Unix seconds), if any.
    pub oldest_unsent_t: Option<f64>,
}

/// An office's record of what one site sent (and said of itself).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SiteRecord {
    pub name: String,
    /// The site's last request (Unix seconds, office clock).
    pub last_contact_t: f64,
    /// The backlog the site reported then.
    pub backlog: Backlog,
}

/// An acknowledgement a site made, to apply at the office by the alarm's
/// natural key.
#[derive(Debug, Clone, PartialEq)]
pub struct ForwardedAck {
    pub kind: String,
    pub severity: String,
    pub subject: String,
    pub raised_t: f64,
    pub acked_t: f64,
    pub by: String,
}

/// What an office stores with a forwarded machine's write: the site's
/// sequence it brings the machine's mark to, and the acknowledgements in
/// it. It commits only if the stored mark is still `after` (what the
/// machine's task had fused before it): a write of the task that failed
/// before it leaves the mark short, and this one fails too rather than
/// leave a hole.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Forwarded {
    pub after: Option<i64>,
    /// Every sequence this write applies (the office holds those rows).
    pub applied: Vec<i64>,
    pub sequence: i64,
    /// The last sequence the site says the office answered committed: the
    /// spans up to it are forgotten (the site never sends those again).
    pub confirmed: Option<i64>,
    pub acks: Vec<ForwardedAck>,
}

/// A row of the audit log: what an admin changed by hand.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AuditEntry {
    pub id: i64,
    /// Unix seconds.
    pub t: f64,
    /// The admin token's name (`cli` from the command line, `anonymous`
    /// while access is open).
    pub actor: String,
    /// What was done, e.g. `reset_forward_mark`.
    pub action: String,
    /// What it was done to (a machine's id).
    pub subject: String,
    /// The change, e.g. `mark 9000 -> 120`.
    pub detail: String,
}

/// An alarm change owed to a webhook.
#[derive(Debug, Clone)]
pub struct WebhookEntry {
    pub id: i64,
    pub change: AlarmChange,
}

/// A forwarded write whose mark moved under it: it fails (the site sends
/// it again; the machine's task is rebuilt from the store first).
pub(crate) fn mark_moved(
    machine_id: i64,
    stored: Option<i64>,
    expected: Option<i64>,
) -> StoreError {
    StoreError::Unavailable(format!(
        "forwarded machine {machine_id}: its committed sequence is {stored:?}, not the {expected:?} \
         this write follows (a write before it failed); the site sends it again"
    ))
}

/// What an office holds of a forwarded machine's rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ForwardHeld {
    /// The mark: the last sequence committed here.
    pub mark: Option<i64>,
    /// Rows up to this sequence were applied before the office kept a
    /// record of each (an upgrade): trusted as held.
    pub trusted_to: i64,
    /// The sequences applied and not yet confirmed by the site.
    pub applied: std::collections::BTreeSet<i64>,
}

impl ForwardHeld {
    /// From the mark's row (sequence, trusted_to), if any, and the
    /// sequences applied: as both stores read it.
    pub fn new(mark: Option<(i64, i64)>, applied: std::collections::BTreeSet<i64>) -> ForwardHeld {
        ForwardHeld {
            mark: mark.map(|(sequence, _)| sequence),
            trusted_to: mark.map_or(-1, |(_, trusted_to)| trusted_to),
            applied,
        }
    }

    /// Whether this office holds the row of `sequence`.
    pub fn holds(&self, sequence: i64) -> bool {
        sequence <= self.trusted_to || self.applied.contains(&sequence)
    }
}

/// The audit log's action of a mark set back.
pub const RESET_FORWARD_MARK: &str = "reset_forward_mark";
