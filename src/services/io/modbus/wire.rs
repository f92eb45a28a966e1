//! What one exchange takes on a serial line, known before the line is opened: its frames at the
//! baud rate and the silent intervals between them. A line on which that alone reaches the
//! exchange time the drive regulators are tuned for (`--max-exchange-ms`) would make every
//! exchange a bus fault, so the run is refused with the figures; one that leaves less than
//! [`LINE_MARGIN`] for the rest of the exchange runs with a warning.

use std::time::Duration;

use super::{ExchangeMode, WireLoad};
use crate::services::io::line::LineTiming;

/// What an exchange needs beyond its time on the wire: the station's turnaround (from the end
/// of a request to the start of its answer) and the PC's latency in handing the answer to the
/// exchange thread. Measured over emulated lines on a virtual machine whose host holds a CPU
/// for one to two milliseconds now and then: with 0.68 ms left (a 40-byte image at 115 200
/// baud) the median of five exchanges went over the bound in about one run in three, and three
/// runs in a row once; with 1.06 ms (the TRIJOINT's 36 bytes) no run did.
pub const LINE_MARGIN: Duration = Duration::from_millis(1);

/// The baud rates serial ports and Modbus RTU stations commonly offer, for a suggestion.
pub const STANDARD_BAUDS: [u32; 8] = [9_600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600];

/// One exchange's time on a serial line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WireTime {
    /// The exchange (never `Auto`).
    pub mode: ExchangeMode,
    /// The tables it carries: `[coils, discrete inputs, input registers, holding registers]`.
    pub sizes: [u16; 4],
    /// Its frames.
    pub load: WireLoad,
    /// The line's baud rate.
    pub baud: u32,
    /// Its frames at `baud` and a silent interval after each (ns).
    pub ns: u64,
}

impl WireTime {
    /// The exchange `mode` over tables of `sizes` on a Modbus RTU line at `baud`.
    pub fn of(mode: ExchangeMode, sizes: [u16; 4], baud: u32) -> WireTime {
        let load = WireLoad::of(mode, sizes);
        WireTime {
            mode,
            sizes,
            load,
            baud,
            ns: load.on_line(&LineTiming::modbus_rtu(baud)),
        }
    }

    /// What the exchange leaves of `bound` (zero when it needs all of it or more).
    pub fn leaves(&self, bound: Duration) -> Duration {
        bound.saturating_sub(Duration::from_nanos(self.ns))
    }

    /// The first standard baud rate above this one at which the exchange leaves
    /// [`LINE_MARGIN`] of `bound`, with its time there.
    pub fn faster_line(&self, bound: Duration) -> Option<WireTime> {
        STANDARD_BAUDS
            .into_iter()
            .filter(|&baud| baud > self.baud)
            .map(|baud| WireTime::of(self.mode, self.sizes, baud))
            .find(|t| t.leaves(bound) >= LINE_MARGIN)
    }

    /// The exchange as a log line names it: `image, 40 bytes in 1 transaction, 7.32 ms at
    /// 115200 baud`.
    pub fn describe(&self) -> String {
        let n = self.load.transactions;
        format!(
            "{}, {} bytes in {n} transaction{}, {:.2} ms at {} baud",
            self.mode.name(),
            self.load.bytes,
            if n == 1 { "" } else { "s" },
            ms(self.ns),
            self.baud
        )
    }

    /// What to do instead, for `bound`: a faster line (`a faster line will do: 230400 baud
    /// takes 5.41 ms`), or why none will.
    fn suggestion(&self, bound: Duration) -> String {
        let fastest = STANDARD_BAUDS[STANDARD_BAUDS.len() - 1];
        match (self.faster_line(bound), self.mode) {
            (Some(t), _) => format!("a faster line will do: {} baud takes {:.2} ms", t.baud, ms(t.ns)),
            (None, ExchangeMode::Tables) => format!(
                "no standard baud rate up to {fastest} leaves {} ms for {} transactions: --exchange image sends one",
                LINE_MARGIN.as_millis(),
                self.load.transactions
            ),
            (None, _) => format!(
                "no standard baud rate up to {fastest} leaves {} ms: a station on Modbus TCP will do",
                LINE_MARGIN.as_millis()
            ),
        }
    }

    /// Checks the line against `bound` (`--max-exchange-ms`): `Err` with why when the wire alone
    /// takes it all, a warning when it leaves less than [`LINE_MARGIN`], else `Ok(None)`.
    pub fn check(&self, bound: Duration) -> Result<Option<String>, String> {
        let left = self.leaves(bound);
        if left.is_zero() {
            return Err(format!(
                "one exchange ({}) takes longer on the wire than the {} ms an exchange may take \
                 (--max-exchange-ms, what the drive regulators are tuned for): every exchange would \
                 be a bus fault; {}; or a larger --max-exchange-ms once the regulators are checked \
                 for slower inputs",
                self.describe(),
                bound.as_millis(),
                self.suggestion(bound)
            ));
        }
        if left < LINE_MARGIN {
            return Ok(Some(format!(
                "one exchange ({}) leaves {:.2} ms of the {} ms an exchange may take \
                 (--max-exchange-ms) for the station's turnaround and this computer's latency: when \
                 they take more, three exchanges in five, the link is a bus fault (too slow); {}",
                self.describe(),
                left.as_secs_f64() * 1e3,
                bound.as_millis(),
                self.suggestion(bound)
            )));
        }
        Ok(None)
    }
}

fn ms(ns: u64) -> f64 {
    ns as f64 / 1e6
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The TRIJOINT's station: 18 coils, 18 discrete inputs, 2 input and 3 holding registers.
    const TRIJOINT: [u16; 4] = [18, 18, 2, 3];

    fn bound() -> Duration {
        Duration::from_millis(8)
    }

    #[test]
    fn the_trijoints_image_at_115200_baud_runs_without_a_word() {
        let t = WireTime::of(ExchangeMode::Image, TRIJOINT, 115_200);
        // 36 bytes of 11 bits at 115 200 baud (3.44 ms) and two silent intervals of 1.75 ms.
        assert_eq!(t.load.bytes, 36);
        assert!((ms(t.ns) - 6.94).abs() < 0.005, "{}", ms(t.ns));
        assert_eq!(t.check(bound()), Ok(None));
    }

    #[test]
    fn the_four_tables_at_115200_baud_are_refused_with_a_faster_line() {
        let t = WireTime::of(ExchangeMode::Tables, TRIJOINT, 115_200);
        let why = t.check(bound()).expect_err("21.26 ms is over 8 ms");
        assert_eq!(
            why,
            "one exchange (tables, 76 bytes in 4 transactions, 21.26 ms at 115200 baud) takes longer on the \
             wire than the 8 ms an exchange may take (--max-exchange-ms, what the drive regulators are tuned \
             for): every exchange would be a bus fault; no standard baud rate up to 921600 leaves 1 ms for 4 \
             transactions: --exchange image sends one; or a larger --max-exchange-ms once the regulators are \
             checked for slower inputs"
        );
    }

    #[test]
    fn a_line_with_less_than_a_millisecond_to_spare_is_said_with_the_next_rate_that_has_it() {
        // Two more output registers than the TRIJOINT's image: 40 bytes, as pn101's.
        let t = WireTime::of(ExchangeMode::Image, [18, 18, 2, 5], 115_200);
        assert_eq!(t.load.bytes, 40);
        let warning = t.check(bound()).expect("runs").expect("a warning");
        assert_eq!(
            warning,
            "one exchange (image, 40 bytes in 1 transaction, 7.32 ms at 115200 baud) leaves 0.68 ms of the 8 ms \
             an exchange may take (--max-exchange-ms) for the station's turnaround and this computer's latency: \
             when they take more, three exchanges in five, the link is a bus fault (too slow); a faster line \
             will do: 230400 baud takes 5.41 ms"
        );
    }

    #[test]
    fn the_exchange_time_falls_with_the_baud_rate_to_the_silent_intervals() {
        // Property over every standard rate and sizes up to the image's limits: the time on the
        // wire is the frames' characters of 11 bits plus 1.75 ms per frame above 19 200 baud,
        // and a faster line never takes longer.
        for sizes in [[1, 1, 1, 1], TRIJOINT, [64, 64, 16, 16], [0, 96, 0, 48]] {
            for mode in [ExchangeMode::Image, ExchangeMode::Tables] {
                let times: Vec<WireTime> = STANDARD_BAUDS.iter().map(|&b| WireTime::of(mode, sizes, b)).collect();
                for t in &times {
                    let chars_ns = t.load.bytes as f64 * 11.0 / t.baud as f64 * 1e9;
                    let silent_ns = if t.baud > 19_200 {
                        1.75e6
                    } else {
                        3.5 * 11.0 / t.baud as f64 * 1e9
                    };
                    let expected = chars_ns + 2.0 * t.load.transactions as f64 * silent_ns;
                    assert!(
                        (t.ns as f64 - expected).abs() < 1e3 * t.load.bytes as f64,
                        "{t:?}: {expected}"
                    );
                }
                assert!(times.windows(2).all(|w| w[1].ns <= w[0].ns), "{times:?}");
            }
        }
    }
}
