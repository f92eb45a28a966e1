//! Jogging (MOTION): the operator's command moves M's set-point, slowed by the joint speed limit
//! and the braking curves, stopped at the border of the allowed region.

use pkm_kinematics::Kinematics;

use super::params::BORDER_TOLERANCE_MM;
use super::*;

impl Main {
    /// Whether M may be commanded to `m`: reachable inside the software limits and not near a
    /// singularity. Writes the carriage positions for it into `joints`.
    pub(super) fn allowed(&self, m: [f64; 2], joints: &mut [f64; 2]) -> bool {
        let Some(k) = &self.limits else { return false };
        k.inverse(&m, joints).is_ok()
            && k.singularity_measure(&m)
                .is_ok_and(|s| s >= self.p.singularity_threshold)
    }

    /// Moves M's set-point by `v`·dt, slowed so that no carriage set-point exceeds the joint
    /// speed limit or its braking curve towards its software limit, and stopping at the border
    /// of the allowed region.
    pub(super) fn jog(&mut self, io: &mut Io, v: [f64; 2]) {
        let mut v = v;
        let mut next = self.step_m(io, v);
        // The mechanism is smooth over one step, so scaling M's velocity scales the carriages'
        // — unless the step was cut short at the border of the allowed region, where the scaled
        // step may then go further: scale again until no carriage is too fast.
        for _ in 0..8 {
            let scale = self.joint_speed_scale(io);
            if scale >= 1.0 - 1e-6 {
                break;
            }
            v = v.map(|c| c * scale);
            next = self.step_m(io, v);
        }
        self.m_setpoint = next;
    }

    /// The largest factor (at most 1) by which the carriage velocities of the planned step may
    /// be taken: none faster than `max_joint_speed_mm_s`, and none faster than it can still stop
    /// at its software limit with `brake_decel_mm_s2` — for a step of `dt` at speed `v` with `d`
    /// left, v·dt + v²/(2a) ≤ d, so v ≤ a·(√(dt² + 2d/a) − dt): a carriage close to its limit
    /// creeps onto it rather than arriving at speed.
    pub(super) fn joint_speed_scale(&self, io: &Io) -> f64 {
        let (a, dt) = (self.p.brake_decel_mm_s2, io.dt_s);
        let mut scale: f64 = 1.0;
        for i in 0..2 {
            let v = io.velocities[i];
            if v == 0.0 {
                continue;
            }
            let [lower, upper] = self.soft[i];
            let d = if v > 0.0 {
                upper - io.setpoints[i]
            } else {
                io.setpoints[i] - lower
            }
            .max(0.0);
            let braking = a * ((dt * dt + 2.0 * d / a).sqrt() - dt);
            scale = scale.min(self.p.max_joint_speed_mm_s.min(braking) / v.abs());
        }
        scale.max(0.0)
    }

    /// Plans M's step by `v`·dt, stopping at the border of the allowed region: the carriage
    /// velocities into `io`; returns M's set-point at the end of the step.
    pub(super) fn step_m(&self, io: &mut Io, v: [f64; 2]) -> [f64; 2] {
        let from = self.m_setpoint;
        let at = |t: f64| [from[0] + v[0] * io.dt_s * t, from[1] + v[1] * io.dt_s * t];
        let mut joints = [0.0; 2];
        let mut t = 1.0;
        if !self.allowed(at(1.0), &mut joints) {
            // The border lies on this step: bisect for the farthest allowed point, to
            // BORDER_TOLERANCE_MM along the step. An operator holding the joystick against the
            // border is the common case: M is on it already, and one check says so.
            let length = v[0].hypot(v[1]) * io.dt_s;
            let tolerance = if length > 0.0 {
                BORDER_TOLERANCE_MM / length
            } else {
                1.0
            };
            let (mut lo, mut hi) = (0.0, 1.0);
            if !self.allowed(at(tolerance), &mut joints) {
                hi = 0.0;
            }
            while hi - lo > tolerance {
                let mid = (lo + hi) / 2.0;
                if self.allowed(at(mid), &mut joints) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            t = lo;
        }
        if self.allowed(at(t), &mut joints) {
            for ((v, q), sp) in io.velocities.iter_mut().zip(joints).zip(io.setpoints) {
                *v = (q - sp) / io.dt_s;
            }
            at(t)
        } else {
            io.hold();
            from
        }
    }
}
