//! The programs of the TRIJOINT application (application.md), on the runtime's program interface:
//! the encoder program and the drive controller with the fast interlock (10 ms class), and the
//! main automaton with referencing and jogging (50 ms class), which config.json runs.

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
