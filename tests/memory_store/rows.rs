//! The rows a [`super::MemoryStore`] keeps, and a write applied to them
//! all or nothing.

use std::cmp::Ordering;
use std::collections::{BTreeMap, BTreeSet};

use tunnelnav::auth::Token;
use tunnelnav::config::MachineSpec;
use tunnelnav::fusion::{EngineOutput, Reading, SensorKind, StreamKind};
use tunnelnav::store::alarms::{AlarmChange, AlarmFilter, AlarmRow, Change, StoredAlarm};
use tunnelnav::store::codec::{decode_output, decode_reading};
use tunnelnav::store::history::BUCKET_WIDTHS_S;
use tunnelnav::store::outbox::{OutboxConfig, WebhookEntry};
use tunnelnav::store::{
    Extremes, StoreError, StoredMachine, StoredSnapshot, Write, WriteOutcome, stored_machine,
};

/// A time as a key: ordered by `f64::total_cmp`, −0 taken as 0 (as
/// SQLite's unique index takes them).
#[derive(Debug, Clone, Copy)]
pub struct Time(pub f64);

impl Time {
    pub fn of(t: f64) -> Time {
        Time(if t == 0.0 { 0.0 } else { t })
    }
}

impl PartialEq for Time {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Time {}
impl PartialOrd for Time {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Time {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0)
    }
}

pub struct Machine {
    pub id: i64,
    pub spec_json: String,
    pub snapshot: StoredSnapshot,
}

pub struct StoredReading {
    pub machine_id: i64,
    pub t: f64,
    pub sensor: SensorKind,
    pub data: Vec<u8>,
}

pub struct StoredEstimate {
    pub extremes: [f64; 2],
    pub values: Vec<u8>,
    pub codec: u32,
}

/// A stream's estimates: by (machine, engine), then by time.
pub type Estimates = BTreeMap<(i64, &'static str), BTreeMap<Time, StoredEstimate>>;

pub struct Rows {
    outbox: OutboxConfig,
    /// By protocol id.
    pub machines: BTreeMap<String, Machine>,
    /// By id, which is the arrival order; never reused.
    pub readings: BTreeMap<i64, StoredReading>,
    /// (machine, sensor, time) of every reading: each stored once.
    reading_keys: BTreeSet<(i64, SensorKind, Time)>,
    last_reading_id: i64,
    pub estimates: Estimates,
    /// The extremes per (machine, engine, width, bucket), kept when
    /// retention thins the estimates.
    pub buckets: BTreeMap<(i64, &'static str, i64, i64), Extremes>,
    /// Alarm rows by id (the index into this list, plus one), with their
    /// machine's id.
    alarms: Vec<(i64, StoredAlarm)>,
    /// (hash, token), by id.
    pub tokens: Vec<(String, Token)>,
    pub webhooks: Vec<WebhookEntry>,
    last_webhook_id: i64,
}

impl Rows {
    pub fn new(outbox: OutboxConfig) -> Rows {
        Rows {
            outbox,
            machines: BTreeMap::new(),
            readings: BTreeMap::new(),
            reading_keys: BTreeSet::new(),
            last_reading_id: 0,
            estimates: BTreeMap::new(),
            buckets: BTreeMap::new(),
            alarms: Vec::new(),
            tokens: Vec::new(),
            webhooks: Vec::new(),
            last_webhook_id: 0,
        }
    }

    /// The newest reading id of a machine (0 if none).
    fn newest_reading_id(&self, machine_id: i64) -> i64 {
        self.readings
            .iter()
            .rev()
            .find(|(_, r)| r.machine_id == machine_id)
            .map_or(0, |(&id, _)| id)
    }

    fn machine_by_id(&mut self, machine_id: i64) -> Option<&mut Machine> {
        self.machines.values_mut().find(|m| m.id == machine_id)
    }

    pub fn put_machine(&mut self, spec: &MachineSpec, snapshot: String) -> Result<i64, StoreError> {
        let spec_json =
            serde_json::to_string(spec).map_err(|e| StoreError::Corrupt(e.to_string()))?;
        let next_id = self.machines.values().map(|m| m.id).max().unwrap_or(0) + 1;
        let id = self.machines.get(&spec.id).map_or(next_id, |m| m.id);
        let snapshot = StoredSnapshot {
            last_reading_id: self.newest_reading_id(id),
            state: snapshot,
        };
        self.machines.insert(
            spec.id.clone(),
            Machine {
                id,
                spec_json,
                snapshot,
            },
        );
        Ok(id)
    }

    pub fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.machines
            .values()
            .map(|m| stored_machine(m.id, m.spec_json.clone()))
            .collect()
    }

    pub fn snapshot(&self, machine_id: i64) -> Option<StoredSnapshot> {
        self.machines
            .values()
            .find(|m| m.id == machine_id)
            .map(|m| m.snapshot.clone())
    }

    /// Applies `write`: checked first, then changed, so a refused write
    /// changes nothing.
    pub fn write(&mut self, write: &Write) -> Result<(WriteOutcome, Vec<AlarmChange>), StoreError> {
        if write.lease_epoch.is_some() {
            return Err(StoreError::Unsupported {
                backend: "memory",
                what: "leases (one node only)",
            });
        }
        if write.forwarded.is_some() {
            return Err(StoreError::Unsupported {
                backend: "memory",
                what: "an office's forwarded machines",
            });
        }
        let machine_id = write.machine_id;
        if !self.machines.values().any(|m| m.id == machine_id) {
            return Err(StoreError::Corrupt(format!("no machine {machine_id}")));
        }
        let mut outcome = WriteOutcome::default();
        for reading in &write.readings {
            let key = (machine_id, reading.sensor, Time::of(reading.t));
            if self.reading_keys.contains(&key) {
                outcome.duplicates += 1;
                continue;
            }
            self.last_reading_id += 1;
            self.reading_keys.insert(key);
            self.readings.insert(
                self.last_reading_id,
                StoredReading {
                    machine_id,
                    t: reading.t,
                    sensor: reading.sensor,
                    data: reading.data.clone(),
                },
            );
            outcome.stored += 1;
        }
        for estimate in &write.estimates {
            let engine = estimate.engine.as_str();
            // One recomputed after a restart is the same estimate: kept once.
            self.estimates
                .entry((machine_id, engine))
                .or_default()
                .entry(Time::of(estimate.t))
                .or_insert_with(|| StoredEstimate {
                    extremes: estimate.extremes,
                    values: estimate.values.clone(),
                    codec: estimate.codec,
                });
            let point = Extremes::point(estimate.t, estimate.extremes);
            for width_s in BUCKET_WIDTHS_S {
                let bucket = (estimate.t / width_s as f64).floor() as i64;
                self.buckets
                    .entry((machine_id, engine, width_s, bucket))
                    .and_modify(|b| b.merge(&point))
                    .or_insert(point);
            }
        }
        let changes = self.apply_alarms(machine_id, &write.alarms);
        for change in &changes {
            self.owe_webhook(change.clone());
        }
        if let Some(state) = &write.snapshot {
            let last_reading_id = self.newest_reading_id(machine_id);
            if let Some(machine) = self.machine_by_id(machine_id) {
                machine.snapshot = StoredSnapshot {
                    last_reading_id,
                    state: state.clone(),
                };
            }
        }
        Ok((outcome, changes))
    }

    /// A raise stored once (machine, kind, severity, subject, time); a
    /// clear closes the open alarms of its key raised by then.
    fn apply_alarms(&mut self, machine_id: i64, rows: &[AlarmRow]) -> Vec<AlarmChange> {
        let machine = self
            .machines
            .iter()
            .find(|(_, m)| m.id == machine_id)
            .map(|(name, _)| name.clone())
            .unwrap_or_default();
        let mut changes = Vec::new();
        for row in rows {
            let same_key = |(m, a): &(i64, StoredAlarm)| {
                *m == machine_id
                    && a.kind == row.kind
                    && a.severity == row.severity
                    && a.subject == row.subject
            };
            if row.raised {
                if self
                    .alarms
                    .iter()
                    .any(|entry| same_key(entry) && entry.1.raised_t == row.t)
                {
                    continue;
                }
                let alarm = StoredAlarm {
                    id: self.alarms.len() as i64 + 1,
                    machine: machine.clone(),
                    kind: row.kind.to_string(),
                    severity: row.severity.to_string(),
                    subject: row.subject.clone(),
                    message: row.message.clone(),
                    raised_t: row.t,
                    cleared_t: None,
                    acked_t: None,
                    acked_by: None,
                    now: None,
                };
                self.alarms.push((machine_id, alarm.clone()));
                changes.push(AlarmChange {
                    transition: Change::Raised,
                    alarm,
                });
            } else {
                for entry in self.alarms.iter_mut() {
                    if same_key(entry) && entry.1.cleared_t.is_none() && entry.1.raised_t <= row.t {
                        entry.1.cleared_t = Some(row.t);
                        changes.push(AlarmChange {
                            transition: Change::Cleared,
                            alarm: entry.1.clone(),
                        });
                    }
                }
            }
        }
        changes
    }

    /// Records `change` for its severity's webhook, if one is configured.
    pub fn owe_webhook(&mut self, change: AlarmChange) {
        let owed = match change.alarm.severity.as_str() {
            "warn" => self.outbox.webhook_warn,
            "alarm" => self.outbox.webhook_alarm,
            _ => false,
        };
        if owed {
            self.last_webhook_id += 1;
            self.webhooks.push(WebhookEntry {
                id: self.last_webhook_id,
                change,
            });
        }
    }

    pub fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
    ) -> Result<Vec<Reading>, StoreError> {
        self.readings
            .range(after_id + 1..)
            .filter(|(_, r)| r.machine_id == machine_id)
            .map(|(_, r)| decode_reading(r.t, r.sensor, &r.data))
            .collect()
    }

    /// In time order, readings of one time in arrival order.
    pub fn readings_between(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
    ) -> Result<Vec<Reading>, StoreError> {
        let mut found: Vec<(Time, i64, &StoredReading)> = self
            .readings
            .iter()
            .filter(|(_, r)| {
                r.machine_id == machine_id
                    && r.t >= from_t
                    && r.t <= to_t
                    && sensor.is_none_or(|s| s == r.sensor)
            })
            .map(|(&id, r)| (Time::of(r.t), id, r))
            .collect();
        found.sort_by_key(|&(t, id, _)| (t, id));
        found
            .into_iter()
            .map(|(_, _, r)| decode_reading(r.t, r.sensor, &r.data))
            .collect()
    }

    pub fn estimates_between(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
    ) -> Result<Vec<EngineOutput>, StoreError> {
        let Some(stream) = self.estimates.get(&(machine_id, engine.as_str())) else {
            return Ok(Vec::new());
        };
        if from_t > to_t {
            return Ok(Vec::new());
        }
        stream
            .range(Time::of(from_t)..=Time::of(to_t))
            .map(|(t, e)| decode_output(engine, t.0, e.codec, &e.values))
            .collect()
    }

    pub fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        self.estimates
            .get(&(machine_id, engine.as_str()))
            .and_then(|stream| stream.last_key_value())
            .map(|(t, e)| decode_output(engine, t.0, e.codec, &e.values))
            .transpose()
    }

    pub fn last_reading_t(&self, machine_id: i64, sensor: SensorKind) -> Option<f64> {
        self.readings
            .values()
            .filter(|r| r.machine_id == machine_id && r.sensor == sensor)
            .map(|r| Time::of(r.t))
            .max()
            .map(|t| t.0)
    }

    /// Newest first: raised later, then the later raise of one time.
    pub fn alarms(&self, filter: &AlarmFilter) -> Vec<StoredAlarm> {
        let mut found: Vec<StoredAlarm> = self
            .alarms
            .iter()
            .map(|(_, alarm)| alarm)
            .filter(|a| filter.machine.as_ref().is_none_or(|m| *m == a.machine))
            .filter(|a| !filter.active_only || a.cleared_t.is_none())
            .filter(|a| {
                filter.during.is_none_or(|(from, to)| {
                    a.raised_t <= to && a.cleared_t.is_none_or(|cleared| cleared >= from)
                })
            })
            .cloned()
            .collect();
        found.sort_by(|a, b| b.raised_t.total_cmp(&a.raised_t).then(b.id.cmp(&a.id)));
        found.truncate(filter.limit.unwrap_or(usize::MAX));
        found
    }

    /// The first acknowledgement stands; the alarm and whether this one
    /// acknowledged it.
    pub fn ack_alarm(&mut self, id: i64, by: &str, t: f64) -> Option<(StoredAlarm, bool)> {
        let index = usize::try_from(id).ok()?.checked_sub(1)?;
        let (_, alarm) = self.alarms.get_mut(index)?;
        let acked = alarm.acked_t.is_none();
        if acked {
            alarm.acked_t = Some(t);
            alarm.acked_by = Some(by.to_string());
        }
        Some((alarm.clone(), acked))
    }

    /// The bytes the rows' contents take.
    pub fn bytes(&self) -> u64 {
        let readings: usize = self.readings.values().map(|r| 24 + r.data.len()).sum();
        let estimates: usize = self
            .estimates
            .values()
            .flat_map(|s| s.values())
            .map(|e| 28 + e.values.len())
            .sum();
        let machines: usize = self
            .machines
            .values()
            .map(|m| m.spec_json.len() + m.snapshot.state.len())
            .sum();
        (readings + estimates + machines + self.alarms.len() * 64) as u64
    }

    /// Deletes reading `id` (retention), freeing its key.
    pub fn delete_reading(&mut self, id: i64) {
        if let Some(r) = self.readings.remove(&id) {
            self.reading_keys
                .remove(&(r.machine_id, r.sensor, Time::of(r.t)));
        }
    }
}
