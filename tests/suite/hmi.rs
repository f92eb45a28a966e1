//! The operator screen's inputs in virtual time (no server: its command sink written directly,
//! as the server writes it): the screen's jog of one pose coordinate moves that coordinate alone,
//! its jog of one joint moves that joint alone (once referenced, never before), its STOP is an
//! ERROR like the panel's.

use crate::common;

use common::{get, machine_config, transitions};
use pkm_joints::vars;
use pkm_plc::compose::{self, Options, Setup};

#[test]
fn the_screens_jog_of_one_axis_moves_that_axis_alone_and_its_stop_is_the_panels() {
    let (mut plc, sink) = with_screen(machine_config("hexapod", |_| {}), None);
    let mut at_ready: Option<[f64; 6]> = None;
    let mut after_jog: Option<[f64; 6]> = None;
    let seen = transitions(&mut plc, 16_000, |plc, t| {
        let tool: [f64; 6] = std::array::from_fn(|c| get(plc, vars::TOOL[c]));
        match t {
            // READY at 7.65 s: +z (the third pose coordinate) held for two seconds.
            9_000 => {
                at_ready = Some(tool);
                sink.update(|c| {
                    c.jog = [0.6, 0.0];
                    c.jog_axis = 3;
                });
            }
            11_000 => sink.update(|c| c.jog = [0.0; 2]),
            13_000 => {
                after_jog = Some(tool);
                sink.update(|c| c.presses[pkm_plc::services::hmi::commands::press::STOP] += 1);
            }
            _ => {}
        }
    });
    let (before, after) = (at_ready.expect("READY"), after_jog.expect("jogged"));
    assert!(after[2] - before[2] > 5.0, "z moved: {before:?} → {after:?}");
    for c in [0, 1, 3, 4, 5] {
        assert!(
            (after[c] - before[c]).abs() < 0.01,
            "coordinate {c} stayed: {before:?} → {after:?}"
        );
    }
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        ["REBOOT", "INIT", "READY", "MOTION", "READY", "ERROR"],
        "{seen:?}"
    );
    assert_eq!(seen[5].2.as_deref(), Some("STOP"));
    assert!(seen[5].0 - 13_000 <= 50, "within a main cycle: {seen:?}");
}

/// A PLC of the configuration `loaded` on its simulated machine, with the screen's commands.
fn with_screen(
    loaded: pkm_plc::runtime::config::LoadedConfig,
    scenario: Option<&std::path::Path>,
) -> (
    pkm_plc::runtime::plc::Plc,
    pkm_plc::services::hmi::commands::CommandSink,
) {
    let setup = Setup::new(loaded).expect("a machine");
    let built = compose::build(
        setup,
        Options {
            hmi: true,
            scenario: scenario.map(std::path::Path::to_path_buf),
            ..Options::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    (built.plc, built.hmi.expect("the screen's commands"))
}

#[test]
fn the_screens_jog_of_one_joint_moves_that_joint_alone_and_stops_on_the_border() {
    let (mut plc, sink) = with_screen(machine_config("hexapod", |_| {}), None);
    let joints =
        |plc: &pkm_plc::runtime::plc::Plc| -> [f64; 6] { std::array::from_fn(|j| get(plc, vars::JOINT_POSITION[j])) };
    let (mut at_ready, mut after_jog, mut on_border) = (None, None, None);
    let mut fastest: f64 = 0.0;
    let seen = transitions(&mut plc, 120_000, |plc, t| {
        let q = joints(plc);
        if t > 9_000 {
            fastest = fastest.max(get(plc, vars::SETPOINT_VELOCITY[1]).abs());
        }
        match t {
            // READY at 7.65 s: joint 2 lengthened, at 0.8 of the screen's joint speed (5 mm/s).
            9_000 => {
                at_ready = Some(q);
                sink.update(|c| {
                    c.jog = [0.8, 0.0];
                    c.jog_axis = -2;
                });
            }
            11_000 => after_jog = Some(q),
            // Held on: the joint brakes for the border of the allowed region and stands on it.
            110_000 => {
                on_border = Some(q);
                sink.update(|c| c.jog = [0.0; 2]);
            }
            _ => {}
        }
    });
    let (before, after) = (at_ready.expect("READY"), after_jog.expect("jogged"));
    assert!(
        (7.0..8.0).contains(&(after[1] - before[1])),
        "joint 2 lengthened by about 0.8 × 5 mm/s × 2 s: {before:?} → {after:?}"
    );
    for j in [0, 2, 3, 4, 5] {
        assert!(
            (after[j] - before[j]).abs() < 0.01,
            "joint {} stayed: {before:?} → {after:?}",
            j + 1
        );
    }
    assert!(fastest <= 4.0 + 1e-9, "never above the commanded 4 mm/s: {fastest}");
    let border = on_border.expect("held on");
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        ["REBOOT", "INIT", "READY", "MOTION", "READY"],
        "stopped on the border without an error: {seen:?}"
    );
    let stood = seen[4].0;
    assert!(stood > 110_000, "moved until released: {seen:?}");
    // Where it stood: the tool's pose inside the world limits (±100 mm) and the joint inside its
    // software limits (400 + 2 … 1000 − 2 mm).
    let tool: [f64; 6] = std::array::from_fn(|c| get(&plc, vars::TOOL[c]));
    assert!(border[1] > after[1] + 20.0, "went on to the border: {border:?}");
    assert!((402.0..=998.0).contains(&border[1]), "{border:?}");
    assert!(tool[..3].iter().all(|c| c.abs() <= 100.0 + 0.01), "{tool:?}");
}

#[test]
fn the_screen_never_jogs_a_joint_before_referencing_even_with_the_panels_override_held() {
    // pn101's joint 1 stands past its positive limit switch (60 mm) at power-on: INIT waits in
    // joint mode. The panel's override is held; the screen's joint jog moves nothing.
    let edit = |c: &mut serde_json::Value| c["plant"]["joints"][0]["start_mm"] = serde_json::json!(60.5);
    let dir = tempfile::tempdir().expect("a temporary directory");
    let scenario = dir.path().join("override.json");
    std::fs::write(
        &scenario,
        r#"{"events": [{"at_ms": 500, "input": "BUTTON_OVERRIDE", "value": true}]}"#,
    )
    .expect("the scenario written");
    let (mut plc, sink) = with_screen(machine_config("pn101", edit), Some(&scenario));
    let mut notes = Vec::new();
    let seen = transitions(&mut plc, 4_000, |plc, t| {
        if t == 1_000 {
            sink.update(|c| {
                c.jog = [-1.0, 0.0];
                c.jog_axis = -1;
            });
        }
        let note = plc.app_status().and_then(|s| s.note).map(str::to_string);
        if notes.last() != Some(&note) {
            notes.push(note);
        }
    });
    assert_eq!(
        common::joint_plant(&plc).position_mm(0),
        60.5,
        "joint 1 stayed on its switch"
    );
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT"], "{seen:?}");
    assert_eq!(
        notes.last().cloned().flatten().as_deref(),
        Some(
            "the screen jogs once the machine is referenced; in joint mode, jog from the panel with BUTTON_OVERRIDE held"
        ),
        "{notes:?}"
    );
}

#[test]
fn the_screens_jog_of_one_trijoint_carriage_moves_it_alone_within_its_software_limit() {
    use pkm_trijoint::vars as t;
    let (mut plc, sink) = with_screen(common::loaded(&common::repo_config()), None);
    let carriages = |plc: &pkm_plc::runtime::plc::Plc| t::POSITION_MM.map(|v| get(plc, v));
    let m = |plc: &pkm_plc::runtime::plc::Plc| t::M.map(|v| get(plc, v));
    let (mut at_ready, mut after_jog, mut held) = (None, None, None);
    let seen = transitions(&mut plc, 90_000, |plc, t| match t {
        // READY at 40.2 s: the left carriage down, at half of M's jog speed (20 mm/s).
        42_000 => {
            at_ready = Some((carriages(plc), m(plc)));
            sink.update(|c| {
                c.jog = [-0.5, 0.0];
                c.jog_axis = -1;
            });
        }
        43_000 => after_jog = Some((carriages(plc), m(plc))),
        // Held on: it brakes for its software limit (or the border of M's region) and stands.
        85_000 => {
            held = Some(carriages(plc));
            sink.update(|c| c.jog = [0.0; 2]);
        }
        _ => {}
    });
    let ((q0, m0), (q1, m1)) = (at_ready.expect("READY"), after_jog.expect("jogged"));
    assert!(
        (-10.5..-8.0).contains(&(q1[0] - q0[0])),
        "the left carriage went down by about 10 mm/s × 1 s: {q0:?} → {q1:?}"
    );
    assert!(
        (q1[1] - q0[1]).abs() < 0.01,
        "the right carriage stayed: {q0:?} → {q1:?}"
    );
    assert!(
        (m1[0] - m0[0]).hypot(m1[1] - m0[1]) > 1.0,
        "M followed: {m0:?} → {m1:?}"
    );
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        ["REBOOT", "INIT", "READY", "MOTION", "READY"],
        "stood without an error: {seen:?}"
    );
    let stood = held.expect("held on");
    assert!(
        stood[0] < q1[0] - 20.0 && stood[0] >= 2.0 - 0.05,
        "went on, and stood inside the lower software limit (2 mm): {stood:?}"
    );
}

#[test]
fn the_screen_draws_the_mechanisms_at_the_measured_joints() {
    use pkm_plc::image::Value;
    use pkm_plc::services::hmi::mechanism::Mechanism;
    let setup = Setup::new(common::loaded(&common::repo_config())).expect("the TRIJOINT");
    let plc = setup.plc(setup.declaring_bus().expect("a bus")).expect("a PLC");
    let mut mechanism = Mechanism::of(&setup, &plc).expect("the TRIJOINT's kinematics draws");
    let mut image = plc.global_image().to_vec();
    for name in ["JOINT1_POSITION", "JOINT2_POSITION"] {
        let i = plc.vars().index_of(name).expect("a position");
        image[usize::from(i)] = Value::Real(125.0);
    }
    let links = mechanism.links(&image).expect("a pose at mid-travel");
    assert_eq!(links.len(), 6, "two guides, the rod, the arm's triangle");
    // Outside the travel: no pose, nothing drawn.
    let i = plc.vars().index_of("JOINT1_POSITION").expect("a position");
    image[usize::from(i)] = Value::Real(1e6);
    assert!(mechanism.links(&image).is_none());
    // The hexapod's: six struts and the outlines of base and platform, at its home lengths.
    let hexapod = Setup::new(machine_config("hexapod", |_| {})).expect("the hexapod");
    let plc = hexapod.plc(hexapod.declaring_bus().expect("a bus")).expect("a PLC");
    let mut mechanism = Mechanism::of(&hexapod, &plc).expect("the hexapod's kinematics draws");
    let mut image = plc.global_image().to_vec();
    for j in 0..6 {
        let i = plc.vars().index_of(vars::JOINT_POSITION[j].name()).expect("a position");
        image[usize::from(i)] = Value::Real(755.57);
    }
    assert_eq!(mechanism.links(&image).map(<[_]>::len), Some(19));
}

#[test]
fn the_screen_loads_another_program_outside_auto_and_the_run_replays_with_it() {
    use pkm_api::trajectory::vars as nc;
    let dir = tempfile::tempdir().expect("a temporary directory");
    let library = dir.path().join("programs");
    std::fs::create_dir(&library).expect("the directory");
    for file in ["ox-x-target.ngc", "ox-x-text.ngc", "hexapod-tilted-circle.ngc"] {
        std::fs::copy(common::root().join("programs").join(file), library.join(file)).expect("copied");
    }
    let options = || Options {
        hmi: true,
        programs: Some(library.clone()),
        ..Options::default()
    };
    let setup = Setup::new(machine_config("ox-x", |_| {})).expect("the O-X glide");
    let built = compose::build(setup, options()).unwrap_or_else(|e| panic!("{e}"));
    // The hexapod's program does not fit the O-X glide: listed with why, not offered.
    assert_eq!(built.refused.len(), 1, "{:?}", built.refused);
    assert!(built.refused[0].0.ends_with("hexapod-tilted-circle.ngc"));
    assert!(
        built.refused[0]
            .1
            .ends_with("hexapod-tilted-circle.ngc:5:4: A: this machine's axes are X Y Z"),
        "{}",
        built.refused[0].1
    );
    let library_of = built.library.expect("two programs");
    let files: Vec<&str> = library_of.jobs.iter().map(|j| j.file.as_str()).collect();
    assert!(
        files[0].ends_with("ox-x-target.ngc") && files[1].ends_with("ox-x-text.ngc"),
        "{files:?}"
    );
    assert!(!library_of.autostart, "offered programs wait for a start");
    let (mut plc, sink) = (built.plc, built.hmi.expect("the screen's commands"));
    let trace = dir.path().join("load.jsonl");
    let digest = built.setup.digest().expect("a digest");
    let recorder =
        pkm_plc::services::trace::record::Recorder::create_with(&trace, &plc, &digest, Some(&library_of), None)
            .expect("the trace");
    plc.set_recorder(Box::new(recorder));
    let mut loaded = Vec::new();
    let mut text_completed = false;
    let press = |k: usize| sink.update(|c| c.presses[k] += 1);
    let seen = transitions(&mut plc, 80_000, |plc, t| {
        let k = get(plc, nc::NC_PROGRAM);
        text_completed |= k == 2 && get(plc, nc::NC_COMPLETED);
        if loaded.last().map(|(_, l)| *l) != Some(k) {
            loaded.push((t, k));
        }
        match t {
            // READY at 11.65 s, nothing started: load the text, start it.
            13_000 => sink.update(|c| c.program = 2),
            14_000 => press(pkm_plc::services::hmi::commands::press::NC[0]),
            // While it runs, the target is chosen: taken once the text has ended.
            20_000 => sink.update(|c| c.program = 1),
            _ => {}
        }
    });
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY", "AUTO", "READY"], "{seen:?}");
    let (auto, ended) = (seen[3].0, seen[4].0);
    // The text's plan: 41.74 s.
    assert!(
        ((ended - auto) as f64 / 1000.0 - 41.74).abs() < 0.2,
        "the text ran: {auto} … {ended} ms"
    );
    assert_eq!(loaded[0], (0, 1), "{loaded:?}");
    assert_eq!(loaded[1].1, 2, "{loaded:?}");
    assert!(loaded[1].0 <= 13_050, "loaded within a main cycle: {loaded:?}");
    assert_eq!(loaded[2].1, 1, "{loaded:?}");
    assert!(
        loaded[2].0 >= ended,
        "not while the text ran: {loaded:?} (ended {ended})"
    );
    assert!(text_completed, "the text completed");
    // The target loaded after the text's run: no run of it to report.
    assert!(!get(&plc, nc::NC_COMPLETED) && get(&plc, nc::NC_RUN_S) == 0.0);
    match plc.take_recorder().map(|r| r.finish()) {
        Some(Ok(_)) => {}
        other => panic!("the trace: {:?}", other.map(|r| r.map_err(|e| e.to_string()))),
    }
    // Replayed with the programs the trace carries.
    let setup = Setup::new(machine_config("ox-x", |_| {})).expect("the O-X glide");
    let report = pkm_plc::compose::replay::replay(&trace, &setup, false).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.records > 1000, "{}", report.records);
}

/// A manual tool change: the program stands at each `T… M6` with the tool asked for, the
/// screen's confirmation goes on, and the run — the requests and confirmations are process-image
/// variables — replays from its trace, which carries the tool table.
#[test]
fn a_manual_tool_change_waits_for_the_screen_and_the_run_replays() {
    use pkm_api::trajectory::vars as nc;
    let dir = tempfile::tempdir().expect("a temporary directory");
    let table = dir.path().join("tool.tbl");
    std::fs::write(&table, "T1 P1 Z10 D6 ;6 mm end mill\nT2 P2 Z20 D3 ;3 mm drill\n").expect("the table");
    let program = dir.path().join("tools.ngc");
    std::fs::write(
        &program,
        "(MSG, clamp the part)\nT1 M6\nG43 H1\nG1 X5 F600\nT2 M6\nG43 H2\nG0 X0\nM2\n",
    )
    .expect("the program");
    let setup = || {
        Setup::new(machine_config("ox-x", |_| {}))
            .expect("the O-X glide")
            .with_tool_table(Some(&table))
            .unwrap_or_else(|e| panic!("{}", e.message))
    };
    let options = Options {
        hmi: true,
        program: Some(program.clone()),
        ..Options::default()
    };
    let built = compose::build(setup(), options).unwrap_or_else(|e| panic!("{e}"));
    let (mut plc, sink) = (built.plc, built.hmi.expect("the screen's commands"));
    let trace = dir.path().join("tools.jsonl");
    let tools = built
        .setup
        .tools
        .as_ref()
        .map(|t| pkm_plc::services::trace::TraceProgram {
            file: t.file.clone(),
            text: t.text.clone(),
        });
    let digest = built.setup.digest().expect("a digest");
    let recorder =
        pkm_plc::services::trace::record::Recorder::create_with(&trace, &plc, &digest, built.library.as_ref(), tools)
            .expect("the trace");
    plc.set_recorder(Box::new(recorder));
    // (state, a change waits, the tool asked, the tool in the spindle), as they change.
    let mut log: Vec<(i16, bool, i32, i32)> = Vec::new();
    let mut changes = Vec::new();
    let mut still_waiting = false;
    transitions(&mut plc, 30_000, |plc, t| {
        let entry = (
            get(plc, nc::NC_STATE),
            get(plc, nc::TOOL_CHANGE),
            get(plc, nc::TOOL_PREP_NUMBER),
            get(plc, nc::TOOL_NUMBER),
        );
        if log.last() != Some(&entry) {
            if entry.1 && !log.last().is_some_and(|l| l.1) {
                changes.push((t, entry.2));
            }
            log.push(entry);
        }
        // The operator confirms each change a few seconds after it was asked for, naming it;
        // a confirmation of the first change repeated while the second waits (a late second
        // click) confirms nothing.
        match t {
            16_000 => sink.update(|c| c.tool_confirm = 1),
            19_000 => sink.update(|c| c.tool_confirm = 1),
            21_900 => still_waiting = get(plc, nc::TOOL_CHANGE) && get(plc, nc::TOOL_CHANGE_NUMBER) == 2,
            22_000 => sink.update(|c| c.tool_confirm = 2),
            _ => {}
        }
    });
    assert!(
        still_waiting,
        "the second change waits for its own confirmation: {log:?}"
    );
    assert_eq!(changes.len(), 2, "{log:?}");
    assert_eq!(changes[0].1, 1, "tool 1 first: {log:?}");
    assert_eq!(changes[1].1, 2, "then tool 2: {log:?}");
    assert!(
        changes[0].0 < 16_000 && changes[1].0 > 16_000 && changes[1].0 < 22_000,
        "{changes:?}"
    );
    assert!(
        log.contains(&(7, true, 1, 0)),
        "standing at the first change, no tool yet: {log:?}"
    );
    assert!(log.contains(&(7, true, 2, 1)), "at the second, tool 1 in: {log:?}");
    assert!(get(&plc, nc::NC_COMPLETED), "{log:?}");
    assert_eq!(get(&plc, nc::TOOL_NUMBER), 2);
    assert_eq!(get(&plc, nc::NC_MESSAGES), 1, "the MSG was reached");
    match plc.take_recorder().map(|r| r.finish()) {
        Some(Ok(_)) => {}
        other => panic!("the trace: {:?}", other.map(|r| r.map_err(|e| e.to_string()))),
    }
    // The replay reads the program with the trace's tool table, not the setup's (here none).
    let bare = Setup::new(machine_config("ox-x", |_| {})).expect("the O-X glide");
    let report = pkm_plc::compose::replay::replay(&trace, &bare, false).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.records > 1000, "{}", report.records);
}

/// The screen's preview of a program marks its rapids, which the page draws dashed: the points
/// of `G0 X10` are rapids, those of the `G1` after it are not.
#[test]
fn the_preview_marks_the_rapids() {
    let setup = Setup::new(machine_config("ox-x", |_| {})).expect("the O-X glide");
    let job =
        pkm_plc::compose::nc_job::prepare_text(&setup, "p.ngc".into(), "G0 X10\nG1 Y10 F600\nG0 X0 Y0\nM2\n".into())
            .and_then(pkm_plc::compose::nc_job::Prepared::into_job)
            .unwrap_or_else(|e| panic!("{}", e.message));
    let points = pkm_plc::services::hmi::server::preview(job.trajectory.as_ref());
    let rapid_out = points
        .iter()
        .filter(|p| p[3] == 1.0 && p[1].abs() < 1e-9 && p[0] > 0.5)
        .count();
    let feed = points
        .iter()
        .filter(|p| p[3] == 0.0 && (p[0] - 10.0).abs() < 1e-9 && p[1] > 0.5)
        .count();
    assert!(rapid_out > 10, "the G0 X10 is drawn as a rapid: {rapid_out} points");
    assert!(feed > 10, "the G1 Y10 as a feed move: {feed} points");
    assert!(points.iter().all(|p| p[3] == 0.0 || p[3] == 1.0));
}

/// What the DRO shows of a running program: the commanded feed, the measured one, the distance
/// to go along the line, and the spindle at the screen's override.
#[test]
fn the_dro_gets_the_feed_the_distance_to_go_and_the_spindle_at_its_override() {
    use pkm_api::trajectory::vars as nc;
    let dir = tempfile::tempdir().expect("a temporary directory");
    let program = dir.path().join("line.ngc");
    std::fs::write(&program, "S1000 M3\nG1 X20 F600\nM5\nG0 X0\nM2\n").expect("the program");
    let options = Options {
        hmi: true,
        program: Some(program),
        ..Options::default()
    };
    let setup = Setup::new(machine_config("ox-x", |_| {})).expect("the O-X glide");
    let built = compose::build(setup, options).unwrap_or_else(|e| panic!("{e}"));
    let (mut plc, sink) = (built.plc, built.hmi.expect("the screen's commands"));
    sink.update(|c| c.spindle_override = 50);
    // (feed, measured feed, distance to go, rpm) while the G1 runs at its feed.
    let mut at_feed: Vec<(f64, f64, f64, f64)> = Vec::new();
    let mut togo = Vec::new();
    transitions(&mut plc, 20_000, |plc, _| {
        let line: i32 = get(plc, nc::NC_LINE);
        let feed: f64 = get(plc, nc::NC_FEED);
        if line == 2 {
            togo.push(get::<f64>(plc, nc::NC_DISTANCE_TO_GO));
            if (feed - 600.0).abs() < 1e-6 {
                at_feed.push((
                    feed,
                    get(plc, nc::NC_FEED_MEASURED),
                    togo[togo.len() - 1],
                    get(plc, nc::SPINDLE_RPM),
                ));
            }
        }
    });
    assert!(
        at_feed.len() > 50,
        "the line ran at its feed: {} samples",
        at_feed.len()
    );
    for (_, measured, _, rpm) in &at_feed[10..] {
        assert!((measured - 600.0).abs() < 15.0, "measured {measured} mm/min");
        assert_eq!(*rpm, 500.0, "S1000 at 50 %");
    }
    assert!(
        togo.first().is_some_and(|d| *d > 19.9) && togo.last().is_some_and(|d| *d < 0.1),
        "{:?} … {:?}",
        togo.first(),
        togo.last()
    );
    assert!(
        togo.windows(2).all(|w| w[1] <= w[0] + 1e-9),
        "the distance to go only falls"
    );
}

/// The screen's Reference in READY references the machine again (REBOOT, INIT, READY: no
/// error); pressed in INIT it changes nothing. The TRIJOINT's program and the joint machines'
/// (the hexapod) take it alike.
#[test]
fn the_screens_reference_references_again_from_ready_only() {
    use pkm_plc::services::hmi::commands::press;
    // (machine, first READY, the press in READY, the press while it references, the end) in ms.
    for (machine, ready_ms, again_ms, in_init_ms, end_ms) in [
        ("trijoint", 42_650, 45_000, 47_000, 100_000),
        ("hexapod", 7_650, 9_000, 10_000, 20_000),
    ] {
        // The TRIJOINT's configuration is the repository's own.
        let loaded = if machine == "trijoint" {
            common::loaded(&common::repo_config())
        } else {
            machine_config(machine, |_| {})
        };
        let (mut plc, sink) = with_screen(loaded, None);
        let seen = transitions(&mut plc, end_ms, |_, t| {
            if t == again_ms || t == in_init_ms {
                sink.update(|c| c.presses[press::REFERENCE] += 1);
            }
        });
        let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
        assert_eq!(
            names,
            ["REBOOT", "INIT", "READY", "REBOOT", "INIT", "READY"],
            "{machine}: {seen:?}"
        );
        assert!(
            seen.iter().all(|(_, _, reason)| reason.is_none()),
            "{machine}: {seen:?}"
        );
        assert!(seen[2].0 <= ready_ms, "{machine}: READY first at {} ms", seen[2].0);
        // Taken within a main cycle (the press lasts 100 ms).
        assert!(seen[3].0 - again_ms <= 50, "{machine}: {seen:?}");
        assert!(get(&plc, vars::REFERENCED), "{machine}: referenced again");
    }
}
