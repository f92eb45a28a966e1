//! The canned cycles G73, G81, G82, G83, G85 and G89 as LinuxCNC makes them: the values that carry from block to
//! block of a series, and each cycle's moves.

use crate::NcError;
use crate::lexer::Word;

use super::block::{AXES, Action, Blend, Block, MAX_DWELL_S};
use super::modes::stops;
use super::state::{Cycle, FeedMode, State};
use super::words::{count, format_code};

/// What a canned cycle's block asks for (program units, as written).
struct Asked {
    /// The feed of its cuts (mm/min).
    feed: f64,
    /// The retract plane R.
    r: f64,
    /// The bottom of the hole (the plane's normal coordinate).
    bottom: f64,
    /// The dwell at the bottom (G82, s).
    dwell: f64,
    /// The depth of each peck (G73, G83).
    peck: f64,
    /// How many times it runs (L).
    repeats: u32,
}

/// How far above the bottom of the last peck a G83 rapid returns, and how far G73 retracts to
/// break the chip (mm): LinuxCNC 2.9's `G83_RAPID_DELTA` and `G73_RETRACTION`, 0.010 inch.
const PECK_CLEARANCE_MM: f64 = 0.254;

impl State<'_> {
    /// A canned cycle (G73, G81, G82, G83, G85, G89: `code`) at the block's position, as LinuxCNC's
    /// `convert_cycle_xy` (and its other planes) makes it: up to the R plane if below it, over
    /// the hole, down to R, the cycle, back to the clearance level (R in G99, the series'
    /// starting height in G98); L times. Every move stops exactly at its end.
    ///
    /// Long, and kept whole: the cycle's moves are made by one closure over the position being
    /// built, which every part of the cycle (the approach, each repeat, each peck) calls.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn cycle<'w>(
        &mut self,
        line: usize,
        code: u16,
        previous: Option<u16>,
        first: &Word,
        get: &dyn Fn(char) -> Option<&'w Word>,
        axis_words: &[(usize, &Word)],
        polar: [Option<&Word>; 2],
        m: &[(u16, &Word)],
        out: &mut Vec<Block>,
    ) -> Result<(), NcError> {
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let name = format_code('G', code);
        let [a0, a1, n] = self.plane.axes();
        let normal = AXES[n];
        let Asked {
            feed,
            r: r_given,
            bottom: bottom_given,
            dwell,
            peck,
            repeats,
        } = self.asked(line, code, previous, first, get, axis_words)?;
        // In program coordinates: a0, a1 the plane's axes, n its normal (Z in G17).
        let mut p = self.program_position();
        let initial = *self.cycle_initial.get_or_insert(p[n]);
        let given = |c: usize| axis_words.iter().find(|(k, _)| *k == c).map(|(_, w)| w.value);
        // Polar coordinates (G17 only, checked with the block): the distance (@, in program
        // units as the cycle's other words) and the angle (^, radians here) around the
        // program's origin.
        let [distance_word, angle_word] = polar;
        let distance = distance_word.map(|w| w.value);
        let angle = angle_word.map(|w| w.value.to_radians());
        let (mut aa, mut bb, step, r, bottom);
        if self.incremental {
            step = [given(a0).unwrap_or(0.0), given(a1).unwrap_or(0.0)];
            r = r_given + initial;
            bottom = r + bottom_given;
            (aa, bb) = (p[a0], p[a1]);
        } else {
            step = [0.0, 0.0];
            (r, bottom) = (r_given, bottom_given);
            (aa, bb) = (given(a0).unwrap_or(p[a0]), given(a1).unwrap_or(p[a1]));
            if distance.is_some() || angle.is_some() {
                // Either alone keeps the other as the tool's position has it.
                let radius = distance.unwrap_or_else(|| p[a1].hypot(p[a0]));
                let theta = angle.unwrap_or_else(|| p[a1].atan2(p[a0]));
                (aa, bb) = (radius * theta.cos(), radius * theta.sin());
            }
        }
        // In G91 each repeat lengthens the position's distance from the origin by @ and turns
        // it by ^ (a bolt circle: `G91 G81 ^60 L6`), as LinuxCNC does.
        let polar_step = |aa: f64, bb: f64| -> Result<(f64, f64), NcError> {
            let (mut aa, mut bb) = (aa, bb);
            for (word, lengthen, turn) in [(distance_word, distance, None), (angle_word, None, angle)] {
                let Some(word) = word else { continue };
                if aa == 0.0 && bb == 0.0 {
                    return Err(at(
                        word,
                        format!(
                            "{name}: an incremental polar step (G91 @, ^) has no direction at the program's origin: move off it, or use G90"
                        ),
                    ));
                }
                let radius = bb.hypot(aa) + lengthen.unwrap_or(0.0);
                let theta = bb.atan2(aa) + turn.unwrap_or(0.0);
                (aa, bb) = (radius * theta.cos(), radius * theta.sin());
            }
            Ok((aa, bb))
        };
        if r < bottom {
            return Err(at(
                get('R').unwrap_or(first),
                format!("{name}: the retract plane R ({r}) is below the bottom {normal} ({bottom})"),
            ));
        }
        let mut old = initial;
        let mut current = p[n];
        let here = [p[a0], p[a1]];
        let feed = Some(feed);
        let mut go = |this: &mut Self, out: &mut Vec<Block>, point: [f64; 3], feed: Option<f64>| {
            (p[a0], p[a1], p[n]) = (point[0], point[1], point[2]);
            // Over the hole when the tool is there already, a move goes nowhere: none is made.
            this.line_to(line, this.machine_position(&p), feed, Blend::ExactStop, out);
        };
        // Below the R plane: straight up to it first.
        if old < r {
            go(self, out, [here[0], here[1], r], None);
            old = r;
            current = r;
        }
        let clear = if self.retract_to_r { r } else { old };
        let unit = self.unit();
        // A cycle's repeats and pecks make moves before the program's cost is counted: bounded
        // here, so that a tiny Q or a large L cannot fill the memory within one block.
        let (room, max_moves) = (
            self.bounds.max_moves.saturating_sub(self.cost.moves),
            self.bounds.max_moves,
        );
        let full = |out: &Vec<Block>| {
            (out.len() > room).then(|| {
                at(
                    first,
                    format!(
                        "{name}: the cycle makes more than the {max_moves} moves the program may make (the bound: nc.max_moves): fewer repeats L, or a deeper peck Q"
                    ),
                )
            })
        };
        for turn in 0..repeats {
            if let Some(e) = full(out) {
                return Err(e);
            }
            if self.incremental {
                (aa, bb) = polar_step(aa, bb)?;
            }
            aa += step[0];
            bb += step[1];
            if turn == 0 && current > r {
                go(self, out, [aa, bb, current], None);
                go(self, out, [aa, bb, r], None);
            } else {
                go(self, out, [aa, bb, clear], None);
                if clear > r {
                    go(self, out, [aa, bb, r], None);
                }
            }
            if matches!(code, 730 | 830) {
                let mut depth = r - peck;
                while depth > bottom {
                    if let Some(e) = full(out) {
                        return Err(e);
                    }
                    go(self, out, [aa, bb, depth], feed);
                    if code == 830 {
                        // G83: out of the hole to R, then back down to just above the peck.
                        go(self, out, [aa, bb, r], None);
                    }
                    // G73 breaks the chip with a short rapid up; G83 comes back down to here.
                    go(self, out, [aa, bb, depth + PECK_CLEARANCE_MM / unit], None);
                    depth -= peck;
                }
            }
            go(self, out, [aa, bb, bottom], feed);
            if matches!(code, 820 | 890) {
                out.push(Block {
                    line,
                    column: 1,
                    action: Action::Dwell(dwell),
                });
            }
            if matches!(code, 850 | 890) {
                // A bore: out of the hole at the feed, to R.
                go(self, out, [aa, bb, r], feed);
            }
            go(self, out, [aa, bb, clear], None);
        }
        self.cycle = Cycle {
            r: r_given,
            bottom: bottom_given,
            dwell,
            peck,
        };
        stops(line, m, out);
        Ok(())
    }

    /// The values of canned cycle `code` this block asks for: its own words, else (continuing the
    /// same cycle) the last block's; each checked.
    fn asked<'w>(
        &self,
        line: usize,
        code: u16,
        previous: Option<u16>,
        first: &Word,
        get: &dyn Fn(char) -> Option<&'w Word>,
        axis_words: &[(usize, &Word)],
    ) -> Result<Asked, NcError> {
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let name = format_code('G', code);
        let [_, _, n] = self.plane.axes();
        if let Some((_, w)) = axis_words.iter().find(|(c, _)| *c >= 3) {
            return Err(at(
                w,
                format!("{name} moves X Y Z only: {} cannot move in a canned cycle", w.letter),
            ));
        }
        if self.feed_mode == FeedMode::InverseTime {
            return Err(at(
                first,
                format!("{name} cannot run in inverse time (G93), as in LinuxCNC: G94 or G95 first"),
            ));
        }
        let feed = self.feed_of(0.0, first, line, &name)?;
        // The values that carry from the cycle's last block when it continues.
        let same = previous == Some(code);
        let normal = AXES[n];
        let carried = |letter: char, last: f64, what: &str| match get(letter) {
            Some(w) => Ok(w.value),
            None if same => Ok(last),
            None => Err(at(first, format!("{name} needs {letter}, {what}"))),
        };
        let r_given = carried('R', self.cycle.r, "the retract plane")?;
        let bottom_given = carried(normal, self.cycle.bottom, "the bottom of the hole")?;
        let dwell = if matches!(code, 820 | 890) {
            let p = carried('P', self.cycle.dwell, "the dwell at the bottom in seconds")?;
            if !(0.0..=MAX_DWELL_S).contains(&p) {
                return Err(at(
                    get('P').unwrap_or(first),
                    format!("the dwell P must be between 0 and {MAX_DWELL_S} s, got {p}"),
                ));
            }
            p
        } else {
            self.cycle.dwell
        };
        let peck = if matches!(code, 730 | 830) {
            let q = carried('Q', self.cycle.peck, "the depth of each peck")?;
            if q <= 0.0 {
                return Err(at(
                    get('Q').unwrap_or(first),
                    format!("the peck depth Q must be positive, got {q}"),
                ));
            }
            q
        } else {
            self.cycle.peck
        };
        let repeats = count(get('L'), 10_000).map_err(|l| {
            at(
                l,
                format!(
                    "L, the number of repeats, is a whole number from 1 to 10000, got {}",
                    l.value
                ),
            )
        })?;
        Ok(Asked {
            feed,
            r: r_given,
            bottom: bottom_given,
            dwell,
            peck,
            repeats,
        })
    }
}
