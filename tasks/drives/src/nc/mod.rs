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

use pkm_api::trajectory::{MAX_AXES, MAX_FEED_OVERRIDE, Trajectory, TrajectoryEventKind, TrajectorySample};

pub use pkm_api::trajectory::vars;

mod channel;
mod control;

pub use channel::NcChannel;
pub use control::{LineReason, ProgramControl, notes};

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
    /// Standing at an M66 until its input is as it asks, or its timeout has passed; a hold or
    /// resume does not leave it.
    Waiting = 8,
}

impl RunState {
    /// Every state, in code order.
    pub const ALL: [RunState; 9] = [
        RunState::Idle,
        RunState::Running,
        RunState::Holding,
        RunState::Held,
        RunState::Paused,
        RunState::Done,
        RunState::BlockDone,
        RunState::ToolChange,
        RunState::Waiting,
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
            RunState::Waiting => "waiting for an input (M66)",
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
    /// The operator's confirmation of the manual tool change that waits (a level; its rising
    /// edge confirms): the channel raises it only for a confirmation of that change.
    pub tool_changed: bool,
    /// The program's digital inputs (`NC_DIN_0` …), which M66 waits on.
    pub inputs: [bool; DIGITAL_INPUTS],
}

pub use pkm_api::trajectory::{ANALOG_OUTPUTS, DIGITAL_INPUTS, DIGITAL_OUTPUTS};

/// An M66 the executor stands at.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Wait {
    /// The input.
    index: usize,
    /// LinuxCNC's L: 0 no wait, 1 rises, 2 falls, 3 on, 4 off.
    mode: u8,
    /// The longest wait (s).
    timeout_s: f64,
    /// How long it has waited (s).
    waited_s: f64,
    /// The input's level last cycle (a rise or a fall is counted from the wait's start).
    was: Option<bool>,
}

impl Default for Operator {
    /// 100 % feed and rapids, no single block.
    fn default() -> Self {
        Operator {
            feed: 1.0,
            rapid: 1.0,
            single_block: false,
            tool_changed: false,
            inputs: [false; DIGITAL_INPUTS],
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
            inputs: [false; DIGITAL_INPUTS],
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
    /// Standing for a G4 until this time of the program (s): its line is the one executing.
    dwell_until: Option<f64>,
    /// The tool the M6 it stands at asks for.
    tool_asked: u32,
    /// A tool change confirmed and not yet taken by [`Executor::confirmed_tool`].
    tool_confirmed: Option<u32>,
    /// The tool-change confirmation's level last cycle.
    tool_changed_was: bool,
    /// How many of the program's messages this run has reached.
    messages: u32,
    /// The program coordinates the run has reached (system 1 … 6, offset); system 0 before.
    work: (u8, [f64; MAX_AXES]),
    /// The program's digital outputs as M62 … M65 set them (off at each run's start).
    digital: [bool; DIGITAL_OUTPUTS],
    /// The program's analog outputs as M67, M68 set them (0 at each run's start).
    analog: [f64; ANALOG_OUTPUTS],
    /// The M66 it stands at.
    wait: Option<Wait>,
    /// How many of this run's M66 gave up at their timeout.
    timeouts: u32,
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
            dwell_until: None,
            tool_asked: 0,
            tool_confirmed: None,
            tool_changed_was: false,
            messages: 0,
            work: (0, [0.0; MAX_AXES]),
            digital: [false; DIGITAL_OUTPUTS],
            analog: [0.0; ANALOG_OUTPUTS],
            wait: None,
            timeouts: 0,
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

    /// The speed along the path it commands now (mm/s, or degrees/s where only rotations
    /// move): the plan's where it stands times the rate it walks at; 0 standing.
    pub fn commanded_speed(&self) -> f64 {
        match self.state {
            RunState::Running | RunState::Holding => self.current.speed * self.rate,
            _ => 0.0,
        }
    }

    /// The distance along the path to the end of the executing line's motion (mm): where the
    /// next line's begins, or the program's end after the last line's motion began.
    pub fn distance_to_go(&self) -> f64 {
        let s = self.current.s;
        // Looked up from just before where it stands: at a line's end exactly, that line's end
        // (not the next line's).
        let end = self
            .trajectory
            .block_end((s - 1e-9).max(0.0))
            .map_or(self.trajectory.length_mm(), |(end, _)| end);
        (end - s).max(0.0)
    }

    /// The program coordinates the run has reached: the work system (1 … 6 for G54 … G59; 0
    /// before the first) and the offset of program coordinates from machine coordinates.
    pub fn work(&self) -> (u8, &[f64; MAX_AXES]) {
        (self.work.0, &self.work.1)
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
        if self.state == RunState::Waiting {
            self.wait_for(&operator.inputs, dt);
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
        if self.at_pause || self.dwell_until.is_some_and(|until| self.t < until) {
            // Standing at the M0, or for the G4: its line is the one executing.
            self.current.line = self.line;
        } else {
            self.dwell_until = None;
            self.line = self.current.line;
        }
        if matches!(self.state, RunState::Paused | RunState::ToolChange | RunState::Waiting) {
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
        // trajectory's tangential acceleration bound.
        let change = if speed > 1e-9 {
            Change::within(
                self.rate,
                speed,
                self.current.planned_accel * dt,
                self.current.accel * dt,
            )
        } else {
            Change { up: 1.0, down: 1.0 }
        };
        let before = self.rate;
        let Some(target) = self.new_rate(operator, speed, change, dt) else {
            return;
        };
        self.look_ahead(operator, dt, before, target, change.down);
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
                self.digital = [false; DIGITAL_OUTPUTS];
                self.analog = [0.0; ANALOG_OUTPUTS];
                self.wait = None;
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
                self.work = (0, [0.0; MAX_AXES]);
                self.digital = [false; DIGITAL_OUTPUTS];
                self.analog = [0.0; ANALOG_OUTPUTS];
                self.wait = None;
                self.timeouts = 0;
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

    /// Standing at an M66: on once its input is as it asks (a rise or a fall seen since the
    /// wait began, or the level), or once its timeout has passed (counted: the program goes on,
    /// as LinuxCNC's does).
    fn wait_for(&mut self, inputs: &[bool; DIGITAL_INPUTS], dt: f64) {
        let Some(wait) = &mut self.wait else {
            return;
        };
        let level = inputs.get(wait.index).copied().unwrap_or(false);
        let was = wait.was.replace(level);
        let met = match wait.mode {
            1 => was == Some(false) && level,
            2 => was == Some(true) && !level,
            3 => level,
            4 => !level,
            _ => true,
        };
        let timed_out = !met && wait.waited_s >= wait.timeout_s;
        wait.waited_s += dt;
        if met || timed_out {
            if timed_out {
                self.timeouts += 1;
            }
            self.wait = None;
            self.state = RunState::Running;
            self.at_pause = false;
            self.next_event += 1;
        }
    }

    /// The program's digital outputs (M62 … M65) and analog outputs (M67, M68) as the run has
    /// set them.
    pub fn outputs(&self) -> (&[bool; DIGITAL_OUTPUTS], &[f64; ANALOG_OUTPUTS]) {
        (&self.digital, &self.analog)
    }

    /// How many of this run's M66 gave up at their timeout.
    pub fn wait_timeouts(&self) -> u32 {
        self.timeouts
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
                TrajectoryEventKind::Dwell { seconds } => {
                    self.line = e.line;
                    self.dwell_until = Some(e.t + seconds);
                    self.next_event += 1;
                }
                TrajectoryEventKind::WorkOffset { system, offset } => {
                    self.work = (system, offset);
                    self.next_event += 1;
                }
                TrajectoryEventKind::DigitalOutput { index, on } => {
                    if let Some(out) = self.digital.get_mut(usize::from(index)) {
                        *out = on;
                    }
                    self.next_event += 1;
                }
                TrajectoryEventKind::AnalogOutput { index, value } => {
                    if let Some(out) = self.analog.get_mut(usize::from(index)) {
                        *out = value;
                    }
                    self.next_event += 1;
                }
                TrajectoryEventKind::WaitInput { index, mode, timeout_s } => {
                    self.line = e.line;
                    self.at_pause = true;
                    self.wait = Some(Wait {
                        index: usize::from(index),
                        mode,
                        timeout_s,
                        waited_s: 0.0,
                        was: None,
                    });
                    self.state = RunState::Waiting;
                    self.rate = 0.0;
                    break;
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
    fn new_rate(&mut self, operator: Operator, speed: f64, change: Change, dt: f64) -> Option<f64> {
        let mut target = f64::INFINITY;
        if self.state == RunState::Holding {
            self.rate = (self.rate - change.down).max(0.0);
            if self.rate == 0.0 {
                self.state = RunState::Held;
                return None;
            }
        } else {
            target = target_rate(&self.current, operator);
            self.rate = if self.rate < target {
                (self.rate + change.up).min(target)
            } else {
                (self.rate - change.down).max(target)
            };
            // Never faster than the fast profile where it stands (where the override was
            // lowered, the tool brakes towards the new rate, within what it can brake from).
            self.rate = self.rate.min(envelope(&self.current));
            if let Some((s_stop, _)) = self.block_stop
                && speed > 1e-9
                && !self.plan_stops
            {
                let step = self.braking_speed(s_stop - self.current.s, dt) * dt;
                if step < self.rate * speed * dt {
                    self.rate = self.rate_covering(step, dt);
                }
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
                    TrajectoryEventKind::Pause
                        | TrajectoryEventKind::ToolChange { .. }
                        | TrajectoryEventKind::WaitInput { .. }
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
    /// line's end, comes to rest exactly `distance` (mm) ahead in whole cycles of `dt`: n cycles
    /// at v, v − a·dt, …, v − (n−1)·a·dt that cover the distance, the last at most a·dt, so that
    /// the tool stands the cycle after. (The continuous v² = 2·a·d, taken cycle by cycle, leaves
    /// a last step up to 1.125 a·dt harsher than the bound where the distance is not a sum of
    /// whole decrements.)
    fn braking_speed(&self, distance: f64, dt: f64) -> f64 {
        let a = self.braking_accel;
        if !(a.is_finite() && a > 0.0) {
            return f64::INFINITY;
        }
        let step = a * dt;
        // The distance in units of one step's travel: d / (a·dt²).
        let d = distance.max(0.0) / (step * dt);
        if d <= 0.0 {
            return 0.0;
        }
        // The fewest cycles: n (n + 1) / 2 ≥ d.
        let n = (-0.5 + (0.25 + 2.0 * d).sqrt()).ceil().max(1.0);
        step * (d / n + (n - 1.0) / 2.0)
    }

    /// The rate (at most the rate now) at which this cycle's step covers `step` (mm) of the path.
    /// The plan's own speed changes within the step: where it brakes too, the rate from its
    /// speed where the step begins covers less than `step`, and the next cycle catches up
    /// (seen: a joint at 125 % of its acceleration for a cycle where a single block's braking met
    /// the plan's own braking before a corner). A few Newton steps on the distance the plan's
    /// time line covers (its derivative: the plan's speed where the step ends).
    fn rate_covering(&self, step: f64, dt: f64) -> f64 {
        let (high, here) = (self.rate, self.current.s);
        let mut rate = (step / (self.current.speed * dt)).min(high);
        for _ in 0..4 {
            // From where the tool stands each time: a cursor behind the time looks forward
            // from there, one past it would search from the plan's start.
            let mut cursor = self.cursor;
            let end = self.trajectory.sample(self.t + rate * dt, &mut cursor);
            let miss = end.s - here - step;
            if miss.abs() <= 1e-9 || end.speed <= 1e-9 {
                break;
            }
            rate = (rate - miss / (end.speed * dt)).clamp(0.0, high);
        }
        rate
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

/// How much the rate may rise and fall in one cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Change {
    up: f64,
    down: f64,
}

impl Change {
    /// The change of the rate from `r` that changes the tool's speed by at most `a_dt` (mm/s)
    /// in a cycle, where the plan's speed is `v` (mm/s) and changes by `c` (mm/s) in a cycle of
    /// its own time. The tool's speed is r·v; a cycle later, at the rate x, it is x·v plus what
    /// the plan's own change gives in x of a cycle, x·(x·c): it changes by v·(x − r) + c·x².
    /// (Taken without the plan's change, a resume that catches up with a plan speeding up at its
    /// bound asks for up to twice the bound.) Where the plan's change works against the rate's,
    /// c·x² is taken at r, where it is larger: the bound holds with room.
    fn within(r: f64, v: f64, c: f64, a_dt: f64) -> Change {
        // The rate x > 0 at which v·x + c·x² = u, for c > 0 (the larger root), written
        // 2u / (v + √(v² + 4cu)): the same as (−v + √(v² + 4cu)) / 2c, without its cancellation,
        // which for a plan's change tiny beside its speed (c = 2.3e-8, v = 203 mm/s) gave a rate
        // 0.08 % too large, past the bound.
        // (v = u = 0: no rate change, not 0/0.)
        let root = |u: f64| {
            let d = v + (v * v + 4.0 * c * u).max(0.0).sqrt();
            if d > 0.0 { 2.0 * u / d } else { 0.0 }
        };
        let up = if c > 0.0 {
            root(v * r + a_dt) - r
        } else {
            (a_dt - c * r * r) / v
        };
        let down = if c >= 0.0 && v * r > a_dt {
            r - if c > 0.0 { root(v * r - a_dt) } else { r - a_dt / v }
        } else if c >= 0.0 {
            // Slow enough to stand within the cycle.
            r
        } else {
            (a_dt + c * r * r) / v
        };
        Change {
            up: up.max(0.0),
            down: down.max(0.0),
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use pkm_api::library::NcLibrary;
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

        /// Position, speed and its change within one move at `t`.
        fn within(t: f64) -> (f64, f64, f64) {
            let ramp = V / A;
            if t < ramp {
                (0.5 * A * t * t, A * t, A)
            } else if t < MOVE_S - ramp {
                (0.5 * A * ramp * ramp + V * (t - ramp), V, 0.0)
            } else {
                let left = (MOVE_S - t).max(0.0);
                (10.0 - 0.5 * A * left * left, A * left, -A)
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
            let (x, v, planned_accel) = Self::within(local);
            let x = x + if second { 10.0 } else { 0.0 };
            let mut s = TrajectorySample {
                line: if second { 4 } else { 2 },
                s: x,
                speed: v,
                speed_max: v,
                accel: A,
                planned_accel,
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

    /// A G4 of line 3 where the first move ends: its line is the one executing while the tool
    /// stands for it (it was the move's before), and the next move's once it has passed.
    #[test]
    fn a_dwells_line_is_shown_while_the_tool_dwells() {
        let mut t = TwoMoves::new(false);
        t.events.insert(
            1,
            TrajectoryEvent {
                t: MOVE_S,
                line: 3,
                kind: TrajectoryEventKind::Dwell { seconds: 0.3 },
            },
        );
        let mut e = Executor::new(Arc::new(t));
        walk(&mut e, Command::Run, 1000, |e| e.time_s() >= 1.0);
        assert_eq!(e.line(), 2);
        walk(&mut e, Command::Run, 1000, |e| e.time_s() >= MOVE_S + 0.05);
        assert_eq!((e.line(), e.sample().line), (3, 3));
        walk(&mut e, Command::Run, 1000, |e| e.time_s() >= MOVE_S + 0.35);
        assert_eq!(e.line(), 4);
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

    /// The tool's speed (mm/s) a cycle after the rate becomes `x`, on a plan whose speed is `v`
    /// and changes by `c` in a cycle of its own time: the plan runs x of a cycle, so its speed
    /// is then v + c·x, and the tool moves at x times that.
    fn speed_after(x: f64, v: f64, c: f64) -> f64 {
        x * (v + c * x)
    }

    proptest::proptest! {
        /// Whatever the plan's own acceleration (within the bound, as the planner keeps it), the
        /// largest change `Change::within` allows in either direction from a rate up to 1
        /// changes the tool's speed by at most the bound in a cycle; and where the plan does not
        /// work against it, by the bound exactly (no speed is given away).
        #[test]
        fn a_rate_change_keeps_the_tool_within_its_acceleration(
            r in 0.0f64..1.0,
            v in 0.1f64..300.0,
            share in -1.0f64..1.0,
            a_dt in 0.01f64..2.0,
        ) {
            let c = share * a_dt;
            let change = Change::within(r, v, c, a_dt);
            // Now the tool moves at r times the plan's speed.
            let now = r * v;
            let up = speed_after(r + change.up, v, c) - now;
            // (The executor's rate stops at standing.)
            let down = speed_after((r - change.down).max(0.0), v, c) - now;
            let slack = 1e-9 * (1.0 + now.abs());
            proptest::prop_assert!(up <= a_dt + slack, "up {} by {up} over {a_dt}", change.up);
            proptest::prop_assert!(down >= -a_dt - slack, "down {} by {down} over {a_dt}", change.down);
            if c >= 0.0 {
                proptest::prop_assert!((up - a_dt).abs() <= 1e-6 * (1.0 + a_dt), "up only {up} of {a_dt}");
            }
            if c >= 0.0 && now > a_dt {
                proptest::prop_assert!((down + a_dt).abs() <= 1e-6 * (1.0 + a_dt), "down only {down} of {a_dt}");
            }
        }
    }

    /// [`TwoMoves`] with, between the moves, digital output 1 on with the second move's start,
    /// analog output 0 to 2.5, and an M66 on input 2 in `mode` (LinuxCNC's L) for at most 0.5 s.
    fn with_io(mode: u8) -> Executor {
        let mut t = TwoMoves::new(false);
        let at = |kind| TrajectoryEvent {
            t: MOVE_S,
            line: 3,
            kind,
        };
        t.events
            .insert(1, at(TrajectoryEventKind::AnalogOutput { index: 0, value: 2.5 }));
        t.events.insert(
            2,
            at(TrajectoryEventKind::WaitInput {
                index: 2,
                mode,
                timeout_s: 0.5,
            }),
        );
        t.events
            .insert(3, at(TrajectoryEventKind::DigitalOutput { index: 1, on: true }));
        Executor::new(Arc::new(t))
    }

    /// Steps with input 2 at `input(cycle)` until the second move begins or 300 cycles: the
    /// cycles it stood waiting at the M66, and the outputs when it stood there first.
    /// The program's outputs: digital, analog.
    type Outputs = ([bool; DIGITAL_OUTPUTS], [f64; ANALOG_OUTPUTS]);

    fn stand_at_m66(e: &mut Executor, input: impl Fn(usize) -> bool) -> (usize, Option<Outputs>) {
        let (mut waited, mut seen) = (0, None);
        for cycle in 0..300 {
            let mut operator = Operator::default();
            operator.inputs[2] = input(cycle);
            e.step(Command::Run, operator, DT, false);
            if e.state() == RunState::Waiting {
                waited += 1;
                let (d, a) = e.outputs();
                seen.get_or_insert((*d, *a));
            }
            if e.sample().joints[0] > 10.5 {
                break;
            }
        }
        (waited, seen)
    }

    #[test]
    fn m66_waits_for_its_input_or_its_timeout_and_outputs_follow_the_program() {
        // L3 (on), the input never on: it gives up after its 0.5 s timeout (50 cycles) and the
        // program goes on. The analog output is set before the wait, the digital one only with
        // the next move.
        let mut e = with_io(3);
        let (waited, seen) = stand_at_m66(&mut e, |_| false);
        assert!((50..=52).contains(&waited), "{waited} cycles");
        assert_eq!(seen, Some(([false; 4], [2.5, 0.0])));
        assert_eq!(e.wait_timeouts(), 1);
        assert_eq!(e.outputs().0, &[false, true, false, false], "M62 with the second move");
        // On from the start of the wait: no wait beyond its cycle.
        let mut e = with_io(3);
        let (waited, _) = stand_at_m66(&mut e, |_| true);
        assert!(waited <= 1, "{waited}");
        assert_eq!(e.wait_timeouts(), 0);
        // L1 (rises): an input already on does not count; its rise 20 cycles later does.
        let mut e = with_io(1);
        let (waited, _) = stand_at_m66(&mut e, |_| true);
        assert!(
            (50..=52).contains(&waited),
            "an input on all along never rises: {waited}"
        );
        let mut e = with_io(1);
        let (mut waited, mut started) = (0, None::<usize>);
        for cycle in 0..300 {
            let mut operator = Operator::default();
            if e.state() == RunState::Waiting {
                started.get_or_insert(cycle);
            }
            operator.inputs[2] = started.is_some_and(|s| cycle >= s + 20);
            e.step(Command::Run, operator, DT, false);
            if e.state() == RunState::Waiting {
                waited += 1;
            }
            if e.sample().joints[0] > 10.5 {
                break;
            }
        }
        assert!((20..=22).contains(&waited), "{waited}");
        assert_eq!(e.wait_timeouts(), 0);
        // Off: the outputs are off again (the channel keeps them off outside a run too).
        e.step(Command::Off, Operator::default(), DT, false);
        assert_eq!(e.outputs(), (&[false; 4], &[0.0; 2]));
    }

    #[test]
    fn a_resume_behind_a_plan_speeding_up_catches_up_at_the_bound_not_twice_it() {
        // Held at rate 0.5 on a plan that gains 1 mm/s a cycle at 100 mm/s: the rate may rise
        // by less than a plain a_dt / v would give, since the plan's own gain comes with it.
        let (r, v, c, a_dt) = (0.5, 100.0, 1.0, 1.0);
        let change = Change::within(r, v, c, a_dt);
        let plain = a_dt / v;
        assert!(change.up < plain, "{} against {plain}", change.up);
        let gained = speed_after(r + change.up, v, c) - r * v;
        assert!((gained - a_dt).abs() < 1e-9, "{gained}");
    }
}
