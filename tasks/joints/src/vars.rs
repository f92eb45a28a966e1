//! The process-image variables of the joint-driven machines, one typed constant (or a table of
//! six, indexed by joint from 0) each: the names of the I/O maps' bindings, the names the
//! programs exchange, and the observable names (`JOINTn_POSITION`, `TOOL_X` …).

use pkm_api::image::Var;

/// Six names `JOINT1_<suffix>` … `JOINT6_<suffix>` as typed variables.
macro_rules! joints {
    ($suffix:literal) => {
        [
            Var::new(concat!("JOINT1_", $suffix)),
            Var::new(concat!("JOINT2_", $suffix)),
            Var::new(concat!("JOINT3_", $suffix)),
            Var::new(concat!("JOINT4_", $suffix)),
            Var::new(concat!("JOINT5_", $suffix)),
            Var::new(concat!("JOINT6_", $suffix)),
        ]
    };
}

/// The red STOP button on the operator panel.
pub const BUTTON_STOP: Var<bool> = Var::new("BUTTON_STOP");
/// The joystick's own STOP button (an addition the I/O map may leave out).
pub const JOYSTICK_STOP: Var<bool> = Var::new("JOYSTICK_STOP");
/// The panel's direction buttons: left, right, up, down (the stick's −x, +x, +y, −y).
pub const BUTTONS: [Var<bool>; 4] = [
    Var::new("BUTTON_LEFT"),
    Var::new("BUTTON_RIGHT"),
    Var::new("BUTTON_UP"),
    Var::new("BUTTON_DOWN"),
];
/// The panel's axis button: each press selects the next pair of world axes the stick drives
/// (after referencing) or the next joint (joint mode, before it).
pub const BUTTON_AXES: Var<bool> = Var::new("BUTTON_AXES");
/// The joystick's button with the same function (optional in the I/O map).
pub const JOYSTICK_AXES: Var<bool> = Var::new("JOYSTICK_AXES");
/// The limit override: held, joint jog may move a joint off an active limit input (INIT only).
pub const BUTTON_OVERRIDE: Var<bool> = Var::new("BUTTON_OVERRIDE");
/// The joystick's axes, x and y (−1 … 1).
pub const JOYSTICK: [Var<f64>; 2] = [Var::new("JOYSTICK_X"), Var::new("JOYSTICK_Y")];
/// Whether the joystick is connected.
pub const JOYSTICK_CONNECTED: Var<bool> = Var::new("JOYSTICK_CONNECTED");
/// The bus's fault status (every bus provides it).
pub const BUS_FAULT: Var<bool> = Var::new(pkm_api::bus::BUS_FAULT);

/// pn101's shared inputs: every negative limit switch on one input, every positive one on a
/// second, every reference switch on a third (its parallel port had five inputs).
pub const SHARED_LIMIT: [Var<bool>; 2] = [Var::new("LIMIT_NEG"), Var::new("LIMIT_POS")];
/// pn101's shared reference input.
pub const SHARED_REFERENCE: Var<bool> = Var::new("REFERENCE");
/// Per-joint limit switches (negative end).
pub const LIMIT_NEG: [Var<bool>; 6] = joints!("LIMIT_NEG");
/// Per-joint limit switches (positive end).
pub const LIMIT_POS: [Var<bool>; 6] = joints!("LIMIT_POS");
/// Per-joint reference switches.
pub const REFERENCE: [Var<bool>; 6] = joints!("REFERENCE");

/// The drive's counter: a stepper module's emitted steps, or an encoder (16-bit, wrapping).
pub const COUNTER: [Var<i16>; 6] = joints!("COUNTER");
/// A stepper channel's enable.
pub const ENABLE: [Var<bool>; 6] = joints!("ENABLE");
/// A stepper channel's speed set-point (steps/s).
pub const SPEED: [Var<i16>; 6] = joints!("SPEED");
/// A motor bridge's pulse width (±32767 = ±100 % duty).
pub const PWM: [Var<i16>; 6] = joints!("PWM");
/// A motor bridge's error status.
pub const BRIDGE_ERROR: [Var<bool>; 6] = joints!("BRIDGE_ERROR");
/// A motor bridge's clear error.
pub const CLEAR_ERROR: [Var<bool>; 6] = joints!("CLEAR_ERROR");
/// The PWM period of bridge modules 1 … 3 (two bridges each; µs, 0 disables them).
pub const PWM_PERIOD: [Var<u16>; 3] = [
    Var::new("PWM_PERIOD1"),
    Var::new("PWM_PERIOD2"),
    Var::new("PWM_PERIOD3"),
];

/// Joint positions (mm; the drive program): measured, or for open-loop steppers the emitted
/// steps. Joint coordinates of the kinematics once referenced, from the power-on position
/// before.
pub const JOINT_POSITION: [Var<f64>; 6] = joints!("POSITION");
/// Joint position set-points (mm; the main program).
pub const SETPOINT: [Var<f64>; 6] = joints!("SETPOINT");
/// Joint velocity set-points (mm/s): the drive program moves the set-point on at this velocity
/// until the next main cycle.
pub const SETPOINT_VELOCITY: [Var<f64>; 6] = joints!("SETPOINT_VELOCITY");
/// Where joint zero lies on the drive's counted travel (mm from power-on), found by
/// referencing.
pub const OFFSET: [Var<f64>; 6] = joints!("OFFSET");
/// The position (mm from power-on) at the last rising edge of the joint's reference input:
/// a touch-probe capture in the fast class.
pub const CAPTURE: [Var<f64>; 6] = joints!("CAPTURE");
/// How many captures the joint's reference input made.
pub const CAPTURES: [Var<i32>; 6] = joints!("CAPTURES");
/// Following-error faults.
pub const FOLLOWING_ERROR: [Var<bool>; 6] = joints!("FOLLOWING_ERROR");
/// Encoder faults (a counter jump no joint can make).
pub const ENCODER_FAULT: [Var<bool>; 6] = joints!("ENCODER_FAULT");

/// The tool pose (mm, degrees; machine frame), forward kinematics of the joint positions.
pub const TOOL: [Var<f64>; 6] = [
    Var::new("TOOL_X"),
    Var::new("TOOL_Y"),
    Var::new("TOOL_Z"),
    Var::new("TOOL_A"),
    Var::new("TOOL_B"),
    Var::new("TOOL_C"),
];

/// The main state (`MainState::code`).
pub const MAIN_STATE: Var<i16> = Var::new("main_state");
/// The error reason's code (0: none).
pub const ERROR_REASON: Var<i16> = Var::new("error_reason");
/// The drives may move.
pub const DRIVES_ENABLE: Var<bool> = Var::new("drives_enable");
/// When the set-points were last written (s).
pub const SETPOINT_TIME_S: Var<f64> = Var::new("setpoint_time_s");
/// Whether the machine is referenced.
pub const REFERENCED: Var<bool> = Var::new("referenced");
/// Limit inputs do not stop the drives: joint jog with the override held in INIT.
pub const LIMIT_OVERRIDE: Var<bool> = Var::new("limit_override");
/// Acknowledges the drives' latched faults (REBOOT's pulse).
pub const FAULT_ACK: Var<bool> = Var::new("fault_ack");
/// What the stick drives: the world axis pair (after referencing) or the joint (before), from 0.
pub const JOG_SELECTION: Var<i16> = Var::new("jog_selection");
/// The fast interlock holds the drives (STOP, a limit input, a fault, a following error).
pub const INTERLOCK: Var<bool> = Var::new("interlock");
