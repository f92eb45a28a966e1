//! The PI position regulator of one drive, with velocity and acceleration feed-forward
//! (LinuxCNC's FF1 and FF2) and anti-windup by conditional integration.

use pkm_api::image::Declare;
use pkm_api::ranges;

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
    /// Acceleration feed-forward: output per mm/s² of set-point acceleration (the change of the
    /// set-point velocity since the last step). A drive whose speed follows its output with a
    /// lag τ needs τ · `velocity_ff` more while the set-point accelerates; without it the lag
    /// is a following error that grows with every acceleration.
    pub accel_ff: f64,
    /// Output limit (symmetric, > 0).
    pub output_limit: f64,
}

impl PiGains {
    /// Checks each gain against its range (the same for every machine); problems against
    /// `at(key)`, the key named as in the parameter files (`kp`, `ki`, `velocity_ff`, …).
    pub fn check(&self, decl: &mut Declare<'_>, at: impl Fn(&str) -> String) {
        decl.within(&at("kp"), self.kp, &ranges::PROPORTIONAL_GAIN);
        decl.within(&at("ki"), self.ki, &ranges::INTEGRAL_GAIN);
        decl.within(&at("velocity_ff"), self.velocity_ff, &ranges::VELOCITY_FF);
        decl.within(&at("accel_ff"), self.accel_ff, &ranges::ACCEL_FF);
        decl.within(&at("output_limit"), self.output_limit, &ranges::OUTPUT_LIMIT);
    }
}

/// One drive's PI regulator.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pi {
    integral: f64,
    /// The set-point velocity of the last step (for the acceleration).
    last_velocity: f64,
}

impl Pi {
    /// One step: returns the output for following error `e` (mm) over `dt` seconds at set-point
    /// velocity `v` (mm/s), clamped to the output limit.
    pub fn step(&mut self, g: &PiGains, e: f64, v: f64, dt: f64) -> f64 {
        let accel = (v - self.last_velocity) / dt;
        self.last_velocity = v;
        let unclamped = g.velocity_ff * v + g.accel_ff * accel + g.kp * e + g.ki * (self.integral + e * dt);
        let out = unclamped.clamp(-g.output_limit, g.output_limit);
        // Integrate only while the output is not saturated, or when the error drives it back.
        if out == unclamped || unclamped.signum() != e.signum() {
            self.integral += e * dt;
        }
        out
    }

    /// Forgets the integral and the last velocity (on enable and after a stop).
    pub fn reset(&mut self) {
        self.integral = 0.0;
        self.last_velocity = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GAINS: PiGains = PiGains {
        kp: 0.25,
        ki: 1.0,
        velocity_ff: 1.0 / 80.0,
        accel_ff: 0.0,
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
    fn acceleration_feed_forward_adds_the_lag_of_a_ramp() {
        let g = PiGains {
            accel_ff: 0.05 / 80.0,
            ..GAINS
        };
        let mut pi = Pi::default();
        // 0 → 2 mm/s in 10 ms: 200 mm/s², τ = 50 ms at 80 mm/s full duty: 10 mm/s more.
        let out = pi.step(&g, 0.0, 2.0, 0.01);
        assert!((out - (2.0 + 10.0) / 80.0).abs() < 1e-12, "{out}");
        // At constant speed, none.
        assert!((pi.step(&g, 0.0, 2.0, 0.01) - 2.0 / 80.0).abs() < 1e-12);
    }

    #[test]
    fn reset_forgets_the_integral() {
        let mut pi = Pi::default();
        pi.step(&GAINS, 1.0, 0.0, 0.5);
        pi.reset();
        assert_eq!(pi.step(&GAINS, 0.0, 0.0, 0.01), 0.0);
    }
}
