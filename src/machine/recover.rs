//! A machine rebuilt from the store: its newest estimates, its status and
//! its engines from the latest snapshot and the readings after it.

use std::sync::Arc;

use tokio::sync::oneshot;

use crate::config::MachineSpec;
use crate::fusion::alarms::Transition;
use crate::fusion::{EngineOutput, SensorKind, SnapshotError};
use crate::store::alarms::AlarmRow;
use crate::store::{Store, StoreError, Write};

use super::core::{Emitted, FusedEstimate, MachineCore};
use super::error::MachineError;
use super::status::{MachineStatus, SensorStatus};

/// Estimates written per store request while re-feeding after a restart.
const REFEED_CHUNK: usize = 10_000;

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
