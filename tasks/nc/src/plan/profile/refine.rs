//! A finer grid where the profile needs one: where a coordinate's acceleration could pass
//! between two points what it is at both, and where one end of an interval allows much more
//! acceleration than the other (on a curve taken fast, the curvature takes more of each
//! acceleration as the speed grows, and a constant acceleration over the interval keeps to the
//! lower end's).

use pkm_kinematics::frame::MachineFrame;

use super::super::elements::Element;
use super::super::limits::PlanError;
use super::Point;
use super::bounds::{Bounds, settle};
use super::place::{alpha_beta, place};
use crate::watch::Watched;

/// How far (a share of its limit) a coordinate's acceleration may pass its value at the ends of
/// an interval in between, before the grid is made finer there.
const BETWEEN: f64 = 0.001;
/// How much finer the grid is made where the acceleration one end of an interval allows
/// differs from the other's by more than this share of an acceleration.
const UNEVEN: f64 = 0.05;
/// How much more (a share) one end of an interval may allow the acceleration it takes at the
/// other end's bound, at each end's own speed, before the grid is made finer there: over an
/// interval the acceleration is constant, and keeps the lower bound where the time-optimal
/// motion follows the bound as it changes (a short move, whose speed changes all along it,
/// lost 1.3 % on a grid of a third of a millimetre).
const GAIN: f64 = 0.002;
/// The most points an interval is split into.
const MOST_SPLIT: usize = 16;
/// The points refining may add to any program in all, besides a quarter of its own.
pub(crate) const EXTRA_POINTS: usize = 8192;

/// How many points refining may add to a profile of `points` points in all.
pub(crate) fn allowance(points: usize) -> usize {
    points / 4 + EXTRA_POINTS
}
/// How many times the grid is refined at the most.
pub(in super::super) const REFINEMENTS: usize = 8;

/// Into how many intervals the interval from point `i` to the next is split.
fn split(points: &[Point], bounds: &Bounds, i: usize) -> usize {
    let (p, q) = (&points[i], &points[i + 1]);
    let ds = q.s - p.s;
    let (x0, x1) = (p.v * p.v, q.v * q.v);
    if ds <= 0.0 {
        return 1;
    }
    let (start, end) = bounds.interval(points, i);
    let coordinates = &bounds.coordinates;
    // A coordinate's acceleration q′ u + q″ x is held at both ends; in between it is bilinear
    // in the derivatives and the speed squared (both change in proportion to the distance, to
    // first order), and passes its ends' by at most Δq″ Δx / 4: split so that this stays below
    // BETWEEN of its limit (halved intervals, a quarter of it).
    let between = start
        .iter()
        .zip(end)
        .zip(coordinates.iter())
        .filter(|(_, (_, _, accel))| accel.is_finite() && *accel > 0.0)
        .map(|((d0, d1), (_, _, accel))| (f64::from(d1[1]) - f64::from(d0[1])).abs() * (x1 - x0).abs() / 4.0 / accel)
        .fold(0.0, f64::max);
    let by_speed = if between > BETWEEN {
        (between / BETWEEN).sqrt().ceil() as usize
    } else {
        1
    };
    // Where the speed is below both ends' caps (the acceleration bounds it), and the bounds of
    // a coordinate at one end differ from the other's at the interval's highest speed by more
    // than UNEVEN of an acceleration, a finer grid follows the bounds more closely: over an
    // interval the acceleration keeps both ends' bounds at once.
    let (cap0, cap1) = bounds.interval_caps(points, i);
    let x = x0.max(x1);
    let capped = x0 >= (1.0 - UNEVEN) * cap0 * cap0 && x1 >= (1.0 - UNEVEN) * cap1 * cap1;
    let scale = coordinates
        .bounds(start)
        .chain(coordinates.bounds(end))
        .map(|(a, _)| a)
        .fold(f64::INFINITY, f64::min);
    let by_bound = if capped || !(scale.is_finite() && scale > 0.0) {
        1
    } else {
        let uneven = start
            .iter()
            .zip(end)
            .zip(coordinates.iter())
            .filter_map(|((d0, d1), &(_, _, a))| {
                let (a0, b0) = alpha_beta(*d0, a)?;
                let (a1, b1) = alpha_beta(*d1, a)?;
                // The highest and the lowest bound at each end, at the same speed.
                Some(
                    ((a0 - b0 * x) - (a1 - b1 * x))
                        .abs()
                        .max(((-a0 - b0 * x) - (-a1 - b1 * x)).abs()),
                )
            })
            .fold(0.0, f64::max);
        ((uneven / (UNEVEN * scale)).ceil() as usize).max(1)
    };
    by_speed.max(by_bound).max(by_gain(points, bounds, i)).min(MOST_SPLIT)
}

/// Into how many intervals the interval from point `i` to the next is split where its
/// acceleration is at one end's bound and the other end allows more than [`GAIN`] more.
fn by_gain(points: &[Point], bounds: &Bounds, i: usize) -> usize {
    let (u, x0, x1) = motion(points, i);
    if u == 0.0 {
        return 1;
    }
    let (start, end) = bounds.interval(points, i);
    let coordinates = &bounds.coordinates;
    // The bound in the direction of the acceleration at speed squared x: α − β x speeding up,
    // α + β x braking (the magnitude of −α − β x).
    let sign = u.signum();
    let bound = |row: &[super::place::Derivs], x: f64| {
        coordinates
            .bounds(row)
            .map(|(a, b)| a - sign * b * x)
            .fold(f64::INFINITY, f64::min)
    };
    let (b0, b1) = (bound(start, x0), bound(end, x1));
    let low = b0.min(b1);
    if !(low.is_finite() && low > 0.0) || u.abs() < AT_LIMIT * low {
        return 1;
    }
    let gain = (b0.max(b1) - low) / low;
    if gain > GAIN {
        (gain / GAIN).ceil().min(MOST_SPLIT as f64) as usize
    } else {
        1
    }
}

/// Nearer a limit than this (a share of it) an interval is at it.
const AT_LIMIT: f64 = 0.99;
/// How far past its limit a coordinate may be in the middle of an interval before the interval
/// is split (the margin below every limit covers it).
const PAST_LIMIT: f64 = 0.0005;

/// The tangential acceleration over the interval from point `i` to the next (constant, as the
/// passes plan it), and its speeds squared at both ends.
fn motion(points: &[Point], i: usize) -> (f64, f64, f64) {
    let (p, q) = (&points[i], &points[i + 1]);
    let (x0, x1) = (p.v * p.v, q.v * q.v);
    let ds = q.s - p.s;
    let u = if ds > 0.0 { (x1 - x0) / (2.0 * ds) } else { 0.0 };
    (u, x0, x1)
}

/// The most of its limits (speed and acceleration, as a share) any coordinate uses with the
/// derivatives `row` at the speed squared `x` and tangential acceleration `u`.
fn used(coordinates: &super::place::Coordinates, row: &[super::place::Derivs], u: f64, x: f64) -> f64 {
    row.iter()
        .zip(coordinates.iter())
        .map(|(d, &(_, _, accel))| {
            let (d1, d2) = (f64::from(d[0]), f64::from(d[1]));
            (d1 * u + d2 * x).abs() / accel.max(1e-300)
        })
        .chain(
            row.iter()
                .zip(coordinates.iter())
                .map(|(d, &(_, speed, _))| f64::from(d[0]).abs() * x.sqrt() / speed.max(1e-300)),
        )
        .fold(0.0, f64::max)
}

/// Whether the interval from point `i` to the next is at a coordinate's limit at either end.
fn tight(points: &[Point], bounds: &Bounds, i: usize) -> bool {
    let (u, x0, x1) = motion(points, i);
    let (start, end) = bounds.interval(points, i);
    used(&bounds.coordinates, start, u, x0).max(used(&bounds.coordinates, end, u, x1)) >= AT_LIMIT
}

/// Whether a coordinate passes its limit in the middle of the interval from point `i` to the
/// next, where its derivatives are `middle`.
fn passes_in_middle(points: &[Point], bounds: &Bounds, i: usize, middle: &[super::place::Derivs]) -> bool {
    let (u, x0, x1) = motion(points, i);
    used(&bounds.coordinates, &middle[..bounds.width], u, (x0 + x1) / 2.0) > 1.0 + PAST_LIMIT
}

/// The profile's points with more between those that need them ([`split`]; at most `allowance`
/// more, which is lowered by as many), and their bounds; `None` where none is needed.
pub(in super::super) fn refine(
    points: &[Point],
    bounds: &Bounds,
    elements: &[Element],
    frame: &MachineFrame,
    allowance: &mut usize,
    watched: &mut Watched<'_>,
) -> Result<Option<(Vec<Point>, Bounds)>, PlanError> {
    let count = points.len();
    let mut splits: Vec<u8> = (0..count.saturating_sub(1))
        .map(|i| split(points, bounds, i) as u8)
        .collect();
    // An interval at a limit at either end is looked at in its middle too: where a coordinate
    // passes its limit there (its derivatives change along the interval in a way its ends do
    // not tell), it is split.
    for (i, k) in splits.iter_mut().enumerate() {
        if *k == 1 && tight(points, bounds, i) {
            let (p, q) = (&points[i], &points[i + 1]);
            let e = &elements[p.element as usize];
            watched.step().map_err(|why| PlanError {
                line: e.line,
                column: e.column,
                message: why,
            })?;
            let u_end = if q.element == p.element { q.u } else { 1.0 };
            let middle = place(e, (p.u + u_end) / 2.0, frame, &bounds.coordinates)?;
            if passes_in_middle(points, bounds, i, &middle.derivs) {
                *k = 2;
            }
        }
    }
    let wanted: usize = splits.iter().map(|&k| usize::from(k) - 1).sum();
    if wanted == 0 {
        return Ok(None);
    }
    // Within the allowance: each interval's share of it.
    let scale = (*allowance as f64 / wanted as f64).min(1.0);
    let parts = |k: u8| 1 + ((f64::from(k) - 1.0) * scale).floor() as usize;
    let added: usize = splits.iter().map(|&k| parts(k) - 1).sum();
    if added == 0 {
        return Ok(None);
    }
    *allowance -= added.min(*allowance);
    let coordinates = bounds.coordinates;
    let m = coordinates.count;
    let mut out: Vec<Point> = Vec::with_capacity(count + added);
    let mut refined = Bounds::with_capacity(coordinates, count + added, 0);
    refined.ends = bounds.ends.clone();
    refined.end_caps = bounds.end_caps.clone();
    for i in 0..count {
        out.push(points[i]);
        refined.rows.extend_from_slice(bounds.at(i));
        refined.own_caps.push(bounds.own_caps[i]);
        let Some(&k) = splits.get(i) else { break };
        let (p, q) = (&points[i], &points[i + 1]);
        let e = &elements[p.element as usize];
        let u_end = if q.element == p.element { q.u } else { 1.0 };
        let parts = parts(k);
        for j in 1..parts {
            watched.step().map_err(|why| PlanError {
                line: e.line,
                column: e.column,
                message: why,
            })?;
            let share = j as f64 / parts as f64;
            let u = p.u + (u_end - p.u) * share;
            let mut point = Point::new(p.s + (q.s - p.s) * share, p.element, u, e.feed);
            let here = place(e, u, frame, &coordinates)?;
            refined.rows.extend_from_slice(&here.derivs[..m]);
            refined.own_caps.push(here.cap.min(e.feed));
            settle(&mut point, &here, None, f64::INFINITY, &coordinates);
            out.push(point);
        }
    }
    Ok(Some((out, refined)))
}
