//! The planned path: the program's moves as elements in world coordinates, consecutive lines
//! merged within G64 Q, corners rounded within G64 P (by an arc between two lines, by two arcs
//! where a curve meets the corner), and the stops where nothing may be blended.

use pkm_api::trajectory::TrajectoryEventKind;

use crate::interp::block::{Action, Blend, Output, Path, Pose, Program, Spindle, WaitMode};
use crate::path::Segment;

/// Consecutive lines turning by less than this (rad) are one straight path: at 1 m/s the
/// direction's change is a 1 µm/s step no drive notices, and below it a blend's centre (found
/// along a bisector of length 2 sin(θ/2)) loses its precision — two 0.03 mm CAM lines written to
/// three decimals turned by 2e-8 rad and gave a centre that was not a number.
const STRAIGHT: f64 = 1e-6;
/// How far from its corner the path may pass under G64 without a tolerance (mm): LinuxCNC
/// rounds a 40 mm square's corners by 1.47 mm at F1200 on the O-X glide's limits (more at higher
/// feeds); here the bound is fixed, whatever the feed.
pub const PLAIN_G64_MM: f64 = 1.0;
/// Lines turning by more than this (rad) reverse: the tool stops.
pub const REVERSAL: f64 = std::f64::consts::PI - 1e-3;

/// A piece of the planned path.
#[derive(Clone, Debug, PartialEq)]
pub struct Element {
    /// Its geometry.
    pub segment: Segment,
    /// The program line it comes from (a blend: the line after the corner).
    pub line: usize,
    /// The column of the word that made it on that line.
    pub column: usize,
    /// Its programmed speed (mm/s; infinite for a rapid, which the axes' limits bound).
    pub feed: f64,
    /// Whether the tool stops at its end.
    pub stop_after: bool,
    /// How long the tool stands still at its end (G4, s).
    pub dwell_after_s: f64,
    /// The G64 tolerance in force at its end (`None`: exact stop or no limit).
    pub(super) tolerance: Option<Option<f64>>,
}

/// The most program lines G64 Q merges into one straight line (the deviation check of a new
/// line looks at every vertex merged before it).
const MAX_MERGED: usize = 64;

/// Whether every point of `vertices` lies within `q` (mm, in all coordinates) of the straight
/// line from `a` to `b`.
fn within_line<'a>(vertices: impl IntoIterator<Item = &'a Pose>, a: &Pose, b: &Pose, q: f64) -> bool {
    let d: Pose = std::array::from_fn(|c| b[c] - a[c]);
    let len2: f64 = d.iter().map(|x| x * x).sum();
    vertices.into_iter().all(|p| {
        let t = if len2 > 0.0 {
            ((0..6).map(|c| (p[c] - a[c]) * d[c]).sum::<f64>() / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let dist2: f64 = (0..6).map(|c| (a[c] + t * d[c] - p[c]).powi(2)).sum();
        dist2 <= q * q
    })
}

/// An event of a program before it is placed on the time line: its line, what it does, and how
/// long the tool has dwelt at its stop before it (s).
pub(super) struct Pending {
    pub(super) line: usize,
    pub(super) kind: TrajectoryEventKind,
    pub(super) dwelt_s: f64,
}

/// The elements of `program` (its moves, corners blended, stops marked) and how long it dwells
/// before its first move (s).
pub fn elements(program: &Program) -> (Vec<Element>, f64) {
    let (elements, dwell, _) = elements_and_events(program);
    (elements, dwell)
}

/// [`elements`], and the program's events with their lines.
pub(super) fn elements_and_events(program: &Program) -> (Vec<Element>, f64, Vec<Pending>) {
    // At most one element a block: sized once, not grown by copies.
    let mut out: Vec<Element> = Vec::with_capacity(program.blocks.len());
    let mut initial_dwell = 0.0;
    let mut events = Vec::new();
    // The dwell at the current stop so far (since the last move).
    let mut dwelt = 0.0;
    // G64 Q: the vertices the last element has swallowed (its start first).
    let mut merged: Vec<Pose> = Vec::new();
    for block in &program.blocks {
        match block.action {
            Action::Move {
                from,
                to,
                path,
                feed_mm_min,
                blend,
            } => {
                let segment = Segment::new(from, to, path);
                if segment.length() < 1e-9 {
                    continue;
                }
                dwelt = 0.0;
                let feed = feed_mm_min.map_or(f64::INFINITY, |f| f / 60.0);
                let (tolerance, merge) = match blend {
                    Blend::ExactStop => (None, None),
                    Blend::Within { tolerance, merge } => (Some(tolerance), merge),
                };
                // G64 Q: a line that continues the last one within Q is merged into it — as
                // LinuxCNC merges, lines that keep the rotations only (a turn of the tool merged
                // into a line a micrometre long would turn it within that micrometre).
                if let (Some(q), Some(last), Path::Line) = (merge, out.last_mut(), path) {
                    let joins = !last.segment.is_arc()
                        && segment.keeps_rotations()
                        && last.segment.keeps_rotations()
                        && !last.stop_after
                        && last.feed == feed
                        && last.tolerance == tolerance
                        && merged.len() < MAX_MERGED
                        && merged
                            .split_first()
                            .is_some_and(|(start, inner)| within_line(inner.iter().chain([&from]), start, &to, q));
                    if joins {
                        merged.push(from);
                        last.segment = Segment::new(merged[0], to, Path::Line);
                        continue;
                    }
                }
                merged.clear();
                merged.push(from);
                out.push(Element {
                    segment,
                    line: block.line,
                    column: block.column,
                    feed,
                    stop_after: blend == Blend::ExactStop,
                    dwell_after_s: 0.0,
                    tolerance,
                });
            }
            Action::Dwell(s) => {
                // Its line is the one executing while the tool stands for it.
                events.push(Pending {
                    line: block.line,
                    kind: TrajectoryEventKind::Dwell { seconds: s },
                    dwelt_s: dwelt,
                });
                dwelt += s;
                match out.last_mut() {
                    Some(e) => {
                        e.stop_after = true;
                        e.dwell_after_s += s;
                    }
                    None => initial_dwell += s,
                }
            }
            Action::Message(index) => {
                // The tool does not stop for a message: it is shown as the tool passes.
                events.push(Pending {
                    line: block.line,
                    kind: TrajectoryEventKind::Message { index },
                    dwelt_s: dwelt,
                });
            }
            Action::Output { output, synced: true } => {
                // M62, M63, M67: with the next move's start, the tool not stopping for it.
                events.push(Pending {
                    line: block.line,
                    kind: output_event(output),
                    dwelt_s: dwelt,
                });
            }
            Action::WorkOffset { system, offset } => {
                // Nor for new program coordinates: the DRO takes them as the tool passes.
                events.push(Pending {
                    line: block.line,
                    kind: TrajectoryEventKind::WorkOffset { system, offset },
                    dwelt_s: dwelt,
                });
            }
            Action::Pause { .. }
            | Action::Output { synced: false, .. }
            | Action::Wait { .. }
            | Action::Spindle { .. }
            | Action::Coolant { .. }
            | Action::ToolChange { .. }
            | Action::End => {
                if let Some(e) = out.last_mut() {
                    e.stop_after = true;
                }
                let kind = match block.action {
                    Action::Spindle { direction, speed_rpm } => Some(TrajectoryEventKind::Spindle {
                        direction: match direction {
                            Spindle::Clockwise => 1,
                            Spindle::CounterClockwise => -1,
                            Spindle::Off => 0,
                        },
                        rpm: if direction == Spindle::Off { 0.0 } else { speed_rpm },
                    }),
                    Action::Coolant { mist, flood } => Some(TrajectoryEventKind::Coolant { mist, flood }),
                    // M1 stops as M0 does: the optional-stop switch is taken as on, as
                    // LinuxCNC's is by default.
                    Action::Pause { .. } => Some(TrajectoryEventKind::Pause),
                    Action::ToolChange { tool } => Some(TrajectoryEventKind::ToolChange { tool }),
                    // M64, M65, M68 and M66 with the tool standing, as LinuxCNC's (they end a
                    // blend).
                    Action::Output { output, .. } => Some(output_event(output)),
                    Action::Wait { input, mode, timeout_s } => Some(TrajectoryEventKind::WaitInput {
                        index: input,
                        mode: match mode {
                            WaitMode::Immediate => 0,
                            WaitMode::Rise => 1,
                            WaitMode::Fall => 2,
                            WaitMode::High => 3,
                            WaitMode::Low => 4,
                        },
                        timeout_s,
                    }),
                    _ => None,
                };
                if let Some(kind) = kind {
                    events.push(Pending {
                        line: block.line,
                        kind,
                        dwelt_s: dwelt,
                    });
                }
            }
        }
    }
    if let Some(e) = out.last_mut() {
        e.stop_after = true;
    }
    let mut blended = blend_corners(out);
    // Sized for two elements a move; the memory past the blends' is given back (a large
    // vector is remapped, not copied).
    blended.shrink_to_fit();
    (blended, initial_dwell, events)
}

/// Rounds the corners between consecutive lines within their tolerance; marks the others stops.
///
/// Long, and kept whole: one pass over the elements that carries the corner at hand (what a
/// blend took of the element's start, the element waiting for its end); split, that state would
/// pass in and out of every part.
fn blend_corners(elements: Vec<Element>) -> Vec<Element> {
    let mut out: Vec<Element> = Vec::with_capacity(elements.len() * 2);
    let mut iter = elements.into_iter();
    // How much of the current element's start a previous blend took (mm).
    let mut current = match iter.next() {
        Some(e) => e,
        None => return out,
    };
    let mut trimmed_start = 0.0;
    for mut next in iter {
        if current.stop_after {
            out.push(current);
            current = next;
            trimmed_start = 0.0;
            continue;
        }
        let d1 = current.segment.direction(1.0);
        let d2 = next.segment.direction(0.0);
        let cos = dot3(d1, d2).clamp(-1.0, 1.0);
        let theta = cos.acos();
        let both_lines = !current.segment.is_arc() && !next.segment.is_arc();
        // The rotations' rates must continue too where the path goes on without a blend.
        let (r1, r2) = (current.segment.rotation_rates().1, next.segment.rotation_rates().0);
        let rates_continue = (0..3).all(|c| (r1[c] - r2[c]).abs() < 1e-9);
        let same_kind = current.feed.is_finite() == next.feed.is_finite();
        let moving = current.segment.linear_length() > 1e-9 && next.segment.linear_length() > 1e-9;
        if theta <= STRAIGHT && moving && same_kind && rates_continue {
            out.push(current);
            current = next;
            trimmed_start = 0.0;
            continue;
        }
        let rotations_stay = current.segment.keeps_rotations() && next.segment.keeps_rotations();
        if !both_lines && same_kind && moving && rotations_stay && theta > STRAIGHT && theta < REVERSAL {
            // A line into an arc, an arc into a line or an arc: two arcs tangent to both and
            // to each other (a biarc) within the tolerance, where they coplanar.
            let room = (current.segment.linear_length() + trimmed_start) / 2.0;
            let tolerance = current.tolerance.flatten().unwrap_or(PLAIN_G64_MM);
            if let Some((before, pieces, after, cut)) =
                biarc_blend(&current.segment, &next.segment, theta, tolerance, room)
            {
                current.segment = before;
                let feed = current.feed.min(next.feed);
                let tolerance = current.tolerance;
                out.push(current);
                for piece in pieces {
                    out.push(Element {
                        segment: piece,
                        line: next.line,
                        column: next.column,
                        feed,
                        stop_after: false,
                        dwell_after_s: 0.0,
                        tolerance,
                    });
                }
                next.segment = after;
                trimmed_start = cut;
                current = next;
                continue;
            }
        }
        if !(both_lines && same_kind && moving && theta > STRAIGHT && theta < REVERSAL) {
            // Tangent-continuous arcs go on; anything else stops at the corner (a kink of even a
            // milliradian taken at speed is a jump of the joints' velocities).
            current.stop_after = !(moving && same_kind && theta <= STRAIGHT && rates_continue);
            out.push(current);
            current = next;
            trimmed_start = 0.0;
            continue;
        }
        let (len_a, len_b) = (current.segment.linear_length(), next.segment.linear_length());
        let half = (theta / 2.0).tan();
        // G64 without P (or P0, P-1) rounds within PLAIN_G64_MM, so that a corner is never cut
        // by more than that, whatever the feed and the lines' lengths.
        let tolerance = current.tolerance.flatten().unwrap_or(PLAIN_G64_MM);
        let by_tolerance = tolerance / (1.0 / (theta / 2.0).cos() - 1.0);
        let room = ((len_a + trimmed_start) / 2.0).min(len_a).min(len_b / 2.0);
        let radius = by_tolerance.min(room / half);
        if radius.is_nan() || radius <= 1e-9 {
            current.stop_after = true;
            out.push(current);
            current = next;
            trimmed_start = 0.0;
            continue;
        }
        let cut = radius * half;
        // The 6-D poses where the blend leaves the first line and joins the second.
        let a_from = *current.segment.from();
        let a_end = current.segment.at((len_a - cut) / len_a);
        let b_start = next.segment.at(cut / len_b);
        let corner = *current.segment.to();
        let bisector = [d2[0] - d1[0], d2[1] - d1[1], d2[2] - d1[2]];
        let norm = dot3(bisector, bisector).sqrt();
        let reach = radius / (theta / 2.0).cos();
        let center: [f64; 3] = std::array::from_fn(|c| corner[c] + bisector[c] / norm * reach);
        let u_raw: [f64; 3] = std::array::from_fn(|c| a_end[c] - center[c]);
        let un = dot3(u_raw, u_raw).sqrt();
        let u = u_raw.map(|x| x / un);
        // The lines' own rates, found before the first was cut short: what is left of it may
        // be too short to say.
        let rates = (r1, r2);
        let segment = Segment::blend(a_end, b_start, center, u, d1, radius, theta, rates);
        if misses_its_ends(&segment) {
            // A turn so slight that the blend's centre, found along a bisector of length
            // 2 sin(θ/2), is off by micrometres: taken as straight, the tool going on through
            // the corner (as below STRAIGHT).
            current.stop_after = !rates_continue;
            out.push(current);
            current = next;
            trimmed_start = 0.0;
            continue;
        }
        current.segment = Segment::new(a_from, a_end, crate::interp::block::Path::Line);
        let blend = Element {
            segment,
            line: next.line,
            column: next.column,
            feed: current.feed.min(next.feed),
            stop_after: false,
            dwell_after_s: 0.0,
            tolerance: current.tolerance,
        };
        out.push(current);
        out.push(blend);
        next.segment = Segment::new(b_start, *next.segment.to(), crate::interp::block::Path::Line);
        trimmed_start = cut;
        current = next;
    }
    out.push(current);
    // A line both its corners' blends took whole is gone; its stop (if any) goes to the piece
    // before it.
    // (Compacted in place: a copy would hold the program's elements twice.)
    let mut kept = 0;
    for r in 0..out.len() {
        if out[r].segment.length() > 1e-9 {
            out.swap(kept, r);
            kept += 1;
        } else if kept > 0 {
            let (stop, dwell) = (out[r].stop_after, out[r].dwell_after_s);
            out[kept - 1].stop_after |= stop;
            out[kept - 1].dwell_after_s += dwell;
        }
    }
    out.truncate(kept);
    out
}

/// The blend of the corner where `a` meets `b` (turning by `theta`) when one of them is an arc:
/// `a` shortened at its end and `b` at its start by the same length, joined by two arcs tangent
/// to both and to each other, that pass the corner within `tolerance`; `room`: the most `a`
/// may give. `None` where no such blend exists (the two do not lie in one plane, or they are too
/// short): the tool stops there.
fn biarc_blend(
    a: &Segment,
    b: &Segment,
    theta: f64,
    tolerance: f64,
    room: f64,
) -> Option<(Segment, [Segment; 2], Segment, f64)> {
    let (len_a, len_b) = (a.linear_length(), b.linear_length());
    let corner = *a.to();
    // As between two lines: the arc that passes the corner at the tolerance, at most half of
    // each move; smaller while the biarc passes farther.
    let half = (theta / 2.0).tan();
    let mut cut = (tolerance / (1.0 / (theta / 2.0).cos() - 1.0) * half)
        .min(room)
        .min(len_a)
        .min(len_b / 2.0);
    for _ in 0..8 {
        if cut <= 1e-6 {
            return None;
        }
        let (end_a, start_b) = (1.0 - cut / len_a, cut / len_b);
        let before = a.trimmed(0.0, end_a);
        let after = b.trimmed(start_b, 1.0);
        // The directions where the pieces meet, from the moves themselves: what is left of a
        // move may be too short to say.
        if let Some(pieces) = biarc(a.at(end_a), a.direction(end_a), b.at(start_b), b.direction(start_b)) {
            let nearest = pieces
                .iter()
                .flat_map(|p| (0..=16).map(move |i| p.at(f64::from(i) / 16.0)))
                .map(|q| distance3(&q, &corner))
                .fold(f64::INFINITY, f64::min);
            if nearest <= tolerance {
                return Some((before, pieces, after, cut));
            }
        }
        cut /= 2.0;
    }
    None
}

fn sub3(a: &Pose, b: &Pose) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn distance3(a: &Pose, b: &Pose) -> f64 {
    let d = sub3(a, b);
    dot3(d, d).sqrt()
}

/// Two arcs from `p0` (leaving along `t0`) to `p1` (arriving along `t1`), tangent to each other
/// where they meet (the biarc whose tangent lines from both ends are equally long); `None` when
/// the ends and their tangents do not lie in one plane or no such pair exists.
fn biarc(p0: Pose, t0: [f64; 3], p1: Pose, t1: [f64; 3]) -> Option<[Segment; 2]> {
    let v = sub3(&p1, &p0);
    let n = [
        t0[1] * t1[2] - t0[2] * t1[1],
        t0[2] * t1[0] - t0[0] * t1[2],
        t0[0] * t1[1] - t0[1] * t1[0],
    ];
    let (vn, nn) = (dot3(v, v).sqrt(), dot3(n, n).sqrt());
    if vn < 1e-12 || (nn > 1e-9 && dot3(v, n).abs() > 1e-6 * vn * nn) {
        return None;
    }
    let t = [t0[0] + t1[0], t0[1] + t1[1], t0[2] + t1[2]];
    let (vt, vv, denom) = (dot3(v, t), dot3(v, v), 2.0 * (1.0 - dot3(t0, t1)));
    let d = if denom.abs() < 1e-12 {
        vv / (2.0 * vt)
    } else {
        (-vt + (vt * vt + denom * vv).sqrt()) / denom
    };
    if !(d.is_finite() && d > 0.0) {
        return None;
    }
    let mut joint = p0;
    for c in 0..3 {
        joint[c] = (p0[c] + d * t0[c] + p1[c] - d * t1[c]) / 2.0;
    }
    let (first, tj) = arc_from(p0, t0, joint)?;
    let (second, end) = arc_from(joint, tj, p1)?;
    (dot3(end, t1) > 1.0 - 1e-6).then_some([first, second])
}

/// The circular arc from `from` leaving along `t0` to `to` (a line where `to` lies ahead on the
/// tangent), and its direction at `to`.
fn arc_from(from: Pose, t0: [f64; 3], to: Pose) -> Option<(Segment, [f64; 3])> {
    let c = sub3(&to, &from);
    let along = dot3(c, t0);
    let perp = [c[0] - along * t0[0], c[1] - along * t0[1], c[2] - along * t0[2]];
    let (cn, pn) = (dot3(c, c).sqrt(), dot3(perp, perp).sqrt());
    if cn < 1e-12 {
        return None;
    }
    if pn < 1e-9 * cn {
        return (along > 0.0).then(|| (Segment::new(from, to, crate::interp::block::Path::Line), t0));
    }
    let normal = perp.map(|x| x / pn);
    let radius = cn * cn / (2.0 * pn);
    let center: [f64; 3] = std::array::from_fn(|k| from[k] + radius * normal[k]);
    let u = normal.map(|x| -x);
    let rel = [to[0] - center[0], to[1] - center[1], to[2] - center[2]];
    let mut sweep = dot3(rel, t0).atan2(dot3(rel, u));
    if sweep <= 0.0 {
        sweep += std::f64::consts::TAU;
    }
    let end: [f64; 3] = std::array::from_fn(|k| -sweep.sin() * u[k] + sweep.cos() * t0[k]);
    let arc = Segment::blend(from, to, center, u, t0, radius, sweep, ([0.0; 3], [0.0; 3]));
    if misses_its_ends(&arc) {
        // An arc that hardly turns, on a radius of kilometres: its centre, found along a normal
        // of a few nanometres, is off by micrometres, and the circle misses `to` by as much — a
        // step in the tool's path where the next element starts. The line there turns by less
        // than a ten-thousandth of a radian from the tangent.
        return (along > 0.0).then(|| {
            (
                Segment::new(from, to, crate::interp::block::Path::Line),
                c.map(|x| x / cn),
            )
        });
    }
    Some((arc, end))
}

/// Whether a blend's circle, as its formula gives it, misses its own ends by more than
/// [`ENDS_MISSED_MM`]: a centre found along a very short normal or bisector (an arc that hardly
/// turns) is off by micrometres, and the tool would step where the element meets the next.
fn misses_its_ends(arc: &Segment) -> bool {
    let (start, end) = (arc.at_extended(0.0), arc.at_extended(1.0));
    let off = |p: &Pose, q: &Pose| distance3(p, q);
    off(&start, arc.from()) > ENDS_MISSED_MM || off(&end, arc.to()) > ENDS_MISSED_MM
}

/// How far a blend's circle may miss its ends (mm): below what any drive resolves.
const ENDS_MISSED_MM: f64 = 1e-9;

/// The event of an output a program sets.
fn output_event(output: Output) -> TrajectoryEventKind {
    match output {
        Output::Digital { index, on } => TrajectoryEventKind::DigitalOutput { index, on },
        Output::Analog { index, value } => TrajectoryEventKind::AnalogOutput { index, value },
    }
}
