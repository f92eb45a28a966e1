//! The passes that make a profile: backwards, the largest speed at each point from which the
//! tool can still keep every limit and stand where it must; forwards, as fast as the limits
//! allow within that. Each interval between two points keeps the bounds of both its ends, as a
//! two-variable linear problem in the speeds squared at its ends.

use super::MAX_COORDINATES;
use super::Point;
use super::bounds::Bounds;
use super::place::{Coordinates, Derivs};

/// The most bounds an interval has on either side: one a coordinate at each end, and rest or
/// the next point's top speed.
const MAX_BOUNDS: usize = 2 * MAX_COORDINATES + 1;

/// What an interval of length `ds` allows, as bounds on the speed squared at its end, x₁,
/// linear in the speed squared at its start, x₀ (the tangential acceleration over it is
/// u = (x₁ − x₀) / 2 ds): x₁ ≥ a + b x₀ (`lower`), x₁ ≤ c + d x₀ (`upper`), and x₀ ≤
/// `start_max` where an end's bound leaves x₁ free.
struct Span {
    lower: [(f64, f64); MAX_BOUNDS],
    lowers: usize,
    upper: [(f64, f64); MAX_BOUNDS],
    uppers: usize,
    start_max: f64,
}

impl Span {
    /// The bounds of the coordinates at the interval's start (`start`) and end (`end`), and
    /// x₁ ≤ `end_top`.
    fn new(coordinates: &Coordinates, start: &[Derivs], end: &[Derivs], ds: f64, end_top: f64) -> Span {
        let mut span = Span {
            lower: [(0.0, 0.0); MAX_BOUNDS],
            lowers: 1,
            upper: [(end_top, 0.0); MAX_BOUNDS],
            uppers: 1,
            start_max: f64::INFINITY,
        };
        let h = 2.0 * ds;
        // At the start: −α − β x₀ ≤ u ≤ α − β x₀.
        for (a, b) in coordinates.bounds(start) {
            span.push(false, -h * a, 1.0 - h * b);
            span.push(true, h * a, 1.0 - h * b);
        }
        // At the end: −α − β x₁ ≤ u ≤ α − β x₁, that is x₁ (1 + 2 ds β) ≥ x₀ − 2 ds α and
        // ≤ x₀ + 2 ds α; divided by k = 1 + 2 ds β, a negative k swaps the sides.
        for (a, b) in coordinates.bounds(end) {
            let k = 1.0 + h * b;
            if k.abs() < 1e-12 {
                // x₀ − 2 ds α ≤ 0 ≤ x₀ + 2 ds α, whatever x₁.
                span.start_max = span.start_max.min(h * a);
            } else {
                span.push(k < 0.0, -h * a / k, 1.0 / k);
                span.push(k > 0.0, h * a / k, 1.0 / k);
            }
        }
        span
    }

    fn push(&mut self, upper: bool, a: f64, b: f64) {
        if upper {
            self.upper[self.uppers] = (a, b);
            self.uppers += 1;
        } else {
            self.lower[self.lowers] = (a, b);
            self.lowers += 1;
        }
    }

    /// The largest x₀ for which some x₁ keeps every bound: for every lower bound i and upper
    /// bound j, a_i + b_i x₀ ≤ c_j + d_j x₀.
    fn start_limit(&self) -> f64 {
        let mut x = self.start_max;
        for &(a, b) in &self.lower[..self.lowers] {
            for &(c, d) in &self.upper[..self.uppers] {
                if b - d > 0.0 {
                    x = x.min((c - a) / (b - d));
                }
            }
        }
        x
    }

    /// The largest x₁ reachable from `x0`.
    fn end_limit(&self, x0: f64) -> f64 {
        self.upper[..self.uppers]
            .iter()
            .map(|(c, d)| c + d * x0)
            .fold(f64::INFINITY, f64::min)
    }
}

/// The profile through `points` with each point's cap as `cap` gives it, written to the field
/// `speed`: backwards, the largest speed at each point from which the tool can still keep every
/// limit and stand where it must; forwards, as fast as the limits allow within that.
pub(in super::super) fn profile(
    points: &mut [Point],
    bounds: &Bounds,
    cap: fn(&Point) -> f64,
    speed: fn(&mut Point) -> &mut f64,
) {
    let count = points.len();
    if count == 0 {
        return;
    }
    let coordinates = &bounds.coordinates;
    // Backwards: the controllable speed squared, written to `speed` for now.
    let mut next = 0.0;
    for i in (0..count).rev() {
        let p = &points[i];
        let mut x = if p.stop { 0.0 } else { cap(p) * cap(p) };
        if i + 1 < count && x > 0.0 {
            let ds = points[i + 1].s - p.s;
            let (start, end) = bounds.interval(points, i);
            x = x.min(Span::new(coordinates, start, end, ds, next).start_limit());
        }
        let x = x.max(0.0);
        *speed(&mut points[i]) = x;
        next = x;
    }
    // Forwards from rest.
    let mut x = 0.0f64;
    for i in 0..count {
        let top = *speed(&mut points[i]);
        x = x.min(top).max(0.0);
        *speed(&mut points[i]) = x.sqrt();
        if i + 1 < count {
            let ds = points[i + 1].s - points[i].s;
            let (start, end) = bounds.interval(points, i);
            let top = *speed(&mut points[i + 1]);
            x = Span::new(coordinates, start, end, ds, top).end_limit(x);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::PlanLimits;
    use proptest::prelude::*;

    /// Whether some speed squared at the end of the interval, within `top`, keeps every
    /// coordinate's acceleration within its limit at both ends when the start's is `x0`,
    /// straight from q̈ = q′ u + q″ x with u = (x₁ − x₀) / 2 ds: each bound is a range of x₁.
    fn feasible(c: &Coordinates, start: &[Derivs], end: &[Derivs], ds: f64, x0: f64, top: f64) -> bool {
        let (mut lo, mut hi) = (0.0f64, top);
        for (at_end, row) in [(false, start), (true, end)] {
            for (d, &(_, _, a)) in row.iter().zip(c.iter()) {
                let (d1, d2) = (f64::from(d[0]), f64::from(d[1]));
                // q̈ = k x₁ + m, within ±a.
                let (k, m) = if at_end {
                    (d1 / (2.0 * ds) + d2, -d1 * x0 / (2.0 * ds))
                } else {
                    (d1 / (2.0 * ds), -d1 * x0 / (2.0 * ds) + d2 * x0)
                };
                let a = a * (1.0 + 1e-9) + 1e-9;
                if k.abs() < 1e-300 {
                    if m.abs() > a {
                        return false;
                    }
                    continue;
                }
                let (p, q) = ((-a - m) / k, (a - m) / k);
                lo = lo.max(p.min(q));
                hi = hi.min(p.max(q));
            }
        }
        lo <= hi
    }

    proptest! {
        /// The largest start the backward pass finds is the largest from which some end within
        /// the top keeps every bound, found by trying ends one by one. (A coordinate that does
        /// not move along the path caps the speed by itself, outside the passes.)
        #[test]
        fn the_start_limit_is_the_largest_start_some_end_allows(
            rows in prop::collection::vec(((0.01f64..2.0), any::<bool>(), -50.0f64..50.0).prop_map(|(a, s, b)| (if s { a } else { -a }, b)), 6),
            ds in 0.001f64..0.5,
            top in 0.0f64..400.0,
        ) {
            let limits = PlanLimits {
                joint_speed: vec![20.0; 3],
                joint_accel: vec![100.0; 3],
                axis_speed: [f64::INFINITY; 6],
                axis_accel: [f64::INFINITY; 6],
            };
            let c = Coordinates::of(&limits, 3);
            let to = |r: &[(f64, f64)]| -> Vec<Derivs> { r.iter().map(|(a, b)| [*a as f32, *b as f32]).collect() };
            let (start, end) = (to(&rows[..3]), to(&rows[3..]));
            let limit = Span::new(&c, &start, &end, ds, top).start_limit();
            let feasible = |x0: f64| feasible(&c, &start, &end, ds, x0, top);
            if limit.is_finite() && limit > 1e-6 && limit < 1e6 {
                prop_assert!(feasible(limit * (1.0 - 1e-9)), "the limit {limit} is allowed");
                prop_assert!(!feasible(limit * 1.01 + 1e-6), "past the limit {limit} is not");
            }
        }
    }
}
