//! The interface between the runtime and application programs.
//!
//! A program is the counterpart of a B&R program object: an init part that runs once before the
//! first cycle and a cyclic part that the runtime calls in every cycle of its task class. A cycle is
//! a pure step: the program sees its latched inputs, the cycle's nominal time and runtime events,
//! and writes its outputs. It never reads a clock, touches a file or a wire.

use serde::de::DeserializeOwned;

use crate::image::{Declare, Input, Output, PlcType, Value};
use crate::problem::Problem;

/// A cycle time violation that the runtime reports to the application (reaction `error`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleViolation {
    /// Index of the task class that violated its cycle time (configuration order).
    pub class: usize,
    /// How far past its deadline (release + cycle time) that cycle ended, in nanoseconds.
    pub late_by_ns: u64,
}

/// Where the runtime's notion of "now" comes from while a cycle runs.
///
/// Real time reads the monotonic clock; virtual time keeps a simulated clock. Only the runtime and
/// [`Cycle::burn`] (for test programs that model a heavy cycle) use it.
pub trait Clock {
    /// Nanoseconds since the schedule's epoch.
    fn now_ns(&mut self) -> u64;
    /// Spends `ns` nanoseconds of execution time: busy-waits in real time, advances the simulated
    /// clock in virtual time.
    fn burn(&mut self, ns: u64);
}

/// What a program sees during one cycle (or its init part).
pub struct Cycle<'a> {
    image: &'a mut [Value],
    time_ns: u64,
    cycle: u64,
    period_ns: u64,
    violation: Option<CycleViolation>,
    clock: &'a mut dyn Clock,
}

/// Where a cycle stands: its nominal start time, number and period, and the runtime's event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleInfo {
    /// The cycle's nominal start time (ns since the start of the schedule).
    pub time_ns: u64,
    /// The class's cycle number, from 0.
    pub cycle: u64,
    /// The class's cycle time (ns).
    pub period_ns: u64,
    /// A cycle time violation to deliver, if there is one.
    pub violation: Option<CycleViolation>,
}

impl<'a> Cycle<'a> {
    /// A cycle over a task class's `image` (the runtime builds one per program per cycle; unit
    /// tests of a program build their own).
    pub fn new(image: &'a mut [Value], info: CycleInfo, clock: &'a mut dyn Clock) -> Self {
        Cycle {
            image,
            time_ns: info.time_ns,
            cycle: info.cycle,
            period_ns: info.period_ns,
            violation: info.violation,
            clock,
        }
    }

    /// The latched value of an input.
    #[inline]
    pub fn get<T: PlcType>(&self, input: Input<T>) -> T {
        T::from_value(self.image[usize::from(input.index)])
    }

    /// Writes an output; it is published when the cycle ends.
    #[inline]
    pub fn set<T: PlcType>(&mut self, output: Output<T>, value: T) {
        self.image[usize::from(output.index)] = value.into_value();
    }

    /// The value an output has now (as last written, or its safe value before the first write).
    #[inline]
    pub fn output_value<T: PlcType>(&self, output: Output<T>) -> T {
        T::from_value(self.image[usize::from(output.index)])
    }

    /// The nominal start time of this cycle in nanoseconds since the start of the schedule
    /// (deterministic: the same in real and virtual time).
    #[inline]
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }

    /// The number of this cycle of the task class, from 0 (the init part sees 0 too).
    #[inline]
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// The task class's cycle time in nanoseconds.
    #[inline]
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// A cycle time violation (reaction `error`) that happened since this program's last cycle.
    #[inline]
    pub fn violation(&self) -> Option<CycleViolation> {
        self.violation
    }

    /// Spends execution time, for test programs that model a heavy cycle. Real time busy-waits;
    /// virtual time advances the simulated clock, so overruns are reproducible there too.
    pub fn burn(&mut self, ns: u64) {
        self.clock.burn(ns);
    }
}

/// The state the main program reports: shown on the status line and in the run summary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AppStatus<'a> {
    /// The state's name (REBOOT, INIT, READY, MOTION, ERROR for the TRIJOINT application).
    pub state: &'a str,
    /// Why the program is in its error state, if it is.
    pub reason: Option<&'a str>,
    /// What the operator should know in this state besides an error (what INIT waits for, say).
    pub note: Option<&'a str>,
    /// Values worth showing with the state (name, value), e.g. positions: at most
    /// [`MAX_STATUS_VALUES`], every one of them shown.
    pub values: &'a [(&'static str, f64)],
}

/// The most values a main program shows with its state (the runtime keeps room for all of
/// them): the program line, six pose coordinates and six joints fit, with room to spare.
pub const MAX_STATUS_VALUES: usize = 16;

/// An application program.
pub trait Program: Send {
    /// The init part: runs once before the first cycle, with the inputs latched.
    fn init(&mut self, _ctx: &mut Cycle<'_>) {}
    /// The cyclic part.
    fn cycle(&mut self, ctx: &mut Cycle<'_>);
    /// The program's state, if it is the kind of program that has one (the main program). A
    /// program reports a state on every call, from its construction on, or never: the runtime
    /// asks once, when it builds the task class, which programs report one.
    fn status(&self) -> Option<AppStatus<'_>> {
        None
    }
}

/// The configuration of one program instance, handed to its factory.
pub struct ProgramArgs<'a> {
    /// The `params` object of the program entry, if there is one.
    pub params: Option<&'a serde_json::Value>,
    /// The configuration's `kinematics` section (machine geometry), if there is one; checked
    /// separately, so programs may take it as valid.
    pub kinematics: Option<&'a serde_json::Value>,
    /// The cycle time of the task class the program runs in (µs).
    pub cycle_us: u32,
    /// Whether that class is the fastest configured (no class has a shorter cycle).
    pub fastest_class: bool,
    /// The NC programs of the run (`run --program`, `--programs`), checked and planned; the
    /// main program runs the loaded one in AUTO and the drive program samples it.
    pub nc: Option<&'a crate::library::NcLibrary>,
}

impl ProgramArgs<'_> {
    /// Parses the `params` strictly into `P`; a problem is recorded against the program entry's
    /// path (with the path inside `params`) and `P::default()` is returned so that declaration can
    /// go on and every problem of the configuration is reported at once.
    pub fn parse<P: DeserializeOwned + Default>(&self, decl: &mut Declare<'_>) -> P {
        let Some(params) = self.params else {
            return P::default();
        };
        match crate::strict_json::section::<P>(params, "params") {
            Ok(p) => p,
            Err(Problem { at, message }) => {
                decl.issue(&at, message);
                P::default()
            }
        }
    }
}

/// Creates a program: declares its variables through `decl` and returns it.
pub type Factory = fn(&ProgramArgs<'_>, &mut Declare<'_>) -> Box<dyn Program>;

/// A program type that configurations can name.
#[derive(Clone, Copy)]
pub struct ProgramInfo {
    /// The name used in config.json (`"program": NAME`).
    pub name: &'static str,
    /// One line on what it does.
    pub summary: &'static str,
    /// Its factory.
    pub factory: Factory,
}

/// The program types a build knows.
#[derive(Clone, Default)]
pub struct Registry {
    programs: Vec<ProgramInfo>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a program type.
    pub fn register(&mut self, info: ProgramInfo) -> &mut Self {
        self.programs.push(info);
        self
    }

    /// Looks a program type up by name.
    pub fn get(&self, name: &str) -> Option<&ProgramInfo> {
        self.programs.iter().find(|p| p.name == name)
    }

    /// All registered program types.
    pub fn programs(&self) -> &[ProgramInfo] {
        &self.programs
    }
}
