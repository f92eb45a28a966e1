//! The velocity profile: points along the path at most [`GRID_SPACING`] (and [`ARC_STEP`] of a
//! curve) apart ([`grid`]); at each, the derivatives of every world axis and joint along the path
//! (the poses, and the inverse kinematics of the poses, a hair before and after the point), and
//! from them what bounds the speed there and the change of speed at each speed ([`place`],
//! [`bounds`]). A backward pass finds the fastest speed at each point from which the tool can
//! still keep every limit and stand where it must; a forward pass then goes as fast as the
//! limits allow within it ([`passes`]: time-optimal path parameterisation by reachability, as
//! TOPP-RA does). Where the speed changes fast on a curve the grid is made finer and the passes
//! run again ([`refine`]). Between two points the speed changes with constant acceleration, or —
//! where the tool starts, stops or changes speed slowly — up to a speed at the full
//! acceleration, holds it and changes again ([`timing`]), so that a slow feed ramps at the
//! machine's acceleration and not at what one interval's length allows.
//!
//! The bound of every coordinate k (a world axis with limits, a joint) on the tangential
//! acceleration s̈ at the speed squared x = ṡ² comes from q̈ = q′ s̈ + q″ ṡ²: |q′ s̈ + q″ x| ≤ A,
//! that is −α − β x ≤ s̈ ≤ α − β x with α = A/|q′| and β = q″/q′. Between two points the
//! acceleration keeps the bounds of both ends at their speeds, and the speed the caps of both
//! ends and of what the derivatives say of the interval between them.
//!
//! [`GRID_SPACING`]: super::GRID_SPACING
//! [`ARC_STEP`]: super::ARC_STEP

mod bounds;
mod grid;
mod passes;
mod place;
mod refine;
mod timing;

pub(super) use bounds::{caps, interior_caps};
pub use grid::steps;
pub(super) use grid::{grid, stops_and_holds};
pub(super) use passes::profile;
pub(crate) use refine::allowance;
pub(super) use refine::{REFINEMENTS, refine};
pub(super) use timing::times;

use pkm_kinematics::MAX_DOF;

use super::limits::Limit;

/// The share of each acceleration the path's curvature may take at the highest speed: the rest
/// is kept for a change of speed, so that the tool is never at a speed from which no tangential
/// acceleration at all keeps the limits (the time-optimal motion would use all of it).
pub(super) const CURVE_SHARE: f64 = 0.99;
/// The plan keeps every speed and acceleration this much below its limit: between two points
/// the derivatives change a little from what they are at the points.
pub(super) const MARGIN: f64 = 0.002;
/// The most coordinates that bound the profile: the world axes and the joints.
const MAX_COORDINATES: usize = 6 + MAX_DOF;

/// The memory one point of a velocity profile takes while the program is planned (bytes): the
/// point, the derivatives of every coordinate there, and its own element's cap.
pub(crate) const POINT_BYTES: u64 =
    (size_of::<Point>() + MAX_COORDINATES * size_of::<[f32; 2]>() + size_of::<f64>()) as u64;

/// How the speed changes from a point to the next.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Shape {
    /// false: the speed squared changes in proportion to the distance over the whole interval
    /// (constant acceleration). true: in three phases, each so, between the interval's ends
    /// and `turns`.
    pub(super) bent: bool,
    /// Where the phases meet: the distance from the interval's start (mm) and the speed
    /// squared there (mm²/s²), in order.
    pub(super) turns: [(f64, f64); 2],
}

/// A point of the velocity profile.
#[derive(Clone, Copy, Debug)]
pub(super) struct Point {
    /// Distance along the path.
    pub(super) s: f64,
    pub(super) element: u32,
    pub(super) u: f64,
    /// Speed cap — the feed, every speed limit, the curvature's share of every acceleration —
    /// and what sets it.
    pub(super) cap: f64,
    pub(super) limit: Limit,
    /// The cap at the highest feed override (the feed times
    /// [`MAX_FEED_OVERRIDE`](pkm_api::trajectory::MAX_FEED_OVERRIDE), the machine's limits
    /// unchanged).
    pub(super) cap_fast: f64,
    /// The tool stands here (the start, an exact stop, the end).
    pub(super) stop: bool,
    /// The change of speed every coordinate allows in both directions at rest (mm/s²); at speed
    /// v it is at least `accel − bend · v²` up to `cap_fast`, and at least
    /// `(1 − CURVE_SHARE) · accel` (what the curvature leaves).
    pub(super) accel: f64,
    /// How that bound falls with the speed squared (1/mm).
    pub(super) bend: f64,
    /// Planned speed.
    pub(super) v: f64,
    /// The speed of the profile planned at the highest feed override.
    pub(super) v_fast: f64,
    /// When the tool passes (s).
    pub(super) t: f64,
    /// Standing still here this long before going on (s).
    pub(super) hold: f64,
    /// How the speed changes to the next point.
    pub(super) shape: Shape,
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
            stop: false,
            accel: f64::INFINITY,
            bend: 0.0,
            v: 0.0,
            v_fast: 0.0,
            t: 0.0,
            hold: 0.0,
            shape: Shape::default(),
        }
    }
}
