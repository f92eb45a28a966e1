//! World mode (READY, MOTION): the stick drives a pair of world axes of the tool through the
//! inverse kinematics. The tool's jog speed ramps with the configured acceleration, brakes in
//! time for the border of the allowed region (software limits of the joints, world limits, the
//! singularity threshold) and stops on it without an error; no joint set-point moves faster than
//! the joint's speed limit.

use pkm_kinematics::MAX_DOF;

use super::automaton::{Io, Main};

/// How close to the border of the allowed region a jog stops (mm or degrees along its path).
const BORDER_TOLERANCE: f64 = 1e-6;

impl Main {
    /// The operator's command as a velocity of the tool (per pose coordinate, mm/s or
    /// degrees/s): the stick's x and y on the selected pair of axes.
    pub(super) fn world_command(&self, io: &Io) -> [f64; MAX_DOF] {
        let mut v = [0.0; MAX_DOF];
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
        if self.allowed(&self.along(u, reach), &mut joints) {
            return reach;
        }
        let (mut lo, mut hi) = (0.0, reach);
        while hi - lo > BORDER_TOLERANCE {
            let mid = (lo + hi) / 2.0;
            if self.allowed(&self.along(u, mid), &mut joints) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }

    /// One jog step towards the commanded tool velocity.
    pub(super) fn jog(&mut self, io: &mut Io, command: [f64; MAX_DOF]) {
        let (n, dt, a) = (self.n, io.dt_s, self.p.jog.accel_mm_s2);
        for (v, c) in self.pose_velocity.iter_mut().zip(command) {
            *v += (c - *v).clamp(-a * dt, a * dt);
        }
        let mut speed = self.pose_velocity[..n].iter().map(|v| v * v).sum::<f64>().sqrt();
        if speed == 0.0 {
            io.hold();
            return;
        }
        let mut u = [0.0; MAX_DOF];
        for (d, v) in u.iter_mut().zip(&self.pose_velocity) {
            *d = v / speed;
        }
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
