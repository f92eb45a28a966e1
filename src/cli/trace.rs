//! `trace`: a trace as VCD, SVG time plots, the tool path, or the summary a reviewer diffs.

use super::Failure;
use super::args::{TraceArgs, TraceOp};

pub fn run(args: TraceArgs) -> Result<(), Failure> {
    use pkm_plc::services::trace::export::{ExportError, to_svg, to_vcd};
    if let TraceOp::Summary { trace, every } = &args.op {
        let text = pkm_plc::services::trace::expected::summary(trace, (every * 1e6) as u64)
            .map_err(|e| Failure::usage(e.to_string()))?;
        print!("{text}");
        return Ok(());
    }
    let (result, out) = match &args.op {
        TraceOp::Vcd { trace, out } => (to_vcd(trace, out), out),
        TraceOp::Plot { trace, out, vars } => (to_svg(trace, out, vars), out),
        TraceOp::Path { trace, out, magnify } => (pkm_plc::services::trace::path::to_svg(trace, out, *magnify), out),
        TraceOp::Summary { .. } => unreachable!("handled above"),
    };
    match result {
        Ok(done) => {
            let cut = done.cut.map(|c| format!(" ({c})")).unwrap_or_default();
            println!("{}: {} records written{cut}", out.display(), done.records);
            Ok(())
        }
        Err(e @ ExportError::Output { .. }) => Err(Failure::run(e.to_string())),
        Err(e) => Err(Failure::usage(e.to_string())),
    }
}
