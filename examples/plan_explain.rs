//! One program held against the planner's properties, as the property tests and the long run
//! (`plan_soak`) hold it, with what a developer needs to see why it fails: the plan's elements,
//! the checks' figures, the time-optimal motion's time per line, and the planned speed beside
//! the time-optimal one along the path.
//!
//! `cargo run --release --example plan_explain -- MACHINE FILE [SPACING_MM]` (the reference's
//! grid, 0.005 mm by default; a finer one shows whether the reference has converged).

#[path = "shared/optimal.rs"]
mod optimal;
#[path = "shared/plan_check.rs"]
mod plan_check;
#[path = "shared/shipped.rs"]
mod shipped;

use pkm_plc::compose::nc_job;

/// Where along the path the two speeds are printed.
const ROWS: usize = 40;

fn main() {
    if let Err(e) = explain() {
        eprintln!("plan_explain: {e}");
        std::process::exit(2);
    }
}

fn explain() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [machine, file, rest @ ..] = args.as_slice() else {
        return Err("usage: plan_explain MACHINE FILE [SPACING_MM]".into());
    };
    let spacing = match rest.first() {
        Some(s) => s.parse::<f64>().map_err(|e| format!("spacing {s}: {e}"))?,
        None => 0.005,
    };
    let text = std::fs::read_to_string(file).map_err(|e| format!("{file}: {e}"))?;
    let setup = shipped::setup(machine)?;
    let prepared = nc_job::prepare_text(&setup, file.into(), text).map_err(|e| e.message)?;
    let plan = prepared.plan.as_ref().ok_or("a point is out of the machine's reach")?;
    let limits = nc_job::plan_limits(&setup, &prepared.motion, prepared.frame.dof());
    let mut start = 0.0;
    for e in plan.elements() {
        println!(
            "element of line {}: from {start:.5} mm, {:.6} mm{}, feed {:.3} mm/s{}",
            e.line,
            e.segment.length(),
            if e.segment.is_arc() {
                format!(", a curve of {:.3e} rad", e.segment.sweep())
            } else {
                String::new()
            },
            e.feed,
            if e.stop_after { ", stops" } else { "" }
        );
        start += e.segment.length();
    }
    match plan_check::check(plan, &prepared.program, &prepared.frame, &limits, 10_000) {
        Ok(m) => println!("holds: {m:?}"),
        Err(e) => println!("FAILS: {e}"),
    }
    let o = optimal::optimal(plan, &prepared.frame, &limits, spacing, plan_check::LIMIT_TOLERANCE)?;
    println!(
        "planned {:.6} s; time-optimal {:.6} s ({:.4}×), lower bound {:.6} s, on {} samples",
        plan.duration_s - plan.dwell_s,
        o.time_s,
        (plan.duration_s - plan.dwell_s) / o.time_s,
        o.lower_bound_s,
        o.samples
    );
    println!("time-optimal per line: {:?}", o.per_line);
    // The plan sampled finely in time, then both speeds at the same places along the path.
    let mut cursor = 0;
    let planned: Vec<(f64, f64, f64)> = (0..=ROWS * 50)
        .map(|i| {
            let t = plan.duration_s * i as f64 / (ROWS * 50) as f64;
            let s = plan.sample(t, &mut cursor);
            (s.s, s.speed, t)
        })
        .collect();
    println!(
        "{:>10} {:>12} {:>9} {:>12}",
        "mm", "planned mm/s", "at s", "optimal mm/s"
    );
    for i in 0..=ROWS {
        let s = plan.length_mm * i as f64 / ROWS as f64;
        let near = |a: f64, b: f64| (a - s).abs().total_cmp(&(b - s).abs());
        let (Some(p), Some(r)) = (
            planned.iter().min_by(|a, b| near(a.0, b.0)),
            o.speeds.iter().min_by(|a, b| near(a.0, b.0)),
        ) else {
            continue;
        };
        println!("{s:>10.5} {:>12.4} {:>9.4} {:>12.4}", p.1, p.2, r.1);
    }
    Ok(())
}
