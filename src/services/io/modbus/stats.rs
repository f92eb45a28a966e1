//! The Modbus link's counters: what the exchange loop counts and what the summary reports.

use std::sync::atomic::{AtomicU64, Ordering};

use super::ExchangeMode;
use super::exchange::Failure;

/// Counters of the exchange loop.
#[derive(Debug)]
pub struct LinkStats {
    /// Successful exchanges.
    pub exchanges: AtomicU64,
    /// Requests that timed out with nothing received.
    pub timeouts: AtomicU64,
    /// Responses that arrived damaged: a bad CRC or bytes no valid frame could be made of.
    pub corrupt: AtomicU64,
    /// Exception responses.
    pub exceptions: AtomicU64,
    /// Lost or refused connections.
    pub disconnects: AtomicU64,
    /// Times the newest input image grew older than the bound (`max_input_age`).
    pub stale: AtomicU64,
    /// Times the exchanges grew slower on average than the bound (`max_exchange`).
    pub slow: AtomicU64,
    /// Summed duration of the successful exchanges (ns).
    pub exchange_ns_total: AtomicU64,
    /// Longest successful exchange (ns).
    pub exchange_ns_max: AtomicU64,
    /// Shortest successful exchange (ns; `u64::MAX` before the first).
    pub exchange_ns_min: AtomicU64,
}

impl Default for LinkStats {
    fn default() -> Self {
        LinkStats {
            exchanges: AtomicU64::new(0),
            timeouts: AtomicU64::new(0),
            corrupt: AtomicU64::new(0),
            exceptions: AtomicU64::new(0),
            disconnects: AtomicU64::new(0),
            stale: AtomicU64::new(0),
            slow: AtomicU64::new(0),
            exchange_ns_total: AtomicU64::new(0),
            exchange_ns_max: AtomicU64::new(0),
            exchange_ns_min: AtomicU64::new(u64::MAX),
        }
    }
}

impl LinkStats {
    /// Counts a successful exchange that took `ns`.
    pub(super) fn succeeded(&self, ns: u64) {
        self.exchange_ns_total.fetch_add(ns, Ordering::Relaxed);
        self.exchange_ns_max.fetch_max(ns, Ordering::Relaxed);
        self.exchange_ns_min.fetch_min(ns, Ordering::Relaxed);
        self.exchanges.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts a failed exchange under its kind.
    pub(super) fn failed(&self, failure: Failure) {
        let counter = match failure {
            Failure::Timeout => &self.timeouts,
            Failure::Corrupt => &self.corrupt,
            Failure::Exception => &self.exceptions,
            Failure::Disconnected => &self.disconnects,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// One line for the log at the end of a run: exchanges (in `mode`), their mean and longest
    /// duration, and every kind of failure.
    pub fn summary(&self, mode: ExchangeMode) -> String {
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let n = get(&self.exchanges);
        format!(
            "{n} exchanges ({}), mean {:.0} µs, max {:.0} µs; {} timeouts, {} corrupt, {} exceptions, {} disconnects, {} stale, {} slow",
            mode.name(),
            get(&self.exchange_ns_total) as f64 / n.max(1) as f64 / 1e3,
            get(&self.exchange_ns_max) as f64 / 1e3,
            get(&self.timeouts),
            get(&self.corrupt),
            get(&self.exceptions),
            get(&self.disconnects),
            get(&self.stale),
            get(&self.slow)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_successes_and_each_kind_of_failure() {
        let s = LinkStats::default();
        s.succeeded(2_000);
        s.succeeded(4_000);
        s.failed(Failure::Timeout);
        s.failed(Failure::Corrupt);
        s.failed(Failure::Corrupt);
        s.failed(Failure::Disconnected);
        assert_eq!(s.exchange_ns_min.load(Ordering::Relaxed), 2_000);
        assert_eq!(
            s.summary(ExchangeMode::Image),
            "2 exchanges (image), mean 3 µs, max 4 µs; 1 timeouts, 2 corrupt, 0 exceptions, 1 disconnects, 0 stale, 0 slow"
        );
    }
}
