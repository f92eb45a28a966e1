//! Scenario files: timed operator actions and fault injections for the simulated machine.
//!
//! ```json
//! {"events": [
//!   {"at_ms": 1000, "input": "BUTTON_STOP", "value": true},
//!   {"at_ms": 1200, "input": "BUTTON_STOP", "value": false},
//!   {"at_ms": 2000, "joystick": [0.5, -0.2]},
//!   {"at_ms": 3000, "fault": "switch_stuck", "switch": "SWITCH_LEFT_UPPER", "value": true},
//!   {"at_ms": 4000, "fault": "encoder_glitch", "drive": "left", "counts": 500},
//!   {"at_ms": 5000, "program": "hold"}
//! ]}
//! ```
//!
//! A `program` event (`start`, `hold`, `resume`) presses the panel's program button bound to
//! `NC_START`, `NC_HOLD` or `NC_RESUME` for [`PROGRAM_PRESS_MS`]; a `tool_changed` event
//! (`{"at_ms": 9000, "tool_changed": 2}`: tool 2 put in the spindle) presses the one bound to
//! `TOOL_CHANGED` as long.
//!
//! Inputs and switches are named by the process-image variable they are bound to in the I/O map;
//! drives by the names the machine's plant gives them. The file format is the runtime's; what an
//! action does is the plant's ([`Plant::apply`]).

use pkm_api::machine::{Action, Plant, Role};
use serde::Deserialize;

use super::ResolvedWiring;
use crate::image::Problem;
use crate::runtime::config::{self, ConfigError};
use crate::services::io::catalogue::Direction;
use crate::services::io::map::IoMap;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioFile {
    events: Vec<EventEntry>,
    /// How long a run of the scenario lasts when `--duration` does not say (s).
    #[serde(default)]
    duration_s: Option<f64>,
}

/// The longest a scenario may say its run lasts (s): 10 000 000 s, as `--duration`.
pub const MAX_DURATION_S: f64 = 1e7;

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
    drive: Option<String>,
    #[serde(default)]
    counts: Option<i64>,
    #[serde(default)]
    program: Option<ProgramCommand>,
    /// A manual tool change done: the tool put in the spindle, then the panel's tool-changed
    /// button (`TOOL_CHANGED`) pressed.
    #[serde(default)]
    tool_changed: Option<u32>,
}

/// A program event: which program button is pressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProgramCommand {
    /// Start the program (from READY).
    Start,
    /// Feed hold.
    Hold,
    /// Resume after a feed hold or an M0.
    Resume,
}

impl ProgramCommand {
    /// The input variable of its button.
    fn variable(self) -> &'static str {
        match self {
            ProgramCommand::Start => "NC_START",
            ProgramCommand::Hold => "NC_HOLD",
            ProgramCommand::Resume => "NC_RESUME",
        }
    }
}

/// How long a program event holds its button down (ms): two main cycles of 50 ms.
pub const PROGRAM_PRESS_MS: u64 = 100;

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

impl FaultKind {
    /// Its name in a scenario.
    fn name(self) -> &'static str {
        match self {
            FaultKind::SwitchStuck => "switch_stuck",
            FaultKind::SwitchFree => "switch_free",
            FaultKind::EncoderGlitch => "encoder_glitch",
            FaultKind::BridgeError => "bridge_error",
            FaultKind::DriveDead => "drive_dead",
            FaultKind::DriveAlive => "drive_alive",
            FaultKind::JoystickUnplugged => "joystick_unplugged",
            FaultKind::JoystickPlugged => "joystick_plugged",
        }
    }
}

/// A parsed scenario: actions in time order.
#[derive(Clone, Debug, Default)]
pub struct Scenario {
    /// (time in ns, action), sorted by time; events at the same time keep their file order.
    pub events: Vec<(u64, Action)>,
    /// How long a run of it lasts when the command line does not say (s): its `duration_s`.
    pub duration_s: Option<f64>,
}

impl Scenario {
    /// When its last event comes (s; 0 without events).
    pub fn last_event_s(&self) -> f64 {
        self.events.last().map_or(0.0, |(t, _)| *t as f64 / 1e9)
    }

    /// Whether an event moves, plugs or unplugs the joystick: the simulated machine has a
    /// joystick (plugged in at the start) only for such a scenario, so that a run without one
    /// says "not connected" as the lab's machine with none plugged in would.
    pub fn uses_joystick(&self) -> bool {
        self.events
            .iter()
            .any(|(_, a)| matches!(a, Action::Joystick(..) | Action::JoystickConnected(_)))
    }
}

/// The plant signal that the variable `name` is bound to through the I/O map and the wiring.
fn signal_of(name: &str, map: &IoMap, wiring: &ResolvedWiring) -> Option<usize> {
    let b = map
        .bindings
        .iter()
        .find(|b| b.variable == name && b.direction == Direction::Input)?;
    wiring.signal_at(b.module, b.channel)
}

impl Scenario {
    /// Parses and checks a scenario against the I/O map and the wiring; `hint` says which other
    /// machines have an input variable of that name, for an event that names one this machine
    /// has not (empty: none).
    pub fn parse(
        text: &str,
        origin: &str,
        map: &IoMap,
        wiring: &ResolvedWiring,
        plant: &dyn Plant,
        hint: &dyn Fn(&str) -> String,
    ) -> Result<Scenario, ConfigError> {
        let file: ScenarioFile = config::parse_strict(text, origin)?;
        let mut problems = Vec::new();
        let mut events = Vec::new();
        for (i, e) in file.events.iter().enumerate() {
            let at = format!("events[{i}]");
            let kinds = usize::from(e.input.is_some())
                + usize::from(e.joystick.is_some())
                + usize::from(e.fault.is_some())
                + usize::from(e.program.is_some())
                + usize::from(e.tool_changed.is_some());
            if kinds != 1 {
                problems.push(Problem {
                    at: at.clone(),
                    message: ONE_KIND.into(),
                });
                continue;
            }
            let strays = stray_fields(e);
            if !strays.is_empty() {
                for (field, message) in strays {
                    problems.push(Problem {
                        at: format!("{at}.{field}"),
                        message,
                    });
                }
                continue;
            }
            let Some(t_ns) = e.at_ms.checked_mul(1_000_000) else {
                problems.push(Problem {
                    at: format!("{at}.at_ms"),
                    message: format!(
                        "{} ms is beyond the latest time the runtime's clock holds ({} ms, 584 years)",
                        e.at_ms,
                        u64::MAX / 1_000_000
                    ),
                });
                continue;
            };
            // A program button, or the tool-changed button (the tool put in first: the button
            // cannot say which, as on the machine; the PLC takes the one its change asked for,
            // and the tool named is the scenario's account): pressed for PROGRAM_PRESS_MS.
            let button = match (e.program, e.tool_changed) {
                (Some(command), _) => Some((program_button(command, map, wiring, plant), "program")),
                (None, Some(_)) => Some((
                    panel_button("TOOL_CHANGED", "no tool-changed button", map, wiring, plant),
                    "tool_changed",
                )),
                (None, None) => None,
            };
            if let Some((button, field)) = button {
                match button {
                    Ok(signal) => {
                        events.push((t_ns, Action::Press { signal, pressed: true }));
                        events.push((
                            t_ns.saturating_add(PROGRAM_PRESS_MS * 1_000_000),
                            Action::Press { signal, pressed: false },
                        ));
                    }
                    Err(message) => problems.push(Problem {
                        at: format!("{at}.{field}"),
                        message,
                    }),
                }
                continue;
            }
            match event_action(e, map, wiring, plant, hint) {
                Ok(action) => events.push((t_ns, action)),
                Err((field, message)) => problems.push(Problem {
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
        let scenario = Scenario {
            events,
            duration_s: file.duration_s,
        };
        if let Some(d) = file.duration_s {
            let last = scenario.last_event_s();
            let message = if !(d.is_finite() && d > 0.0 && d <= MAX_DURATION_S) {
                format!("must be more than 0 and at most {MAX_DURATION_S} seconds, got {d}")
            } else if d < last {
                format!("{d} s ends the run before the last event, at {last} s")
            } else {
                return Ok(scenario);
            };
            return Err(ConfigError::Invalid {
                file: origin.to_string(),
                problems: vec![Problem::new("duration_s", message)],
            });
        }
        Ok(scenario)
    }
}

/// The fields an event gives that its kind does not take (a `value` on a joystick event, a
/// `drive` on an input): each is a mistake the event would otherwise silently ignore.
fn stray_fields(e: &EventEntry) -> Vec<(&'static str, String)> {
    let (kind, takes): (String, &[&str]) = if e.input.is_some() {
        ("an input event".into(), &["value"])
    } else if e.joystick.is_some() {
        ("a joystick event".into(), &[])
    } else if e.program.is_some() {
        ("a program event".into(), &[])
    } else if e.tool_changed.is_some() {
        ("a tool change event".into(), &[])
    } else {
        let takes: &[&str] = match e.fault {
            Some(FaultKind::SwitchStuck) => &["switch", "value"],
            Some(FaultKind::SwitchFree) => &["switch"],
            Some(FaultKind::EncoderGlitch) => &["drive", "counts"],
            Some(FaultKind::BridgeError | FaultKind::DriveDead | FaultKind::DriveAlive) => &["drive"],
            Some(FaultKind::JoystickUnplugged | FaultKind::JoystickPlugged) | None => &[],
        };
        let name = e.fault.map_or("?", FaultKind::name);
        (format!("the \"{name}\" fault"), takes)
    };
    let given = [
        ("value", e.value.is_some()),
        ("switch", e.switch.is_some()),
        ("drive", e.drive.is_some()),
        ("counts", e.counts.is_some()),
    ];
    given
        .iter()
        .filter(|(field, present)| *present && !takes.contains(field))
        .map(|(field, _)| {
            let allowed = if takes.is_empty() {
                "nothing besides at_ms".to_string()
            } else {
                takes
                    .iter()
                    .map(|t| format!("\"{t}\""))
                    .collect::<Vec<_>>()
                    .join(" and ")
            };
            (
                *field,
                format!("{kind} takes {allowed}; \"{field}\" does not belong to it"),
            )
        })
        .collect()
}

/// What every event must have exactly one of.
const ONE_KIND: &str =
    "an event has exactly one of \"input\", \"joystick\", \"fault\", \"program\" or \"tool_changed\"";

/// The plant's button bound to `command`'s variable.
fn program_button(
    command: ProgramCommand,
    map: &IoMap,
    wiring: &ResolvedWiring,
    plant: &dyn Plant,
) -> Result<usize, String> {
    panel_button(command.variable(), "no program buttons", map, wiring, plant)
}

/// The plant's panel button the I/O map binds to the input variable `name`; else why not (the
/// panel has `lacking`).
fn panel_button(
    name: &str,
    lacking: &str,
    map: &IoMap,
    wiring: &ResolvedWiring,
    plant: &dyn Plant,
) -> Result<usize, String> {
    match signal_of(name, map, wiring) {
        Some(signal) if plant.signals()[signal].role == Role::Button => Ok(signal),
        _ => Err(format!(
            "{} binds no panel button of the machine to {name}: this machine's simulated panel has {lacking}",
            map.origin
        )),
    }
}

fn event_action(
    e: &EventEntry,
    map: &IoMap,
    wiring: &ResolvedWiring,
    plant: &dyn Plant,
    hint: &dyn Fn(&str) -> String,
) -> Result<Action, (&'static str, String)> {
    let need_value = || {
        e.value
            .ok_or(("value", "this event needs \"value\": true or false".to_string()))
    };
    let need_drive = || {
        let names = plant.drives();
        e.drive
            .as_deref()
            .and_then(|d| names.iter().position(|n| *n == d))
            .ok_or_else(|| {
                let quoted: Vec<String> = names.iter().map(|n| format!("\"{n}\"")).collect();
                let message = match &e.drive {
                    None => format!("this fault needs \"drive\": {}", or_list(&quoted)),
                    Some(d) => format!(
                        "no drive \"{}\" on this machine: use {}",
                        crate::runtime::config::shorten(d),
                        or_list(&quoted)
                    ),
                };
                ("drive", message)
            })
    };
    if let Some(name) = &e.input {
        return match signal_of(name, map, wiring) {
            Some(signal) if plant.signals()[signal].role == Role::Button => Ok(Action::Press {
                signal,
                pressed: need_value()?,
            }),
            Some(other) => Err((
                "input",
                format!(
                    "\"{name}\" is wired to the machine's {}, not to an operator panel button; use a fault for switches",
                    plant.signals()[other].key
                ),
            )),
            None => Err((
                "input",
                format!(
                    "no input variable \"{name}\" in {} wired to the machine{}",
                    map.origin,
                    hint(name)
                ),
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
            Some(signal) if plant.signals()[signal].role == Role::Switch => Ok(signal),
            _ => Err((
                "switch",
                format!("\"{name}\" is not a limit switch input of {}", map.origin),
            )),
        }
    };
    match e.fault {
        Some(FaultKind::SwitchStuck) => Ok(Action::StickSwitch {
            signal: switch()?,
            stuck: Some(need_value()?),
        }),
        Some(FaultKind::SwitchFree) => Ok(Action::StickSwitch {
            signal: switch()?,
            stuck: None,
        }),
        Some(FaultKind::EncoderGlitch) => {
            let counts = e
                .counts
                .ok_or(("counts", "an encoder glitch needs \"counts\"".to_string()))?;
            Ok(Action::EncoderGlitch {
                drive: need_drive()?,
                counts,
            })
        }
        Some(FaultKind::BridgeError) => Ok(Action::BridgeError { drive: need_drive()? }),
        Some(FaultKind::DriveDead) => Ok(Action::DriveDead {
            drive: need_drive()?,
            dead: true,
        }),
        Some(FaultKind::DriveAlive) => Ok(Action::DriveDead {
            drive: need_drive()?,
            dead: false,
        }),
        Some(FaultKind::JoystickUnplugged) => Ok(Action::JoystickConnected(false)),
        Some(FaultKind::JoystickPlugged) => Ok(Action::JoystickConnected(true)),
        None => Err(("", ONE_KIND.to_string())),
    }
}

/// `"a"`, `"a" or "b"`, `"a", "b" or "c"`.
fn or_list(items: &[String]) -> String {
    match items {
        [] => "the plant has no drives".to_string(),
        [one] => one.clone(),
        [init @ .., last] => format!("{} or {last}", init.join(", ")),
    }
}
