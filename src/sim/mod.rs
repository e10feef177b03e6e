//! Seeded, pure scenario generators with known truth. The same seed gives
//! the same readings on every machine.

pub mod axis_drive;
pub mod faults;
mod noise;
pub mod pipejack;
pub mod pipejack_envelope;
pub mod ring_build;
pub mod tbm;
pub mod tbm_envelope;
pub mod vehicle;
pub mod vehicle_envelope;
