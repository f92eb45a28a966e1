//! `check`: validates a configuration, its machine's sections and its I/O map, and says what it holds.

use super::args::ConfigArg;
use super::{Failure, build};
use pkm_plc::compose::{Built, Options};

pub fn run(args: ConfigArg) -> Result<(), Failure> {
    let Built { setup, plc, .. } = build(&args, Options::default())?;
    let loaded = &setup.loaded;
    let classes: Vec<String> = plc
        .classes()
        .map(|c| format!("{} ({} ms)", c.name, c.period_ns as f64 / 1e6))
        .collect();
    println!(
        "{}: valid ({} task classes: {}; {} process-image variables; I/O map: {})",
        loaded.origin,
        classes.len(),
        classes.join(", "),
        plc.vars().vars().len(),
        loaded.config.io_map.as_deref().unwrap_or("none")
    );
    Ok(())
}
