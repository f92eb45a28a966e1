//! I/O map files (`io-map/*.json`): the modules present and the bindings channel → variable,
//! each assigned to the task class whose cycle exchanges it.

use std::collections::HashMap;

use serde::Deserialize;

use super::catalogue::{self, Direction, ModuleType};
use pkm_api::machine::EmbeddedFile;

use crate::config::{self, ConfigError, LoadedConfig};
use crate::image::{Problem, Reader, Value, VarIndex, VarTable, VarType, Writer};

/// The file as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IoMapFile {
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
    /// The modules.
    pub modules: Vec<Module>,
    /// The bindings.
    pub bindings: Vec<Binding>,
}

impl IoMap {
    /// Parses and validates a map; `classes` are the configured task class names.
    pub fn parse(text: &str, origin: &str, classes: &[String]) -> Result<IoMap, ConfigError> {
        let file: IoMapFile = config::parse_strict(text, origin)?;
        let mut problems = Vec::new();
        let mut push = |at: String, message: String| problems.push(Problem { at, message });
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
            match catalogue::module_type(&m.module_type) {
                Some(ty) => modules.push(Module {
                    name: m.name.clone(),
                    ty,
                    slot: m.slot,
                }),
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
        // One problem per variable bound more than once, at its second binding, naming them all.
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
        if problems.is_empty() {
            Ok(IoMap {
                origin: origin.to_string(),
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
                crate::files::read_text(&path, crate::files::MAX_TEXT_BYTES).map_err(|source| ConfigError::Read {
                    file: origin.clone(),
                    source,
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
