//! What a program's text may cost: values nested without end, programs that make
//! millions of moves or metres of path from a few bytes, canned cycles of countless pecks, and
//! reading that never ends are refused — with their line and column and the bound they pass —
//! instead of aborting the process, filling the memory or planning for minutes.

use crate::common;

use common::{pkm, stderr};
use pkm_nc::lexer::{MAX_NESTING, Parameters, read_line};

/// Writes `text` as `name` in `dir`; its path as text.
fn program(dir: &std::path::Path, name: &str, text: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write the program");
    path.to_str().expect("utf-8").to_string()
}

/// `nc check FILE` on the O-X glide (and `more` arguments): its exit code and its error line.
fn check(file: &str, more: &[&str]) -> (Option<i32>, String) {
    let mut args = vec!["nc", "check", file];
    if more.is_empty() {
        args.extend(["--machine", "ox-x"]);
    }
    args.extend(more);
    let o = pkm(&args);
    (o.status.code(), stderr(&o).trim_end().to_string())
}

const NESTING: &str = "the value nests deeper than 64 levels (brackets, signs, parameters of parameters and functions, counted together): write it in steps with parameters";

#[test]
fn values_nested_without_end_are_refused_where_they_pass_the_bound() {
    // Both aborted `nc check` and `run --program` with a stack overflow before (SIGABRT).
    let dir = tempfile::tempdir().expect("tempdir");
    let brackets = program(
        dir.path(),
        "brackets.ngc",
        &format!("G1 X[{}1{}] F100\nM2\n", "[".repeat(16_000), "]".repeat(16_000)),
    );
    assert_eq!(
        check(&brackets, &[]),
        (Some(2), format!("error: {brackets}:1:69: {NESTING}"))
    );
    let signs = program(
        dir.path(),
        "signs.ngc",
        &format!("G0 X0\nG1 X{}[1] F100\nM2\n", "-".repeat(32_000)),
    );
    assert_eq!(check(&signs, &[]), (Some(2), format!("error: {signs}:2:69: {NESTING}")));
}

#[test]
fn the_deepest_values_read_in_a_small_stack() {
    // Every kind of nesting at the bound's depth, read on a thread of 256 KiB (the threads that
    // read programs have 2 MiB or more): the bound keeps every program's reading far from a
    // stack overflow, in unoptimised builds too.
    let k = MAX_NESTING - 1;
    let lines = [
        format!("G1 X{}1{}", "[".repeat(k), "]".repeat(k)),
        format!("G1 X{}[1]", "-".repeat(k - 1)),
        // Each function is two levels: its own and its argument's bracket.
        format!("G1 X[{}1{}]", "abs[".repeat(k / 2 - 1), "]".repeat(k / 2 - 1)),
        format!("G1 X{}1", "#".repeat(k - 1)),
    ];
    /// Every numbered parameter holds 1: `##…#1` is #1.
    struct Ones;
    impl Parameters for Ones {
        fn numbered(&self, _: usize) -> Result<f64, String> {
            Ok(1.0)
        }
        fn named(&self, _: &str) -> Option<f64> {
            None
        }
    }
    let read_all = move || {
        lines
            .iter()
            .map(|l| read_line(l, 1, false, &Ones).map(|_| ()).map_err(|e| e.to_string()))
            .collect::<Vec<_>>()
    };
    let results = std::thread::Builder::new()
        .stack_size(256 * 1024)
        .spawn(read_all)
        .expect("a thread")
        .join()
        .expect("no overflow");
    assert!(results.iter().all(Result::is_ok), "{results:?}");
}

#[test]
fn a_few_bytes_that_make_millions_of_moves_or_metres_are_refused_at_the_line_that_passes_the_bound() {
    let dir = tempfile::tempdir().expect("tempdir");
    // 79 bytes, two million moves: 1.1 GB kept per MDI job before.
    let moves = program(
        dir.path(),
        "moves.ngc",
        "F6000\no1 repeat [999999]\nG1 X1\nG1 X0\no1 endrepeat\nM2\n",
    );
    assert_eq!(
        check(&moves, &[]),
        (
            Some(2),
            format!(
                "error: {moves}:4:1: the program makes more than 1000000 moves and other actions (the bound: nc.max_moves): split it, or loop over fewer"
            )
        )
    );
    // 100 000 circles of 1000 turns: 628 km of path, which the check sampled for minutes.
    let turns = program(
        dir.path(),
        "turns.ngc",
        "G1 F600\no1 repeat [100000]\nG2 X0 Y0 I1 J0 P1000\no1 endrepeat\nM2\n",
    );
    let (code, error) = check(&turns, &[]);
    assert_eq!(code, Some(2));
    assert!(
        error.starts_with(&format!(
            "error: {turns}:3:1: the program's plan would take more than 2048 MiB (the bound: nc.max_plan_mib): 218 actions so far, and a velocity profile of "
        )),
        "{error}"
    );
    // A canned cycle of pecks a thousandth of a millimetre deep, a thousand times.
    let pecks = program(
        dir.path(),
        "pecks.ngc",
        "G0 X0 Y0 Z5\nG83 X1 Y1 Z-20 R1 Q0.001 F100 L1000\nG80\nM2\n",
    );
    assert_eq!(
        check(&pecks, &[]),
        (
            Some(2),
            format!(
                "error: {pecks}:2:5: G83: the cycle makes more than the 1000000 moves the program may make (the bound: nc.max_moves): fewer repeats L, or a deeper peck Q"
            )
        )
    );
}

#[test]
fn the_bounds_are_the_configurations_and_checked_with_their_path() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = common::read_json(&common::root().join("machines/ox-x.json"));
    config["io_map"] = common::root().join("io-map/ox-x.json").to_str().expect("utf-8").into();
    config["nc"]["max_moves"] = 1000.into();
    let path = common::write_config(dir.path(), "ox-x.json", &config);
    let config_arg = path.to_str().expect("utf-8");
    let moves = program(
        dir.path(),
        "moves.ngc",
        "F600\no1 repeat [600]\nG1 X1\nG1 X0\no1 endrepeat\nM2\n",
    );
    let (code, error) = check(&moves, &["--config", config_arg]);
    assert_eq!(code, Some(2));
    assert!(error.ends_with("4:1: the program makes more than 1000 moves and other actions (the bound: nc.max_moves): split it, or loop over fewer"), "{error}");
    // Out of their ranges: refused by `check` with their path.
    config["nc"]["max_moves"] = 10.into();
    config["nc"]["max_plan_mib"] = 0.into();
    config["nc"]["max_planning_s"] = 0.into();
    let path = common::write_config(dir.path(), "ox-x.json", &config);
    let o = pkm(&["check", "--config", path.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2));
    let text = stderr(&o);
    for at in ["nc.max_moves: ", "nc.max_plan_mib: ", "nc.max_planning_s: "] {
        assert!(text.contains(at), "{at} in {text}");
    }
}

#[test]
fn reading_that_does_not_end_in_time_is_stopped_at_the_time_bound() {
    // Twenty million lines of a loop that sets a parameter: no move, so no bound of cost
    // applies; the time bound stops it (a second here).
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = common::read_json(&common::root().join("machines/ox-x.json"));
    config["io_map"] = common::root().join("io-map/ox-x.json").to_str().expect("utf-8").into();
    config["nc"]["max_planning_s"] = 1.into();
    let path = common::write_config(dir.path(), "ox-x.json", &config);
    let endless = program(
        dir.path(),
        "endless.ngc",
        "#1=0\no1 while [#1 LT 100000000]\n#1=[#1+1]\no1 endwhile\nM2\n",
    );
    let (code, error) = check(&endless, &["--config", path.to_str().expect("utf-8")]);
    assert_eq!(code, Some(2));
    assert!(
        error.ends_with(
            ": stopped: reading, checking and planning the program took longer than 1 s (the bound: nc.max_planning_s)"
        ),
        "{error}"
    );
}
