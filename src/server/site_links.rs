//! An office's record of its sites' links: each site as it last reported
//! (kept in memory, written to the store every few seconds per site), the
//! one forwarding request of a site at a time, and when `site_link` is
//! due.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::forward::SiteReport;
use crate::config::forwarded_site;
use crate::store::outbox::{Backlog, SiteRecord};

/// A site not heard from for this long is shown as cut off (it reports
/// every [`super::forward::REPORT_EVERY`]).
pub const LINK_DOWN_AFTER: Duration = Duration::from_secs(10);

/// A site's link as the office sees it.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SiteStatus {
    pub site: String,
    /// Heard from within the last 10 s.
    pub connected: bool,
    /// The site's last request, Unix seconds (office clock).
    pub last_contact_t: f64,
    /// Outbox rows the site had not sent at its last report.
    pub backlog_items: u64,
    /// Readings in them.
    pub backlog_readings: u64,
    /// How old the site's oldest unsent row is now (while cut off: at
    /// least the time since the last contact), seconds.
    pub oldest_unsent_s: f64,
    /// `site_link` is raised: older than `[sites] backlog_alarm_s`.
    pub alarm: bool,
    /// The site's machines here (`{site}.{machine}`).
    pub machines: Vec<String>,
}

/// The sites this office has heard from, as they last reported (kept in
/// memory, written to the store every few seconds per site).
#[derive(Default)]
pub struct SiteLinks {
    links: Mutex<BTreeMap<String, Link>>,
    /// One forwarding request of a site at a time (per site: sites are as
    /// many as their tokens), so a mark read and checked stays the mark
    /// until the answer.
    forwarding: Mutex<BTreeMap<String, Arc<tokio::sync::Mutex<()>>>>,
}

#[derive(Debug, Clone)]
struct Link {
    record: SiteRecord,
    /// When the record was last stored (office clock).
    stored_t: f64,
    /// Whether `site_link` is raised; `None` until first decided (after a
    /// restart: raised or cleared again, which the store keeps once).
    alarm: Option<bool>,
}

/// Interval between writes of a site's record while it keeps reporting
/// (other nodes read it from the store as often).
const STORE_EVERY_S: f64 = 2.0;

impl SiteLinks {
    /// The links as the store last recorded them; `raised`: the sites
    /// whose `site_link` is open.
    pub fn load(records: Vec<SiteRecord>, raised: &[String]) -> SiteLinks {
        let links = records
            .into_iter()
            .map(|record| {
                let link = Link {
                    stored_t: record.last_contact_t,
                    alarm: raised.contains(&record.name).then_some(true),
                    record,
                };
                (link.record.name.clone(), link)
            })
            .collect();
        SiteLinks {
            links: Mutex::new(links),
            forwarding: Mutex::default(),
        }
    }

    /// The lock that serialises `site`'s forwarding requests.
    pub(super) fn forwarding(&self, site: &str) -> Arc<tokio::sync::Mutex<()>> {
        match self.forwarding.lock() {
            Ok(mut locks) => locks.entry(site.to_string()).or_default().clone(),
            // A poisoned map: a lock of its own (serialises nothing more
            // than before; the actor's check still holds).
            Err(_) => Arc::default(),
        }
    }

    /// A site was heard from at `now_t`, with `backlog` if it said; the
    /// record to store, if it is time.
    pub(super) fn contact(
        &self,
        site: &str,
        now_t: f64,
        report: Option<&SiteReport>,
    ) -> Option<SiteRecord> {
        let mut links = self.links.lock().ok()?;
        let link = links.entry(site.to_string()).or_insert_with(|| Link {
            record: SiteRecord {
                name: site.to_string(),
                last_contact_t: now_t,
                backlog: Backlog::default(),
            },
            stored_t: f64::NEG_INFINITY,
            alarm: None,
        });
        link.record.last_contact_t = now_t;
        if let Some(report) = report {
            link.record.backlog = Backlog {
                items: report.backlog_items,
                readings: report.backlog_readings,
                oldest_unsent_t: (report.backlog_items > 0)
                    .then(|| now_t - report.oldest_unsent_s.max(0.0)),
            };
        }
        (now_t - link.stored_t >= STORE_EVERY_S).then(|| {
            link.stored_t = now_t;
            link.record.clone()
        })
    }

    /// Each site's status at `now_t`.
    pub(super) fn statuses(
        &self,
        now_t: f64,
        machines: &[String],
        limit_s: f64,
    ) -> Vec<SiteStatus> {
        let Ok(links) = self.links.lock() else {
            return Vec::new();
        };
        links
            .values()
            .map(|link| {
                let record = &link.record;
                let oldest_unsent_s = unsent_age_s(record, now_t);
                SiteStatus {
                    site: record.name.clone(),
                    connected: now_t - record.last_contact_t <= LINK_DOWN_AFTER.as_secs_f64(),
                    last_contact_t: record.last_contact_t,
                    backlog_items: record.backlog.items,
                    backlog_readings: record.backlog.readings,
                    oldest_unsent_s,
                    alarm: oldest_unsent_s > limit_s,
                    machines: machines
                        .iter()
                        .filter(|m| forwarded_site(m) == Some(record.name.as_str()))
                        .cloned()
                        .collect(),
                }
            })
            .collect()
    }

    /// The records other nodes stored (several nodes): a site heard
    /// there more recently than here is taken as they recorded it.
    pub(super) fn merge(&self, records: Vec<SiteRecord>) {
        let Ok(mut links) = self.links.lock() else {
            return;
        };
        for record in records {
            match links.get_mut(&record.name) {
                Some(link) if link.record.last_contact_t >= record.last_contact_t => {}
                Some(link) => link.record = record,
                None => {
                    let link = Link {
                        stored_t: record.last_contact_t,
                        record,
                        alarm: None,
                    };
                    links.insert(link.record.name.clone(), link);
                }
            }
        }
    }

    /// Notes `site`'s `site_link` as stored raised or cleared.
    pub(super) fn alarm_stored(&self, site: &str, raised: bool) {
        if let Ok(mut links) = self.links.lock()
            && let Some(link) = links.get_mut(site)
        {
            link.alarm = Some(raised);
        }
    }

    /// Sites whose `site_link` must change at `now_t`: (site, raise, since
    /// when, message); [`SiteLinks::alarm_stored`] notes each once done.
    pub(super) fn alarm_changes(
        &self,
        now_t: f64,
        limit_s: f64,
    ) -> Vec<(String, bool, f64, String)> {
        let Ok(links) = self.links.lock() else {
            return Vec::new();
        };
        let mut changes = Vec::new();
        for link in links.values() {
            let age_s = unsent_age_s(&link.record, now_t);
            let raise = age_s > limit_s;
            if link.alarm == Some(raise) {
                continue;
            }
            let since_t = now_t - age_s;
            let message = if raise {
                format!(
                    "site `{}`: data not received for {age_s:.0} s (limit {limit_s:.0} s); last contact {:.0} s ago",
                    link.record.name,
                    now_t - link.record.last_contact_t
                )
            } else {
                format!("site `{}`: caught up", link.record.name)
            };
            changes.push((link.record.name.clone(), raise, since_t, message));
        }
        changes
    }
}

/// How old a site's oldest unsent row is at `now_t`: as it reported, and
/// while it is silent at least the time since its last contact (a site
/// keeps producing readings it cannot send).
fn unsent_age_s(record: &SiteRecord, now_t: f64) -> f64 {
    let reported = record
        .backlog
        .oldest_unsent_t
        .map_or(0.0, |t| (now_t - t).max(0.0));
    let silent = now_t - record.last_contact_t;
    if silent > LINK_DOWN_AFTER.as_secs_f64() {
        reported.max(silent)
    } else {
        reported
    }
}
