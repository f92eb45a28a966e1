//! The TRIJOINT 900H lab model as a pkm-plc machine (docs/trijoint.md): its programs on the
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

use pkm_api::machine::{EmbeddedFile, Home, Machine, Motion, PlantSetup, Sections, program_params};
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

/// The lab model's configuration (the repository's config.json), built into the binary.
pub const CONFIG: EmbeddedFile = EmbeddedFile {
    name: "config.json",
    text: include_str!("../../../config.json"),
};

/// The machine's sections, parsed strictly and checked (defaults for a section left out); every
/// problem of both, with its full path, kinematics first.
fn sections(s: &Sections<'_>) -> Result<(KinematicsConfig, PlantConfig), Vec<Problem>> {
    let kinematics = KinematicsConfig::from_section(s.kinematics);
    let plant = match s.plant {
        None => Ok(PlantConfig::default()),
        Some(v) => pkm_api::strict_json::section(v, "plant").map_err(|p| vec![p]),
    }
    .and_then(|plant| {
        let problems = problem::under("plant", plant.check());
        if problems.is_empty() { Ok(plant) } else { Err(problems) }
    });
    match (kinematics, plant) {
        (Ok(k), Ok(p)) => Ok((k, p)),
        (k, p) => Err([k.err(), p.err()].into_iter().flatten().flatten().collect()),
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

    fn check(&self, s: &Sections<'_>) -> Vec<Problem> {
        sections(s).err().unwrap_or_default()
    }

    fn default_io_map(&self) -> EmbeddedFile {
        IO_MAP
    }

    fn configuration(&self) -> EmbeddedFile {
        CONFIG
    }

    fn motion(&self, config: &serde_json::Value) -> Result<Motion, Vec<Problem>> {
        let kinematics = KinematicsConfig::from_section(config.get("kinematics"))?;
        let p: main_program::MainParams = match program_params(config, "trijoint.main") {
            None => main_program::MainParams::default(),
            Some(v) => pkm_api::strict_json::section(v, "params of trijoint.main").map_err(|p| vec![p])?,
        };
        let t = &kinematics.trijoint;
        let travel = [t.h1_travel[1] - t.h1_travel[0], t.h2_travel[1] - t.h2_travel[0]];
        let m = p.soft_limit_margin_mm;
        Ok(Motion {
            model: "trijoint",
            axes: &["x", "y"],
            // M's frame is the mechanism's; referencing ends at the start position.
            home: Home::Joints(p.start_position(t).to_vec()),
            soft_limits: travel.iter().map(|t| [m, t - m]).collect(),
            world_limits: vec![[-pkm_api::machine::NO_WORLD_LIMIT, pkm_api::machine::NO_WORLD_LIMIT]; 2],
            singularity_threshold: p.singularity_threshold,
            joint_speed: vec![p.max_joint_speed_mm_s; 2],
            joint_accel: vec![p.brake_decel_mm_s2; 2],
            joint_vars: vars::POSITION_MM.iter().map(|v| v.name()).collect(),
            setpoint_vars: vars::SETPOINT_MM.iter().map(|v| v.name()).collect(),
        })
    }

    fn plant(&self, s: &Sections<'_>) -> Result<PlantSetup, Vec<Problem>> {
        let (kinematics, config) = sections(s)?;
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
