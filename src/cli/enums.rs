//! The command line's spelling of library enums: clap's `ValueEnum` stays out of the library
//! types, which a configuration file or another front end (the web screen) uses too.

use pkm_plc::runtime::config::TimeSourceKind;
use pkm_plc::services::io::modbus::ExchangeMode;

/// `--time-source` / `--sources`: the timers the real-time scheduler can wait on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TimeSource {
    /// The best measured on Linux: `nanosleep`.
    Auto,
    /// tokio's timer (`sleep_until` on absolute deadlines, as `tokio::time::interval` uses):
    /// 1 ms granularity.
    Tokio,
    /// A timerfd armed with an absolute deadline, registered with tokio's `AsyncFd`.
    Timerfd,
    /// `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)` on the dedicated cyclic thread.
    Nanosleep,
}

impl From<TimeSource> for TimeSourceKind {
    fn from(s: TimeSource) -> Self {
        match s {
            TimeSource::Auto => TimeSourceKind::Auto,
            TimeSource::Tokio => TimeSourceKind::Tokio,
            TimeSource::Timerfd => TimeSourceKind::Timerfd,
            TimeSource::Nanosleep => TimeSourceKind::Nanosleep,
        }
    }
}

/// `--exchange`: how a Modbus bus talks to the station.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Exchange {
    /// `image` on a serial line, `tables` over TCP.
    Auto,
    /// Four requests on the standard tables: read discrete inputs (2), read input registers
    /// (4), write coils (15), write holding registers (16). Any Modbus server with the
    /// register map will do.
    Tables,
    /// One read/write-multiple-registers transaction (23) on the packed process image. Needs a
    /// station that mirrors it (io-sim does); 36 bytes on the wire for the TRIJOINT station
    /// against 76 for `tables`, which is what makes a 10 ms cycle at 115 200 baud.
    Image,
}

impl From<Exchange> for ExchangeMode {
    fn from(e: Exchange) -> Self {
        match e {
            Exchange::Auto => ExchangeMode::Auto,
            Exchange::Tables => ExchangeMode::Tables,
            Exchange::Image => ExchangeMode::Image,
        }
    }
}
