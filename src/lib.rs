//! pkm-plc: a soft-PLC for parallel-kinematic machine models.
//!
//! The runtime (this crate's `src/`) is the counterpart of B&R Automation Runtime: task classes,
//! the process image, buses, time, cycle monitoring, configuration and the command line. It knows
//! no machine: machines plug in through [`pkm_api::machine::Machine`], and [`machines`] is the one
//! place that lists the machine crates this build links. [`compose`] turns a configuration into a
//! built PLC.

pub mod backoff;
pub mod bench;
pub mod bus;
pub mod compose;
pub mod config;
pub mod files;
pub mod hmi;
pub mod io;
pub mod link_bench;
pub mod log_limit;
pub mod machines;
pub mod nc_job;
pub mod opcua;
pub mod plc;
pub mod run;
pub mod screen_job;
pub mod selftest;
pub mod service;
pub mod signals;
pub mod sim;
pub mod station_cmd;
pub mod stats;
pub mod status;
pub mod summary;
pub mod timing;
pub mod trace;

/// The process image (from the program interface crate, `pkm-api`).
pub use pkm_api::image;
/// The program interface (from `pkm-api`).
pub use pkm_api::program;
/// Strict JSON (from `pkm-api`).
pub use pkm_api::strict_json;
