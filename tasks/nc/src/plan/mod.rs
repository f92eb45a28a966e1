//! The planner (docs/nc.md): the program's moves as one path in world coordinates — corners of
//! consecutive lines rounded by arcs within the G64 P tolerance, exact stops at G61 and wherever
//! the path cannot be blended —, and a velocity profile along it that keeps every world axis and
//! every joint within its speed and acceleration limits: joint rates through the kinematics
//! (derivatives of the inverse kinematics along the path), so the tool slows down near a
//! singularity rather than asking a drive for more than it has. It runs off the cyclic path and
//! may allocate; [`Plan::sample`] gives the pose at any time without allocating.
//!
//! The profile is computed on points at most [`GRID_SPACING`] (and [`ARC_STEP`] of a curve)
//! apart, twice: as programmed, and with every feed times [`MAX_FEED_OVERRIDE`] (the machine's
//! limits unchanged), the speed a feed override above 100 % may take at each point. Each is the
//! fastest the limits allow along the path (`profile`), but for a share of each acceleration
//! kept for braking on curves and a small margin below every limit. [`verify`] checks a plan
//! against the machine's limits through the kinematics before it is handed on.
//!
//! [`MAX_FEED_OVERRIDE`]: pkm_api::trajectory::MAX_FEED_OVERRIDE

mod elements;
mod limits;
mod profile;
mod verify;

use pkm_api::trajectory::TrajectoryEvent;
use pkm_kinematics::frame::MachineFrame;

pub use elements::{Element, PLAIN_G64_MM, REVERSAL, elements};
pub use limits::{Limit, Limited, PlanError, PlanLimits};
pub use profile::steps;
pub(crate) use profile::{POINT_BYTES, allowance};
pub use verify::{Checked, TOLERANCE, verify};

use crate::interp::block::{Pose, Program};
use crate::watch::{Unwatched, Watch, Watched};
use elements::{Pending, elements_and_events};
use profile::{CURVE_SHARE, Point, profile};

/// The largest distance between two points of the velocity profile (mm, or degrees where only
/// rotations move).
pub const GRID_SPACING: f64 = 0.5;
/// The largest angle of a curve between two points of the velocity profile (rad): 11.25°, so
/// that the direction of the curve's acceleration turns little between them (the part of it a
/// world axis takes is within 0.5 % of its largest between two points).
pub const ARC_STEP: f64 = std::f64::consts::PI / 16.0;

/// A planned program.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Where the tool stands before its first move (and throughout, without moves).
    start: Pose,
    elements: Vec<Element>,
    points: Vec<Point>,
    /// Its duration (s), dwells included.
    pub duration_s: f64,
    /// Its path's length (mm).
    pub length_mm: f64,
    /// The blocks whose speed is limited below their feed, and why.
    pub limited: Vec<Limited>,
    /// What happens besides motion (M0/M1, spindle, coolant, tool changes, messages), in time
    /// order.
    pub events: Vec<TrajectoryEvent>,
    /// The program's messages, as its message events name them.
    pub messages: Vec<pkm_api::trajectory::NcMessage>,
    /// How long the feed moves (not the rapids) take as planned (s), dwells excluded.
    pub feed_time_s: f64,
    /// How long they would take at their programmed feeds: Σ length ÷ feed (s).
    pub programmed_feed_time_s: f64,
    /// How long the tool dwells (G4) in all (s): the duration less this is the motion's.
    pub dwell_s: f64,
    /// The memory planning held besides the plan, at its most (bytes): the bounds of every
    /// coordinate at every point of the profile, given back when the profile was done.
    pub planning_bytes: u64,
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
    /// The planned speed's rate of change there (mm/s²).
    pub planned_accel: f64,
    /// A rapid (G0) executes.
    pub rapid: bool,
    /// The programmed feed of the move executing (mm/s; 0 for a rapid).
    pub feed: f64,
}

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
    let (elements, initial_dwell, pending) = elements_and_events(program);
    let (mut points, length_mm) = profile::grid(&elements);
    let mut watched = Watched::new(watch);
    let mut bounds = profile::caps(&mut points, &elements, frame, limits, &mut watched)?;
    profile::interior_caps(&mut points, &mut bounds);
    profile::stops_and_holds(&mut points, &elements, initial_dwell);
    // The profile as programmed, and at the highest feed override (the executor walks the
    // first and may go as fast as the second where the override asks).
    profile(&mut points, &bounds, |p| p.cap, |p| &mut p.v);
    // Finer where it needs to be, and planned again.
    let mut allowance = profile::allowance(points.len());
    for _ in 0..profile::REFINEMENTS {
        let Some((finer, finer_bounds)) =
            profile::refine(&points, &bounds, &elements, frame, &mut allowance, &mut watched)?
        else {
            break;
        };
        (points, bounds) = (finer, finer_bounds);
        profile::interior_caps(&mut points, &mut bounds);
        profile(&mut points, &bounds, |p| p.cap, |p| &mut p.v);
    }
    profile(&mut points, &bounds, |p| p.cap_fast, |p| &mut p.v_fast);
    // A program without moves still dwells.
    let duration_s = if points.is_empty() {
        initial_dwell
    } else {
        profile::times(&mut points, &bounds)
    };
    // The bounds served the profile; the plan keeps its points.
    let planning_bytes = bounds.heap_bytes();
    drop(bounds);
    let limited = limited_blocks(&points, &elements);
    let events = place_events(&pending, &elements, &points);
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
    let dwell_s = initial_dwell + elements.iter().map(|e| e.dwell_after_s).sum::<f64>();
    Ok(Plan {
        start: program.start,
        planning_bytes,
        dwell_s,
        duration_s,
        length_mm,
        elements,
        points,
        limited,
        events,
        messages: program.messages.clone(),
        feed_time_s,
        programmed_feed_time_s,
    })
}

/// The blocks whose feed the machine limits, each with the lowest speed any of its points may
/// take and why.
fn limited_blocks(points: &[Point], elements: &[Element]) -> Vec<Limited> {
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
    limited.shrink_to_fit();
    limited
}

/// The program's events on the time line.
fn place_events(pending: &[Pending], elements: &[Element], points: &[Point]) -> Vec<TrajectoryEvent> {
    // The events on the time line: each at the stop after the last element of an earlier line
    // (elements come in line order; a blend takes the line after its corner, and no stop is
    // blended), after the dwell that came before it there.
    pending
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
        .collect()
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
            + self.events.capacity() * size_of::<TrajectoryEvent>()
            + self
                .messages
                .iter()
                .map(|m| size_of_val(m) + m.text.capacity())
                .sum::<usize>()) as u64
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

    /// The program line whose motion takes longest as planned (dwells left out), and how long
    /// (s); `None` for a plan without motion.
    pub fn longest_move(&self) -> Option<(usize, f64)> {
        let mut longest: Option<(usize, f64)> = None;
        let mut current: Option<(usize, f64)> = None;
        for w in self.points.windows(2) {
            let line = self.elements[w[0].element as usize].line;
            let dt = w[1].t - (w[0].t + w[0].hold);
            match &mut current {
                Some((l, t)) if *l == line => *t += dt,
                _ => {
                    if let Some(done) = current.take()
                        && longest.is_none_or(|(_, t)| done.1 > t)
                    {
                        longest = Some(done);
                    }
                    current = Some((line, dt));
                }
            }
        }
        match (longest, current) {
            (Some(l), Some(c)) if c.1 > l.1 => Some(c),
            (None, c) => c,
            (l, _) => l,
        }
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
                pose: self.start,
                line: 0,
                s: 0.0,
                speed: 0.0,
                speed_max: 0.0,
                accel: f64::INFINITY,
                planned_accel: 0.0,
                rapid: false,
                feed: 0.0,
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
                planned_accel: 0.0,
                rapid: !self.elements[element].feed.is_finite(),
                feed: programmed(self.elements[element].feed),
            };
        }
        let q = &points[i + 1];
        let ds = q.s - p.s;
        let dt = q.t - (p.t + p.hold);
        // max and min, not clamp: a number that is not one must not panic on the cyclic side.
        let tau = (t - p.t - p.hold).max(0.0).min(dt);
        let (travelled, speed, planned_accel) = p.travel(q, dt, tau);
        // Within the interval's element (the last interval of an element ends at its u = 1).
        let u = (p.u + travelled / e.segment.length()).min(1.0);
        let element = p.element as usize;
        // The bound at this speed; where a mixed bound of several joints leaves less, the share
        // a curve leaves at its cap.
        let (rest, bend) = (p.accel.min(q.accel), p.bend.max(q.bend));
        // The fast profile over the same interval: its speed squared taken as linear in the
        // distance.
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
            accel: (rest - bend * speed * speed).max((1.0 - CURVE_SHARE) * rest),
            planned_accel,
            rapid: !e.feed.is_finite(),
            feed: programmed(e.feed),
        }
    }
}

/// An element's programmed feed as a sample gives it: 0 for a rapid (whose is infinite).
fn programmed(feed: f64) -> f64 {
    if feed.is_finite() { feed } else { 0.0 }
}

#[cfg(test)]
mod tests;
