//! The live status line on a terminal, and a log writer that keeps logs and status line apart.

use std::io::{self, IsTerminal, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::runtime::snapshot::Snapshot;

/// Whether a status line is on screen (logs then clear it before they print).
static ACTIVE: AtomicBool = AtomicBool::new(false);
/// Serializes writes to stderr between the status line and the logger.
static STDERR: Mutex<()> = Mutex::new(());

/// A `tracing` writer for stderr that first clears the status line if one is shown; the status
/// task redraws it on its next tick.
#[derive(Clone, Copy, Debug, Default)]
pub struct LogWriter;

impl Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let _guard = STDERR.lock().unwrap_or_else(|p| p.into_inner());
        let mut err = io::stderr().lock();
        if ACTIVE.load(Ordering::Relaxed) {
            err.write_all(b"\r\x1b[2K")?;
        }
        err.write_all(buf)?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        io::stderr().flush()
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for LogWriter {
    type Writer = LogWriter;
    fn make_writer(&'a self) -> Self::Writer {
        LogWriter
    }
}

/// Formats one status line from a snapshot.
pub fn format_line(s: &Snapshot) -> String {
    let mut line = format!("t={:8.1}s", s.t_ns as f64 / 1e9);
    if !s.state.is_empty() {
        line.push_str("  ");
        line.push_str(&s.state);
        if !s.reason.is_empty() {
            line.push_str(&format!(" ({})", s.reason));
        }
        if !s.note.is_empty() {
            line.push_str(&format!(" [{}]", s.note));
        }
    }
    for (name, value) in &s.values {
        // NaN means "not known yet" (M before referencing, say).
        if value.is_nan() {
            line.push_str(&format!(" {name}=-"));
        } else if *name == "line" {
            // A program line is a whole number.
            line.push_str(&format!(" {name}={value:.0}"));
        } else {
            line.push_str(&format!(" {name}={value:.2}"));
        }
    }
    for c in &s.classes {
        line.push_str(&format!(
            "  | {} {} cyc late {:.0}/{:.0}µs exec {:.0}µs ovr {}",
            c.name,
            c.cycles,
            c.lateness_mean_ns / 1e3,
            c.lateness_max_ns as f64 / 1e3,
            c.exec_mean_ns / 1e3,
            c.overruns
        ));
    }
    line
}

/// Whether a status line makes sense: stderr is a terminal.
pub fn wanted() -> bool {
    io::stderr().is_terminal()
}

/// Redraws the status line every `every` until the returned flag is set; call [`finish`] after.
pub fn spawn(snapshot: Arc<Mutex<Snapshot>>, every: Duration) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(every);
        loop {
            tick.tick().await;
            let line = match snapshot.lock() {
                Ok(s) => format_line(&s),
                Err(_) => return,
            };
            let _guard = STDERR.lock().unwrap_or_else(|p| p.into_inner());
            let mut err = io::stderr().lock();
            // A failed write to the terminal is not worth stopping the PLC for.
            let _ = write!(err, "\r\x1b[2K{line}");
            let _ = err.flush();
            ACTIVE.store(true, Ordering::Relaxed);
        }
    })
}

/// Clears the status line (after the status task has been aborted).
pub fn finish() {
    if ACTIVE.swap(false, Ordering::Relaxed) {
        let _guard = STDERR.lock().unwrap_or_else(|p| p.into_inner());
        let _ = write!(io::stderr(), "\r\x1b[2K");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_program_line_is_a_whole_number_and_positions_have_two_decimals() {
        let s = Snapshot {
            state: "AUTO".into(),
            values: vec![("line", 12.0), ("x", 1.23456), ("q6", f64::NAN)],
            ..Snapshot::default()
        };
        let line = format_line(&s);
        assert!(line.ends_with("  AUTO line=12 x=1.23 q6=-"), "{line}");
    }
}
