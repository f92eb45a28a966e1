//! The parts of the soaks' random scenarios that every machine's soak shares: joystick moves,
//! STOP presses and the injected faults as scenario events.

use super::Rng;

/// One simulated hour (ms).
pub const HOUR_MS: u64 = 3_600_000;

/// How many simulated hours a soak runs: `PKM_SOAK_HOURS` (a whole number ≥ 1), else 1 — the
/// test command runs one hour per machine; `PKM_SOAK_HOURS=24 cargo test --release --test suite
/// soak` runs the day the README's figures come from.
pub fn hours() -> u64 {
    match std::env::var("PKM_SOAK_HOURS") {
        Ok(h) => h
            .parse::<u64>()
            .ok()
            .filter(|h| *h >= 1)
            .unwrap_or_else(|| panic!("PKM_SOAK_HOURS={h}: a whole number of hours, at least 1")),
        Err(_) => 1,
    }
}

/// A joystick move at `t` (ms): released three times in ten, else anywhere.
pub fn joystick(rng: &mut Rng, t: u64) -> String {
    let (x, y) = if rng.next() < 0.3 {
        (0.0, 0.0)
    } else {
        (rng.next() * 2.0 - 1.0, rng.next() * 2.0 - 1.0)
    };
    format!(r#"{{"at_ms": {t}, "joystick": [{x:.3}, {y:.3}]}}"#)
}

/// A press of `input` at `t` (ms), released after `hold_ms`.
pub fn press(input: &str, t: u64, hold_ms: u64) -> [String; 2] {
    [
        format!(r#"{{"at_ms": {t}, "input": "{input}", "value": true}}"#),
        format!(r#"{{"at_ms": {}, "input": "{input}", "value": false}}"#, t + hold_ms),
    ]
}

/// STOP pressed (for 150 ms) again and again through `hours`, `gap` ms apart (the range). One
/// press in three starts the sequence that once sent the hexapod's re-referencing blind into its
/// limit switches: STOP, its acknowledgement a second later, STOP again 0.3 … 5 s into the new
/// referencing, and that one's acknowledgement a second later.
pub fn stop_presses(rng: &mut Rng, gap: (u64, u64), hours: u64) -> Vec<String> {
    let mut events = Vec::new();
    let mut t = 0;
    while t < hours * HOUR_MS {
        t += rng.between(gap.0, gap.1);
        events.extend(press("BUTTON_STOP", t, 150));
        if rng.next() < 1.0 / 3.0 {
            let again = t + 1_000 + 50 + rng.between(300, 5_000);
            for at in [t + 1_000, again, again + 1_000] {
                events.extend(press("BUTTON_STOP", at, 150));
            }
            t = again + 1_000;
        }
    }
    events
}

/// An injected fault.
#[derive(Clone, Copy, Debug)]
pub enum Fault<'a> {
    /// This limit or reference switch stuck on for a second.
    StuckSwitch(&'a str),
    /// This drive's counter jumps by 20 000 counts.
    CounterGlitch(&'a str),
    /// This drive's motor bridge latches an error.
    BridgeError(&'a str),
    /// This drive stops responding for two seconds.
    DeadDrive(&'a str),
}

/// The scenario events of `fault` at `t` (ms), and how long it lasts (ms; 0 for a one-off).
pub fn fault(fault: Fault<'_>, t: u64) -> (Vec<String>, u64) {
    match fault {
        Fault::StuckSwitch(s) => (
            vec![
                format!(r#"{{"at_ms": {t}, "fault": "switch_stuck", "switch": "{s}", "value": true}}"#),
                format!(r#"{{"at_ms": {}, "fault": "switch_free", "switch": "{s}"}}"#, t + 1_000),
            ],
            1_000,
        ),
        Fault::CounterGlitch(d) => (
            vec![format!(
                r#"{{"at_ms": {t}, "fault": "encoder_glitch", "drive": "{d}", "counts": 20000}}"#
            )],
            0,
        ),
        Fault::BridgeError(d) => (
            vec![format!(r#"{{"at_ms": {t}, "fault": "bridge_error", "drive": "{d}"}}"#)],
            0,
        ),
        Fault::DeadDrive(d) => (
            vec![
                format!(r#"{{"at_ms": {t}, "fault": "drive_dead", "drive": "{d}"}}"#),
                format!(r#"{{"at_ms": {}, "fault": "drive_alive", "drive": "{d}"}}"#, t + 2_000),
            ],
            2_000,
        ),
    }
}
