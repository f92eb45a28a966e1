//! Real time: the monotonic clock, the timers the cyclic thread can wait on, real-time priority
//! and memory locking.
//!
//! Every wait is for an absolute deadline on CLOCK_MONOTONIC, so lateness never accumulates into
//! drift. Which timer is used is a configuration choice (`timing.source`); `pkm-plc bench`
//! measures them side by side, and `auto` picks the best one measured (see the README).

use std::io;
use std::os::fd::{AsFd, AsRawFd, RawFd};
use std::time::Duration;

use nix::sys::time::TimeSpec;
use nix::sys::timerfd::{ClockId as TfdClock, Expiration, TimerFd, TimerFlags, TimerSetTimeFlags};
use nix::time::{ClockId, ClockNanosleepFlags, clock_gettime, clock_nanosleep};

use crate::program::Clock;
use crate::runtime::config::TimeSourceKind;

/// Reads CLOCK_MONOTONIC in nanoseconds.
pub fn monotonic_ns() -> u64 {
    match clock_gettime(ClockId::CLOCK_MONOTONIC) {
        Ok(ts) => ts_to_ns(ts),
        // CLOCK_MONOTONIC always exists on Linux; clock_gettime on it cannot fail.
        Err(e) => panic!("CLOCK_MONOTONIC unreadable: {e}"),
    }
}

fn ts_to_ns(ts: TimeSpec) -> u64 {
    (ts.tv_sec() as u64) * 1_000_000_000 + ts.tv_nsec() as u64
}

fn ns_to_ts(ns: u64) -> TimeSpec {
    TimeSpec::from_duration(Duration::from_nanos(ns))
}

/// The real clock as the scheduler sees it: nanoseconds since an epoch on CLOCK_MONOTONIC.
#[derive(Clone, Copy, Debug)]
pub struct MonotonicClock {
    epoch_ns: u64,
}

impl MonotonicClock {
    /// A clock whose zero is `epoch_ns` on CLOCK_MONOTONIC (may lie slightly in the future).
    pub fn with_epoch(epoch_ns: u64) -> Self {
        MonotonicClock { epoch_ns }
    }

    /// The epoch on CLOCK_MONOTONIC.
    pub fn epoch_ns(&self) -> u64 {
        self.epoch_ns
    }
}

impl Clock for MonotonicClock {
    fn now_ns(&mut self) -> u64 {
        monotonic_ns().saturating_sub(self.epoch_ns)
    }

    fn burn(&mut self, ns: u64) {
        let until = monotonic_ns() + ns;
        while monotonic_ns() < until {
            std::hint::spin_loop();
        }
    }
}

/// Something the cyclic thread can block on until an absolute CLOCK_MONOTONIC deadline.
pub trait Waiter {
    /// Returns at or after `deadline_ns` (CLOCK_MONOTONIC); at once if it has passed.
    fn wait_until(&mut self, deadline_ns: u64) -> io::Result<()>;
}

/// Creates the waiter for a time source (`auto` must have been resolved).
pub fn waiter(kind: TimeSourceKind) -> io::Result<Box<dyn Waiter>> {
    Ok(match kind.resolve() {
        TimeSourceKind::Nanosleep | TimeSourceKind::Auto => Box::new(NanosleepWaiter),
        TimeSourceKind::Timerfd => Box::new(TimerfdWaiter::new()?),
        TimeSourceKind::Tokio => Box::new(TokioWaiter::new()?),
    })
}

/// `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`.
struct NanosleepWaiter;

impl Waiter for NanosleepWaiter {
    fn wait_until(&mut self, deadline_ns: u64) -> io::Result<()> {
        let ts = ns_to_ts(deadline_ns);
        loop {
            match clock_nanosleep(ClockId::CLOCK_MONOTONIC, ClockNanosleepFlags::TIMER_ABSTIME, &ts) {
                Ok(_) => return Ok(()),
                // A signal woke us early: the deadline is absolute, so sleep again.
                Err(nix::errno::Errno::EINTR) => continue,
                Err(e) => return Err(io::Error::from(e)),
            }
        }
    }
}

/// A timerfd with an absolute one-shot expiration, awaited through tokio's `AsyncFd` on a
/// current-thread runtime owned by the cyclic thread.
struct TimerfdWaiter {
    runtime: tokio::runtime::Runtime,
    fd: tokio::io::unix::AsyncFd<RawTimerFd>,
}

/// `AsyncFd` needs `AsRawFd`, which nix's `TimerFd` does not implement.
struct RawTimerFd(TimerFd);

impl AsRawFd for RawTimerFd {
    fn as_raw_fd(&self) -> RawFd {
        self.0.as_fd().as_raw_fd()
    }
}

impl TimerfdWaiter {
    fn new() -> io::Result<Self> {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_io().build()?;
        let tfd = TimerFd::new(
            TfdClock::CLOCK_MONOTONIC,
            TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC,
        )
        .map_err(io::Error::from)?;
        let fd = {
            let _guard = runtime.enter();
            // SAFETY: the timerfd is open and owned by `RawTimerFd`, which the `AsyncFd` owns; it
            // stays open, and `as_raw_fd` returns the same descriptor, until the `AsyncFd` drops.
            unsafe { tokio::io::unix::AsyncFd::register_with_interest(RawTimerFd(tfd), tokio::io::Interest::READABLE) }
                .map_err(io::Error::from)?
        };
        Ok(TimerfdWaiter { runtime, fd })
    }
}

impl Waiter for TimerfdWaiter {
    fn wait_until(&mut self, deadline_ns: u64) -> io::Result<()> {
        if monotonic_ns() >= deadline_ns {
            return Ok(());
        }
        self.fd
            .get_ref()
            .0
            .set(
                Expiration::OneShot(ns_to_ts(deadline_ns)),
                TimerSetTimeFlags::TFD_TIMER_ABSTIME,
            )
            .map_err(io::Error::from)?;
        let fd = &self.fd;
        self.runtime.block_on(async {
            loop {
                let mut guard = fd.readable().await?;
                let mut expirations = [0u8; 8];
                let read = guard.try_io(|inner| {
                    // SAFETY: reading 8 bytes into an 8-byte buffer from a valid, open timerfd.
                    let n = unsafe { libc::read(inner.as_raw_fd(), expirations.as_mut_ptr().cast(), 8) };
                    if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n) }
                });
                match read {
                    Ok(Ok(_)) => return Ok(()),
                    Ok(Err(e)) if e.kind() == io::ErrorKind::Interrupted => continue,
                    Ok(Err(e)) => return Err(e),
                    // Spurious readiness: wait again.
                    Err(_would_block) => continue,
                }
            }
        })
    }
}

/// tokio's own timer (`sleep_until`, the mechanism behind `tokio::time::interval`).
struct TokioWaiter {
    runtime: tokio::runtime::Runtime,
    /// The same instant on both clocks, to convert CLOCK_MONOTONIC deadlines to tokio instants.
    origin: (tokio::time::Instant, u64),
}

impl TokioWaiter {
    fn new() -> io::Result<Self> {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_time().build()?;
        // std's Instant is CLOCK_MONOTONIC on Linux; take both readings back to back.
        let origin = (tokio::time::Instant::now(), monotonic_ns());
        Ok(TokioWaiter { runtime, origin })
    }
}

impl Waiter for TokioWaiter {
    fn wait_until(&mut self, deadline_ns: u64) -> io::Result<()> {
        let at = self.origin.0 + Duration::from_nanos(deadline_ns.saturating_sub(self.origin.1));
        self.runtime.block_on(async move { tokio::time::sleep_until(at).await });
        Ok(())
    }
}

/// Sets the calling thread's timer slack to 1 ns. Normal threads get 50 µs by default, which the
/// kernel may add to every timed wait; SCHED_FIFO threads have none anyway.
pub fn minimize_timer_slack() -> io::Result<()> {
    // SAFETY: PR_SET_TIMERSLACK takes one integer argument; the rest are ignored.
    let rc = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Wraps a waiter: it sleeps until `spin_ns` before the deadline, then busy-waits to it. This
/// trades CPU time (`spin_ns` per release) for the wake-up latency of the OS timer.
pub struct SpinningWaiter {
    inner: Box<dyn Waiter>,
    spin_ns: u64,
}

impl SpinningWaiter {
    /// Wraps `inner` with a spin margin of `spin_ns`.
    pub fn new(inner: Box<dyn Waiter>, spin_ns: u64) -> Self {
        SpinningWaiter { inner, spin_ns }
    }
}

impl Waiter for SpinningWaiter {
    fn wait_until(&mut self, deadline_ns: u64) -> io::Result<()> {
        self.inner.wait_until(deadline_ns.saturating_sub(self.spin_ns))?;
        while monotonic_ns() < deadline_ns {
            std::hint::spin_loop();
        }
        Ok(())
    }
}

/// Asks for SCHED_FIFO at `priority` for the calling thread.
pub fn set_realtime_priority(priority: u8) -> io::Result<()> {
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: pid 0 is the calling thread; `param` is a valid sched_param for the call's duration.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Returns the calling thread to normal (SCHED_OTHER) scheduling.
pub fn set_normal_priority() -> io::Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: as in `set_realtime_priority`.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// The smallest RLIMIT_MEMLOCK under which locking is attempted without CAP_IPC_LOCK: with
/// MCL_FUTURE every later allocation (thread stacks, buffers) must fit under the limit, and the
/// common 8 MiB default would make the next thread creation fail.
const MIN_MEMLOCK_LIMIT: u64 = 512 * 1024 * 1024;

/// Why memory was not locked.
#[derive(Debug, thiserror::Error)]
pub enum LockMemoryError {
    /// The limit is too small to lock the process and everything it will allocate.
    #[error(
        "the locked-memory limit is {limit_kib} KiB and the process lacks CAP_IPC_LOCK; locking would make later \
         allocations fail, so memory is not locked. Run as root, or raise the limit (ulimit -l unlimited)"
    )]
    LimitTooSmall {
        /// RLIMIT_MEMLOCK in KiB.
        limit_kib: u64,
    },
    /// mlockall refused.
    #[error("mlockall: {0}")]
    Os(io::Error),
}

/// Locks the process's current and future memory, so page faults cannot delay a cycle — but only
/// where that is safe: with CAP_IPC_LOCK, or under a locked-memory limit of at least 512 MiB.
///
/// Pages are locked as they are first touched (`MCL_ONFAULT`, Linux 4.4; before it, all at
/// once): what the process uses stays resident and cannot be paged out, what it never touches
/// — most of its 38 MB binary (the OPC UA server's and the screen's code, the NodeSets), the
/// capacity of buffers not yet filled — is neither read nor counted. Locking every page at once
/// made a run 62 MB resident, 31 MB of it the binary's own file. The cycle's pages are touched
/// by its init part and first cycles, and its stack by [`prefault_stack`], so after them it
/// never waits on a page fault.
pub fn lock_memory() -> Result<(), LockMemoryError> {
    use nix::sys::mman::{MlockAllFlags, mlockall};
    use nix::sys::resource::{Resource, getrlimit};
    if !has_cap_ipc_lock() {
        let (soft, _hard) = getrlimit(Resource::RLIMIT_MEMLOCK).map_err(|e| LockMemoryError::Os(e.into()))?;
        if soft != nix::sys::resource::RLIM_INFINITY && soft < MIN_MEMLOCK_LIMIT {
            return Err(LockMemoryError::LimitTooSmall { limit_kib: soft / 1024 });
        }
    }
    let all = MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE;
    match mlockall(all | MlockAllFlags::from_bits_retain(libc::MCL_ONFAULT)) {
        Ok(()) => Ok(()),
        // A kernel before 4.4 knows no MCL_ONFAULT: every page at once, then.
        Err(nix::errno::Errno::EINVAL) => mlockall(all).map_err(|e| LockMemoryError::Os(e.into())),
        Err(e) => Err(LockMemoryError::Os(e.into())),
    }
}

/// How much of the cyclic thread's stack [`prefault_stack`] touches: far more than a cycle
/// uses (its programs keep their state on the heap).
const STACK_PREFAULT: usize = 256 * 1024;

/// Touches [`STACK_PREFAULT`] bytes of the calling thread's stack, so that with memory locked on
/// fault ([`lock_memory`]) the cycle's deepest calls find their stack pages resident.
#[inline(never)]
pub fn prefault_stack() {
    let mut pages = [0u8; STACK_PREFAULT];
    std::hint::black_box(&mut pages);
}

/// Whether the process has CAP_IPC_LOCK (bit 14 of the effective capability set), which lifts the
/// locked-memory limit.
fn has_cap_ipc_lock() -> bool {
    const CAP_IPC_LOCK: u32 = 14;
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|status| {
            let hex = status
                .lines()
                .find_map(|l| l.strip_prefix("CapEff:"))?
                .trim()
                .to_string();
            u64::from_str_radix(&hex, 16).ok()
        })
        .is_some_and(|caps| caps & (1 << CAP_IPC_LOCK) != 0)
}
