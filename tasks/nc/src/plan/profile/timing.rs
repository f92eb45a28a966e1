//! When the tool passes each point: between two points the speed squared changes in proportion
//! to the distance (constant acceleration), or — where that is faster: a start from rest, a slow
//! feed, whose whole change of speed takes a small part of the interval — it rises at the bounds
//! of both ends, follows the caps of both ends and falls at the bounds again (three phases of
//! constant acceleration); and where the tool is a time into an interval.

use super::bounds::Bounds;
use super::place::Derivs;
use super::{Point, Shape};

/// When the tool passes each point, how the speed changes to the next, and the program's
/// duration (s).
pub(in super::super) fn times(points: &mut [Point], bounds: &Bounds) -> f64 {
    let count = points.len();
    let mut t = 0.0;
    for i in 0..count {
        points[i].t = t;
        t += points[i].hold;
        if i + 1 < count {
            let (shape, dt) = interval(points, bounds, i);
            points[i].shape = shape;
            t += dt;
        }
    }
    t
}

/// The time of the phases of an interval from (0, `x0`) through `turns` to (`ds`, `x1`), each
/// (distance from the interval's start, speed squared there), the speed squared in proportion
/// to the distance within each.
fn phases_time(x0: f64, turns: [(f64, f64); 2], ds: f64, x1: f64) -> f64 {
    let knots = [(0.0, x0), turns[0], turns[1], (ds, x1)];
    knots
        .windows(2)
        .map(|w| {
            let (len, v) = (w[1].0 - w[0].0, w[0].1.sqrt() + w[1].1.sqrt());
            if len <= 0.0 {
                0.0
            } else if v > 0.0 {
                2.0 * len / v
            } else {
                f64::INFINITY
            }
        })
        .sum()
}

/// How the speed changes from point `i` to the next, and how long that takes (s): with
/// constant acceleration, or — where that is faster — rising at the bounds of both ends, along
/// the caps of both ends (their speeds squared joined by a straight line), and falling at the
/// bounds again: the lowest of the three lines in the speed squared against the distance.
fn interval(points: &[Point], bounds: &Bounds, i: usize) -> (Shape, f64) {
    let (p, q) = (&points[i], &points[i + 1]);
    let ds = q.s - p.s;
    let (v0, v1) = (p.v, q.v);
    let linear = if v0 + v1 > 0.0 {
        2.0 * ds / (v0 + v1)
    } else {
        f64::INFINITY
    };
    let plain = (Shape::default(), linear);
    let (x0, x1) = (v0 * v0, v1 * v1);
    // The caps of the interval's element at both its ends (never below what the ends take).
    let (cap0, cap1) = bounds.interval_caps(points, i);
    let (c0, c1) = ((cap0 * cap0).max(x0), (cap1 * cap1).max(x1));
    if !(c0.is_finite() && c1.is_finite() && ds > 0.0) {
        return plain;
    }
    let (start, end) = bounds.interval(points, i);
    let coordinates = &bounds.coordinates;
    // The bounds over every speed the interval may take, at both ends: each is concave in the
    // speed squared, so its least over a range of speeds is at the lowest or the highest.
    let least = |row: &[Derivs], sign: f64, highest: f64| {
        [x0.min(x1), highest]
            .into_iter()
            .flat_map(|x| coordinates.bounds(row).map(move |(a, b)| a - sign * b * x))
            .fold(f64::INFINITY, f64::min)
    };
    // The lines, speed squared against the distance s: rising 2 rise s from x0, the caps'
    // c0 + (c1 − c0) s / ds, falling to x1 at 2 fall (ds − s). The bounds are taken up to a
    // guess of the highest speed, raised to the highest found until they held up to it (they
    // fall with the speed: a higher guess gives a lower peak).
    let slope = (c1 - c0) / ds;
    let mut guess = x0.max(x1);
    for _ in 0..4 {
        let rise = least(start, 1.0, guess).min(least(end, 1.0, guess));
        let fall = least(start, -1.0, guess).min(least(end, -1.0, guess));
        if !(rise > 0.0 && fall > 0.0 && rise.is_finite() && fall.is_finite()) {
            return plain;
        }
        let (up, down) = (2.0 * rise, 2.0 * fall);
        // Where rising meets falling, and each meets the caps' line (where it reaches it).
        let meet = (x1 - x0 + down * ds) / (up + down);
        let x_meet = x0 + up * meet;
        let line = |s: f64| c0 + slope * s;
        let turns = if x_meet <= line(meet) {
            [(meet, x_meet), (meet, x_meet)]
        } else {
            let reach = if up > slope { (c0 - x0) / (up - slope) } else { ds };
            let leave = if down > -slope {
                (down * ds + x1 - c0) / (down + slope)
            } else {
                0.0
            };
            let (reach, leave) = (reach.max(0.0).min(ds), leave.max(0.0).min(ds));
            if reach > leave {
                return plain;
            }
            [(reach, line(reach)), (leave, line(leave))]
        };
        if !(0.0..=ds).contains(&turns[0].0) || !(0.0..=ds).contains(&turns[1].0) {
            return plain;
        }
        let peak = turns[0].1.max(turns[1].1).max(x0).max(x1);
        if peak > guess * (1.0 + 1e-12) {
            guess = peak;
            continue;
        }
        let dt = phases_time(x0, turns, ds, x1);
        return if dt < linear {
            (Shape { bent: true, turns }, dt)
        } else {
            plain
        };
    }
    plain
}

impl Point {
    /// The distance travelled from this point towards `next` after `tau` seconds of the
    /// interval (`dt` long), the speed then and its rate of change.
    pub(in super::super) fn travel(&self, next: &Point, dt: f64, tau: f64) -> (f64, f64, f64) {
        let ds = next.s - self.s;
        let (v0, v1) = (self.v, next.v);
        if !self.shape.bent {
            // Constant acceleration over the interval.
            let a = if dt > 0.0 { (v1 - v0) / dt } else { 0.0 };
            let travelled = v0 * tau + 0.5 * a * tau * tau;
            // max and min, not clamp: a number that is not one must not panic on the cyclic
            // side.
            return (travelled.max(0.0).min(ds), (v0 + a * tau).max(0.0), a);
        }
        // The phase the time falls in, constant acceleration within it.
        let [first, second] = self.shape.turns;
        let knots = [(0.0, v0 * v0), first, second, (ds, v1 * v1)];
        let mut left = tau;
        for w in knots.windows(2) {
            let (len, va, vb) = (w[1].0 - w[0].0, w[0].1.sqrt(), w[1].1.sqrt());
            if len <= 0.0 || va + vb <= 0.0 {
                continue;
            }
            let t = 2.0 * len / (va + vb);
            if left < t {
                let a = (vb - va) / t;
                let travelled = w[0].0 + va * left + 0.5 * a * left * left;
                return (travelled.max(0.0).min(ds), (va + a * left).max(0.0), a);
            }
            left -= t;
        }
        (ds.max(0.0), v1, 0.0)
    }
}
