//! The signals that end the soft-PLC or the station in an orderly way.
//!
//! Every signal whose default action ends the process (signal(7): "Term" or "Core") and that a
//! process can handle asks for the same stop as SIGTERM: Ctrl-C, a closed terminal or ssh
//! session (SIGHUP), SIGQUIT, the user and alarm signals, a CPU or real-time limit reached
//! (SIGXCPU: `RLIMIT_CPU`, and `RLIMIT_RTTIME` for a SCHED_FIFO thread), a file size limit
//! (SIGXFSZ), a UPS's power-fail notice (SIGPWR), the profiling timers, SIGIO, SIGSYS (a
//! seccomp filter), SIGABRT and SIGTRAP sent by another process, SIGSTKFLT and the real-time
//! signals SIGRTMIN … SIGRTMAX. Without a handler each of them would end the process without
//! the safe stop, leaving a station's outputs as they were (a drive at 34 % PWM, the spindle on).
//!
//! Not handled, and why: SIGKILL and SIGSTOP cannot be; SIGSEGV, SIGBUS, SIGILL and SIGFPE mean
//! the process itself crashed (a handler that returned would fault again); SIGPIPE is ignored by
//! every Rust program (a write to a closed pipe or socket fails with EPIPE instead); the others
//! (SIGCHLD, SIGCONT, SIGURG, SIGWINCH, SIGTSTP, SIGTTIN, SIGTTOU) do not end a process. What
//! cannot be handled — SIGKILL, a crash, a process stopped by SIGSTOP, a cut cable — is the
//! station's output watchdog's job ([`crate::services::sim::server`]).

use std::future::poll_fn;
use std::task::Poll;

use tokio::signal::unix::{Signal, SignalKind, signal};

/// The terminating signals handled by name (the real-time signals come from [`handled`]).
pub const NAMED: [(&str, i32); 17] = [
    ("SIGINT", libc::SIGINT),
    ("SIGTERM", libc::SIGTERM),
    ("SIGHUP", libc::SIGHUP),
    ("SIGQUIT", libc::SIGQUIT),
    ("SIGUSR1", libc::SIGUSR1),
    ("SIGUSR2", libc::SIGUSR2),
    ("SIGALRM", libc::SIGALRM),
    ("SIGVTALRM", libc::SIGVTALRM),
    ("SIGPROF", libc::SIGPROF),
    ("SIGXCPU", libc::SIGXCPU),
    ("SIGXFSZ", libc::SIGXFSZ),
    ("SIGPWR", libc::SIGPWR),
    ("SIGIO", libc::SIGIO),
    ("SIGSYS", libc::SIGSYS),
    ("SIGSTKFLT", libc::SIGSTKFLT),
    ("SIGABRT", libc::SIGABRT),
    ("SIGTRAP", libc::SIGTRAP),
];

/// Every handled signal with its name: the named ones (SIGPOLL is SIGIO, SIGIOT is SIGABRT on
/// Linux) and the real-time signals, `SIGRTMIN`, `SIGRTMIN+1`, … `SIGRTMAX`.
pub fn handled() -> Vec<(String, i32)> {
    let mut all: Vec<(String, i32)> = NAMED.iter().map(|(name, n)| (name.to_string(), *n)).collect();
    let (min, max) = (libc::SIGRTMIN(), libc::SIGRTMAX());
    for number in min..=max {
        let name = match number - min {
            0 => "SIGRTMIN".to_string(),
            k if number == max => format!("SIGRTMAX (SIGRTMIN+{k})"),
            k => format!("SIGRTMIN+{k}"),
        };
        all.push((name, number));
    }
    all
}

/// The handled signals, registered with the running tokio runtime (from then on they no
/// longer terminate the process by themselves).
pub struct Terminating(Vec<(String, Signal)>);

impl Terminating {
    /// Registers the handlers; one that cannot be registered is logged and skipped.
    pub fn register() -> Terminating {
        let signals = handled()
            .into_iter()
            .filter_map(|(name, number)| match signal(SignalKind::from_raw(number)) {
                Ok(s) => Some((name, s)),
                Err(e) => {
                    tracing::warn!("cannot handle {name}: {e}");
                    None
                }
            })
            .collect();
        Terminating(signals)
    }

    /// Waits for the next terminating signal; returns its name.
    pub async fn recv(&mut self) -> String {
        poll_fn(|cx| {
            for (name, s) in &mut self.0 {
                if s.poll_recv(cx).is_ready() {
                    return Poll::Ready(name.clone());
                }
            }
            Poll::Pending
        })
        .await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default action of every signal of Linux (signal(7)): whether it ends the process.
    fn ends_the_process(number: i32) -> bool {
        let keeps = [
            libc::SIGCHLD,
            libc::SIGCONT,
            libc::SIGURG,
            libc::SIGWINCH,
            libc::SIGSTOP,
            libc::SIGTSTP,
            libc::SIGTTIN,
            libc::SIGTTOU,
        ];
        !keeps.contains(&number)
    }

    #[test]
    fn every_signal_that_ends_the_process_is_handled_but_crashes_and_the_unhandleable() {
        // Crashes of the process itself, the two that cannot be handled, and SIGPIPE (ignored
        // by the Rust runtime).
        let left_out = [
            libc::SIGSEGV,
            libc::SIGBUS,
            libc::SIGILL,
            libc::SIGFPE,
            libc::SIGKILL,
            libc::SIGSTOP,
            libc::SIGPIPE,
        ];
        let handled: Vec<i32> = handled().iter().map(|(_, n)| *n).collect();
        for number in 1..=libc::SIGRTMAX() {
            // glibc keeps the two below SIGRTMIN for itself.
            if (libc::SIGSYS + 1..libc::SIGRTMIN()).contains(&number) {
                continue;
            }
            let expected = ends_the_process(number) && !left_out.contains(&number);
            assert_eq!(handled.contains(&number), expected, "signal {number}");
        }
        // Each once.
        let mut unique = handled.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), handled.len());
    }
}
