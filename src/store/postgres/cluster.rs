//! Several server nodes on one database: who is alive, and which node
//! fuses which machine.
//!
//! A node registers in `nodes` (its name, the URL other nodes forward to,
//! the SHA-256 of the cluster key it signs with: never a key) and holds a session advisory lock on its
//! name, so two live processes never share one. It fuses a machine only
//! while it holds the machine's row in `leases`, renewed every heartbeat
//! and lapsing `ttl` after the last; a lapsed lease may be taken by any
//! node, bumping its `epoch`. The writer checks the lease inside every
//! commit (see `writer.rs`), so a node that lost a machine cannot store
//! anything for it, even if it has not noticed yet. Times are the
//! database's (`now()`), so the nodes' clocks need not agree.

use std::collections::BTreeSet;

use sha2::{Digest, Sha256};
use tokio::sync::mpsc;
use tokio_postgres::{AsyncMessage, Client, GenericClient};

use super::connect::{Endpoint, connect, with_causes};
use crate::store::alarms::AlarmChange;
use crate::store::error::StoreError;

/// A node as registered.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeRow {
    pub node: String,
    /// Where the node answers, e.g. `http://10.0.0.5:8080`.
    pub url: String,
    /// The SHA-256 (hex) of the cluster key it signs with; empty if none.
    pub key_sha256: String,
    /// Its heartbeat is younger than the lease time.
    pub live: bool,
}

/// Who fuses a declared machine.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    pub machine: String,
    pub machine_id: i64,
    /// The lease's node, if any lease was ever taken, and whether it is
    /// still in force.
    pub holder: Option<(String, bool)>,
}

/// A node's membership: its own connection, on which the name's lock is
/// held for as long as the session lives.
pub struct Membership {
    client: Client,
    endpoint: Endpoint,
    node: String,
    url: String,
    key_sha256: String,
}

/// The lock the previous release's one writer held exclusively.
const OLD_WRITER_LOCK: i64 = 0x7475_6e6e_656c_7772; // "tunnelwr"

/// A membership session waits at most a second for a row lock (a hung
/// node's open transaction must not stall this one's heartbeat) and five
/// for any statement.
async fn settle_session(client: &Client) -> Result<(), StoreError> {
    client
        .batch_execute("SET lock_timeout = '1s'; SET statement_timeout = '5s'")
        .await?;
    Ok(())
}

/// How long a starting node waits for its name's lock (a process killed
/// a moment ago still holds it until PostgreSQL sees its socket close).
const NAME_WAIT: std::time::Duration = std::time::Duration::from_secs(3);

/// The advisory lock of node name `node`.
fn name_lock(node: &str) -> i64 {
    let digest = Sha256::digest(format!("tunnelnav node {node}").as_bytes());
    let mut first = [0u8; 8];
    first.copy_from_slice(&digest[..8]);
    i64::from_be_bytes(first)
}

async fn try_lock(client: &Client, node: &str) -> Result<bool, StoreError> {
    Ok(client
        .query_one("SELECT pg_try_advisory_lock($1)", &[&name_lock(node)])
        .await?
        .get(0))
}

impl Membership {
    /// Joins as `wanted`, or, if a live process holds that name, as
    /// `wanted-2`, `wanted-3`, ... (up to 16); answers at `url`, signs
    /// with the key whose SHA-256 is `key_sha256`.
    pub(super) async fn join(
        endpoint: Endpoint,
        wanted: &str,
        url: &str,
        key_sha256: &str,
    ) -> Result<Membership, StoreError> {
        let client = connect(&endpoint).await?;
        settle_session(&client).await?;
        // A server of the release before several nodes holds this lock
        // alone while it writes: never alongside it.
        let shared: bool = client
            .query_one(
                "SELECT pg_try_advisory_lock_shared($1)",
                &[&OLD_WRITER_LOCK],
            )
            .await?
            .get(0);
        if !shared {
            return Err(StoreError::Location(
                "has a server of an older tunnelnav release (one server per database) writing \
                 to it: stop that server first"
                    .into(),
            ));
        }
        let mut node = None;
        let waited_from = std::time::Instant::now();
        while !try_lock(&client, wanted).await? {
            if waited_from.elapsed() >= NAME_WAIT {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        }
        if try_lock(&client, wanted).await? {
            node = Some(wanted.to_string());
        } else {
            for n in 2..=16 {
                let candidate = format!("{wanted}-{n}");
                if try_lock(&client, &candidate).await? {
                    tracing::info!(node = %candidate, taken = %wanted, "node name taken by a live process; joining under another");
                    node = Some(candidate);
                    break;
                }
            }
        }
        let node = node.ok_or_else(|| {
            StoreError::Location(format!(
                "node names `{wanted}` to `{wanted}-16` are all held by live servers"
            ))
        })?;
        let mut membership = Membership {
            client,
            endpoint,
            node,
            url: url.to_string(),
            key_sha256: key_sha256.to_string(),
        };
        membership.register().await?;
        membership.supersede().await?;
        Ok(membership)
    }

    /// Takes the leases an earlier process of this name still holds with
    /// new epochs (after any commit of its in flight), so nothing that
    /// process may still have queued is stored.
    async fn supersede(&mut self) -> Result<(), StoreError> {
        let tx = self.client.transaction().await?;
        tx.execute(
            "SELECT 1 FROM leases WHERE node = $1 AND expires_at > now() \
             ORDER BY machine_id FOR UPDATE",
            &[&self.node],
        )
        .await?;
        tx.execute(
            "UPDATE leases SET epoch = epoch + 1 WHERE node = $1 AND expires_at > now()",
            &[&self.node],
        )
        .await?;
        tx.commit().await?;
        Ok(())
    }

    /// The name this node joined under.
    pub fn node(&self) -> &str {
        &self.node
    }

    async fn register(&self) -> Result<(), StoreError> {
        self.client
            .execute(
                "INSERT INTO nodes (node, url, key_sha256, seen_at) VALUES ($1, $2, $3, now()) \
                 ON CONFLICT (node) DO UPDATE SET url = excluded.url, \
                 key_sha256 = excluded.key_sha256, seen_at = excluded.seen_at",
                &[&self.node, &self.url, &self.key_sha256],
            )
            .await?;
        Ok(())
    }

    /// A new connection if the old one was lost, with the name's lock
    /// taken again (refused if another process took the name meanwhile).
    async fn reconnect_if_lost(&mut self) -> Result<(), StoreError> {
        if !self.client.is_closed() {
            return Ok(());
        }
        let client = connect(&self.endpoint).await?;
        settle_session(&client).await?;
        let shared: bool = client
            .query_one(
                "SELECT pg_try_advisory_lock_shared($1)",
                &[&OLD_WRITER_LOCK],
            )
            .await?
            .get(0);
        if !shared {
            return Err(StoreError::Location(
                "a server of an older tunnelnav release took the database while this node \
                 was cut off"
                    .into(),
            ));
        }
        if !try_lock(&client, &self.node).await? {
            return Err(StoreError::Location(format!(
                "node name `{}` was taken by another process while this one was cut off",
                self.node
            )));
        }
        self.client = client;
        Ok(())
    }

    /// Says this node is alive and renews its leases still in force for
    /// `ttl_s` (a lapsed one is taken anew by [`Membership::acquire`], with
    /// a new epoch); the machines it holds with their epochs.
    pub async fn heartbeat(&mut self, ttl_s: f64) -> Result<Vec<(i64, i64)>, StoreError> {
        self.reconnect_if_lost().await?;
        self.register().await?;
        // A renewal changes no key: it does not wait for the commits that
        // hold the lease (`FOR KEY SHARE`, writer.rs).
        let rows = self
            .client
            .query(
                "UPDATE leases SET expires_at = now() + make_interval(secs => $2) \
                 WHERE node = $1 AND expires_at > now() RETURNING machine_id, epoch",
                &[&self.node, &ttl_s],
            )
            .await?;
        Ok(rows.iter().map(|row| (row.get(0), row.get(1))).collect())
    }

    /// Takes the leases of `machine_ids` that no node holds in force; the
    /// machines taken with their new epochs. A lapsed row is locked first
    /// (`FOR UPDATE`, in id order), which waits for a commit still holding
    /// it, so nothing its previous holder stores lands after the taking;
    /// rows another transaction holds are left for the next round.
    pub async fn acquire(
        &mut self,
        machine_ids: &[i64],
        ttl_s: f64,
    ) -> Result<Vec<(i64, i64)>, StoreError> {
        if machine_ids.is_empty() {
            return Ok(Vec::new());
        }
        let tx = self.client.transaction().await?;
        let lapsed: Vec<i64> = tx
            .query(
                "SELECT machine_id FROM leases WHERE machine_id = ANY($1) AND expires_at < now() \
                 ORDER BY machine_id FOR UPDATE SKIP LOCKED",
                &[&machine_ids],
            )
            .await?
            .iter()
            .map(|row| row.get(0))
            .collect();
        let mut taken: Vec<(i64, i64)> = tx
            .query(
                "UPDATE leases SET node = $2, epoch = epoch + 1, \
                 expires_at = now() + make_interval(secs => $3) \
                 WHERE machine_id = ANY($1) RETURNING machine_id, epoch",
                &[&lapsed, &self.node, &ttl_s],
            )
            .await?
            .iter()
            .map(|row| (row.get(0), row.get(1)))
            .collect();
        let never: Vec<(i64, i64)> = tx
            .query(
                "INSERT INTO leases (machine_id, node, epoch, expires_at) \
                 SELECT w.machine_id, $2, 1, now() + make_interval(secs => $3) \
                 FROM unnest($1::int8[]) AS w(machine_id) \
                 WHERE EXISTS (SELECT 1 FROM machines m WHERE m.id = w.machine_id) \
                 ORDER BY w.machine_id \
                 ON CONFLICT (machine_id) DO NOTHING RETURNING machine_id, epoch",
                &[&machine_ids, &self.node, &ttl_s],
            )
            .await?
            .iter()
            .map(|row| (row.get(0), row.get(1)))
            .collect();
        tx.commit().await?;
        taken.extend(never);
        Ok(taken)
    }

    /// Gives up machine `machine_id` (its final snapshot stored first), so
    /// another node may take it at once.
    pub async fn release(&self, machine_id: i64) -> Result<(), StoreError> {
        // The row stays, lapsed, so the next taking's epoch is higher.
        self.client
            .execute(
                "UPDATE leases SET expires_at = '-infinity' WHERE machine_id = $1 AND node = $2",
                &[&machine_id, &self.node],
            )
            .await?;
        Ok(())
    }

    /// Leaves: every lease given up, the node no longer live.
    pub async fn leave(&self) -> Result<(), StoreError> {
        self.client
            .execute(
                "UPDATE leases SET expires_at = '-infinity' WHERE node = $1",
                &[&self.node],
            )
            .await?;
        self.client
            .execute(
                "UPDATE nodes SET seen_at = '-infinity' WHERE node = $1",
                &[&self.node],
            )
            .await?;
        Ok(())
    }
}

/// Every declared machine and who holds it.
pub(super) async fn placements(client: &impl GenericClient) -> Result<Vec<Placement>, StoreError> {
    let rows = client
        .query(
            "SELECT m.machine, m.id, l.node, l.expires_at > now() FROM machines m \
                 LEFT JOIN leases l ON l.machine_id = m.id ORDER BY m.id",
            &[],
        )
        .await?;
    Ok(rows
        .iter()
        .map(|row| {
            let node: Option<String> = row.get(2);
            let live: Option<bool> = row.get(3);
            Placement {
                machine: row.get(0),
                machine_id: row.get(1),
                holder: node.map(|n| (n, live.unwrap_or(false))),
            }
        })
        .collect())
}

/// Every registered node; live if its heartbeat is younger than `ttl_s`.
pub(super) async fn nodes(
    client: &impl GenericClient,
    ttl_s: f64,
) -> Result<Vec<NodeRow>, StoreError> {
    let rows = client
        .query(
            "SELECT node, url, key_sha256, seen_at > now() - make_interval(secs => $1) FROM nodes \
                 ORDER BY node",
            &[&ttl_s],
        )
        .await?;
    Ok(rows
        .iter()
        .map(|row| NodeRow {
            node: row.get(0),
            url: row.get(1),
            key_sha256: row.get(2),
            live: row.get(3),
        })
        .collect())
}

/// The channel a commit with estimates notifies, with the machine's id.
const ESTIMATES_CHANNEL: &str = "tunnelnav_estimates";
/// The channel of alarm changes, with the node and the change as JSON.
const ALARMS_CHANNEL: &str = "tunnelnav_alarms";
/// PostgreSQL's limit on a notification's payload is 8000 bytes.
const MAX_PAYLOAD: usize = 7900;

/// What another node's commit tells this one.
#[derive(Debug)]
pub enum Notice {
    /// Machine `0` has new estimates.
    Estimates(i64),
    /// An alarm changed on node `node`.
    Alarm {
        node: String,
        change: Box<AlarmChange>,
    },
    /// The listening connection was made again: notices may have been
    /// missed, look again at everything followed.
    Resync,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct AlarmNotice {
    node: String,
    change: AlarmChange,
}

/// Tells the listening nodes, at this transaction's commit, that the
/// machines `machine_ids` have new estimates.
pub(super) async fn notify_estimates(
    client: &impl GenericClient,
    machine_ids: BTreeSet<i64>,
) -> Result<(), StoreError> {
    if machine_ids.is_empty() {
        return Ok(());
    }
    let ids: Vec<String> = machine_ids.iter().map(i64::to_string).collect();
    client
        .execute(
            "SELECT pg_notify($1, id) FROM unnest($2::text[]) AS id",
            &[&ESTIMATES_CHANNEL, &ids],
        )
        .await?;
    Ok(())
}

/// Tells the listening nodes (at commit) that `change` happened on `node`.
pub(super) async fn notify_alarm(
    client: &impl GenericClient,
    node: &str,
    change: &AlarmChange,
) -> Result<(), StoreError> {
    let payload = serde_json::to_string(&AlarmNotice {
        node: node.to_string(),
        change: change.clone(),
    })
    .map_err(|e| StoreError::Corrupt(e.to_string()))?;
    if payload.len() > MAX_PAYLOAD {
        tracing::warn!(
            alarm = change.alarm.id,
            "alarm change too long to tell the other nodes"
        );
        return Ok(());
    }
    client
        .execute("SELECT pg_notify($1, $2)", &[&ALARMS_CHANNEL, &payload])
        .await?;
    Ok(())
}

/// Listens for other nodes' commits on a connection of its own, made again
/// when lost (then [`Notice::Resync`]); ends when the receiver is dropped.
pub(super) fn listen(endpoint: Endpoint) -> mpsc::Receiver<Notice> {
    let (notices, received) = mpsc::channel(1024);
    tokio::spawn(async move {
        let mut first = true;
        loop {
            if notices.is_closed() {
                return;
            }
            match listen_once(&endpoint, &notices, first).await {
                Ok(()) => return,
                Err(e) => {
                    tracing::warn!(error = %e, "lost the notification connection; listening again")
                }
            }
            first = false;
            tokio::time::sleep(std::time::Duration::from_secs(1)).await;
        }
    });
    received
}

/// One connection's worth of [`listen`]: `Ok` when the receiver is gone.
async fn listen_once(
    endpoint: &Endpoint,
    notices: &mpsc::Sender<Notice>,
    first: bool,
) -> Result<(), StoreError> {
    let (client, mut connection) = endpoint
        .config
        .connect(endpoint.tls.clone())
        .await
        .map_err(|e| {
            StoreError::Unavailable(format!("cannot reach PostgreSQL: {}", with_causes(&e)))
        })?;
    let (messages_tx, mut messages) = mpsc::unbounded_channel();
    let driver = tokio::spawn(async move {
        let mut stream = futures_util::stream::poll_fn(move |cx| connection.poll_message(cx));
        while let Some(message) = futures_util::StreamExt::next(&mut stream).await {
            match message {
                Ok(AsyncMessage::Notification(n)) => {
                    if messages_tx.send(Ok(n)).is_err() {
                        return;
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    let _ = messages_tx.send(Err(e));
                    return;
                }
            }
        }
    });
    let listened = client
        .batch_execute(&format!(
            "LISTEN {ESTIMATES_CHANNEL}; LISTEN {ALARMS_CHANNEL}"
        ))
        .await;
    if let Err(e) = listened {
        driver.abort();
        return Err(e.into());
    }
    if !first && notices.send(Notice::Resync).await.is_err() {
        driver.abort();
        return Ok(());
    }
    let outcome = loop {
        let Some(message) = messages.recv().await else {
            break Err(StoreError::Unavailable(
                "notification connection closed".into(),
            ));
        };
        let notification = match message {
            Ok(n) => n,
            Err(e) => break Err(e.into()),
        };
        let notice = match notification.channel() {
            ESTIMATES_CHANNEL => notification.payload().parse().ok().map(Notice::Estimates),
            ALARMS_CHANNEL => serde_json::from_str::<AlarmNotice>(notification.payload())
                .ok()
                .map(|n| Notice::Alarm {
                    node: n.node,
                    change: Box::new(n.change),
                }),
            _ => None,
        };
        if let Some(notice) = notice
            && notices.send(notice).await.is_err()
        {
            break Ok(());
        }
    };
    driver.abort();
    drop(client);
    outcome
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_names_lock_apart() {
        assert_ne!(name_lock("a"), name_lock("b"));
        assert_eq!(name_lock("office-1"), name_lock("office-1"));
    }
}
