//! Link faults on Modbus TCP and RTU: garbage bytes, bad CRCs, slow responses, exception responses, a station
//! that disappears and comes back, a link too slow for the regulators. Each must become a bus fault
//! (ERROR "bus fault: LINK: CAUSE", PWM zero),
//! never a hang or a panic; a returning station brings the link back.

use crate::common;

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use common::stderr;

#[derive(Clone, Copy)]
enum Misbehaviour {
    Garbage,
    Slow,
    Exception,
    /// Well-formed frames, but a read-discrete-inputs response of 1 byte for any quantity; the
    /// other requests answered correctly (input registers zero).
    Short,
    /// Correct answers (inputs all zero), each 60 ms late: below the request timeout, so no
    /// exchange ever fails, but the inputs are always stale.
    Late,
}

/// A station that answers every request wrongly, on a free loopback port.
fn bad_station(how: Misbehaviour) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = listener.local_addr().expect("address").port();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            std::thread::spawn(move || serve_badly(stream, how));
        }
    });
    port
}

fn serve_badly(mut s: TcpStream, how: Misbehaviour) {
    let mut header = [0u8; 7];
    loop {
        // MBAP header: transaction (2), protocol (2), length (2), unit (1); then the PDU.
        if s.read_exact(&mut header).is_err() {
            return;
        }
        let len = usize::from(u16::from_be_bytes([header[4], header[5]])).saturating_sub(1);
        let mut pdu = vec![0u8; len];
        if s.read_exact(&mut pdu).is_err() {
            return;
        }
        let reply: Vec<u8> = match how {
            Misbehaviour::Garbage => vec![0xde, 0xad, 0xbe, 0xef, 0x00, 0x01, 0x02, 0x03, 0xff],
            Misbehaviour::Slow => {
                std::thread::sleep(Duration::from_millis(500));
                continue;
            }
            Misbehaviour::Exception => {
                // Exception 4 (server device failure) for the request's function.
                vec![header[0], header[1], 0, 0, 0, 3, header[6], pdu[0] | 0x80, 4]
            }
            Misbehaviour::Short | Misbehaviour::Late => {
                if matches!(how, Misbehaviour::Late) {
                    std::thread::sleep(Duration::from_millis(60));
                }
                let quantity = usize::from(u16::from_be_bytes([pdu[3], pdu[4]]));
                let body: Vec<u8> = match pdu[0] {
                    // Short: 1 byte of inputs, whatever was asked for, all eight true.
                    2 if matches!(how, Misbehaviour::Short) => vec![2, 1, 0xff],
                    2 => [vec![2, quantity.div_ceil(8) as u8], vec![0; quantity.div_ceil(8)]].concat(),
                    4 => [vec![4, (2 * quantity) as u8], vec![0; 2 * quantity]].concat(),
                    // Writes: echo address and quantity.
                    f => vec![f, pdu[1], pdu[2], pdu[3], pdu[4]],
                };
                let len = (body.len() + 1) as u16;
                [
                    vec![header[0], header[1], 0, 0],
                    len.to_be_bytes().to_vec(),
                    vec![header[6]],
                    body,
                ]
                .concat()
            }
        };
        if s.write_all(&reply).is_err() {
            return;
        }
    }
}

/// Runs the PLC against the station on `port` for `seconds`, its exchange's requests sent as
/// `requests` says (the I/O map's option); the summary, the log and the exit code (1 when no
/// exchange ever succeeded: the bus never came up).
fn run_against(port: u16, seconds: &str, requests: &str) -> (serde_json::Value, String, Option<i32>) {
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut command, summary) = common::bus_fault_run(&format!("127.0.0.1:{port}"), seconds, dir.path());
    // The bad stations imitate a generic one: the standard exchange's requests from address 0.
    let config = dir.path().join("busy-machine-config.json");
    common::on_generic_station(&config);
    common::edit_io_map(&config, |map| map["requests"] = requests.into());
    let o = command.output().expect("run");
    let s = common::read_json(&summary);
    (s, stderr(&o), o.status.code())
}

#[test]
fn garbage_slow_and_exceptional_stations_are_bus_faults() {
    // The exchange's four requests sent together (the default), and one after another where
    // the cause reads otherwise.
    for (how, name, requests) in [
        (Misbehaviour::Garbage, "garbage", "pipelined"),
        (Misbehaviour::Garbage, "garbage", "sequential"),
        (Misbehaviour::Slow, "slow", "pipelined"),
        (Misbehaviour::Slow, "slow", "sequential"),
        (Misbehaviour::Exception, "exception", "pipelined"),
        // Regression: a short response was read as "the rest are false".
        (Misbehaviour::Short, "short", "pipelined"),
        // Regression: late answers never made a bus fault.
        (Misbehaviour::Late, "late", "pipelined"),
    ] {
        let port = bad_station(how);
        let (s, log, code) = run_against(port, "2", requests);
        let sequential = requests == "sequential";
        assert_eq!(s["main"]["state"], "ERROR", "{name}: {s}");
        // A station that never answered right: the bus never came up, the run failed.
        let came_up = matches!(how, Misbehaviour::Late);
        assert_eq!(code, Some(if came_up { 0 } else { 1 }), "{name}: {log}");
        if !came_up {
            assert!(log.contains("the bus never came up: "), "{name}: {log}");
        }
        // The reason names the link and why it failed.
        let reason = s["main"]["error_reason"].as_str().unwrap_or_default();
        let cause = match how {
            Misbehaviour::Garbage if sequential => {
                "failed exchanges in a row, the last: a response to read discrete inputs 0 … 17 that could not be decoded: "
            }
            Misbehaviour::Garbage => {
                "failed exchanges in a row, the last: a response to read discrete inputs 0 … 17 and the 3 requests sent with it \
                 that could not be decoded: not a Modbus TCP header: [de, ad, be, ef, 00, 01, 02]"
            }
            Misbehaviour::Short => {
                "failed exchanges in a row, the last: a response to read discrete inputs 0 … 17 with 8 values, not the 18 asked for (another register map?)"
            }
            Misbehaviour::Slow if sequential => {
                "failed exchanges in a row, the last: no response to read discrete inputs 0 … 17 within 100 ms"
            }
            Misbehaviour::Slow => {
                "failed exchanges in a row, the last: no response to read discrete inputs 0 … 17 and the 3 requests sent \
                 with it within 100 ms"
            }
            Misbehaviour::Exception => {
                "failed exchanges in a row, the last: exception 4 (Server device failure) to read discrete inputs 0 … 17"
            }
            Misbehaviour::Late => "",
        };
        assert!(
            reason.starts_with(&format!("bus fault: tcp:127.0.0.1:{port}: ")) && reason.contains(cause),
            "{name} ({requests}): {reason}"
        );
        let logged = match how {
            Misbehaviour::Late => "the newest input image is",
            _ => "failed exchanges in a row",
        };
        assert!(log.contains(logged), "{name}: {log}");
        let counts = log
            .lines()
            .find(|l| l.contains(" exchanges (tables)"))
            .expect("link report");
        let count = |wanted: &str| -> u64 {
            counts
                .split(", ")
                .chain(counts.split("; "))
                .find_map(|part| {
                    part.strip_suffix(wanted)
                        .and_then(|p| p.rsplit(' ').next())
                        .and_then(|n| n.parse().ok())
                })
                .unwrap_or(0)
        };
        match how {
            Misbehaviour::Garbage | Misbehaviour::Short => assert!(count(" corrupt") > 3, "{name}: {counts}"),
            Misbehaviour::Slow => assert!(count(" timeouts") > 3, "{name}: {counts}"),
            Misbehaviour::Exception => assert!(count(" exceptions") > 3, "{name}: {counts}"),
            // Stale inputs first (50 ms), then too slow on average (four exchanges).
            Misbehaviour::Late => assert!(count(" stale") >= 1 && count(" slow") == 1, "{name}: {counts}"),
        }
    }
}

#[test]
fn the_link_comes_back_when_the_station_returns_but_error_stays_until_acknowledged() {
    let start = |port: u16| common::start_io_sim(&format!("127.0.0.1:{port}"), &[]);
    let (first, address) = start(0);
    let port = address.port();
    let dir = tempfile::tempdir().expect("tempdir");
    let (command, summary) = common::bus_fault_run(&format!("127.0.0.1:{port}"), "6", dir.path());
    let mut run = common::start_with_link_up(command);
    drop(first); // the station disappears...
    // ...the link says so (a bus fault: its failures past the bound)...
    let gone = Instant::now();
    while !run.log().contains("failed exchanges in a row") {
        assert!(gone.elapsed() < Duration::from_secs(30), "no bus fault: {}", run.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    let second = start(port).0; // ...and it comes back on the same port
    assert!(run.wait().success(), "{}", run.log());
    drop(second);
    let (s, log) = (common::read_json(&summary), run.log());
    assert!(log.contains("failed exchanges in a row"), "{log}");
    assert!(log.contains("the link works again"), "{log}");
    assert_eq!(s["main"]["state"], "ERROR");
    let reason = s["main"]["error_reason"].as_str().unwrap_or_default();
    assert!(
        reason.starts_with(&format!("bus fault: tcp:127.0.0.1:{port}: ")),
        "{reason}"
    );
    // The reason starts with the episode's first cause, the lost station, from the moment ERROR
    // was entered to the end — not the failures that came after it (before: "5 failed exchanges in
    // a row, the last: cannot connect: Connection refused").
    let entered = log
        .lines()
        .find_map(|l| l.split(": ERROR (").nth(1))
        .and_then(|r| r.strip_suffix(')'))
        .unwrap_or_else(|| panic!("no ERROR entry in {log}"));
    // The same, or — where the inputs went stale before any exchange had failed — the same
    // with the link's fault after it.
    assert!(reason.starts_with(entered), "{reason}\n{log}");
    assert!(
        reason.contains("the exchanges fail since: ") || reason.contains("failed exchanges in a row, the first: "),
        "the first failure is named: {reason}"
    );
}

/// A proxy in front of `upstream` that passes one request at a time on and holds every
/// response `delay` before passing it back (a slow link: an exchange's four requests take
/// 4 × `delay`). Returns its port, and the most requests a client had sent it at once: the
/// one being answered and those already waiting behind it. Its threads stand for the network
/// and run at the priority of the threads that emulate hardware where the test may
/// (`io::line::hardware_priority`): at normal priority, beside `stress-ng --cpu 2` and the
/// suite, its 0.5 ms holds grew into exchanges of 9 ms, over the 8 ms bound.
fn delaying_proxy(upstream: std::net::SocketAddr, delay: Duration) -> (u16, Arc<AtomicUsize>) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = listener.local_addr().expect("address").port();
    let most = Arc::new(AtomicUsize::new(0));
    let most_seen = Arc::clone(&most);
    std::thread::spawn(move || {
        for client in listener.incoming().flatten() {
            let most = Arc::clone(&most_seen);
            std::thread::spawn(move || {
                pkm_plc::services::io::line::hardware_priority();
                let mut client = client;
                let Ok(mut station) = TcpStream::connect(upstream) else {
                    return;
                };
                let frame = |from: &mut TcpStream| -> Option<Vec<u8>> {
                    let mut header = [0u8; 7];
                    from.read_exact(&mut header).ok()?;
                    let len = usize::from(u16::from_be_bytes([header[4], header[5]])).saturating_sub(1);
                    let mut pdu = vec![0u8; len];
                    from.read_exact(&mut pdu).ok()?;
                    Some([header.to_vec(), pdu].concat())
                };
                while let Some(request) = frame(&mut client) {
                    // Before this request is answered: how many more the client has sent.
                    let waiting = frames_waiting(&client);
                    most.fetch_max(1 + waiting, Ordering::Relaxed);
                    let Some(response) = station.write_all(&request).ok().and_then(|()| frame(&mut station)) else {
                        return;
                    };
                    std::thread::sleep(delay);
                    if client.write_all(&response).is_err() {
                        return;
                    }
                }
            });
        }
    });
    (port, most)
}

/// The complete Modbus TCP frames received on `stream` and not read yet.
fn frames_waiting(stream: &TcpStream) -> usize {
    let mut bytes = [0u8; 4096];
    let peeked = stream
        .set_nonblocking(true)
        .and_then(|()| stream.peek(&mut bytes))
        .unwrap_or(0);
    stream.set_nonblocking(false).expect("blocking again");
    let (mut at, mut frames) = (0, 0);
    while at + 7 <= peeked {
        at += 6 + usize::from(u16::from_be_bytes([bytes[at + 4], bytes[at + 5]]));
        if at <= peeked {
            frames += 1;
        }
    }
    frames
}

/// Pipelining: an exchange's four requests reach the station before its first answer, one
/// round trip for all four. With `"requests": "sequential"` in the I/O map each waits for the
/// answer before it. Both drive the X20BC0087 (its module table, watchdog and error bits read
/// on the same connection) without a fault.
#[test]
fn an_exchange_sends_its_requests_together_unless_the_map_says_one_after_another() {
    let (_sim, address) = common::start_io_sim("127.0.0.1:0", &[]);
    for (requests, together) in [("pipelined", 4), ("sequential", 1)] {
        let (port, most) = delaying_proxy(address, Duration::from_micros(500));
        let dir = tempfile::tempdir().expect("tempdir");
        let (mut command, summary) = common::bus_fault_run(&format!("127.0.0.1:{port}"), "2", dir.path());
        let config = dir.path().join("busy-machine-config.json");
        common::edit_io_map(&config, |map| map["requests"] = requests.into());
        let o = command.output().expect("run");
        let log = stderr(&o);
        assert_eq!(o.status.code(), Some(0), "{requests}: {log}");
        let s = common::read_json(&summary);
        assert_ne!(s["main"]["state"], "ERROR", "{requests}: {s}");
        assert!(!log.contains("bus fault"), "{requests}: {log}");
        assert_eq!(
            most.load(Ordering::Relaxed),
            together,
            "{requests}: requests in flight at once"
        );
    }
}

/// Regression: with 8 ms added to every response (33 ms exchanges, inputs never
/// older than the 50 ms bound) the regulators oscillated (PWM 83 %, 60 mm/s where 15 were
/// commanded) until an encoder fault stopped them with a misleading reason. The slow link is a
/// bus fault within a few exchanges, and the reason says so.
#[test]
fn a_link_slower_than_the_regulators_were_tuned_for_is_a_bus_fault_that_says_so() {
    // A generic station, as `run_against` runs the PLC on.
    let (_sim, address) = common::start_io_sim("127.0.0.1:0", &["--config", common::generic_busy_config()]);
    let (port, _) = delaying_proxy(address, Duration::from_millis(8));
    let (s, log, code) = run_against(port, "3", "pipelined");
    assert_eq!(code, Some(0), "exchanges succeeded, slowly: {log}");
    assert_eq!(s["main"]["state"], "ERROR", "{s}");
    let reason = s["main"]["error_reason"].as_str().unwrap_or_default();
    assert!(
        reason.starts_with(&format!(
            "bus fault: tcp:127.0.0.1:{port}: the link is too slow: its exchanges take "
        )) && reason.ends_with(
            " ms (the median of the last 5), over the 8 ms the drive regulators are tuned for (--max-exchange-ms)"
        ),
        "{reason}"
    );
    assert!(!log.contains("encoder fault"), "{log}");
    let slow = log
        .lines()
        .find(|l| l.contains(" exchanges (tables)"))
        .unwrap_or_default();
    assert!(slow.ends_with(", 1 slow"), "{slow}");
}

/// A station at the far end of a serial line (a socket pair, as the emulated line's ends are)
/// that answers every request with `reply(request)`, for `answers` requests, then closes its
/// end (the line vanishes; its last answer can still be read).
fn rtu_station(answers: usize, reply: fn(&[u8]) -> Vec<u8>) -> std::os::unix::net::UnixStream {
    let (mut station, plc_end) = std::os::unix::net::UnixStream::pair().expect("a socket pair");
    station.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    std::thread::spawn(move || {
        let mut buf = [0u8; 256];
        for _ in 0..answers {
            let Ok(n) = station.read(&mut buf) else { return };
            if n == 0 || station.write_all(&reply(&buf[..n])).is_err() {
                return;
            }
        }
    });
    plc_end
}

/// Runs the Modbus driver alone (no application) against `port` until it reports a bus fault.
/// Its requests wait a second for their answer (100 ms by default): the station's thread answers
/// at once, but on a busy machine it may be scheduled late, and these tests count what the
/// answers are, not how fast they come.
fn driver_against(port: std::os::unix::net::UnixStream) -> pkm_plc::services::io::modbus::ModbusBus {
    use pkm_plc::runtime::bus::Bus as _;
    let map = common::io_map(&common::loaded(&common::repo_config()));
    let options = pkm_plc::services::io::modbus::ModbusOptions {
        timeout: Duration::from_secs(1),
        ..Default::default()
    };
    let mut bus = pkm_plc::services::io::modbus::ModbusBus::new(
        map,
        pkm_plc::services::io::modbus::Transport::Stream(Some(port)),
        options,
    )
    .expect("the image fits");
    let mut table = pkm_plc::image::VarTable::new();
    bus.declare(&mut table);
    // Returns once the first image arrived or the link failed (a failing link is a bus fault,
    // not a refusal of the station).
    bus.start().expect("a generic station is not refused");
    bus
}

#[test]
fn rtu_corrupt_frames_and_a_vanished_port_are_counted_bus_faults() {
    use pkm_plc::runtime::bus::Bus as _;
    use std::sync::atomic::Ordering::Relaxed;
    // A well-formed response to the packed-image request (23) whose CRC is wrong.
    let bad_crc = |_: &[u8]| {
        let mut frame = common::rtu_frame(&[0x17, 8, 0, 0, 0, 0, 0x59, 0xF8, 0x59, 0xF8]);
        let last = frame.len() - 1;
        frame[last] ^= 0xFF;
        frame
    };
    // The failures that make the fault are corrupt frames (a request's answer may still come too
    // late now and then on a very busy machine: a timeout).
    let corrupt_fault = |bus: &pkm_plc::services::io::modbus::ModbusBus, what: &str| {
        let stats = bus.stats();
        let (corrupt, timeouts) = (stats.corrupt.load(Relaxed), stats.timeouts.load(Relaxed));
        assert!(bus.fault(), "{what}: a bus fault");
        assert!(
            corrupt >= 1 && corrupt + timeouts > 3,
            "{what}: corrupt {corrupt}, timeouts {timeouts}"
        );
        assert_eq!(stats.exchanges.load(Relaxed), 0, "{what}");
    };
    corrupt_fault(&driver_against(rtu_station(20, bad_crc)), "bad CRCs");
    // Garbage bytes.
    corrupt_fault(
        &driver_against(rtu_station(20, |_| vec![0xde, 0xad, 0xbe, 0xef, 0x00, 0x01])),
        "garbage",
    );

    // A station that answers correctly once, then its port vanishes: the driver cannot reopen
    // a line it was handed, so every reconnection fails — counted, a bus fault, no hang.
    let good = |_: &[u8]| common::rtu_frame(&[0x17, 8, 0, 0, 0, 0, 0x59, 0xF8, 0x59, 0xF8]);
    let bus = driver_against(rtu_station(1, good));
    assert!(!bus.fault(), "the first image arrived");
    let stats = bus.stats();
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    // The inputs go stale at once (a bus fault within 50 ms); the vanished port is counted when
    // the driver next tries it. Wait for both.
    while !(bus.fault() && stats.disconnects.load(Relaxed) > 0) && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(bus.fault(), "no bus fault after the port vanished");
    assert_eq!(stats.exchanges.load(Relaxed), 1);
    assert!(
        stats.disconnects.load(Relaxed) > 0,
        "disconnects: {}",
        stats.disconnects.load(Relaxed)
    );
}

#[test]
fn declaring_the_variables_opens_nothing_starting_the_bus_opens_the_link() {
    use pkm_plc::runtime::bus::Bus as _;
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    listener.set_nonblocking(true).expect("nonblocking");
    let address = listener.local_addr().expect("address");
    let map = common::io_map(&common::loaded(&common::repo_config()));
    let mut bus = pkm_plc::services::io::modbus::ModbusBus::new(
        map,
        pkm_plc::services::io::modbus::Transport::Tcp(address),
        Default::default(),
    )
    .expect("tables fit");
    let mut table = pkm_plc::image::VarTable::new();
    bus.declare(&mut table);
    // The configuration can still be refused at this point: nothing may have connected.
    assert_eq!(
        listener.accept().map(|_| ()).map_err(|e| e.kind()),
        Err(std::io::ErrorKind::WouldBlock),
        "declare connected to the station"
    );
    assert!(!bus.fault(), "a bus fault before the link was opened");
    // The station accepts (the kernel completes the handshake) but never answers: start returns
    // with a bus fault once the failures pass the bound, within the startup wait (its module
    // table unread: a station that never answers is a fault, not a refused station).
    bus.start().expect("not refused");
    assert!(listener.accept().is_ok(), "start did not connect");
    assert!(bus.fault(), "no bus fault from a station that never answers");
    bus.write_safe(&table.initial_image());
}

/// A wrong port and a missing serial device say why, and a run whose bus never came up
/// fails.
#[test]
fn a_link_that_never_comes_up_names_its_cause_and_fails_the_run() {
    // A port nobody listens on (bound, then let go).
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a port")
        .port();
    for (bus, cause) in [
        (format!("tcp:127.0.0.1:{port}"), "cannot connect: Connection refused"),
        (
            "serial:/dev/pkm-plc-no-such-port".to_string(),
            "cannot connect: No such file or directory",
        ),
    ] {
        let o = common::pkm_command()
            .args(["run", "--bus", &bus, "--duration", "1", "--hmi", "none"])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .env("RUST_LOG", "info")
            .output()
            .expect("run");
        let log = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{bus}: {log}");
        assert!(log.contains(&format!("bus fault: {bus}")), "{bus}: {log}");
        assert!(log.contains(cause), "{bus}: {log}");
        let last = log.lines().last().unwrap_or_default();
        assert!(
            last.starts_with(&format!("error: {bus}"))
                && last.contains(": the bus never came up: ")
                && last.contains(cause),
            "{bus}: {last}"
        );
    }
}
