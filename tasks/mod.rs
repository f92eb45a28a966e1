//! The application (the counterpart of the Automation Studio "Logical View"): machine
//! kinematics, and, as the issues land, the encoder program, the main program and the regulators.
//!
//! The application reads and writes named variables of the process image through
//! [`crate::program`] and [`crate::image`]; it never touches a serial port, a clock or a file.
//! `tests/architecture.rs` checks that.

pub mod kinematics;
pub mod trijoint;
