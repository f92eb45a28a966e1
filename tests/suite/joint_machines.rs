//! The joint-driven machines (pn101, O-X glide X and O, hexapod) on their simulated plants, in
//! virtual time, driven by scenarios: power-up and referencing to READY, the tool pose at home,
//! world jog along x, the workspace border, STOP with the drives zeroed in the same fast cycle
//! and the acknowledgement; pn101's shared inputs and its steppers' pull-out.

use crate::common;

use common::{get, joint_plant, machine_config, run, state, transitions};
use pkm_joints::vars;
use pkm_kinematics::frame::MachineFrame;
use pkm_plc::runtime::plc::Plc;

const MACHINES: [&str; 4] = ["pn101", "ox-x", "ox-o", "hexapod"];

/// The machine's PLC on its simulated plant, its configuration edited by `edit`.
fn build(name: &str, scenario: Option<&str>, edit: impl FnOnce(&mut serde_json::Value)) -> Plc {
    common::sim_plc(
        &machine_config(name, edit),
        &pkm_plc::compose::machines::all_programs(),
        scenario,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

/// Number of joints and of pose coordinates.
fn dof(name: &str) -> usize {
    if name == "hexapod" { 6 } else { 3 }
}

/// The machine frame of the machine's default kinematics.
fn frame(name: &str) -> MachineFrame {
    let model = pkm_kinematics::Machine::from_name(name).expect("a model");
    MachineFrame::default_for(model).expect("home is a pose")
}

/// When the machine reaches READY after power-on (ms of simulated time).
fn ready_ms(name: &str) -> u64 {
    let mut plc = build(name, None, |_| {});
    let seen = transitions(&mut plc, 180_000, |_, _| {});
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY"], "{name}: {seen:?}");
    seen[2].0
}

fn tool(plc: &Plc, n: usize) -> Vec<f64> {
    vars::TOOL[..n].iter().map(|v| get(plc, *v)).collect()
}

fn joints(plc: &Plc, n: usize) -> Vec<f64> {
    vars::JOINT_POSITION[..n].iter().map(|v| get(plc, *v)).collect()
}

#[test]
fn every_machine_references_and_reaches_ready_at_the_forward_kinematics_of_its_reference_joints() {
    for name in MACHINES {
        let n = dof(name);
        let mut plc = build(name, None, |_| {});
        let seen = transitions(&mut plc, 180_000, |_, _| {});
        let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
        assert_eq!(names, ["REBOOT", "INIT", "READY"], "{name}: {seen:?}");
        eprintln!("{name}: READY after {:.2} s", seen[2].0 as f64 / 1000.0);
        let f = frame(name);
        let mut expected = [0.0; 6];
        f.forward(f.home_joints(), None, &mut expected[..n])
            .expect("fk of home");
        let (q, x) = (joints(&plc, n), tool(&plc, n));
        for (j, (q, home)) in q.iter().zip(f.home_joints()).enumerate() {
            assert!(
                (q - home).abs() < 0.01,
                "{name}: joint {} at {q} (reference {home})",
                j + 1
            );
            // The controller's joint position is the plant's true one (the reference switch
            // defines it), to the capture's resolution.
            let truth = joint_plant(&plc).position_mm(j);
            assert!(
                (q - truth).abs() < 0.01,
                "{name}: joint {} reads {q} true {truth}",
                j + 1
            );
        }
        for c in 0..n {
            assert!(
                (x[c] - expected[c]).abs() < 0.01,
                "{name}: tool {x:?} vs FK of home {expected:?}"
            );
        }
        // TOOL_* is the forward kinematics of the joint positions (of the last main cycle; the
        // hexapod's regulators still settle by a micrometre since).
        let mut fk = [0.0; 6];
        f.forward(&q, None, &mut fk[..n]).expect("fk");
        for c in 0..n {
            assert!((x[c] - fk[c]).abs() < 0.005, "{name}: {x:?} vs {fk:?}");
        }
    }
}

/// A scenario: the stick at `(x, y)` from `at_ms` for `for_ms`.
fn stick(at_ms: u64, x: f64, y: f64, for_ms: u64) -> String {
    format!(
        r#"{{"events": [{{"at_ms": {at_ms}, "joystick": [{x}, {y}]}}, {{"at_ms": {}, "joystick": [0, 0]}}]}}"#,
        at_ms + for_ms
    )
}

#[test]
fn a_world_jog_along_x_moves_only_x() {
    for name in MACHINES {
        let n = dof(name);
        let start = ready_ms(name) + 1000;
        let mut plc = build(name, Some(&stick(start, 0.7, 0.0, 3000)), |_| {});
        let mut home: Option<Vec<f64>> = None;
        let mut worst = 0.0f64;
        let mut moved = 0.0f64;
        let seen = transitions(&mut plc, start + 6000, |plc, t| {
            if t < start {
                return;
            }
            let x = tool(plc, n);
            let h = home.get_or_insert_with(|| x.clone());
            moved = moved.max((x[0] - h[0]).abs());
            for c in 1..n {
                worst = worst.max((x[c] - h[c]).abs());
            }
        });
        let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
        assert_eq!(
            names,
            ["REBOOT", "INIT", "READY", "MOTION", "READY"],
            "{name}: {seen:?}"
        );
        eprintln!("{name}: x moved {moved:.3} mm, other coordinates at most {worst:.4}");
        assert!(moved > 5.0, "{name}: the tool moved {moved} mm along x");
        assert!(worst <= 0.05, "{name}: another coordinate moved {worst} mm");
    }
}

#[test]
fn a_jog_into_the_workspace_border_stops_there_without_an_error() {
    for name in MACHINES {
        let n = dof(name);
        let start = ready_ms(name) + 1000;
        // World limits far away (the widest their ranges allow): the border is the
        // mechanism's (joint software limits, no assembly, the singularity threshold).
        let far = |c: &mut serde_json::Value| {
            let limits: Vec<[f64; 2]> = (0..n)
                .map(|k| if k < 3 { [-1000.0, 1000.0] } else { [-180.0, 180.0] })
                .collect();
            c["task_classes"][1]["programs"][0]["params"]["world_limits"] = serde_json::json!(limits);
        };
        let mut plc = build(name, Some(&stick(start, 1.0, 0.0, 120_000)), far);
        let mut last: Vec<f64> = Vec::new();
        let mut still_from = 0;
        let seen = transitions(&mut plc, start + 120_000, |plc, t| {
            let x = tool(plc, n);
            if last.is_empty() || (x[0] - last[0]).abs() > 0.01 {
                still_from = t;
            }
            last = x;
            let p = joint_plant(plc);
            for j in 0..n {
                let [lo, hi] = p.hard_stops_mm(j);
                assert!((lo..=hi).contains(&p.position_mm(j)));
            }
        });
        let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
        assert_eq!(names, ["REBOOT", "INIT", "READY", "MOTION"], "{name}: {seen:?}");
        assert!(
            still_from < start + 110_000,
            "{name}: the tool still moves at {still_from} ms, x = {}",
            last[0]
        );
        let p = joint_plant(&plc);
        for j in 0..n {
            assert_eq!(p.lost_steps(j), 0.0, "{name}: joint {} lost steps", j + 1);
        }
        eprintln!(
            "{name}: stopped at the border at x = {:.3} mm after {} ms",
            last[0],
            still_from - start
        );
    }
}

/// Whether every drive output of the machine is zero now.
fn drives_zero(plc: &Plc, name: &str) -> bool {
    (0..dof(name)).all(|j| {
        if name == "hexapod" {
            get(plc, vars::PWM[j]) == 0
        } else {
            get(plc, vars::SPEED[j]) == 0 && !get(plc, vars::ENABLE[j])
        }
    })
}

#[test]
fn stop_zeroes_the_drives_in_the_same_fast_cycle_and_the_acknowledgement_references_again() {
    for name in MACHINES {
        let ready = ready_ms(name);
        let jog = ready + 1000;
        let stop = jog + 1500;
        let scenario = format!(
            r#"{{"events": [
                {{"at_ms": {jog}, "joystick": [0.8, 0]}},
                {{"at_ms": {stop}, "input": "BUTTON_STOP", "value": true}},
                {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}},
                {{"at_ms": {}, "joystick": [0, 0]}},
                {{"at_ms": {}, "input": "BUTTON_STOP", "value": true}},
                {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}}
            ]}}"#,
            stop + 200,
            stop + 300,
            stop + 1000,
            stop + 1200
        );
        let mut plc = build(name, Some(&scenario), |_| {});
        let mut moving_before = false;
        let mut checked = false;
        let seen = transitions(&mut plc, stop + 1000 + ready + 2000, |plc, t| {
            if t < stop {
                moving_before |= !drives_zero(plc, name) && state(plc) == "MOTION";
            } else if !checked && get(plc, vars::BUTTON_STOP) {
                checked = true;
                assert!(
                    drives_zero(plc, name),
                    "{name}: drive outputs at {t} ms, the cycle STOP is seen"
                );
            }
        });
        assert!(moving_before && checked, "{name}");
        let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
        assert_eq!(
            names,
            ["REBOOT", "INIT", "READY", "MOTION", "ERROR", "REBOOT", "INIT", "READY"],
            "{name}: {seen:?}"
        );
        assert_eq!(seen[4].2.as_deref(), Some("STOP"));
    }
}

/// How far (mm) each joint stands past its reference switch, in the direction in which the
/// switch is on (the plant's truth, not the controller's belief).
fn past_reference(plc: &Plc, n: usize) -> Vec<f64> {
    let plant = joint_plant(plc);
    (0..n)
        .map(|j| {
            let (at, direction) = plant.reference_switch(j);
            (plant.position_mm(j) - at) * direction
        })
        .collect()
}

/// STOP in READY, acknowledged; STOP again while the new referencing runs (at five timings up to
/// 5 s into it), acknowledged: the next referencing reaches READY, and no joint is ever driven
/// past its reference switch by more than the search's braking (once the hexapod's return went
/// to the reference positions of the counted frame, 737 mm past its switches at 50 % PWM, until
/// a limit switch tripped).
#[test]
fn a_stop_during_re_referencing_never_sends_a_joint_past_its_reference_switch() {
    for name in MACHINES {
        let n = dof(name);
        let stop = ready_ms(name) + 1000;
        let ack = stop + 1000;
        for into_ms in [300, 1200, 2500, 3700, 5000] {
            let again = ack + 1000 + into_ms;
            let presses: Vec<String> = [stop, ack, again, again + 1000]
                .iter()
                .map(|t| {
                    format!(
                        r#"{{"at_ms": {t}, "input": "BUTTON_STOP", "value": true}}, {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}}"#,
                        t + 150
                    )
                })
                .collect();
            let scenario = format!(r#"{{"events": [{}]}}"#, presses.join(", "));
            let mut plc = build(name, Some(&scenario), |_| {});
            // Per joint: how far past its switch it stood when INIT was entered, and the farthest
            // it went beyond that during the visit.
            let mut entry: Option<Vec<f64>> = None;
            let mut worst = 0.0f64;
            let seen = transitions(&mut plc, again + 1000 + 3 * ready_ms(name), |plc, _| {
                if state(plc) != "INIT" {
                    entry = None;
                    return;
                }
                let past = past_reference(plc, n);
                let from = entry.get_or_insert_with(|| past.clone());
                for (p, f) in past.iter().zip(from.iter()) {
                    worst = worst.max(p - f.max(0.0));
                }
            });
            let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
            assert_eq!(
                names,
                [
                    "REBOOT", "INIT", "READY", "ERROR", "REBOOT", "INIT", "ERROR", "REBOOT", "INIT", "READY"
                ],
                "{name}, STOP {into_ms} ms into referencing: {seen:?}"
            );
            assert_eq!(seen[6].2.as_deref(), Some("STOP"), "{name}: {seen:?}");
            assert!(
                worst < 3.0,
                "{name}, STOP {into_ms} ms into referencing: a joint went {worst:.1} mm past its reference switch"
            );
        }
    }
}

/// A stepper that lost steps (its motor dead while jogged) leaves the counted positions wrong
/// while the references are still believed known (STOP keeps them): the return of the next
/// referencing sees the reference input contradict them and stops with ERROR at once instead
/// of moving on by them; acknowledged, the machine references from where it stands.
#[test]
fn a_reference_input_that_contradicts_the_known_positions_stops_referencing() {
    let ready = ready_ms("ox-x");
    let (jog, stop) = (ready + 2000, ready + 6000);
    let scenario = format!(
        r#"{{"events": [
            {{"at_ms": {jog}, "fault": "drive_dead", "drive": "joint1"}},
            {{"at_ms": {jog}, "joystick": [0.8, 0]}},
            {{"at_ms": {}, "joystick": [0, 0]}},
            {{"at_ms": {}, "fault": "drive_alive", "drive": "joint1"}},
            {{"at_ms": {stop}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}}
        ]}}"#,
        jog + 1500,
        jog + 3000,
        stop + 150,
        stop + 1000,
        stop + 1150,
        stop + 5000,
        stop + 5150,
    );
    let mut plc = build("ox-x", Some(&scenario), |_| {});
    let seen = transitions(&mut plc, stop + 5000 + 2 * ready, |_, _| {});
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        [
            "REBOOT", "INIT", "READY", "MOTION", "READY", "ERROR", "REBOOT", "INIT", "ERROR", "REBOOT", "INIT", "READY"
        ],
        "{seen:?}"
    );
    assert_eq!(
        seen[8].2.as_deref(),
        Some(
            "reference input JOINT1_REFERENCE contradicts joint 1's position in the last referencing's frame: the positions are not known; acknowledge to reference from where the joints stand"
        )
    );
    // Caught within a few main cycles of the return's start, and referenced again from there:
    // the controller's positions are the plant's.
    assert!(seen[8].0 - seen[7].0 <= 500, "{seen:?}");
    for j in 0..3 {
        let q = get(&plc, vars::JOINT_POSITION[j]);
        let truth = joint_plant(&plc).position_mm(j);
        assert!((q - truth).abs() < 0.01, "joint {} reads {q}, true {truth}", j + 1);
    }
}

/// pn101's shared reference input on at power-on because joint 3 stands on its switch: joint 1,
/// referenced first, leaves for at most the travel beyond its own switch, finds the input still
/// on, goes back to where it started and stops with ERROR — where it once left for 12 s, into
/// its limit switch.
#[test]
fn pn101_a_joint_never_leaves_a_switch_another_joint_holds_beyond_its_own_switchs_reach() {
    let edit = |c: &mut serde_json::Value| c["plant"]["joints"][2]["start_mm"] = serde_json::json!(-57.0);
    let mut plc = build("pn101", None, edit);
    let start = joint_plant(&plc).position_mm(0);
    let mut farthest = 0.0f64;
    let seen = transitions(&mut plc, 30_000, |plc, _| {
        farthest = farthest.max((joint_plant(plc).position_mm(0) - start).abs());
    });
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "ERROR"], "{seen:?}");
    assert_eq!(
        seen[2].2.as_deref(),
        Some(
            "INIT: reference input REFERENCE stays on while joint 1 backs off its switch: another joint is on its switch (the shared input cannot say which); \
             the joint went back to where it started. Acknowledge, then hold BUTTON_OVERRIDE and jog the joint on its switch off it in joint mode"
        )
    );
    // Its switch at 55 mm, its travel to 60 mm: 5 mm, a back-off of 2 and the agreement of 1.
    assert!(farthest <= 8.5, "joint 1 left {farthest:.2} mm");
    assert!(farthest >= 7.5, "joint 1 tried {farthest:.2} mm");
    let back = (joint_plant(&plc).position_mm(0) - start).abs();
    assert!(back < 0.05, "joint 1 stands {back:.3} mm from where it started");
    assert!(joint_plant(&plc).position_mm(2) <= -55.0, "joint 3 still on its switch");
}

#[test]
fn pn101_references_one_joint_at_a_time_in_order() {
    let mut plc = build("pn101", None, |_| {});
    let mut order: Vec<usize> = Vec::new();
    run(&mut plc, 120_000, |plc, _| {
        if state(plc) != "INIT" {
            return;
        }
        let moving: Vec<usize> = (0..3)
            .filter(|j| get(plc, vars::SETPOINT_VELOCITY[*j]) != 0.0)
            .collect();
        assert!(
            moving.len() <= 1,
            "joints {moving:?} move together on the shared reference input"
        );
        if let Some(&j) = moving.first()
            && order.last() != Some(&j)
        {
            order.push(j);
        }
    });
    assert_eq!(order, [0, 1, 2], "joint 1, then 2, then 3");
    assert_eq!(state(&plc), "READY");
}

#[test]
fn pn101_a_shared_limit_input_trips_error_naming_it() {
    let at = ready_ms("pn101") + 1000;
    let scenario =
        format!(r#"{{"events": [{{"at_ms": {at}, "fault": "switch_stuck", "switch": "LIMIT_POS", "value": true}}]}}"#);
    let mut plc = build("pn101", Some(&scenario), |_| {});
    let seen = transitions(&mut plc, at + 500, |_, _| {});
    let last = seen.last().expect("states");
    assert_eq!(last.1, "ERROR");
    assert_eq!(
        last.2.as_deref(),
        Some(
            "limit input LIMIT_POS (shared by joints 1, 2, 3: it does not say which; acknowledge, then jog off in joint mode with BUTTON_OVERRIDE held)"
        )
    );
}

#[test]
fn pn101_on_a_shared_limit_at_power_on_joint_jog_with_the_override_moves_off_it() {
    // Joint 1 stands past its positive limit switch (60 mm) at power-on.
    let edit = |c: &mut serde_json::Value| c["plant"]["joints"][0]["start_mm"] = serde_json::json!(60.5);
    let scenario = r#"{"events": [
        {"at_ms": 1000, "joystick": [-0.5, 0]},
        {"at_ms": 2000, "input": "BUTTON_OVERRIDE", "value": true},
        {"at_ms": 4000, "joystick": [0, 0]},
        {"at_ms": 4500, "input": "BUTTON_OVERRIDE", "value": false}
    ]}"#;
    let mut plc = build("pn101", Some(scenario), edit);
    let mut at_2s = f64::NAN;
    let mut notes = Vec::new();
    let seen = transitions(&mut plc, 120_000, |plc, t| {
        if t == 1990 {
            at_2s = joint_plant(plc).position_mm(0);
        }
        let note = plc.app_status().and_then(|s| s.note).map(str::to_string);
        if notes.last() != Some(&note) {
            notes.push(note);
        }
    });
    assert_eq!(at_2s, 60.5, "without the override the joint stays on the limit");
    // The status line tells the operator what INIT waits for.
    assert_eq!(
        notes,
        [
            None,
            Some("a limit input is active: hold BUTTON_OVERRIDE and jog the joint off it".to_string()),
            Some("joint mode, limits overridden: jog the selected joint off the limit".to_string()),
            Some("joint mode: release BUTTON_OVERRIDE to reference".to_string()),
            None
        ]
    );
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY"], "{seen:?}");
    assert_eq!(joint_plant(&plc).lost_steps(0), 0.0);
}

#[test]
fn pn101_a_stepper_driven_past_its_pull_out_limit_loses_steps_that_open_loop_cannot_see() {
    // Referencing searches at 12 mm/s, above the motors' 10 mm/s pull-out speed.
    let edit = |c: &mut serde_json::Value| {
        let classes = c["task_classes"].as_array_mut().expect("classes");
        classes[0]["programs"][0]["params"]["steppers"][0]["max_speed_mm_s"] = serde_json::json!(12.0);
        classes[1]["programs"][0]["params"]["joints"][0]["max_speed_mm_s"] = serde_json::json!(12.0);
        classes[1]["programs"][0]["params"]["joints"][0]["reference"]["search_speed_mm_s"] = serde_json::json!(12.0);
    };
    let mut plc = build("pn101", None, edit);
    run(&mut plc, 3000, |_, _| {});
    let p = joint_plant(&plc);
    let counted = get(&plc, vars::JOINT_POSITION[0]);
    let truth = p.position_mm(0) - (-10.0);
    eprintln!(
        "after 3 s: counted {counted:.3} mm, moved {truth:.3} mm, lost {} steps",
        p.lost_steps(0)
    );
    assert!(p.lost_steps(0) > 400.0, "lost {}", p.lost_steps(0));
    assert!(
        counted - truth > 1.0,
        "the counter says {counted}, the carriage moved {truth}"
    );
    assert_eq!(state(&plc), "INIT", "open loop: the controller does not see it");
}
