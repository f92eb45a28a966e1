//! The cyclic code allocates nothing. An allocation in a cycle takes the allocator's lock,
//! which a thread at normal priority may hold while it waits for a CPU (priority inversion),
//! and may map memory, which waits for the process's memory map: either can make a cycle late
//! by far more than its own work. Here every machine runs as shipped on its simulated plant,
//! with the screen's inputs: referenced from power-on, its first shipped program run to its
//! end, jogged, the program started again and stopped (ERROR), acknowledged — and every pass
//! over the due task classes is counted by the allocator, which counts only on the thread that
//! runs the passes and only while it does.
//!
//! A trace recorder is not in these runs: it allocates a buffer when its writer has not handed
//! the last ones back yet, which in virtual time (cycles back to back) it never has; in real time
//! its pool of buffers suffices (the RTU runs report `0 extra buffers`).
//!
//! A binary of its own: the counting allocator is the process's.

#[path = "common/mod.rs"]
mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use pkm_plc::compose::{self, Built, Options};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::VirtualClock;
use pkm_plc::services::hmi::commands::{CommandSink, press};

/// The system's allocator, counting the allocations of the thread that runs a pass.
struct Counting;

thread_local! {
    /// Set while this thread runs a pass over the due classes.
    static IN_A_PASS: Cell<bool> = const { Cell::new(false) };
    /// Set while the allocator notes an allocation (which allocates itself).
    static NOTING: Cell<bool> = const { Cell::new(false) };
}

/// Allocations made in passes.
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);
/// Where the first allocation in a pass was made (a backtrace).
static FIRST: Mutex<Option<String>> = Mutex::new(None);

fn note_allocation() {
    if !IN_A_PASS.with(Cell::get) || NOTING.with(Cell::get) {
        return;
    }
    NOTING.with(|n| n.set(true));
    if ALLOCATIONS.fetch_add(1, Ordering::Relaxed) == 0 {
        let trace = std::backtrace::Backtrace::force_capture().to_string();
        if let Ok(mut first) = FIRST.lock() {
            *first = Some(trace);
        }
    }
    NOTING.with(|n| n.set(false));
}

// SAFETY: every call is passed on to the system's allocator unchanged; the counting touches
// only thread-locals, an atomic and (once, outside any allocation of its own) a mutex.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_allocation();
        // SAFETY: the caller's contract is System's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_allocation();
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_allocation();
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// A machine in virtual time with the screen's inputs.
struct Run {
    machine: &'static str,
    plc: Plc,
    clock: VirtualClock,
    screen: CommandSink,
    /// The states seen, in order.
    seen: Vec<String>,
}

impl Run {
    /// Runs passes until the main state has left whatever it is now and become `state` (at
    /// most `max_s` of simulated time); each pass counted.
    fn until_next(&mut self, state: &str, max_s: u64) {
        let end = self.plc.next_release() + max_s * 1_000_000_000;
        let mut left = false;
        loop {
            let now = common::state(&self.plc).to_string();
            if self.seen.last() != Some(&now) {
                self.seen.push(now.clone());
            }
            left |= now != state;
            if left && now == state {
                return;
            }
            assert!(
                self.plc.next_release() < end,
                "{}: not {state} within {max_s} s: {:?}, reason {:?}",
                self.machine,
                self.seen,
                self.plc.app_status().and_then(|s| s.reason)
            );
            let t = self.plc.next_release();
            self.clock.advance_to(t);
            IN_A_PASS.with(|p| p.set(true));
            self.plc.run_due(&mut self.clock, u64::MAX);
            IN_A_PASS.with(|p| p.set(false));
        }
    }
}

#[test]
fn no_cycle_of_any_machine_allocates_from_power_on_through_a_program_a_jog_and_an_error() {
    let mut counted = Vec::new();
    for machine in common::MACHINES {
        let loaded = match machine {
            "trijoint" => common::loaded(&common::repo_config()),
            _ => common::machine_config(machine, |_| {}),
        };
        let setup = compose::Setup::new(loaded).unwrap_or_else(|e| panic!("{machine}: {e}"));
        let options = Options {
            hmi: true,
            programs: Some(common::root().join("programs")),
            ..Options::default()
        };
        let Built { plc, hmi, .. } = compose::build(setup, options).unwrap_or_else(|e| panic!("{machine}: {e}"));
        let mut run = Run {
            machine,
            plc,
            clock: VirtualClock::default(),
            screen: hmi.expect("the screen's inputs"),
            seen: Vec::new(),
        };
        // Before the first cycle (in a real-time run, before the schedule starts).
        run.plc.init(0, &mut run.clock);
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        // Referenced from power-on; the first shipped program (loaded at start) run to its end.
        run.until_next("READY", 300);
        run.screen.update(|c| c.presses[press::NC[0]] += 1);
        run.until_next("AUTO", 5);
        run.until_next("READY", 600);
        // Jogged along +x for as long as it takes to start moving, then let go.
        run.screen.update(|c| c.jog = [1.0, 0.0]);
        run.until_next("MOTION", 5);
        run.screen.update(|c| c.jog = [0.0, 0.0]);
        run.until_next("READY", 30);
        // The program again, stopped on its way: ERROR, and READY once acknowledged.
        run.screen.update(|c| c.presses[press::NC[0]] += 1);
        run.until_next("AUTO", 5);
        run.screen.update(|c| c.presses[press::STOP] += 1);
        run.until_next("ERROR", 5);
        // Acknowledged: READY, after referencing again where the machine asks for it (pn101).
        run.screen.update(|c| c.acknowledgements += 1);
        run.until_next("READY", 300);
        let made = ALLOCATIONS.load(Ordering::Relaxed) - before;
        counted.push(format!(
            "{machine}: {made} in {} cycles, {:?}",
            run.plc.classes().map(|c| c.stats.cycles).sum::<u64>(),
            run.seen
        ));
    }
    let first = FIRST.lock().map(|f| f.clone()).unwrap_or_default();
    assert_eq!(
        ALLOCATIONS.load(Ordering::Relaxed),
        0,
        "allocations in the cycles: {counted:#?}\nthe first:\n{}",
        first.unwrap_or_default()
    );
    eprintln!("no allocation in any cycle: {counted:#?}");
}
