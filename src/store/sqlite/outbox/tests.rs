use super::*;
use crate::config::MachineDeclaration;
use crate::store::alarms::AlarmRow;
use crate::store::handle::Store;
use crate::store::rows::ReadingRow;
use crate::store::rows::Write;
use crate::store::rows::WriteOutcome;
use tokio::sync::oneshot;

fn spec(id: &str) -> crate::config::MachineSpec {
    serde_json::from_value::<MachineDeclaration>(serde_json::json!({"engines": {"attitude": {}}}))
        .unwrap()
        .validate(id)
        .unwrap()
}

fn readings(from_t: f64, count: usize) -> Vec<ReadingRow> {
    (0..count)
        .map(|i| {
            ReadingRow::new(&Reading {
                t: from_t + i as f64,
                data: crate::fusion::SensorData::Level { height_m: 1.0 },
            })
        })
        .collect()
}

async fn write(
    store: &Store,
    machine_id: i64,
    readings: Vec<ReadingRow>,
    alarms: Vec<AlarmRow>,
    forwarded: Option<Forwarded>,
) -> Result<WriteOutcome, StoreError> {
    let (reply, answer) = oneshot::channel();
    store
        .write(Write {
            machine_id,
            readings,
            estimates: Vec::new(),
            alarms,
            snapshot: None,
            after_commit: None,
            reply: Some(reply),
            lease_epoch: None,
            forwarded: forwarded.map(Box::new),
        })
        .await
        .unwrap();
    answer.await.unwrap()
}

fn stale(raised: bool, t: f64) -> AlarmRow {
    AlarmRow {
        kind: "stale_sensor",
        severity: "alarm",
        subject: "level".into(),
        raised,
        t,
        message: "silent".into(),
    }
}

#[tokio::test]
async fn a_site_owes_its_office_only_what_it_stored_after_telling_it() {
    let dir = tempfile::tempdir().unwrap();
    let forward = OutboxConfig {
        forward: true,
        ..Default::default()
    };
    let store = Store::open_with(dir.path(), None, forward).unwrap();
    let site = store.sqlite().unwrap().clone();
    // Declared: the declaration is owed, then a batch of 25 000
    // readings goes in three rows (10 000, 10 000, 5 000).
    let id = store
        .put_machine(spec("m1"), "state-0".into())
        .await
        .unwrap();
    write(&store, id, readings(0.0, 25_000), Vec::new(), None)
        .await
        .unwrap();
    let entries = site.office_entries(id, u64::MAX).unwrap();
    let kinds: Vec<(String, usize)> = entries
        .iter()
        .map(|e| match &e.item {
            OfficeItem::Machine(d) => (format!("machine {}", d.snapshot), 0),
            OfficeItem::Readings(r) => ("readings".into(), r.len()),
            OfficeItem::Alarm(_) => ("alarm".into(), 0),
        })
        .collect();
    assert_eq!(
        kinds,
        [
            ("machine state-0".to_string(), 0),
            ("readings".into(), 10_000),
            ("readings".into(), 10_000),
            ("readings".into(), 5_000)
        ]
    );
    assert!(entries.windows(2).all(|w| w[0].sequence < w[1].sequence));
    let backlog = site.office_backlog().unwrap();
    assert_eq!((backlog.items, backlog.readings), (4, 25_000));
    // At most 12 000 readings a request: the declaration and one row
    // (a second would pass it).
    assert_eq!(site.office_entries(id, 12_000).unwrap().len(), 2);
    // Sent up to the first readings row: the rest stays, and the
    // acknowledged sequence is remembered.
    site.office_sent(id, entries[1].sequence).await.unwrap();
    assert_eq!(site.office_entries(id, u64::MAX).unwrap().len(), 2);
    assert_eq!(
        site.office_pending().unwrap(),
        [(id, "m1".to_string(), Some(entries[1].sequence))]
    );

    // Not forwarding any more: what was owed is dropped, and the
    // machine is untold; alarm changes are then not recorded for the
    // office...
    assert_eq!(site.forward_off().await.unwrap(), 2);
    drop(site);
    store.close().await;
    drop(store);
    let store = Store::open_with(dir.path(), None, forward).unwrap();
    let site = store.sqlite().unwrap().clone();
    write(&store, id, Vec::new(), vec![stale(true, 5.0)], None)
        .await
        .unwrap();
    assert!(site.office_pending().unwrap().is_empty());
    // ... until forwarding starts again: the machine is declared
    // afresh with its state, above every earlier sequence (the wall
    // clock in microseconds), and later changes follow it.
    site.forward_to("http://office:8080".into(), "north".into())
        .await
        .unwrap();
    write(&store, id, Vec::new(), vec![stale(false, 9.0)], None)
        .await
        .unwrap();
    let entries = site.office_entries(id, u64::MAX).unwrap();
    assert!(matches!(&entries[0].item, OfficeItem::Machine(d) if d.snapshot == "state-0"));
    assert!(matches!(&entries[1].item, OfficeItem::Alarm(c) if c.transition == Change::Cleared));
    assert_eq!(entries.len(), 2);
    assert!(entries[0].sequence as f64 >= (wall_clock_s() - 60.0) * 1e6);
    store.close().await;
}

#[tokio::test]
async fn an_office_commits_a_forwarded_write_only_after_the_mark_it_follows() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).unwrap();
    let id = store
        .put_forwarded_machine(spec("m1"), "state".into(), 10)
        .await
        .unwrap();
    assert_eq!(store.forward_mark(id).unwrap(), Some(10));
    let forwarded = |after, sequence| {
        Some(Forwarded {
            after,
            applied: vec![sequence],
            sequence,
            confirmed: None,
            acks: Vec::new(),
        })
    };
    // Following 10: committed, the mark at 12.
    let stored = write(
        &store,
        id,
        readings(0.0, 3),
        Vec::new(),
        forwarded(Some(10), 12),
    )
    .await
    .unwrap();
    assert_eq!(stored.stored, 3);
    assert_eq!(store.forward_mark(id).unwrap(), Some(12));
    // A write that follows 11 (one before it failed): refused whole.
    let refused = write(
        &store,
        id,
        readings(10.0, 2),
        Vec::new(),
        forwarded(Some(11), 14),
    )
    .await;
    assert!(
        matches!(refused, Err(StoreError::Unavailable(_))),
        "{refused:?}"
    );
    assert_eq!(store.forward_mark(id).unwrap(), Some(12));
    let mut count = 0;
    store
        .readings_since(id, 0, |_| {
            count += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!(count, 3);
    store.close().await;
}
