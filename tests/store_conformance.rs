//! One conformance suite, run against every store backend through the
//! `Backend` trait (issues 37, 59): SQLite in a temporary data dir,
//! PostgreSQL in a cluster of the test's own (tests/common/postgres.rs;
//! skipped without PostgreSQL unless `TUNNELNAV_POSTGRES_TEST=required`),
//! and a test-only backend kept in memory (tests/memory_store/: what a new
//! backend takes, one folder and the `mod` line below). Each operation the PostgreSQL
//! store has so far is held to the SQLite store's answers: declaring
//! machines, group-committed writes (readings stored once, in arrival
//! order; estimates with their codec; alarms raised and cleared once;
//! snapshots after the last reading), reads after a restart, a newer
//! schema refused, a refused connection reported as transient.

mod common;
mod memory_store;

use common::postgres::PgCluster;
use memory_store::MemoryStore;
use tokio::sync::oneshot;
use tunnelnav::config::{MachineDeclaration, MachineSpec};
use tunnelnav::fusion::alarms::{AlarmKey, AlarmKind, Severity, Transition};
use tunnelnav::fusion::{
    AttitudeEstimate, EngineOutput, EstimateValues, Reading, SensorData, SensorKind, StreamKind,
};
use tunnelnav::store::alarms::{AlarmFilter, AlarmRow};
use tunnelnav::store::postgres::{PgLocation, PgStore};
use tunnelnav::store::{EstimateRow, ReadingRow, Store, StoreError, Write, WriteOutcome};

/// A blocking read, on a blocking thread.
async fn read<R: Send + 'static>(
    store: &Store,
    read: impl FnOnce(&Store) -> Result<R, StoreError> + Send + 'static,
) -> R {
    let store = store.clone();
    tokio::task::spawn_blocking(move || read(&store))
        .await
        .unwrap()
        .unwrap()
}

fn readings_since(store: &Store, id: i64, after: i64) -> Result<Vec<String>, StoreError> {
    let mut out = Vec::new();
    store.readings_since(id, after, |r: Reading| {
        out.push(r.to_json());
        Ok(())
    })?;
    Ok(out)
}

fn estimates_page(
    store: &Store,
    id: i64,
    from_t: f64,
    to_t: f64,
    max_points: usize,
) -> Result<(bool, Vec<String>), StoreError> {
    let page = store.estimates_page(id, StreamKind::Attitude, from_t, to_t, max_points)?;
    Ok((
        page.downsampled,
        page.estimates.iter().map(|e| format!("{e:?}")).collect(),
    ))
}

/// Readings exported in `[from_t, to_t]`, at most `most`.
fn export_readings(
    store: &Store,
    id: i64,
    sensor: Option<SensorKind>,
    from_t: f64,
    to_t: f64,
    most: usize,
) -> Result<Vec<String>, StoreError> {
    let mut out = Vec::new();
    store.export_readings(id, sensor, from_t, to_t, |r: &Reading| {
        out.push(r.to_json());
        out.len() < most
    })?;
    Ok(out)
}

/// Estimates exported in `[from_t, to_t]`, at most `most`.
fn export_estimates(
    store: &Store,
    id: i64,
    from_t: f64,
    to_t: f64,
    most: usize,
) -> Result<Vec<String>, StoreError> {
    let mut out = Vec::new();
    store.export_estimates(
        id,
        StreamKind::Attitude,
        from_t,
        to_t,
        |e: &EngineOutput| {
            out.push(format!("{e:?}"));
            out.len() < most
        },
    )?;
    Ok(out)
}

fn spec(id: &str) -> MachineSpec {
    serde_json::from_value::<MachineDeclaration>(serde_json::json!({"engines": {"attitude": {}}}))
        .unwrap()
        .validate(id)
        .unwrap()
}

fn level(t: f64) -> ReadingRow {
    ReadingRow::new(&Reading {
        t,
        data: SensorData::Level { height_m: t / 10.0 },
    })
}

fn estimate(t: f64, pitch_deg: f64) -> EstimateRow {
    EstimateRow::new(&EngineOutput {
        integrity: tunnelnav::fusion::Integrity::OK,
        t,
        values: EstimateValues::Attitude(AttitudeEstimate {
            pitch_deg,
            roll_deg: -pitch_deg,
            pitch_pred_deg: pitch_deg,
            roll_pred_deg: -pitch_deg,
            pred_t: t + 1.0,
            pitch_sigma_deg: Some(0.01),
            roll_sigma_deg: None,
            pitch_pred_sigma_deg: Some(0.02),
            laser_ok: true,
            pitch_correction_deg: 0.001,
            laser_age_s: Some(3.0),
            model_version: 2,
            incl_pitch_deg: pitch_deg,
            incl_roll_deg: 0.0,
        }),
    })
}

fn transition(raised: bool, t: f64) -> AlarmRow {
    AlarmRow::new(&Transition {
        key: AlarmKey {
            kind: AlarmKind::LaserDropout,
            severity: Severity::Warn,
            subject: String::new(),
        },
        raised,
        t,
        message: if raised {
            "no laser".into()
        } else {
            "laser again".into()
        },
    })
}

/// A write, committed; what it stored and the alarms it changed.
async fn commit(
    store: &Store,
    machine_id: i64,
    readings: Vec<ReadingRow>,
    estimates: Vec<EstimateRow>,
    alarms: Vec<AlarmRow>,
    snapshot: Option<&str>,
) -> (WriteOutcome, usize) {
    let (reply, answer) = oneshot::channel();
    let (changed_tx, changed) = oneshot::channel();
    store
        .write(Write {
            machine_id,
            readings,
            estimates,
            alarms,
            snapshot: snapshot.map(str::to_string),
            after_commit: Some(Box::new(move |changes| {
                let _ = changed_tx.send(changes.map_or(0, |c| c.len()));
            })),
            reply: Some(reply),
            lease_epoch: None,
            forwarded: None,
        })
        .await
        .unwrap();
    let outcome = answer.await.unwrap().unwrap();
    (outcome, changed.await.unwrap())
}

/// What the suite saw, to compare the backends by.
async fn conformance(open: impl AsyncFn() -> Store) -> Vec<String> {
    let mut seen = Vec::new();
    let store = open().await;
    let a = store
        .put_machine(spec("tbm-a"), "fresh a".into())
        .await
        .unwrap();
    let b = store
        .put_machine(spec("tbm-b"), "fresh b".into())
        .await
        .unwrap();
    assert_ne!(a, b);
    // Redeclaring keeps the id and replaces the snapshot.
    assert_eq!(
        store
            .put_machine(spec("tbm-a"), "fresh a2".into())
            .await
            .unwrap(),
        a
    );
    let snap = read(&store, move |s| s.snapshot(a)).await.unwrap();
    assert_eq!((snap.last_reading_id, snap.state.as_str()), (0, "fresh a2"));

    // Readings across two days (two partitions on PostgreSQL), a resent
    // one stored once, arrival order kept (not time order).
    let day = 86_400.0;
    let first = vec![
        level(5.0 * day + 10.0),
        level(5.0 * day + 20.0),
        level(6.0 * day + 1.0),
    ];
    let (outcome, _) = commit(
        &store,
        a,
        first,
        vec![estimate(5.0 * day + 10.0, 0.5)],
        vec![],
        None,
    )
    .await;
    seen.push(format!("{outcome:?}"));
    let again = vec![level(5.0 * day + 20.0), level(5.0 * day + 15.0)];
    let (outcome, _) = commit(
        &store,
        a,
        again,
        vec![
            estimate(5.0 * day + 10.0, 0.5),
            estimate(6.0 * day + 1.0, 0.7),
        ],
        vec![],
        Some("after 4"),
    )
    .await;
    seen.push(format!("{outcome:?}"));
    assert_eq!(
        outcome,
        WriteOutcome {
            stored: 1,
            duplicates: 1
        }
    );
    let snap = read(&store, move |s| s.snapshot(a)).await.unwrap();
    assert_eq!(snap.state, "after 4");
    let after_snapshot = snap.last_reading_id;
    commit(
        &store,
        a,
        vec![level(6.0 * day + 2.0)],
        vec![],
        vec![],
        None,
    )
    .await;
    let since = read(&store, move |s| readings_since(s, a, after_snapshot)).await;
    assert_eq!(since.len(), 1, "{since:?}");
    seen.extend(since);
    let all = read(&store, move |s| readings_since(s, a, 0)).await;
    seen.extend(all.clone());
    let times: Vec<f64> = all
        .iter()
        .map(|r| {
            serde_json::from_str::<serde_json::Value>(r).unwrap()["t"]
                .as_f64()
                .unwrap()
        })
        .collect();
    assert_eq!(
        times,
        [
            5.0 * day + 10.0,
            5.0 * day + 20.0,
            6.0 * day + 1.0,
            5.0 * day + 15.0,
            6.0 * day + 2.0
        ]
    );
    // Another machine's readings are its own.
    assert!(
        read(&store, move |s| readings_since(s, b, 0))
            .await
            .is_empty()
    );

    let latest = read(&store, move |s| s.latest_estimate(a, StreamKind::Attitude))
        .await
        .unwrap();
    assert_eq!(latest.t, 6.0 * day + 1.0);
    seen.push(format!("{latest:?}"));
    assert!(
        read(&store, move |s| s.latest_estimate(b, StreamKind::Attitude))
            .await
            .is_none()
    );
    let last = read(&store, move |s| s.last_reading_t(a, SensorKind::Level)).await;
    assert_eq!(last, Some(6.0 * day + 2.0));
    assert_eq!(
        read(&store, move |s| s.last_reading_t(a, SensorKind::Laser)).await,
        None
    );

    // An alarm raised once (a recomputed raise changes nothing), cleared once.
    let (_, changed) = commit(
        &store,
        a,
        vec![],
        vec![],
        vec![transition(true, 100.0)],
        None,
    )
    .await;
    assert_eq!(changed, 1);
    let (_, changed) = commit(
        &store,
        a,
        vec![],
        vec![],
        vec![transition(true, 100.0)],
        None,
    )
    .await;
    assert_eq!(changed, 0);
    let active = AlarmFilter {
        machine: Some("tbm-a".into()),
        active_only: true,
        ..AlarmFilter::default()
    };
    let listed = read(&store, {
        let active = active.clone();
        move |s| s.alarms(&active)
    })
    .await;
    assert_eq!(listed.len(), 1);
    let (_, changed) = commit(
        &store,
        a,
        vec![],
        vec![],
        vec![transition(false, 160.0)],
        None,
    )
    .await;
    assert_eq!(changed, 1);
    assert!(read(&store, move |s| s.alarms(&active)).await.is_empty());
    let every = read(&store, |s| s.alarms(&AlarmFilter::default())).await;
    assert_eq!(every.len(), 1);
    assert_eq!(
        (every[0].raised_t, every[0].cleared_t),
        (100.0, Some(160.0))
    );
    // Only those active in a range (raised by its end, not cleared before
    // its start), at most `limit`.
    for (during, expected) in [
        ((90.0, 99.0), 0),
        ((90.0, 100.0), 1),
        ((160.0, 200.0), 1),
        ((160.5, 200.0), 0),
    ] {
        let filter = AlarmFilter {
            during: Some(during),
            ..AlarmFilter::default()
        };
        let found = read(&store, move |s| s.alarms(&filter)).await;
        assert_eq!(found.len(), expected, "{during:?}");
    }
    let none = AlarmFilter {
        limit: Some(0),
        ..AlarmFilter::default()
    };
    assert!(read(&store, move |s| s.alarms(&none)).await.is_empty());
    seen.push(format!(
        "{:?}",
        every
            .iter()
            .map(|a| (&a.machine, &a.kind, &a.message))
            .collect::<Vec<_>>()
    ));

    // History: a day of estimates on machine b, every 10 s, with a spike;
    // in full, then downsampled from the stored buckets.
    let spike_t = 2.0 * day + 40_000.0;
    let many: Vec<EstimateRow> = (0..8640)
        .map(|i| {
            let t = 2.0 * day + f64::from(i) * 10.0;
            estimate(
                t,
                if t == spike_t {
                    9.0
                } else {
                    (t / 3000.0).sin()
                },
            )
        })
        .collect();
    let readings: Vec<ReadingRow> = (0..8640)
        .flat_map(|i| {
            let t = 2.0 * day + f64::from(i) * 10.0;
            [
                level(t),
                ReadingRow::new(&Reading {
                    t,
                    data: SensorData::Odometer { distance_m: t },
                }),
            ]
        })
        .collect();
    commit(&store, b, readings, many, vec![], None).await;
    let (downsampled, full) = read(&store, move |s| {
        estimates_page(s, b, 2.0 * day, 2.0 * day + 3600.0, 1000)
    })
    .await;
    assert!(!downsampled);
    assert_eq!(full.len(), 361);
    let (downsampled, thin) =
        read(&store, move |s| estimates_page(s, b, 0.0, 10.0 * day, 200)).await;
    assert!(downsampled && thin.len() <= 200, "{}", thin.len());
    assert!(thin.iter().any(|e| e.contains("pitch_deg: 9.0")));
    seen.push(format!("{full:?}"));
    seen.push(format!("{thin:?}"));
    // Exports: one sensor or all, in time order, stopping when told.
    let odometer = read(&store, move |s| {
        export_readings(
            s,
            b,
            Some(SensorKind::Odometer),
            2.0 * day,
            3.0 * day,
            usize::MAX,
        )
    })
    .await;
    assert_eq!(odometer.len(), 8640);
    let first = read(&store, move |s| {
        export_readings(s, b, None, 2.0 * day + 50.0, 3.0 * day, 7)
    })
    .await;
    assert_eq!(first.len(), 7);
    seen.extend(first);
    seen.push(format!("{:?}", odometer.last()));
    let estimates = read(&store, move |s| {
        export_estimates(s, b, 2.0 * day, 3.0 * day, 6000)
    })
    .await;
    assert_eq!(estimates.len(), 6000);
    seen.push(format!("{:?}", estimates.last()));

    // Acknowledged once, by its first acknowledger; an unknown id is None.
    let id = every[0].id;
    let (acked, first_time) = store
        .ack_alarm(id, "shift-a".into(), 170.0, |_| {})
        .await
        .unwrap()
        .unwrap();
    assert!(first_time && acked.acked_by.as_deref() == Some("shift-a"));
    let (acked, first_time) = store
        .ack_alarm(id, "shift-b".into(), 180.0, |_| {})
        .await
        .unwrap()
        .unwrap();
    assert!(!first_time && acked.acked_t == Some(170.0));
    assert!(
        store
            .ack_alarm(id + 1000, "x".into(), 1.0, |_| {})
            .await
            .unwrap()
            .is_none()
    );
    assert!(store.size_bytes().await.unwrap() > 0);

    // A restart sees the same.
    store.close().await;
    assert!(matches!(
        store
            .write(Write {
                machine_id: a,
                readings: vec![level(1.0)],
                estimates: vec![],
                alarms: vec![],
                snapshot: None,
                after_commit: None,
                reply: None,
                lease_epoch: None,
                forwarded: None,
            })
            .await,
        Err(StoreError::Closed)
    ));
    drop(store);
    let store = open().await;
    let machines = read(&store, |s| s.machines()).await;
    assert_eq!(
        machines
            .iter()
            .map(|m| (m.db_id, m.spec.id.as_str()))
            .collect::<Vec<_>>(),
        [(a, "tbm-a"), (b, "tbm-b")]
    );
    assert_eq!(machines[0].spec, spec("tbm-a"));
    let again = read(&store, move |s| readings_since(s, a, 0)).await;
    assert_eq!(again, all);
    seen
}

/// A retention pass: readings of days 1-4 of which the snapshot covers
/// days 1-3, estimates at 1 Hz over day 1; keep readings 2.5 days, full
/// estimates 3 days, at the start of day 5. What remains, and what the
/// pass said it deleted.
async fn retention(store: Store) -> Vec<String> {
    use tunnelnav::store::retention::{Pruned, Retention};
    let day = 86_400.0;
    let id = store
        .put_machine(spec("tbm-r"), "fresh".into())
        .await
        .unwrap();
    let covered: Vec<ReadingRow> = (0..3 * 24)
        .map(|h| level(day + f64::from(h) * 3600.0))
        .collect();
    let estimates: Vec<EstimateRow> = (0..86_400)
        .step_by(7)
        .map(|s| estimate(day + f64::from(s), f64::from(s % 100) / 100.0))
        .collect();
    commit(
        &store,
        id,
        covered,
        estimates,
        vec![],
        Some("covers days 1-3"),
    )
    .await;
    let uncovered: Vec<ReadingRow> = (0..24)
        .map(|h| level(4.0 * day + f64::from(h) * 3600.0))
        .collect();
    commit(&store, id, uncovered, vec![], vec![], None).await;

    let policy = Retention {
        keep_readings_s: Some(2.5 * day),
        full_estimates_s: Some(3.0 * day),
        every_s: 3600.0,
    };
    let now = 5.0 * day;
    let steps = read(&store, move |s| s.retention_plan(now, &policy, 10)).await;
    let mut pruned = Pruned::default();
    for step in steps {
        loop {
            let done = store.retention_step(step).await.unwrap();
            pruned.add(done);
            if !step.again(&done) {
                break;
            }
        }
    }
    // The readings before t = 2.5 days, all covered by the snapshot: day 1
    // and the first half of day 2 (PostgreSQL drops day 1's partition).
    assert_eq!(pruned.readings, 36);
    let left = read(&store, move |s| readings_since(s, id, 0)).await;
    assert_eq!(left.len(), 3 * 24 + 24 - 36);
    let left = left.clone();
    // A pruned reading resent is stored again (PostgreSQL: its day's
    // partition made anew), as a late one.
    let (outcome, _) = commit(&store, id, vec![level(day)], vec![], vec![], None).await;
    assert_eq!(outcome.stored, 1);
    // Thinned to one a minute: 1440 of day 1's 12,343.
    let estimates = read(&store, move |s| {
        export_estimates(s, id, 0.0, 10.0 * day, usize::MAX)
    })
    .await;
    assert_eq!(estimates.len(), 1440);
    vec![
        format!("{pruned:?}"),
        format!("{left:?}"),
        format!("{estimates:?}"),
    ]
}

/// Large writes of two machines queued together (one group commit; on
/// PostgreSQL one `COPY` each for readings and estimates), then resent
/// with new rows among them: each row stored once, in the order given.
async fn large_batches(store: Store) -> Vec<String> {
    let mut seen = Vec::new();
    let x = store.put_machine(spec("tbm-x"), "x".into()).await.unwrap();
    let y = store.put_machine(spec("tbm-y"), "y".into()).await.unwrap();
    // Not in time order: arrival order is what the ids keep.
    let first: Vec<f64> = (0..100).map(|i| f64::from((i * 37) % 100 + 1)).collect();
    let mut resent: Vec<f64> = Vec::new();
    for (i, t) in first.iter().enumerate() {
        resent.push(*t);
        if i % 2 == 0 {
            resent.push(101.0 + (i / 2) as f64);
        }
    }
    for times in [&first, &resent] {
        let mut answers = Vec::new();
        for machine_id in [x, y] {
            let (reply, answer) = oneshot::channel();
            store
                .write(Write {
                    machine_id,
                    readings: times.iter().map(|&t| level(t)).collect(),
                    estimates: times.iter().map(|&t| estimate(t, t / 100.0)).collect(),
                    alarms: vec![],
                    snapshot: None,
                    after_commit: None,
                    reply: Some(reply),
                    lease_epoch: None,
                    forwarded: None,
                })
                .await
                .unwrap();
            answers.push(answer);
        }
        for answer in answers {
            seen.push(format!("{:?}", answer.await.unwrap().unwrap()));
        }
    }
    assert_eq!(
        seen[2..],
        [
            "WriteOutcome { stored: 50, duplicates: 100 }",
            "WriteOutcome { stored: 50, duplicates: 100 }"
        ]
    );
    for machine_id in [x, y] {
        let stored = read(&store, move |s| readings_since(s, machine_id, 0)).await;
        let expected: Vec<String> = first
            .iter()
            .chain(resent.iter().filter(|&&t| t > 100.0))
            .map(|&t| {
                Reading {
                    t,
                    data: SensorData::Level { height_m: t / 10.0 },
                }
                .to_json()
            })
            .collect();
        assert_eq!(stored, expected);
        let estimates = read(&store, move |s| {
            export_estimates(s, machine_id, 0.0, 1000.0, usize::MAX)
        })
        .await;
        assert_eq!(estimates.len(), 150);
        seen.extend(estimates);
    }
    seen
}

/// Tokens: made (an ingest token names its machine), read in force with
/// the hash of the text shown once, listed oldest first, revoked once
/// (the first time stands), an unknown id refused.
async fn tokens(store: Store) -> Vec<String> {
    use tunnelnav::auth::{Scope, TokenError, hash};
    assert!(matches!(
        store
            .create_token("gateway", Scope::Ingest, None, 1.0)
            .await,
        Err(StoreError::Token(TokenError::MachineMissing))
    ));
    let (reader, reader_text) = store
        .create_token("reader", Scope::Read, None, 1.0)
        .await
        .unwrap();
    let (gateway, _) = store
        .create_token("gateway", Scope::Ingest, Some("tbm-a"), 2.0)
        .await
        .unwrap();
    assert_ne!(reader, gateway);
    let active = store.active_tokens().await.unwrap();
    assert_eq!(active.len(), 2);
    assert!(
        active
            .iter()
            .any(|(h, t)| *h == hash(&reader_text) && t.id == reader)
    );
    let revoked = store.revoke_token(reader, 5.0).await.unwrap();
    assert_eq!(revoked.revoked_t, Some(5.0));
    let again = store.revoke_token(reader, 6.0).await.unwrap();
    assert_eq!(again.revoked_t, Some(5.0));
    assert!(matches!(
        store.revoke_token(gateway + 100, 7.0).await,
        Err(StoreError::Token(TokenError::NoSuchToken(_)))
    ));
    let active = store.active_tokens().await.unwrap();
    assert_eq!(
        active.iter().map(|(_, t)| t.id).collect::<Vec<_>>(),
        [gateway]
    );
    store
        .tokens()
        .await
        .unwrap()
        .iter()
        .map(|t| {
            format!(
                "{} {} {:?} {} {:?}",
                t.name,
                t.scope.as_str(),
                t.machine,
                t.created_t,
                t.revoked_t
            )
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_store_keeps_tokens_alike() {
    let dir = tempfile::tempdir().unwrap();
    let sqlite = tokens(Store::open(dir.path()).unwrap()).await;
    let memory = tokens(Store::new(MemoryStore::new(Default::default()))).await;
    assert_eq!(memory, sqlite);
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let location = PgLocation {
        url: cluster.database("tokens"),
        password_file: None,
        ca_file: None,
    };
    let postgres = tokens(
        Store::open_postgres(&location, Default::default())
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(postgres, sqlite);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn both_stores_take_large_batches_alike() {
    let dir = tempfile::tempdir().unwrap();
    let sqlite = large_batches(Store::open(dir.path()).unwrap()).await;
    let memory = large_batches(Store::new(MemoryStore::new(Default::default()))).await;
    assert_eq!(memory, sqlite);
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let location = PgLocation {
        url: cluster.database("large"),
        password_file: None,
        ca_file: None,
    };
    let postgres = large_batches(
        Store::open_postgres(&location, Default::default())
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(postgres, sqlite);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn both_stores_keep_alike() {
    let dir = tempfile::tempdir().unwrap();
    let sqlite = retention(Store::open(dir.path()).unwrap()).await;
    let memory = retention(Store::new(MemoryStore::new(Default::default()))).await;
    assert_eq!(memory, sqlite);
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let location = PgLocation {
        url: cluster.database("retention"),
        password_file: None,
        ca_file: None,
    };
    let postgres = retention(
        Store::open_postgres(&location, Default::default())
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(postgres, sqlite);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn both_stores_answer_alike() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().to_path_buf();
    let sqlite = conformance(async || Store::open(&path).unwrap()).await;
    let rows = MemoryStore::new(Default::default());
    let memory = conformance(async || Store::new(rows.reopen())).await;
    assert_eq!(memory, sqlite);

    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let location = PgLocation {
        url: cluster.database("conformance"),
        password_file: None,
        ca_file: None,
    };
    let postgres = conformance(async || {
        Store::open_postgres(&location, Default::default())
            .await
            .unwrap()
    })
    .await;
    assert_eq!(postgres, sqlite);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn postgres_refuses_a_newer_schema_and_reports_a_refused_connection_as_transient() {
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let location = PgLocation {
        url: cluster.database("newer"),
        password_file: None,
        ca_file: None,
    };
    let store = PgStore::open(&location).await.unwrap();
    store.close().await;
    // A later release migrated this database further.
    let (client, connection) = tokio_postgres::connect(&location.url, tokio_postgres::NoTls)
        .await
        .unwrap();
    tokio::spawn(connection);
    client
        .execute("UPDATE tunnelnav_schema SET version = version + 1", &[])
        .await
        .unwrap();
    let err = PgStore::open(&location).await.err().unwrap();
    assert!(matches!(err, StoreError::NewerSchema { .. }), "{err}");

    // The database goes away under a running store and comes back: writes
    // in between fail as transient (503), later ones go in.
    let store = Store::open_postgres(&location, Default::default()).await;
    assert!(matches!(store, Err(StoreError::NewerSchema { .. })));
    client
        .execute("UPDATE tunnelnav_schema SET version = version - 1", &[])
        .await
        .unwrap();
    drop(client);
    let store = Store::open_postgres(&location, Default::default())
        .await
        .unwrap();
    let id = store
        .put_machine(spec("tbm-gone"), "fresh".into())
        .await
        .unwrap();
    cluster.stop();
    let write = |t: f64| {
        let store = store.clone();
        async move {
            let (reply, answer) = oneshot::channel();
            store
                .write(Write {
                    machine_id: id,
                    readings: vec![level(t)],
                    estimates: vec![],
                    alarms: vec![],
                    snapshot: None,
                    after_commit: None,
                    reply: Some(reply),
                    lease_epoch: None,
                    forwarded: None,
                })
                .await
                .unwrap();
            answer.await.unwrap()
        }
    };
    let err = write(1.0).await.unwrap_err();
    assert!(err.is_transient(), "{err}");
    cluster.start_again();
    assert_eq!(write(2.0).await.unwrap().stored, 1);
    assert_eq!(
        read(&store, move |s| readings_since(s, id, 0)).await.len(),
        1
    );

    // Nothing listens on the cluster's port once it is stopped.
    let port = cluster.port;
    drop(cluster);
    let gone = PgLocation {
        url: format!("postgres://postgres@127.0.0.1:{port}/newer"),
        password_file: None,
        ca_file: None,
    };
    let err = PgStore::open(&gone).await.err().unwrap();
    assert!(err.is_transient(), "{err}");

    // A password file is read; a missing one is named.
    let missing = PgLocation {
        url: location.url.clone(),
        password_file: Some("/nonexistent/tunnelnav-password".into()),
        ca_file: None,
    };
    let err = PgStore::open(&missing).await.err().unwrap();
    assert!(
        err.to_string().contains("/nonexistent/tunnelnav-password"),
        "{err}"
    );
}

/// TLS to PostgreSQL: with `sslmode=require` the server's certificate is
/// checked against the CA file named (`--store-ca-file`, `[store]
/// ca_file`): the office's own CA is accepted, and without it (the
/// system's roots) the connection is refused, naming the certificate. A
/// URL without `sslmode` connects plainly as before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn postgres_over_tls_checks_the_servers_certificate() {
    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, IsCa, KeyPair};
    let Some(mut cluster) = PgCluster::start() else {
        return;
    };
    let mut ca = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = CertifiedIssuer::self_signed(ca, KeyPair::generate().unwrap()).unwrap();
    let key = KeyPair::generate().unwrap();
    let certificate = CertificateParams::new(vec!["127.0.0.1".to_string()])
        .unwrap()
        .signed_by(&key, &ca)
        .unwrap();
    cluster.enable_tls(&certificate.pem(), &key.serialize_pem());
    let plain = cluster.database("tls");
    let dir = tempfile::tempdir().unwrap();
    let ca_file = dir.path().join("office-ca.pem");
    std::fs::write(&ca_file, ca.pem()).unwrap();

    let location = |url: &str, ca_file: Option<std::path::PathBuf>| PgLocation {
        url: url.to_string(),
        password_file: None,
        ca_file,
    };
    let tls = format!("{plain}?sslmode=require");
    let store = Store::open_postgres(&location(&tls, Some(ca_file.clone())), Default::default())
        .await
        .unwrap();
    let id = store
        .put_machine(spec("tbm-tls"), "s".into())
        .await
        .unwrap();
    let (outcome, _) = commit(&store, id, vec![level(1.0)], vec![], vec![], None).await;
    assert_eq!(outcome.stored, 1);
    store.close().await;

    let refused = Store::open_postgres(&location(&tls, None), Default::default())
        .await
        .err()
        .unwrap();
    assert!(refused.to_string().contains("certificate"), "{refused}");
    // Plain as before when the URL does not ask for TLS.
    let store = Store::open_postgres(&location(&plain, None), Default::default())
        .await
        .unwrap();
    let machines = read(&store, |s| s.machines()).await;
    assert_eq!(machines.len(), 1);
    store.close().await;
}
