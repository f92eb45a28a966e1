//! The process-image side of program execution: the main program's command and the operator's
//! overrides, single block and tool-change confirmation in; the joints' set-points, the
//! executing line, the commanded and measured pose and feed, the spindle and coolant, the tool
//! change's request and the messages reached out; and the run's measured contour and following
//! errors for the summary.

use std::sync::Arc;

use pkm_api::image::{Declare, Input, Output};
use pkm_api::library::NcLibrary;
use pkm_api::program::Cycle;
use pkm_api::trajectory::{MAX_AXES, MAX_FEED_OVERRIDE, OVERRIDE_DEFAULT, Trajectory, TrajectorySample};

use super::{Command, Executor, Operator, RunState, vars};

/// How many cycles the measured feed is taken over (10: 100 ms at 10 ms, so that a stepper's
/// 0.0025 mm steps do not make it jump).
const FEED_WINDOW: usize = 10;

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
    spindle_override: Input<i16>,
    feed: Output<f64>,
    feed_measured: Output<f64>,
    distance_to_go: Output<f64>,
    /// The measured tool point (x y z) of the last [`FEED_WINDOW`] cycles, a ring (for the
    /// measured feed), and how many of them are filled.
    recent: [[f64; 3]; FEED_WINDOW],
    recent_filled: usize,
    /// The tool-change confirmations: the panel's and the screen's.
    /// The panel's confirmation (`TOOL_CHANGED`) and the screen's confirmed change number.
    tool_changed: Input<bool>,
    screen_confirm: Input<i32>,
    /// The PLC's tool changes so far (the one that waits is the last), and whether one waited
    /// last cycle.
    changes: u32,
    waited: bool,
    change_number: Output<i32>,
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
    /// Laser mode: the S word of full power and the beam's power (`LASER_POWER`, 0 … 1).
    laser: Option<(f64, Output<f64>)>,
    /// The program's inputs and outputs (M62 … M68).
    digital_in: [Input<bool>; super::DIGITAL_INPUTS],
    digital_out: [Output<bool>; super::DIGITAL_OUTPUTS],
    analog_out: [Output<f64>; super::ANALOG_OUTPUTS],
    /// The running program's coordinates (`NC_WORK_SYSTEM`, `NC_WORK_OFFSET_*`).
    work_system: Output<i16>,
    work_offset: Vec<Output<f64>>,
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
            spindle_override: decl.read_optional_or(vars::NC_SPINDLE_OVERRIDE, OVERRIDE_DEFAULT),
            feed: decl.write(vars::NC_FEED, 0.0),
            feed_measured: decl.write(vars::NC_FEED_MEASURED, 0.0),
            distance_to_go: decl.write(vars::NC_DISTANCE_TO_GO, 0.0),
            recent: [[0.0; 3]; FEED_WINDOW],
            recent_filled: 0,
            tool_changed: decl.read_optional(vars::TOOL_CHANGED),
            screen_confirm: decl.read_optional(pkm_api::hmi::HMI_TOOL_CONFIRM),
            changes: 0,
            waited: false,
            change_number: decl.write(vars::TOOL_CHANGE_NUMBER, 0),
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
            laser: library
                .laser_s_max
                .map(|s_max| (s_max, decl.write(vars::LASER_POWER, 0.0))),
            digital_in: vars::NC_DIN.map(|v| decl.read_optional(v)),
            digital_out: vars::NC_DOUT.map(|v| decl.write(v, false)),
            analog_out: vars::NC_AOUT.map(|v| decl.write(v, 0.0)),
            work_system: decl.write(vars::NC_WORK_SYSTEM, 0),
            work_offset: vars::NC_WORK_OFFSET[..coordinates.min(MAX_AXES)]
                .iter()
                .map(|v| decl.write(*v, 0.0))
                .collect(),
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
        self.recent_filled = 0;
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

    /// The measured tool point's speed (mm/s) over the last [`FEED_WINDOW`] cycles of `dt`,
    /// with this cycle's point taken in.
    fn measured_speed(&mut self, dt: f64) -> f64 {
        let point = [self.measured[0], self.measured[1], self.measured[2]];
        let at = self.recent_filled % FEED_WINDOW;
        let oldest = if self.recent_filled >= FEED_WINDOW {
            Some(self.recent[at])
        } else {
            None
        };
        self.recent[at] = point;
        self.recent_filled = self.recent_filled.saturating_add(1);
        let Some(oldest) = oldest else {
            return 0.0;
        };
        let d: f64 = (0..3).map(|c| (point[c] - oldest[c]).powi(2)).sum::<f64>().sqrt();
        d / (dt * FEED_WINDOW as f64)
    }

    /// Whether the tool change that waits is confirmed now (a level; the executor takes its
    /// rising edge): by the panel's `TOOL_CHANGED` rising while it waits, or by the screen
    /// naming this change's number. A screen's confirmation of another change (one that came
    /// late, after the change it meant) confirms nothing.
    fn confirms(&self, ctx: &Cycle<'_>) -> bool {
        let panel = ctx.get(self.tool_changed);
        let waits = self.executor.tool_asked().is_some();
        let screen = waits && self.changes > 0 && i64::from(ctx.get(self.screen_confirm)) == i64::from(self.changes);
        panel || screen
    }

    /// The tool change's and the messages' outputs after a step; `reached`: the messages the
    /// run had reached before it.
    fn tool_outputs(&mut self, ctx: &mut Cycle<'_>, reached: u32) {
        let asked = self.executor.tool_asked();
        // A change that begins gets the next number of the PLC's run (never reused: a
        // confirmation of an earlier one cannot confirm it).
        if asked.is_some() && !self.waited {
            self.changes = self.changes.saturating_add(1);
            ctx.set(self.change_number, i32::try_from(self.changes).unwrap_or(i32::MAX));
        }
        self.waited = asked.is_some();
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
            tool_changed: self.confirms(ctx),
            inputs: self.digital_in.map(|i| ctx.get(i)),
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
        let spindle_override = (f64::from(ctx.get(self.spindle_override)) / 100.0).clamp(0.0, MAX_FEED_OVERRIDE);
        ctx.set(self.spindle_on, turning);
        ctx.set(self.spindle_reverse, turning && direction < 0);
        ctx.set(self.spindle_rpm, if turning { rpm * spindle_override } else { 0.0 });
        // The commanded feed and the distance to go.
        ctx.set(self.feed, self.executor.commanded_speed() * 60.0);
        ctx.set(self.distance_to_go, self.executor.distance_to_go());
        // The coolant too: on only while the program runs and the drives may move.
        let (mist, flood) = self.executor.coolant();
        let flows = auto && !interlock;
        ctx.set(self.coolant_mist, flows && mist);
        ctx.set(self.coolant_flood, flows && flood);
        if let Some((s_max, out)) = self.laser {
            ctx.set(
                out,
                (laser_power(&self.executor, s_max, flows) * spindle_override).min(1.0),
            );
        }
        // The program's outputs: as it set them while it runs and the drives may move, off in
        // every other state (ERROR, STOP, the interlock, the end).
        let (digital, analog) = self.executor.outputs();
        for (out, on) in self.digital_out.iter().zip(digital) {
            ctx.set(*out, flows && *on);
        }
        for (out, value) in self.analog_out.iter().zip(analog) {
            ctx.set(*out, if flows { *value } else { 0.0 });
        }
        // The program's coordinates while it runs (the DRO's work position); none outside.
        let running = auto && !matches!(state, RunState::Idle | RunState::Done);
        let (system, offset) = self.executor.work();
        ctx.set(self.work_system, if running { i16::from(system) } else { 0 });
        for (out, value) in self.work_offset.iter().zip(offset) {
            ctx.set(*out, if running { *value } else { 0.0 });
        }
        if !auto || state == RunState::Idle {
            ctx.set(self.feed_measured, 0.0);
            return None;
        }
        if state != RunState::Done {
            // The run's measurements: the measured tool point against the programmed path,
            // each joint against its set-point.
            ctx.set(self.run_s, ctx.output_value(self.run_s) + dt);
            let mut pose = [0.0; MAX_AXES];
            if self.executor.trajectory().forward(positions, &self.measured, &mut pose) {
                self.measured = pose;
                for (out, value) in self.tool.iter().zip(&pose) {
                    ctx.set(*out, *value);
                }
            }
            let measured = self.measured_speed(dt);
            ctx.set(self.feed_measured, measured * 60.0);
            let trajectory = self.executor.trajectory();
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

/// The laser's power now (0 … 1 of full power at S = `s_max`, before the spindle override,
/// which scales it as grbl's does), grbl's laser mode: M3 the
/// programmed S constant, M4 that times the tool's speed along the path over the programmed
/// feed (corners and ramps, where the tool is slower, get less); 0 during rapids, with M5, in a
/// feed hold or a pause, and wherever `flows` is not (outside AUTO, STOP, the interlock).
fn laser_power(executor: &Executor, s_max: f64, flows: bool) -> f64 {
    let (direction, rpm) = executor.spindle();
    let sample = executor.sample();
    let cutting = matches!(executor.state(), RunState::Running | RunState::Holding);
    if !flows || direction == 0 || !cutting || sample.rapid {
        return 0.0;
    }
    let power = (rpm / s_max).clamp(0.0, 1.0);
    if direction > 0 {
        return power;
    }
    if sample.feed <= 0.0 {
        return 0.0;
    }
    power * (executor.commanded_speed() / sample.feed).clamp(0.0, 1.0)
}
