//! The machines this build knows: the one place in the runtime that names machine crates. Adding
//! a machine is a crate under `tasks/` that implements [`Machine`], a dependency in Cargo.toml,
//! and one line in [`BUILTIN`].

use pkm_api::machine::Machine;

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
    crate::selftest::register(&mut registry);
    for info in BUILTIN.iter().flat_map(|m| m.programs()) {
        registry.register(*info);
    }
    registry
}
