//! `pkm-plc nc check FILE`: an NC program read, interpreted and checked offline against the
//! configured machine — every point of its path reachable (docs/nc.md) — with its path length and
//! bounding box. No PLC runs, nothing moves.

use serde_json::{Map, Value, json};

use pkm_kinematics::frame::MachineFrame;
use pkm_kinematics::{KinematicsConfig, Machine as Model};
use pkm_nc::interp::{self, AXES};
use pkm_plc::compose::Setup;
use pkm_plc::compose::nc_job::{Prepared, prepare};

use super::args::{NcArgs, NcOp};

pub use pkm_plc::compose::nc_job::NcFailure;

/// Runs `pkm-plc nc`.
pub fn run(args: NcArgs) -> Result<(), NcFailure> {
    let NcOp::Check {
        file,
        config,
        json,
        svg,
        verbose,
        tool_table,
        var_file,
    } = args.op;
    let fail = |code: u8, message: String| NcFailure { code, message };
    let loaded = super::load_config(&config).map_err(|e| fail(2, e.to_string()))?;
    let setup = Setup::new(loaded)
        .map_err(|e| fail(2, e.to_string()))?
        .with_tool_table(tool_table.as_deref())
        .and_then(|s| s.with_param_file(var_file.as_deref()))
        .map_err(|e| fail(e.code, e.message))?;
    let prepared = prepare(&setup, &file)?;
    let Prepared {
        name,
        machine,
        text: _,
        motion,
        kinematics,
        model,
        frame,
        program,
        report,
        plan: planned,
    } = &prepared;
    let n = frame.dof();
    let keys = frame.kinematics().pose_keys();
    let mut lines = vec![format!(
        "{name}: {} moves on {}: feed path {:.3} mm, rapids {:.3} mm",
        report.moves,
        machine.name(),
        report.feed_length_mm,
        report.rapid_length_mm
    )];
    if let Some(b) = &report.bounding_box {
        let parts: Vec<String> = b
            .iter()
            .enumerate()
            .map(|(c, [lo, hi])| format!("{} {lo:.3} … {hi:.3}", AXES[c]))
            .collect();
        lines.push(format!("bounding box (machine frame): {}", parts.join(", ")));
    }
    if let Some(p) = &planned {
        lines.push(format!("planned time {:.3} s", p.duration_s));
        if p.programmed_feed_time_s > 0.0 {
            lines.push(format!(
                "feed moves: {:.3} s planned, {:.3} s at the programmed feeds ({:.3}×)",
                p.feed_time_s,
                p.programmed_feed_time_s,
                p.feed_time_s / p.programmed_feed_time_s
            ));
        }
        lines.extend(limited_lines(name, &p.limited, verbose));
    }
    if let Some(out) = json {
        let pose_json = |p: &[f64; 6]| -> Value {
            let mut m = Map::new();
            for c in 0..n {
                m.insert(keys[c].to_string(), json!(p[c]));
            }
            Value::Object(m)
        };
        let bbox: Map<String, Value> = report
            .bounding_box
            .iter()
            .flatten()
            .enumerate()
            .map(|(c, b)| (keys[c].to_string(), json!(b)))
            .collect();
        let doc = json!({
            "file": name,
            "machine": machine.name(),
            "moves": report.moves,
            "feed_length_mm": report.feed_length_mm,
            "rapid_length_mm": report.rapid_length_mm,
            "bounding_box": bbox,
            "planned_time_s": planned.as_ref().map(|p| p.duration_s),
            "feed_time_s": planned.as_ref().map(|p| p.feed_time_s),
            "programmed_feed_time_s": planned.as_ref().map(|p| p.programmed_feed_time_s),
            "limited": planned.as_ref().map(|p| p.limited.iter().map(|l| json!({
                "line": l.line,
                "programmed_mm_min": l.programmed_mm_min,
                "reachable_mm_min": l.reachable_mm_min,
                "why": l.why.text(),
            })).collect::<Vec<_>>()).unwrap_or_default(),
            "unreachable": report.unreachable.iter().map(|u| json!({
                "line": u.line, "pose": pose_json(&u.pose), "why": u.why
            })).collect::<Vec<_>>(),
        });
        let text = serde_json::to_string_pretty(&doc).map_err(|e| fail(1, e.to_string()))?;
        std::fs::write(&out, text + "\n").map_err(|e| fail(1, format!("{}: {e}", out.display())))?;
    }
    if let Some(out) = svg {
        draw(&out, program, frame, kinematics, *model, motion, name)?;
        lines.push(format!("tool path drawn in {}", out.display()));
    }
    if report.unreachable.is_empty() {
        lines.push(format!(
            "every point of the path is reachable (sampled every {} mm and {}°)",
            pkm_nc::check::SAMPLE_SPACING,
            pkm_nc::check::SAMPLE_SPACING
        ));
        println!("{}", lines.join("\n"));
        return Ok(());
    }
    println!("{}", lines.join("\n"));
    Err(fail(
        1,
        format!(
            "the program leaves what the machine can reach:\n{}",
            prepared.unreachable_lines().join("\n")
        ),
    ))
}

/// What `nc check` says of the blocks whose feed the machine lowers: every block with `verbose`;
/// else one line per cause (a CAM program's thousands of blocks would be thousands of lines),
/// naming how many blocks it slows and the slowest of them — or, for a cause of one block, that
/// block.
fn limited_lines(name: &str, limited: &[pkm_nc::plan::Limited], verbose: bool) -> Vec<String> {
    let one = |l: &pkm_nc::plan::Limited| {
        format!(
            "{name}:{}: F{} slows to {:.1} mm/min at its slowest point: {}",
            l.line,
            l.programmed_mm_min,
            l.reachable_mm_min,
            l.why.text()
        )
    };
    if verbose {
        return limited.iter().map(one).collect();
    }
    // Per cause, in the order of first appearance: its blocks and the slowest of them.
    let mut causes: Vec<(pkm_nc::plan::Limit, usize, &pkm_nc::plan::Limited)> = Vec::new();
    for l in limited {
        match causes.iter_mut().find(|(why, _, _)| *why == l.why) {
            Some((_, count, slowest)) => {
                *count += 1;
                if l.reachable_mm_min < slowest.reachable_mm_min {
                    *slowest = l;
                }
            }
            None => causes.push((l.why, 1, l)),
        }
    }
    causes
        .iter()
        .map(|(why, count, slowest)| {
            if *count == 1 {
                one(slowest)
            } else {
                format!(
                    "{name}: {count} blocks slow below their feed because of {}; the slowest, line {}: F{} → {:.1} mm/min (--verbose lists them all)",
                    why.text(),
                    slowest.line,
                    slowest.programmed_mm_min,
                    slowest.reachable_mm_min
                )
            }
        })
        .collect()
}

/// Draws `program`'s tool path over the machine's sampled workspace into `out`.
fn draw(
    out: &std::path::Path,
    program: &interp::Program,
    frame: &MachineFrame,
    kinematics: &KinematicsConfig,
    model: Model,
    motion: &pkm_api::machine::Motion,
    name: &str,
) -> Result<(), NcFailure> {
    let n = frame.dof();
    let ws = pkm_kinematics::workspace::sample(kinematics, model, 40, motion.singularity_threshold);
    let paths: Vec<crate::cli::kin_svg::Polyline> = program
        .blocks
        .iter()
        .filter_map(|b| match b.action {
            interp::Action::Move {
                from,
                to,
                path,
                feed_mm_min,
                ..
            } => {
                let segment = pkm_nc::path::Segment::new(from, to, path);
                let steps = (segment.length() / 0.5).ceil().max(1.0) as usize;
                let points = (0..=steps)
                    .map(|i| {
                        let pose = segment.at(i as f64 / steps as f64);
                        let mut mechanism = vec![0.0; n];
                        frame.to_mechanism(&pose[..n], &mut mechanism);
                        mechanism
                    })
                    .collect();
                Some(crate::cli::kin_svg::Polyline {
                    points,
                    rapid: feed_mm_min.is_none(),
                })
            }
            _ => None,
        })
        .collect();
    // The plane of the path's two largest extents (of x y z).
    let mut extent: Vec<(usize, f64)> = (0..n.min(3))
        .map(|c| {
            let (lo, hi) = paths
                .iter()
                .flat_map(|p| p.points.iter())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p[c]), hi.max(p[c]))
                });
            (c, hi - lo)
        })
        .collect();
    extent.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut axes = [extent.first().map_or(0, |e| e.0), extent.get(1).map_or(1, |e| e.0)];
    axes.sort_unstable();
    let keys = frame.kinematics().pose_keys();
    let caption = format!(
        "{name} on {}: {}-{} (mechanism frame; workspace samples projected; rapids grey)",
        model.name(),
        keys[axes[0]],
        keys[axes[1]]
    );
    let fail = |code: u8, message: String| NcFailure { code, message };
    let svg = crate::cli::kin_svg::draw_with(&ws, keys, axes, Some(&caption), &paths)
        .map_err(|e| fail(1, format!("{}: drawing failed: {e}", out.display())))?;
    std::fs::write(out, svg).map_err(|e| fail(1, format!("{}: {e}", out.display())))
}
