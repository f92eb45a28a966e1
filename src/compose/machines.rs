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
