//! The HID joystick in the process image: its states reach the TRIJOINT application through
//! `JoystickBus` like any input (virtual time, the simulated machine), a disconnect in the middle of
//! a motion stops M and returns to READY, a reconnect drives again, and its STOP button acts in
//! addition to the panel's. Also the raw-record reader on fabricated captures, and a capture played on
//! the simulated clock by `run --virtual --joystick FILE`.

use crate::common;

use pkm_trijoint::vars;
use std::io::Cursor;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use common::{get, state, var};
use pkm_plc::image::{Value, VarTable};
use pkm_plc::runtime::bus::NoBus;
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::VirtualClock;
use pkm_plc::services::io::hid::{End, JoystickBus, JoystickFeed, JoystickState, read_records};
use pkm_plc::services::io::joystick::codes::*;
use pkm_plc::services::io::joystick::{InputEvent, JoystickMapping};

/// Power-on to READY takes 42.6 s of simulated time.
const READY_MS: u64 = 44_000;

/// The TRIJOINT application on the simulated machine with the HID joystick laid over it.
fn build() -> (Plc, JoystickFeed) {
    let loaded = common::loaded(&common::repo_config());
    let setup = pkm_plc::compose::Setup::new(loaded.clone()).expect("known machine");
    let sim = setup.sim_bus(None).expect("sim");
    let map = setup.io_map().expect("valid map").expect("an io_map");
    let (bus, feed, _probe) = JoystickBus::new(Box::new(sim), &map);
    assert!(bus.binds_anything());
    let plc = Plc::build(
        &loaded.config,
        &pkm_plc::compose::machines::all_programs(),
        Box::new(bus),
    )
    .expect("valid");
    (plc, feed)
}

/// Virtual time that can be resumed: `advance` runs every release before `until_ms`.
struct Run {
    plc: Plc,
    clock: VirtualClock,
}

impl Run {
    fn start(mut plc: Plc) -> Run {
        let mut clock = VirtualClock::default();
        plc.init(0, &mut clock);
        Run { plc, clock }
    }

    fn advance(&mut self, until_ms: u64, mut each: impl FnMut(&Plc, u64)) {
        while self.plc.next_release() < until_ms * 1_000_000 {
            let t = self.plc.next_release();
            self.clock.advance_to(t);
            self.plc.run_due(&mut self.clock, u64::MAX);
            each(&self.plc, t / 1_000_000);
        }
    }
}

fn deflected(x: f64, y: f64) -> JoystickState {
    JoystickState {
        x,
        y,
        connected: true,
        ..JoystickState::DISCONNECTED
    }
}

fn m(plc: &Plc) -> [f64; 2] {
    [get(plc, vars::M[0]), get(plc, vars::M[1])]
}

#[test]
fn the_joystick_drives_m_a_disconnect_stops_it_and_a_reconnect_drives_again() {
    let (plc, mut feed) = build();
    let mut run = Run::start(plc);
    run.advance(READY_MS, |_, _| {});
    assert_eq!(state(&run.plc), "READY");
    // Until the joystick has published, the simulated machine's own stays: none (not
    // connected) without a scenario that uses one.
    assert_eq!(var(&run.plc, vars::JOYSTICK_CONNECTED), Value::Bool(false));

    // Full deflection to the right: MOTION, M moves in +x only.
    let start = m(&run.plc);
    feed.publish(deflected(1.0, 0.0));
    run.advance(READY_MS + 2000, |_, _| {});
    assert_eq!(state(&run.plc), "MOTION");
    let moved = m(&run.plc);
    assert!(moved[0] - start[0] > 10.0, "TOOL_X {} → {}", start[0], moved[0]);
    assert!((moved[1] - start[1]).abs() < 0.5, "TOOL_Y {} → {}", start[1], moved[1]);

    // Unplugged in the middle of the motion: the next main cycle is READY, the set-points stop.
    feed.publish(JoystickState::DISCONNECTED);
    let mut ready_at = None;
    run.advance(READY_MS + 3000, |plc, t| {
        if ready_at.is_none() && state(plc) == "READY" {
            ready_at = Some(t);
        }
        if ready_at.is_some() {
            for (side, setpoint) in ["left", "right"].into_iter().zip(vars::SETPOINT_MM_S) {
                let v = get(plc, setpoint);
                assert_eq!(v, 0.0, "{side} set-point velocity at {t} ms");
            }
        }
    });
    assert_eq!(
        ready_at,
        Some(READY_MS + 2000),
        "READY in the first main cycle after the disconnect"
    );
    assert_eq!(var(&run.plc, vars::JOYSTICK_CONNECTED), Value::Bool(false));
    assert_eq!(get(&run.plc, vars::JOYSTICK[0]), 0.0);
    let stopped = m(&run.plc);
    run.advance(READY_MS + 4000, |plc, t| {
        for (side, setpoint) in ["left", "right"].into_iter().zip(vars::SETPOINT_MM_S) {
            let v = get(plc, setpoint);
            assert_eq!(v, 0.0, "{side} set-point velocity at {t} ms");
        }
    });
    let still = m(&run.plc);
    assert!(
        (still[0] - stopped[0]).abs() < 0.05,
        "M drifted {stopped:?} → {still:?}"
    );

    // Plugged in again and pulled towards the operator (y = −1): M moves down.
    feed.publish(deflected(0.0, 0.0));
    run.advance(READY_MS + 4500, |_, _| {});
    assert_eq!(state(&run.plc), "READY", "a centred joystick does not move M");
    feed.publish(deflected(0.0, -1.0));
    run.advance(READY_MS + 6500, |_, _| {});
    assert_eq!(state(&run.plc), "MOTION");
    let down = m(&run.plc);
    assert!(still[1] - down[1] > 10.0, "TOOL_Y {} → {}", still[1], down[1]);
    assert_eq!(state(&run.plc), "MOTION");
}

#[test]
fn the_joystick_stop_acts_in_the_same_fast_cycle_in_addition_to_the_panel_stop() {
    let (plc, mut feed) = build();
    let mut run = Run::start(plc);
    run.advance(READY_MS, |_, _| {});
    feed.publish(deflected(0.6, 0.0));
    run.advance(READY_MS + 1005, |_, _| {});
    assert_eq!(state(&run.plc), "MOTION");
    feed.publish(JoystickState {
        stop: true,
        ..deflected(0.6, 0.0)
    });
    // The fast class at READY_MS + 1010 latches JOYSTICK_STOP and its interlock zeroes PWM there.
    let mut first = true;
    run.advance(READY_MS + 1200, |plc, t| {
        if first {
            first = false;
            assert_eq!(t, READY_MS + 1010);
            assert_eq!(var(plc, vars::JOYSTICK_STOP), Value::Bool(true));
            assert_eq!(var(plc, vars::INTERLOCK), Value::Bool(true), "interlock at {t} ms");
            for pwm in vars::VELOCITY_SET {
                assert_eq!(var(plc, pwm), Value::Int(0));
            }
        }
    });
    let status = run.plc.app_status().expect("status");
    assert_eq!((status.state, status.reason), ("ERROR", Some("STOP")));
}

fn ev(t_ms: i64, kind: u16, code: u16, value: i32) -> Vec<u8> {
    InputEvent {
        time_us: 1_700_000_000_000_000 + t_ms * 1000,
        kind,
        code,
        value,
    }
    .to_bytes()
    .to_vec()
}

/// A capture: at 0 ms the stick full right; at 60 ms pulled back, STOP (trigger) pressed.
fn capture() -> Vec<u8> {
    [
        ev(0, EV_ABS, ABS_X, 32767),
        ev(0, EV_SYN, SYN_REPORT, 0),
        ev(60, EV_ABS, ABS_X, 0),
        ev(60, EV_ABS, ABS_Y, 32767),
        ev(60, EV_KEY, BTN_TRIGGER, 1),
        ev(60, EV_SYN, SYN_REPORT, 0),
    ]
    .concat()
}

/// The joystick laid over no bus, with the repository's I/O map.
fn joystick_alone() -> (JoystickBus, JoystickFeed) {
    let map = common::io_map(&common::loaded(&common::repo_config()));
    let (bus, feed, _probe) = JoystickBus::new(Box::new(NoBus), &map);
    (bus, feed)
}

/// The joystick channels' values after a source read `bytes`.
fn image_after(bytes: Vec<u8>, paced: bool) -> (End, [Value; 4]) {
    let (mut bus, mut feed) = joystick_alone();
    let mut table = VarTable::new();
    pkm_plc::runtime::bus::Bus::declare(&mut bus, &mut table);
    let mut image = table.initial_image();
    let mapping = JoystickMapping {
        stop_button: Some(BTN_TRIGGER),
        ..JoystickMapping::default()
    };
    let end = read_records(Cursor::new(bytes), &mapping, paced, &mut feed, &AtomicBool::new(false));
    pkm_plc::runtime::bus::Bus::read_inputs(&mut bus, 1, 0, &mut image);
    let get = |n: &str| image[usize::from(table.index_of(n).expect("variable"))];
    (
        end,
        [
            get("JOYSTICK_X"),
            get("JOYSTICK_Y"),
            get("JOYSTICK_STOP"),
            get("JOYSTICK_CONNECTED"),
        ],
    )
}

#[test]
fn a_capture_file_is_played_at_its_pace_and_then_ends() {
    let started = Instant::now();
    let (end, values) = image_after(capture(), true);
    // A lower bound only: playing may be late on a loaded machine, never early.
    assert!(
        started.elapsed() >= Duration::from_millis(60),
        "{:?}",
        started.elapsed()
    );
    assert_eq!(end, End::CaptureEnded);
    // y is inverted by default: pulled back is −1, and the trigger is the STOP button.
    assert_eq!(
        values,
        [
            Value::Real(0.0),
            Value::Real(-1.0),
            Value::Bool(true),
            Value::Bool(true)
        ]
    );
}

#[test]
fn a_fifo_whose_writer_closes_and_a_failing_device_are_lost_links() {
    let (end, values) = image_after(capture()[..3 * 24].to_vec(), false);
    assert_eq!(end, End::Lost("the writer closed it".into()));
    // Events after the last report count for nothing.
    assert_eq!(values[0], Value::Real(1.0));

    /// A device that delivers one report and then fails as an unplugged one does.
    struct Unplugged(Cursor<Vec<u8>>);
    impl std::io::Read for Unplugged {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            match self.0.read(buf)? {
                0 => Err(std::io::Error::from_raw_os_error(19)),
                n => Ok(n),
            }
        }
    }
    let (_bus, mut feed) = joystick_alone();
    let end = read_records(
        Unplugged(Cursor::new(capture()[..2 * 24].to_vec())),
        &JoystickMapping::default(),
        false,
        &mut feed,
        &AtomicBool::new(false),
    );
    assert_eq!(end, End::Lost("No such device (os error 19)".into()));
}

/// The value of `var` in the last record of `trace` at or before `t_s`.
fn traced(trace: &std::path::Path, var: &str, t_s: f64) -> f64 {
    let mut reader = pkm_plc::services::trace::read::TraceReader::open(trace).expect("trace");
    let index = reader
        .variables()
        .iter()
        .position(|(n, _)| n == var)
        .expect("variable in the trace");
    let mut value = f64::NAN;
    while let Some(r) = reader.next_record().expect("record") {
        if r.t_us as f64 * 1e-6 > t_s {
            break;
        }
        if let Some((_, Value::Real(x))) = r.outputs.iter().chain(&r.inputs).find(|(k, _)| *k == index) {
            value = *x;
        }
    }
    value
}

#[test]
fn a_capture_file_plays_on_the_simulated_clock_in_virtual_time() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Once READY (41.6 s), the stick full right from 45 s to 47 s of the capture's time.
    let capture = dir.path().join("session.bin");
    std::fs::write(
        &capture,
        [
            ev(0, EV_ABS, ABS_X, 0),
            ev(0, EV_SYN, SYN_REPORT, 0),
            ev(45_000, EV_ABS, ABS_X, 32767),
            ev(45_000, EV_SYN, SYN_REPORT, 0),
            ev(47_000, EV_ABS, ABS_X, 0),
            ev(47_000, EV_SYN, SYN_REPORT, 0),
            ev(60_000, EV_SYN, SYN_REPORT, 0),
        ]
        .concat(),
    )
    .expect("write the capture");
    let run = |name: &str| {
        let trace = dir.path().join(name);
        let o = common::pkm(&[
            "run",
            "--virtual",
            "--duration",
            "50",
            "--joystick",
            capture.to_str().expect("utf-8"),
            "--trace",
            trace.to_str().expect("utf-8"),
        ]);
        assert_eq!(o.status.code(), Some(0), "{}", common::stderr(&o));
        trace
    };
    let (first, second) = (run("1.jsonl"), run("2.jsonl"));
    // Deterministic: the same session gives the same run, record for record.
    assert!(
        std::fs::read(&first).expect("trace") == std::fs::read(&second).expect("trace"),
        "two runs of one capture differ"
    );
    let (before, after) = (traced(&first, "TOOL_X", 44.95), traced(&first, "TOOL_X", 50.0));
    assert!(after - before > 20.0, "TOOL_X {before:.3} → {after:.3} mm");
    // The stick's deflection is in the trace at its capture time, and the run replays.
    assert_eq!(traced(&first, "JOYSTICK_X", 44.99), 0.0);
    assert_eq!(traced(&first, "JOYSTICK_X", 45.0), 1.0);
    assert_eq!(traced(&first, "JOYSTICK_X", 47.0), 0.0);
    let o = common::pkm(&["replay", first.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(0), "{}", common::stderr(&o));

    // A live source needs real time.
    let o = common::pkm(&["run", "--virtual", "--duration", "1", "--joystick", "/dev/null"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        common::stderr(&o),
        "error: --joystick /dev/null: a character device: only a regular file can be read here (in virtual time \
         --joystick plays a capture file; a device or FIFO needs real time)\n"
    );
}

/// The simulated machine has a joystick only where its scenario uses one: without, its
/// `Connected` is off (the screen then says "not connected", not "connected" for a joystick
/// nobody plugged in); a scenario that moves it has it plugged in from the start.
#[test]
fn the_simulated_machine_has_a_joystick_only_where_its_scenario_uses_one() {
    let loaded = common::loaded(&common::repo_config());
    let setup = pkm_plc::compose::Setup::new(loaded.clone()).expect("known machine");
    let dir = tempfile::tempdir().expect("tempdir");
    let scenario = dir.path().join("stick.json");
    std::fs::write(&scenario, r#"{"events": [{"at_ms": 50000, "joystick": [0.5, 0.0]}]}"#).expect("scenario");
    for (file, connected) in [(None, false), (Some(scenario.as_path()), true)] {
        let sim = setup.sim_bus(file).expect("sim");
        let plc = Plc::build(
            &loaded.config,
            &pkm_plc::compose::machines::all_programs(),
            Box::new(sim),
        )
        .expect("valid");
        let mut run = Run::start(plc);
        run.advance(1_000, |_, _| {});
        assert_eq!(get(&run.plc, vars::JOYSTICK_CONNECTED), connected, "scenario {file:?}");
    }
}
