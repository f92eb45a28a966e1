//! The machine plug-in interface: how a machine (TRIJOINT, pn101, O-X glide, hexapod) supplies
//! its programs, the check of its own configuration sections, its default I/O map and its
//! simulated plant. The runtime knows machines only through [`Machine`]; config.json names the
//! machine it runs (`"machine": "trijoint"`).
//!
//! As in LinuxCNC, where a machine is configuration over generic components, the generic half of
//! the simulated machine stays in the runtime: module channel images, the wiring of plant signals
//! to channels through the I/O map, scenario files and fault injection. A machine's [`Plant`]
//! supplies only the physics behind its signals.

use std::any::Any;
use std::fmt;

use crate::image::{Direction, Value, VarType};
use crate::problem::Problem;
use crate::program::ProgramInfo;

/// The world limit of a machine without world limits (its joints bound it): the kinematics'
/// bound on any length (mm), past any lab model's travel.
pub const NO_WORLD_LIMIT: f64 = 10_000.0;

/// The main automaton's states as users and clients read them, each at the index of its code
/// in the process image: what a SCADA maps the state's number to (OPC UA's `MainState`).
pub const MAIN_STATES: [&str; 6] = ["REBOOT", "INIT", "READY", "MOTION", "ERROR", "AUTO"];

/// What a machine's ERROR reason code (`error_reason` in the process image) says, by class: the
/// ranges every machine's codes follow, so that a SCADA's alarms (OPC UA's conditions) tell a
/// limit switch from an encoder fault on any machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReasonClass {
    /// No error (0).
    None,
    /// STOP pressed (1).
    Stop,
    /// A limit switch or limit input (10 … 19, 100 … 129).
    LimitSwitch,
    /// An implausible encoder change (20 … 29).
    EncoderFault,
    /// A cycle time violation the runtime reported (50).
    CycleTime,
    /// The field bus failed beyond its error bound (55).
    BusFault,
    /// Any other: a drive's bridge or following error, a referencing that failed, the
    /// program's path.
    Other,
}

impl ReasonClass {
    /// The class of the ERROR reason `code`.
    pub fn of(code: i16) -> ReasonClass {
        match code {
            0 => ReasonClass::None,
            1 => ReasonClass::Stop,
            10..=19 | 100..=129 => ReasonClass::LimitSwitch,
            20..=29 => ReasonClass::EncoderFault,
            50 => ReasonClass::CycleTime,
            55 => ReasonClass::BusFault,
            _ => ReasonClass::Other,
        }
    }
}

/// The configuration sections that belong to the machine (each `None` when config.json leaves it
/// out: the machine's defaults apply).
#[derive(Clone, Copy, Debug, Default)]
pub struct Sections<'a> {
    /// `kinematics`: the kinematic parameters.
    pub kinematics: Option<&'a serde_json::Value>,
    /// `plant`: the simulated machine (drives, wiring).
    pub plant: Option<&'a serde_json::Value>,
}

/// A file built into the binary that the built-in configuration may name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EmbeddedFile {
    /// The name a configuration uses for it (`io-map/trijoint.json`).
    pub name: &'static str,
    /// Its text.
    pub text: &'static str,
}

/// A machine: its programs, its configuration checks, its default I/O map and its plant.
pub trait Machine: Sync + fmt::Debug {
    /// The name config.json uses (`"machine": NAME`).
    fn name(&self) -> &'static str;
    /// One line on the machine.
    fn summary(&self) -> &'static str;
    /// The program types it brings.
    fn programs(&self) -> &'static [ProgramInfo];
    /// Checks the machine's sections of the configuration; problems carry their full JSON path
    /// (`kinematics.trijoint.d`, `plant.left.tau_s`).
    fn check(&self, sections: &Sections<'_>) -> Vec<Problem>;
    /// The I/O map of the machine's lab model, built into the binary.
    fn default_io_map(&self) -> EmbeddedFile;
    /// The machine's configuration file (`machines/NAME.json`; the TRIJOINT's `config.json`),
    /// built into the binary: `--machine NAME` reads the file of that name where it exists and
    /// takes this text where it does not.
    fn configuration(&self) -> EmbeddedFile;
    /// Builds the simulated plant from the (checked) sections; problems as in [`Machine::check`].
    fn plant(&self, sections: &Sections<'_>) -> Result<PlantSetup, Vec<Problem>>;
    /// Where the tool may go, as NC programs need it, from the whole (checked) configuration:
    /// the machine's main program's parameters and its kinematics.
    fn motion(&self, config: &serde_json::Value) -> Result<Motion, Vec<Problem>>;
    /// What must hold between the machine's sections and its programs' parameters, each valid
    /// on its own, in the whole (checked) configuration; problems carry their full JSON path.
    /// None by default.
    fn cross_check(&self, _config: &serde_json::Value) -> Vec<Problem> {
        Vec::new()
    }
}

/// The JSON path of program `name`'s parameters in `config`
/// (`task_classes[1].programs[0].params`), if the configuration runs it.
pub fn program_params_path(config: &serde_json::Value, name: &str) -> Option<String> {
    let classes = config.get("task_classes")?.as_array()?;
    classes.iter().enumerate().find_map(|(c, class)| {
        let programs = class.get("programs")?.as_array()?;
        let p = programs
            .iter()
            .position(|p| p.get("program").and_then(|n| n.as_str()) == Some(name))?;
        Some(format!("task_classes[{c}].programs[{p}].params"))
    })
}

/// Where a machine's tool may go: what NC programs are checked and planned against.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// The kinematic model, as `pkm-plc kin` names it (`pn101`).
    pub model: &'static str,
    /// The machine frame's coordinates (`x`, `y`, `z`, `a`, `b`, `c` as far as it has them).
    pub axes: &'static [&'static str],
    /// The machine frame's origin: the joints at the reference point (`Joints`) or the home
    /// pose in the mechanism frame (`Pose`).
    pub home: Home,
    /// The joints' software limits, `[min, max]` (mm).
    pub soft_limits: Vec<[f64; 2]>,
    /// The world limits per coordinate of the machine frame, `[min, max]`; ±[`NO_WORLD_LIMIT`]
    /// where the machine has none (its joints bound it).
    pub world_limits: Vec<[f64; 2]>,
    /// The tool is never commanded where the singularity measure is below this.
    pub singularity_threshold: f64,
    /// Per joint: the speed its set-point may take (mm/s).
    pub joint_speed: Vec<f64>,
    /// Per joint: the acceleration its set-point may take (mm/s²).
    pub joint_accel: Vec<f64>,
    /// Per joint: the variable holding its measured position in the kinematics' joint
    /// coordinates (once referenced), for drawings of the mechanism.
    pub joint_vars: Vec<&'static str>,
    /// Per joint: the variable holding its position set-point in the kinematics' joint
    /// coordinates: the forward kinematics of these is where the tool stands commanded (a
    /// job made on the screen starts there).
    pub setpoint_vars: Vec<&'static str>,
}

/// Where a machine frame's origin is.
#[derive(Clone, Debug, PartialEq)]
pub enum Home {
    /// The tool point at these joints.
    Joints(Vec<f64>),
    /// This pose of the mechanism frame.
    Pose(Vec<f64>),
}

/// The `params` of the first entry of program `name` in a configuration's task classes, if it
/// has any.
pub fn program_params<'a>(config: &'a serde_json::Value, name: &str) -> Option<&'a serde_json::Value> {
    config
        .get("task_classes")?
        .as_array()?
        .iter()
        .filter_map(|class| class.get("programs")?.as_array())
        .flatten()
        .find(|p| p.get("program").and_then(|n| n.as_str()) == Some(name))?
        .get("params")
}

/// A plant as its machine built it, with what the runtime needs to wire it.
pub struct PlantSetup {
    /// The plant.
    pub plant: Box<dyn Plant>,
    /// Its integration step (ns); cycles see the plant at their nominal start time.
    pub step_ns: u64,
    /// For each of the plant's [`Plant::signals`], in order: the channel it is wired to
    /// (`MODULE.Channel`) and the JSON path that says so (`plant.wiring.stop_button`).
    pub wiring: Vec<(String, String)>,
}

/// What a plant signal is to an operator or a scenario file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// An operator panel button: a scenario's `input` event presses and releases it.
    Button,
    /// A limit switch: a scenario's `switch_stuck` / `switch_free` faults name it.
    Switch,
    /// Anything else (encoders, bridges, PWM, the joystick's channels).
    Other,
}

/// One signal of a plant, as its harness carries it to a module channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Signal {
    /// The signal's key in the plant's wiring section (`stop_button`).
    pub key: &'static str,
    /// Field → PLC (input) or back (output).
    pub direction: Direction,
    /// The type of the channel it is wired to.
    pub ty: VarType,
    /// What it is to a scenario.
    pub role: Role,
}

/// A scenario action, resolved by the runtime (signals by index into [`Plant::signals`], drives
/// by index into [`Plant::drives`]) and applied to the plant at its time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// Press (true) or release a [`Role::Button`] signal.
    Press {
        /// The signal.
        signal: usize,
        /// Pressed or released.
        pressed: bool,
    },
    /// Set the joystick's axes (each in −1 … 1).
    Joystick(f64, f64),
    /// Stick a [`Role::Switch`] signal on (`Some(true)`), off (`Some(false)`), or free it (`None`).
    StickSwitch {
        /// The signal.
        signal: usize,
        /// The stuck state.
        stuck: Option<bool>,
    },
    /// A drive's encoder counter jumps.
    EncoderGlitch {
        /// The drive.
        drive: usize,
        /// By how many counts.
        counts: i64,
    },
    /// A drive's motor bridge latches an error (overcurrent).
    BridgeError {
        /// The drive.
        drive: usize,
    },
    /// A drive stops responding (true) or responds again (false), with no error shown.
    DriveDead {
        /// The drive.
        drive: usize,
        /// Dead or alive.
        dead: bool,
    },
    /// The joystick is plugged in (true) or unplugged.
    JoystickConnected(bool),
}

/// One joint of a simulated machine as it truly is, whatever its controller believes.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct JointTruth {
    /// The joint's true position (mm), in the joint coordinates of the machine's kinematics.
    pub position_mm: f64,
    /// Whether a stepper drives it (open loop: it can lose steps); otherwise a DC motor whose
    /// encoder sees every movement.
    pub stepper: bool,
    /// Steps the stepper module emitted that the motor did not make (0 for a DC motor).
    pub lost_steps: f64,
    /// How often the stepper fell out of step (0 for a DC motor).
    pub stalls: u64,
}

/// The physics behind a machine's signals. Time advances in fixed steps, so a run depends only on
/// its inputs: no clock, no randomness.
pub trait Plant: Send + Any {
    /// The signals the plant's harness carries, in a fixed order (indices are stable).
    fn signals(&self) -> &[Signal];
    /// The drives' names as scenario files give them (`left`, `right`), by index.
    fn drives(&self) -> &[&'static str];
    /// Advances the plant by `dt_s` seconds.
    fn step(&mut self, dt_s: f64);
    /// Advances the plant by `n` steps of `dt_s` seconds each (the runtime's hot path: a
    /// machine's implementation of this loop inlines its `step`).
    fn steps(&mut self, dt_s: f64, n: u64) {
        for _ in 0..n {
            self.step(dt_s);
        }
    }
    /// The value of input signal `signal` now.
    fn read(&self, signal: usize) -> Value;
    /// Applies the value of output signal `signal` (a value of another type is ignored).
    fn write(&mut self, signal: usize, value: Value);
    /// The values of the input signals `signals` into `values` (indexed by signal): one call per
    /// exchange on the runtime's hot path, whose loop inlines the machine's `read`.
    fn read_into(&self, signals: &[usize], values: &mut [Value]) {
        for &s in signals {
            values[s] = self.read(s);
        }
    }
    /// Applies the output signals `signals` from `values` (indexed by signal), in order.
    fn write_from(&mut self, signals: &[usize], values: &[Value]) {
        for &s in signals {
            self.write(s, values[s]);
        }
    }
    /// Applies a scenario action.
    fn apply(&mut self, action: Action);
    /// What each joint truly did (by joint, in the PLC's joint order): for a simulated
    /// station's report and the tests that hold the PLC's view against the machine's.
    fn joints(&self) -> Vec<JointTruth>;
    /// How many time steps the mechanism jammed (the drives pushed against a linkage that
    /// could not follow).
    fn jams(&self) -> u64;
    /// The plant as `Any`, for tests and displays that know its type.
    fn as_any(&self) -> &dyn Any;
    /// The plant as mutable `Any`, for tests that act on the machine by hand.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}
