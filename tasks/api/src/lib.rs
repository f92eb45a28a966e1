//! pkm-api: the program interface of the pkm-plc soft-PLC.
//!
//! Everything an application crate (a machine, its kinematics, its programs, its simulated
//! plant) needs from the runtime, and nothing that touches a wire, a clock, a thread or a
//! terminal: the process image ([`image`]), programs and their cycles ([`program`]), the bus and
//! clock traits ([`bus`], [`program::Clock`]), the machine plug-in interface ([`machine`]), the
//! one problem type of configuration checks ([`problem`]) and strict JSON ([`strict_json`]).
//!
//! The runtime (the `pkm-plc` crate) builds on this; application crates depend on it alone.

pub mod bus;
pub mod hmi;
pub mod image;
pub mod library;
pub mod machine;
pub mod offsets;
pub mod problem;
pub mod program;
pub mod ranges;
pub mod screen_jobs;
pub mod strict_json;
pub mod trajectory;
