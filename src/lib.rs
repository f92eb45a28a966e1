//! pkm-plc: a soft-PLC for parallel-kinematic machine models.
//!
//! The runtime (this crate's `src/`) is the counterpart of B&R Automation Runtime: task classes,
//! the process image, buses, time, cycle monitoring, configuration and the command line. It knows
//! no machine; application programs plug in through [`program::Program`].

pub mod bench;
pub mod bus;
pub mod config;
pub mod image;
pub mod plc;
pub mod program;
pub mod run;
pub mod selftest;
pub mod stats;
pub mod status;
pub mod summary;
pub mod timing;

/// The program types this build knows: until the TRIJOINT application lands, only the runtime's
/// self-test programs.
pub fn registry() -> program::Registry {
    let mut registry = program::Registry::new();
    selftest::register(&mut registry);
    registry
}
