//! Ring build (issue 60): which universal tapered ring's key position to
//! build next, and where the built rings are.
//!
//! - `spec.rs`: the declared rings (`"rings"`), what a key position does;
//! - `chain.rs`: the ring chain, each ring's centre and direction from the
//!   one before, its taper and key;
//! - `clearance.rs`: the tail clearance, measured round the ring, fitted
//!   to where the ring sits in the tail;
//! - `plan.rs`: the look-ahead that picks the key positions, its declared
//!   cost, and the naive rule it is measured against;
//! - `builder.rs`: the built lining tracked ring by ring, corrected by
//!   measured clearances, and the plan from it.

pub mod builder;
pub mod chain;
pub mod clearance;
pub mod plan;
pub mod spec;

pub use builder::{BuiltRing, MachineAt, RingBuilder};
pub use chain::{Face, Ring};
pub use clearance::ClearanceFit;
pub use plan::{Course, Plan, PlannedRing, Situation};
pub use spec::RingSpec;

#[cfg(test)]
mod tests;
