//! The simulated machine, generic half: module channel images exchanged synchronously with the
//! cycles ([`bus::SimBus`]), the wiring of the machine's plant signals to the channels of the I/O
//! map as the real machine's harness is, scenario files that drive the operator panel and inject
//! faults, and the Modbus station that serves it all (io-sim). The physics behind the signals is
//! the machine's [`Plant`](pkm_api::machine::Plant).

pub mod bus;
pub mod bus_controller;
pub mod modbus;
pub mod on_line;
pub mod pdu;
pub mod scenario;
pub mod server;

use pkm_api::machine::{Machine, Plant, Sections};

use crate::image::Problem;
use crate::runtime::config::{ConfigError, LoadedConfig};
use crate::services::io::map::IoMap;

/// A resolved harness: for each wired plant signal (by its index in
/// [`Plant::signals`](pkm_api::machine::Plant::signals)), the (module, channel) it is wired to.
#[derive(Clone, Debug, Default)]
pub struct ResolvedWiring {
    /// Every signal with its channel, in the plant's signal order.
    pub signals: Vec<(usize, (usize, usize))>,
}

impl ResolvedWiring {
    /// Resolves the plant's wiring (`MODULE.Channel` per signal, and where the configuration
    /// says so) against the I/O map's modules.
    pub fn resolve(plant: &dyn Plant, wiring: &[(String, String)], map: &IoMap) -> Result<Self, Vec<Problem>> {
        let mut signals: Vec<(usize, (usize, usize))> = Vec::new();
        let mut problems = Vec::new();
        for (i, (signal, (reference, at))) in plant.signals().iter().zip(wiring).enumerate() {
            match map.resolve(reference, signal.direction, signal.ty, at) {
                Ok(channel) => {
                    if let Some((other, _)) = signals.iter().find(|(_, c)| *c == channel) {
                        let other = plant.signals()[*other].key;
                        problems.push(Problem::new(at, format!("{reference} is already wired to {other}")));
                    }
                    signals.push((i, channel));
                }
                Err(problem) => problems.push(problem),
            }
        }
        if problems.is_empty() {
            Ok(ResolvedWiring { signals })
        } else {
            Err(problems)
        }
    }

    /// The plant signal wired to channel (`module`, `channel`), if one is.
    pub fn signal_at(&self, module: usize, channel: usize) -> Option<usize> {
        self.signals
            .iter()
            .find(|(_, at)| *at == (module, channel))
            .map(|(s, _)| *s)
    }
}

/// Why the simulated machine could not be built.
#[derive(Debug)]
pub enum BuildError {
    /// The machine could not build its plant from its sections: the problems its own check of
    /// those sections reports (so a full configuration check need not report them again).
    Plant(ConfigError),
    /// The wiring to the I/O map or the scenario file.
    Other(ConfigError),
}

impl From<BuildError> for ConfigError {
    fn from(e: BuildError) -> Self {
        match e {
            BuildError::Plant(e) | BuildError::Other(e) => e,
        }
    }
}

impl From<ConfigError> for BuildError {
    fn from(e: ConfigError) -> Self {
        BuildError::Other(e)
    }
}

/// Builds the simulated machine of `machine` for a loaded configuration over its I/O map `map`:
/// the machine builds its plant from its sections, the runtime wires it to the map's channels and
/// loads the scenario file if one is given. A scenario's input that this machine has not is
/// refused with `input_hint(name)` added: the other machines that have it.
pub fn build(
    loaded: &LoadedConfig,
    machine: &dyn Machine,
    map: IoMap,
    scenario: Option<&std::path::Path>,
    input_hint: &dyn Fn(&str) -> String,
) -> Result<bus::SimBus, BuildError> {
    let config = &loaded.config;
    let invalid = |problems: Vec<Problem>| ConfigError::Invalid {
        file: loaded.origin.clone(),
        problems,
    };
    let sections = Sections {
        kinematics: config.kinematics.as_ref(),
        plant: config.plant.as_ref(),
    };
    let setup = machine.plant(&sections).map_err(|p| BuildError::Plant(invalid(p)))?;
    let wiring = ResolvedWiring::resolve(setup.plant.as_ref(), &setup.wiring, &map).map_err(invalid)?;
    let scenario = match scenario {
        None => scenario::Scenario::default(),
        Some(path) => {
            let origin = path.display().to_string();
            let text =
                crate::runtime::files::read_text(path, crate::runtime::files::MAX_TEXT_BYTES).map_err(|source| {
                    ConfigError::Read {
                        file: origin.clone(),
                        source,
                    }
                })?;
            scenario::Scenario::parse(&text, &origin, &map, &wiring, setup.plant.as_ref(), input_hint)?
        }
    };
    Ok(bus::SimBus::new(map, setup.plant, wiring, scenario, setup.step_ns))
}
