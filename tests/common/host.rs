//! Whether the host let the soft-PLC keep its cycle. A real-time test runs the PLC as shipped: a
//! fast cycle that ends more than 10 ms past its deadline is an ERROR. The virtual machines CI
//! runs on stop now and then for tens of milliseconds as a whole (the hypervisor takes the virtual
//! CPUs, or the kernel, which preempts nothing here, runs a long path): a thread at SCHED_FIFO 99
//! pinned to a CPU, which no process of ours can delay, saw stalls of up to 15 ms there during
//! the real-time suite on an otherwise idle machine, and once all five PLCs running at that
//! moment ended the same cycle 19–27 ms late.
//!
//! Such a stall is the host's, not the PLC's; it is told from one of ours by witnesses: a thread
//! per CPU, pinned to it at SCHED_FIFO 99, that sleeps a millisecond at a time and notes every
//! wake-up more than [`STALL`] late. [`on_a_steady_host`] runs a scenario again when it failed
//! and a PLC the harness started reported a cycle time violation just after a stall of its
//! CPU's witness — and only then: every other failure, and a violation that no witness saw the
//! host cause, fails the test at once. Without real-time priority there are no witnesses (they
//! would be delayed by the very load they must tell apart) and nothing is repeated.

use std::sync::{Mutex, Once};
use std::time::{Duration, Instant};

/// The shortest host stall that can excuse a cycle time violation: the PLC's tolerance is 10 ms
/// past the deadline, so a stall of less cannot make a cycle miss it.
pub const STALL: Duration = Duration::from_millis(10);

/// How many times a scenario runs at most.
pub const ATTEMPTS: usize = 3;

/// How long after a stall ends a PLC's violation may reach the harness: the PLC logs it at the
/// end of the late cycle, and the harness reads the log at normal priority on a busy machine.
const REPORT_LAG: Duration = Duration::from_secs(2);

/// The most stalls and violations kept (the oldest are dropped; a scenario looks only at its own
/// span).
const KEPT: usize = 4096;

/// A stall a witness saw: when it ended and how long it lasted.
#[derive(Clone, Copy, Debug)]
struct Stall {
    ended: Instant,
    length: Duration,
    cpu: usize,
}

static STALLS: Mutex<Vec<Stall>> = Mutex::new(Vec::new());
static VIOLATIONS: Mutex<Vec<Instant>> = Mutex::new(Vec::new());
static WITNESSES: Once = Once::new();
static WATCHING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

fn keep<T>(list: &Mutex<Vec<T>>, item: T) {
    if let Ok(mut list) = list.lock() {
        if list.len() >= KEPT {
            list.remove(0);
        }
        list.push(item);
    }
}

/// Notes that a PLC the harness started reported a cycle time violation (from its log, as the
/// line is read).
pub fn note_log_line(line: &str) {
    if line.contains("cycle time violation") {
        note_violation();
    }
}

/// Notes that a PLC the harness runs reported a cycle time violation (one run in the test's own
/// process: its state's reason said so).
pub fn note_violation() {
    keep(&VIOLATIONS, Instant::now());
}

/// Starts the witnesses once per test binary; whether they watch (real-time priority granted).
pub fn start_witnesses() -> bool {
    WITNESSES.call_once(|| {
        // SAFETY: sysconf takes no pointer.
        let cpus = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) }.max(1) as usize;
        let (tx, rx) = std::sync::mpsc::channel();
        for cpu in 0..cpus {
            let tx = tx.clone();
            let spawned = std::thread::Builder::new()
                .name(format!("host-witness-{cpu}"))
                .spawn(move || witness(cpu, &tx));
            if spawned.is_err() {
                return;
            }
        }
        drop(tx);
        // Every witness must be pinned and at priority: a CPU without one would hide its stalls.
        let ready = rx.iter().take(cpus).filter(|ok| *ok).count();
        WATCHING.store(ready == cpus, std::sync::atomic::Ordering::SeqCst);
    });
    WATCHING.load(std::sync::atomic::Ordering::SeqCst)
}

/// One CPU's witness: pinned to `cpu` at SCHED_FIFO 99, it says whether it got there, then
/// notes every wake-up later than [`STALL`].
fn witness(cpu: usize, ready: &std::sync::mpsc::Sender<bool>) {
    // SAFETY: a zeroed cpu_set_t is an empty set; CPU_SET writes one bit of it; pid 0 is this
    // thread; both calls read the structures only for their duration.
    let pinned = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
    };
    let param = libc::sched_param { sched_priority: 99 };
    // SAFETY: pid 0 is this thread; `param` is valid for the call.
    let prioritised = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } == 0;
    let _ = ready.send(pinned && prioritised);
    if !(pinned && prioritised) {
        return;
    }
    let tick = Duration::from_millis(1);
    let mut last = Instant::now();
    loop {
        std::thread::sleep(tick);
        let now = Instant::now();
        let late = now.saturating_duration_since(last).saturating_sub(tick);
        if late >= STALL {
            keep(
                &STALLS,
                Stall {
                    ended: now,
                    length: late,
                    cpu,
                },
            );
        }
        last = now;
    }
}

/// The longest stall a witness saw that a violation reported between `from` and `to` may be
/// laid to: one that ended at most [`REPORT_LAG`] before the violation was read.
fn stall_behind_a_violation(from: Instant, to: Instant) -> Option<Stall> {
    let violations: Vec<Instant> = VIOLATIONS
        .lock()
        .map(|v| v.iter().copied().filter(|&at| at >= from && at <= to).collect())
        .unwrap_or_default();
    let stalls = STALLS.lock().map(|s| s.clone()).unwrap_or_default();
    stalls
        .into_iter()
        .filter(|stall| {
            violations
                .iter()
                .any(|&at| stall.ended <= at && at.saturating_duration_since(stall.ended) <= REPORT_LAG)
        })
        .max_by_key(|stall| stall.length)
}

/// Runs `scenario`, and runs it again (at most [`ATTEMPTS`] times in all) when it failed only
/// because the host stalled: a witness saw a stall of [`STALL`] or more and a PLC the harness
/// started reported a cycle time violation right after it. Any other failure is the test's.
/// `what` names the scenario in the line that says it is repeated.
pub fn on_a_steady_host<T>(what: &str, scenario: impl Fn() -> T) -> T {
    let watching = start_witnesses();
    let mut attempt = 1;
    loop {
        let from = Instant::now();
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(&scenario)) {
            Ok(done) => return done,
            Err(failure) => {
                let stall = if watching {
                    stall_behind_a_violation(from, Instant::now())
                } else {
                    None
                };
                match stall {
                    Some(stall) if attempt < ATTEMPTS => {
                        eprintln!(
                            "{what}: the host stalled CPU {} for {:.1} ms (its witness at SCHED_FIFO 99 \
                             woke that late) and a PLC reported a cycle time violation right after: \
                             not the PLC's doing; attempt {} of {ATTEMPTS}",
                            stall.cpu,
                            stall.length.as_secs_f64() * 1e3,
                            attempt + 1,
                        );
                        attempt += 1;
                    }
                    _ => std::panic::resume_unwind(failure),
                }
            }
        }
    }
}
