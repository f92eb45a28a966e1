//! Executing an NC program in the fast class (docs/nc.md, Running): the [`Executor`] walks the
//! planned trajectory once per cycle — feed hold and resume, the feed and rapid overrides as the
//! rate at which it walks (above 100 % up to the profile planned for the highest override), single
//! block as a stand at the end of each line, M0 as a pause at its block, M3/M4/M5 as the
//! spindle's state — and the [`NcChannel`] is its process-image side: the main program's command
//! and the operator's overrides and single block in, the joints'
//! set-points out to the drive program, the executing line, the commanded pose, the spindle
//! outputs, and the run's measured contour and following errors for the summary.
//!
//! The main program decides (AUTO entered, start, hold, resume); the executor only follows its
//! command. It allocates nothing and reads no clock: time is the cycle's.

use std::sync::Arc;

use pkm_api::image::{Declare, Input, Output};
use pkm_api::library::NcLibrary;
use pkm_api::program::Cycle;
use pkm_api::trajectory::{
    MAX_AXES, MAX_FEED_OVERRIDE, OVERRIDE_DEFAULT, Trajectory, TrajectoryEventKind, TrajectorySample,
};

use crate::automaton::MainState;

pub use pkm_api::trajectory::vars;

/// What the main program asks of the executor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Not in AUTO: the executor is idle, the next `Run` starts the program from its beginning.
    Off = 0,
    /// Run: start from idle, resume from a hold.
    Run = 1,
    /// Feed hold: brake along the path and stand; an M0 pause is left by a hold, then a run.
    Hold = 2,
}

impl Command {
    /// The command with this code (anything unknown is `Off`: stand still).
    pub fn from_code(code: i16) -> Command {
        match code {
            1 => Command::Run,
            2 => Command::Hold,
            _ => Command::Off,
        }
    }
}

/// Where the executor stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunState {
    /// No program running.
    Idle = 0,
    /// Walking the trajectory at the programmed rate.
    Running = 1,
    /// A feed hold: braking along the path.
    Holding = 2,
    /// Standing after a feed hold (or a paused M0 the main program took over).
    Held = 3,
    /// Standing at an M0 (or M1) until the main program holds and resumes.
    Paused = 4,
    /// At the program's end.
    Done = 5,
    /// Standing at the end of a line in single block, until the main program holds and
    /// resumes (as at an M0).
    BlockDone = 6,
    /// Standing at an M6 until the operator confirms the tool change (`TOOL_CHANGED`); a hold
    /// or resume does not leave it.
    ToolChange = 7,
}

impl RunState {
    /// Every state, in code order.
    pub const ALL: [RunState; 8] = [
        RunState::Idle,
        RunState::Running,
        RunState::Holding,
        RunState::Held,
        RunState::Paused,
        RunState::Done,
        RunState::BlockDone,
        RunState::ToolChange,
    ];

    /// The state with this code.
    pub fn from_code(code: i16) -> Option<RunState> {
        RunState::ALL.into_iter().find(|s| *s as i16 == code)
    }

    /// The name shown to users.
    pub fn name(self) -> &'static str {
        match self {
            RunState::Idle => "idle",
            RunState::Running => "running",
            RunState::Holding => "holding",
            RunState::Held => "held",
            RunState::Paused => "paused (M0)",
            RunState::Done => "done",
            RunState::BlockDone => "single block: line done",
            RunState::ToolChange => "tool change (M6)",
        }
    }
}

/// What the operator sets besides the command: the overrides and single block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Operator {
    /// The feed override: a fraction of the programmed feed, 0 … [`MAX_FEED_OVERRIDE`].
    pub feed: f64,
    /// The rapid override: a fraction of the rapids' speed, 0 … 1.
    pub rapid: f64,
    /// Stand at the end of every line.
    pub single_block: bool,
    /// The operator's confirmation of a manual tool change (a level; its rising edge
    /// confirms).
    pub tool_changed: bool,
}

impl Default for Operator {
    /// 100 % feed and rapids, no single block.
    fn default() -> Self {
        Operator {
            feed: 1.0,
            rapid: 1.0,
            single_block: false,
            tool_changed: false,
        }
    }
}

impl Operator {
    /// The overrides in percent (as `NC_FEED_OVERRIDE` and `NC_RAPID_OVERRIDE` hold them),
    /// clamped to 0 … 150 % and 0 … 100 %.
    pub fn from_percent(feed: i16, rapid: i16, single_block: bool) -> Operator {
        Operator {
            feed: (f64::from(feed) / 100.0).clamp(0.0, MAX_FEED_OVERRIDE),
            rapid: (f64::from(rapid) / 100.0).clamp(0.0, 1.0),
            single_block,
            tool_changed: false,
        }
    }
}

/// The trajectory walker.
pub struct Executor {
    trajectory: Arc<dyn Trajectory>,
    state: RunState,
    /// Where on the planned time line (s).
    t: f64,
    /// How fast the time line is walked (0 … 1, up to the fast profile's speed over the planned
    /// one under a feed override above 100 %): a feed hold brings it to 0.
    rate: f64,
    /// In single block: the end of a line it brakes to and stands at (distance along the path,
    /// planned time), and the lowest tangential acceleration bound met on the way there (mm/s²).
    block_stop: Option<(f64, f64)>,
    braking_accel: f64,
    /// The plan comes to rest at that end by itself.
    plan_stops: bool,
    cursor: usize,
    ahead: usize,
    next_event: usize,
    spindle: i8,
    rpm: f64,
    /// The coolant (M7, M8; M9 off): mist, flood.
    coolant: (bool, bool),
    /// The executing line, kept at an event's.
    line: u32,
    /// Standing at an M0 (paused, or held after it) or an M6: its line is the one executing.
    at_pause: bool,
    /// The tool the M6 it stands at asks for.
    tool_asked: u32,
    /// A tool change confirmed and not yet taken by [`Executor::confirmed_tool`].
    tool_confirmed: Option<u32>,
    /// The tool-change confirmation's level last cycle.
    tool_changed_was: bool,
    /// How many of the program's messages this run has reached.
    messages: u32,
    /// A sampled pose had no joints: standing at the last one that had.
    fault: bool,
    current: TrajectorySample,
    /// The time `current` was sampled at.
    current_t: f64,
    velocities: [f64; MAX_AXES],
    /// The sample taken for the velocities last cycle (its time, the sample, its cursor): the
    /// next cycle's set-point, so it is not computed twice.
    next: Option<(f64, TrajectorySample, usize)>,
}

impl Executor {
    /// An idle executor of `trajectory`, standing at its start.
    pub fn new(trajectory: Arc<dyn Trajectory>) -> Executor {
        let mut cursor = 0;
        let current = trajectory.sample(0.0, &mut cursor);
        Executor {
            trajectory,
            state: RunState::Idle,
            t: 0.0,
            rate: 0.0,
            block_stop: None,
            braking_accel: f64::INFINITY,
            plan_stops: false,
            cursor: 0,
            ahead: 0,
            next_event: 0,
            spindle: 0,
            rpm: 0.0,
            coolant: (false, false),
            line: current.line,
            at_pause: false,
            tool_asked: 0,
            tool_confirmed: None,
            tool_changed_was: false,
            messages: 0,
            fault: false,
            current,
            current_t: 0.0,
            velocities: [0.0; MAX_AXES],
            next: None,
        }
    }

    /// Its state.
    pub fn state(&self) -> RunState {
        self.state
    }

    /// Where on the planned time line it stands (s).
    pub fn time_s(&self) -> f64 {
        self.t
    }

    /// The trajectory where it stands.
    pub fn sample(&self) -> &TrajectorySample {
        &self.current
    }

    /// The joints' velocities (mm/s) towards where it stands next cycle.
    pub fn velocities(&self) -> &[f64; MAX_AXES] {
        &self.velocities
    }

    /// The executing line.
    pub fn line(&self) -> u32 {
        self.line
    }

    /// Whether a sampled pose had no joints (the executor stands at the last that had, until
    /// the next start).
    pub fn fault(&self) -> bool {
        self.fault
    }

    /// The spindle: direction (1, −1, 0) and speed (rpm).
    pub fn spindle(&self) -> (i8, f64) {
        (self.spindle, self.rpm)
    }

    /// The coolant as the program has it: mist (M7), flood (M8).
    pub fn coolant(&self) -> (bool, bool) {
        self.coolant
    }

    /// The tool the M6 it stands at asks for (in [`RunState::ToolChange`]).
    pub fn tool_asked(&self) -> Option<u32> {
        (self.state == RunState::ToolChange).then_some(self.tool_asked)
    }

    /// The tool of a change confirmed since the last call (then in the spindle).
    pub fn confirmed_tool(&mut self) -> Option<u32> {
        self.tool_confirmed.take()
    }

    /// How many of the program's messages this run has reached: the last one reached is
    /// [`Trajectory::messages`]`[n − 1]`.
    pub fn messages_reached(&self) -> u32 {
        self.messages
    }

    /// The trajectory.
    pub fn trajectory(&self) -> &Arc<dyn Trajectory> {
        &self.trajectory
    }

    /// One cycle of `dt` seconds under `command` and the operator's settings `operator`;
    /// `frozen` (the drives' interlock is engaged) stands still where it is. Afterwards
    /// [`Executor::sample`] is the set-point for this cycle and [`Executor::velocities`] the
    /// joints' velocities towards the next one.
    pub fn step(&mut self, command: Command, operator: Operator, dt: f64, frozen: bool) {
        let confirm = operator.tool_changed && !self.tool_changed_was;
        self.tool_changed_was = operator.tool_changed;
        if confirm && self.state == RunState::ToolChange {
            // The tool is in: on from the M6.
            self.state = RunState::Running;
            self.at_pause = false;
            self.next_event += 1;
            self.tool_confirmed = Some(self.tool_asked);
        }
        self.take(command);
        self.velocities = [0.0; MAX_AXES];
        if frozen || self.fault {
            self.rate = 0.0;
        }
        if self.fault {
            // Standing at the last pose that had joints.
            return;
        }
        // The sample is a function of the time alone: last cycle's look-ahead is this one's,
        // and an idle executor (every cycle of a run whose programs wait for a start) stands at
        // the time it last sampled.
        let sample = match self.next.take() {
            Some((t, sample, cursor)) if t == self.t => {
                self.cursor = cursor;
                sample
            }
            _ if self.state == RunState::Idle && self.current_t == self.t => self.current,
            _ => self.trajectory.sample(self.t, &mut self.cursor),
        };
        if sample.joints.iter().any(|q| !q.is_finite()) {
            self.fault = true;
            return;
        }
        self.current = sample;
        self.current_t = self.t;
        let duration = self.trajectory.duration_s();
        let moving = matches!(self.state, RunState::Running | RunState::Holding) && !frozen;
        if moving {
            self.happen_events();
        }
        if self.at_pause {
            // Standing at the M0: its line is the one executing.
            self.current.line = self.line;
        } else {
            self.line = self.current.line;
        }
        if matches!(self.state, RunState::Paused | RunState::ToolChange) {
            return;
        }
        if moving && self.t >= duration && self.next_event >= self.trajectory.events().len() {
            self.state = RunState::Done;
        }
        if !moving || self.state == RunState::Done || self.stands_at_block_end(operator, dt) {
            return;
        }
        let speed = self.current.speed;
        // The rate changes so that the speed along the path changes by at most the
        // trajectory's tangential acceleration bound: v·dr/dt ≤ a.
        let change = if speed > 1e-9 {
            self.current.accel * dt / speed
        } else {
            1.0
        };
        let before = self.rate;
        let Some(target) = self.new_rate(operator, speed, change, dt) else {
            return;
        };
        self.look_ahead(operator, dt, before, target, change);
    }

    /// Takes the main program's command: off, run (from the start, or on after a hold or a
    /// pause), hold.
    fn take(&mut self, command: Command) {
        match (command, self.state) {
            (Command::Off, _) => {
                self.state = RunState::Idle;
                self.spindle = 0;
                self.rpm = 0.0;
                self.coolant = (false, false);
            }
            (Command::Run, RunState::Idle) => {
                self.state = RunState::Running;
                self.at_pause = false;
                self.fault = false;
                self.t = 0.0;
                self.rate = 1.0;
                self.block_stop = None;
                self.cursor = 0;
                self.next_event = 0;
                self.messages = 0;
            }
            (Command::Run, RunState::Holding | RunState::Held) => {
                self.state = RunState::Running;
                if std::mem::take(&mut self.at_pause) {
                    // The M0 it stood at is done.
                    self.next_event += 1;
                }
                // A line's end it stood at is done: the next one is looked for.
                if self.block_stop.is_some_and(|(_, t)| self.t >= t) {
                    self.block_stop = None;
                }
            }
            (Command::Hold, RunState::Running) => self.state = RunState::Holding,
            (Command::Hold, RunState::Paused | RunState::BlockDone) => self.state = RunState::Held,
            _ => {}
        }
    }

    /// The events where the tool stands happen, in order, up to a pause (the tool is at rest at
    /// each).
    fn happen_events(&mut self) {
        let events = self.trajectory.events();
        while let Some(e) = events.get(self.next_event)
            && e.t <= self.t
        {
            match e.kind {
                TrajectoryEventKind::Spindle { direction, rpm } => {
                    self.spindle = direction;
                    self.rpm = if direction == 0 { 0.0 } else { rpm };
                    self.next_event += 1;
                }
                TrajectoryEventKind::Coolant { mist, flood } => {
                    self.coolant = (mist, flood);
                    self.next_event += 1;
                }
                TrajectoryEventKind::Message { index } => {
                    self.messages = index.saturating_add(1);
                    self.next_event += 1;
                }
                TrajectoryEventKind::Pause => {
                    self.line = e.line;
                    self.at_pause = true;
                    self.state = RunState::Paused;
                    self.rate = 0.0;
                    break;
                }
                TrajectoryEventKind::ToolChange { tool } => {
                    self.line = e.line;
                    self.at_pause = true;
                    self.tool_asked = tool;
                    self.state = RunState::ToolChange;
                    self.rate = 0.0;
                    break;
                }
            }
        }
    }

    /// Single block: whether the tool stands at the end of its line now (until the main program
    /// holds and resumes); else where it will stand, and how hard it may brake there.
    fn stands_at_block_end(&mut self, operator: Operator, dt: f64) -> bool {
        if !operator.single_block {
            self.block_stop = None;
        } else if self.state == RunState::Running {
            if self.block_stop.is_some_and(|(_, t)| self.t >= t) {
                // At the end of the line: stand until the main program holds and resumes.
                self.state = RunState::BlockDone;
                self.rate = 0.0;
                return true;
            }
            if self.block_stop.is_none() {
                self.block_stop = self.reachable_block_end();
                // The bound where it will stand (a corner's is often the lowest on the way).
                // Where the plan itself comes to rest there (within a cycle of its bound), it
                // brakes by itself: a second braking on top of its own would be harsher than
                // either.
                if let Some((_, t_stop)) = self.block_stop {
                    let mut cursor = self.cursor;
                    let there = self.trajectory.sample(t_stop, &mut cursor);
                    self.braking_accel = there.accel;
                    self.plan_stops = there.speed <= there.accel * dt;
                }
            }
            self.braking_accel = self.braking_accel.min(self.current.accel);
        }
        false
    }

    /// The rate for this cycle: towards zero in a hold (`None` once held), else towards the
    /// operator's override within the fast profile and the single block's braking; the rate
    /// aimed at.
    fn new_rate(&mut self, operator: Operator, speed: f64, change: f64, dt: f64) -> Option<f64> {
        let mut target = f64::INFINITY;
        if self.state == RunState::Holding {
            self.rate = (self.rate - change).max(0.0);
            if self.rate == 0.0 {
                self.state = RunState::Held;
                return None;
            }
        } else {
            target = target_rate(&self.current, operator);
            self.rate = if self.rate < target {
                (self.rate + change).min(target)
            } else {
                (self.rate - change).max(target)
            };
            // Never faster than the fast profile where it stands (where the override was
            // lowered, the tool brakes towards the new rate, within what it can brake from).
            self.rate = self.rate.min(envelope(&self.current));
            if let Some((s_stop, _)) = self.block_stop
                && speed > 1e-9
                && !self.plan_stops
            {
                self.rate = self.rate.min(self.braking_speed(s_stop - self.current.s, dt) / speed);
            }
        }
        Some(target)
    }

    /// The time the next cycle stands at, its sample looked up now (the next cycle's), and the
    /// joints' velocities towards it; above the planned profile the rate is kept where the step
    /// ends too.
    fn look_ahead(&mut self, operator: Operator, dt: f64, before: f64, target: f64, change: f64) {
        let mut next = self.next_time(dt);
        self.ahead = self.cursor;
        let mut ahead = self.trajectory.sample(next, &mut self.ahead);
        // Above the planned profile the rate is also kept where the step ends: where the fast
        // profile brakes, the rate of its start would carry the tool past what it can brake
        // from.
        if self.rate > 1.0 {
            let mut ceiling = envelope(&ahead);
            if before >= target {
                // Following the operator's profile down.
                ceiling = ceiling.min(target_rate(&ahead, operator).max(before - change));
            }
            if self.rate > ceiling {
                self.rate = ceiling.max(1.0);
                next = self.next_time(dt);
                self.ahead = self.cursor;
                ahead = self.trajectory.sample(next, &mut self.ahead);
            }
        }
        if ahead.joints.iter().any(|q| !q.is_finite()) {
            // The next pose has none: stand here (and fault at it next cycle).
            self.t = next;
            return;
        }
        self.next = Some((next, ahead, self.ahead));
        for (v, (q1, q0)) in self
            .velocities
            .iter_mut()
            .zip(ahead.joints.iter().zip(&self.current.joints))
        {
            *v = (q1 - q0) / dt;
        }
        self.t = next;
    }

    /// Where the next cycle stands at the rate: not past the program's end, the next pause,
    /// nor the end of the line single block stands at.
    fn next_time(&self, dt: f64) -> f64 {
        let events = self.trajectory.events();
        let mut next = (self.t + self.rate * dt).min(self.trajectory.duration_s());
        if let Some(pause) = events[self.next_event.min(events.len())..]
            .iter()
            .take_while(|e| e.t <= next)
            .find(|e| {
                matches!(
                    e.kind,
                    TrajectoryEventKind::Pause | TrajectoryEventKind::ToolChange { .. }
                )
            })
        {
            next = pause.t.max(self.t);
        }
        if let Some((s_stop, t_stop)) = self.block_stop {
            // Within one cycle of the bound of the end, the last step goes there (the braking
            // rate, measured against a plan that may brake too, would only approach it).
            let last = self.braking_accel * dt * dt;
            next = if s_stop - self.current.s <= last && self.rate > 0.0 {
                t_stop.max(self.t)
            } else {
                next.min(t_stop.max(self.t))
            };
        }
        next
    }

    /// The highest speed from which the tool, braking at the lowest bound met on the way to the
    /// line's end, comes to rest within `distance` (mm) in whole cycles of `dt`: v·dt + (v − a·dt)·dt + … ≤ distance.
    fn braking_speed(&self, distance: f64, dt: f64) -> f64 {
        let a = self.braking_accel;
        if !(a.is_finite() && a > 0.0) {
            return f64::INFINITY;
        }
        let step = a * dt;
        (step * (-0.5 + (0.25 + 2.0 * distance.max(0.0) / (step * dt)).sqrt())).max(0.0)
    }

    /// The first end of a line ahead that the tool can still stop at from its speed now.
    fn reachable_block_end(&self) -> Option<(f64, f64)> {
        let here = &self.current;
        let v = self.rate * here.speed;
        let needed = if here.accel > 0.0 {
            v * v / (2.0 * here.accel)
        } else {
            0.0
        };
        let mut end = self.trajectory.block_end(here.s);
        while let Some((s_end, _)) = end
            && s_end - here.s < needed
        {
            end = self.trajectory.block_end(s_end);
        }
        end
    }
}

/// The rate the operator's overrides ask for at `s`: the rapid override on a rapid; on a feed
/// move the feed override up to 100 %, and above it a blend of the planned profile and the fast
/// one in speed squared (each keeps the machine's limits, so their blend does).
fn target_rate(s: &TrajectorySample, operator: Operator) -> f64 {
    if s.rapid {
        return operator.rapid;
    }
    if operator.feed <= 1.0 {
        return operator.feed;
    }
    let share = (operator.feed - 1.0) / (MAX_FEED_OVERRIDE - 1.0);
    let fast = envelope(s);
    (1.0 + share * (fast * fast - 1.0)).sqrt()
}

/// The fastest rate at `s`: the fast profile's speed over the planned one (1 where the tool
/// stands on the plan, or on a rapid).
fn envelope(s: &TrajectorySample) -> f64 {
    if s.speed > 1e-9 && !s.rapid {
        (s.speed_max / s.speed).max(1.0)
    } else {
        1.0
    }
}

/// The trajectory of a run whose library has no program yet (only screen jobs to come): it
/// stands at the origin and is never started (nothing is loaded).
struct Nothing {
    dof: usize,
}

impl Trajectory for Nothing {
    fn dof(&self) -> usize {
        self.dof
    }
    fn duration_s(&self) -> f64 {
        0.0
    }
    fn length_mm(&self) -> f64 {
        0.0
    }
    fn sample(&self, _t: f64, _cursor: &mut usize) -> TrajectorySample {
        TrajectorySample::default()
    }
    fn events(&self) -> &[pkm_api::trajectory::TrajectoryEvent] {
        &[]
    }
    fn block_end(&self, _s: f64) -> Option<(f64, f64)> {
        None
    }
    fn forward(&self, _joints: &[f64], _hint: &[f64; MAX_AXES], _pose: &mut [f64; MAX_AXES]) -> bool {
        false
    }
    fn path_distance(&self, _pose: &[f64; MAX_AXES], _t: f64) -> f64 {
        0.0
    }
}

/// The process-image side of program execution, declared by a machine's drive program when a
/// program is loaded.
pub struct NcChannel {
    executor: Executor,
    /// The run's programs (kept here, so that swapping one in never frees one; the screen's
    /// jobs stay in the library until the run ends).
    library: NcLibrary,
    /// The number of the one the executor walks (1-based, as `NC_PROGRAM`).
    loaded: i16,
    program: Input<i16>,
    command: Input<i16>,
    feed_override: Input<i16>,
    rapid_override: Input<i16>,
    single_block: Input<bool>,
    /// The tool-change confirmations: the panel's and the screen's.
    tool_changed: [Input<bool>; 2],
    tool_change: Output<bool>,
    tool_prep: Output<i32>,
    tool_number: Output<i32>,
    message: Output<i32>,
    messages: Output<i32>,
    state: Output<i16>,
    line: Output<i32>,
    time: Output<f64>,
    pose: Vec<Output<f64>>,
    tool: Vec<Output<f64>>,
    spindle_on: Output<bool>,
    spindle_reverse: Output<bool>,
    spindle_rpm: Output<f64>,
    coolant_mist: Output<bool>,
    coolant_flood: Output<bool>,
    contour: Output<f64>,
    contour_max: Output<f64>,
    contour_rms: Output<f64>,
    following_max: Vec<Output<f64>>,
    run_s: Output<f64>,
    completed: Output<bool>,
    fault: Output<bool>,
    /// The measured tool pose of the last cycle (the forward kinematics' start).
    measured: [f64; MAX_AXES],
    squares: f64,
    samples: u64,
}

impl NcChannel {
    /// Declares the execution's variables for `library`'s programs (the first loaded; a library
    /// without programs waits for a screen job) on a machine of `coordinates` joints and pose
    /// coordinates (the first ones of x y z a b c).
    pub fn declare(library: &NcLibrary, coordinates: usize, decl: &mut Declare<'_>) -> NcChannel {
        let first = library.trajectory(1);
        let loaded = if first.is_some() { 1 } else { 0 };
        let first = first.unwrap_or_else(|| Arc::new(Nothing { dof: coordinates }));
        let n = first.dof();
        let executor = Executor::new(first);
        let measured = executor.sample().pose;
        NcChannel {
            executor,
            library: library.clone(),
            loaded,
            program: decl.read(vars::NC_PROGRAM),
            command: decl.read(vars::NC_COMMAND),
            feed_override: decl.read_optional_or(vars::NC_FEED_OVERRIDE, OVERRIDE_DEFAULT),
            rapid_override: decl.read_optional_or(vars::NC_RAPID_OVERRIDE, OVERRIDE_DEFAULT),
            single_block: decl.read_optional(vars::NC_SINGLE_BLOCK),
            tool_changed: [vars::TOOL_CHANGED, pkm_api::hmi::HMI_TOOL_CHANGED].map(|v| decl.read_optional(v)),
            tool_change: decl.write(vars::TOOL_CHANGE, false),
            tool_prep: decl.write(vars::TOOL_PREP_NUMBER, 0),
            tool_number: decl.write(vars::TOOL_NUMBER, 0),
            message: decl.write(vars::NC_MESSAGE, 0),
            messages: decl.write(vars::NC_MESSAGES, 0),
            state: decl.write(vars::NC_STATE, RunState::Idle as i16),
            line: decl.write(vars::NC_LINE, 0),
            time: decl.write(vars::NC_TIME_S, 0.0),
            pose: vars::NC_POSE[..coordinates.min(MAX_AXES)]
                .iter()
                .map(|v| decl.write(*v, 0.0))
                .collect(),
            tool: vars::NC_TOOL[..coordinates.min(MAX_AXES)]
                .iter()
                .map(|v| decl.write(*v, 0.0))
                .collect(),
            spindle_on: decl.write(vars::SPINDLE_ON, false),
            spindle_reverse: decl.write(vars::SPINDLE_REVERSE, false),
            spindle_rpm: decl.write(vars::SPINDLE_RPM, 0.0),
            coolant_mist: decl.write(vars::COOLANT_MIST, false),
            coolant_flood: decl.write(vars::COOLANT_FLOOD, false),
            contour: decl.write(vars::NC_CONTOUR_ERROR, 0.0),
            contour_max: decl.write(vars::NC_CONTOUR_MAX, 0.0),
            contour_rms: decl.write(vars::NC_CONTOUR_RMS, 0.0),
            following_max: vars::NC_FOLLOWING_MAX[..n.min(MAX_AXES)]
                .iter()
                .map(|v| decl.write(*v, 0.0))
                .collect(),
            run_s: decl.write(vars::NC_RUN_S, 0.0),
            completed: decl.write(vars::NC_COMPLETED, false),
            fault: decl.write(vars::NC_FAULT, false),
            measured,
            squares: 0.0,
            samples: 0,
        }
    }

    /// A new run, or another program loaded: the run's measurements start afresh.
    fn new_run(&mut self, ctx: &mut Cycle<'_>) {
        self.squares = 0.0;
        self.samples = 0;
        self.measured = self.executor.sample().pose;
        ctx.set(self.contour, 0.0);
        ctx.set(self.contour_max, 0.0);
        ctx.set(self.contour_rms, 0.0);
        ctx.set(self.run_s, 0.0);
        ctx.set(self.completed, false);
        for f in &self.following_max {
            ctx.set(*f, 0.0);
        }
    }

    /// The tool change's and the messages' outputs after a step; `reached`: the messages the
    /// run had reached before it.
    fn tool_outputs(&mut self, ctx: &mut Cycle<'_>, reached: u32) {
        let asked = self.executor.tool_asked();
        ctx.set(self.tool_change, asked.is_some());
        if let Some(tool) = asked {
            ctx.set(self.tool_prep, i32::try_from(tool).unwrap_or(i32::MAX));
        }
        if let Some(tool) = self.executor.confirmed_tool() {
            ctx.set(self.tool_number, i32::try_from(tool).unwrap_or(i32::MAX));
        }
        let now = self.executor.messages_reached();
        ctx.set(self.message, i32::try_from(now).unwrap_or(i32::MAX));
        if now > reached {
            let new = i32::try_from(now - reached).unwrap_or(i32::MAX);
            ctx.set(self.messages, ctx.output_value(self.messages).saturating_add(new));
        }
    }

    /// One fast cycle: `auto` (the main state is AUTO), `interlock` (the drives are being
    /// stopped), the joints' measured `positions`. Returns the joints' set-points and
    /// velocities while the program drives them (in AUTO).
    pub fn step(
        &mut self,
        ctx: &mut Cycle<'_>,
        auto: bool,
        interlock: bool,
        positions: &[f64],
    ) -> Option<([f64; MAX_AXES], [f64; MAX_AXES])> {
        let dt = ctx.period_ns() as f64 * 1e-9;
        // The program the main program loaded, taken while the executor stands idle (the main
        // program changes it only outside AUTO; the library keeps its programs alive, and a
        // screen job's plan is freed off the cyclic path once nothing holds it, so the swap
        // frees nothing in the cycle).
        let k = ctx.get(self.program);
        if k != self.loaded
            && self.executor.state() == RunState::Idle
            && let Some(trajectory) = self.library.trajectory(k)
        {
            self.executor = Executor::new(trajectory);
            self.loaded = k;
            // The figures of the last run were another program's.
            self.new_run(ctx);
        }
        let command = if auto {
            Command::from_code(ctx.get(self.command))
        } else {
            Command::Off
        };
        let operator = Operator {
            tool_changed: self.tool_changed.iter().any(|i| ctx.get(*i)),
            ..Operator::from_percent(
                ctx.get(self.feed_override),
                ctx.get(self.rapid_override),
                ctx.get(self.single_block),
            )
        };
        let before = self.executor.state();
        let reached = self.executor.messages_reached();
        self.executor.step(command, operator, dt, interlock);
        let state = self.executor.state();
        self.tool_outputs(ctx, reached);
        if before == RunState::Idle && state != RunState::Idle {
            self.new_run(ctx);
        }
        ctx.set(self.state, state as i16);
        ctx.set(self.fault, self.executor.fault());
        if state == RunState::Done {
            ctx.set(self.completed, true);
        }
        let sample = *self.executor.sample();
        ctx.set(self.line, i32::try_from(self.executor.line()).unwrap_or(i32::MAX));
        ctx.set(self.time, self.executor.time_s());
        for (out, value) in self.pose.iter().zip(&sample.pose) {
            ctx.set(*out, *value);
        }
        let (direction, rpm) = self.executor.spindle();
        // The spindle stops with the drives.
        let turning = auto && direction != 0 && !interlock;
        ctx.set(self.spindle_on, turning);
        ctx.set(self.spindle_reverse, turning && direction < 0);
        ctx.set(self.spindle_rpm, if turning { rpm } else { 0.0 });
        // The coolant too: on only while the program runs and the drives may move.
        let (mist, flood) = self.executor.coolant();
        let flows = auto && !interlock;
        ctx.set(self.coolant_mist, flows && mist);
        ctx.set(self.coolant_flood, flows && flood);
        if !auto || state == RunState::Idle {
            return None;
        }
        if state != RunState::Done {
            // The run's measurements: the measured tool point against the programmed path,
            // each joint against its set-point.
            ctx.set(self.run_s, ctx.output_value(self.run_s) + dt);
            let trajectory = self.executor.trajectory();
            let mut pose = [0.0; MAX_AXES];
            if trajectory.forward(positions, &self.measured, &mut pose) {
                self.measured = pose;
                for (out, value) in self.tool.iter().zip(&pose) {
                    ctx.set(*out, *value);
                }
            }
            // The contour is kept on feed moves; a rapid has none to keep.
            if !sample.rapid {
                let error = trajectory.path_distance(&self.measured, self.executor.time_s());
                self.squares += error * error;
                self.samples += 1;
                ctx.set(self.contour, error);
                if error > ctx.output_value(self.contour_max) {
                    ctx.set(self.contour_max, error);
                }
                ctx.set(self.contour_rms, (self.squares / self.samples as f64).sqrt());
            }
            for ((out, q), s) in self.following_max.iter().zip(positions).zip(&sample.joints) {
                let e = (q - s).abs();
                if e > ctx.output_value(*out) {
                    ctx.set(*out, e);
                }
            }
        }
        Some((sample.joints, *self.executor.velocities()))
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use pkm_api::trajectory::TrajectoryEvent;

    /// One axis: two moves of 10 mm at 10 mm/s, accelerating and braking at 50 mm/s², with a
    /// stop between them at t = 1.2 s (where an M0 stands) and M3 at the start, M5 at the end.
    struct TwoMoves {
        events: Vec<TrajectoryEvent>,
        /// From this time on the poses have no joints (a trajectory its check let through).
        hole_from_s: f64,
    }

    const V: f64 = 10.0;
    const A: f64 = 50.0;
    /// One move: 0.2 s up to speed (1 mm), 0.8 s at speed (8 mm), 0.2 s down (1 mm).
    const MOVE_S: f64 = 1.2;

    impl TwoMoves {
        fn new(pause: bool) -> TwoMoves {
            let mut events = vec![TrajectoryEvent {
                t: 0.0,
                line: 1,
                kind: TrajectoryEventKind::Spindle {
                    direction: 1,
                    rpm: 1000.0,
                },
            }];
            if pause {
                events.push(TrajectoryEvent {
                    t: MOVE_S,
                    line: 3,
                    kind: TrajectoryEventKind::Pause,
                });
            }
            events.push(TrajectoryEvent {
                t: 2.0 * MOVE_S,
                line: 5,
                kind: TrajectoryEventKind::Spindle { direction: 0, rpm: 0.0 },
            });
            TwoMoves {
                events,
                hole_from_s: f64::INFINITY,
            }
        }

        /// Position and speed within one move at `t`.
        fn within(t: f64) -> (f64, f64) {
            let ramp = V / A;
            if t < ramp {
                (0.5 * A * t * t, A * t)
            } else if t < MOVE_S - ramp {
                (0.5 * A * ramp * ramp + V * (t - ramp), V)
            } else {
                let left = (MOVE_S - t).max(0.0);
                (10.0 - 0.5 * A * left * left, A * left)
            }
        }
    }

    impl Trajectory for TwoMoves {
        fn dof(&self) -> usize {
            1
        }
        fn duration_s(&self) -> f64 {
            2.0 * MOVE_S
        }
        fn length_mm(&self) -> f64 {
            20.0
        }
        fn sample(&self, t: f64, _cursor: &mut usize) -> TrajectorySample {
            let t = t.clamp(0.0, 2.0 * MOVE_S);
            let (second, local) = if t < MOVE_S { (false, t) } else { (true, t - MOVE_S) };
            let (x, v) = Self::within(local);
            let x = x + if second { 10.0 } else { 0.0 };
            let mut s = TrajectorySample {
                line: if second { 4 } else { 2 },
                s: x,
                speed: v,
                speed_max: v,
                accel: A,
                ..TrajectorySample::default()
            };
            s.pose[0] = x;
            s.joints[0] = if t >= self.hole_from_s { f64::NAN } else { x };
            s
        }
        fn events(&self) -> &[TrajectoryEvent] {
            &self.events
        }
        fn block_end(&self, s: f64) -> Option<(f64, f64)> {
            (s < 10.0).then_some((10.0, MOVE_S))
        }
        fn forward(&self, joints: &[f64], _hint: &[f64; MAX_AXES], pose: &mut [f64; MAX_AXES]) -> bool {
            pose[0] = joints[0];
            true
        }
        fn path_distance(&self, _pose: &[f64; MAX_AXES], _t: f64) -> f64 {
            0.0
        }
    }

    const DT: f64 = 0.01;

    fn executor(pause: bool) -> Executor {
        Executor::new(Arc::new(TwoMoves::new(pause)))
    }

    /// [`TwoMoves`] with a tool change (tool 7) and two messages where the M0 would stand.
    fn with_tool_change() -> Executor {
        let mut t = TwoMoves::new(false);
        let at = |kind| TrajectoryEvent {
            t: MOVE_S,
            line: 3,
            kind,
        };
        t.events.insert(1, at(TrajectoryEventKind::Message { index: 0 }));
        t.events.insert(2, at(TrajectoryEventKind::ToolChange { tool: 7 }));
        t.events.insert(3, at(TrajectoryEventKind::Message { index: 1 }));
        Executor::new(Arc::new(t))
    }

    /// Steps under `command` until `until` holds or `max` cycles; the positions seen.
    fn walk(e: &mut Executor, command: Command, max: usize, until: impl Fn(&Executor) -> bool) -> Vec<f64> {
        let mut seen = Vec::new();
        for _ in 0..max {
            e.step(command, Operator::default(), DT, false);
            seen.push(e.sample().joints[0]);
            if until(e) {
                break;
            }
        }
        seen
    }

    #[test]
    fn another_program_is_loaded_outside_auto_only_and_waits_for_a_start() {
        use pkm_api::trajectory::NcJob;
        let job = |file: &str| NcJob {
            file: file.into(),
            text: String::new(),
            trajectory: Arc::new(TwoMoves::new(false)),
        };
        let library = NcLibrary::new(vec![job("a.ngc"), job("b.ngc")], true);
        let mut control = ProgramControl::of(Some(&library));
        assert_eq!(control.number(), 1);
        assert!(control.trajectory().is_some());
        // Unknown numbers and the loaded one change nothing; in AUTO nothing is loaded.
        for (request, auto) in [(0, false), (3, false), (-1, false), (1, false), (2, true)] {
            assert!(!control.select(request, auto), "{request} {auto}");
        }
        assert_eq!(control.number(), 1);
        assert!(control.select(2, false));
        assert_eq!(control.number(), 2);
        // A program loaded from the screen does not start by itself at READY.
        assert!(!control.start(true));
        control.buttons([true, false, false]);
        assert!(control.start(true), "NC_START starts it");
        // Without programs nothing is loaded.
        assert!(ProgramControl::of(None).trajectory().is_none());
        let empty = NcLibrary::new(Vec::new(), false);
        let control = ProgramControl::of(Some(&empty));
        assert_eq!((control.number(), control.trajectory().is_some()), (0, false));
    }

    #[test]
    fn a_tool_change_stands_until_the_operator_confirms_and_holds_do_not_leave_it() {
        let mut e = with_tool_change();
        walk(&mut e, Command::Run, 300, |e| e.state() == RunState::ToolChange);
        assert_eq!(e.state(), RunState::ToolChange);
        assert_eq!((e.tool_asked(), e.sample().joints[0], e.line()), (Some(7), 10.0, 3));
        assert_eq!(
            e.messages_reached(),
            1,
            "the message before the change, not the one after"
        );
        // Neither a run, a hold, nor a hold and run leave it.
        for command in [Command::Run, Command::Hold, Command::Run] {
            e.step(command, Operator::default(), DT, false);
            assert_eq!(e.state(), RunState::ToolChange, "{command:?}");
        }
        let confirm = Operator {
            tool_changed: true,
            ..Operator::default()
        };
        e.step(Command::Run, confirm, DT, false);
        assert_eq!(
            (e.state(), e.confirmed_tool(), e.confirmed_tool()),
            (RunState::Running, Some(7), None)
        );
        assert_eq!(e.messages_reached(), 2);
        // A confirmation held on does not confirm the next change: only its rising edge does.
        let mut e = with_tool_change();
        walk(&mut e, Command::Run, 300, |e| e.state() == RunState::ToolChange);
        e.step(Command::Run, confirm, DT, false);
        assert_eq!(e.state(), RunState::Running);
        e.step(Command::Off, confirm, DT, false);
        e.step(Command::Run, confirm, DT, false);
        for _ in 0..300 {
            e.step(Command::Run, confirm, DT, false);
        }
        assert_eq!(e.state(), RunState::ToolChange, "a held confirmation is not a new one");
        assert_eq!(e.messages_reached(), 1, "a new run counts its messages afresh");
        // STOP (off) leaves the change idle.
        e.step(Command::Off, Operator::default(), DT, false);
        assert_eq!((e.state(), e.tool_asked()), (RunState::Idle, None));
    }

    #[test]
    fn a_run_walks_the_trajectory_to_its_end_with_the_velocities_of_its_steps() {
        let mut e = executor(false);
        assert_eq!(e.state(), RunState::Idle);
        let mut last: Option<(f64, f64)> = None;
        let mut cycles = 0;
        while e.state() != RunState::Done {
            e.step(Command::Run, Operator::default(), DT, false);
            let x = e.sample().joints[0];
            if let Some((x0, v0)) = last {
                assert!((x - (x0 + v0 * DT)).abs() < 1e-9, "the velocity led to this set-point");
            }
            last = Some((x, e.velocities()[0]));
            assert_eq!(
                e.spindle(),
                if e.state() == RunState::Done {
                    (0, 0.0)
                } else {
                    (1, 1000.0)
                }
            );
            cycles += 1;
            assert!(cycles < 1000);
        }
        // 2.4 s of 10 ms cycles, and the one that stands at the end (one more where the sum of
        // the steps falls short of 2.4 s by a rounding).
        assert!((241..=242).contains(&cycles), "{cycles} cycles");
        assert_eq!(e.sample().joints[0], 20.0);
        assert_eq!(e.line(), 4);
        e.step(Command::Off, Operator::default(), DT, false);
        assert_eq!(e.state(), RunState::Idle);
    }

    #[test]
    fn a_hold_brakes_within_the_acceleration_stands_and_resumes_where_it_stood() {
        let mut e = executor(false);
        walk(&mut e, Command::Run, 50, |_| false);
        let before = e.sample().joints[0];
        let mut positions = walk(&mut e, Command::Hold, 100, |e| e.state() == RunState::Held);
        assert_eq!(e.state(), RunState::Held);
        positions.insert(0, before);
        // Never faster than the plan, the speed changing by at most the acceleration bound.
        let speeds: Vec<f64> = positions.windows(2).map(|w| (w[1] - w[0]) / DT).collect();
        for w in speeds.windows(2) {
            assert!(w[1] <= w[0] + 1e-9, "braking only: {speeds:?}");
            assert!((w[0] - w[1]) <= A * DT * 1.01, "within {A} mm/s²: {speeds:?}");
        }
        assert!(speeds.len() < 30, "stopped from 10 mm/s in {} cycles", speeds.len());
        let stood = e.sample().joints[0];
        walk(&mut e, Command::Hold, 50, |_| false);
        assert_eq!(e.sample().joints[0], stood, "standing");
        assert_eq!(e.velocities()[0], 0.0);
        walk(&mut e, Command::Run, 1000, |e| e.state() == RunState::Done);
        assert_eq!(e.state(), RunState::Done);
        assert_eq!(e.sample().joints[0], 20.0);
    }

    #[test]
    fn an_m0_stands_until_a_hold_and_a_run_and_names_its_line() {
        let mut e = executor(true);
        walk(&mut e, Command::Run, 300, |e| e.state() == RunState::Paused);
        assert_eq!(e.state(), RunState::Paused);
        walk(&mut e, Command::Run, 50, |_| false);
        assert_eq!(e.state(), RunState::Paused, "a run alone does not leave the pause");
        assert_eq!(e.sample().joints[0], 10.0);
        assert_eq!((e.line(), e.sample().line), (3, 3));
        assert_eq!(e.spindle(), (1, 1000.0), "the spindle turns through the pause");
        e.step(Command::Hold, Operator::default(), DT, false);
        assert_eq!((e.state(), e.line()), (RunState::Held, 3));
        walk(&mut e, Command::Run, 1000, |e| e.state() == RunState::Done);
        assert_eq!(e.state(), RunState::Done);
        assert_eq!(e.line(), 4);
    }

    #[test]
    fn an_engaged_interlock_freezes_the_walk() {
        let mut e = executor(false);
        walk(&mut e, Command::Run, 30, |_| false);
        let at = e.time_s();
        for _ in 0..10 {
            e.step(Command::Run, Operator::default(), DT, true);
            assert_eq!(e.time_s(), at);
            assert_eq!(e.velocities()[0], 0.0);
        }
    }

    #[test]
    fn a_pose_without_joints_stands_the_executor_at_the_last_that_had_and_says_so() {
        let mut e = Executor::new(Arc::new(TwoMoves {
            hole_from_s: 0.5,
            ..TwoMoves::new(false)
        }));
        let seen = walk(&mut e, Command::Run, 200, |e| e.fault());
        assert!(e.fault(), "the hole was met");
        let stood = e.sample().joints[0];
        assert!(
            stood.is_finite() && stood == *seen.last().unwrap_or(&f64::NAN),
            "{stood}"
        );
        walk(&mut e, Command::Run, 20, |_| false);
        assert_eq!(e.sample().joints[0], stood, "standing");
        assert_eq!(e.velocities()[0], 0.0);
        // Off, then a new start: the fault is forgotten (and met again).
        e.step(Command::Off, Operator::default(), DT, false);
        e.step(Command::Run, Operator::default(), DT, false);
        assert!(!e.fault());
    }
}
