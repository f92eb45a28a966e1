//! The PLC as a systemd service (`Type=notify`): a notification socket of the test's own stands
//! in for the service manager's (`NOTIFY_SOCKET`, `WATCHDOG_USEC`).

use crate::common;

use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::time::{Duration, Instant};

/// The notifications received on `socket` until `until` holds for them or `within` passes:
/// each with the time it came, since `start`.
fn receive(
    socket: &UnixDatagram,
    start: Instant,
    within: Duration,
    until: impl Fn(&[(Duration, String)]) -> bool,
) -> Vec<(Duration, String)> {
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let mut got = Vec::new();
    let mut buffer = [0u8; 4096];
    while start.elapsed() < within && !until(&got) {
        if let Ok(n) = socket.recv(&mut buffer) {
            for line in String::from_utf8_lossy(&buffer[..n]).lines() {
                got.push((start.elapsed(), line.to_string()));
            }
        }
    }
    got
}

/// A manager's socket in `dir`, and the run of `config` told about it, its watchdog at 400 ms.
fn run_notifying(dir: &Path, config: &Path, more: &[&str]) -> (UnixDatagram, common::Logged) {
    let path = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&path).expect("a notification socket");
    let mut command = common::pkm_command();
    command
        .args([
            "run",
            "--config",
            config.to_str().expect("utf-8"),
            "--joystick",
            "none",
            "--hmi",
            "none",
        ])
        .args(more)
        .env("NOTIFY_SOCKET", &path)
        .env("WATCHDOG_USEC", "400000")
        .env("RUST_LOG", "info");
    let (run, _) = common::Logged::start(command, "real time, time source", Duration::from_secs(60));
    (socket, run)
}

#[test]
fn the_service_manager_hears_ready_then_watchdog_then_stopping() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::write_realtime_config(dir.path());
    let start = Instant::now();
    let (socket, mut run) = run_notifying(dir.path(), &config, &[]);
    let got = receive(&socket, start, Duration::from_secs(60), |got| {
        got.iter().filter(|(_, m)| m == "WATCHDOG=1").count() >= 6
    });
    // The pings come at least as often as the manager's WATCHDOG_USEC (400 ms) asks: the PLC
    // sends one every half of it. Judged by their mean interval (one late read of this test's
    // own thread on a busy machine moves a single interval, not five).
    let pings: Vec<Duration> = got.iter().filter(|(_, m)| m == "WATCHDOG=1").map(|(t, _)| *t).collect();
    assert!(pings.len() >= 6, "six WATCHDOG=1 within 60 s: {got:?}");
    let mean = (pings[5] - pings[0]) / 5;
    assert!(
        mean <= Duration::from_micros(400_000),
        "WATCHDOG=1 every {mean:?} on average: the manager, at WATCHDOG_USEC=400000, would kill the service"
    );
    let messages: Vec<&str> = got.iter().map(|(_, m)| m.as_str()).collect();
    let ready = messages
        .iter()
        .position(|m| *m == "READY=1")
        .unwrap_or_else(|| panic!("no READY=1: {messages:?}\n{}", run.log()));
    let first_ping = messages.iter().position(|m| *m == "WATCHDOG=1").expect("WATCHDOG=1");
    assert!(ready < first_ping, "READY=1 first: {messages:?}");
    assert!(
        messages
            .iter()
            .any(|m| m.starts_with("STATUS=INIT") || m.starts_with("STATUS=REBOOT")),
        "the main state as the service's status: {messages:?}"
    );
    assert!(run.log().contains("service manager: READY"), "{}", run.log());
    // SIGTERM: the manager hears that the service stops.
    // SAFETY: a signal to the child this test started.
    unsafe { libc::kill(run.child.id() as i32, libc::SIGTERM) };
    let got = receive(&socket, start, Duration::from_secs(30), |got| {
        got.iter().any(|(_, m)| m == "STOPPING=1")
    });
    assert!(got.iter().any(|(_, m)| m == "STOPPING=1"), "no STOPPING=1: {got:?}");
    assert!(run.wait().success(), "{}", run.log());
}

/// One cycle of 3 s (a selftest program burning the CPU at cycle 100, 1 s in): while it hangs, no
/// WATCHDOG=1 reaches the manager (it would kill the process after its WatchdogSec); once the
/// cycles go on, the messages do too. Its cyclic thread runs at normal priority: burning 3 s at
/// SCHED_FIFO would take a core from the real-time tests running beside it.
#[test]
fn a_stalled_cycle_stops_the_watchdog_messages() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::write_config(
        dir.path(),
        "stall.json",
        &serde_json::json!({"timing": {"realtime_priority": 0, "lock_memory": false}, "task_classes": [{
            "name": "fast", "cycle_us": 10000, "tolerance_us": 10000, "priority": 1, "on_violation": "log",
            "programs": [{"program": "selftest.idle",
                          "params": {"burn_us": 3_000_000, "burn_from_cycle": 100, "burn_until_cycle": 101}}]}]}),
    );
    let start = Instant::now();
    let (socket, mut run) = run_notifying(dir.path(), &config, &["--duration", "6"]);
    // Until the stall has passed: the violation's log line, then two more pings.
    let got = receive(&socket, start, Duration::from_secs(60), |got| {
        run.log().contains("cycle 100 ended")
            && got.iter().rev().take(2).all(|(_, m)| m == "WATCHDOG=1")
            && got.iter().filter(|(_, m)| m == "WATCHDOG=1").count() >= 4
    });
    assert!(run.wait().success(), "{}", run.log());
    let pings: Vec<Duration> = got.iter().filter(|(_, m)| m == "WATCHDOG=1").map(|(t, _)| *t).collect();
    let gaps: Vec<f64> = pings.windows(2).map(|w| (w[1] - w[0]).as_secs_f64()).collect();
    let longest = gaps.iter().copied().fold(0.0, f64::max);
    assert!(
        longest >= 2.5,
        "no pause in the watchdog messages while the cycle hung 3 s: gaps {gaps:?}\n{}",
        run.log()
    );
    assert!(pings.len() >= 4, "the messages resume after the stall: {got:?}");
}
