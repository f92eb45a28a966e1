//! `pkm-plc nc check`: a program read and checked offline against the configured machine.

use crate::common;

use common::{pkm, stderr, stdout};

/// Writes `text` as `name` in `dir`; its path as text.
fn program(dir: &std::path::Path, name: &str, text: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write the program");
    path.to_str().expect("utf-8").to_string()
}

#[test]
fn a_program_inside_the_workspace_is_reported_with_its_length_and_box() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(
        dir.path(),
        "circle.ngc",
        "%\nG0 X10 Y0\nG1 Z-5 F300\nG3 X10 Y0 I-10 J0\nG0 Z0\nM2\n%\n",
    );
    let json = dir.path().join("report.json");
    let o = pkm(&[
        "nc",
        "check",
        &file,
        "--machine",
        "ox-x",
        "--json",
        json.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(
        stdout(&o),
        format!(
            "{file}: 4 moves on ox-x: feed path 67.832 mm, rapids 15.000 mm\n\
             bounding box (machine frame): X -10.000 … 10.000, Y -10.000 … 10.000, Z -5.000 … 0.000\n\
             planned time 15.582 s\n\
             feed moves: 13.966 s planned, 13.566 s at the programmed feeds (1.029×)\n\
             every point of the path is reachable (sampled every 0.1 mm and 0.1°)\n"
        )
    );
    let r = common::read_json(&json);
    assert_eq!(r["machine"], "ox-x");
    assert_eq!(r["moves"], 4);
    assert_eq!(r["unreachable"], serde_json::json!([]));
    assert_eq!(r["bounding_box"]["z"], serde_json::json!([-5.0, 0.0]));
    assert!(
        (r["planned_time_s"].as_f64().expect("a time") - 15.582).abs() < 0.001,
        "{r}"
    );
    assert_eq!(r["limited"], serde_json::json!([]));
    // The plunge (5 mm) and the circle (62.832 mm) at F300: 13.566 s.
    let at_feed = r["programmed_feed_time_s"].as_f64().expect("a time");
    assert!((at_feed - 67.832 / 5.0).abs() < 0.001, "{r}");
    assert!(r["feed_time_s"].as_f64().expect("a time") > at_feed, "{r}");
}

#[test]
fn a_feed_the_joints_cannot_give_is_reported_with_the_reachable_feed_and_why() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(dir.path(), "fast.ngc", "G1 X20 F6000\nM2\n");
    let o = pkm(&["nc", "check", &file, "--machine", "pn101"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).contains(&format!(
            "{file}:1: F6000 slows to 480.0 mm/min at its slowest point: the speed of joint 1\n"
        )),
        "{}",
        stdout(&o)
    );
}

#[test]
fn unreachable_points_are_named_by_line_and_nothing_else_is_said_to_pass() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(dir.path(), "far.ngc", "G1 X1 F100\nG1 X200\nG1 X0\n");
    let o = pkm(&["nc", "check", &file, "--machine", "pn101"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(
        stderr(&o),
        format!(
            "error: the program leaves what the machine can reach:\n\
             {file}:2: at X40.100 Y0.000 Z0.000: X = 40.100 is outside the world limits -40 … 40\n\
             {file}:3: at X199.900 Y0.000 Z0.000: X = 199.900 is outside the world limits -40 … 40\n"
        )
    );
    assert!(!stdout(&o).contains("reachable"), "{}", stdout(&o));
}

#[test]
fn a_refused_word_is_named_with_file_line_and_column() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(dir.path(), "cycle.ngc", "G1 X1 F100\n  G81 X1 Z-1 R1\n");
    let o = pkm(&["nc", "check", &file, "--machine", "pn101"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!("error: {file}:2:3: G81 is not supported (canned cycles)\n")
    );
    let file = program(dir.path(), "tilt.ngc", "G1 A5 F100\n");
    let o = pkm(&["nc", "check", &file, "--machine", "ox-o"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!("error: {file}:1:4: A: this machine's axes are X Y Z\n")
    );
    // The hexapod has rotations; a few degrees of tilt are inside its workspace.
    let file = program(dir.path(), "tilt.ngc", "G1 X5 A3 B-3 F100\nG1 X0 A0 B0\n");
    let o = pkm(&["nc", "check", &file, "--machine", "hexapod"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}

#[test]
fn every_shipped_program_passes_the_check_on_its_machine() {
    let dir = common::root().join("programs");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).expect("programs/") {
        let path = entry.expect("entry").path();
        if path.extension().is_none_or(|e| e != "ngc") {
            continue;
        }
        let file = path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        // `MACHINE-….ngc`: the program of that machine.
        let machine = ["trijoint", "pn101", "ox-x", "ox-o", "hexapod"]
            .into_iter()
            .find(|m| file.starts_with(&format!("{m}-")))
            .unwrap_or_else(|| panic!("{file}: named after no machine"));
        let o = pkm(&["nc", "check", path.to_str().expect("utf-8"), "--machine", machine]);
        assert_eq!(o.status.code(), Some(0), "{file}: {}", stderr(&o));
        assert!(
            stdout(&o).contains("every point of the path is reachable"),
            "{}",
            stdout(&o)
        );
        count += 1;
    }
    assert!(count >= 5, "{count} programs");
}

#[test]
fn the_tool_path_is_drawn_inside_the_workspace() {
    let dir = tempfile::tempdir().expect("tempdir");
    let svg = dir.path().join("pn101.svg");
    let o = pkm(&[
        "nc",
        "check",
        "programs/pn101-shapes.ngc",
        "--machine",
        "pn101",
        "--svg",
        svg.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).contains(&format!("tool path drawn in {}\n", svg.display())),
        "{}",
        stdout(&o)
    );
    let text = std::fs::read_to_string(&svg).expect("svg");
    assert!(text.starts_with("<svg"), "{}", &text[..80.min(text.len())]);
    assert!(
        text.contains("programs/pn101-shapes.ngc on pn101: x-y"),
        "the caption names program, machine and plane"
    );
    // The workspace's samples and the path's moves (16, each a polyline).
    assert!(text.matches("<circle").count() > 1000, "workspace samples");
    assert!(text.matches("<polyline").count() >= 16, "the moves");
}

/// The O-X glide's configuration with `nc` set, written to `dir`.
fn ox_x_with_nc(dir: &std::path::Path, nc: serde_json::Value) -> String {
    let mut c = common::read_json(&common::root().join("machines/ox-x.json"));
    c["io_map"] = common::root().join("io-map/ox-x.json").to_str().expect("utf-8").into();
    c["nc"] = nc;
    let path = dir.join("ox-x.json");
    std::fs::write(&path, c.to_string()).expect("write the configuration");
    path.to_str().expect("utf-8").to_string()
}

#[test]
fn work_offsets_and_axis_limits_come_from_the_configuration() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = ox_x_with_nc(
        dir.path(),
        serde_json::json!({"work_offsets": {"G55": [20, 0, -5]}, "axis_speed": [50, 2, 50], "axis_accel": [500, 500, 500]}),
    );
    let file = program(dir.path(), "p.ngc", "G55 G1 X0 Y10 Z0 F600\nM2\n");
    let o = pkm(&["nc", "check", &file, "--config", &config]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    // G55's origin is at machine x 20, z −5; y may run 2 mm/s only.
    assert!(
        stdout(&o).contains("bounding box (machine frame): X 0.000 … 20.000, Y 0.000 … 10.000, Z -5.000 … 0.000"),
        "{}",
        stdout(&o)
    );
    assert!(
        stdout(&o).contains(&format!("{file}:1: F600 slows to ")),
        "{}",
        stdout(&o)
    );
    assert!(stdout(&o).contains("the speed of axis Y\n"), "{}", stdout(&o));
    // Checked with paths: a wrong length, a system that is not one, a limit that is not positive.
    let config = ox_x_with_nc(
        dir.path(),
        serde_json::json!({"work_offsets": {"G55": [1, 2]}, "axis_speed": [1, 0, 1]}),
    );
    let o = pkm(&["check", "--config", &config]);
    assert_eq!(o.status.code(), Some(2), "check sees it too: {}", stderr(&o));
    let o = pkm(&["nc", "check", &file, "--config", &config]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {config}: 2 problems:\n  at nc.work_offsets.G55: one value per coordinate of the machine (X Y Z): 3, got 2\n  at nc.axis_speed[1]: must be between 0.01 and 1000 mm/s, got 0\n"
        )
    );
    let config = ox_x_with_nc(dir.path(), serde_json::json!({"work_offsets": {"G60": [0, 0, 0]}}));
    let o = pkm(&["nc", "check", &file, "--config", &config]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {config}: at nc.work_offsets.G60: a work coordinate system is one of G54, G55, G56, G57, G58, G59\n"
        )
    );
}
