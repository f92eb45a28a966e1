//! Where the velocity profile has its points: at least two an element, at most
//! [`GRID_SPACING`] apart and [`ARC_STEP`] of a curve; and which of them the tool stands at.

use super::super::elements::Element;
use super::super::{ARC_STEP, GRID_SPACING};
use super::Point;
use crate::path::Segment;

/// How many intervals the profile has along `segment`: at least two, at most [`GRID_SPACING`]
/// long, at most [`ARC_STEP`] of a curve.
pub fn steps(segment: &Segment) -> usize {
    let by_length = (segment.length() / GRID_SPACING).ceil();
    let by_angle = (segment.sweep() / ARC_STEP).ceil();
    // `as` saturates a huge count.
    (by_length.max(by_angle) as usize).max(2)
}

/// The points of the velocity profile along `elements`, and the path's length (mm).
pub(in super::super) fn grid(elements: &[Element]) -> (Vec<Point>, f64) {
    // The points, counted first: a program of a million moves has millions of them, and a
    // vector grown by doubling would hold up to twice their memory.
    let count = elements.iter().map(|e| steps(&e.segment)).sum::<usize>() + 1;
    let mut points: Vec<Point> = Vec::with_capacity(count);
    let mut s = 0.0;
    for (k, e) in elements.iter().enumerate() {
        let len = e.segment.length();
        let steps = steps(&e.segment);
        for i in 0..steps {
            let u = i as f64 / steps as f64;
            points.push(Point::new(s + len * u, k as u32, u, e.feed));
        }
        s += len;
    }
    if let Some((last, e)) = elements.iter().enumerate().next_back() {
        points.push(Point::new(s, last as u32, 1.0, e.feed));
    }
    (points, s)
}

/// The start, every stop and the end at rest; dwells held at the stop after their element, the
/// program's first dwell at its start.
pub(in super::super) fn stops_and_holds(points: &mut [Point], elements: &[Element], initial_dwell: f64) {
    let count = points.len();
    for i in 1..count {
        if points[i].u == 0.0 {
            let before = &elements[points[i - 1].element as usize];
            if before.stop_after {
                points[i].stop = true;
                points[i].hold = before.dwell_after_s;
            }
        }
    }
    if let Some(last) = points.last_mut() {
        last.stop = true;
        last.hold = elements.last().map_or(0.0, |e| e.dwell_after_s);
    }
    if let Some(first) = points.first_mut() {
        first.stop = true;
        first.hold += initial_dwell;
    }
}
