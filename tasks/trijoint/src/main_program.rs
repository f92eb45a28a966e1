//! The main program (50 ms class, HW_obsluha of the original): the REBOOT → INIT → READY ⇄ MOTION
//! and ERROR automaton of application.md, as a statig state machine.
//!
//! Every cycle dispatches one event: an accepted STOP press, else a supervision fault, else a tick.
//! The superstate `operating` (INIT, READY, MOTION) turns STOP and faults into ERROR; ERROR turns
//! an accepted STOP press into REBOOT (acknowledgement). STOP acts on the press (the rising edge),
//! not the level: with the original's level semantics, holding STOP longer than the lockout would
//! acknowledge the error and restart INIT while the button is still held.

use serde::Deserialize;
use statig::prelude::*;

use super::state::MainState;
use pkm_api::image::{Declare, Input, Output, Var};

use crate::vars;
use pkm_api::program::{AppStatus, Cycle, Program, ProgramArgs};
use pkm_kinematics::trijoint::{Trijoint, TrijointParams};
use pkm_kinematics::{Kinematics, KinematicsConfig};

/// Parameters of the main program.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MainParams {
    /// After an accepted STOP press the button is ignored this long (ms).
    pub stop_lockout_ms: u64,
    /// PWM period written to the motor bridges (µs).
    pub pwm_period_us: u16,
    /// Speed of the coarse switch search and of moves in INIT (mm/s).
    pub init_speed_mm_s: f64,
    /// Speed of the second approach to a switch (mm/s).
    pub approach_speed_mm_s: f64,
    /// Speed of the final approach (mm/s): at most one encoder count per 10 ms cycle, so that the
    /// switch position is known to one count (7000 counts/mm: 0.0143 mm/s).
    pub creep_speed_mm_s: f64,
    /// The second approach starts this far before the coarse switch position (mm).
    pub approach_distance_mm: f64,
    /// The final approach starts this far before the second approach's switch position (mm).
    pub creep_distance_mm: f64,
    /// A switch not found within this time is an INIT timeout (s).
    pub search_timeout_s: f64,
    /// Carriage positions after INIT, from the lower switches (mm); default: the middle.
    pub start_position_mm: Option<[f64; 2]>,
    /// Software limits lie this far inside the switches (mm).
    pub soft_limit_margin_mm: f64,
    /// Speed of the spindle point M at full joystick deflection (mm/s).
    pub max_speed_mm_s: f64,
    /// No carriage set-point moves faster than this while jogging (mm/s): near the ends of the
    /// travel a modest speed of M asks the carriages for more, and a carriage that cannot
    /// follow lags, then overshoots. The jog slows M down instead.
    pub max_joint_speed_mm_s: f64,
    /// Deceleration with which a jogging carriage set-point brakes towards its software limit
    /// (mm/s²), so that the carriage stops inside the limit instead of overshooting a set-point
    /// that stopped dead.
    pub brake_decel_mm_s2: f64,
    /// Joystick deflections below this count as released.
    pub dead_zone: f64,
    /// M is never commanded where the singularity measure is below this.
    pub singularity_threshold: f64,
}

impl Default for MainParams {
    fn default() -> Self {
        MainParams {
            stop_lockout_ms: 500,
            pwm_period_us: 50,
            init_speed_mm_s: 15.0,
            approach_speed_mm_s: 1.0,
            creep_speed_mm_s: 0.012,
            approach_distance_mm: 0.5,
            creep_distance_mm: 0.03,
            search_timeout_s: 30.0,
            start_position_mm: None,
            soft_limit_margin_mm: 2.0,
            max_speed_mm_s: 20.0,
            max_joint_speed_mm_s: 40.0,
            brake_decel_mm_s2: 100.0,
            dead_zone: 0.05,
            singularity_threshold: 0.3,
        }
    }
}

/// The longest cycle the main program may run in (µs).
const MAX_MAIN_CYCLE_US: u32 = 100_000;

/// How close to the border of the allowed region a jog step that crosses it stops (mm, along
/// the step): 1 nm, far below the encoders' resolution, in about 21 halvings of a 2 mm step.
const BORDER_TOLERANCE_MM: f64 = 1e-6;

/// The safety-relevant parameters' ranges (the other parameters need only be positive): a value
/// outside is refused by `check`, naming the key.
fn check_ranges(p: &MainParams, geometry: &TrijointParams, decl: &mut Declare<'_>) {
    let mut within = |key: &str, v: f64, range: std::ops::RangeInclusive<f64>, why: &str| {
        if !(v.is_finite() && range.contains(&v)) {
            decl.issue(
                &format!("params.{key}"),
                format!("must be between {} and {}{why}, got {v}", range.start(), range.end()),
            );
        }
    };
    within(
        "stop_lockout_ms",
        p.stop_lockout_ms as f64,
        100.0..=10_000.0,
        " ms: a shorter lockout lets a bouncing STOP contact acknowledge the error it caused",
    );
    within(
        "pwm_period_us",
        f64::from(p.pwm_period_us),
        10.0..=10_000.0,
        " µs: 0 switches the motor bridges off",
    );
    within(
        "singularity_threshold",
        p.singularity_threshold,
        0.01..=0.99,
        " (a ratio of singular values; 0 would let M reach a singularity)",
    );
    within("dead_zone", p.dead_zone, 0.0..=0.9, " (a fraction of full deflection)");
    let shorter = (geometry.h1_travel[1] - geometry.h1_travel[0]).min(geometry.h2_travel[1] - geometry.h2_travel[0]);
    within(
        "soft_limit_margin_mm",
        p.soft_limit_margin_mm,
        0.1..=(shorter / 4.0).max(0.1),
        " mm (at most a quarter of the shorter travel)",
    );
    within("max_speed_mm_s", p.max_speed_mm_s, 0.1..=1000.0, " mm/s");
    within("max_joint_speed_mm_s", p.max_joint_speed_mm_s, 0.1..=1000.0, " mm/s");
    within("brake_decel_mm_s2", p.brake_decel_mm_s2, 1.0..=100_000.0, " mm/s²");
    within("search_timeout_s", p.search_timeout_s, 1.0..=3600.0, " s");
}

/// Why the machine is in ERROR.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reason {
    /// The STOP button.
    Stop,
    /// A limit switch in READY or MOTION (index: left upper, left down, right upper, right down).
    LimitSwitch(usize),
    /// An implausible encoder change (drive 0 left, 1 right).
    EncoderFault(usize),
    /// A motor bridge error (drive).
    BridgeError(usize),
    /// A following error (drive).
    FollowingError(usize),
    /// A cycle time violation reported by the runtime.
    CycleTimeViolation,
    /// The field bus failed beyond its error bound.
    BusFault,
    /// A switch not reached during INIT — in time, or at all because the carriage was blocked
    /// (switch index as for `LimitSwitch`).
    InitTimeout(usize),
    /// The wrong switch during INIT (switch index as for `LimitSwitch`).
    InitWrongSwitch(usize),
}

/// The limit switches in the original program's order: left upper, left lower, right upper,
/// right lower.
const SWITCHES: [Var<bool>; 4] = [
    vars::SWITCHES[0][1],
    vars::SWITCHES[0][0],
    vars::SWITCHES[1][1],
    vars::SWITCHES[1][0],
];

impl Reason {
    /// The reason as users read it.
    pub fn text(self) -> &'static str {
        const LIMIT: [&str; 4] = [
            "limit switch SWITCH_LEFT_UPPER",
            "limit switch SWITCH_LEFT_DOWN",
            "limit switch SWITCH_RIGHT_UPPER",
            "limit switch SWITCH_RIGHT_DOWN",
        ];
        const WRONG: [&str; 4] = [
            "INIT: wrong switch SWITCH_LEFT_UPPER",
            "INIT: wrong switch SWITCH_LEFT_DOWN",
            "INIT: wrong switch SWITCH_RIGHT_UPPER",
            "INIT: wrong switch SWITCH_RIGHT_DOWN",
        ];
        const NOT_REACHED: [&str; 4] = [
            "INIT timeout: SWITCH_LEFT_UPPER not reached",
            "INIT timeout: SWITCH_LEFT_DOWN not reached",
            "INIT timeout: SWITCH_RIGHT_UPPER not reached",
            "INIT timeout: SWITCH_RIGHT_DOWN not reached",
        ];
        const SIDE: [[&str; 2]; 3] = [
            ["encoder fault left", "encoder fault right"],
            ["motor bridge error left", "motor bridge error right"],
            ["following error left", "following error right"],
        ];
        match self {
            Reason::Stop => "STOP",
            Reason::LimitSwitch(i) => LIMIT[i.min(3)],
            Reason::EncoderFault(d) => SIDE[0][d.min(1)],
            Reason::BridgeError(d) => SIDE[1][d.min(1)],
            Reason::FollowingError(d) => SIDE[2][d.min(1)],
            Reason::CycleTimeViolation => "cycle time violation",
            Reason::BusFault => "bus fault",
            Reason::InitTimeout(i) => NOT_REACHED[i.min(3)],
            Reason::InitWrongSwitch(i) => WRONG[i.min(3)],
        }
    }

    /// A number for the process image (`error_reason`): 0 is no error.
    pub fn code(self) -> i16 {
        match self {
            Reason::Stop => 1,
            Reason::LimitSwitch(i) => 10 + i as i16,
            Reason::EncoderFault(d) => 20 + d as i16,
            Reason::BridgeError(d) => 30 + d as i16,
            Reason::FollowingError(d) => 40 + d as i16,
            Reason::CycleTimeViolation => 50,
            Reason::BusFault => 55,
            Reason::InitTimeout(i) => 60 + i as i16,
            Reason::InitWrongSwitch(i) => 70 + i as i16,
        }
    }
}

/// The events the automaton handles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// An accepted STOP press.
    Stop,
    /// A supervision fault.
    Fault(Reason),
    /// A cycle without either.
    Tick,
}

/// Which end of a drive's travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum End {
    Lower = 0,
    Upper = 1,
}

impl End {
    fn direction(self) -> f64 {
        match self {
            End::Lower => -1.0,
            End::Upper => 1.0,
        }
    }

    fn other(self) -> End {
        match self {
            End::Lower => End::Upper,
            End::Upper => End::Lower,
        }
    }

    /// Index of drive `i`'s switch at this end in [`SWITCHES`] order.
    fn switch(self, drive: usize) -> usize {
        drive * 2 + if self == End::Upper { 0 } else { 1 }
    }
}

/// One drive's progress through referencing. Each switch is found three times, ever slower:
/// stage 0 at the init speed, stage 1 at the approach speed, stage 2 creeping at most one count
/// per 10 ms cycle; the encoder program's capture of the last one is the switch position.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Search {
    /// Moving towards the switch until its capture counter moves past `seen[end]`.
    Seek {
        end: End,
        stage: u8,
        seen: [i32; 2],
        since_s: f64,
    },
    /// Moving back to `target`, clear of the switch, before the next stage.
    Retreat { end: End, stage: u8, target: f64 },
    /// Both switches found; waiting for the other drive.
    Found,
    /// Moving to the start position.
    ToStart { target: f64 },
    /// At the start position.
    Done,
}

/// Inputs and outputs of one cycle, shared with the states.
#[derive(Clone, Debug, Default)]
pub struct Io {
    now_s: f64,
    dt_s: f64,
    positions: [f64; 2],
    switches: [bool; 4],
    captures: [[f64; 2]; 2],
    capture_counts: [[i32; 2]; 2],
    joystick: [f64; 2],
    joystick_connected: bool,
    buttons: [bool; 4],
    // Outputs. A set-point is published with its velocity: the 10 ms controller moves it on at
    // that velocity until the next main cycle.
    enable: bool,
    setpoints: [f64; 2],
    velocities: [f64; 2],
    references: [f64; 2],
    acknowledge: bool,
    referenced: bool,
}

impl Io {
    /// Holds both drives at their current set-points.
    fn hold(&mut self) {
        self.velocities = [0.0; 2];
    }

    /// Moves set-point `i` towards `target` at up to `speed`; true once it is there.
    fn ramp_to(&mut self, i: usize, target: f64, speed: f64) -> bool {
        let gap = target - self.setpoints[i];
        self.velocities[i] = (gap / self.dt_s).clamp(-speed, speed);
        gap.abs() < 1e-9
    }
}

/// The automaton's shared storage.
pub struct Automaton {
    p: MainParams,
    geometry: TrijointParams,
    state: MainState,
    /// When the current state was entered (s); REBOOT lasts one cycle.
    entered_s: f64,
    reason: Option<Reason>,
    edges: [[f64; 2]; 2],
    limits: Option<Trijoint>,
    /// The software limits of the carriages, [lower, upper] per drive (mm, referenced).
    soft: [[f64; 2]; 2],
    m_setpoint: [f64; 2],
    searches: [Search; 2],
}

#[state_machine(initial = "State::reboot()", context_identifier = "io")]
impl Automaton {
    #[state(entry_action = "enter_reboot")]
    fn reboot(&mut self, io: &mut Io, event: &Event) -> Outcome<State> {
        match event {
            // The acknowledge pulses go out for the one cycle REBOOT lasts; then reference.
            Event::Tick if io.now_s > self.entered_s => Transition(State::init()),
            _ => Handled,
        }
    }

    #[action]
    fn enter_reboot(&mut self, io: &mut Io) {
        self.state = MainState::Reboot;
        self.entered_s = io.now_s;
        self.reason = None;
        self.limits = None;
        io.enable = false;
        io.acknowledge = true;
        io.referenced = false;
        io.references = [0.0; 2];
        io.hold();
    }

    #[superstate]
    fn operating(&mut self, event: &Event) -> Outcome<State> {
        match event {
            Event::Stop => Transition(State::error(Reason::Stop)),
            Event::Fault(reason) => Transition(State::error(*reason)),
            Event::Tick => Handled,
        }
    }

    #[state(superstate = "operating", entry_action = "enter_init")]
    fn init(&mut self, io: &mut Io, event: &Event) -> Outcome<State> {
        if *event != Event::Tick {
            return Super;
        }
        io.enable = true;
        io.acknowledge = false;
        for i in 0..2 {
            if let Err(reason) = self.step_search(io, i) {
                return Transition(State::error(reason));
            }
        }
        if self.searches.iter().all(|s| *s == Search::Found) {
            self.finish_referencing(io);
        }
        if self.searches.iter().all(|s| *s == Search::Done) {
            return Transition(State::ready());
        }
        Handled
    }

    #[action]
    fn enter_init(&mut self, io: &mut Io) {
        self.state = MainState::Init;
        io.setpoints = io.positions;
        io.hold();
        self.searches = [0, 1].map(|i| Search::Seek {
            end: End::Upper,
            stage: 0,
            seen: io.capture_counts[i],
            since_s: io.now_s,
        });
    }

    #[state(superstate = "operating", entry_action = "enter_ready")]
    fn ready(&mut self, io: &mut Io, event: &Event) -> Outcome<State> {
        if *event != Event::Tick {
            return Super;
        }
        io.hold();
        if self.command(io) != [0.0; 2] {
            return Transition(State::motion());
        }
        Handled
    }

    #[action]
    fn enter_ready(&mut self, io: &mut Io) {
        self.state = MainState::Ready;
        io.hold();
    }

    #[state(superstate = "operating", entry_action = "enter_motion")]
    fn motion(&mut self, io: &mut Io, event: &Event) -> Outcome<State> {
        if *event != Event::Tick {
            return Super;
        }
        let v = self.command(io);
        if v == [0.0; 2] {
            io.hold();
            return Transition(State::ready());
        }
        self.jog(io, v);
        Handled
    }

    #[action]
    fn enter_motion(&mut self) {
        self.state = MainState::Motion;
    }

    #[state(entry_action = "enter_error")]
    fn error(reason: &mut Reason, io: &mut Io, event: &Event) -> Outcome<State> {
        // The reason is kept in the state (and in shared storage for the status, on entry).
        let _ = reason;
        // Drives off; the set-points follow the carriages, so that re-enabling is bumpless.
        io.enable = false;
        io.setpoints = io.positions;
        io.hold();
        match event {
            Event::Stop => Transition(State::reboot()),
            _ => Handled,
        }
    }

    #[action]
    fn enter_error(&mut self, reason: &mut Reason, io: &mut Io) {
        self.state = MainState::Error;
        self.reason = Some(*reason);
        io.enable = false;
        io.setpoints = io.positions;
        io.hold();
    }
}

impl Automaton {
    /// The automaton in REBOOT, with its parameters and the machine's geometry.
    pub fn new(p: MainParams, geometry: TrijointParams) -> Self {
        Automaton {
            p,
            geometry,
            state: MainState::Reboot,
            entered_s: 0.0,
            reason: None,
            edges: [[0.0; 2]; 2],
            limits: None,
            soft: [[0.0; 2]; 2],
            m_setpoint: [0.0; 2],
            searches: [Search::Done; 2],
        }
    }

    /// The operator's command as a velocity of M (mm/s): joystick, else direction buttons. A
    /// joystick that is not connected commands nothing, whatever its axes read.
    fn command(&self, io: &Io) -> [f64; 2] {
        let dz = self.p.dead_zone;
        let [jx, jy] = if io.joystick_connected { io.joystick } else { [0.0; 2] };
        let (mut x, mut y) = (
            if jx.abs() > dz { jx } else { 0.0 },
            if jy.abs() > dz { jy } else { 0.0 },
        );
        if x == 0.0 && y == 0.0 {
            let [left, right, up, down] = io.buttons.map(|b| f64::from(u8::from(b)));
            x = right - left;
            y = up - down;
        }
        [x * self.p.max_speed_mm_s, y * self.p.max_speed_mm_s]
    }

    /// Whether M may be commanded to `m`: reachable inside the software limits and not near a
    /// singularity. Writes the carriage positions for it into `joints`.
    fn allowed(&self, m: [f64; 2], joints: &mut [f64; 2]) -> bool {
        let Some(k) = &self.limits else { return false };
        k.inverse(&m, joints).is_ok()
            && k.singularity_measure(&m)
                .is_ok_and(|s| s >= self.p.singularity_threshold)
    }

    /// Moves M's set-point by `v`·dt, slowed so that no carriage set-point exceeds the joint
    /// speed limit or its braking curve towards its software limit, and stopping at the border
    /// of the allowed region.
    fn jog(&mut self, io: &mut Io, v: [f64; 2]) {
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
    fn joint_speed_scale(&self, io: &Io) -> f64 {
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
    fn step_m(&self, io: &mut Io, v: [f64; 2]) -> [f64; 2] {
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

    /// One cycle of drive `i`'s referencing.
    fn step_search(&mut self, io: &mut Io, i: usize) -> Result<(), Reason> {
        let p = &self.p;
        match self.searches[i] {
            Search::Seek {
                end,
                stage,
                seen,
                since_s,
            } => {
                // The other switch tripping while seeking this one: wrong wiring or direction.
                if io.capture_counts[i][end.other() as usize] != seen[end.other() as usize] {
                    return Err(Reason::InitWrongSwitch(end.other().switch(i)));
                }
                if io.now_s - since_s > p.search_timeout_s {
                    return Err(Reason::InitTimeout(end.switch(i)));
                }
                let speed = [p.init_speed_mm_s, p.approach_speed_mm_s, p.creep_speed_mm_s][usize::from(stage.min(2))];
                if io.capture_counts[i][end as usize] != seen[end as usize] {
                    let edge = io.captures[i][end as usize];
                    io.setpoints[i] = io.positions[i];
                    io.velocities[i] = 0.0;
                    self.searches[i] = match (stage, end) {
                        (0 | 1, _) => {
                            let back = if stage == 0 {
                                p.approach_distance_mm
                            } else {
                                p.creep_distance_mm
                            };
                            Search::Retreat {
                                end,
                                stage: stage + 1,
                                target: edge - end.direction() * back,
                            }
                        }
                        (_, End::Upper) => {
                            self.edges[i][1] = edge;
                            Search::Seek {
                                end: End::Lower,
                                stage: 0,
                                seen: io.capture_counts[i],
                                since_s: io.now_s,
                            }
                        }
                        (_, End::Lower) => {
                            self.edges[i][0] = edge;
                            Search::Found
                        }
                    };
                } else if stage == 0 && io.switches[end.switch(i)] {
                    // Started on the switch: no edge to see from here; back off first.
                    let target = io.positions[i] - end.direction() * p.approach_distance_mm;
                    self.searches[i] = Search::Retreat { end, stage: 0, target };
                } else {
                    io.velocities[i] = end.direction() * speed;
                }
            }
            Search::Retreat { end, stage, target } => {
                let speed = if stage <= 1 {
                    p.init_speed_mm_s
                } else {
                    p.approach_speed_mm_s
                };
                if io.ramp_to(i, target, speed) && (io.positions[i] - target).abs() < 0.005 {
                    if io.switches[end.switch(i)] {
                        // Still on the switch: back off further.
                        let target = target - end.direction() * p.approach_distance_mm;
                        self.searches[i] = Search::Retreat { end, stage, target };
                    } else {
                        self.searches[i] = Search::Seek {
                            end,
                            stage,
                            seen: io.capture_counts[i],
                            since_s: io.now_s,
                        };
                    }
                }
            }
            // Only this drive waits: holding both here would freeze the other drive's search
            // every cycle whenever this one finished first (an asymmetric start).
            Search::Found => io.velocities[i] = 0.0,
            Search::ToStart { target } => {
                if io.ramp_to(i, target, p.init_speed_mm_s) && (io.positions[i] - target).abs() < 0.01 {
                    self.searches[i] = Search::Done;
                }
            }
            Search::Done => io.velocities[i] = 0.0,
        }
        Ok(())
    }

    /// Both drives' switches are known: set the references (0 mm at the lower switches), the
    /// software limits, and send the carriages to their start positions.
    fn finish_referencing(&mut self, io: &mut Io) {
        let travel = self.edges.map(|[lower, upper]| upper - lower);
        for (i, [lower, _]) in self.edges.iter().enumerate() {
            io.references[i] = *lower;
            // The set-points move into the referenced frame with the positions.
            io.setpoints[i] -= lower;
        }
        io.referenced = true;
        let m = self.p.soft_limit_margin_mm;
        let limits = Trijoint::new(&TrijointParams {
            h1_travel: [m, travel[0] - m],
            h2_travel: [m, travel[1] - m],
            ..self.geometry.clone()
        });
        let start = self.p.start_position_mm.unwrap_or([travel[0] / 2.0, travel[1] / 2.0]);
        let mut pose = [0.0; 2];
        if limits.forward(&start, None, &mut pose).is_ok() {
            self.m_setpoint = pose;
        }
        self.limits = Some(limits);
        self.soft = travel.map(|t| [m, t - m]);
        self.searches = [0, 1].map(|i| Search::ToStart { target: start[i] });
    }
}

struct Vars {
    stop: Input<bool>,
    joystick_stop: Input<bool>,
    bus_fault: Input<bool>,
    switches: [Input<bool>; 4],
    buttons: [Input<bool>; 4],
    joystick: [Input<f64>; 2],
    joystick_connected: Input<bool>,
    positions: [Input<f64>; 2],
    captures: [[Input<f64>; 2]; 2],
    capture_counts: [[Input<i32>; 2]; 2],
    encoder_faults: [Input<bool>; 2],
    bridge_errors: [Input<bool>; 2],
    following_errors: [Input<bool>; 2],
    state: Output<i16>,
    reason: Output<i16>,
    enable: Output<bool>,
    setpoints: [Output<f64>; 2],
    velocities: [Output<f64>; 2],
    setpoint_time: Output<f64>,
    references: [Output<f64>; 2],
    acknowledge: Output<bool>,
    clear_errors: [Output<bool>; 2],
    period: Output<u16>,
    referenced: Output<bool>,
    m: [Output<f64>; 2],
}

/// The main program.
pub struct MainProgram {
    machine: StateMachine<Automaton>,
    io: Io,
    vars: Vars,
    stop_was_pressed: bool,
    stop_accepted_at: Option<f64>,
    lockout_s: f64,
    display: Trijoint,
    /// M and the carriage positions, for the status line.
    shown: [(&'static str, f64); 6],
}

impl MainProgram {
    /// Declares the program's variables.
    pub fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p: MainParams = args.parse(decl);
        for (k, v) in [
            ("init_speed_mm_s", p.init_speed_mm_s),
            ("approach_speed_mm_s", p.approach_speed_mm_s),
            ("creep_speed_mm_s", p.creep_speed_mm_s),
            ("approach_distance_mm", p.approach_distance_mm),
            ("creep_distance_mm", p.creep_distance_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                decl.issue(&format!("params.{k}"), format!("must be positive, got {v}"));
            }
        }
        let geometry = args
            .kinematics
            .and_then(|k| serde_json::from_value::<KinematicsConfig>(k.clone()).ok())
            .unwrap_or_default()
            .trijoint;
        check_ranges(&p, &geometry, decl);
        if args.cycle_us > MAX_MAIN_CYCLE_US {
            decl.issue(
                "program",
                format!(
                    "trijoint.main runs in a class of {} ms; at most {} ms: STOP, limit switches and faults \
                     become ERROR in its cycle",
                    args.cycle_us / 1000,
                    MAX_MAIN_CYCLE_US / 1000
                ),
            );
        }
        let vars = Vars {
            stop: decl.read(vars::BUTTON_STOP),
            joystick_stop: decl.read_optional(vars::JOYSTICK_STOP),
            bus_fault: decl.read(vars::BUS_FAULT),
            switches: SWITCHES.map(|v| decl.read(v)),
            buttons: vars::BUTTONS.map(|v| decl.read(v)),
            joystick: vars::JOYSTICK.map(|v| decl.read(v)),
            joystick_connected: decl.read(vars::JOYSTICK_CONNECTED),
            positions: vars::POSITION_MM.map(|v| decl.read(v)),
            captures: vars::CAPTURE_MM.map(|d| d.map(|v| decl.read(v))),
            capture_counts: vars::CAPTURES.map(|d| d.map(|v| decl.read(v))),
            encoder_faults: vars::ENCODER_FAULT.map(|v| decl.read(v)),
            bridge_errors: vars::BRIDGE_ERROR.map(|v| decl.read(v)),
            following_errors: vars::FOLLOWING_ERROR.map(|v| decl.read(v)),
            state: decl.write(vars::MAIN_STATE, MainState::Reboot.code()),
            reason: decl.write(vars::ERROR_REASON, 0),
            enable: decl.write(vars::DRIVES_ENABLE, false),
            setpoints: vars::SETPOINT_MM.map(|v| decl.write(v, 0.0)),
            velocities: vars::SETPOINT_MM_S.map(|v| decl.write(v, 0.0)),
            setpoint_time: decl.write(vars::SETPOINT_TIME_S, 0.0),
            references: vars::REFERENCE_MM.map(|v| decl.write(v, 0.0)),
            acknowledge: decl.write(vars::ENCODER_FAULT_ACK, false),
            clear_errors: vars::CLEAR_ERROR.map(|v| decl.write(v, false)),
            period: decl.write(vars::PERIOD_DURATION, 0),
            referenced: decl.write(vars::REFERENCED, false),
            m: vars::M.map(|v| decl.write(v, 0.0)),
        };
        let lockout_s = p.stop_lockout_ms as f64 * 1e-3;
        let display = Trijoint::new(&TrijointParams {
            h1_travel: [-1e6, 1e6],
            h2_travel: [-1e6, 1e6],
            ..geometry.clone()
        });
        Box::new(MainProgram {
            machine: Automaton::new(p, geometry).state_machine(),
            io: Io::default(),
            vars,
            stop_was_pressed: false,
            stop_accepted_at: None,
            lockout_s,
            display,
            shown: [
                ("Mx", f64::NAN),
                ("My", f64::NAN),
                ("h1", f64::NAN),
                ("h2", f64::NAN),
                ("jx", f64::NAN),
                ("jy", f64::NAN),
            ],
        })
    }

    /// Reads the inputs into `io` and advances the set-points to where the controller has taken
    /// them since the last cycle.
    fn read(&mut self, ctx: &Cycle<'_>) {
        let (v, io) = (&self.vars, &mut self.io);
        io.now_s = ctx.time_ns() as f64 * 1e-9;
        io.dt_s = ctx.period_ns() as f64 * 1e-9;
        io.positions = v.positions.map(|p| ctx.get(p));
        io.switches = v.switches.map(|s| ctx.get(s));
        io.buttons = v.buttons.map(|b| ctx.get(b));
        io.joystick = v.joystick.map(|j| ctx.get(j));
        io.joystick_connected = ctx.get(v.joystick_connected);
        io.captures = v.captures.map(|c| c.map(|x| ctx.get(x)));
        io.capture_counts = v.capture_counts.map(|c| c.map(|x| ctx.get(x)));
        for i in 0..2 {
            io.setpoints[i] += io.velocities[i] * io.dt_s;
        }
    }

    /// The event of this cycle.
    fn event(&mut self, ctx: &Cycle<'_>) -> Event {
        let v = &self.vars;
        let state = self.machine.inner().state;
        let now = self.io.now_s;
        // The joystick's STOP acts in addition to the panel's, never instead of it.
        let pressed = ctx.get(v.stop) || ctx.get(v.joystick_stop);
        let press = pressed && !self.stop_was_pressed;
        self.stop_was_pressed = pressed;
        let enabled = self.stop_accepted_at.is_none_or(|t| now - t >= self.lockout_s);
        if press && enabled && state != MainState::Reboot {
            self.stop_accepted_at = Some(now);
            return Event::Stop;
        }
        if !matches!(state, MainState::Init | MainState::Ready | MainState::Motion) {
            return Event::Tick;
        }
        if ctx.violation().is_some() {
            return Event::Fault(Reason::CycleTimeViolation);
        }
        if ctx.get(v.bus_fault) {
            return Event::Fault(Reason::BusFault);
        }
        for d in 0..2 {
            if ctx.get(v.encoder_faults[d]) {
                return Event::Fault(Reason::EncoderFault(d));
            }
            if ctx.get(v.bridge_errors[d]) {
                return Event::Fault(Reason::BridgeError(d));
            }
            if ctx.get(v.following_errors[d]) {
                // Blocked while seeking a switch in INIT (a switch stuck off, say, leaves the
                // carriage at its hard stop): say which switch was not reached.
                let seeking = match self.machine.inner().searches[d] {
                    Search::Seek { end, .. } if state == MainState::Init => Some(end.switch(d)),
                    _ => None,
                };
                return Event::Fault(seeking.map_or(Reason::FollowingError(d), Reason::InitTimeout));
            }
        }
        if state != MainState::Init
            && let Some(i) = self.io.switches.iter().position(|s| *s)
        {
            return Event::Fault(Reason::LimitSwitch(i));
        }
        Event::Tick
    }

    fn write(&mut self, ctx: &mut Cycle<'_>) {
        let automaton = self.machine.inner();
        let (v, io) = (&self.vars, &self.io);
        ctx.set(v.state, automaton.state.code());
        ctx.set(v.reason, automaton.reason.map_or(0, Reason::code));
        ctx.set(v.enable, io.enable);
        for i in 0..2 {
            ctx.set(v.setpoints[i], io.setpoints[i]);
            ctx.set(v.velocities[i], io.velocities[i]);
            ctx.set(v.references[i], io.references[i]);
            ctx.set(v.clear_errors[i], io.acknowledge);
        }
        ctx.set(v.setpoint_time, io.now_s);
        ctx.set(v.acknowledge, io.acknowledge);
        ctx.set(v.period, self.machine.inner().p.pwm_period_us);
        ctx.set(v.referenced, io.referenced);
        let mut m = [f64::NAN; 2];
        if io.referenced && self.display.forward(&io.positions, None, &mut m).is_ok() {
            ctx.set(v.m[0], m[0]);
            ctx.set(v.m[1], m[1]);
        }
        self.shown = [
            ("Mx", m[0]),
            ("My", m[1]),
            ("h1", io.positions[0]),
            ("h2", io.positions[1]),
            // The joystick's axes; "-" while it is not connected.
            (
                "jx",
                if io.joystick_connected {
                    io.joystick[0]
                } else {
                    f64::NAN
                },
            ),
            (
                "jy",
                if io.joystick_connected {
                    io.joystick[1]
                } else {
                    f64::NAN
                },
            ),
        ];
    }
}

impl Program for MainProgram {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        self.read(ctx);
        let event = self.event(ctx);
        self.machine.handle_with_context(&event, &mut self.io);
        self.write(ctx);
    }

    fn status(&self) -> Option<AppStatus<'_>> {
        let a = self.machine.inner();
        Some(AppStatus {
            state: a.state.name(),
            reason: a.reason.map(Reason::text),
            values: &self.shown,
        })
    }
}
