//! The lease epoch that fences a machine's writes (several nodes).

use std::sync::Arc;
use std::sync::atomic::Ordering;

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
