//! The I/O simulator as a Modbus TCP slave, driven by a Modbus client over loopback.

use crate::common;

use std::net::SocketAddr;
use std::process::Stdio;
use std::time::Duration;

use common::IoSim;

use tokio_modbus::prelude::*;

/// Starts `pkm-plc io-sim` on a free loopback port as a generic station of the TRIJOINT's
/// modules, its output watchdog off: these clients pause between writes for longer than a
/// controller would (the watchdog has tests of its own).
fn start() -> (IoSim, SocketAddr) {
    common::start_io_sim(
        "127.0.0.1:0",
        &["--watchdog-ms", "0", "--config", common::generic_busy_config()],
    )
}

/// Starts io-sim and runs `body` with a Modbus TCP client connected to it.
fn with_client(body: impl AsyncFnOnce(&mut client::Context)) {
    let (_sim, address) = start();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        let mut ctx = tcp::connect(address).await.expect("connect");
        body(&mut ctx).await;
    });
}

#[test]
fn a_modbus_client_drives_the_simulated_machine_over_tcp() {
    with_client(async |ctx| {
        // Power-on: no switch, STOP or bridge error; both counters at 125 mm × 7000 counts/mm,
        // wrapped to 16 bits.
        let inputs = ctx
            .read_discrete_inputs(0, 18)
            .await
            .expect("io")
            .expect("no exception");
        assert_eq!(inputs, vec![false; 18]);
        let counters = ctx.read_input_registers(0, 2).await.expect("io").expect("no exception");
        assert_eq!(counters, [23032, 23032]);

        // Bridges on (period 50 µs, holding register 0); the left motor (PWM02, holding register
        // 2) at full duty for 0.3 s, then off.
        ctx.write_single_register(0, 50)
            .await
            .expect("io")
            .expect("no exception");
        ctx.write_single_register(2, 32767)
            .await
            .expect("io")
            .expect("no exception");
        tokio::time::sleep(Duration::from_millis(300)).await;
        ctx.write_single_register(2, 0)
            .await
            .expect("io")
            .expect("no exception");
        let holding = ctx
            .read_holding_registers(0, 3)
            .await
            .expect("io")
            .expect("no exception");
        assert_eq!(holding, [50, 0, 0]);
        tokio::time::sleep(Duration::from_millis(300)).await;
        let counters = ctx.read_input_registers(0, 2).await.expect("io").expect("no exception");
        assert_ne!(counters[0], 23032, "the left carriage moved");
        assert_eq!(counters[1], 23032, "the right one did not");

        // A rising edge on CounterReset01 of the left counter (coil 12) zeroes it.
        ctx.write_single_coil(12, true)
            .await
            .expect("io")
            .expect("no exception");
        let counters = ctx.read_input_registers(0, 1).await.expect("io").expect("no exception");
        assert!(
            (counters[0] as i16).abs() < 100,
            "reset counter reads {}",
            counters[0] as i16
        );

        // Outside the map: an exception, not a hang.
        let beyond = ctx.read_input_registers(2, 1).await.expect("io");
        assert_eq!(beyond, Err(ExceptionCode::IllegalDataAddress));
        let beyond = ctx.write_single_coil(18, true).await.expect("io");
        assert_eq!(beyond, Err(ExceptionCode::IllegalDataAddress));
    });
}

#[test]
fn the_packed_process_image_exchanges_everything_in_one_transaction() {
    with_client(async |ctx| {
        // Output image at 8192: coils 0–15, coils 16–17, then holding registers 0–2. Set
        // CounterReset01 of the left counter (coil 12) and the PWM period (50); read the input
        // image at 4096: discrete inputs 0–15, 16–17, then both counters.
        let written = [1 << 12, 0, 50, 0, 0];
        let image = ctx
            .read_write_multiple_registers(4096, 4, 8192, &written)
            .await
            .expect("io")
            .expect("no exception");
        assert_eq!(image, [0, 0, 23032, 23032], "power-on: no switch, STOP or bridge error");
        // The modules act on the outputs when they next sample: the next exchange sees the reset.
        let image = ctx
            .read_write_multiple_registers(4096, 4, 8192, &written)
            .await
            .expect("io")
            .expect("no exception");
        assert!(
            (image[2] as i16).abs() < 100,
            "left counter reset, reads {}",
            image[2] as i16
        );
        assert_eq!(image[3], 23032, "the right counter untouched");
        // The same data through the standard tables.
        let holding = ctx
            .read_holding_registers(0, 3)
            .await
            .expect("io")
            .expect("no exception");
        assert_eq!(holding, [50, 0, 0]);
        let coils = ctx.read_coils(0, 18).await.expect("io").expect("no exception");
        let set: Vec<usize> = (0..coils.len()).filter(|&i| coils[i]).collect();
        assert_eq!(set, [12]);
        let counters = ctx.read_input_registers(0, 2).await.expect("io").expect("no exception");
        assert_eq!(counters[1], image[3]);
        // The output image reads back as written; the input image is read-only; neither
        // reaches past its end.
        let back = ctx
            .read_holding_registers(8192, 5)
            .await
            .expect("io")
            .expect("no exception");
        assert_eq!(back, written);
        let refused = ctx.write_single_register(4096, 1).await.expect("io");
        assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
        let refused = ctx.read_holding_registers(4096, 5).await.expect("io");
        assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
        let refused = ctx.write_multiple_registers(8192 + 4, &[0, 0]).await.expect("io");
        assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
    });
}

/// Real time, the TRIJOINT on a generic station with every limit as shipped: READY (40 s of
/// referencing), then a jog from the operator's screen once the machine is READY; the run ends
/// when asked.
#[test]
fn the_soft_plc_references_and_jogs_over_modbus_tcp() {
    common::host::on_a_steady_host("the_soft_plc_references_and_jogs_over_modbus_tcp", || {
        let dir = tempfile::tempdir().expect("tempdir");
        let config = common::machine_test_config(dir.path(), "trijoint");
        common::on_generic_station(&config);
        let (_sim, address) = common::start_io_sim("127.0.0.1:0", &["--config", config.to_str().expect("utf-8")]);
        let (s, t) = (dir.path().join("summary.json"), dir.path().join("trace.jsonl"));
        let mut command = common::pkm_command();
        command
            .args([
                "run",
                "--bus",
                &format!("tcp:{address}"),
                "--summary",
                s.to_str().expect("utf-8"),
            ])
            .args(["--trace", t.to_str().expect("utf-8")])
            .args(["--config", config.to_str().expect("utf-8")])
            .args(["--hmi", "127.0.0.1:0", "--joystick", "none"])
            .env("RUST_LOG", "info");
        let (mut run, url) = common::Logged::start(command, "operator screen at ", std::time::Duration::from_secs(30));
        let ready = run.wait_for_state(0, "READY", std::time::Duration::from_secs(90));
        common::screen_jog(&url, 1.0, 0.0, std::time::Duration::from_millis(1500));
        // The jog moved it, and it stands again once released.
        let moved = run.wait_for_state(ready, "MOTION", std::time::Duration::from_secs(10));
        run.wait_for_state(moved, "READY", std::time::Duration::from_secs(20));
        assert!(run.terminate().success(), "{}", run.log());
        let s = common::read_json(&s);
        assert_eq!(s["bus"], format!("tcp:{address}"));
        assert_eq!(s["main"]["state"], "READY", "{s}");
        // The jog moved the machine over the link.
        let trace = std::fs::read_to_string(&t).expect("trace");
        assert!(trace.contains(r#""state":"MOTION""#), "no MOTION in the trace");
        assert!(!trace.contains(r#""state":"ERROR""#), "an ERROR in the trace");
    })
}

#[test]
fn a_lost_link_is_a_bus_fault_without_hang() {
    let (sim, address) = start();
    let dir = tempfile::tempdir().expect("tempdir");
    let (command, s) = common::bus_fault_run(&address.to_string(), "3", dir.path());
    common::on_generic_station(&dir.path().join("busy-machine-config.json"));
    let mut run = common::start_with_link_up(command);
    drop(sim); // the station disappears
    assert!(run.wait().success(), "the run ends by itself: {}", run.log());
    let s = common::read_json(&s);
    assert_eq!(s["main"]["state"], "ERROR", "{s}");
    let reason = s["main"]["error_reason"].as_str().unwrap_or_default();
    // The first cause: the inputs stopped, with the exchange that failed first — not the
    // refused reconnections after it, which are logged. Which of the exchange's requests failed
    // first depends on where in the exchange the station vanished.
    let first_request = |text: &str, after: &str| {
        text.split(after)
            .nth(1)
            .is_some_and(|rest| rest.starts_with("read ") || rest.starts_with("write "))
    };
    assert!(
        reason.starts_with(&format!("bus fault: tcp:{address}: "))
            && (first_request(reason, "the exchanges fail since: ")
                || first_request(reason, "failed exchanges in a row, the first: ")),
        "{reason}"
    );
    assert!(
        first_request(&run.log(), "failed exchanges in a row, the first: "),
        "the fault is logged: {}",
        run.log()
    );
    assert!(
        run.log()
            .contains(", the last: cannot connect: Connection refused (os error 111)"),
        "{}",
        run.log()
    );
}

#[test]
fn the_soft_plc_exchanges_the_packed_image_over_tcp_too() {
    let (_sim, address) = start();
    // This tests the exchange, not the scheduler's timing: late cycles are logged, not an ERROR.
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::write_generic_station_config(dir.path());
    let o = common::pkm_command()
        .args(["run", "--bus", &format!("tcp:{address}"), "--exchange", "image"])
        .args(["--duration", "1", "--joystick", "none"])
        .args(["--config", config.to_str().expect("utf-8")])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .output()
        .expect("run");
    let log = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{log}");
    let report = log
        .lines()
        .find(|l| l.contains(" exchanges (image)"))
        .unwrap_or_else(|| panic!("no link report: {log}"));
    assert!(
        report.ends_with("0 timeouts, 0 corrupt, 0 exceptions, 0 disconnects, 0 stale, 0 slow"),
        "{report}"
    );
    assert!(
        log.contains("final state INIT"),
        "referencing runs over the image exchange: {log}"
    );
}

/// A joint-driven machine over Modbus TCP, in real time: the hexapod's configuration with every
/// limit as shipped (its switch searches faster) served by io-sim with its I/O map and plant.
/// READY, then a jog along +x from the operator's screen; the run ends when asked.
#[test]
fn the_hexapod_references_and_jogs_over_modbus_tcp() {
    common::host::on_a_steady_host("the_hexapod_references_and_jogs_over_modbus_tcp", || {
        let dir = tempfile::tempdir().expect("tempdir");
        let config_path = common::machine_test_config(dir.path(), "hexapod");
        let (_sim, address) = common::start_io_sim("127.0.0.1:0", &["--config", config_path.to_str().expect("utf-8")]);
        let (s, t) = (dir.path().join("summary.json"), dir.path().join("trace.jsonl"));
        let mut command = common::pkm_command();
        command
            .args(["run", "--bus", &format!("tcp:{address}")])
            .args(["--summary", s.to_str().expect("utf-8")])
            .args(["--trace", t.to_str().expect("utf-8")])
            .args(["--config", config_path.to_str().expect("utf-8")])
            .args(["--hmi", "127.0.0.1:0", "--joystick", "none"])
            .env("RUST_LOG", "info");
        let (mut run, url) = common::Logged::start(command, "operator screen at ", std::time::Duration::from_secs(30));
        let ready = run.wait_for_state(0, "READY", std::time::Duration::from_secs(90));
        common::screen_jog(&url, 1.0, 0.0, std::time::Duration::from_millis(1500));
        // The jog moved it, and it stands again once released.
        let moved = run.wait_for_state(ready, "MOTION", std::time::Duration::from_secs(10));
        run.wait_for_state(moved, "READY", std::time::Duration::from_secs(20));
        assert!(run.terminate().success(), "{}", run.log());
        let s = common::read_json(&s);
        assert_eq!(s["main"]["program"], "hexapod.main");
        assert_eq!(s["main"]["state"], "READY", "{s}");
        // The tool pose is in the summary: the jog moved the tool along +x only.
        let x = s["main"]["values"]["x"].as_f64().expect("x in the summary");
        assert!(x > 1.0, "the tool moved {x} mm along x: {s}");
        for c in ["y", "z", "a", "b", "c"] {
            let v = s["main"]["values"][c].as_f64().expect("pose in the summary");
            assert!(v.abs() < 0.05, "{c} = {v}: {s}");
        }
        let trace = std::fs::read_to_string(&t).expect("trace");
        assert!(trace.contains(r#""state":"MOTION""#), "no MOTION in the trace");
        assert!(!trace.contains(r#""state":"ERROR""#), "an ERROR in the trace");
    })
}
