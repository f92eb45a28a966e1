//! The interpreter's modal state: where the tool is, the modes in force, what the program has
//! cost so far; the system parameters that give it to a program; and the conversion of one block,
//! group by group.

use crate::NcError;
use crate::budget::{Bounds, Cost};
use crate::flow;
use crate::lexer;

use pkm_api::trajectory::NcMessage;

use crate::tools::ToolTable;

use super::block::{AXES, Action, Blend, Block, Machine, Plane, Pose};
use super::compensation::Compensation;
use super::words::Words;

/// The modal state.
pub(super) struct State<'a> {
    pub(super) machine: &'a Machine<'a>,
    /// What the program may cost, and what its blocks so far cost.
    pub(super) bounds: Bounds,
    pub(super) cost: Cost,
    /// The tool's position (machine world coordinates).
    pub(super) position: Pose,
    /// The motion mode (G code in tenths: 0, 10, 20, 30, or a canned cycle's: 730, 810 … 890).
    pub(super) motion: Option<u16>,
    pub(super) plane: Plane,
    pub(super) inches: bool,
    pub(super) incremental: bool,
    /// The work coordinate system in force (0 = G54).
    pub(super) system: usize,
    /// G92's offset.
    pub(super) g92: Pose,
    /// The work coordinate systems' origins G54 … G59 (machine coordinates): the machine's, as
    /// G10 L2 and L20 change them.
    pub(super) work: [Pose; 6],
    /// G92's offset as its parameters (#5211 …) keep it: G92.2 suspends the offset, G92.3 brings
    /// it back from here.
    pub(super) g92_kept: Pose,
    /// The positions G28 and G30 go to (machine coordinates; #5161 …, #5181 …), as G28.1 and
    /// G30.1 stored them.
    pub(super) stored: [Pose; 2],
    /// The feed (mm/min; in G95 mm per revolution), as F set it in the feed mode in force.
    pub(super) feed_mm_min: Option<f64>,
    /// The feed mode (G93, G94, G95).
    pub(super) feed_mode: FeedMode,
    /// In G93, this block's F (moves per minute); F is not modal there.
    pub(super) inverse_time: Option<f64>,
    pub(super) speed_rpm: f64,
    /// The tool table as the program has changed it (G10 L1, L10).
    pub(super) tools: ToolTable,
    /// The tool T selected (for the next M6).
    pub(super) selected: Option<u32>,
    /// The tool in the spindle as the program put it there (M6, M61); `None` until it does:
    /// what a program before it left is not known when this one is read.
    pub(super) in_spindle: Option<u32>,
    /// The tool offsets in force (G43, G43.1; machine units), added to the work offsets.
    pub(super) tool_offset: Pose,
    /// The messages so far.
    pub(super) messages: Vec<NcMessage>,
    /// The coolant: mist (M7), flood (M8); M9 turns both off.
    pub(super) coolant: (bool, bool),
    /// G5's first control point when a G5 gives no I J: the last G5's P Q reversed (program
    /// units; 0 before any), as LinuxCNC keeps it.
    pub(super) spline_ij: [f64; 2],
    pub(super) blend: Blend,
    /// G90.1: an arc's I J K are absolute program coordinates (G91.1, the default: offsets from
    /// its start).
    pub(super) arc_absolute: bool,
    /// G99 (the default, as LinuxCNC's): a canned cycle retracts to its R plane; G98: to where
    /// the first cycle of a series started, if that is higher.
    pub(super) retract_to_r: bool,
    /// The canned cycle's values that carry to the next block of the same cycle.
    pub(super) cycle: Cycle,
    /// The height (normal coordinate, program units) where the present series of canned
    /// cycles started; `None` after any other motion.
    pub(super) cycle_initial: Option<f64>,
    /// Where the program first set G95 (line, column).
    pub(super) per_revolution: Option<(usize, usize)>,
    /// Cutter compensation while it is on (G41, G42).
    pub(super) comp: Option<Compensation>,
    /// Where the tool stands after G40 ended compensation, off the programmed point the
    /// interpreter reads from: the next move starts there.
    pub(super) comp_exit: Option<Pose>,
    /// After G40, until a straight move: an arc would start off its programmed circle
    /// (LinuxCNC refuses it too).
    pub(super) arc_after_comp: bool,
}

/// How F is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FeedMode {
    /// G93: each move takes 1/F minutes.
    InverseTime,
    /// G94 (the default): units per minute.
    PerMinute,
    /// G95: units per spindle revolution, at the programmed speed S.
    PerRevolution,
}

/// A canned cycle's values as its last block gave them (program units, as written: in G91, R
/// from the initial level and Z from R).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Cycle {
    pub(super) r: f64,
    pub(super) bottom: f64,
    pub(super) dwell: f64,
    pub(super) peck: f64,
}

/// The state as LinuxCNC's system parameters give it, in program units.
impl flow::System for State<'_> {
    fn refusal(&self, index: usize) -> Option<&'static str> {
        (self.compensating() && (5420..=5428).contains(&index)).then_some(
            "#5420-#5428 (where the tool is) cannot be read while cutter compensation (G41, G42) is on, as in LinuxCNC: where a compensated move ends is known only with the move after it",
        )
    }

    fn numbered(&self, index: usize) -> Option<f64> {
        let position = self.program_position();
        match index {
            // G28's and G30's stored positions (machine coordinates).
            5161..=5166 => Some(self.stored[0][index - 5161] / self.scale(index - 5161)),
            5181..=5186 => Some(self.stored[1][index - 5181] / self.scale(index - 5181)),
            // Whether G92's offset is in force, and its parameters (kept while G92.2 suspends it).
            5210 => Some(if self.g92 == [0.0; 6] { 0.0 } else { 1.0 }),
            5211..=5216 => Some(self.g92_kept[index - 5211] / self.scale(index - 5211)),
            // The coordinate system in force, 1 for G54.
            5220 => Some((self.system + 1) as f64),
            // G54 … G59's origins, 20 parameters per system (X Y Z A B C first).
            5221..=5326 if (index - 5221) % 20 < 6 => {
                let (system, c) = ((index - 5221) / 20, (index - 5221) % 20);
                Some(self.work[system][c] / self.scale(c))
            }
            // The tool in the spindle (once the program has put one there), and its offsets in
            // the tool table — whether G43 applies them or not, as LinuxCNC 2.9 gives them (0
            // without a tool).
            5400 => self.in_spindle.map(f64::from),
            5401..=5406 => {
                let table = self
                    .in_spindle
                    .and_then(|tool| self.tools.get(tool))
                    .map_or([0.0; 6], |t| self.on_machine(t.offsets));
                Some(table[index - 5401] / self.scale(index - 5401))
            }
            // The tool's position in the coordinate system in force (refused while cutter
            // compensation is on: [`flow::System::refusal`]).
            5420..=5425 => Some(position[index - 5420]),
            _ => None,
        }
    }

    fn named(&self, name: &str) -> Option<f64> {
        let truth = |b: bool| if b { 1.0 } else { 0.0 };
        let position = self.program_position();
        Some(match name {
            "_x" | "_y" | "_z" | "_a" | "_b" | "_c" => {
                let c = AXES
                    .iter()
                    .position(|a| name[1..].eq_ignore_ascii_case(&a.to_string()))?;
                position[c]
            }
            "_feed" => self.feed_mm_min.map_or(0.0, |f| f / self.unit()),
            "_rpm" => self.speed_rpm,
            "_current_tool" => f64::from(self.in_spindle?),
            "_selected_tool" => self.selected.map_or(-1.0, f64::from),
            "_metric" => truth(!self.inches),
            "_imperial" => truth(self.inches),
            "_absolute" => truth(!self.incremental),
            "_incremental" => truth(self.incremental),
            "_coord_system" => 540.0 + 10.0 * self.system as f64,
            "_motion_mode" => f64::from(self.motion.unwrap_or(800)),
            "_plane" => match self.plane {
                Plane::Xy => 170.0,
                Plane::Zx => 180.0,
                Plane::Yz => 190.0,
            },
            _ => return None,
        })
    }
}

impl<'a> State<'a> {
    pub(super) fn new(machine: &'a Machine<'a>) -> State<'a> {
        State {
            machine,
            bounds: Bounds::default(),
            cost: Cost::default(),
            position: machine.start,
            motion: None,
            plane: Plane::Xy,
            inches: false,
            incremental: false,
            system: 0,
            g92: [0.0; 6],
            work: machine.work_offsets,
            g92_kept: [0.0; 6],
            stored: machine.homes,
            feed_mm_min: None,
            feed_mode: FeedMode::PerMinute,
            inverse_time: None,
            speed_rpm: 0.0,
            tools: machine.tools.cloned().unwrap_or_default(),
            selected: None,
            in_spindle: None,
            tool_offset: [0.0; 6],
            messages: Vec::new(),
            coolant: (false, false),
            spline_ij: [0.0; 2],
            arc_absolute: false,
            retract_to_r: true,
            cycle: Cycle::default(),
            cycle_initial: None,
            per_revolution: None,
            comp: None,
            comp_exit: None,
            arc_after_comp: false,
            blend: Blend::Within {
                tolerance: None,
                merge: None,
            },
        }
    }

    /// The program coordinates in force: the work coordinate system (1 … 6: G54 … G59) and the
    /// offset of program coordinates from machine coordinates (its origin, G92's and the tool's
    /// length offset): a position is the program's coordinates plus it.
    pub(super) fn frame(&self) -> (u8, Pose) {
        (self.system as u8 + 1, self.offset())
    }

    /// mm per program length unit.
    pub(super) fn unit(&self) -> f64 {
        if self.inches { 25.4 } else { 1.0 }
    }

    /// Machine units (mm, degrees) per program unit of coordinate `c`.
    pub(super) fn scale(&self, c: usize) -> f64 {
        if c < 3 { self.unit() } else { 1.0 }
    }

    /// Converts one block (see [`State::convert`]); the first move after G40 starts where the
    /// compensated tool stood.
    pub(super) fn block(&mut self, block: &lexer::Block, out: &mut Vec<Block>) -> Result<(), NcError> {
        let before = out.len();
        self.convert(block, out)?;
        if let Some(exit) = self.comp_exit {
            let first_move = out[before..].iter_mut().find_map(|b| match &mut b.action {
                Action::Move { from, .. } => Some(from),
                _ => None,
            });
            if let Some(from) = first_move {
                *from = exit;
                self.comp_exit = None;
            }
        }
        Ok(())
    }

    /// Converts one block, in LinuxCNC's order of execution: its message, feed, speed, tool
    /// selection and change, spindle, coolant, the program's inputs and outputs, dwell, plane,
    /// units, cutter compensation, tool offsets, work offsets, path control, distance mode, G10,
    /// G92, going home, motion, stop. Each group's conversion is in the file that names it.
    fn convert(&mut self, block: &lexer::Block, out: &mut Vec<Block>) -> Result<(), NcError> {
        self.message(block, out);
        if block.words.is_empty() {
            return Ok(());
        }
        let words = Words::sort(block)?;
        words.check_axes(self.machine)?;
        self.feed_and_speed(&words)?;
        self.select_tool(&words)?;
        self.change_tool(&words, out)?;
        self.spindle(&words, out);
        self.coolant(&words, out);
        words.check_owners(self.motion_now(&words))?;
        self.io(&words, out)?;
        self.check_polar(&words)?;
        self.dwell(&words, out)?;
        self.modes(&words)?;
        self.tool_length(&words)?;
        self.set_coordinate_system(&words, out)?;
        self.set_origin(&words)?;
        self.go_home(&words, out)?;
        self.motion(&words, out)
    }
}
