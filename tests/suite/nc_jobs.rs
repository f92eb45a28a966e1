//! The screen's jobs, in virtual time: MDI lines and a program run from a chosen
//! line are planned from where the tool stands, loaded and started through the screen's
//! inputs, run to their end on the simulated O-X glide, and go into the trace — whose replay
//! plans them again and agrees on every cycle.

use crate::common;

use common::{get, machine_config};
use pkm_api::screen_jobs::{ScreenJob, ScreenJobKind, ScreenJobSpec};
use pkm_api::trajectory::vars;
use pkm_joints::vars::TOOL;
use pkm_plc::compose::screen_job::{self, StandingPose};
use pkm_plc::compose::{self, Built, Options, Setup};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::VirtualClock;
use pkm_plc::services::hmi::commands::press;

/// A run in virtual time that goes on where it stood (the screen's commands come between).
struct Virtual {
    plc: Plc,
    clock: VirtualClock,
}

impl Virtual {
    fn new(mut plc: Plc) -> Virtual {
        let mut clock = VirtualClock::default();
        plc.init(0, &mut clock);
        Virtual { plc, clock }
    }

    /// Runs until `until_ms`; the main program's states on the way, and `each(plc)` after
    /// every pass.
    fn until(&mut self, until_ms: u64, mut each: impl FnMut(&Plc)) -> Vec<String> {
        let mut states: Vec<String> = Vec::new();
        while self.plc.next_release() < until_ms * 1_000_000 {
            let t = self.plc.next_release();
            self.clock.advance_to(t);
            self.plc.run_due(&mut self.clock, u64::MAX);
            let state = common::state(&self.plc);
            if states.last().is_none_or(|s| s != state) {
                states.push(state.to_string());
            }
            each(&self.plc);
        }
        states
    }
}

/// The O-X glide as shipped, built with a screen (and the `programs` folder, if any): its setup,
/// PLC, library of programs and jobs, and the screen's inputs.
fn ox_x_with_screen(
    programs: Option<std::path::PathBuf>,
) -> (
    Setup,
    Plc,
    pkm_api::library::NcLibrary,
    pkm_plc::services::hmi::commands::CommandSink,
) {
    let setup = Setup::new(machine_config("ox-x", |_| {})).expect("ox-x");
    let options = Options {
        programs,
        hmi: true,
        ..Options::default()
    };
    let Built {
        setup,
        plc,
        library,
        hmi,
        ..
    } = compose::build(setup, options).unwrap_or_else(|e| panic!("{e}"));
    (
        setup,
        plc,
        library.expect("a library for the screen's jobs"),
        hmi.expect("the screen's inputs"),
    )
}

/// A program of the O-X glide's plane: a 10 mm square from its start, the reference pose.
const SQUARE: &str = "G21 G90 G61\nG1 X10 F600\nY10\nX0\nY0\nM2\n";

#[test]
fn mdi_lines_and_a_run_from_a_line_start_where_the_tool_stands_and_replay_identically() {
    let dir = tempfile::tempdir().expect("tempdir");
    let programs = dir.path().join("programs");
    std::fs::create_dir(&programs).expect("a directory");
    std::fs::write(programs.join("square.ngc"), SQUARE).expect("the program");
    let (setup, plc, library, sink) = ox_x_with_screen(Some(programs));
    let trace = dir.path().join("jobs.jsonl");
    let digest = setup.digest().expect("a digest");
    let recorder = pkm_plc::services::trace::record::Recorder::create_with(&trace, &plc, &digest, Some(&library), None)
        .expect("the trace");
    let mut plc = plc;
    plc.set_recorder(Box::new(recorder));
    let mut run = Virtual::new(plc);
    let standing = StandingPose::of(&setup, &run.plc).expect("the O-X glide's set-points");
    // O-X is READY after referencing (11.65 s).
    let seen = run.until(13_000, |_| {});
    assert_eq!(seen.last().map(String::as_str), Some("READY"), "{seen:?}");
    // A job as the screen makes one: planned from where the tool stands, loaded and started.
    let make = |plc: &Plc, kind: ScreenJobKind| {
        let start = standing.pose(plc.global_image()).expect("a pose");
        let mut at = [0.0; 6];
        at.copy_from_slice(&start);
        let spec = ScreenJobSpec {
            kind,
            start: at,
            offsets: None,
            tool_table: None,
        };
        let job = screen_job::plan(&setup, &library, &spec).unwrap_or_else(|e| panic!("{e}"));
        let slot = library.screen.push(ScreenJob { spec, job }).expect("room");
        let number = library.screen_number(slot).expect("a number");
        sink.update(|c| {
            c.program = number;
            c.presses[press::NC[0]] += 1;
        });
        number
    };
    let mdi = make(
        &run.plc,
        ScreenJobKind::Mdi {
            text: "G1 X4 Y3 F600\nG0 X6".into(),
        },
    );
    assert_eq!(mdi, 2, "numbered after the library's one program");
    let seen = run.until(20_000, |_| {});
    assert_eq!(seen, ["AUTO", "READY"]);
    let at = |plc: &Plc| [get(plc, TOOL[0]), get(plc, TOOL[1])];
    let [x, y] = at(&run.plc);
    assert!(
        (x - 6.0).abs() < 0.01 && (y - 3.0).abs() < 0.01,
        "the MDI lines ended at ({x}, {y})"
    );
    assert!(get(&run.plc, vars::NC_COMPLETED));
    assert_eq!(get(&run.plc, vars::NC_PROGRAM), 2);
    // The square from its third line (Y10): to (10, 0) first, then up, across and down.
    let from = make(&run.plc, ScreenJobKind::FromLine { program: 1, line: 3 });
    assert_eq!(from, 3);
    let mut lines = Vec::new();
    let seen = run.until(40_000, |plc| {
        let line = get(plc, vars::NC_LINE);
        if get(plc, vars::NC_STATE) == 1 && lines.last() != Some(&line) {
            lines.push(line);
        }
    });
    assert_eq!(seen, ["AUTO", "READY"]);
    assert_eq!(lines, [3, 4, 5], "the lines it ran");
    let [x, y] = at(&run.plc);
    assert!(
        x.abs() < 0.01 && y.abs() < 0.01,
        "the square ended at its start: ({x}, {y})"
    );
    assert!(get(&run.plc, vars::NC_CONTOUR_MAX) <= 0.02);
    // The trace holds both jobs, and its replay plans them again and agrees.
    let recorder = run.plc.take_recorder().expect("the recorder");
    recorder.finish().expect("the trace is written");
    let text = std::fs::read_to_string(&trace).expect("the trace");
    assert!(text.contains(r#""job":{"number":2,"#), "the MDI job is in the trace");
    assert!(
        text.contains(r#""from_line":{"program":1,"line":3}"#),
        "the run from a line is in it"
    );
    let report = pkm_plc::compose::replay::replay(&trace, &setup, false).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.records > 1000, "{} records", report.records);
}

#[test]
fn a_job_that_cannot_run_is_refused_with_its_line_and_nothing_is_stored() {
    let setup = Setup::new(machine_config("ox-x", |_| {})).expect("ox-x");
    let library = pkm_plc::compose::nc_job::library(None, Vec::new(), true, None).expect("a screen's library");
    let spec = |text: &str| ScreenJobSpec {
        kind: ScreenJobKind::Mdi { text: text.into() },
        start: [0.0; 6],
        offsets: None,
        tool_table: None,
    };
    let refused = |text: &str| {
        screen_job::plan(&setup, &library, &spec(text))
            .map(|_| ())
            .expect_err("refused")
            .message
    };
    assert_eq!(
        refused("G1 X5"),
        "MDI:1:4: no feed rate: an F word is needed before the first G1, G2 or G3"
    );
    assert!(
        refused("G0 X900").starts_with("MDI: the program leaves what ox-x can reach"),
        "{}",
        refused("G0 X900")
    );
    assert_eq!(refused("  \n"), "MDI: no line to run");
    // 55 hours as planned: three dwells of 66 000 s (G4 P is in seconds; 66 000 ms was meant).
    assert_eq!(
        refused("G1 X1 F60\nG4 P66000\nG4 P66000\nG4 P66000\nG1 X0 F120"),
        "MDI: planned to run 55 h (55 h of it dwells), longer than the 12 h a program \
         may (nc.max_duration_h); the longest move is line 1's, 1.0 s. A feed or a dwell \
         mistyped is the usual cause (F is per minute, G4 P in seconds); else split the program \
         or raise the bound"
    );
    // Within the bound it plans (a dwell of 11 hours).
    screen_job::plan(&setup, &library, &spec("G1 X1 F60\nG4 P39600"))
        .map(|_| ())
        .unwrap_or_else(|e| panic!("{}", e.message));
    let from = ScreenJobSpec {
        kind: ScreenJobKind::FromLine { program: 1, line: 3 },
        start: [0.0; 6],
        offsets: None,
        tool_table: None,
    };
    let e = screen_job::plan(&setup, &library, &from)
        .map(|_| ())
        .expect_err("no program 1");
    assert_eq!(e.message, "no program 1 to run from a line: the run has 0");
    assert_eq!(library.screen.made(), 0);
}

/// `nc.max_duration_h` bounds what a program may take as planned: at 0.5 h a 40-minute feed is
/// refused, with the line whose move takes longest; a bound out of its range is a refusal too.
#[test]
fn a_program_planned_longer_than_nc_max_duration_h_is_refused() {
    let setup = Setup::new(machine_config("ox-x", |c| {
        c["nc"]["max_duration_h"] = serde_json::json!(0.5)
    }))
    .expect("ox-x");
    let library = pkm_plc::compose::nc_job::library(None, Vec::new(), true, None).expect("a screen's library");
    let spec = ScreenJobSpec {
        kind: ScreenJobKind::Mdi {
            text: "G1 X2 F60\nG1 X0 F0.05\n".into(),
        },
        start: [0.0; 6],
        offsets: None,
        tool_table: None,
    };
    let e = screen_job::plan(&setup, &library, &spec)
        .map(|_| ())
        .expect_err("refused");
    assert_eq!(
        e.message,
        "MDI:2:7: the feed F must be at least 0.1 units/min (slower, a millimetre takes hours), got 0.05"
    );
    let spec = ScreenJobSpec {
        kind: ScreenJobKind::Mdi {
            text: "G1 X4 F60\nG1 X0 F0.1\n".into(),
        },
        ..spec
    };
    let e = screen_job::plan(&setup, &library, &spec)
        .map(|_| ())
        .expect_err("refused");
    assert_eq!(
        e.message,
        "MDI: planned to run 40 min 4 s, longer than the 30 min 0 s a program may (nc.max_duration_h); \
         the longest move is line 2's, 40 min 0 s. A feed or a dwell mistyped is the usual cause (F is \
         per minute, G4 P in seconds); else split the program or raise the bound"
    );
    let setup = Setup::new(machine_config("ox-x", |c| {
        c["nc"]["max_duration_h"] = serde_json::json!(0.0)
    }))
    .expect("ox-x");
    let e = screen_job::plan(&setup, &library, &spec)
        .map(|_| ())
        .expect_err("refused");
    assert!(e.message.contains("nc.max_duration_h"), "{}", e.message);
}

/// An O-X run built with a screen from `setup` (its 3 coordinates), its library, and the desk
/// the screen makes jobs at — its offsets and their keeper as the setup gives them.
fn screen_desk(setup: Setup) -> (Plc, pkm_api::library::NcLibrary, pkm_plc::services::hmi::jobs::JobDesk) {
    let options = Options {
        hmi: true,
        ..Options::default()
    };
    let Built {
        setup, plc, library, ..
    } = compose::build(setup, options).unwrap_or_else(|e| panic!("{e}"));
    let library = library.expect("a screen's run has a library");
    let standing = StandingPose::of(&setup, &plc).expect("the set-points");
    let desk = pkm_plc::services::hmi::jobs::JobDesk::new(
        setup.clone(),
        library.clone(),
        standing,
        None,
        setup.persistent(3),
        setup.keeper(3),
    );
    (plc, library, desk)
}

#[test]
fn the_screen_makes_a_job_from_ready_only_numbered_after_the_programs() {
    let (plc, library, desk) = screen_desk(Setup::new(machine_config("ox-x", |_| {})).expect("ox-x"));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    let mdi = || ScreenJobKind::Mdi {
        text: "G1 X2 F300".into(),
    };
    let refused = runtime
        .block_on(desk.make(mdi()))
        .map(|m| m.number)
        .expect_err("no frame yet");
    assert_eq!(
        refused,
        "a job runs from READY: the PLC has not published its state yet"
    );
    desk.observe("INIT", plc.global_image());
    let refused = runtime.block_on(desk.make(mdi())).map(|m| m.number).expect_err("INIT");
    assert_eq!(refused, "a job runs from READY: the machine is INIT");
    desk.observe("READY", plc.global_image());
    let made = runtime.block_on(desk.make(mdi())).unwrap_or_else(|e| panic!("{e}"));
    // No program in the library: the first job is number 1; its text ends as a program does.
    assert_eq!((made.number, made.job.file.as_str()), (1, "MDI"));
    assert_eq!(made.job.text, "G1 X2 F300\nM2\n");
    assert_eq!(library.screen.made(), 1);
}

/// A touch-off: from READY only, the work system moved so that where the tool stands reads the
/// value (as G10 L20), written to the parameter file (LinuxCNC's `.var`), a job planned after it
/// with the new origin — and a run started with that file starts from it.
#[test]
fn a_touch_off_moves_the_work_origin_keeps_it_in_the_parameter_file_and_jobs_follow_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let var = dir.path().join("ox-x.var");
    let setup = Setup::new(machine_config("ox-x", |_| {}))
        .expect("ox-x")
        .with_param_file(Some(&var))
        .unwrap_or_else(|e| panic!("{}", e.message));
    assert_eq!(setup.persistent, None, "no file yet: the configuration's offsets");
    let (plc, library, desk) = screen_desk(setup);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    desk.observe("INIT", plc.global_image());
    assert_eq!(
        runtime.block_on(desk.touch_off(0, 0, 5.0)).map(|_| ()),
        Err("a touch-off is made in READY: the machine is INIT".to_string())
    );
    desk.observe("READY", plc.global_image());
    // The tool stands at the reference pose (0, 0, 0): X reads 5 there when G54's origin is at −5.
    let t = runtime.block_on(desk.touch_off(0, 0, 5.0)).expect("a touch-off");
    assert_eq!((t.was, t.now), (0.0, -5.0));
    let t = runtime.block_on(desk.touch_off(1, 2, -2.5)).expect("G55 Z");
    assert_eq!(t.now, 2.5);
    assert!(desk.offsets_changed());
    let text = std::fs::read_to_string(&var).expect("the parameter file");
    assert!(text.contains("5221\t-5.000000\n"), "{text}");
    assert!(text.contains("5243\t2.500000\n"), "{text}");
    // Replaced whole: nothing left beside it.
    assert!(!dir.path().join("ox-x.var.new").exists());
    // A job planned now: G1 X10 in G54 goes to machine X 5.
    let made = runtime
        .block_on(desk.make(ScreenJobKind::Mdi {
            text: "G1 X10 F300".into(),
        }))
        .unwrap_or_else(|e| panic!("{e}"));
    let end = made
        .job
        .trajectory
        .sample(made.job.trajectory.duration_s(), &mut 0)
        .pose;
    assert!((end[0] - 5.0).abs() < 1e-9, "{end:?}");
    assert!(
        library.screen_spec(made.number).and_then(|s| s.offsets).is_some(),
        "the job carries them"
    );
    // The next run starts from the file; a file that cannot be read names its line.
    let next = Setup::new(machine_config("ox-x", |_| {}))
        .expect("ox-x")
        .with_param_file(Some(&var))
        .unwrap_or_else(|e| panic!("{}", e.message));
    assert_eq!(next.persistent(3).origins[0][0], -5.0);
    std::fs::write(&var, "5221 -5\n5230 90\n").expect("write");
    let refused = Setup::new(machine_config("ox-x", |_| {}))
        .expect("ox-x")
        .with_param_file(Some(&var))
        .map(|_| ())
        .expect_err("a rotation");
    assert_eq!(
        refused.message,
        format!(
            "{}:2:1: #5230 rotates a coordinate system by 90°: rotation (G10 R) is not supported",
            var.display()
        )
    );
}

/// Four lines of a few millimetres at F6000 near home: before the planner was rewritten more
/// than half of such programs planned to NaN, and this one, sent as MDI, took the PLC down from
/// its cyclic thread. The same text through every other entry point: `tests/suite/nc_entry_points.rs`.
#[test]
fn the_mdi_that_took_the_plc_down_runs_to_its_end() {
    let (setup, plc, library, sink) = ox_x_with_screen(None);
    let mut run = Virtual::new(plc);
    let standing = StandingPose::of(&setup, &run.plc).expect("the O-X glide's set-points");
    let seen = run.until(13_000, |_| {});
    assert_eq!(seen.last().map(String::as_str), Some("READY"), "{seen:?}");
    let start = standing.pose(run.plc.global_image()).expect("a pose");
    let mut at = [0.0; 6];
    at.copy_from_slice(&start);
    let spec = ScreenJobSpec {
        kind: ScreenJobKind::Mdi {
            text: crate::nc_entry_points::NAN_PROGRAM.into(),
        },
        start: at,
        offsets: None,
        tool_table: None,
    };
    let job = screen_job::plan(&setup, &library, &spec).unwrap_or_else(|e| panic!("{e}"));
    assert!(job.trajectory.duration_s().is_finite());
    let slot = library.screen.push(ScreenJob { spec, job }).expect("room");
    let number = library.screen_number(slot).expect("a number");
    sink.update(|c| {
        c.program = number;
        c.presses[press::NC[0]] += 1;
    });
    let seen = run.until(25_000, |plc| {
        assert!(get(plc, TOOL[0]).is_finite() && get(plc, TOOL[1]).is_finite());
    });
    assert_eq!(seen, ["AUTO", "READY"]);
    assert!(get(&run.plc, vars::NC_COMPLETED));
    let [x, y] = [get(&run.plc, TOOL[0]), get(&run.plc, TOOL[1])];
    assert!(
        (x + 4.204).abs() < 0.01 && (y - 2.846).abs() < 0.01,
        "the MDI lines ended at ({x}, {y})"
    );
}

/// A touch-off rewrites the parameter file with what it keeps and every number of the file it
/// does not: LinuxCNC's G92 offset, G59.3, U and the a b c of G54 on the 3-axis O-X glide
/// (before, the rewrite deleted them).
#[test]
fn a_touch_off_keeps_the_numbers_of_the_parameter_file_it_does_not_use() {
    let dir = tempfile::tempdir().expect("tempdir");
    let var = dir.path().join("ox-x.var");
    let linuxcnc = "5161 1.5\n5167 9\n5210 1\n5211 3.25\n5212 -1\n5220 2\n5221 4\n5224 30\n5227 8\n5381 6\n";
    std::fs::write(&var, linuxcnc).expect("write");
    let setup = Setup::new(machine_config("ox-x", |_| {}))
        .expect("ox-x")
        .with_param_file(Some(&var))
        .unwrap_or_else(|e| panic!("{}", e.message));
    let (plc, _library, desk) = screen_desk(setup);
    desk.observe("READY", plc.global_image());
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    runtime.block_on(desk.touch_off(0, 1, 2.0)).expect("G54 Y");
    let text = std::fs::read_to_string(&var).expect("the parameter file");
    for kept in [
        "5167\t9\n",
        "5210\t1\n",
        "5211\t3.25\n",
        "5212\t-1\n",
        "5220\t2\n",
        "5224\t30\n",
        "5227\t8\n",
        "5381\t6\n",
    ] {
        assert!(text.contains(kept), "{kept:?} kept in {text}");
    }
    assert!(text.contains("5161\t1.500000\n5162\t0.000000\n"), "{text}");
    assert!(
        text.contains("5221\t4.000000\n5222\t-2.000000\n5223\t0.000000\n5224\t30\n"),
        "{text}"
    );
    // LinuxCNC reads it: each number once, in increasing order.
    let numbers: Vec<usize> = text
        .lines()
        .map(|l| l.split('\t').next().and_then(|n| n.parse().ok()).expect("a number"))
        .collect();
    assert!(numbers.windows(2).all(|w| w[0] < w[1]), "{numbers:?}");
}

/// `--var-file` naming a symbolic link is refused (a touch-off would put a file in the link's
/// place); a file that is not a parameter file is refused with where, not what it holds (before:
/// its first field quoted — a line of /etc/shadow when run as root).
#[test]
fn a_parameter_file_is_named_itself_and_a_foreign_one_is_not_echoed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let foreign = dir.path().join("shadow");
    std::fs::write(&foreign, "root:$6$salt$secrethash:19000:0:99999:7:::\n").expect("write");
    let refused = |path: &std::path::Path| {
        Setup::new(machine_config("ox-x", |_| {}))
            .expect("ox-x")
            .with_param_file(Some(path))
            .map(|_| ())
            .expect_err("refused")
            .message
    };
    assert_eq!(
        refused(&foreign),
        format!(
            "{}:1:1: not a parameter's number (a whole number, 5221 say)",
            foreign.display()
        )
    );
    let link = dir.path().join("ox-x.var");
    std::os::unix::fs::symlink(&foreign, &link).expect("a symbolic link");
    assert_eq!(
        refused(&link),
        format!(
            "{}: is a symbolic link: a touch-off rewrites the parameter file, and would replace the link with a file \
             of its own; name the file itself",
            link.display()
        )
    );
}
