//! The check of a plan at the boundary to the cyclic side: a plan reaches the cyclic programs only
//! as a [`Checked`] plan, and only [`verify`] makes one. It is sampled as the drives will be fed —
//! once per cycle of the fast task class — every sampled pose taken through the inverse
//! kinematics, and every joint's and limited world axis' speed and acceleration (first and
//! second differences of the samples) held against the machine's limits. Every number of the
//! plan must be finite, its distances and times must only grow. A plan that fails is refused with
//! the program line and column where it fails: the planner has a fault there, and nothing moves.

use std::ops::Deref;

use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;

use super::{Plan, PlanError, PlanLimits};
use crate::interp::block::AXES;
use crate::watch::{Watch, Watched};

/// How far past a limit a sampled speed or acceleration may be (a share of the limit): the
/// planner keeps below every limit at its points, and between them its derivatives change a
/// little.
pub const TOLERANCE: f64 = 0.005;

/// A plan that [`verify`] found finite and within the machine's limits.
#[derive(Clone, Debug)]
pub struct Checked {
    plan: Plan,
}

impl Deref for Checked {
    type Target = Plan;

    fn deref(&self) -> &Plan {
        &self.plan
    }
}

impl Checked {
    /// The plan.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }
}

/// Checks `plan` (made on `frame` within `limits`), sampled every `cycle_s` seconds as the fast
/// task class will sample it, asking `watch` every [`crate::watch::WATCH_EVERY`] samples whether
/// to go on.
pub fn verify(
    plan: Plan,
    frame: &MachineFrame,
    limits: &PlanLimits,
    cycle_s: f64,
    watch: &dyn Watch,
) -> Result<Checked, PlanError> {
    let at = |element: usize, message: String| {
        let e = plan.elements.get(element).or(plan.elements.last());
        PlanError {
            line: e.map_or(0, |e| e.line),
            column: e.map_or(1, |e| e.column),
            message: format!("{message}: a fault of the planner; the program is refused and nothing moves"),
        }
    };
    // Its numbers: finite, distances and times growing.
    if !(plan.duration_s.is_finite() && plan.duration_s >= 0.0) {
        return Err(at(0, format!("the planned duration is {} s", plan.duration_s)));
    }
    let mut before: Option<&super::Point> = None;
    for p in &plan.points {
        let finite = [p.s, p.u, p.cap, p.v, p.v_fast, p.t, p.hold, p.bend]
            .iter()
            .all(|x| x.is_finite())
            && !p.accel.is_nan()
            && p.v >= 0.0
            && p.hold >= 0.0;
        if !finite {
            return Err(at(
                p.element as usize,
                format!("the plan is not a number at {:.4} mm of the path", p.s),
            ));
        }
        if let Some(b) = before
            && (p.s < b.s || p.t < b.t + b.hold)
        {
            return Err(at(
                p.element as usize,
                format!("the plan goes back at {:.4} mm of the path", p.s),
            ));
        }
        before = Some(p);
    }
    if !(cycle_s.is_finite() && cycle_s > 0.0) {
        return Err(at(0, format!("the plan is checked at a cycle of {cycle_s} s")));
    }
    // Sampled as the drives are fed: speeds and accelerations from the differences.
    let n = frame.dof();
    let mut coordinates: Vec<(usize, f64, f64, String)> = Vec::with_capacity(6 + n);
    for (c, axis) in AXES.iter().enumerate().take(n.min(6)) {
        if limits.axis_speed[c].is_finite() || limits.axis_accel[c].is_finite() {
            coordinates.push((c, limits.axis_speed[c], limits.axis_accel[c], format!("axis {axis}")));
        }
    }
    for j in 0..n {
        coordinates.push((
            6 + j,
            limits.joint_speed[j],
            limits.joint_accel[j],
            format!("joint {}", j + 1),
        ));
    }
    let mut watched = Watched::new(watch);
    // Past the end by a cycle: the tool stands there, as the executor stands it.
    let steps = (plan.duration_s / cycle_s).ceil() as usize + 1;
    let mut cursor = 0;
    let mut history: [[f64; 6 + MAX_DOF]; 2] = [[0.0; 6 + MAX_DOF]; 2];
    for k in 0..=steps {
        let t = k as f64 * cycle_s;
        let sample = plan.sample(t, &mut cursor);
        let element = plan.points.get(cursor).map_or(0, |p| p.element as usize);
        watched.step().map_err(|why| at(element, why))?;
        let mut y = [0.0; 6 + MAX_DOF];
        y[..6].copy_from_slice(&sample.pose);
        if !sample.pose.iter().all(|x| x.is_finite()) {
            return Err(at(element, format!("the plan's pose at {t:.3} s is not a number")));
        }
        frame
            .inverse(&sample.pose[..n], &mut y[6..6 + n])
            .map_err(|e| at(element, format!("the plan's pose at {t:.3} s has no joints: {e}")))?;
        for (c, speed, accel, name) in &coordinates {
            let unit = if *c >= 3 && *c < 6 { "°" } else { " mm" };
            if k >= 1 {
                let v = (y[*c] - history[1][*c]) / cycle_s;
                if v.abs() > speed * (1.0 + TOLERANCE) + 1e-9 {
                    return Err(at(
                        element,
                        format!(
                            "the plan asks {name} for {:.3}{unit}/s at {t:.3} s, past its limit of {speed}{unit}/s",
                            v.abs()
                        ),
                    ));
                }
            }
            if k >= 2 {
                let a = (y[*c] - 2.0 * history[1][*c] + history[0][*c]) / (cycle_s * cycle_s);
                if a.abs() > accel * (1.0 + TOLERANCE) + 1e-6 {
                    return Err(at(
                        element,
                        format!(
                            "the plan asks {name} for {:.2}{unit}/s² at {:.3} s, past its limit of {accel}{unit}/s²",
                            a.abs(),
                            t - cycle_s
                        ),
                    ));
                }
            }
        }
        history[0] = history[1];
        history[1] = y;
    }
    Ok(Checked { plan })
}
