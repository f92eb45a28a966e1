//! The TRIJOINT 900H lab model as a pkm-plc machine (application.md): its programs on the
//! runtime's program interface — the encoder program and the drive controller with the fast
//! interlock (10 ms class), and the main automaton with referencing and jogging (50 ms class) —,
//! the check of its configuration sections, its I/O map and its simulated plant.

pub mod control;
pub mod encoders;
pub mod harness;
pub mod main_program;
pub mod plant;
pub mod state;
pub mod vars;

use pkm_api::machine::{EmbeddedFile, Machine, PlantSetup, Sections};
use pkm_api::problem::{self, Problem};
use pkm_api::program::ProgramInfo;
use pkm_kinematics::KinematicsConfig;

use crate::harness::{PlantConfig, SIGNALS};

/// The TRIJOINT machine.
#[derive(Debug)]
pub struct Trijoint;

/// The machine, as the composition root lists it.
pub static MACHINE: Trijoint = Trijoint;

/// The TRIJOINT programs.
pub const PROGRAMS: [ProgramInfo; 3] = [
    ProgramInfo {
        name: "trijoint.encoders",
        summary: "10 ms: unwraps the 16-bit counters, positions and velocities in mm, encoder faults, switch captures",
        factory: encoders::Encoders::create,
    },
    ProgramInfo {
        name: "trijoint.main",
        summary: "50 ms: the REBOOT/INIT/READY/MOTION/ERROR automaton, referencing, jogging M in the plane",
        factory: main_program::MainProgram::create,
    },
    ProgramInfo {
        name: "trijoint.control",
        summary: "10 ms: PI position regulators, following-error supervision, fast interlock",
        factory: control::Control::create,
    },
];

/// The lab model's I/O map (the repository's io-map/trijoint.json), built into the binary.
pub const IO_MAP: EmbeddedFile = EmbeddedFile {
    name: "io-map/trijoint.json",
    text: include_str!("../../../io-map/trijoint.json"),
};

/// The `plant` section, parsed strictly (defaults when it is left out).
fn plant_config(section: Option<&serde_json::Value>) -> Result<PlantConfig, Problem> {
    match section {
        None => Ok(PlantConfig::default()),
        Some(v) => pkm_api::strict_json::section(v, "plant"),
    }
}

impl Machine for Trijoint {
    fn name(&self) -> &'static str {
        "trijoint"
    }

    fn summary(&self) -> &'static str {
        "TRIJOINT 900H lab model: two carriages on inclined guides, tool point M in the plane"
    }

    fn programs(&self) -> &'static [ProgramInfo] {
        &PROGRAMS
    }

    fn check(&self, sections: &Sections<'_>) -> Vec<Problem> {
        let mut problems = KinematicsConfig::from_section(sections.kinematics)
            .err()
            .unwrap_or_default();
        match plant_config(sections.plant) {
            Ok(plant) => problems.extend(problem::under("plant", plant.check())),
            Err(p) => problems.push(p),
        }
        problems
    }

    fn default_io_map(&self) -> EmbeddedFile {
        IO_MAP
    }

    fn plant(&self, sections: &Sections<'_>) -> Result<PlantSetup, Vec<Problem>> {
        let problems = self.check(sections);
        let (Ok(kinematics), Ok(config)) = (
            KinematicsConfig::from_section(sections.kinematics),
            plant_config(sections.plant),
        ) else {
            return Err(problems);
        };
        if !problems.is_empty() {
            return Err(problems);
        }
        let plant = plant::Plant::new(
            &config.left,
            &config.right,
            config.mechanism.then_some(&kinematics.trijoint),
        );
        let wiring = config
            .wiring
            .channels()
            .iter()
            .zip(SIGNALS)
            .map(|(channel, s)| (channel.to_string(), format!("plant.wiring.{}", s.key)))
            .collect();
        Ok(PlantSetup {
            plant: Box::new(plant),
            step_ns: u64::from(config.step_us) * 1000,
            wiring,
        })
    }
}
