//! Retention in PostgreSQL ([`crate::store::retention`] says what it
//! keeps): whole days' partitions dropped where they can be, rows deleted
//! where not.

use super::handle::PgStore;
use super::schema::{self, PARTITION_S};
use crate::fusion::StreamKind;
use crate::store::error::StoreError;
use crate::store::retention::{self, Pruned, Retention, Step};

impl PgStore {
    /// The steps of a retention pass of `policy` at `now_t` (blocking).
    pub fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError> {
        let client = self.reader()?;
        let oldest = |machine: i64, stream: StreamKind| -> Result<Option<f64>, StoreError> {
            Ok(self
                .runtime
                .block_on(client.query_one(
                    "SELECT min(t) FROM estimates WHERE machine_id = $1 AND engine = $2",
                    &[&machine, &stream.as_str()],
                ))?
                .get(0))
        };
        let machines: Vec<i64> = self
            .runtime
            .block_on(client.query("SELECT id FROM machines", &[]))?
            .iter()
            .map(|row| row.get(0))
            .collect();
        retention::plan_steps(now_t, policy, batch, &machines, oldest)
    }

    /// Does one step of a pass on the writer's connection. Readings go by
    /// whole day partitions where every reading in them is older than the
    /// cut and covered by its machine's snapshot, then row by row.
    pub async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError> {
        self.maintain(move |client| Box::pin(async move { apply_step(client, step).await }))
            .await
    }
}

/// One retention step on PostgreSQL.
async fn apply_step(client: &mut tokio_postgres::Client, step: Step) -> Result<Pruned, StoreError> {
    match step {
        Step::Readings { cut, batch } => {
            let mut readings = 0;
            // Whole partitions first: their end at or before the cut, none
            // of their readings after its machine's snapshot.
            let days: Vec<i64> = schema::partitions(client)
                .await?
                .into_iter()
                .filter(|(table, day)| {
                    table == "readings" && (*day + 1) as f64 * PARTITION_S <= cut
                })
                .map(|(_, day)| day)
                .collect();
            for day in days {
                let (_, name) = schema::partition("readings", day as f64 * PARTITION_S);
                let uncovered: i64 = client
                    .query_one(
                        &format!(
                            "SELECT count(*) FROM {name} r LEFT JOIN snapshots s \
                             ON s.machine_id = r.machine_id \
                             WHERE s.last_reading_id IS NULL OR r.id > s.last_reading_id"
                        ),
                        &[],
                    )
                    .await?
                    .get(0);
                if uncovered > 0 {
                    continue;
                }
                let tx = client.transaction().await?;
                let rows: i64 = tx
                    .query_one(&format!("SELECT count(*) FROM {name}"), &[])
                    .await?
                    .get(0);
                tx.batch_execute(&format!("DROP TABLE {name}")).await?;
                tx.commit().await?;
                readings += rows as u64;
            }
            // Then what is left, a batch at a time.
            readings += client
                .execute(
                    "DELETE FROM readings WHERE t < $1 AND (machine_id, id) IN ( \
                         SELECT r.machine_id, r.id FROM readings r \
                         JOIN snapshots s ON s.machine_id = r.machine_id \
                         WHERE r.t < $1 AND r.id <= s.last_reading_id LIMIT $2)",
                    &[&cut, &(batch as i64)],
                )
                .await?;
            Ok(Pruned {
                readings,
                estimates: 0,
            })
        }
        Step::Thin {
            machine,
            stream,
            from,
            to,
        } => {
            let estimates = client
                .execute(
                    "DELETE FROM estimates WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t < $4 \
                     AND t NOT IN (SELECT min(t) FROM estimates \
                     WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t < $4 \
                     GROUP BY floor(t / $5))",
                    &[&machine, &stream.as_str(), &from, &to, &retention::THIN_TO_S],
                )
                .await?;
            Ok(Pruned {
                readings: 0,
                estimates,
            })
        }
    }
}
