//! Every configuration error path, with the exact message a user sees.

use pkm_plc::image::{Declare, Reader, VarTable, VarType};
use pkm_plc::program::{Cycle, Program, ProgramArgs, ProgramInfo, Registry};
use pkm_plc::runtime::bus::NoBus;
use pkm_plc::runtime::config::{self, ConfigError};
use pkm_plc::runtime::plc::Plc;

/// Parses and builds `json` (named `cfg.json`) with `registry`; returns the error as displayed.
fn error_with(json: &str, registry: &Registry) -> String {
    let loaded = match config::parse(json, "cfg.json") {
        Ok(l) => l,
        Err(e) => return e.to_string(),
    };
    match Plc::build(&loaded.config, registry, Box::new(NoBus)) {
        Ok(_) => panic!("configuration unexpectedly valid: {json}"),
        Err(problems) => ConfigError::Invalid {
            file: loaded.origin,
            problems,
        }
        .to_string(),
    }
}

fn error(json: &str) -> String {
    error_with(json, &pkm_plc::compose::machines::all_programs())
}

/// One task class with the given fields replacing the defaults.
fn class(overrides: &str) -> String {
    let mut fields = serde_json::json!({
        "name": "fast", "cycle_us": 10000, "tolerance_us": 10000, "priority": 1,
        "programs": [{"program": "selftest.idle"}]
    });
    let extra: serde_json::Value = serde_json::from_str(overrides).expect("test override is JSON");
    for (k, v) in extra.as_object().expect("object").iter() {
        fields[k] = v.clone();
    }
    fields.to_string()
}

#[test]
fn the_default_configuration_is_valid() {
    // Built-in and file configuration, each with its I/O map and the simulated machine, as
    // `pkm-plc check` and `pkm-plc run` build them.
    let file = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config.json"));
    for loaded in [config::load(None), config::load(Some(file))] {
        let setup = pkm_plc::compose::Setup::new(loaded.expect("parses")).expect("known machine");
        let bus = setup.sim_bus(None).expect("I/O map and plant");
        if let Err(e) = setup.plc(Box::new(bus)) {
            panic!("{e}");
        }
    }
}

#[test]
fn unreadable_file() {
    let e = config::load(Some(std::path::Path::new("/nonexistent/cfg.json"))).unwrap_err();
    assert_eq!(
        e.to_string(),
        "/nonexistent/cfg.json: cannot read the file: No such file or directory (os error 2)"
    );
}

#[test]
fn syntax_errors_give_line_and_column() {
    assert_eq!(
        error("{\"task_classes\": [ }"),
        "cfg.json: line 1, column 20: expected value"
    );
    assert_eq!(
        error("{\"task_classes\": []} x"),
        "cfg.json: line 1, column 22: trailing characters"
    );
    assert_eq!(
        error("{\n  \"task_classes\": [],\n"),
        "cfg.json: line 3, column 0: EOF while parsing a value"
    );
}

#[test]
fn unknown_fields_are_refused_with_the_expected_ones() {
    assert_eq!(
        error(r#"{"tasks": []}"#),
        "cfg.json: at tasks: unknown field `tasks`, expected one of `machine`, `task_classes`, `timing`, `io_map`, `plant`, `kinematics`, `joystick`, `nc`, `identification`"
    );
    assert_eq!(
        error(&format!(r#"{{"task_classes": [{}]}}"#, class(r#"{"cycle_ms": 10}"#))),
        "cfg.json: at task_classes[0].cycle_ms: unknown field `cycle_ms`, expected one of `name`, `cycle_us`, \
         `tolerance_us`, `priority`, `on_violation`, `programs`"
    );
    assert_eq!(
        error(r#"{"task_classes": [], "timing": {"spin": 3}}"#),
        "cfg.json: at timing.spin: unknown field `spin`, expected one of `source`, `realtime_priority`, \
         `lock_memory`, `spin_us`"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"programs": [{"program": "selftest.idle", "args": 1}]}"#)
        )),
        "cfg.json: at task_classes[0].programs[0].args: unknown field `args`, expected `program` or `params`"
    );
}

#[test]
fn wrong_types_and_missing_fields() {
    assert_eq!(
        error(&format!(r#"{{"task_classes": [{}]}}"#, class(r#"{"cycle_us": "10"}"#))),
        "cfg.json: at task_classes[0].cycle_us: invalid type: string \"10\", expected u32"
    );
    assert_eq!(
        error(r#"{"task_classes": [{"name": "f", "cycle_us": 10000, "tolerance_us": 1, "programs": []}]}"#),
        "cfg.json: at task_classes[0]: missing field `priority`"
    );
    assert_eq!(error(r#"{}"#), "cfg.json: at (top level): missing field `task_classes`");
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"on_violation": "stop"}"#)
        )),
        "cfg.json: at task_classes[0].on_violation: unknown variant `stop`, expected `log` or `error`"
    );
    assert_eq!(
        error(r#"{"task_classes": [], "timing": {"source": "hpet"}}"#),
        "cfg.json: at timing.source: unknown variant `hpet`, expected one of `auto`, `tokio`, `timerfd`, `nanosleep`"
    );
    // Regression: these were JSON syntax errors without a path.
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"on_violation": 42}"#)
        )),
        "cfg.json: at task_classes[0].on_violation: invalid type: integer `42`, expected enum Reaction"
    );
    assert_eq!(
        error(r#"{"task_classes": [], "timing": [1, 2]}"#),
        "cfg.json: at timing: invalid type: sequence, expected struct TimingConfig"
    );
    // A value of megabytes is cut in the message, which says how long it was.
    let long = error(&format!(
        r#"{{"task_classes": [], "timing": {{"source": "{}"}}}}"#,
        "y".repeat(1 << 20)
    ));
    assert!(long.len() < 400, "{} bytes", long.len());
    assert!(
        long.starts_with("cfg.json: at timing.source: unknown variant `yyyy") && long.contains("(1048"),
        "{long}"
    );
    assert_eq!(
        error(r#"{"task_classes": [], "timing": {"realtime_priority": 300}}"#),
        "cfg.json: at timing.realtime_priority: invalid value: integer `300`, expected u8"
    );
}

#[test]
fn task_class_checks() {
    assert_eq!(
        error(r#"{"task_classes": []}"#),
        "cfg.json: at task_classes: at least one task class is required"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"name": "fast class"}"#)
        )),
        "cfg.json: at task_classes[0].name: task class name \"fast class\" is not valid: use letters, digits, '_' and '-'"
    );
    assert_eq!(
        error(&format!(r#"{{"task_classes": [{}]}}"#, class(r#"{"cycle_us": 100}"#))),
        "cfg.json: at task_classes[0].cycle_us: cycle time must be between 200 and 10000000 µs, got 100"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"tolerance_us": 20000000}"#)
        )),
        "cfg.json: at task_classes[0].tolerance_us: tolerance must be at most the cycle time (10000 µs): a cycle that starts later than that has missed its slot, got 20000000"
    );
    assert_eq!(
        error(&format!(r#"{{"task_classes": [{}]}}"#, class(r#"{"priority": 0}"#))),
        "cfg.json: at task_classes[0].priority: priority must be 1 (highest) or more, got 0"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}, {}]}}"#,
            class("{}"),
            class(r#"{"priority": 2, "programs": []}"#)
        )),
        "cfg.json: at task_classes[1].name: task class name \"fast\" is already used by task_classes[0]"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}, {}]}}"#,
            class("{}"),
            class(r#"{"name": "main", "cycle_us": 50000, "programs": []}"#)
        )),
        "cfg.json: at task_classes[1].priority: priority 1 is already used by task class \"fast\" (task_classes[0]); \
         priorities are unique"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}, {}]}}"#,
            class(r#"{"priority": 2}"#),
            class(r#"{"name": "main", "cycle_us": 50000, "priority": 1, "programs": []}"#)
        )),
        "cfg.json: at task_classes[1].priority: task class \"fast\" (10000 µs, priority 2) is faster than \"main\" \
         (50000 µs, priority 1) but has the lower priority; a faster class must have the higher priority \
         (a smaller number)"
    );
}

#[test]
fn the_nameplate_is_strict_and_checked() {
    assert_eq!(
        error(r#"{"task_classes": [], "identification": {"serial": "1"}}"#),
        "cfg.json: at identification.serial: unknown field `serial`, expected one of `manufacturer`, `model`, \
         `serial_number`, `product_instance_uri`, `year_of_construction`"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}], "identification": {{"product_instance_uri": "my machine", "year_of_construction": 204}}}}"#,
            class("{}")
        )),
        "cfg.json: 2 problems:\n  at identification.product_instance_uri: a URI (scheme:rest, without spaces, \
         e.g. urn:example-lab:trijoint:0001), got \"my machine\"\n  at identification.year_of_construction: a year \
         1900…2200, got 204"
    );
}

#[test]
fn joystick_section_is_strict_and_checked() {
    assert_eq!(
        error(r#"{"task_classes": [], "joystick": {"deadzone": 0.1}}"#),
        "cfg.json: at joystick.deadzone: unknown field `deadzone`, expected one of `x_axis`, `y_axis`, \
         `invert_x`, `invert_y`, `dead_zone`, `axis_range`, `stop_button`, `deadman_button`, `buttons`"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}], "joystick": {{"dead_zone": 0.95, "x_axis": 1}}}}"#,
            class("{}")
        )),
        "cfg.json: 2 problems:\n  at joystick.dead_zone: must be at least 0 and below 0.9, got 0.95\n  \
         at joystick.y_axis: must differ from x_axis (1)"
    );
}

#[test]
fn timing_checks() {
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}], "timing": {{"realtime_priority": 120}}}}"#,
            class("{}")
        )),
        "cfg.json: at timing.realtime_priority: real-time priority must be 1..=99 (or 0: do not ask), got 120"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}], "timing": {{"spin_us": 5000}}}}"#,
            class("{}")
        )),
        "cfg.json: at timing.spin_us: spin margin must be at most 1000 µs, got 5000"
    );
}

#[test]
fn program_checks() {
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"programs": [{"program": "encoder"}]}"#)
        )),
        "cfg.json: at task_classes[0].programs[0].program: unknown program \"encoder\"; known programs: \
         selftest.producer, selftest.consumer, selftest.idle, trijoint.encoders, trijoint.main, trijoint.control, pn101.drives, pn101.main, \
         ox-x.drives, ox-x.main, ox-o.drives, ox-o.main, hexapod.drives, hexapod.main"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}, {}]}}"#,
            class("{}"),
            class(r#"{"name": "main", "cycle_us": 50000, "priority": 2}"#)
        )),
        "cfg.json: at task_classes[1].programs[0].program: program \"selftest.idle\" is already configured at \
         task_classes[0].programs[0]; each program runs once"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"programs": [{"program": "selftest.idle", "params": {"burn": 5}}]}"#)
        )),
        "cfg.json: at task_classes[0].programs[0].params.burn: unknown field `burn`, expected one of `burn_us`, \
         `burn_every`, `burn_from_cycle`, `burn_until_cycle`"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"programs": [{"program": "selftest.idle", "params": {"burn_us": -1}}]}"#)
        )),
        "cfg.json: at task_classes[0].programs[0].params.burn_us: invalid value: integer `-1`, expected u32"
    );
    assert_eq!(
        error(&format!(
            r#"{{"task_classes": [{}]}}"#,
            class(r#"{"programs": [{"program": "selftest.consumer"}]}"#)
        )),
        "cfg.json: 6 problems:\n  \
         at task_classes[0].programs[0]: variable \"selftest_seq\" read by \"selftest.consumer\" has no writer: no program writes it and no bus input is bound to it\n  \
         at task_classes[0].programs[0]: variable \"selftest_copy1\" read by \"selftest.consumer\" has no writer: no program writes it and no bus input is bound to it\n  \
         at task_classes[0].programs[0]: variable \"selftest_copy2\" read by \"selftest.consumer\" has no writer: no program writes it and no bus input is bound to it\n  \
         at task_classes[0].programs[0]: variable \"selftest_copy3\" read by \"selftest.consumer\" has no writer: no program writes it and no bus input is bound to it\n  \
         at task_classes[0].programs[0]: variable \"selftest_copy4\" read by \"selftest.consumer\" has no writer: no program writes it and no bus input is bound to it\n  \
         at task_classes[0].programs[0]: variable \"selftest_walk\" read by \"selftest.consumer\" has no writer: no program writes it and no bus input is bound to it"
    );
}

/// A test program whose variables come from its params: `{"writes": [..], "reads": [[name, type]..]}`.
struct Declared;
impl Program for Declared {
    fn cycle(&mut self, _ctx: &mut Cycle<'_>) {}
}

#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct DeclaredParams {
    #[serde(default)]
    writes: Vec<String>,
    #[serde(default)]
    reads_real: Vec<String>,
}

fn declared(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
    let p: DeclaredParams = args.parse(decl);
    for w in &p.writes {
        decl.output::<i32>(w, 0);
    }
    for r in &p.reads_real {
        decl.input::<f64>(r);
    }
    Box::new(Declared)
}

fn test_registry() -> Registry {
    let mut r = Registry::new();
    for name in ["a", "b"] {
        r.register(ProgramInfo {
            name,
            summary: "test",
            factory: declared,
        });
    }
    r
}

#[test]
fn variable_conflicts_between_programs() {
    let two = |a: &str, b: &str| {
        format!(
            r#"{{"task_classes": [
                {{"name": "fast", "cycle_us": 10000, "tolerance_us": 10000, "priority": 1, "programs": [{{"program": "a", "params": {a}}}]}},
                {{"name": "main", "cycle_us": 50000, "tolerance_us": 50000, "priority": 2, "programs": [{{"program": "b", "params": {b}}}]}}
            ]}}"#
        )
    };
    assert_eq!(
        error_with(&two(r#"{"writes": ["x"]}"#, r#"{"writes": ["x"]}"#), &test_registry()),
        "cfg.json: at task_classes[1].programs[0]: variable \"x\" has two writers: program \"a\" \
         (task_classes[0].programs[0]) and program \"b\" (task_classes[1].programs[0]); a variable has exactly one writer"
    );
    assert_eq!(
        error_with(
            &two(r#"{"writes": ["x"]}"#, r#"{"reads_real": ["x"]}"#),
            &test_registry()
        ),
        "cfg.json: at task_classes[1].programs[0]: variable \"x\" is used as REAL here but as DINT by program \"a\" \
         (task_classes[0].programs[0])"
    );
    assert_eq!(
        error_with(&two(r#"{"writes": ["bad name"]}"#, r#"{}"#), &test_registry()),
        "cfg.json: at task_classes[0].programs[0]: variable name \"bad name\" is not valid: use letters, digits, '_' and '.'"
    );
}

#[test]
fn every_problem_is_reported_at_once() {
    let json = format!(
        r#"{{"task_classes": [{}, {}], "timing": {{"spin_us": 2000}}}}"#,
        class(r#"{"cycle_us": 0, "programs": [{"program": "nope"}]}"#),
        class(r#"{"priority": 1}"#)
    );
    let e = error(&json);
    assert!(e.starts_with("cfg.json: 5 problems:\n"), "{e}");
    for part in [
        "at task_classes[0].cycle_us: cycle time must be between 200 and 10000000 µs, got 0",
        "at task_classes[1].name: task class name \"fast\" is already used by task_classes[0]",
        "at task_classes[1].priority: priority 1 is already used",
        "at timing.spin_us: spin margin must be at most 1000 µs, got 2000",
        "at task_classes[0].programs[0].program: unknown program \"nope\"",
    ] {
        assert!(e.contains(part), "missing {part:?} in:\n{e}");
    }
}

#[test]
fn bus_declarations_take_part_in_the_checks() {
    // A variable read by the bus (an output to the field) that no program writes.
    let mut t = VarTable::new();
    t.declare_reader(
        "PWM01",
        VarType::Int,
        Reader {
            class: 0,
            who: "bus".into(),
            at: "io_map.bindings[0]".into(),
            needs_writer: true,
        },
    );
    let issues = t.finish().unwrap_err();
    assert_eq!(
        issues[0].message,
        "variable \"PWM01\" read by \"bus\" has no writer: no program writes it and no bus input is bound to it"
    );
}

use crate::common;

/// The repository's configuration changed by `change`, built on the simulated machine with the
/// I/O map changed by `change_map`; the problems as displayed (empty when it is valid).
fn problems_of(change: impl Fn(&mut serde_json::Value), change_map: impl Fn(&mut serde_json::Value)) -> String {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut map = common::read_json(&common::root().join("io-map/trijoint.json"));
    change_map(&mut map);
    let map_path = dir.path().join("map.json");
    std::fs::write(&map_path, map.to_string()).expect("write the map");
    let mut config = common::repo_config();
    config["io_map"] = map_path.to_str().expect("utf-8").into();
    change(&mut config);
    let loaded = match config::parse(&config.to_string(), "cfg.json") {
        Ok(mut l) => {
            l.dir = Some(common::root().to_path_buf());
            l
        }
        Err(e) => return e.to_string(),
    };
    let problems = match pkm_plc::compose::Setup::new(loaded.clone()) {
        Ok(setup) => setup.section_problems(),
        Err(e) => return e.to_string(),
    };
    if !problems.is_empty() {
        return ConfigError::Invalid {
            file: loaded.origin,
            problems,
        }
        .to_string();
    }
    match common::sim_plc(&loaded, &pkm_plc::compose::machines::all_programs(), None) {
        Ok(_) => String::new(),
        Err(e) => e.to_string(),
    }
}

fn main_params(v: serde_json::Value) -> impl Fn(&mut serde_json::Value) {
    move |c| c["task_classes"][1]["programs"][0]["params"] = v.clone()
}

fn no_change(_: &mut serde_json::Value) {}

/// Regression: each of these was accepted by `check`.
#[test]
fn safety_relevant_settings_are_refused_naming_the_key() {
    let cases: Vec<(String, &str)> = vec![
        // The fast interlock and the encoders moved into the 100 ms class.
        (
            problems_of(
                |c| {
                    let control = c["task_classes"][0]["programs"][1].take();
                    c["task_classes"][0]["programs"] = serde_json::json!([c["task_classes"][0]["programs"][0].take()]);
                    c["task_classes"][2]["programs"] = serde_json::json!([control]);
                },
                no_change,
            ),
            "at task_classes[2].programs[0].program: trijoint.control is the fast interlock (STOP and switches to PWM zero): it must run in the fastest task class, of at most 20 ms; it runs in one of 100 ms that is not the fastest",
        ),
        (
            problems_of(
                |c| {
                    let encoders = c["task_classes"][0]["programs"][0].take();
                    c["task_classes"][0]["programs"] = serde_json::json!([c["task_classes"][0]["programs"][1].take()]);
                    c["task_classes"][2]["programs"] = serde_json::json!([encoders]);
                },
                no_change,
            ),
            "at task_classes[2].programs[0].program: trijoint.encoders is the encoder unwrap and touch probe: it must run in the fastest task class",
        ),
        // BUTTON_STOP and a PWM output exchanged by the 100 ms class.
        (
            problems_of(no_change, |m| m["bindings"][0]["task_class"] = "spare".into()),
            "input \"BUTTON_STOP\" is latched by class \"spare\" (100 ms) but read by \"trijoint.control\" in class \"fast\" (10 ms), which would see it up to 100 ms late: bind it to \"fast\"",
        ),
        (
            problems_of(no_change, |m| m["bindings"][18]["task_class"] = "spare".into()),
            "output \"velocity_right_set\" is written by \"trijoint.control\" in class \"fast\" (10 ms) but exchanged by class \"spare\" (100 ms), so the module would see it up to 100 ms late: bind it to \"fast\"",
        ),
        (
            problems_of(
                |c| c["task_classes"][0]["programs"][1]["params"] = serde_json::json!({"max_following_error_mm": 0}),
                no_change,
            ),
            "at task_classes[0].programs[1].params.max_following_error_mm: must be between 0.01 and 50 mm (beyond it a blocked or dead drive goes unnoticed; 0 would stop at every step), got 0",
        ),
        (
            problems_of(
                |c| c["task_classes"][0]["programs"][1]["params"] = serde_json::json!({"max_following_error_mm": 1e12}),
                no_change,
            ),
            "params.max_following_error_mm: must be between 0.01 and 50 mm (beyond it a blocked or dead drive goes unnoticed; 0 would stop at every step), got 1000000000000",
        ),
        (
            problems_of(main_params(serde_json::json!({"singularity_threshold": -1})), no_change),
            "at task_classes[1].programs[0].params.singularity_threshold: must be between 0.01 and 0.99 (a ratio of singular values; 0 would let the tool reach a singularity), got -1",
        ),
        (
            problems_of(main_params(serde_json::json!({"singularity_threshold": 2})), no_change),
            "params.singularity_threshold: must be between 0.01 and 0.99 (a ratio of singular values; 0 would let the tool reach a singularity), got 2",
        ),
        (
            problems_of(main_params(serde_json::json!({"soft_limit_margin_mm": -5})), no_change),
            "params.soft_limit_margin_mm: must be between 0.1 and 62.5 mm (0 puts the software limits on the hard ends of the travel; at most a quarter of the shortest travel), got -5",
        ),
        (
            problems_of(
                main_params(serde_json::json!({"soft_limit_margin_mm": 1000})),
                no_change,
            ),
            "params.soft_limit_margin_mm: must be between 0.1 and 62.5 mm (0 puts the software limits on the hard ends of the travel; at most a quarter of the shortest travel), got 1000",
        ),
        (
            problems_of(main_params(serde_json::json!({"stop_lockout_ms": 0})), no_change),
            "params.stop_lockout_ms: must be between 100 and 10000 ms (a shorter lockout lets a bouncing STOP contact acknowledge the error it caused; a longer one leaves STOP dead for too long), got 0",
        ),
        (
            problems_of(main_params(serde_json::json!({"dead_zone": 1.5})), no_change),
            "params.dead_zone: must be between 0 and 0.9 (a fraction of full deflection), got 1.5",
        ),
        (
            problems_of(main_params(serde_json::json!({"pwm_period_us": 0})), no_change),
            "params.pwm_period_us: must be between 10 and 10000 µs (0 switches the motor bridges off), got 0",
        ),
        (
            problems_of(|c| c["task_classes"][0]["tolerance_us"] = 10_000_000.into(), no_change),
            "at task_classes[0].tolerance_us: tolerance must be at most the cycle time (10000 µs): a cycle that starts later than that has missed its slot, got 10000000",
        ),
        (
            problems_of(|c| c["task_classes"][0]["tolerance_us"] = 0.into(), no_change),
            "at task_classes[0].tolerance_us: tolerance must be at least a tenth of the cycle time (1000 µs): below it every wake-up of a busy operating system is a cycle time violation, got 0",
        ),
        (
            problems_of(main_params(serde_json::json!({"init_speed_mm_s": 1e6})), no_change),
            "params.init_speed_mm_s: must be between 0.01 and 1000 mm/s, got 1000000",
        ),
        (
            problems_of(main_params(serde_json::json!({"creep_speed_mm_s": 2.0})), no_change),
            "params.creep_speed_mm_s: must be between 0.001 and 1 mm/s, got 2",
        ),
        (
            problems_of(|c| c["kinematics"]["trijoint"]["l2"] = 1e308.into(), no_change),
            "at kinematics.trijoint.l2: must be a positive length in mm, at most 10000, got 1e308",
        ),
        // A struct given as a positional array, and a duplicate key.
        (
            problems_of(|c| c["kinematics"]["trijoint"] = serde_json::json!([1, 2]), no_change),
            "cfg.json: at kinematics.trijoint: invalid type: sequence, expected struct TrijointParams",
        ),
    ];
    for (shown, wanted) in &cases {
        assert!(shown.contains(wanted), "wanted {wanted:?} in:\n{shown}");
    }
    let e = config::parse(
        r#"{"io_map": "a.json", "io_map": "b.json", "task_classes": []}"#,
        "cfg.json",
    )
    .unwrap_err();
    assert_eq!(e.to_string(), "cfg.json: at (top level): duplicate key \"io_map\"");
}

#[test]
fn a_joint_machine_configuration_is_checked_as_a_whole_with_paths() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut c = common::read_json(&common::root().join("machines/pn101.json"));
    c["io_map"] = common::root().join("io-map/pn101.json").to_str().expect("utf-8").into();
    let main = &mut c["task_classes"][1]["programs"][0]["params"];
    main["reference_order"] = serde_json::json!([[1, 2], [3]]);
    main["jog"]["axis_pairs"] = serde_json::json!([["x", "q"]]);
    main["world_limits"] = serde_json::json!([[0, 1]]);
    c["task_classes"][0]["programs"][0]["params"]["steppers"][0]["max_speed_mm_s"] = 100.into();
    c["plant"]["joints"][1]["motor"] = serde_json::json!({"dc": {"v_max_mm_s": 1, "tau_s": 1, "counts_per_mm": 1}});
    c["plant"]["wiring"]["joint9_speed"] = "SM1.Enable01".into();
    let path = dir.path().join("pn101.json");
    std::fs::write(&path, c.to_string()).expect("write");
    let o = common::pkm(&["check", "--config", path.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2));
    let p = path.display();
    assert_eq!(
        common::stderr(&o),
        format!(
            "error: {p}: 6 problems:
  at task_classes[0].programs[0].params.steppers[0].max_speed_mm_s: 100 mm/s at 400 steps/mm is more than the module's 32767 steps/s
  at task_classes[1].programs[0].params.reference_order[0]: pn101's joints share one reference input: only one joint at a time can say it reached its switch, so each group holds one joint; got [1, 2]
  at task_classes[1].programs[0].params.world_limits: one [min, max] per pose coordinate (x, y, z); got 1
  at task_classes[1].programs[0].params.jog.axis_pairs[0]: \"q\" is not a world axis of pn101; its axes are x, y, z
  at plant.joints[1].motor: this machine's drives are \"stepper\" motors (its I/O map and drive program say so)
  at plant.wiring.joint9_speed: the machine has no signal \"joint9_speed\"; its signals are stop_button, button_left, button_right, button_up, button_down, button_axes, button_override, limit_neg, limit_pos, reference, program_start, program_hold, program_resume, tool_changed, joint1_enable, joint1_speed, joint1_counter, joint2_enable, joint2_speed, joint2_counter, joint3_enable, joint3_speed, joint3_counter, joystick_x, joystick_y, joystick_connected
"
        )
    );
    // A misspelt key inside a machine's params is refused with its path, over the defaults.
    let mut c = common::read_json(&common::root().join("machines/ox-x.json"));
    c["io_map"] = common::root().join("io-map/ox-x.json").to_str().expect("utf-8").into();
    c["task_classes"][1]["programs"][0]["params"] = serde_json::json!({"jog": {"dead_zon": 0.1}});
    std::fs::write(&path, c.to_string()).expect("write");
    let o = common::pkm(&["check", "--config", path.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        common::stderr(&o)
            .contains("at task_classes[1].programs[0].params.jog.dead_zon: unknown field `dead_zon`, expected one of"),
        "{}",
        common::stderr(&o)
    );
}

/// The station an I/O map names: its kind, the hardware IDs of its modules and an X20BC0087's
/// slots and watchdog are checked when the map is read, each problem at its key.
#[test]
fn an_io_maps_station_is_checked_where_it_is_written() {
    let cases: Vec<(String, &str)> = vec![
        (
            problems_of(no_change, |m| m["station"] = "X20BC0088".into()),
            "map.json: at station: unknown variant `X20BC0088`, expected `generic` or `X20BC0087`",
        ),
        (
            problems_of(no_change, |m| m["modules"][0]["id"] = "0xBEEF".into()),
            "at modules[0].id: the X20DI9371's hardware ID is 0x1B95 (its data sheet's B&R ID code), not 0xBEEF",
        ),
        (
            problems_of(no_change, |m| m["modules"][2]["id"] = "16#1B".into()),
            "at modules[2].id: \"16#1B\" is not a hardware ID: a number 0–65535, or hexadecimal as \"0x1B95\"",
        ),
        (
            problems_of(no_change, |m| m["modules"][4]["slot"] = 7.into()),
            "at modules[4].slot: slot 7 on an X20BC0087 station, where slot 5 is next: the bus controller numbers its modules by their place on the backplane, 1, 2, 3 … without a gap",
        ),
        (
            problems_of(no_change, |m| m["watchdog_ms"] = 10.into()),
            "at watchdog_ms: 10 ms is outside 20–5000 ms: shorter trips on an ordinary late exchange, longer leaves the drives running that long after the soft-PLC stopped",
        ),
        (
            problems_of(no_change, |m| {
                m["station"] = "generic".into();
                m["watchdog_ms"] = 200.into();
            }),
            "at watchdog_ms: the generic station has no watchdog to set (io-sim's is --watchdog-ms); watchdog_ms is an X20BC0087's",
        ),
    ];
    for (problems, expected) in cases {
        assert!(problems.contains(expected), "expected «{expected}» in:\n{problems}");
    }
    // A pinned ID that agrees, in either spelling, and the generic station: accepted.
    assert_eq!(problems_of(no_change, |m| m["modules"][2]["id"] = 0x2345.into()), "");
    assert_eq!(problems_of(no_change, |m| m["modules"][0]["id"] = "0x1b95".into()), "");
    assert_eq!(problems_of(no_change, |m| m["station"] = "generic".into()), "");
}
