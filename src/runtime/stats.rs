//! Cycle statistics: execution time and start lateness per task class.
//!
//! Recording never allocates (the histogram is sized once), so it can run in the cyclic path.

use hdrhistogram::Histogram;
use serde::Serialize;

/// Largest value the histograms resolve (100 s in ns); larger values saturate.
const HIST_MAX_NS: u64 = 100_000_000_000;

/// Min, max, mean and a histogram (1 % resolution) of one measured quantity, in nanoseconds.
#[derive(Clone, Debug)]
pub struct Stat {
    count: u64,
    sum: u128,
    min: u64,
    max: u64,
    hist: Histogram<u64>,
}

impl Default for Stat {
    fn default() -> Self {
        Self::new()
    }
}

impl Stat {
    /// An empty statistic.
    pub fn new() -> Self {
        let hist = match Histogram::new_with_bounds(1, HIST_MAX_NS, 2) {
            Ok(h) => h,
            // Constant, valid bounds: failure would be a bug in this file.
            Err(e) => panic!("histogram bounds are constant and valid: {e}"),
        };
        Stat {
            count: 0,
            sum: 0,
            min: u64::MAX,
            max: 0,
            hist,
        }
    }

    /// Records one value.
    #[inline]
    pub fn record(&mut self, ns: u64) {
        self.count += 1;
        self.sum += u128::from(ns);
        self.min = self.min.min(ns);
        self.max = self.max.max(ns);
        self.hist.saturating_record(ns.min(HIST_MAX_NS));
    }

    /// Number of values recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Largest value recorded (0 when empty).
    pub fn max_ns(&self) -> u64 {
        self.max
    }

    /// Mean of the values (0 when empty).
    pub fn mean_ns(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum as f64 / self.count as f64
        }
    }

    /// The value at quantile `q` (0..1), to the histogram's 1 % resolution.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        // The histogram answers with the top of a 1 % bucket; clamp to what was really seen.
        if self.count == 0 {
            0
        } else {
            self.hist.value_at_quantile(q).clamp(self.min, self.max)
        }
    }

    /// A summary in microseconds.
    pub fn summary_us(&self) -> StatSummary {
        let us = |ns: f64| (ns / 1000.0 * 1000.0).round() / 1000.0;
        if self.count == 0 {
            return StatSummary::default();
        }
        StatSummary {
            min: us(self.min as f64),
            mean: us(self.mean_ns()),
            p50: us(self.quantile_ns(0.50) as f64),
            p99: us(self.quantile_ns(0.99) as f64),
            max: us(self.max as f64),
        }
    }
}

/// min / mean / p50 / p99 / max in microseconds (three decimals).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StatSummary {
    /// Smallest value.
    pub min: f64,
    /// Mean value.
    pub mean: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest value.
    pub max: f64,
}

/// Everything measured of one task class.
#[derive(Clone, Debug, Default)]
pub struct ClassStats {
    /// Cycles run.
    pub cycles: u64,
    /// Releases skipped because an earlier cycle ended after the whole window of that release.
    pub missed: u64,
    /// Cycles that ended after their deadline (release + cycle time).
    pub overruns: u64,
    /// Overruns beyond the tolerance: cycle time violations, which trigger the configured reaction.
    pub violations: u64,
    /// Execution time from cycle start (after input latching began) to published outputs.
    pub exec: Stat,
    /// Start lateness: actual start minus nominal release.
    pub lateness: Stat,
}
