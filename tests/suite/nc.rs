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
             planned time 14.890 s\n\
             feed moves: 13.679 s planned, 13.566 s at the programmed feeds (1.008×)\n\
             every point of the path is reachable (sampled every 0.1 mm and 0.1°)\n"
        )
    );
    let r = common::read_json(&json);
    assert_eq!(r["machine"], "ox-x");
    assert_eq!(r["moves"], 4);
    assert_eq!(r["unreachable"], serde_json::json!([]));
    assert_eq!(r["bounding_box"]["z"], serde_json::json!([-5.0, 0.0]));
    assert!(
        (r["planned_time_s"].as_f64().expect("a time") - 14.890).abs() < 0.001,
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
            "{file}:1: F6000 slows to 479.0 mm/min at its slowest point: the speed of joint 1\n"
        )),
        "{}",
        stdout(&o)
    );
}

/// `nc check --tool-table`: a program's tools read from LinuxCNC's `tool.tbl`; without a table,
/// or with a table that cannot be read, the refusal names the file and what is wrong.
#[test]
fn nc_check_reads_the_programs_tools_from_the_tool_table() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(dir.path(), "tools.ngc", "T1 M6\nG43 H1\nG1 Z-5 F100\nG49 G0 Z0\nM2\n");
    let table = dir.path().join("tool.tbl");
    std::fs::write(&table, "T1 P1 Z30 D6 ;6 mm end mill\n").expect("write");
    let table = table.to_str().expect("utf-8").to_string();
    let o = pkm(&["nc", "check", &file, "--machine", "ox-x", "--tool-table", &table]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let o = pkm(&["nc", "check", &file, "--machine", "ox-x"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {file}:1:1: T1: there is no tool table (give one with --tool-table or nc.tool_table in the configuration)\n"
        )
    );
    std::fs::write(&table, "T1 P1 Z30\nT2 Zx\n").expect("write");
    let o = pkm(&["nc", "check", &file, "--machine", "ox-x", "--tool-table", &table]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr(&o), format!("error: {table}:2:4: Z needs a number\n"));
    // The configuration's `nc.tool_table`, relative to the configuration's directory.
    std::fs::write(dir.path().join("tool.tbl"), "T1 P1 Z30\n").expect("write");
    let config = ox_x_with_nc(dir.path(), serde_json::json!({"tool_table": "tool.tbl"}));
    let o = pkm(&["nc", "check", &file, "--config", &config]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    // The shipped example: two tools on the O-X glide.
    let (example, example_table) = (
        common::root().join("programs/tools/ox-x-tools.ngc"),
        common::root().join("programs/tools/tool.tbl"),
    );
    let o = pkm(&[
        "nc",
        "check",
        example.to_str().expect("utf-8"),
        "--machine",
        "ox-x",
        "--tool-table",
        example_table.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    // A parameter file moves G54: the same program's box moves with it.
    let var = dir.path().join("ox-x.var");
    std::fs::write(&var, "5221 3\n5222 -4\n").expect("write");
    let plain = program(dir.path(), "plain.ngc", "G1 X5 Y5 F600\nG0 X0 Y0\nM2\n");
    let o = pkm(&[
        "nc",
        "check",
        &plain,
        "--machine",
        "ox-x",
        "--var-file",
        var.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("X 0.000 … 8.000, Y -4.000 … 1.000"),
        "{}",
        stdout(&o)
    );
    let missing = dir.path().join("none.tbl");
    let missing = missing.to_str().expect("utf-8");
    let o = pkm(&["nc", "check", &file, "--machine", "ox-x", "--tool-table", missing]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).starts_with(&format!("error: {missing}: cannot read the tool table: ")),
        "{}",
        stderr(&o)
    );
}

/// A program with many blocks the machine slows gets one line per cause, not a line
/// per block (a CAM program's 19 321 lines); `--verbose` lists every block.
#[test]
fn lowered_feeds_are_summed_up_per_cause_and_listed_with_verbose() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(dir.path(), "fast.ngc", "G61 G1 X20 F6000\nX0\nX20\nX0\nM2\n");
    let o = pkm(&["nc", "check", &file, "--machine", "pn101"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).contains(&format!(
            "{file}: 4 blocks slow below their feed because of the speed of joint 1; the slowest, line 1: F6000 → 479.0 mm/min (--verbose lists them all)\n"
        )),
        "{}",
        stdout(&o)
    );
    let o = pkm(&["nc", "check", &file, "--machine", "pn101", "--verbose"]);
    for line in 1..=4 {
        assert!(
            stdout(&o).contains(&format!(
                "{file}:{line}: F6000 slows to 479.0 mm/min at its slowest point: the speed of joint 1\n"
            )),
            "{}",
            stdout(&o)
        );
    }
}

#[test]
fn unreachable_points_are_named_by_line_and_nothing_else_is_said_to_pass() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = program(dir.path(), "far.ngc", "G1 X1 F100\nG1 X200\nG1 X0\nM2\n");
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
    let file = program(dir.path(), "cycle.ngc", "G1 X1 F100\n  G84 X1 Z-1 R1\n");
    let o = pkm(&["nc", "check", &file, "--machine", "pn101"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!("error: {file}:2:3: G84 is not supported (canned cycles other than G73, G81, G82, G83, G85, G89)\n")
    );
    let file = program(dir.path(), "tilt.ngc", "G1 A5 F100\n");
    let o = pkm(&["nc", "check", &file, "--machine", "ox-o"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!("error: {file}:1:4: A: this machine's axes are X Y Z\n")
    );
    // The hexapod has rotations; a few degrees of tilt are inside its workspace.
    let file = program(dir.path(), "tilt.ngc", "G1 X5 A3 B-3 F100\nG1 X0 A0 B0\nM2\n");
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
    // A part cut in x–z is drawn in x–z, the plane that shows it.
    let file = program(dir.path(), "xz.ngc", "G1 X10 F300\nG1 Z-2\nG1 X0\nG0 Z0\nM2\n");
    let svg = dir.path().join("xz.svg");
    let o = pkm(&[
        "nc",
        "check",
        &file,
        "--machine",
        "ox-x",
        "--svg",
        svg.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&svg).expect("svg");
    assert!(text.contains("xz.ngc on ox-x: x-z"), "the caption names the x–z plane");
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

/// One move as both interpreters give it: rapid, feed or arc, its end (x y z) and, for an arc
/// in X–Y, its centre and direction.
#[derive(Debug, PartialEq)]
struct Canonical {
    kind: &'static str,
    end: [f64; 3],
    arc: Option<([f64; 2], bool)>,
    /// A feed move's feed (mm/min).
    feed: Option<f64>,
}

/// The tool table both interpreters read the comparison programs with (mm).
const TOOL_TABLE: &str = "T1 P1 Z50 D6 ;6 mm end mill\nT2 P2 X0.5 Z30.5 D3 ;3 mm drill\nT3 P3 Z32.3342 D5.1054\nT4 P4 Z12.9794 D3.175 ;1/8 in end mill\nT5 P5 Z-2 D10\nT6 P6 Z10 D1.5875\nT7 P7 Z5 D0.8\nT15 P15 Z20 D4.2\n";

/// [`TOOL_TABLE`] for `rs274`, which reads a tool table in inches (its machine units): every
/// offset divided by 25.4.
fn tool_table_in_inches() -> String {
    let table = pkm_nc::tools::ToolTable::parse(TOOL_TABLE).expect("the test's table");
    table
        .tools
        .iter()
        .map(|t| {
            format!(
                "T{} P{} X{:.9} Y{:.9} Z{:.9} D{:.9}\n",
                t.number,
                t.pocket,
                t.offsets[0] / 25.4,
                t.offsets[1] / 25.4,
                t.offsets[2] / 25.4,
                t.diameter / 25.4
            )
        })
        .collect()
}

fn rounded(v: [f64; 3]) -> [f64; 3] {
    v.map(|x| (x * 1e4).round() / 1e4)
}

/// Our reading of `text` on a machine with X Y Z, no work offsets, starting at 0, with
/// [`TOOL_TABLE`].
fn our_program(text: &str) -> Result<pkm_nc::interp::Program, pkm_nc::NcError> {
    our_program_with(text, &pkm_nc::params::WorkOffsets::default())
}

/// [`our_program`] with the work offsets and home positions of a parameter file.
fn our_program_with(
    text: &str,
    offsets: &pkm_nc::params::WorkOffsets,
) -> Result<pkm_nc::interp::Program, pkm_nc::NcError> {
    let tools = pkm_nc::tools::ToolTable::parse(TOOL_TABLE).expect("the test's table");
    pkm_nc::interp::read(
        text,
        &pkm_nc::interp::Machine {
            axes: &["x", "y", "z"],
            start: [0.0; 6],
            work_offsets: offsets.origins,
            block_delete: false,
            homes: offsets.homes,
            tools: Some(&tools),
        },
    )
}

/// Our moves of `text` ([`our_program`]).
fn ours(text: &str) -> Vec<Canonical> {
    ours_with(text, &pkm_nc::params::WorkOffsets::default())
}

/// Our moves of `text` with `offsets` ([`our_program_with`]).
fn ours_with(text: &str, offsets: &pkm_nc::params::WorkOffsets) -> Vec<Canonical> {
    use pkm_nc::interp::{Action, Path};
    let program = our_program_with(text, offsets).unwrap_or_else(|e| panic!("{e}"));
    // A spline's pieces are left out, as `rs274` prints a spline apart (`NURBS_FEED`, no moves).
    let lines: Vec<&str> = text.lines().collect();
    let spline_line = |line: usize| lines.get(line.wrapping_sub(1)).is_some_and(|l| is_spline_line(l));
    program
        .blocks
        .iter()
        .filter(|b| !spline_line(b.line))
        .filter_map(|b| match b.action {
            // Moves that go nowhere are left out, as on LinuxCNC's side.
            Action::Move {
                from,
                to,
                path: Path::Line,
                ..
            } if rounded([from[0], from[1], from[2]]) == rounded([to[0], to[1], to[2]]) => None,
            Action::Move {
                to, path, feed_mm_min, ..
            } => Some(Canonical {
                kind: match (path, feed_mm_min) {
                    (Path::Arc { .. }, _) => "arc",
                    (_, None) => "rapid",
                    _ => "feed",
                },
                end: rounded([to[0], to[1], to[2]]),
                arc: match path {
                    Path::Arc { center, clockwise, .. } => Some(([center[0], center[1]], clockwise)),
                    Path::Line => None,
                },
                feed: feed_mm_min,
            }),
            _ => None,
        })
        .collect()
}

/// Whether a program line holds G5 or G5.1 (not G53, G54, …; in any case, with leading zeros).
fn is_spline_line(line: &str) -> bool {
    let upper = line.to_uppercase();
    let code = upper.split('(').next().unwrap_or("").replace(' ', "");
    code.match_indices('G').any(|(at, _)| {
        let rest = code[at + 1..].trim_start_matches('0');
        rest.starts_with('5')
            && !rest[1..].starts_with(|c: char| c.is_ascii_digit())
            && !rest[1..].starts_with(".2")
            && !rest[1..].starts_with(".3")
    })
}

/// LinuxCNC's moves of `text`, from its `rs274` (canonical calls); moves that go nowhere (the
/// zero-length feed it issues for a motion mode set alone) left out.
fn linuxcnc(rs274: &std::path::Path, text: &str) -> Vec<Canonical> {
    canonical_moves(&rs274_output(rs274, text, None))
}

/// The moves in what `rs274` printed.
fn canonical_moves(stdout: &str) -> Vec<Canonical> {
    let mut at = [0.0; 3];
    let mut moves = Vec::new();
    // rs274 prints positions in program coordinates, with the offsets it sets apart: the work
    // system's (`SET_G5X_OFFSET`), G92's or G52's (`SET_G92_OFFSET`) and the tool's
    // (`USE_TOOL_LENGTH_OFFSET`), added back here.
    let (mut g5x, mut g92, mut tool) = ([0.0; 3], [0.0; 3], [0.0; 3]);
    // rs274 prints lengths in the units in force (inches after G20), arcs in their plane.
    let mut unit = 1.0;
    let mut plane = [0, 1, 2];
    // The feed: per minute, or per revolution at the spindle's speed.
    let (mut feed, mut per_rev, mut rpm) = (0.0, false, 0.0);
    for line in stdout.lines() {
        let Some((call, args)) = line.split_once('(') else {
            continue;
        };
        let call = call.rsplit(' ').next().unwrap_or("");
        match call {
            "USE_LENGTH_UNITS" => {
                unit = if args.contains("INCHES") { 25.4 } else { 1.0 };
                continue;
            }
            "SELECT_PLANE" => {
                plane = if args.contains("XZ") {
                    [2, 0, 1]
                } else if args.contains("YZ") {
                    [1, 2, 0]
                } else {
                    [0, 1, 2]
                };
                continue;
            }
            "USE_TOOL_LENGTH_OFFSET" => {
                // "x y z, a b c, u v w": the first group.
                let first = args.split(',').next().unwrap_or("");
                let v: Vec<f64> = first.split_whitespace().filter_map(|x| x.parse().ok()).collect();
                tool = [v[0] * unit, v[1] * unit, v[2] * unit];
                continue;
            }
            _ => {}
        }
        let n: Vec<f64> = args
            .trim_end_matches(')')
            .split(',')
            .filter_map(|x| x.trim().parse::<f64>().ok())
            .collect();
        let lengths: Vec<f64> = n.iter().map(|x| x * unit).collect();
        match call {
            "SET_G5X_OFFSET" if n.len() >= 4 => {
                // The first value is the system's number, not a length.
                g5x = [lengths[1], lengths[2], lengths[3]];
                continue;
            }
            "SET_G92_OFFSET" if n.len() >= 3 => {
                g92 = [lengths[0], lengths[1], lengths[2]];
                continue;
            }
            "SET_FEED_MODE" if n.len() >= 2 => {
                per_rev = n[1] == 1.0;
                continue;
            }
            "SET_FEED_RATE" if !n.is_empty() => {
                feed = lengths[0];
                continue;
            }
            "SET_SPINDLE_SPEED" if n.len() >= 2 => {
                rpm = n[1];
                continue;
            }
            _ => {}
        }
        let n = lengths;
        let offset: [f64; 3] = std::array::from_fn(|c| g5x[c] + g92[c] + tool[c]);
        let (kind, end, arc) = match call {
            "STRAIGHT_TRAVERSE" => ("rapid", [n[0], n[1], n[2]], None),
            "STRAIGHT_FEED" => ("feed", [n[0], n[1], n[2]], None),
            // First end, second end, first centre, second centre, rotation, the normal axis'
            // end, … — first and second in the plane's order (X Y, Z X, Y Z).
            "ARC_FEED" => {
                let mut end = [0.0; 3];
                for (k, c) in plane.iter().enumerate() {
                    end[*c] = [n[0], n[1], n[5]][k];
                }
                ("arc", end, Some(([n[2], n[3]], n[4] < 0.0)))
            }
            _ => continue,
        };
        let end = rounded(std::array::from_fn(|c| end[c] + offset[c]));
        let arc = arc.map(|([c0, c1], cw)| ([c0 + offset[plane[0]], c1 + offset[plane[1]]], cw));
        if kind != "arc" && end == rounded(at) {
            continue;
        }
        at = end;
        let feed = (kind != "rapid").then_some(if per_rev { feed * rpm } else { feed });
        moves.push(Canonical { kind, end, arc, feed });
    }
    moves
}

/// LinuxCNC's `rs274` where Debian's `linuxcnc-uspace` installed it; else the test `name` is
/// skipped (and fails where the run requires its prerequisites).
fn rs274_or_skip(name: &str) -> Option<&'static std::path::Path> {
    let found = ["/usr/bin/rs274", "/usr/local/bin/rs274"]
        .iter()
        .map(std::path::Path::new)
        .find(|p| p.exists());
    if found.is_none() {
        common::skip(
            name,
            "no rs274 here (apt-get install linuxcnc-uspace; .ci/run installs it)",
        );
    }
    found
}

/// What LinuxCNC 2.9's `rs274` prints for `text`, read with [`tool_table_in_inches`] and the
/// parameter file `var` if one is given (its text as `rs274` reads it: in inches).
fn rs274_output(rs274: &std::path::Path, text: &str, var: Option<&str>) -> String {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("p.ngc");
    std::fs::write(&file, text).expect("write");
    std::fs::write(dir.path().join("tool.tbl"), tool_table_in_inches()).expect("write");
    let mut args = vec!["-t", "tool.tbl", "-g"];
    if let Some(var) = var {
        std::fs::write(dir.path().join("p.var"), var).expect("write");
        args.extend(["-v", "p.var"]);
    }
    // One rs274 at a time: two run at once (two tests) have printed nothing for one of them.
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    // A run that ends without PROGRAM_END (seen once in CI, not reproduced) is tried again.
    let run = || {
        std::process::Command::new(rs274)
            .args(&args)
            .arg(&file)
            .current_dir(dir.path())
            .output()
            .expect("rs274 runs")
    };
    let mut out = run();
    for _ in 0..2 {
        let said = String::from_utf8_lossy(&out.stdout);
        // (A parameter file it refuses ends the run before the program.)
        if said.contains("PROGRAM_END") || said.contains("Parameter file") {
            break;
        }
        out = run();
    }
    String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr)
}

/// Subroutines with arguments, defined after M2 (LinuxCNC finds them), named and numbered
/// parameters set in parallel.
const PARAMETERS_AND_SUBROUTINES: &str = "#1 = 5\n#<r> = [#1 * 2]\nG1 X#1 Y[#<r>+1] F[100*2]\n#2 = 3 #3 = #2\nG0 X#3\no100 call [1] [2]\nG1 X#1\no<foo> call [7]\nG0 Z#<_value>\nM2\no100 sub\nG1 X#1 Y#2\no100 endsub\no<foo> sub\nG1 Z#1\no<foo> endsub [#1 + 1]\n";

/// LinuxCNC's operators, functions and precedence.
const EXPRESSIONS: &str = "G1 F100 X[round[2.5]] Y[round[-2.5]] Z[-7 mod 3]\nX[2**3**2] Y[1+2*3-4/2] Z[1 lt 2 and 3 gt 4]\nX[atan[1]/[1]] Y[fix[-1.5]] Z[fup[-1.5]]\nX[1 eq 1.00009] Y[1 eq 1.00011] Z[-[2]]\nX-#1 Y[exists[#<nope>]] Z[sqrt[16]+abs[-2]]\n#<_g> = 3\nX#<_g> Y[2 - 3 - 4] Z[8/2/2]\nX[5 mod -3] Y[1 or 0 xor 1] Z[2*-3]\nX[sin[30]] Y[cos[60]] Z[tan[45]]\nX[exp[0]] Y[ln[1]] Z[acos[0]+asin[1]]\nX[1 ne 2] Y[3 ge 3] Z[2 le 1]\nX [ 1 + 2 ] Y # 1 Z 1 0\nG55 G0 X#5420 Y#5220\nG54 X#<_coord_system> Y#<_motion_mode> Z#<_feed>\nM2\n";

/// Conditionals and every kind of loop, break and continue. (Not `continue` in a `do` loop:
/// LinuxCNC 2.9 then runs a later `repeat` twice over, a fault of its own we do not copy.)
const LOOPS: &str = "#1 = 0\no1 while [#1 LT 4]\n#1 = [#1 + 1]\no2 if [#1 EQ 2]\no1 continue\no2 endif\nG1 X#1 F100\no1 endwhile\no6 do\nG1 X[#1 * 2]\n#1 = [#1 - 1]\no6 while [#1 GT 2]\no3 repeat [2.6]\nG1 Y[#1 + 1]\n#1 = [#1 + 1]\no3 endrepeat\n#2 = 0\no4 while [1]\n#2 = [#2 + 1]\no5 if [#2 GT 3]\no4 break\no5 elseif [#2 EQ 2]\nG1 Z-2\no5 else\nG1 Z[-#2]\no5 endif\no4 endwhile\nM2\n";

/// G83 pecks from above R, G98 back to the series' start, G91 with three repeats (the moves of
/// LinuxCNC 2.9's `rs274`).
const CANNED_CYCLES: &str =
    "G0 Z10\nG83 X1 Y1 Z-5 R2 Q2 F100\nG98 G81 X5 Z-1 R1\nG91 G81 X2 Y0 R-3 Z-1 L3\nG90 G0 X0\nM2\n";

/// The dialect CAM programs use, read by our interpreter and by LinuxCNC 2.9's
/// `rs274` (Debian's `linuxcnc-uspace`), give the same moves. Without `rs274` here the test says
/// so and passes; the interpreter's own tests check the same programs against the moves written
/// in them.
#[test]
fn the_cam_dialect_gives_the_moves_linuxcnc_gives() {
    let Some(rs274) = rs274_or_skip("nc::the_cam_dialect_gives_the_moves_linuxcnc_gives") else {
        return;
    };
    let programs = [
        "G21 G90 G17\nG1 F600\nX10\nY5\nG0 X0 Y0\nM2\n",
        "%\nG40 G49 G80 G94 G17 G21 G90\nG0 X1 Y1\nG1 Z-1 F300\nX5 Y 1 0.5\nG0 Z2\n%\n",
        "G1 X1 F100\nM2\nG1 X5\nnot G-code at all\n",
        "G1 X1 F100\n/G1 X5\nM2\n",
        "G0 X10 Y0\nG2 I-10 F100\nG3 X0 Y10 I-10 J0\nG90.1 G2 X10 Y0 I0 J0\nG91.1 G3 X0 Y10 I-10\nM30\n",
        "G61.1 G1 X1 F100\nG64 P0 X2\nG64 P0.01 Q0.01 X3\nG64 P-1 X4\nG64 X5\nG61 X6\nM2\n",
        "G20 G1 X1 F10\nG21 G91 X1 Y2\nG90 X0 Y0\nM2\n",
        // Parameters, expressions, subroutines, conditionals and loops.
        PARAMETERS_AND_SUBROUTINES,
        EXPRESSIONS,
        LOOPS,
        // Canned cycles: G83 pecks, G98 and G99, G91 with L repeats, another plane.
        CANNED_CYCLES,
        "G0 Z5\nG18 G81 X-3 Y1 Z2 R4 F50\nX-6\nG80\nG0 Y5\nG19 G99 G82 X-2 Y1 Z-2 R3 P0.5\nM2\n",
        "G20 G0 Z1\nG83 X0.5 Z-0.3 R0.1 Q0.1 F4\nM2\n",
        // G10 L2 and L20 on the system in force and on another.
        "G10 L2 P2 X5 Y1\nG0 X1\nG55\nG0 X1\nG10 L20 P2 X0\nG0 X1\nG10 L2 P0 Z3\nG0 X0\nG54\nG0 X0\nG0 X3\nG10 L20 P1 X1\nG0 X0\nM2\n",
        // The chip-breaking peck, the bores with and without a dwell, in G98 and G99.
        "G0 Z5\nG73 X1 Y1 Z-5 R2 Q2 F100\nX3 Q1.5\nG98 G85 X4 Y2 Z-3 R1\nG99 G89 X5 Z-2 R1 P0.5\nG80\nG0 X0\nM2\n",
        // Going home: G28 through a point, the stored position of G28.1, G30 for one axis, and
        // a cycle series that G28 ends.
        "G0 X10 Y5 Z3\nG28.1\nG0 X1 Y1 Z1\nG91 G28 Z0\nG90 G28\nG0 X4 Y4\nG30 X2\nG30.1\nG0 X0\nG30\nM2\n",
        "G81 X1 Z-1 R1 F10\nG28 Z5\nX3\nM2\n",
        // G92 and its variants, G52 (which shares G92's offset), G92 after G52.
        "G0 X3\nG92 X5\nG0 X0 Y1\nG92.2\nG0 X1\nG92.3\nG0 X2\nG92.1\nG0 X3\nG52 X5 Y-1\nG0 X0 Y0\nG92 X2\nG0 X1\nG52 X0 Y0\nG0 X1\nM2\n",
        // Tools: a change, G43 with H and with the tool in the spindle, G43.1 (the axes it
        // names), G49, in inches. (Not G20 while an offset is in force: rs274 then mixes an
        // offset in millimetres with positions in inches.)
        "G21 G90\nT1 M6\nG43 H1\nG0 X1 Y1 Z5\nG1 Z-1 F100\nG49 G0 Z2\nT2 M6 M3 S1000\nG43\nG0 Z0\nG43.1 X1 Z2\nG0 Z0\nG43.1 Z3\nG0 Z1\nG49\nG20 G43.1 Z0.5\nG0 Z1\nG21 G49\nG0 Z0\nM2\n",
        // (M61 then G43 without H: rs274 applies no offset, its stand-alone tool table not knowing
        // M61's tool; LinuxCNC's documented meaning, ours, applies the tool's.)
        "G43 H2 G0 Z1 X1\nG43 H0\nG0 Z2\nM61 Q5\nG43 H5\nG0 Z3\nM5 M9\nM2\n",
        // The tool table changed by G10 L1 and L10; offsets under G92 and G10 L20; G28 and G53
        // with a tool offset.
        "T1 M6\nG10 L1 P1 Z20 R2\nG43 H1\nG0 Z1\nG0 X1 Z3\nG10 L10 P2 Z0\nG43 H2\nG0 Z1\nM2\n",
        "G43 H1\nG0 Z1\nG92 Z0\nG0 Z-1\nG10 L20 P1 Z5\nG0 Z0\nG92.1\nG0 Z10\nG28 Z5\nG53 G0 Z2\nG0 Z1\nM2\n",
        // Feed modes: inverse time on lines and arcs, per revolution at the programmed speed.
        "G93 G1 X10 F2\nG2 X20 I5 F3\nG1 Y5 Z1 F0.5\nG94 G1 X0 F100\nS2000 G95 G1 X5 F0.1\nY3\nS1000 G1 X2\nG94 G1 Y0 F50\nM2\n",
        // Messages do not move the tool.
        "(MSG, starting)\nG0 X1 (MSG,on a move)\n#1=2\n(DEBUG, at #1 #<_x>)\nG0 X#1\nM2\n",
        // #5401 … #5403: the table's offsets of the tool in the spindle, with G43 or not (in
        // inches: rs274's table, and so these parameters, are in its machine units).
        "G20\nT1 M6\nG0 X#5403\nG43\nG0 Y#5403\nG49\nG0 Z#5403\nT2 M6\nG0 X#5401 Y#5403\nM2\n",
        // Feeds below 0.1 a minute per revolution and in inverse time (realistic ones).
        "S1000 G95 G1 X1 F0.05\nG20\nS500 G1 X0.1 F0.004\nG21 G93 G1 X10 F0.05\nG1 X10.001 F1\nM2\n",
        // Arcs whose end lies a little off their circle (3-decimal CAM output): within
        // LinuxCNC's 0.0283 mm, or 0.1 % of a large radius.
        "G1 X2 Y0 F600\nG3 X0 Y2.0025 I-2 J0\nG2 X2 Y0.01 I0 J-2.0025\nG0 X50 Y0\nG3 X0 Y50.04 I-50 J0\nM2\n",
    ];
    for text in programs {
        let (o, l) = (ours(text), linuxcnc(rs274, text));
        assert!(agree(&o, &l), "{text}\nours: {o:?}\nLinuxCNC: {l:?}");
    }
}

/// Whether two lists of moves agree: the same kinds, ends and centres within what `rs274`
/// prints (4 decimals, of inches after G20: 0.00254 mm).
fn agree(ours: &[Canonical], theirs: &[Canonical]) -> bool {
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 0.003);
    // Feeds as rs274 prints them: 4 decimals of the program's units per minute.
    let feeds = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(x), Some(y)) => (x - y).abs() <= 0.003 + 1e-6 * x.abs(),
        (None, None) => true,
        _ => false,
    };
    ours.len() == theirs.len()
        && ours.iter().zip(theirs).all(|(a, b)| {
            a.kind == b.kind
                && feeds(a.feed, b.feed)
                && close(&a.end, &b.end)
                && match (a.arc, b.arc) {
                    (None, None) => true,
                    (Some((ca, da)), Some((cb, db))) => da == db && close(&ca, &cb),
                    _ => false,
                }
        })
}

/// LinuxCNC's own example programs (Debian's `linuxcnc-uspace` installs them in
/// /usr/share/linuxcnc/ncfiles): every one we read gives the moves LinuxCNC's `rs274` gives, and
/// these, which use subroutines, return values, loops, expressions, arcs by radius in inches and
/// all three planes, are read. The others need what we refuse (tool changes, cutter
/// compensation, probing, lathe cycles, …) and are listed with why.
#[test]
fn linuxcncs_example_programs_give_its_moves() {
    let (rs274, dir) = (
        std::path::Path::new("/usr/bin/rs274"),
        std::path::Path::new("/usr/share/linuxcnc/ncfiles"),
    );
    if !rs274.exists() || !dir.is_dir() {
        common::skip(
            "nc::linuxcncs_example_programs_give_its_moves",
            "no LinuxCNC here (apt-get install linuxcnc-uspace)",
        );
        return;
    }
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .expect("ncfiles")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "ngc"))
        .collect();
    files.sort();
    let mut read = Vec::new();
    for path in files {
        let Ok(text) = std::fs::read_to_string(&path) else {
            continue;
        };
        let name = path
            .file_stem()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        match our_program(&text) {
            Err(e) => eprintln!("{name}: not read: {e}"),
            // `T1 M06 G43 H1` on one line: after a tool change rs274 takes the position again
            // from its stand-alone canon, which knows nothing of the tool offset, so that its
            // next `G0 X1 Y1` raises Z by the tool's length; LinuxCNC itself takes the position
            // with the offset, and Z stays. Ours keeps Z too (asserted below).
            Ok(program) if name == "skeleton" => {
                let first_xy = program.blocks.iter().find_map(|b| match b.action {
                    pkm_nc::interp::Action::Move { from, to, .. } if to[0] != 0.0 => Some((from[2], to[2])),
                    _ => None,
                });
                assert_eq!(first_xy, Some((0.0, 0.0)), "skeleton: the move to X1 Y1 stays at Z0");
                read.push(name);
            }
            Ok(_) => {
                let (o, l) = (ours(&text), linuxcnc(rs274, &text));
                let first = o
                    .iter()
                    .zip(&l)
                    .position(|(a, b)| !agree(std::slice::from_ref(a), std::slice::from_ref(b)));
                assert!(
                    agree(&o, &l),
                    "{name}: {} moves here, {} by LinuxCNC; the first that differs: {:?} and {:?}",
                    o.len(),
                    l.len(),
                    first.and_then(|i| o.get(i)),
                    first.and_then(|i| l.get(i))
                );
                read.push(name);
            }
        }
    }
    for name in [
        "3dtest",
        "arcspiral",
        "flowsnake",
        "tort",
        "retval",
        "factorial",
        "g881",
        "g882",
        "skeleton",
        // Polar coordinates: lines, a spiral of G91 steps, bolt circles of canned cycles.
        "polar",
        "spiral",
        "hole-circle",
        // Cubic splines (G5) in loops: 13 000 pieces, the moves between them rs274's.
        "systems",
        // Cutter compensation: contours with G41 and G42, the tool from the spindle or D,
        // entry and exit moves (`mmount`'s, before its rigid tapping, in the compensation test).
        "comp",
        "comp-g1",
        "comp311",
        "comp311_2",
        "gmoccapy_2_tools_with_cutter_radius_compensation",
    ] {
        assert!(read.iter().any(|r| r == name), "{name} was not read: {read:?}");
    }
}

/// Message comments read as LinuxCNC 2.9's `rs274` writes them (`MESSAGE(…)`): which comments
/// are messages, the text after the comma, DEBUG's parameters substituted, a line's last comment
/// only; and programs both refuse (a tool not in the table, T not whole, G95 with no spindle
/// speed, G93 without F).
#[test]
fn messages_and_refusals_agree_with_linuxcnc() {
    let Some(rs274) = [std::path::Path::new("/usr/bin/rs274")]
        .into_iter()
        .find(|p| p.exists())
    else {
        common::skip(
            "nc::messages_and_refusals_agree_with_linuxcnc",
            "no rs274 here (apt-get install linuxcnc-uspace; .ci/run installs it)",
        );
        return;
    };
    let text = "( MSG,a)\n(msg,b)\n(MSG c)\n(MSG,)\n#1=2.5\n(DEBUG,x=#1 y=#<nope> z=#<_y> w=#5220 #)\n(debug, -#1)\nG0 X1 (MSG, in block)\nG0 X2 (DEBUG,#1) (MSG,two)\n(DEBUG,#[1+1])\nT1 M6 (MSG, tool 1)\nM2\n";
    let theirs: Vec<String> = rs274_output(rs274, text, None)
        .lines()
        .filter_map(|l| {
            l.split_once("MESSAGE(\"")
                .map(|(_, m)| m.trim_end_matches("\")").to_string())
        })
        .collect();
    let ours: Vec<String> = our_program(text)
        .unwrap_or_else(|e| panic!("{e}"))
        .messages
        .into_iter()
        .map(|m| m.text)
        .collect();
    assert_eq!(ours, theirs);
    assert_eq!(theirs.len(), 9, "{theirs:?}");
    for text in [
        "T99 M6\nM2\n",
        "G43 H99\nM2\n",
        "T1.5\nM2\n",
        "T-1 M6\nM2\n",
        "T1 T2 M6\nM2\n",
        "G95 G1 X10 F2\nM2\n",
        "G93 G1 X10 F2\nG1 X20\nM2\n",
        "G93 G81 X1 Z-1 R1 F2\nM2\n",
        // Arcs whose end lies too far off their circle.
        "G1 X2 Y0 F600\nG3 X0 Y2.03 I-2 J0\nM2\n",
        "G1 X50 Y0 F600\nG3 X0 Y50.06 I-50 J0\nM2\n",
    ] {
        assert!(our_program(text).is_err(), "we read {text:?}");
        assert!(
            !rs274_output(rs274, text, None).contains("PROGRAM_END"),
            "rs274 read {text:?}"
        );
    }
}

/// A parameter file as LinuxCNC 2.9's `rs274` reads it (given its copy in inches, its machine
/// units): the G54 and G55 origins and G28's position move the same moves; and a file whose
/// numbers do not increase is refused by both.
#[test]
fn a_parameter_file_is_read_as_linuxcnc_reads_it() {
    let Some(rs274) = rs274_or_skip("nc::a_parameter_file_is_read_as_linuxcnc_reads_it") else {
        return;
    };
    // (number, value in mm): G28's position, G54's and G55's origins.
    let values = [
        (5161, 10.0),
        (5162, -5.0),
        (5163, 20.0),
        (5221, 1.5),
        (5222, -2.0),
        (5223, 0.5),
        (5241, 12.7),
        (5242, 3.0),
    ];
    let file = |scale: f64, order: &[usize]| -> String {
        order
            .iter()
            .map(|&k| format!("{}\t{:.9}\n", values[k].0, values[k].1 / scale))
            .collect()
    };
    let in_order: Vec<usize> = (0..values.len()).collect();
    let ours_read = pkm_nc::params::parse(&file(1.0, &in_order)).expect("our reading");
    let program = "G0 X1 Y1 Z1\nG55 G0 X0 Y0\nG54 G1 X2 F100\nG28\nG0 X0 Y0 Z0\nM2\n";
    let theirs = canonical_moves(&rs274_output(rs274, program, Some(&file(25.4, &in_order))));
    let ours = ours_with(program, &ours_read);
    assert!(
        theirs.len() >= 5 && agree(&ours, &theirs),
        "ours: {ours:?}\nLinuxCNC: {theirs:?}"
    );
    // Out of order: #5222 before #5221.
    let mut swapped = in_order.clone();
    swapped.swap(3, 4);
    assert_eq!(
        pkm_nc::params::parse(&file(1.0, &swapped)).map_err(|e| e.to_string()),
        Err("5:1: #5221 after #5222: the numbers must increase from line to line, as LinuxCNC reads them".to_string())
    );
    let said = rs274_output(rs274, program, Some(&file(25.4, &swapped)));
    assert!(said.contains("Parameter file out of order"), "{said}");
}

/// The program coordinates the DRO shows while a program runs (our interpreter's
/// `Action::WorkOffset`) are LinuxCNC's: at every move, the work system in force and the offset
/// of program coordinates from machine coordinates agree with what `rs274` sets before that move
/// (`SET_G5X_OFFSET`, `SET_G92_OFFSET` and `USE_TOOL_LENGTH_OFFSET`, summed), through G54 … G59,
/// G10 L2 and L20, G92 and its variants, G52, G43, G43.1 and G49.
#[test]
fn the_program_coordinates_shown_at_every_move_are_linuxcncs() {
    let Some(rs274) = rs274_or_skip("nc::the_program_coordinates_shown_at_every_move_are_linuxcncs") else {
        return;
    };
    let programs = [
        "G10 L2 P2 X5 Y1\nG0 X1\nG55\nG0 X1\nG10 L20 P2 X0\nG0 X1\nG10 L2 P0 Z3\nG0 X0\nG54\nG0 X0\nG0 X3\nG10 L20 P1 X1\nG0 X0\nM2\n",
        "G0 X3\nG92 X5\nG0 X0 Y1\nG92.2\nG0 X1\nG92.3\nG0 X2\nG92.1\nG0 X3\nG52 X5 Y-1\nG0 X0 Y0\nG92 X2\nG0 X1\nG52 X0 Y0\nG0 X1\nM2\n",
        "G21 G90\nT1 M6\nG43 H1\nG0 X1 Y1 Z5\nG1 Z-1 F100\nG49 G0 Z2\nT2 M6 M3 S1000\nG43\nG0 Z0\nG43.1 X1 Z2\nG0 Z0\nG43.1 Z3\nG0 Z1\nG49\nG0 Z0\nM2\n",
        "G43 H1\nG0 Z1\nG92 Z0\nG0 Z-1\nG10 L20 P1 Z5\nG0 Z0\nG92.1\nG0 Z10\nG56 G0 X1\nG10 L2 P3 X-2 Y4\nG0 Y1\nG59 G0 X2\nM2\n",
    ];
    for text in programs {
        let ours = our_frames(text);
        let theirs = linuxcnc_frames(&rs274_output(rs274, text, None));
        let agree = ours.len() == theirs.len()
            && ours
                .iter()
                .zip(&theirs)
                .all(|(a, b)| a.0 == b.0 && a.1.iter().zip(&b.1).all(|(x, y)| (x - y).abs() <= 0.003));
        assert!(agree, "{text}\nours: {ours:?}\nLinuxCNC: {theirs:?}");
        assert!(ours.len() > 1, "{text}: the program coordinates change: {ours:?}");
    }
}

/// The program coordinates in force at each of our moves (that goes somewhere), each change once:
/// (work system 1 … 6, offset x y z).
fn our_frames(text: &str) -> Vec<(u8, [f64; 3])> {
    use pkm_nc::interp::Action;
    let program = our_program(text).unwrap_or_else(|e| panic!("{e}"));
    let mut frame = None;
    let mut frames: Vec<(u8, [f64; 3])> = Vec::new();
    for b in &program.blocks {
        match b.action {
            Action::WorkOffset { system, offset } => frame = Some((system, rounded([offset[0], offset[1], offset[2]]))),
            Action::Move { from, to, .. } if rounded([from[0], from[1], from[2]]) != rounded([to[0], to[1], to[2]]) => {
                let now = frame.expect("program coordinates before the first move");
                if frames.last() != Some(&now) {
                    frames.push(now);
                }
            }
            _ => {}
        }
    }
    frames
}

/// The program coordinates `rs274` has set before each move it prints, each change once.
fn linuxcnc_frames(stdout: &str) -> Vec<(u8, [f64; 3])> {
    let (mut system, mut g5x, mut g92, mut tool) = (1u8, [0.0; 3], [0.0; 3], [0.0; 3]);
    let mut unit = 1.0;
    let mut frames: Vec<(u8, [f64; 3])> = Vec::new();
    for line in stdout.lines() {
        let Some((call, args)) = line.split_once('(') else {
            continue;
        };
        let call = call.rsplit(' ').next().unwrap_or("");
        let n: Vec<f64> = args
            .trim_end_matches(')')
            .split([',', ' '])
            .filter_map(|x| x.trim().parse::<f64>().ok())
            .collect();
        match call {
            "USE_LENGTH_UNITS" => unit = if args.contains("INCHES") { 25.4 } else { 1.0 },
            "SET_G5X_OFFSET" if n.len() >= 4 => {
                system = n[0] as u8;
                g5x = [n[1] * unit, n[2] * unit, n[3] * unit];
            }
            "SET_G92_OFFSET" if n.len() >= 3 => g92 = [n[0] * unit, n[1] * unit, n[2] * unit],
            "USE_TOOL_LENGTH_OFFSET" if n.len() >= 3 => tool = [n[0] * unit, n[1] * unit, n[2] * unit],
            "STRAIGHT_TRAVERSE" | "STRAIGHT_FEED" | "ARC_FEED" => {
                let now = (system, rounded(std::array::from_fn(|c| g5x[c] + g92[c] + tool[c])));
                if frames.last() != Some(&now) {
                    frames.push(now);
                }
            }
            _ => {}
        }
    }
    frames
}

/// Polar coordinates (`@` the distance, `^` the angle around the program's origin) give the moves
/// LinuxCNC 2.9's `rs274` gives: in G90 both, or either alone (the other as the tool's position
/// has it); in G91 a distance that lengthens the tool's own, an angle that turns it on; around
/// the origin G92 moved; a feed's and an arc's end; in inches. Both refuse the same programs,
/// ours saying why at the word.
#[test]
fn polar_coordinates_give_linuxcncs_moves_and_refusals() {
    let Some(rs274) = rs274_or_skip("nc::polar_coordinates_give_linuxcncs_moves_and_refusals") else {
        return;
    };
    for text in [
        "G0 X3 Y4\nG1 F100 @10\n^90\nG91 @-5\n^-45\nG90 G92 X0 Y0\nG0 @2 ^180\nG92.1\nG0 X5 Y0\nG3 @5 ^90 I-5 J0\nG20 G0 @1 ^30\nM2\n",
        "G0 @5 ^30 Z2\nG1 F200 ^120\nG91 ^120 Z-1\n^120\n@2.5\nG90 G2 @7.5 ^-90 R7.5\nM2\n",
        "G10 L2 P2 X10 Y-5\nG55 G0 @4 ^45\nG54 G0 @4 ^45\nM2\n",
        // The plane in force before the block counts, as in LinuxCNC: this moves in XY.
        "G18 G0 @5 ^30\nG0 X0 Z1\nM2\n",
    ] {
        let (o, l) = (ours(text), linuxcnc(rs274, text));
        assert!(agree(&o, &l), "{text}\nours: {o:?}\nLinuxCNC: {l:?}");
        assert!(o.len() >= 2, "{text}: {o:?}");
    }
    for (text, why) in [
        (
            "G1 F100 X1 @5 ^30\nM2\n",
            "1:9: X and polar coordinates (@, ^) in one block: the end is one or the other",
        ),
        (
            "G1 F100 @5 Y1\nM2\n",
            "1:12: Y and polar coordinates (@, ^) in one block: the end is one or the other",
        ),
        (
            "G18 G0 X1\nG0 @5 ^30\nM2\n",
            "2:4: polar coordinates (@, ^) are taken in the XY plane only (G17)",
        ),
        (
            "G53 G0 @5 ^30\nM2\n",
            "1:8: polar coordinates (@, ^) cannot go with G53 (machine coordinates)",
        ),
        (
            "G0 @5\nM2\n",
            "1:4: a distance (@) alone needs an angle (^) where the tool stands at the program's origin",
        ),
        (
            "G91 G1 F100 @5\nM2\n",
            "1:13: an incremental polar move (G91 @) has no direction at the program's origin: move off it, or use G90",
        ),
        (
            "G91 G0 ^30\nM2\n",
            "1:8: an incremental polar move (G91 ^) turns nothing at the program's origin: move off it, or use G90",
        ),
        (
            "G0 Z1\nG91 G81 R0 Z-1 ^60 L6 F10\nM2\n",
            "2:16: G81: an incremental polar step (G91 @, ^) has no direction at the program's origin: move off it, or use G90",
        ),
        (
            "G0 X1\nG92 @1\nM2\n",
            "2:5: polar coordinates (@, ^) give a move's end (G0, G1, G2, G3), not G92's values",
        ),
    ] {
        let ours = our_program(text).map(|_| ()).map_err(|e| e.to_string());
        assert_eq!(ours, Err(why.to_string()), "{text}");
        assert!(
            !rs274_output(rs274, text, None).contains("PROGRAM_END"),
            "rs274 read {text:?}"
        );
    }
}

/// Compensated contours (G41, G42, G41.1, G42.1): the part's contour in the program, the tool's
/// centre one radius beside it. Each gives the path LinuxCNC 2.9's `rs274` gives — every move,
/// every corner arc, every shortened move in a concave corner, in the order it makes them: entry
/// moves (lines and arcs), convex and concave corners between lines and arcs both ways, rapids,
/// moves along the tool's axis between compensated moves, a helix, the exit after G40 and a
/// second compensation, G91, inches, the ZX plane (G18), a diameter given (G41.1, a negative one
/// on the other side), the tool from the table (`D`) or in the spindle.
const COMPENSATED_CONTOURS: [&str; 16] = [
    "G0 X-10 Y-10\nG41 D1\nG1 X0 Y0\nG1 X20\nG3 X30 Y10 R10\nG1 Y30\nG1 X0\nG1 Y0\nG40\nG0 X-10 Y-10\n",
    "G0 X-10 Y-10\nG42 D1\nG1 X0 Y0\nG1 X20\nG3 X30 Y10 R10\nG1 Y30\nG1 X0\nG1 Y0\nG40\nG0 X-10 Y-10\n",
    "G0 X-10 Y-10\nG41 D1\nG1 X0 Y0\nG1 X20\nG1 Y10\nG1 X5\nG1 Y5\nG1 X-3\nG40\nG0 X-10\n",
    "G0 X-10 Y-10\nG41 D1\nG1 X0 Y0\nG1 X20\nG1 X21 Y-1\nG1 X30 Y-1\nG40\nG0 Y-10\n",
    "G0 X0 Y-20\nG41 D1\nG1 X0 Y-10\nG3 X10 Y0 R10\nG1 X10 Y10\nG1 X0 Y10\nG1 X0 Y-10\nG40\nG0 X0 Y-20\n",
    "G0 X-5 Y-20\nG42 D1\nG1 X0 Y-10\nG2 X-10 Y0 R10\nG2 X0 Y10 R10\nG3 X10 Y20 R10\nG1 X30\nG2 X40 Y10 I0 J-10\nG1 Y-10\nG40\nG0 X50 Y-20\n",
    "G18 G0 X-10 Z-10\nG41 D1\nG1 X0 Z0\nG1 Z20\nG2 X10 Z30 R10\nG1 X30\nG1 Z0\nG40\nG0 X40 Z-10\n",
    "G0 X-10 Y-10\nG41.1 D8\nG1 X0 Y0\nX20\nY10\nX0\nY0\nG40\nG0 X-10 Y-10\nG42.1 D-4\nG1 X0 Y0\nX20\nY10\nX0\nY0\nG40 G0 X-10 Y-10\n",
    "G20 G0 X-1 Y-1\nG41 D1\nG1 X0 Y0\nX2\nG3 X2.5 Y0.5 R0.5\nG1 Y2\nX0\nY0\nG40\nG0 X-1 Y-1\n",
    "G0 X-10 Y-10\nG91 G41 D1\nG1 X10 Y10\nX20\nY10\nX-20\nY-10\nG40 G0 X-10 Y-10\n",
    "G0 X-10 Y-10 Z5\nG41 D1\nG1 X0 Y0\nG1 Z-1\nG1 X20\nG1 Z1\nG1 Z-1\nG1 Y10\nG1 Z2\nG1 X5\nG40\nG0 X-10\n",
    "G0 X-10 Y-10\nG41 D1\nG0 X0 Y0\nG0 X20\nG0 Y10\nG1 X0\nG0 Y0\nG40\nG0 X-10 Y-10\n",
    "G0 X0 Y-10\nG41 D1\nG3 X10 Y0 I0 J10\nG3 X0 Y10 I-10 J0\nG1 X-10\nG40\nG0 X-20 Y0\nG0 X0 Y-30\nG42 D1\nG2 X-20 Y0 R25\nG1 Y10\nG40\nG0 X-30\n",
    "G0 X-10 Y-10 Z0\nG41 D1\nG1 X0 Y0 F100\nG3 X20 Y0 I10 J0 Z-2\nG1 Y10\nG40\nG0 X-10\nG0 X-10 Y-10\nG41 D1\nG1 X0 Y0\nX20\nG40\nG1 X30 Y-10\nG41 D5\nG1 X40 Y0\nX60\nY20\nG40\nG0 X70\n",
    "G0 X-20 Y0\nT2 M6\nG41\nG1 X-10 Y0\nG3 X10 Y0 R10\nG3 X30 Y0 R10\nG2 X50 Y0 R10\nG1 Y-20\nG40\nG0 X60\n",
    "G0 X30 Y-20\nG42 D1\nG1 X30 Y0\nG3 X-30 Y0 R30\nG1 Y-20\nX30\nG40\nG0 Y-30\n",
];

#[test]
fn cutter_compensation_gives_linuxcncs_path_and_refusals() {
    let Some(rs274) = rs274_or_skip("nc::cutter_compensation_gives_linuxcncs_path_and_refusals") else {
        return;
    };
    for contour in COMPENSATED_CONTOURS {
        let text = format!("G21 F100\n{contour}M2\n");
        let (o, l) = (ours(&text), linuxcnc(rs274, &text));
        assert!(agree(&o, &l), "{text}\nours: {o:?}\nLinuxCNC: {l:?}");
        // The compensated path is not the programmed one.
        let plain = ours(
            &["G41.1 D8", "G42.1 D-4", "G41 D1", "G42 D1", "G41 D5", "G41\n"]
                .iter()
                .fold(text.clone(), |t, g| t.replace(g, "\n")),
        );
        assert!(o.iter().zip(&plain).any(|(a, b)| a.end != b.end), "{text}");
    }
    // LinuxCNC's mounting plate (`mmount`): 300 lines of profiles and pockets with G41, an
    // oversize tool, up to its rigid tapping (G33.1, which we refuse).
    if let Ok(plate) = std::fs::read_to_string("/usr/share/linuxcnc/ncfiles/mmount.ngc") {
        let upto = plate.find("T6 M6").expect("mmount's sixth tool");
        // Without its G43s: after a tool change the stand-alone rs274 takes the position
        // again without the tool's offset (see the examples' test), which moves Z apart.
        let text = format!("{}M2\n", &plate[..upto]).replace(" G43", "");
        let (o, l) = (ours(&text), linuxcnc(rs274, &text));
        assert!(
            agree(&o, &l) && o.len() > 300,
            "mmount: {} moves here, {} by LinuxCNC",
            o.len(),
            l.len()
        );
    }
    // Each refused where LinuxCNC refuses it (its message beside ours).
    for (text, ours_why, theirs) in [
        (
            "G41 D1\nG1 Z-1\n",
            "2:4: the entry move of cutter compensation must be longer than the tool's radius (3.000 mm): it is 0.000 mm long in the plane",
            "Length of cutter compensation entry move is not greater than the tool radius",
        ),
        (
            "G41 D1\nG3 X2 Y0 R1\n",
            "2:4: the entry arc of cutter compensation must end farther from where it starts than the tool's radius (3.000 mm)",
            "Radius of cutter compensation entry arc is not greater than the tool radius",
        ),
        (
            "G41 D1\nG1 X10\nX20\nX20 Y1\nX40\n",
            "5:1: the tool (radius 3.000 mm) cannot reach this concave corner without gouging: the move before it is too short",
            "Straight feed in concave corner cannot be reached by the tool without gouging",
        ),
        (
            "G41 D1\nG1 X10\nG3 X12 Y2 R2\n",
            "3:4: the tool (radius 3.000 mm) does not fit inside this arc (radius 2.000 mm): cutter compensation needs a smaller tool or a larger arc",
            "Tool radius not less than arc radius with comp",
        ),
        (
            "G41 D1\nG1 X10\nG40\nG2 X20 R5\n",
            "4:1: the move after G40 (cutter compensation off) must be a straight one (G0, G1), as in LinuxCNC: an arc would start off its circle",
            "The move just after exiting cutter compensation mode must be straight, not an arc",
        ),
        (
            "G41 D1\nG1 X10\nG0 X#5420\n",
            "3:5: #5420-#5428 (where the tool is) cannot be read while cutter compensation (G41, G42) is on, as in LinuxCNC: where a compensated move ends is known only with the move after it",
            "Cannot read current position with cutter radius compensation on",
        ),
        (
            "G1 X1 D1\n",
            "1:7: D belongs to G41, G42 (the tool whose diameter cutter compensation takes) or G41.1, G42.1 (the diameter)",
            "",
        ),
        (
            "G41 D8\n",
            "1:5: G41 D8: tool 8 is not in the tool table",
            "Requested tool 8 not found in the tool table",
        ),
        (
            "G41 D1.5\n",
            "1:5: G41's D is the number of a tool of the table, a whole number from 0: got 1.5 (G41.1, G42.1 take a diameter)",
            "G41 requires D word to be a whole number",
        ),
        (
            "G41.1\n",
            "1:1: G41.1 needs D: the tool's diameter",
            "G41.1 with no D word",
        ),
        (
            "G41\n",
            "1:1: G41 without a tool number compensates for the tool in the spindle, and this program has not put one there (T… M6, or M61 Q…): write G41 D…",
            "",
        ),
        (
            "G19\nG41 D1\n",
            "2:1: cutter compensation works in the XY (G17) and ZX (G18) planes, not in G19 (as LinuxCNC's)",
            "Cutter radius compensation allowed only in XY, XZ planes",
        ),
        (
            "G41 D1\nG42 D1\n",
            "2:1: cutter compensation is on already: G40 before G42",
            "Cannot turn cutter radius comp on when on",
        ),
        (
            "G41 D1\nG55\n",
            "2:1: the coordinate system cannot change while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change coordinate systems with cutter radius compensation on",
        ),
        (
            "G41 D1\nG64 P0.1\n",
            "2:1: path control (G61, G64) cannot change while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change control mode with cutter radius compensation on",
        ),
        (
            "G41 D1\nG92 X0\n",
            "2:1: G92 cannot change the offsets while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change axis offsets with cutter radius comp",
        ),
        (
            "G41 D1\nG18\n",
            "2:1: the plane cannot change while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change planes with cutter radius compensation on",
        ),
        (
            "G41 D1\nG28\n",
            "2:1: G28 cannot go home while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot use g28 or g30 with cutter radius comp",
        ),
        (
            "G41 D1\nG28.1\n",
            "2:1: G28.1 cannot store a position while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot set reference point with cutter compensation in effect",
        ),
        (
            "G41 D1\nG81 X1 Y1 Z-1 R1\n",
            "2:1: canned cycles cannot run while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot use canned cycles with cutter compensation on",
        ),
        (
            "G41 D1\nG0 X20\nG5 X30 Y10 I1 J1 P1 Q1\n",
            "3:1: a spline (G5, G5.1) cannot be compensated (a CAM post can write its contour as lines and arcs) while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot convert spline with cutter radius compensation",
        ),
        (
            "G41 D1\nM62 P1\n",
            "2:1: the program's outputs and inputs (M62 … M68) cannot be used while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot set motion output with cutter radius compensation on",
        ),
        (
            "G41 D1\nG0 X20\nG53 G0 X30\n",
            "3:1: G53 (machine coordinates) cannot go with cutter compensation (G41, G42): end it with G40 first",
            "Cannot use g53 with cutter radius comp",
        ),
        (
            "G41 D1\nG98\n",
            "2:1: the canned cycles' retract (G98, G99) cannot change while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change retract mode with cutter radius compensation on",
        ),
        (
            "G41 D1\nG10 L2 P1 X1\n",
            "2:1: G10 cannot change the coordinate system in force while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change the active coordinate system with cutter radius compensation on",
        ),
        (
            "G41 D1\nG43 H1\n",
            "2:1: the tool length offset (G43, G43.1, G49) cannot change while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change tool offset with cutter radius compensation on",
        ),
        (
            "G41 D1\nT2 M6\n",
            "2:4: the tool cannot change (M6) while cutter compensation (G41, G42) is on: end it with G40 first",
            "Cannot change tools with cutter radius compensation on",
        ),
    ] {
        let text = format!("G21 F100\n{text}M2\n");
        let ours = our_program(&text).map(|_| ()).map_err(|e| e.to_string());
        // Our lines count from the program's first line, the G21 F100 the test adds.
        let (at, why) = ours_why.split_once(':').expect("line:column: why");
        let expected = format!("{}:{why}", at.parse::<usize>().expect("a line") + 1);
        assert_eq!(ours, Err(expected), "{text}");
        let said = rs274_output(rs274, &text, None);
        if theirs.is_empty() {
            // LinuxCNC reads a D alone, and G41 with no tool in the spindle as a tool of
            // diameter 0; we refuse them with why (the spindle's tool, known only as the
            // program runs, could differ).
            continue;
        }
        assert!(
            !said.contains("PROGRAM_END") && said.contains(theirs),
            "rs274 read {text:?}: {said}"
        );
    }
}

/// G5 (cubic) and G5.1 (quadratic) splines read as LinuxCNC 2.9's `rs274` reads them: one spline
/// of the same order where it makes a `NURBS_FEED` (4 control points, or 3), the moves around
/// them the same — in G91 too, where a move after a spline starts at the spline's end — and the
/// same programs refused (without P Q, with one of I J, outside G17, with Z, without a feed).
/// G5.2 (NURBS) is refused with its reason. The pieces' closeness to the curve is the
/// interpreter's own test (`interp::spline`).
#[test]
fn splines_are_linuxcncs_and_nurbs_are_refused_with_why() {
    let Some(rs274) = rs274_or_skip("nc::splines_are_linuxcncs_and_nurbs_are_refused_with_why") else {
        return;
    };
    for text in [
        "G0 X0 Y0\nG1 F100\nG5 I0 J3 P0 Q-3 X1 Y1\nG5 P0 Q-3 X2 Y2\nG1 X3\nG5.1 X5 Y1 I1 J-2\nG1 Y0\nM2\n",
        "G91 G1 X1 F200\nG5 I1 J1 P-1 Q1 X4 Y0\nG1 X1\nG5.1 I1 J1 X2 Y0\nG1 Y1\nG90 G1 X0 Y0\nM2\n",
        "G20 G1 X0.5 F10\nG5 I0.2 J0.5 P0 Q-0.3 X1 Y1\nG1 X2\nM2\n",
    ] {
        let orders: Vec<&str> = text
            .lines()
            .filter_map(|l| {
                if l.contains("G5.1") {
                    Some("3")
                } else if l.contains("G5") {
                    Some("4")
                } else {
                    None
                }
            })
            .collect();
        let output = rs274_output(rs274, text, None);
        let theirs: Vec<&str> = output
            .lines()
            .filter_map(|l| l.split_once("NURBS_FEED(").map(|(_, rest)| &rest[..1]))
            .collect();
        assert_eq!(theirs, orders, "{text}: rs274's splines");
        // Our moves but the splines' pieces, against rs274's (which prints splines apart).
        let spline_lines: Vec<usize> = text
            .lines()
            .enumerate()
            .filter(|(_, l)| l.contains("G5"))
            .map(|(k, _)| k + 1)
            .collect();
        let program = our_program(text).unwrap_or_else(|e| panic!("{e}"));
        let mut pieces = 0;
        let mut ours = Vec::new();
        for b in &program.blocks {
            let pkm_nc::interp::Action::Move {
                from,
                to,
                path,
                feed_mm_min,
                ..
            } = b.action
            else {
                continue;
            };
            if spline_lines.contains(&b.line) {
                pieces += 1;
                assert!(feed_mm_min.is_some(), "a spline feeds");
                continue;
            }
            if rounded([from[0], from[1], from[2]]) == rounded([to[0], to[1], to[2]]) {
                continue;
            }
            ours.push(Canonical {
                kind: if feed_mm_min.is_some() { "feed" } else { "rapid" },
                end: rounded([to[0], to[1], to[2]]),
                arc: match path {
                    pkm_nc::interp::Path::Arc { center, clockwise, .. } => Some(([center[0], center[1]], clockwise)),
                    pkm_nc::interp::Path::Line => None,
                },
                feed: feed_mm_min,
            });
        }
        assert!(pieces >= 8 * orders.len(), "{text}: {pieces} pieces");
        let l = canonical_moves(&output);
        assert!(agree(&ours, &l), "{text}\nours: {ours:?}\nLinuxCNC: {l:?}");
    }
    for (text, why) in [
        (
            "G1 F100\nG5 I0 J1 X1 Y1\nM2\n",
            "2:1: G5: P and Q are both needed (the second control point's offset from the end)",
        ),
        (
            "G1 F100\nG5 I0 P0 Q-1 X1 Y1\nM2\n",
            "2:4: G5: I and J both, or neither (then the last G5's P and Q, reversed)",
        ),
        (
            "G1 F100\nG5.1 X1 Y1 I0.5\nM2\n",
            "2:12: G5.1: I and J are both needed (the control point's offset from the start)",
        ),
        (
            "G18 G1 F100\nG5 I0 J1 P0 Q-1 X1\nM2\n",
            "2:1: G5: splines are taken in the XY plane only (G17)",
        ),
        (
            "G1 F100\nG5 I0 J1 P0 Q-1 X1 Y1 Z1\nM2\n",
            "2:23: G5: a spline moves in X and Y only, not in Z",
        ),
        (
            "G0 X1\nG5 I0 J1 P0 Q-1 X2 Y1\nM2\n",
            "2:17: no feed rate: an F word is needed before the first G5 or G5.1",
        ),
        (
            "G1 F100\nG5 I0 J1 P0 Q-1\nM2\n",
            "2:1: a spline (G5, G5.1) needs its end: X, Y",
        ),
    ] {
        let ours = our_program(text).map(|_| ()).map_err(|e| e.to_string());
        assert_eq!(ours, Err(why.to_string()), "{text}");
        assert!(
            !rs274_output(rs274, text, None).contains("PROGRAM_END"),
            "rs274 read {text:?}"
        );
    }
    assert_eq!(
        our_program("G1 F100\nG5.2 X0 Y1 P1 L3\nM2\n").map(|_| ()).map_err(|e| e.to_string()),
        Err("2:1: G5.2 is not supported (NURBS blocks: a CAM program can write them as cubic splines (G5) or as lines and arcs)".to_string())
    );
}

/// M62 … M68 read as LinuxCNC 2.9's `rs274` reads them: each output in its place among the
/// moves — with the next move (`SET_MOTION_OUTPUT_BIT`, `…_VALUE`: M62, M63, M67) or at once
/// (`SET_AUX_OUTPUT_BIT`, `…_VALUE`: M64, M65, M68), before the move of its own line — and the
/// same programs refused (no P, no P or E for M66, two of them in a block, a wait without a
/// timeout, an analog input waited on). Stricter than `rs274` where it takes what LinuxCNC's
/// configuration would refuse: outputs beyond P3 and E1, a P that is not whole, L beyond 4, M67
/// without Q.
#[test]
fn motion_synchronised_and_immediate_io_is_linuxcncs() {
    let Some(rs274) = rs274_or_skip("nc::motion_synchronised_and_immediate_io_is_linuxcncs") else {
        return;
    };
    let text = "G1 F100 X1\nM62 P0\nM64 P1\nG1 X2 M63 P0\nM65 P1\nM67 E0 Q2.5\nM68 E1 Q-1\nG1 X3\nM66 P2 L3 Q5\nM66 P1 L0\nG1 X0 M62 P3\nM63 P3\nM2\n";
    // (what, index, value) of each output, and "move" with its x.
    let theirs: Vec<(String, u8, f64)> = rs274_output(rs274, text, None)
        .lines()
        .filter_map(|l| {
            let (call, args) = l.split_once('(')?;
            let call = call.rsplit(' ').next()?;
            let n: Vec<f64> = args
                .trim_end_matches(')')
                .split(',')
                .filter_map(|x| x.trim().parse().ok())
                .collect();
            let what = match call {
                "SET_MOTION_OUTPUT_BIT" => ("M62", n[0] as u8, 1.0),
                "CLEAR_MOTION_OUTPUT_BIT" => ("M63", n[0] as u8, 0.0),
                "SET_AUX_OUTPUT_BIT" => ("M64", n[0] as u8, 1.0),
                "CLEAR_AUX_OUTPUT_BIT" => ("M65", n[0] as u8, 0.0),
                "SET_MOTION_OUTPUT_VALUE" => ("M67", n[0] as u8, n[1]),
                "SET_AUX_OUTPUT_VALUE" => ("M68", n[0] as u8, n[1]),
                "STRAIGHT_FEED" | "STRAIGHT_TRAVERSE" => ("move", 0, n[0]),
                _ => return None,
            };
            Some((what.0.to_string(), what.1, what.2))
        })
        .collect();
    use pkm_nc::interp::{Action, Output};
    let ours: Vec<(String, u8, f64)> = our_program(text)
        .unwrap_or_else(|e| panic!("{e}"))
        .blocks
        .iter()
        .filter_map(|b| match b.action {
            Action::Output {
                output: Output::Digital { index, on },
                synced,
            } => Some((
                match (synced, on) {
                    (true, true) => "M62",
                    (true, false) => "M63",
                    (false, true) => "M64",
                    (false, false) => "M65",
                }
                .to_string(),
                index,
                if on { 1.0 } else { 0.0 },
            )),
            Action::Output {
                output: Output::Analog { index, value },
                synced,
            } => Some((if synced { "M67" } else { "M68" }.to_string(), index, value)),
            Action::Move { to, .. } => Some(("move".to_string(), 0, to[0])),
            _ => None,
        })
        .collect();
    // rs274 writes a zero-length feed for G1 alone; both have the same moves otherwise.
    let theirs: Vec<_> = theirs
        .into_iter()
        .filter(|(w, _, x)| !(w == "move" && *x == 0.0))
        .collect();
    let ours: Vec<_> = ours
        .into_iter()
        .filter(|(w, _, x)| !(w == "move" && *x == 0.0))
        .collect();
    assert_eq!(ours, theirs, "{text}");
    assert_eq!(ours.iter().filter(|(w, ..)| w != "move").count(), 8, "{ours:?}");
    for (text, why) in [
        (
            "M62\nM2\n",
            "1:1: M62 needs P: the digital output (0 … 3, NC_DOUT_0 … NC_DOUT_3)",
        ),
        (
            "M66 L3 Q1\nM2\n",
            "1:1: M66 needs P: the digital input (0 … 3, NC_DIN_0 … NC_DIN_3)",
        ),
        (
            "M62 P0 M63 P1\nM2\n",
            "1:8: M62 and M63 are in one modal group: a block holds one of them",
        ),
        (
            "M66 P1 L1\nM2\n",
            "1:1: M66 L1 … L4 needs Q: the longest wait in seconds, more than 0 (then the program goes on)",
        ),
        (
            "M66 P0 L3 Q-1\nM2\n",
            "1:11: M66 L1 … L4 needs Q: the longest wait in seconds, more than 0 (then the program goes on)",
        ),
        (
            "M66 E0 L1 Q2\nM2\n",
            "1:5: M66 E waits on no analog input (L1 … L4 are for digital inputs, P), as in LinuxCNC",
        ),
    ] {
        let ours = our_program(text).map(|_| ()).map_err(|e| e.to_string());
        assert_eq!(ours, Err(why.to_string()), "{text}");
        assert!(
            !rs274_output(rs274, text, None).contains("PROGRAM_END"),
            "rs274 read {text:?}"
        );
    }
    for (text, why) in [
        (
            "M62 P4\nM2\n",
            "1:5: M62 P4: the digital outputs are P0 … P3 (NC_DOUT_0 … NC_DOUT_3)",
        ),
        (
            "M64 P1.5\nM2\n",
            "1:5: M64 P1.5: the digital outputs are P0 … P3 (NC_DOUT_0 … NC_DOUT_3)",
        ),
        ("M67 E0\nM2\n", "1:1: M67 needs Q: the output's value"),
        (
            "M68 E2 Q1\nM2\n",
            "1:5: M68 E2: the analog outputs are E0 … E1 (NC_AOUT_0 … NC_AOUT_1)",
        ),
        (
            "M66 P0 L5 Q1\nM2\n",
            "1:8: M66 L is the wait's mode: 0 (none), 1 (the input rises), 2 (falls), 3 (is on), 4 (is off)",
        ),
        (
            "#1 = #5399\nM2\n",
            "1:6: #5399 is the input M66 read: known only as the program runs, and this interpreter reads the whole program before it runs (M66 waits here, its value cannot steer the program)",
        ),
    ] {
        assert_eq!(
            our_program(text).map(|_| ()).map_err(|e| e.to_string()),
            Err(why.to_string()),
            "{text}"
        );
    }
}
