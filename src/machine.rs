//! One machine: its engines behind a reorder buffer ([`MachineCore`], plain
//! synchronous code) and the task that owns them ([`spawn`]), the only
//! bridge from the async server to the fusion core.
//!
//! Per ingest request the task time-orders the batch, pushes it through the
//! reorder buffer into every engine that uses each sensor, and sends the
//! readings, the estimates they produced and now and then a snapshot to the
//! store as one write. The request is answered by the store after the
//! commit; the estimates are broadcast to live clients at the same moment.
//! The task does not wait for the commit, so one machine's requests are
//! pipelined into the store's group commits.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, mpsc, oneshot, watch};

use crate::clock::Clock;
use crate::config::MachineSpec;
use crate::fusion::alarms::{AlarmKind, AlarmNow, AlarmRules, AlarmState, Transition};
use crate::fusion::estimate::EstimateWriter;
use crate::fusion::pipeline::{Pipeline, PipelineState};
use crate::fusion::reorder::{Admission, ReorderBuffer};
use crate::fusion::{
    EngineKind, EngineModel, EngineOutput, ParamError, Reading, SensorKind, Signals, SnapshotError,
    StreamKind,
};
use crate::store::alarms::{AlarmChange, AlarmRow};
use crate::store::{EstimateRow, ReadingRow, Store, StoreError, Write, WriteOutcome};

/// Most readings the reorder buffer holds per machine.
pub const REORDER_MAX_LEN: usize = 100_000;
/// A snapshot is stored after this many readings, so a restart re-feeds at
/// most this many.
pub const SNAPSHOT_EVERY_READINGS: u64 = 20_000;
/// Estimates a slow live client may fall behind by before it gets a `gap`.
pub const LIVE_BUFFER: usize = 4096;
/// Estimates written per store request while re-feeding after a restart.
const REFEED_CHUNK: usize = 10_000;

/// Why a machine could not be built or restored.
#[derive(Debug, thiserror::Error)]
pub enum MachineError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error(transparent)]
    Snapshot(#[from] SnapshotError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("stored reading is invalid: {0}")]
    StoredReading(String),
    #[error("machine `{0}` has stopped")]
    Stopped(String),
    #[error("machine `{machine}` is busy: {queued} requests are waiting for it")]
    Busy { machine: String, queued: usize },
}

/// An estimate as the machine emits it: attributed, serialised once.
#[derive(Debug, Clone)]
pub struct FusedEstimate {
    /// The engine or stage that made it.
    pub engine: StreamKind,
    pub t: f64,
    /// What the alarm rules and the status watch in it.
    pub signals: Signals,
    /// The protocol JSON, one object, no newline.
    pub json: Arc<str>,
}

impl FusedEstimate {
    /// A stored estimate of `machine`'s `engine` as the live stream shows it.
    pub fn stored(
        machine: &str,
        engine: StreamKind,
        output: &EngineOutput,
    ) -> Result<FusedEstimate, StoreError> {
        let json = serde_json::to_string(&output.for_machine(machine))
            .map_err(|e| StoreError::Corrupt(format!("stored estimate: {e}")))?;
        Ok(FusedEstimate {
            engine,
            t: output.t,
            signals: output.values.signals(),
            json: Arc::from(json),
        })
    }
}

/// One engine output in both forms it leaves the machine in: JSON for live
/// clients and the status, a compact row for the store.
#[derive(Debug)]
pub struct Emitted {
    pub live: FusedEstimate,
    pub row: EstimateRow,
}

/// What live clients receive.
pub type LiveEstimate = Arc<FusedEstimate>;

/// A machine's engines, stages and reorder buffer: deterministic, no IO.
/// The same readings in the same arrival order give the same estimates
/// here, in a restored copy, and (for time-ordered input) in `replay`.
pub struct MachineCore {
    pipeline: Pipeline,
    reorder: ReorderBuffer,
    alarms: AlarmRules,
    /// Alarm transitions since [`MachineCore::take_alarms`].
    transitions: Vec<Transition>,
    writer: EstimateWriter,
    ready: Vec<Reading>,
    outputs: Vec<EngineOutput>,
    line: Vec<u8>,
    /// Whether the alarm rules run here: not for a machine an office holds
    /// for a site, whose alarms come from the site.
    own_alarms: bool,
}

#[derive(Serialize, Deserialize)]
struct CoreState {
    #[serde(flatten)]
    pipeline: PipelineState,
    reorder: serde_json::Value,
    /// Absent in snapshots from before the alarms: no alarm active.
    #[serde(default)]
    alarms: AlarmState,
}

impl MachineCore {
    /// Fresh engines and stages for `spec`.
    pub fn new(spec: &MachineSpec) -> Result<MachineCore, ParamError> {
        Ok(Self::assemble(
            spec,
            spec.pipeline()?,
            ReorderBuffer::new(spec.reorder_window_s, REORDER_MAX_LEN),
            AlarmState::default(),
        ))
    }

    /// Engines and stages continuing from a [`MachineCore::snapshot`].
    pub fn restore(spec: &MachineSpec, state: &str) -> Result<MachineCore, SnapshotError> {
        Self::from_snapshot(spec, state, Pipeline::restore)
    }

    /// Like [`MachineCore::restore`], a stage this release added that may
    /// be seeded starting from `newest`, the machine's newest stored
    /// output of each stream ([`Pipeline::restore_seeded`]).
    pub fn restore_seeded(
        spec: &MachineSpec,
        state: &str,
        newest: &[EngineOutput],
    ) -> Result<MachineCore, SnapshotError> {
        Self::from_snapshot(spec, state, |pipeline, declaration| {
            Pipeline::restore_seeded(pipeline, declaration, newest)
        })
    }

    /// The engines of a [`MachineCore::snapshot`] under a declaration that
    /// differs only in what the stages read (the design axis, geometry,
    /// tolerances, start): the engines go on where they stood, a stage the
    /// declaration now calls for starts from here.
    pub fn redeclared(spec: &MachineSpec, state: &str) -> Result<MachineCore, SnapshotError> {
        Self::from_snapshot(spec, state, Pipeline::restore_adding_stages)
    }

    /// The core of a snapshot's `state`, its pipeline restored by `pipeline`.
    fn from_snapshot(
        spec: &MachineSpec,
        state: &str,
        pipeline: impl FnOnce(
            PipelineState,
            &crate::fusion::stage::Declaration,
        ) -> Result<Pipeline, SnapshotError>,
    ) -> Result<MachineCore, SnapshotError> {
        let state: CoreState =
            serde_json::from_str(state).map_err(|e| SnapshotError::Invalid(e.to_string()))?;
        Ok(Self::assemble(
            spec,
            pipeline(state.pipeline, &spec.stage_declaration())?,
            ReorderBuffer::restore(state.reorder)?,
            state.alarms,
        ))
    }

    fn assemble(
        spec: &MachineSpec,
        pipeline: Pipeline,
        reorder: ReorderBuffer,
        alarms: AlarmState,
    ) -> Self {
        MachineCore {
            pipeline,
            reorder,
            alarms: AlarmRules::new(spec.alarms, spec.tolerances, &spec.streams(), alarms),
            transitions: Vec::new(),
            writer: EstimateWriter::new(&spec.id),
            ready: Vec::new(),
            outputs: Vec::new(),
            line: Vec::new(),
            own_alarms: crate::config::forwarded_site(&spec.id).is_none(),
        }
    }

    /// The whole state as JSON.
    pub fn snapshot(&self) -> String {
        let state = CoreState {
            pipeline: self.pipeline.state(),
            reorder: self.reorder.snapshot(),
            alarms: self.alarms.state().clone(),
        };
        serde_json::to_string(&state).unwrap_or_default()
    }

    /// Offers one reading; appends the estimates that became ready to `out`.
    pub fn push(&mut self, reading: Reading, out: &mut Vec<Emitted>) -> Admission {
        let admission = self.reorder.push(reading);
        self.reorder.pop_ready(&mut self.ready);
        for reading in self.ready.drain(..) {
            self.outputs.clear();
            if self.own_alarms {
                self.alarms.reading(&reading, &mut self.transitions);
            }
            self.pipeline.feed(&reading, &mut self.outputs);
            for output in &self.outputs {
                let stream = output.values.stream();
                let signals = output.values.signals();
                if self.own_alarms {
                    self.alarms.signals(
                        output.t,
                        stream,
                        output.integrity,
                        &signals,
                        &mut self.transitions,
                    );
                }
                self.line.clear();
                self.writer.write_line(output, &mut self.line);
                let json = std::str::from_utf8(self.line.trim_ascii_end()).unwrap_or("{}");
                out.push(Emitted {
                    live: FusedEstimate {
                        engine: stream,
                        t: output.t,
                        signals,
                        json: Arc::from(json),
                    },
                    row: EstimateRow::new(output),
                });
            }
        }
        admission
    }

    /// The alarms raised and cleared since the last call.
    pub fn take_alarms(&mut self) -> Vec<Transition> {
        std::mem::take(&mut self.transitions)
    }

    /// What each active alarm's quantity reads now, by kind and subject.
    pub fn alarm_now(&self) -> &BTreeMap<(AlarmKind, String), AlarmNow> {
        self.alarms.now()
    }

    /// The server runs the machine again at `now_t`: its downtime is not
    /// its sensors' silence.
    pub fn resumed(&mut self, now_t: f64) {
        self.alarms.resumed(now_t);
    }

    /// When [`MachineCore::resumed`] last said the server resumed.
    pub fn resumed_t(&self) -> Option<f64> {
        self.alarms.resumed_t()
    }

    /// The server clock at `now_t`: sensors silent too long. Returns the
    /// alarms raised (and any pending from readings).
    pub fn tick(&mut self, now_t: f64) -> Vec<Transition> {
        if self.own_alarms {
            self.alarms.tick(now_t, &mut self.transitions);
        }
        self.take_alarms()
    }

    /// Each engine's model report, if it has one.
    pub fn models(&self) -> BTreeMap<EngineKind, EngineModel> {
        self.pipeline.models()
    }
}

/// Last reading of one sensor.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SensorStatus {
    /// Time of the newest reading received, Unix seconds.
    pub last_t: f64,
    /// Readings received since the server started.
    pub readings: u64,
}

/// What a machine looks like now; published after every request.
#[derive(Debug, Clone, Default)]
pub struct MachineStatus {
    /// Latest estimate of each engine and stage, protocol JSON.
    pub latest: BTreeMap<StreamKind, LiveEstimate>,
    pub sensors: BTreeMap<SensorKind, SensorStatus>,
    /// Readings dropped as older than one of the same sensor already fused
    /// (stored all the same), since the server started.
    pub late: u64,
    /// What each active alarm's quantity reads now, by kind and subject.
    pub alarm_now: BTreeMap<(AlarmKind, String), AlarmNow>,
}

/// One part of what a site forwards for a machine, with its sequence.
#[derive(Debug, Clone)]
pub enum ForwardedPart {
    /// Readings, fused in the order the site stored them.
    Readings(Vec<Reading>),
    /// An alarm change the site made.
    Alarm(Box<AlarmChange>),
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

/// The newest stored output of each of the machine's streams. Blocking.
pub fn newest_outputs(
    store: &Store,
    spec: &MachineSpec,
    db_id: i64,
) -> Result<Vec<EngineOutput>, MachineError> {
    let mut newest = Vec::new();
    for stream in spec.streams() {
        newest.extend(store.latest_estimate(db_id, stream)?);
    }
    Ok(newest)
}

/// The status a restarted machine starts from: each engine's latest stored
/// estimate and each sensor's latest stored reading. Blocking.
pub fn stored_status(
    store: &Store,
    spec: &MachineSpec,
    db_id: i64,
) -> Result<MachineStatus, MachineError> {
    let mut status = MachineStatus::default();
    for engine in spec.streams() {
        let Some(output) = store.latest_estimate(db_id, engine)? else {
            continue;
        };
        status.latest.insert(
            engine,
            Arc::new(FusedEstimate::stored(&spec.id, engine, &output)?),
        );
    }
    for sensor in SensorKind::ALL {
        if let Some(last_t) = store.last_reading_t(db_id, sensor)? {
            status.sensors.insert(
                sensor,
                SensorStatus {
                    last_t,
                    readings: 0,
                },
            );
        }
    }
    Ok(status)
}

/// Restores the machine from its latest snapshot, re-feeds the readings
/// stored after it (writing the estimates they give, which are usually
/// already stored), and stores a fresh snapshot. Blocking. `lease_epoch`:
/// the lease this node holds the machine under (several nodes), checked
/// by each of these writes.
pub fn recover(
    store: &Store,
    spec: &MachineSpec,
    db_id: i64,
    lease_epoch: Option<i64>,
) -> Result<MachineCore, MachineError> {
    let snapshot = store.snapshot(db_id)?;
    let (mut core, after_id) = match &snapshot {
        Some(s) => match MachineCore::restore(spec, &s.state) {
            Ok(core) => (core, s.last_reading_id),
            // An engine whose state this release no longer reads starts
            // afresh from every stored reading: slower once, nothing lost.
            Err(SnapshotError::Outdated {
                engine,
                found,
                expected,
            }) => {
                tracing::warn!(
                    machine = %spec.id, %engine, found, expected,
                    "snapshot from an earlier release: rebuilding the engines from the stored readings"
                );
                (MachineCore::new(spec)?, 0)
            }
            // A stage this release adds: seeded from the newest stored
            // estimates where that equals a replay, else it starts with the
            // machine's history.
            Err(SnapshotError::MissingStage(_)) => {
                let newest = newest_outputs(store, spec, db_id)?;
                match MachineCore::restore_seeded(spec, &s.state, &newest) {
                    Ok(core) => (core, s.last_reading_id),
                    Err(SnapshotError::MissingStage(stage)) => {
                        tracing::warn!(
                            machine = %spec.id, %stage,
                            "snapshot without a stage the machine now runs: rebuilding from the stored readings"
                        );
                        (MachineCore::new(spec)?, 0)
                    }
                    Err(e) => return Err(e.into()),
                }
            }
            Err(e) => return Err(e.into()),
        },
        None => (MachineCore::new(spec)?, 0),
    };
    let mut estimates = Vec::new();
    let flush =
        |estimates: &mut Vec<Emitted>, alarms: Vec<Transition>, snapshot: Option<String>| {
            let (reply, answer) = oneshot::channel();
            store.write_blocking(Write {
                machine_id: db_id,
                alarms: alarms.iter().map(AlarmRow::new).collect(),
                readings: Vec::new(),
                estimates: estimates.drain(..).map(|e| e.row).collect(),
                snapshot,
                after_commit: None,
                reply: Some(reply),
                lease_epoch,
                forwarded: None,
            })?;
            answer.blocking_recv().map_err(|_| StoreError::Closed)??;
            Ok::<_, MachineError>(())
        };
    let mut failure = None;
    let refed = store.readings_since(db_id, after_id, |reading| {
        if let Err(e) = reading.validate() {
            failure = Some(MachineError::StoredReading(format!(
                "{e}: {}",
                reading.to_json()
            )));
        } else {
            core.push(reading, &mut estimates);
        }
        if estimates.len() >= REFEED_CHUNK {
            flush(&mut estimates, core.take_alarms(), None)
                .map_err(|e| StoreError::Corrupt(e.to_string()))?;
        }
        Ok(())
    })?;
    if let Some(e) = failure {
        return Err(e);
    }
    let alarms = core.take_alarms();
    flush(&mut estimates, alarms, Some(core.snapshot()))?;
    tracing::info!(machine = %spec.id, refed, "machine restored");
    Ok(core)
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

/// The lease epoch a machine runs under on this node (several nodes on
/// PostgreSQL), shared by its handle and its task: every write carries
/// it. Raised in place when this node takes a lapsed lease back that no
/// other node held meanwhile.
#[derive(Debug, Clone)]
pub struct LeaseEpoch(Arc<std::sync::atomic::AtomicI64>);

impl LeaseEpoch {
    /// No lease (one server).
    const NONE: i64 = i64::MIN;

    pub fn new(epoch: Option<i64>) -> LeaseEpoch {
        LeaseEpoch(Arc::new(std::sync::atomic::AtomicI64::new(
            epoch.unwrap_or(Self::NONE),
        )))
    }

    pub fn get(&self) -> Option<i64> {
        let epoch = self.0.load(Ordering::SeqCst);
        (epoch != Self::NONE).then_some(epoch)
    }

    pub fn set(&self, epoch: i64) {
        self.0.store(epoch, Ordering::SeqCst);
    }
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
                ForwardedPart::Alarm(change) => {
                    match crate::store::alarms::forwarded_rows(&change) {
                        Some((raise_and_clear, ack)) => {
                            rows.extend(raise_and_clear);
                            forwarded.acks.extend(ack);
                        }
                        None => tracing::warn!(
                            machine = %self.spec.id, kind = %change.alarm.kind,
                            "a forwarded alarm of a kind or severity this release does not know: not stored"
                        ),
                    }
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
        for reading in readings {
            let sensor = reading.sensor();
            let entry = self.current.sensors.entry(sensor).or_insert(SensorStatus {
                last_t: reading.t,
                readings: 0,
            });
            entry.last_t = entry.last_t.max(reading.t);
            entry.readings += 1;
            rows.push(ReadingRow::new(&reading));
            if self.core.push(reading, &mut estimates) == Admission::Late {
                self.current.late += 1;
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
                None => write_failed.store(true, Ordering::SeqCst),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineDeclaration;
    use crate::fusion::SensorData;
    use crate::fusion::alarms::{AlarmKind, Severity};
    use crate::fusion::reading::ProjectPoint;

    /// An attitude machine on a straight axis due north from (1000, 5000),
    /// level at 50 m, with ±50/100 mm horizontal tolerances.
    fn spec() -> MachineSpec {
        serde_json::from_value::<MachineDeclaration>(serde_json::json!({
            "engines": {"attitude": {}},
            "geometry": {"front_m": [4.0, 0.0, 0.0], "rear_m": [-5.0, 0.0, 0.0]},
            "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                           "vertical_mm": {"warn": 30, "alarm": 60}},
            "alignment": {"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
                          "horizontal": [{"type": "line", "length_m": 100.0}],
                          "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}
        }))
        .unwrap()
        .validate("tbm-alarms")
        .unwrap()
    }

    /// A laser reading at `t` with the machine `right_mm` right of the axis.
    fn laser(t: f64, right_mm: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Laser {
                pitch_deg: 0.0,
                roll_deg: 0.0,
                yaw_deg: Some(0.0),
                position: Some(ProjectPoint {
                    easting_m: 1000.0 + right_mm / 1000.0,
                    northing_m: 5020.0,
                    height_m: 50.0,
                }),
            },
        }
    }

    fn inclinometer(t: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg: 0.0,
                roll_deg: 0.0,
                temp_c: None,
            },
        }
    }

    fn feed(
        core: &mut MachineCore,
        readings: impl IntoIterator<Item = Reading>,
    ) -> Vec<Transition> {
        let mut out = Vec::new();
        for reading in readings {
            core.push(reading, &mut out);
        }
        core.take_alarms()
    }

    #[test]
    fn the_machine_raises_clears_and_remembers_its_alarms_across_a_snapshot() {
        let spec = spec();
        let mut core = MachineCore::new(&spec).unwrap();
        // 70 mm right from t = 0, every 2 s: warn raised once the 10 s
        // minimum has passed, dated 0.
        let raised = feed(&mut core, (0..=10).map(|i| laser(2.0 * f64::from(i), 70.0)));
        assert_eq!(raised.len(), 1, "{raised:?}");
        assert_eq!(
            (
                raised[0].key.kind,
                raised[0].key.severity,
                raised[0].raised,
                raised[0].t
            ),
            (AlarmKind::Deviation, Severity::Warn, true, 0.0)
        );
        // Restored from a snapshot, it stays raised: no second raise.
        let mut restored = MachineCore::restore(&spec, &core.snapshot()).unwrap();
        assert!(
            feed(
                &mut restored,
                (11..20).map(|i| laser(2.0 * f64::from(i), 70.0))
            )
            .is_empty()
        );
        // Back on the axis from t = 40, an inclinometer reading between
        // each: cleared at t = 60 (gone 10 s, and held a minute from its
        // onset), dated 40.
        let cleared = feed(
            &mut restored,
            (20..=30).flat_map(|i| {
                let t = 2.0 * f64::from(i);
                [laser(t, 0.0), inclinometer(t + 1.0)]
            }),
        );
        assert_eq!(cleared.len(), 1, "{cleared:?}");
        assert!(!cleared[0].raised && cleared[0].t == 40.0);
        // The machine then falls silent: the inclinometer is stale after 5
        // of its 2 s periods, at least 10 s, past its last reading at
        // t = 61 (the laser's silence is a laser dropout's business).
        assert!(restored.tick(70.0).is_empty());
        let stale = restored.tick(72.0);
        assert_eq!(stale.len(), 1, "{stale:?}");
        assert_eq!(
            (stale[0].key.kind, stale[0].key.subject.as_str(), stale[0].t),
            (AlarmKind::StaleSensor, "inclinometer", 71.0)
        );
    }

    #[test]
    fn a_snapshot_from_before_the_alarms_restores_with_none_active() {
        let spec = spec();
        let core = MachineCore::new(&spec).unwrap();
        let mut state: serde_json::Value = serde_json::from_str(&core.snapshot()).unwrap();
        state.as_object_mut().unwrap().remove("alarms");
        let mut restored = MachineCore::restore(&spec, &state.to_string()).unwrap();
        let raised = feed(
            &mut restored,
            (0..=10).map(|i| laser(2.0 * f64::from(i), 70.0)),
        );
        assert_eq!(raised.len(), 1);
    }
}
