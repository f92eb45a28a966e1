//! The I/O map, the module catalogue and the simulated TRIJOINT lab model: every validation error
//! with its message, and the plant's behaviour seen through the process image.

use crate::common;

use std::path::Path;

use common::{plant, run, var};
use pkm_kinematics::trijoint::TrijointParams;
use pkm_plc::image::{Declare, Input, Output, Value};
use pkm_plc::program::{Cycle, Program, ProgramArgs, ProgramInfo, Registry};
use pkm_plc::runtime::config::{ConfigError, LoadedConfig};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::services::io::map::IoMap;
use pkm_trijoint::vars;

const CLASSES: [&str; 3] = ["fast", "main", "spare"];

fn map_error(json: &str) -> String {
    let classes: Vec<String> = CLASSES.iter().map(|s| s.to_string()).collect();
    match IoMap::parse(json, "map.json", &classes) {
        Ok(_) => panic!("map unexpectedly valid"),
        Err(e) => e.to_string(),
    }
}

const MODULES: &str =
    r#""modules": [{"name": "DI", "type": "X20DI9371", "slot": 1}, {"name": "MM", "type": "X20MM2436", "slot": 2}]"#;

#[test]
fn the_default_io_map_validates() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/io-map/trijoint.json")).expect("map");
    let classes: Vec<String> = CLASSES.iter().map(|s| s.to_string()).collect();
    let map = IoMap::parse(&text, "io-map/trijoint.json", &classes).expect("valid");
    assert_eq!(map.modules.len(), 6);
    for name in [
        "BUTTON_STOP",
        "SWITCH_LEFT_UPPER",
        "SWITCH_RIGHT_DOWN",
        "velocity_left_set",
        "period_duration",
    ] {
        assert!(map.bindings.iter().any(|b| b.variable == name), "{name} is bound");
    }
}

#[test]
fn module_errors() {
    assert_eq!(
        map_error(r#"{"modules": [{"name": "A", "type": "X20AI4622", "slot": 1}], "bindings": []}"#),
        "map.json: at modules[0].type: unknown module type \"X20AI4622\"; known types: X20DI9371, X20DO9322, \
         X20DC1196, X20MM2436, X20SM2436, Joystick"
    );
    assert_eq!(
        map_error(
            r#"{"modules": [{"name": "A", "type": "X20DI9371", "slot": 1}, {"name": "B", "type": "X20DO9322", "slot": 1}], "bindings": []}"#
        ),
        "map.json: at modules[1].slot: slot 1 is already taken by module \"A\" (modules[0])"
    );
    assert_eq!(
        map_error(
            r#"{"modules": [{"name": "A", "type": "X20DI9371", "slot": 1}, {"name": "A", "type": "X20DO9322", "slot": 2}], "bindings": []}"#
        ),
        "map.json: at modules[1].name: module name \"A\" is already used by modules[0]"
    );
    assert_eq!(
        map_error(r#"{"modules": [{"name": "A", "kind": "X20DI9371", "slot": 1}], "bindings": []}"#),
        "map.json: at modules[0].kind: unknown field `kind`, expected one of `name`, `type`, `slot`, `id`"
    );
}

fn binding_error(bindings: &str) -> String {
    map_error(&format!("{{{MODULES}, \"bindings\": [{bindings}]}}"))
}

#[test]
fn binding_errors() {
    assert_eq!(
        binding_error(r#"{"module": "DX", "channel": "DigitalInput01", "variable": "A", "task_class": "fast"}"#),
        "map.json: at bindings[0].module: unknown module \"DX\"; modules in this map: DI, MM"
    );
    assert_eq!(
        binding_error(r#"{"module": "DI", "channel": "DigitalInput13", "variable": "A", "task_class": "fast"}"#),
        "map.json: at bindings[0].channel: module \"DI\" (X20DI9371) has no channel \"DigitalInput13\"; its channels: \
         DigitalInput01, DigitalInput02, DigitalInput03, DigitalInput04, DigitalInput05, DigitalInput06, DigitalInput07, \
         DigitalInput08, DigitalInput09, DigitalInput10, DigitalInput11, DigitalInput12"
    );
    assert_eq!(
        binding_error(r#"{"module": "DI", "channel": "DigitalInput01", "variable": "A", "task_class": "slow"}"#),
        "map.json: at bindings[0].task_class: no task class \"slow\" in the configuration; task classes: fast, main, spare"
    );
    assert_eq!(
        binding_error(
            r#"{"module": "DI", "channel": "DigitalInput01", "variable": "A", "task_class": "fast"},
               {"module": "DI", "channel": "DigitalInput01", "variable": "B", "task_class": "fast"}"#
        ),
        "map.json: at bindings[1].channel: channel DI.DigitalInput01 is already bound by bindings[0]"
    );
    assert_eq!(
        binding_error(
            r#"{"module": "MM", "channel": "PulseWidthCurrentPWM01", "variable": "v", "task_class": "fast"},
               {"module": "MM", "channel": "PulseWidthCurrentPWM02", "variable": "v", "task_class": "fast"}"#
        ),
        "map.json: at bindings[1].variable: variable \"v\" is bound to 2 outputs: bindings[0] \
         (MM.PulseWidthCurrentPWM01), bindings[1] (MM.PulseWidthCurrentPWM02); a variable is bound to one channel"
    );
    assert_eq!(
        binding_error(
            r#"{"module": "DI", "channel": "DigitalInput01", "variable": "s", "task_class": "fast"},
               {"module": "MM", "channel": "ClearError01", "variable": "s", "task_class": "fast"}"#
        ),
        "map.json: at bindings[1].variable: variable \"s\" is bound to 2 channels (inputs and outputs): \
         bindings[0] (DI.DigitalInput01), bindings[1] (MM.ClearError01); a variable is bound to one channel"
    );
}

#[test]
fn thousands_of_bindings_of_one_variable_are_one_problem() {
    // 4000 channels on 334 input modules, all bound to "A": one line, not 4000²/2.
    let modules: Vec<String> = (0..334)
        .map(|i| format!(r#"{{"name": "DI{i}", "type": "X20DI9371", "slot": {}}}"#, i + 1))
        .collect();
    let bindings: Vec<String> = (0..4000)
        .map(|k| {
            format!(
                r#"{{"module": "DI{}", "channel": "DigitalInput{:02}", "variable": "A", "task_class": "fast"}}"#,
                k / 12,
                k % 12 + 1
            )
        })
        .collect();
    let map = format!(
        r#"{{"modules": [{}], "bindings": [{}]}}"#,
        modules.join(","),
        bindings.join(",")
    );
    assert_eq!(
        map_error(&map),
        "map.json: at bindings[1].variable: variable \"A\" is bound to 4000 inputs: bindings[0] (DI0.DigitalInput01), \
         bindings[1] (DI0.DigitalInput02), bindings[2] (DI0.DigitalInput03), bindings[3] (DI0.DigitalInput04), \
         bindings[4] (DI0.DigitalInput05), bindings[5] (DI0.DigitalInput06), bindings[6] (DI0.DigitalInput07), \
         bindings[7] (DI0.DigitalInput08), and 3992 more; a variable is bound to one channel"
    );
}

/// A program for tests: drives the motors with constant outputs and reads whatever it is told to,
/// so that direction and type conflicts with the I/O map can be provoked.
struct Drive {
    left: Output<i16>,
    right: Output<i16>,
    params: DriveParams,
}

#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct DriveParams {
    #[serde(default)]
    left: i16,
    #[serde(default)]
    right: i16,
    #[serde(default)]
    until_ms: Option<u64>,
    #[serde(default)]
    write_bool: Option<String>,
    #[serde(default)]
    read_dint: Option<String>,
}

impl Program for Drive {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let on = self.params.until_ms.is_none_or(|u| ctx.time_ns() < u * 1_000_000);
        ctx.set(self.left, if on { self.params.left } else { 0 });
        ctx.set(self.right, if on { self.params.right } else { 0 });
    }
}

fn registry() -> Registry {
    let mut r = pkm_plc::compose::machines::all_programs();
    r.register(ProgramInfo {
        name: "test.drive",
        summary: "test",
        factory: |args: &ProgramArgs<'_>, decl: &mut Declare<'_>| {
            let params: DriveParams = args.parse(decl);
            if let Some(name) = &params.write_bool {
                decl.output::<bool>(name, false);
            }
            if let Some(name) = &params.read_dint {
                let _: Input<i32> = decl.input(name);
            }
            Box::new(Drive {
                left: decl.output("velocity_left_set", 0),
                right: decl.output("velocity_right_set", 0),
                params,
            })
        },
    });
    // The bridges' PWM period, written by the class that exchanges it (the main class): an
    // output written by a faster class than its exchange is refused.
    r.register(ProgramInfo {
        name: "test.period",
        summary: "test",
        factory: |_: &ProgramArgs<'_>, decl: &mut Declare<'_>| Box::new(Period(decl.output("period_duration", 0))),
    });
    r
}

struct Period(Output<u16>);

impl Program for Period {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        ctx.set(self.0, 50);
    }
}

/// The repository's config.json with the fast class running `test.drive` with `params`, and
/// `plant` merged into the plant section.
fn loaded_config(params: &str, plant: &str) -> LoadedConfig {
    let mut c = common::repo_config();
    c["task_classes"][0]["programs"] = serde_json::json!([{"program": "test.drive", "params": serde_json::from_str::<serde_json::Value>(params).expect("params")}]);
    c["task_classes"][1]["programs"] = serde_json::json!([{"program": "test.period"}]);
    c["plant"] = serde_json::from_str(plant).expect("plant");
    common::loaded(&c)
}

fn build(params: &str, plant: &str, scenario: Option<&str>) -> Result<Plc, ConfigError> {
    common::sim_plc(&loaded_config(params, plant), &registry(), scenario)
}

#[test]
fn programs_that_contradict_the_io_map_are_refused() {
    let map = format!("{}/io-map/trijoint.json", env!("CARGO_MANIFEST_DIR"));
    // Writing a variable bound to an input channel (a direction mismatch).
    let e = build(r#"{"write_bool": "SWITCH_LEFT_UPPER"}"#, "{}", None)
        .err()
        .expect("refused")
        .to_string();
    assert_eq!(
        e,
        format!(
            "test-config.json: at task_classes[0].programs[0]: variable \"SWITCH_LEFT_UPPER\" has two writers: the bus \
             ({map}: bindings[5] (DI.DigitalInput06)) and program \"test.drive\" (task_classes[0].programs[0]); a \
             variable has exactly one writer"
        )
    );
    // Reading a BOOL input as DINT (a type mismatch).
    let e = build(r#"{"read_dint": "BUTTON_STOP"}"#, "{}", None)
        .err()
        .expect("refused")
        .to_string();
    assert_eq!(
        e,
        format!(
            "test-config.json: at task_classes[0].programs[0]: variable \"BUTTON_STOP\" is used as DINT here but as BOOL \
             by the bus ({map}: bindings[0] (DI.DigitalInput01))"
        )
    );
}

#[test]
fn wiring_and_plant_errors_name_their_paths() {
    let e = build("{}", r#"{"wiring": {"pwm_left": "DI.DigitalInput10"}}"#, None)
        .err()
        .expect("refused")
        .to_string();
    assert_eq!(
        e,
        "test-config.json: at plant.wiring.pwm_left: DI.DigitalInput10 is a BOOL input channel, but a INT output channel \
         is needed here"
    );
    let e = build("{}", r#"{"wiring": {"encoder_left": "ENC.Counter01"}}"#, None)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        e.starts_with("test-config.json: at plant.wiring.encoder_left: no module \"ENC\" in "),
        "{e}"
    );
    let e = build("{}", r#"{"left": {"lower_switch_mm": -5}}"#, None)
        .err()
        .expect("refused")
        .to_string();
    assert_eq!(
        e,
        "test-config.json: at plant.left: positions must satisfy hard_stop_min_mm < lower_switch_mm < upper_switch_mm \
         < hard_stop_max_mm, got -3 < -5 < 250 < 253"
    );
}

#[test]
fn scenario_errors_name_the_event() {
    let bad = |events: &str| {
        build("{}", "{}", Some(&format!(r#"{{"events": [{events}]}}"#)))
            .err()
            .expect("refused")
            .to_string()
    };
    let e = bad(r#"{"at_ms": 5, "input": "BUTTON_GO", "value": true}"#);
    assert!(
        e.ends_with(&format!(
            "scenario.json: at events[0].input: no input variable \"BUTTON_GO\" in {}/io-map/trijoint.json wired to the machine",
            env!("CARGO_MANIFEST_DIR")
        )),
        "{e}"
    );
    let e = bad(r#"{"at_ms": 5, "input": "SWITCH_LEFT_UPPER", "value": true}"#);
    assert!(
        e.contains(
            "at events[0].input: \"SWITCH_LEFT_UPPER\" is wired to the machine's switch_left_upper, not to an operator panel button"
        ),
        "{e}"
    );
    let e = bad(r#"{"at_ms": 5, "joystick": [0.5, 0.5], "input": "BUTTON_STOP", "value": true}"#);
    assert!(
        e.contains("at events[0]: an event has exactly one of \"input\", \"joystick\", \"fault\", \"program\" or \"tool_changed\""),
        "{e}"
    );
    // A field the event's kind does not take is a mistake, not ignored.
    let e = bad(r#"{"at_ms": 5, "joystick": [0.5, 0.5], "value": true}"#);
    assert!(
        e.ends_with("scenario.json: at events[0].value: a joystick event takes nothing besides at_ms; \"value\" does not belong to it"),
        "{e}"
    );
    let e =
        bad(r#"{"at_ms": 5, "fault": "encoder_glitch", "drive": "left", "counts": 5, "switch": "SWITCH_LEFT_UPPER"}"#);
    assert!(
        e.ends_with(
            "scenario.json: at events[0].switch: the \"encoder_glitch\" fault takes \"drive\" and \"counts\"; \"switch\" does not belong to it"
        ),
        "{e}"
    );
    // Regression: this wrapped to t ≈ 0 and fired at once.
    let e = bad(r#"{"at_ms": 18446744073710, "input": "BUTTON_STOP", "value": true}"#);
    assert!(
        e.ends_with(
            "scenario.json: at events[0].at_ms: 18446744073710 ms is beyond the latest time the runtime's clock holds \
             (18446744073709 ms, 584 years)"
        ),
        "{e}"
    );
    let e = bad(r#"{"at_ms": 5, "fault": "bridge_error"}"#);
    assert!(
        e.contains("at events[0].drive: this fault needs \"drive\": \"left\" or \"right\""),
        "{e}"
    );
    let e = bad(r#"{"at_ms": 5, "fault": "switch_stuck", "switch": "BUTTON_STOP", "value": true}"#);
    assert!(
        e.contains("at events[0].switch: \"BUTTON_STOP\" is not a limit switch input of"),
        "{e}"
    );
    let e = bad(r#"{"at_ms": 5, "joystick": [2, 0]}"#);
    assert!(
        e.contains("at events[0].joystick: axes must lie in −1 … 1, got [2, 0]"),
        "{e}"
    );
    let e = bad(r#"{"at_ms": 5, "fault": "meltdown", "drive": "left"}"#);
    assert!(e.contains("at events[0].fault: unknown variant `meltdown`"), "{e}");
}

#[test]
fn a_carriage_at_full_duty_reaches_its_switch_in_the_expected_time_and_stops_at_the_hard_stop() {
    // Right drive from 125 mm up at full duty: 125 mm at 80 mm/s after a 50 ms lag ≈ 1.6125 s.
    // The mechanism is off here so that the right carriage can travel alone.
    let mut plc = build(r#"{"right": 32767}"#, r#"{"mechanism": false}"#, None).expect("valid");
    let mut first_seen = None;
    run(&mut plc, 4000, |plc, t| {
        if first_seen.is_none() && var(plc, vars::SWITCHES[1][1]) == Value::Bool(true) {
            first_seen = Some(t);
        }
    });
    assert_eq!(first_seen, Some(1620), "the first 10 ms cycle at or after 1.6125 s");
    let p = plant(&plc);
    assert_eq!(p.position_mm(1), 253.0, "at the hard stop");
    assert_eq!(p.velocity_mm_s(1), 0.0);
    assert_eq!(var(&plc, vars::SWITCHES[1][1]), Value::Bool(true));
    assert_eq!(p.position_mm(0), 125.0, "the left carriage did not move");
}

#[test]
fn the_counter_seen_by_the_plc_wraps_exactly() {
    let mut plc = build(r#"{"left": -32767}"#, r#"{"mechanism": false}"#, None).expect("valid");
    let mut checked = 0;
    let mut wraps = 0;
    let mut last = None;
    run(&mut plc, 2000, |plc, _| {
        let counts = (plant(plc).position_mm(0) * 7000.0).round() as i64;
        let expected = (counts + 32_768).rem_euclid(65_536) - 32_768;
        let Value::Int(seen) = var(plc, vars::ENCODER_COUNTER[0]) else {
            panic!("INT")
        };
        assert_eq!(i64::from(seen), expected);
        if let Some(prev) = last
            && i64::from(seen) > prev
        {
            wraps += 1;
        }
        last = Some(i64::from(seen));
        checked += 1;
    });
    assert!(checked >= 200 && wraps >= 10, "{checked} cycles, {wraps} wraps");
}

#[test]
fn the_linkage_jams_where_it_cannot_assemble() {
    // With a 200 mm rod, arm and rod span at most 500 mm, but |AC| grows from 475 mm towards
    // 548 mm as the left carriage goes down: the machine jams at h1 ≈ 78.3 mm, long before the
    // lower switch.
    let mut loaded = loaded_config(r#"{"left": -32767}"#, "{}");
    loaded.config.kinematics = Some(serde_json::json!({"trijoint": {"l3": 200.0}}));
    let mut jammed = common::sim_plc(&loaded, &registry(), None).expect("valid");
    run(&mut jammed, 4000, |_, _| {});
    let p = plant(&jammed);
    assert!(p.jams() > 0);
    let h1 = p.position_mm(0);
    assert!((h1 - 78.3).abs() < 0.5, "stopped where the linkage is stretched: {h1}");
    assert_eq!(var(&jammed, vars::SWITCHES[0][0]), Value::Bool(false));
    // It stands where the linkage is just at full stretch: |AC| = l2 + l3.
    let g = TrijointParams::default();
    let (c, s) = (g.alpha1_deg.to_radians().cos(), g.alpha1_deg.to_radians().sin());
    let a = [g.d - 125.0 * c, 125.0 * s];
    let cc = [h1 * c, h1 * s];
    let ac = (a[0] - cc[0]).hypot(a[1] - cc[1]);
    assert!((ac - 500.0).abs() < 0.2, "|AC| = {ac}");
}

#[test]
fn a_stuck_switch_stays_stuck_until_freed() {
    let scenario = r#"{"events": [
        {"at_ms": 100, "fault": "switch_stuck", "switch": "SWITCH_LEFT_UPPER", "value": true},
        {"at_ms": 500, "fault": "switch_free", "switch": "SWITCH_LEFT_UPPER"},
        {"at_ms": 600, "fault": "switch_stuck", "switch": "SWITCH_RIGHT_DOWN", "value": false}
    ]}"#;
    let mut plc = build(r#"{"right": -32767}"#, r#"{"mechanism": false}"#, Some(scenario)).expect("valid");
    run(&mut plc, 3500, |plc, t| {
        let ms = t;
        let stuck = (100..500).contains(&ms);
        assert_eq!(var(plc, vars::SWITCHES[0][1]), Value::Bool(stuck), "at {ms} ms");
        if ms >= 600 {
            assert_eq!(
                var(plc, vars::SWITCHES[1][0]),
                Value::Bool(false),
                "stuck off at {ms} ms"
            );
        }
    });
    assert!(
        plant(&plc).position_mm(1) < 0.0,
        "the right carriage passed its (dead) lower switch"
    );
}

#[test]
fn panel_inputs_and_faults_from_a_scenario() {
    let scenario = r#"{"events": [
        {"at_ms": 200, "input": "BUTTON_STOP", "value": true},
        {"at_ms": 300, "input": "BUTTON_STOP", "value": false},
        {"at_ms": 400, "joystick": [0.5, -0.25]},
        {"at_ms": 500, "fault": "encoder_glitch", "drive": "right", "counts": 1000},
        {"at_ms": 600, "fault": "bridge_error", "drive": "left"},
        {"at_ms": 700, "fault": "drive_dead", "drive": "right"}
    ]}"#;
    let mut plc = build(
        r#"{"left": 16000, "right": 16000}"#,
        r#"{"mechanism": false}"#,
        Some(scenario),
    )
    .expect("valid");
    let mut counter_before = 0i64;
    run(&mut plc, 1500, |plc, t| {
        let ms = t;
        assert_eq!(
            var(plc, vars::BUTTON_STOP),
            Value::Bool((200..300).contains(&ms)),
            "at {ms} ms"
        );
        if ms == 490 {
            let Value::Int(c) = var(plc, vars::ENCODER_COUNTER[1]) else {
                panic!()
            };
            counter_before = i64::from(c);
        }
        if ms >= 600 {
            assert_eq!(var(plc, vars::BRIDGE_ERROR[0]), Value::Bool(true), "latched at {ms} ms");
        }
    });
    let p = plant(&plc);
    assert_eq!(p.joystick(), [0.5, -0.25]);
    assert_eq!(var(&plc, vars::JOYSTICK[0]), Value::Real(0.5));
    assert!(p.velocity_mm_s(0).abs() < 1e-3, "no drive after the bridge error");
    assert!(p.velocity_mm_s(1).abs() < 1e-3, "the dead drive coasted to a stop");
    assert_eq!(
        var(&plc, vars::BRIDGE_ERROR[1]),
        Value::Bool(false),
        "a dead drive shows no error"
    );
    assert!(counter_before != 0);
}

#[test]
fn the_shipped_scenarios_are_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).expect("scenarios/") {
        let path = entry.expect("entry").path();
        let text = std::fs::read_to_string(&path).expect("readable");
        let file = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        // `NAME-….json` is a scenario of machine NAME; the others are the TRIJOINT's.
        match ["pn101", "ox-x", "ox-o", "hexapod"]
            .iter()
            .find(|m| file.starts_with(&format!("{m}-")))
        {
            Some(machine) => common::sim_plc(
                &common::machine_config(machine, |_| {}),
                &pkm_plc::compose::machines::all_programs(),
                Some(&text),
            )
            .map(|_| ()),
            None => build("{}", "{}", Some(&text)).map(|_| ()),
        }
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        count += 1;
    }
    assert!(count >= 9);
}
