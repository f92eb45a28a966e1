//! The process-image variables of the TRIJOINT application, one typed constant each: the names
//! of io-map/trijoint.json's bindings and of the variables the programs exchange. Arrays are
//! indexed by drive (0 = left, h1; 1 = right, h2) and, for switches, by end (0 = lower,
//! 1 = upper).

use pkm_api::image::Var;

/// The red STOP button on the operator panel.
pub const BUTTON_STOP: Var<bool> = Var::new("BUTTON_STOP");
/// The joystick's own STOP button (an addition the I/O map may leave out).
pub const JOYSTICK_STOP: Var<bool> = Var::new("JOYSTICK_STOP");
/// The panel's direction buttons: left, right, up, down.
pub const BUTTONS: [Var<bool>; 4] = [
    Var::new("BUTTON_LEFT"),
    Var::new("BUTTON_RIGHT"),
    Var::new("BUTTON_UP"),
    Var::new("BUTTON_DOWN"),
];
/// The joystick's axes, x and y (−1 … 1).
pub const JOYSTICK: [Var<f64>; 2] = [Var::new("JOYSTICK_X"), Var::new("JOYSTICK_Y")];
/// Whether the joystick is connected.
pub const JOYSTICK_CONNECTED: Var<bool> = Var::new("JOYSTICK_CONNECTED");
/// The bus's fault status (every bus provides it).
pub const BUS_FAULT: Var<bool> = Var::new(pkm_api::bus::BUS_FAULT);

/// The limit switches per drive, (lower, upper). The original program calls the lower ones
/// `…_DOWN`.
pub const SWITCHES: [[Var<bool>; 2]; 2] = [
    [Var::new("SWITCH_LEFT_DOWN"), Var::new("SWITCH_LEFT_UPPER")],
    [Var::new("SWITCH_RIGHT_DOWN"), Var::new("SWITCH_RIGHT_UPPER")],
];
/// The encoder counters (16-bit, wrapping).
pub const ENCODER_COUNTER: [Var<i16>; 2] = [Var::new("encoder_left_counter"), Var::new("encoder_right_counter")];
/// The motor bridges' error status.
pub const BRIDGE_ERROR: [Var<bool>; 2] = [Var::new("bridge_error_left"), Var::new("bridge_error_right")];

/// Unwrapped encoder counts (encoder program).
pub const COUNTS: [Var<i32>; 2] = [Var::new("counts_left"), Var::new("counts_right")];
/// Carriage positions (mm, encoder program).
pub const POSITION_MM: [Var<f64>; 2] = [Var::new("JOINT1_POSITION"), Var::new("JOINT2_POSITION")];
/// Carriage velocities (mm/s, encoder program).
pub const VELOCITY_MM_S: [Var<f64>; 2] = [Var::new("velocity_left_mm_s"), Var::new("velocity_right_mm_s")];
/// Encoder faults (a counter jump no carriage can make).
pub const ENCODER_FAULT: [Var<bool>; 2] = [Var::new("encoder_fault_left"), Var::new("encoder_fault_right")];
/// Positions captured at the switch edges, per drive and end (mm).
pub const CAPTURE_MM: [[Var<f64>; 2]; 2] = [
    [Var::new("capture_left_lower_mm"), Var::new("capture_left_upper_mm")],
    [Var::new("capture_right_lower_mm"), Var::new("capture_right_upper_mm")],
];
/// How many captures each switch edge made.
pub const CAPTURES: [[Var<i32>; 2]; 2] = [
    [Var::new("captures_left_lower"), Var::new("captures_left_upper")],
    [Var::new("captures_right_lower"), Var::new("captures_right_upper")],
];

/// The main state (`MainState::code`).
pub const MAIN_STATE: Var<i16> = Var::new("main_state");
/// The error reason's code (0: none).
pub const ERROR_REASON: Var<i16> = Var::new("error_reason");
/// The drives may move.
pub const DRIVES_ENABLE: Var<bool> = Var::new("drives_enable");
/// Position set-points (mm).
pub const SETPOINT_MM: [Var<f64>; 2] = [Var::new("setpoint_left_mm"), Var::new("setpoint_right_mm")];
/// Velocity set-points (mm/s).
pub const SETPOINT_MM_S: [Var<f64>; 2] = [Var::new("setpoint_left_mm_s"), Var::new("setpoint_right_mm_s")];
/// When the set-points were last written (s).
pub const SETPOINT_TIME_S: Var<f64> = Var::new("setpoint_time_s");
/// Reference offsets found by referencing (mm).
pub const REFERENCE_MM: [Var<f64>; 2] = [Var::new("reference_left_mm"), Var::new("reference_right_mm")];
/// Acknowledges encoder faults.
pub const ENCODER_FAULT_ACK: Var<bool> = Var::new("encoder_fault_ack");
/// The bridges' ClearError outputs.
pub const CLEAR_ERROR: [Var<bool>; 2] = [Var::new("clear_error_left"), Var::new("clear_error_right")];
/// The bridges' PWM period (µs; 0 disables them).
pub const PERIOD_DURATION: Var<u16> = Var::new("period_duration");
/// Whether the machine is referenced.
pub const REFERENCED: Var<bool> = Var::new("referenced");
/// The spindle point M (mm): x and y.
pub const M: [Var<f64>; 2] = [Var::new("TOOL_X"), Var::new("TOOL_Y")];

/// The PWM pulse widths (drive controller).
pub const VELOCITY_SET: [Var<i16>; 2] = [Var::new("velocity_left_set"), Var::new("velocity_right_set")];
/// Following-error faults (drive controller).
pub const FOLLOWING_ERROR: [Var<bool>; 2] = [Var::new("following_error_left"), Var::new("following_error_right")];
/// The fast interlock holds the drives (STOP or a switch).
pub const INTERLOCK: Var<bool> = Var::new("interlock");
