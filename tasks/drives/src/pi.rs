//! The PI position regulator of one drive, with velocity feed-forward (LinuxCNC's FF1) and
//! anti-windup by conditional integration.

/// Gains and limit of a [`Pi`] regulator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PiGains {
    /// Proportional gain: output per mm of following error.
    pub kp: f64,
    /// Integral gain: output per mm·s.
    pub ki: f64,
    /// Velocity feed-forward: output per mm/s of set-point velocity. With it the output that moves
    /// the drive at the set-point's speed comes from the set-point itself, so the integral need
    /// not carry it — and need not unwind, overshooting, when the set-point brakes.
    pub velocity_ff: f64,
    /// Output limit (symmetric, > 0).
    pub output_limit: f64,
}

/// One drive's PI regulator.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pi {
    integral: f64,
}

impl Pi {
    /// One step: returns the output for following error `e` (mm) over `dt` seconds at set-point
    /// velocity `v` (mm/s), clamped to the output limit.
    pub fn step(&mut self, g: &PiGains, e: f64, v: f64, dt: f64) -> f64 {
        let unclamped = g.velocity_ff * v + g.kp * e + g.ki * (self.integral + e * dt);
        let out = unclamped.clamp(-g.output_limit, g.output_limit);
        // Integrate only while the output is not saturated, or when the error drives it back.
        if out == unclamped || unclamped.signum() != e.signum() {
            self.integral += e * dt;
        }
        out
    }

    /// Forgets the integral (on enable and after a stop).
    pub fn reset(&mut self) {
        self.integral = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GAINS: PiGains = PiGains {
        kp: 0.25,
        ki: 1.0,
        velocity_ff: 1.0 / 80.0,
        output_limit: 1.0,
    };

    #[test]
    fn saturates_without_winding_up() {
        let mut pi = Pi::default();
        for _ in 0..1000 {
            assert_eq!(pi.step(&GAINS, 100.0, 0.0, 0.01), 1.0);
        }
        // After a long saturation the integral has not grown, so a small error gives a small output.
        let out = pi.step(&GAINS, 0.1, 0.0, 0.01);
        assert!(out < 0.2, "{out}");
    }

    #[test]
    fn feed_forward_alone_drives_at_the_set_point_speed() {
        let mut pi = Pi::default();
        assert_eq!(pi.step(&GAINS, 0.0, 40.0, 0.01), 0.5);
    }

    #[test]
    fn reset_forgets_the_integral() {
        let mut pi = Pi::default();
        pi.step(&GAINS, 1.0, 0.0, 0.5);
        pi.reset();
        assert_eq!(pi.step(&GAINS, 0.0, 0.0, 0.01), 0.0);
    }
}
