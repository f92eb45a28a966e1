//! The main program's side of program execution, the same on every machine: the program
//! buttons, the start, hold and resume, the command to the executor, the operator's notes, and
//! the error reason that names the program line.

use std::sync::Arc;

use pkm_api::library::NcLibrary;
use pkm_api::trajectory::Trajectory;

use super::{Command, RunState};
use crate::automaton::MainState;

/// The main program's side of program execution, the same on every machine: the program
/// buttons' presses, the start (by itself at the first READY after `run --program`, then by
/// NC_START, only where the program starts), feed hold and resume (an M0 taken over as a hold),
/// and the command to the executor.
#[derive(Clone, Debug, Default)]
pub struct ProgramControl {
    /// The buttons' levels last cycle: start, hold, resume.
    was: [bool; 3],
    /// This cycle's presses (rising edges): start, hold, resume.
    pressed: [bool; 3],
    /// The program stands: a feed hold, or an M0 taken over as one.
    held: bool,
    /// A resume pressed, taken once the program stands.
    resume_pending: bool,
    /// It stands at the end of a line in single block (not at a feed hold or an M0).
    block_done: bool,
    /// The last start was refused: the tool is not where the program starts.
    refused: bool,
    /// The next READY starts the program by itself.
    autostart: bool,
    /// The command to the executor.
    command: Option<Command>,
    /// The loaded program's number (1-based, as `NC_PROGRAM`; 0: none), its trajectory, and the
    /// run's programs.
    loaded: i16,
    trajectory: Option<Held>,
    library: Option<NcLibrary>,
}

/// A trajectory the main program holds while it is loaded (taken from the library when it is
/// loaded: a screen job's plan may leave the library once another program is loaded, and is
/// freed off the cyclic path once nothing holds it).
#[derive(Clone)]
struct Held(Arc<dyn Trajectory>);

impl std::fmt::Debug for Held {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Trajectory")
            .field("duration_s", &self.0.duration_s())
            .finish()
    }
}

/// The operator's notes about the program.
pub mod notes {
    /// A start refused in READY.
    pub const NOT_AT_START: &str = "program not started: the tool is not at the program's start, the reference pose (STOP, acknowledge and reference to return there)";
    /// Standing at the end of a line in single block.
    pub const BLOCK_DONE: &str = "single block: the line is done; NC_RESUME runs the next";
    /// Standing at an M66.
    pub const WAITING: &str = "M66: the program waits for its input (NC_DIN_n, as its line says), at most its timeout";
    /// Standing at a manual tool change.
    pub const TOOL_CHANGE: &str =
        "tool change (M6): put the tool TOOL_PREP_NUMBER names in the spindle, then confirm (TOOL_CHANGED)";
}

impl ProgramControl {
    /// The control of `library`'s programs, if the run has a library (the first program loaded;
    /// it starts by itself at the first READY after `run --program`); without, nothing ever
    /// starts.
    pub fn of(library: Option<&NcLibrary>) -> ProgramControl {
        match library {
            Some(l) => ProgramControl {
                autostart: l.autostart,
                command: Some(Command::Off),
                loaded: if l.jobs.is_empty() { 0 } else { 1 },
                trajectory: l.trajectory(1).map(Held),
                library: Some(l.clone()),
                ..ProgramControl::default()
            },
            None => ProgramControl::default(),
        }
    }

    /// Outside AUTO: loads program `request` (1-based: the library's, then the screen's jobs; 0
    /// or an unknown number: no request) in place of the loaded one. True when the loaded
    /// program changed; a program loaded this way starts by NC_START only.
    ///
    /// The trajectory it held for the program loaded before is let go here: never the last
    /// reference (the library keeps its programs; a screen job's plan is freed off the cyclic
    /// path), so that nothing is freed in the cycle.
    pub fn select(&mut self, request: i16, auto: bool) -> bool {
        if auto || request == self.loaded {
            return false;
        }
        let Some(trajectory) = self.library.as_ref().and_then(|l| l.trajectory(request)) else {
            return false;
        };
        self.loaded = request;
        self.trajectory = Some(Held(trajectory));
        self.autostart = false;
        self.refused = false;
        true
    }

    /// The loaded program's trajectory, if a program is loaded.
    pub fn trajectory(&self) -> Option<&Arc<dyn Trajectory>> {
        self.trajectory.as_ref().map(|h| &h.0)
    }

    /// The loaded program's number, as `NC_PROGRAM` holds it (1-based; 0: none).
    pub fn number(&self) -> i16 {
        self.loaded
    }

    /// Takes the program buttons' levels of this cycle (start, hold, resume).
    pub fn buttons(&mut self, levels: [bool; 3]) {
        self.pressed = std::array::from_fn(|i| levels[i] && !self.was[i]);
        self.was = levels;
    }

    /// In READY: whether the program starts now. `at_start`: the tool stands where the program
    /// starts.
    pub fn start(&mut self, at_start: bool) -> bool {
        if self.command.is_none() || !(self.pressed[0] || std::mem::take(&mut self.autostart)) {
            return false;
        }
        self.refused = !at_start;
        at_start
    }

    /// AUTO entered: the program runs.
    pub fn enter(&mut self) {
        self.held = false;
        self.resume_pending = false;
        self.command = Some(Command::Run);
    }

    /// One cycle of AUTO with the executor in `state`: false once the program has ended.
    pub fn auto(&mut self, state: Option<RunState>) -> bool {
        let [_, hold, resume] = self.pressed;
        if hold || matches!(state, Some(RunState::Paused | RunState::BlockDone)) {
            self.held = true;
            self.resume_pending = false;
            self.block_done = state == Some(RunState::BlockDone);
        }
        self.resume_pending |= resume && self.held;
        // A resume goes through once the executor stands held (an M0 becomes held one cycle
        // after this program holds it).
        if self.resume_pending && state == Some(RunState::Held) {
            self.held = false;
            self.resume_pending = false;
            self.block_done = false;
        }
        self.command = Some(if self.held { Command::Hold } else { Command::Run });
        state != Some(RunState::Done)
    }

    /// AUTO left (to READY or ERROR), or ERROR entered: the executor goes idle.
    pub fn leave(&mut self) {
        self.command = self.command.map(|_| Command::Off);
    }

    /// Something else happened in READY (a jog): a refused start is forgotten.
    pub fn forget_refusal(&mut self) {
        self.refused = false;
    }

    /// The command to the executor (`None`: no program loaded).
    pub fn command(&self) -> Option<Command> {
        self.command
    }

    /// The operator's note: in AUTO where the program stands (executor in `state`); in READY
    /// why a start was refused.
    pub fn note(&self, auto: bool, state: Option<RunState>) -> Option<&'static str> {
        if !auto {
            return self.refused.then_some(notes::NOT_AT_START);
        }
        Some(match state {
            Some(RunState::Holding) => "feed hold: braking on the path",
            Some(RunState::Held) if !self.resume_pending && self.held && self.block_done => notes::BLOCK_DONE,
            Some(RunState::Held) if !self.resume_pending && self.held => {
                "the program stands (feed hold or M0): NC_RESUME goes on"
            }
            Some(RunState::Paused) => "M0: the program stands; NC_RESUME goes on",
            Some(RunState::ToolChange) => notes::TOOL_CHANGE,
            Some(RunState::Waiting) => notes::WAITING,
            Some(RunState::BlockDone) => notes::BLOCK_DONE,
            Some(RunState::Done) => "program done",
            _ => "running the program",
        })
    }
}

/// An error reason with the program line that was executing (docs/nc.md: STOP and faults in
/// AUTO name the line), written into capacity reserved at creation: entering ERROR allocates
/// nothing.
#[derive(Clone, Debug)]
pub struct LineReason {
    with_line: Option<i32>,
    text: String,
}

impl Default for LineReason {
    fn default() -> Self {
        LineReason {
            with_line: None,
            text: String::with_capacity(Self::CAPACITY),
        }
    }
}

impl LineReason {
    /// Room for a reason with its line (bytes).
    const CAPACITY: usize = 512;

    /// After a cycle of the automaton that went from `before` to `after` (with `reason`, the
    /// reason's text, if it is in ERROR): takes the line `line` that was executing when ERROR
    /// was entered from AUTO.
    pub fn observe(&mut self, before: MainState, after: MainState, reason: Option<&str>, line: i32) {
        if let (MainState::Error, false, Some(reason)) = (after, before == MainState::Error, reason) {
            self.entered(before == MainState::Auto, reason, line);
        }
    }

    /// ERROR entered with the reason `reason` (from AUTO: `from_auto`); `line` was executing.
    fn entered(&mut self, from_auto: bool, reason: &str, line: i32) {
        use std::fmt::Write as _;
        self.with_line = from_auto.then_some(line);
        if from_auto {
            self.text.clear();
            let _ = write!(self.text, "{reason} (program line {line})");
        }
    }

    /// The reason to show: with its line where ERROR came from AUTO, else `plain`.
    pub fn text<'a>(&'a self, plain: &'a str) -> &'a str {
        if self.with_line.is_some() { &self.text } else { plain }
    }
}
