//! World mode (READY, MOTION): the stick drives a pair of world axes of the tool through the
//! inverse kinematics. The tool's jog speed ramps with the configured acceleration, brakes in
//! time for the border of the allowed region (software limits of the joints, world limits, the
//! singularity threshold) and stops on it without an error; no joint set-point moves faster than
//! the joint's speed limit. The screen may also jog one joint alone, under the same rules: the
//! tool follows by the forward kinematics and must stay in the allowed region.

use pkm_kinematics::MAX_DOF;

use super::automaton::{Io, Main};

/// How close to the border of the allowed region a jog stops (mm or degrees along its path).
const BORDER_TOLERANCE: f64 = 1e-6;

/// How far (up to `reach`) a jog may go from where `allowed(0)` holds: `reach` if `allowed`
/// holds there, else the border found by bisection to [`BORDER_TOLERANCE`] (the allowed region
/// is taken as connected along the short path looked at).
fn reachable(reach: f64, mut allowed: impl FnMut(f64) -> bool) -> f64 {
    if allowed(reach) {
        return reach;
    }
    let (mut lo, mut hi) = (0.0, reach);
    while hi - lo > BORDER_TOLERANCE {
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
    /// The operator's command as a velocity of the tool (per pose coordinate, mm/s or
    /// degrees/s): the stick's x and y on the selected pair of axes.
    pub(super) fn world_command(&self, io: &Io) -> [f64; MAX_DOF] {
        let mut v = [0.0; MAX_DOF];
        if io.screen_joint != 0 {
            return v;
        }
        // The screen's button of one pose coordinate moves that coordinate alone.
        if (1..=self.n).contains(&io.screen_axis) {
            let k = io.screen_axis - 1;
            v[k] = self.stick(io)[0] * self.axis_speed[k];
            return v;
        }
        let Some(&[a, b]) = self.pairs.get(self.selection) else {
            return v;
        };
        let [x, y] = self.stick(io);
        v[a] = x * self.axis_speed[a];
        v[b] += y * self.axis_speed[b];
        v
    }

    /// Whether the tool may be commanded to `pose` (machine frame): inside the world limits,
    /// reachable with every joint inside its software limits, and not near a singularity. Writes
    /// the joints for it into `joints`.
    pub(super) fn allowed(&self, pose: &[f64; MAX_DOF], joints: &mut [f64; MAX_DOF]) -> bool {
        let n = self.n;
        let inside_world = pose[..n]
            .iter()
            .zip(&self.p.world_limits)
            .all(|(c, [lo, hi])| (*lo..=*hi).contains(c));
        inside_world
            && self.frame.inverse(&pose[..n], &mut joints[..n]).is_ok()
            && joints[..n]
                .iter()
                .zip(&self.soft)
                .all(|(q, [lo, hi])| (*lo..=*hi).contains(q))
            && self
                .frame
                .singularity_measure(&pose[..n])
                .is_ok_and(|s| s >= self.p.singularity_threshold)
    }

    /// The pose `t` along the direction `u` from the set-point.
    fn along(&self, u: &[f64; MAX_DOF], t: f64) -> [f64; MAX_DOF] {
        let mut p = self.pose;
        for (c, d) in p.iter_mut().zip(u) {
            *c += d * t;
        }
        p
    }

    /// How far along `u` (a unit direction) from the set-point the allowed region reaches,
    /// looked for up to `reach`.
    fn free_distance(&self, u: &[f64; MAX_DOF], reach: f64) -> f64 {
        let mut joints = [0.0; MAX_DOF];
        reachable(reach, |t| self.allowed(&self.along(u, t), &mut joints))
    }

    /// The tool's acceleration along the unit direction `u` (at most the jog's): a joint whose
    /// speed is `g` times the tool's along `u` accelerates `g` times as hard, so the tool takes at
    /// most the smallest of the joints' accelerations divided by their gear ratio — half of it:
    /// the set-points change velocity in 50 ms steps, and the drives' ramps (1.5× the joint's
    /// acceleration on the steppers) need the other half to follow them without running ahead of
    /// a set-point that brakes at a software limit.
    fn accel_along(&self, u: &[f64; MAX_DOF]) -> f64 {
        const H: f64 = 1e-3;
        let n = self.n;
        let (mut q0, mut q1) = ([0.0; MAX_DOF], [0.0; MAX_DOF]);
        let a = self.p.jog.accel_mm_s2;
        if self.frame.inverse(&self.pose[..n], &mut q0[..n]).is_err()
            || self.frame.inverse(&self.along(u, H)[..n], &mut q1[..n]).is_err()
        {
            return a;
        }
        (0..n)
            .map(|j| {
                let g = (q1[j] - q0[j]).abs() / H;
                if g > 0.0 {
                    0.5 * self.p.joints[j].max_accel_mm_s2 / g
                } else {
                    f64::INFINITY
                }
            })
            .fold(a, f64::min)
    }

    /// One jog step towards the commanded tool velocity.
    pub(super) fn jog(&mut self, io: &mut Io, command: [f64; MAX_DOF]) {
        let (n, dt) = (self.n, io.dt_s);
        let before = self.pose_velocity;
        let ramp = |a: f64| {
            let mut v = before;
            for (v, c) in v.iter_mut().zip(command) {
                *v += (c - *v).clamp(-a * dt, a * dt);
            }
            let speed = v[..n].iter().map(|v| v * v).sum::<f64>().sqrt();
            let mut u = [0.0; MAX_DOF];
            if speed > 0.0 {
                for (d, v) in u.iter_mut().zip(&v) {
                    *d = v / speed;
                }
            }
            (v, speed, u)
        };
        let (mut v, mut speed, mut u) = ramp(self.p.jog.accel_mm_s2);
        if speed == 0.0 {
            self.pose_velocity = v;
            io.hold();
            return;
        }
        // The tool's acceleration, such that no joint accelerates beyond its limit along this
        // direction: where the mechanism gears a joint up, the tool accelerates and brakes less.
        let a = self.accel_along(&u);
        if a < self.p.jog.accel_mm_s2 {
            (v, speed, u) = ramp(a);
            if speed == 0.0 {
                self.pose_velocity = v;
                io.hold();
                return;
            }
        }
        self.pose_velocity = v;
        // Brake in time: the step and the braking distance after it must stay allowed,
        // v·dt + v²/(2a) ≤ d.
        let reach = speed * dt + speed * speed / (2.0 * a);
        let free = self.free_distance(&u, reach);
        if free < reach {
            speed = speed.min(a * ((dt * dt + 2.0 * free / a).sqrt() - dt));
        }
        // No joint faster than its limit: scale the tool's speed (the mechanism is smooth over
        // one step, so the joints' speeds scale with it).
        let mut joints = [0.0; MAX_DOF];
        for _ in 0..8 {
            let step = self.free_distance(&u, speed * dt).min(speed * dt);
            let next = self.along(&u, step);
            if !self.allowed(&next, &mut joints) {
                break;
            }
            let scale = (0..n)
                .map(|j| {
                    let qdot = (joints[j] - io.setpoints[j]) / dt;
                    if qdot == 0.0 {
                        1.0
                    } else {
                        self.p.joints[j].max_speed_mm_s / qdot.abs()
                    }
                })
                .fold(1.0f64, f64::min);
            if scale >= 1.0 - 1e-9 {
                break;
            }
            speed *= scale * (1.0 - 1e-6);
        }
        let step = self.free_distance(&u, speed * dt).min(speed * dt);
        let next = self.along(&u, step);
        if step > 0.0 && self.allowed(&next, &mut joints) {
            for ((v, q), sp) in io.velocities[..n].iter_mut().zip(&joints).zip(&io.setpoints) {
                *v = (q - sp) / dt;
            }
            self.pose = next;
            for (v, d) in self.pose_velocity.iter_mut().zip(&u) {
                *v = d * step / dt;
            }
        } else {
            // On the border, pushing outwards: stand still there, no error.
            io.hold();
            self.pose_velocity = [0.0; MAX_DOF];
        }
    }
}

impl Main {
    /// The screen's jog of one joint alone, in world mode: the joint and its commanded
    /// set-point velocity (mm/s), if the screen holds one.
    pub(super) fn joint_command(&self, io: &Io) -> Option<(usize, f64)> {
        let j = io.screen_joint.checked_sub(1).filter(|j| *j < self.n)?;
        let x = self.stick(io)[0];
        (x != 0.0).then_some((j, x * self.p.jog.joint_speed_mm_s))
    }

    /// The tool pose at the joints `q` (machine frame), if it is one the tool may be commanded
    /// to: the forward kinematics from the set-point's pose, and back by the inverse to `q`
    /// itself (not to another assembly of the mechanism).
    fn pose_at(&self, q: &[f64; MAX_DOF]) -> Option<[f64; MAX_DOF]> {
        let n = self.n;
        let mut pose = [0.0; MAX_DOF];
        let mut back = [0.0; MAX_DOF];
        self.frame
            .forward(&q[..n], Some(&self.pose[..n]), &mut pose[..n])
            .ok()?;
        let same = |back: &[f64; MAX_DOF]| (0..n).all(|j| (back[j] - q[j]).abs() < 1e-6);
        (self.allowed(&pose, &mut back) && same(&back)).then_some(pose)
    }

    /// One step of the screen's jog of a joint alone (world mode): the joint's set-point ramps
    /// towards the command (0 once released, or when another is commanded) at half its
    /// acceleration (as a world jog's joints, for the drives' ramps), brakes in time for the
    /// border of the allowed region, and stops on it. The other joints hold; the tool's pose
    /// follows. False once it stands, the command released.
    pub(super) fn jog_joint(&mut self, io: &mut Io, command: Option<(usize, f64)>) -> bool {
        let (j, before) = self.joint_jog.unwrap_or((command.map_or(0, |(j, _)| j), 0.0));
        let target = match command {
            Some((k, v)) if k == j => v,
            _ => 0.0,
        };
        let (dt, a) = (io.dt_s, 0.5 * self.p.joints[j].max_accel_mm_s2);
        let v = target.clamp(before - a * dt, before + a * dt);
        io.hold();
        let mut speed = v.abs();
        if speed == 0.0 {
            self.joint_jog = None;
            return false;
        }
        let direction = v.signum();
        let from = io.setpoints;
        let at = |t: f64| {
            let mut q = from;
            q[j] += direction * t;
            q
        };
        // Brake in time: the step and the braking distance after it must stay allowed.
        let reach = speed * dt + speed * speed / (2.0 * a);
        let free = reachable(reach, |t| self.pose_at(&at(t)).is_some());
        if free < reach {
            speed = speed.min(a * ((dt * dt + 2.0 * free / a).sqrt() - dt));
        }
        let step = (speed * dt).min(free);
        match self.pose_at(&at(step)).filter(|_| step > 0.0) {
            Some(pose) => {
                io.velocities[j] = direction * step / dt;
                self.pose = pose;
                self.joint_jog = Some((j, direction * step / dt));
                true
            }
            None => {
                // On the border, pushing outwards: stand there, no error.
                self.joint_jog = None;
                target != 0.0
            }
        }
    }
}
