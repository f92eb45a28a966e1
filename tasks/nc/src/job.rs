//! A planned program as the cyclic programs sample it ([`pkm_api::trajectory::Trajectory`]): the
//! plan's poses with the joints for them (inverse kinematics), the forward kinematics of
//! measured joints, and the distance of a measured tool point to the programmed path.

use pkm_api::trajectory::{MAX_AXES, Trajectory, TrajectoryEvent, TrajectorySample};
use pkm_kinematics::frame::MachineFrame;

use crate::plan::{Checked, Plan};

/// How far either side of the executor's time the path is searched for the point closest to
/// the measured tool (s): more than any drive lags.
const SEARCH_WINDOW_S: f64 = 0.25;
/// Samples across the window before the closest is refined.
const SEARCH_STEPS: usize = 100;
/// Refinement steps (each shrinks the bracket to 2/3).
const REFINE_STEPS: usize = 40;

/// A plan on its machine: only a [`Checked`] plan becomes one.
pub struct PlannedProgram {
    plan: Checked,
    frame: MachineFrame,
}

impl PlannedProgram {
    /// `plan` on the machine `frame` it was planned and checked for.
    pub fn new(plan: Checked, frame: MachineFrame) -> PlannedProgram {
        PlannedProgram { plan, frame }
    }

    /// The plan.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// The tool point's coordinates (x y z, or x y on a planar machine).
    fn point_axes(&self) -> usize {
        self.frame.dof().min(3)
    }

    /// The squared distance from the tool point of `pose` to the path at `t`.
    fn squared(&self, pose: &[f64; MAX_AXES], t: f64, cursor: &mut usize) -> f64 {
        let on = self.plan.sample(t, cursor).pose;
        (0..self.point_axes()).map(|c| (on[c] - pose[c]).powi(2)).sum()
    }
}

impl Trajectory for PlannedProgram {
    fn dof(&self) -> usize {
        self.frame.dof()
    }

    fn duration_s(&self) -> f64 {
        self.plan.duration_s
    }

    fn length_mm(&self) -> f64 {
        self.plan.length_mm
    }

    fn sample(&self, t: f64, cursor: &mut usize) -> TrajectorySample {
        // max and min, not clamp, which panics on a bound that is not a number.
        let s = self.plan.sample(t.max(0.0).min(self.plan.duration_s), cursor);
        let n = self.frame.dof();
        let mut joints = [0.0; MAX_AXES];
        // Every point of a plan was reachable when it was planned (its joints were computed
        // then); between the planner's points the path is smooth and stays so.
        if self.frame.inverse(&s.pose[..n], &mut joints[..n]).is_err() {
            joints = [f64::NAN; MAX_AXES];
        }
        TrajectorySample {
            pose: s.pose,
            joints,
            line: u32::try_from(s.line).unwrap_or(u32::MAX),
            s: s.s,
            speed: s.speed,
            speed_max: s.speed_max,
            accel: s.accel,
            planned_accel: s.planned_accel,
            rapid: s.rapid,
            feed: s.feed,
        }
    }

    fn events(&self) -> &[TrajectoryEvent] {
        &self.plan.events
    }

    fn messages(&self) -> &[pkm_api::trajectory::NcMessage] {
        &self.plan.messages
    }

    fn block_end(&self, s: f64) -> Option<(f64, f64)> {
        self.plan.block_end(s)
    }

    fn forward(&self, joints: &[f64], hint: &[f64; MAX_AXES], pose: &mut [f64; MAX_AXES]) -> bool {
        let n = self.frame.dof();
        joints.len() >= n
            && self
                .frame
                .forward(&joints[..n], Some(&hint[..n]), &mut pose[..n])
                .is_ok()
    }

    fn path_distance(&self, pose: &[f64; MAX_AXES], t: f64) -> f64 {
        // The closest of evenly spaced samples across the window, then a ternary search in the
        // bracket around it (the distance is unimodal that close to the path). Every sample
        // walks a cursor forward from one found by bisection: no scan of the plan.
        let duration = self.plan.duration_s;
        let (lo, hi) = ((t - SEARCH_WINDOW_S).max(0.0), (t + SEARCH_WINDOW_S).min(duration));
        let mut cursor = self.plan.cursor_at(lo);
        let step = (hi - lo) / SEARCH_STEPS as f64;
        let (mut best_t, mut best) = (lo, f64::INFINITY);
        for i in 0..=SEARCH_STEPS {
            let at = lo + step * i as f64;
            let d = self.squared(pose, at, &mut cursor);
            if d < best {
                (best_t, best) = (at, d);
            }
        }
        let (mut a, mut b) = ((best_t - step).max(lo), (best_t + step).min(hi));
        let mut at_a = self.plan.cursor_at(a);
        for _ in 0..REFINE_STEPS {
            let (m1, m2) = (a + (b - a) / 3.0, b - (b - a) / 3.0);
            let mut c1 = at_a;
            let d1 = self.squared(pose, m1, &mut c1);
            let mut c2 = c1;
            if d1 <= self.squared(pose, m2, &mut c2) {
                b = m2;
            } else {
                a = m1;
                at_a = c1;
            }
        }
        best.min(self.squared(pose, (a + b) / 2.0, &mut at_a)).sqrt()
    }
}
