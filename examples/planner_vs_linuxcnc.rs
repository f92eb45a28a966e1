//! The planner's times against LinuxCNC 2.9's on the same programs: each program is
//! read, checked and planned on the O-X glide (X configuration, its own limits) as `nc check`
//! plans it, and its planned time, whole and of the feed moves, printed beside the time
//! LinuxCNC's motion planner took for it in simulation with the same axis limits.
//!
//! `cargo run --release --example planner_vs_linuxcnc`
//!
//! Beside it, each program planned as LinuxCNC plans it — each world axis bounded by the
//! sliders' speed and acceleration (the limits LinuxCNC was given), the sliders themselves not
//! at all, since LinuxCNC's trivial kinematics do not know them — and what that plan asks of
//! the sliders (sampled every millisecond through the O-X kinematics).
//!
//! Exit 1 when a program plans slower than LinuxCNC (whole program or feed moves), so the
//! figure cannot drift silently; the README's table is this example's output.

#[path = "shared/spiral.rs"]
mod spiral;

use pkm_kinematics::MAX_DOF;
use pkm_nc::plan::PlanLimits;
use pkm_plc::compose::Setup;
use pkm_plc::compose::{machines, nc_job};
use pkm_plc::runtime::config;

/// A 40 mm square at F1200 in the blending mode `mode`.
fn square(mode: &str) -> String {
    format!("G21 G90 G17 {mode}\nG0 X-20 Y-20\nG1 X20 F1200\nY20\nX-20\nY-20\nG0 X0 Y0\nM2\n")
}

/// Circles of radius 20 and 5 mm at F1200.
const CIRCLES: &str = "G21 G90 G17 G64 P0.01\nG0 X20 Y0\nG2 I-20 F1200\nG0 X5 Y0\nG2 I-5\nG0 X0 Y0\nM2\n";

fn main() {
    // (program, its text, LinuxCNC's whole time, LinuxCNC's feed-move time), seconds.
    let programs: Vec<(&str, String, f64, f64)> = vec![
        ("square G61", square("G61"), 11.291, 8.892),
        ("square G64 P0.01", square("G64 P0.01"), 11.388, 8.788),
        ("circles R20, R5", CIRCLES.to_string(), 11.176, 8.393),
        ("CAM spiral, 2000 lines", spiral::program(2000, 1200.0), 30.856, 28.049),
        (
            "programs/ox-x-target.ngc",
            include_str!("../programs/ox-x-target.ngc").to_string(),
            67.121,
            55.446,
        ),
    ];
    let Some(machine) = machines::find("ox-x") else {
        eprintln!("planner_vs_linuxcnc: no machine ox-x in this build");
        std::process::exit(2);
    };
    let file = machine.configuration();
    let setup = config::parse(file.text, file.name)
        .map_err(|e| e.to_string())
        .and_then(|loaded| Setup::new(loaded).map_err(|e| e.to_string()))
        .unwrap_or_else(|e| {
            eprintln!("planner_vs_linuxcnc: {e}");
            std::process::exit(2);
        });
    println!(
        "{:<26} {:>9} {:>9} {:>7}   {:>9} {:>9} {:>7}   {:>9} {:>7} {:>10} {:>11}",
        "program (ox-x)",
        "ours s",
        "LinuxCNC",
        "ratio",
        "feed s",
        "LinuxCNC",
        "ratio",
        "as LCNC s",
        "ratio",
        "slider v",
        "slider a"
    );
    let mut slower = false;
    let mut sliders = (f64::NAN, f64::NAN);
    for (name, text, linuxcnc, linuxcnc_feed) in programs {
        let prepared = nc_job::prepare_text(&setup, name.to_string(), text).unwrap_or_else(|e| {
            eprintln!("planner_vs_linuxcnc: {name}: {}", e.message);
            std::process::exit(2);
        });
        let Some(plan) = &prepared.plan else {
            eprintln!("planner_vs_linuxcnc: {name}: not reachable on ox-x");
            std::process::exit(2);
        };
        let (whole, feed) = (plan.duration_s, plan.feed_time_s);
        sliders = slider_limits(&prepared.motion);
        let (as_linuxcnc, speed, accel) = as_linuxcnc_plans(&prepared).unwrap_or_else(|e| {
            eprintln!("planner_vs_linuxcnc: {name}: {e}");
            std::process::exit(2);
        });
        println!(
            "{name:<26} {whole:>9.3} {linuxcnc:>9.3} {:>7.3}   {feed:>9.3} {linuxcnc_feed:>9.3} {:>7.3}   \
             {as_linuxcnc:>9.3} {:>7.3} {speed:>6.1} mm/s {accel:>6.0} mm/s²",
            whole / linuxcnc,
            feed / linuxcnc_feed,
            as_linuxcnc / linuxcnc
        );
        slower |= whole > linuxcnc || feed > linuxcnc_feed;
    }
    let (speed, accel) = sliders;
    println!(
        "as LCNC: planned with {speed} mm/s and {accel} mm/s² per world axis and the sliders unbounded; \
         slider v, a: the most that plan asks of a slider (theirs: {speed} mm/s, {accel} mm/s²)"
    );
    if slower {
        println!("slower than LinuxCNC on at least one program");
        std::process::exit(1);
    }
}

/// The machine's lowest slider speed (mm/s) and acceleration (mm/s²).
fn slider_limits(motion: &pkm_api::machine::Motion) -> (f64, f64) {
    let lowest = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    (lowest(&motion.joint_speed), lowest(&motion.joint_accel))
}

/// The program planned as LinuxCNC plans it (its world axes bounded by the sliders' limits,
/// the sliders not at all): its duration (s), and the highest slider speed (mm/s) and
/// acceleration (mm/s²) it asks for.
fn as_linuxcnc_plans(prepared: &nc_job::Prepared) -> Result<(f64, f64, f64), String> {
    let n = prepared.frame.dof();
    let (speed, accel) = slider_limits(&prepared.motion);
    let limits = PlanLimits {
        joint_speed: vec![f64::INFINITY; n],
        joint_accel: vec![f64::INFINITY; n],
        axis_speed: [speed; 6],
        axis_accel: [accel; 6],
    };
    let plan = pkm_nc::plan::plan(&prepared.program, &prepared.frame, &limits).map_err(|e| e.to_string())?;
    // The sliders every millisecond; speeds and accelerations by differences.
    const DT: f64 = 1e-3;
    let steps = (plan.duration_s / DT).ceil() as usize;
    let mut cursor = 0;
    let mut joints: Vec<[f64; MAX_DOF]> = Vec::with_capacity(steps + 1);
    for k in 0..=steps {
        let pose = plan.sample(k as f64 * DT, &mut cursor).pose;
        let mut q = [0.0; MAX_DOF];
        prepared
            .frame
            .inverse(&pose[..n], &mut q[..n])
            .map_err(|e| e.to_string())?;
        joints.push(q);
    }
    let (mut top_speed, mut top_accel) = (0.0f64, 0.0f64);
    for w in joints.windows(3) {
        for ((q0, q1), q2) in w[0][..n].iter().zip(&w[1][..n]).zip(&w[2][..n]) {
            top_speed = top_speed.max((q1 - q0).abs() / DT);
            top_accel = top_accel.max((q2 - 2.0 * q1 + q0).abs() / (DT * DT));
        }
    }
    Ok((plan.duration_s, top_speed, top_accel))
}
