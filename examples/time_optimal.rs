//! The planner against the physical limit: each program is planned as `nc check` plans it, and
//! its planned motion time (dwells excluded) compared with the time-optimal motion along the same
//! path under the same joint limits, with the programmed feed as a limit on the path speed and
//! rapids bounded by the joints alone — computed twice, apart from the planner:
//!
//! - by TOPP-RA itself (the `toppra` package on PyPI, `tools/toppra_bench.py`), on the path
//!   sampled every 0.02 mm through the inverse kinematics, where toppra is installed;
//! - by this repository's own reachability reference (`shared/optimal.rs`), which the property
//!   tests use.
//!
//! Per program: our time, TOPP-RA's and the ratio, the reference's and the ratio, and the line
//! where ours is furthest above TOPP-RA's (lines of at least 20 ms).
//!
//! ```text
//! python3 -m venv target/toppra/venv && target/toppra/venv/bin/pip install toppra
//! cargo run --release --example time_optimal [-- --machine ox-x] [--python PATH] [--only NAME]
//! ```
//!
//! Without toppra (no `target/toppra/venv/bin/python`, nor `--python`) the reference alone is
//! compared. The paths go to `target/time-optimal/`.

#[path = "shared/bench_programs.rs"]
mod bench_programs;
#[path = "shared/export_path.rs"]
mod export_path;
#[path = "shared/optimal.rs"]
mod optimal;
#[path = "shared/shipped.rs"]
mod shipped;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use pkm_nc::plan::Plan;
use pkm_plc::compose::nc_job;

/// Our motion's time per program line (s): the plan sampled every half millisecond, each step
/// in which the tool moves counted to the line it runs.
fn our_lines(plan: &Plan) -> BTreeMap<usize, f64> {
    let mut per_line = BTreeMap::new();
    let (dt, mut cursor) = (0.0005, 0);
    let mut last = plan.sample(0.0, &mut cursor);
    let steps = (plan.duration_s / dt).ceil() as usize;
    for k in 1..=steps {
        let now = plan.sample((k as f64 * dt).min(plan.duration_s), &mut cursor);
        if now.s != last.s {
            *per_line.entry(last.line).or_insert(0.0) += dt;
        }
        last = now;
    }
    per_line
}

/// TOPP-RA's time and its time per line for the path in `file`, by `python`.
fn toppra(python: &Path, file: &Path) -> Result<(f64, BTreeMap<usize, f64>), String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/toppra_bench.py");
    let out = std::process::Command::new(python)
        .arg(&script)
        .arg(file)
        .output()
        .map_err(|e| format!("{}: {e}", python.display()))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr)
            .lines()
            .last()
            .unwrap_or("failed")
            .to_string());
    }
    let result = file.with_extension("toppra.json");
    let text = std::fs::read_to_string(&result).map_err(|e| format!("{}: {e}", result.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let time = v["time_s"].as_f64().ok_or("no time_s")?;
    let per_line = v["per_line"]
        .as_object()
        .ok_or("no per_line")?
        .iter()
        .filter_map(|(k, t)| Some((k.parse().ok()?, t.as_f64()?)))
        .collect();
    Ok((time, per_line))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1));
    let machine = arg("--machine").map_or("ox-x", String::as_str);
    let python = arg("--python").map(PathBuf::from).or_else(|| {
        let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/toppra/venv/bin/python");
        venv.exists().then_some(venv)
    });
    let programs = bench_programs::programs();
    let setup = shipped::setup(machine).unwrap_or_else(|e| {
        eprintln!("time_optimal: {e}");
        std::process::exit(2);
    });
    let out_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/time-optimal");
    if let Err(e) = std::fs::create_dir_all(&out_dir) {
        eprintln!("time_optimal: {}: {e}", out_dir.display());
        std::process::exit(2);
    }
    if python.is_none() {
        eprintln!(
            "time_optimal: no toppra (python3 -m venv target/toppra/venv && target/toppra/venv/bin/pip install toppra): the reference alone"
        );
    }
    println!(
        "{:<24} {:>6} {:>9} {:>9} {:>7} {:>9} {:>7}  worst line vs TOPP-RA",
        format!("program ({machine})"),
        "lines",
        "ours s",
        "TOPP-RA s",
        "ratio",
        "ref. s",
        "ratio",
    );
    for (name, text) in programs {
        if arg("--only").is_some_and(|only| !name.contains(only.as_str())) {
            continue;
        }
        let lines = text.lines().count();
        let prepared = match nc_job::prepare_text(&setup, name.to_string(), text) {
            Ok(p) => p,
            Err(e) => {
                println!("{name:<24} not planned: {}", e.message);
                continue;
            }
        };
        let Some(plan) = &prepared.plan else {
            println!("{name:<24} not reachable on {machine}");
            continue;
        };
        let limits = nc_job::plan_limits(&setup, &prepared.motion, prepared.frame.dof());
        let ours = plan.duration_s - plan.dwell_s;
        let reference = optimal::optimal(plan, &prepared.frame, &limits, 0.02, 0.0)
            .map(|o| (format!("{:.3}", o.time_s), format!("{:.4}", ours / o.time_s)))
            .unwrap_or_else(|e| (format!("failed: {e}"), String::new()));
        let mut topp = (String::from("-"), String::from("-"), String::new());
        if let Some(python) = &python {
            let file = out_dir.join(format!("{machine}-{}.json", name.replace([' ', ',', '+', '/'], "_")));
            let written = export_path::export(plan, &prepared.frame, &limits)
                .and_then(|v| std::fs::write(&file, v.to_string()).map_err(|e| e.to_string()));
            topp = match written.and_then(|()| toppra(python, &file)) {
                Ok((t, per_line)) => {
                    let ours_per_line = our_lines(plan);
                    let worst = per_line
                        .iter()
                        .filter(|(_, t)| **t >= 0.02)
                        .filter_map(|(line, t)| Some((*line, ours_per_line.get(line)? / t)))
                        .max_by(|a, b| a.1.total_cmp(&b.1))
                        .map(|(line, r)| format!("line {line}: {r:.3}"))
                        .unwrap_or_default();
                    (format!("{t:.3}"), format!("{:.4}", ours / t), worst)
                }
                Err(e) => (format!("failed: {e}"), String::new(), String::new()),
            };
        }
        println!(
            "{name:<24} {lines:>6} {ours:>9.3} {:>9} {:>7} {:>9} {:>7}  {}",
            topp.0, topp.1, reference.0, reference.1, topp.2
        );
    }
}
