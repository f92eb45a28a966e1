//! `replay`: feeds a trace's inputs to the programs of its configuration and compares every
//! output and state.

use super::args::{ConfigArg, ReplayArgs};
use super::{Failure, load_setup};

pub fn run(args: ReplayArgs) -> Result<(), Failure> {
    use pkm_plc::compose::replay::{ReplayError, replay};
    let setup = if args.config.config.is_none() && args.config.machine.is_none() {
        // The trace says which machine it was recorded on.
        let machine = recorded_machine(&args.trace);
        let arg = ConfigArg {
            config: None,
            machine: machine.map(str::to_string),
        };
        load_setup(&arg)?
    } else {
        load_setup(&args.config)?
    };
    match replay(&args.trace, &setup, args.force) {
        Ok(r) => {
            let (identical, cut) = match &r.cut {
                None => ("identical", String::new()),
                Some(cut) => ("identical up to the cut", format!("; {cut}")),
            };
            println!(
                "{}: {identical}: {} records over {:.1} s of recorded time, replayed in {:.3} s ({:.0}x){cut}",
                args.trace.display(),
                r.records,
                r.recorded_s,
                r.wall.as_secs_f64(),
                r.recorded_s / r.wall.as_secs_f64().max(1e-9)
            );
            Ok(())
        }
        Err(e @ ReplayError::Differs(_)) => Err(Failure::run(format!("{}: {e}", args.trace.display()))),
        Err(e) => Err(Failure::usage(e.to_string())),
    }
}

/// The machine whose own configuration a trace was recorded with (its header's digest is that
/// configuration's), if one's is.
fn recorded_machine(trace: &std::path::Path) -> Option<&'static str> {
    let reader = pkm_plc::services::trace::read::TraceReader::open(trace).ok()?;
    pkm_plc::compose::setup::with_digest(&reader.header().config_digest)
}
