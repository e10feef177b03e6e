//! One conformance suite, run against both stores (issue 37): SQLite in a
//! temporary data dir, PostgreSQL in a cluster of the test's own
//! (tests/common/postgres.rs; skipped without PostgreSQL unless
//! `TUNNELNAV_POSTGRES_TEST=required`). Each operation the PostgreSQL
//! store has so far is held to the SQLite store's answers: declaring
//! machines, group-committed writes (readings stored once, in arrival
//! order; estimates with their codec; alarms raised and cleared once;
//! snapshots after the last reading), reads after a restart, a newer
//! schema refused, a refused connection reported as transient.

mod common;

use common::postgres::PgCluster;
use tokio::sync::oneshot;
use tunnelnav::config::{MachineDeclaration, MachineSpec};
use tunnelnav::fusion::alarms::{AlarmKey, AlarmKind, Severity, Transition};
use tunnelnav::fusion::{
    AttitudeEstimate, EngineOutput, EstimateValues, Reading, SensorData, SensorKind, StreamKind,
};
use tunnelnav::store::alarms::{AlarmFilter, AlarmRow, StoredAlarm};
use tunnelnav::store::postgres::{PgLocation, PgStore};
use tunnelnav::store::{
    EstimateRow, ReadingRow, Store, StoreError, StoredMachine, StoredSnapshot, Write, WriteOutcome,
};

/// The store operations the suite holds both backends to.
#[derive(Clone)]
enum Backend {
    Sqlite(Store),
    Postgres(PgStore),
}

impl Backend {
    async fn put_machine(&self, spec: MachineSpec, snapshot: &str) -> i64 {
        match self {
            Backend::Sqlite(s) => s.put_machine(spec, snapshot.into()).await,
            Backend::Postgres(p) => p.put_machine(spec, snapshot.into()).await,
        }
        .unwrap()
    }

    async fn write(&self, write: Write) -> Result<(), StoreError> {
        match self {
            Backend::Sqlite(s) => s.write(write).await,
            Backend::Postgres(p) => p.write(write).await,
        }
    }

    async fn close(&self) {
        match self {
            Backend::Sqlite(s) => s.close().await,
            Backend::Postgres(p) => p.close().await,
        }
    }

    /// A blocking read, on a blocking thread.
    async fn read<R: Send + 'static>(
        &self,
        read: impl FnOnce(&Backend) -> Result<R, StoreError> + Send + 'static,
    ) -> R {
        let this = self.clone();
        tokio::task::spawn_blocking(move || read(&this))
            .await
            .unwrap()
            .unwrap()
    }

    fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        match self {
            Backend::Sqlite(s) => s.machines(),
            Backend::Postgres(p) => p.machines(),
        }
    }

    fn snapshot(&self, id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        match self {
            Backend::Sqlite(s) => s.snapshot(id),
            Backend::Postgres(p) => p.snapshot(id),
        }
    }

    fn readings_since(&self, id: i64, after: i64) -> Result<Vec<String>, StoreError> {
        let mut out = Vec::new();
        let push = |r: Reading| {
            out.push(r.to_json());
            Ok(())
        };
        match self {
            Backend::Sqlite(s) => s.readings_since(id, after, push),
            Backend::Postgres(p) => p.readings_since(id, after, push),
        }?;
        Ok(out)
    }

    fn latest_estimate(
        &self,
        id: i64,
        stream: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        match self {
            Backend::Sqlite(s) => s.latest_estimate(id, stream),
            Backend::Postgres(p) => p.latest_estimate(id, stream),
        }
    }

    fn last_reading_t(&self, id: i64, sensor: SensorKind) -> Result<Option<f64>, StoreError> {
        match self {
            Backend::Sqlite(s) => s.last_reading_t(id, sensor),
            Backend::Postgres(p) => p.last_reading_t(id, sensor),
        }
    }

    fn estimates_page(
        &self,
        id: i64,
        stream: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<(bool, Vec<String>), StoreError> {
        let page = match self {
            Backend::Sqlite(s) => s.estimates_page(id, stream, from_t, to_t, max_points),
            Backend::Postgres(p) => p.estimates_page(id, stream, from_t, to_t, max_points),
        }?;
        Ok((
            page.downsampled,
            page.estimates.iter().map(|e| format!("{e:?}")).collect(),
        ))
    }

    /// Readings exported in `[from_t, to_t]`, at most `most`.
    fn export_readings(
        &self,
        id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        most: usize,
    ) -> Result<Vec<String>, StoreError> {
        let mut out = Vec::new();
        let take = |r: &Reading| {
            out.push(r.to_json());
            out.len() < most
        };
        match self {
            Backend::Sqlite(s) => s.export_readings(id, sensor, from_t, to_t, take),
            Backend::Postgres(p) => p.export_readings(id, sensor, from_t, to_t, take),
        }?;
        Ok(out)
    }

    /// Estimates exported in `[from_t, to_t]`, at most `most`.
    fn export_estimates(
        &self,
        id: i64,
        stream: StreamKind,
        from_t: f64,
        to_t: f64,
        most: usize,
    ) -> Result<Vec<String>, StoreError> {
        let mut out = Vec::new();
        let take = |e: &EngineOutput| {
            out.push(format!("{e:?}"));
            out.len() < most
        };
        match self {
            Backend::Sqlite(s) => s.export_estimates(id, stream, from_t, to_t, take),
            Backend::Postgres(p) => p.export_estimates(id, stream, from_t, to_t, take),
        }?;
        Ok(out)
    }

    fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        match self {
            Backend::Sqlite(s) => s.alarms(filter),
            Backend::Postgres(p) => p.alarms(filter),
        }
    }
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
    store: &Backend,
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
        })
        .await
        .unwrap();
    let outcome = answer.await.unwrap().unwrap();
    (outcome, changed.await.unwrap())
}

/// What the suite saw, to compare the backends by.
async fn conformance(open: impl AsyncFn() -> Backend) -> Vec<String> {
    let mut seen = Vec::new();
    let store = open().await;
    let a = store.put_machine(spec("tbm-a"), "fresh a").await;
    let b = store.put_machine(spec("tbm-b"), "fresh b").await;
    assert_ne!(a, b);
    // Redeclaring keeps the id and replaces the snapshot.
    assert_eq!(store.put_machine(spec("tbm-a"), "fresh a2").await, a);
    let snap = store.read(move |s| s.snapshot(a)).await.unwrap();
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
    let snap = store.read(move |s| s.snapshot(a)).await.unwrap();
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
    let since = store
        .read(move |s| s.readings_since(a, after_snapshot))
        .await;
    assert_eq!(since.len(), 1, "{since:?}");
    seen.extend(since);
    let all = store.read(move |s| s.readings_since(a, 0)).await;
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
    assert!(store.read(move |s| s.readings_since(b, 0)).await.is_empty());

    let latest = store
        .read(move |s| s.latest_estimate(a, StreamKind::Attitude))
        .await
        .unwrap();
    assert_eq!(latest.t, 6.0 * day + 1.0);
    seen.push(format!("{latest:?}"));
    assert!(
        store
            .read(move |s| s.latest_estimate(b, StreamKind::Attitude))
            .await
            .is_none()
    );
    let last = store
        .read(move |s| s.last_reading_t(a, SensorKind::Level))
        .await;
    assert_eq!(last, Some(6.0 * day + 2.0));
    assert_eq!(
        store
            .read(move |s| s.last_reading_t(a, SensorKind::Laser))
            .await,
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
    };
    let listed = store
        .read({
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
    assert!(store.read(move |s| s.alarms(&active)).await.is_empty());
    let every = store.read(|s| s.alarms(&AlarmFilter::default())).await;
    assert_eq!(every.len(), 1);
    assert_eq!(
        (every[0].raised_t, every[0].cleared_t),
        (100.0, Some(160.0))
    );
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
    let (downsampled, full) = store
        .read(move |s| {
            s.estimates_page(b, StreamKind::Attitude, 2.0 * day, 2.0 * day + 3600.0, 1000)
        })
        .await;
    assert!(!downsampled);
    assert_eq!(full.len(), 361);
    let (downsampled, thin) = store
        .read(move |s| s.estimates_page(b, StreamKind::Attitude, 0.0, 10.0 * day, 200))
        .await;
    assert!(downsampled && thin.len() <= 200, "{}", thin.len());
    assert!(thin.iter().any(|e| e.contains("pitch_deg: 9.0")));
    seen.push(format!("{full:?}"));
    seen.push(format!("{thin:?}"));
    // Exports: one sensor or all, in time order, stopping when told.
    let odometer = store
        .read(move |s| {
            s.export_readings(
                b,
                Some(SensorKind::Odometer),
                2.0 * day,
                3.0 * day,
                usize::MAX,
            )
        })
        .await;
    assert_eq!(odometer.len(), 8640);
    let first = store
        .read(move |s| s.export_readings(b, None, 2.0 * day + 50.0, 3.0 * day, 7))
        .await;
    assert_eq!(first.len(), 7);
    seen.extend(first);
    seen.push(format!("{:?}", odometer.last()));
    let estimates = store
        .read(move |s| s.export_estimates(b, StreamKind::Attitude, 2.0 * day, 3.0 * day, 6000))
        .await;
    assert_eq!(estimates.len(), 6000);
    seen.push(format!("{:?}", estimates.last()));

    // A restart sees the same.    // A restart sees the same.
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
            })
            .await,
        Err(StoreError::Closed)
    ));
    drop(store);
    let store = open().await;
    let machines = store.read(|s| s.machines()).await;
    assert_eq!(
        machines
            .iter()
            .map(|m| (m.db_id, m.spec.id.as_str()))
            .collect::<Vec<_>>(),
        [(a, "tbm-a"), (b, "tbm-b")]
    );
    assert_eq!(machines[0].spec, spec("tbm-a"));
    let again = store.read(move |s| s.readings_since(a, 0)).await;
    assert_eq!(again, all);
    seen
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn both_stores_answer_alike() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().to_path_buf();
    let sqlite = conformance(async || Backend::Sqlite(Store::open(&path).unwrap())).await;

    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let location = PgLocation {
        url: cluster.database("conformance"),
        password_file: None,
    };
    let postgres =
        conformance(async || Backend::Postgres(PgStore::open(&location).await.unwrap())).await;
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

    // Nothing listens on the cluster's port once it is stopped.
    let port = cluster.port;
    drop(cluster);
    let gone = PgLocation {
        url: format!("postgres://postgres@127.0.0.1:{port}/newer"),
        password_file: None,
    };
    let err = PgStore::open(&gone).await.err().unwrap();
    assert!(err.is_transient(), "{err}");

    // A password file is read; a missing one is named.
    let missing = PgLocation {
        url: location.url.clone(),
        password_file: Some("/nonexistent/tunnelnav-password".into()),
    };
    let err = PgStore::open(&missing).await.err().unwrap();
    assert!(
        err.to_string().contains("/nonexistent/tunnelnav-password"),
        "{err}"
    );
}
