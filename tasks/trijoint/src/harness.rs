//! The harness of the TRIJOINT lab model: the `plant` section of config.json (drive parameters,
//! integration step, and which module channel each signal of the machine is wired to) and the
//! table of the plant's signals in the order of [`SIGNALS`].

use pkm_api::image::{Direction, Value, VarType};
use pkm_api::machine::{Action, Role, Signal};
use pkm_api::problem::Problem;
use serde::Deserialize;

use crate::plant::{Button, DriveId, DriveParams, Plant, SwitchEnd};

/// The `plant` section of config.json.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// Integration step (µs); cycles see the plant at their nominal start time.
    pub step_us: u32,
    /// The left drive (h1).
    pub left: DriveParams,
    /// The right drive (h2).
    pub right: DriveParams,
    /// Whether the linkage jams at unassemblable carriage pairs (TRIJOINT geometry from the
    /// kinematics section).
    pub mechanism: bool,
    /// Which module channel each signal of the machine is wired to.
    pub wiring: Wiring,
}

impl Default for PlantConfig {
    fn default() -> Self {
        PlantConfig {
            step_us: 1000,
            left: DriveParams::default(),
            right: DriveParams::default(),
            mechanism: true,
            wiring: Wiring::default(),
        }
    }
}

/// The machine's harness: `MODULE.Channel` for every signal.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Wiring {
    /// The red STOP button.
    pub stop_button: String,
    /// Direction button left.
    pub button_left: String,
    /// Direction button right.
    pub button_right: String,
    /// Direction button up.
    pub button_up: String,
    /// Direction button down.
    pub button_down: String,
    /// Program start (NC_START).
    pub program_start: String,
    /// Feed hold (NC_HOLD).
    pub program_hold: String,
    /// Program resume (NC_RESUME).
    pub program_resume: String,
    /// Limit switch, left drive, upper end.
    pub switch_left_upper: String,
    /// Limit switch, left drive, lower end.
    pub switch_left_lower: String,
    /// Limit switch, right drive, upper end.
    pub switch_right_upper: String,
    /// Limit switch, right drive, lower end.
    pub switch_right_lower: String,
    /// Encoder counter, left drive.
    pub encoder_left: String,
    /// Encoder counter, right drive.
    pub encoder_right: String,
    /// Counter reset, left drive.
    pub counter_reset_left: String,
    /// Counter reset, right drive.
    pub counter_reset_right: String,
    /// Motor bridge pulse width, left drive.
    pub pwm_left: String,
    /// Motor bridge pulse width, right drive.
    pub pwm_right: String,
    /// Motor bridges' PWM period.
    pub pwm_period: String,
    /// Clear error, left bridge.
    pub clear_error_left: String,
    /// Clear error, right bridge.
    pub clear_error_right: String,
    /// Error status, left bridge.
    pub bridge_error_left: String,
    /// Error status, right bridge.
    pub bridge_error_right: String,
    /// Joystick x axis.
    pub joystick_x: String,
    /// Joystick y axis.
    pub joystick_y: String,
    /// Joystick connected.
    pub joystick_connected: String,
}

impl Default for Wiring {
    fn default() -> Self {
        let s = |v: &str| v.to_string();
        Wiring {
            stop_button: s("DI.DigitalInput01"),
            button_left: s("DI.DigitalInput02"),
            button_right: s("DI.DigitalInput03"),
            button_up: s("DI.DigitalInput04"),
            button_down: s("DI.DigitalInput05"),
            program_start: s("DI.DigitalInput10"),
            program_hold: s("DI.DigitalInput11"),
            program_resume: s("DI.DigitalInput12"),
            switch_left_upper: s("DI.DigitalInput06"),
            switch_left_lower: s("DI.DigitalInput07"),
            switch_right_upper: s("DI.DigitalInput08"),
            switch_right_lower: s("DI.DigitalInput09"),
            encoder_left: s("DC_LEFT.Counter01"),
            encoder_right: s("DC_RIGHT.Counter01"),
            counter_reset_left: s("DC_LEFT.CounterReset01"),
            counter_reset_right: s("DC_RIGHT.CounterReset01"),
            pwm_left: s("MM.PulseWidthCurrentPWM02"),
            pwm_right: s("MM.PulseWidthCurrentPWM01"),
            pwm_period: s("MM.PeriodDurationPWM01"),
            clear_error_left: s("MM.ClearError02"),
            clear_error_right: s("MM.ClearError01"),
            bridge_error_left: s("MM.Error02"),
            bridge_error_right: s("MM.Error01"),
            joystick_x: s("JOY.AxisX"),
            joystick_y: s("JOY.AxisY"),
            joystick_connected: s("JOY.Connected"),
        }
    }
}

impl PlantConfig {
    /// Checks the parameters; problems have their path below `plant`.
    pub fn check(&self) -> Vec<Problem> {
        let mut problems = Vec::new();
        if self.step_us == 0 || self.step_us > 10_000 {
            problems.push(Problem::new(
                "step_us",
                format!("must be 1 … 10000 µs, got {}", self.step_us),
            ));
        }
        self.left.check("left", &mut problems);
        self.right.check("right", &mut problems);
        problems
    }
}

/// What a signal is to the TRIJOINT plant, by the index of [`SIGNALS`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// A panel button (input to the PLC).
    Button(Button),
    /// A limit switch (input).
    Switch(DriveId, SwitchEnd),
    /// An encoder counter (input).
    Encoder(DriveId),
    /// A counter reset (output).
    CounterReset(DriveId),
    /// A bridge's pulse width (output).
    Pwm(DriveId),
    /// The bridges' period (output).
    PwmPeriod,
    /// A bridge's clear error (output).
    ClearError(DriveId),
    /// A bridge's error status (input).
    BridgeError(DriveId),
    /// A joystick axis, 0 = x, 1 = y (input).
    JoystickAxis(usize),
    /// Joystick connected (input).
    JoystickConnected,
}

const fn signal(key: &'static str, direction: Direction, ty: VarType, role: Role) -> Signal {
    Signal {
        key,
        direction,
        ty,
        role,
    }
}

use Direction::{Input as I, Output as O};
use VarType::{Bool, Int, Real, Uint};

/// The plant's signals, in wiring order (the order of the `plant.wiring` keys).
pub const SIGNALS: [Signal; 26] = [
    signal("stop_button", I, Bool, Role::Button),
    signal("button_left", I, Bool, Role::Button),
    signal("button_right", I, Bool, Role::Button),
    signal("button_up", I, Bool, Role::Button),
    signal("button_down", I, Bool, Role::Button),
    signal("program_start", I, Bool, Role::Button),
    signal("program_hold", I, Bool, Role::Button),
    signal("program_resume", I, Bool, Role::Button),
    signal("switch_left_upper", I, Bool, Role::Switch),
    signal("switch_left_lower", I, Bool, Role::Switch),
    signal("switch_right_upper", I, Bool, Role::Switch),
    signal("switch_right_lower", I, Bool, Role::Switch),
    signal("encoder_left", I, Int, Role::Other),
    signal("encoder_right", I, Int, Role::Other),
    signal("counter_reset_left", O, Bool, Role::Other),
    signal("counter_reset_right", O, Bool, Role::Other),
    signal("pwm_left", O, Int, Role::Other),
    signal("pwm_right", O, Int, Role::Other),
    signal("pwm_period", O, Uint, Role::Other),
    signal("clear_error_left", O, Bool, Role::Other),
    signal("clear_error_right", O, Bool, Role::Other),
    signal("bridge_error_left", I, Bool, Role::Other),
    signal("bridge_error_right", I, Bool, Role::Other),
    signal("joystick_x", I, Real, Role::Other),
    signal("joystick_y", I, Real, Role::Other),
    signal("joystick_connected", I, Bool, Role::Other),
];

/// What each of [`SIGNALS`] is to the plant, by the same index.
pub const WIRES: [Wire; 26] = {
    use Button as B;
    use SwitchEnd as E;
    [
        Wire::Button(B::Stop),
        Wire::Button(B::Left),
        Wire::Button(B::Right),
        Wire::Button(B::Up),
        Wire::Button(B::Down),
        Wire::Button(B::ProgramStart),
        Wire::Button(B::ProgramHold),
        Wire::Button(B::ProgramResume),
        Wire::Switch(0, E::Upper),
        Wire::Switch(0, E::Lower),
        Wire::Switch(1, E::Upper),
        Wire::Switch(1, E::Lower),
        Wire::Encoder(0),
        Wire::Encoder(1),
        Wire::CounterReset(0),
        Wire::CounterReset(1),
        Wire::Pwm(0),
        Wire::Pwm(1),
        Wire::PwmPeriod,
        Wire::ClearError(0),
        Wire::ClearError(1),
        Wire::BridgeError(0),
        Wire::BridgeError(1),
        Wire::JoystickAxis(0),
        Wire::JoystickAxis(1),
        Wire::JoystickConnected,
    ]
};

impl Wiring {
    /// The channel (`MODULE.Channel`) of each of [`SIGNALS`], by the same index.
    pub fn channels(&self) -> [&str; 26] {
        [
            &self.stop_button,
            &self.button_left,
            &self.button_right,
            &self.button_up,
            &self.button_down,
            &self.program_start,
            &self.program_hold,
            &self.program_resume,
            &self.switch_left_upper,
            &self.switch_left_lower,
            &self.switch_right_upper,
            &self.switch_right_lower,
            &self.encoder_left,
            &self.encoder_right,
            &self.counter_reset_left,
            &self.counter_reset_right,
            &self.pwm_left,
            &self.pwm_right,
            &self.pwm_period,
            &self.clear_error_left,
            &self.clear_error_right,
            &self.bridge_error_left,
            &self.bridge_error_right,
            &self.joystick_x,
            &self.joystick_y,
            &self.joystick_connected,
        ]
    }
}

/// The plant as the runtime sees it: its signals in the order of [`SIGNALS`], each read from or
/// written to the part of the model its wire leads to.
/// The drives' names in scenario files, by [`DriveId`].
const DRIVES: [&str; 2] = ["left", "right"];

impl pkm_api::machine::Plant for Plant {
    fn signals(&self) -> &[Signal] {
        &SIGNALS
    }

    fn drives(&self) -> &[&'static str] {
        &DRIVES
    }

    fn step(&mut self, dt_s: f64) {
        Plant::step(self, dt_s);
    }

    fn read(&self, signal: usize) -> Value {
        match WIRES[signal] {
            Wire::Button(b) => Value::Bool(self.button(b)),
            Wire::Switch(d, end) => Value::Bool(self.switch(d, end)),
            Wire::Encoder(d) => Value::Int(self.counter(d)),
            Wire::BridgeError(d) => Value::Bool(self.bridge_error(d)),
            Wire::JoystickAxis(a) => Value::Real(self.joystick()[a]),
            Wire::JoystickConnected => Value::Bool(self.joystick_connected()),
            // Outputs read back as the bus's zero: the runtime reads input signals only.
            Wire::CounterReset(_) | Wire::ClearError(_) => Value::Bool(false),
            Wire::Pwm(_) => Value::Int(0),
            Wire::PwmPeriod => Value::Uint(0),
        }
    }

    fn write(&mut self, signal: usize, value: Value) {
        match (WIRES[signal], value) {
            (Wire::Pwm(d), Value::Int(v)) => self.set_pwm(d, v),
            (Wire::PwmPeriod, Value::Uint(v)) => self.set_period(v),
            (Wire::ClearError(d), Value::Bool(v)) => self.set_clear_error(d, v),
            (Wire::CounterReset(d), Value::Bool(v)) => self.set_counter_reset(d, v),
            _ => {}
        }
    }

    fn apply(&mut self, action: Action) {
        match action {
            Action::Press { signal, pressed } => {
                if let Wire::Button(b) = WIRES[signal] {
                    self.set_button(b, pressed);
                }
            }
            Action::Joystick(x, y) => self.set_joystick(x, y),
            Action::StickSwitch { signal, stuck } => {
                if let Wire::Switch(d, end) = WIRES[signal] {
                    self.stick_switch(d, end, stuck);
                }
            }
            Action::EncoderGlitch { drive, counts } => self.encoder_glitch(drive, counts),
            Action::BridgeError { drive } => self.bridge_fault(drive),
            Action::DriveDead { drive, dead } => self.set_dead(drive, dead),
            Action::JoystickConnected(c) => self.set_joystick_connected(c),
        }
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn joints(&self) -> Vec<pkm_api::machine::JointTruth> {
        (0..DRIVES.len())
            .map(|d| pkm_api::machine::JointTruth {
                position_mm: self.position_mm(d),
                stepper: false,
                lost_steps: 0.0,
                stalls: 0,
            })
            .collect()
    }

    fn jams(&self) -> u64 {
        Plant::jams(self)
    }
}
