//! Motion: the motion mode (G0 G1 G2 G3, the canned cycles, G80's cancel), machine
//! coordinates for one block (G53), and each move — a straight line, or an arc by its centre or
//! radius, helical where the block moves the axis normal to its plane.

use crate::NcError;
use crate::lexer::Word;

use super::block::{Action, Blend, Block, Path, Plane, Pose};
use super::modes::stops;
use super::state::State;
use super::words::{Words, count};

/// The least radius of an arc, and how far past half its chord an R may fall short (mm; LinuxCNC's
/// `RADIUS_TOLERANCE`, 0.00005 in).
const RADIUS_TOLERANCE_MM: f64 = 0.00005 * 25.4;
/// How far the radius at an arc's end may differ from the radius at its start (mm; LinuxCNC's
/// `CENTER_ARC_RADIUS_TOLERANCE_MM`, 2 · 0.01 · √2), or in inch programs (inches) …
pub(super) const SPIRAL_TOLERANCE_MM: f64 = 2.0 * 0.01 * std::f64::consts::SQRT_2;
pub(super) const SPIRAL_TOLERANCE_INCH: f64 = 2.0 * 0.001 * std::f64::consts::SQRT_2;
/// … or, up to a hundred times that, this share of the radius (LinuxCNC's
/// `SPIRAL_RELATIVE_TOLERANCE`). Within them the arc is traced as a spiral from the start's
/// radius to the end's, as LinuxCNC traces it.
const SPIRAL_RELATIVE_TOLERANCE: f64 = 0.001;

impl State<'_> {
    /// The motion the block makes, if any: its motion code, or with axis words alone the mode
    /// in force (G80 in the block makes none).
    pub(super) fn motion_now(&self, words: &Words<'_>) -> Option<u16> {
        // Polar coordinates (@, ^) are axis words as X and Y are.
        let has_axis_word =
            super::block::AXES.iter().any(|a| words.get(*a).is_some()) || words.polar().iter().any(Option::is_some);
        // G28, G30, G52 and G92 take the block's axis words: the motion mode makes no move.
        if words.uses_axis_words() {
            return words.motion_word().map(|(c, _)| c);
        }
        match words.motion_word() {
            Some((c, _)) => Some(c),
            None if has_axis_word && !words.has_g(800) => self.motion,
            None => None,
        }
    }

    /// The block's motion: G80, the motion mode, a canned cycle, or a move (G53 with it), then
    /// its program stops.
    pub(super) fn motion(&mut self, words: &Words<'_>, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let get = |letter: char| words.get(letter);
        let motion_word = words.motion_word();
        let cycle_now = self.motion_now(words).is_some_and(super::words::is_cycle);
        let axis_words = words.axis_words();
        let machine_coords = words.has_g(530);
        let polar = words.polar();
        if words.has_g(800) {
            // G80 (canned cycle cancel) sets no motion mode; CAM programs write it in their
            // preamble.
            if let Some((_, a)) = axis_words.first() {
                return Err(at(
                    a,
                    "axis words cannot go with G80 (it cancels the motion mode; G80 does not)".into(),
                ));
            }
            self.motion = None;
            self.cycle_initial = None;
        }
        let previous_motion = self.motion;
        if let Some((code, _)) = motion_word {
            self.motion = Some(code);
        }
        if cycle_now {
            let code_word = motion_word.map_or(words.first, |(_, w)| w);
            self.refuse_while_compensating(line, code_word, "canned cycles cannot run")?;
            if let Some(w) = words.g_word(530) {
                return Err(at(w, "G53 goes with a G0 or G1 move in this block".into()));
            }
            let first = axis_words.first().map_or(words.first, |(_, w)| *w);
            let code = self.motion.unwrap_or_default();
            return self.cycle(
                line,
                code,
                previous_motion,
                first,
                &get,
                &axis_words,
                polar,
                &words.m,
                out,
            );
        }
        // An arc without axis words but with its centre is a full circle where the tool stands.
        let full_circle = matches!(motion_word, Some((20 | 30, _))) && axis_words.is_empty() && {
            let [o0, o1] = self.plane.offsets();
            get(o0).is_some() || get(o1).is_some()
        };
        let moves =
            !words.uses_axis_words() && (!axis_words.is_empty() || polar.iter().any(Option::is_some) || full_circle);
        if let Some(w) = words.g_word(530) {
            if !matches!(self.motion, Some(0 | 10)) || !moves {
                return Err(at(w, "G53 goes with a G0 or G1 move in this block".into()));
            }
            if self.incremental {
                return Err(at(w, "G53 needs absolute distances (G90)".into()));
            }
            if self.offsetting() {
                return Err(at(
                    w,
                    "G53 (machine coordinates) cannot go with cutter compensation (G41, G42): end it with G40 first"
                        .into(),
                ));
            }
        }
        // G0 or G1 alone sets the motion mode for the lines that follow (LinuxCNC's meaning);
        // an arc alone needs its centre.
        if let Some((50 | 51, w)) = motion_word
            && !moves
            && !words.uses_axis_words()
        {
            return Err(at(w, "a spline (G5, G5.1) needs its end: X, Y".into()));
        }
        if let Some((20 | 30, w)) = motion_word
            && !moves
            && !words.uses_axis_words()
        {
            let [o0, o1] = self.plane.offsets();
            return Err(at(
                w,
                format!("an arc needs its centre ({o0} {o1}) or its end and radius (R)"),
            ));
        }
        if moves {
            self.cycle_initial = None;
            let first = axis_words.first().map(|(_, w)| *w).or(polar[0]).or(polar[1]);
            let Some(mode) = self.motion else {
                return Err(at(
                    first.unwrap_or(words.first),
                    "an axis word needs a motion mode: G0, G1, G2 or G3 first".into(),
                ));
            };
            let mut to = self.target(&axis_words, machine_coords);
            if polar.iter().any(Option::is_some) {
                to = self.polar_target(line, polar, to)?;
            }
            let first = first.unwrap_or_else(|| motion_word.map(|(_, w)| w).unwrap_or(words.first));
            let code_word = motion_word.map_or(first, |(_, w)| w);
            if matches!(mode, 50 | 51) {
                self.refuse_while_compensating(
                    line,
                    code_word,
                    "a spline (G5, G5.1) cannot be compensated (a CAM post can write its contour as lines and arcs)",
                )?;
            }
            if matches!(mode, 20 | 30 | 50 | 51) && self.arc_after_comp {
                return Err(at(
                    code_word,
                    "the move after G40 (cutter compensation off) must be a straight one (G0, G1), as in LinuxCNC: an arc would start off its circle".into(),
                ));
            }
            self.arc_after_comp = false;
            if matches!(mode, 50 | 51) {
                self.spline(line, words, mode == 50, to, first, out)?;
                stops(line, &words.m, out);
                return Ok(());
            }
            // While cutter compensation offsets the moves, the programmed path runs from the
            // programmed point, and the feed is the programmed move's (as LinuxCNC's).
            let from = self.base();
            let path = match mode {
                0 | 10 => Path::Line,
                _ => self.arc(line, first, mode == 20, &from, &to, &get)?,
            };
            let feed = match mode {
                0 => None,
                _ => {
                    let length = crate::path::Segment::new(from, to, path).length();
                    Some(self.feed_of(length, first, line, "G1, G2 or G3")?)
                }
            };
            if self.offsetting() {
                let arc = match path {
                    Path::Arc {
                        center,
                        clockwise,
                        extra_turns,
                        ..
                    } => {
                        let turns = i32::try_from(extra_turns + 1).unwrap_or(i32::MAX);
                        Some((center, if clockwise { -turns } else { turns }))
                    }
                    Path::Line => None,
                };
                let programmed = super::compensation::Programmed {
                    to,
                    arc,
                    rapid: mode == 0,
                    feed,
                };
                self.compensated_move(line, first, &programmed, out)?;
                stops(line, &words.m, out);
                return Ok(());
            }
            self.push_move(line, to, path, feed, self.blend, out);
        }
        stops(line, &words.m, out);
        Ok(())
    }

    /// Adds a move of line `line` from where the tool is to `to` along `path` at `feed` (`None`:
    /// a rapid), ending as `blend` says; the tool is there after it.
    pub(super) fn push_move(
        &mut self,
        line: usize,
        to: Pose,
        path: Path,
        feed: Option<f64>,
        blend: Blend,
        out: &mut Vec<Block>,
    ) {
        out.push(Block {
            line,
            column: 1,
            action: Action::Move {
                from: self.position,
                to,
                path,
                feed_mm_min: feed,
                blend,
            },
        });
        self.position = to;
    }

    /// The arc from the current position to `to`, by its centre (I J K) or radius (R).
    /// Refuses polar coordinates (@, ^) where LinuxCNC does — on a machine without X and Y, in
    /// another plane than G17, beside X or Y, with G53 — and where we do not take them: with a
    /// code that takes the block's axis words (G10, G28, G92, …). Called
    /// before the block changes the plane: LinuxCNC checks the plane in force before it (a
    /// `G18 G0 @5 ^30` moves in XY).
    pub(super) fn check_polar(&self, words: &Words<'_>) -> Result<(), NcError> {
        let [distance, angle] = words.polar();
        let Some(p) = distance.or(angle) else {
            return Ok(());
        };
        let machine_coords = words.has_g(530);
        let at = |w: &Word, message: &str| Err(NcError::new(words.line, w.column, message.to_string()));
        let has = |axis: &str| self.machine.axes.iter().any(|a| a.eq_ignore_ascii_case(axis));
        if !(has("x") && has("y")) {
            return at(p, "polar coordinates (@, ^) need a machine with X and Y axes");
        }
        if self.plane != Plane::Xy {
            return at(p, "polar coordinates (@, ^) are taken in the XY plane only (G17)");
        }
        for letter in ['X', 'Y'] {
            if let Some(w) = words.get(letter) {
                return at(
                    w,
                    &format!("{letter} and polar coordinates (@, ^) in one block: the end is one or the other"),
                );
            }
        }
        if machine_coords {
            return at(p, "polar coordinates (@, ^) cannot go with G53 (machine coordinates)");
        }
        if let Some(code) = words.axis_word_taker() {
            return at(
                p,
                &format!(
                    "polar coordinates (@, ^) give a move's end (G0, G1, G2, G3), not {}'s values",
                    super::words::format_code('G', code)
                ),
            );
        }
        Ok(())
    }

    /// The end of a move written in polar coordinates, as LinuxCNC takes them: the distance (@)
    /// and the angle (^, degrees counter-clockwise from +X) around the program's origin. In G90
    /// they give the end; either alone keeps the other as the tool's position has it. In G91
    /// the distance lengthens the tool's own, the angle turns it on. X and Y of `to` are
    /// replaced; the other axes stay as `to` has them.
    fn polar_target(&self, line: usize, polar: [Option<&Word>; 2], mut to: Pose) -> Result<Pose, NcError> {
        let offset = self.offset();
        let base = self.base();
        let (mut x, mut y) = (base[0] - offset[0], base[1] - offset[1]);
        let indeterminate = |w: &Word, message: &str| Err(NcError::new(line, w.column, message.to_string()));
        let [distance, angle] = polar;
        let distance_mm = distance.map(|w| w.value * self.scale(0));
        let angle_rad = angle.map(|w| w.value.to_radians());
        if self.incremental {
            if let (Some(w), Some(d)) = (distance, distance_mm) {
                if x == 0.0 && y == 0.0 {
                    return indeterminate(
                        w,
                        "an incremental polar move (G91 @) has no direction at the program's origin: move off it, or use G90",
                    );
                }
                let (r, t) = (x.hypot(y) + d, y.atan2(x));
                (x, y) = (r * t.cos(), r * t.sin());
            }
            if let (Some(w), Some(a)) = (angle, angle_rad) {
                if x == 0.0 && y == 0.0 {
                    return indeterminate(
                        w,
                        "an incremental polar move (G91 ^) turns nothing at the program's origin: move off it, or use G90",
                    );
                }
                let (r, t) = (x.hypot(y), y.atan2(x) + a);
                (x, y) = (r * t.cos(), r * t.sin());
            }
        } else {
            let r = match (distance, distance_mm) {
                (_, Some(d)) => d,
                _ => x.hypot(y),
            };
            let t = match (angle_rad, distance) {
                (Some(a), _) => a,
                (None, Some(w)) if x == 0.0 && y == 0.0 => {
                    return indeterminate(
                        w,
                        "a distance (@) alone needs an angle (^) where the tool stands at the program's origin",
                    );
                }
                _ => y.atan2(x),
            };
            (x, y) = (r * t.cos(), r * t.sin());
        }
        to[0] = x + offset[0];
        to[1] = y + offset[1];
        Ok(to)
    }

    pub(super) fn arc<'w>(
        &self,
        line: usize,
        first: &Word,
        clockwise: bool,
        from: &Pose,
        to: &Pose,
        get: &dyn Fn(char) -> Option<&'w Word>,
    ) -> Result<Path, NcError> {
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let [a0, a1, _] = self.plane.axes();
        let (s, e) = ([from[a0], from[a1]], [to[a0], to[a1]]);
        let turns = count(get('P'), 1000).map_err(|p| {
            at(
                p,
                format!(
                    "an arc's P is its number of turns, a whole number from 1, got {}",
                    p.value
                ),
            )
        })?;
        let [o0, o1] = self.plane.offsets();
        let plane_name = match self.plane {
            Plane::Xy => "G17 (X–Y)",
            Plane::Zx => "G18 (Z–X)",
            Plane::Yz => "G19 (Y–Z)",
        };
        for letter in ['I', 'J', 'K'] {
            if letter != o0
                && letter != o1
                && let Some(w) = get(letter)
            {
                return Err(at(
                    w,
                    format!("{letter} is not an offset of an arc in {plane_name}: use {o0} and {o1}"),
                ));
            }
        }
        let center = match (get('R'), get(o0), get(o1)) {
            (Some(r), None, None) => {
                let radius = r.value * self.unit();
                let chord = [e[0] - s[0], e[1] - s[1]];
                let d = chord[0].hypot(chord[1]);
                if d < 1e-9 {
                    return Err(at(r, "a full circle is given by its centre (I J K), not by R".into()));
                }
                if radius.abs() < d / 2.0 - RADIUS_TOLERANCE_MM {
                    return Err(at(
                        r,
                        format!(
                            "the radius {} mm is shorter than half the chord ({:.4} mm)",
                            radius.abs(),
                            d / 2.0
                        ),
                    ));
                }
                let h = (radius * radius - d * d / 4.0).max(0.0).sqrt();
                // The centre lies to the left of the chord for a short counter-clockwise arc;
                // a negative R asks for the long arc (more than half a turn).
                let left = !clockwise ^ (radius < 0.0);
                let sign = if left { 1.0 } else { -1.0 };
                let mid = [(s[0] + e[0]) / 2.0, (s[1] + e[1]) / 2.0];
                [mid[0] - sign * h * chord[1] / d, mid[1] + sign * h * chord[0] / d]
            }
            (Some(r), _, _) => return Err(at(r, "an arc has a radius (R) or a centre (I J K), not both".into())),
            (None, None, None) => {
                return Err(at(
                    first,
                    format!("an arc needs its centre ({o0} {o1}) or its radius (R)"),
                ));
            }
            (None, i, j) => {
                let c = if self.arc_absolute {
                    // G90.1: the centre in program coordinates, both of its words given.
                    let (Some(i), Some(j)) = (i, j) else {
                        return Err(at(
                            first,
                            format!("in G90.1 (absolute arc centres) an arc needs both {o0} and {o1}"),
                        ));
                    };
                    let offset = self.offset();
                    [i.value * self.unit() + offset[a0], j.value * self.unit() + offset[a1]]
                } else {
                    [
                        s[0] + i.map_or(0.0, |w| w.value) * self.unit(),
                        s[1] + j.map_or(0.0, |w| w.value) * self.unit(),
                    ]
                };
                let r_start = (s[0] - c[0]).hypot(s[1] - c[1]);
                let r_end = (e[0] - c[0]).hypot(e[1] - c[1]);
                if r_start < 1e-9 {
                    return Err(at(first, "the arc's centre is its start point".into()));
                }
                if r_start < RADIUS_TOLERANCE_MM || r_end < RADIUS_TOLERANCE_MM {
                    return Err(at(
                        first,
                        format!(
                            "the arc's radius is {r_start:.5} mm at the start and {r_end:.5} mm at the end: below {RADIUS_TOLERANCE_MM} mm an arc has no radius (as LinuxCNC reads it)"
                        ),
                    ));
                }
                // As LinuxCNC compares them: in the program's units.
                let tolerance = if self.unit() == 1.0 {
                    SPIRAL_TOLERANCE_MM
                } else {
                    SPIRAL_TOLERANCE_INCH * self.unit()
                };
                let differs = (r_start - r_end).abs();
                let relative = differs / r_start.max(r_end);
                if differs > 100.0 * tolerance || (relative > SPIRAL_RELATIVE_TOLERANCE && differs > tolerance) {
                    return Err(at(
                        first,
                        format!(
                            "the arc's end is not on its circle: radius {r_start:.4} mm at the start, {r_end:.4} mm at the end (LinuxCNC allows {tolerance:.4} mm, or {}% of the radius)",
                            SPIRAL_RELATIVE_TOLERANCE * 100.0
                        ),
                    ));
                }
                c
            }
        };
        Ok(Path::Arc {
            plane: self.plane,
            center,
            clockwise,
            extra_turns: turns - 1,
        })
    }
}
