//! tunnelnav: live attitude and position of tunnel boring and pipe-jacking
//! machines, fused from their sensors.
//!
//! # Layout
//! - [`fusion`]: the pure core. Protocol readings and estimates, the
//!   [`fusion::Engine`] trait, parameters, the reorder buffer, and one module
//!   per engine (`attitude`: He et al. 2021). No IO, no async, no clocks.
//! - [`sim`]: seeded, pure scenario generators with known truth (`simulate`,
//!   `eval`, tests, benchmarks).
//! - [`eval`]: runs engines and baselines over simulated drives, and over
//!   recorded trials with optical truth (BROAD), and scores them against
//!   the truth.
//! - [`replay`]: streams an NDJSON file of readings through an engine.
//! - [`config`]: machine declarations (`PUT` bodies, the TOML config file).
//! - [`store`]: the SQLite store; one writer thread with group commit,
//!   pooled readers.
//! - [`machine`]: one task per machine owning its engines; the only bridge
//!   from async code to the fusion core.
//! - [`server`]: axum routes, shared state, errors, live stream, metrics.
//! - [`cli`]: one file per subcommand; `main.rs` only parses and dispatches.

pub mod auth;
pub mod cli;
pub mod config;
pub mod eval;
pub mod fusion;
pub mod machine;
pub mod replay;
pub mod server;
pub mod sim;
pub mod store;
