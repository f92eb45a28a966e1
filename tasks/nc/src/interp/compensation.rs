//! What cutter compensation holds while it is on (G41, G42): the side, the tool's radius, the
//! programmed point, the moves whose ends the next move may still change; and a move as the
//! program gives it. The conversion is [`super::comp`]'s.

use super::block::Pose;

/// The side of the path the tool runs on, looking along the path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Side {
    /// G41, G41.1.
    Left,
    /// G42, G42.1.
    Right,
}

/// Cutter compensation while it is on.
#[derive(Clone, Debug)]
pub(super) struct Compensation {
    /// The side the tool runs on (a negative diameter swaps G41's and G42's).
    pub(super) side: Side,
    /// The tool's radius (mm). Zero (a tool without a diameter): the side is set, the moves are
    /// not offset — LinuxCNC's meaning.
    pub(super) radius: f64,
    /// The programmed point: where the program's path is (machine coordinates), `None` until
    /// the first move after G41 or G42 (the entry move).
    pub(super) programmed: Option<Pose>,
    /// The moves whose end the next move may still change (indices in the program's actions).
    pub(super) open: Vec<Open>,
    /// Where the last open move in the plane starts (LinuxCNC's `endpoint`), where known: a
    /// moved end must not turn it back.
    pub(super) start: Option<[f64; 2]>,
}

/// An open move and what moving its end must keep.
#[derive(Clone, Copy, Debug)]
pub(super) struct Open {
    /// Its index in the program's actions.
    pub(super) index: usize,
    /// What it is.
    pub(super) kind: OpenKind,
}

/// What an open move is.
#[derive(Clone, Copy, Debug)]
pub(super) enum OpenKind {
    /// A line, and the direction it runs in the plane (the programmed one).
    Line { rapid: bool, direction: [f64; 2] },
    /// An arc: its turns (LinuxCNC's signed `turn`) and the programmed sweep (rad; 0: not
    /// checked).
    Arc { turn: i32, sweep: f64 },
}

/// A move's end as the program gives it: where the program's path goes, and the shape of the
/// programmed path.
pub(super) struct Programmed {
    pub(super) to: Pose,
    /// An arc's centre (machine coordinates, the plane's two axes) and turns (signed, LinuxCNC's
    /// `turn`); `None`: a line.
    pub(super) arc: Option<([f64; 2], i32)>,
    /// A rapid (G0).
    pub(super) rapid: bool,
    /// The feed (mm/min; `None` for a rapid).
    pub(super) feed: Option<f64>,
}
