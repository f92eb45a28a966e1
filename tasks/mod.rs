//! The application (the counterpart of the Automation Studio "Logical View"): the kinematics of
//! the four machine models and the TRIJOINT programs (encoders, drive controller, main automaton).
//!
//! The application reads and writes named variables of the process image through
//! [`crate::program`] and [`crate::image`]; it never touches a serial port, a clock or a file.
//! `tests/architecture.rs` checks that.

pub mod kinematics;
pub mod trijoint;
