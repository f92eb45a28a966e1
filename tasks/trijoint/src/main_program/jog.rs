//! Jogging (MOTION): the operator's command moves M's set-point, slowed by the joint speed limit
//! and the braking curves, stopped at the border of the allowed region. The screen may also jog
//! one carriage alone, under the same rules: M follows by the forward kinematics.

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
        let t = farthest(v[0].hypot(v[1]) * io.dt_s, |t| self.allowed(at(t), &mut joints));
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

/// How far along a step of `length` (mm) from an allowed point the allowed region reaches, as a
/// fraction of the step: 1 if `allowed(1)`, else the border bisected to [`BORDER_TOLERANCE_MM`]
/// along the step. An operator holding the joystick against the border is the common case: the
/// set-point is on it already, and one more check says so.
fn farthest(length: f64, mut allowed: impl FnMut(f64) -> bool) -> f64 {
    if allowed(1.0) {
        return 1.0;
    }
    let tolerance = if length > 0.0 {
        BORDER_TOLERANCE_MM / length
    } else {
        1.0
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    if !allowed(tolerance) {
        hi = 0.0;
    }
    while hi - lo > tolerance {
        let mid = (lo + hi) / 2.0;
        if allowed(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

impl Main {
    /// The screen's jog of one carriage alone: the carriage (0: left, 1: right) and its
    /// commanded velocity (mm/s: full deflection is M's jog speed), if the screen holds one.
    pub(super) fn carriage_command(&self, io: &Io) -> Option<(usize, f64)> {
        let i = io.screen_carriage.checked_sub(1).filter(|i| *i < 2)?;
        let x = io.joystick[0];
        (x.abs() > self.p.dead_zone).then(|| (i, x * self.p.max_speed_mm_s.min(self.p.max_joint_speed_mm_s)))
    }

    /// M at the carriage positions `q`, if M may be commanded there: the forward kinematics from
    /// M's set-point, and back by the inverse to `q` itself (not to the mechanism's other
    /// assembly).
    fn m_at(&self, q: [f64; 2]) -> Option<[f64; 2]> {
        let k = self.limits.as_ref()?;
        let mut m = [0.0; 2];
        k.forward(&q, Some(&self.m_setpoint), &mut m).ok()?;
        let mut back = [0.0; 2];
        (self.allowed(m, &mut back) && (0..2).all(|i| (back[i] - q[i]).abs() < 1e-6)).then_some(m)
    }

    /// One step of the screen's jog of carriage `i` at `v` (mm/s): slowed by its braking curve
    /// towards its software limit, stopped at the border of the allowed region; the other
    /// carriage holds, M follows.
    pub(super) fn jog_carriage(&mut self, io: &mut Io, i: usize, v: f64) {
        io.hold();
        io.velocities[i] = v;
        io.velocities[i] *= self.joint_speed_scale(io);
        let (from, step) = (io.setpoints, io.velocities[i] * io.dt_s);
        let at = |t: f64| {
            let mut q = from;
            q[i] += step * t;
            q
        };
        let t = farthest(step.abs(), |t| self.m_at(at(t)).is_some());
        match self.m_at(at(t)) {
            Some(m) => {
                io.velocities[i] = step * t / io.dt_s;
                self.m_setpoint = m;
            }
            None => io.hold(),
        }
    }
}
