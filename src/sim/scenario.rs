//! Scenario files: timed operator actions and fault injections for the simulated machine.
//!
//! ```json
//! {"events": [
//!   {"at_ms": 1000, "input": "BUTTON_STOP", "value": true},
//!   {"at_ms": 1200, "input": "BUTTON_STOP", "value": false},
//!   {"at_ms": 2000, "joystick": [0.5, -0.2]},
//!   {"at_ms": 3000, "fault": "switch_stuck", "switch": "SWITCH_LEFT_UPPER", "value": true},
//!   {"at_ms": 4000, "fault": "encoder_glitch", "drive": "left", "counts": 500}
//! ]}
//! ```
//!
//! Inputs and switches are named by the process-image variable they are bound to in the I/O map.

use serde::Deserialize;

use super::plant::{Button, DriveId, Plant, SwitchEnd};
use super::{ResolvedWiring, Signal};
use crate::config::{self, ConfigError};
use crate::image::DeclIssue;
use crate::io::catalogue::Direction;
use crate::io::map::IoMap;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioFile {
    events: Vec<EventEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct EventEntry {
    at_ms: u64,
    #[serde(default)]
    input: Option<String>,
    #[serde(default)]
    value: Option<bool>,
    #[serde(default)]
    joystick: Option<[f64; 2]>,
    #[serde(default)]
    fault: Option<FaultKind>,
    #[serde(default)]
    switch: Option<String>,
    #[serde(default)]
    drive: Option<DriveName>,
    #[serde(default)]
    counts: Option<i64>,
}

/// The fault kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// A limit switch stuck at `value` (true: on, false: off).
    SwitchStuck,
    /// A stuck limit switch works again.
    SwitchFree,
    /// The encoder counter of `drive` jumps by `counts`.
    EncoderGlitch,
    /// The motor bridge of `drive` latches an error (overcurrent); ClearError resets it.
    BridgeError,
    /// The drive stops responding to PWM, without any error shown.
    DriveDead,
    /// A dead drive responds again.
    DriveAlive,
    /// The joystick is unplugged.
    JoystickUnplugged,
    /// The joystick is plugged in again.
    JoystickPlugged,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum DriveName {
    Left,
    Right,
}

/// What an event does to the plant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// Press (true) or release a panel button.
    Button(Button, bool),
    /// Set the joystick's axes.
    Joystick(f64, f64),
    /// Stick a switch (`Some`) or free it (`None`).
    StickSwitch(DriveId, SwitchEnd, Option<bool>),
    /// Encoder counter jump.
    EncoderGlitch(DriveId, i64),
    /// Bridge error.
    BridgeError(DriveId),
    /// Drive stops (true) or resumes (false) responding.
    DriveDead(DriveId, bool),
    /// Joystick plugged (true) or unplugged.
    JoystickConnected(bool),
}

impl Action {
    /// Applies the action to the plant.
    pub fn apply(self, plant: &mut Plant) {
        match self {
            Action::Button(b, on) => plant.set_button(b, on),
            Action::Joystick(x, y) => plant.set_joystick(x, y),
            Action::StickSwitch(d, e, s) => plant.stick_switch(d, e, s),
            Action::EncoderGlitch(d, n) => plant.encoder_glitch(d, n),
            Action::BridgeError(d) => plant.bridge_fault(d),
            Action::DriveDead(d, dead) => plant.set_dead(d, dead),
            Action::JoystickConnected(c) => plant.set_joystick_connected(c),
        }
    }
}

/// A parsed scenario: actions in time order.
#[derive(Clone, Debug, Default)]
pub struct Scenario {
    /// (time in ns, action), sorted by time; events at the same time keep their file order.
    pub events: Vec<(u64, Action)>,
}

/// The signal that the variable `name` is bound to through the I/O map and the wiring.
fn signal_of(name: &str, map: &IoMap, wiring: &ResolvedWiring) -> Option<Signal> {
    let b = map
        .bindings
        .iter()
        .find(|b| b.variable == name && b.direction == Direction::Input)?;
    wiring
        .signals
        .iter()
        .find(|(_, at)| *at == (b.module, b.channel))
        .map(|(s, _)| *s)
}

impl Scenario {
    /// Parses and checks a scenario against the I/O map and the wiring.
    pub fn parse(text: &str, origin: &str, map: &IoMap, wiring: &ResolvedWiring) -> Result<Scenario, ConfigError> {
        let file: ScenarioFile = config::parse_strict(text, origin)?;
        let mut problems = Vec::new();
        let mut events = Vec::new();
        for (i, e) in file.events.iter().enumerate() {
            let at = format!("events[{i}]");
            let kinds =
                usize::from(e.input.is_some()) + usize::from(e.joystick.is_some()) + usize::from(e.fault.is_some());
            if kinds != 1 {
                problems.push(DeclIssue {
                    at: at.clone(),
                    message: "an event has exactly one of \"input\", \"joystick\" or \"fault\"".into(),
                });
                continue;
            }
            let Some(t_ns) = e.at_ms.checked_mul(1_000_000) else {
                problems.push(DeclIssue {
                    at: format!("{at}.at_ms"),
                    message: format!(
                        "{} ms is beyond the latest time the runtime's clock holds ({} ms, 584 years)",
                        e.at_ms,
                        u64::MAX / 1_000_000
                    ),
                });
                continue;
            };
            match event_action(e, map, wiring) {
                Ok(action) => events.push((t_ns, action)),
                Err((field, message)) => problems.push(DeclIssue {
                    at: if field.is_empty() { at } else { format!("{at}.{field}") },
                    message,
                }),
            }
        }
        if !problems.is_empty() {
            return Err(ConfigError::Invalid {
                file: origin.to_string(),
                problems,
            });
        }
        events.sort_by_key(|(t, _)| *t);
        Ok(Scenario { events })
    }
}

fn event_action(e: &EventEntry, map: &IoMap, wiring: &ResolvedWiring) -> Result<Action, (&'static str, String)> {
    let need_value = || {
        e.value
            .ok_or(("value", "this event needs \"value\": true or false".to_string()))
    };
    let need_drive = || match e.drive {
        Some(DriveName::Left) => Ok(0),
        Some(DriveName::Right) => Ok(1),
        None => Err(("drive", "this fault needs \"drive\": \"left\" or \"right\"".to_string())),
    };
    if let Some(name) = &e.input {
        return match signal_of(name, map, wiring) {
            Some(Signal::Button(b)) => Ok(Action::Button(b, need_value()?)),
            Some(other) => Err((
                "input",
                format!("\"{name}\" is wired to {other:?}, not to an operator panel button; use a fault for switches"),
            )),
            None => Err((
                "input",
                format!("no input variable \"{name}\" in {} wired to the machine", map.origin),
            )),
        };
    }
    if let Some([x, y]) = e.joystick {
        if !(x.is_finite() && y.is_finite() && (-1.0..=1.0).contains(&x) && (-1.0..=1.0).contains(&y)) {
            return Err(("joystick", format!("axes must lie in −1 … 1, got [{x}, {y}]")));
        }
        return Ok(Action::Joystick(x, y));
    }
    let switch = || {
        let Some(name) = &e.switch else {
            return Err((
                "switch",
                "this fault needs \"switch\": the variable of a limit switch".to_string(),
            ));
        };
        match signal_of(name, map, wiring) {
            Some(Signal::Switch(d, end)) => Ok((d, end)),
            _ => Err((
                "switch",
                format!("\"{name}\" is not a limit switch input of {}", map.origin),
            )),
        }
    };
    match e.fault {
        Some(FaultKind::SwitchStuck) => {
            let (d, end) = switch()?;
            Ok(Action::StickSwitch(d, end, Some(need_value()?)))
        }
        Some(FaultKind::SwitchFree) => {
            let (d, end) = switch()?;
            Ok(Action::StickSwitch(d, end, None))
        }
        Some(FaultKind::EncoderGlitch) => {
            let counts = e
                .counts
                .ok_or(("counts", "an encoder glitch needs \"counts\"".to_string()))?;
            Ok(Action::EncoderGlitch(need_drive()?, counts))
        }
        Some(FaultKind::BridgeError) => Ok(Action::BridgeError(need_drive()?)),
        Some(FaultKind::DriveDead) => Ok(Action::DriveDead(need_drive()?, true)),
        Some(FaultKind::DriveAlive) => Ok(Action::DriveDead(need_drive()?, false)),
        Some(FaultKind::JoystickUnplugged) => Ok(Action::JoystickConnected(false)),
        Some(FaultKind::JoystickPlugged) => Ok(Action::JoystickConnected(true)),
        None => Err((
            "",
            "an event has exactly one of \"input\", \"joystick\" or \"fault\"".to_string(),
        )),
    }
}
