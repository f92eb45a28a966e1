//! The lab's station, an X20BC0087 bus controller, as io-sim serves it for the TRIJOINT's I/O
//! map: driven by a pymodbus client written from the public register description; refused by
//! `run` when its modules are not the map's; listed by `station scan`; and its watchdog, which
//! the soft-PLC sets and feeds only while its cycle runs.

use crate::common;

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

/// io-sim serving `config`'s map (the TRIJOINT's X20BC0087 when `None`), its log at info in `log`.
fn io_sim(config: Option<&Path>, args: &[&str], log: &Path) -> (common::IoSim, std::net::SocketAddr) {
    let mut all: Vec<&str> = args.to_vec();
    if let Some(config) = config {
        all.extend(["--config", config.to_str().expect("utf-8")]);
    }
    common::start_io_sim_logging(
        "127.0.0.1:0",
        &all,
        std::fs::File::create(log).expect("log file"),
        "info",
    )
}

#[test]
fn a_client_written_from_the_register_description_drives_io_sims_x20bc0087() {
    let python = match common::python_interop() {
        Ok(p) => p,
        Err(why) => {
            common::skip(
                "bus_controller::a_client_written_from_the_register_description_drives_io_sims_x20bc0087",
                &format!("no pymodbus: {why}"),
            );
            return;
        }
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("sim.log");
    // Its stored watchdog off: the client sets its own.
    let (sim, address) = io_sim(None, &["--node", "5", "--watchdog-ms", "0"], &log);
    let o = std::process::Command::new(&python)
        .arg(format!("{}/tests/interop/bc_client.py", env!("CARGO_MANIFEST_DIR")))
        .args([address.to_string(), "5".to_string()])
        .output()
        .expect("bc_client.py");
    drop(sim);
    let sim_log = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(
        o.status.success(),
        "{}{}\nio-sim: {sim_log}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(String::from_utf8_lossy(&o.stdout), "ok\n");
    assert!(sim_log.contains("X20BC0087 watchdog expired"), "{sim_log}");
}

#[test]
fn run_refuses_a_station_whose_di_and_do_swapped_slots_before_writing_anything() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The station: the lab's modules with DI and DO swapped on the backplane.
    let station = dir.path().join("station");
    std::fs::create_dir(&station).expect("dir");
    let station_config = common::write_realtime_config(&station);
    common::edit_io_map(&station_config, |map| {
        map["modules"][0]["slot"] = 2.into();
        map["modules"][1]["slot"] = 1.into();
    });
    let log = dir.path().join("sim.log");
    let (sim, address) = io_sim(Some(&station_config), &[], &log);
    let config = common::write_realtime_config(dir.path());
    let started = Instant::now();
    let o = common::pkm_command()
        .args([
            "run",
            "--bus",
            &format!("tcp:{address}"),
            "--duration",
            "5",
            "--joystick",
            "none",
        ])
        .args(["--config", config.to_str().expect("utf-8")])
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .output()
        .expect("run");
    let took = started.elapsed();
    drop(sim);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let expected = format!(
        "error: the X20BC0087 at tcp:{address} holds other modules than the I/O map says, so nothing is written to \
         it: slot 1: the I/O map expects X20DI9371 (ID 0x1B95, module \"DI\"), the station reports X20DO9322 (ID \
         0x1B9A); slot 2: the I/O map expects X20DO9322 (ID 0x1B9A, module \"DO\"), the station reports X20DI9371 \
         (ID 0x1B95)\n"
    );
    assert!(err.ends_with(&expected), "{err}");
    assert!(!err.contains("t=0.000 s: REBOOT"), "no cycle ran: {err}");
    assert!(
        took < Duration::from_secs(5),
        "refused at once, not at the end of the run: {took:?}"
    );
    // Nothing was written to the station: no client took its outputs.
    let sim_log = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(sim_log.contains("an X20BC0087 (node 1) with 5 modules"), "{sim_log}");
    assert!(
        !sim_log.contains("owns the outputs"),
        "the refused PLC wrote to the station: {sim_log}"
    );
}

#[test]
fn station_scan_lists_io_sims_x20bc0087_and_writes_a_map_skeleton() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (sim, address) = io_sim(None, &["--node", "12"], &dir.path().join("sim.log"));
    let map = dir.path().join("scanned.json");
    let o = common::pkm(&[
        "station",
        "scan",
        &format!("tcp:{address}"),
        "--write-map",
        map.to_str().expect("utf-8"),
    ]);
    let out = common::stdout(&o);
    assert_eq!(o.status.code(), Some(0), "{}", common::stderr(&o));
    assert!(out.starts_with(&format!("X20BC0087 at {address} (node 12)\n")), "{out}");
    assert!(
        out.contains(&format!(
            "  network: MAC 00:60:65:00:00:0c, IP 127.0.0.1 (in flash 127.0.0.1), subnet 255.0.0.0, gateway 0.0.0.0, \
             Modbus port {}\n",
            address.port()
        )),
        "{out}"
    );
    // io-sim's stored setting: its --watchdog-ms (100), any telegram feeds it.
    assert!(
        out.contains("  watchdog: 100 ms, reset by any telegram, running"),
        "{out}"
    );
    assert!(out.contains("  status 0x0000, errors: none\n"), "{out}");
    assert!(
        out.contains(
            "  process data: 5 modules; analog in 2 modules 4 B, analog out 1 modules 6 B, digital in 2 modules 3 B, \
             digital out 4 modules 5 B\n"
        ),
        "{out}"
    );
    for row in [
        "   1  0x1B95  X20DI9371                       1  0x1B95      254       none       none          0        none\n",
        "   2  0x1B9A  X20DO9322                       2  0x1B9A      254       none       none       none           0\n",
        // io-sim's map does not pin the ID: it reports 0xFFFF, which nobody takes for a module's.
        "   5  0xFFFF  no ID (io-sim)                  5  -           254       none          0          2           4\n",
    ] {
        assert!(out.contains(row), "{row:?} in {out}");
    }
    // The skeleton: the station, its modules with their IDs pinned; a module the catalogue does
    // not know has a type to be written by hand, and the map is refused until it is.
    let skeleton = common::read_json(&map);
    assert_eq!(skeleton["station"], "X20BC0087");
    assert_eq!(
        skeleton["modules"][0],
        serde_json::json!({"name": "DI9371_1", "type": "X20DI9371", "slot": 1, "id": "0x1B95"})
    );
    // No ID to pin from io-sim's stand-in; a map that pins it is refused.
    assert_eq!(skeleton["modules"][4].get("id"), None, "{skeleton}");
    let mut pinned = skeleton.clone();
    pinned["modules"][4]["type"] = "X20MM2436".into();
    pinned["modules"][4]["id"] = "0xFFFF".into();
    let classes = ["fast".to_string(), "main".to_string()];
    let text = std::fs::read_to_string(&map).expect("map");
    let refused =
        pkm_plc::services::io::map::IoMap::parse(&text, "scanned.json", &classes).expect_err("types to write");
    assert!(
        refused
            .to_string()
            .contains("at modules[2].type: unknown module type \"unknown: io-sim's map does not pin this module's ID; write its type\""),
        "{refused}"
    );
    let refused = pkm_plc::services::io::map::IoMap::parse(&pinned.to_string(), "scanned.json", &classes)
        .expect_err("io-sim's stand-in pinned");
    assert!(
        refused.to_string().contains(
            "at modules[4].id: 0xFFFF is what io-sim reports for a module whose ID its map does not pin, no module's \
             own: pin the ID the real station reports (`pkm-plc station scan`), or none"
        ),
        "{refused}"
    );
    // Written by hand, it loads, and lays the data out where the station has it.
    let mut named = skeleton.clone();
    for (i, ty) in [(2, "X20DC1196"), (3, "X20DC1196"), (4, "X20MM2436")] {
        named["modules"][i]["type"] = ty.into();
    }
    let loaded = pkm_plc::services::io::map::IoMap::parse(&named.to_string(), "scanned.json", &classes).expect("valid");
    let registers = pkm_plc::services::io::registers::RegisterMap::of(&loaded);
    let shipped = common::io_map(&common::loaded(&common::repo_config()));
    assert_eq!(
        registers.sizes(),
        pkm_plc::services::io::registers::RegisterMap::of(&shipped).sizes()
    );
    // A scan writes nothing and overwrites no map.
    let again = common::pkm(&[
        "station",
        "scan",
        &format!("tcp:{address}"),
        "--write-map",
        map.to_str().expect("utf-8"),
    ]);
    assert_eq!(again.status.code(), Some(1));
    assert!(
        common::stderr(&again).contains("exists already; the scan does not overwrite a map"),
        "{}",
        common::stderr(&again)
    );
    drop(sim);
    let refused = common::pkm(&["station", "scan", &format!("tcp:{address}"), "--timeout-ms", "500"]);
    assert_eq!(refused.status.code(), Some(1));
    assert!(
        common::stderr(&refused).starts_with(&format!("error: cannot connect to {address}: ")),
        "{}",
        common::stderr(&refused)
    );
}

/// A PLC stopped mid-run (SIGSTOP: its cycle and its link frozen, as a hung process is) no longer
/// writes; the station's watchdog, which the PLC set to 300 ms, zeroes the outputs — though
/// another client writes to the station every 20 ms meanwhile: refused (exception 6, the PLC
/// still holds the outputs), its writes do not feed the watchdog. When the PLC goes on, it sees
/// the station's "watchdog expired", goes to ERROR saying so, and resets the watchdog only after
/// that: the machine stays in ERROR until acknowledged.
#[test]
fn a_frozen_plc_lets_the_station_watchdog_stop_the_drives_and_says_so_when_it_wakes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let sim_log = dir.path().join("sim.log");
    // A watchdog of 300 ms: a busy machine's start does not trip it, the stop does.
    let config = common::write_realtime_config(dir.path());
    common::edit_io_map(&config, |map| map["watchdog_ms"] = 300.into());
    let (_sim, address) = io_sim(Some(&config), &[], &sim_log);
    let summary = dir.path().join("summary.json");
    let mut command = common::pkm_command();
    command
        .args([
            "run",
            "--bus",
            &format!("tcp:{address}"),
            "--joystick",
            "none",
            "--hmi",
            "none",
        ])
        .args(["--config", config.to_str().expect("utf-8")])
        .args(["--summary", summary.to_str().expect("utf-8")])
        // Inputs frozen for the stop are not what this is about: the station's watchdog is.
        .args(["--max-input-age-ms", "5000", "--max-exchange-ms", "1000"])
        .env("RUST_LOG", "info");
    let mut run = common::start_with_link_up(command);
    let pid = run.child.id().to_string();
    let signal = |name: &str| {
        let status = std::process::Command::new("kill")
            .args([name, &pid])
            .status()
            .expect("kill");
        assert!(status.success(), "kill {name}");
    };
    let expiries = || {
        std::fs::read_to_string(&sim_log)
            .unwrap_or_default()
            .matches("X20BC0087 watchdog expired")
            .count()
    };
    let before = expiries();
    // Another client writes an unused coil (DigitalOutput12) every 20 ms from before the PLC
    // freezes until the watchdog has expired; its answers are kept.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut s = common::modbus_connect(address);
    let other = {
        let stop = std::sync::Arc::clone(&stop);
        std::thread::spawn(move || {
            let mut answers = Vec::new();
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                answers.push(common::modbus_transact(
                    &mut s,
                    answers.len() as u16,
                    &[0x05, 0, 11, 0xFF, 0],
                ));
                std::thread::sleep(Duration::from_millis(20));
            }
            // Closed here: had its last write come after the expiry and taken the free outputs,
            // they are free again for the PLC.
            answers
        })
    };
    signal("-STOP");
    // The station's watchdog acts within its 300 ms; waited for in its log.
    let deadline = Instant::now() + Duration::from_secs(20);
    while expiries() == before {
        assert!(
            Instant::now() < deadline,
            "the station's watchdog never expired (another client writing every 20 ms)"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let answers = other.join().expect("the other client");
    // It wrote while the PLC was frozen (300 ms at least: 15 writes), and was refused while
    // the PLC held the outputs; a write that came after the expiry, when they were free, may
    // have been carried out.
    let refused = answers.iter().take_while(|a| a.as_slice() == [0x85, 0x06]).count();
    assert!(refused >= 5, "{answers:?}");
    assert!(answers[refused..].iter().all(|a| a[0] == 0x05), "{answers:?}");
    signal("-CONT");
    run.wait_for(0, "the X20BC0087's watchdog reset", Duration::from_secs(30))
        .unwrap_or_else(|| panic!("the PLC never reset the station's watchdog:\n{}", run.log()));
    assert!(run.terminate().success(), "{}", run.log());
    let s = common::read_json(&summary);
    assert_eq!(s["main"]["state"], "ERROR", "{s}");
    assert_eq!(
        s["main"]["error_reason"],
        format!("bus fault: tcp:{address}: the X20BC0087 reports watchdog expired"),
        "{s}"
    );
    let log = run.log();
    assert!(
        log.contains(&format!(
            "modbus tcp:{address}: bus fault: the X20BC0087 reports watchdog expired"
        )),
        "{log}"
    );
    assert!(
        std::fs::read_to_string(&sim_log)
            .unwrap_or_default()
            .contains("X20BC0087 watchdog reset by a client"),
        "the PLC reset the station's watchdog"
    );
}

/// The link writes only what the cycle hands over: when the cycle stops handing outputs over (a
/// hung cycle) while the link thread goes on, the link only reads, and the station's watchdog —
/// fed by writes only, as the soft-PLC sets it — zeroes the outputs.
#[test]
fn a_cycle_that_stops_handing_outputs_over_stops_feeding_the_station_watchdog() {
    use pkm_plc::runtime::bus::Bus as _;
    let dir = tempfile::tempdir().expect("tempdir");
    // A watchdog of 1 s and outputs written while under 1 s old: a busy machine delays neither
    // that long.
    let config = common::write_realtime_config(dir.path());
    common::edit_io_map(&config, |map| map["watchdog_ms"] = 1000.into());
    let sim_log = dir.path().join("sim.log");
    let (_sim, address) = io_sim(Some(&config), &[], &sim_log);
    let loaded = pkm_plc::runtime::config::load(Some(&config)).expect("the configuration");
    let map = common::io_map(&loaded);
    let options = pkm_plc::services::io::modbus::ModbusOptions {
        max_input_age: Duration::from_millis(500),
        timeout: Duration::from_secs(1),
        ..Default::default()
    };
    let mut bus = pkm_plc::services::io::modbus::ModbusBus::new(
        map,
        pkm_plc::services::io::modbus::Transport::Tcp(address),
        options,
    )
    .expect("tables");
    let mut table = pkm_plc::image::VarTable::new();
    bus.declare(&mut table);
    bus.start().expect("the station is the map's");
    let image = table.initial_image();
    // The cycle runs for a second: the watchdog is fed.
    let fed = Instant::now();
    while fed.elapsed() < Duration::from_secs(1) {
        bus.write_outputs(0, 0, &image);
        std::thread::sleep(Duration::from_millis(10));
    }
    let read = |path: &Path| std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        !read(&sim_log).contains("watchdog expired"),
        "fed, yet expired: {}",
        read(&sim_log)
    );
    let exchanges = |bus: &pkm_plc::services::io::modbus::ModbusBus| {
        bus.stats().exchanges.load(std::sync::atomic::Ordering::Relaxed)
    };
    let before = exchanges(&bus);
    // The cycle hangs: no more outputs. The station's watchdog acts after the outputs' 1 s of
    // age and its own 1 s.
    let deadline = Instant::now() + Duration::from_secs(30);
    while !read(&sim_log).contains("X20BC0087 watchdog expired") {
        assert!(
            Instant::now() < deadline,
            "the station's watchdog never expired: {}",
            read(&sim_log)
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(exchanges(&bus) > before, "the link went on reading the inputs");
    // The link reads the station's error bits: a bus fault that names the watchdog, and it stays
    // (the link does not reset the station's watchdog while no outputs come).
    let deadline = Instant::now() + Duration::from_secs(10);
    let cause = || {
        let mut cause = String::new();
        bus.write_fault_cause(&mut cause);
        cause
    };
    while !(bus.fault() && cause().contains("the X20BC0087 reports watchdog expired")) {
        assert!(
            Instant::now() < deadline,
            "no bus fault from the expired watchdog: {}",
            cause()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    assert!(bus.fault(), "the fault stands while the cycle hands no outputs over");
    bus.write_safe(&image);
}

/// A station that answers as an X20BC0087 from a module table it is given, and counts the
/// write requests it gets (their function codes): a bus controller that lies, served on
/// loopback by a thread of the test.
struct LyingStation {
    address: std::net::SocketAddr,
    writes: std::sync::Arc<std::sync::Mutex<Vec<u8>>>,
}

impl LyingStation {
    fn start(table: Vec<pkm_plc::services::io::x20bc0087::ModuleRecord>) -> LyingStation {
        use pkm_plc::services::io::x20bc0087::MODULE_TABLE;
        use std::io::{Read, Write};
        let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        let address = listener.local_addr().expect("address");
        let writes = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let seen = writes.clone();
        let words: Vec<u16> = table.iter().flat_map(|r| r.to_words()).collect();
        std::thread::spawn(move || {
            for stream in listener.incoming() {
                let Ok(mut stream) = stream else { return };
                let (words, seen) = (words.clone(), seen.clone());
                std::thread::spawn(move || {
                    let mut head = [0u8; 7];
                    while stream.read_exact(&mut head).is_ok() {
                        let len = usize::from(u16::from_be_bytes([head[4], head[5]]));
                        let mut pdu = vec![0u8; len.saturating_sub(1)];
                        if stream.read_exact(&mut pdu).is_err() || pdu.is_empty() {
                            return;
                        }
                        let field = |i: usize| u16::from_be_bytes([pdu[i], pdu[i + 1]]);
                        let reply: Vec<u8> = match pdu[0] {
                            // Reads: the module table where it lies, zero elsewhere.
                            3 | 4 => {
                                let (start, count) = (field(1), field(3));
                                let mut r = vec![pdu[0], (count * 2) as u8];
                                for a in start..start.saturating_add(count) {
                                    let w = a
                                        .checked_sub(MODULE_TABLE)
                                        .and_then(|i| words.get(usize::from(i)))
                                        .copied()
                                        .unwrap_or(0);
                                    r.extend(w.to_be_bytes());
                                }
                                r
                            }
                            1 | 2 => {
                                let count = field(3);
                                let mut r = vec![pdu[0], count.div_ceil(8) as u8];
                                r.resize(2 + usize::from(count.div_ceil(8)), 0);
                                r
                            }
                            // Writes: counted, and answered as carried out.
                            5 | 6 | 15 | 16 => {
                                seen.lock().unwrap_or_else(|p| p.into_inner()).push(pdu[0]);
                                pdu[..5].to_vec()
                            }
                            f => vec![f | 0x80, 1],
                        };
                        let mut frame = head[..4].to_vec();
                        frame.extend(((reply.len() + 1) as u16).to_be_bytes());
                        frame.push(head[6]);
                        frame.extend(reply);
                        if stream.write_all(&frame).is_err() {
                            return;
                        }
                    }
                });
            }
        });
        LyingStation { address, writes }
    }

    fn writes(&self) -> Vec<u8> {
        self.writes.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// A station whose table puts a counter's word at an odd byte index (a register split in two)
/// is refused before anything is written to it — its watchdog's setting and reset are writes,
/// and used to come before this refusal, whose message says nothing was written.
#[test]
fn run_refuses_a_station_whose_analog_data_lies_at_an_odd_byte_before_writing_anything() {
    use pkm_plc::services::io::registers::RegisterMap;
    use pkm_plc::services::io::x20bc0087::expected_modules;
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::write_realtime_config(dir.path());
    let loaded = common::loaded(&common::read_json(&config));
    let map = common::io_map(&loaded);
    let registers = RegisterMap::of(&map);
    let mut table: Vec<_> = expected_modules(&map, &registers).iter().map(|m| m.record()).collect();
    // The right counter's word at byte 3: it would straddle registers 1 and 2.
    table[3].analog_in = 3;
    let station = LyingStation::start(table);
    let o = common::pkm_command()
        .args([
            "run",
            "--bus",
            &format!("tcp:{}", station.address),
            "--duration",
            "5",
            "--joystick",
            "none",
        ])
        .args(["--config", config.to_str().expect("utf-8")])
        .stdout(Stdio::null())
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.ends_with(&format!(
            "error: the X20BC0087 at tcp:{} assigns data the soft-PLC cannot address, so nothing is written to it: slot 4: \
             the station puts the module's analog data at byte index 3, which is odd: registers are two bytes each\n",
            station.address
        )),
        "{err}"
    );
    assert_eq!(
        station.writes(),
        Vec::<u8>::new(),
        "write requests (function codes) the refused station got"
    );
}

/// A station whose module table lists 253 modules where its own count says none, all of one
/// serial number: `station scan` reports what it read, warns of each contradiction, and writes
/// no map from it (it used to write a 253-module map without a word).
#[test]
fn station_scan_writes_no_map_from_a_station_that_contradicts_itself() {
    use pkm_plc::services::io::x20bc0087::{MAX_MODULES, ModuleRecord, NO_DATA};
    let record = ModuleRecord {
        status: 1,
        id: 0x1B95,
        serial: 7,
        analog_in: NO_DATA,
        analog_out: NO_DATA,
        digital_in: 0,
        digital_out: NO_DATA,
        configured_id: 0x1B95,
        function_model: 254,
        ..ModuleRecord::default()
    };
    let station = LyingStation::start(vec![record; usize::from(MAX_MODULES)]);
    let dir = tempfile::tempdir().expect("tempdir");
    let map = dir.path().join("scanned.json");
    let o = common::pkm(&[
        "station",
        "scan",
        &format!("tcp:{}", station.address),
        "--write-map",
        map.to_str().expect("utf-8"),
    ]);
    let err = common::stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        common::stdout(&o).contains(" 253  0x1B95  X20DI9371"),
        "the report lists what was read"
    );
    let address = station.address;
    for line in [
        format!(
            "warning: station {address}: the station says it holds 0 modules (register 0x1100), its module table lists 253\n"
        ),
        format!(
            "warning: station {address}: slot 1: its digital input data at byte 0 lies beyond the 0 bytes of digital inputs the station reports\n"
        ),
        format!("warning: station {address}: slots 1 and 2 report the same serial number, 7\n"),
    ] {
        assert!(err.contains(&line), "{line:?} in {err}");
    }
    assert!(
        err.contains("scanned.json: not written: the station's answers contradict each other ("),
        "{err}"
    );
    assert!(!map.exists(), "no map is written");
    assert_eq!(station.writes(), Vec::<u8>::new(), "a scan only reads");
}
