//! Running as a service (systemd, `Type=notify`, see `packaging/pkm-plc.service`): the
//! notifications the service manager waits for, and a log format whose levels the journal reads.
//!
//! - `READY=1` once every task class has run a cycle with a complete input image (no bus fault):
//!   a PLC whose station never answers never becomes ready, and the manager's start timeout
//!   restarts it.
//! - `WATCHDOG=1` every half of the manager's `WatchdogSec`, and only while the cyclic thread
//!   makes progress (its heartbeat, the release time of its latest pass, has advanced): a hung
//!   cycle stops the messages, the manager kills and restarts the PLC, and meanwhile the
//!   station's own watchdog has set the outputs safe.
//! - `STATUS=` the main state (and its reason), for `systemctl status`; `STOPPING=1` at a stop.
//!
//! Nothing here runs on the cyclic thread.

use std::fmt;
use std::time::{Duration, Instant};

use sd_notify::NotifyState;
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields};
use tracing_subscriber::registry::LookupSpan;

/// The notifications of one run, when a service manager asked for them (`NOTIFY_SOCKET`).
#[derive(Debug)]
pub struct Notifier {
    /// The manager's watchdog time, if it runs one (`WATCHDOG_USEC`).
    watchdog: Option<Duration>,
    ready: bool,
    /// The heartbeat at the last `WATCHDOG=1`.
    beat_at_ping: Option<u64>,
    last_ping: Instant,
    status: String,
}

impl Notifier {
    /// A notifier when the process was started with `NOTIFY_SOCKET`, else `None`.
    pub fn from_env() -> Option<Notifier> {
        std::env::var_os("NOTIFY_SOCKET")?;
        let watchdog = sd_notify::watchdog_enabled();
        match watchdog {
            Some(w) => tracing::info!(
                "service manager: READY once running, WATCHDOG every {} ms while the cycles run",
                (w / 2).as_millis()
            ),
            None => tracing::info!("service manager: READY once running (no watchdog asked for)"),
        }
        Some(Notifier {
            watchdog,
            ready: false,
            beat_at_ping: None,
            last_ping: Instant::now(),
            status: String::new(),
        })
    }

    /// Called every few milliseconds with whether the PLC runs (`running`: every class has run
    /// a cycle with a complete input image), the cyclic thread's `heartbeat` and the main
    /// `state` for people.
    pub fn tick(&mut self, running: bool, heartbeat: u64, state: &str) {
        if running && !self.ready {
            self.ready = true;
            self.send(&[NotifyState::Ready]);
            tracing::info!("service manager: READY");
        }
        if !state.is_empty() && state != self.status {
            self.status.clear();
            self.status.push_str(state);
            self.send(&[NotifyState::Status(state)]);
        }
        let Some(watchdog) = self.watchdog else { return };
        // Fed at half the manager's time, and only when the cycles went on since the last feed.
        if self.last_ping.elapsed() >= watchdog / 2 && self.beat_at_ping != Some(heartbeat) {
            self.send(&[NotifyState::Watchdog]);
            self.beat_at_ping = Some(heartbeat);
            self.last_ping = Instant::now();
        }
    }

    /// The run is stopping.
    pub fn stopping(&mut self) {
        self.send(&[NotifyState::Stopping]);
    }

    fn send(&self, state: &[NotifyState<'_>]) {
        if let Err(e) = sd_notify::notify(state) {
            tracing::debug!("service manager: cannot notify: {e}");
        }
    }
}

/// Whether stderr goes to the journal: systemd sets `JOURNAL_STREAM` for a service whose output
/// it collects.
pub fn logging_to_journal() -> bool {
    std::env::var_os("JOURNAL_STREAM").is_some()
}

/// Log lines as the journal reads them from a service's stderr: a `<N>` priority prefix (3 error,
/// 4 warning, 6 info, 7 debug), then the message and its fields; no time stamp (the journal
/// keeps its own) and no colour.
pub struct JournalFormat;

impl JournalFormat {
    /// The syslog priority of `level`.
    pub fn priority(level: &Level) -> u8 {
        match *level {
            Level::ERROR => 3,
            Level::WARN => 4,
            Level::INFO => 6,
            _ => 7,
        }
    }
}

impl<S, N> FormatEvent<S, N> for JournalFormat
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(&self, ctx: &FmtContext<'_, S, N>, mut writer: Writer<'_>, event: &Event<'_>) -> fmt::Result {
        write!(writer, "<{}>", JournalFormat::priority(event.metadata().level()))?;
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        writeln!(writer)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_map_to_syslog_priorities() {
        assert_eq!(JournalFormat::priority(&Level::ERROR), 3);
        assert_eq!(JournalFormat::priority(&Level::WARN), 4);
        assert_eq!(JournalFormat::priority(&Level::INFO), 6);
        assert_eq!(JournalFormat::priority(&Level::DEBUG), 7);
        assert_eq!(JournalFormat::priority(&Level::TRACE), 7);
    }
}
