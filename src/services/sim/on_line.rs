//! A station served as Modbus RTU behind an emulated serial line, on a thread of its own.

use std::os::unix::net::UnixStream;

use super::modbus::{Station, StationReport};
use super::server::{ServerOptions, serve_rtu};

/// A station served as Modbus RTU at the far end of an emulated serial line
/// ([`crate::services::io::line`]), on its own thread: what `link-bench` and the RTU end-to-end test talk
/// to. Dropping it stops the line and the station.
pub struct StationOnLine {
    line: Option<crate::services::io::line::PacedLine>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<Option<StationReport>>>,
}

impl StationOnLine {
    /// Serves `station` behind a line with `timing` and the server's `options`; returns it with
    /// the driver's end of the line (to be handed to `Transport::Stream`).
    pub fn start(
        station: Station,
        timing: crate::services::io::line::LineTiming,
        options: ServerOptions,
    ) -> std::io::Result<(StationOnLine, UnixStream)> {
        let (station_end, line_a) = UnixStream::pair()?;
        let (line_b, driver_end) = UnixStream::pair()?;
        station_end.set_nonblocking(true)?;
        // Built here, so that a failure is an error of the caller's rather than a silent thread.
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("station-on-line".into())
            .spawn(move || {
                crate::services::io::line::hardware_priority();
                runtime.block_on(async move {
                    // Registered with the reactor here, in the station's runtime.
                    let stream = match tokio::net::UnixStream::from_std(station_end) {
                        Ok(stream) => stream,
                        Err(e) => {
                            tracing::error!("station on line: cannot use its end of the line: {e}");
                            return None;
                        }
                    };
                    let stop = async {
                        let _ = stopped.await;
                    };
                    serve_rtu(stream, station, options, stop).await.ok()
                })
            })?;
        let line = crate::services::io::line::PacedLine::start(line_a, line_b, timing)?;
        let served = StationOnLine {
            line: Some(line),
            stop: Some(stop),
            thread: Some(thread),
        };
        Ok((served, driver_end))
    }

    /// Stops the line and the station; returns what the machine did ([`StationReport`]), if
    /// the station was still serving.
    pub fn stop(mut self) -> Option<StationReport> {
        self.shut_down()
    }

    fn shut_down(&mut self) -> Option<StationReport> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let report = self.thread.take().and_then(|t| t.join().ok()).flatten();
        drop(self.line.take());
        report
    }
}

impl Drop for StationOnLine {
    fn drop(&mut self) {
        self.shut_down();
    }
}
