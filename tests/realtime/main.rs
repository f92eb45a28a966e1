//! The end-to-end tests that run `pkm-plc` (or its Modbus link) in real time, in one binary so
//! that they run side by side: each spends most of its time waiting on real time (a machine
//! referencing, a station's watchdog, a client's subscription), not on the CPU.
//!
//! - [`bus_controller`]: the lab's X20BC0087 as io-sim serves it.
//! - [`interop`]: against an independent Modbus implementation (pymodbus).
//! - [`io_sim`]: the I/O simulator as a Modbus TCP slave.
//! - [`joystick_fifo`]: a joystick through a FIFO.
//! - [`machines_over_modbus`]: every machine over Modbus TCP, both exchanges.
//! - [`modbus_faults`]: link faults on Modbus TCP and RTU.
//! - [`node_red`]: a Node-RED flow of 20 OPC UA nodes (node-red-contrib-opcua).
//! - [`opcua`]: the OPC UA server with Python's asyncua.
//! - [`service`]: the notifications a service manager (systemd) waits for.
//! - [`station_safety`]: what the station and the soft-PLC do when things go wrong.
//! - [`trace_cuts`]: traces that a crash cut short.
//!
//! Two kinds stay binaries of their own: the operator screen's browser tests
//! (`tests/hmi_browser.rs`, two at a time) and Modbus RTU over an emulated line
//! (`tests/modbus_rtu.rs`); beside these tests they were slowed beyond their links' limits.

#[path = "../common/mod.rs"]
mod common;

mod bus_controller;
mod interop;
mod io_sim;
mod joystick_fifo;
mod lockout;
mod machines_over_modbus;
mod modbus_faults;
mod node_red;
mod opcua;
mod screen_jobs;
mod screen_ws;
mod service;
mod simulation;
mod station_safety;
mod trace_cuts;

/// How many tests run at once unless `RUST_TEST_THREADS` or `--test-threads` says otherwise.
/// These tests wait far more than they compute: eight at once took 40 s on 2 cores where
/// libtest's default, one per core, took 2 minutes.
const TEST_THREADS: &str = "8";

/// libtest has no setting per test binary, only the environment it reads when it starts: this
/// binary sets that default before `main`, from the ELF constructors the loader runs first.
#[used]
#[unsafe(link_section = ".init_array")]
static DEFAULT_TEST_THREADS: extern "C" fn() = {
    extern "C" fn set() {
        if std::env::var_os("RUST_TEST_THREADS").is_none() {
            // SAFETY: constructors run before `main`, while the process has a single thread, so
            // nothing reads the environment meanwhile.
            unsafe { std::env::set_var("RUST_TEST_THREADS", TEST_THREADS) };
        }
    }
    set
};
