//! pkm-plc: a soft-PLC for parallel-kinematic machine models.
//!
//! The library is built in three layers, and imports run one way, from the top down:
//!
//! - [`compose`] — **composition**: a configuration turned into a built PLC. It resolves the
//!   machine a configuration names ([`compose::machines`] is the one place that lists the machine
//!   crates this build links), reads and plans its NC programs and the screen's jobs, picks the
//!   bus, lays the screen's and the joystick's variables over it, and drives a real-time run with
//!   its servers ([`compose::serve`]) or a replay ([`compose::replay`]).
//! - [`services`] — **services** the PLC talks through: field I/O ([`services::io`]: the I/O map,
//!   Modbus, the joystick), the simulated machine ([`services::sim`]), traces
//!   ([`services::trace`]), the operator's screen ([`services::hmi`]) and OPC UA
//!   ([`services::opcua`]). Each is given what it needs by the composition; none builds a PLC.
//! - [`runtime`] — **the runtime core**, the counterpart of B&R Automation Runtime: task classes
//!   over the process image, buses, time and its sources, cycle monitoring, signals, statistics,
//!   the configuration's schema. It knows no machine, no wire and no server.
//!
//! The command line (`src/main.rs` and `src/cli/`, the binary) sits on top: it parses arguments
//! and calls the composition. Machines plug in through [`pkm_api::machine::Machine`] (the crates
//! under `tasks/`).

pub mod compose;
pub mod runtime;
pub mod services;

/// The process image (from the program interface crate, `pkm-api`).
pub use pkm_api::image;
/// The program interface (from `pkm-api`).
pub use pkm_api::program;
/// Strict JSON (from `pkm-api`).
pub use pkm_api::strict_json;
