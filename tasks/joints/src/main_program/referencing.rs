//! INIT: joint mode while a limit input is active, then referencing (docs/machines.md) group by group
//! of the configured order — joints sharing a reference input one at a time, the others
//! together. Each joint finds its reference switch twice (a search, then a slow approach whose
//! captured edge is the reference) and goes to its reference position; the next group starts
//! when the whole group is there.
//!
//! No search runs without its switch ahead: no search, leave or back-off travels
//! farther than the switch can be from where it began (the travel on that side of the switch);
//! a leave that does not clear the input within it (a shared input another joint holds, a
//! switch stuck on) takes the joint back to where it started before the error, so that repeated
//! attempts do not walk it; and where the references are known the inputs must agree with the
//! positions (the main program's supervision, [`Main::contradiction`]).

use pkm_kinematics::MAX_DOF;

use super::automaton::{Io, Main, Phase, Search};
use super::reason::Reason;

/// How far (mm) a joint may stand from its reference switch's edge, in the frame of the last
/// referencing, while its reference input says the other side (the switch's repeatability, a
/// cycle's travel between the input's and the position's sampling, a stepper's rounding).
pub const SWITCH_AGREEMENT_MM: f64 = 1.0;

impl Main {
    /// Joint mode (INIT, before referencing): while a limit input is active or the override is
    /// held, INIT waits and the stick's x (or the left/right buttons) moves the selected joint;
    /// the axis button selects the next joint. On an active limit input nothing moves unless the
    /// override is held — then the drive program lets the joints move off it. True when
    /// referencing may start: no limit input, the override released, every joint at rest.
    pub(super) fn joint_jog(&mut self, io: &mut Io) -> bool {
        if io.axes_pressed {
            self.selection = (self.selection + 1) % self.n;
        }
        io.limit_override = io.override_held;
        // Single joints move before referencing from the panel alone, with the override held by
        // someone at the machine: the positions are not known yet, the software limits are not
        // in force, and only the limit switches guard the travel. Never from the screen.
        let x = if io.override_held && !io.screen_jog {
            self.stick(io)[0]
        } else {
            0.0
        };
        for j in 0..self.n {
            let v = if j == self.selection {
                x * self.p.jog.joint_speed_mm_s
            } else {
                0.0
            };
            io.ramp_velocity(j, v, self.p.joints[j].max_accel_mm_s2);
        }
        !io.limit_active && !io.override_held && io.velocities[..self.n].iter().all(|v| *v == 0.0)
    }

    /// Starts the return to the reference positions known from the last referencing.
    pub(super) fn start_return(&mut self, io: &mut Io) {
        io.limit_override = false;
        self.phase = Phase::Returning;
        self.ret_from = io.setpoints;
        self.ret_s = 0.0;
        self.ret_rate = 0.0;
        self.ret_since_s = io.now_s;
    }

    /// One cycle of the return; true once every joint is at its reference position. The joints
    /// move on one straight line in joint space (all arrive together), at no joint's speed or
    /// acceleration beyond its limit.
    pub(super) fn step_return(&mut self, io: &mut Io) -> Result<bool, Reason> {
        let (n, dt) = (self.n, io.dt_s);
        // The set-points moved on by rate·dt since the last cycle (`read`); so does the progress.
        self.ret_s += self.ret_rate * dt;
        let (mut speed, mut accel) = (f64::INFINITY, f64::INFINITY);
        for j in 0..n {
            let d = (self.home[j] - self.ret_from[j]).abs();
            if d > 0.0 {
                let r = &self.p.joints[j];
                speed = speed.min(r.max_speed_mm_s.min(2.0 * r.reference.search_speed_mm_s) / d);
                accel = accel.min(r.max_accel_mm_s2 / d);
            }
        }
        if speed.is_finite() {
            self.ret_rate = super::automaton::profile(self.ret_s, self.ret_rate, 1.0, speed, accel, dt);
        } else {
            (self.ret_s, self.ret_rate) = (1.0, 0.0);
        }
        for j in 0..n {
            io.velocities[j] = self.ret_rate * (self.home[j] - self.ret_from[j]);
        }
        let arrived = (1.0 - self.ret_s).abs() < 1e-9
            && self.ret_rate == 0.0
            && (0..n).all(|j| (io.positions[j] - self.home[j]).abs() < 0.05);
        if arrived {
            io.hold();
            return Ok(true);
        }
        if io.now_s - self.ret_since_s > self.p.search_timeout_s {
            let worst = (0..n)
                .max_by(|a, b| {
                    let gap = |j: usize| (io.positions[j] - self.home[j]).abs();
                    gap(*a).total_cmp(&gap(*b))
                })
                .unwrap_or(0);
            return Err(Reason::InitTimeout(worst));
        }
        Ok(false)
    }

    /// Starts referencing group `g`. The joints stay in the frame they are in: the last
    /// referencing's (its offsets) or, before any, the counted one. A referencing cut short
    /// (STOP during INIT) leaves every joint in a frame that still matches its switch — the
    /// joints it referenced in the new one, the others in the old one — so the next INIT's
    /// return goes where the reference positions really are. (Resetting the offsets here once
    /// sent the return of an interrupted referencing to the reference positions *of the counted
    /// frame*: on the hexapod 737 mm past the switches, into the limit switches.)
    ///
    /// A joint that starts on its switch leaves it first. With a shared input the joint may not
    /// be the one that holds it; its leave is then bounded and undone (pn101's joint 1 once left
    /// for 12 s, into its limit switch, while joint 3 held the input).
    pub(super) fn start_group(&mut self, io: &mut Io, g: usize) {
        io.limit_override = false;
        self.phase = Phase::Group(g);
        for k in 0..self.p.reference_order[g].len() {
            let j = self.p.reference_order[g][k] - 1;
            self.searches[j] = if io.reference_on[j] {
                Search::Leave {
                    since_s: io.now_s,
                    from: io.positions[j],
                }
            } else {
                Search::Seek {
                    stage: 0,
                    seen: io.capture_counts[j],
                    since_s: io.now_s,
                    from: io.positions[j],
                }
            };
        }
    }

    /// How far (mm) joint `j` stands past its reference switch in the frame it is in (negative:
    /// before it).
    fn past_switch(&self, io: &Io, j: usize) -> f64 {
        let r = &self.p.joints[j].reference;
        (io.positions[j] - r.switch_mm) * r.direction
    }

    /// The farthest (mm) joint `j`'s switch can be from where a search towards it begins
    /// (`towards`: the search direction; else leaving it): the joint's travel on the other side
    /// of the switch, and a back-off and the agreement beyond.
    pub(super) fn search_bound(&self, j: usize, towards: bool) -> f64 {
        let r = &self.p.joints[j].reference;
        let margin = self.p.soft_limit_margin_mm;
        let [lo, hi] = [self.soft[j][0] - margin, self.soft[j][1] + margin];
        let (below, above) = ((r.switch_mm - lo).max(0.0), (hi - r.switch_mm).max(0.0));
        // Searching in +direction, the joint is below the switch (in the direction's sense).
        let side = if (r.direction > 0.0) == towards { below } else { above };
        side + r.back_off_mm + SWITCH_AGREEMENT_MM
    }

    /// Whether joint `j`'s reference input contradicts the frame the joints are believed in:
    /// with the references known, the input is on exactly where the frame puts a joint past its
    /// switch (for a shared input: any joint), up to [`SWITCH_AGREEMENT_MM`]. A contradiction
    /// means the positions are not what the last referencing made them (a fault falsified
    /// them): moving on by them would search, or return, blind — past the switch, into the
    /// limit switches.
    pub(super) fn switch_contradicts(&self, io: &Io, j: usize) -> bool {
        if !self.known {
            return false;
        }
        let past = |k: usize| self.past_switch(io, k);
        let (expected, margin) = if self.shared_reference {
            let nearest = (0..self.n).map(|k| past(k).abs()).fold(f64::INFINITY, f64::min);
            ((0..self.n).any(|k| past(k) >= 0.0), nearest)
        } else {
            (past(j) >= 0.0, past(j).abs())
        };
        io.reference_on[j] != expected && margin > SWITCH_AGREEMENT_MM
    }

    /// The first joint whose reference input contradicts the frame, if any.
    pub(super) fn contradiction(&self, io: &Io) -> Option<usize> {
        (0..self.n).find(|&j| self.switch_contradicts(io, j))
    }

    /// One cycle of group `g`; true when every joint of it is at its reference position.
    pub(super) fn step_group(&mut self, io: &mut Io, g: usize) -> Result<bool, Reason> {
        let mut done = true;
        for k in 0..self.p.reference_order[g].len() {
            let j = self.p.reference_order[g][k] - 1;
            self.step_search(io, j)?;
            done &= self.searches[j] == Search::Done;
        }
        Ok(done)
    }

    fn step_search(&mut self, io: &mut Io, j: usize) -> Result<(), Reason> {
        let joint = &self.p.joints[j];
        let r = &joint.reference;
        let accel = joint.max_accel_mm_s2;
        let timeout = self.p.search_timeout_s;
        match self.searches[j] {
            Search::Leave { since_s, from } => {
                if !io.reference_on[j] {
                    self.searches[j] = Search::Seek {
                        stage: 0,
                        seen: io.capture_counts[j],
                        since_s: io.now_s,
                        from: io.positions[j],
                    };
                } else if io.now_s - since_s > timeout || (io.positions[j] - from).abs() > self.search_bound(j, false) {
                    self.searches[j] = Search::Undo {
                        to: from,
                        since_s: io.now_s,
                    };
                } else {
                    io.ramp_velocity(j, -r.direction * r.search_speed_mm_s, accel);
                }
            }
            Search::Undo { to, since_s } => {
                let back = io.move_to(j, to, r.search_speed_mm_s, accel);
                if (back && (io.positions[j] - to).abs() < 0.05) || io.now_s - since_s > timeout {
                    io.velocities[j] = 0.0;
                    return Err(Reason::ReferenceStaysOn(j));
                }
            }
            Search::Seek {
                stage,
                seen,
                since_s,
                from,
            } => {
                if io.capture_counts[j] != seen {
                    // The capture is counted; the joint moves in the frame of its offset.
                    let counted = io.captures[j];
                    if stage == 0 {
                        let edge = counted - io.offsets[j];
                        self.searches[j] = Search::Retreat {
                            target: edge - r.direction * r.back_off_mm,
                            since_s: io.now_s,
                            edge,
                        };
                    } else {
                        // The reference: the switch's edge is the joint's `switch_mm`. The
                        // set-points and positions move into the new frame with it.
                        let offset = counted - r.switch_mm;
                        let shift = offset - io.offsets[j];
                        io.offsets[j] = offset;
                        io.setpoints[j] -= shift;
                        io.positions[j] -= shift;
                        self.searches[j] = Search::ToHome { since_s: io.now_s };
                    }
                } else if io.now_s - since_s > timeout {
                    return Err(Reason::InitTimeout(j));
                } else if (io.positions[j] - from).abs() > self.search_bound(j, true) {
                    return Err(Reason::ReferenceNotFound(j));
                } else {
                    let speed = if stage == 0 {
                        r.search_speed_mm_s
                    } else {
                        r.latch_speed_mm_s
                    };
                    io.ramp_velocity(j, r.direction * speed, accel);
                }
            }
            Search::Retreat { target, since_s, edge } => {
                if io.now_s - since_s > timeout {
                    return Err(Reason::ReferenceStaysOn(j));
                }
                if io.move_to(j, target, r.search_speed_mm_s, accel) {
                    self.searches[j] = if io.reference_on[j] {
                        // Still on the switch: back off further, but never farther than the
                        // switch's edge can be from the joint.
                        let target = target - r.direction * r.back_off_mm;
                        if (target - edge).abs() > self.search_bound(j, false) {
                            return Err(Reason::ReferenceStaysOn(j));
                        }
                        Search::Retreat { target, since_s, edge }
                    } else {
                        Search::Seek {
                            stage: 1,
                            seen: io.capture_counts[j],
                            since_s: io.now_s,
                            from: io.positions[j],
                        }
                    };
                }
            }
            Search::ToHome { since_s } => {
                let home = self.home[j];
                let there = io.move_to(j, home, joint.max_speed_mm_s.min(2.0 * r.search_speed_mm_s), accel);
                if there && (io.positions[j] - home).abs() < 0.01 {
                    self.searches[j] = Search::Done;
                } else if io.now_s - since_s > timeout {
                    return Err(Reason::InitTimeout(j));
                }
            }
            Search::Done => io.velocities[j] = 0.0,
        }
        Ok(())
    }

    /// Every group is referenced and at home: world mode starts at the home pose.
    pub(super) fn finish_referencing(&mut self, io: &mut Io) {
        io.referenced = true;
        self.known = true;
        io.hold();
        let n = self.n;
        let mut pose = [0.0; MAX_DOF];
        // The set-points are the home joints exactly; their pose is the machine frame's origin
        // (up to the angles of the home pose).
        if self.frame.forward(&io.setpoints[..n], None, &mut pose[..n]).is_ok() {
            self.pose = pose;
        }
        self.pose_velocity = [0.0; MAX_DOF];
        self.selection = 0;
    }
}
