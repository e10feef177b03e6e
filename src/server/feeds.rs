//! Live sockets for machines another node fuses (several nodes on one
//! PostgreSQL store): each such machine followed here has a feed, filled
//! from the store whenever a commit of the machine's node says it added
//! estimates (PostgreSQL `NOTIFY`, see `store::postgres::cluster`), with
//! the estimates after the newest one sent, in time order. Alarm changes
//! made on other nodes go to this node's sockets the same way (their
//! webhooks are posted by the node that made them).
//!
//! A feed outlives a change of hands: whichever node fuses the machine
//! next notifies alike, so a socket opened here keeps receiving.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use tokio::sync::{broadcast, mpsc, watch};

use super::error::ApiError;
use super::notify::AlarmNotifier;
use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, StreamKind};
use crate::machine::{FusedEstimate, LIVE_BUFFER, LiveEstimate, MachineStatus};
use crate::store::Store;
use crate::store::postgres::cluster::Notice;

/// One followed machine.
struct Feed {
    spec: Arc<MachineSpec>,
    db_id: i64,
    sender: broadcast::Sender<LiveEstimate>,
    /// The newest estimate's time sent, by stream; held while fetching.
    sent_to: tokio::sync::Mutex<BTreeMap<StreamKind, f64>>,
}

/// The feeds of the machines followed on this node, by stored id.
#[derive(Default)]
pub struct Feeds {
    feeds: Mutex<HashMap<i64, Arc<Feed>>>,
}

/// A socket's view of a followed machine.
pub struct Followed {
    pub spec: Arc<MachineSpec>,
    pub estimates: broadcast::Receiver<LiveEstimate>,
    /// The newest stored estimate of each stream.
    pub latest: MachineStatus,
}

impl Feeds {
    /// Follows stored machine `db_id`, declared as `spec`.
    pub async fn follow(
        &self,
        store: &Store,
        spec: MachineSpec,
        db_id: i64,
    ) -> Result<Followed, ApiError> {
        // Subscribed (under the map's lock, so the feed is never without
        // a reader there) before the newest is read: nothing falls
        // between (an estimate may come twice; `t` tells).
        let (feed, fresh, estimates) = {
            let mut feeds = self
                .feeds
                .lock()
                .map_err(|_| ApiError::Internal("feeds poisoned".into()))?;
            match feeds.get(&db_id) {
                Some(feed) if *feed.spec == spec => (feed.clone(), false, feed.sender.subscribe()),
                _ => {
                    let feed = Arc::new(Feed {
                        spec: Arc::new(spec),
                        db_id,
                        sender: broadcast::channel(LIVE_BUFFER).0,
                        sent_to: tokio::sync::Mutex::new(BTreeMap::new()),
                    });
                    let estimates = feed.sender.subscribe();
                    feeds.insert(db_id, feed.clone());
                    (feed, true, estimates)
                }
            }
        };
        let mut sent_to = feed.sent_to.lock().await;
        let latest = {
            let (store, spec) = (store.clone(), feed.spec.clone());
            tokio::task::spawn_blocking(move || crate::machine::stored_status(&store, &spec, db_id))
                .await
                .map_err(|e| ApiError::Internal(e.to_string()))?
                .map_err(|e| ApiError::Internal(e.to_string()))?
        };
        if fresh {
            for (&stream, estimate) in &latest.latest {
                sent_to.insert(stream, estimate.t);
            }
        }
        Ok(Followed {
            spec: feed.spec.clone(),
            estimates,
            latest,
        })
    }

    /// Live clients of stored machine `db_id` on this node.
    pub fn clients(&self, db_id: i64) -> usize {
        self.feeds
            .lock()
            .ok()
            .and_then(|f| f.get(&db_id).map(|feed| feed.sender.receiver_count()))
            .unwrap_or(0)
    }

    /// The feeds still followed (those no socket reads any more dropped).
    fn followed(&self) -> Vec<Arc<Feed>> {
        let Ok(mut feeds) = self.feeds.lock() else {
            return Vec::new();
        };
        feeds.retain(|_, feed| feed.sender.receiver_count() > 0);
        feeds.values().cloned().collect()
    }
}

/// Sends the estimates stored after the newest one sent.
async fn fetch(store: &Store, feed: &Feed) -> Result<(), ApiError> {
    let mut sent_to = feed.sent_to.lock().await;
    let after = sent_to.clone();
    let (store, spec, db_id) = (store.clone(), feed.spec.clone(), feed.db_id);
    let new = tokio::task::spawn_blocking(move || {
        let mut new: Vec<(StreamKind, EngineOutput)> = Vec::new();
        for stream in spec.streams() {
            let from = after.get(&stream).copied().unwrap_or(f64::NEG_INFINITY);
            store.export_estimates(db_id, stream, from, f64::INFINITY, |output| {
                if output.t > from {
                    new.push((stream, output.clone()));
                }
                true
            })?;
        }
        Ok::<_, crate::store::StoreError>(new)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))??;
    let mut new = new;
    new.sort_by(|a, b| a.1.t.total_cmp(&b.1.t));
    for (stream, output) in new {
        let estimate = FusedEstimate::stored(&feed.spec.id, stream, &output)?;
        sent_to.insert(stream, output.t);
        // No receivers is fine: the feed goes at the next notice.
        let _ = feed.sender.send(Arc::new(estimate));
    }
    Ok(())
}

/// Takes other nodes' notices until the server stops (`stopping`): new estimates to the
/// feeds that follow their machine, alarm changes to this node's sockets.
/// `node`: this node's name; `feeds`: the machines followed here.
pub async fn relay(
    store: Store,
    node: String,
    feeds: Arc<Feeds>,
    alarms: AlarmNotifier,
    mut notices: mpsc::Receiver<Notice>,
    mut stopping: watch::Receiver<bool>,
) {
    loop {
        let first = tokio::select! {
            notice = notices.recv() => match notice {
                Some(notice) => notice,
                None => return,
            },
            _ = stopping.wait_for(|stopping| *stopping) => return,
        };
        // Everything waiting, each machine fetched once.
        let mut dirty = std::collections::BTreeSet::new();
        let mut all = false;
        let mut next = Some(first);
        while let Some(notice) = next.take() {
            match notice {
                Notice::Estimates(id) => {
                    dirty.insert(id);
                }
                Notice::Resync => all = true,
                Notice::Alarm {
                    node: node_of_change,
                    change,
                } => {
                    if node_of_change != node {
                        alarms.relay(*change);
                    }
                }
            }
            next = notices.try_recv().ok();
        }
        for feed in feeds
            .followed()
            .into_iter()
            .filter(|feed| all || dirty.contains(&feed.db_id))
        {
            if let Err(e) = fetch(&store, &feed).await {
                tracing::warn!(machine = %feed.spec.id, error = %e, "cannot fetch a followed machine's estimates");
            }
        }
    }
}
