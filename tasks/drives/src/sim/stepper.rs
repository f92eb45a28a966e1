//! A stepper motor on a lead screw behind one channel of an X20-like stepper module: the module
//! emits steps at the commanded rate and counts them (a 16-bit wrapping counter); the motor
//! follows while the rate and its change stay within its pull-out limits, and **loses steps**
//! beyond them — it stalls, the counter still counts, the carriage does not move. A stalled motor
//! catches the step train again once the commanded rate is within its pull-in rate (the rate it
//! can start at without a ramp). A carriage driven against a hard stop or a jammed mechanism
//! stalls too. Open-loop control cannot see any of this; [`Stepper::lost_steps`] lets tests.

use crate::counter::wrap;

/// A stepper drive's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepperParams {
    /// Steps per mm of carriage travel.
    pub steps_per_mm: f64,
    /// Above this speed (mm/s) the motor falls out of step.
    pub pull_out_speed_mm_s: f64,
    /// The fastest the rotor's speed can change (mm/s²): the rotor's speed follows the commanded
    /// speed at most this fast, and a commanded speed that runs ahead of it by more than the
    /// pull-in speed makes the motor fall out of step. A set-point raised in steps every cycle
    /// is followed as long as its average ramp stays within this, however its writes are spaced.
    pub pull_out_accel_mm_s2: f64,
    /// The start-stop speed (mm/s): the motor follows any change of the commanded speed between
    /// rates at most this fast, and any jump of at most this from the speed its rotor follows; a
    /// stalled motor runs again once the commanded speed is at most this.
    pub pull_in_speed_mm_s: f64,
}

/// One stepper drive and its carriage.
#[derive(Clone, Debug)]
pub struct Stepper {
    p: StepperParams,
    enabled: bool,
    /// Commanded step rate (steps/s) as last written.
    commanded: f64,
    /// The rate the rotor follows (steps/s): it moves towards the commanded rate at most at the
    /// pull-out acceleration. Judged by state, not by the time between writes: a station that
    /// writes the same set-point twice in a millisecond (a Modbus exchange's coils, then its
    /// registers) or a set-point's change a little early or late is the same step train to
    /// the motor.
    followed: f64,
    /// Steps emitted by the module since power-on, in steps·µs: the set-point is a whole number
    /// of steps/s and a time step a whole number of µs, so the count is exact (summing fractions
    /// of a step in floating point would put the counter one step short at whole counts). At
    /// the module's fastest 32 767 steps/s an i64 holds 8.9 years of it.
    emitted_step_us: i64,
    /// Steps the motor actually made since power-on, in the same unit.
    moved_step_us: i64,
    /// The time step the last `step` was given (s), and it in whole µs.
    dt: (f64, i64),
    /// Carriage position at power-on (mm).
    start_mm: f64,
    stalled: bool,
    stalls: u64,
}

impl Stepper {
    /// A stepper whose carriage stands at `position_mm`, disabled, its counter at zero.
    pub fn new(p: StepperParams, position_mm: f64) -> Stepper {
        Stepper {
            p,
            enabled: false,
            commanded: 0.0,
            followed: 0.0,
            emitted_step_us: 0,
            moved_step_us: 0,
            dt: (f64::NAN, 0),
            start_mm: position_mm,
            stalled: false,
            stalls: 0,
        }
    }

    /// The module's outputs as the station wrote them: the channel's enable and its speed
    /// set-point (steps/s). Writing the same outputs again changes nothing.
    pub fn command(&mut self, enable: bool, rate_steps_s: i16) {
        let rate = if enable { f64::from(rate_steps_s) } else { 0.0 };
        // Within the start-stop range (both rates at most the pull-in rate) a motor follows any
        // change at once; beyond it, a rate at most the pull-in rate from what the rotor follows.
        let pull_in = self.p.pull_in_speed_mm_s * self.p.steps_per_mm;
        let start_stop = rate.abs() <= pull_in && self.followed.abs() <= pull_in;
        if !start_stop && (rate - self.followed).abs() > pull_in {
            self.stall();
        }
        if start_stop && !self.stalled {
            self.followed = rate;
        }
        self.enabled = enable;
        self.commanded = f64::from(rate_steps_s);
    }

    /// Advances `dt` seconds. `travel` is the carriage's hard stops `[min, max]` (mm); `jammed`
    /// says the mechanism blocks this joint's motion in the commanded direction.
    pub fn step(&mut self, dt: f64, travel: [f64; 2], jammed: bool) {
        let rate = self.rate();
        if rate.abs() > self.p.pull_out_speed_mm_s * self.p.steps_per_mm {
            self.stall();
        } else if self.stalled && rate.abs() <= self.p.pull_in_speed_mm_s * self.p.steps_per_mm {
            // The rotor catches the step train at a rate it can start at.
            self.stalled = false;
            self.followed = rate;
        }
        self.follow(rate, dt);
        if rate == 0.0 {
            return;
        }
        if self.dt.0 != dt {
            self.dt = (dt, (dt * 1e6).round() as i64);
        }
        // `rate` is a whole number of steps/s (an INT set-point).
        let steps = rate as i64 * self.dt.1;
        self.emitted_step_us += steps;
        if self.stalled || jammed {
            return;
        }
        // Counted from power-on, as the emitted steps are, so a motor that never lost a step has
        // made exactly the steps emitted.
        let [min, max] = self.travel_step_us(travel);
        self.moved_step_us = (self.moved_step_us + steps).clamp(min, max);
    }

    /// `n` steps of `dt` at once, the same as `n` calls of [`Stepper::step`] to the last bit:
    /// between two writes the commanded rate is constant, so the first step settles whether
    /// the motor is out of step, the step counts grow by whole numbers (their clamp at a hard
    /// stop is the same once as step by step, the steps all going one way), and only the
    /// followed rate is moved step by step, until it has caught up.
    pub fn steps(&mut self, dt: f64, n: u64, travel: [f64; 2], jammed: bool) {
        if n == 0 {
            return;
        }
        self.step(dt, travel, jammed);
        let rest = n - 1;
        let rate = self.rate();
        for _ in 0..rest {
            if self.followed == rate {
                break;
            }
            self.follow(rate, dt);
        }
        if rate == 0.0 || rest == 0 {
            return;
        }
        // `step` cached `dt` in whole µs.
        let steps = rate as i64 * self.dt.1 * rest as i64;
        self.emitted_step_us += steps;
        if self.stalled || jammed {
            return;
        }
        let [min, max] = self.travel_step_us(travel);
        self.moved_step_us = (self.moved_step_us + steps).clamp(min, max);
    }

    /// The rotor's rate moved towards `rate` for `dt`, at most at the pull-out acceleration.
    fn follow(&mut self, rate: f64, dt: f64) {
        let reach = self.p.pull_out_accel_mm_s2 * self.p.steps_per_mm * dt;
        self.followed += (rate - self.followed).clamp(-reach, reach);
    }

    /// The hard stops `travel` (mm) as the step counts that reach them from power-on (steps·µs).
    fn travel_step_us(&self, travel: [f64; 2]) -> [i64; 2] {
        travel.map(|mm| ((mm - self.start_mm) * self.p.steps_per_mm * 1e6).round() as i64)
    }

    /// The commanded rate in effect (steps/s): zero while disabled.
    fn rate(&self) -> f64 {
        if self.enabled { self.commanded } else { 0.0 }
    }

    fn stall(&mut self) {
        if !self.stalled {
            self.stalled = true;
            self.stalls += 1;
        }
    }

    /// The carriage turned by hand by `mm` (the motor unpowered): it moves, the module counts
    /// nothing.
    pub fn turn_by_hand(&mut self, mm: f64, travel: [f64; 2]) {
        let [min, max] = self.travel_step_us(travel);
        let by = (mm * self.p.steps_per_mm * 1e6).round() as i64;
        self.moved_step_us = (self.moved_step_us + by).clamp(min, max);
    }

    /// The module's step counter: the steps emitted, 16-bit, wrapping.
    #[inline]
    pub fn counter(&self) -> i16 {
        wrap(self.emitted_step_us.div_euclid(1_000_000))
    }

    /// The carriage's true position (mm).
    #[inline]
    pub fn position_mm(&self) -> f64 {
        self.start_mm + self.moved_step_us as f64 * 1e-6 / self.p.steps_per_mm
    }

    /// Steps emitted that the motor did not make (stalls, hard stops, jams).
    pub fn lost_steps(&self) -> f64 {
        (self.emitted_step_us - self.moved_step_us) as f64 * 1e-6
    }

    /// The steps emitted since power-on (fractions of the step under way included).
    pub fn emitted(&self) -> f64 {
        self.emitted_step_us as f64 * 1e-6
    }

    /// Whether the motor is out of step now.
    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// How many times the motor fell out of step.
    pub fn stalls(&self) -> u64 {
        self.stalls
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// pn101's defaults (docs/machines.md): 400 steps/mm, 8 mm/s, 40 mm/s²; pull-out at 1.25× the
    /// speed and 2× the acceleration.
    const PN101: StepperParams = StepperParams {
        steps_per_mm: 400.0,
        pull_out_speed_mm_s: 10.0,
        pull_out_accel_mm_s2: 80.0,
        pull_in_speed_mm_s: 2.0,
    };
    const TRAVEL: [f64; 2] = [-5.0, 305.0];

    /// Runs a 10 ms set-point cycle of 1 ms plant steps at `rate` steps/s.
    fn cycle(s: &mut Stepper, rate: i16) {
        s.command(true, rate);
        for _ in 0..10 {
            s.step(0.001, TRAVEL, false);
        }
    }

    /// Ramps from the current rate to `to` by `per_cycle` steps/s every 10 ms.
    fn ramp(s: &mut Stepper, from: i16, to: i16, per_cycle: i16) -> i16 {
        let mut rate = from;
        while rate != to {
            rate = if to > rate {
                (rate + per_cycle).min(to)
            } else {
                (rate - per_cycle).max(to)
            };
            cycle(s, rate);
        }
        rate
    }

    #[test]
    fn within_its_limits_it_follows_the_steps_exactly() {
        let mut s = Stepper::new(PN101, 100.0);
        // 8 mm/s reached at 40 mm/s² (160 steps/s per 10 ms), held 1 s, ramped down.
        let rate = ramp(&mut s, 0, 3200, 160);
        for _ in 0..100 {
            cycle(&mut s, rate);
        }
        ramp(&mut s, rate, 0, 160);
        assert_eq!(s.lost_steps(), 0.0);
        assert_eq!(s.stalls(), 0);
        let moved_mm = s.position_mm() - 100.0;
        assert!((moved_mm - s.emitted() / 400.0).abs() < 1e-9);
        // Ramp up 336 steps, 1 s at 3200 steps/s, ramp down 304 steps: 3840 steps, 9.6 mm.
        assert!((moved_mm - 9.6).abs() < 1e-9, "{moved_mm}");
    }

    #[test]
    fn how_a_station_spaces_its_writes_does_not_matter() {
        // The ramp of `within_its_limits…`, as a Modbus station delivers it: each set-point
        // written twice in the same millisecond (coils, then registers), arriving 5 or 15 ms
        // after the one before (an exchange loop every 5 ms beside a 10 ms cycle).
        let mut s = Stepper::new(PN101, 100.0);
        let mut rate = 0;
        let mut k = 0;
        while rate < 3200 {
            rate += 160;
            s.command(true, rate);
            s.command(true, rate);
            let ms = if k % 2 == 0 { 5 } else { 15 };
            for _ in 0..ms {
                s.step(0.001, TRAVEL, false);
            }
            k += 1;
        }
        assert_eq!(s.stalls(), 0);
        assert_eq!(s.lost_steps(), 0.0);
    }

    #[test]
    fn a_ramp_steeper_than_the_pull_out_acceleration_loses_steps() {
        let mut s = Stepper::new(PN101, 100.0);
        // 150 mm/s² (600 steps/s every 10 ms) against a pull-out of 80 mm/s²: beyond the
        // start-stop range the rotor falls behind by 0.7 mm/s every set-point, out of step once
        // more than 2 mm/s behind: at 4.5 mm/s.
        let mut rate = 0;
        while rate < 3200 && !s.stalled() {
            rate += 600;
            cycle(&mut s, rate);
        }
        assert!(s.stalled(), "followed up to {rate} steps/s");
        assert_eq!(rate, 1800);
    }

    #[test]
    fn too_fast_a_speed_loses_steps_the_counter_still_counts() {
        let mut s = Stepper::new(PN101, 100.0);
        // 12 mm/s (4800 steps/s), above the 10 mm/s pull-out speed, reached gently.
        let rate = ramp(&mut s, 0, 4800, 100);
        for _ in 0..100 {
            cycle(&mut s, rate);
        }
        assert!(s.stalled());
        assert!(s.lost_steps() > 4000.0, "{}", s.lost_steps());
        // The counter shows every emitted step: what open-loop control takes as the position.
        let counted_mm = f64::from(s.counter()) / 400.0;
        assert!(counted_mm - (s.position_mm() - 100.0) > 10.0);
    }

    #[test]
    fn too_hard_a_start_loses_steps_and_a_slow_rate_catches_up() {
        let mut s = Stepper::new(PN101, 100.0);
        // Starting within the start-stop speed (2 mm/s) at once is fine.
        cycle(&mut s, 800);
        cycle(&mut s, 0);
        assert!(!s.stalled());
        // From standstill to 8 mm/s in one 10 ms set-point: 320 000 steps/s², far above pull-out.
        cycle(&mut s, 3200);
        assert!(s.stalled());
        assert!((s.position_mm() - 100.02).abs() < 1e-9, "{}", s.position_mm());
        // Down to 1 mm/s gently: within the pull-in rate, the motor runs again.
        ramp(&mut s, 3200, 400, 160);
        let before = s.position_mm();
        cycle(&mut s, 400);
        assert!(!s.stalled());
        assert!((s.position_mm() - before - 0.01).abs() < 1e-9);
        assert!(s.lost_steps() > 0.0);
        assert_eq!(s.stalls(), 1);
    }

    #[test]
    fn a_hard_stop_holds_the_carriage_and_the_steps_are_lost() {
        let mut s = Stepper::new(PN101, 304.0);
        let rate = ramp(&mut s, 0, 800, 160);
        for _ in 0..100 {
            cycle(&mut s, rate);
        }
        assert_eq!(s.position_mm(), 305.0);
        assert!(s.lost_steps() > 300.0);
    }

    #[test]
    fn disabled_it_emits_nothing_and_a_jam_moves_nothing() {
        let mut s = Stepper::new(PN101, 50.0);
        s.command(false, 3200);
        s.step(0.01, TRAVEL, false);
        assert_eq!((s.counter(), s.position_mm()), (0, 50.0));
        s.command(true, 100);
        s.step(0.01, TRAVEL, true);
        assert_eq!((s.counter(), s.position_mm()), (1, 50.0));
    }

    #[test]
    fn the_counter_wraps_at_16_bits() {
        let mut s = Stepper::new(PN101, 0.0);
        let rate = ramp(&mut s, 0, 3200, 160);
        // 32 768 steps and more: 82 mm at 8 mm/s.
        for _ in 0..1100 {
            cycle(&mut s, rate);
        }
        assert!(s.emitted() > 32_768.0);
        assert_eq!(s.counter(), wrap(s.emitted().floor() as i64));
        assert!(s.counter() < 0);
    }

    /// The stepper's state, every field, for comparing two motors bit for bit.
    fn state(s: &Stepper) -> String {
        format!("{s:?}")
    }

    proptest::proptest! {
        /// `steps(n)` is `n` calls of `step`, to the last bit, whatever the commands before
        /// (ramps within and beyond the pull-out limits, stalls, disabling), the hard stops and
        /// a dead drive: the plant takes a cycle's steps at once only because of this.
        #[test]
        fn n_steps_at_once_are_n_single_steps(
            commands in proptest::collection::vec((proptest::bool::weighted(0.9), -5000i16..5000, 1u64..25), 1..40),
            start in -4.0f64..300.0,
            dead in proptest::bool::weighted(0.1),
        ) {
            let mut one = Stepper::new(PN101, start);
            let mut many = one.clone();
            for (enable, rate, n) in commands {
                one.command(enable, rate);
                many.command(enable, rate);
                for _ in 0..n {
                    one.step(0.001, TRAVEL, dead);
                }
                many.steps(0.001, n, TRAVEL, dead);
                proptest::prop_assert_eq!(state(&one), state(&many));
            }
        }
    }
}
