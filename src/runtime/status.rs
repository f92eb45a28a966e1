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

/// The width assumed when the terminal does not say (nor `COLUMNS`).
pub const DEFAULT_WIDTH: usize = 80;

/// A part of the status line: shown in line order, kept in order of `rank` (0 first) while the
/// line fits.
struct Field {
    rank: u8,
    text: String,
}

/// Formats one status line from a snapshot, at most `width - 1` characters (a line as wide as
/// the terminal would wrap on some): the state with its reason first, then the time, the
/// positions and values, the note and each class's figures — what does not fit is left out,
/// least important first, and a reason too long for the line is cut with an ellipsis.
pub fn format_line(s: &Snapshot, width: usize) -> String {
    let room = width.saturating_sub(1).max(20);
    let mut fields = Vec::new();
    if !s.state.is_empty() {
        let mut state = s.state.clone();
        if !s.reason.is_empty() {
            state.push_str(&format!(" ({})", s.reason));
        }
        fields.push(Field {
            rank: 0,
            text: cut(&state, room),
        });
    }
    fields.push(Field {
        rank: 1,
        text: format!("t={:.1}s", s.t_ns as f64 / 1e9),
    });
    for (name, value) in &s.values {
        // NaN means "not known yet" (M before referencing, say); a program line is a whole
        // number.
        let text = if value.is_nan() {
            format!("{name}=-")
        } else if *name == "line" {
            format!("{name}={}", fixed(*value, 0))
        } else {
            format!("{name}={}", fixed(*value, 2))
        };
        fields.push(Field { rank: 2, text });
    }
    if !s.note.is_empty() {
        fields.push(Field {
            rank: 3,
            text: format!("[{}]", s.note),
        });
    }
    for c in &s.classes {
        fields.push(Field {
            rank: 4,
            text: format!(
                "| {} {} cyc late {}/{}µs exec {}µs ovr {}",
                c.name,
                c.cycles,
                fixed(c.lateness_mean_ns / 1e3, 0),
                fixed(c.lateness_max_ns as f64 / 1e3, 0),
                fixed(c.exec_mean_ns / 1e3, 0),
                c.overruns
            ),
        });
    }
    // Kept by rank, then by place, while the line (one space between fields) fits: the first
    // that does not fit ends it, so no field shows without the more important ones.
    let mut order: Vec<usize> = (0..fields.len()).collect();
    order.sort_by_key(|&k| (fields[k].rank, k));
    let mut kept = vec![false; fields.len()];
    let mut used = 0;
    for k in order {
        let len = fields[k].text.chars().count() + usize::from(used > 0);
        if used + len > room {
            break;
        }
        kept[k] = true;
        used += len;
    }
    let shown: Vec<&str> = fields
        .iter()
        .zip(&kept)
        .filter(|(_, k)| **k)
        .map(|(f, _)| f.text.as_str())
        .collect();
    shown.join(" ")
}

/// `value` with `decimals` decimals, never `-0.00`: a value that rounds to zero is zero.
fn fixed(value: f64, decimals: usize) -> String {
    let text = format!("{value:.decimals$}");
    match text.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => text,
    }
}

/// `text` cut to `room` characters, an ellipsis at the cut.
fn cut(text: &str, room: usize) -> String {
    if text.chars().count() <= room {
        return text.to_string();
    }
    let mut out: String = text.chars().take(room.saturating_sub(1)).collect();
    out.push('…');
    out
}

/// The terminal's width on standard error: what the terminal says, else `COLUMNS`, else
/// [`DEFAULT_WIDTH`].
pub fn terminal_width() -> usize {
    #[cfg(unix)]
    {
        // SAFETY: TIOCGWINSZ writes a `winsize` into the struct we own; a descriptor that is
        // not a terminal makes the call fail without writing.
        let mut size: libc::winsize = unsafe { std::mem::zeroed() };
        let ok = unsafe { libc::ioctl(libc::STDERR_FILENO, libc::TIOCGWINSZ, &mut size) } == 0;
        if ok && size.ws_col > 0 {
            return usize::from(size.ws_col);
        }
    }
    std::env::var("COLUMNS")
        .ok()
        .and_then(|c| c.trim().parse::<usize>().ok())
        .filter(|&c| c > 0)
        .unwrap_or(DEFAULT_WIDTH)
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
            // Asked at every redraw: the operator may resize the terminal.
            let width = terminal_width();
            let line = match snapshot.lock() {
                Ok(s) => format_line(&s, width),
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
    use crate::runtime::snapshot::ClassSnapshot;

    /// A busy TRIJOINT's snapshot: a long reason, positions, two classes.
    fn busy() -> Snapshot {
        let class = |name: &str| ClassSnapshot {
            name: name.into(),
            cycles: 123_456,
            overruns: 0,
            violations: 0,
            lateness_mean_ns: 41_000.0,
            lateness_max_ns: 1_234_000,
            exec_mean_ns: 12_000.0,
            exec_max_ns: 80_000,
        };
        Snapshot {
            t_ns: 1_234_500_000_000,
            classes: vec![class("fast"), class("main")],
            state: "ERROR".into(),
            reason: "following error of drive 2: 5.12 mm over 4.00 mm (program line 12)".into(),
            note: "acknowledge with STOP".into(),
            values: vec![("line", 12.0), ("x", -0.0001), ("y", 207.384), ("q1", f64::NAN)],
            bus_fault: false,
        }
    }

    #[test]
    fn the_program_line_is_a_whole_number_and_positions_have_two_decimals() {
        let s = Snapshot {
            state: "AUTO".into(),
            values: vec![("line", 12.0), ("x", 1.23456), ("q6", f64::NAN)],
            ..Snapshot::default()
        };
        let line = format_line(&s, 200);
        assert!(line.ends_with("AUTO t=0.0s line=12 x=1.23 q6=-"), "{line}");
    }

    #[test]
    fn the_line_fits_the_terminal_dropping_the_least_important_first() {
        let s = busy();
        let wide = format_line(&s, 400);
        assert!(
            wide.contains("| main 123456 cyc late 41/1234µs exec 12µs ovr 0"),
            "{wide}"
        );
        assert!(wide.contains("[acknowledge with STOP]"), "{wide}");
        for width in [40, 60, 80, 100, 132, 200] {
            let line = format_line(&s, width);
            assert!(line.chars().count() < width, "{width}: {line}");
            assert!(line.starts_with("ERROR (following error"), "{width}: {line}");
        }
        // At 80 columns the state and its long reason leave room for nothing else.
        let line = format_line(&s, 80);
        assert_eq!(
            line,
            "ERROR (following error of drive 2: 5.12 mm over 4.00 mm (program line 12))"
        );
        let line = format_line(&s, 132);
        assert!(
            line.ends_with("(program line 12)) t=1234.5s line=12 x=0.00 y=207.38 q1=-"),
            "{line}"
        );
        let line = format_line(&s, 140);
        assert!(line.ends_with("q1=- [acknowledge with STOP]"), "{line}");
        // A machine at work on 80 columns: its state, the time, the positions, one class.
        let ready = Snapshot {
            state: "AUTO".into(),
            reason: String::new(),
            note: String::new(),
            ..busy()
        };
        assert_eq!(format_line(&ready, 80), "AUTO t=1234.5s line=12 x=0.00 y=207.38 q1=-");
        // Narrower than the reason: cut, with an ellipsis.
        let line = format_line(&s, 40);
        assert_eq!(line.chars().count(), 39, "{line}");
        assert!(line.ends_with('…'), "{line}");
    }

    #[test]
    fn no_value_shows_as_a_negative_zero() {
        assert_eq!(fixed(-0.0001, 2), "0.00");
        assert_eq!(fixed(-0.0, 0), "0");
        assert_eq!(fixed(-0.004, 2), "0.00");
        assert_eq!(fixed(-0.005001, 2), "-0.01");
        assert_eq!(fixed(-12.5, 2), "-12.50");
        let line = format_line(&busy(), 400);
        assert!(!line.contains("-0.00") && line.contains("x=0.00"), "{line}");
    }
}
