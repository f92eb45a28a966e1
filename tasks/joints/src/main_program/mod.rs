//! The main program (50 ms class) of a joint-driven machine: the REBOOT/INIT/READY/MOTION/ERROR
//! automaton with the STOP press-and-lockout rule and the limit-input rules of docs/trijoint.md,
//! referencing, joint jog before it and world jog after it, and the tool pose (forward
//! kinematics of the joint positions, machine frame) for traces and the status line.
//!
//! Every cycle dispatches one event: an accepted STOP press, else a supervision fault, else a
//! tick. A limit input is a fault in every operating state but INIT's joint mode, where the
//! operator jogs off it with the override held.

mod automaton;
mod jog;
mod reason;
mod referencing;

pub use automaton::{Automaton, Event, Io, Main, Phase};
pub use reason::Reason;

use automaton::Search;
use reason::ReasonTexts;

use pkm_api::hmi;
use pkm_api::image::{Declare, Input, Output};
use pkm_api::program::{AppStatus, Cycle, Program, ProgramArgs};
use pkm_api::ranges;
use pkm_drives::automaton::{MainState, StopButton, StopInputs, event as automaton_event};
use pkm_drives::nc::{self, RunState};
use pkm_kinematics::frame::{Home, MachineFrame};
use pkm_kinematics::{KinematicsConfig, MAX_DOF, Machine as Model};
use statig::prelude::*;

use crate::params::{self, MainParams};
use crate::spec::Spec;
use crate::switches::Switches;
use crate::vars;

/// The longest cycle the main program may run in (µs).
pub const MAX_MAIN_CYCLE_US: u32 = 100_000;

struct Vars {
    stop: StopInputs,
    bus_fault: Input<bool>,
    limits: Vec<Input<bool>>,
    buttons: [Input<bool>; 4],
    axes: Input<bool>,
    joystick_axes: Input<bool>,
    override_button: Input<bool>,
    stick: [Input<f64>; 2],
    stick_connected: Input<bool>,
    joints: Vec<JointVars>,
    state: Output<i16>,
    reason: Output<i16>,
    enable: Output<bool>,
    setpoint_time: Output<f64>,
    acknowledge: Output<bool>,
    referenced: Output<bool>,
    limit_override: Output<bool>,
    selection: Output<i16>,
    tool: Vec<Output<f64>>,
    nc: Option<NcVars>,
    hmi: HmiVars,
}

/// The operator screen's inputs (zero without a screen).
struct HmiVars {
    jog: [Input<f64>; 2],
    jog_axis: Input<i16>,
    axes: Input<bool>,
    nc: [Input<bool>; 3],
    /// Reference again (a press, taken in READY).
    reference: Input<bool>,
}

impl HmiVars {
    fn declare(decl: &mut Declare<'_>) -> HmiVars {
        HmiVars {
            jog: hmi::HMI_JOG.map(|v| decl.read_optional(v)),
            jog_axis: decl.read_optional(hmi::HMI_JOG_AXIS),
            axes: decl.read_optional(hmi::HMI_AXES),
            nc: hmi::HMI_NC.map(|v| decl.read_optional(v)),
            reference: decl.read_optional(hmi::HMI_REFERENCE),
        }
    }
}

/// The variables of program execution, declared when a program is loaded.
struct NcVars {
    /// The screen's request to load another of the run's programs.
    request: Input<i16>,
    /// The loaded program's number.
    program: Output<i16>,
    start: Input<bool>,
    hold: Input<bool>,
    resume: Input<bool>,
    state: Input<i16>,
    line: Input<i32>,
    pose: Vec<Input<f64>>,
    fault: Input<bool>,
    command: Output<i16>,
}

/// One joint's variables.
struct JointVars {
    reference: Input<bool>,
    position: Input<f64>,
    capture: Input<f64>,
    captures: Input<i32>,
    encoder_fault: Input<bool>,
    bridge_error: Option<Input<bool>>,
    following_error: Input<bool>,
    setpoint: Output<f64>,
    velocity: Output<f64>,
    offset: Output<f64>,
}

/// The values the main program shows: the program line, the tool pose and the joints — all of
/// them, whatever the machine (the runtime keeps room for every one).
const SHOWN: usize = 1 + 2 * MAX_DOF;
const _: () = assert!(SHOWN <= pkm_api::program::MAX_STATUS_VALUES);

/// The main program.
pub struct MainProgram {
    machine: StateMachine<Automaton>,
    io: Io,
    vars: Vars,
    n: usize,
    stop: StopButton,
    axes_was_pressed: bool,
    /// The screen's Reference as the last cycle saw it (a press is its rising edge).
    reference_was_pressed: bool,
    texts: ReasonTexts,
    /// The tool pose from the last cycle (machine frame), the Newton start of the next.
    tool: [f64; MAX_DOF],
    /// Tool pose and joints for the status line: at most 12 values.
    shown: [(&'static str, f64); SHOWN],
    shown_len: usize,
    /// The reason with the program line executing when ERROR was entered from AUTO.
    line_reason: nc::LineReason,
}

/// The pose coordinates' names on the status line.
const POSE_NAMES: [&str; 6] = ["x", "y", "z", "a", "b", "c"];
/// The joints' names on the status line.
const JOINT_NAMES: [&str; 6] = ["q1", "q2", "q3", "q4", "q5", "q6"];

/// Checks the main parameters against the machine and its kinematics: every number within its
/// range of [`pkm_api::ranges`], the lists as long as the machine needs.
fn check(spec: &Spec, p: &MainParams, keys: &[&str], travel: &[[f64; 2]], decl: &mut Declare<'_>) {
    decl.within(
        "params.stop_lockout_ms",
        p.stop_lockout_ms as f64,
        &ranges::STOP_LOCKOUT_MS,
    );
    check_joints(spec, p, travel, decl);
    check_reference_order(spec, p, decl);
    check_limits(p, keys, travel, decl);
    check_jog(spec, p, keys, decl);
}

/// One entry per joint: its speed, acceleration and referencing.
fn check_joints(spec: &Spec, p: &MainParams, travel: &[[f64; 2]], decl: &mut Declare<'_>) {
    let n = spec.joints();
    if p.joints.len() != n {
        decl.issue(
            "params.joints",
            format!("{} has {n} joints; got {}", spec.name, p.joints.len()),
        );
    }
    for (i, j) in p.joints.iter().enumerate() {
        let at = |k: &str| format!("params.joints[{i}].{k}");
        let r = &j.reference;
        decl.within(&at("max_speed_mm_s"), j.max_speed_mm_s, &ranges::SPEED_MM_S);
        decl.within(&at("max_accel_mm_s2"), j.max_accel_mm_s2, &ranges::ACCEL_MM_S2);
        decl.within(
            &at("reference.search_speed_mm_s"),
            r.search_speed_mm_s,
            &ranges::SPEED_MM_S.up_to_within(j.max_speed_mm_s),
        );
        decl.within(
            &at("reference.latch_speed_mm_s"),
            r.latch_speed_mm_s,
            &ranges::SLOW_SPEED_MM_S,
        );
        decl.within(&at("reference.back_off_mm"), r.back_off_mm, &ranges::SEARCH_DISTANCE_MM);
        if r.direction.abs() != 1.0 {
            decl.issue(
                &at("reference.direction"),
                format!("must be 1 or -1, got {}", r.direction),
            );
        }
        if r.latch_speed_mm_s > r.search_speed_mm_s {
            decl.issue(
                &at("reference.latch_speed_mm_s"),
                format!(
                    "must not exceed search_speed_mm_s ({}), got {}",
                    r.search_speed_mm_s, r.latch_speed_mm_s
                ),
            );
        }
        if let Some([lo, hi]) = travel.get(i)
            && !(*lo..=*hi).contains(&r.switch_mm)
        {
            decl.issue(
                &at("reference.switch_mm"),
                format!("must lie within the joint's travel {lo} … {hi} mm, got {}", r.switch_mm),
            );
        }
    }
}

/// Every joint referenced once, in groups a shared reference input allows.
fn check_reference_order(spec: &Spec, p: &MainParams, decl: &mut Declare<'_>) {
    let n = spec.joints();
    let mut seen = vec![false; n];
    let shared = Switches::of(spec).shared();
    for (g, group) in p.reference_order.iter().enumerate() {
        for &joint in group {
            if joint == 0 || joint > n {
                decl.issue(
                    &format!("params.reference_order[{g}]"),
                    format!("joints are numbered 1 … {n}, got {joint}"),
                );
            } else if std::mem::replace(&mut seen[joint - 1], true) {
                decl.issue(
                    &format!("params.reference_order[{g}]"),
                    format!("joint {joint} is referenced twice"),
                );
            }
        }
        if shared && group.len() > 1 {
            decl.issue(
                &format!("params.reference_order[{g}]"),
                format!(
                    "{}'s joints share one reference input: only one joint at a time can say it reached its switch, so each group holds one joint; got {group:?}",
                    spec.name
                ),
            );
        }
    }
    if let Some(missing) = seen.iter().position(|s| !s) {
        decl.issue(
            "params.reference_order",
            format!("joint {} is never referenced", missing + 1),
        );
    }
}

/// The search's time, the software limits' margin, the world's limits (holding the reference
/// pose) and the singularity threshold.
fn check_limits(p: &MainParams, keys: &[&str], travel: &[[f64; 2]], decl: &mut Declare<'_>) {
    decl.within("params.search_timeout_s", p.search_timeout_s, &ranges::TIMEOUT_S);
    let shortest = travel.iter().map(|[lo, hi]| hi - lo).fold(f64::INFINITY, f64::min);
    decl.within(
        "params.soft_limit_margin_mm",
        p.soft_limit_margin_mm,
        &ranges::SOFT_LIMIT_MARGIN_MM.up_to(shortest / 4.0),
    );
    if p.world_limits.len() != keys.len() {
        decl.issue(
            "params.world_limits",
            format!(
                "one [min, max] per pose coordinate ({}); got {}",
                keys.join(", "),
                p.world_limits.len()
            ),
        );
    }
    for (i, ([lo, hi], key)) in p.world_limits.iter().zip(keys).enumerate() {
        let range = if ranges::is_rotation(key) {
            ranges::ANGLE_DEG
        } else {
            ranges::POSITION_MM
        };
        let at = format!("params.world_limits[{i}]");
        let inside = decl.within(&format!("{at}[0]"), *lo, &range) & decl.within(&format!("{at}[1]"), *hi, &range);
        if inside && lo >= hi {
            decl.issue(&at, format!("must be [min, max] with min < max, got [{lo}, {hi}]"));
        } else if inside && !(*lo..=*hi).contains(&0.0) {
            // The machine frame's origin is the reference pose: where referencing leaves the tool.
            decl.issue(
                &at,
                format!(
                    "must hold the reference pose, {key} = 0 (the machine frame's origin, where referencing leaves the tool), got [{lo}, {hi}]"
                ),
            );
        }
    }
    decl.within(
        "params.singularity_threshold",
        p.singularity_threshold,
        &ranges::SINGULARITY_THRESHOLD,
    );
}

/// The jog's speeds, acceleration, dead zone and the stick's pairs of world axes.
fn check_jog(spec: &Spec, p: &MainParams, keys: &[&str], decl: &mut Declare<'_>) {
    let jog = &p.jog;
    decl.within(
        "params.jog.linear_speed_mm_s",
        jog.linear_speed_mm_s,
        &ranges::SPEED_MM_S,
    );
    decl.within("params.jog.accel_mm_s2", jog.accel_mm_s2, &ranges::ACCEL_MM_S2);
    decl.within("params.jog.joint_speed_mm_s", jog.joint_speed_mm_s, &ranges::SPEED_MM_S);
    // Checked on every machine: one without rotations ignores it (0 there says so), but its
    // file gives it.
    let angular = if keys.iter().any(|k| ranges::is_rotation(k)) {
        ranges::ANGULAR_SPEED_DEG_S
    } else {
        ranges::ANGULAR_SPEED_DEG_S.from(0.0)
    };
    decl.within("params.jog.angular_speed_deg_s", jog.angular_speed_deg_s, &angular);
    decl.within("params.jog.dead_zone", jog.dead_zone, &ranges::DEAD_ZONE);
    if jog.axis_pairs.is_empty() {
        decl.issue(
            "params.jog.axis_pairs",
            "needs at least one pair of world axes for the stick",
        );
    }
    for (i, pair) in jog.axis_pairs.iter().enumerate() {
        for k in pair {
            if !keys.contains(&k.as_str()) {
                decl.issue(
                    &format!("params.jog.axis_pairs[{i}]"),
                    format!(
                        "\"{k}\" is not a world axis of {}; its axes are {}",
                        spec.name,
                        keys.join(", ")
                    ),
                );
            }
        }
        if pair[0] == pair[1] {
            decl.issue(
                &format!("params.jog.axis_pairs[{i}]"),
                format!("names \"{}\" twice", pair[0]),
            );
        }
    }
}

impl MainProgram {
    /// Declares the program's variables for `spec`.
    pub fn create(spec: &'static Spec, args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p = params::parse(args, decl, spec.default_main());
        let kinematics = args
            .kinematics
            .and_then(|k| serde_json::from_value::<KinematicsConfig>(k.clone()).ok())
            .unwrap_or_default();
        let kin = kinematics.build(spec.model);
        let keys: &'static [&'static str] = kin.pose_keys();
        let travel: Vec<[f64; 2]> = kin.joint_limits().to_vec();
        check(spec, &p, keys, &travel, decl);
        if args.cycle_us > MAX_MAIN_CYCLE_US {
            decl.issue(
                "program",
                format!(
                    "{} runs in a class of {} ms; at most {} ms: STOP, limit inputs and faults become ERROR in its cycle",
                    spec.programs[1].name,
                    args.cycle_us / 1000,
                    MAX_MAIN_CYCLE_US / 1000
                ),
            );
        }
        let n = spec.joints();
        let home = match spec.model {
            Model::Hexapod => Home::Pose(&kinematics.hexapod.home),
            _ => Home::Joints(&[0.0; MAX_DOF]),
        };
        let frame = MachineFrame::new(kin, home).unwrap_or_else(|e| {
            decl.issue(
                "program",
                format!("the machine's home is not a pose of its kinematics: {e}"),
            );
            default_frame(spec)
        });
        let margin = p.soft_limit_margin_mm;
        let mut soft = [[0.0; 2]; MAX_DOF];
        for (s, [lo, hi]) in soft.iter_mut().zip(&travel) {
            *s = [lo + margin, hi - margin];
        }
        let pairs: Vec<[usize; 2]> = p
            .jog
            .axis_pairs
            .iter()
            .filter_map(|[a, b]| Some([keys.iter().position(|k| k == a)?, keys.iter().position(|k| k == b)?]))
            .collect();
        let switches = Switches::of(spec);
        let texts = ReasonTexts::new(n, &switches);
        let dc = spec.drive == crate::spec::DriveKind::Dc;
        let joints = (0..n)
            .map(|j| JointVars {
                reference: decl.read(switches.reference(j)),
                position: decl.read(vars::JOINT_POSITION[j]),
                capture: decl.read(vars::CAPTURE[j]),
                captures: decl.read(vars::CAPTURES[j]),
                encoder_fault: decl.read(vars::ENCODER_FAULT[j]),
                bridge_error: dc.then(|| decl.read(vars::BRIDGE_ERROR[j])),
                following_error: decl.read(vars::FOLLOWING_ERROR[j]),
                setpoint: decl.write(vars::SETPOINT[j], 0.0),
                velocity: decl.write(vars::SETPOINT_VELOCITY[j], 0.0),
                offset: decl.write(vars::OFFSET[j], 0.0),
            })
            .collect();
        let vars = Vars {
            stop: StopInputs::declare(decl, vars::BUTTON_STOP, vars::JOYSTICK_STOP),
            bus_fault: decl.read(vars::BUS_FAULT),
            limits: switches.limits().iter().map(|l| decl.read(l.var)).collect(),
            buttons: vars::BUTTONS.map(|b| decl.read(b)),
            axes: decl.read(vars::BUTTON_AXES),
            joystick_axes: decl.read_optional(vars::JOYSTICK_AXES),
            override_button: decl.read(vars::BUTTON_OVERRIDE),
            stick: vars::JOYSTICK.map(|v| decl.read(v)),
            stick_connected: decl.read(vars::JOYSTICK_CONNECTED),
            joints,
            state: decl.write(vars::MAIN_STATE, MainState::Reboot.code()),
            reason: decl.write(vars::ERROR_REASON, 0),
            enable: decl.write(vars::DRIVES_ENABLE, false),
            setpoint_time: decl.write(vars::SETPOINT_TIME_S, 0.0),
            acknowledge: decl.write(vars::FAULT_ACK, false),
            referenced: decl.write(vars::REFERENCED, false),
            limit_override: decl.write(vars::LIMIT_OVERRIDE, false),
            selection: decl.write(vars::JOG_SELECTION, 0),
            tool: vars::TOOL[..keys.len()].iter().map(|v| decl.write(*v, 0.0)).collect(),
            nc: args.nc.map(|_| NcVars {
                request: decl.read_optional(hmi::HMI_NC_PROGRAM),
                program: decl.write(nc::vars::NC_PROGRAM, 1),
                start: decl.read_optional(nc::vars::NC_START),
                hold: decl.read_optional(nc::vars::NC_HOLD),
                resume: decl.read_optional(nc::vars::NC_RESUME),
                state: decl.read(nc::vars::NC_STATE),
                line: decl.read(nc::vars::NC_LINE),
                pose: nc::vars::NC_POSE[..keys.len()].iter().map(|v| decl.read(*v)).collect(),
                fault: decl.read(nc::vars::NC_FAULT),
                command: decl.write(nc::vars::NC_COMMAND, nc::Command::Off as i16),
            }),
            hmi: HmiVars::declare(decl),
        };
        let stop = StopButton::new(p.stop_lockout_ms as f64 * 1e-3);
        let main = Main::new(p, frame, soft, pairs, Switches::of(spec).shared());
        let io = Io {
            program: nc::ProgramControl::of(args.nc),
            ..Io::default()
        };
        Box::new(MainProgram {
            machine: Automaton::new(main).state_machine(),
            io,
            vars,
            n,
            stop,
            axes_was_pressed: false,
            reference_was_pressed: false,
            texts,
            tool: [0.0; MAX_DOF],
            shown: [("", f64::NAN); SHOWN],
            shown_len: 0,
            line_reason: nc::LineReason::default(),
        })
    }
}

/// The machine frame of `spec` with the default kinematics, whose home is a pose by
/// construction (the kinematics tests check it).
fn default_frame(spec: &Spec) -> MachineFrame {
    MachineFrame::default_for(spec.model).unwrap_or_else(|e| {
        panic!(
            "{}'s default home is not a pose of its default kinematics: {e}",
            spec.name
        )
    })
}

impl MainProgram {
    /// Reads the inputs into `io` and advances the set-points to where the drive program has
    /// taken them since the last cycle.
    fn read(&mut self, ctx: &Cycle<'_>) {
        let (v, io) = (&self.vars, &mut self.io);
        io.now_s = ctx.time_ns() as f64 * 1e-9;
        io.dt_s = ctx.period_ns() as f64 * 1e-9;
        for (j, jv) in v.joints.iter().enumerate() {
            io.positions[j] = ctx.get(jv.position);
            io.captures[j] = ctx.get(jv.capture);
            io.capture_counts[j] = ctx.get(jv.captures);
            io.reference_on[j] = ctx.get(jv.reference);
            io.setpoints[j] += io.velocities[j] * io.dt_s;
        }
        io.limit_active = v.limits.iter().any(|l| ctx.get(*l));
        io.stick = v.stick.map(|s| ctx.get(s));
        io.stick_connected = ctx.get(v.stick_connected);
        // The screen's jog, while held, in place of the stick.
        let screen = v.hmi.jog.map(|j| ctx.get(j));
        io.screen_jog = screen != [0.0; 2];
        (io.screen_axis, io.screen_joint) = (0, 0);
        if io.screen_jog {
            io.stick = screen;
            io.stick_connected = true;
            let axis = ctx
                .get(v.hmi.jog_axis)
                .clamp(*hmi::JOG_AXIS_RANGE.start(), *hmi::JOG_AXIS_RANGE.end());
            io.screen_axis = axis.max(0).unsigned_abs() as usize;
            io.screen_joint = axis.min(0).unsigned_abs() as usize;
        }
        io.buttons = v.buttons.map(|b| ctx.get(b));
        io.override_held = ctx.get(v.override_button);
        let axes = ctx.get(v.axes) || ctx.get(v.joystick_axes) || ctx.get(v.hmi.axes);
        io.axes_pressed = axes && !self.axes_was_pressed;
        self.axes_was_pressed = axes;
        if let Some(nc) = &v.nc {
            let auto = self.machine.inner().state == MainState::Auto;
            io.program.select(ctx.get(nc.request), auto);
            let screen = v.hmi.nc.map(|b| ctx.get(b));
            io.program.buttons([
                ctx.get(nc.start) || screen[0],
                ctx.get(nc.hold) || screen[1],
                ctx.get(nc.resume) || screen[2],
            ]);
            io.nc_state = RunState::from_code(ctx.get(nc.state));
            io.nc_line = ctx.get(nc.line);
            for (p, input) in io.nc_pose.iter_mut().zip(&nc.pose) {
                *p = ctx.get(*input);
            }
        }
    }

    /// The event of this cycle (the shared rule; this machine's supervision faults in order).
    fn event(&mut self, ctx: &Cycle<'_>) -> Event {
        let v = &self.vars;
        let automaton = self.machine.inner();
        let state = automaton.state;
        let app = &automaton.app;
        let pressed = v.stop.pressed(ctx);
        let asked = ctx.get(v.hmi.reference);
        let reference = asked && !self.reference_was_pressed;
        self.reference_was_pressed = asked;
        automaton_event(&mut self.stop, pressed, reference, self.io.now_s, state, || {
            if ctx.violation().is_some() {
                return Some(Reason::CycleTimeViolation);
            }
            if ctx.get(v.bus_fault) {
                return Some(Reason::BusFault);
            }
            if v.nc.as_ref().is_some_and(|nc| ctx.get(nc.fault)) {
                return Some(Reason::ProgramFault);
            }
            for (j, jv) in v.joints.iter().enumerate() {
                if ctx.get(jv.encoder_fault) {
                    return Some(Reason::EncoderFault(j));
                }
                if jv.bridge_error.is_some_and(|b| ctx.get(b)) {
                    return Some(Reason::BridgeError(j));
                }
                if ctx.get(jv.following_error) {
                    // While seeking its switch in INIT a following error says the joint lags its
                    // set-point: blocked (at its hard stop, by a switch that never came), or its
                    // drive or the link too slow. Named as such, not as a switch not reached.
                    let seeking = state == MainState::Init && matches!(app.searches[j], Search::Seek { .. });
                    return Some(if seeking {
                        Reason::InitFollowingError(j)
                    } else {
                        Reason::FollowingError(j)
                    });
                }
            }
            // A limit input is a fault except in INIT's joint mode, where the operator jogs off it.
            let joint_mode = state == MainState::Init && app.phase == Phase::Waiting;
            // Wherever the joints move by positions believed known (INIT's return and search in
            // the last referencing's frame, world mode), the reference switches check them: a
            // position a fault falsified (a stepper's lost steps) stops the machine at the
            // switch, before it searches, returns or jogs blind into a limit switch.
            if !joint_mode
                && state.operating()
                && let Some(j) = app.contradiction(&self.io)
            {
                return Some(Reason::ReferenceContradicts(j));
            }
            if joint_mode {
                return None;
            }
            v.limits.iter().position(|l| ctx.get(*l)).map(Reason::Limit)
        })
    }

    fn write(&mut self, ctx: &mut Cycle<'_>) {
        let automaton = self.machine.inner();
        let app = &automaton.app;
        let (v, io, n) = (&self.vars, &self.io, self.n);
        ctx.set(v.state, automaton.state.code());
        ctx.set(v.reason, automaton.reason.map_or(0, Reason::code));
        ctx.set(v.enable, io.enable);
        for (j, jv) in v.joints.iter().enumerate() {
            ctx.set(jv.setpoint, io.setpoints[j]);
            ctx.set(jv.velocity, io.velocities[j]);
            ctx.set(jv.offset, io.offsets[j]);
        }
        ctx.set(v.setpoint_time, io.now_s);
        ctx.set(v.acknowledge, io.acknowledge);
        ctx.set(v.referenced, io.referenced);
        ctx.set(v.limit_override, io.limit_override);
        ctx.set(v.selection, app.selection as i16);
        if let (Some(nc), Some(command)) = (&v.nc, io.program.command()) {
            ctx.set(nc.command, command as i16);
            ctx.set(nc.program, io.program.number());
        }
        let coords = v.tool.len();
        let mut shown = 0;
        if automaton.state == MainState::Auto {
            self.shown[shown] = ("line", f64::from(io.nc_line));
            shown += 1;
        }
        if io.referenced {
            let mut pose = [0.0; MAX_DOF];
            let hint = self.tool;
            if app
                .frame
                .forward(&io.positions[..n], Some(&hint[..n]), &mut pose[..n])
                .is_ok()
            {
                self.tool = pose;
                for (c, out) in v.tool.iter().enumerate() {
                    ctx.set(*out, pose[c]);
                }
            }
            for (name, value) in POSE_NAMES.iter().zip(&self.tool).take(coords) {
                self.shown[shown] = (name, *value);
                shown += 1;
            }
        }
        for (name, value) in JOINT_NAMES.iter().zip(&io.positions).take(n) {
            self.shown[shown] = (name, *value);
            shown += 1;
        }
        self.shown_len = shown;
    }
}

impl MainProgram {
    /// What INIT waits for, while it waits in joint mode; where the program stands in AUTO; why
    /// a start was refused in READY.
    fn note(&self) -> Option<&'static str> {
        let a = self.machine.inner();
        if matches!(a.state, MainState::Auto | MainState::Ready) {
            return self.io.program.note(a.state == MainState::Auto, self.io.nc_state);
        }
        if a.state != MainState::Init || a.app.phase != Phase::Waiting {
            return None;
        }
        if self.io.screen_jog {
            return Some(
                "the screen jogs once the machine is referenced; in joint mode, jog from the panel with BUTTON_OVERRIDE held",
            );
        }
        Some(match (self.io.limit_active, self.io.override_held) {
            (true, false) => "a limit input is active: hold BUTTON_OVERRIDE and jog the joint off it",
            (true, true) => "joint mode, limits overridden: jog the selected joint off the limit",
            (false, true) => "joint mode: release BUTTON_OVERRIDE to reference",
            (false, false) => "referencing starts once the joints are at rest",
        })
    }
}

impl Program for MainProgram {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        self.read(ctx);
        let event = self.event(ctx);
        let before = self.machine.inner().state;
        self.machine.handle_with_context(&event, &mut self.io);
        // The program line executing goes with an ERROR's reason.
        let a = self.machine.inner();
        let reason = a.reason.map(|r| self.texts.text(r));
        self.line_reason.observe(before, a.state, reason, self.io.nc_line);
        self.write(ctx);
    }

    fn status(&self) -> Option<AppStatus<'_>> {
        let a = self.machine.inner();
        Some(AppStatus {
            state: a.state.name(),
            reason: a.reason.map(|r| self.line_reason.text(self.texts.text(r))),
            note: self.note(),
            values: &self.shown[..self.shown_len],
        })
    }
}
