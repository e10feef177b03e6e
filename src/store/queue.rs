//! The queue every backend's writer takes its requests from, and what
//! they share of a group commit: gathering a group, answering each
//! request after the commit, folding estimates into extreme buckets.

use std::collections::BTreeMap;

use tokio::sync::{mpsc, oneshot};

use super::alarms::AlarmChange;
use super::error::StoreError;
use super::history::{BUCKET_WIDTHS_S, Extremes};
use super::rows::{Write, WriteOutcome};
use crate::config::MachineSpec;
use crate::fusion::StreamKind;

/// Most requests committed in one transaction.
pub(crate) const MAX_GROUP: usize = 512;
/// Requests waiting for the writer before senders wait (backpressure).
pub(crate) const QUEUE_LEN: usize = 1024;

/// What a writer's queue carries; `J`, the backend's maintenance job.
pub(crate) enum Queued<J> {
    Request(Request),
    /// Commit what is queued and stop writing (SQLite: checkpoint the
    /// log into the database first).
    Close(oneshot::Sender<()>),
    /// Work on the writing connection outside any group (retention): run
    /// after the group gathered before it is committed.
    Job(J),
}

/// A request the writer commits in a group.
pub(crate) enum Request {
    Write(Write),
    PutMachine {
        spec: Box<MachineSpec>,
        /// The fresh state of the (re)declared machine's engines.
        snapshot: String,
        /// An office: the site's sequence of this declaration.
        forwarded: Option<i64>,
        reply: oneshot::Sender<Result<i64, StoreError>>,
    },
}

/// Puts `first` and the requests waiting behind it (up to [`MAX_GROUP`]
/// in `group`) into `group`; a job or a close ends the gathering and is
/// returned, to run after the group's commit.
pub(crate) fn gather<J>(
    first: Queued<J>,
    queue: &mut mpsc::Receiver<Queued<J>>,
    group: &mut Vec<Request>,
) -> (Option<J>, Option<oneshot::Sender<()>>) {
    let (mut job, mut close) = (None, None);
    let mut next = Some(first);
    while let Some(request) = next.take() {
        match request {
            Queued::Close(reply) => close = Some(reply),
            Queued::Job(queued) => job = Some(queued),
            Queued::Request(request) => {
                group.push(request);
                if group.len() < MAX_GROUP {
                    next = queue.try_recv().ok();
                }
            }
        }
    }
    (job, close)
}

/// What a committed request did.
pub(crate) enum Outcome {
    /// What a write stored and the alarms it changed.
    Write(WriteOutcome, Vec<AlarmChange>),
    Put(i64),
}

/// Answers `request` with `result`: a write's `after_commit`, then its
/// reply; a declaration's reply.
pub(crate) fn answer(request: Request, result: Result<Outcome, StoreError>) {
    match request {
        Request::Write(write) => {
            let result = result.map(|o| match o {
                Outcome::Write(w, alarms) => (w, alarms),
                Outcome::Put(_) => (WriteOutcome::default(), Vec::new()),
            });
            let (outcome, alarms) = match result {
                Ok((w, alarms)) => (Ok(w), Some(alarms)),
                Err(e) => (Err(e), None),
            };
            if let Some(after_commit) = write.after_commit {
                after_commit(alarms);
            }
            if let Some(reply) = write.reply {
                let _ = reply.send(outcome);
            }
        }
        Request::PutMachine { reply, .. } => {
            let _ = reply.send(result.map(|o| match o {
                Outcome::Put(id) => id,
                Outcome::Write(..) => 0,
            }));
        }
    }
}

/// Extremes per (machine, engine, bucket width, bucket).
pub(crate) type Buckets = BTreeMap<(i64, StreamKind, i64, i64), Extremes>;

/// Folds the extremes of `write`'s estimates into `buckets`. A recomputed
/// estimate is the stored one again (same time, same values), so folding
/// it in changes nothing.
pub(crate) fn fold_buckets(write: &Write, buckets: &mut Buckets) {
    for estimate in &write.estimates {
        let point = Extremes::point(estimate.t, estimate.extremes);
        for width_s in BUCKET_WIDTHS_S {
            let bucket = (estimate.t / width_s as f64).floor() as i64;
            buckets
                .entry((write.machine_id, estimate.engine, width_s, bucket))
                .and_modify(|b| b.merge(&point))
                .or_insert(point);
        }
    }
}
