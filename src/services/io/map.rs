//! I/O map files (`io-map/*.json`): the modules present and the bindings channel → variable,
//! each assigned to the task class whose cycle exchanges it.

use std::collections::HashMap;

use serde::Deserialize;

use super::catalogue::{self, Direction, ModuleType};
use pkm_api::machine::EmbeddedFile;

use crate::image::{Problem, Reader, Value, VarIndex, VarTable, VarType, Writer};
use crate::runtime::config::{self, ConfigError, LoadedConfig};

/// The file as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IoMapFile {
    /// The station the modules sit in; the generic one when absent.
    #[serde(default)]
    pub station: StationKind,
    /// An X20BC0087's watchdog threshold (ms), which the soft-PLC sets at every connection:
    /// without a write for this long the bus controller sets every output to zero.
    #[serde(default)]
    pub watchdog_ms: Option<u16>,
    /// How the requests of one exchange go over Modbus TCP: together (the default) or one
    /// after another.
    #[serde(default)]
    pub requests: Requests,
    /// The modules of the station.
    pub modules: Vec<ModuleEntry>,
    /// The channel bindings.
    pub bindings: Vec<BindingEntry>,
}

/// One module of the station.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleEntry {
    /// A unique name, used by bindings and by the simulated machine's wiring.
    pub name: String,
    /// The module type (see the catalogue).
    #[serde(rename = "type")]
    pub module_type: String,
    /// Its slot in the station (unique).
    pub slot: u16,
    /// Its hardware ID (the data sheet's "B&R ID code"), a number or a text such as `"0x1B95"`;
    /// needed on an X20BC0087 station where the catalogue does not know it.
    #[serde(default)]
    pub id: Option<IdText>,
}

/// A hardware ID as written: a number, or a text in decimal or `0x` hexadecimal.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum IdText {
    /// A JSON number.
    Number(u16),
    /// A JSON string.
    Text(String),
}

impl IdText {
    /// The ID, or why the text is none.
    fn value(&self) -> Result<u16, String> {
        match self {
            IdText::Number(n) => Ok(*n),
            IdText::Text(t) => {
                let t = t.trim();
                let parsed = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
                    Some(hex) => u16::from_str_radix(hex, 16),
                    None => t.parse(),
                };
                parsed.map_err(|_| {
                    format!("\"{t}\" is not a hardware ID: a number 0–65535, or hexadecimal as \"0x1B95\"")
                })
            }
        }
    }
}

/// The hardware ID io-sim's X20BC0087 reports for a module whose ID its I/O map does not pin.
/// Not 0: a practice run against io-sim must not teach a lab to pin a made-up ID. 0xFFFF is
/// B&R's "none" (as in the data indexes), no module's ID code, and an I/O map refuses to pin
/// it, so a map copied from a practice scan is refused until the real ID is written.
pub const SIMULATED_UNPINNED_ID: u16 = 0xFFFF;

/// An X20BC0087's watchdog threshold when the map gives none (ms): ten 10 ms cycles.
pub const DEFAULT_WATCHDOG_MS: u16 = 100;
/// The thresholds accepted (ms).
pub const WATCHDOG_MS: std::ops::RangeInclusive<u16> = 20..=5000;

/// The station behind the field bus: how its modules' data is laid out in Modbus registers.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
pub enum StationKind {
    /// The project's own layout: every channel in slot order, each kind of data in its own table
    /// from address 0, plus the packed process image (io-sim serves it; see `registers`).
    #[default]
    #[serde(rename = "generic")]
    Generic,
    /// B&R's X20BC0087 Modbus TCP bus controller: process data by byte index as it assigns it
    /// (function model 254), its module table, watchdog and error registers.
    #[serde(rename = "X20BC0087")]
    X20bc0087,
}

impl StationKind {
    /// The name as the I/O map writes it.
    pub fn name(self) -> &'static str {
        match self {
            StationKind::Generic => "generic",
            StationKind::X20bc0087 => "X20BC0087",
        }
    }
}

/// How the requests of one Modbus TCP exchange go on the wire. A serial line carries one
/// request at a time whatever this says.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Requests {
    /// Every request of the exchange sent at once, each answer matched to its request by the
    /// MBAP transaction identifier: about one round trip for the exchange, not one per request.
    #[default]
    Pipelined,
    /// Each request after the previous one's answer, for a station that does not take
    /// pipelined requests (it answers only the first, or closes the connection).
    Sequential,
}

impl Requests {
    /// The name as the I/O map writes it.
    pub fn name(self) -> &'static str {
        match self {
            Requests::Pipelined => "pipelined",
            Requests::Sequential => "sequential",
        }
    }
}

/// One binding.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BindingEntry {
    /// The module's name.
    pub module: String,
    /// The channel's name.
    pub channel: String,
    /// The process-image variable.
    pub variable: String,
    /// The task class that exchanges it.
    pub task_class: String,
}

/// A module of a validated map.
#[derive(Clone, Debug)]
pub struct Module {
    /// Its name.
    pub name: String,
    /// Its type.
    pub ty: &'static ModuleType,
    /// Its slot.
    pub slot: u16,
    /// Its hardware ID: the map's, else the catalogue's; `None` when neither gives one.
    pub id: Option<u16>,
}

/// A validated binding.
#[derive(Clone, Debug)]
pub struct Binding {
    /// Index into [`IoMap::modules`].
    pub module: usize,
    /// Index into the module type's channels.
    pub channel: usize,
    /// The variable's name.
    pub variable: String,
    /// The task class index.
    pub class: usize,
    /// The channel's direction.
    pub direction: Direction,
    /// The channel's type.
    pub ty: VarType,
    /// Where it is written, for messages: `FILE: bindings[i] (MODULE.Channel)`.
    pub at: String,
}

impl Binding {
    /// Declares the bound variable for a bus: an input channel makes the bus its writer; an
    /// output channel makes the bus a reader that needs no writer (an output nobody writes keeps
    /// its safe value, as an unwritten I/O-mapped variable does on a B&R controller).
    pub fn declare(&self, table: &mut VarTable) -> VarIndex {
        match self.direction {
            Direction::Input => table.declare_writer(
                &self.variable,
                self.ty,
                Writer::Bus {
                    class: self.class,
                    at: self.at.clone(),
                },
                Value::zero(self.ty),
            ),
            Direction::Output => table.declare_reader(
                &self.variable,
                self.ty,
                Reader {
                    class: self.class,
                    who: crate::image::BUS_READER.into(),
                    at: self.at.clone(),
                    needs_writer: false,
                },
            ),
        }
    }
}

/// A validated I/O map.
#[derive(Clone, Debug)]
pub struct IoMap {
    /// The file it came from.
    pub origin: String,
    /// The station the modules sit in.
    pub station: StationKind,
    /// An X20BC0087's watchdog threshold (ms).
    pub watchdog_ms: u16,
    /// How an exchange's requests go over Modbus TCP.
    pub requests: Requests,
    /// The modules.
    pub modules: Vec<Module>,
    /// The bindings.
    pub bindings: Vec<Binding>,
}

impl IoMap {
    /// Parses and validates a map; `classes` are the configured task class names. Every problem
    /// of the file is reported at once.
    pub fn parse(text: &str, origin: &str, classes: &[String]) -> Result<IoMap, ConfigError> {
        let file: IoMapFile = config::parse_strict(text, origin)?;
        let mut problems = Vec::new();
        let mut push = |at: String, message: String| problems.push(Problem { at, message });
        let modules = parse_modules(&file, &mut push);
        let (bindings, by_variable) = parse_bindings(&file, &modules, classes, origin, &mut push);
        shared_variables(&bindings, &by_variable, &mut push);
        check_station(&file, &modules, &mut push);
        if problems.is_empty() {
            Ok(IoMap {
                origin: origin.to_string(),
                station: file.station,
                watchdog_ms: file.watchdog_ms.unwrap_or(DEFAULT_WATCHDOG_MS),
                requests: file.requests,
                modules,
                bindings,
            })
        } else {
            Err(ConfigError::Invalid {
                file: origin.to_string(),
                problems,
            })
        }
    }

    /// Resolves `MODULE.Channel` to (module index, channel index), checking direction and type;
    /// a problem is reported at `at`, where the reference was written.
    pub fn resolve(
        &self,
        reference: &str,
        direction: Direction,
        ty: VarType,
        at: &str,
    ) -> Result<(usize, usize), Problem> {
        let problem = |message: String| Problem::new(at, message);
        let Some((module, channel)) = reference.split_once('.') else {
            return Err(problem(format!("\"{reference}\" is not of the form MODULE.Channel")));
        };
        let Some(mi) = self.modules.iter().position(|m| m.name == module) else {
            return Err(problem(format!("no module \"{module}\" in {}", self.origin)));
        };
        let mt = self.modules[mi].ty;
        let Some((ci, c)) = mt.channel(channel) else {
            return Err(problem(format!(
                "module \"{module}\" ({}) has no channel \"{channel}\"",
                mt.name
            )));
        };
        if c.direction != direction || c.ty != ty {
            return Err(problem(format!(
                "{reference} is a {} {} channel, but a {} {} channel is needed here",
                c.ty,
                c.direction.name(),
                ty,
                direction.name()
            )));
        }
        Ok((mi, ci))
    }
}

/// What an X20BC0087 station asks of its map: the field-bus modules in slots 1, 2, … without a
/// gap (the bus controller numbers them by their place on the backplane). `modules` are the
/// valid ones of `file`, in file order (a module of unknown type was reported already).
fn check_bus_controller(file: &IoMapFile, modules: &[Module], push: &mut impl FnMut(String, String)) {
    let field: Vec<(usize, &Module)> = file
        .modules
        .iter()
        .enumerate()
        .filter_map(|(i, entry)| {
            let m = modules.iter().find(|m| m.name == entry.name)?;
            m.ty.field_bus.then_some((i, m))
        })
        .collect();
    let mut slots: Vec<(u16, usize)> = field.iter().map(|(i, m)| (m.slot, *i)).collect();
    slots.sort_unstable();
    for (expected, (slot, i)) in (1u16..).zip(&slots) {
        if *slot != expected {
            push(
                format!("modules[{i}].slot"),
                format!(
                    "slot {slot} on an X20BC0087 station, where slot {expected} is next: the bus controller numbers \
                     its modules by their place on the backplane, 1, 2, 3 … without a gap"
                ),
            );
            break;
        }
    }
}

impl IoMap {
    /// Loads and validates the configuration's I/O map; `None` when it names none. `embedded` is
    /// the machine's built-in map, which the built-in configuration names.
    pub fn load(loaded: &LoadedConfig, embedded: Option<EmbeddedFile>) -> Result<Option<IoMap>, ConfigError> {
        let Some((text, origin)) = io_map_text(loaded, embedded)? else {
            return Ok(None);
        };
        let classes: Vec<String> = loaded.config.task_classes.iter().map(|c| c.name.clone()).collect();
        IoMap::parse(&text, &origin, &classes).map(Some)
    }
}

/// The text of the configuration's I/O map and the name to report it by: the file relative to
/// the configuration's directory, or for the built-in configuration the machine's built-in map
/// (`embedded`). `None` when the configuration names no I/O map.
pub fn io_map_text(
    loaded: &LoadedConfig,
    embedded: Option<EmbeddedFile>,
) -> Result<Option<(String, String)>, ConfigError> {
    let Some(map_name) = &loaded.config.io_map else {
        return Ok(None);
    };
    Ok(Some(match &loaded.dir {
        Some(dir) => {
            let path = dir.join(map_name);
            let origin = path.display().to_string();
            let text =
                crate::runtime::files::read_text(&path, crate::runtime::files::MAX_TEXT_BYTES).map_err(|source| {
                    ConfigError::Read {
                        file: origin.clone(),
                        source,
                    }
                })?;
            (text, origin)
        }
        None => match embedded.filter(|e| e.name == map_name) {
            Some(e) => (e.text.to_string(), format!("<built-in {}>", e.name)),
            None => {
                return Err(ConfigError::Invalid {
                    file: loaded.origin.clone(),
                    problems: vec![Problem {
                        at: "io_map".into(),
                        message: format!("the built-in configuration has no I/O map \"{map_name}\""),
                    }],
                });
            }
        },
    }))
}

/// The map's modules: each name and slot once, each type in the catalogue, a given ID the
/// catalogue's.
fn parse_modules(file: &IoMapFile, push: &mut impl FnMut(String, String)) -> Vec<Module> {
    let mut modules = Vec::new();
    // Names and slots seen so far: each check is a lookup, so a map of thousands of entries
    // is checked in linear time.
    let mut names: HashMap<&str, usize> = HashMap::new();
    let mut slots: HashMap<u16, usize> = HashMap::new();
    for (i, m) in file.modules.iter().enumerate() {
        let at = format!("modules[{i}]");
        if let Some(&j) = names.get(m.name.as_str()) {
            push(
                format!("{at}.name"),
                format!("module name \"{}\" is already used by modules[{j}]", m.name),
            );
        } else {
            names.insert(&m.name, i);
        }
        if let Some(&j) = slots.get(&m.slot) {
            push(
                format!("{at}.slot"),
                format!(
                    "slot {} is already taken by module \"{}\" (modules[{j}])",
                    m.slot, file.modules[j].name
                ),
            );
        } else {
            slots.insert(m.slot, i);
        }
        let given = match m.id.as_ref().map(IdText::value) {
            Some(Ok(SIMULATED_UNPINNED_ID)) => {
                push(
                    format!("{at}.id"),
                    format!(
                        "{SIMULATED_UNPINNED_ID:#06X} is what io-sim reports for a module whose ID its map does not pin, \
                         no module's own: pin the ID the real station reports (`pkm-plc station scan`), or none"
                    ),
                );
                None
            }
            Some(Ok(id)) => Some(id),
            Some(Err(message)) => {
                push(format!("{at}.id"), message);
                None
            }
            None => None,
        };
        match catalogue::module_type(&m.module_type) {
            Some(ty) => {
                if let (Some(given), Some(known)) = (given, ty.hardware_id)
                    && given != known
                {
                    push(
                        format!("{at}.id"),
                        format!(
                            "the {}'s hardware ID is {known:#06X} (its data sheet's B&R ID code), not {given:#06X}",
                            ty.name
                        ),
                    );
                }
                modules.push(Module {
                    name: m.name.clone(),
                    ty,
                    slot: m.slot,
                    id: given.or(ty.hardware_id),
                });
            }
            None => {
                let known: Vec<&str> = catalogue::CATALOGUE.iter().map(|t| t.name).collect();
                push(
                    format!("{at}.type"),
                    format!(
                        "unknown module type \"{}\"; known types: {}",
                        m.module_type,
                        known.join(", ")
                    ),
                );
            }
        }
    }
    modules
}

/// Per variable, the bindings (indices into the bindings) that bind it, in file order.
type ByVariable<'f> = HashMap<&'f str, Vec<usize>>;

/// The map's bindings: each to a module of the map, a channel of its type not bound before, and
/// a configured task class; and which bindings bind each variable.
fn parse_bindings<'f>(
    file: &'f IoMapFile,
    modules: &[Module],
    classes: &[String],
    origin: &str,
    push: &mut impl FnMut(String, String),
) -> (Vec<Binding>, ByVariable<'f>) {
    let mut bindings: Vec<Binding> = Vec::new();
    let mut by_channel: HashMap<(usize, usize), usize> = HashMap::new();
    let module_index: HashMap<&str, usize> = modules
        .iter()
        .enumerate()
        .rev()
        .map(|(i, m)| (m.name.as_str(), i))
        .collect();
    // Per variable, the bindings (indices into `bindings`) that bind it, in file order.
    let mut by_variable: HashMap<&str, Vec<usize>> = HashMap::new();
    for (i, b) in file.bindings.iter().enumerate() {
        let at = format!("bindings[{i}]");
        let Some(&mi) = module_index.get(b.module.as_str()) else {
            let known: Vec<&str> = modules.iter().map(|m| m.name.as_str()).collect();
            push(
                format!("{at}.module"),
                format!(
                    "unknown module \"{}\"; modules in this map: {}",
                    b.module,
                    known.join(", ")
                ),
            );
            continue;
        };
        let ty = modules[mi].ty;
        let Some((ci, channel)) = ty.channel(&b.channel) else {
            let known: Vec<&str> = ty.channels.iter().map(|c| c.name).collect();
            push(
                format!("{at}.channel"),
                format!(
                    "module \"{}\" ({}) has no channel \"{}\"; its channels: {}",
                    b.module,
                    ty.name,
                    b.channel,
                    known.join(", ")
                ),
            );
            continue;
        };
        let Some(class) = classes.iter().position(|c| *c == b.task_class) else {
            push(
                format!("{at}.task_class"),
                format!(
                    "no task class \"{}\" in the configuration; task classes: {}",
                    b.task_class,
                    classes.join(", ")
                ),
            );
            continue;
        };
        if let Some(&j) = by_channel.get(&(mi, ci)) {
            push(
                format!("{at}.channel"),
                format!("channel {}.{} is already bound by bindings[{j}]", b.module, b.channel),
            );
            continue;
        }
        by_channel.insert((mi, ci), i);
        by_variable.entry(&b.variable).or_default().push(bindings.len());
        bindings.push(Binding {
            module: mi,
            channel: ci,
            variable: b.variable.clone(),
            class,
            direction: channel.direction,
            ty: channel.ty,
            at: format!("{origin}: {at} ({}.{})", b.module, b.channel),
        });
    }
    (bindings, by_variable)
}

/// One problem per variable bound more than once, at its second binding, naming them all.
fn shared_variables(bindings: &[Binding], by_variable: &ByVariable<'_>, push: &mut impl FnMut(String, String)) {
    let mut shared: Vec<&Vec<usize>> = by_variable.values().filter(|v| v.len() > 1).collect();
    shared.sort();
    for list in shared {
        let first = &bindings[list[0]];
        let directions: Vec<Direction> = list.iter().map(|&k| bindings[k].direction).collect();
        let what = if directions.iter().all(|d| *d == Direction::Input) {
            "inputs"
        } else if directions.iter().all(|d| *d == Direction::Output) {
            "outputs"
        } else {
            "channels (inputs and outputs)"
        };
        let channel = |k: usize| {
            let b = &bindings[k];
            let index = b.at.rsplit_once(": ").map_or(b.at.as_str(), |(_, rest)| rest);
            index.to_string()
        };
        const SHOWN: usize = 8;
        let mut named: Vec<String> = list.iter().take(SHOWN).map(|&k| channel(k)).collect();
        if list.len() > SHOWN {
            named.push(format!("and {} more", list.len() - SHOWN));
        }
        let second = channel(list[1]);
        let at = second.split_once(' ').map_or(second.as_str(), |(at, _)| at);
        push(
            format!("{at}.variable"),
            format!(
                "variable \"{}\" is bound to {} {what}: {}; a variable is bound to one channel",
                first.variable,
                list.len(),
                named.join(", ")
            ),
        );
    }
}

/// The station's own rules: an X20BC0087's slots and watchdog; a generic station has no watchdog.
fn check_station(file: &IoMapFile, modules: &[Module], push: &mut impl FnMut(String, String)) {
    match (file.station, file.watchdog_ms) {
        (StationKind::X20bc0087, watchdog) => {
            check_bus_controller(file, modules, push);
            if let Some(ms) = watchdog.filter(|ms| !WATCHDOG_MS.contains(ms)) {
                push(
                    "watchdog_ms".into(),
                    format!(
                        "{ms} ms is outside {}–{} ms: shorter trips on an ordinary late exchange, longer leaves \
                         the drives running that long after the soft-PLC stopped",
                        WATCHDOG_MS.start(),
                        WATCHDOG_MS.end()
                    ),
                );
            }
        }
        (StationKind::Generic, Some(_)) => push(
            "watchdog_ms".into(),
            "the generic station has no watchdog to set (io-sim's is --watchdog-ms); watchdog_ms is an X20BC0087's"
                .into(),
        ),
        (StationKind::Generic, None) => {}
    }
}
