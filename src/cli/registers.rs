//! `registers`: the Modbus register map that the configuration's I/O map gives.

use super::args::ConfigArg;
use super::{Failure, load_setup};

pub fn run(args: ConfigArg) -> Result<(), Failure> {
    let setup = load_setup(&args)?;
    let Some(map) = setup.io_map()? else {
        return Err(Failure::usage(format!(
            "{}: the configuration names no I/O map",
            setup.origin()
        )));
    };
    print!(
        "{}",
        pkm_plc::services::io::registers::RegisterMap::of(&map).report(&map)
    );
    Ok(())
}
