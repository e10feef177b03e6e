//! Alarms in PostgreSQL: listed, and acknowledged on a writer's
//! connection so the acknowledgement is ordered with the commits.

use tokio_postgres::GenericClient;

use super::handle::PgStore;
use super::{cluster, writer};
use crate::store::alarms::{AlarmChange, AlarmFilter, Change, StoredAlarm};
use crate::store::error::StoreError;

impl PgStore {
    /// The alarms `filter` asks for, newest first.
    pub fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        self.read(async |client| {
            let sql = format!(
                "SELECT {ALARM_COLUMNS} FROM alarms a JOIN machines m ON m.id = a.machine_id \
                 WHERE ($1::text IS NULL OR m.machine = $1) AND (NOT $2 OR a.cleared_t IS NULL) \
                 AND ($3::float8 IS NULL OR a.raised_t <= $3) \
                 AND ($4::float8 IS NULL OR a.cleared_t IS NULL OR a.cleared_t >= $4) \
                 ORDER BY a.raised_t DESC, a.id DESC LIMIT $5"
            );
            let (from, to) = (filter.during.map(|d| d.0), filter.during.map(|d| d.1));
            // PostgreSQL reads a null limit as none.
            let limit = filter.limit.map(|n| i64::try_from(n).unwrap_or(i64::MAX));
            let rows = client
                .query(
                    &sql,
                    &[&filter.machine, &filter.active_only, &to, &from, &limit],
                )
                .await?;
            Ok(rows.iter().map(writer::stored_alarm).collect())
        })
    }

    /// Acknowledges alarm `id` by `by` at `t`, as
    /// [`Store::ack_alarm`](crate::store::Store::ack_alarm) does.
    pub async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: impl FnOnce(AlarmChange) + Send + 'static,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        let node = self.fence.get().cloned();
        let outbox = self.outbox.get().copied().unwrap_or_default();
        self.maintain(move |client| {
            Box::pin(async move {
                // The acknowledgement and what it owes the webhooks, in
                // one commit.
                let tx = client.transaction().await?;
                let acked = tx
                    .execute(
                        "UPDATE alarms SET acked_t = $2, acked_by = $3 WHERE id = $1 AND acked_t IS NULL",
                        &[&id, &t, &by],
                    )
                    .await?
                    == 1;
                let alarm = alarm_by_id(&tx, id).await?;
                let mut change = None;
                if let (true, Some(alarm)) = (acked, &alarm) {
                    let acknowledged = AlarmChange {
                        transition: Change::Acknowledged,
                        alarm: alarm.clone(),
                    };
                    if let Some(node) = &node {
                        cluster::notify_alarm(&tx, node, &acknowledged).await?;
                        let machine_id: i64 = tx
                            .query_one("SELECT machine_id FROM alarms WHERE id = $1", &[&id])
                            .await?
                            .get(0);
                        writer::record_webhooks(
                            &tx,
                            &outbox,
                            node,
                            machine_id,
                            std::slice::from_ref(&acknowledged),
                        )
                        .await?;
                    }
                    change = Some(acknowledged);
                }
                tx.commit().await?;
                if let Some(change) = change {
                    announce(change);
                }
                Ok(alarm.map(|alarm| (alarm, acked)))
            })
        })
        .await
    }
}

/// The columns of a stored alarm, `a` the alarm and `m` its machine.
const ALARM_COLUMNS: &str = "a.id, m.machine, a.kind, a.severity, a.subject, a.message, \
                             a.raised_t, a.cleared_t, a.acked_t, a.acked_by";

/// The alarm with this id.
pub(super) async fn alarm_by_id(
    client: &impl GenericClient,
    id: i64,
) -> Result<Option<StoredAlarm>, StoreError> {
    let sql = format!(
        "SELECT {ALARM_COLUMNS} FROM alarms a JOIN machines m ON m.id = a.machine_id WHERE a.id = $1"
    );
    Ok(client
        .query_opt(&sql, &[&id])
        .await?
        .map(|row| writer::stored_alarm(&row)))
}
