//! The planner's times against LinuxCNC 2.9's on the same programs (`shared/bench_programs.rs`):
//! each program is planned on the O-X glide as `nc check` plans it, and its motion time (dwells
//! excluded) printed beside the time LinuxCNC's own motion took for it in its simulator, with
//! every world axis bounded by the sliders' speed and acceleration (the limits a lab would give
//! LinuxCNC, whose trivial kinematics know nothing of the sliders), and the most LinuxCNC's
//! motion, taken every millisecond through the O-X kinematics, asks of a slider.
//!
//! ```text
//! cargo run --release --example planner_vs_linuxcnc              # LinuxCNC's figures as measured
//! cargo run --release --example planner_vs_linuxcnc -- --measure # LinuxCNC run again (real time)
//! ```
//!
//! `--measure` runs `tools/linuxcnc_motion.py` (Debian's `linuxcnc-uspace`) on every program,
//! in real time (about half an hour), and prints the rows of [`LINUXCNC`] to write back here.
//!
//! Exit 1 when a program plans slower than LinuxCNC where LinuxCNC's own motion keeps the
//! sliders' limits (to 0.5 %), so the figure cannot drift silently; the table in `docs/nc.md`
//! is this example's output.

#[path = "shared/bench_programs.rs"]
mod bench_programs;
#[path = "shared/shipped.rs"]
mod shipped;

use std::path::Path;

use pkm_kinematics::MAX_DOF;
use pkm_plc::compose::nc_job;

/// LinuxCNC 2.9's motion of each program on the O-X glide's slider limits (20 mm/s,
/// 100 mm/s² per world axis), measured by `--measure`: its time (s, dwells excluded), and the
/// most it asks of a slider (mm/s, mm/s²): measured 2026-11-28 with Debian's linuxcnc-uspace
/// 2.9.0~pre1.
const LINUXCNC: &[(&str, f64, f64, f64)] = &[
    ("line 10 mm F1200", 0.702, 20.0, 100.0),
    ("square G61", 11.294, 20.0, 100.0),
    ("square G64", 10.476, 20.0, 101.0),
    ("square G64 P0.01", 11.391, 20.0, 101.0),
    ("circles R20, R5", 11.179, 20.0, 101.0),
    ("CAM spiral, 2000 lines", 30.859, 20.0, 136.0),
    ("ox-x-target.ngc", 67.124, 20.0, 137.0),
    ("slow feeds + G81", 155.102, 21.2, 126.0),
    ("adaptive clearing", 225.428, 22.3, 125.0),
    ("3-D raster finish", 78.313, 26.3, 148.0),
    ("text engraving", 419.572, 21.5, 138.0),
    ("slow feeds + cycles", 866.704, 24.4, 135.0),
];

/// What LinuxCNC's motion of one program was.
struct Motion {
    time_s: f64,
    slider_speed: f64,
    slider_accel: f64,
}

/// Runs `text` in LinuxCNC's simulator with `speed` and `accel` per axis, and takes its motion
/// through `prepared`'s kinematics.
fn measure(prepared: &nc_job::Prepared, text: &str, speed: f64, accel: f64, dwell_s: f64) -> Result<Motion, String> {
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let (program, samples) = (dir.path().join("p.ngc"), dir.path().join("samples.txt"));
    std::fs::write(&program, text).map_err(|e| e.to_string())?;
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/linuxcnc_motion.py");
    let out = std::process::Command::new(&script)
        .args(["--vel", &speed.to_string(), "--acc", &accel.to_string()])
        .arg(&program)
        .arg(&samples)
        .output()
        .map_err(|e| format!("{}: {e}", script.display()))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
    }
    let text = std::fs::read_to_string(&samples).map_err(|e| e.to_string())?;
    let n = prepared.frame.dof();
    let mut joints: Vec<[f64; MAX_DOF]> = Vec::new();
    for line in text.lines() {
        let xyz: Vec<f64> = line.split_whitespace().filter_map(|v| v.parse().ok()).collect();
        if xyz.len() != 3 {
            return Err(format!("a sample that is not x y z: {line}"));
        }
        let mut pose = [0.0; 6];
        pose[..3].copy_from_slice(&xyz);
        let mut q = [0.0; MAX_DOF];
        prepared
            .frame
            .inverse(&pose[..n], &mut q[..n])
            .map_err(|e| format!("LinuxCNC's motion leaves the workspace: {e}"))?;
        joints.push(q);
    }
    const DT: f64 = 1e-3;
    let (mut top_speed, mut top_accel) = (0.0f64, 0.0f64);
    for w in joints.windows(3) {
        for ((q0, q1), q2) in w[0][..n].iter().zip(&w[1][..n]).zip(&w[2][..n]) {
            top_speed = top_speed.max((q1 - q0).abs() / DT);
            top_accel = top_accel.max((q2 - 2.0 * q1 + q0).abs() / (DT * DT));
        }
    }
    Ok(Motion {
        time_s: (joints.len().saturating_sub(1)) as f64 * DT - dwell_s,
        slider_speed: top_speed,
        slider_accel: top_accel,
    })
}

fn main() {
    let measuring = std::env::args().any(|a| a == "--measure");
    let setup = shipped::setup("ox-x").unwrap_or_else(|e| {
        eprintln!("planner_vs_linuxcnc: {e}");
        std::process::exit(2);
    });
    println!(
        "{:<24} {:>9} {:>9} {:>7}   {:>9} {:>10}  keeps the limits",
        "program (ox-x)", "ours s", "LinuxCNC", "ratio", "slider v", "slider a"
    );
    let mut slower = false;
    let mut measured = Vec::new();
    for (name, text) in bench_programs::programs() {
        let prepared = nc_job::prepare_text(&setup, name.to_string(), text.clone()).unwrap_or_else(|e| {
            eprintln!("planner_vs_linuxcnc: {name}: {}", e.message);
            std::process::exit(2);
        });
        let Some(plan) = &prepared.plan else {
            eprintln!("planner_vs_linuxcnc: {name}: not reachable on ox-x");
            std::process::exit(2);
        };
        let ours = plan.duration_s - plan.dwell_s;
        let lowest = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let (speed, accel) = (
            lowest(&prepared.motion.joint_speed),
            lowest(&prepared.motion.joint_accel),
        );
        let theirs = if measuring {
            match measure(&prepared, &text, speed, accel, plan.dwell_s) {
                Ok(m) => {
                    measured.push(format!(
                        "    ({name:?}, {:.3}, {:.1}, {:.1}),",
                        m.time_s, m.slider_speed, m.slider_accel
                    ));
                    Some(m)
                }
                Err(e) => {
                    println!("{name:<24} {ours:>9.3} LinuxCNC failed: {e}");
                    continue;
                }
            }
        } else {
            LINUXCNC
                .iter()
                .find(|(n, ..)| *n == name)
                .map(|&(_, time_s, slider_speed, slider_accel)| Motion {
                    time_s,
                    slider_speed,
                    slider_accel,
                })
        };
        let Some(m) = theirs else {
            println!("{name:<24} {ours:>9.3} (LinuxCNC not measured: --measure)");
            continue;
        };
        let keeps = m.slider_speed <= speed * 1.005 && m.slider_accel <= accel * 1.005;
        println!(
            "{name:<24} {ours:>9.3} {:>9.3} {:>7.3}   {:>4.1} mm/s {:>5.0} mm/s²  {}",
            m.time_s,
            ours / m.time_s,
            m.slider_speed,
            m.slider_accel,
            if keeps { "yes" } else { "no" }
        );
        slower |= keeps && ours > m.time_s;
    }
    if measuring {
        println!(
            "\nconst LINUXCNC: &[(&str, f64, f64, f64)] = &[\n{}\n];",
            measured.join("\n")
        );
    }
    if slower {
        println!("slower than LinuxCNC on a program whose LinuxCNC motion keeps the sliders' limits");
        std::process::exit(1);
    }
}
