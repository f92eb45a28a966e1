//! The machines this build knows: the one place in the runtime that names machine crates. Adding
//! a machine is a crate under `tasks/` that implements [`Machine`], a dependency in Cargo.toml,
//! and one line in [`BUILTIN`].

use std::path::PathBuf;

use pkm_api::machine::Machine;

use crate::runtime::config::{self, ConfigError, LoadedConfig};

/// Every machine this build links, by the name config.json gives (`"machine": NAME`).
pub static BUILTIN: &[&dyn Machine] = &[
    &pkm_trijoint::MACHINE,
    &pkm_joints::MACHINES[0],
    &pkm_joints::MACHINES[1],
    &pkm_joints::MACHINES[2],
    &pkm_joints::MACHINES[3],
];

/// The machine named `name`, if this build has it.
pub fn find(name: &str) -> Option<&'static dyn Machine> {
    BUILTIN.iter().copied().find(|m| m.name() == name)
}

/// The names of the machines this build has, for messages (`trijoint`).
pub fn names() -> String {
    let names: Vec<&str> = BUILTIN.iter().map(|m| m.name()).collect();
    names.join(", ")
}

/// The machine that brings program type `program`, if one does (for a hint when a configuration
/// names a program of a machine it does not run).
pub fn owner_of(program: &str) -> Option<&'static dyn Machine> {
    BUILTIN
        .iter()
        .copied()
        .find(|m| m.programs().iter().any(|p| p.name == program))
}

/// Every program type of this build: the runtime's self-test programs and every machine's (for
/// tests that add their own programs to a real machine's).
pub fn all_programs() -> pkm_api::program::Registry {
    let mut registry = pkm_api::program::Registry::new();
    crate::compose::selftest::register(&mut registry);
    for info in BUILTIN.iter().flat_map(|m| m.programs()) {
        registry.register(*info);
    }
    registry
}

/// The configuration of machine `name` (`--machine NAME`): its file (`machines/NAME.json`; the
/// TRIJOINT's `config.json`) where it is in the working directory, else the copy built into the
/// binary. `None` for a machine this build does not have.
pub fn configuration(name: &str) -> Option<Result<LoadedConfig, ConfigError>> {
    let file = find(name)?.configuration();
    let path = PathBuf::from(file.name);
    Some(if path.is_file() {
        config::load(Some(&path))
    } else {
        config::parse(file.text, &format!("<built-in {}>", file.name))
    })
}

/// Machine `name` with its own configuration (as [`configuration`] loads it), if this build has
/// it and the configuration loads: for the hints that look through every machine.
pub fn setup(name: &str) -> Option<crate::compose::Setup> {
    configuration(name)
        .and_then(Result::ok)
        .and_then(|loaded| crate::compose::Setup::new(loaded).ok())
}

/// The machine whose configuration (as [`configuration`] loads it) has the digest `digest` — a
/// trace's `config_digest` — if one has.
pub fn with_digest(digest: &str) -> Option<&'static str> {
    BUILTIN
        .iter()
        .map(|m| m.name())
        .find(|name| setup(name).and_then(|s| s.digest().ok()).is_some_and(|d| d == digest))
}

/// The machines whose own I/O map binds an input variable `name` (for a hint when a scenario
/// names an input the configured machine has not).
pub fn with_input(name: &str) -> Vec<&'static str> {
    BUILTIN
        .iter()
        .map(|m| m.name())
        .filter(|machine| {
            setup(machine)
                .and_then(|setup| setup.io_map().ok().flatten())
                .is_some_and(|map| {
                    map.bindings
                        .iter()
                        .any(|b| b.variable == name && b.direction == crate::services::io::catalogue::Direction::Input)
                })
        })
        .collect()
}

/// A hint that names the machines in `names` (`--machine NAME`), or nothing without any.
pub fn hint(names: &[&str]) -> String {
    match names {
        [] => String::new(),
        [one] => format!(" (machine {one} has it: --machine {one})"),
        more => format!(" (machines {} have it: --machine NAME)", more.join(", ")),
    }
}
