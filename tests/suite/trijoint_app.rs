//! The TRIJOINT application on the simulated machine, in virtual time, driven by scenarios:
//! referencing, jogging, STOP with lockout and acknowledgement, faults.

use crate::common;

use common::{get, plant, run, state, var};
use pkm_kinematics::Kinematics;
use pkm_kinematics::trijoint::{Trijoint, TrijointParams};
use pkm_plc::image::Value;
use pkm_plc::runtime::plc::Plc;
use pkm_trijoint::vars;

const COUNT_MM: f64 = 1.0 / 7000.0;

/// The repository's config.json (the TRIJOINT application) with a scenario.
fn build(scenario: Option<&str>) -> Plc {
    common::sim_plc(
        &common::loaded(&common::repo_config()),
        &pkm_plc::compose::machines::all_programs(),
        scenario,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn power_on_references_the_machine_and_reaches_ready() {
    let mut plc = build(None);
    let seen = common::transitions(&mut plc, 60_000, |_, _| {});
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY"], "{seen:?}");
    let ready_at = seen[2].0;
    eprintln!("READY after {ready_at} ms");
    // Referenced positions are the plant's true positions from the lower switch (at 0 mm).
    let p = plant(&plc);
    for (i, side) in ["left", "right"].iter().enumerate() {
        let measured = get(&plc, vars::POSITION_MM[i]);
        assert!(
            (measured - p.position_mm(i)).abs() <= COUNT_MM + 1e-9,
            "{side}: {measured} vs {}",
            p.position_mm(i)
        );
        assert!(
            (p.position_mm(i) - 125.0).abs() < 0.01,
            "{side} at the middle: {}",
            p.position_mm(i)
        );
    }
}

/// The TRIJOINT kinematics with the default geometry, unlimited travel (for the plant's truth).
fn truth() -> Trijoint {
    Trijoint::new(&TrijointParams {
        h1_travel: [-1e3, 1e3],
        h2_travel: [-1e3, 1e3],
        ..TrijointParams::default()
    })
}

fn true_m(plc: &Plc) -> [f64; 2] {
    let p = plant(plc);
    let mut m = [0.0; 2];
    truth()
        .forward(&[p.position_mm(0), p.position_mm(1)], None, &mut m)
        .expect("the plant assembles");
    m
}

/// Power-on takes 42.6 s of simulated time; scenarios start after it.
const READY_MS: u64 = 43_000;

fn no_switch_ever(plc: &Plc, t: u64) {
    if t > 1000 && state(plc) != "INIT" {
        for s in vars::SWITCHES.into_iter().flatten() {
            let name = s.name();
            assert_eq!(var(plc, s), Value::Bool(false), "{name} at {t} ms in {}", state(plc));
        }
    }
}

#[test]
fn jogging_moves_m_in_the_commanded_direction_at_the_commanded_speed() {
    // x at half deflection for 2 s (10 mm/s), then y down at full deflection for 1 s (20 mm/s).
    let scenario = format!(
        r#"{{"events": [
            {{"at_ms": {a}, "joystick": [0.5, 0.0]}},
            {{"at_ms": {b}, "joystick": [0.0, -1.0]}},
            {{"at_ms": {c}, "joystick": [0.0, 0.0]}}
        ]}}"#,
        a = READY_MS,
        b = READY_MS + 2000,
        c = READY_MS + 3000
    );
    let mut plc = build(Some(&scenario));
    let mut marks = Vec::new();
    let mut states = Vec::new();
    run(&mut plc, READY_MS + 4000, |plc, t| {
        no_switch_ever(plc, t);
        if [READY_MS, READY_MS + 2000, READY_MS + 3000, READY_MS + 3950].contains(&t) {
            marks.push(true_m(plc));
        }
        if t >= READY_MS - 100 && states.last() != Some(&state(plc).to_string()) {
            states.push(state(plc).to_string());
        }
        if (READY_MS + 500..READY_MS + 2000).contains(&t) && t % 50 == 0 {
            // Steady motion: the displayed M (FK of the measured positions) matches the truth.
            let shown = [get(plc, vars::M[0]), get(plc, vars::M[1])];
            let real_m = true_m(plc);
            assert!(
                (shown[0] - real_m[0]).abs() < 0.01 && (shown[1] - real_m[1]).abs() < 0.01,
                "{shown:?} vs {real_m:?}"
            );
        }
    });
    assert_eq!(states, ["READY", "MOTION", "READY"]);
    let dx = [marks[1][0] - marks[0][0], marks[1][1] - marks[0][1]];
    assert!((dx[0] - 20.0).abs() < 1.0 && dx[1].abs() < 0.2, "x jog: {dx:?}");
    let dy = [marks[2][0] - marks[1][0], marks[2][1] - marks[1][1]];
    assert!(dy[0].abs() < 0.3 && (dy[1] + 20.0).abs() < 1.0, "y jog: {dy:?}");
    let settle = [marks[3][0] - marks[2][0], marks[3][1] - marks[2][1]];
    assert!(
        settle[0].abs() < 0.3 && settle[1].abs() < 0.6,
        "stops after release: {settle:?}"
    );
}

#[test]
fn jogging_stops_at_the_border_of_the_allowed_region_without_error() {
    // Full deflection up and to the right for 30 s: far beyond the workspace.
    let scenario = format!(r#"{{"events": [{{"at_ms": {READY_MS}, "joystick": [0.7, 0.7]}}]}}"#);
    let mut plc = build(Some(&scenario));
    let mut last = [0.0; 2];
    run(&mut plc, READY_MS + 30_000, |plc, t| {
        no_switch_ever(plc, t);
        assert_ne!(state(plc), "ERROR", "at {t} ms: {:?}", plc.app_status());
        last = true_m(plc);
    });
    assert_eq!(state(&plc), "MOTION", "still commanded, standing at the border");
    let p = plant(&plc);
    let (h1, h2) = (p.position_mm(0), p.position_mm(1));
    // At the border: a carriage at its software limit (2 mm inside a switch), or the singularity
    // threshold; never beyond.
    assert!(
        (1.99..=248.01).contains(&h1) && (1.99..=248.01).contains(&h2),
        "carriages {h1}, {h2}"
    );
    assert!(
        p.velocity_mm_s(0).abs() < 0.05 && p.velocity_mm_s(1).abs() < 0.05,
        "standing still at {last:?}"
    );
}

#[test]
fn stop_during_motion_lockout_and_acknowledgement() {
    let t0 = READY_MS + 1000;
    let scenario = format!(
        r#"{{"events": [
            {{"at_ms": {READY_MS}, "joystick": [0.0, 0.6]}},
            {{"at_ms": {t0}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {r1}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {p2}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {r2}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {j0}, "joystick": [0.0, 0.0]}},
            {{"at_ms": {p3}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {r3}, "input": "BUTTON_STOP", "value": false}}
        ]}}"#,
        r1 = t0 + 100,
        p2 = t0 + 300,
        r2 = t0 + 400,
        j0 = t0 + 500,
        p3 = t0 + 1000,
        r3 = t0 + 1100
    );
    let mut plc = build(Some(&scenario));
    let seen = common::transitions(&mut plc, t0 + 50_000, |plc, t| {
        if t >= t0 && t < t0 + 1000 {
            for pwm in vars::VELOCITY_SET {
                assert_eq!(var(plc, pwm), Value::Int(0), "PWM at {t} ms");
            }
        }
    });
    let after: Vec<(u64, &str, Option<&str>)> = seen
        .iter()
        .filter(|(t, ..)| *t >= READY_MS)
        .map(|(t, s, r)| (*t, s.as_str(), r.as_deref()))
        .collect();
    // MOTION; ERROR (STOP) at the STOP press's main cycle; the press at +300 ms is inside the
    // 500 ms lockout and ignored; the press at +1000 ms acknowledges: REBOOT, INIT, READY.
    let names: Vec<&str> = after.iter().map(|(_, s, _)| *s).collect();
    assert_eq!(names, ["MOTION", "ERROR", "REBOOT", "INIT", "READY"], "{after:?}");
    assert_eq!(after[1], (t0, "ERROR", Some("STOP")));
    assert_eq!(after[2].0, t0 + 1000);
}

/// Regression: when one drive found its switches first, INIT used to hold *both*
/// drives every cycle, so re-referencing from an asymmetric pose ended in "INIT timeout".
#[test]
fn acknowledgement_from_an_asymmetric_pose_references_again() {
    let (jog_end, ack) = (READY_MS + 15_000, READY_MS + 16_000);
    let scenario = format!(
        r#"{{"events": [
            {{"at_ms": {READY_MS}, "joystick": [-1.0, 1.0]}},
            {{"at_ms": {jog_end}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {r1}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {r1}, "joystick": [0.0, 0.0]}},
            {{"at_ms": {ack}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {r2}, "input": "BUTTON_STOP", "value": false}}
        ]}}"#,
        r1 = jog_end + 100,
        r2 = ack + 100,
    );
    let mut plc = build(Some(&scenario));
    let mut at_stop = [0.0; 2];
    let seen = common::transitions(&mut plc, ack + 60_000, |plc, t| {
        if t == jog_end {
            at_stop = [plant(plc).position_mm(0), plant(plc).position_mm(1)];
        }
    });
    // The jog left the carriages far apart: one drive reaches its switches well before the other.
    assert!((at_stop[0] - at_stop[1]).abs() > 50.0, "carriages at {at_stop:?}");
    let after: Vec<(&str, Option<&str>)> = seen
        .iter()
        .filter(|(t, ..)| *t >= jog_end)
        .map(|(_, s, r)| (s.as_str(), r.as_deref()))
        .collect();
    assert_eq!(
        after,
        [
            ("ERROR", Some("STOP")),
            ("REBOOT", None),
            ("INIT", None),
            ("READY", None)
        ],
        "{seen:?}"
    );
}

fn fault_scenario(fault: &str) -> String {
    let at = READY_MS + 500;
    format!(r#"{{"events": [{{"at_ms": {READY_MS}, "joystick": [0.3, 0.3]}}, {{"at_ms": {at}, {fault}}}]}}"#)
}

fn assert_fault(fault: &str, reason: &str) {
    let mut plc = build(Some(&fault_scenario(fault)));
    let mut error_at = None;
    run(&mut plc, READY_MS + 5000, |plc, t| {
        if error_at.is_none() && state(plc) == "ERROR" {
            error_at = Some(t);
        }
        if error_at.is_some() {
            for pwm in vars::VELOCITY_SET {
                assert_eq!(var(plc, pwm), Value::Int(0), "PWM in ERROR at {t} ms");
            }
        }
        // (INIT runs onto the switches on purpose; from READY on no carriage passes one.)
        let p = plant(plc);
        for i in 0..2 {
            assert!(
                t < READY_MS || (0.0..=250.0).contains(&p.position_mm(i)),
                "carriage {i} beyond its switches at {t} ms"
            );
        }
    });
    let t = error_at.unwrap_or_else(|| panic!("{fault}: no ERROR"));
    assert!(
        (READY_MS + 500..=READY_MS + 600).contains(&t),
        "{fault}: ERROR at {t} ms"
    );
    assert_eq!(plc.app_status().and_then(|s| s.reason), Some(reason), "{fault}");
}

#[test]
fn a_stuck_limit_switch_is_an_error_with_its_name() {
    assert_fault(
        r#""fault": "switch_stuck", "switch": "SWITCH_RIGHT_DOWN", "value": true"#,
        "limit switch SWITCH_RIGHT_DOWN",
    );
}

#[test]
fn an_encoder_glitch_is_an_encoder_fault() {
    assert_fault(
        r#""fault": "encoder_glitch", "drive": "left", "counts": 20000"#,
        "encoder fault left",
    );
}

#[test]
fn a_motor_bridge_error_is_an_error() {
    assert_fault(
        r#""fault": "bridge_error", "drive": "right""#,
        "motor bridge error right",
    );
}

#[test]
fn a_dead_drive_is_a_following_error() {
    let died = READY_MS + 500;
    let mut plc = build(Some(&fault_scenario(r#""fault": "drive_dead", "drive": "left""#)));
    let (mut error_at, mut speed) = (None, 0.0);
    run(&mut plc, READY_MS + 5000, |plc, t| {
        if t <= died {
            speed = get(plc, vars::SETPOINT_MM_S[0]).abs();
        }
        if error_at.is_none() && state(plc) == "ERROR" {
            error_at = Some(t);
        }
    });
    assert_eq!(plc.app_status().and_then(|s| s.reason), Some("following error left"));
    // The set-point runs on at the jog's speed while the carriage stands: the error passes the
    // bound (5 mm) after 5 mm / speed. It is an ERROR within the main cycles that follow (the
    // carriage's coasting, the fast class's detection, the main cycle's look: 150 ms at most).
    let after = error_at.expect("ERROR") - died;
    let expected = 5.0 / speed * 1000.0;
    eprintln!(
        "dead drive: ERROR {after} ms after it died; the set-point at {speed:.2} mm/s passes 5 mm after {expected:.0} ms"
    );
    assert!(speed > 1.0, "the jog moves the left carriage: {speed} mm/s");
    assert!(
        (expected..=expected + 150.0).contains(&(after as f64)),
        "ERROR {after} ms after the drive died; expected {expected:.0} … {:.0} ms",
        expected + 150.0
    );
}

/// Runs from power-on until ERROR (or `until_ms`); returns the reason.
fn error_reason(plc: &mut Plc, until_ms: u64) -> Option<String> {
    let mut reason = None;
    run(plc, until_ms, |plc, _| {
        if reason.is_none() && state(plc) == "ERROR" {
            reason = plc.app_status().and_then(|s| s.reason).map(str::to_string);
        }
    });
    reason
}

#[test]
fn init_names_the_following_error_of_a_carriage_blocked_while_it_seeks_a_switch() {
    // The left upper switch is dead: the carriage runs into its hard stop instead, and lags its
    // set-point. The reason says so, and which switch it sought — not that the switch is at
    // fault, which a drive or a link too slow would make as well.
    let scenario =
        r#"{"events": [{"at_ms": 0, "fault": "switch_stuck", "switch": "SWITCH_LEFT_UPPER", "value": false}]}"#;
    let mut plc = build(Some(scenario));
    assert_eq!(
        error_reason(&mut plc, 30_000).as_deref(),
        Some(
            "INIT: following error while seeking SWITCH_LEFT_UPPER: the carriage is blocked, or its drive or the link lags"
        )
    );
    assert!(plant(&plc).position_mm(0) <= 253.0);
}

#[test]
fn init_reports_the_wrong_switch() {
    // While the right carriage seeks its upper switch, its lower switch trips.
    let scenario =
        r#"{"events": [{"at_ms": 2000, "fault": "switch_stuck", "switch": "SWITCH_RIGHT_DOWN", "value": true}]}"#;
    let mut plc = build(Some(scenario));
    assert_eq!(
        error_reason(&mut plc, 30_000).as_deref(),
        Some("INIT: wrong switch SWITCH_RIGHT_DOWN")
    );
}

#[test]
fn a_cycle_time_violation_sends_the_application_to_error() {
    // The spare class runs a program that takes 250 ms once (at 45 s), beyond its 100 ms
    // tolerance, with the reaction "error".
    let mut c = common::repo_config();
    c["task_classes"][2]["on_violation"] = serde_json::json!("error");
    c["task_classes"][2]["programs"] = serde_json::json!([{"program": "selftest.idle",
        "params": {"burn_us": 250000, "burn_from_cycle": 450, "burn_until_cycle": 451}}]);
    let mut plc =
        common::sim_plc(&common::loaded(&c), &pkm_plc::compose::machines::all_programs(), None).expect("valid");
    assert_eq!(error_reason(&mut plc, 50_000).as_deref(), Some("cycle time violation"));
}

/// The repository's configuration with the main program's `params`.
fn with_main_params(params: serde_json::Value) -> serde_json::Value {
    let mut config = common::repo_config();
    for class in config["task_classes"].as_array_mut().expect("classes") {
        for program in class["programs"].as_array_mut().expect("programs") {
            if program["program"] == "trijoint.main" {
                program["params"] = params.clone();
            }
        }
    }
    config
}

/// Regression: the jog stopped the set-point dead at the software limit, so the
/// carriages overshot it (249.94 mm of a 248 mm limit in a 24 h soak) and 25 mm/s tripped a
/// switch. Jog into every border and corner at full deflection, at the default speed and faster:
/// each carriage stays within its software limit but for the braking tolerance, no switch.
#[test]
fn jogging_into_every_border_stops_inside_the_soft_limits() {
    for max_speed in [20.0, 25.0, 60.0] {
        let directions = [
            [1.0, 0.0],
            [-1.0, 0.0],
            [0.0, 1.0],
            [0.0, -1.0],
            [1.0, 1.0],
            [-1.0, -1.0],
            [-1.0, 1.0],
            [1.0, -1.0],
        ];
        let mut events = Vec::new();
        for (k, d) in directions.iter().enumerate() {
            let at = READY_MS + 20_000 * k as u64;
            events.push(format!(r#"{{"at_ms": {at}, "joystick": [{}, {}]}}"#, d[0], d[1]));
        }
        let scenario = format!(r#"{{"events": [{}]}}"#, events.join(","));
        let config = with_main_params(serde_json::json!({ "max_speed_mm_s": max_speed }));
        let mut plc = common::sim_plc(
            &common::loaded(&config),
            &pkm_plc::compose::machines::all_programs(),
            Some(&scenario),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let mut worst: f64 = 0.0;
        run(&mut plc, READY_MS + 20_000 * directions.len() as u64, |plc, t| {
            no_switch_ever(plc, t);
            if t > READY_MS {
                assert_ne!(state(plc), "ERROR", "{max_speed} mm/s at {t} ms");
                let p = plant(plc);
                for i in 0..2 {
                    let x = p.position_mm(i);
                    let e = (2.0 - x).max(x - 248.0);
                    worst = worst.max(e);
                }
            }
        });
        eprintln!("{max_speed} mm/s: worst excursion beyond a soft limit {worst:.4} mm");
        assert!(worst <= 0.5, "{max_speed} mm/s: {worst} mm beyond a soft limit");
    }
}
