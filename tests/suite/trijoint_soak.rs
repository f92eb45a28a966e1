//! Soak: one simulated hour (`PKM_SOAK_HOURS`) of random joystick input, STOP presses (one in
//! three a STOP during the referencing its acknowledgement starts) and injected faults on the
//! simulated machine, with the machine's invariants checked after every cycle.

use crate::common;

use common::Rng;
use common::soak::{self, Fault, HOUR_MS};

use std::time::Instant;

use pkm_plc::image::Value;
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::VirtualClock;

/// Joystick changes every 2–8 s, STOP presses every 20–90 s, a fault every 2–5 min. Returns the
/// scenario, the number of STOP presses, and the windows (ms) in which a fault that can keep
/// referencing from finishing (a stuck switch, a dead drive) is active.
fn random_scenario(seed: u64, hours: u64) -> (String, usize, Vec<(u64, u64)>) {
    let mut blocking = Vec::new();
    let mut rng = Rng(seed);
    let mut events = Vec::new();
    let mut t = 0;
    while t < hours * HOUR_MS {
        t += rng.between(2_000, 8_000);
        events.push(soak::joystick(&mut rng, t));
    }
    let stops = soak::stop_presses(&mut rng, (20_000, 90_000), hours);
    let presses = stops.len() / 2;
    events.extend(stops);
    let switches = [
        "SWITCH_LEFT_UPPER",
        "SWITCH_LEFT_DOWN",
        "SWITCH_RIGHT_UPPER",
        "SWITCH_RIGHT_DOWN",
    ];
    let drives = ["left", "right"];
    let mut t = 60_000;
    while t < hours * HOUR_MS {
        let drive = drives[(rng.next() * 2.0) as usize];
        let fault = match (rng.next() * 4.0) as usize {
            0 => Fault::StuckSwitch(switches[(rng.next() * 4.0) as usize]),
            1 => Fault::CounterGlitch(drive),
            2 => Fault::BridgeError(drive),
            _ => Fault::DeadDrive(drive),
        };
        let (fault_events, lasts) = soak::fault(fault, t);
        events.extend(fault_events);
        // A glitch or a bridge error lasts no time; the others can keep referencing from ending.
        if lasts > 0 {
            blocking.push((t, t + lasts));
        }
        t += rng.between(120_000, 300_000);
    }
    (format!(r#"{{"events": [{}]}}"#, events.join(",\n")), presses, blocking)
}

fn build(scenario: &str) -> Plc {
    common::sim_plc(
        &common::loaded(&common::repo_config()),
        &pkm_plc::compose::machines::all_programs(),
        Some(scenario),
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn one_simulated_hour_of_random_operation_keeps_every_invariant() {
    let hours = soak::hours();
    let (scenario, presses, blocking) = random_scenario(0x005E_ED0F_50A4, hours);
    let mut plc = build(&scenario);
    let started = Instant::now();
    let driving = |s: &str| matches!(s, "INIT" | "READY" | "MOTION");
    let mut clock = VirtualClock::default();
    plc.init(0, &mut clock);
    let mut previous = String::from("REBOOT");
    let mut error_since: Option<u64> = None;
    let mut visits = std::collections::BTreeMap::<String, usize>::new();
    let mut longest_error = 0;
    let (mut acknowledged, mut referenced_again) = (0, 0);
    let mut worst_past_soft_limit: f64 = 0.0;
    let mut stops_in_init = 0;
    while plc.next_release() < hours * HOUR_MS * 1_000_000 {
        let t_ns = plc.next_release();
        clock.advance_to(t_ns);
        plc.run_due(&mut clock, u64::MAX);
        let t = t_ns / 1_000_000;
        let status = plc.app_status().expect("status");
        let state = status.state.to_string();
        // Carriages inside their hard stops.
        let plant = common::plant(&plc);
        for i in 0..2 {
            assert!((-3.0..=253.0).contains(&plant.position_mm(i)), "carriage {i} at {t} ms");
        }
        // PWM zero whenever the state does not drive (from the first fast cycle that sees it).
        if !driving(&state) && !driving(&previous) {
            for pwm in pkm_trijoint::vars::VELOCITY_SET {
                assert_eq!(
                    common::var(&plc, pwm),
                    Value::Int(0),
                    "{} in {state} at {t} ms",
                    pwm.name()
                );
            }
        }
        // Jogging brakes before the software limits (2 … 248 mm from the lower switches, at
        // 0 mm): a carriage passes one by no more than the braking tolerance, 0.5 mm.
        if matches!(state.as_str(), "READY" | "MOTION") {
            for i in 0..2 {
                let past = (2.0 - plant.position_mm(i)).max(plant.position_mm(i) - 248.0);
                worst_past_soft_limit = worst_past_soft_limit.max(past);
                assert!(
                    past <= 0.5,
                    "carriage {i} {past:.3} mm past its soft limit at {t} ms in {state}"
                );
            }
        }
        // Every acknowledgement references again: READY, or ERROR for a reason — and a failed
        // referencing ("INIT …") only while a fault that blocks it was active within the search
        // time (an asymmetric pose once made re-referencing time out).
        if previous == "REBOOT" && state != "REBOOT" {
            acknowledged += 1;
        }
        if previous == "INIT" && state == "READY" {
            referenced_again += 1;
        }
        if previous == "INIT" && state == "ERROR" {
            let reason = status.reason.unwrap_or("");
            let explained =
                !reason.starts_with("INIT") || blocking.iter().any(|&(from, to)| from <= t && to + 35_000 >= t);
            assert!(explained, "referencing failed without a fault at {t} ms: {reason}");
        }
        // Every ERROR has a reason; ERROR is only left by acknowledgement (to REBOOT).
        if state == "ERROR" {
            assert!(status.reason.is_some(), "ERROR without a reason at {t} ms");
        }
        if previous == "ERROR" && state != "ERROR" {
            assert_eq!(state, "REBOOT", "ERROR left for {state} at {t} ms");
        }
        if state != previous {
            *visits.entry(state.clone()).or_default() += 1;
            if state == "ERROR" {
                error_since = Some(t);
                stops_in_init += usize::from(previous == "INIT" && status.reason == Some("STOP"));
            } else if let Some(since) = error_since.take() {
                longest_error = longest_error.max(t - since);
            }
        }
        previous = state;
    }
    let wall = started.elapsed();
    eprintln!(
        "soak: {hours} simulated hour(s) in {:.2} s; states entered: {visits:?}; {presses} STOP presses, {stops_in_init} during INIT; longest ERROR {longest_error} ms; \
         {referenced_again} of {acknowledged} acknowledgements referenced again ({stops_in_init} cut short by STOP); at most {worst_past_soft_limit:.3} mm past a soft limit",
        wall.as_secs_f64()
    );
    // A referencing that STOP cut short neither succeeded nor failed.
    assert!(
        referenced_again * 2 > acknowledged - stops_in_init,
        "{referenced_again} of {acknowledged}, {stops_in_init} cut short by STOP"
    );
    // Not vacuous: the run went through every state many times, and every ERROR was acknowledged
    // by one of the next STOP presses (at most 90 s apart, the first may fall in the lockout).
    for s in ["INIT", "READY", "MOTION", "ERROR", "REBOOT"] {
        assert!(
            visits.get(s).copied().unwrap_or(0) >= 10 * hours as usize,
            "{s} entered only {:?} times",
            visits.get(s)
        );
    }
    assert!(longest_error <= 181_000, "an ERROR lasted {longest_error} ms");
    assert!(
        stops_in_init >= 5 * hours as usize,
        "only {stops_in_init} STOPs during INIT"
    );
}
