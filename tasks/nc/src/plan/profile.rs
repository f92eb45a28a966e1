//! The velocity profile: points along the path at most [`GRID_SPACING`] apart, each capped by
//! the feed and by what every world axis and joint allows there (speed, and the acceleration the
//! path's curvature takes), then walked forward and backward so that each speed is reachable from
//! its neighbours', and timed.

use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;

use pkm_api::trajectory::MAX_FEED_OVERRIDE;

use super::GRID_SPACING;
use super::elements::Element;
use super::limits::{Limit, PlanError, PlanLimits};
use crate::interp::block::Pose;
use crate::watch::Watched;

/// How far from a curve a long line gets a point of its own (mm).
const JUNCTION: f64 = 0.05;
/// The share of an axis' or joint's acceleration a curve may take at its highest speed (the
/// rest is left for the change of speed): LinuxCNC's √3/2 for the normal acceleration on arcs.
pub(super) const NORMAL_SHARE: f64 = 0.866;
/// The memory one point of a velocity profile takes (bytes).
pub(crate) const POINT_BYTES: u64 = size_of::<Point>() as u64;

/// A point of the velocity profile.
#[derive(Clone, Copy, Debug)]
pub(super) struct Point {
    /// Distance along the path.
    pub(super) s: f64,
    pub(super) element: u32,
    pub(super) u: f64,
    /// Speed cap and what sets it.
    pub(super) cap: f64,
    pub(super) limit: Limit,
    /// The cap at the highest feed override (the feed times [`MAX_FEED_OVERRIDE`], the
    /// machine's limits unchanged).
    pub(super) cap_fast: f64,
    /// Tangential acceleration bound at rest (mm/s²); at speed v it is `accel − bend · v²`
    /// (what the path's curvature leaves of the axes' and joints' accelerations).
    pub(super) accel: f64,
    /// How the bound falls with the speed squared (1/mm).
    pub(super) bend: f64,
    /// The same up to `cap_fast`.
    pub(super) bend_fast: f64,
    /// Planned speed.
    pub(super) v: f64,
    /// The speed of the profile planned at the highest feed override.
    pub(super) v_fast: f64,
    /// When the tool passes (s).
    pub(super) t: f64,
    /// Standing still here this long before going on (s).
    pub(super) hold: f64,
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

/// How many points' poses and joints the caps need at once: the point, two before, two after.
const WINDOW: usize = 5;

/// The points of the velocity profile along `elements`, and the path's length (mm).
pub(super) fn grid(elements: &[Element]) -> (Vec<Point>, f64) {
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
    (points, s)
}

/// Each point's caps and acceleration bounds, from the derivatives along the path of the world
/// axes (the poses) and of the joints (IK of the poses); `watched` is asked at every point.
pub(super) fn caps(
    points: &mut [Point],
    elements: &[Element],
    frame: &MachineFrame,
    limits: &PlanLimits,
    watched: &mut Watched<'_>,
) -> Result<(), PlanError> {
    let n = frame.dof();
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
        caps_at(points, elements, limits, n, i, &poses, &joints);
    }
    Ok(())
}

/// The caps and bounds of point `i`, from the poses and joints of the window around it.
fn caps_at(
    points: &mut [Point],
    elements: &[Element],
    limits: &PlanLimits,
    n: usize,
    i: usize,
    poses: &[Pose; WINDOW],
    joints: &[[f64; MAX_DOF]; WINDOW],
) {
    let count = points.len();
    let pose = |k: usize| &poses[k % WINDOW];
    let joint = |k: usize| &joints[k % WINDOW];
    let (a, b) = (i.saturating_sub(1), (i + 1).min(count - 1));
    let ds = points[b].s - points[a].s;
    if ds <= 0.0 {
        return;
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

/// Dwells held at the stop after their element, the program's first dwell at its start, and the
/// end at rest.
pub(super) fn holds(points: &mut [Point], elements: &[Element], initial_dwell: f64) {
    let count = points.len();
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
}

/// When the tool passes each point, and the program's duration (s).
pub(super) fn times(points: &mut [Point]) -> f64 {
    let count = points.len();
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
    t
}

/// Forward and backward passes over `points`, with each point's cap and bend as `limits` gives
/// them: over an interval the speed changes by at most the bound of each end at that end's
/// speed (v₁² − v₀² ≤ 2 ds (accel − bend · v²)); each point's bound holds up to its cap, which
/// its speed never passes. `speed` is the field the profile is written to.
pub(super) fn profile(points: &mut [Point], limits: impl Fn(&Point) -> (f64, f64), speed: fn(&mut Point) -> &mut f64) {
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
