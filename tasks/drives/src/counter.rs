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

/// `x` rounded to the nearest whole number, halves away from zero — `x.round() as i64`, to the
/// bit — without the library call `round` is on a baseline x86-64 (no SSE4.1): counters and
/// duty cycles are rounded for every joint in every fast cycle.
#[inline]
pub fn round_count(x: f64) -> i64 {
    // From 2⁵² on every f64 is whole; NaN and the infinities take the library's way too.
    if x.abs() < 4_503_599_627_370_496.0 {
        let whole = x as i64; // towards zero
        // Exact: below 2⁵², x less its whole part is representable.
        let fraction = x - whole as f64;
        if fraction >= 0.5 {
            whole + 1
        } else if fraction <= -0.5 {
            whole - 1
        } else {
            whole
        }
    } else {
        x.round() as i64
    }
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

    #[test]
    fn rounding_is_the_librarys_at_its_edges() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -2.5,
            0.49999999999999994,
            -0.49999999999999994,
            4_503_599_627_370_495.5,
            4_503_599_627_370_496.0,
            9.3e18,
            -9.3e18,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert_eq!(round_count(x), x.round() as i64, "{x}");
        }
    }

    proptest! {
        /// Any number rounds as the library rounds it.
        #[test]
        fn rounding_is_the_librarys(x in proptest::num::f64::ANY, scaled in -1.0e7f64..1.0e7) {
            prop_assert_eq!(round_count(x), x.round() as i64);
            prop_assert_eq!(round_count(scaled), scaled.round() as i64);
        }

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
