//! What a PostgreSQL store owes its webhooks, and an office's records:
//! forwarded machines' marks and held rows, sites and the audit log.

use super::handle::PgStore;
use crate::store::error::StoreError;
use crate::store::outbox::{
    AuditEntry, Backlog, ForwardHeld, RESET_FORWARD_MARK, SiteRecord, WebhookEntry,
};

impl PgStore {
    /// Alarm changes this node owes the webhook of `severity`, oldest
    /// first.
    pub fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError> {
        let node = self.fence.get().cloned().unwrap_or_default();
        self.read(async |client| {
            client
                .query(
                    "SELECT id, body FROM outbox WHERE node = $1 AND kind = $2 ORDER BY id LIMIT $3",
                    &[&node, &severity, &(limit as i64)],
                )
                .await?
                .iter()
                .map(|row| {
                    let (id, body): (i64, String) = (row.get(0), row.get(1));
                    Ok(WebhookEntry {
                        id,
                        change: serde_json::from_str(&body).map_err(|e| {
                            StoreError::Corrupt(format!("outbox row {id}: {e}"))
                        })?,
                    })
                })
                .collect()
        })
    }

    /// A webhook change is done with (delivered or given up).
    pub async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        self.pooled()
            .await?
            .execute("DELETE FROM outbox WHERE id = $1", &[&id])
            .await?;
        Ok(())
    }

    /// Forgets the changes this node owes a webhook no longer configured.
    pub async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        let node = self.fence.get().cloned().unwrap_or_default();
        Ok(self
            .pooled()
            .await?
            .execute(
                "DELETE FROM outbox WHERE node = $1 AND kind = $2",
                &[&node, &severity],
            )
            .await?)
    }

    /// An office: the last sequence of machine `machine_id` its site sent
    /// that is committed here.
    pub fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query_opt(
                    "SELECT sequence FROM forward_marks WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .map(|row| row.get(0)))
        })
    }

    /// An office: every site's record.
    pub fn sites(&self) -> Result<Vec<SiteRecord>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query(
                    "SELECT name, last_contact_t, backlog_items, backlog_readings, oldest_unsent_t \
                     FROM sites ORDER BY name",
                    &[],
                )
                .await?
                .iter()
                .map(|r| SiteRecord {
                    name: r.get(0),
                    last_contact_t: r.get(1),
                    backlog: Backlog {
                        items: r.get::<_, i64>(2).max(0) as u64,
                        readings: r.get::<_, i64>(3).max(0) as u64,
                        oldest_unsent_t: r.get(4),
                    },
                })
                .collect())
        })
    }

    /// An office: what this office holds of forwarded machine
    /// `machine_id`'s rows, as on SQLite.
    pub fn forward_held(&self, machine_id: i64) -> Result<ForwardHeld, StoreError> {
        self.read(async |client| {
            let mark = client
                .query_opt(
                    "SELECT sequence, trusted_to FROM forward_marks WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .map(|row| (row.get::<_, i64>(0), row.get::<_, i64>(1)));
            let applied = client
                .query(
                    "SELECT sequence FROM forward_applied WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .iter()
                .map(|row| row.get(0))
                .collect();
            Ok(ForwardHeld::new(mark, applied))
        })
    }

    /// An office: sets forwarded machine `machine`'s mark back to
    /// `sequence` (never forward), with an audit row, as on SQLite
    /// ([`crate::store::sqlite::outbox::reset_mark`]); the mark it had.
    pub async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError> {
        let mut client = self.pooled().await?;
        let tx = client.transaction().await?;
        let Some((machine_id, was)) = tx
            .query_opt(
                "SELECT f.machine_id, f.sequence FROM forward_marks f \
                 JOIN machines m ON m.id = f.machine_id WHERE m.machine = $1 FOR UPDATE OF f",
                &[&machine],
            )
            .await?
            .map(|row| (row.get::<_, i64>(0), row.get::<_, i64>(1)))
        else {
            return Ok(None);
        };
        // Back only: a mark set forward would skip rows. What lies above
        // it is applied again when the site sends it (readings are stored
        // once).
        let sequence = sequence.min(was);
        tx.execute(
            "UPDATE forward_marks SET sequence = $2, trusted_to = least(trusted_to, $2) \
             WHERE machine_id = $1",
            &[&machine_id, &sequence],
        )
        .await?;
        tx.execute(
            "DELETE FROM forward_applied WHERE machine_id = $1 AND sequence > $2",
            &[&machine_id, &sequence],
        )
        .await?;
        tx.execute(
            "INSERT INTO audit (t, actor, action, subject, detail) VALUES ($1, $2, $3, $4, $5)",
            &[
                &t,
                &actor,
                &RESET_FORWARD_MARK,
                &machine,
                &format!("mark {was} -> {sequence}"),
            ],
        )
        .await?;
        tx.commit().await?;
        Ok(Some(was))
    }

    /// The audit log, oldest first.
    pub fn audit(&self) -> Result<Vec<AuditEntry>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query(
                    "SELECT id, t, actor, action, subject, detail FROM audit ORDER BY id",
                    &[],
                )
                .await?
                .iter()
                .map(|row| AuditEntry {
                    id: row.get(0),
                    t: row.get(1),
                    actor: row.get(2),
                    action: row.get(3),
                    subject: row.get(4),
                    detail: row.get(5),
                })
                .collect())
        })
    }

    /// An office: records a site's contact.
    pub async fn put_site(&self, site: SiteRecord) -> Result<(), StoreError> {
        let client = self.pooled().await?;
        client
            .execute(
                "INSERT INTO sites (name, last_contact_t, backlog_items, backlog_readings, oldest_unsent_t) \
                 VALUES ($1, $2, $3, $4, $5) ON CONFLICT (name) DO UPDATE SET \
                 last_contact_t = $2, backlog_items = $3, backlog_readings = $4, oldest_unsent_t = $5",
                &[
                    &site.name,
                    &site.last_contact_t,
                    &(site.backlog.items as i64),
                    &(site.backlog.readings as i64),
                    &site.backlog.oldest_unsent_t,
                ],
            )
            .await?;
        Ok(())
    }
}
