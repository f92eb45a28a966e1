//! Joystick event decoding on fabricated captures (the byte layout of `cat /dev/input/eventN`).

use pkm_plc::services::io::joystick::codes::*;
use pkm_plc::services::io::joystick::{Command, Decoder, EVENT_SIZE, InputEvent, JoystickMapping, parse_events};
use proptest::prelude::*;

fn ev(t_ms: i64, kind: u16, code: u16, value: i32) -> InputEvent {
    InputEvent {
        time_us: t_ms * 1000,
        kind,
        code,
        value,
    }
}

fn report(t_ms: i64) -> InputEvent {
    ev(t_ms, EV_SYN, SYN_REPORT, 0)
}

/// Feeds events; returns the commands produced at each report.
fn feed(d: &mut Decoder, events: &[InputEvent]) -> Vec<Command> {
    events.iter().filter_map(|e| d.apply(e)).collect()
}

#[test]
fn records_have_the_kernel_layout_and_partial_records_wait() {
    let e = ev(1_234_567, EV_ABS, ABS_Y, -123);
    let bytes = e.to_bytes();
    assert_eq!(bytes.len(), EVENT_SIZE);
    assert_eq!(&bytes[0..8], &1234i64.to_ne_bytes(), "tv_sec");
    assert_eq!(&bytes[8..16], &567_000i64.to_ne_bytes(), "tv_usec");
    assert_eq!(InputEvent::from_bytes(&bytes), e);
    let mut stream: Vec<u8> = [e, report(1)].iter().flat_map(|e| e.to_bytes()).collect();
    stream.extend_from_slice(&bytes[..10]);
    let (events, used) = parse_events(&stream);
    assert_eq!(events, vec![e, report(1)]);
    assert_eq!(used, 2 * EVENT_SIZE);
}

#[test]
fn dead_zone_scaling_inversion_and_centre_drift() {
    let mut d = Decoder::new(JoystickMapping::default(), None);
    // A stick resting slightly off centre (1 % of full scale) is centred.
    let c = feed(
        &mut d,
        &[ev(0, EV_ABS, ABS_X, 330), ev(0, EV_ABS, ABS_Y, -300), report(0)],
    );
    assert_eq!(
        c,
        [Command {
            x: 0.0,
            y: 0.0,
            stop: false,
            buttons: [false; 4]
        }]
    );
    // Full deflection right and away from the operator: x = 1, y = +1 (y is inverted by default).
    let c = feed(
        &mut d,
        &[ev(10, EV_ABS, ABS_X, 32767), ev(10, EV_ABS, ABS_Y, -32768), report(10)],
    );
    assert!((c[0].x - 1.0).abs() < 1e-4 && (c[0].y - 1.0).abs() < 1e-4, "{c:?}");
    // Half deflection: the dead zone is taken out continuously.
    let c = feed(&mut d, &[ev(20, EV_ABS, ABS_X, -16384), report(20)]);
    let expected = -(0.5 - 0.08) / 0.92;
    assert!((c[0].x - expected).abs() < 1e-4, "{} vs {expected}", c[0].x);
    // Just outside the dead zone the output starts from 0, not from 0.08.
    let c = feed(&mut d, &[ev(30, EV_ABS, ABS_X, 2_900), report(30)]);
    assert!(c[0].x > 0.0 && c[0].x < 0.01, "{}", c[0].x);
    // Inverting x.
    let mut d = Decoder::new(
        JoystickMapping {
            invert_x: true,
            ..JoystickMapping::default()
        },
        None,
    );
    let c = feed(&mut d, &[ev(0, EV_ABS, ABS_X, 32767), report(0)]);
    assert!((c[0].x + 1.0).abs() < 1e-4);
}

#[test]
fn a_device_range_scales_the_axes() {
    let mut d = Decoder::new(JoystickMapping::default(), Some([[0, 255], [0, 255]]));
    let c = feed(
        &mut d,
        &[ev(0, EV_ABS, ABS_X, 255), ev(0, EV_ABS, ABS_Y, 128), report(0)],
    );
    assert!((c[0].x - 1.0).abs() < 1e-9 && c[0].y == 0.0, "{c:?}");
}

#[test]
fn values_change_only_at_a_report_and_a_dropped_report_stops() {
    let mut d = Decoder::new(JoystickMapping::default(), None);
    assert_eq!(feed(&mut d, &[ev(0, EV_ABS, ABS_X, 32767)]), []);
    assert_eq!(d.command().x, 0.0, "no report yet");
    feed(&mut d, &[report(0)]);
    assert!(d.command().x > 0.99);
    // The kernel dropped events: stop at once; the next full report restores the state.
    let c = feed(&mut d, &[ev(10, EV_SYN, SYN_DROPPED, 0), report(10)]);
    assert_eq!(c[0].x, 0.0);
    let c = feed(&mut d, &[ev(20, EV_ABS, ABS_X, -32768), report(20)]);
    assert!(c[0].x < -0.99);
}

#[test]
fn stop_button_edges_and_dead_man() {
    let mapping = JoystickMapping {
        stop_button: Some(BTN_TRIGGER),
        deadman_button: Some(BTN_THUMB),
        ..JoystickMapping::default()
    };
    let mut d = Decoder::new(mapping, None);
    // Deflected but the dead-man button is not held: no motion.
    let c = feed(&mut d, &[ev(0, EV_ABS, ABS_X, 32767), report(0)]);
    assert_eq!(c[0].x, 0.0);
    let c = feed(&mut d, &[ev(10, EV_KEY, BTN_THUMB, 1), report(10)]);
    assert!(c[0].x > 0.99, "held: the stick counts");
    // STOP: press, auto-repeat (ignored), release.
    let c = feed(&mut d, &[ev(20, EV_KEY, BTN_TRIGGER, 1), report(20)]);
    assert!(c[0].stop);
    let c = feed(&mut d, &[ev(30, EV_KEY, BTN_TRIGGER, 2), report(30)]);
    assert!(c[0].stop, "auto-repeat changes nothing");
    let c = feed(
        &mut d,
        &[ev(40, EV_KEY, BTN_TRIGGER, 0), ev(40, EV_KEY, BTN_THUMB, 0), report(40)],
    );
    assert!(!c[0].stop && c[0].x == 0.0, "{c:?}");
}

#[test]
fn mapping_checks() {
    let bad = JoystickMapping {
        dead_zone: 0.95,
        axis_range: [5, 5],
        y_axis: ABS_X,
        ..JoystickMapping::default()
    };
    let problems: Vec<String> = bad
        .check()
        .into_iter()
        .map(|p| format!("{}: {}", p.at, p.message))
        .collect();
    assert_eq!(
        problems,
        [
            "dead_zone: must be at least 0 and below 0.9, got 0.95",
            "axis_range: must be [min, max] with min < max, got [5, 5]",
            "y_axis: must differ from x_axis (0)",
        ]
    );
}

proptest! {
    /// Over the whole raw range: within −1…1, the sign of the deflection, and monotonic.
    #[test]
    fn outputs_are_bounded_signed_and_monotonic(a in -32768i32..=32767, b in -32768i32..=32767) {
        let mut d = Decoder::new(JoystickMapping { invert_y: false, ..JoystickMapping::default() }, None);
        let x = |d: &mut Decoder, v: i32| feed(d, &[ev(0, EV_ABS, ABS_X, v), report(0)])[0].x;
        let (xa, xb) = (x(&mut d, a), x(&mut d, b));
        prop_assert!((-1.0..=1.0).contains(&xa));
        prop_assert!(xa == 0.0 || (xa > 0.0) == (f64::from(a) > -0.5));
        if a <= b {
            prop_assert!(xa <= xb);
        }
    }
}
