//! The signals that end the soft-PLC or the station in an orderly way.
//!
//! Not only Ctrl-C and SIGTERM: a closed terminal or ssh session sends SIGHUP, and SIGQUIT,
//! SIGUSR1, SIGUSR2 and SIGALRM also terminate a process that does not handle them — without
//! the safe stop, leaving a station's outputs as they were (a drive at 19 % PWM). Every one of
//! them that can be handled asks for the same stop as SIGTERM. What cannot be handled (SIGKILL,
//! a crash, a cut cable) is the station's output watchdog's job ([`crate::sim::server`]).

use std::future::poll_fn;
use std::task::Poll;

use tokio::signal::unix::{Signal, SignalKind, signal};

/// The terminating signals handled, with the names logs use.
pub const HANDLED: [(&str, i32); 7] = [
    ("SIGINT", libc::SIGINT),
    ("SIGTERM", libc::SIGTERM),
    ("SIGHUP", libc::SIGHUP),
    ("SIGQUIT", libc::SIGQUIT),
    ("SIGUSR1", libc::SIGUSR1),
    ("SIGUSR2", libc::SIGUSR2),
    ("SIGALRM", libc::SIGALRM),
];

/// The handled signals, registered with the running tokio runtime (from then on they no
/// longer terminate the process by themselves).
pub struct Terminating(Vec<(&'static str, Signal)>);

impl Terminating {
    /// Registers the handlers; one that cannot be registered is logged and skipped.
    pub fn register() -> Terminating {
        let signals = HANDLED
            .iter()
            .filter_map(|&(name, number)| match signal(SignalKind::from_raw(number)) {
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
    pub async fn recv(&mut self) -> &'static str {
        poll_fn(|cx| {
            for (name, s) in &mut self.0 {
                if s.poll_recv(cx).is_ready() {
                    return Poll::Ready(*name);
                }
            }
            Poll::Pending
        })
        .await
    }
}
