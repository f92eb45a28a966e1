//! What a program may cost.
//!
//! A short text can make millions of moves (`o1 repeat [999999]` around two lines) or a move
//! thousands of metres long (an arc of `P1000` turns), and checking and planning cost in
//! proportion to the path, not to the text. So the interpreter counts what each move will cost
//! as it makes it ([`Cost`]): the moves, the points of the plan's velocity profile (one every
//! [`crate::plan::GRID_SPACING`], at least two a move, and those of the blend at each corner)
//! with the points refining may add to it, and the samples of the check (one every
//! [`crate::check::SAMPLE_SPACING`]). From them it knows the memory the program and its plan
//! will take, and it refuses the program at the line where the moves or the memory pass their
//! [`Bounds`], before anything is checked or planned.
//!
//! The time it may take is the runtime's to bound, through a [`crate::watch::Watch`].

use crate::check::SAMPLE_SPACING;
use crate::interp::block::{Action, Blend, Block};
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
/// about a million short CAM lines (up to two kilobytes each, counted as [`Cost::bytes`] does).
pub const DEFAULT_MAX_MIB: u64 = 2048;

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
    /// [`crate::plan::GRID_SPACING`] along it, one every [`crate::plan::ARC_STEP`] of an arc;
    /// and those of the blend at each corner).
    pub points: u64,
    /// Samples of the check (one every [`crate::check::SAMPLE_SPACING`] along the path).
    pub samples: u64,
    /// The bytes the program's messages take (their text is kept twice: read, and in the plan).
    pub text: u64,
    /// Where the last move ended blended into the next: its direction there (the bits of its
    /// x y z), whose turn to the next move's sets the blend's points, and whether it was a line.
    last: Option<([u64; 3], bool)>,
}

/// The memory one action takes while the program is planned, beyond its points: the block the
/// interpreter made of it, its element of the path and a blend's (at a corner), and an entry in
/// the list of limited feeds. (Measured: 990 000 G64 P0.01 lines of 0.2 mm, turning by 7° at
/// each corner, peaked at 1.29 GB of the process on the O-X glide and 1.41 GB on the hexapod,
/// against 1.78 GB counted: a point is counted with the derivatives of twelve coordinates and
/// the points refining may add.)
const BYTES_PER_ACTION: u64 =
    (size_of::<Block>() + 2 * size_of::<crate::plan::Element>() + size_of::<crate::plan::Limited>()) as u64;
/// The points a blend at a corner that turns by `theta` (rad) has at the most, counted as the
/// planner counts them: the arc between two lines, or the two arcs (each turning by at most as
/// much) where a curve meets the corner. Its length is taken from the moves', whose points are
/// already counted.
fn blend_points(theta: f64, both_lines: bool) -> u64 {
    if theta >= crate::plan::REVERSAL {
        // The tool stops where it turns back: no blend.
        return 0;
    }
    let arcs = if both_lines { 1 } else { 2 };
    arcs * ((theta / crate::plan::ARC_STEP).ceil() as u64).max(2)
}

impl Cost {
    /// Adds what `block` costs.
    pub fn add(&mut self, block: &Block) {
        self.moves += 1;
        let Action::Move {
            from, to, path, blend, ..
        } = block.action
        else {
            // A dwell, a pause, the spindle: the tool stops, no corner is blended.
            self.last = None;
            return;
        };
        let segment = Segment::new(from, to, path);
        // As the planner counts them (`as` saturates a huge count), and the corner's blend.
        let steps = crate::plan::steps(&segment) as u64;
        let corner = self.last.map_or(0, |(bits, line_before)| {
            let before = bits.map(f64::from_bits);
            let after = segment.direction(0.0);
            let cos = (0..3).map(|c| before[c] * after[c]).sum::<f64>().clamp(-1.0, 1.0);
            blend_points(cos.acos(), line_before && !segment.is_arc())
        });
        self.points = self.points.saturating_add(steps + corner);
        self.last = (blend != Blend::ExactStop).then(|| (segment.direction(1.0).map(f64::to_bits), !segment.is_arc()));
        let samples = ((segment.linear_length().max(segment.angular()) / SAMPLE_SPACING).ceil() as u64).max(1);
        self.samples = self.samples.saturating_add(samples);
    }

    /// Adds a message of `text_bytes` bytes (its text kept twice, with its record).
    pub fn add_message(&mut self, text_bytes: usize) {
        let one = (text_bytes + size_of::<pkm_api::trajectory::NcMessage>()) as u64;
        self.text = self.text.saturating_add(2 * one);
    }

    /// The memory the program and its plan take at the most (bytes): its actions, the points
    /// of its velocity profile (and those the planner may add where it refines it), its
    /// messages.
    pub fn bytes(&self) -> u64 {
        let points = usize::try_from(self.points).unwrap_or(usize::MAX);
        let refined = self.points.saturating_add(crate::plan::allowance(points) as u64);
        (self.moves as u64)
            .saturating_mul(BYTES_PER_ACTION)
            .saturating_add(refined.saturating_mul(crate::plan::POINT_BYTES))
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
                "the program's plan would take more than {} MiB (the bound: nc.max_plan_mib): {} actions so far, and a velocity profile of {} points (one every {GRID_SPACING} mm of the path, at least two a move, one every {}° of an arc); split it, or make the path shorter",
                bounds.max_bytes >> 20,
                self.moves,
                self.points,
                crate::plan::ARC_STEP.to_degrees()
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interp::{Blend, Path, Plane};

    fn line(to: [f64; 6]) -> Block {
        line_from([0.0; 6], to, Blend::ExactStop)
    }

    fn line_from(from: [f64; 6], to: [f64; 6], blend: Blend) -> Block {
        Block {
            line: 1,
            column: 1,
            action: Action::Move {
                from,
                to,
                path: Path::Line,
                feed_mm_min: Some(600.0),
                blend,
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
                points: 20,
                samples: 100,
                text: 0,
                last: None,
            }
        );
        // A short move: two points, one sample.
        cost.add(&line([0.01, 0.0, 0.0, 0.0, 0.0, 0.0]));
        assert_eq!((cost.points, cost.samples), (22, 101));
        // Only rotations: degrees count as millimetres.
        cost.add(&line([0.0, 0.0, 0.0, 5.0, 0.0, 0.0]));
        assert_eq!((cost.moves, cost.samples), (3, 151));
        // A dwell costs its action only.
        cost.add(&Block {
            line: 2,
            column: 1,
            action: Action::Dwell(1.0),
        });
        assert_eq!((cost.moves, cost.points), (4, 32));
    }

    #[test]
    fn a_blended_corner_costs_the_points_of_its_blend() {
        let within = Blend::Within {
            tolerance: Some(0.1),
            merge: None,
        };
        let mut cost = Cost::default();
        // Ten blended lines, each of 2 mm and four points, turning by 90° at each corner: nine
        // blends of eight steps of 11.25°.
        let corners = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]];
        for k in 0..10 {
            let [a, b] = [corners[k % 4], corners[(k + 1) % 4]];
            cost.add(&line_from(
                [a[0], a[1], 0.0, 0.0, 0.0, 0.0],
                [b[0], b[1], 0.0, 0.0, 0.0, 0.0],
                within,
            ));
        }
        assert_eq!(cost.points, 10 * 4 + 9 * 8);
        // A reversal stops the tool: no blend.
        cost.add(&line_from(
            [2.0, 2.0, 0.0, 0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            within,
        ));
        assert_eq!(cost.points, 11 * 4 + 9 * 8);
        // A move to an exact stop is blended into at its start, not at its end.
        cost.add(&line_from(
            [2.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [4.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            Blend::ExactStop,
        ));
        cost.add(&line_from(
            [4.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [4.0, 2.0, 0.0, 0.0, 0.0, 0.0],
            within,
        ));
        assert_eq!(cost.points, 13 * 4 + 10 * 8);
        // A line into an arc, turning by 90°: two arcs of as many steps as one would have.
        cost.add(&Block {
            line: 1,
            column: 1,
            action: Action::Move {
                from: [4.0, 2.0, 0.0, 0.0, 0.0, 0.0],
                to: [6.0, 4.0, 0.0, 0.0, 0.0, 0.0],
                path: Path::Arc {
                    plane: Plane::Xy,
                    center: [4.0, 4.0],
                    clockwise: false,
                    extra_turns: 0,
                },
                feed_mm_min: Some(600.0),
                blend: within,
            },
        });
        // The quarter circle of radius 2 mm (3.14 mm): eight steps of 11.25°.
        assert_eq!(cost.points, 13 * 4 + 10 * 8 + 8 + 2 * 8);
    }

    #[test]
    fn an_arc_of_many_turns_costs_its_whole_length() {
        // A circle of radius 1 mm, 1000 turns (P1000): 6.28 m of path.
        let mut cost = Cost::default();
        cost.add(&Block {
            line: 3,
            column: 1,
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
        // Every 11.25° (32 a turn) is more than every 0.5 mm of a 6.28 mm circle.
        assert_eq!(cost.points, 32_000);
    }

    #[test]
    fn the_bounds_are_said_when_passed() {
        let bounds = Bounds {
            max_moves: 2,
            max_bytes: 16 << 20,
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
        let why = long.beyond(&bounds).expect("200 000 points pass 16 MiB");
        assert!(
            why.starts_with("the program's plan would take more than 16 MiB (the bound: nc.max_plan_mib): 1 actions so far, and a velocity profile of 200000 points"),
            "{why}"
        );
    }
}
