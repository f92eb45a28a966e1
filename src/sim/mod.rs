//! The simulated machine: a plant model of the TRIJOINT lab model behind a simulated bus that
//! exchanges module channel images with the cycles, wired to the channels of the I/O map as the
//! real machine's harness is. Scenario files drive the operator panel and inject faults.

pub mod bus;
pub mod modbus;
pub mod pdu;
pub mod plant;
pub mod scenario;
pub mod server;

use serde::Deserialize;

use crate::config::{ConfigError, LoadedConfig};
use crate::image::{DeclIssue, VarType};
use crate::io::catalogue::Direction;
use crate::io::map::IoMap;

/// The `plant` section of config.json.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// Integration step (µs); cycles see the plant at their nominal start time.
    pub step_us: u32,
    /// The left drive (h1).
    pub left: plant::DriveParams,
    /// The right drive (h2).
    pub right: plant::DriveParams,
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
            left: plant::DriveParams::default(),
            right: plant::DriveParams::default(),
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

/// A signal of the machine, as wired.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Signal {
    /// A panel button (input to the PLC).
    Button(plant::Button),
    /// A limit switch (input).
    Switch(plant::DriveId, plant::SwitchEnd),
    /// An encoder counter (input).
    Encoder(plant::DriveId),
    /// A counter reset (output).
    CounterReset(plant::DriveId),
    /// A bridge's pulse width (output).
    Pwm(plant::DriveId),
    /// The bridges' period (output).
    PwmPeriod,
    /// A bridge's clear error (output).
    ClearError(plant::DriveId),
    /// A bridge's error status (input).
    BridgeError(plant::DriveId),
    /// A joystick axis, 0 = x, 1 = y (input).
    JoystickAxis(usize),
    /// Joystick connected (input).
    JoystickConnected,
}

/// A resolved harness: per signal, its (module, channel).
#[derive(Clone, Debug)]
pub struct ResolvedWiring {
    /// Every signal with its channel.
    pub signals: Vec<(Signal, (usize, usize))>,
}

impl Wiring {
    fn entries(&self) -> Vec<(&'static str, &str, Signal, Direction, VarType)> {
        use Direction::{Input as I, Output as O};
        use plant::{Button as B, SwitchEnd as E};
        vec![
            (
                "stop_button",
                &self.stop_button,
                Signal::Button(B::Stop),
                I,
                VarType::Bool,
            ),
            (
                "button_left",
                &self.button_left,
                Signal::Button(B::Left),
                I,
                VarType::Bool,
            ),
            (
                "button_right",
                &self.button_right,
                Signal::Button(B::Right),
                I,
                VarType::Bool,
            ),
            ("button_up", &self.button_up, Signal::Button(B::Up), I, VarType::Bool),
            (
                "button_down",
                &self.button_down,
                Signal::Button(B::Down),
                I,
                VarType::Bool,
            ),
            (
                "switch_left_upper",
                &self.switch_left_upper,
                Signal::Switch(0, E::Upper),
                I,
                VarType::Bool,
            ),
            (
                "switch_left_lower",
                &self.switch_left_lower,
                Signal::Switch(0, E::Lower),
                I,
                VarType::Bool,
            ),
            (
                "switch_right_upper",
                &self.switch_right_upper,
                Signal::Switch(1, E::Upper),
                I,
                VarType::Bool,
            ),
            (
                "switch_right_lower",
                &self.switch_right_lower,
                Signal::Switch(1, E::Lower),
                I,
                VarType::Bool,
            ),
            ("encoder_left", &self.encoder_left, Signal::Encoder(0), I, VarType::Int),
            (
                "encoder_right",
                &self.encoder_right,
                Signal::Encoder(1),
                I,
                VarType::Int,
            ),
            (
                "counter_reset_left",
                &self.counter_reset_left,
                Signal::CounterReset(0),
                O,
                VarType::Bool,
            ),
            (
                "counter_reset_right",
                &self.counter_reset_right,
                Signal::CounterReset(1),
                O,
                VarType::Bool,
            ),
            ("pwm_left", &self.pwm_left, Signal::Pwm(0), O, VarType::Int),
            ("pwm_right", &self.pwm_right, Signal::Pwm(1), O, VarType::Int),
            ("pwm_period", &self.pwm_period, Signal::PwmPeriod, O, VarType::Uint),
            (
                "clear_error_left",
                &self.clear_error_left,
                Signal::ClearError(0),
                O,
                VarType::Bool,
            ),
            (
                "clear_error_right",
                &self.clear_error_right,
                Signal::ClearError(1),
                O,
                VarType::Bool,
            ),
            (
                "bridge_error_left",
                &self.bridge_error_left,
                Signal::BridgeError(0),
                I,
                VarType::Bool,
            ),
            (
                "bridge_error_right",
                &self.bridge_error_right,
                Signal::BridgeError(1),
                I,
                VarType::Bool,
            ),
            (
                "joystick_x",
                &self.joystick_x,
                Signal::JoystickAxis(0),
                I,
                VarType::Real,
            ),
            (
                "joystick_y",
                &self.joystick_y,
                Signal::JoystickAxis(1),
                I,
                VarType::Real,
            ),
            (
                "joystick_connected",
                &self.joystick_connected,
                Signal::JoystickConnected,
                I,
                VarType::Bool,
            ),
        ]
    }

    /// Resolves every signal against the I/O map's modules; problems as (path below
    /// `plant.wiring`, message).
    pub fn resolve(&self, map: &IoMap) -> Result<ResolvedWiring, Vec<(String, String)>> {
        let mut signals = Vec::new();
        let mut problems = Vec::new();
        for (key, reference, signal, direction, ty) in self.entries() {
            match map.resolve(reference, direction, ty) {
                Ok(at) => {
                    if let Some((other, _)) = signals.iter().find(|(_, a)| *a == at) {
                        problems.push((key.to_string(), format!("{reference} is already wired to {other:?}")));
                    }
                    signals.push((signal, at));
                }
                Err(message) => problems.push((key.to_string(), message)),
            }
        }
        if problems.is_empty() {
            Ok(ResolvedWiring { signals })
        } else {
            Err(problems)
        }
    }
}

impl PlantConfig {
    /// Checks the parameters; problems as (path below `plant`, message).
    pub fn check(&self) -> Vec<(String, String)> {
        let mut problems = Vec::new();
        if self.step_us == 0 || self.step_us > 10_000 {
            problems.push(("step_us".into(), format!("must be 1 … 10000 µs, got {}", self.step_us)));
        }
        self.left.check("left", &mut problems);
        self.right.check("right", &mut problems);
        problems
    }
}

/// Builds the simulated machine for a loaded configuration: loads and checks its I/O map (relative
/// to the configuration file; the built-in configuration uses the built-in map), the plant
/// parameters and the wiring, and the scenario file if one is given.
pub fn build(
    loaded: &LoadedConfig,
    mechanism: &crate::tasks::kinematics::trijoint::TrijointParams,
    scenario: Option<&std::path::Path>,
) -> Result<bus::SimBus, ConfigError> {
    let config = &loaded.config;
    let invalid = |problems: Vec<(String, String)>, prefix: &str| ConfigError::Invalid {
        file: loaded.origin.clone(),
        problems: problems
            .into_iter()
            .map(|(at, message)| DeclIssue {
                at: format!("{prefix}{at}"),
                message,
            })
            .collect(),
    };
    let Some(map) = IoMap::load(loaded)? else {
        return Err(invalid(
            vec![("io_map".into(), "the simulated bus needs an I/O map".into())],
            "",
        ));
    };
    let problems = config.plant.check();
    if !problems.is_empty() {
        return Err(invalid(problems, "plant."));
    }
    let wiring = config
        .plant
        .wiring
        .resolve(&map)
        .map_err(|p| invalid(p, "plant.wiring."))?;
    let scenario = match scenario {
        None => scenario::Scenario::default(),
        Some(path) => {
            let origin = path.display().to_string();
            let text =
                crate::files::read_text(path, crate::files::MAX_TEXT_BYTES).map_err(|source| ConfigError::Read {
                    file: origin.clone(),
                    source,
                })?;
            scenario::Scenario::parse(&text, &origin, &map, &wiring)?
        }
    };
    let plant = plant::Plant::new(
        &config.plant.left,
        &config.plant.right,
        config.plant.mechanism.then_some(mechanism),
    );
    Ok(bus::SimBus::new(
        map,
        plant,
        wiring,
        scenario,
        u64::from(config.plant.step_us) * 1000,
    ))
}
