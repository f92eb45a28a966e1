//! Drivers that move a [`Plc`] through time: virtual (as fast as the CPU allows, deterministic)
//! and real (a dedicated cyclic thread waiting on absolute deadlines).

use std::io;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracing::{info, warn};

// A snapshot keeps room for every value a main program may show (no allocation, no cut).

use crate::program::Clock;
use crate::runtime::config::TimeSourceKind;
use crate::runtime::plc::Plc;
use crate::runtime::snapshot::Snapshot;
use crate::runtime::timing::{self, MonotonicClock};

/// Simulated time: `now` only moves when the driver advances it or a program burns time.
#[derive(Clone, Copy, Debug, Default)]
pub struct VirtualClock {
    now_ns: u64,
}

impl VirtualClock {
    /// Moves the clock forward to `t_ns` (never backwards).
    pub fn advance_to(&mut self, t_ns: u64) {
        self.now_ns = self.now_ns.max(t_ns);
    }
}

impl Clock for VirtualClock {
    fn now_ns(&mut self) -> u64 {
        self.now_ns
    }
    fn burn(&mut self, ns: u64) {
        self.now_ns += ns;
    }
}

/// The log target of the machine's state changes and notes ([`StateLog`]): the log's budget
/// always lets them pass (`log_limit`), their rate being the automaton's, not a peer's.
pub const STATE_LOG_TARGET: &str = module_path!();

/// Logs the main program's state changes (with the error reason) and its notes to the operator
/// (a refused program start, what INIT waits for), at the time they happen. Only a change
/// formats anything, so it costs nothing in steady operation.
#[derive(Debug, Default)]
struct StateLog {
    last: String,
    note: String,
    /// [`Plc::status_seq`] when the state was last looked at: until it changes, the state has
    /// not (comparing the state's texts after every pass took a tenth of a simulated hour).
    seen: Option<u64>,
}

impl StateLog {
    fn observe(&mut self, plc: &Plc, t_ns: u64) {
        let seq = plc.status_seq();
        if self.seen == Some(seq) {
            return;
        }
        self.seen = Some(seq);
        let Some(status) = plc.app_status() else { return };
        if status.state != self.last {
            match plc.error_reason() {
                Some(reason) => warn!("t={:.3} s: {} ({reason})", t_ns as f64 * 1e-9, status.state),
                None => info!("t={:.3} s: {}", t_ns as f64 * 1e-9, status.state),
            }
            self.last.clear();
            self.last.push_str(status.state);
        }
        let note = status.note.unwrap_or("");
        if note != self.note {
            if !note.is_empty() {
                info!("t={:.3} s: note: {note}", t_ns as f64 * 1e-9);
            }
            self.note.clear();
            self.note.push_str(note);
        }
    }
}

/// What a virtual-time run reports besides the PLC's own statistics.
#[derive(Clone, Copy, Debug)]
pub struct VirtualReport {
    /// Simulated time covered (ns).
    pub simulated_ns: u64,
    /// Wall-clock time the run took.
    pub wall: Duration,
}

/// Runs the PLC in virtual time for `duration_ns` of simulated time: every release before
/// `duration_ns` is run. Ends with [`Plc::shutdown`].
pub fn run_virtual(plc: &mut Plc, duration_ns: u64) -> VirtualReport {
    run_virtual_observed(plc, duration_ns, &mut |_, _| {})
}

/// [`run_virtual`], with `observe` called after each pass with its time (ns; off the cycles' own
/// time: virtual time waits for it).
pub fn run_virtual_observed(plc: &mut Plc, duration_ns: u64, observe: &mut dyn FnMut(&Plc, u64)) -> VirtualReport {
    let started = Instant::now();
    let mut clock = VirtualClock::default();
    let mut log = StateLog::default();
    plc.init(0, &mut clock);
    loop {
        let t = plc.next_release();
        if t >= duration_ns {
            break;
        }
        clock.advance_to(t);
        plc.run_due(&mut clock, duration_ns);
        log.observe(plc, t);
        observe(plc, t);
    }
    plc.shutdown();
    VirtualReport {
        simulated_ns: duration_ns,
        wall: started.elapsed(),
    }
}

/// A paced simulation's schedule: simulated time `t` is due at `anchor_wall + (t − anchor_t) /
/// pace` on the wall clock. A machine that cannot keep up (a pass more than a second late) is
/// said once, and the schedule is anchored again where it is: the simulation goes on at its
/// pace from there rather than racing to catch up.
#[derive(Default)]
struct Behind {
    /// The wall-clock time (ns, monotonic) and the simulated time it is anchored at; `None`:
    /// at the run's epoch and 0.
    anchor: Option<(u64, u64)>,
    said: bool,
}

impl Behind {
    /// When the pass at simulated time `t` is due (ns, monotonic).
    fn due(&self, epoch_ns: u64, t: u64, pace: f64) -> u64 {
        let (wall, t0) = self.anchor.unwrap_or((epoch_ns, 0));
        wall + (t.saturating_sub(t0) as f64 / pace) as u64
    }

    /// Takes the pass at simulated time `t`, due at `due` and started at `now` (ns, monotonic).
    fn check(&mut self, now: u64, due: u64, t: u64) {
        let late_ns = now.saturating_sub(due);
        if late_ns > 1_000_000_000 {
            if !self.said {
                self.said = true;
                warn!(
                    "the simulation fell {:.1} s behind its pace at t={:.1} s: this computer cannot simulate the machine that fast (a lower --pace keeps up); it goes on at its pace from here",
                    late_ns as f64 / 1e9,
                    t as f64 / 1e9
                );
            }
            self.anchor = Some((now, t));
        }
    }
}

/// How a real-time run is set up.
#[derive(Clone, Copy, Debug)]
pub struct RealTimeOptions {
    /// The timer to wait on.
    pub source: TimeSourceKind,
    /// SCHED_FIFO priority for the cyclic thread; 0 does not ask.
    pub realtime_priority: u8,
    /// Lock the process's memory first.
    pub lock_memory: bool,
    /// Busy-wait the last `spin_ns` before each release (0: none).
    pub spin_ns: u64,
    /// Stop after this much time (ns; simulated time when paced); `None` runs until
    /// [`RealTimeRun::stop`].
    pub duration_ns: Option<u64>,
    /// A simulation paced at this many times real time (1 … 50): the cycles run in virtual
    /// time — each at its release exactly, as `--virtual` runs them, deterministic and never
    /// late — and the thread waits between them so that simulated time passes this much faster
    /// than the wall clock. `None`: real time.
    pub pace: Option<f64>,
}

/// Why a real-time run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The timer could not be created or waited on.
    #[error("time source {source_name}: {error}")]
    Timer {
        /// The time source.
        source_name: &'static str,
        /// The OS error.
        error: io::Error,
    },
    /// The cyclic thread could not be started.
    #[error("cannot start the cyclic thread: {0}")]
    Thread(io::Error),
    /// The cyclic thread panicked (a bug).
    #[error("the cyclic thread panicked: {0}")]
    Panicked(String),
    /// The bus refused its station before any output was written (modules not the I/O map's).
    #[error("{0}")]
    StationRefused(String),
}

/// The result of a real-time run.
pub struct RealTimeOutcome {
    /// The PLC, with its statistics, after shutdown.
    pub plc: Plc,
    /// The time source used.
    pub source: TimeSourceKind,
    /// Whether the cyclic thread ran with SCHED_FIFO.
    pub realtime_priority: bool,
    /// Time from the first release to the end (ns).
    pub elapsed_ns: u64,
    /// CLOCK_MONOTONIC at cycle time 0 (ns): a cycle at time `t` was released at `epoch_ns + t`.
    pub epoch_ns: u64,
}

/// A real-time run in progress.
pub struct RealTimeRun {
    stop: Arc<AtomicBool>,
    snapshot: Arc<Mutex<Snapshot>>,
    /// The release time (ns) of the cyclic thread's latest pass: it advances while the cycles
    /// run (a service manager's watchdog is fed from it).
    heartbeat: Arc<AtomicU64>,
    thread: JoinHandle<Result<RealTimeOutcome, RunError>>,
}

/// How often the cyclic thread refreshes the shared snapshot (ns).
const SNAPSHOT_EVERY_NS: u64 = 100_000_000;

/// Starts the cyclic thread. Memory locking and real-time priority are asked for when configured;
/// where the process may not have them, a warning is logged and the run goes on without.
pub fn start_realtime(plc: Plc, options: RealTimeOptions) -> Result<RealTimeRun, RunError> {
    start_realtime_with(plc, options, None)
}

/// [`start_realtime`], publishing a frame for the operator's screen after every pass in which
/// the main class ran.
pub fn start_realtime_with(
    mut plc: Plc,
    options: RealTimeOptions,
    mut screen: Option<crate::runtime::frame::FramePublisher>,
) -> Result<RealTimeRun, RunError> {
    if options.lock_memory
        && let Err(e) = timing::lock_memory()
    {
        warn!("could not lock memory: {e}; page faults may delay cycles");
    }
    let stop = Arc::new(AtomicBool::new(false));
    let snapshot = Arc::new(Mutex::new(Snapshot::for_plc(&plc)));
    let heartbeat = Arc::new(AtomicU64::new(0));
    let (stop_t, snap_t, beat_t) = (Arc::clone(&stop), Arc::clone(&snapshot), Arc::clone(&heartbeat));
    let source = options.source.resolve();
    let thread = std::thread::Builder::new()
        .name("plc-cyclic".into())
        .spawn(move || {
            timing::prefault_stack();
            let realtime_priority = options.realtime_priority > 0 && {
                match timing::set_realtime_priority(options.realtime_priority) {
                    Ok(()) => {
                        info!(
                            "cyclic thread runs with SCHED_FIFO priority {}",
                            options.realtime_priority
                        );
                        true
                    }
                    Err(e) => {
                        warn!(
                            "could not get real-time priority SCHED_FIFO {} ({e}); running with normal \
                             scheduling, so expect larger cycle lateness. Run as root, or grant \
                             CAP_SYS_NICE or an rtprio limit (ulimit -r)",
                            options.realtime_priority
                        );
                        false
                    }
                }
            };
            if let Err(e) = timing::minimize_timer_slack() {
                warn!("could not reduce the timer slack of the cyclic thread ({e}); wake-ups may be up to 50 µs later");
            }
            let mut waiter = timing::waiter(source).map_err(|error| RunError::Timer {
                source_name: source.name(),
                error,
            })?;
            if options.spin_ns > 0 {
                waiter = Box::new(timing::SpinningWaiter::new(waiter, options.spin_ns));
            }
            // The link opens first: its wait for the first input image must not eat into the schedule.
            plc.start_bus().map_err(RunError::StationRefused)?;
            // The schedule starts 2 ms from now, so the init parts finish before the first release.
            let mut clock = MonotonicClock::with_epoch(timing::monotonic_ns() + 2_000_000);
            // Paced, the cycles read the simulated clock; the wall clock only paces them.
            let mut simulated = options.pace.map(|_| VirtualClock::default());
            match &mut simulated {
                Some(virtual_clock) => plc.init(0, virtual_clock),
                None => plc.init(0, &mut clock),
            }
            let mut next_snapshot = SNAPSHOT_EVERY_NS;
            let mut log = StateLog::default();
            let mut behind = Behind::default();
            let end_ns = options.duration_ns.unwrap_or(u64::MAX);
            loop {
                let t = plc.next_release();
                if stop_t.load(Ordering::Relaxed) || t >= end_ns {
                    break;
                }
                let due = match options.pace {
                    Some(pace) => behind.due(clock.epoch_ns(), t, pace),
                    None => clock.epoch_ns() + t,
                };
                waiter.wait_until(due).map_err(|error| RunError::Timer {
                    source_name: source.name(),
                    error,
                })?;
                match &mut simulated {
                    Some(virtual_clock) => {
                        behind.check(timing::monotonic_ns(), due, t);
                        virtual_clock.advance_to(t);
                        plc.run_due(virtual_clock, end_ns);
                    }
                    None => plc.run_due(&mut clock, end_ns),
                }
                beat_t.store(t, Ordering::Relaxed);
                log.observe(&plc, t);
                if let Some(screen) = &mut screen {
                    screen.after_pass(&plc, t);
                }
                if t >= next_snapshot {
                    next_snapshot = t + SNAPSHOT_EVERY_NS;
                    // Never block the cyclic thread: if the status line holds the lock, skip.
                    if let Ok(mut s) = snap_t.try_lock() {
                        s.update(&plc, t);
                    }
                }
            }
            let wall_ns = clock.now_ns();
            let elapsed_ns = simulated.as_mut().map_or(wall_ns, |c| c.now_ns());
            if let Some(pace) = options.pace {
                info!(
                    "simulation paced at {pace}x real time: {:.3} s simulated in {:.3} s ({:.1}x)",
                    elapsed_ns as f64 / 1e9,
                    wall_ns as f64 / 1e9,
                    elapsed_ns as f64 / wall_ns.max(1) as f64
                );
            }
            plc.shutdown();
            if let Ok(mut s) = snap_t.lock() {
                s.update(&plc, elapsed_ns);
            }
            Ok(RealTimeOutcome {
                plc,
                source,
                realtime_priority,
                elapsed_ns,
                epoch_ns: clock.epoch_ns(),
            })
        })
        .map_err(RunError::Thread)?;
    Ok(RealTimeRun {
        stop,
        snapshot,
        heartbeat,
        thread,
    })
}

impl RealTimeRun {
    /// Asks the cyclic thread to stop after its current wait; outputs are then set safe.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// A handle to ask for a stop from elsewhere (a signal handler task, say).
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.stop)
    }

    /// The shared snapshot, refreshed about ten times a second.
    pub fn snapshot(&self) -> Arc<Mutex<Snapshot>> {
        Arc::clone(&self.snapshot)
    }

    /// The cyclic thread's heartbeat: the release time (ns) of its latest pass.
    pub fn heartbeat(&self) -> Arc<AtomicU64> {
        Arc::clone(&self.heartbeat)
    }

    /// Whether the cyclic thread has ended.
    pub fn is_finished(&self) -> bool {
        self.thread.is_finished()
    }

    /// Waits for the cyclic thread to end.
    pub fn join(self) -> Result<RealTimeOutcome, RunError> {
        match self.thread.join() {
            Ok(result) => result,
            Err(panic) => {
                let message = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "unknown panic".into());
                Err(RunError::Panicked(message))
            }
        }
    }
}
