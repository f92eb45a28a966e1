//! The harness of a joint-driven machine: its signals (panel, switches, drives, joystick) in a
//! fixed order, what each is to the plant, and the default wiring to the module channels of the
//! machine's I/O map (panel and switches on 12-channel input modules `DI1`, `DI2` …; steppers on
//! two-channel modules `SM1`, `SM2` …; encoders on `DC1` … and bridges on `MM1` …).

use std::collections::BTreeMap;

use pkm_api::image::{Direction, VarType};
use pkm_api::machine::{Role, Signal};

use crate::spec::{DriveKind, Spec, SwitchLayout};

/// What a signal is to the plant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// A panel button, by index in [`PANEL`].
    Button(usize),
    /// A limit switch: the joint (`None`: shared by all) and the end (0 negative, 1 positive).
    Limit(Option<usize>, usize),
    /// A reference switch: the joint (`None`: shared by all).
    Reference(Option<usize>),
    /// A joint's counter (emitted steps or encoder counts).
    Counter(usize),
    /// A stepper channel's enable.
    Enable(usize),
    /// A stepper channel's speed set-point.
    Speed(usize),
    /// A bridge's pulse width.
    Pwm(usize),
    /// A bridge's clear error.
    ClearError(usize),
    /// A bridge's error status.
    BridgeError(usize),
    /// A bridge module's PWM period.
    PwmPeriod(usize),
    /// A joystick axis, 0 = x, 1 = y.
    JoystickAxis(usize),
    /// Joystick connected.
    JoystickConnected,
}

/// The panel's buttons' signal keys: STOP, the four directions, the axis button, the override;
/// then the program buttons (start, feed hold, resume), wired after the switches.
pub const PANEL: [&str; 11] = [
    "stop_button",
    "button_left",
    "button_right",
    "button_up",
    "button_down",
    "button_axes",
    "button_override",
    "program_start",
    "program_hold",
    "program_resume",
    // The manual tool change's confirmation (`TOOL_CHANGED`): the tool asked for is in.
    "tool_changed",
];

/// How many of [`PANEL`]'s buttons come before the switches (the original panel's).
const PANEL_BEFORE_SWITCHES: usize = 7;

macro_rules! keys {
    ($suffix:literal) => {
        [
            concat!("joint1_", $suffix),
            concat!("joint2_", $suffix),
            concat!("joint3_", $suffix),
            concat!("joint4_", $suffix),
            concat!("joint5_", $suffix),
            concat!("joint6_", $suffix),
        ]
    };
}

const LIMIT_NEG: [&str; 6] = keys!("limit_neg");
const LIMIT_POS: [&str; 6] = keys!("limit_pos");
const REFERENCE: [&str; 6] = keys!("reference");
const COUNTER: [&str; 6] = keys!("counter");
const ENABLE: [&str; 6] = keys!("enable");
const SPEED: [&str; 6] = keys!("speed");
const PWM: [&str; 6] = keys!("pwm");
const CLEAR_ERROR: [&str; 6] = keys!("clear_error");
const BRIDGE_ERROR: [&str; 6] = keys!("bridge_error");
const PWM_PERIOD: [&str; 3] = ["pwm_period1", "pwm_period2", "pwm_period3"];

/// The machine's signals and what each is, in wiring order, with each signal's default channel.
///
/// Long, and kept whole: a table, one entry per signal of the machine family.
pub fn signals(spec: &Spec) -> Vec<(Signal, Wire, String)> {
    use Direction::{Input as I, Output as O};
    use VarType::{Bool, Int, Real, Uint};
    let signal = |key, direction, ty, role| Signal {
        key,
        direction,
        ty,
        role,
    };
    let mut out = Vec::new();
    let mut inputs = 0usize;
    // Digital inputs fill 12-channel modules in order.
    let mut next_input = || {
        let (module, channel) = (inputs / 12 + 1, inputs % 12 + 1);
        inputs += 1;
        format!("DI{module}.DigitalInput{channel:02}")
    };
    for (i, key) in PANEL.iter().enumerate().take(PANEL_BEFORE_SWITCHES) {
        out.push((signal(*key, I, Bool, Role::Button), Wire::Button(i), next_input()));
    }
    let n = spec.joints();
    match spec.switches {
        SwitchLayout::Shared => {
            out.push((
                signal("limit_neg", I, Bool, Role::Switch),
                Wire::Limit(None, 0),
                next_input(),
            ));
            out.push((
                signal("limit_pos", I, Bool, Role::Switch),
                Wire::Limit(None, 1),
                next_input(),
            ));
            out.push((
                signal("reference", I, Bool, Role::Switch),
                Wire::Reference(None),
                next_input(),
            ));
        }
        SwitchLayout::PerJoint => {
            for j in 0..n {
                out.push((
                    signal(LIMIT_NEG[j], I, Bool, Role::Switch),
                    Wire::Limit(Some(j), 0),
                    next_input(),
                ));
                out.push((
                    signal(LIMIT_POS[j], I, Bool, Role::Switch),
                    Wire::Limit(Some(j), 1),
                    next_input(),
                ));
                out.push((
                    signal(REFERENCE[j], I, Bool, Role::Switch),
                    Wire::Reference(Some(j)),
                    next_input(),
                ));
            }
        }
    }
    for (i, key) in PANEL.iter().enumerate().skip(PANEL_BEFORE_SWITCHES) {
        out.push((signal(*key, I, Bool, Role::Button), Wire::Button(i), next_input()));
    }
    for j in 0..n {
        let (module, channel) = (j / 2 + 1, j % 2 + 1);
        match spec.drive {
            DriveKind::Stepper => {
                out.push((
                    signal(ENABLE[j], O, Bool, Role::Other),
                    Wire::Enable(j),
                    format!("SM{module}.Enable{channel:02}"),
                ));
                out.push((
                    signal(SPEED[j], O, Int, Role::Other),
                    Wire::Speed(j),
                    format!("SM{module}.SpeedSetpoint{channel:02}"),
                ));
                out.push((
                    signal(COUNTER[j], I, Int, Role::Other),
                    Wire::Counter(j),
                    format!("SM{module}.StepCounter{channel:02}"),
                ));
            }
            DriveKind::Dc => {
                out.push((
                    signal(COUNTER[j], I, Int, Role::Other),
                    Wire::Counter(j),
                    format!("DC{}.Counter01", j + 1),
                ));
                out.push((
                    signal(PWM[j], O, Int, Role::Other),
                    Wire::Pwm(j),
                    format!("MM{module}.PulseWidthCurrentPWM{channel:02}"),
                ));
                out.push((
                    signal(CLEAR_ERROR[j], O, Bool, Role::Other),
                    Wire::ClearError(j),
                    format!("MM{module}.ClearError{channel:02}"),
                ));
                out.push((
                    signal(BRIDGE_ERROR[j], I, Bool, Role::Other),
                    Wire::BridgeError(j),
                    format!("MM{module}.Error{channel:02}"),
                ));
            }
        }
    }
    if spec.drive == DriveKind::Dc {
        for (m, key) in PWM_PERIOD.iter().enumerate().take(n.div_ceil(2)) {
            out.push((
                signal(key, O, Uint, Role::Other),
                Wire::PwmPeriod(m),
                format!("MM{}.PeriodDurationPWM01", m + 1),
            ));
        }
    }
    out.push((
        signal("joystick_x", I, Real, Role::Other),
        Wire::JoystickAxis(0),
        "JOY.AxisX".into(),
    ));
    out.push((
        signal("joystick_y", I, Real, Role::Other),
        Wire::JoystickAxis(1),
        "JOY.AxisY".into(),
    ));
    out.push((
        signal("joystick_connected", I, Bool, Role::Other),
        Wire::JoystickConnected,
        "JOY.Connected".into(),
    ));
    out
}

/// The default wiring: every signal to its channel in the machine's I/O map.
pub fn default_wiring(spec: &Spec) -> BTreeMap<String, String> {
    signals(spec)
        .into_iter()
        .map(|(s, _, channel)| (s.key.to_string(), channel))
        .collect()
}
