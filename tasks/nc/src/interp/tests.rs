//! The interpreter against what LinuxCNC reads: moves, modes, offsets, arcs, cycles, refusals.

use super::*;

const XYZ: [&str; 3] = ["x", "y", "z"];
const XYZABC: [&str; 6] = ["x", "y", "z", "a", "b", "c"];

fn machine(axes: &'static [&'static str]) -> Machine<'static> {
    let mut work_offsets = [[0.0; 6]; 6];
    work_offsets[1] = [100.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    Machine {
        axes,
        start: [0.0; 6],
        work_offsets,
        block_delete: false,
        homes: [[0.0; 6]; 2],
        tools: None,
    }
}

/// `text` with an end: a program must end (M2), and what follows an end is never read.
fn ended(text: &str) -> String {
    format!("{text}\nM2")
}

fn run(text: &str) -> Vec<Block> {
    without_frames(
        read(&ended(text), &machine(&XYZ))
            .unwrap_or_else(|e| panic!("{e}"))
            .blocks,
    )
}

/// `blocks` without their program coordinates (`Action::WorkOffset`, tested on their own):
/// what moves, switches and waits.
fn without_frames(blocks: Vec<Block>) -> Vec<Block> {
    blocks
        .into_iter()
        .filter(|b| !matches!(b.action, Action::WorkOffset { .. }))
        .collect()
}

fn refused(text: &str) -> String {
    read(&ended(text), &machine(&XYZ)).expect_err("refused").to_string()
}

fn moves(blocks: &[Block]) -> Vec<(Pose, Path, Option<f64>)> {
    blocks
        .iter()
        .filter_map(|b| match b.action {
            Action::Move {
                to, path, feed_mm_min, ..
            } => Some((to, path, feed_mm_min)),
            _ => None,
        })
        .collect()
}

#[test]
fn rapid_and_feed_moves_absolute_incremental_inch_and_modal() {
    let b = run("G0 X10 Y5\nG1 Z-1 F600\nX20\nG91 X1 Y1\nG20\nG90 X1 F10\nG21 G0 X0 Y0 Z0\n");
    let m = moves(&b);
    assert_eq!(m[0], ([10.0, 5.0, 0.0, 0.0, 0.0, 0.0], Path::Line, None));
    assert_eq!(m[1], ([10.0, 5.0, -1.0, 0.0, 0.0, 0.0], Path::Line, Some(600.0)));
    assert_eq!(m[2].0, [20.0, 5.0, -1.0, 0.0, 0.0, 0.0], "G1 is modal");
    assert_eq!(m[3].0, [21.0, 6.0, -1.0, 0.0, 0.0, 0.0], "G91 adds");
    assert_eq!(
        m[4],
        ([25.4, 6.0, -1.0, 0.0, 0.0, 0.0], Path::Line, Some(254.0)),
        "G20: inches"
    );
    assert_eq!(m[5], ([0.0; 6], Path::Line, None));
    assert!(
        b.iter()
            .filter(|b| matches!(b.action, Action::Move { .. }))
            .all(|b| b.line >= 1 && b.line <= 7)
    );
    assert_eq!(b[1].line, 2);
}

#[test]
fn work_offsets_g92_and_g53() {
    // G55 has its origin at machine x = 100.
    let b = run("G55 G0 X1\nG92 X0\nG0 X5\nG53 G0 X2\nG54 G0 X3\n");
    let m = moves(&b);
    assert_eq!(m[0].0[0], 101.0);
    assert_eq!(m[1].0[0], 106.0, "G92 X0 made machine x 101 read 0");
    assert_eq!(m[2].0[0], 2.0, "G53: machine coordinates");
    assert_eq!(m[3].0[0], 4.0, "G54 (origin 0) with G92's offset of 1 still in force");
}

#[test]
fn arcs_by_centre_and_radius_helical_turns_and_planes() {
    let b = run(
        "G0 X10 Y0\nG3 X0 Y10 I-10 J0 F100\nG2 X10 Y0 R10\nG3 X10 Y0 Z5 I-10 P2\nG18 G2 X0 Z-5 K0 I-10\nG19 G3 Y10 Z5 J5 K5\n",
    );
    let m = moves(&b);
    assert_eq!(
        m[1].1,
        Path::Arc {
            plane: Plane::Xy,
            center: [0.0, 0.0],
            clockwise: false,
            extra_turns: 0
        }
    );
    match m[2].1 {
        Path::Arc {
            center,
            clockwise: true,
            ..
        } => {
            assert!(
                center[0].abs() < 1e-9 && center[1].abs() < 1e-9,
                "R10 from (0,10) to (10,0) cw: {center:?}"
            )
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(m[3].0[2], 5.0, "helix: Z rises along the arc");
    assert!(matches!(m[3].1, Path::Arc { extra_turns: 1, .. }), "P2: one extra turn");
    assert!(matches!(m[4].1, Path::Arc { plane: Plane::Zx, center, .. } if center == [5.0, 0.0]));
    assert!(matches!(m[5].1, Path::Arc { plane: Plane::Yz, .. }));
    // The long arc: a negative R.
    let b = run("G0 X10 Y0\nG3 X0 Y10 R-10 F100\n");
    match moves(&b)[1].1 {
        Path::Arc { center, .. } => assert!(
            (center[0] - 10.0).abs() < 1e-9 && (center[1] - 10.0).abs() < 1e-9,
            "{center:?}"
        ),
        other => panic!("{other:?}"),
    }
}

#[test]
fn dwell_pauses_spindle_blending_and_end() {
    let b = run("G64 P0.05\nS1200 M3\nG4 P1.5\nG1 X1 F100\nM1\nG61 X2\nM5\nM0\nM2\n");
    let actions: Vec<Action> = b.iter().map(|b| b.action).collect();
    assert!(matches!(actions[0], Action::Spindle { direction: Spindle::Clockwise, speed_rpm } if speed_rpm == 1200.0));
    assert_eq!(actions[1], Action::Dwell(1.5));
    assert!(matches!(actions[2], Action::Move { blend: Blend::Within { tolerance: Some(t), .. }, .. } if t == 0.05));
    assert_eq!(actions[3], Action::Pause { optional: true });
    assert!(matches!(
        actions[4],
        Action::Move {
            blend: Blend::ExactStop,
            ..
        }
    ));
    assert!(matches!(
        actions[5],
        Action::Spindle {
            direction: Spindle::Off,
            ..
        }
    ));
    assert_eq!(actions[6], Action::Pause { optional: false });
    assert_eq!(actions[7], Action::End);
    assert_eq!(b[7].line, 9);
    let b = run("M4\nM30\n");
    assert!(matches!(
        b[0].action,
        Action::Spindle {
            direction: Spindle::CounterClockwise,
            ..
        }
    ));
    assert_eq!(b[1].action, Action::End);
}

#[test]
fn rotations_on_the_hexapod_only() {
    let b = read(&ended("G1 X1 A2 B-3 C4 F100"), &machine(&XYZABC)).expect("hexapod");
    assert_eq!(moves(&b.blocks)[0].0, [1.0, 0.0, 0.0, 2.0, -3.0, 4.0]);
    // G20 scales lengths, not angles.
    let b = read(&ended("G20 G1 X1 A2 F1"), &machine(&XYZABC)).expect("hexapod");
    assert_eq!(moves(&b.blocks)[0].0, [25.4, 0.0, 0.0, 2.0, 0.0, 0.0]);
    assert_eq!(refused("G1 X1 A2 F100"), "1:7: A: this machine's axes are X Y Z");
    let planar = read(&ended("G1 X1 Z2 F100"), &machine(&["x", "y"])).expect_err("refused");
    assert_eq!(planar.to_string(), "1:7: Z: this machine's axes are X Y");
}

#[test]
fn what_the_subset_lacks_is_refused_with_line_column_and_reason() {
    for (text, message) in [
        ("G43.2 H1", "1:1: G43.2 is not supported (adding tool offsets)"),
        ("G96 S100", "1:1: G96 is not supported (spindle speed modes)"),
        (
            "G1 X1 F10\nG84 X1 Z-1 R1",
            "2:1: G84 is not supported (canned cycles other than G73, G81, G82, G83, G85, G89)",
        ),
        (
            "G28.2",
            "1:1: G28.2 is not supported (G28 and G30 variants other than G28.1, G30.1)",
        ),
        ("G54.1", "1:1: G54.1 is not supported"),
        ("G1.5", "1:1: G1.5 is not supported"),
        (
            "T1 M6",
            "1:1: T1: there is no tool table (give one with --tool-table or nc.tool_table in the configuration)",
        ),
        (
            "M7 M8",
            "1:4: M7 and M8 are in one modal group: a block holds one of them",
        ),
        ("M98 P10", "1:1: M98 is not supported (subprograms, user codes)"),
        ("M100", "1:1: M100 is not supported (user-defined M codes)"),
        ("G1 U1", "1:4: U: axes U V W are not supported"),
        (
            "G10 L1 P1 Z0",
            "1:8: G10 L1: there is no tool table (give one with --tool-table or nc.tool_table in the configuration)",
        ),
        (
            "G10 L3 P1 Z0",
            "1:5: G10 L3 is not supported: L1 and L10 set a tool's offsets, L2 and L20 a work coordinate system",
        ),
        (
            "G0 G1 X1",
            "1:4: G0 and G1 are in one modal group: a block holds one of them",
        ),
        (
            "G90 G91",
            "1:5: G90 and G91 are in one modal group: a block holds one of them",
        ),
        (
            "M3 M5",
            "1:4: M3 and M5 are in one modal group: a block holds one of them",
        ),
        ("G1 X1 X2 F1", "1:7: X twice in one block"),
        (
            "G1 X1",
            "1:4: no feed rate: an F word is needed before the first G1, G2 or G3",
        ),
        ("X1", "1:1: an axis word needs a motion mode: G0, G1, G2 or G3 first"),
        (
            "G2 F100",
            "1:1: an arc needs its centre (I J) or its end and radius (R)",
        ),
        (
            "G80 X1",
            "1:5: axis words cannot go with G80 (it cancels the motion mode; G80 does not)",
        ),
        (
            "G1 X1 F100\nG80\nX2",
            "3:1: an axis word needs a motion mode: G0, G1, G2 or G3 first",
        ),
        (
            "G1 X1 Q0.1 F100",
            "1:7: Q belongs to G64 (merging lines within it), G73, G83 (the peck depth), G5 (a control point), M61 (the tool), M66 (a timeout), M67, M68 (a value) or G10 L1 (a lathe tool's orientation)",
        ),
        (
            "G64 P0.1 Q-1",
            "1:10: the merging tolerance Q must be zero or positive, got -1",
        ),
        (
            "G90.1 G2 X10 I5 F100",
            "1:10: in G90.1 (absolute arc centres) an arc needs both I and J",
        ),
        (
            "G1 X1 F100\n%",
            "2:1: '%' opens a program only on its first line (and then closes it)",
        ),
        ("G1 X1 F0", "1:7: the feed F must be positive, got 0"),
        ("G4", "1:1: G4 needs P, the dwell in seconds"),
        ("G4 P-1", "1:4: the dwell P must be zero or positive seconds, got -1"),
        (
            "G1 X1 P2 F1",
            "1:7: P belongs to G4 (dwell), G10 (the coordinate system), G64 (tolerance), an arc (turns), G5 (a control point), G82, G89 (dwell) or M62 … M66 (a digital input or output)",
        ),
        (
            "G1 X1 I2 F1",
            "1:7: I belongs to an arc (G2, G3) or a spline (G5, G5.1)",
        ),
        ("G2 X1 F1", "1:4: an arc needs its centre (I J) or its radius (R)"),
        (
            "G2 X1 Y1 I1 R1 F1",
            "1:13: an arc has a radius (R) or a centre (I J K), not both",
        ),
        (
            "G2 X1 K1 F1",
            "1:7: K is not an offset of an arc in G17 (X–Y): use I and J",
        ),
        (
            "G2 X10 I1 F1",
            "1:4: the arc's end is not on its circle: radius 1.0000 mm at the start, 9.0000 mm at the end (LinuxCNC allows 0.0283 mm, or 0.1% of the radius)",
        ),
        (
            "G2 X0.002 I0.001 F1",
            "1:4: the arc's radius is 0.00100 mm at the start and 0.00100 mm at the end: below 0.00127 mm an arc has no radius (as LinuxCNC reads it)",
        ),
        ("G2 X0 I0 J0 F1", "1:4: the arc's centre is its start point"),
        (
            "G2 X10 R2 F1",
            "1:8: the radius 2 mm is shorter than half the chord (5.0000 mm)",
        ),
        (
            "G2 X0 Y0 R2 F1",
            "1:10: a full circle is given by its centre (I J K), not by R",
        ),
        (
            "G2 X0 I1 P1.5 F1",
            "1:10: an arc's P is its number of turns, a whole number from 1, got 1.5",
        ),
        ("G53 X1", "1:1: G53 goes with a G0 or G1 move in this block"),
        ("G91 G53 G0 X1", "1:5: G53 needs absolute distances (G90)"),
        (
            "G92",
            "1:1: G92 needs at least one axis word: the program coordinates the tool is at",
        ),
        ("G0 X1 N5", "1:7: a line number (N) comes first in its block"),
        (
            "G0 X1 E2",
            "1:7: E belongs to M66 (an analog input), M67, M68 (an analog output); extruders are not supported",
        ),
        ("S-5", "1:1: the spindle speed S must be zero or positive, got -5"),
        ("G1.25 X1", "1:1: G1.25 is not a code"),
        // Absurd values, refused where they are written.
        (
            "G1 X1 F0.01",
            "1:7: the feed F must be at least 0.1 units/min (slower, a millimetre takes hours), got 0.01",
        ),
        (
            "G4 P86401",
            "1:4: the dwell P must be at most 86400 s (a day), got 86401",
        ),
        (
            "S100001 M3",
            "1:1: the spindle speed S must be at most 100000 rpm, got 100001",
        ),
    ] {
        assert_eq!(refused(text), message, "{text:?}");
    }
    let huge = format!("G1 X1{} F100", "9".repeat(400));
    assert_eq!(
        refused(&huge),
        "1:4: X: the number is out of range (at most 1e9 in magnitude)"
    );
    assert_eq!(
        refused("G0 X1\nG1 Y 1000000000.5 F1"),
        "2:4: Y: the number is out of range (at most 1e9 in magnitude)"
    );
}

/// The dialect CAM programs use, with the moves LinuxCNC 2.9's `rs274` prints for
/// the same text (checked by hand against it; `tests/suite/nc.rs` compares where it is
/// installed).
#[test]
fn the_cam_dialect_means_what_linuxcnc_reads() {
    // A motion mode set alone carries to lines with only axis words.
    let m = moves(&run("G1 F600\nX10\nY5\nG0 X0 Y0"));
    assert_eq!(m.len(), 3);
    assert_eq!(m[0], ([10.0, 0.0, 0.0, 0.0, 0.0, 0.0], Path::Line, Some(600.0)));
    assert_eq!(m[1].0, [10.0, 5.0, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(m[2], ([0.0; 6], Path::Line, None));
    // The usual preamble sets states; G80 leaves no motion mode.
    let m = moves(&run("G40 G49 G80 G94 G17 G21 G90\nG1 X1 F100"));
    assert_eq!(m[0].0, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    // An arc with its centre and no axis word: a full circle where the tool stands.
    let m = moves(&run("G2 I5 F100"));
    assert_eq!(m[0].0, [0.0; 6]);
    assert!(matches!(m[0].1, Path::Arc { center, clockwise: true, .. } if center == [5.0, 0.0]));
    // Absolute arc centres (G90.1), and back (G91.1).
    let m = moves(&run("G0 X2\nG90.1 G2 X10 Y0 I6 J0 F100\nG91.1 G2 X2 Y0 I-4 J0"));
    assert!(matches!(m[1].1, Path::Arc { center, .. } if center == [6.0, 0.0]));
    assert!(matches!(m[2].1, Path::Arc { center, .. } if center == [6.0, 0.0]));
    // G61.1 stops exactly; G64 P0 and P-1 are G64 without a tolerance; Q merges, within P
    // where Q is not given (as LinuxCNC), not at all with Q0.
    let b = run("G61.1\nG1 X1 F100\nG64 P0\nG1 X2\nG64 P0.01 Q0.02\nX3\nG64 P-1\nX4\nG64 P0.03\nX5\nG64 P0.03 Q0\nX6");
    let blends: Vec<Blend> = b
        .iter()
        .filter_map(|b| match b.action {
            Action::Move { blend, .. } => Some(blend),
            _ => None,
        })
        .collect();
    let within = |tolerance, merge| Blend::Within { tolerance, merge };
    assert_eq!(
        blends,
        [
            Blend::ExactStop,
            within(None, None),
            within(Some(0.01), Some(0.02)),
            within(None, None),
            within(Some(0.03), Some(0.03)),
            within(Some(0.03), None)
        ]
    );
    // What follows the end is never read (LinuxCNC ignores it), even what is not G-code.
    let p = read("G1 X1 F100\nM2\nG1 X5\nnot a program", &machine(&XYZ)).expect("read to M2");
    assert_eq!(moves(&p.blocks).len(), 1);
    let p = read("%\nG1 X1 F100\n%\nG1 X5\n", &machine(&XYZ)).expect("read to the closing %");
    assert_eq!(moves(&p.blocks).len(), 1);
    // Block delete: off (the default) the line runs; on it is skipped.
    let text = "G1 X1 F100\n/G1 X5\nM2";
    assert_eq!(moves(&read(text, &machine(&XYZ)).expect("read").blocks).len(), 2);
    let on = Machine {
        block_delete: true,
        ..machine(&XYZ)
    };
    assert_eq!(moves(&read(text, &on).expect("read").blocks).len(), 1);
    // A program must end, as LinuxCNC says.
    assert_eq!(
        read("G1 X1 F100\nG1 X2", &machine(&XYZ))
            .expect_err("no end")
            .to_string(),
        "2:1: the file ended with no program end (M2, M30) and no '%' delimiters: is the program complete?"
    );
    assert_eq!(
        read("%\nG1 X1 F100\n", &machine(&XYZ))
            .expect_err("no closing %")
            .to_string(),
        "2:1: the file ended without the closing '%' (or M2, M30): is the program complete?"
    );
}

/// The moves LinuxCNC 2.9's `rs274` prints for the same program (also compared with it in
/// `tests/suite/nc.rs` where it is installed): G83 from above R, G98, G91 with L3.
#[test]
fn canned_cycles_make_linuxcncs_moves() {
    let b = run("G0 Z10\nG83 X1 Y1 Z-5 R2 Q2 F100\nG98 G81 X5 Z-1 R1\nG91 G81 X2 Y0 R-3 Z-1 L3\nG90 G0 X0");
    let r = |x: f64, y: f64, z: f64| ([x, y, z, 0.0, 0.0, 0.0], Path::Line, None);
    let f = |x: f64, y: f64, z: f64| ([x, y, z, 0.0, 0.0, 0.0], Path::Line, Some(100.0));
    let expected = [
        r(0.0, 0.0, 10.0),
        // G83: over the hole, down to R, pecks of 2 with a rapid back to R and to 0.254 mm
        // above the last peck, the bottom, back to R (G99).
        r(1.0, 1.0, 10.0),
        r(1.0, 1.0, 2.0),
        f(1.0, 1.0, 0.0),
        r(1.0, 1.0, 2.0),
        r(1.0, 1.0, 0.254),
        f(1.0, 1.0, -2.0),
        r(1.0, 1.0, 2.0),
        r(1.0, 1.0, -1.746),
        f(1.0, 1.0, -4.0),
        r(1.0, 1.0, 2.0),
        r(1.0, 1.0, -3.746),
        f(1.0, 1.0, -5.0),
        r(1.0, 1.0, 2.0),
        // G98: back to where the series started (Z10).
        r(5.0, 1.0, 2.0),
        r(5.0, 1.0, 1.0),
        f(5.0, 1.0, -1.0),
        r(5.0, 1.0, 10.0),
        // G91 L3: X2 each time, R 3 below the start (7), the bottom 1 below R.
        r(7.0, 1.0, 10.0),
        r(7.0, 1.0, 7.0),
        f(7.0, 1.0, 6.0),
        r(7.0, 1.0, 10.0),
        r(9.0, 1.0, 10.0),
        r(9.0, 1.0, 7.0),
        f(9.0, 1.0, 6.0),
        r(9.0, 1.0, 10.0),
        r(11.0, 1.0, 10.0),
        r(11.0, 1.0, 7.0),
        f(11.0, 1.0, 6.0),
        r(11.0, 1.0, 10.0),
        r(0.0, 1.0, 10.0),
    ];
    let got = moves(&b);
    assert_eq!(got.len(), expected.len(), "{got:?}");
    for (g, e) in got.iter().zip(&expected) {
        assert!(
            g.0.iter().zip(&e.0).all(|(a, b)| (a - b).abs() < 1e-9) && g.1 == e.1 && g.2 == e.2,
            "{g:?} vs {e:?}"
        );
    }
    // Every move of a cycle stops exactly; G82 dwells at the bottom; a block with only X
    // and Y repeats the cycle with its values.
    let b = run("G64 G0 Z5\nG82 X1 Z-1 R1 P0.5 F60\nX2\nG80");
    assert!(b.iter().skip(1).filter(|b| b.action != Action::End).all(|b| matches!(
        b.action,
        Action::Move {
            blend: Blend::ExactStop,
            ..
        } | Action::Dwell(_)
    )));
    let dwells: Vec<Action> = b
        .iter()
        .map(|b| b.action)
        .filter(|a| matches!(a, Action::Dwell(_)))
        .collect();
    assert_eq!(dwells, [Action::Dwell(0.5), Action::Dwell(0.5)]);
    let last_move = b.iter().rev().find(|b| matches!(b.action, Action::Move { .. }));
    assert_eq!(last_move.map(|b| b.line), Some(3), "X2 drilled again");
    for (text, message) in [
        ("G81 X1 Z-1 F10", "1:5: G81 needs R, the retract plane"),
        ("G81 X1 R1 F10", "1:5: G81 needs Z, the bottom of the hole"),
        ("G83 X1 Z-1 R1 F10", "1:5: G83 needs Q, the depth of each peck"),
        ("G83 X1 Z-1 R1 Q0 F10", "1:15: the peck depth Q must be positive, got 0"),
        (
            "G82 X1 Z-1 R1 F10",
            "1:5: G82 needs P, the dwell at the bottom in seconds",
        ),
        (
            "G81 X1 Z1 R-1 F10",
            "1:11: G81: the retract plane R (-1) is below the bottom Z (1)",
        ),
        (
            "G81 X1 Z-1 R1 L0 F10",
            "1:15: L, the number of repeats, is a whole number from 1 to 10000, got 0",
        ),
        (
            "G81 X1 Z-1 R1",
            "1:5: no feed rate: an F word is needed before the first G81",
        ),
        (
            "G1 X1 L2 F10",
            "1:7: L belongs to a canned cycle (its repeats), G10 (L2, L20) or M66 (the wait's mode)",
        ),
        (
            "G1 X1 R2 F10",
            "1:7: R belongs to an arc (G2, G3) or a canned cycle (G73, G81 … G89)",
        ),
    ] {
        assert_eq!(refused(text), message, "{text}");
    }
    let hexapod = read(&ended("G81 X1 A1 Z-1 R1 F10"), &machine(&XYZABC)).expect_err("refused");
    assert_eq!(
        hexapod.to_string(),
        "1:8: G81 moves X Y Z only: A cannot move in a canned cycle"
    );
}

/// The interpreter's state as LinuxCNC's system parameters, in program units.
#[test]
fn system_parameters_give_the_state() {
    // G55's origin is at machine x 100.
    let m = moves(&run(
        "G55 G0 X5\nG1 X#5420 Y#5220 Z#5241 F#<_coord_system>\nG20\nG0 X[#<_x>] Y#<_metric> Z#<_motion_mode>\nG21 G92 X0\nG0 Y#5211",
    ));
    assert_eq!(m[0].0[0], 105.0);
    assert_eq!(
        m[1].0[..3],
        [105.0, 2.0, 100.0],
        "position 5, system 2 (G55), G55's x origin 100"
    );
    assert_eq!(m[1].2, Some(550.0));
    let inch = 25.4;
    // A line's values are read before its own codes act: G20 on a line of its own.
    assert!((m[2].0[0] - 105.0).abs() < 1e-9, "#<_x> in inches, moved to in inches");
    assert_eq!(m[2].0[1], 0.0, "G20: not metric");
    assert!(
        (m[2].0[2] - 10.0 * inch).abs() < 1e-9,
        "G1 before the line: motion mode 10"
    );
    assert_eq!(m[3].0[1], 5.0, "G92 X0 at 5: its offset #5211 reads 5");
}

#[test]
fn a_byte_order_mark_is_not_part_of_the_program() {
    let m = machine(&XYZ);
    let with = read("\u{feff}G0 X1\nM2", &m).expect("a BOM then a program");
    let without = read("G0 X1\nM2", &m).expect("the program");
    assert_eq!(format!("{:?}", with.blocks), format!("{:?}", without.blocks));
    // Columns count from the first character after the mark.
    assert_eq!(refused("\u{feff}G1 X1 F0"), refused("G1 X1 F0"));
}

#[test]
fn going_home_and_the_g92_variants_mean_what_linuxcnc_reads() {
    // G28 through a point to the stored position of the axes named; G28.1 stores.
    let blocks = run("G0 X10 Y5 Z3\nG28.1\nG0 X1 Y1 Z1\nG91 G28 Z0");
    assert_eq!(
        moves(&blocks).last().map(|m| m.0),
        Some([1.0, 1.0, 3.0, 0.0, 0.0, 0.0]),
        "Z alone goes to its stored height"
    );
    // The parameters give the stored positions and G92's offset (kept while G92.2 suspends it).
    let blocks = run("G0 X10 Y5\nG30.1\nG92 X2\nG92.2\nG1 X#5181 Y#5211 Z#5210 F100");
    assert_eq!(
        moves(&blocks).last().map(|m| m.0),
        Some([10.0, 8.0, 0.0, 0.0, 0.0, 0.0])
    );
    // Refused where LinuxCNC refuses, with why.
    for (text, why) in [
        (
            "G0 G92 X1",
            "1:1: G0 and G92 both use the block's axis words: a block holds one of them",
        ),
        (
            "G28.1 X1",
            "1:7: G28.1 stores where the tool is: axis words cannot go with it",
        ),
        (
            "G52",
            "1:1: G52 needs at least one axis word: the offset of the local coordinate system",
        ),
        (
            "G28 G92 X1",
            "1:5: G28 and G92 are in one modal group: a block holds one of them",
        ),
        (
            "G28.2",
            "1:1: G28.2 is not supported (G28 and G30 variants other than G28.1, G30.1)",
        ),
    ] {
        assert_eq!(refused(text), why, "{text}");
    }
}

#[test]
fn the_chip_breaking_peck_and_the_bores_move_as_linuxcnc_moves() {
    let z = |blocks: &[Block]| -> Vec<(f64, bool)> {
        moves(blocks)
            .iter()
            .map(|(to, _, feed)| ((to[2] * 1e4).round() / 1e4, feed.is_some()))
            .collect()
    };
    // G73: each peck fed, then 0.254 mm up at a rapid; the last to the bottom; out at a rapid.
    let blocks = run("G0 X1 Y1 Z5\nG73 Z-5 R2 Q2 F100");
    assert_eq!(
        z(&blocks),
        [
            (5.0, false),
            (2.0, false),
            (0.0, true),
            (0.254, false),
            (-2.0, true),
            (-1.746, false),
            (-4.0, true),
            (-3.746, false),
            (-5.0, true),
            (2.0, false)
        ]
    );
    // G89: in at the feed, the dwell, out at the feed to R, then (G98) up to where it started.
    let blocks = run("G0 X1 Y1 Z5\nG98 G89 Z-5 R2 P0.5 F100");
    assert_eq!(
        z(&blocks),
        [(5.0, false), (2.0, false), (-5.0, true), (2.0, true), (5.0, false)]
    );
    assert!(blocks.iter().any(|b| b.action == Action::Dwell(0.5)));
}

#[test]
fn g10_sets_a_work_coordinate_system_as_linuxcnc_does() {
    // L2: G55's origin at X5 Y1; L20: G55 moved so that the tool reads X0 where it stands.
    let blocks = run("G10 L2 P2 X5 Y1\nG55 G0 X1\nG10 L20 P2 X0\nG0 X1\nG1 X#5241 Y#5242 F100");
    let to: Vec<Pose> = moves(&blocks).iter().map(|m| m.0).collect();
    assert_eq!(to[0], [6.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(to[1], [7.0, 0.0, 0.0, 0.0, 0.0, 0.0], "G55's X origin at 6 now");
    assert_eq!(to[2], [12.0, 2.0, 0.0, 0.0, 0.0, 0.0], "#5241, #5242: G55's origin");
    for (text, why) in [
        (
            "G10 L2 X1",
            "1:1: G10 L2 and L20 need P: the coordinate system (1 … 6 for G54 … G59, 0 the one in force)",
        ),
        (
            "G10 L2 P7 X1",
            "1:8: P is the coordinate system, 1 … 6 for G54 … G59 or 0 for the one in force; got 7",
        ),
        (
            "G10 L2 P1 R30",
            "1:11: R (a coordinate system's rotation) is not supported",
        ),
        (
            "G10 P1 X1",
            "1:1: G10 needs L: L1 or L10 (a tool's offsets), L2 or L20 (a work coordinate system)",
        ),
    ] {
        assert_eq!(refused(text), why, "{text}");
    }
}

#[test]
fn m7_m8_m9_switch_the_coolant() {
    let blocks = run("M8\nG0 X1\nM7\nM9");
    let coolant: Vec<(bool, bool)> = blocks
        .iter()
        .filter_map(|b| match b.action {
            Action::Coolant { mist, flood } => Some((mist, flood)),
            _ => None,
        })
        .collect();
    assert_eq!(coolant, [(false, true), (true, true), (false, false)]);
}

/// The tool table of the tool tests.
const TOOLS: &str = "T1 P1 Z50 D6 ;6 mm end mill\nT2 P2 X0.5 Z30.5 D3 ;drill\n";

/// `text` read on an X Y Z machine with [`TOOLS`].
fn with_tools(text: &str) -> Result<Program, NcError> {
    let tools = crate::tools::ToolTable::parse(TOOLS).expect("a table");
    let mut m = machine(&XYZ);
    m.tools = Some(&tools);
    read(&ended(text), &m).map(|p| Program {
        blocks: without_frames(p.blocks),
        ..p
    })
}

/// The program coordinates `text` reads in, each where it comes: (line, system, offset x y z),
/// with the tool table and G55 at x 100 (G54 at 0).
fn frames(text: &str) -> Vec<(usize, u8, [f64; 3])> {
    let tools = crate::tools::ToolTable::parse(TOOLS).expect("a table");
    let mut m = machine(&XYZ);
    m.tools = Some(&tools);
    m.work_offsets[1][0] = 100.0;
    let p = read(&ended(text), &m).unwrap_or_else(|e| panic!("{e}"));
    p.blocks
        .iter()
        .filter_map(|b| match b.action {
            Action::WorkOffset { system, offset } => Some((b.line, system, [offset[0], offset[1], offset[2]])),
            _ => None,
        })
        .collect()
}

#[test]
fn the_program_coordinates_come_first_and_wherever_the_system_g92_or_the_tool_offset_changes() {
    // G54 from the first line; G55 (x 100); G92 makes x read 5 where the tool is (x 110 in
    // machine coordinates: offset 105); G43 adds tool 2's offsets (TOOLS: X 0.5, Z 30.5); G92.1 and G49
    // take theirs away; M2's line changes nothing.
    let f = frames(
        "G0 X1
G55
G0 X10
G92 X5
T2 M6
G43
G0 Z1
G92.1
G49
G54",
    );
    assert_eq!(
        f,
        [
            (1, 1, [0.0, 0.0, 0.0]),
            (2, 2, [100.0, 0.0, 0.0]),
            (4, 2, [105.0, 0.0, 0.0]),
            (6, 2, [105.5, 0.0, 30.5]),
            (8, 2, [100.5, 0.0, 30.5]),
            (9, 2, [100.0, 0.0, 0.0]),
            (10, 1, [0.0, 0.0, 0.0]),
        ]
    );
    // Before the block's own move, which runs in them.
    let tools = crate::tools::ToolTable::parse(TOOLS).expect("a table");
    let mut m = machine(&XYZ);
    m.tools = Some(&tools);
    let p = read(
        &ended(
            "G0 X1
G55 G0 X2",
        ),
        &m,
    )
    .expect("read");
    let kinds: Vec<(usize, bool)> = p
        .blocks
        .iter()
        .filter(|b| !matches!(b.action, Action::End))
        .map(|b| (b.line, matches!(b.action, Action::WorkOffset { .. })))
        .collect();
    assert_eq!(kinds, [(1, true), (1, false), (2, true), (2, false)]);
}

#[test]
fn a_tool_change_stops_the_spindle_and_waits_for_the_tool_asked_for() {
    let p = with_tools("M3 S1000\nT2 M6\nG43\nG0 Z1\nT0 M6\nG49").expect("read");
    let actions: Vec<Action> = p.blocks.iter().map(|b| b.action).collect();
    assert_eq!(
        actions[1..3],
        [
            Action::Spindle {
                direction: Spindle::Off,
                speed_rpm: 1000.0
            },
            Action::ToolChange { tool: 2 }
        ]
    );
    // G43 takes the tool in the spindle: the tool's tip at Z1 puts the spindle 30.5 mm higher,
    // its X offset 0.5 mm over.
    assert_eq!(moves(&p.blocks)[0].0, [0.0, 0.0, 31.5, 0.0, 0.0, 0.0]);
    assert!(
        actions.contains(&Action::ToolChange { tool: 0 }),
        "T0 M6 empties the spindle"
    );
}

#[test]
fn tool_offsets_follow_g43_g43_1_g49_and_the_parameters_show_them() {
    let p = with_tools("T1 M6\nG43 H1\nG0 Z1\nG43.1 X2\nG0 X0\nG49\nG0 Z0\nG43 H1\nG0 X#5403").expect("read");
    let to: Vec<Pose> = moves(&p.blocks).iter().map(|m| m.0).collect();
    assert_eq!(to[0], [0.0, 0.0, 51.0, 0.0, 0.0, 0.0]);
    assert_eq!(to[1], [2.0, 0.0, 51.0, 0.0, 0.0, 0.0], "G43.1 X2 keeps Z's offset");
    assert_eq!(to[2], [2.0, 0.0, 0.0, 0.0, 0.0, 0.0], "G49: none");
    // #5403 the Z offset (50); #5400 the tool in the spindle: refused until the program has
    // put one there, then its number.
    assert!(with_tools("G0 X#5400").is_err());
    assert_eq!(
        moves(&with_tools("T2 M6\nG0 X#5400").expect("read").blocks)[0].0[0],
        2.0
    );
    // X to #5403 (tool 1's Z offset, 50); Z stays where G0 Z0 put it.
    assert_eq!(to[3], [50.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    // #5401 … #5406: the table's offsets of the tool in the spindle, applied or not (as
    // LinuxCNC 2.9 gives them); 0 without a tool.
    let p = with_tools("G0 X#5403\nT1 M6\nG0 X#5403\nG43.1 Z7\nG0 Y#5403\nG49\nT2 M6\nG0 X#5401 Y#5403").expect("read");
    let to: Vec<Pose> = moves(&p.blocks).iter().map(|m| m.0).collect();
    assert_eq!(to[0][0], 0.0);
    assert_eq!(to[1][0], 50.0);
    assert_eq!(to[2][1], 50.0, "G43.1 leaves the table's");
    assert_eq!((to[3][0], to[3][1]), (0.5, 30.5));
    // G10 L1 changes tool 1 for the rest of the program; L10 sets it from where the tool is.
    let p = with_tools("G10 L1 P1 Z20\nG43 H1\nG0 Z0\nG10 L10 P2 Z5\nG43 H2\nG0 Z5").expect("read");
    let to: Vec<Pose> = moves(&p.blocks).iter().map(|m| m.0).collect();
    assert_eq!(to[0][2], 20.0);
    assert_eq!(
        to[1], to[0],
        "L10 makes the tool read Z5 where it stands: G0 Z5 goes nowhere"
    );
    // Each is written back to the tool table as the run reaches it: the entry's line as
    // LinuxCNC writes it, at the G10's place among the actions.
    let entries: Vec<(u32, &str)> = p
        .messages
        .iter()
        .filter(|m| m.kind == pkm_api::trajectory::NcMessageKind::ToolEntry)
        .map(|m| (m.line, m.text.as_str()))
        .collect();
    assert_eq!(
        entries,
        [
            (1, "T1 P1 Z+20.000000 D6.000000 ;6 mm end mill"),
            (4, "T2 P2 X+0.500000 Z+15.000000 D3.000000 ;drill")
        ]
    );
    assert!(matches!(p.blocks[0].action, Action::Message(0)), "{:?}", p.blocks[0]);
    // G10 L1 fills the table to its most, not beyond.
    let fill = "#1 = 1\no1 while [#1 LE 1001]\nG10 L1 P#1 Z1\n#1 = [#1 + 1]\no1 endwhile";
    assert_eq!(
        with_tools(fill).map(|_| ()).expect_err("full").to_string(),
        "3:8: G10 L1: the tool table holds 1000 tools already, its most"
    );
}

#[test]
fn tool_words_are_refused_with_why() {
    for (text, why) in [
        ("T3 M6", "1:1: T3: tool 3 is not in the tool table"),
        ("T1.5", "1:1: T is a tool's number, a whole number 0 … 99999; got 1.5"),
        (
            "M6",
            "1:1: M6 needs a tool selected first: T… (T0 empties the spindle); the tool a program before this one left is not known here",
        ),
        (
            "G43",
            "1:1: G43 without H applies the tool in the spindle, and this program has not put one there (T… M6, or M61 Q…): write G43 H…",
        ),
        ("G0 X1 H1", "1:7: H belongs to G43 (the tool whose offsets apply)"),
        ("M61", "1:1: M61 needs Q: the number of the tool in the spindle"),
        ("M61 Q4", "1:5: Q4: tool 4 is not in the tool table"),
        (
            "G1 X1 D1 F100",
            "1:7: D belongs to G41, G42 (the tool whose diameter cutter compensation takes) or G41.1, G42.1 (the diameter)",
        ),
        (
            "G10 L11 P1 Z1",
            "1:5: G10 L11 is not supported: it measures a tool against G59.3, a coordinate system this interpreter does not have (G54 … G59); L10 measures it in the system in force",
        ),
        ("G10 L1 Z1", "1:5: G10 L1 needs P: the tool's number"),
        (
            "G10 L1 P1 R-1",
            "1:11: R is the tool's radius, zero or positive; got -1",
        ),
        ("G43.1", "1:1: G43.1 needs at least one axis word: the tool's offsets"),
        ("T1 T2", "1:4: T twice in one block"),
    ] {
        assert_eq!(with_tools(text).map(|_| ()).expect_err(text).to_string(), why, "{text}");
    }
}

#[test]
fn inverse_time_and_per_revolution_feeds_are_per_minute_on_the_path() {
    let p = with_tools("G93 G1 X10 F2\nG1 X20 F0.5\nG94 G1 X0 F100\nS2000 G95 G1 X5 F0.1\nG94 G20 G1 X10 F10")
        .expect("read");
    let feeds: Vec<Option<f64>> = moves(&p.blocks).iter().map(|m| m.2).collect();
    // 10 mm in 1/2 min; 10 mm in 2 min; 100 mm/min; 0.1 mm a turn at 2000 rpm; F10 read in
    // millimetres before the block's G20, as LinuxCNC reads it.
    assert_eq!(feeds, [Some(20.0), Some(5.0), Some(100.0), Some(200.0), Some(10.0)]);
    // Feeds below 0.1 a minute are ordinary per revolution and in inverse time: 0.05 mm a turn
    // at 1000 rpm, 0.004 in a turn at 500 rpm (in mm), 7.46 mm in 20 min; and 0.001 mm in one
    // minute at 0.1 mm/min, the least feed, as LinuxCNC 2.9 raises an inverse-time feed.
    let p = with_tools("S1000 G95 G1 X1 F0.05\nG20\nS500 G1 X0.1 F0.004\nG21 G93 G1 X10 F0.05\nG1 X10.001 F1")
        .expect("read");
    let feeds: Vec<f64> = moves(&p.blocks).iter().filter_map(|m| m.2).collect();
    let expected = [50.0, 0.004 * 25.4 * 500.0, (10.0 - 2.54) * 0.05, 0.1];
    assert!(
        feeds.len() == 4 && feeds.iter().zip(expected).all(|(f, e)| (f - e).abs() < 1e-9),
        "{feeds:?}"
    );
    for (text, why) in [
        (
            "G1 X1 F0.01",
            "1:7: the feed F must be at least 0.1 units/min (slower, a millimetre takes hours), got 0.01",
        ),
        (
            "S10 G95 G1 X1 F0.001",
            "1:12: per revolution (G95) the feed is F × S = 0.0100 mm/min: it must be at least 0.1 units/min (slower, a millimetre takes hours)",
        ),
        (
            "G93 G1 X10 F2\nX20",
            "2:1: in inverse time (G93) every G1, G2 or G3 needs F in its own block: the move takes 1/F minutes",
        ),
        (
            "G95 G1 X1 F0.1",
            "1:8: with the spindle speed S at 0, G1, G2 or G3 cannot feed per revolution (G95): set S first",
        ),
        (
            "G93 G81 X1 Z-1 R1 F2",
            "1:9: G81 cannot run in inverse time (G93), as in LinuxCNC: G94 or G95 first",
        ),
        (
            "G1 X1 F100\nG93 G1 X2",
            "2:8: in inverse time (G93) every G1, G2 or G3 needs F in its own block: the move takes 1/F minutes",
        ),
    ] {
        assert_eq!(with_tools(text).map(|_| ()).expect_err(text).to_string(), why, "{text}");
    }
}

#[test]
fn message_comments_become_messages_in_order() {
    let p = with_tools(
        "(MSG, load the part)\n#1 = 4\nG0 X1 (print,x is #<_x>, #1 is #1) ; (MSG,not this)\n/(DEBUG,#2)\n(msg x)",
    )
    .expect("read");
    let m: Vec<(u32, pkm_api::trajectory::NcMessageKind, &str)> =
        p.messages.iter().map(|m| (m.line, m.kind, m.text.as_str())).collect();
    use pkm_api::trajectory::NcMessageKind::*;
    assert_eq!(
        m,
        [
            (1, Msg, " load the part"),
            (3, Print, "x is 0.000000, 4.000000 is 4.000000"),
            (4, Debug, "0.000000")
        ]
    );
    // The message comes before the block's move, as LinuxCNC's.
    assert_eq!(p.blocks[1].action, Action::Message(1));
    assert!(matches!(p.blocks[2].action, Action::Move { .. }));
}

#[test]
fn a_loop_of_long_messages_is_refused_where_it_passes_the_memory_bound() {
    // 20 000 messages of 4 kB: 160 MB kept (twice), past a 64 MiB bound, refused at the message's
    // line before the memory is taken.
    let long = "x".repeat(4000);
    let text = format!("o1 repeat [20000]\n(DEBUG, {long})\no1 endrepeat\nM2\n");
    let bounds = crate::budget::Bounds {
        max_bytes: 64 << 20,
        ..crate::budget::Bounds::default()
    };
    let e = read_bounded(&text, &machine(&XYZ), &bounds, &crate::watch::Unwatched).expect_err("refused");
    assert_eq!(e.line, 2, "{e}");
    assert!(e.message.contains("more than 64 MiB"), "{e}");
}
