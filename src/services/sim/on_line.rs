//! A station served as Modbus RTU behind an emulated serial line, on a thread of its own.

use super::modbus::Station;
use super::server::{ServerOptions, serve_rtu};

/// A station served as Modbus RTU at the far end of an emulated serial line
/// ([`crate::services::io::line`]), on its own thread: what `link-bench` and the RTU end-to-end test talk
/// to. Dropping it stops the line and the station.
pub struct StationOnLine {
    line: Option<crate::services::io::line::PacedLine>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl StationOnLine {
    /// Serves `station` behind a line with `timing` and the server's `options`; returns it with
    /// the driver's end of the line (to be handed to `Transport::Port`).
    pub fn start(
        station: Station,
        timing: crate::services::io::line::LineTiming,
        options: ServerOptions,
    ) -> std::io::Result<(StationOnLine, serialport::TTYPort)> {
        let (station_end, line_a) = crate::services::io::line::pty_pair()?;
        let (line_b, driver_end) = crate::services::io::line::pty_pair()?;
        // Built here, so that a failure is an error of the caller's rather than a silent thread.
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("station-on-line".into())
            .spawn(move || {
                crate::services::io::line::hardware_priority();
                runtime.block_on(async move {
                    // Registered with the reactor here, in the station's runtime.
                    let Ok(stream) = tokio_serial::SerialStream::try_from(station_end) else {
                        tracing::error!("station on line: cannot use the pseudo-terminal");
                        return;
                    };
                    tokio::select! {
                        _ = serve_rtu(stream, station, options) => {}
                        _ = stopped => {}
                    }
                });
            })?;
        let line = crate::services::io::line::PacedLine::start(line_a, line_b, timing)?;
        let served = StationOnLine {
            line: Some(line),
            stop: Some(stop),
            thread: Some(thread),
        };
        Ok((served, driver_end))
    }
}

impl Drop for StationOnLine {
    fn drop(&mut self) {
        drop(self.line.take());
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
