//! The planner (docs/nc.md): the program's moves as one path in world coordinates — corners of
//! consecutive lines rounded by arcs within the G64 P tolerance, exact stops at G61 and wherever
//! the path cannot be blended —, and a velocity profile along it that keeps every world axis and
//! every joint within its speed and acceleration limits: joint rates through the kinematics
//! (derivatives of the inverse kinematics along the path), so the tool slows down near a
//! singularity rather than asking a drive for more than it has. It runs off the cyclic path and
//! may allocate; [`Plan::sample`] gives the pose at any time without allocating.
//!
//! The profile is computed on points at most [`GRID_SPACING`] apart: at each, a speed cap (the
//! feed; each axis' and joint's speed; the part of each acceleration the path's curvature uses)
//! and a tangential acceleration bound; a forward and a backward pass bring the speed within
//! reach of its neighbours' — twice: as programmed, and with every feed times
//! [`MAX_FEED_OVERRIDE`] (the machine's limits unchanged), the speed a feed override above 100 %
//! may take at each point. Half of each acceleration limit is given to the curvature and half
//! to the change of speed, so their sum stays within the limit.

use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;

use pkm_api::trajectory::{MAX_FEED_OVERRIDE, TrajectoryEvent, TrajectoryEventKind};

use crate::interp::block::{AXES, Action, Blend, Path, Pose, Program, Spindle};
use crate::path::Segment;
use crate::watch::{Unwatched, Watch, Watched};

/// The largest distance between two points of the velocity profile (mm, or degrees where only
/// rotations move).
pub const GRID_SPACING: f64 = 0.5;

/// Consecutive lines turning by less than this (rad) are one straight path: at 1 m/s the
/// direction's change is a 1 µm/s step no drive notices, and below it a blend's centre (found
/// along a bisector of length 2 sin(θ/2)) loses its precision — two 0.03 mm CAM lines written to
/// three decimals turned by 2e-8 rad and gave a centre that was not a number.
const STRAIGHT: f64 = 1e-6;
/// How far from its corner the path may pass under G64 without a tolerance (mm): LinuxCNC
/// rounds a 40 mm square's corners by 1.47 mm at F1200 on the O-X glide's limits (more at higher
/// feeds); here the bound is fixed, whatever the feed.
pub const PLAIN_G64_MM: f64 = 1.0;
/// How far from a curve a long line gets a point of its own (mm).
const JUNCTION: f64 = 0.05;
/// The share of an axis' or joint's acceleration a curve may take at its highest speed (the
/// rest is left for the change of speed): LinuxCNC's √3/2 for the normal acceleration on arcs.
const NORMAL_SHARE: f64 = 0.866;
/// Lines turning by more than this (rad) reverse: the tool stops.
const REVERSAL: f64 = std::f64::consts::PI - 1e-3;

/// The machine's limits.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanLimits {
    /// Per joint: speed (mm/s).
    pub joint_speed: Vec<f64>,
    /// Per joint: acceleration (mm/s²).
    pub joint_accel: Vec<f64>,
    /// Per world axis x y z a b c: speed (mm/s, degrees/s), also the speed of rapids.
    pub axis_speed: [f64; 6],
    /// Per world axis: acceleration (mm/s², degrees/s²).
    pub axis_accel: [f64; 6],
}

/// A piece of the planned path.
#[derive(Clone, Debug, PartialEq)]
pub struct Element {
    /// Its geometry.
    pub segment: Segment,
    /// The program line it comes from (a blend: the line after the corner).
    pub line: usize,
    /// Its programmed speed (mm/s; infinite for a rapid, which the axes' limits bound).
    pub feed: f64,
    /// Whether the tool stops at its end.
    pub stop_after: bool,
    /// How long the tool stands still at its end (G4, s).
    pub dwell_after_s: f64,
    /// The G64 tolerance in force at its end (`None`: exact stop or no limit).
    tolerance: Option<Option<f64>>,
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

/// What limits a point's speed below the feed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Limit {
    /// The programmed feed.
    Feed,
    /// A world axis' speed (index in x y z a b c).
    AxisSpeed(usize),
    /// A joint's speed.
    JointSpeed(usize),
    /// A world axis' acceleration on the path's curvature.
    AxisCurvature(usize),
    /// A joint's acceleration on the path's curvature (a corner blend, an arc, the mechanism).
    JointCurvature(usize),
}

impl Limit {
    /// The limit as users read it.
    pub fn text(self) -> String {
        match self {
            Limit::Feed => "the programmed feed".into(),
            Limit::AxisSpeed(c) => format!("the speed of axis {}", AXES[c]),
            Limit::JointSpeed(j) => format!("the speed of joint {}", j + 1),
            Limit::AxisCurvature(c) => format!("the acceleration of axis {} on the curve", AXES[c]),
            Limit::JointCurvature(j) => format!("the acceleration of joint {} on the curve", j + 1),
        }
    }
}

/// The memory one point of a velocity profile takes (bytes).
pub(crate) const POINT_BYTES: u64 = size_of::<Point>() as u64;

#[derive(Clone, Copy, Debug)]
struct Point {
    /// Distance along the path.
    s: f64,
    element: u32,
    u: f64,
    /// Speed cap and what sets it.
    cap: f64,
    limit: Limit,
    /// The cap at the highest feed override (the feed times [`MAX_FEED_OVERRIDE`], the
    /// machine's limits unchanged).
    cap_fast: f64,
    /// Tangential acceleration bound at rest (mm/s²); at speed v it is `accel − bend · v²`
    /// (what the path's curvature leaves of the axes' and joints' accelerations).
    accel: f64,
    /// How the bound falls with the speed squared (1/mm).
    bend: f64,
    /// The same up to `cap_fast`.
    bend_fast: f64,
    /// Planned speed.
    v: f64,
    /// The speed of the profile planned at the highest feed override.
    v_fast: f64,
    /// When the tool passes (s).
    t: f64,
    /// Standing still here this long before going on (s).
    hold: f64,
}

impl Point {
    /// A point at `s` (`u` along `element`) capped at `cap` (both profiles), before its bounds,
    /// speeds and time are found.
    fn new(s: f64, element: u32, u: f64, cap: f64) -> Point {
        Point {
            s,
            element,
            u,
            cap,
            limit: Limit::Feed,
            cap_fast: cap,
            accel: f64::INFINITY,
            bend: 0.0,
            bend_fast: 0.0,
            v: 0.0,
            v_fast: 0.0,
            t: 0.0,
            hold: 0.0,
        }
    }
}

/// A block whose speed the machine limits below its feed.
#[derive(Clone, Debug, PartialEq)]
pub struct Limited {
    /// The program line.
    pub line: usize,
    /// Its feed (mm/min).
    pub programmed_mm_min: f64,
    /// The highest speed any point of it may take (mm/min).
    pub reachable_mm_min: f64,
    /// Why.
    pub why: Limit,
}

/// A planned program.
#[derive(Clone, Debug)]
pub struct Plan {
    elements: Vec<Element>,
    points: Vec<Point>,
    /// Its duration (s), dwells included.
    pub duration_s: f64,
    /// Its path's length (mm).
    pub length_mm: f64,
    /// The blocks whose speed is limited below their feed, and why.
    pub limited: Vec<Limited>,
    /// What happens besides motion (M0/M1, spindle), in time order.
    pub events: Vec<TrajectoryEvent>,
    /// How long the feed moves (not the rapids) take as planned (s), dwells excluded.
    pub feed_time_s: f64,
    /// How long they would take at their programmed feeds: Σ length ÷ feed (s).
    pub programmed_feed_time_s: f64,
}

/// A point of the plan at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// The pose.
    pub pose: Pose,
    /// The program line executing.
    pub line: usize,
    /// The distance along the path from the start (mm).
    pub s: f64,
    /// The speed along the path (mm/s).
    pub speed: f64,
    /// The speed of the profile planned at the highest feed override (mm/s; at least `speed`).
    pub speed_max: f64,
    /// The tangential acceleration bound there (mm/s²).
    pub accel: f64,
    /// A rapid (G0) executes.
    pub rapid: bool,
}

/// Why a program cannot be planned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct PlanError {
    /// The program line.
    pub line: usize,
    /// What fails.
    pub message: String,
}

/// An event of a program before it is placed on the time line: its line, what it does, and how
/// long the tool has dwelt at its stop before it (s).
struct Pending {
    line: usize,
    kind: TrajectoryEventKind,
    dwelt_s: f64,
}

/// The elements of `program` (its moves, corners blended, stops marked) and how long it dwells
/// before its first move (s).
pub fn elements(program: &Program) -> (Vec<Element>, f64) {
    let (elements, dwell, _) = elements_and_events(program);
    (elements, dwell)
}

/// [`elements`], and the program's events with their lines.
fn elements_and_events(program: &Program) -> (Vec<Element>, f64, Vec<Pending>) {
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
                // G64 Q: a line that continues the last one within Q is merged into it.
                if let (Some(q), Some(last), Path::Line) = (merge, out.last_mut(), path) {
                    let joins = !last.segment.is_arc()
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
                    feed,
                    stop_after: blend == Blend::ExactStop,
                    dwell_after_s: 0.0,
                    tolerance,
                });
            }
            Action::Dwell(s) => {
                dwelt += s;
                match out.last_mut() {
                    Some(e) => {
                        e.stop_after = true;
                        e.dwell_after_s += s;
                    }
                    None => initial_dwell += s,
                }
            }
            Action::Pause { .. } | Action::Spindle { .. } | Action::End => {
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
                    // M1 stops as M0 does: the optional-stop switch is taken as on, as
                    // LinuxCNC's is by default.
                    Action::Pause { .. } => Some(TrajectoryEventKind::Pause),
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
        if !both_lines && same_kind && moving && rotations_stay && theta > 1e-3 && theta < REVERSAL {
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
            // Tangent-continuous arcs go on; anything else stops at the corner.
            current.stop_after = !(moving && same_kind && theta < 1e-3 && rates_continue);
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
        current.segment = Segment::new(a_from, a_end, crate::interp::block::Path::Line);
        let rates = (current.segment.rotation_rates().1, next.segment.rotation_rates().0);
        let blend = Element {
            segment: Segment::blend(a_end, b_start, center, u, d1, radius, theta, rates),
            line: next.line,
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
        let before = a.trimmed(0.0, 1.0 - cut / len_a);
        let after = b.trimmed(cut / len_b, 1.0);
        if let Some(pieces) = biarc(*before.to(), before.direction(1.0), *after.from(), after.direction(0.0)) {
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
    Some((
        Segment::blend(from, to, center, u, t0, radius, sweep, ([0.0; 3], [0.0; 3])),
        end,
    ))
}

/// How many points' poses and joints the caps need at once: the point, two before, two after.
const WINDOW: usize = 5;

/// Plans `program` on the machine `frame` within `limits`.
pub fn plan(program: &Program, frame: &MachineFrame, limits: &PlanLimits) -> Result<Plan, PlanError> {
    plan_watched(program, frame, limits, &Unwatched)
}

/// [`plan`], asking `watch` every [`crate::watch::WATCH_EVERY`] points whether to go on.
pub fn plan_watched(
    program: &Program,
    frame: &MachineFrame,
    limits: &PlanLimits,
    watch: &dyn Watch,
) -> Result<Plan, PlanError> {
    let mut watched = Watched::new(watch);
    let (elements, initial_dwell, pending) = elements_and_events(program);
    let n = frame.dof();
    let curved = |k: Option<usize>| k.and_then(|k| elements.get(k)).is_some_and(|e| e.segment.is_arc());
    // Each element split into at least two intervals: arcs and blends at least every 22.5°, so
    // that their curvature is seen; a move next to a curve gets a point JUNCTION from their
    // junction, so that the bound there (the curve's) holds over that short piece, not over a
    // whole interval of the move.
    let split = |k: usize, e: &Element| {
        let len = e.segment.length();
        let turns = e.segment.sweep() * 8.0 / std::f64::consts::PI;
        let steps = ((len / GRID_SPACING).ceil().max(turns.ceil()) as usize).max(2);
        let long = len > 4.0 * JUNCTION;
        (
            len,
            steps,
            long && curved(k.checked_sub(1)),
            long && curved(Some(k + 1)),
        )
    };
    // The points, counted first: a program of a million moves has millions of them, and a
    // vector grown by doubling would hold up to twice their memory.
    let count: usize = elements
        .iter()
        .enumerate()
        .map(|(k, e)| {
            let (_, steps, near_start, near_end) = split(k, e);
            steps + usize::from(near_start) + usize::from(near_end)
        })
        .sum::<usize>()
        + 1;
    let mut points: Vec<Point> = Vec::with_capacity(count);
    let mut s = 0.0;
    for (k, e) in elements.iter().enumerate() {
        let (len, steps, near_start, near_end) = split(k, e);
        for i in 0..steps {
            let grid = i as f64 / steps as f64;
            let extra_start = (i == 0 && near_start).then_some(JUNCTION / len);
            let extra_end = (i + 1 == steps && near_end).then_some(1.0 - JUNCTION / len);
            for u in std::iter::once(grid).chain(extra_start).chain(extra_end) {
                points.push(Point::new(s + len * u, k as u32, u, e.feed));
            }
        }
        s += len;
    }
    if let Some(last) = elements.len().checked_sub(1) {
        points.push(Point::new(s, last as u32, 1.0, 0.0));
    }
    let count = points.len();
    // Poses and joints of the points, computed as the caps below need them: at most two points
    // on either side of the one at hand (a window of five), so that a program of a million
    // lines does not hold a pose and joints for each of its points at once.
    let mut poses: [Pose; WINDOW] = [[0.0; 6]; WINDOW];
    let mut joints: [[f64; MAX_DOF]; WINDOW] = [[0.0; MAX_DOF]; WINDOW];
    let mut computed = 0;
    // Caps and acceleration bounds from the derivatives along the path.
    for i in 0..count {
        watched.step().map_err(|why| PlanError {
            line: elements[points[i].element as usize].line,
            message: why,
        })?;
        while computed < count && computed <= i + 2 {
            let p = &points[computed];
            let e = &elements[p.element as usize];
            let pose = e.segment.at(p.u);
            let mut q = [0.0; MAX_DOF];
            frame.inverse(&pose[..n], &mut q[..n]).map_err(|err| PlanError {
                line: e.line,
                message: format!("the path leaves the workspace: {err}"),
            })?;
            poses[computed % WINDOW] = pose;
            joints[computed % WINDOW] = q;
            computed += 1;
        }
        let pose = |k: usize| &poses[k % WINDOW];
        let joint = |k: usize| &joints[k % WINDOW];
        let (a, b) = (i.saturating_sub(1), (i + 1).min(count - 1));
        let ds = points[b].s - points[a].s;
        if ds <= 0.0 {
            continue;
        }
        let e = &elements[points[i].element as usize];
        let mut cap = e.feed;
        let mut limit = Limit::Feed;
        // The machine's own cap, whatever the feed.
        let mut machine = f64::INFINITY;
        let mut accel = f64::INFINITY;
        // The second derivative across the point, and within each element on either side of
        // it: at the junction of a line and a blend the curve starts, and an average over both
        // would hide it.
        let element = |k: usize| points[k].element;
        let mut triples: [Option<[usize; 3]>; 3] = [None; 3];
        if a < i && i < b {
            triples[0] = Some([a, i, b]);
        }
        if i + 2 < count && element(i + 1) == element(i + 2) && element(i) == element(i + 1) {
            triples[1] = Some([i, i + 1, i + 2]);
        }
        if i >= 2 && element(i - 2) == element(i - 1) {
            triples[2] = Some([i - 2, i - 1, i]);
        }
        let curvature = |y: &dyn Fn(usize) -> f64| {
            triples
                .iter()
                .flatten()
                .filter(|[x, m, z]| points[*m].s - points[*x].s > 1e-9 && points[*z].s - points[*m].s > 1e-9)
                .map(|[x, m, z]| second(y(*x), y(*m), y(*z), points[*x].s, points[*m].s, points[*z].s).abs())
                .fold(0.0, f64::max)
        };
        let mut consider = |value: f64, l: Limit| {
            machine = machine.min(value);
            if value < cap {
                cap = value;
                limit = l;
            }
        };
        // Per world axis and joint: its limit of acceleration, its first and second derivative
        // along the path here.
        let mut rates: [(f64, f64, f64); 6 + MAX_DOF] = [(0.0, 0.0, 0.0); 6 + MAX_DOF];
        #[allow(clippy::needless_range_loop)] // c indexes the poses of three points and the limits
        for c in 0..n.min(6) {
            let d1 = (pose(b)[c] - pose(a)[c]) / ds;
            if d1.abs() > 1e-12 {
                consider(limits.axis_speed[c] / d1.abs(), Limit::AxisSpeed(c));
            }
            let d2 = curvature(&|k| pose(k)[c]);
            if d2 > 1e-12 {
                consider(
                    (NORMAL_SHARE * limits.axis_accel[c] / d2).sqrt(),
                    Limit::AxisCurvature(c),
                );
            }
            rates[c] = (limits.axis_accel[c], d1.abs(), d2);
        }
        #[allow(clippy::needless_range_loop)] // j indexes the joints of three points and the limits
        for j in 0..n {
            let d1 = (joint(b)[j] - joint(a)[j]) / ds;
            if d1.abs() > 1e-12 {
                consider(limits.joint_speed[j] / d1.abs(), Limit::JointSpeed(j));
            }
            let d2 = curvature(&|k| joint(k)[j]);
            if d2 > 1e-12 {
                consider(
                    (NORMAL_SHARE * limits.joint_accel[j] / d2).sqrt(),
                    Limit::JointCurvature(j),
                );
            }
            rates[6 + j] = (limits.joint_accel[j], d1.abs(), d2);
        }
        // The change of speed gets what the path's curvature leaves of each acceleration at the
        // speed the tool has (q̈ = q′ s̈ + q″ ṡ²): |s̈| ≤ (A − |q″| v²) / |q′|, all of it where
        // the tool stands or the path is straight. One bound for all, accel − bend · v²: the
        // chord of their lower envelope from v = 0 to the cap, below every coordinate's there
        // (the envelope of lines in v² is concave), and positive at the cap (each coordinate
        // keeps 1 − NORMAL_SHARE of its acceleration there).
        // The start, and every stop, at rest.
        let stop = i == 0 || (points[i].u == 0.0 && elements[points[i - 1].element as usize].stop_after);
        let cap_fast = (e.feed * MAX_FEED_OVERRIDE).min(machine);
        for (limit, d1, _) in rates {
            if d1 > 1e-12 {
                accel = accel.min(limit / d1);
            }
        }
        // The chord up to the cap, and up to the cap at the highest override (the envelope is
        // concave: a chord to a higher speed lies lower, so each holds up to its own cap only).
        let bend_to = |top: f64| {
            let top = if stop { 0.0 } else { top * top };
            let at_cap = rates
                .iter()
                .filter(|(_, d1, _)| *d1 > 1e-12)
                .map(|(limit, d1, d2)| (limit - d2 * top) / d1)
                .fold(f64::INFINITY, f64::min);
            if top.is_finite() && top > 0.0 && at_cap.is_finite() {
                ((accel - at_cap) / top).max(0.0)
            } else {
                0.0
            }
        };
        let (bend, bend_fast) = (bend_to(cap), bend_to(cap_fast));
        let p = &mut points[i];
        p.cap = if stop { 0.0 } else { cap };
        p.cap_fast = if stop { 0.0 } else { cap_fast };
        p.bend_fast = bend_fast;
        // A stop is the program's, not a limit of the machine.
        p.limit = if stop { Limit::Feed } else { limit };
        p.accel = accel;
        p.bend = bend;
    }
    // Dwells: held at the stop after their element.
    for i in 1..count {
        if points[i].u == 0.0 {
            let before = &elements[points[i - 1].element as usize];
            if before.stop_after {
                points[i].hold = before.dwell_after_s;
            }
        }
    }
    if let Some(last) = points.last_mut() {
        last.cap = 0.0;
        last.cap_fast = 0.0;
        last.limit = Limit::Feed;
        last.hold = elements.last().map_or(0.0, |e| e.dwell_after_s);
    }
    if let Some(first) = points.first_mut() {
        first.hold += initial_dwell;
    }
    // The profile as programmed, and at the highest feed override (the executor walks the
    // first and may go as fast as the second where the override asks).
    profile(&mut points, |p| (p.cap, p.bend), |p| &mut p.v);
    profile(&mut points, |p| (p.cap_fast, p.bend_fast), |p| &mut p.v_fast);
    // Times.
    let mut t = 0.0;
    for i in 0..count {
        if i > 0 {
            let ds = points[i].s - points[i - 1].s;
            let (v0, v1) = (points[i - 1].v, points[i].v);
            t += if v0 + v1 > 0.0 {
                2.0 * ds / (v0 + v1)
            } else {
                2.0 * (ds / points[i - 1].accel.min(points[i].accel)).sqrt()
            };
        }
        points[i].t = t;
        t += points[i].hold;
    }
    // The blocks whose feed the machine limits.
    let mut limited: Vec<Limited> = Vec::new();
    for p in points.iter().filter(|p| p.limit != Limit::Feed) {
        let e = &elements[p.element as usize];
        if !e.feed.is_finite() || p.cap >= e.feed * (1.0 - 1e-6) {
            continue;
        }
        // Points come in line order: a line's entry, if any, is the last.
        match limited.last_mut().filter(|l| l.line == e.line) {
            Some(l) if p.cap * 60.0 < l.reachable_mm_min => {
                l.reachable_mm_min = p.cap * 60.0;
                l.why = p.limit;
            }
            Some(_) => {}
            None => limited.push(Limited {
                line: e.line,
                programmed_mm_min: e.feed * 60.0,
                reachable_mm_min: p.cap * 60.0,
                why: p.limit,
            }),
        }
    }
    // The events on the time line: each at the stop after the last element of an earlier line
    // (elements come in line order; a blend takes the line after its corner, and no stop is
    // blended), after the dwell that came before it there.
    let events = pending
        .iter()
        .map(|e| {
            let before = elements.partition_point(|el| el.line < e.line);
            let arrival = if before == 0 {
                0.0
            } else {
                let stop = points.partition_point(|p| (p.element as usize) < before);
                points.get(stop).or(points.last()).map_or(0.0, |p| p.t)
            };
            TrajectoryEvent {
                t: arrival + e.dwelt_s,
                line: u32::try_from(e.line).unwrap_or(u32::MAX),
                kind: e.kind,
            }
        })
        .collect();
    // The feed moves' time as planned (each interval belongs to the element of its start) and
    // at their programmed feeds.
    let feed_time_s = points
        .windows(2)
        .filter(|w| elements[w[0].element as usize].feed.is_finite())
        .map(|w| w[1].t - (w[0].t + w[0].hold))
        .sum();
    let programmed_feed_time_s = elements
        .iter()
        .filter(|e| e.feed.is_finite())
        .map(|e| e.segment.length() / e.feed)
        .sum();
    limited.shrink_to_fit();
    Ok(Plan {
        duration_s: t,
        length_mm: s,
        elements,
        points,
        limited,
        events,
        feed_time_s,
        programmed_feed_time_s,
    })
}

/// Forward and backward passes over `points`, with each point's cap and bend as `limits` gives
/// them: over an interval the speed changes by at most the bound of each end at that end's
/// speed (v₁² − v₀² ≤ 2 ds (accel − bend · v²)); each point's bound holds up to its cap, which
/// its speed never passes. `speed` is the field the profile is written to.
fn profile(points: &mut [Point], limits: impl Fn(&Point) -> (f64, f64), speed: fn(&mut Point) -> &mut f64) {
    let reachable = |from: f64, ds: f64, p: &Point, q: &Point| {
        let (pb, qb) = (limits(p).1, limits(q).1);
        let by_start = from * from + 2.0 * ds * (p.accel - pb * from * from);
        let by_end = (from * from + 2.0 * ds * q.accel) / (1.0 + 2.0 * ds * qb);
        by_start.min(by_end).max(0.0).sqrt()
    };
    let count = points.len();
    for i in 0..count {
        let v = if i == 0 {
            0.0
        } else {
            let ds = points[i].s - points[i - 1].s;
            let from = *speed(&mut points[i - 1]);
            reachable(from, ds, &points[i - 1], &points[i]).min(limits(&points[i]).0)
        };
        *speed(&mut points[i]) = v;
    }
    for i in (0..count.saturating_sub(1)).rev() {
        let ds = points[i + 1].s - points[i].s;
        let from = *speed(&mut points[i + 1]);
        let v = reachable(from, ds, &points[i + 1], &points[i]);
        let here = speed(&mut points[i]);
        *here = here.min(v);
    }
}

/// The second derivative through three points at `sa < si < sb`.
fn second(ya: f64, yi: f64, yb: f64, sa: f64, si: f64, sb: f64) -> f64 {
    2.0 * ((yb - yi) / (sb - si) - (yi - ya) / (si - sa)) / (sb - sa)
}

impl Plan {
    /// The memory the plan holds (bytes): its elements, the points of its velocity profile,
    /// its events and the list of limited feeds, as allocated.
    pub fn heap_bytes(&self) -> u64 {
        let arcs = self.elements.iter().filter(|e| e.segment.is_arc()).count();
        (self.elements.capacity() * size_of::<Element>()
            + arcs * crate::path::ARC_BYTES
            + self.points.capacity() * size_of::<Point>()
            + self.limited.capacity() * size_of::<Limited>()
            + self.events.capacity() * size_of::<TrajectoryEvent>()) as u64
    }
}

impl Plan {
    /// The first place after `s` (mm) where the motion of one program line ends and the next
    /// line's begins: its distance along the path and its planned time (s, when the tool
    /// arrives there). Allocates nothing.
    pub fn block_end(&self, s: f64) -> Option<(f64, f64)> {
        let points = &self.points;
        let first = points.partition_point(|p| p.s <= s);
        let mut element = points.get(first.checked_sub(1)?)?.element as usize;
        let line = self.elements.get(element)?.line;
        // The next element of another line.
        while self.elements.get(element)?.line == line {
            element += 1;
        }
        let at = points.partition_point(|p| (p.element as usize) < element);
        points.get(at).map(|p| (p.s, p.t))
    }

    /// The path's elements.
    pub fn elements(&self) -> &[Element] {
        &self.elements
    }

    /// A cursor for [`Plan::sample`] at time `t`, found by bisection.
    pub fn cursor_at(&self, t: f64) -> usize {
        self.points.partition_point(|p| p.t <= t).saturating_sub(1)
    }

    /// The pose at time `t` (s from the start); `cursor` remembers where the last call was, so
    /// that sampling forward in time costs O(1) per call. Allocates nothing.
    pub fn sample(&self, t: f64, cursor: &mut usize) -> Sample {
        let points = &self.points;
        let Some(last) = points.last() else {
            return Sample {
                pose: [0.0; 6],
                line: 0,
                s: 0.0,
                speed: 0.0,
                speed_max: 0.0,
                accel: f64::INFINITY,
                rapid: false,
            };
        };
        if *cursor >= points.len() || points[*cursor].t > t {
            *cursor = 0;
        }
        while *cursor + 1 < points.len() && points[*cursor + 1].t <= t {
            *cursor += 1;
        }
        let i = *cursor;
        let p = &points[i];
        let e = &self.elements[p.element as usize];
        // Standing at the point through its hold (at its time exactly only where it has one:
        // a point the tool passes has the speed of its interval's start).
        if i + 1 >= points.len() || t < p.t + p.hold || (p.hold > 0.0 && t == p.t + p.hold) {
            let (element, u) = if i + 1 >= points.len() {
                (last.element as usize, 1.0)
            } else {
                (p.element as usize, p.u)
            };
            return Sample {
                pose: self.elements[element].segment.at(u),
                line: self.elements[element].line,
                s: if i + 1 >= points.len() { last.s } else { p.s },
                speed: 0.0,
                speed_max: 0.0,
                accel: p.accel,
                rapid: !self.elements[element].feed.is_finite(),
            };
        }
        let q = &points[i + 1];
        let ds = q.s - p.s;
        let dt = q.t - (p.t + p.hold);
        let tau = (t - p.t - p.hold).clamp(0.0, dt);
        // Constant acceleration over the interval.
        let a = if dt > 0.0 { (q.v - p.v) / dt } else { 0.0 };
        let travelled = (p.v * tau + 0.5 * a * tau * tau).clamp(0.0, ds);
        // Within the interval's element (the last interval of an element ends at its u = 1).
        let u = (p.u + travelled / e.segment.length()).min(1.0);
        let element = p.element as usize;
        let speed = p.v + a * tau;
        // The bound at this speed; where a mixed bound of several joints leaves less, the share
        // a curve leaves at its cap.
        let (rest, bend) = (p.accel.min(q.accel), p.bend.max(q.bend));
        // The fast profile over the same interval: constant acceleration too, so its speed
        // squared is linear in the distance.
        let share = if ds > 0.0 { travelled / ds } else { 0.0 };
        let fast = (p.v_fast * p.v_fast + (q.v_fast * q.v_fast - p.v_fast * p.v_fast) * share)
            .max(0.0)
            .sqrt();
        Sample {
            pose: self.elements[element].segment.at(u),
            line: self.elements[element].line,
            s: p.s + travelled,
            speed,
            speed_max: fast.max(speed),
            accel: (rest - bend * speed * speed).max((1.0 - NORMAL_SHARE) * rest),
            rapid: !e.feed.is_finite(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interp::{Machine, read};

    fn frame(model: pkm_kinematics::Machine) -> MachineFrame {
        MachineFrame::default_for(model).expect("the default home is a pose")
    }

    fn limits(n: usize, speed: f64, accel: f64) -> PlanLimits {
        PlanLimits {
            joint_speed: vec![speed; n],
            joint_accel: vec![accel; n],
            axis_speed: [50.0; 6],
            axis_accel: [500.0; 6],
        }
    }

    fn planned(model: pkm_kinematics::Machine, text: &str, l: &PlanLimits) -> Plan {
        let f = frame(model);
        let program = read(
            // A program ends (M2); what follows an end is never read.
            &format!("{text}\nM2"),
            &Machine {
                block_delete: false,
                axes: f.kinematics().pose_keys(),
                start: [0.0; 6],
                work_offsets: [[0.0; 6]; 6],
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        plan(&program, &f, l).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Samples every `dt` from start to end.
    fn samples(p: &Plan, dt: f64) -> Vec<Sample> {
        let mut cursor = 0;
        let steps = (p.duration_s / dt).ceil() as usize + 1;
        (0..=steps).map(|i| p.sample(i as f64 * dt, &mut cursor)).collect()
    }

    /// What the interpreter counts for a program bounds what the program and its plan hold:
    /// short blended lines, arcs, long lines, exact stops, rotations.
    #[test]
    fn the_counted_cost_bounds_the_memory_of_the_program_and_its_plan() {
        let spiral: String = (0..5000)
            .map(|i| {
                let (a, r) = (i as f64 * 0.02, 5.0 + i as f64 * 0.001);
                format!("X{:.3} Y{:.3}\n", r * a.cos() - 5.0, r * a.sin())
            })
            .collect();
        let arcs: String = (0..200).map(|_| "G2 X0 Y0 I2 J0 P3\nG3 X0 Y0 I-1 J0\n").collect();
        let lines: String = (0..300).map(|i| format!("X{} Y{}\n", i % 2 * 30, i % 3 * 10)).collect();
        let tilts: String = (0..300).map(|i| format!("X{} A{}\n", i % 2, i % 3)).collect();
        for (model, text) in [
            (pkm_kinematics::Machine::OxX, format!("G64 P0.01\nG1 F3000\n{spiral}")),
            (pkm_kinematics::Machine::OxX, format!("G64 P0.05\nG1 F600\n{arcs}")),
            (pkm_kinematics::Machine::OxX, format!("G61\nG1 F600\n{lines}")),
            (pkm_kinematics::Machine::Hexapod, format!("G64\nG1 F300\n{tilts}")),
        ] {
            let f = frame(model);
            let program = read(
                &format!("{text}M2"),
                &Machine {
                    block_delete: false,
                    axes: f.kinematics().pose_keys(),
                    start: [0.0; 6],
                    work_offsets: [[0.0; 6]; 6],
                },
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let mut cost = crate::budget::Cost::default();
            for b in &program.blocks {
                cost.add(b);
            }
            let plan = plan(&program, &f, &limits(f.dof(), 50.0, 500.0)).unwrap_or_else(|e| panic!("{e}"));
            let held = (program.blocks.capacity() * size_of::<crate::interp::Block>()) as u64 + plan.heap_bytes();
            assert!(
                held <= cost.bytes() && held * 2 > cost.bytes(),
                "{model:?}: {held} bytes held, {} counted",
                cost.bytes()
            );
        }
    }

    /// G64 Q (LinuxCNC's naive CAM detector): a CAM program's run of short lines that stray less
    /// than Q from one straight line is run as that line — fewer corners, a shorter time — and
    /// lines that turn more than Q stay lines of their own.
    #[test]
    fn g64_q_merges_nearly_collinear_lines_within_q() {
        let zigzag: String = (1..=100)
            .map(|i| format!("X{} Y{}\n", i as f64 * 0.5, if i % 2 == 0 { 0.0 } else { 0.004 }))
            .collect();
        let l = limits(3, 20.0, 100.0);
        let without = planned(
            pkm_kinematics::Machine::OxX,
            &format!("G64 P0.01\nG1 F600\n{zigzag}"),
            &l,
        );
        let merged = planned(
            pkm_kinematics::Machine::OxX,
            &format!("G64 P0.01 Q0.01\nG1 F600\n{zigzag}"),
            &l,
        );
        // Without Q every corner is blended: a hundred pieces and more.
        assert!(without.elements().len() > 100, "{}", without.elements().len());
        // At most 64 lines a merge: two lines of 32 and 18 mm.
        let lines: Vec<f64> = merged.elements().iter().map(|e| e.segment.length()).collect();
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(
            merged.duration_s < without.duration_s,
            "{} vs {}",
            merged.duration_s,
            without.duration_s
        );
        // A turn beyond Q is not merged away.
        let corner = planned(
            pkm_kinematics::Machine::OxX,
            "G64 P0.01 Q0.01\nG1 F600 X10\nX20 Y1\n",
            &l,
        );
        assert!(corner.elements().len() >= 2);
    }

    const SQUARE_AND_CIRCLE: &str = "G64 P0.05\nG1 X20 Y0 F1200\nY20\nX0\nY0\nG0 X10\nG2 X10 Y0 I-10 F900\nM2\n";

    #[test]
    fn every_joint_keeps_its_speed_and_acceleration_at_every_sample() {
        // Checked against the kinematics: joint positions by IK of the sampled poses, their
        // differences over 2 ms.
        const TILTS: &str = "G64 P0.05\nG1 X10 A3 F600\nY10 B-3\nX0 A0\nY0 B0\nG2 X0 Y0 I5 J0 C2\nM2\n";
        for (model, n, program, speed, accel) in [
            (pkm_kinematics::Machine::OxX, 3, SQUARE_AND_CIRCLE, 20.0, 100.0),
            (pkm_kinematics::Machine::Pn101, 3, SQUARE_AND_CIRCLE, 8.0, 40.0),
            (pkm_kinematics::Machine::Hexapod, 6, TILTS, 25.0, 200.0),
        ] {
            let l = limits(n, speed, accel);
            let p = planned(model, program, &l);
            let f = frame(model);
            let dt = 0.002;
            let q: Vec<[f64; MAX_DOF]> = samples(&p, dt)
                .iter()
                .map(|s| {
                    let mut q = [0.0; MAX_DOF];
                    f.inverse(&s.pose[..n], &mut q[..n]).expect("reachable");
                    q
                })
                .collect();
            let (mut vmax, mut amax) = (0.0f64, 0.0f64);
            for w in q.windows(3) {
                for ((q0, q1), q2) in w[0][..n].iter().zip(&w[1][..n]).zip(&w[2][..n]) {
                    vmax = vmax.max(((q1 - q0) / dt).abs());
                    amax = amax.max(((q2 - 2.0 * q1 + q0) / (dt * dt)).abs());
                }
            }
            assert!(vmax <= speed * 1.01, "{model:?}: joint speed {vmax} > {speed}");
            assert!(amax <= accel * 1.05, "{model:?}: joint acceleration {amax} > {accel}");
        }
    }

    #[test]
    fn blends_stay_within_the_tolerance_and_exact_stops_stop() {
        let l = limits(3, 100.0, 1000.0);
        // The square's corners rounded within 0.05 mm: every sample within 0.05 mm of the
        // programmed polyline.
        let p = planned(
            pkm_kinematics::Machine::OxX,
            "G64 P0.05\nG1 X20 F1200\nY20\nX0\nY0\nM2\n",
            &l,
        );
        let corners = [[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0], [0.0, 0.0]];
        let distance = |x: f64, y: f64| {
            corners
                .windows(2)
                .map(|w| {
                    let (a, b) = (w[0], w[1]);
                    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                    let t = (((x - a[0]) * dx + (y - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                    (x - a[0] - t * dx).hypot(y - a[1] - t * dy)
                })
                .fold(f64::INFINITY, f64::min)
        };
        let worst = samples(&p, 0.001)
            .iter()
            .map(|s| distance(s.pose[0], s.pose[1]))
            .fold(0.0, f64::max);
        assert!(worst <= 0.05 + 1e-9, "{worst} mm off the programmed path");
        assert!(worst > 0.01, "the corners are rounded, not stopped at: {worst}");
        // G64 without P: within PLAIN_G64_MM, not half of each 20 mm line (5.8 mm before).
        let plain = planned(pkm_kinematics::Machine::OxX, "G64\nG1 X20 F1200\nY20\nX0\nY0\nM2\n", &l);
        let worst = samples(&plain, 0.001)
            .iter()
            .map(|s| distance(s.pose[0], s.pose[1]))
            .fold(0.0, f64::max);
        assert!(worst <= PLAIN_G64_MM + 1e-9, "{worst} mm off the programmed path");
        // A 90° corner's arc passes the corner at the bound, the lines at 1 − cos 45° of its
        // radius: 0.707 of the bound.
        assert!(worst > 0.7 * PLAIN_G64_MM, "rounded up to the bound: {worst}");
        // G61: the tool stops at each corner; it takes longer.
        let exact = planned(pkm_kinematics::Machine::OxX, "G61\nG1 X20 F1200\nY20\nX0\nY0\nM2\n", &l);
        assert!(
            exact.duration_s > p.duration_s,
            "{} vs {}",
            exact.duration_s,
            p.duration_s
        );
        let closest = samples(&exact, 0.001)
            .iter()
            .map(|s| (s.pose[0] - 20.0).hypot(s.pose[1]))
            .fold(f64::INFINITY, f64::min);
        assert!(closest < 1e-3, "the tool reaches the corner: {closest} mm");
    }

    /// Short CAM lines written to three decimals, two of them turning by 2e-8 rad: planned,
    /// every sample a finite pose (the blend between the two had a centre that was not a number).
    #[test]
    fn nearly_collinear_short_lines_plan_to_finite_poses() {
        let l = limits(3, 200.0, 2000.0);
        let p = planned(
            pkm_kinematics::Machine::Pn101,
            "G64 P0.01\nG0 X2.572 Y4.288\nG1 F600\nX2.545 Y4.304\nX2.518 Y4.320\nX2.491 Y4.335\nX2.464 Y4.351\nX2.436 Y4.366",
            &l,
        );
        assert!(p.duration_s > 0.0);
        for s in samples(&p, 0.002) {
            assert!(s.pose.iter().all(|v| v.is_finite()), "{s:?}");
        }
    }

    /// A line into an arc at an angle (90° here) is blended within G64 P by two arcs
    /// instead of stopping: the tool keeps moving through the corner, passes it within P, and
    /// the part takes less time than with G61.
    #[test]
    fn a_line_into_an_arc_is_blended_within_the_tolerance() {
        let l = limits(3, 100.0, 1000.0);
        let text = |mode: &str| format!("{mode}\nG1 X10 F600\nG3 X20 Y0 I5 J0\nG1 X30\nM2\n");
        let blended = planned(pkm_kinematics::Machine::OxX, &text("G64 P0.01"), &l);
        let exact = planned(pkm_kinematics::Machine::OxX, &text("G61"), &l);
        assert!(
            blended.duration_s < exact.duration_s,
            "{} vs {}",
            blended.duration_s,
            exact.duration_s
        );
        let samples = samples(&blended, 0.0005);
        // Through both corners the tool never stands.
        let moving = samples
            .iter()
            .filter(|s| (s.pose[0] - 10.0).hypot(s.pose[1]) < 0.2 || (s.pose[0] - 20.0).hypot(s.pose[1]) < 0.2)
            .map(|s| s.speed)
            .fold(f64::INFINITY, f64::min);
        assert!(moving > 0.5, "the slowest speed at the corners: {moving} mm/s");
        // Within P of the programmed path: the lines (y = 0 outside 10 … 20) and the lower half
        // circle about (15, 0).
        let off = |s: &Sample| {
            let (x, y) = (s.pose[0], s.pose[1]);
            let to_circle = if y <= 0.0 {
                ((x - 15.0).hypot(y) - 5.0).abs()
            } else {
                f64::INFINITY
            };
            let to_lines = if x <= 10.0 || x >= 20.0 {
                y.abs()
            } else {
                (x - 10.0).hypot(y).min((x - 20.0).hypot(y))
            };
            to_circle.min(to_lines)
        };
        let worst = samples.iter().map(off).fold(0.0, f64::max);
        assert!(worst <= 0.01 + 1e-9, "{worst} mm off the programmed path");
    }

    #[test]
    fn a_long_line_runs_at_its_feed_and_lasts_length_over_feed_plus_the_ramps() {
        let l = limits(3, 100.0, 1000.0);
        let p = planned(pkm_kinematics::Machine::OxX, "G1 X100 F1200\nM2\n", &l);
        let top = samples(&p, 0.01).iter().map(|s| s.speed).fold(0.0, f64::max);
        assert!((top - 20.0).abs() < 1e-6, "the feed 20 mm/s is reached: {top}");
        // 100 mm at 20 mm/s, plus the ramps' 20 mm/s ÷ a, where a is the tool's tangential
        // acceleration (half the slowest limit over the largest gear ratio).
        assert!(p.duration_s > 5.0 && p.duration_s < 5.6, "{}", p.duration_s);
        assert!(p.limited.is_empty(), "{:?}", p.limited);
    }

    #[test]
    fn a_feed_beyond_a_joints_speed_is_limited_and_said_why() {
        // pn101's joints run 8 mm/s: a 100 mm/s feed along x cannot be had.
        let l = limits(3, 8.0, 40.0);
        let p = planned(pkm_kinematics::Machine::Pn101, "G1 X20 F6000\nM2\n", &l);
        assert_eq!(p.limited.len(), 1, "{:?}", p.limited);
        let lim = &p.limited[0];
        assert_eq!(lim.line, 1);
        assert_eq!(lim.programmed_mm_min, 6000.0);
        assert!(matches!(lim.why, Limit::JointSpeed(_)), "{lim:?}");
        assert!(lim.reachable_mm_min < 6000.0);
    }

    #[test]
    fn short_segments_do_not_slow_the_tool() {
        // A circle of radius 30 mm as CAM writes it: chords of 0.05 … 0.5 mm, blended within
        // 0.01 mm. Its planned time stays within 5 % of length ÷ feed.
        let mut text = String::from("G64 P0.01\nG0 X30 Y0\n");
        let (mut angle, mut i) = (0.0f64, 0u32);
        while angle < std::f64::consts::TAU {
            let chord = 0.05 + 0.45 * f64::from(i % 10) / 9.0;
            angle = (angle + chord / 30.0).min(std::f64::consts::TAU);
            text.push_str(&format!(
                "G1 X{:.4} Y{:.4} F1200\n",
                30.0 * angle.cos(),
                30.0 * angle.sin()
            ));
            i += 1;
        }
        text.push_str("M2\n");
        let l = limits(3, 100.0, 1000.0);
        let p = planned(pkm_kinematics::Machine::OxX, &text, &l);
        let feed_time = (p.length_mm - 30.0) / 20.0;
        assert!(i > 600, "{i} segments");
        assert!(
            p.duration_s < 1.05 * feed_time + 2.0,
            "{} s for {} s at the feed",
            p.duration_s,
            feed_time
        );
        assert!(
            p.elements().iter().all(|e| e.segment.length() > 1e-9),
            "no empty pieces"
        );
    }

    #[test]
    fn rotations_join_without_a_kink_and_a_straight_line_with_a_new_rate_stops() {
        let l = limits(6, 25.0, 200.0);
        // A corner blended: the tilt's rate changes smoothly through it.
        let p = planned(
            pkm_kinematics::Machine::Hexapod,
            "G64 P0.5\nG1 X10 A2 F600\nY10 A0\nM2\n",
            &l,
        );
        let blend = p.elements().iter().find(|e| e.segment.is_arc()).expect("a blend");
        let (r0, r1) = blend.segment.rotation_rates();
        assert!(
            (r0[0] - 0.2).abs() < 1e-9 && (r1[0] + 0.2).abs() < 1e-9,
            "{r0:?} {r1:?}"
        );
        // Straight on, but the tilt changes its rate: the tool stops between the two.
        let p = planned(
            pkm_kinematics::Machine::Hexapod,
            "G64\nG1 X10 A2 F600\nX20 A0\nM2\n",
            &l,
        );
        assert!(p.elements()[0].stop_after, "{:?}", p.elements()[0]);
        assert_eq!(p.elements().len(), 2);
    }

    #[test]
    fn a_dwell_holds_the_tool() {
        let l = limits(3, 100.0, 1000.0);
        let without = planned(pkm_kinematics::Machine::OxX, "G1 X10 F600\nG1 X20\nM2\n", &l);
        let with = planned(pkm_kinematics::Machine::OxX, "G1 X10 F600\nG4 P2\nG1 X20\nM2\n", &l);
        assert!(
            with.duration_s > without.duration_s + 2.0,
            "{} vs {}",
            with.duration_s,
            without.duration_s
        );
        let mut cursor = 0;
        let s = with.sample(with.duration_s / 2.0, &mut cursor);
        assert!((s.pose[0] - 10.0).abs() < 1e-9 && s.speed == 0.0, "{s:?}");
    }

    #[test]
    fn pauses_and_spindle_changes_stand_where_the_tool_stops_for_them() {
        let l = limits(3, 100.0, 1000.0);
        let p = planned(
            pkm_kinematics::Machine::OxX,
            "S1000 M3\nG64 P0.1\nG1 X10 F600\nG4 P1\nM0\nG1 X20\nM5\nM2\n",
            &l,
        );
        let kinds: Vec<(u32, TrajectoryEventKind)> = p.events.iter().map(|e| (e.line, e.kind)).collect();
        assert_eq!(
            kinds,
            [
                (
                    1,
                    TrajectoryEventKind::Spindle {
                        direction: 1,
                        rpm: 1000.0
                    }
                ),
                (5, TrajectoryEventKind::Pause),
                (7, TrajectoryEventKind::Spindle { direction: 0, rpm: 0.0 }),
            ]
        );
        assert_eq!(p.events[0].t, 0.0);
        // The pause after the dwell, at the end of the first line: the tool stands at X10.
        let mut cursor = 0;
        let at = p.sample(p.events[1].t, &mut cursor);
        assert!((at.pose[0] - 10.0).abs() < 1e-9 && at.speed == 0.0, "{at:?}");
        let before = p.sample(p.events[1].t - 0.5, &mut cursor);
        assert!((before.pose[0] - 10.0).abs() < 1e-9, "dwelling first: {before:?}");
        assert!((p.events[2].t - p.duration_s).abs() < 1e-9, "M5 at the end");
    }
}
