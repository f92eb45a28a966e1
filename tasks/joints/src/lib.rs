//! The machine-agnostic application for joint-driven machines — pn101, the O-X glide in its X
//! and O configurations, the hexapod (docs/machines.md) — on the runtime's program interface: a drive
//! program per machine (fast class: counters, regulation, the fast interlock) and a main program
//! (the REBOOT/INIT/READY/MOTION/ERROR automaton, referencing, joint and world jog through the
//! kinematics), the checks of their configuration sections, their I/O maps, configurations and
//! simulated plants. What they share with the TRIJOINT (counter unwrap, PI, the interlock rule,
//! the states and the STOP rule, the simulated drives) comes from pkm-drives.

pub mod drives;
pub mod main_program;
pub mod params;
pub mod plant;
pub mod spec;
pub mod switches;
pub mod vars;

use pkm_api::image::Declare;
use pkm_api::machine::{EmbeddedFile, Home, Machine, Motion, PlantSetup, Sections, program_params};
use pkm_api::problem::{self, Problem};
use pkm_api::program::{Program, ProgramArgs, ProgramInfo};
use pkm_kinematics::KinematicsConfig;

use plant::config::PlantConfig;
use spec::{DriveKind, Spec, SwitchLayout};

/// Declares a machine: its spec and its two programs' factories.
macro_rules! machine {
    ($spec:ident, $programs:ident, $drives:ident, $main:ident, $name:literal, $summary:literal, $model:expr, $drive:expr, $switches:expr) => {
        fn $drives(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
            drives::Drives::create(&$spec, args, decl)
        }
        fn $main(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
            main_program::MainProgram::create(&$spec, args, decl)
        }
        static $programs: [ProgramInfo; 2] = [
            ProgramInfo {
                name: concat!($name, ".drives"),
                summary: "10 ms: counters to joint positions, reference captures, regulation, following error, fast interlock",
                factory: $drives,
            },
            ProgramInfo {
                name: concat!($name, ".main"),
                summary: "50 ms: REBOOT/INIT/READY/MOTION/ERROR, referencing, joint jog, world jog through the kinematics, tool pose",
                factory: $main,
            },
        ];
        /// The machine's spec.
        pub static $spec: Spec = Spec {
            name: $name,
            summary: $summary,
            model: $model,
            drive: $drive,
            switches: $switches,
            io_map: EmbeddedFile {
                name: concat!("../io-map/", $name, ".json"),
                text: include_str!(concat!("../../../io-map/", $name, ".json")),
            },
            config: EmbeddedFile {
                name: concat!("machines/", $name, ".json"),
                text: include_str!(concat!("../../../machines/", $name, ".json")),
            },
            programs: &$programs,
        };
    };
}

machine!(
    PN101,
    PN101_PROGRAMS,
    pn101_drives,
    pn101_main,
    "pn101",
    "pn101: 3-DOF spatial parallel mechanism, three lead-screw carriages on open-loop steppers, shared limit and reference inputs",
    pkm_kinematics::Machine::Pn101,
    DriveKind::Stepper,
    SwitchLayout::Shared
);
machine!(
    OX_X,
    OX_X_PROGRAMS,
    ox_x_drives,
    ox_x_main,
    "ox-x",
    "O-X glide, crossed X configuration: two sliders and a serial y axis on steppers, own switches per joint",
    pkm_kinematics::Machine::OxX,
    DriveKind::Stepper,
    SwitchLayout::PerJoint
);
machine!(
    OX_O,
    OX_O_PROGRAMS,
    ox_o_drives,
    ox_o_main,
    "ox-o",
    "O-X glide, extended O configuration: two sliders and a serial y axis on steppers, own switches per joint",
    pkm_kinematics::Machine::OxO,
    DriveKind::Stepper,
    SwitchLayout::PerJoint
);
machine!(
    HEXAPOD,
    HEXAPOD_PROGRAMS,
    hexapod_drives,
    hexapod_main,
    "hexapod",
    "Stewart-Gough hexapod: six struts on DC motors with encoders, own switches per strut",
    pkm_kinematics::Machine::Hexapod,
    DriveKind::Dc,
    SwitchLayout::PerJoint
);

/// A joint-driven machine as the runtime sees it.
#[derive(Debug)]
pub struct JointMachine(pub &'static Spec);

/// The machines, as the composition root lists them.
pub static MACHINES: [JointMachine; 4] = [
    JointMachine(&PN101),
    JointMachine(&OX_X),
    JointMachine(&OX_O),
    JointMachine(&HEXAPOD),
];

impl JointMachine {
    /// The machine's sections, parsed strictly and checked (defaults for a section or key left
    /// out); every problem of both, with its full path, kinematics first.
    fn sections(&self, s: &Sections<'_>) -> Result<(KinematicsConfig, PlantConfig), Vec<Problem>> {
        let spec = self.0;
        let kinematics = KinematicsConfig::from_section(s.kinematics);
        let signals = plant::harness::signals(spec);
        let keys: Vec<&str> = signals.iter().map(|(s, _, _)| s.key).collect();
        let plant = plant_section(spec, s.plant).and_then(|plant| {
            let problems = problem::under(
                "plant",
                plant.check(spec.joints(), &keys, spec.drive == DriveKind::Stepper),
            );
            if problems.is_empty() { Ok(plant) } else { Err(problems) }
        });
        let (k, p) = match (kinematics, plant) {
            (Ok(k), Ok(p)) => (k, p),
            (k, p) => return Err([k.err(), p.err()].into_iter().flatten().flatten().collect()),
        };
        // The mechanism must assemble where the joints stand at power-on.
        if p.mechanism {
            let mut widened = k.clone();
            widen_travel(&mut widened, spec, &p);
            let kin = widened.build(spec.model);
            let starts: Vec<f64> = p.joints.iter().map(|j| j.start_mm).collect();
            let mut pose = [0.0; pkm_kinematics::MAX_DOF];
            if let Err(e) = kin.forward(&starts, None, &mut pose[..starts.len()]) {
                return Err(vec![Problem::new(
                    "plant.joints",
                    format!("the mechanism cannot assemble at the joints' start_mm {starts:?}: {e}"),
                )]);
            }
        }
        Ok((k, p))
    }
}

/// The `plant` section laid over the machine's defaults and parsed strictly.
fn plant_section(spec: &Spec, section: Option<&serde_json::Value>) -> Result<PlantConfig, Vec<Problem>> {
    params::over_defaults(section, "plant", spec.default_plant()).map_err(|p| vec![p])
}

impl Machine for JointMachine {
    fn name(&self) -> &'static str {
        self.0.name
    }

    fn summary(&self) -> &'static str {
        self.0.summary
    }

    fn programs(&self) -> &'static [ProgramInfo] {
        self.0.programs
    }

    fn check(&self, s: &Sections<'_>) -> Vec<Problem> {
        self.sections(s).err().unwrap_or_default()
    }

    fn default_io_map(&self) -> EmbeddedFile {
        self.0.io_map
    }

    fn configuration(&self) -> EmbeddedFile {
        self.0.config
    }

    fn motion(&self, config: &serde_json::Value) -> Result<Motion, Vec<Problem>> {
        let spec = self.0;
        let kinematics = KinematicsConfig::from_section(config.get("kinematics"))?;
        let main = spec.programs[1].name;
        let p = params::over_defaults(
            program_params(config, main),
            &format!("params of {main}"),
            spec.default_main(),
        )
        .map_err(|p| vec![p])?;
        let kin = kinematics.build(spec.model);
        let m = p.soft_limit_margin_mm;
        Ok(Motion {
            model: spec.model.name(),
            axes: kin.pose_keys(),
            home: match spec.model {
                pkm_kinematics::Machine::Hexapod => Home::Pose(kinematics.hexapod.home.to_vec()),
                _ => Home::Joints(vec![0.0; kin.dof()]),
            },
            soft_limits: kin.joint_limits().iter().map(|[lo, hi]| [lo + m, hi - m]).collect(),
            world_limits: p.world_limits,
            singularity_threshold: p.singularity_threshold,
            joint_speed: p.joints.iter().map(|j| j.max_speed_mm_s).collect(),
            joint_accel: p.joints.iter().map(|j| j.max_accel_mm_s2).collect(),
            joint_vars: vars::JOINT_POSITION[..kin.dof()].iter().map(|v| v.name()).collect(),
            setpoint_vars: vars::SETPOINT[..kin.dof()].iter().map(|v| v.name()).collect(),
        })
    }

    /// The main program's reference switches are the simulated machine's: the same position and
    /// direction per joint (the two sections describe one switch; a difference references the
    /// simulated machine to another zero than the program believes, or searches the wrong way).
    fn cross_check(&self, config: &serde_json::Value) -> Vec<Problem> {
        let spec = self.0;
        let main = spec.programs[1].name;
        let (Ok(p), Ok(plant)) = (
            params::over_defaults::<params::MainParams>(program_params(config, main), "params", spec.default_main()),
            plant_section(spec, config.get("plant")),
        ) else {
            // Each is refused with its path by its own check.
            return Vec::new();
        };
        let at = pkm_api::machine::program_params_path(config, main).unwrap_or_else(|| format!("params of {main}"));
        let mut problems = Vec::new();
        for (j, (joint, simulated)) in p.joints.iter().zip(&plant.joints).enumerate() {
            let r = &joint.reference;
            if (r.switch_mm - simulated.reference_switch_mm).abs() > 1e-9 {
                problems.push(Problem::new(
                    format!("{at}.joints[{j}].reference.switch_mm"),
                    format!(
                        "joint {}'s reference switch is at {} mm in the simulated machine (plant.joints[{j}].reference_switch_mm), got {}: both describe the same switch",
                        j + 1,
                        simulated.reference_switch_mm,
                        r.switch_mm
                    ),
                ));
            }
            if r.direction != simulated.reference_direction {
                problems.push(Problem::new(
                    format!("{at}.joints[{j}].reference.direction"),
                    format!(
                        "joint {}'s reference switch is on beyond it in the {} direction in the simulated machine (plant.joints[{j}].reference_direction), got {}: the search would go the other way",
                        j + 1,
                        if simulated.reference_direction > 0.0 { "+" } else { "-" },
                        r.direction
                    ),
                ));
            }
        }
        problems
    }

    fn plant(&self, s: &Sections<'_>) -> Result<PlantSetup, Vec<Problem>> {
        let spec = self.0;
        let (kinematics, config) = self.sections(s)?;
        let signals = plant::harness::signals(spec);
        let wiring = signals
            .iter()
            .map(|(s, _, default)| {
                let channel = config.wiring.get(s.key).cloned().unwrap_or_else(|| default.clone());
                (channel, format!("plant.wiring.{}", s.key))
            })
            .collect();
        let mechanism = config.mechanism.then(|| {
            // The mechanism is checked over the whole mechanical range, up to the hard stops.
            let mut k = kinematics.clone();
            widen_travel(&mut k, spec, &config);
            k.build(spec.model)
        });
        let plant = plant::Plant::new(
            &config,
            signals.into_iter().map(|(s, w, _)| (s, w)).collect(),
            mechanism,
        );
        Ok(PlantSetup {
            plant: Box::new(plant),
            step_ns: u64::from(config.step_us) * 1000,
            wiring,
        })
    }
}

/// Sets the kinematics' joint travel to the plant's hard stops, so that the jam check refuses
/// only what the linkage cannot assemble.
fn widen_travel(k: &mut KinematicsConfig, spec: &Spec, config: &PlantConfig) {
    let stops: Vec<[f64; 2]> = config.joints.iter().map(|j| j.hard_stops_mm).collect();
    let copy3 = |t: &mut [[f64; 2]; 3]| {
        for (t, s) in t.iter_mut().zip(&stops) {
            *t = *s;
        }
    };
    match spec.model {
        pkm_kinematics::Machine::Pn101 => copy3(&mut k.pn101.travel),
        pkm_kinematics::Machine::OxX => copy3(&mut k.ox_x.travel),
        pkm_kinematics::Machine::OxO => copy3(&mut k.ox_o.travel),
        pkm_kinematics::Machine::Hexapod => {
            let lo = stops.iter().map(|s| s[0]).fold(f64::INFINITY, f64::min);
            let hi = stops.iter().map(|s| s[1]).fold(f64::NEG_INFINITY, f64::max);
            k.hexapod.strut_travel = [lo, hi];
        }
        pkm_kinematics::Machine::Trijoint => {}
    }
}
