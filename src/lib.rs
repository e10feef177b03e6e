//! tunnelnav: live attitude and position of tunnel boring and pipe-jacking
//! machines, fused from their sensors.
//!
//! # Layout
//! - [`fusion`]: the pure core. Protocol readings and estimates, the
//!   [`fusion::Engine`] and [`fusion::Stage`] traits, what a machine
//!   declares to them ([`fusion::Declaration`]), parameters, the reorder
//!   buffer, and one module per engine (`attitude`: He et al. 2021; `zupt`:
//!   Zhang et al. 2024; `fuzzy`: Wang 2005) and per stage. No IO, no async,
//!   no clocks.
//! - [`sim`]: seeded, pure scenario generators with known truth (`simulate`,
//!   `eval`, tests, benchmarks).
//! - [`eval`]: runs engines and baselines over simulated drives, and over
//!   recorded trials with optical truth (BROAD), and scores them against
//!   the truth.
//! - [`replay`]: streams an NDJSON file of readings through an engine.
//! - [`config`]: machine declarations (`PUT` bodies and the config file's
//!   `[machines]`), validated.
//! - [`clock`]: the service's clock (possibly accelerated, in the demo).
//! - [`auth`]: access tokens, hashed in the store.
//! - [`tls`]: TLS for the service's own outgoing connections (the MQTT
//!   broker, PostgreSQL): rustls, a peer checked against a named CA file
//!   or the system's roots.
//! - [`store`]: one `Store` over the `store::Backend` trait, a folder per
//!   backend with the same topic files: SQLite (`store::sqlite`, the
//!   default: one writer thread with group commit, pooled readers) and
//!   PostgreSQL (`store::postgres`: writer tasks with the same group
//!   commit, day partitions, several nodes by leases, `tunnelnav
//!   migrate`); a test-only backend in memory under `tests/`.
//! - [`machine`]: one task per machine owning its engines; the only bridge
//!   from async code to the fusion core (`core`: the synchronous
//!   [`machine::MachineCore`]; `actor`: the task; `status`: what it looks
//!   like now; `recover`: a machine rebuilt from the store; `lease`: the
//!   epoch each write carries; `error`). It
//!   hands committed alarm changes to a [`machine::AlarmSink`] it defines.
//! - [`server`]: axum routes (the router and `run` in its `mod.rs`),
//!   start-up (`boot.rs`), shared state (`server::state`), the fleet
//!   (`fleet.rs`), the cluster (`server::cluster`), settings and the config file
//!   (`server::settings`), errors, live stream, MQTT, metrics, alarm
//!   notifications (the sink's subscriber).
//! - [`cli`]: one file per subcommand; `main.rs` only parses and dispatches.
//! - `toy_engine` (unit tests only): a toy engine proving what adding an
//!   engine touches (docs/development.md).
//!
//! Imports run downwards only: nothing below `server` (the fusion core,
//! `sim`, `eval`, `replay`, `config`, `clock`, `auth`, `tls`, `store`,
//! `machine`)
//! imports it or `cli`, and `server` does not import `cli`
//! (`tests/layering.rs`).

pub mod auth;
pub mod cli;
pub mod clock;
pub mod config;
pub mod eval;
pub mod fusion;
pub mod machine;
pub mod replay;
pub mod server;
pub mod sim;
pub mod store;
pub mod tls;
#[cfg(test)]
mod toy_engine;
