//! The TRIJOINT encoder program and drive controller on the simulated machine, with a stand-in for
//! the main program (which is not there yet): unwrap, position control, following error and the
//! fast interlock.

use crate::common;

use common::{get, plant, run, var};
use pkm_plc::image::{Declare, Input, Output, Value};
use pkm_plc::program::{Cycle, Program, ProgramArgs, ProgramInfo, Registry};
use pkm_plc::runtime::plc::Plc;
use pkm_trijoint::encoders::unwrap;
use pkm_trijoint::state::MainState;
use pkm_trijoint::vars;
use proptest::prelude::*;

proptest! {
    /// Any motion whose per-sample change stays within half the counter range is unwrapped
    /// exactly from the wrapping 16-bit counter.
    #[test]
    fn unwrap_is_exact_for_any_profile_below_half_the_range(
        start in any::<i32>().prop_map(i64::from),
        steps in prop::collection::vec(-32_767i64..=32_767, 1..400),
    ) {
        let mut truth = start;
        let mut counts = start;
        let mut last_raw = truth as i16;
        for step in steps {
            truth += step;
            let raw = truth as i16;
            let (next, delta) = unwrap(counts, last_raw, raw);
            prop_assert_eq!(delta, step);
            counts = next;
            last_raw = raw;
            prop_assert_eq!(counts, truth);
        }
    }
}

/// Stands in for the main program: a state, the drive enable, and a set-point ramp on the left
/// drive of `ramp_mm` at `speed_mm_s` starting at `ramp_from_ms`, published with its velocity and
/// time every main cycle as the main program will.
struct MainStandIn {
    p: StandInParams,
    position: Input<f64>,
    state: Output<i16>,
    enable: Output<bool>,
    setpoints: [Output<f64>; 2],
    velocities: [Output<f64>; 2],
    time: Output<f64>,
    base: Option<[f64; 2]>,
    right_position: Input<f64>,
    period: Output<u16>,
}

#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StandInParams {
    state: String,
    ramp_from_ms: u64,
    ramp_mm: f64,
    speed_mm_s: f64,
}

impl Program for MainStandIn {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let state = MainState::ALL
            .into_iter()
            .find(|s| s.name() == self.p.state)
            .unwrap_or(MainState::Error);
        ctx.set(self.state, state.code());
        ctx.set(self.enable, true);
        ctx.set(self.period, 50);
        let base = *self
            .base
            .get_or_insert([ctx.get(self.position), ctx.get(self.right_position)]);
        let t = ctx.time_ns() as f64 * 1e-9;
        let since = (t - self.p.ramp_from_ms as f64 * 1e-3).max(0.0);
        let travelled = (self.p.speed_mm_s * since).min(self.p.ramp_mm);
        let moving = t * 1e3 >= self.p.ramp_from_ms as f64 && travelled < self.p.ramp_mm;
        ctx.set(self.setpoints[0], base[0] + travelled);
        ctx.set(self.velocities[0], if moving { self.p.speed_mm_s } else { 0.0 });
        ctx.set(self.setpoints[1], base[1]);
        ctx.set(self.velocities[1], 0.0);
        ctx.set(self.time, t);
    }
}

fn registry() -> Registry {
    let mut r = pkm_plc::compose::machines::all_programs();
    r.register(ProgramInfo {
        name: "test.main",
        summary: "test",
        factory: |args: &ProgramArgs<'_>, decl: &mut Declare<'_>| {
            let p: StandInParams = args.parse(decl);
            // The references stay at 0: positions are relative to the counters at power-on.
            decl.output::<f64>("reference_left_mm", 0.0);
            decl.output::<f64>("reference_right_mm", 0.0);
            decl.output::<bool>("encoder_fault_ack", false);
            Box::new(MainStandIn {
                p,
                position: decl.input("JOINT1_POSITION"),
                right_position: decl.input("JOINT2_POSITION"),
                state: decl.output("main_state", 0),
                enable: decl.output("drives_enable", false),
                setpoints: [
                    decl.output("setpoint_left_mm", 0.0),
                    decl.output("setpoint_right_mm", 0.0),
                ],
                velocities: [
                    decl.output("setpoint_left_mm_s", 0.0),
                    decl.output("setpoint_right_mm_s", 0.0),
                ],
                time: decl.output("setpoint_time_s", 0.0),
                base: None,
                period: decl.output("period_duration", 0),
            })
        },
    });
    r
}

fn build(stand_in: &str, scenario: Option<&str>) -> Plc {
    let mut c = common::repo_config();
    c["task_classes"][0]["programs"] =
        serde_json::json!([{"program": "trijoint.encoders"}, {"program": "trijoint.control"}]);
    c["task_classes"][1]["programs"] = serde_json::json!([{"program": "test.main", "params": serde_json::from_str::<serde_json::Value>(stand_in).expect("params")}]);
    common::sim_plc(&common::loaded(&c), &registry(), scenario).unwrap_or_else(|e| panic!("{e}"))
}

const READY_RAMP: &str = r#"{"state": "READY", "ramp_from_ms": 500, "ramp_mm": 10.0, "speed_mm_s": 20.0}"#;

#[test]
fn positions_follow_the_plant_to_one_count() {
    let mut plc = build(READY_RAMP, None);
    let start = plant(&plc).position_mm(0);
    let mut checked = 0;
    run(&mut plc, 2000, |plc, _| {
        let measured = get(plc, vars::POSITION_MM[0]);
        // Positions are relative to the counter at power-on (125 mm ↔ 23 032 counts).
        let truth = plant(plc).position_mm(0) - start + 23_032.0 / 7000.0;
        assert!(
            (measured - truth).abs() <= 1.0 / 7000.0 + 1e-12,
            "{measured} vs {truth}"
        );
        checked += 1;
    });
    assert!(checked > 100);
}

#[test]
fn the_regulator_follows_a_ramp_and_settles() {
    let mut plc = build(READY_RAMP, None);
    let start = plant(&plc).position_mm(0);
    let mut worst_following = 0.0f64;
    run(&mut plc, 2500, |plc, _| {
        assert_eq!(var(plc, vars::FOLLOWING_ERROR[0]), Value::Bool(false));
        let sp = get(plc, vars::SETPOINT_MM[0]);
        worst_following = worst_following.max((sp - get(plc, vars::POSITION_MM[0])).abs());
    });
    let end = plant(&plc).position_mm(0);
    assert!((end - start - 10.0).abs() < 0.01, "moved {} mm", end - start);
    assert!(worst_following < 2.0, "largest following error {worst_following} mm");
    assert!(
        (plant(&plc).position_mm(1) - 125.0).abs() < 0.01,
        "the right drive held its position"
    );
}

#[test]
fn stop_zeroes_the_pwm_in_the_same_fast_cycle() {
    let scenario = r#"{"events": [{"at_ms": 700, "input": "BUTTON_STOP", "value": true}]}"#;
    let mut plc = build(READY_RAMP, Some(scenario));
    let mut driving_before = false;
    run(&mut plc, 1000, |plc, t| {
        let Value::Int(pwm) = var(plc, vars::VELOCITY_SET[0]) else {
            panic!()
        };
        if t == 690 {
            driving_before = pwm != 0;
        }
        if t >= 700 {
            assert_eq!(pwm, 0, "PWM at {t} ms");
            assert_eq!(var(plc, vars::INTERLOCK), Value::Bool(true));
        }
    });
    assert!(driving_before, "the drive was moving before STOP");
}

#[test]
fn a_limit_switch_interlocks_outside_init_only() {
    let scenario =
        r#"{"events": [{"at_ms": 600, "fault": "switch_stuck", "switch": "SWITCH_RIGHT_UPPER", "value": true}]}"#;
    let mut plc = build(READY_RAMP, Some(scenario));
    run(&mut plc, 800, |plc, t| {
        if t >= 600 {
            assert_eq!(
                var(plc, vars::VELOCITY_SET[0]),
                Value::Int(0),
                "READY: interlocked at {t} ms"
            );
        }
    });
    let mut plc = build(&READY_RAMP.replace("READY", "INIT"), Some(scenario));
    let mut moving = false;
    run(&mut plc, 800, |plc, t| {
        if t >= 650 && var(plc, vars::VELOCITY_SET[0]) != Value::Int(0) {
            moving = true;
        }
    });
    assert!(moving, "INIT runs into switches on purpose: no interlock");
}

#[test]
fn a_dead_drive_is_a_following_error_and_a_glitch_an_encoder_fault() {
    let scenario = r#"{"events": [{"at_ms": 400, "fault": "drive_dead", "drive": "left"}]}"#;
    let mut plc = build(READY_RAMP, Some(scenario));
    let mut flagged_at = None;
    run(&mut plc, 1500, |plc, t| {
        if flagged_at.is_none() && var(plc, vars::FOLLOWING_ERROR[0]) == Value::Bool(true) {
            flagged_at = Some(t);
        }
    });
    // The set-point leaves at 500 ms at 20 mm/s: 5 mm of following error after 250 ms.
    let t = flagged_at.expect("following error flagged");
    assert!((750..=770).contains(&t), "flagged at {t} ms");

    let scenario = r#"{"events": [{"at_ms": 600, "fault": "encoder_glitch", "drive": "right", "counts": 20000}]}"#;
    let mut plc = build(READY_RAMP, Some(scenario));
    run(&mut plc, 800, |plc, t| {
        let fault = var(plc, vars::ENCODER_FAULT[1]) == Value::Bool(true);
        assert_eq!(fault, t >= 600, "encoder fault at {t} ms");
        if t >= 600 {
            assert_eq!(var(plc, vars::VELOCITY_SET[0]), Value::Int(0), "interlocked at {t} ms");
        }
    });
}
