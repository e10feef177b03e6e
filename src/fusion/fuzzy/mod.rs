//! The `fuzzy` engine (Wang 2005): MEMS IMU and magnetometer fused by a
//! Mamdani expert system's decision of the motion status. So far: the
//! general Mamdani inference module the engine is built on ([`mamdani`]).

pub mod mamdani;
