//! The runtime core: what runs the cycles, whatever the machine and whatever the wire. The PLC
//! ([`plc`]) executes task classes over the process image and a [`bus::Bus`]; [`run`] drives it
//! in real time on its own thread or in virtual time, keeping time by a source of [`timing`];
//! [`signals`] turns the process's terminating signals into a safe stop; [`stats`], [`status`]
//! and [`summary`] measure and report the cycles; [`frame`] hands each main cycle's state to
//! whoever watches (the screen, OPC UA) without the cyclic thread waiting; [`messages`] turns
//! the NC programs' message comments the cycle reached back into their texts; [`service_mode`]
//! is what a cyclic program's panic leads to; [`config`] is the
//! configuration file's schema, reading and checks. Nothing here imports the services or the
//! composition above it.

pub mod backoff;
pub mod bus;
pub mod config;
pub mod files;
pub mod frame;
pub mod log_limit;
pub mod messages;
pub mod plc;
pub mod run;
pub mod service;
pub mod service_mode;
pub mod signals;
pub mod snapshot;
pub mod stats;
pub mod status;
pub mod summary;
pub mod timing;
pub mod tool_table;
