//! The main automaton of a joint-driven machine: the shared REBOOT → INIT → READY ⇄ MOTION and
//! ERROR state machine of pkm-drives with what these machines do in each state (`Main`), and the
//! inputs and outputs of a cycle (`Io`). INIT is joint mode (waiting while a limit input is
//! active or the override is held, the operator jogging single joints), then the return to the
//! known reference positions and referencing group by group; READY and MOTION are world mode.
//! Referencing and jogging have their own modules.

use pkm_drives::automaton::Application;
use pkm_drives::nc::{ProgramControl, RunState};
use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;

use super::reason::Reason;
use crate::params::MainParams;

/// The events the automaton handles: the shared automaton's, with these machines' reasons.
pub type Event = pkm_drives::automaton::Event<Reason>;

/// The main automaton: the shared one with the joint-driven machines' referencing and jog.
pub type Automaton = pkm_drives::automaton::Automaton<Main>;

/// Inputs and outputs of one main cycle, shared with the states.
#[derive(Clone, Debug, Default)]
pub struct Io {
    pub(super) now_s: f64,
    pub(super) dt_s: f64,
    pub(super) positions: [f64; MAX_DOF],
    pub(super) captures: [f64; MAX_DOF],
    pub(super) capture_counts: [i32; MAX_DOF],
    pub(super) reference_on: [bool; MAX_DOF],
    /// Some limit input is active.
    pub(super) limit_active: bool,
    pub(super) stick: [f64; 2],
    pub(super) stick_connected: bool,
    /// The screen jogs this pose coordinate alone (1-based; 0: the stick's pair).
    pub(super) screen_axis: usize,
    /// The screen jogs this joint alone (1-based; 0: none), in world mode only.
    pub(super) screen_joint: usize,
    /// The screen's jog is held (its deflection stands in `stick`).
    pub(super) screen_jog: bool,
    pub(super) buttons: [bool; 4],
    pub(super) override_held: bool,
    /// The axis button was pressed this cycle (a rising edge).
    pub(super) axes_pressed: bool,
    /// The loaded program's control: its buttons, start, hold and resume, the command.
    pub(super) program: ProgramControl,
    /// The executor's state, line and commanded pose (from the drive program).
    pub(super) nc_state: Option<RunState>,
    pub(super) nc_line: i32,
    pub(super) nc_pose: [f64; MAX_DOF],
    // Outputs. A set-point is published with its velocity: the drive program moves it on at
    // that velocity until the next main cycle.
    pub(super) enable: bool,
    pub(super) setpoints: [f64; MAX_DOF],
    pub(super) velocities: [f64; MAX_DOF],
    pub(super) offsets: [f64; MAX_DOF],
    pub(super) acknowledge: bool,
    pub(super) referenced: bool,
    pub(super) limit_override: bool,
}

impl Io {
    /// Stops every joint's set-point where it is.
    pub(super) fn hold(&mut self) {
        self.velocities = [0.0; MAX_DOF];
    }

    /// Changes joint `j`'s set-point velocity towards `v` by at most `accel`·dt.
    pub(super) fn ramp_velocity(&mut self, j: usize, v: f64, accel: f64) {
        let step = accel * self.dt_s;
        self.velocities[j] = v.clamp(self.velocities[j] - step, self.velocities[j] + step);
    }

    /// Moves joint `j`'s set-point towards `target` at up to `speed`, accelerating and braking at
    /// up to `accel`; true once it is there at rest.
    pub(super) fn move_to(&mut self, j: usize, target: f64, speed: f64, accel: f64) -> bool {
        let before = self.velocities[j];
        self.velocities[j] = profile(self.setpoints[j], before, target, speed, accel, self.dt_s);
        (target - self.setpoints[j]).abs() < 1e-9 && before.abs() <= accel * self.dt_s
    }
}

/// The next velocity of a quantity at `at` moving at `v` towards `target`: at most `speed`,
/// changed by at most `accel`·dt, and slow enough to stop at the target — after a step of dt
/// and braking, v·dt + v²/(2a) ≤ d, so v ≤ a·(√(dt² + 2d/a) − dt).
pub(super) fn profile(at: f64, v: f64, target: f64, speed: f64, accel: f64, dt: f64) -> f64 {
    let gap = target - at;
    let braking = accel * ((dt * dt + 2.0 * gap.abs() / accel).sqrt() - dt);
    let wanted = gap.signum() * speed.min(braking).min(gap.abs() / dt);
    wanted.clamp(v - accel * dt, v + accel * dt)
}

/// One joint's progress through referencing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Search {
    /// Started on the switch: moving against the search direction from `from` until the input
    /// is off.
    Leave { since_s: f64, from: f64 },
    /// A leave that did not clear the input: back to where it started (`to`), then ERROR.
    Undo { to: f64, since_s: f64 },
    /// Moving towards the switch from `from` until its capture count moves past `seen`; stage 0
    /// searches, stage 1 approaches slowly and takes the reference.
    Seek {
        stage: u8,
        seen: i32,
        since_s: f64,
        from: f64,
    },
    /// Backing off the switch (its edge at `edge`) to `target` before the slow approach.
    Retreat { target: f64, since_s: f64, edge: f64 },
    /// Referenced; moving to the reference (home) position.
    ToHome { since_s: f64 },
    /// At the reference position.
    Done,
}

/// Where INIT stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Joint mode: waiting for the limit inputs to clear and the override to be released (the
    /// operator jogs single joints).
    Waiting,
    /// Re-referencing: all joints return together, on a straight line in joint space, to the
    /// reference positions they know from the last referencing before searching their switches
    /// again — a mechanism whose joints search one at a time from an arbitrary pose could jam.
    Returning,
    /// Referencing the group of this index in the reference order.
    Group(usize),
}

/// What a joint-driven machine does in each state of the shared automaton, and what it keeps.
pub struct Main {
    pub(super) p: MainParams,
    pub(super) n: usize,
    pub(super) frame: MachineFrame,
    /// Joints at home (the reference positions), in joint coordinates.
    pub(super) home: [f64; MAX_DOF],
    /// Software limits per joint, [min, max] (mm).
    pub(super) soft: [[f64; 2]; MAX_DOF],
    /// Jog speed at full deflection per pose coordinate (mm/s or degrees/s).
    pub(super) axis_speed: [f64; MAX_DOF],
    /// The stick's pairs of pose coordinates, resolved to indices.
    pub(super) pairs: Vec<[usize; 2]>,
    pub(super) phase: Phase,
    pub(super) searches: [Search; MAX_DOF],
    /// The tool pose set-point (machine frame) and its velocity, in world mode.
    pub(super) pose: [f64; MAX_DOF],
    pub(super) pose_velocity: [f64; MAX_DOF],
    /// In world mode, the joint the screen jogs alone and its set-point velocity (mm/s), until
    /// it stands again.
    pub(super) joint_jog: Option<(usize, f64)>,
    /// What the stick drives: a joint in joint mode, a pair of world axes in world mode.
    pub(super) selection: usize,
    /// The joints' references are known from an earlier referencing (kept through REBOOT).
    pub(super) known: bool,
    /// The joints share one reference input (pn101): it is on when any joint is past its switch.
    pub(super) shared_reference: bool,
    /// The return to the reference positions: where it started, its progress (0 … 1), the
    /// progress's rate (1/s), and when it started (s).
    pub(super) ret_from: [f64; MAX_DOF],
    pub(super) ret_s: f64,
    pub(super) ret_rate: f64,
    pub(super) ret_since_s: f64,
}

/// How close the tool must be to the program's start pose for a start (mm, degrees).
const START_TOLERANCE: f64 = 1e-3;

impl Application for Main {
    type Reason = Reason;
    type Io = Io;
    const STOP: Reason = Reason::Stop;

    fn now_s(io: &Io) -> f64 {
        io.now_s
    }

    fn enter_reboot(&mut self, io: &mut Io) {
        io.enable = false;
        io.acknowledge = true;
        io.referenced = false;
        io.limit_override = false;
        // The offsets stay: INIT returns to the reference positions by them before it finds
        // the joints' zeros again.
        io.hold();
    }

    fn enter_init(&mut self, io: &mut Io) {
        io.setpoints = io.positions;
        io.hold();
        self.phase = Phase::Waiting;
        self.selection = 0;
    }

    fn init(&mut self, io: &mut Io) -> Result<bool, Reason> {
        io.enable = true;
        io.acknowledge = false;
        match self.phase {
            Phase::Waiting => {
                if self.joint_jog(io) {
                    if self.known {
                        self.start_return(io);
                    } else {
                        self.start_group(io, 0);
                    }
                }
            }
            Phase::Returning => {
                if self.step_return(io)? {
                    self.start_group(io, 0);
                }
            }
            Phase::Group(g) => {
                io.limit_override = false;
                if self.step_group(io, g)? {
                    if g + 1 < self.p.reference_order.len() {
                        self.start_group(io, g + 1);
                    } else {
                        self.finish_referencing(io);
                        return Ok(true);
                    }
                }
            }
        }
        Ok(false)
    }

    fn enter_ready(&mut self, io: &mut Io) {
        self.pose_velocity = [0.0; MAX_DOF];
        self.joint_jog = None;
        io.hold();
        io.program.leave();
    }

    fn start_auto(&mut self, io: &mut Io) -> bool {
        let Some(trajectory) = io.program.trajectory() else {
            return false;
        };
        let mut cursor = 0;
        let start = trajectory.sample(0.0, &mut cursor).pose;
        // A program starts where it was checked and planned from: the reference pose.
        let n = self.n;
        let at_start = (0..n).all(|c| (self.pose[c] - start[c]).abs() <= START_TOLERANCE);
        io.program.start(at_start)
    }

    fn enter_auto(&mut self, io: &mut Io) {
        self.pose_velocity = [0.0; MAX_DOF];
        io.hold();
        io.program.enter();
    }

    fn auto(&mut self, io: &mut Io) -> bool {
        // No jog in AUTO: the drive program takes the joints' set-points from the program; these
        // follow its pose, so that READY takes over where it ends.
        io.hold();
        let n = self.n;
        let mut joints = [0.0; MAX_DOF];
        if self.frame.inverse(&io.nc_pose[..n], &mut joints[..n]).is_ok() {
            self.pose = io.nc_pose;
            io.setpoints = joints;
        }
        io.program.auto(io.nc_state)
    }

    fn ready(&mut self, io: &mut Io) -> bool {
        io.hold();
        if io.axes_pressed && !self.pairs.is_empty() {
            self.selection = (self.selection + 1) % self.pairs.len();
        }
        let jog = self.world_command(io) != [0.0; MAX_DOF] || self.joint_command(io).is_some();
        if jog {
            io.program.forget_refusal();
        }
        jog
    }

    fn enter_motion(&mut self, _io: &mut Io) {}

    fn motion(&mut self, io: &mut Io) -> bool {
        // One jog at a time: a joint's (the screen's) or the tool's, each braked to a stand
        // before the other starts.
        let joint = self.joint_command(io);
        if (self.joint_jog.is_some() || (joint.is_some() && self.pose_velocity == [0.0; MAX_DOF]))
            && self.jog_joint(io, joint)
        {
            return true;
        }
        let command = self.world_command(io);
        if command == [0.0; MAX_DOF] && self.pose_velocity == [0.0; MAX_DOF] {
            io.hold();
            return false;
        }
        self.jog(io, command);
        true
    }

    fn enter_error(&mut self, reason: Reason, io: &mut Io) {
        // After STOP or a limit input the counted positions still hold: re-referencing returns
        // by them first. A drive, counter, bus or timing fault may have falsified them.
        if !matches!(reason, Reason::Stop | Reason::Limit(_)) {
            self.known = false;
        }
        io.program.leave();
        self.pose_velocity = [0.0; MAX_DOF];
        self.joint_jog = None;
        self.error(io);
    }

    fn error(&mut self, io: &mut Io) {
        // Drives off; the set-points follow the joints, so that re-enabling is bumpless.
        io.enable = false;
        io.limit_override = false;
        io.setpoints = io.positions;
        io.hold();
    }
}

impl Main {
    /// A machine's part of the automaton.
    pub(super) fn new(
        p: MainParams,
        frame: MachineFrame,
        soft: [[f64; 2]; MAX_DOF],
        pairs: Vec<[usize; 2]>,
        shared_reference: bool,
    ) -> Self {
        let n = frame.dof();
        let mut home = [0.0; MAX_DOF];
        home[..n].copy_from_slice(frame.home_joints());
        let mut axis_speed = [0.0; MAX_DOF];
        for (s, key) in axis_speed.iter_mut().zip(frame.kinematics().pose_keys()) {
            *s = if pkm_api::ranges::is_rotation(key) {
                p.jog.angular_speed_deg_s
            } else {
                p.jog.linear_speed_mm_s
            };
        }
        Main {
            p,
            n,
            frame,
            home,
            soft,
            axis_speed,
            pairs,
            phase: Phase::Waiting,
            searches: [Search::Done; MAX_DOF],
            pose: [0.0; MAX_DOF],
            pose_velocity: [0.0; MAX_DOF],
            joint_jog: None,
            selection: 0,
            known: false,
            shared_reference,
            ret_from: [0.0; MAX_DOF],
            ret_s: 0.0,
            ret_rate: 0.0,
            ret_since_s: 0.0,
        }
    }

    /// The stick's deflection (x, y), dead zone applied; the panel's direction buttons when the
    /// stick is at rest. A joystick that is not connected commands nothing.
    pub(super) fn stick(&self, io: &Io) -> [f64; 2] {
        let dz = self.p.jog.dead_zone;
        let [jx, jy] = if io.stick_connected { io.stick } else { [0.0; 2] };
        let [x, y] = [jx, jy].map(|v| if v.abs() > dz { v } else { 0.0 });
        if x != 0.0 || y != 0.0 {
            return [x, y];
        }
        let [left, right, up, down] = io.buttons.map(|b| f64::from(u8::from(b)));
        [right - left, up - down]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// A move with `profile` from rest reaches its target, at rest, without passing it, and
        /// never exceeds its speed or its acceleration.
        #[test]
        fn a_profiled_move_arrives_without_overshoot_within_its_limits(
            distance in -200.0f64..200.0,
            speed in 0.5f64..50.0,
            accel in 5.0f64..500.0,
        ) {
            let dt = 0.05;
            let (mut at, mut v) = (0.0f64, 0.0f64);
            let mut steps = 0;
            loop {
                let next = profile(at, v, distance, speed, accel, dt);
                prop_assert!(next.abs() <= speed + 1e-9, "speed {next}");
                prop_assert!((next - v).abs() <= accel * dt + 1e-9, "acceleration {}", (next - v) / dt);
                v = next;
                at += v * dt;
                prop_assert!(at.abs() <= distance.abs() + 1e-9, "passed the target: {at} of {distance}");
                if (distance - at).abs() < 1e-9 && v.abs() <= accel * dt {
                    break;
                }
                steps += 1;
                prop_assert!(steps < 100_000, "never arrives: at {at} v {v}");
            }
        }
    }
}
