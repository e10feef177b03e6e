//! A machine whose write fails (a busy database): the engines are rebuilt
//! from the store, and the status's counters take back what the failed
//! write had counted, so the gateway's resend is counted once. Run on the
//! test-only memory backend, which fails writes on request.

mod memory_store;

use std::sync::Arc;

use memory_store::MemoryStore;
use tunnelnav::clock::Clock;
use tunnelnav::config::{MachineDeclaration, MachineSpec};
use tunnelnav::fusion::{Reading, SensorData, SensorKind};
use tunnelnav::machine::{self, AlarmSink, MachineCore, MachineError, MachineStatus, Surroundings};
use tunnelnav::store::alarms::AlarmChange;
use tunnelnav::store::{Store, StoreError};

struct NoAlarms;

impl AlarmSink for NoAlarms {
    fn publish(&self, _changes: Vec<AlarmChange>) {}
}

fn spec() -> MachineSpec {
    serde_json::from_value::<MachineDeclaration>(serde_json::json!({"engines": {"attitude": {}}}))
        .unwrap()
        .validate("tbm-busy")
        .unwrap()
}

fn inclinometer(t: f64) -> Reading {
    Reading {
        t,
        data: SensorData::Inclinometer {
            pitch_deg: 0.5,
            roll_deg: 0.1,
            temp_c: None,
        },
    }
}

fn batch(from_s: u32, count: u32) -> Vec<Reading> {
    (from_s..from_s + count)
        .map(|t| inclinometer(1_772_431_200.0 + f64::from(t)))
        .collect()
}

fn counts(status: &MachineStatus) -> (u64, u64) {
    let readings = status
        .sensors
        .get(&SensorKind::Inclinometer)
        .map_or(0, |s| s.readings);
    (readings, status.late)
}

#[tokio::test]
async fn a_refused_batch_is_counted_once_when_it_is_resent() {
    let memory = MemoryStore::new(Default::default());
    let store = Store::new(memory.clone());
    let spec = spec();
    let core = MachineCore::new(&spec).unwrap();
    let snapshot = core.snapshot();
    let db_id = store.put_machine(spec.clone(), snapshot).await.unwrap();
    let handle = machine::spawn(
        Surroundings {
            store: store.clone(),
            queue_len: 8,
            clock: Clock::system(),
            alarm_changes: Arc::new(NoAlarms),
        },
        spec,
        db_id,
        None,
        core,
        MachineStatus::default(),
        None,
    );

    // Seconds 100..110 stored; then 50..60 arrive: older than what was
    // fused, so late (stored, not fused).
    handle.ingest(batch(100, 10)).await.unwrap();
    memory.fail_next_writes(1);
    let refused = handle.ingest(batch(50, 10)).await;
    assert!(
        matches!(
            refused,
            Err(MachineError::Store(StoreError::Unavailable(_)))
        ),
        "{refused:?}"
    );
    // The gateway resends the refused batch: it is counted once.
    let outcome = handle.ingest(batch(50, 10)).await.unwrap();
    assert_eq!((outcome.stored, outcome.duplicates), (10, 0), "{outcome:?}");
    assert_eq!(counts(&handle.status()), (20, 10));

    // A refused batch of readings that would have been fused, resent.
    memory.fail_next_writes(1);
    assert!(handle.ingest(batch(110, 5)).await.is_err());
    handle.ingest(batch(110, 5)).await.unwrap();
    assert_eq!(counts(&handle.status()), (25, 10));
    handle.stop().await;
}
