//! An emulated RS-485 line: two byte streams (ends of socket pairs) joined the way a half-duplex
//! line at a given baud rate joins a Modbus RTU master and slave. A socket moves bytes
//! instantly; this relay passes each frame on only when the line would have finished carrying it,
//! and a frame that turns the line around waits for the silent interval that ends the frame
//! before it (the slave cannot see a request's end any sooner; the master must keep the line
//! silent as long before its next request). That is what makes an exchange time measured here the
//! time the exchange would take on a real line, save the adapters' own latency.
//!
//! Socket pairs rather than pseudo-terminals: a pty hands its bytes to the reader through the
//! kernel's tty layer, in a worker thread at normal priority, which a busy machine starved for
//! tens of milliseconds however high the line's own threads ran; a socket delivers in the
//! writer's own call. (`io-sim --serial` still takes a device path: [`pty_pair`] gives tests one.)
//!
//! A frame is recognised by the line changing direction, which is exact for Modbus (request,
//! response, request, ...); several frames in one direction are carried back to back.

use std::io::{self, Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::TTYPort;

/// A pseudo-terminal pair (its master, its slave) whose descriptors no child process inherits:
/// for tests of a program that opens a serial device by its path (`io-sim --serial`).
///
/// `serialport`'s `TTYPort::pair` opens both ends without close-on-exec, so a process spawned
/// meanwhile by any thread (a test beside this one, a helper) kept the master open: closing it
/// then no longer hung the slave up, and a vanished station went unnoticed. The flag is set as
/// soon as the pair exists; a fork within those microseconds is the only way left to inherit it.
pub fn pty_pair() -> io::Result<(TTYPort, TTYPort)> {
    use std::os::fd::AsRawFd as _;
    let (master, slave) = TTYPort::pair().map_err(io::Error::from)?;
    for fd in [master.as_raw_fd(), slave.as_raw_fd()] {
        // SAFETY: `fd` belongs to a port alive here; F_SETFD only changes its descriptor flags.
        if unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) } == -1 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok((master, slave))
}

/// Bits per character on a Modbus RTU line: start, 8 data, parity (or a second stop bit), stop.
pub const BITS_PER_CHAR: u64 = 11;

/// The timing of a line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineTiming {
    /// Time to carry one character (ns).
    pub char_ns: u64,
    /// The silent interval that ends a frame (ns).
    pub silent_ns: u64,
}

impl LineTiming {
    /// Modbus RTU at `baud`: 11-bit characters; the silent interval is 3.5 characters, fixed at
    /// 1.75 ms above 19 200 baud as the Modbus serial line specification prescribes.
    pub fn modbus_rtu(baud: u32) -> LineTiming {
        let char_ns = BITS_PER_CHAR * 1_000_000_000 / u64::from(baud.max(1));
        let silent_ns = if baud > 19_200 { 1_750_000 } else { char_ns * 7 / 2 };
        LineTiming { char_ns, silent_ns }
    }

    /// Time a frame of `bytes` takes on the line (ns).
    pub fn frame_ns(&self, bytes: usize) -> u64 {
        self.char_ns * bytes as u64
    }
}

/// Who used the line last, and until when.
struct LineState {
    free_at: Instant,
    last_sender: usize,
}

/// A running emulated line; dropping it stops the relay.
pub struct PacedLine {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl PacedLine {
    /// Joins `a` and `b` (each the relay's end of a socket pair) through a line with `timing`.
    pub fn start(a: UnixStream, b: UnixStream, timing: LineTiming) -> io::Result<PacedLine> {
        let stop = Arc::new(AtomicBool::new(false));
        let state = Arc::new(Mutex::new(LineState {
            free_at: Instant::now(),
            last_sender: 0,
        }));
        let mut threads = Vec::new();
        for (sender, from, to) in [(0, a.try_clone()?, b.try_clone()?), (1, b, a)] {
            let stop = Arc::clone(&stop);
            let state = Arc::clone(&state);
            let thread = std::thread::Builder::new()
                .name(format!("line-{sender}"))
                .spawn(move || {
                    hardware_priority();
                    carry(sender, from, to, timing, &state, &stop)
                })?;
            threads.push(thread);
        }
        Ok(PacedLine { stop, threads })
    }
}

impl Drop for PacedLine {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// One direction: read what `sender` sends, pass it on when the line has carried it.
fn carry(
    sender: usize,
    mut from: UnixStream,
    mut to: UnixStream,
    timing: LineTiming,
    state: &Mutex<LineState>,
    stop: &AtomicBool,
) {
    // Sleeps here must be precise to well under a character time.
    let _ = crate::runtime::timing::minimize_timer_slack();
    // Reads wake up now and then to see whether the line is to stop.
    if from.set_read_timeout(Some(Duration::from_millis(20))).is_err() {
        return;
    }
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let n = match from.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => n,
            Err(e) if matches!(e.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut) => continue,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(_) => return,
        };
        let received = Instant::now();
        let done = {
            let Ok(mut line) = state.lock() else { return };
            let mut start = received.max(line.free_at);
            if line.last_sender != sender {
                start = start.max(line.free_at + Duration::from_nanos(timing.silent_ns));
            }
            let done = start + Duration::from_nanos(timing.frame_ns(n));
            line.free_at = done;
            line.last_sender = sender;
            done
        };
        std::thread::sleep(done.saturating_duration_since(Instant::now()));
        if to.write_all(&buf[..n]).is_err() {
            return;
        }
    }
}

/// SCHED_FIFO priority of the threads that emulate hardware (a line's carriers, a station on
/// a line): above the cyclic thread's 80 and everything else. A UART or a station's own
/// processor is never starved by a busy PC; threads at normal priority were, by seconds, beside
/// CPU-bound processes, and the line then looked broken. Below the cyclic threads (70) they
/// waited for the cycles of the PLCs they served, two of them on two cores in the RTU tests'
/// debug builds, and the line's exchanges took over the 8 ms the drives allow beside
/// `stress-ng --cpu 2`. They run for microseconds a frame: the cycles hardly notice them, as
/// they hardly notice a real UART's interrupts.
pub const HARDWARE_PRIORITY: u8 = 90;

/// Puts the calling thread at [`HARDWARE_PRIORITY`] where the process may (root,
/// CAP_SYS_NICE); elsewhere it stays at normal priority, which serves on a quiet machine.
pub fn hardware_priority() {
    let _ = crate::runtime::timing::set_realtime_priority(HARDWARE_PRIORITY);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pty_pair_is_not_inherited_by_child_processes() {
        use std::os::fd::AsRawFd as _;
        let (master, slave) = pty_pair().expect("pty");
        for fd in [master.as_raw_fd(), slave.as_raw_fd()] {
            // SAFETY: F_GETFD on a descriptor of a port alive here.
            let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
            assert_eq!(flags & libc::FD_CLOEXEC, libc::FD_CLOEXEC, "fd {fd}");
        }
    }

    #[test]
    fn modbus_rtu_timing() {
        let t = LineTiming::modbus_rtu(115_200);
        assert_eq!(t.char_ns, 95_486);
        assert_eq!(t.silent_ns, 1_750_000);
        let t = LineTiming::modbus_rtu(9600);
        assert_eq!(t.char_ns, 1_145_833);
        assert_eq!(t.silent_ns, 4_010_415, "3.5 characters at 19 200 baud and below");
    }

    #[test]
    fn a_frame_arrives_when_the_line_has_carried_it() {
        let (mut master, relay_a) = UnixStream::pair().expect("socket pair");
        let (relay_b, mut slave) = UnixStream::pair().expect("socket pair");
        // 1200 baud: 9.17 ms a character, so 10 characters take 92 ms.
        let _line = PacedLine::start(relay_a, relay_b, LineTiming::modbus_rtu(1200)).expect("line");
        slave.set_read_timeout(Some(Duration::from_secs(2))).expect("timeout");
        let sent = Instant::now();
        master.write_all(b"0123456789").expect("write");
        let mut got = [0u8; 10];
        slave.read_exact(&mut got).expect("read");
        let took = sent.elapsed();
        assert_eq!(&got, b"0123456789");
        // A lower bound only: the relay may be late (a loaded machine), never early.
        assert!(took >= Duration::from_millis(91), "carried in {took:?}");
    }
}
