//! The bounds of the profile: every point's derivatives (and every element's at its end), the
//! speed caps they set at the points and between them, and each point's bounds of braking for
//! the executor.

use pkm_kinematics::frame::MachineFrame;

use pkm_api::trajectory::MAX_FEED_OVERRIDE;

use super::super::elements::Element;
use super::super::limits::{Limit, PlanError, PlanLimits};
use super::Point;
use super::place::{Coordinates, Derivs, Place, place};
use crate::watch::Watched;

/// The derivatives of every coordinate at every point and at the end of every element, and the
/// caps that come with them.
pub(in super::super) struct Bounds {
    /// A row of `width` derivatives per point.
    pub(super) rows: Vec<Derivs>,
    /// A row per element, at its end.
    pub(super) ends: Vec<Derivs>,
    /// Per element, the speed cap at its end (its feed, and what the machine allows there).
    pub(super) end_caps: Vec<f64>,
    /// Per point, the speed cap its own element sets there (the point's cap may be lower where
    /// the element before ends there).
    pub(super) own_caps: Vec<f64>,
    pub(super) width: usize,
    /// The coordinates, with their limits.
    pub(super) coordinates: Coordinates,
}

impl Bounds {
    /// Empty bounds of `coordinates`, with room for `points` points and `elements` elements.
    pub(super) fn with_capacity(coordinates: Coordinates, points: usize, elements: usize) -> Bounds {
        let width = coordinates.count;
        Bounds {
            rows: Vec::with_capacity(points * width),
            ends: Vec::with_capacity(elements * width),
            end_caps: Vec::with_capacity(elements),
            own_caps: Vec::with_capacity(points),
            width,
            coordinates,
        }
    }

    /// The memory they hold (bytes).
    pub(in super::super) fn heap_bytes(&self) -> u64 {
        ((self.rows.capacity() + self.ends.capacity()) * size_of::<Derivs>()
            + (self.end_caps.capacity() + self.own_caps.capacity()) * size_of::<f64>()) as u64
    }

    /// Point `point`'s derivatives.
    pub(super) fn at(&self, point: usize) -> &[Derivs] {
        &self.rows[point * self.width..(point + 1) * self.width]
    }

    /// Element `element`'s derivatives at its end.
    fn end(&self, element: usize) -> &[Derivs] {
        &self.ends[element * self.width..(element + 1) * self.width]
    }

    /// The speed caps of the interval from point `i` to the next at its start and at its end:
    /// its element's at both.
    pub(super) fn interval_caps(&self, points: &[Point], i: usize) -> (f64, f64) {
        let (p, q) = (&points[i], &points[i + 1]);
        let end = if q.element == p.element {
            self.own_caps[i + 1]
        } else {
            self.end_caps[p.element as usize]
        };
        (self.own_caps[i], end)
    }

    /// The derivatives at the start and at the end of the interval from point `i` to the next
    /// (both of the start's element).
    pub(super) fn interval(&self, points: &[Point], i: usize) -> (&[Derivs], &[Derivs]) {
        let here = points[i].element;
        let end = if points[i + 1].element == here {
            self.at(i + 1)
        } else {
            self.end(here as usize)
        };
        (self.at(i), end)
    }
}

/// Each point's caps and acceleration bounds, from the derivatives along the path of the world
/// axes (the poses) and of the joints (IK of the poses); `watched` is asked at every point.
/// Returns the derivatives of every coordinate at every point and at the end of every element,
/// which the passes and the timing use.
pub(in super::super) fn caps(
    points: &mut [Point],
    elements: &[Element],
    frame: &MachineFrame,
    limits: &PlanLimits,
    watched: &mut Watched<'_>,
) -> Result<Bounds, PlanError> {
    let coordinates = Coordinates::of(limits, frame.dof());
    let m = coordinates.count;
    let mut bounds = Bounds::with_capacity(coordinates, points.len(), elements.len());
    let count = points.len();
    for i in 0..count {
        let k = points[i].element as usize;
        let e = &elements[k];
        watched.step().map_err(|why| PlanError {
            line: e.line,
            column: e.column,
            message: why,
        })?;
        let last = i + 1 == count;
        let here = place(e, points[i].u, frame, &coordinates)?;
        // Where elements meet, the end of the one before bounds the point too; the path's
        // last point is its last element's end.
        let junction = i > 0 && points[i - 1].element as usize != k;
        let end = if last {
            Some(here)
        } else if junction {
            Some(place(
                &elements[points[i - 1].element as usize],
                1.0,
                frame,
                &coordinates,
            )?)
        } else {
            None
        };
        if let Some(end) = &end {
            bounds.ends.extend_from_slice(&end.derivs[..m]);
            let ended = if last {
                e
            } else {
                &elements[points[i - 1].element as usize]
            };
            bounds.end_caps.push(end.cap.min(ended.feed));
        }
        bounds.rows.extend_from_slice(&here.derivs[..m]);
        bounds.own_caps.push(here.cap.min(e.feed));
        // Where the feed changes, the slower one holds at the junction.
        let feed_before = if junction {
            elements[points[i - 1].element as usize].feed
        } else {
            f64::INFINITY
        };
        settle(&mut points[i], &here, end.as_ref(), feed_before, &coordinates);
    }
    Ok(bounds)
}

/// Sets point `p`'s caps, their reason and its bounds of braking from what its place allows
/// (`here`), and where an element ends there, what that end allows (`end`) and that element's
/// feed (`feed_before`). The point's cap holds its own element's feed before.
pub(super) fn settle(p: &mut Point, here: &Place, end: Option<&Place>, feed_before: f64, coordinates: &Coordinates) {
    let m = coordinates.count;
    let (mut cap, mut limit, mut accel) = (here.cap, here.limit, here.accel);
    if let Some(end) = end {
        if end.cap < cap {
            (cap, limit) = (end.cap, end.limit);
        }
        accel = accel.min(end.accel);
    }
    let feed = p.cap.min(feed_before);
    p.limit = if cap < feed { limit } else { Limit::Feed };
    p.cap = feed.min(cap);
    p.cap_fast = (feed * MAX_FEED_OVERRIDE).min(cap);
    p.accel = accel;
    // The chord of the bound in both directions, min over k of α − |β| x, from rest to the
    // fastest speed either profile may take here (the bound is concave in x: the chord lies
    // below it).
    let x_fast = p.cap_fast * p.cap_fast;
    if x_fast.is_finite() && x_fast > 0.0 && accel.is_finite() {
        let symmetric = |derivs: &[Derivs]| {
            coordinates
                .bounds(&derivs[..m])
                .map(|(a, b)| a - b.abs() * x_fast)
                .fold(f64::INFINITY, f64::min)
        };
        let mut at_fast = symmetric(&here.derivs);
        if let Some(end) = end {
            at_fast = at_fast.min(symmetric(&end.derivs));
        }
        p.bend = ((accel - at_fast) / x_fast).max(0.0);
    }
}

/// Where between two points a coordinate's rate along the path is looked at (fractions of the
/// interval), besides where it is highest.
const INSIDE: [f64; 7] = [0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875];

/// How much lower than its ends' caps a coordinate's speed cap must be between two points
/// (squared, as a share) before it lowers them: the margin below every limit covers less.
const SAG: f64 = 0.001;

/// The shares of the interval's speed caps (squared; `c0` and `c1` at its ends) a coordinate
/// with the speed limit `speed` leaves between two points `ds` apart where its derivatives are
/// `d0` and `d1`: its rate q′ between them is the cubic through both ends with the slopes q″
/// there, and a speed squared that changes in proportion to the distance from one end's cap to
/// the other's must stay below its cap (speed / |q′|)² all along ((1, 1) where it does).
///
/// Of the ways to lower them — one end alone, the other alone, or both by the same share — the
/// one that keeps the lower end's cap highest: where a joint slows down along the path (its
/// cap rising, in a curve that the straight line cuts), the lower end keeps its cap, and the
/// tool is not slowed where it is slowest already.
fn sag(d0: Derivs, d1: Derivs, ds: f64, speed: f64, c0: f64, c1: f64) -> (f64, f64) {
    let (a, b) = (f64::from(d0[0]), f64::from(d1[0]));
    let (m0, m1) = (ds * f64::from(d0[1]), ds * f64::from(d1[1]));
    let c2 = 3.0 * (b - a) - 2.0 * m0 - m1;
    let c3 = 2.0 * (a - b) + m0 + m1;
    let h = |t: f64| a + t * (m0 + t * (c2 + t * c3));
    // Where h′(t) = m0 + 2 c2 t + 3 c3 t² is zero inside: the highest |q′|.
    let (qa, qb, qc) = (3.0 * c3, 2.0 * c2, m0);
    let roots: [Option<f64>; 2] = if qa.abs() < 1e-300 {
        [(qb != 0.0).then(|| -qc / qb), None]
    } else {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc < 0.0 {
            [None, None]
        } else {
            let r = disc.sqrt();
            [Some((-qb + r) / (2.0 * qa)), Some((-qb - r) / (2.0 * qa))]
        }
    };
    // The coordinate's cap (squared) at every place looked at.
    let mut caps = [(0.0, f64::INFINITY); INSIDE.len() + 2];
    let mut count = 0;
    for t in INSIDE
        .into_iter()
        .chain(roots.into_iter().flatten())
        .filter(|t| *t > 0.0 && *t < 1.0)
    {
        let rate = h(t).abs();
        if rate > 0.0 {
            caps[count] = (t, (speed / rate).powi(2));
            count += 1;
        }
    }
    let caps = &caps[..count];
    let least = caps
        .iter()
        .map(|&(t, f)| f / ((1.0 - t) * c0 + t * c1))
        .fold(1.0f64, f64::min);
    if least >= 1.0 - SAG {
        return (1.0, 1.0);
    }
    // Both by the same share; the end at t = 1 alone; the end at t = 0 alone.
    let mut best = (least, least);
    let end_alone = caps.iter().map(|&(t, f)| (f - (1.0 - t) * c0) / t).fold(c1, f64::min);
    let start_alone = caps.iter().map(|&(t, f)| (f - t * c1) / (1.0 - t)).fold(c0, f64::min);
    // The slower end's cap is what the tool's time depends on most: the way that keeps it
    // highest, and of two that keep it alike, the one that keeps more of the other.
    let worth = |(k0, k1): (f64, f64)| ((k0 * c0).min(k1 * c1), k0 * c0 + k1 * c1);
    for (k0, k1) in [(1.0, end_alone / c1), (start_alone / c0, 1.0)] {
        if k0 >= 0.0 && k1 >= 0.0 && worth((k0, k1)) > worth(best) {
            best = (k0, k1);
        }
    }
    best
}

/// The speed caps between the points: where a coordinate's speed cap sags between two points
/// below the straight line of its ends' (squared; its rate q′ along the path bulges, or curves),
/// the ends' caps are lowered ([`sag`]), so that the speed between them, which changes in
/// proportion to the distance in the speed squared, stays below it.
pub(in super::super) fn interior_caps(points: &mut [Point], bounds: &mut Bounds) {
    let m = bounds.width;
    for i in 0..points.len().saturating_sub(1) {
        let ds = points[i + 1].s - points[i].s;
        if ds <= 0.0 {
            continue;
        }
        // The interval's caps at its ends.
        let (c0, c1) = bounds.interval_caps(points, i);
        if !(c0.is_finite() && c1.is_finite()) {
            continue;
        }
        // Each end lowered as far as the coordinate that needs it most there wants (lowering
        // an end further keeps every other coordinate's line below its cap too).
        let (mut keep, mut why) = ([1.0f64; 2], [Limit::Feed; 2]);
        {
            let (start, end) = bounds.interval(points, i);
            for k in 0..m {
                let speed = bounds.coordinates.list[k].1;
                if !speed.is_finite() {
                    continue;
                }
                let kept = sag(start[k], end[k], ds, speed, c0 * c0, c1 * c1);
                for (end, kept) in [kept.0, kept.1].into_iter().enumerate() {
                    if kept < keep[end] {
                        (keep[end], why[end]) = (kept, bounds.coordinates.why(k, true));
                    }
                }
            }
        }
        if keep == [1.0, 1.0] {
            continue;
        }
        let (cap0, cap1) = (c0 * keep[0].sqrt(), c1 * keep[1].sqrt());
        bounds.own_caps[i] = bounds.own_caps[i].min(cap0);
        if points[i + 1].element == points[i].element {
            bounds.own_caps[i + 1] = bounds.own_caps[i + 1].min(cap1);
        } else {
            let e = points[i].element as usize;
            bounds.end_caps[e] = bounds.end_caps[e].min(cap1);
        }
        for (p, cap, why) in [(i, cap0, why[0]), (i + 1, cap1, why[1])] {
            let p = &mut points[p];
            if cap < p.cap {
                p.cap = cap;
                p.limit = why;
            }
            p.cap_fast = p.cap_fast.min(cap);
        }
    }
}
