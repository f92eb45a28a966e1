//! Cutter radius compensation (G40, G41, G42, G41.1, G42.1) as LinuxCNC 2.9's interpreter makes
//! it (`convert_straight_comp1/2`, `convert_arc_comp1/2`, `move_endpoint_and_flush`): the
//! program's path is the part's contour, and the tool's centre runs one tool radius to its left
//! (G41) or right (G42) in the XY (G17) or ZX (G18) plane.
//!
//! Where a move's compensated end lies depends on the move after it (a concave corner moves the
//! end back; a convex one adds an arc around the corner), so the last compensated moves stay
//! open: their ends are changed in place, in the program's list of actions, when the next move
//! comes. Unlike LinuxCNC, whose queue lets messages, pauses and tool calls overtake the moves
//! it holds back, every action keeps the program's order; and an M0 or M1 between two
//! compensated moves does not close the corner (LinuxCNC then gouges a concave one).

use crate::NcError;
use crate::lexer::Word;

use super::block::{Action, Block, Path, Plane, Pose};
use super::compensation::{Compensation, Open, OpenKind, Programmed, Side};
use super::state::State;
use super::words::{Words, format_code};

/// The angle within which two directions are taken as one corner-free path, or a corner as a
/// reversal (rad; LinuxCNC's `TOLERANCE_CONCAVE_CORNER`).
const SMALL: f64 = 0.05;
/// LinuxCNC's `TOLERANCE_EQUAL`.
const TOLERANCE_EQUAL: f64 = 0.0001;
const PI: f64 = std::f64::consts::PI;
const HALF_PI: f64 = std::f64::consts::FRAC_PI_2;

/// The plane coordinates of `p`.
fn in_plane(p: &Pose, plane: Plane) -> [f64; 2] {
    let [a, b, _] = plane.axes();
    [p[a], p[b]]
}

/// `p` with its plane coordinates `v`.
fn with_plane(mut p: Pose, plane: Plane, v: [f64; 2]) -> Pose {
    let [a, b, _] = plane.axes();
    p[a] = v[0];
    p[b] = v[1];
    p
}

fn polar(from: [f64; 2], length: f64, angle: f64) -> [f64; 2] {
    [from[0] + length * angle.cos(), from[1] + length * angle.sin()]
}

fn angle(from: [f64; 2], to: [f64; 2]) -> f64 {
    (to[1] - from[1]).atan2(to[0] - from[0])
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The signed sweep (rad, counter-clockwise positive) of an arc of `turn` turns from `from` to
/// `to` around `center` (LinuxCNC's `find_turn`).
fn sweep(from: [f64; 2], center: [f64; 2], turn: i32, to: [f64; 2]) -> f64 {
    if turn == 0 {
        return 0.0;
    }
    let (mut alpha, mut beta) = (angle(center, from), angle(center, to));
    if turn > 0 {
        if beta <= alpha {
            beta += 2.0 * PI;
        }
        beta - alpha + f64::from(turn - 1) * 2.0 * PI
    } else {
        if alpha <= beta {
            alpha += 2.0 * PI;
        }
        beta - alpha + f64::from(turn + 1) * 2.0 * PI
    }
}

/// Whether the tool runs inside an arc of `turn` (LinuxCNC's `TOOL_INSIDE_ARC`).
fn inside(side: Side, turn: i32) -> bool {
    (side == Side::Left && turn > 0) || (side == Side::Right && turn < 0)
}

impl State<'_> {
    /// Whether compensation is on (G41, G42), whether or not its tool has a radius.
    pub(super) fn compensating(&self) -> bool {
        self.comp.is_some()
    }

    /// Whether the moves are offset now: compensation is on with a tool that has a radius.
    pub(super) fn offsetting(&self) -> bool {
        self.comp.as_ref().is_some_and(|c| c.radius > 0.0)
    }

    /// Where a move's unnamed coordinates and incremental distances start: the programmed
    /// point while the moves are offset (the tool is off the path), else where the tool is.
    pub(super) fn base(&self) -> Pose {
        self.comp
            .as_ref()
            .and_then(|c| c.programmed.filter(|_| c.radius > 0.0))
            .unwrap_or(self.position)
    }

    /// Refuses `word` (`what` it does) while compensation is on, as LinuxCNC refuses it.
    pub(super) fn refuse_while_compensating(&self, line: usize, word: &Word, what: &str) -> Result<(), NcError> {
        if self.compensating() {
            return Err(NcError::new(
                line,
                word.column,
                format!("{what} while cutter compensation (G41, G42) is on: end it with G40 first"),
            ));
        }
        Ok(())
    }

    /// G40, G41, G42, G41.1, G42.1 (after the plane and the units, before the offsets, as
    /// LinuxCNC converts them).
    pub(super) fn compensation(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        if words.has_g(400) {
            if let Some(comp) = self.comp.take()
                && comp.radius > 0.0
                && let Some(programmed) = comp.programmed
            {
                // The tool stays where it is; the next move (straight: LinuxCNC's rule) leaves
                // the compensated path from there, and is read from the programmed point.
                self.comp_exit = Some(self.position);
                self.position = programmed;
                self.arc_after_comp = true;
            }
            return Ok(());
        }
        let Some((code, w)) = words.g.iter().find(|(c, _)| matches!(c, 410 | 411 | 420 | 421)) else {
            return Ok(());
        };
        let name = format_code('G', *code);
        if self.comp.is_some() {
            return Err(at(w, format!("cutter compensation is on already: G40 before {name}")));
        }
        if self.plane == Plane::Yz {
            return Err(at(
                w,
                "cutter compensation works in the XY (G17) and ZX (G18) planes, not in G19 (as LinuxCNC's)".into(),
            ));
        }
        let mut side = if matches!(code, 410 | 411) {
            Side::Left
        } else {
            Side::Right
        };
        let d = words.get('D');
        let radius = if matches!(code, 411 | 421) {
            let d = d.ok_or_else(|| at(w, format!("{name} needs D: the tool's diameter")))?;
            d.value * self.unit() / 2.0
        } else {
            let number = match d {
                Some(d) => {
                    let near = d.value.round();
                    if (near - d.value).abs() >= 0.0001 || near < 0.0 {
                        return Err(at(
                            d,
                            format!(
                                "{name}'s D is the number of a tool of the table, a whole number from 0: got {} (G41.1, G42.1 take a diameter)",
                                d.value
                            ),
                        ));
                    }
                    near as u32
                }
                None => 0,
            };
            // D0 or none: the tool in the spindle, as LinuxCNC takes it.
            let tool = if number == 0 {
                self.in_spindle.ok_or_else(|| {
                    at(
                        d.unwrap_or(w),
                        format!(
                            "{name} without a tool number compensates for the tool in the spindle, and this program has not put one there (T… M6, or M61 Q…): write {name} D…"
                        ),
                    )
                })?
            } else {
                number
            };
            if tool == 0 {
                0.0
            } else {
                let entry = self.tool_entry(line, d.unwrap_or(w), &format!("{name} D{tool}"), tool)?;
                if !matches!(entry.orientation, 0 | 9) {
                    return Err(at(
                        d.unwrap_or(w),
                        format!(
                            "{name}: tool {tool} is a lathe tool (orientation Q{}): its compensation about the tool's nose is not supported here, only a milling tool's (Q0 or none)",
                            entry.orientation
                        ),
                    ));
                }
                entry.diameter / 2.0
            }
        };
        // A negative diameter (a tool smaller than the one the path was made for) puts the
        // tool on the other side.
        if radius < 0.0 {
            side = if side == Side::Left { Side::Right } else { Side::Left };
        }
        self.comp = Some(Compensation {
            side,
            radius: radius.abs(),
            programmed: None,
            open: Vec::new(),
            start: None,
        });
        Ok(())
    }

    /// After the program's action at `index` was moved to make room for another: the open
    /// moves' indices follow.
    pub(super) fn inserted_action(&mut self, index: usize) {
        if let Some(comp) = &mut self.comp {
            for open in &mut comp.open {
                if open.index >= index {
                    open.index += 1;
                }
            }
        }
    }

    /// The compensated path of a move to `p.to` (G0, G1, G2, G3 while the moves are offset).
    /// `word`: where its errors point.
    pub(super) fn compensated_move(
        &mut self,
        line: usize,
        word: &Word,
        p: &Programmed,
        out: &mut Vec<Block>,
    ) -> Result<(), NcError> {
        let first = self.comp.as_ref().is_some_and(|c| c.programmed.is_none());
        let result = match (p.arc, first) {
            (None, true) => self.entry_line(line, p, out),
            (None, false) => self.next_line(line, p, out),
            (Some(arc), true) => self.entry_arc(line, p, arc, out),
            (Some(arc), false) => self.next_arc(line, p, arc, out),
        };
        result.map_err(|why| NcError::new(line, word.column, why))
    }

    fn comp(&self) -> &Compensation {
        match &self.comp {
            Some(c) => c,
            None => unreachable!("compensated moves are made only while compensation is on"),
        }
    }

    fn comp_mut(&mut self) -> &mut Compensation {
        match &mut self.comp {
            Some(c) => c,
            None => unreachable!("compensated moves are made only while compensation is on"),
        }
    }

    /// Adds a move from where the tool is to `to` and leaves it open.
    fn open_move(
        &mut self,
        line: usize,
        to: Pose,
        path: Path,
        feed: Option<f64>,
        kind: OpenKind,
        out: &mut Vec<Block>,
    ) {
        self.push_move(line, to, path, feed, self.blend, out);
        let index = out.len() - 1;
        self.comp_mut().open.push(Open { index, kind });
    }

    /// Closes the open moves where they end; `start`: where the next open move starts (LinuxCNC's
    /// `set_endpoint`).
    fn close(&mut self, start: [f64; 2]) {
        let comp = self.comp_mut();
        comp.open.clear();
        comp.start = Some(start);
    }

    /// The pose at the end of the arc around a convex corner (`mid` in the plane): the normal
    /// coordinate where the tool is, the rotations where the move ends (LinuxCNC turns them on
    /// the corner's arc).
    fn corner_end(&self, mid: [f64; 2], p: &Programmed) -> Pose {
        let corner = with_plane(self.position, self.plane, mid);
        std::array::from_fn(|k| if k >= 3 { p.to[k] } else { corner[k] })
    }

    /// Moves the open moves' ends (in the plane) to `to` and closes them (LinuxCNC's
    /// `move_endpoint_and_flush`), refusing a move that would then run backwards (a gouge).
    fn move_end_and_close(&mut self, to: [f64; 2], out: &mut [Block]) -> Result<(), String> {
        let plane = self.plane;
        let inch = self.inches;
        let radius = self.comp().radius;
        let (open, start) = (self.comp().open.clone(), self.comp().start);
        for (k, o) in open.iter().enumerate() {
            let Action::Move {
                from, to: end, path, ..
            } = &mut out[o.index].action
            else {
                unreachable!("an open action is a move");
            };
            match (o.kind, *path) {
                (OpenKind::Arc { turn, sweep: original }, Path::Arc { center, .. }) => {
                    let r1 = distance(in_plane(end, plane), center);
                    let r2 = distance(to, center);
                    if (r1 - r2).abs() > 0.01 {
                        return Err(format!(
                            "cutter compensation cannot join this move to the arc before it: the arc's end would leave its circle by {:.3} mm",
                            (r1 - r2).abs()
                        ));
                    }
                    if let Some(s) = start {
                        let swept = sweep(s, center, turn, to);
                        // LinuxCNC compares the sweeps (rad) with a length's tolerance.
                        let tolerance = if inch { 0.001 } else { 0.0254 };
                        if original != 0.0 && swept.abs() > original.abs() + tolerance {
                            return Err(format!(
                                "the tool (radius {}) cannot reach this concave corner without gouging: the arc before it is too short",
                                length(radius, inch)
                            ));
                        }
                    }
                }
                (OpenKind::Line { rapid, direction }, _) => {
                    if let Some(s) = start {
                        let now = [to[0] - s[0], to[1] - s[1]];
                        if direction[0] * now[0] + direction[1] * now[1] < 0.0 {
                            return Err(format!(
                                "the tool (radius {}) cannot reach this concave corner without gouging: the {} before it is too short",
                                length(radius, inch),
                                if rapid { "rapid" } else { "move" }
                            ));
                        }
                    }
                }
                (OpenKind::Arc { .. }, Path::Line) => unreachable!("an open arc is an arc"),
            }
            *end = with_plane(*end, plane, to);
            if k > 0 {
                *from = with_plane(*from, plane, to);
            }
        }
        if !open.is_empty() {
            self.position = with_plane(self.position, plane, to);
        }
        self.close(to);
        Ok(())
    }

    /// The first move after G41 or G42, a line: it ends one radius to the side of the
    /// programmed end, square to the line from where the tool is (`convert_straight_comp1`).
    fn entry_line(&mut self, line: usize, p: &Programmed, out: &mut Vec<Block>) -> Result<(), String> {
        let plane = self.plane;
        let Compensation { side, radius, .. } = *self.comp();
        let c = in_plane(&self.position, plane);
        let end = in_plane(&p.to, plane);
        let length = distance(c, end);
        if length <= radius {
            return Err(format!(
                "the entry move of cutter compensation must be longer than the tool's radius ({}): it is {} long in the plane",
                self::length(radius, self.inches),
                self::length(length, self.inches)
            ));
        }
        let alpha = angle(c, end) + if side == Side::Left { HALF_PI } else { -HALF_PI };
        let tool = polar(end, radius, alpha);
        self.comp_mut().start = Some(c);
        let kind = OpenKind::Line {
            rapid: p.rapid,
            // LinuxCNC keeps the offset's direction for the entry: it cannot turn back.
            direction: [alpha.cos(), alpha.sin()],
        };
        self.open_move(line, with_plane(p.to, plane, tool), Path::Line, p.feed, kind, out);
        self.comp_mut().programmed = Some(p.to);
        Ok(())
    }

    /// A line after the first compensated move (`convert_straight_comp2`): the corner before it
    /// is closed — an arc around a convex one, the move before shortened into a concave one.
    fn next_line(&mut self, line: usize, p: &Programmed, out: &mut Vec<Block>) -> Result<(), String> {
        let plane = self.plane;
        let Corner {
            side,
            radius,
            c,
            op,
            end,
        } = self.corner(p);
        if end == op {
            // No motion in the plane: the tool stays off the path; the move stays open with
            // the one before it.
            let to = with_plane(p.to, plane, c);
            let kind = OpenKind::Line {
                rapid: p.rapid,
                direction: [0.0, 0.0],
            };
            self.open_move(line, to, Path::Line, p.feed, kind, out);
            self.comp_mut().programmed = Some(p.to);
            return Ok(());
        }
        let mut theta = angle(op, c);
        let mut alpha = angle(op, end);
        let (beta, gamma) = if side == Side::Left {
            if theta < alpha {
                theta += 2.0 * PI;
            }
            (theta - alpha - HALF_PI, HALF_PI)
        } else {
            if alpha < theta {
                alpha += 2.0 * PI;
            }
            (alpha - theta - HALF_PI, -HALF_PI)
        };
        let tool_end = polar(end, radius, alpha + gamma);
        let mid = polar(op, radius, alpha + gamma);
        let front_arc_turn = self.front_arc().map(|(_, turn)| turn);
        let concave = !(-SMALL..=PI + SMALL).contains(&beta)
            // An "h": over the round part and down beside the stem; the tool keeps above and
            // to the side rather than loop around.
            || (beta > PI - SMALL
                && front_arc_turn.is_some_and(|turn| (side == Side::Right && turn > 0) || (side == Side::Left && turn < 0)));
        if !concave && beta > SMALL {
            // Convex: around the corner on an arc about the programmed corner (a rapid goes
            // straight to where the arc would end, as LinuxCNC's).
            self.move_end_and_close(c, out)?;
            let corner = self.corner_end(mid, p);
            let path = if p.rapid {
                Path::Line
            } else {
                Path::Arc {
                    plane,
                    center: op,
                    clockwise: side == Side::Left,
                    extra_turns: 0,
                }
            };
            // Not open: the next move starts where it ends.
            self.push_move(line, corner, path, p.feed, self.blend, out);
            self.close(mid);
        } else if concave {
            let at = match self.front_arc() {
                None => {
                    // Line to line: back along the move before, to where the tool touches both.
                    let half_corner = (beta + PI) / 2.0;
                    if half_corner == 0.0 {
                        return Err(
                            "a zero-degree inside corner (the path turns straight back) cannot be compensated".into(),
                        );
                    }
                    let retreat = radius / half_corner.tan();
                    polar(c, retreat, theta + gamma)
                }
                Some((index, turn)) => {
                    // Arc to line: along the compensated arc before, to where the tool touches
                    // the line.
                    let Action::Move {
                        to: prev_end,
                        path: Path::Arc { center, .. },
                        ..
                    } = out[index].action
                    else {
                        unreachable!("an open arc is an arc");
                    };
                    let old_radius = distance(center, in_plane(&prev_end, plane));
                    let base_dir = angle(op, end);
                    let theta = if turn > 0 {
                        base_dir + HALF_PI
                    } else {
                        base_dir - HALF_PI
                    };
                    let phi = angle(op, center);
                    let programmed_radius = if inside(side, turn) {
                        old_radius + radius
                    } else {
                        old_radius - radius
                    };
                    let d = programmed_radius * (theta - phi).cos();
                    let gouges = || {
                        "the tool cannot follow from the arc before into this move without gouging: the concave corner between them is too tight for it".to_string()
                    };
                    let angle_from_center = if inside(side, turn) {
                        let l = (d - radius) / old_radius;
                        if !(-1.0..=1.0).contains(&l) {
                            return Err(gouges());
                        }
                        if turn > 0 {
                            -l.acos() + theta + PI
                        } else {
                            l.acos() + theta + PI
                        }
                    } else {
                        let l = (d + radius) / old_radius;
                        if !(-1.0..=1.0).contains(&l) {
                            return Err(gouges());
                        }
                        if turn > 0 {
                            l.acos() + theta + PI
                        } else {
                            -l.acos() + theta + PI
                        }
                    };
                    polar(center, old_radius, angle_from_center)
                }
            };
            self.move_end_and_close(at, out)?;
        } else {
            // Straight on (or tangent from an arc): no corner.
            self.close(c);
        }
        let kind = OpenKind::Line {
            rapid: p.rapid,
            direction: [end[0] - op[0], end[1] - op[1]],
        };
        self.open_move(line, with_plane(p.to, plane, tool_end), Path::Line, p.feed, kind, out);
        self.comp_mut().programmed = Some(p.to);
        Ok(())
    }

    /// The corner a move after the first compensated one turns: where the tool is (`c`), the
    /// programmed point it is off (`op`) and the move's programmed end, in the plane.
    fn corner(&self, p: &Programmed) -> Corner {
        let plane = self.plane;
        let Compensation {
            side,
            radius,
            programmed,
            ..
        } = *self.comp();
        Corner {
            side,
            radius,
            c: in_plane(&self.position, plane),
            op: in_plane(&programmed.unwrap_or(self.position), plane),
            end: in_plane(&p.to, plane),
        }
    }

    /// The first open move, if it is an arc: its index and turns.
    fn front_arc(&self) -> Option<(usize, i32)> {
        match self.comp().open.first()?.kind {
            OpenKind::Arc { turn, .. } => Some((self.comp().open[0].index, turn)),
            OpenKind::Line { .. } => None,
        }
    }

    /// The first move after G41 or G42, an arc (`convert_arc_comp1`): an arc from where the
    /// tool is, about a centre moved so that it ends one radius off the programmed end.
    fn entry_arc(
        &mut self,
        line: usize,
        p: &Programmed,
        (center, turn): ([f64; 2], i32),
        out: &mut Vec<Block>,
    ) -> Result<(), String> {
        let (plane, inch) = (self.plane, self.inches);
        let Compensation { side, radius, .. } = *self.comp();
        let c = in_plane(&self.position, plane);
        let end = in_plane(&p.to, plane);
        if distance(c, end) <= radius {
            return Err(format!(
                "the entry arc of cutter compensation must end farther from where it starts than the tool's radius ({})",
                length(radius, inch)
            ));
        }
        self.arc_fits(center, end, turn)?;
        let gamma = if inside(side, turn) {
            angle(end, center)
        } else {
            angle(center, end)
        };
        let tool_end = polar(end, radius, gamma);
        let half_chord = distance(c, tool_end) / 2.0;
        let ab = angle(tool_end, center);
        let a = angle(tool_end, c) - ab;
        if a.cos().abs() < TOLERANCE_EQUAL {
            return Err(self.does_not_fit(distance(center, end)));
        }
        let new_center = polar(tool_end, half_chord / a.cos(), ab);
        let tolerance = if inch {
            super::motion::SPIRAL_TOLERANCE_INCH * 25.4
        } else {
            super::motion::SPIRAL_TOLERANCE_MM
        };
        if (distance(new_center, tool_end) - distance(new_center, c)).abs() > tolerance {
            return Err("cutter compensation cannot make this entry arc: its ends do not lie on one circle".into());
        }
        let path = Path::Arc {
            plane,
            center: new_center,
            clockwise: turn < 0,
            extra_turns: turn.unsigned_abs() - 1,
        };
        let kind = OpenKind::Arc {
            turn,
            sweep: sweep(c, new_center, turn, tool_end),
        };
        self.open_move(line, with_plane(p.to, plane, tool_end), path, p.feed, kind, out);
        self.comp_mut().programmed = Some(p.to);
        Ok(())
    }

    /// An arc after the first compensated move (`convert_arc_comp2`): the compensated arc has
    /// the programmed one's centre; the corner before it is closed as for a line.
    fn next_arc(
        &mut self,
        line: usize,
        p: &Programmed,
        (center, turn): ([f64; 2], i32),
        out: &mut Vec<Block>,
    ) -> Result<(), String> {
        let plane = self.plane;
        let Corner {
            side,
            radius,
            c,
            op,
            end,
        } = self.corner(p);
        let arc_radius = distance(center, end);
        let theta = angle(op, c) + if side == Side::Left { -HALF_PI } else { HALF_PI };
        let mut delta = angle(op, center);
        let alpha = if turn > 0 { delta - HALF_PI } else { delta + HALF_PI };
        let mut beta = if side == Side::Left {
            theta - alpha
        } else {
            alpha - theta
        };
        if beta > 1.5 * PI {
            beta -= 2.0 * PI;
        } else if beta < -HALF_PI {
            beta += 2.0 * PI;
        }
        let tool_inside = inside(side, turn);
        let gamma = if tool_inside {
            self.arc_fits(center, end, turn)?;
            angle(end, center)
        } else {
            delta += PI;
            angle(center, end)
        };
        let tool_end = polar(end, radius, gamma);
        let arc = |clockwise: bool, extra_turns: u32| Path::Arc {
            plane,
            center,
            clockwise,
            extra_turns,
        };
        let kind = OpenKind::Arc {
            turn,
            sweep: sweep(op, center, turn, end),
        };
        if !(-SMALL..=PI + SMALL).contains(&beta) || ((beta - PI).abs() < SMALL && !tool_inside) {
            // Concave: the move before ends where the tool touches this arc.
            let gouges = "the tool cannot reach this arc in the concave corner before it without gouging";
            let at = match self.front_arc() {
                None => {
                    let cy = arc_radius * (beta - HALF_PI).sin();
                    let (from_center, l, angle_from_center);
                    if tool_inside {
                        from_center = arc_radius - radius;
                        l = (cy + radius) / from_center;
                        if !(-1.0..=1.0).contains(&l) {
                            return Err(gouges.into());
                        }
                        angle_from_center = if turn > 0 { theta + l.asin() } else { theta - l.asin() };
                    } else {
                        from_center = arc_radius + radius;
                        l = (cy - radius) / from_center;
                        if !(-1.0..=1.0).contains(&l) {
                            return Err(gouges.into());
                        }
                        angle_from_center = if turn > 0 {
                            theta + PI - l.asin()
                        } else {
                            theta + PI + l.asin()
                        };
                    }
                    polar(center, from_center, angle_from_center)
                }
                Some((index, prev_turn)) => {
                    let Action::Move {
                        to: prev_end,
                        path: Path::Arc {
                            center: prev_center, ..
                        },
                        ..
                    } = out[index].action
                    else {
                        unreachable!("an open arc is an arc");
                    };
                    let old_radius = distance(prev_center, in_plane(&prev_end, plane));
                    let new_radius = if tool_inside {
                        arc_radius - radius
                    } else {
                        arc_radius + radius
                    };
                    let between = distance(prev_center, center);
                    if old_radius == 0.0 || between == 0.0 {
                        return Err("this arc and the arc before it have one centre: cutter compensation cannot join them at a corner".into());
                    }
                    let a = (old_radius * old_radius + between * between - new_radius * new_radius)
                        / (2.0 * old_radius * between);
                    if !(-1.0..=1.0).contains(&a) {
                        return Err("the tool cannot follow from the arc before into this arc without gouging: the concave corner between them is too tight for it".into());
                    }
                    let pullback = a.acos();
                    let towards = angle(prev_center, center);
                    let dir = if inside(side, prev_turn) == (turn > 0) {
                        towards + pullback
                    } else {
                        towards - pullback
                    };
                    polar(prev_center, old_radius, dir)
                }
            };
            self.move_end_and_close(at, out)?;
        } else if beta > SMALL {
            // Convex: around the corner on an arc about the programmed corner first.
            let mid = polar(op, radius, delta);
            let around = Path::Arc {
                plane,
                center: op,
                clockwise: side == Side::Left,
                extra_turns: 0,
            };
            // Not open: the next move starts where it ends.
            self.push_move(line, self.corner_end(mid, p), around, p.feed, self.blend, out);
            self.close(mid);
        } else {
            self.close(c);
        }
        let path = arc(turn < 0, turn.unsigned_abs() - 1);
        self.open_move(line, with_plane(p.to, plane, tool_end), path, p.feed, kind, out);
        self.comp_mut().programmed = Some(p.to);
        Ok(())
    }

    /// Refuses an arc the tool runs inside of that is no larger than the tool.
    fn arc_fits(&self, center: [f64; 2], end: [f64; 2], turn: i32) -> Result<(), String> {
        let Compensation { side, radius, .. } = *self.comp();
        let arc_radius = distance(center, end);
        if inside(side, turn) && arc_radius <= radius {
            return Err(self.does_not_fit(arc_radius));
        }
        Ok(())
    }

    fn does_not_fit(&self, arc_radius: f64) -> String {
        format!(
            "the tool (radius {}) does not fit inside this arc (radius {}): cutter compensation needs a smaller tool or a larger arc",
            length(self.comp().radius, self.inches),
            length(arc_radius, self.inches)
        )
    }
}

/// The corner before a compensated move ([`State::corner`]).
struct Corner {
    side: Side,
    radius: f64,
    /// Where the tool is.
    c: [f64; 2],
    /// The programmed point.
    op: [f64; 2],
    /// The move's programmed end.
    end: [f64; 2],
}

/// A length (mm) in the program's units, for messages.
fn length(mm: f64, inch: bool) -> String {
    if inch {
        format!("{:.4} in", mm / 25.4)
    } else {
        format!("{:.3} mm", (mm * 1000.0).round() / 1000.0)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Action, Block, Machine, Path, read};
    use crate::path::Segment;

    fn machine() -> Machine<'static> {
        Machine {
            axes: &["x", "y", "z"],
            start: [0.0; 6],
            work_offsets: [[0.0; 6]; 6],
            block_delete: false,
            homes: [[0.0; 6]; 2],
            tools: None,
        }
    }

    fn moves(blocks: &[Block]) -> Vec<(usize, Segment)> {
        blocks
            .iter()
            .filter_map(|b| match b.action {
                Action::Move { from, to, path, .. } => Some((b.line, Segment::new(from, to, path))),
                _ => None,
            })
            .collect()
    }

    /// The distance from `p` to the closed polygon `corners`' edges.
    fn to_edges(p: [f64; 2], corners: &[[f64; 2]]) -> f64 {
        (0..corners.len())
            .map(|k| {
                let (a, b) = (corners[k], corners[(k + 1) % corners.len()]);
                let (ab, ap) = ([b[0] - a[0], b[1] - a[1]], [p[0] - a[0], p[1] - a[1]]);
                let t = ((ab[0] * ap[0] + ab[1] * ap[1]) / (ab[0] * ab[0] + ab[1] * ab[1])).clamp(0.0, 1.0);
                (ap[0] - t * ab[0]).hypot(ap[1] - t * ab[1])
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Whether `p` is inside the counter-clockwise convex polygon `corners`.
    fn inside_polygon(p: [f64; 2], corners: &[[f64; 2]]) -> bool {
        (0..corners.len()).all(|k| {
            let (a, b) = (corners[k], corners[(k + 1) % corners.len()]);
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0.0
        })
    }

    proptest::proptest! {
        /// Around any convex polygon (run counter-clockwise, twice), the compensated tool's
        /// centre on the second lap is one tool radius from the polygon's edges everywhere —
        /// inside it with G41.1, outside with G42.1 — as the geometry of an offset contour says,
        /// sampled along every line and arc the interpreter made. Inside, a polygon whose corners
        /// leave the tool no room is refused, and only such a one.
        #[test]
        fn the_tool_runs_one_radius_from_any_convex_contour(
            gaps in proptest::collection::vec(1.0f64..4.0, 3..9),
            turn in 0.0f64..360.0,
            size in 20.0f64..80.0,
            radius in 0.2f64..20.0,
            left in proptest::bool::ANY,
        ) {
            // Corners on a circle, the gaps between them under half a turn (so that the
            // polygon holds its centre) and over 15°.
            let total: f64 = gaps.iter().sum();
            let gaps: Vec<f64> = gaps.iter().map(|g| 360.0 * g / total).collect();
            proptest::prop_assume!(gaps.iter().all(|g| (15.0..175.0).contains(g)));
            let corners: Vec<[f64; 2]> = gaps
                .iter()
                .scan(turn, |a, g| {
                    *a += g;
                    Some([size * a.to_radians().cos(), size * a.to_radians().sin()])
                })
                .collect();
            let n = corners.len();
            // The entry runs along the first edge, into its first corner: no corner there.
            let (a, b) = (corners[0], corners[1]);
            let along = (b[0] - a[0]).hypot(b[1] - a[1]);
            let start = [a[0] - size * (b[0] - a[0]) / along, a[1] - size * (b[1] - a[1]) / along];
            let mut text = format!("G21 F500\nG0 X{} Y{}\nG{}.1 D{}\n", start[0], start[1], if left { 41 } else { 42 }, 2.0 * radius);
            // Two laps and one edge more: the second lap's last corner is closed as any other.
            for k in 0..=2 * n + 1 {
                let [x, y] = corners[k % n];
                text += &format!("G1 X{x} Y{y}\n");
            }
            text += "G40\nG0 X0 Y0\nM2\n";
            // Inside, the tool fits where every edge is longer than what its two corners take
            // back from it (r / tan(half the corner's inner angle) at each end).
            let takes = |k: usize| {
                let (a, b, c) = (corners[(k + n - 1) % n], corners[k], corners[(k + 1) % n]);
                let (u, v) = ([a[0] - b[0], a[1] - b[1]], [c[0] - b[0], c[1] - b[1]]);
                let inner = ((u[0] * v[0] + u[1] * v[1]) / (u[0].hypot(u[1]) * v[0].hypot(v[1]))).clamp(-1.0, 1.0).acos();
                radius / (inner / 2.0).tan()
            };
            let fits = (0..n).all(|k| {
                let (a, b) = (corners[k], corners[(k + 1) % n]);
                (b[0] - a[0]).hypot(b[1] - a[1]) > takes(k) + takes((k + 1) % n) + 1e-6
            });
            let program = read(&text, &machine());
            if left && !fits {
                // Too tight somewhere: refused (or, within rounding, just fitting).
                if program.is_ok() {
                    let tight = (0..n).any(|k| {
                        let (a, b) = (corners[k], corners[(k + 1) % n]);
                        (b[0] - a[0]).hypot(b[1] - a[1]) > takes(k) + takes((k + 1) % n) - 1e-3
                    });
                    proptest::prop_assert!(tight, "{text}");
                }
                return Ok(());
            }
            let program = program.map_err(|e| proptest::test_runner::TestCaseError::fail(format!("{e}\n{text}")))?;
            // The second lap: lines 5 + n … 4 + 2n (line 4 goes to the first corner).
            let lap = (5 + n)..=(4 + 2 * n);
            let mut sampled = 0;
            for (line, segment) in moves(&program.blocks) {
                if !lap.contains(&line) {
                    continue;
                }
                for k in 0..=16 {
                    let p = segment.at(f64::from(k) / 16.0);
                    let d = to_edges([p[0], p[1]], &corners);
                    proptest::prop_assert!((d - radius).abs() < 1e-6, "{text}\nline {line}: {p:?} is {d} from the contour, not {radius}");
                    proptest::prop_assert_eq!(inside_polygon([p[0], p[1]], &corners), left, "{}", text);
                    sampled += 1;
                }
            }
            proptest::prop_assert!(sampled > 0);
        }
    }

    proptest::proptest! {
        /// Any sequence of compensation, moves, arcs, rapids, plunges, pauses and mode changes
        /// is read or refused with a reason; nothing panics, every value is finite, and every
        /// move starts where the one before it ends.
        #[test]
        fn any_compensated_program_is_whole_or_refused(lines in proptest::collection::vec(
            (proptest::sample::select(vec![
                "G41.1 D{d}", "G42.1 D{d}", "G41.1 D-{d}", "G40", "G1 X{x} Y{y}", "G0 X{x} Y{y}", "G1 Z{z}",
                "G2 X{x} Y{y} R{r}", "G3 X{x} Y{y} R-{r}", "G3 X{x} Y{y} I{z} J{r}", "G2 X{x} Y{y} I{r} J0 P2",
                "G91", "G90", "M0", "G20", "G21", "G1 X{x}", "G1 Y{y} Z{z}", "G18", "G17", "G2 X{x} Z{z} R{r}",
                "G40 G1 X{x} Y{y}", "G41.1 D{d} G1 X{x} Y{y}",
            ]), -50.0f64..50.0, -50.0f64..50.0, -5.0f64..5.0, 0.0f64..30.0, 0.0f64..12.0),
            0..30,
        )) {
            let mut text = String::from("G21 F300\n");
            for (line, x, y, z, r, d) in lines {
                text += &line
                    .replace("{x}", &format!("{x:.3}"))
                    .replace("{y}", &format!("{y:.3}"))
                    .replace("{z}", &format!("{z:.3}"))
                    .replace("{r}", &format!("{r:.3}"))
                    .replace("{d}", &format!("{d:.3}"));
                text += "\n";
            }
            text += "M2\n";
            if let Ok(program) = read(&text, &machine()) {
                let segments = moves(&program.blocks);
                for (_, s) in &segments {
                    proptest::prop_assert!(s.from().iter().chain(s.to()).all(|v| v.is_finite()), "{text}");
                    proptest::prop_assert!(s.length().is_finite(), "{text}");
                }
                for pair in segments.windows(2) {
                    proptest::prop_assert_eq!(pair[0].1.to(), pair[1].1.from(), "{}", text);
                }
            }
        }
    }

    /// An M0 between two compensated moves keeps the corner: the move before it still ends
    /// where the tool touches both (LinuxCNC closes its queue at M0 and then runs into the
    /// wall of a concave corner: 3 mm here).
    #[test]
    fn a_pause_in_a_concave_corner_does_not_gouge() {
        let program = read("G21 G0 X-10 Y-10\nG41.1 D6\nG0 X20 Y-10\nM0\nG0 Y10\nM2\n", &machine())
            .unwrap_or_else(|e| panic!("{e}"));
        let ends: Vec<[f64; 2]> = moves(&program.blocks)
            .iter()
            .map(|(_, s)| [s.to()[0], s.to()[1]])
            .collect();
        assert_eq!(ends[1..], [[17.0, -7.0], [17.0, 10.0]]);
        // The pause stays between the two moves.
        let kinds: Vec<&str> = program
            .blocks
            .iter()
            .filter_map(|b| match b.action {
                Action::Move { .. } => Some("move"),
                Action::Pause { .. } => Some("pause"),
                _ => None,
            })
            .collect();
        assert_eq!(kinds, ["move", "move", "pause", "move"]);
    }

    /// Every compensated move starts where the one before it ends, whatever corners moved the
    /// ends, and the exit after G40 starts where the compensated tool stood.
    #[test]
    fn compensated_moves_join_end_to_start() {
        let program = read(
            "G21 F100 G0 X-10 Y-10 Z5\nG41.1 D6\nG1 X0 Y0\nZ-1\nX20\nZ1\nZ-1\nY10\nG3 X10 Y20 R10\nG1 X5\nG40\nG0 X-10\nM2\n",
            &machine(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let segments = moves(&program.blocks);
        for pair in segments.windows(2) {
            assert_eq!(pair[0].1.to(), pair[1].1.from(), "{pair:?}");
        }
        let arcs = segments.iter().filter(|(_, s)| s.is_arc()).count();
        assert!(arcs >= 2, "{segments:?}");
        assert!(matches!(
            program.blocks.iter().rev().find_map(|b| match b.action {
                Action::Move { path, .. } => Some(path),
                _ => None,
            }),
            Some(Path::Line)
        ));
    }
}
