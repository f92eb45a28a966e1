//! A machine as shipped, for the planner's benchmarks and property tests: its configuration as
//! built into the binary (not a file of the working directory that may have been edited).

use pkm_plc::compose::{Setup, machines};
use pkm_plc::runtime::config;

/// The setup of `machine` from its built-in configuration, or why there is none.
pub fn setup(machine: &str) -> Result<Setup, String> {
    let m = machines::find(machine).ok_or_else(|| format!("no machine {machine} in this build"))?;
    let file = m.configuration();
    let loaded = config::parse(file.text, file.name).map_err(|e| e.to_string())?;
    Setup::new(loaded).map_err(|e| e.to_string())
}
