//! What one place of the path allows: the derivatives of every world axis with limits and of
//! every joint along the path there, from the kinematics a hair either side, and from them the
//! speed caps and the bounds of the tangential acceleration.

use pkm_kinematics::frame::MachineFrame;

use super::super::elements::Element;
use super::super::limits::{Limit, PlanError, PlanLimits};
use super::{CURVE_SHARE, MARGIN, MAX_COORDINATES};
use crate::interp::block::Pose;
use crate::path::Segment;

/// How far a point's derivatives are measured either side of it (mm, or degrees where only
/// rotations move), at most: shorter on tight curves.
const DERIVATIVE_STEP: f64 = 0.01;
/// Below this a coordinate does not move along the path (its units per mm of path).
const STILL: f64 = 1e-12;

/// A coordinate's first and second derivatives along the path at a place (q′, q″).
pub(super) type Derivs = [f32; 2];

/// The coordinates that bound the profile: per coordinate, its index in a pose followed by
/// the joints (0 … 5 the world axes, 6 … the joints), its speed and its acceleration limit,
/// each kept [`MARGIN`] below the machine's.
#[derive(Clone, Copy, Debug)]
pub(super) struct Coordinates {
    pub(super) list: [(usize, f64, f64); MAX_COORDINATES],
    pub(super) count: usize,
}

impl Coordinates {
    pub(super) fn of(limits: &PlanLimits, n: usize) -> Coordinates {
        let mut list = [(0, 0.0, 0.0); MAX_COORDINATES];
        let mut count = 0;
        let keep = 1.0 - MARGIN;
        for c in 0..n.min(6) {
            if limits.axis_speed[c].is_finite() || limits.axis_accel[c].is_finite() {
                list[count] = (c, limits.axis_speed[c] * keep, limits.axis_accel[c] * keep);
                count += 1;
            }
        }
        for j in 0..n {
            list[count] = (6 + j, limits.joint_speed[j] * keep, limits.joint_accel[j] * keep);
            count += 1;
        }
        Coordinates { list, count }
    }

    pub(super) fn iter(&self) -> impl Iterator<Item = &(usize, f64, f64)> {
        self.list[..self.count].iter()
    }

    /// The bounds a row of derivatives (one per coordinate) sets on the tangential
    /// acceleration: (α, β) per coordinate that moves along the path and has an acceleration
    /// limit.
    pub(super) fn bounds<'a>(&'a self, row: &'a [Derivs]) -> impl Iterator<Item = (f64, f64)> + 'a {
        row.iter()
            .zip(self.iter())
            .filter_map(|(d, &(_, _, accel))| alpha_beta(*d, accel))
    }

    /// Why a cap of coordinate `k` is what it is: its speed, or its acceleration on the curve.
    pub(super) fn why(&self, k: usize, speed: bool) -> Limit {
        let c = self.list[k].0;
        match (c, speed) {
            (0..6, true) => Limit::AxisSpeed(c),
            (0..6, false) => Limit::AxisCurvature(c),
            (_, true) => Limit::JointSpeed(c - 6),
            (_, false) => Limit::JointCurvature(c - 6),
        }
    }
}

/// The bounds −α − β x ≤ u ≤ α − β x a coordinate with derivatives `d` and acceleration limit
/// `accel` sets on the tangential acceleration u at the speed squared x: (α, β); `None` where it
/// does not move along the path (its curve then caps the speed alone).
pub(super) fn alpha_beta(d: Derivs, accel: f64) -> Option<(f64, f64)> {
    let (d1, d2) = (f64::from(d[0]), f64::from(d[1]));
    (d1.abs() > STILL && accel.is_finite()).then(|| (accel / d1.abs(), d2 / d1))
}

/// What one place of the path allows: the derivatives there, and the speed caps with their
/// reasons.
#[derive(Clone, Copy)]
pub(super) struct Place {
    pub(super) derivs: [Derivs; MAX_COORDINATES],
    /// The machine's cap (mm/s) and why.
    pub(super) cap: f64,
    pub(super) limit: Limit,
    /// The bound of the change of speed in both directions at rest (mm/s²).
    pub(super) accel: f64,
}

/// The derivatives along the path at fraction `u` of `segment` (length `len`): per coordinate
/// of the pose followed by the joints, the first and second, by central differences a hair
/// either side (one-sided where the mechanism has no pose on one side).
fn derivatives(
    segment: &Segment,
    len: f64,
    u: f64,
    frame: &MachineFrame,
) -> Result<[[f64; 2]; MAX_COORDINATES], String> {
    let n = frame.dof();
    // A hair: at most DERIVATIVE_STEP; on a curve a twentieth of a radian (the difference of a
    // curve's cosine over ±h is exact to h²/12) and a sixteenth of the curve (a blend's turn or
    // an arc that hardly turns is continued past its ends only a little). Not shorter for a
    // short line: it is continued past its ends as the same line, and the second difference's
    // rounding grows as 1/h² — over a sixteenth of a millionth of a millimetre of line left
    // between two blends it was noise.
    let h = DERIVATIVE_STEP.min(if segment.is_arc() {
        (0.05 * len / segment.sweep()).min(len / 16.0)
    } else {
        f64::INFINITY
    });
    let du = h / len;
    let at = |v: f64| -> Result<[f64; MAX_COORDINATES], String> {
        let pose: Pose = segment.at_extended(v);
        let mut y = [0.0; MAX_COORDINATES];
        y[..6].copy_from_slice(&pose);
        frame
            .inverse(&pose[..n], &mut y[6..6 + n])
            .map_err(|err| format!("the path leaves the workspace: {err}"))?;
        Ok(y)
    };
    let mid = at(u)?;
    let mut out = [[0.0; 2]; MAX_COORDINATES];
    // Central where both sides have poses; else three points on the side that has them.
    match (at(u - du), at(u + du)) {
        (Ok(a), Ok(b)) => {
            for (c, o) in out.iter_mut().enumerate().take(6 + n) {
                *o = [(b[c] - a[c]) / (2.0 * h), (b[c] - 2.0 * mid[c] + a[c]) / (h * h)];
            }
        }
        (Err(_), Ok(b)) => {
            let b2 = at(u + 2.0 * du)?;
            for (c, o) in out.iter_mut().enumerate().take(6 + n) {
                *o = [
                    (-3.0 * mid[c] + 4.0 * b[c] - b2[c]) / (2.0 * h),
                    (mid[c] - 2.0 * b[c] + b2[c]) / (h * h),
                ];
            }
        }
        (Ok(a), Err(_)) => {
            let a2 = at(u - 2.0 * du)?;
            for (c, o) in out.iter_mut().enumerate().take(6 + n) {
                *o = [
                    (3.0 * mid[c] - 4.0 * a[c] + a2[c]) / (2.0 * h),
                    (mid[c] - 2.0 * a[c] + a2[c]) / (h * h),
                ];
            }
        }
        (Err(e), Err(_)) => return Err(e),
    }
    Ok(out)
}

/// What the place at fraction `u` of `element` allows.
pub(super) fn place(
    element: &Element,
    u: f64,
    frame: &MachineFrame,
    coordinates: &Coordinates,
) -> Result<Place, PlanError> {
    let len = element.segment.length();
    let d = derivatives(&element.segment, len, u, frame).map_err(|message| PlanError {
        line: element.line,
        column: element.column,
        message,
    })?;
    let mut place = Place {
        derivs: [[0.0; 2]; MAX_COORDINATES],
        cap: f64::INFINITY,
        limit: Limit::Feed,
        accel: f64::INFINITY,
    };
    let consider = |place: &mut Place, cap: f64, limit: Limit| {
        if cap < place.cap {
            place.cap = cap;
            place.limit = limit;
        }
    };
    for (k, &(c, speed, accel)) in coordinates.iter().enumerate() {
        let [d1, d2] = d[c];
        place.derivs[k] = [d1 as f32, d2 as f32];
        if d1.abs() > STILL {
            consider(&mut place, speed / d1.abs(), coordinates.why(k, true));
            place.accel = place.accel.min(accel / d1.abs());
        } else if d2.abs() > STILL {
            // It does not move along the path here, but the path's curve accelerates it.
            consider(
                &mut place,
                (CURVE_SHARE * accel / d2.abs()).sqrt(),
                coordinates.why(k, false),
            );
        }
    }
    // The curve's cap: the speed at which some tangential acceleration still keeps every
    // coordinate within CURVE_SHARE of its acceleration — every lower bound below every upper
    // one, −α_j − β_j x ≤ α_k − β_k x: x ≤ (α_j + α_k) / (β_k − β_j). (One coordinate alone
    // can always be kept by braking or speeding up; two pull apart.)
    let m = coordinates.count;
    for k in 0..m {
        let Some((ak, bk)) = alpha_beta(place.derivs[k], coordinates.list[k].2) else {
            continue;
        };
        for j in 0..m {
            let Some((aj, bj)) = alpha_beta(place.derivs[j], coordinates.list[j].2) else {
                continue;
            };
            if bk > bj {
                let x = CURVE_SHARE * (aj + ak) / (bk - bj);
                consider(&mut place, x.sqrt(), coordinates.why(k, false));
            }
        }
    }
    Ok(place)
}
