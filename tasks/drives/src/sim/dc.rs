//! A DC motor with gearbox and lead screw behind a PWM bridge: duty → carriage speed through a
//! first-order lag, a carriage between hard stops. The plant decides whether a step may be taken
//! (a jammed mechanism halts it), so a step is computed first and committed after.

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
        self.velocity_mm_s += (duty.clamp(-1.0, 1.0) * self.v_max_mm_s - self.velocity_mm_s) * self.lag.1;
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
    pub fn position_mm(&self) -> f64 {
        self.position_mm
    }

    /// The carriage's true speed (mm/s).
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
}
