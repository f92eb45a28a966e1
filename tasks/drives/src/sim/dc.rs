//! A DC motor with gearbox and lead screw behind a PWM bridge: duty → carriage speed through a
//! first-order lag, a carriage between hard stops. The plant decides whether a step may be taken
//! (a jammed mechanism halts it), so a step is computed first and committed after.

/// A speed this close to the duty's (mm/s) is the duty's: the lag has settled. A nanometre per
/// second moves a carriage 3.6 µm in an hour, a fortieth of a TRIJOINT encoder count. Without
/// it a speed decaying towards rest ends as a subnormal number that each step's rounding keeps
/// from reaching zero (`v·(1 − lag)` rounds back to `v`, `v·aⁿ` too), and every later step
/// multiplies subnormals, which the CPU does tens of times slower than normal numbers: a
/// standing TRIJOINT's simulated hour took 4.8× the CPU time it takes with them flushed.
const SETTLED_MM_S: f64 = 1e-9;

/// `v`, or `u` where `v` is within [`SETTLED_MM_S`] of it.
#[inline]
fn settled(v: f64, u: f64) -> f64 {
    if (v - u).abs() < SETTLED_MM_S { u } else { v }
}

/// One DC-driven carriage.
#[derive(Clone, Debug)]
pub struct DcAxis {
    v_max_mm_s: f64,
    tau_s: f64,
    hard_stops: [f64; 2],
    position_mm: f64,
    velocity_mm_s: f64,
    /// The step the lag factor was computed for, and the factor 1 − e^(−dt/τ).
    lag: (f64, f64),
    /// The span [`DcAxis::span`] last computed its factors for (step, number of steps), and
    /// those factors: e^(−n·dt/τ) and Σₖ₌₁ⁿ e^(−k·dt/τ).
    span_lag: ((f64, u64), f64, f64),
}

/// Where a carriage ends a span of steps ([`DcAxis::span`]), for [`DcAxis::commit_span`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpanEnd {
    /// The position at the span's end (mm).
    pub position_mm: f64,
    /// The speed at the span's end (mm/s).
    pub velocity_mm_s: f64,
}

impl DcAxis {
    /// A carriage at `start_mm`, at rest; `v_max_mm_s` at full duty after a lag of `tau_s`,
    /// between the hard stops `[min, max]` (mm).
    pub fn new(v_max_mm_s: f64, tau_s: f64, hard_stops: [f64; 2], start_mm: f64) -> DcAxis {
        DcAxis {
            v_max_mm_s,
            tau_s,
            hard_stops,
            position_mm: start_mm,
            velocity_mm_s: 0.0,
            lag: (f64::NAN, 0.0),
            span_lag: ((f64::NAN, 0), 0.0, 0.0),
        }
    }

    /// Updates the speed for `duty` (−1 … 1) over a step of `dt_s` and returns where the carriage
    /// would be at its end, stopped at a hard stop; [`DcAxis::commit`] takes it there.
    #[inline]
    pub fn advance(&mut self, duty: f64, dt_s: f64) -> f64 {
        if self.lag.0 != dt_s {
            // Exact discretisation of the first-order lag over a step of dt.
            self.lag = (dt_s, 1.0 - (-dt_s / self.tau_s).exp());
        }
        let u = duty.clamp(-1.0, 1.0) * self.v_max_mm_s;
        self.velocity_mm_s = settled(self.velocity_mm_s + (u - self.velocity_mm_s) * self.lag.1, u);
        let mut next = self.position_mm + self.velocity_mm_s * dt_s;
        if next <= self.hard_stops[0] {
            next = self.hard_stops[0];
            self.velocity_mm_s = self.velocity_mm_s.max(0.0);
        } else if next >= self.hard_stops[1] {
            next = self.hard_stops[1];
            self.velocity_mm_s = self.velocity_mm_s.min(0.0);
        }
        next
    }

    /// Where `n` steps of [`DcAxis::advance`] at a constant `duty` would take the carriage, in
    /// closed form (the simulated hour's hot path: one evaluation for a 10 ms cycle's ten 1 ms
    /// steps); `None` where a hard stop may be reached within them (the caller then steps).
    ///
    /// The steps are `vₖ = u + (vₖ₋₁ − u)·a` and `xₖ = xₖ₋₁ + vₖ·dt` with `a = e^(−dt/τ)` and `u`
    /// the duty's speed, so `vₙ = u + (v₀ − u)·aⁿ` and `xₙ = x₀ + dt·(n·u + (v₀ − u)·Σₖ₌₁ⁿ aᵏ)`:
    /// the stepped result up to rounding. The speed moves monotonically from `v₀` to `u`, so no
    /// step goes further than `n·dt·max(|v₀|, |u|)`: within that of a hard stop, the span is
    /// refused.
    #[inline]
    pub fn span(&mut self, duty: f64, dt_s: f64, n: u64) -> Option<SpanEnd> {
        if self.span_lag.0 != (dt_s, n) {
            let a = (-dt_s / self.tau_s).exp();
            let a_n = (-(n as f64) * dt_s / self.tau_s).exp();
            // a·(1 − aⁿ)/(1 − a), with 1 − a from expm1 (dt ≪ τ loses digits otherwise).
            let sum = a * (1.0 - a_n) / -(-dt_s / self.tau_s).exp_m1();
            self.span_lag = ((dt_s, n), a_n, sum);
        }
        let (_, a_n, sum) = self.span_lag;
        let u = duty.clamp(-1.0, 1.0) * self.v_max_mm_s;
        let v0 = self.velocity_mm_s;
        let reach = n as f64 * dt_s * v0.abs().max(u.abs());
        if self.position_mm - reach <= self.hard_stops[0] || self.position_mm + reach >= self.hard_stops[1] {
            return None;
        }
        Some(SpanEnd {
            position_mm: self.position_mm + dt_s * (n as f64 * u + (v0 - u) * sum),
            velocity_mm_s: settled(u + (v0 - u) * a_n, u),
        })
    }

    /// Takes the carriage to the end of a span ([`DcAxis::span`]).
    #[inline]
    pub fn commit_span(&mut self, end: SpanEnd) {
        self.position_mm = end.position_mm;
        self.velocity_mm_s = end.velocity_mm_s;
    }

    /// Takes the carriage to `position_mm` (the result of [`DcAxis::advance`]).
    #[inline]
    pub fn commit(&mut self, position_mm: f64) {
        self.position_mm = position_mm;
    }

    /// The mechanism blocks the step: the carriage stands still.
    #[inline]
    pub fn halt(&mut self) {
        self.velocity_mm_s = 0.0;
    }

    /// The carriage's true position (mm).
    #[inline]
    pub fn position_mm(&self) -> f64 {
        self.position_mm
    }

    /// The carriage's true speed (mm/s).
    #[inline]
    pub fn velocity_mm_s(&self) -> f64 {
        self.velocity_mm_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn it_reaches_its_speed_with_the_lag_and_stops_at_the_hard_stops() {
        let mut a = DcAxis::new(80.0, 0.05, [-3.0, 253.0], 125.0);
        for _ in 0..50 {
            let next = a.advance(1.0, 0.001);
            a.commit(next);
        }
        // One time constant: 1 − 1/e of full speed.
        assert!((a.velocity_mm_s() - 80.0 * (1.0 - (-1.0f64).exp())).abs() < 1e-9);
        for _ in 0..5000 {
            let next = a.advance(1.0, 0.001);
            a.commit(next);
        }
        assert_eq!(a.position_mm(), 253.0);
        assert_eq!(a.velocity_mm_s(), 0.0);
        let next = a.advance(-1.0, 0.001);
        assert!(next < 253.0, "it leaves the stop backwards");
        a.halt();
        assert_eq!(a.velocity_mm_s(), 0.0);
    }

    /// `n` steps of `advance` with `duty`, committed.
    fn stepped(a: &mut DcAxis, duty: f64, dt: f64, n: u64) {
        for _ in 0..n {
            let next = a.advance(duty, dt);
            a.commit(next);
        }
    }

    #[test]
    fn a_span_ends_where_its_steps_do_and_is_refused_near_a_hard_stop() {
        let mut spanned = DcAxis::new(80.0, 0.05, [-3.0, 253.0], 125.0);
        let mut steps = spanned.clone();
        // Speeding up, reversing, slowing down: ten cycles of ten 1 ms steps each way.
        for duty in [1.0, 1.0, -0.5, -0.5, 0.2, 0.0, 0.0, 2.0, -3.0, 0.3] {
            let end = spanned.span(duty, 0.001, 10).expect("far from the stops");
            spanned.commit_span(end);
            stepped(&mut steps, duty, 0.001, 10);
            assert!((spanned.position_mm() - steps.position_mm()).abs() < 1e-9);
            assert!((spanned.velocity_mm_s() - steps.velocity_mm_s()).abs() < 1e-9);
        }
        // 0.4 mm from the stop at full speed: ten steps may reach it.
        let mut near = DcAxis::new(40.0, 0.05, [-3.0, 253.0], 252.7);
        assert_eq!(near.span(1.0, 0.001, 10), None);
        assert!(
            near.span(-1.0, 0.001, 10).is_none(),
            "either way: the bound is symmetric"
        );
        let far = DcAxis::new(40.0, 0.05, [-3.0, 253.0], 252.5).span(1.0, 0.001, 10);
        assert!(far.is_some_and(|e| e.position_mm < 253.0));
    }

    /// A carriage coming to rest comes to exactly zero speed, whether stepped or spanned, and
    /// never holds a subnormal speed (which every later step would multiply, slowly).
    #[test]
    fn a_carriage_at_rest_has_exactly_zero_speed() {
        let mut stepped = DcAxis::new(80.0, 0.05, [-3.0, 253.0], 125.0);
        let mut spanned = stepped.clone();
        for _ in 0..100 {
            let next = stepped.advance(1.0, 0.001);
            stepped.commit(next);
            let end = spanned.span(1.0, 0.001, 10).expect("far from the stops");
            spanned.commit_span(end);
        }
        for _ in 0..200_000 {
            let next = stepped.advance(0.0, 0.001);
            stepped.commit(next);
            assert!(!stepped.velocity_mm_s().is_subnormal());
        }
        for _ in 0..20_000 {
            let end = spanned.span(0.0, 0.001, 10).expect("far from the stops");
            spanned.commit_span(end);
            assert!(!spanned.velocity_mm_s().is_subnormal());
        }
        assert_eq!(stepped.velocity_mm_s(), 0.0);
        assert_eq!(spanned.velocity_mm_s(), 0.0);
    }

    proptest::proptest! {
        /// Any speed, duty, time constant and span: the closed form is the stepped result, and a
        /// span it refuses is one whose steps come near a hard stop.
        #[test]
        fn a_span_is_its_steps(
            v0 in -1.0f64..1.0,
            duty in -1.5f64..1.5,
            tau in 0.005f64..0.5,
            v_max in 1.0f64..100.0,
            start in -2.0f64..252.0,
            n in 1u64..40,
        ) {
            let mut spanned = DcAxis::new(v_max, tau, [-3.0, 253.0], start);
            // A start at speed v0·v_max: one long step at that duty from rest, then back to start.
            stepped(&mut spanned, v0, 10.0, 1);
            spanned.commit(start);
            let mut steps = spanned.clone();
            let before = steps.position_mm();
            match spanned.span(duty, 0.001, n) {
                Some(end) => {
                    stepped(&mut steps, duty, 0.001, n);
                    let scale = 1.0 + v_max;
                    proptest::prop_assert!((end.position_mm - steps.position_mm()).abs() < 1e-11 * scale);
                    proptest::prop_assert!((end.velocity_mm_s - steps.velocity_mm_s()).abs() < 1e-11 * scale);
                }
                None => {
                    let reach = n as f64 * 0.001 * v_max * v0.abs().max(duty.abs().min(1.0));
                    proptest::prop_assert!(before - reach <= -3.0 + 1e-9 || before + reach >= 253.0 - 1e-9);
                }
            }
        }
    }
}
