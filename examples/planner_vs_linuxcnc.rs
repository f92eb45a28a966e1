//! The planner's times against LinuxCNC 2.9's on the same programs: each program is
//! read, checked and planned on the O-X glide (X configuration, its own limits) as `nc check`
//! plans it, and its planned time, whole and of the feed moves, printed beside the time
//! LinuxCNC's motion planner took for it in simulation with the same axis limits.
//!
//! `cargo run --release --example planner_vs_linuxcnc`
//!
//! Exit 1 when a program plans slower than LinuxCNC (whole program or feed moves), so the
//! figure cannot drift silently; the README's table is this example's output.

#[path = "shared/spiral.rs"]
mod spiral;

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
        "{:<26} {:>9} {:>9} {:>7}   {:>9} {:>9} {:>7}",
        "program (ox-x)", "ours s", "LinuxCNC", "ratio", "feed s", "LinuxCNC", "ratio"
    );
    let mut slower = false;
    for (name, text, linuxcnc, linuxcnc_feed) in programs {
        let prepared = nc_job::prepare_text(&setup, name.to_string(), text).unwrap_or_else(|e| {
            eprintln!("planner_vs_linuxcnc: {name}: {}", e.message);
            std::process::exit(2);
        });
        let Some(plan) = prepared.plan else {
            eprintln!("planner_vs_linuxcnc: {name}: not reachable on ox-x");
            std::process::exit(2);
        };
        let (whole, feed) = (plan.duration_s, plan.feed_time_s);
        println!(
            "{name:<26} {whole:>9.3} {linuxcnc:>9.3} {:>7.3}   {feed:>9.3} {linuxcnc_feed:>9.3} {:>7.3}",
            whole / linuxcnc,
            feed / linuxcnc_feed
        );
        slower |= whole > linuxcnc || feed > linuxcnc_feed;
    }
    if slower {
        println!("slower than LinuxCNC on at least one program");
        std::process::exit(1);
    }
}
