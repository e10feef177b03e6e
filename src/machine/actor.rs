//! The task that owns a machine's core: its commands, its handle, its
//! live broadcast and status, and the writes it sends the store.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use tokio::sync::{broadcast, mpsc, oneshot, watch};

use crate::clock::Clock;
use crate::config::MachineSpec;
use crate::fusion::reorder::Admission;
use crate::fusion::{EngineKind, EngineModel, Reading, SensorKind};
use crate::store::alarms::{AlarmChange, AlarmRow};
use crate::store::outbox::ForwardedAck;
use crate::store::{EstimateRow, ReadingRow, Store, StoreError, Write, WriteOutcome};

use super::core::{LiveEstimate, MachineCore};
use super::error::MachineError;
use super::lease::LeaseEpoch;
use super::recover::recover;
use super::status::{MachineStatus, SensorStatus};

/// A snapshot is stored after this many readings, so a restart re-feeds at
/// most this many.
pub const SNAPSHOT_EVERY_READINGS: u64 = 20_000;
/// Estimates a slow live client may fall behind by before it gets a `gap`.
pub const LIVE_BUFFER: usize = 4096;

/// One part of what a site forwards for a machine, with its sequence.
#[derive(Debug, Clone)]
pub enum ForwardedPart {
    /// Readings, fused in the order the site stored them.
    Readings(Vec<Reading>),
    /// An alarm change the site made, as the rows that bring the stored
    /// alarm to where the change left it and the acknowledgement in it
    /// (the office makes them: `store::alarms::forwarded_rows`).
    Alarm {
        rows: Vec<AlarmRow>,
        ack: Option<Box<ForwardedAck>>,
    },
}

enum Command {
    Ingest {
        readings: Vec<Reading>,
        reply: oneshot::Sender<Result<WriteOutcome, StoreError>>,
    },
    /// An office: what a site forwarded, each part with its sequence, and
    /// the last sequence the site says is committed here.
    Forwarded {
        parts: Vec<(i64, ForwardedPart)>,
        confirmed: Option<i64>,
        reply: oneshot::Sender<Result<WriteOutcome, StoreError>>,
    },
    /// An office: the mark an admin set back in the store (after it).
    SetForwardMark {
        sequence: i64,
        reply: oneshot::Sender<()>,
    },
    /// Alarms the server raises or clears for the machine (an office's
    /// `site_link`).
    Alarms {
        rows: Vec<AlarmRow>,
        reply: oneshot::Sender<Result<WriteOutcome, StoreError>>,
    },
    Models {
        reply: oneshot::Sender<BTreeMap<EngineKind, EngineModel>>,
    },
    Stop {
        reply: oneshot::Sender<()>,
    },
}

/// The server's handle on a running machine.
pub struct MachineHandle {
    pub spec: Arc<MachineSpec>,
    pub db_id: i64,
    /// The lease epoch it runs under here (several nodes).
    pub lease_epoch: LeaseEpoch,
    commands: mpsc::Sender<Command>,
    live: broadcast::Sender<LiveEstimate>,
    status: watch::Receiver<Arc<MachineStatus>>,
}

impl MachineHandle {
    /// Feeds readings; resolves once they are committed. When the
    /// machine's queue is full (the store or the engines cannot keep up)
    /// it answers [`MachineError::Busy`] at once instead of waiting.
    pub async fn ingest(&self, readings: Vec<Reading>) -> Result<WriteOutcome, MachineError> {
        let (reply, answer) = oneshot::channel();
        self.commands
            .try_send(Command::Ingest { readings, reply })
            .map_err(|e| match e {
                mpsc::error::TrySendError::Full(_) => MachineError::Busy {
                    machine: self.spec.id.clone(),
                    queued: self.commands.max_capacity(),
                },
                mpsc::error::TrySendError::Closed(_) => self.stopped(),
            })?;
        Ok(answer.await.map_err(|_| self.stopped())??)
    }

    /// An office: stores and fuses what the machine's site forwarded, in
    /// order, skipping each part whose sequence is already committed here;
    /// resolves once committed (the mark with it).
    pub async fn forwarded(
        &self,
        parts: Vec<(i64, ForwardedPart)>,
        confirmed: Option<i64>,
    ) -> Result<WriteOutcome, MachineError> {
        let (reply, answer) = oneshot::channel();
        self.commands
            .send(Command::Forwarded {
                parts,
                confirmed,
                reply,
            })
            .await
            .map_err(|_| self.stopped())?;
        Ok(answer.await.map_err(|_| self.stopped())??)
    }

    /// An office: the machine's mark was set back to `sequence` in the
    /// store; the task goes on from it.
    pub async fn set_forward_mark(&self, sequence: i64) -> Result<(), MachineError> {
        let (reply, answer) = oneshot::channel();
        self.commands
            .send(Command::SetForwardMark { sequence, reply })
            .await
            .map_err(|_| self.stopped())?;
        answer.await.map_err(|_| self.stopped())
    }

    /// Stores alarm rows the server decided for this machine.
    pub async fn alarms(&self, rows: Vec<AlarmRow>) -> Result<(), MachineError> {
        let (reply, answer) = oneshot::channel();
        self.commands
            .send(Command::Alarms { rows, reply })
            .await
            .map_err(|_| self.stopped())?;
        answer.await.map_err(|_| self.stopped())??;
        Ok(())
    }

    /// The engines' model reports.
    pub async fn models(&self) -> Result<BTreeMap<EngineKind, EngineModel>, MachineError> {
        let (reply, answer) = oneshot::channel();
        self.commands
            .send(Command::Models { reply })
            .await
            .map_err(|_| self.stopped())?;
        answer.await.map_err(|_| self.stopped())
    }

    /// Stores a final snapshot and stops the task.
    pub async fn stop(&self) {
        let (reply, answer) = oneshot::channel();
        if self.commands.send(Command::Stop { reply }).await.is_ok() {
            let _ = answer.await;
        }
    }

    /// New estimates from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<LiveEstimate> {
        self.live.subscribe()
    }

    /// The current status.
    pub fn status(&self) -> Arc<MachineStatus> {
        self.status.borrow().clone()
    }

    /// Live clients connected.
    pub fn live_clients(&self) -> usize {
        self.live.receiver_count()
    }

    fn stopped(&self) -> MachineError {
        MachineError::Stopped(self.spec.id.clone())
    }
}

/// Where a machine hands the alarm changes its writes committed, in
/// order: the server's notifier (live sockets, webhooks) subscribes here.
pub trait AlarmSink: Send + Sync + 'static {
    /// Takes committed changes; must not block (it runs on the store's
    /// writer thread).
    fn publish(&self, changes: Vec<AlarmChange>);
}

/// What a machine's task shares with the server.
#[derive(Clone)]
pub struct Surroundings {
    pub store: Store,
    /// Ingest requests that may wait for the task (busy beyond).
    pub queue_len: usize,
    /// The server clock, for sensors gone silent.
    pub clock: Clock,
    /// Where committed alarm changes go.
    pub alarm_changes: Arc<dyn AlarmSink>,
}

/// Starts the task that owns `core`.
/// `forward_mark`: an office's, the last sequence of the machine's site
/// committed here.
pub fn spawn(
    surroundings: Surroundings,
    spec: MachineSpec,
    db_id: i64,
    lease_epoch: Option<i64>,
    core: MachineCore,
    current: MachineStatus,
    forward_mark: Option<i64>,
) -> MachineHandle {
    let Surroundings {
        store,
        queue_len,
        clock,
        alarm_changes,
    } = surroundings;
    let lease_epoch = LeaseEpoch::new(lease_epoch);
    let (commands, queue) = mpsc::channel(queue_len.max(1));
    let (live, _) = broadcast::channel(LIVE_BUFFER);
    let (status_tx, status) = watch::channel(Arc::new(current.clone()));
    let spec = Arc::new(spec);
    let actor = Actor {
        store,
        spec: spec.clone(),
        db_id,
        lease_epoch: lease_epoch.clone(),
        core,
        write_failed: Arc::default(),
        uncounted: Arc::default(),
        live: live.clone(),
        status: status_tx,
        current,
        since_snapshot: 0,
        clock,
        alarm_changes,
        forward_mark,
    };
    tokio::spawn(actor.run(queue));
    MachineHandle {
        spec,
        db_id,
        lease_epoch,
        commands,
        live,
        status,
    }
}

struct Actor {
    store: Store,
    spec: Arc<MachineSpec>,
    db_id: i64,
    /// The lease this node runs the machine under (several nodes).
    lease_epoch: LeaseEpoch,
    core: MachineCore,
    /// Set by the store when one of this machine's writes failed: the
    /// engines have seen readings that are not stored, so they are rebuilt
    /// from the store before the next request.
    write_failed: Arc<AtomicBool>,
    /// What failed writes had added to the status's counters, taken back
    /// before the next request (a gateway resends what was refused).
    uncounted: Arc<Mutex<Counted>>,
    live: broadcast::Sender<LiveEstimate>,
    status: watch::Sender<Arc<MachineStatus>>,
    current: MachineStatus,
    since_snapshot: u64,
    /// The server clock, for sensors gone silent.
    clock: Clock,
    /// Where the alarms this machine's writes changed go once committed.
    alarm_changes: Arc<dyn AlarmSink>,
    /// An office: the last sequence of the machine's site fused here.
    forward_mark: Option<i64>,
}

/// What one write adds to the status's counters: its readings per sensor
/// and those fused late.
#[derive(Debug, Default)]
struct Counted {
    readings: BTreeMap<SensorKind, u64>,
    late: u64,
}

impl Counted {
    /// Adds `other`'s counts to these.
    fn add(&mut self, other: Counted) {
        for (sensor, n) in other.readings {
            *self.readings.entry(sensor).or_default() += n;
        }
        self.late += other.late;
    }

    /// Takes these counts back from `status`.
    fn take_back_from(&self, status: &mut MachineStatus) {
        for (sensor, n) in &self.readings {
            if let Some(entry) = status.sensors.get_mut(sensor) {
                entry.readings = entry.readings.saturating_sub(*n);
            }
        }
        status.late = status.late.saturating_sub(self.late);
    }
}

/// Real time between the checks for silent sensors.
const ALARM_TICK: std::time::Duration = std::time::Duration::from_secs(1);

impl Actor {
    async fn run(mut self, mut queue: mpsc::Receiver<Command>) {
        let mut tick = tokio::time::interval(ALARM_TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let command = tokio::select! {
                command = queue.recv() => match command {
                    Some(command) => command,
                    None => return,
                },
                _ = tick.tick() => {
                    self.check_silence().await;
                    continue;
                }
            };
            let mut stale = None;
            if self.write_failed.swap(false, Ordering::SeqCst) {
                self.take_back_uncounted();
                stale = self.rebuild().await;
            }
            match command {
                // Engines that have fused readings the store does not hold
                // must not fuse more: a retry of the lost request would
                // look to them like a duplicate. Until a rebuild succeeds,
                // ingest answers as the store did.
                Command::Ingest { reply, .. } if stale.is_some() => {
                    let why = stale.unwrap_or_default();
                    let _ = reply.send(Err(StoreError::Unrebuilt(why)));
                }
                Command::Forwarded { reply, .. } | Command::Alarms { reply, .. }
                    if stale.is_some() =>
                {
                    let why = stale.unwrap_or_default();
                    let _ = reply.send(Err(StoreError::Unrebuilt(why)));
                }
                Command::Ingest { readings, reply } => {
                    self.ingest(readings, None, Vec::new(), reply).await
                }
                Command::Forwarded {
                    parts,
                    confirmed,
                    reply,
                } => self.forwarded(parts, confirmed, reply).await,
                Command::SetForwardMark { sequence, reply } => {
                    self.forward_mark = Some(sequence);
                    let _ = reply.send(());
                }
                Command::Alarms { rows, reply } => self.ingest(Vec::new(), None, rows, reply).await,
                Command::Models { reply } => {
                    let _ = reply.send(self.core.models());
                }
                // Engines ahead of the store are not snapshotted: the next
                // start rebuilds from what the store holds.
                Command::Stop { reply } if stale.is_some() => {
                    let _ = reply.send(());
                    return;
                }
                Command::Stop { reply } => {
                    let (done, committed) = oneshot::channel();
                    let write = Write {
                        machine_id: self.db_id,
                        alarms: Vec::new(),
                        readings: Vec::new(),
                        estimates: Vec::new(),
                        snapshot: Some(self.core.snapshot()),
                        after_commit: None,
                        reply: Some(done),
                        lease_epoch: self.lease_epoch.get(),
                        forwarded: None,
                    };
                    if self.store.write(write).await.is_ok() {
                        let _ = committed.await;
                    }
                    let _ = reply.send(());
                    return;
                }
            }
        }
    }

    /// Copies what the active alarms read now into the status; whether it
    /// changed.
    fn publish_alarm_now(&mut self) -> bool {
        let now = self.core.alarm_now();
        if *now == self.current.alarm_now {
            return false;
        }
        self.current.alarm_now.clone_from(now);
        true
    }

    /// Sensors silent for too long by the server clock: their alarms,
    /// stored (with no readings) once raised.
    async fn check_silence(&mut self) {
        if self.write_failed.load(Ordering::SeqCst) {
            return;
        }
        let transitions = self.core.tick(self.clock.now_s());
        if self.publish_alarm_now() {
            self.status.send_replace(Arc::new(self.current.clone()));
        }
        if transitions.is_empty() {
            return;
        }
        let write_failed = self.write_failed.clone();
        let notifier = self.alarm_changes.clone();
        let write = Write {
            machine_id: self.db_id,
            alarms: transitions.iter().map(AlarmRow::new).collect(),
            readings: Vec::new(),
            estimates: Vec::new(),
            snapshot: None,
            after_commit: Some(Box::new(move |committed| match committed {
                Some(changes) => notifier.publish(changes),
                None => write_failed.store(true, Ordering::SeqCst),
            })),
            reply: None,
            lease_epoch: self.lease_epoch.get(),
            forwarded: None,
        };
        if let Err(e) = self.store.write(write).await {
            tracing::error!(error = %e, "store closed");
        }
    }

    /// Takes back from the status what failed writes had counted: their
    /// readings are not stored, and a gateway resends them.
    fn take_back_uncounted(&mut self) {
        let failed = std::mem::take(
            &mut *self
                .uncounted
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        failed.take_back_from(&mut self.current);
        self.status.send_replace(Arc::new(self.current.clone()));
    }

    /// Rebuilds the engines from the latest snapshot and the stored
    /// readings after it. Writes queued before the failure was noticed may
    /// still commit estimates computed from the lost readings; the readings
    /// themselves are what the store holds.
    /// `None` when the engines match the store again, else why not.
    async fn rebuild(&mut self) -> Option<String> {
        let (store, spec, db_id, epoch) = (
            self.store.clone(),
            self.spec.clone(),
            self.db_id,
            self.lease_epoch.get(),
        );
        match tokio::task::spawn_blocking(move || recover(&store, &spec, db_id, epoch)).await {
            Ok(Ok(core)) => {
                if self.forward_mark.is_some() {
                    let store = self.store.clone();
                    let db_id = self.db_id;
                    match tokio::task::spawn_blocking(move || store.forward_mark(db_id)).await {
                        Ok(Ok(mark)) => self.forward_mark = mark,
                        Ok(Err(e)) => {
                            self.write_failed.store(true, Ordering::SeqCst);
                            return Some(e.to_string());
                        }
                        Err(e) => {
                            self.write_failed.store(true, Ordering::SeqCst);
                            return Some(e.to_string());
                        }
                    }
                }
                // The rebuilt core keeps when this server resumed the
                // machine: the time it was down is still no silence.
                let mut core = core;
                if let Some(resumed_t) = self.core.resumed_t() {
                    core.resumed(resumed_t);
                }
                self.core = core;
                self.since_snapshot = 0;
                tracing::warn!(machine = %self.spec.id, "engines rebuilt from the store after a failed write");
                None
            }
            Ok(Err(e)) => {
                tracing::error!(machine = %self.spec.id, error = %e, "rebuild failed; retrying on the next request");
                self.write_failed.store(true, Ordering::SeqCst);
                Some(e.to_string())
            }
            Err(e) => {
                tracing::error!(machine = %self.spec.id, error = %e, "rebuild panicked");
                self.write_failed.store(true, Ordering::SeqCst);
                Some(e.to_string())
            }
        }
    }

    /// An office: fuses and stores the parts of a site's forwarding not
    /// committed here yet, readings in the site's order (not re-sorted:
    /// the site stored them sorted per batch, and the same order gives
    /// the same estimates), the site's alarm changes as they were made.
    async fn forwarded(
        &mut self,
        parts: Vec<(i64, ForwardedPart)>,
        confirmed: Option<i64>,
        reply: oneshot::Sender<Result<WriteOutcome, StoreError>>,
    ) {
        if let Err(e) = self.held(&parts, confirmed).await {
            let _ = reply.send(Err(e));
            return;
        }
        let mark = self.forward_mark.unwrap_or(i64::MIN);
        let mut readings = Vec::new();
        let mut forwarded = crate::store::outbox::Forwarded {
            after: self.forward_mark,
            confirmed,
            ..Default::default()
        };
        let mut rows = Vec::new();
        for (sequence, part) in parts.into_iter().filter(|(s, _)| *s > mark) {
            forwarded.applied.push(sequence);
            forwarded.sequence = sequence;
            match part {
                ForwardedPart::Readings(batch) => readings.extend(batch),
                ForwardedPart::Alarm {
                    rows: raise_and_clear,
                    ack,
                } => {
                    rows.extend(raise_and_clear);
                    forwarded.acks.extend(ack.map(|ack| *ack));
                }
            }
        }
        if forwarded.sequence == 0 {
            // Every part was fused already (a resend): answered once what
            // was queued before is committed, so the office reads its
            // mark after that (an empty write queued behind them).
            self.ingest(Vec::new(), None, Vec::new(), reply).await;
            return;
        }
        self.forward_mark = Some(forwarded.sequence);
        self.ingest(readings, Some(forwarded), rows, reply).await;
    }

    /// An office: whether every part at or below the mark (and above
    /// what the site `confirmed`) is a row this office holds, checked here
    /// against the mark the machine goes on from, so no request between
    /// the check and the write moves it. The store's record is read only
    /// for such rows (a resend, or a forged mark).
    async fn held(
        &mut self,
        parts: &[(i64, ForwardedPart)],
        confirmed: Option<i64>,
    ) -> Result<(), StoreError> {
        let below = |mark: Option<i64>| -> Vec<i64> {
            let mark = mark.unwrap_or(i64::MIN);
            let confirmed = confirmed.unwrap_or(i64::MIN);
            parts
                .iter()
                .map(|(sequence, _)| *sequence)
                .filter(|&sequence| sequence <= mark && sequence > confirmed)
                .collect()
        };
        if below(self.forward_mark).is_empty() {
            return Ok(());
        }
        let store = self.store.clone();
        let db_id = self.db_id;
        let held = tokio::task::spawn_blocking(move || store.forward_held(db_id))
            .await
            .map_err(|e| StoreError::Unavailable(e.to_string()))??;
        match below(self.forward_mark)
            .into_iter()
            .find(|&sequence| !held.holds(sequence))
        {
            Some(sequence) => Err(StoreError::NotHeld {
                sequence,
                mark: self.forward_mark.unwrap_or_default(),
            }),
            None => Ok(()),
        }
    }

    /// Fuses `readings` (sorted first, unless `forwarded`: a site's are
    /// fused in the order it stored them) and commits them with their
    /// estimates, `alarm_rows` and, for an office, the site's sequence.
    async fn ingest(
        &mut self,
        mut readings: Vec<Reading>,
        forwarded: Option<crate::store::outbox::Forwarded>,
        alarm_rows: Vec<AlarmRow>,
        reply: oneshot::Sender<Result<WriteOutcome, StoreError>>,
    ) {
        if forwarded.is_none() {
            // A batch is one arrival: put it in time order before the buffer.
            readings.sort_by(|a, b| a.t.total_cmp(&b.t));
        }
        let mut estimates = Vec::new();
        let mut rows = Vec::with_capacity(readings.len());
        let mut counted = Counted::default();
        for reading in readings {
            let sensor = reading.sensor();
            let entry = self.current.sensors.entry(sensor).or_insert(SensorStatus {
                last_t: reading.t,
                readings: 0,
            });
            entry.last_t = entry.last_t.max(reading.t);
            entry.readings += 1;
            *counted.readings.entry(sensor).or_default() += 1;
            rows.push(ReadingRow::new(&reading));
            if self.core.push(reading, &mut estimates) == Admission::Late {
                self.current.late += 1;
                counted.late += 1;
            }
        }
        self.since_snapshot += rows.len() as u64;
        let snapshot = (self.since_snapshot >= SNAPSHOT_EVERY_READINGS).then(|| {
            self.since_snapshot = 0;
            self.core.snapshot()
        });
        let (live, estimate_rows): (Vec<LiveEstimate>, Vec<EstimateRow>) = estimates
            .into_iter()
            .map(|e| (Arc::new(e.live), e.row))
            .unzip();
        for estimate in &live {
            self.current
                .latest
                .insert(estimate.engine, estimate.clone());
        }
        self.publish_alarm_now();
        self.status.send_replace(Arc::new(self.current.clone()));
        let sender = self.live.clone();
        let write_failed = self.write_failed.clone();
        let uncounted = self.uncounted.clone();
        let notifier = self.alarm_changes.clone();
        let mut alarms: Vec<AlarmRow> = self.core.take_alarms().iter().map(AlarmRow::new).collect();
        alarms.extend(alarm_rows);
        let write = Write {
            machine_id: self.db_id,
            alarms,
            readings: rows,
            estimates: estimate_rows,
            snapshot,
            after_commit: Some(Box::new(move |committed| match committed {
                Some(changes) => {
                    for estimate in live {
                        // No receivers is fine.
                        let _ = sender.send(estimate);
                    }
                    notifier.publish(changes);
                }
                None => {
                    uncounted
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .add(counted);
                    write_failed.store(true, Ordering::SeqCst);
                }
            })),
            reply: Some(reply),
            lease_epoch: self.lease_epoch.get(),
            forwarded: forwarded.map(Box::new),
        };
        if let Err(e) = self.store.write(write).await {
            tracing::error!(error = %e, "store closed");
        }
    }
}
