//! A trace as a reviewer reads it: its state transitions and the outputs of the state-carrying
//! class sampled at a fixed interval, as plain text (LinuxCNC keeps such an `expected` file next to
//! each of its tests). The golden traces keep one beside them, so a behaviour change shows up as a
//! readable diff in review, not only as a replay failure at one record.
//!
//! ```text
//! # pkm-plc trace summary: state transitions; outputs of class "main" every 5 s
//! t=0.000 s: state REBOOT
//! t=0.000 s: REBOOT
//!     main_state = 0
//!     drives_enable = false
//! t=0.050 s: state INIT
//! t=5.000 s: INIT
//!     main_state = 1
//!     drives_enable = true
//! ```

use std::fmt::Write as _;
use std::path::Path;

use super::read::{TraceError, TraceReader};
use crate::image::Value;

/// Writes `value` for the summary: REALs rounded to µm (3 decimals), so that a difference in the
/// last bit of a float does not make noise, but one of a micrometre does.
fn show(value: Value) -> String {
    match value {
        Value::Real(r) if r.is_finite() => format!("{r:.3}"),
        Value::Real(_) => "null".to_string(),
        other => super::value_to_json(other).to_string(),
    }
}

/// The summary of the trace at `path`: every state or reason change, and every `every_us` the
/// outputs of the class whose records carry the state (the main program's class).
pub fn summary(path: &Path, every_us: u64) -> Result<String, TraceError> {
    let mut reader = TraceReader::open(path)?;
    let header = reader.header().clone();
    let names: Vec<String> = reader.variables().iter().map(|(n, _)| n.clone()).collect();
    let mut values: Vec<Option<Value>> = vec![None; names.len()];
    let mut out = String::new();
    // The class sampled: the slowest that publishes outputs (the main program's, in a machine's
    // configuration); the state comes with its records.
    let class = (0..header.task_classes.len())
        .filter(|&c| !header.task_classes[c].outputs.is_empty())
        .max_by_key(|&c| (header.task_classes[c].cycle_us, std::cmp::Reverse(c)));
    let mut state: Option<(String, Option<String>)> = None;
    let mut next_sample = 0u64;
    let mut lines = Vec::new();
    while let Some(r) = reader.next_record()? {
        for &(k, v) in r.inputs.iter().chain(&r.outputs) {
            values[k] = Some(v);
        }
        let Some(s) = r.state.as_ref().filter(|_| Some(r.class) == class) else {
            continue;
        };
        let now = (s.to_string(), r.reason.as_deref().map(str::to_string));
        let t = r.t_us as f64 * 1e-6;
        let changed = state.as_ref() != Some(&now);
        if changed {
            let reason = now.1.as_deref().map(|r| format!(" ({r})")).unwrap_or_default();
            lines.push(format!("t={t:.3} s: state {}{reason}", now.0));
            state = Some(now);
        }
        if r.t_us >= next_sample {
            // A sample at a transition belongs to the line above; else it says its time and
            // the state it was taken in.
            lines.push(if changed {
                "  outputs:".to_string()
            } else {
                format!("t={t:.3} s: outputs in {s}")
            });
            for name in &header.task_classes[r.class].outputs {
                if let Some(k) = names.iter().position(|n| n == name)
                    && let Some(v) = values[k]
                {
                    lines.push(format!("    {name} = {}", show(v)));
                }
            }
            next_sample = (r.t_us / every_us + 1) * every_us;
        }
    }
    let class = class.map_or("(none)".to_string(), |c| header.task_classes[c].name.clone());
    let _ = writeln!(
        out,
        "# pkm-plc trace summary: state transitions; outputs of class \"{class}\" every {} s",
        every_us as f64 * 1e-6
    );
    for line in lines {
        let _ = writeln!(out, "{line}");
    }
    if let Some(cut) = reader.cut() {
        let _ = writeln!(out, "# {cut}");
    }
    Ok(out)
}
