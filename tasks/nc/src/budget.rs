//! What a program may cost.
//!
//! A short text can make millions of moves (`o1 repeat [999999]` around two lines) or a move
//! thousands of metres long (an arc of `P1000` turns), and checking and planning cost in
//! proportion to the path, not to the text. So the interpreter counts what each move will cost
//! as it makes it ([`Cost`]): the moves, the points of the plan's velocity profile (one every
//! [`crate::plan::GRID_SPACING`], at least two a move) and the samples of the check (one every
//! [`crate::check::SAMPLE_SPACING`]). From them it knows the memory the program and its plan
//! will take, and it refuses the program at the line where the moves or the memory pass their
//! [`Bounds`], before anything is checked or planned.
//!
//! The time it may take is the runtime's to bound, through a [`crate::watch::Watch`].

use crate::check::SAMPLE_SPACING;
use crate::interp::block::{Action, Block};
use crate::path::Segment;
use crate::plan::GRID_SPACING;

/// What one program may cost.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bounds {
    /// The most moves and other actions (a dwell, a pause, a spindle change) it may make.
    pub max_moves: usize,
    /// The most memory the program read and its plan may take (bytes, as [`Cost::bytes`]
    /// estimates it).
    pub max_bytes: u64,
}

/// The most moves a program makes unless the configuration says otherwise.
pub const DEFAULT_MAX_MOVES: usize = 1_000_000;
/// The most memory a program and its plan take unless the configuration says otherwise (MiB):
/// about a million short CAM lines (a kilobyte each, counted as [`Cost::bytes`] does).
pub const DEFAULT_MAX_MIB: u64 = 1024;

impl Default for Bounds {
    fn default() -> Self {
        Bounds {
            max_moves: DEFAULT_MAX_MOVES,
            max_bytes: DEFAULT_MAX_MIB << 20,
        }
    }
}

/// What a program's moves cost, counted as the interpreter makes them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Cost {
    /// Moves and other actions.
    pub moves: usize,
    /// Points of the velocity profile (at least two a move, one every
    /// [`crate::plan::GRID_SPACING`] along it, one every 22.5° of an arc; and the points a blend
    /// or a junction with a curve may add).
    pub points: u64,
    /// Samples of the check (one every [`crate::check::SAMPLE_SPACING`] along the path).
    pub samples: u64,
    /// The bytes the program's messages take (their text is kept twice: read, and in the plan).
    pub text: u64,
}

/// The memory one action takes while the program is planned, beyond its points: the block the
/// interpreter made of it, its element of the path and a blend's (at a corner), and an entry in
/// the list of limited feeds. (Measured: 990 000 short G64 lines on the O-X glide peaked at
/// 988 MB of the process against 1006 MB counted.)
const BYTES_PER_ACTION: u64 =
    (size_of::<Block>() + 2 * size_of::<crate::plan::Element>() + size_of::<crate::plan::Limited>()) as u64;
/// The points a blend at its corner or a junction with a curve may add to a move.
const EXTRA_POINTS: u64 = 2;

impl Cost {
    /// Adds what `block` costs.
    pub fn add(&mut self, block: &Block) {
        self.moves += 1;
        let Action::Move { from, to, path, .. } = block.action else {
            return;
        };
        let segment = Segment::new(from, to, path);
        let len = segment.length();
        let turns = segment.sweep() * 8.0 / std::f64::consts::PI;
        // As the planner and the check count them; `as` saturates a huge count.
        let steps = ((len / GRID_SPACING).ceil().max(turns.ceil()) as u64).max(2);
        self.points = self.points.saturating_add(steps + EXTRA_POINTS);
        let samples = ((segment.linear_length().max(segment.angular()) / SAMPLE_SPACING).ceil() as u64).max(1);
        self.samples = self.samples.saturating_add(samples);
    }

    /// Adds a message of `text_bytes` bytes (its text kept twice, with its record).
    pub fn add_message(&mut self, text_bytes: usize) {
        let one = (text_bytes + size_of::<pkm_api::trajectory::NcMessage>()) as u64;
        self.text = self.text.saturating_add(2 * one);
    }

    /// The memory the program and its plan take at the most (bytes): its actions, the points
    /// of its velocity profile, its messages.
    pub fn bytes(&self) -> u64 {
        (self.moves as u64)
            .saturating_mul(BYTES_PER_ACTION)
            .saturating_add(self.points.saturating_mul(crate::plan::POINT_BYTES))
            .saturating_add(self.text)
    }

    /// Why the cost passes `bounds`, if it does.
    pub fn beyond(&self, bounds: &Bounds) -> Option<String> {
        if self.moves > bounds.max_moves {
            return Some(format!(
                "the program makes more than {} moves and other actions (the bound: nc.max_moves): split it, or loop over fewer",
                bounds.max_moves
            ));
        }
        let bytes = self.bytes();
        (bytes > bounds.max_bytes).then(|| {
            format!(
                "the program's plan would take more than {} MiB (the bound: nc.max_plan_mib): {} actions so far, and a velocity profile of {} points (one every {GRID_SPACING} mm of the path, at least two a move, one every 22.5° of an arc); split it, or make the path shorter",
                bounds.max_bytes >> 20,
                self.moves,
                self.points
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interp::{Blend, Path, Plane};

    fn line(to: [f64; 6]) -> Block {
        Block {
            line: 1,
            action: Action::Move {
                from: [0.0; 6],
                to,
                path: Path::Line,
                feed_mm_min: Some(600.0),
                blend: Blend::ExactStop,
            },
        }
    }

    #[test]
    fn a_move_costs_its_points_and_samples() {
        let mut cost = Cost::default();
        cost.add(&line([10.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
        assert_eq!(
            cost,
            Cost {
                moves: 1,
                points: 20 + EXTRA_POINTS,
                samples: 100,
                text: 0
            }
        );
        // A short move: two points, one sample.
        cost.add(&line([0.01, 0.0, 0.0, 0.0, 0.0, 0.0]));
        assert_eq!((cost.points, cost.samples), (20 + 2 + 2 * EXTRA_POINTS, 101));
        // Only rotations: degrees count as millimetres.
        cost.add(&line([0.0, 0.0, 0.0, 5.0, 0.0, 0.0]));
        assert_eq!((cost.moves, cost.samples), (3, 151));
        // A dwell costs its action only.
        cost.add(&Block {
            line: 2,
            action: Action::Dwell(1.0),
        });
        assert_eq!((cost.moves, cost.points), (4, 32 + 3 * EXTRA_POINTS));
    }

    #[test]
    fn an_arc_of_many_turns_costs_its_whole_length() {
        // A circle of radius 1 mm, 1000 turns (P1000): 6.28 m of path.
        let mut cost = Cost::default();
        cost.add(&Block {
            line: 3,
            action: Action::Move {
                from: [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                to: [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                path: Path::Arc {
                    plane: Plane::Xy,
                    center: [0.0, 0.0],
                    clockwise: true,
                    extra_turns: 999,
                },
                feed_mm_min: Some(600.0),
                blend: Blend::ExactStop,
            },
        });
        let length = 2000.0 * std::f64::consts::PI;
        assert_eq!(cost.samples, (length / SAMPLE_SPACING).ceil() as u64);
        // Every 22.5° (16 a turn) is more than every 0.5 mm of a 6.28 mm circle.
        assert_eq!(cost.points, 16_000 + EXTRA_POINTS);
    }

    #[test]
    fn the_bounds_are_said_when_passed() {
        let bounds = Bounds {
            max_moves: 2,
            max_bytes: 1 << 20,
        };
        let mut cost = Cost::default();
        for _ in 0..2 {
            cost.add(&line([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
        }
        assert_eq!(cost.beyond(&bounds), None);
        cost.add(&line([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
        assert_eq!(
            cost.beyond(&bounds).as_deref(),
            Some(
                "the program makes more than 2 moves and other actions (the bound: nc.max_moves): split it, or loop over fewer"
            )
        );
        let mut long = Cost::default();
        long.add(&line([100_000.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
        let why = long.beyond(&bounds).expect("200 000 points pass 1 MiB");
        assert!(
            why.starts_with("the program's plan would take more than 1 MiB (the bound: nc.max_plan_mib): 1 actions so far, and a velocity profile of 200002 points"),
            "{why}"
        );
    }
}
