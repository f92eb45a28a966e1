//! A planned motion handed to the cyclic programs: an NC program checked and planned off the
//! cyclic path before the PLC starts (docs/nc.md), which the fast class samples once per cycle
//! without allocating. The runtime builds it (the `pkm-nc` crate plans it); the machines' drive
//! programs execute it (`pkm_drives::nc`); this module is the interface between them.

use std::sync::Arc;

/// The process-image variables of program execution: the main program's and the drive
/// program's, and what the runtime's summary reads.
pub mod vars {
    use crate::image::Var;

    /// Start the program (a press; from READY).
    pub const NC_START: Var<bool> = Var::new("NC_START");
    /// Feed hold (a press; in AUTO).
    pub const NC_HOLD: Var<bool> = Var::new("NC_HOLD");
    /// Resume after a feed hold or an M0 (a press; in AUTO).
    pub const NC_RESUME: Var<bool> = Var::new("NC_RESUME");
    /// The main program's command to the executor (`pkm_drives::nc::Command` code).
    pub const NC_COMMAND: Var<i16> = Var::new("NC_COMMAND");
    /// The executor's state (`pkm_drives::nc::RunState` code).
    pub const NC_STATE: Var<i16> = Var::new("NC_STATE");
    /// The program line executing (0 before the first block).
    pub const NC_LINE: Var<i32> = Var::new("NC_LINE");
    /// Where on the program's planned time line the executor stands (s).
    pub const NC_TIME_S: Var<f64> = Var::new("NC_TIME_S");
    /// The commanded tool pose, per pose coordinate (machine frame, mm and degrees).
    pub const NC_POSE: [Var<f64>; 6] = [
        Var::new("NC_X"),
        Var::new("NC_Y"),
        Var::new("NC_Z"),
        Var::new("NC_A"),
        Var::new("NC_B"),
        Var::new("NC_C"),
    ];
    /// The measured tool pose: the forward kinematics of the measured joints, per pose
    /// coordinate (machine frame, mm and degrees), while a program runs.
    pub const NC_TOOL: [Var<f64>; 6] = [
        Var::new("NC_TOOL_X"),
        Var::new("NC_TOOL_Y"),
        Var::new("NC_TOOL_Z"),
        Var::new("NC_TOOL_A"),
        Var::new("NC_TOOL_B"),
        Var::new("NC_TOOL_C"),
    ];
    /// The work coordinate system the running program has in force: 1 … 6 for G54 … G59; 0
    /// while no program runs (the screen's DRO then shows G54 as the parameter file and the
    /// touch-offs have it).
    pub const NC_WORK_SYSTEM: Var<i16> = Var::new("NC_WORK_SYSTEM");
    /// The running program's offset of program coordinates from machine coordinates, per pose
    /// coordinate (mm, degrees): its work system's origin, G92's (or G52's) offset and the
    /// tool's length offset (G43) together, so that the machine position less it is the position
    /// in the program's own coordinates. 0 while no program runs.
    pub const NC_WORK_OFFSET: [Var<f64>; 6] = [
        Var::new("NC_WORK_OFFSET_X"),
        Var::new("NC_WORK_OFFSET_Y"),
        Var::new("NC_WORK_OFFSET_Z"),
        Var::new("NC_WORK_OFFSET_A"),
        Var::new("NC_WORK_OFFSET_B"),
        Var::new("NC_WORK_OFFSET_C"),
    ];
    /// The program's digital outputs (M62 … M65; LinuxCNC's `motion.digital-out-NN`): on only
    /// while the program runs and the drives may move, off in every other state and at the end.
    pub const NC_DOUT: [Var<bool>; 4] = [
        Var::new("NC_DOUT_0"),
        Var::new("NC_DOUT_1"),
        Var::new("NC_DOUT_2"),
        Var::new("NC_DOUT_3"),
    ];
    /// The program's analog outputs (M67, M68), as `NC_DOUT` (0 outside a run).
    pub const NC_AOUT: [Var<f64>; 2] = [Var::new("NC_AOUT_0"), Var::new("NC_AOUT_1")];
    /// The program's digital inputs, which M66 waits on (an I/O map binds them; false where
    /// nothing writes them).
    pub const NC_DIN: [Var<bool>; 4] = [
        Var::new("NC_DIN_0"),
        Var::new("NC_DIN_1"),
        Var::new("NC_DIN_2"),
        Var::new("NC_DIN_3"),
    ];
    /// Laser mode's beam power (0 … 1 of full power; declared only in laser mode, `nc.laser`):
    /// the S word over `s_max`, constant with M3, times the speed over the programmed feed with
    /// M4; 0 during rapids, with M5, in a hold or pause, outside AUTO and on STOP.
    pub const LASER_POWER: Var<f64> = Var::new("LASER_POWER");
    /// The spindle turns (M3 or M4).
    pub const SPINDLE_ON: Var<bool> = Var::new("SPINDLE_ON");
    /// The spindle turns counter-clockwise (M4).
    pub const SPINDLE_REVERSE: Var<bool> = Var::new("SPINDLE_REVERSE");
    /// The programmed spindle speed (rpm; 0 when off).
    pub const SPINDLE_RPM: Var<f64> = Var::new("SPINDLE_RPM");
    /// Mist coolant on (M7, until M9).
    pub const COOLANT_MIST: Var<bool> = Var::new("COOLANT_MIST");
    /// Flood coolant on (M8, until M9).
    pub const COOLANT_FLOOD: Var<bool> = Var::new("COOLANT_FLOOD");
    /// A manual tool change (M6) waits for the operator: the program stands until it is
    /// confirmed (`TOOL_CHANGED` rises, or the screen's `HMI_TOOL_CONFIRM` names the change).
    pub const TOOL_CHANGE: Var<bool> = Var::new("TOOL_CHANGE");
    /// The tool the change asks for (0: empty the spindle); the last one asked when no change
    /// waits.
    pub const TOOL_PREP_NUMBER: Var<i32> = Var::new("TOOL_PREP_NUMBER");
    /// The operator's confirmation that the tool asked for is in the spindle (a press: its
    /// rising edge, while a change waits, confirms that change). Optional; the screen confirms
    /// by `HMI_TOOL_CONFIRM`, which names the change.
    pub const TOOL_CHANGED: Var<bool> = Var::new("TOOL_CHANGED");
    /// Which tool change of the run waits, or came last: the PLC's tool changes are counted
    /// from 1 since it started (0: none yet). A confirmation names it.
    pub const TOOL_CHANGE_NUMBER: Var<i32> = Var::new("TOOL_CHANGE_NUMBER");
    /// The tool in the spindle as the last confirmed change put it there (0: none, or not
    /// known since the PLC started).
    pub const TOOL_NUMBER: Var<i32> = Var::new("TOOL_NUMBER");
    /// The last message comment the running program reached: its 1-based index in the loaded
    /// program's messages (0: none yet in this run).
    pub const NC_MESSAGE: Var<i32> = Var::new("NC_MESSAGE");
    /// How many message comments programs have reached since the PLC started: an observer that
    /// sees it grow by k knows the last k messages up to `NC_MESSAGE` are new.
    pub const NC_MESSAGES: Var<i32> = Var::new("NC_MESSAGES");
    /// The spindle override (percent, 0 … 150; clamped there): the spindle turns at the
    /// programmed speed times it. Written by the screen as `NC_FEED_OVERRIDE`; 100 when nothing
    /// writes it. (A G95 feed was planned at the programmed speed: the override does not change
    /// it.)
    pub const NC_SPINDLE_OVERRIDE: Var<i16> = Var::new("NC_SPINDLE_OVERRIDE");
    /// The commanded feed now: the speed along the path the executor commands (mm/min; degrees
    /// per minute where only rotations move), overrides included.
    pub const NC_FEED: Var<f64> = Var::new("NC_FEED");
    /// The measured feed: the speed of the measured tool point (x y z) over the last 100 ms
    /// (mm/min), while a program runs.
    pub const NC_FEED_MEASURED: Var<f64> = Var::new("NC_FEED_MEASURED");
    /// The distance to go: along the path to the end of the executing line's motion (mm).
    pub const NC_DISTANCE_TO_GO: Var<f64> = Var::new("NC_DISTANCE_TO_GO");
    /// The contour error now: the distance from the measured tool point to the programmed path
    /// (mm), measured on feed moves (G1, G2, G3; not on rapids).
    pub const NC_CONTOUR_ERROR: Var<f64> = Var::new("NC_CONTOUR_ERROR");
    /// The run's largest contour error so far (mm).
    pub const NC_CONTOUR_MAX: Var<f64> = Var::new("NC_CONTOUR_MAX");
    /// The run's RMS contour error so far (mm).
    pub const NC_CONTOUR_RMS: Var<f64> = Var::new("NC_CONTOUR_RMS");
    /// The run's largest following error per joint (mm).
    pub const NC_FOLLOWING_MAX: [Var<f64>; 6] = [
        Var::new("NC_JOINT1_FOLLOWING_MAX"),
        Var::new("NC_JOINT2_FOLLOWING_MAX"),
        Var::new("NC_JOINT3_FOLLOWING_MAX"),
        Var::new("NC_JOINT4_FOLLOWING_MAX"),
        Var::new("NC_JOINT5_FOLLOWING_MAX"),
        Var::new("NC_JOINT6_FOLLOWING_MAX"),
    ];
    /// How long the current (or last) run has lasted, holds and pauses included (s).
    pub const NC_RUN_S: Var<f64> = Var::new("NC_RUN_S");
    /// The last run reached the program's end.
    pub const NC_COMPLETED: Var<bool> = Var::new("NC_COMPLETED");
    /// The loaded program: its number in the run's [`NcLibrary`](crate::library::NcLibrary)(super::NcLibrary), from 1 (the
    /// main program's choice; the drive program executes it).
    pub const NC_PROGRAM: Var<i16> = Var::new("NC_PROGRAM");
    /// The feed override (percent, 0 … 150; clamped there): how fast feed moves go against
    /// their programmed feed, the machine's limits kept. Written by the screen (or an I/O map's
    /// input); 100 when nothing writes it.
    pub const NC_FEED_OVERRIDE: Var<i16> = Var::new("NC_FEED_OVERRIDE");
    /// The rapid override (percent, 0 … 100; clamped there): how fast rapids (G0) go against
    /// the machine's speed. Written as `NC_FEED_OVERRIDE`; 100 when nothing writes it.
    pub const NC_RAPID_OVERRIDE: Var<i16> = Var::new("NC_RAPID_OVERRIDE");
    /// Single block: the program stands after each line (braking to the end of the line it is
    /// in, or of the first it can still stop at), and NC_RESUME runs the next. A level, taken
    /// whenever it changes; off when nothing writes it.
    pub const NC_SINGLE_BLOCK: Var<bool> = Var::new("NC_SINGLE_BLOCK");
    /// The executor met a pose of the program that has no joints (which its check rules out):
    /// it stands where it was; the main program makes it an ERROR.
    pub const NC_FAULT: Var<bool> = Var::new("NC_FAULT");
}

/// How many digital outputs (`vars::NC_DOUT`), digital inputs (`vars::NC_DIN`) and analog
/// outputs (`vars::NC_AOUT`) programs have (M62 … M68): LinuxCNC's default four digital ones,
/// and two analog outputs.
pub const DIGITAL_OUTPUTS: usize = vars::NC_DOUT.len();
/// See [`DIGITAL_OUTPUTS`].
pub const DIGITAL_INPUTS: usize = vars::NC_DIN.len();
/// See [`DIGITAL_OUTPUTS`].
pub const ANALOG_OUTPUTS: usize = vars::NC_AOUT.len();

/// The most joints or pose coordinates a trajectory has (x y z a b c).
pub const MAX_AXES: usize = 6;

/// The highest feed override (a fraction of the programmed feed): the planner plans each
/// program's profile for it too, so that the executor knows how fast it may go there.
pub const MAX_FEED_OVERRIDE: f64 = 1.5;

/// The override's value when nothing writes `vars::NC_FEED_OVERRIDE` or
/// `vars::NC_RAPID_OVERRIDE` (percent).
pub const OVERRIDE_DEFAULT: i16 = 100;

/// The trajectory at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrajectorySample {
    /// The commanded tool pose (machine frame: mm and degrees, x y z a b c; unused ones 0).
    pub pose: [f64; MAX_AXES],
    /// The joints for that pose (mm; unused ones 0).
    pub joints: [f64; MAX_AXES],
    /// The program line executing (1-based; 0 before the first block).
    pub line: u32,
    /// The distance along the path from the program's start (mm, or degrees where only
    /// rotations move).
    pub s: f64,
    /// The planned speed along the path (mm/s, or degrees/s where only rotations move).
    pub speed: f64,
    /// The speed the profile planned at the highest feed override has here (never below
    /// `speed`): how fast a feed override above 100 % may go.
    pub speed_max: f64,
    /// The largest change of speed along the path the machine's limits allow here at the
    /// planned speed (mm/s²): a feed hold brakes, a resume and an override's change accelerate,
    /// with it.
    pub accel: f64,
    /// How fast the planned speed changes here (mm/s², negative where the plan brakes): where
    /// the tool runs at a fraction of the plan's time, its speed changes by that fraction
    /// squared of this beside what the fraction's own change makes.
    pub planned_accel: f64,
    /// A rapid (G0) executes: no programmed feed, no contour to keep.
    pub rapid: bool,
    /// The programmed feed of the move executing (mm/s, as the program's F, before the feed
    /// override; 0 for a rapid and where none executes): laser mode's M4 scales the beam with the
    /// speed over it.
    pub feed: f64,
}

/// What happens at an instant of a program besides motion (the tool is at rest there).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TrajectoryEventKind {
    /// M0, or M1 (the optional stop): wait for a resume.
    Pause,
    /// G4: the tool stands this long from here, on the time line (the executing line is the
    /// dwell's meanwhile).
    Dwell {
        /// How long (s).
        seconds: f64,
    },
    /// M7, M8, M9: the coolant as it is from here on.
    Coolant {
        /// Mist (M7).
        mist: bool,
        /// Flood (M8).
        flood: bool,
    },
    /// M6: a manual tool change — stand until the operator confirms that tool `tool` is in the
    /// spindle (0: the spindle emptied).
    ToolChange {
        /// The tool asked for.
        tool: u32,
    },
    /// A message comment: the `index`-th (0-based) of [`Trajectory::messages`]. The tool does
    /// not stop for it.
    Message {
        /// Its index.
        index: u32,
    },
    /// The program coordinates from here on: the work coordinate system in force (1 … 6 for
    /// G54 … G59) and the offset of program coordinates from machine coordinates (its origin,
    /// G92's or G52's offset and the tool's length offset, per pose coordinate). At the
    /// program's first line and wherever one of them changes; the tool does not stop for it.
    WorkOffset {
        /// 1 … 6: G54 … G59.
        system: u8,
        /// Machine coordinates less this are program coordinates (mm, degrees).
        offset: [f64; MAX_AXES],
    },
    /// M62 … M65: digital output `index` (`NC_DOUT_n`) on or off — with the next move's start
    /// (M62, M63) or standing (M64, M65).
    DigitalOutput {
        /// 0 … 3.
        index: u8,
        /// On.
        on: bool,
    },
    /// M67, M68: analog output `index` (`NC_AOUT_n`) set to `value`.
    AnalogOutput {
        /// 0 … 1.
        index: u8,
        /// The value.
        value: f64,
    },
    /// M66: the tool stands until digital input `index` (`NC_DIN_n`) is as `mode` says
    /// (LinuxCNC's L: 0 no wait, 1 rises, 2 falls, 3 on, 4 off), at most `timeout_s`; then the
    /// program goes on.
    WaitInput {
        /// 0 … 3.
        index: u8,
        /// LinuxCNC's L.
        mode: u8,
        /// The longest wait (s).
        timeout_s: f64,
    },
    /// M3 (1), M4 (−1), M5 (0) with the programmed speed (rpm).
    Spindle {
        /// 1 clockwise, −1 counter-clockwise, 0 off.
        direction: i8,
        /// The programmed speed (rpm).
        rpm: f64,
    },
}

/// What a program's message asks for: a message comment (LinuxCNC's `(MSG,…)`, `(DEBUG,…)`,
/// `(PRINT,…)`), or a tool table entry a `G10 L1`/`L10` set, which the run writes back to the
/// tool table when it reaches its line, as LinuxCNC does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NcMessageKind {
    /// `(MSG,…)`: shown to the operator (the screen) and logged.
    Msg,
    /// `(DEBUG,…)`: logged, its parameters substituted.
    Debug,
    /// `(PRINT,…)`: logged, its parameters substituted.
    Print,
    /// `G10 L1`, `G10 L10`: the tool's entry as the program set it (the text its line in the
    /// tool table, LinuxCNC's format); logged, and written back to the tool table by a machine's
    /// run (not by a simulation).
    ToolEntry,
}

impl NcMessageKind {
    /// The comment's keyword, upper case (`TOOL` for a tool table entry).
    pub fn keyword(self) -> &'static str {
        match self {
            NcMessageKind::Msg => "MSG",
            NcMessageKind::Debug => "DEBUG",
            NcMessageKind::Print => "PRINT",
            NcMessageKind::ToolEntry => "TOOL",
        }
    }
}

/// A message of a program, as the executor reaches it.
#[derive(Clone, Debug, PartialEq)]
pub struct NcMessage {
    /// Its program line.
    pub line: u32,
    /// What it asks for.
    pub kind: NcMessageKind,
    /// Its text (for DEBUG and PRINT with the parameters' values as they were at its line).
    pub text: String,
}

/// A timed event of a trajectory.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectoryEvent {
    /// When (s from the program's start, on its planned time line).
    pub t: f64,
    /// Its program line.
    pub line: u32,
    /// What it does.
    pub kind: TrajectoryEventKind,
}

/// A planned program as the cyclic programs see it. Every method is allocation-free and
/// deterministic; `sample` and `path_distance` run in the fast class.
pub trait Trajectory: Send + Sync {
    /// The machine's number of joints (and pose coordinates).
    fn dof(&self) -> usize;
    /// The planned duration (s), dwells included, pauses excluded.
    fn duration_s(&self) -> f64;
    /// The path's length (mm).
    fn length_mm(&self) -> f64;
    /// The trajectory at `t` (s, clamped to 0 … duration). `cursor` remembers where the last call
    /// was, so that sampling forward in time costs O(1).
    fn sample(&self, t: f64, cursor: &mut usize) -> TrajectorySample;
    /// The events, in time order.
    fn events(&self) -> &[TrajectoryEvent];
    /// The program's messages, in the order its events reach them.
    fn messages(&self) -> &[NcMessage] {
        &[]
    }
    /// The first place after `s` (mm along the path) where one program line's motion ends and
    /// the next one's begins: its distance along the path and its planned time (s). `None`
    /// after the last line's motion began. Single block stands there.
    fn block_end(&self, s: f64) -> Option<(f64, f64)>;
    /// The tool pose for `joints` (forward kinematics, machine frame), found from `hint` (the
    /// last pose); false where the mechanism has no pose for them.
    fn forward(&self, joints: &[f64], hint: &[f64; MAX_AXES], pose: &mut [f64; MAX_AXES]) -> bool;
    /// The distance (mm) from the tool point (x y z of `pose`; x y on a planar machine) to the
    /// programmed path near the time `t` (s): where a tool that lags or leads its set-point
    /// might be.
    fn path_distance(&self, pose: &[f64; MAX_AXES], t: f64) -> f64;
}

/// An NC program ready to run: its file, its text and its trajectory.
#[derive(Clone)]
pub struct NcJob {
    /// The program's file, as the user named it.
    pub file: String,
    /// The program's text (traces carry it, so that a replay plans the same program).
    pub text: String,
    /// Its trajectory.
    pub trajectory: Arc<dyn Trajectory>,
}

impl std::fmt::Debug for NcJob {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NcJob")
            .field("file", &self.file)
            .field("duration_s", &self.trajectory.duration_s())
            .finish()
    }
}
