//! Absolute positions from 16-bit wrapping counters. The X20 counter modules' encoder counts and
//! the stepper modules' emitted-step counters are both 16-bit signed and wrap; the hardware gives
//! no revolution count, so the program keeps the absolute value by unwrapping every sample.

/// Unwraps a wrapping 16-bit counter: the absolute count after `previous` (absolute) saw the raw
/// counter go from `last_raw` to `raw`. Exact for any true change of less than half the counter
/// range; returns the signed change as well.
pub fn unwrap(previous: i64, last_raw: i16, raw: i16) -> (i64, i64) {
    let delta = i64::from(raw.wrapping_sub(last_raw));
    (previous + delta, delta)
}

/// The raw 16-bit counter value that shows the absolute count `count` (what a module's counter
/// register holds after counting `count` from zero).
pub fn wrap(count: i64) -> i16 {
    count as i16
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn wraps_are_counted_both_ways() {
        assert_eq!(unwrap(32_767, 32_767, -32_768), (32_768, 1));
        assert_eq!(unwrap(-32_768, -32_768, 32_767), (-32_769, -1));
        assert_eq!(unwrap(100, 100, -32_000), (-32_000, -32_100));
    }

    proptest! {
        /// Any walk of steps below half the range is followed exactly through the wrapping counter.
        #[test]
        fn unwrapping_follows_any_walk(start in -1_000_000i64..1_000_000, steps in prop::collection::vec(-32_767i64..=32_767, 1..200)) {
            let mut truth = start;
            let mut raw = wrap(start);
            let mut counted = start;
            for s in steps {
                truth += s;
                let next = wrap(truth);
                let (c, delta) = unwrap(counted, raw, next);
                prop_assert_eq!(delta, s);
                counted = c;
                raw = next;
            }
            prop_assert_eq!(counted, truth);
        }
    }
}
