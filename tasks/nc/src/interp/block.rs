//! What the interpreter makes and what it is given: the machine's poses, the actions of a program
//! in world coordinates (moves, dwells, the spindle, pauses, the end), and the machine it reads
//! for.

use pkm_api::trajectory::NcMessage;

use crate::tools::ToolTable;

/// A pose in the machine's world coordinates: x y z (mm), a b c (degrees); the machine's
/// coordinates first, unused ones zero.
pub type Pose = [f64; 6];

/// The letters of the pose's coordinates, in [`Pose`] order.
pub const AXES: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// The slowest feed accepted (program units per minute): slower, a millimetre takes hours and a
/// typing error (F.01 for F10) runs for days.
pub const MIN_FEED: f64 = 0.1;
/// The longest dwell accepted (s): a day.
pub const MAX_DWELL_S: f64 = 86_400.0;
/// The fastest spindle speed accepted (rpm).
pub const MAX_SPINDLE_RPM: f64 = 100_000.0;

/// The plane of arcs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    /// G17: X–Y, arcs about Z.
    Xy,
    /// G18: Z–X, arcs about Y.
    Zx,
    /// G19: Y–Z, arcs about X.
    Yz,
}

impl Plane {
    /// The indices of the plane's first and second axis and of its normal, in [`Pose`] order.
    pub fn axes(self) -> [usize; 3] {
        match self {
            Plane::Xy => [0, 1, 2],
            Plane::Zx => [2, 0, 1],
            Plane::Yz => [1, 2, 0],
        }
    }

    /// The offset letters of the plane's centre (I J, K I, J K).
    pub(super) fn offsets(self) -> [char; 2] {
        match self {
            Plane::Xy => ['I', 'J'],
            Plane::Zx => ['K', 'I'],
            Plane::Yz => ['J', 'K'],
        }
    }
}

/// The path of a move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Path {
    /// A straight line in world coordinates.
    Line,
    /// An arc (a helix when the normal coordinate changes too).
    Arc {
        /// Its plane.
        plane: Plane,
        /// Its centre in the plane's two axes (machine coordinates, mm).
        center: [f64; 2],
        /// G2 (clockwise, looking down the normal) or G3.
        clockwise: bool,
        /// Full turns beyond the first (P − 1).
        extra_turns: u32,
    },
}

/// How a move ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Blend {
    /// G61: at rest at its end point.
    ExactStop,
    /// G64: blended into the next move, within `tolerance` of the corner (mm; `None`:
    /// within [`crate::plan::PLAIN_G64_MM`] — LinuxCNC's G64 without P, with P0 or P-1); lines
    /// that deviate less than `merge` (mm, G64 Q: LinuxCNC's naive CAM detector) from one
    /// straight line are run as that line.
    Within {
        /// The largest distance from a corner (G64 P).
        tolerance: Option<f64>,
        /// The deviation within which consecutive lines merge (G64 Q).
        merge: Option<f64>,
    },
}

/// The spindle's direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spindle {
    /// M3.
    Clockwise,
    /// M4.
    CounterClockwise,
    /// M5.
    Off,
}

/// How many digital outputs (`NC_DOUT_0` …), digital inputs (`NC_DIN_0` …) and analog outputs
/// (`NC_AOUT_0` …) programs have, as the process image declares them.
pub const DIGITAL_OUTPUTS: u8 = pkm_api::trajectory::DIGITAL_OUTPUTS as u8;
/// See [`DIGITAL_OUTPUTS`].
pub const DIGITAL_INPUTS: u8 = pkm_api::trajectory::DIGITAL_INPUTS as u8;
/// See [`DIGITAL_OUTPUTS`].
pub const ANALOG_OUTPUTS: u8 = pkm_api::trajectory::ANALOG_OUTPUTS as u8;

/// An output a program sets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Output {
    /// Digital output `index` on or off (M62/M64 on, M63/M65 off).
    Digital {
        /// 0 … 3.
        index: u8,
        /// On.
        on: bool,
    },
    /// Analog output `index` to `value` (M67, M68).
    Analog {
        /// 0 … 1.
        index: u8,
        /// The value.
        value: f64,
    },
}

/// What M66 waits for (its L word, LinuxCNC's codes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WaitMode {
    /// L0: no wait (LinuxCNC reads the input into #5399; the tool stands for it).
    Immediate,
    /// L1: the input rises.
    Rise,
    /// L2: the input falls.
    Fall,
    /// L3: the input is on.
    High,
    /// L4: the input is off.
    Low,
}

/// What a block does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// A move from `from` to `to`.
    Move {
        /// Where it starts (machine world coordinates).
        from: Pose,
        /// Where it ends.
        to: Pose,
        /// Its path.
        path: Path,
        /// Its feed (mm/min along the path); `None` for a rapid (G0).
        feed_mm_min: Option<f64>,
        /// How it ends.
        blend: Blend,
    },
    /// G4: stand still this long (s).
    Dwell(f64),
    /// M0 (`optional` false) or M1: stop until resumed.
    Pause {
        /// M1, the optional stop.
        optional: bool,
    },
    /// M3/M4/M5 with the speed (S, rpm) in force.
    Spindle {
        /// The direction.
        direction: Spindle,
        /// The speed (rpm).
        speed_rpm: f64,
    },
    /// M7, M8, M9: the coolant as it is from here on.
    Coolant {
        /// Mist (M7).
        mist: bool,
        /// Flood (M8).
        flood: bool,
    },
    /// M6: stand until the operator has put tool `tool` in the spindle (0: emptied it) and
    /// confirmed (a manual tool change, as LinuxCNC's `hal_manualtoolchange`).
    ToolChange {
        /// The tool asked for.
        tool: u32,
    },
    /// A message comment: the `index`-th of the program's [`Program::messages`].
    Message(u32),
    /// M62 … M65, M67, M68: an output of the program (`NC_DOUT_n`, `NC_AOUT_n`) set — with the
    /// start of the next move (`synced`, M62, M63, M67), or at once, the tool standing (M64,
    /// M65, M68).
    Output {
        /// Which output and to what.
        output: Output,
        /// With the next move's start (no stop), or standing.
        synced: bool,
    },
    /// M66: stand until digital input `input` (`NC_DIN_n`) is as `mode` says, at most
    /// `timeout_s` (then the program goes on, as LinuxCNC's does).
    Wait {
        /// The input (0 … 3).
        input: u8,
        /// What to wait for.
        mode: WaitMode,
        /// The longest wait (s; ignored for [`WaitMode::Immediate`]).
        timeout_s: f64,
    },
    /// The program coordinates from here on (at the first block that does something, and
    /// wherever they change): the work coordinate system in force (1 … 6 for G54 … G59) and the
    /// offset of program coordinates from machine coordinates — its origin, G92's or G52's
    /// offset and the tool's length offset. Shown on the operator's DRO; moves nothing.
    WorkOffset {
        /// 1 … 6: G54 … G59.
        system: u8,
        /// Machine coordinates less this are program coordinates.
        offset: [f64; 6],
    },
    /// M2/M30: the end of the program.
    End,
}

/// An action and the program line it comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Block {
    /// The line (1-based).
    pub line: usize,
    /// The column (1-based, in characters) of the word that made it: a move's first axis word,
    /// else the line's first word.
    pub column: usize,
    /// What it does.
    pub action: Action,
}

/// What the interpreter needs to know of the machine.
#[derive(Clone, Debug)]
pub struct Machine<'a> {
    /// The machine's world coordinates (`x`, `y`, `z`, `a`, `b`, `c`, as the kinematics name
    /// them), in [`Pose`] order.
    pub axes: &'a [&'a str],
    /// Where the tool is when the program starts (machine world coordinates).
    pub start: Pose,
    /// The work offsets of G54 … G59 (machine coordinates of each system's origin).
    pub work_offsets: [Pose; 6],
    /// The positions G28 and G30 go to until the program stores others (G28.1, G30.1; machine
    /// coordinates): the parameter file's.
    pub homes: [Pose; 2],
    /// The block-delete switch: on, lines starting with `/` are skipped; off (LinuxCNC's
    /// default), they run.
    pub block_delete: bool,
    /// The tool table (`None`: the run has none, and T, M6 and G43 H are refused with why).
    pub tools: Option<&'a ToolTable>,
}

/// A program read into blocks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Program {
    /// Its actions, in order.
    pub blocks: Vec<Block>,
    /// Its messages, in the order its [`Action::Message`]s name them.
    pub messages: Vec<NcMessage>,
    /// Where the tool stands when it starts (machine world coordinates): where a program
    /// without moves holds it.
    pub start: Pose,
    /// Where the program first feeds per revolution (G95: line, column), if it does: a laser
    /// machine, whose S is the beam's power, refuses it there.
    pub per_revolution: Option<(usize, usize)>,
}
