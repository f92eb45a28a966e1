//! Scheduling behaviour: class ordering, image consistency, determinism, overruns and their
//! reactions, safe outputs, and every real-time source.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use pkm_plc::image::{Declare, Input, Output, Reader, Value, VarTable, VarType, Writer};
use pkm_plc::program::{Clock, Cycle, Program, ProgramArgs, ProgramInfo, Registry};
use pkm_plc::runtime::bus::{Bus, MailboxReader, NoBus, image_mailbox};
use pkm_plc::runtime::config::{self, Config, TimeSourceKind};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::{self, RealTimeOptions, VirtualClock};
use pkm_plc::runtime::summary::Summary;

// ---------------------------------------------------------------- test programs

/// Counts its cycles into `<name>`, counts init calls into `<name>_inits`, counts releases off the
/// cycle-time grid into `<name>_offgrid`, stamps the release it runs for into `<name>_at` (1 for
/// the release at 0, 2 for the next, ...); if `read` is set, counts the cycles in which the reader
/// did not yet see the current instant's stamp (written by a class of period `read_period_us`)
/// into `<name>_stale`. A stamp rather than a count: a release the writer skipped (a missed
/// cycle on a busy machine) makes one reader cycle stale, not every one after it.
struct Stamp {
    count: Output<i32>,
    inits: Output<i32>,
    offgrid: Output<i32>,
    stale: Output<i32>,
    at: Output<i32>,
    read: Option<(Input<i32>, u64)>,
}

#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StampParams {
    name: String,
    #[serde(default)]
    read: Option<String>,
    #[serde(default)]
    read_period_us: u64,
}

impl Stamp {
    fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p: StampParams = args.parse(decl);
        Box::new(Stamp {
            count: decl.output(&p.name, 0),
            inits: decl.output(&format!("{}_inits", p.name), 0),
            offgrid: decl.output(&format!("{}_offgrid", p.name), 0),
            stale: decl.output(&format!("{}_stale", p.name), 0),
            at: decl.output(&format!("{}_at", p.name), 0),
            read: p.read.map(|r| (decl.input(&r), p.read_period_us * 1000)),
        })
    }
}

impl Program for Stamp {
    fn init(&mut self, ctx: &mut Cycle<'_>) {
        let n = ctx.output_value(self.inits) + 1;
        ctx.set(self.inits, n);
    }
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let n = ctx.output_value(self.count) + 1;
        ctx.set(self.count, n);
        ctx.set(self.at, (ctx.time_ns() / ctx.period_ns() + 1) as i32);
        if ctx.time_ns() % ctx.period_ns() != 0 {
            let o = ctx.output_value(self.offgrid) + 1;
            ctx.set(self.offgrid, o);
        }
        if let Some((input, period)) = self.read {
            // The writer's stamp of this instant if it ran first.
            let expected = (ctx.time_ns() / period + 1) as i32;
            if ctx.get(input) != expected {
                let s = ctx.output_value(self.stale) + 1;
                ctx.set(self.stale, s);
            }
        }
    }
}

/// Reads `bus_seq` and three copies; counts torn sets into `torn` and changes into `changes`.
struct CheckSet {
    seq: Input<i32>,
    copies: [Input<i32>; 3],
    torn: Output<i32>,
    changes: Output<i32>,
    last: i32,
}

impl Program for CheckSet {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let seq = ctx.get(self.seq);
        if self.copies.iter().any(|c| ctx.get(*c) != seq) {
            let t = ctx.output_value(self.torn) + 1;
            ctx.set(self.torn, t);
        }
        if seq != self.last {
            self.last = seq;
            let c = ctx.output_value(self.changes) + 1;
            ctx.set(self.changes, c);
        }
    }
}

/// Counts its cycles into `bomb_count` and panics in the cycle `at` (from 1).
struct Bomb {
    count: Output<i32>,
    at: i32,
}

impl Program for Bomb {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let n = ctx.output_value(self.count) + 1;
        ctx.set(self.count, n);
        if n == self.at {
            let plan: Vec<f64> = Vec::new();
            panic!("boom in cycle {n}: {}", plan.len());
        }
    }
}

#[derive(Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct BombParams {
    at: i32,
}

fn registry() -> Registry {
    let mut r = pkm_plc::compose::machines::all_programs();
    r.register(ProgramInfo {
        name: "bomb",
        summary: "test: panics in a given cycle",
        factory: |args, decl| {
            let p: BombParams = args.parse(decl);
            Box::new(Bomb {
                count: decl.output("bomb_count", 0),
                at: p.at,
            })
        },
    });
    for name in ["stamp.a", "stamp.b", "stamp.c"] {
        r.register(ProgramInfo {
            name,
            summary: "test",
            factory: Stamp::create,
        });
    }
    r.register(ProgramInfo {
        name: "checkset",
        summary: "test",
        factory: |_, decl| {
            Box::new(CheckSet {
                seq: decl.input("bus_seq"),
                copies: std::array::from_fn(|i| decl.input(&format!("bus_c{}", i + 1))),
                torn: decl.output("torn", 0),
                changes: decl.output("changes", 0),
                last: 0,
            })
        },
    });
    r
}

fn parse(json: &str) -> Config {
    config::parse(json, "test.json")
        .expect("test configuration parses")
        .config
}

fn build(json: &str, bus: Box<dyn Bus>) -> Plc {
    match Plc::build(&parse(json), &registry(), bus) {
        Ok(p) => p,
        Err(issues) => panic!("test configuration is valid: {issues:#?}"),
    }
}

fn value(plc: &Plc, name: &str) -> Value {
    let i = plc
        .vars()
        .index_of(name)
        .unwrap_or_else(|| panic!("no variable {name}"));
    plc.global_image()[usize::from(i)]
}

fn dint(plc: &Plc, name: &str) -> i32 {
    match value(plc, name) {
        Value::Dint(v) => v,
        other => panic!("{name} is {other:?}"),
    }
}

fn class_stats(plc: &Plc, name: &str) -> pkm_plc::runtime::stats::ClassStats {
    plc.classes()
        .find(|c| c.name == name)
        .map(|c| c.stats.clone())
        .expect("class exists")
}

/// Reads the image before shutdown resets outputs: runs like `run_virtual` but without shutdown.
fn run_virtual_keep(plc: &mut Plc, duration_ns: u64) {
    let mut clock = VirtualClock::default();
    plc.init(0, &mut clock);
    while plc.next_release() < duration_ns {
        clock.advance_to(plc.next_release());
        plc.run_due(&mut clock, duration_ns);
    }
}

fn ordering_config(writer_priority: u8, reader_priority: u8, reader_cycle_us: u32) -> String {
    format!(
        r#"{{"task_classes": [
            {{"name": "w", "cycle_us": 10000, "tolerance_us": 10000, "priority": {writer_priority},
              "programs": [{{"program": "stamp.a", "params": {{"name": "w"}}}}]}},
            {{"name": "r", "cycle_us": {reader_cycle_us}, "tolerance_us": 10000, "priority": {reader_priority},
              "programs": [{{"program": "stamp.b", "params": {{"name": "r", "read": "w_at", "read_period_us": 10000}}}}]}}
        ]}}"#
    )
}

// ---------------------------------------------------------------- ordering

#[test]
fn the_faster_class_runs_first_when_both_are_due() {
    let mut plc = build(&ordering_config(1, 2, 50_000), Box::new(NoBus));
    run_virtual_keep(&mut plc, 1_000_000_000);
    assert_eq!(dint(&plc, "w"), 100);
    assert_eq!(dint(&plc, "r"), 20);
    // At 0, 50, 100 ms ... the 50 ms class saw the 10 ms class's output of that same instant.
    assert_eq!(dint(&plc, "r_stale"), 0);
    assert_eq!(dint(&plc, "w_inits"), 1, "init part runs once");
    assert_eq!(dint(&plc, "r_inits"), 1, "init part runs once");
    assert_eq!(dint(&plc, "w_offgrid") + dint(&plc, "r_offgrid"), 0);
}

#[test]
fn equal_cycle_times_run_in_priority_order() {
    // Reader first: it always sees the writer's value of the previous instant.
    let mut plc = build(&ordering_config(2, 1, 10_000), Box::new(NoBus));
    run_virtual_keep(&mut plc, 1_000_000_000);
    assert_eq!(dint(&plc, "r_stale"), 100);
    // Writer first: never stale.
    let mut plc = build(&ordering_config(1, 2, 10_000), Box::new(NoBus));
    run_virtual_keep(&mut plc, 1_000_000_000);
    assert_eq!(dint(&plc, "r_stale"), 0);
}

/// A bus that keeps a copy of the whole published image, so tests can look at it after a run
/// (shutdown resets the PLC's own outputs to their safe values).
struct SnoopBus(Arc<Mutex<Vec<Value>>>);

impl Bus for SnoopBus {
    fn name(&self) -> &str {
        "snoop-test"
    }
    fn declare(&mut self, _table: &mut VarTable) {}
    fn read_inputs(&mut self, _class: usize, _t_ns: u64, _image: &mut [Value]) {}
    fn write_outputs(&mut self, _class: usize, _t_ns: u64, image: &[Value]) {
        let mut last = self.0.lock().expect("lock");
        last.clear();
        last.extend_from_slice(image);
    }
    fn write_safe(&mut self, _image: &[Value]) {}
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

#[test]
fn ordering_and_the_absolute_release_grid_hold_in_real_time() {
    let last = Arc::new(Mutex::new(Vec::new()));
    let plc = build(&ordering_config(1, 2, 50_000), Box::new(SnoopBus(Arc::clone(&last))));
    let outcome = run::start_realtime(plc, rt_options(TimeSourceKind::Nanosleep, 300))
        .and_then(|r| r.join())
        .expect("real-time run");
    let w = class_stats(&outcome.plc, "w");
    let r = class_stats(&outcome.plc, "r");
    assert_eq!(w.cycles + w.missed, 30, "releases every 10 ms on the grid for 300 ms");
    assert_eq!(r.cycles + r.missed, 6);
    let image = last.lock().expect("lock").clone();
    let get = |name: &str| image[usize::from(outcome.plc.vars().index_of(name).expect("variable"))];
    // The writer ran first at every instant both were due; only a release the writer skipped
    // (a missed cycle, on a busy machine) leaves the reader its previous stamp.
    let Value::Dint(stale) = get("r_stale") else {
        panic!("r_stale is a DINT")
    };
    assert!(
        u64::try_from(stale).is_ok_and(|s| s <= w.missed),
        "{stale} stale reads, {} releases of the writer skipped",
        w.missed
    );
    assert_eq!(get("w_offgrid"), Value::Dint(0));
    assert_eq!(get("r_offgrid"), Value::Dint(0));
    assert_eq!(get("w"), Value::Dint(w.cycles as i32));
}

// ---------------------------------------------------------------- image consistency

/// A bus whose inputs are written by another thread through a mailbox, as a real bus's exchange
/// loop does.
struct ThreadedBus {
    mailbox: MailboxReader,
}

impl Bus for ThreadedBus {
    fn name(&self) -> &str {
        "threaded-test"
    }
    fn declare(&mut self, table: &mut VarTable) {
        for name in ["bus_seq", "bus_c1", "bus_c2", "bus_c3"] {
            table.declare_writer(
                name,
                VarType::Dint,
                Writer::Bus {
                    class: 0,
                    at: "test-bus".into(),
                },
                Value::Dint(0),
            );
        }
    }
    fn read_inputs(&mut self, class: usize, _t_ns: u64, image: &mut [Value]) {
        if class == 0 {
            self.mailbox.take_latest(image);
        }
    }
    fn write_outputs(&mut self, _class: usize, _t_ns: u64, _image: &[Value]) {}
    fn write_safe(&mut self, _image: &[Value]) {}
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

#[test]
fn a_cycle_never_sees_a_torn_input_set_while_the_bus_writes_concurrently() {
    let json = r#"{"task_classes": [
        {"name": "fast", "cycle_us": 10000, "tolerance_us": 10000, "priority": 1, "programs": [{"program": "checkset"}]}
    ]}"#;
    // The mailbox's slots are the bus variables' indices, known once the table is built: the
    // bus declares them first, so they are 0..4.
    let (mut writer_end, reader_end) = image_mailbox(vec![0, 1, 2, 3], vec![Value::Dint(0); 4]);
    let mut plc = build(json, Box::new(ThreadedBus { mailbox: reader_end }));
    assert_eq!(plc.vars().index_of("bus_seq"), Some(0));
    assert_eq!(plc.vars().index_of("bus_c3"), Some(3));

    let stop = Arc::new(AtomicBool::new(false));
    let published = Arc::new(AtomicU64::new(0));
    let writer = {
        let (stop, published) = (Arc::clone(&stop), Arc::clone(&published));
        std::thread::spawn(move || {
            let mut seq = 0i32;
            while !stop.load(Ordering::Relaxed) {
                seq = seq.wrapping_add(1);
                writer_end.publish(&[Value::Dint(seq); 4]);
                published.fetch_add(1, Ordering::Relaxed);
            }
        })
    };
    // Run cycles until the consumer has seen 1000 new sets, i.e. until cycles and publications
    // really interleaved 1000 times, however the threads are scheduled. The bound only keeps a
    // broken mailbox from hanging the test.
    let mut clock = VirtualClock::default();
    plc.init(0, &mut clock);
    let mut cycles = 0u64;
    while dint(&plc, "changes") < 1000 {
        assert!(cycles < 200_000_000, "the writer's sets never reached the cycles");
        clock.advance_to(plc.next_release());
        plc.run_due(&mut clock, u64::MAX);
        cycles += 1;
    }
    stop.store(true, Ordering::Relaxed);
    writer.join().expect("writer thread");
    assert!(published.load(Ordering::Relaxed) >= 1000);
    assert_eq!(dint(&plc, "torn"), 0, "torn input sets seen in {cycles} cycles");
}

#[test]
fn the_mailbox_hands_over_whole_sets_only() {
    let (mut writer, mut reader) = image_mailbox(vec![2, 0], vec![Value::Int(0), Value::Int(0)]);
    let mut image = vec![Value::Int(-1); 3];
    assert!(!reader.take_latest(&mut image), "nothing published yet");
    assert_eq!(image, vec![Value::Int(0), Value::Int(-1), Value::Int(0)]);
    writer.publish(&[Value::Int(1), Value::Int(2)]);
    writer.publish(&[Value::Int(7), Value::Int(8)]);
    assert!(reader.take_latest(&mut image));
    assert_eq!(
        image,
        vec![Value::Int(8), Value::Int(-1), Value::Int(7)],
        "the latest set, whole"
    );
    assert!(!reader.take_latest(&mut image));
    assert_eq!(image, vec![Value::Int(8), Value::Int(-1), Value::Int(7)]);
}

// ---------------------------------------------------------------- determinism

fn selftest_config(fast_tolerance_us: u32, reaction: &str, burn: &str) -> String {
    format!(
        r#"{{"task_classes": [
            {{"name": "fast", "cycle_us": 10000, "tolerance_us": {fast_tolerance_us}, "priority": 1, "on_violation": "{reaction}",
              "programs": [{{"program": "selftest.producer", "params": {burn}}}]}},
            {{"name": "main", "cycle_us": 50000, "tolerance_us": 50000, "priority": 2,
              "programs": [{{"program": "selftest.consumer"}}]}}
        ]}}"#
    )
}

#[test]
fn two_virtual_runs_give_identical_summaries_and_images() {
    let json = selftest_config(5000, "log", r#"{"burn_us": 17000, "burn_every": 97}"#);
    let run_once = || {
        let mut plc = build(&json, Box::new(NoBus));
        run_virtual_keep(&mut plc, 120_000_000_000);
        let image = plc.global_image().to_vec();
        let summary = Summary::collect(&plc, "virtual", "test.json", 120_000_000_000).to_json();
        (summary, image)
    };
    let (s1, i1) = run_once();
    let (s2, i2) = run_once();
    assert_eq!(s1, s2);
    assert_eq!(i1, i2);
    // And the runs were not trivial: overruns happened and the walk moved.
    assert!(s1.contains("\"violations\": "), "{s1}");
    let fast = serde_json::from_str::<serde_json::Value>(&s1).expect("json")["task_classes"][0].clone();
    assert!(fast["violations"].as_u64().unwrap_or(0) > 100, "{fast}");
}

// ---------------------------------------------------------------- overruns and reactions

/// Runs the self-test pair for 3 s of virtual time with a 5 ms tolerance on the 10 ms class,
/// whose cycle 100 (released at 1000 ms) burns `burn_us`.
fn one_long_cycle(reaction: &str, burn_us: u32) -> Plc {
    let params = format!(r#"{{"burn_us": {burn_us}, "burn_from_cycle": 100, "burn_until_cycle": 101}}"#);
    let mut plc = build(&selftest_config(5000, reaction, &params), Box::new(NoBus));
    run_virtual_keep(&mut plc, 3_000_000_000);
    plc
}

#[test]
fn a_violation_with_reaction_error_sends_the_application_to_error() {
    // 20 ms: the cycle ends at 1020 ms, 10 ms past its deadline, beyond the 5 ms tolerance.
    let plc = one_long_cycle("error", 20_000);
    let fast = class_stats(&plc, "fast");
    assert_eq!((fast.overruns, fast.violations, fast.missed), (1, 1, 1));
    assert_eq!(
        fast.cycles, 299,
        "the release at 1010 ms was skipped, 1020 ms ran at once"
    );
    assert_eq!(fast.exec.max_ns(), 20_000_000);
    let main = class_stats(&plc, "main");
    assert_eq!(
        main.lateness.max_ns(),
        20_000_000,
        "the main class due at 1000 ms started at 1020 ms"
    );
    let status = plc.app_status().expect("consumer reports a state");
    assert_eq!(status.state, "SELFTEST-ERROR");
    assert_eq!(status.reason, Some("cycle time violation"));
}

#[test]
fn a_violation_with_reaction_log_is_counted_only() {
    let plc = one_long_cycle("log", 20_000);
    let fast = class_stats(&plc, "fast");
    assert_eq!((fast.overruns, fast.violations), (1, 1));
    assert_eq!(plc.app_status().map(|s| s.state), Some("SELFTEST-RUN"));
}

#[test]
fn an_overrun_within_the_tolerance_is_not_a_violation() {
    // 12 ms in a 10 ms class: 2 ms past the deadline, inside the 5 ms tolerance.
    let plc = one_long_cycle("error", 12_000);
    let fast = class_stats(&plc, "fast");
    assert_eq!(
        (fast.overruns, fast.violations, fast.missed, fast.cycles),
        (1, 0, 0, 300)
    );
    assert_eq!(fast.lateness.max_ns(), 2_000_000, "the next cycle started 2 ms late");
    assert_eq!(plc.app_status().map(|s| s.state), Some("SELFTEST-RUN"));
}

#[test]
fn a_program_burning_real_time_is_detected_in_a_real_time_run() {
    let json = selftest_config(
        2000,
        "error",
        r#"{"burn_us": 25000, "burn_from_cycle": 5, "burn_until_cycle": 8}"#,
    );
    let plc = build(&json, Box::new(NoBus));
    let outcome = run::start_realtime(plc, rt_options(TimeSourceKind::Nanosleep, 400))
        .and_then(|r| r.join())
        .expect("real-time run");
    let fast = class_stats(&outcome.plc, "fast");
    assert!(fast.violations >= 3, "three 25 ms cycles in a 10 ms class: {fast:?}");
    assert!(fast.exec.max_ns() >= 25_000_000);
    let status = outcome.plc.app_status().expect("state");
    assert_eq!(
        (status.state, status.reason),
        ("SELFTEST-ERROR", Some("cycle time violation"))
    );
}

// ---------------------------------------------------------------- safe outputs and time sources

#[derive(Default)]
struct Recorded {
    last_output: Option<Value>,
    safe: Option<Value>,
}

/// A bus that takes `selftest_seq` as an output to the field and records what it was given.
struct RecordingBus(Arc<Mutex<Recorded>>);

impl Bus for RecordingBus {
    fn name(&self) -> &str {
        "recording-test"
    }
    fn declare(&mut self, table: &mut VarTable) {
        table.declare_reader(
            "selftest_seq",
            VarType::Dint,
            Reader {
                class: 0,
                who: "bus".into(),
                at: "test-bus".into(),
                needs_writer: true,
            },
        );
    }
    fn read_inputs(&mut self, _class: usize, _t_ns: u64, _image: &mut [Value]) {}
    fn write_outputs(&mut self, _class: usize, _t_ns: u64, image: &[Value]) {
        self.0.lock().expect("lock").last_output = Some(image[0]);
    }
    fn write_safe(&mut self, image: &[Value]) {
        self.0.lock().expect("lock").safe = Some(image[0]);
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

#[test]
fn shutdown_hands_safe_outputs_to_the_bus() {
    let recorded = Arc::new(Mutex::new(Recorded::default()));
    let mut plc = build(
        &selftest_config(10000, "error", "{}"),
        Box::new(RecordingBus(Arc::clone(&recorded))),
    );
    run::run_virtual(&mut plc, 1_000_000_000);
    let r = recorded.lock().expect("lock");
    assert_eq!(r.last_output, Some(Value::Dint(100)));
    assert_eq!(r.safe, Some(Value::Dint(0)));
}

#[test]
fn stopping_a_real_time_run_writes_safe_outputs() {
    let recorded = Arc::new(Mutex::new(Recorded::default()));
    let plc = build(
        &selftest_config(10000, "error", "{}"),
        Box::new(RecordingBus(Arc::clone(&recorded))),
    );
    let mut options = rt_options(TimeSourceKind::Nanosleep, 0);
    options.duration_ns = None;
    let run = run::start_realtime(plc, options).expect("start");
    while recorded
        .lock()
        .expect("lock")
        .last_output
        .is_none_or(|v| v == Value::Dint(0))
    {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    run.stop();
    let outcome = run.join().expect("join");
    assert!(class_stats(&outcome.plc, "fast").cycles > 0);
    assert_eq!(recorded.lock().expect("lock").safe, Some(Value::Dint(0)));
}

/// The self-test pair and a program of the fast class that panics in its cycle `at`.
fn bomb_config(at: i32) -> String {
    format!(
        r#"{{"task_classes": [
            {{"name": "fast", "cycle_us": 10000, "tolerance_us": 10000, "priority": 1,
              "programs": [{{"program": "selftest.producer"}}, {{"program": "bomb", "params": {{"at": {at}}}}}]}},
            {{"name": "main", "cycle_us": 50000, "tolerance_us": 50000, "priority": 2,
              "programs": [{{"program": "selftest.consumer"}}]}}
        ]}}"#
    )
}

/// A cyclic program's panic is the PLC's ERROR (service mode), as B&R's runtime makes a task's
/// exception: the reason names the program, its class, where it panicked and its message; the
/// outputs go to their safe values at once and stay there (the bus is given them); no program
/// runs again; and the run goes on to its end — the process does not exit.
#[test]
fn a_cyclic_programs_panic_is_error_with_safe_outputs_and_the_run_goes_on() {
    let recorded = Arc::new(Mutex::new(Recorded::default()));
    let mut plc = build(&bomb_config(5), Box::new(RecordingBus(Arc::clone(&recorded))));
    run_virtual_keep(&mut plc, 1_000_000_000);
    let status = plc.app_status().expect("a status");
    assert_eq!(status.state, "ERROR");
    // Where the bomb panics, as this file has it.
    let line = include_str!("scheduling.rs")
        .lines()
        .position(|l| l.trim_start().starts_with("panic!(\"boom in cycle"))
        .expect("the bomb's panic")
        + 1;
    assert_eq!(
        status.reason,
        Some(
            format!(
                "cyclic program bomb (task class fast) panicked at tests/scheduling.rs:{line}:13: boom in cycle 5: 0"
            )
            .as_str()
        )
    );
    assert!(
        status.note.is_some_and(|n| n.starts_with("service mode")),
        "{:?}",
        status.note
    );
    assert_eq!(plc.error_reason().as_deref(), status.reason);
    let service = plc.service_mode().expect("in service mode");
    assert_eq!((service.program.as_str(), service.class.as_str()), ("bomb", "fast"));
    // The producer's counter reached 5 before the panic and is safe (0) since, in the image
    // and on the bus; no program ran after (the counters stay at their safe values).
    assert_eq!(dint(&plc, "selftest_seq"), 0);
    assert_eq!(dint(&plc, "bomb_count"), 0);
    assert_eq!(dint(&plc, "selftest_checked"), 0);
    let r = recorded.lock().expect("lock");
    assert_eq!(r.safe, Some(Value::Dint(0)), "the bus was given the safe image");
    assert_eq!(
        r.last_output,
        Some(Value::Dint(0)),
        "every cycle after writes the safe value"
    );
    // The cycles went on being scheduled (the screen and OPC UA are fed from them).
    assert_eq!(class_stats(&plc, "fast").cycles, 100);
}

/// In real time too: the cyclic thread survives a program's panic, the run ends when it is
/// stopped, and its outcome reports the ERROR and why.
#[test]
fn a_real_time_run_survives_a_programs_panic() {
    let plc = build(&bomb_config(3), Box::new(NoBus));
    let options = rt_options(TimeSourceKind::Nanosleep, 300);
    let run = run::start_realtime(plc, options).expect("start");
    let outcome = run.join().expect("the cyclic thread ends normally");
    assert!(class_stats(&outcome.plc, "fast").cycles >= 10);
    let reason = outcome.plc.error_reason().expect("a reason");
    assert!(
        reason.starts_with("cyclic program bomb (task class fast) panicked at tests/scheduling.rs:"),
        "{reason}"
    );
    assert!(reason.ends_with("boom in cycle 3: 0"), "{reason}");
}

fn rt_options(source: TimeSourceKind, duration_ms: u64) -> RealTimeOptions {
    RealTimeOptions {
        source,
        realtime_priority: 0,
        lock_memory: false,
        spin_ns: 0,
        duration_ns: Some(duration_ms * 1_000_000),
        pace: None,
    }
}

#[test]
fn every_time_source_keeps_the_release_grid() {
    for source in [
        TimeSourceKind::Tokio,
        TimeSourceKind::Timerfd,
        TimeSourceKind::Nanosleep,
        TimeSourceKind::Auto,
    ] {
        for spin_ns in [0, 100_000] {
            let plc = build(&ordering_config(1, 2, 50_000), Box::new(NoBus));
            let mut options = rt_options(source, 200);
            options.spin_ns = spin_ns;
            let outcome = run::start_realtime(plc, options)
                .and_then(|r| r.join())
                .expect("real-time run");
            let w = class_stats(&outcome.plc, "w");
            assert_eq!(w.cycles + w.missed, 20, "{source:?} spin {spin_ns}: {w:?}");
            assert_eq!(outcome.source, source.resolve());
        }
    }
}

#[test]
fn the_virtual_clock_only_moves_forward() {
    let mut c = VirtualClock::default();
    c.advance_to(10);
    c.advance_to(5);
    assert_eq!(c.now_ns(), 10);
    c.burn(7);
    assert_eq!(c.now_ns(), 17);
}

#[test]
fn a_class_that_overruns_every_cycle_neither_hangs_the_run_nor_starves_the_others() {
    // Every 10 ms cycle takes 20 ms.
    let json = selftest_config(5000, "log", r#"{"burn_us": 20000}"#);
    let mut plc = build(&json, Box::new(NoBus));
    run::run_virtual(&mut plc, 2_000_000_000);
    let fast = class_stats(&plc, "fast");
    let main = class_stats(&plc, "main");
    assert_eq!(fast.cycles, 100, "one 20 ms cycle per 20 ms");
    assert_eq!(fast.violations, 100);
    assert_eq!(main.cycles, 40, "the 50 ms class still runs every release");

    // In real time, a stop request ends such a run too.
    let plc = build(&json, Box::new(NoBus));
    let mut options = rt_options(TimeSourceKind::Nanosleep, 0);
    options.duration_ns = None;
    let run = run::start_realtime(plc, options).expect("start");
    std::thread::sleep(std::time::Duration::from_millis(100));
    run.stop();
    let outcome = run.join().expect("join");
    assert!(class_stats(&outcome.plc, "main").cycles > 0);
}
