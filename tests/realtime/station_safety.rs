//! What the station (io-sim) and the soft-PLC do when things go wrong: malformed
//! frames are answered, never fatal; the output watchdog stops the drives when the controller
//! dies without a safe stop; terminating signals other than SIGINT/SIGTERM stop the PLC safely;
//! io-sim bounds its clients and summarises repeated errors.

use crate::common;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::Stdio;
use std::time::{Duration, Instant};

use common::IoSim;

/// Starts io-sim on a free loopback port with `args`, as a generic station of the TRIJOINT's
/// modules (these tests address its layout and its own watchdog); its log goes to `log`.
fn io_sim(args: &[&str], log: &std::path::Path) -> (IoSim, SocketAddr) {
    let args = [args, &["--config", common::generic_busy_config()]].concat();
    common::start_io_sim_logging(
        "127.0.0.1:0",
        &args,
        std::fs::File::create(log).expect("log file"),
        "info",
    )
}

use common::{modbus_connect as connect, modbus_transact as transact};

/// The station's holding registers 0..3 (PWM period, PWM left, PWM right) through the image
/// read-back, on a raw connection; reads never feed the watchdog.
fn outputs(s: &mut TcpStream) -> [u16; 3] {
    let r = transact(s, 7, &[0x03, 0, 0, 0, 3]);
    assert_eq!(r[..2], [0x03, 6], "{r:?}");
    [0, 1, 2].map(|i| u16::from_be_bytes([r[2 + 2 * i], r[3 + 2 * i]]))
}

/// Polls the station until `done(outputs)` or `limit` passes; returns the time it took.
fn until(s: &mut TcpStream, limit: Duration, done: impl Fn([u16; 3]) -> bool) -> Option<Duration> {
    let start = Instant::now();
    while start.elapsed() < limit {
        if done(outputs(s)) {
            return Some(start.elapsed());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

#[test]
fn malformed_requests_are_answered_with_exceptions_and_io_sim_keeps_serving() {
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("io-sim.log");
    let (mut sim, address) = io_sim(&[], &log);
    let mut s = connect(address);
    // The frame that panicked tokio-modbus 0.17's decoder: write 16 coils with 1 byte of data.
    assert_eq!(transact(&mut s, 1, &[0x0F, 0, 0, 0, 16, 1, 0xFF]), [0x8F, 0x03]);
    // Quantities that overflow when doubled, an unknown function, a truncated read.
    assert_eq!(transact(&mut s, 2, &[0x10, 0, 0, 0x80, 0, 0]), [0x90, 0x03]);
    assert_eq!(transact(&mut s, 3, &[0x41, 1, 2]), [0xC1, 0x01]);
    assert_eq!(transact(&mut s, 4, &[0x04, 0, 0]), [0x84, 0x03]);
    // The same connection still serves a good request.
    assert_eq!(transact(&mut s, 5, &[0x04, 0, 0, 0, 1])[..2], [0x04, 2]);

    // 2000 random well-framed PDUs on 20 connections: every one answered.
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut random = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for c in 0..20 {
        let mut s = connect(address);
        for i in 0..100 {
            let len = 1 + (random() % 40) as usize;
            let mut pdu: Vec<u8> = (0..len).map(|_| random() as u8).collect();
            // Mostly the functions with counts, where decoders go wrong.
            pdu[0] = [0x0F, 0x10, 0x17, 0x01, 0x03, random() as u8][(random() % 6) as usize];
            let r = transact(&mut s, (c * 100 + i) as u16, &pdu);
            assert!(r[0] == pdu[0] || r[0] == pdu[0] | 0x80, "{pdu:02x?} -> {r:02x?}");
        }
    }
    assert!(sim.0.try_wait().expect("status").is_none(), "io-sim is still running");
    drop(sim);
    let log = std::fs::read_to_string(&log).expect("log");
    // Repeats are summarised: a handful of lines, not one per frame.
    assert!(log.lines().count() < 20, "{} log lines:\n{log}", log.lines().count());
    assert!(log.contains("malformed request"), "{log}");
    assert!(!log.contains("panicked"), "{log}");
}

#[test]
fn a_malformed_rtu_frame_is_answered_and_io_sim_serial_keeps_serving() {
    use serialport::SerialPort as _;
    let (mut master, slave) = pkm_plc::services::io::line::pty_pair().expect("a pseudo-terminal pair");
    let path = slave.name().expect("the pty's path");
    master.set_timeout(Duration::from_secs(10)).expect("timeout");
    let mut sim = IoSim(
        common::pkm_command()
            .args(["io-sim", "--serial", &path])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("io-sim starts"),
    );
    let frame = common::rtu_frame;
    let ask = |master: &mut serialport::TTYPort, pdu: &[u8], answer_len: usize| {
        master.write_all(&frame(pdu)).expect("send");
        let mut answer = vec![0u8; answer_len];
        master.read_exact(&mut answer).expect("answer");
        answer
    };
    // io-sim opens the pty when it starts; a request before that is lost, so ask until answered.
    let start = Instant::now();
    master.set_timeout(Duration::from_millis(200)).expect("timeout");
    loop {
        master.write_all(&frame(&[0x04, 0, 0, 0, 1])).expect("send");
        let mut answer = [0u8; 7];
        if master.read_exact(&mut answer).is_ok() {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "io-sim --serial never answered"
        );
    }
    // Late answers to the earlier attempts, if any.
    let mut stale = [0u8; 64];
    while master.read(&mut stale).is_ok_and(|n| n > 0) {}
    master.set_timeout(Duration::from_secs(10)).expect("timeout");
    assert_eq!(ask(&mut master, &[0x0F, 0, 0, 0, 16, 1, 0xFF], 5), frame(&[0x8F, 0x03]));
    // Still serving: read one input register.
    assert_eq!(ask(&mut master, &[0x04, 0, 0, 0, 1], 7)[..3], [1, 0x04, 2]);
    assert!(
        sim.0.try_wait().expect("status").is_none(),
        "io-sim --serial is still running"
    );
}

#[test]
fn the_output_watchdog_zeroes_the_outputs_when_writes_stop() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_sim, address) = io_sim(&["--watchdog-ms", "100"], &dir.path().join("log"));
    let mut s = connect(address);
    // A controller's write: bridges on, both motors at 10 %.
    assert_eq!(
        transact(&mut s, 1, &[0x10, 0, 0, 0, 3, 6, 0, 50, 0x0C, 0xCD, 0x0C, 0xCD])[0],
        0x10
    );
    assert_eq!(outputs(&mut s), [50, 3277, 3277]);
    // No more writes: the watchdog acts, reads do not keep the outputs alive.
    let took = until(&mut s, Duration::from_secs(10), |o| o == [0, 0, 0]).expect("the watchdog acted");
    eprintln!("outputs zero {} ms after the last write", took.as_millis());
    // The next write takes the outputs over again.
    assert_eq!(transact(&mut s, 2, &[0x06, 0, 0, 0, 50])[0], 0x06);
    assert_eq!(outputs(&mut s)[0], 50);
}

/// Starts the soft-PLC against the station at `address` (real time), output to `log`, the
/// link's bounds as shipped.
fn plc_against(address: SocketAddr, log: &std::path::Path) -> common::KillOnDrop {
    run_logging(&["--bus", &format!("tcp:{address}")], log)
}

/// Starts `pkm-plc run` with `args` on the generic station's configuration (unless `args` give
/// one), its log (at info) going to `log`.
fn run_logging(args: &[&str], log: &std::path::Path) -> common::KillOnDrop {
    let config: &[&str] = if args.contains(&"--config") {
        &[]
    } else {
        &["--config", common::generic_busy_config()]
    };
    common::KillOnDrop(
        common::pkm_command()
            .arg("run")
            .args(args)
            .args(config)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(log).expect("log file"))
            .spawn()
            .expect("run starts"),
    )
}

/// Waits until the PLC drives a motor at the station (INIT's switch search starts at once); its
/// log (`log`) says why if it does not.
fn until_driving(s: &mut TcpStream, log: &std::path::Path) {
    let driving = |o: [u16; 3]| o[0] != 0 && (o[1] != 0 || o[2] != 0);
    if until(s, Duration::from_secs(30), driving).is_none() {
        panic!(
            "the PLC does not drive the motors after 30 s; its log:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
    }
}

/// The bound on how long after a PLC's death the station's outputs are zero in these tests: the
/// connection's close zeroes them at once (5 ms measured, polled every 5 ms); a second is far
/// beyond what a busy machine adds, and far below "never", which is what is left without that
/// close when the watchdog is off.
const ZERO_WITHIN: Duration = Duration::from_secs(1);

/// A killed PLC leaves the drives to the station: its connection closes with it and the station
/// zeroes the outputs at once. The station's watchdog is off, so that only the close can do it
/// (with it, the watchdog would after 100 ms: a cut cable).
#[test]
fn a_killed_plc_leaves_the_drives_to_the_station() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_sim, address) = io_sim(&["--watchdog-ms", "0"], &dir.path().join("sim.log"));
    let log = dir.path().join("plc.log");
    let mut plc = plc_against(address, &log);
    let mut s = connect(address);
    until_driving(&mut s, &log);
    plc.kill().expect("SIGKILL");
    plc.wait().expect("reaped");
    let took = until(&mut s, Duration::from_secs(10), |o| o == [0, 0, 0]).expect("outputs zero after SIGKILL");
    eprintln!("outputs zero {} ms after SIGKILL", took.as_millis());
    assert!(took < ZERO_WITHIN, "outputs zero only {took:?} after SIGKILL");
}

/// A second client cannot keep a dead controller's drives running: while the PLC owns the
/// outputs, another client's write (an unused coil, every 20 ms) is refused with exception 6;
/// when the PLC is killed its connection closes and every output goes to zero at once, and the
/// other client's writes do not bring the PWM back.
#[test]
fn only_the_controller_feeds_the_watchdog_and_its_death_zeroes_the_outputs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_sim, address) = io_sim(&[], &dir.path().join("sim.log"));
    // The watchdog is on here (100 ms): the other client's writes must not feed it.
    let log = dir.path().join("plc.log");
    let mut plc = plc_against(address, &log);
    let mut s = connect(address);
    until_driving(&mut s, &log);
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (tx, answers) = std::sync::mpsc::channel::<Vec<u8>>();
    let feeder = {
        let stop = std::sync::Arc::clone(&stop);
        std::thread::spawn(move || {
            let mut other = connect(address);
            let mut t = 100;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                // Write single coil 11 (DigitalOutput12, bound to nothing) on.
                if tx.send(transact(&mut other, t, &[0x05, 0, 11, 0xFF, 0])).is_err() {
                    break;
                }
                t = t.wrapping_add(1);
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };
    // The other client's writes are refused while the PLC drives.
    let first = answers.recv_timeout(Duration::from_secs(10)).expect("an answer");
    assert_eq!(
        first,
        [0x85, 0x06],
        "another client's write while the PLC owns the outputs"
    );
    plc.kill().expect("SIGKILL");
    plc.wait().expect("reaped");
    let took = until(&mut s, Duration::from_secs(10), |o| o == [0, 0, 0]).expect("outputs zero after SIGKILL");
    eprintln!(
        "outputs zero {} ms after SIGKILL, another client writing",
        took.as_millis()
    );
    assert!(took < ZERO_WITHIN, "outputs zero only {took:?} after SIGKILL");
    // The other client takes the outputs with its coil once the PLC is gone; the PWM stays zero.
    let mut taken = false;
    while !taken {
        let answer = answers.recv_timeout(Duration::from_secs(10)).expect("an answer");
        taken = answer[0] == 0x05;
    }
    for _ in 0..20 {
        let _ = answers.recv_timeout(Duration::from_secs(10)).expect("an answer");
        assert_eq!(outputs(&mut s), [0, 0, 0], "the drives were left running");
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    drop(answers);
    feeder.join().expect("the other client");
}

/// A station that accepts connections and closes them at once (full, or not Modbus) is tried
/// again with back-off, not thousands of times a second.
#[test]
fn a_plc_reconnects_with_back_off() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
    let address = listener.local_addr().expect("address");
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("plc.log");
    let bus = format!("tcp:{address}");
    let mut plc = run_logging(&["--bus", &bus, "--hmi", "none", "--duration", "5"], &log);
    listener.set_nonblocking(true).expect("non-blocking");
    let mut accepted = 0;
    while plc.try_wait().expect("status").is_none() {
        match listener.accept() {
            Ok((c, _)) => {
                accepted += 1;
                drop(c);
            }
            Err(_) => std::thread::sleep(Duration::from_millis(1)),
        }
    }
    // 50 ms doubling to 2 s: about ten attempts in five seconds (and the start's wait).
    eprintln!("{accepted} connections in the PLC's 5 s");
    assert!((2..=25).contains(&accepted), "{accepted} connection attempts");
}

#[test]
fn hangup_quit_user_power_and_limit_signals_stop_the_plc_safely() {
    // The ones a probe found ending the PLC with PWM up to 34 % and the spindle on among them.
    for (signal, name) in [
        (libc::SIGHUP, "SIGHUP"),
        (libc::SIGQUIT, "SIGQUIT"),
        (libc::SIGUSR1, "SIGUSR1"),
        (libc::SIGPWR, "SIGPWR"),
        (libc::SIGXCPU, "SIGXCPU"),
        (libc::SIGVTALRM, "SIGVTALRM"),
        (libc::SIGPROF, "SIGPROF"),
        (libc::SIGIO, "SIGIO"),
        (libc::SIGSYS, "SIGSYS"),
    ] {
        let dir = tempfile::tempdir().expect("tempdir");
        // No watchdog: only the PLC's own safe stop can zero the outputs.
        let (_sim, address) = io_sim(&["--watchdog-ms", "0"], &dir.path().join("sim.log"));
        let log = dir.path().join("plc.log");
        let mut plc = plc_against(address, &log);
        let mut s = connect(address);
        until_driving(&mut s, &log);
        // SAFETY: kill(2) on a child process we own and have not reaped.
        assert_eq!(unsafe { libc::kill(plc.id() as i32, signal) }, 0);
        let status = plc.wait().expect("the PLC exits");
        let log = std::fs::read_to_string(&log).expect("log");
        assert_eq!(status.code(), Some(0), "{name}: {log}");
        assert!(log.contains(&format!("{name}: stopping")), "{name}: {log}");
        assert_eq!(outputs(&mut s), [0, 0, 0], "{name}: outputs after the stop");
        // The PLC confirmed them: an exchange after the safe outputs succeeded.
        assert!(log.contains("the safe outputs reached the station"), "{name}: {log}");
    }
}

/// A PLC whose station is gone when it stops says that the safe outputs could not be confirmed,
/// and what the station must do instead.
#[test]
fn safe_outputs_that_cannot_reach_the_station_are_said_so() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (sim, address) = io_sim(&["--watchdog-ms", "0"], &dir.path().join("sim.log"));
    let log = dir.path().join("plc.log");
    let mut plc = plc_against(address, &log);
    let mut s = connect(address);
    until_driving(&mut s, &log);
    drop(s);
    drop(sim);
    // SAFETY: kill(2) on a child process we own and have not reaped.
    assert_eq!(unsafe { libc::kill(plc.id() as i32, libc::SIGTERM) }, 0);
    plc.wait().expect("the PLC exits");
    let log = std::fs::read_to_string(&log).expect("log");
    assert!(
        log.contains("the safe outputs could not be confirmed at the station: no exchange succeeded within"),
        "{log}"
    );
    assert!(!log.contains("the safe outputs reached the station"), "{log}");
}

/// Waits until `log` has a line containing `text` (the process writes it), or `limit` passes.
fn until_logged(log: &std::path::Path, text: &str, limit: Duration) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if std::fs::read_to_string(log).is_ok_and(|l| l.contains(text)) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

/// Every signal the PLC handles (the named ones and SIGRTMIN … SIGRTMAX) ends a running PLC
/// through the safe stop with exit code 0; SIGPIPE, which Rust ignores, does not end it.
#[test]
fn every_terminating_signal_ends_the_plc_through_the_safe_stop() {
    let dir = tempfile::tempdir().expect("tempdir");
    let signals = pkm_plc::runtime::signals::handled();
    // A few at a time: each is a real-time PLC (without field I/O or screen).
    for (batch, chunk) in signals.chunks(8).enumerate() {
        let started: Vec<(common::KillOnDrop, std::path::PathBuf, &(String, i32))> = chunk
            .iter()
            .enumerate()
            .map(|(k, signal)| {
                let log = dir.path().join(format!("{batch}-{k}.log"));
                let child = run_logging(
                    &[
                        "--bus",
                        "none",
                        "--hmi",
                        "none",
                        "--joystick",
                        "none",
                        "--duration",
                        "300",
                    ],
                    &log,
                );
                (child, log, signal)
            })
            .collect();
        for (mut child, log, (name, number)) in started {
            assert!(
                until_logged(&log, "running in real time", Duration::from_secs(60)),
                "{name}: the PLC did not start: {}",
                std::fs::read_to_string(&log).unwrap_or_default()
            );
            if batch == 0 {
                // SIGPIPE first: ignored, the PLC runs on.
                // SAFETY: kill(2) on a child process we own and have not reaped.
                assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGPIPE) }, 0);
            }
            // SAFETY: as above.
            assert_eq!(unsafe { libc::kill(child.id() as i32, *number) }, 0);
            let status = child.wait().expect("the PLC exits");
            let text = std::fs::read_to_string(&log).expect("log");
            assert_eq!(status.code(), Some(0), "{name} ({number}): {status:?}\n{text}");
            assert!(
                text.contains(&format!(
                    "{name}: stopping after the current cycle, outputs to safe values"
                )),
                "{name}: {text}"
            );
        }
    }
}

#[test]
fn io_sim_bounds_its_clients_and_stops_on_sigterm() {
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("log");
    let (mut sim, address) = io_sim(&["--max-connections", "2", "--idle-timeout-s", "1"], &log);
    let mut a = connect(address);
    let _b = connect(address);
    assert_eq!(transact(&mut a, 1, &[0x04, 0, 0, 0, 1])[0], 0x04);
    // A third client is closed as it connects.
    let mut c = connect(address);
    let mut byte = [0u8; 1];
    assert!(
        matches!(c.read(&mut byte), Ok(0) | Err(_)),
        "the third client was served"
    );
    // An idle client is disconnected after the idle time; the server goes on.
    let mut buf = [0u8; 1];
    assert!(
        matches!(a.read(&mut buf), Ok(0) | Err(_)),
        "the idle client stays connected"
    );
    let mut d = connect(address);
    assert_eq!(transact(&mut d, 2, &[0x04, 0, 0, 0, 1])[0], 0x04);
    // SAFETY: kill(2) on a child process we own and have not reaped.
    assert_eq!(unsafe { libc::kill(sim.0.id() as i32, libc::SIGTERM) }, 0);
    let status = sim.0.wait().expect("io-sim exits");
    assert_eq!(status.code(), Some(0));
    let log = std::fs::read_to_string(&log).expect("log");
    assert!(log.contains("connection refused"), "{log}");
    assert!(log.contains("idle client disconnected"), "{log}");
    assert!(log.contains("SIGTERM: stopping"), "{log}");
}
