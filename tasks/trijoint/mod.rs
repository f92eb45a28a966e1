//! The programs of the TRIJOINT application (application.md), on the runtime's program interface.
//!
//! Landed so far: the encoder program and the drive controller (10 ms class). The main automaton
//! (50 ms class) is the next step; until it lands the default configuration runs the runtime's
//! self-test programs.

pub mod control;
pub mod encoders;
pub mod main_program;
pub mod state;

use crate::program::{ProgramInfo, Registry};

/// Registers the TRIJOINT programs.
pub fn register(registry: &mut Registry) {
    registry
        .register(ProgramInfo {
            name: "trijoint.encoders",
            summary: "10 ms: unwraps the 16-bit counters, positions and velocities in mm, encoder faults, switch captures",
            factory: encoders::Encoders::create,
        })
                .register(ProgramInfo {
            name: "trijoint.main",
            summary: "50 ms: the REBOOT/INIT/READY/MOTION/ERROR automaton, referencing, jogging M in the plane",
            factory: main_program::MainProgram::create,
        })
        .register(ProgramInfo {
            name: "trijoint.control",
            summary: "10 ms: PI position regulators, following-error supervision, fast interlock",
            factory: control::Control::create,
        });
}
