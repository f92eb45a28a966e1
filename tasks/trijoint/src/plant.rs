//! The plant: a model of the TRIJOINT lab model's mechanics and operator panel.
//!
//! Per drive: a DC motor with gearbox (PWM duty → carriage speed with a first-order lag; no
//! motion without an enabled bridge), a lead screw, a carriage between hard stops, limit switches
//! just inside the hard stops, and a 16-bit wrapping encoder counter. The two carriages are linked
//! by the mechanism of docs/kinematics.md: a pair of positions the linkage cannot assemble is never
//! entered — the plant stops there, as a jammed machine would. Time advances in fixed steps, so a
//! run depends only on its inputs.

use pkm_api::problem::Problem;
use serde::Deserialize;

use pkm_drives::sim::dc::DcAxis;
use pkm_kinematics::Kinematics;
use pkm_kinematics::trijoint::{Trijoint, TrijointParams};

/// Parameters of one drive.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriveParams {
    /// Carriage speed at full duty, after the lag (mm/s).
    pub v_max_mm_s: f64,
    /// Time constant of the motor's first-order lag (s).
    pub tau_s: f64,
    /// Encoder counts per mm of carriage travel (motor encoder × gearbox ÷ lead).
    pub counts_per_mm: f64,
    /// The lower limit switch trips at or below this position (mm).
    pub lower_switch_mm: f64,
    /// The upper limit switch trips at or above this position (mm).
    pub upper_switch_mm: f64,
    /// Lower hard stop (mm): the carriage cannot pass it.
    pub hard_stop_min_mm: f64,
    /// Upper hard stop (mm).
    pub hard_stop_max_mm: f64,
    /// Position at power-on (mm).
    pub start_mm: f64,
}

impl Default for DriveParams {
    fn default() -> Self {
        DriveParams {
            // 250 mm of travel in about 3.1 s at full duty.
            v_max_mm_s: 80.0,
            tau_s: 0.05,
            // 500-line encoder, quadrature (2000 counts/rev), 14:1 gearbox, 4 mm lead.
            counts_per_mm: 7000.0,
            lower_switch_mm: 0.0,
            upper_switch_mm: 250.0,
            hard_stop_min_mm: -3.0,
            hard_stop_max_mm: 253.0,
            start_mm: 125.0,
        }
    }
}

impl DriveParams {
    /// Checks the parameters; problems as (path below `at`, message).
    pub fn check(&self, at: &str, problems: &mut Vec<Problem>) {
        use pkm_api::ranges::{self, check_into};
        check_into(
            problems,
            format!("{at}.v_max_mm_s"),
            self.v_max_mm_s,
            &ranges::MOTOR_SPEED_MM_S,
        );
        check_into(problems, format!("{at}.tau_s"), self.tau_s, &ranges::MOTOR_LAG_S);
        check_into(
            problems,
            format!("{at}.counts_per_mm"),
            self.counts_per_mm,
            &ranges::COUNTS_PER_MM,
        );
        let order = [
            self.hard_stop_min_mm,
            self.lower_switch_mm,
            self.upper_switch_mm,
            self.hard_stop_max_mm,
        ];
        let mut inside = true;
        for (k, v) in [
            "hard_stop_min_mm",
            "lower_switch_mm",
            "upper_switch_mm",
            "hard_stop_max_mm",
        ]
        .iter()
        .zip(order)
        {
            inside &= check_into(problems, format!("{at}.{k}"), v, &ranges::POSITION_MM);
        }
        if inside && !order.windows(2).all(|w| w[0] < w[1]) {
            problems.push(Problem::new(
                at.to_string(),
                format!(
                    "positions must satisfy hard_stop_min_mm < lower_switch_mm < upper_switch_mm < hard_stop_max_mm, got {} < {} < {} < {}",
                    order[0], order[1], order[2], order[3]
                ),
            ));
        }
        if !(self.hard_stop_min_mm..=self.hard_stop_max_mm).contains(&self.start_mm) {
            problems.push(Problem::new(
                format!("{at}.start_mm"),
                format!("must lie between the hard stops, got {}", self.start_mm),
            ));
        }
    }
}

/// The operator panel's buttons.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Button {
    /// The red STOP button.
    Stop,
    /// Direction buttons.
    Left,
    /// Right.
    Right,
    /// Up.
    Up,
    /// Down.
    Down,
    /// Program start.
    ProgramStart,
    /// Feed hold.
    ProgramHold,
    /// Program resume.
    ProgramResume,
}

/// Which limit switch of a drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SwitchEnd {
    /// At the lower end of the travel.
    Lower,
    /// At the upper end.
    Upper,
}

/// The state of one drive.
#[derive(Clone, Debug)]
struct Drive {
    p: DriveParams,
    axis: DcAxis,
    pwm: i16,
    /// Added to the counter (counter reset, glitches).
    counter_offset: i64,
    counter_reset: bool,
    clear_error: bool,
    bridge_error: bool,
    dead: bool,
    stuck: [Option<bool>; 2],
}

/// The plant.
#[derive(Clone, Debug)]
pub struct Plant {
    drives: [Drive; 2],
    period_us: u16,
    buttons: [bool; 8],
    joystick: [f64; 2],
    joystick_connected: bool,
    mechanism: Option<Trijoint>,
    jams: u64,
}

/// Drive index: 0 = left (h1, guide 1), 1 = right (h2, guide 2).
pub type DriveId = usize;

impl Plant {
    /// A plant with two drives; `mechanism` (TRIJOINT geometry) adds the linkage's jam, `None`
    /// leaves the carriages independent.
    pub fn new(left: &DriveParams, right: &DriveParams, mechanism: Option<&TrijointParams>) -> Self {
        let drive = |p: &DriveParams| Drive {
            p: p.clone(),
            axis: DcAxis::new(
                p.v_max_mm_s,
                p.tau_s,
                [p.hard_stop_min_mm, p.hard_stop_max_mm],
                p.start_mm,
            ),
            pwm: 0,
            counter_offset: 0,
            counter_reset: false,
            clear_error: false,
            bridge_error: false,
            dead: false,
            stuck: [None, None],
        };
        // The linkage is checked over the whole mechanical range, up to the hard stops.
        let mechanism = mechanism.map(|m| {
            Trijoint::new(&TrijointParams {
                h1_travel: [left.hard_stop_min_mm, left.hard_stop_max_mm],
                h2_travel: [right.hard_stop_min_mm, right.hard_stop_max_mm],
                ..m.clone()
            })
        });
        Plant {
            drives: [drive(left), drive(right)],
            period_us: 0,
            buttons: [false; 8],
            joystick: [0.0; 2],
            joystick_connected: true,
            mechanism,
            jams: 0,
        }
    }

    /// Advances the plant by `dt_s` seconds.
    pub fn step(&mut self, dt_s: f64) {
        let enabled_period = self.period_us > 0;
        let mut next = [0.0; 2];
        for (i, d) in self.drives.iter_mut().enumerate() {
            let duty = if enabled_period && !d.bridge_error && !d.dead {
                f64::from(d.pwm) / 32767.0
            } else {
                0.0
            };
            next[i] = d.axis.advance(duty, dt_s);
        }
        // Standing still cannot jam: skip the linkage check then (most of a run).
        let moved = self.drives.iter().zip(next).any(|(d, n)| d.axis.position_mm() != n);
        if let Some(m) = self.mechanism.as_ref().filter(|_| moved) {
            let mut pose = [0.0; 2];
            if m.forward(&next, None, &mut pose).is_err() {
                // The linkage cannot assemble there: the machine jams and stands still.
                self.jams += 1;
                for d in &mut self.drives {
                    d.axis.halt();
                }
                return;
            }
        }
        for (d, n) in self.drives.iter_mut().zip(next) {
            d.axis.commit(n);
        }
    }

    /// Sets a drive's PWM pulse width (±32767 = ±100 % duty).
    pub fn set_pwm(&mut self, drive: DriveId, pulse_width: i16) {
        self.drives[drive].pwm = pulse_width;
    }

    /// Sets the bridges' PWM period (µs); 0 leaves both bridges disabled.
    pub fn set_period(&mut self, period_us: u16) {
        self.period_us = period_us;
    }

    /// The ClearError output of a bridge: a rising edge clears a latched bridge error.
    pub fn set_clear_error(&mut self, drive: DriveId, on: bool) {
        let d = &mut self.drives[drive];
        if on && !d.clear_error {
            d.bridge_error = false;
        }
        d.clear_error = on;
    }

    /// The CounterReset output of an encoder module: a rising edge sets the counter to 0.
    pub fn set_counter_reset(&mut self, drive: DriveId, on: bool) {
        let d = &mut self.drives[drive];
        if on && !d.counter_reset {
            d.counter_offset = -(d.axis.position_mm() * d.p.counts_per_mm).round() as i64;
        }
        d.counter_reset = on;
    }

    /// The encoder counter: 16-bit signed, wrapping.
    pub fn counter(&self, drive: DriveId) -> i16 {
        let d = &self.drives[drive];
        let counts = (d.axis.position_mm() * d.p.counts_per_mm).round() as i64 + d.counter_offset;
        // Two's-complement truncation to 16 bits is exactly the hardware's wrap.
        counts as i16
    }

    /// Whether a limit switch is active (a stuck switch reports its stuck state).
    pub fn switch(&self, drive: DriveId, end: SwitchEnd) -> bool {
        let d = &self.drives[drive];
        let index = end as usize;
        d.stuck[index].unwrap_or(match end {
            SwitchEnd::Lower => d.axis.position_mm() <= d.p.lower_switch_mm,
            SwitchEnd::Upper => d.axis.position_mm() >= d.p.upper_switch_mm,
        })
    }

    /// Whether a bridge reports an error (latched until ClearError).
    pub fn bridge_error(&self, drive: DriveId) -> bool {
        self.drives[drive].bridge_error
    }

    /// Presses or releases a panel button.
    pub fn set_button(&mut self, button: Button, pressed: bool) {
        self.buttons[button as usize] = pressed;
    }

    /// Whether a panel button is pressed.
    pub fn button(&self, button: Button) -> bool {
        self.buttons[button as usize]
    }

    /// Sets the joystick's axes (each clamped to −1..1).
    pub fn set_joystick(&mut self, x: f64, y: f64) {
        self.joystick = [x.clamp(-1.0, 1.0), y.clamp(-1.0, 1.0)];
    }

    /// The joystick's axes.
    pub fn joystick(&self) -> [f64; 2] {
        self.joystick
    }

    /// Plugs or unplugs the joystick.
    pub fn set_joystick_connected(&mut self, connected: bool) {
        self.joystick_connected = connected;
        if !connected {
            self.joystick = [0.0; 2];
        }
    }

    /// Whether the joystick is connected.
    pub fn joystick_connected(&self) -> bool {
        self.joystick_connected
    }

    /// Fault: a limit switch stuck on (`Some(true)`), stuck off (`Some(false)`), or free (`None`).
    pub fn stick_switch(&mut self, drive: DriveId, end: SwitchEnd, stuck: Option<bool>) {
        self.drives[drive].stuck[end as usize] = stuck;
    }

    /// Fault: the encoder counter jumps by `counts`.
    pub fn encoder_glitch(&mut self, drive: DriveId, counts: i64) {
        self.drives[drive].counter_offset += counts;
    }

    /// Fault: the bridge latches an error (as on overcurrent); the motor loses its drive.
    pub fn bridge_fault(&mut self, drive: DriveId) {
        self.drives[drive].bridge_error = true;
    }

    /// Fault: the drive stops responding to PWM (true) or recovers (false), with no error shown.
    pub fn set_dead(&mut self, drive: DriveId, dead: bool) {
        self.drives[drive].dead = dead;
    }

    /// The carriage's true position (mm): for tests and the status line, not for the PLC.
    pub fn position_mm(&self, drive: DriveId) -> f64 {
        self.drives[drive].axis.position_mm()
    }

    /// The carriage's true velocity (mm/s).
    pub fn velocity_mm_s(&self, drive: DriveId) -> f64 {
        self.drives[drive].axis.velocity_mm_s()
    }

    /// How many steps the linkage jammed.
    pub fn jams(&self) -> u64 {
        self.jams
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(plant: &mut Plant, seconds: f64) {
        for _ in 0..(seconds * 1000.0).round() as usize {
            plant.step(0.001);
        }
    }

    #[test]
    fn no_motion_without_an_enabled_bridge() {
        let p = DriveParams::default();
        let mut plant = Plant::new(&p, &p, None);
        plant.set_pwm(0, 32767);
        run(&mut plant, 1.0);
        assert_eq!(plant.position_mm(0), 125.0, "period 0: bridge disabled");
        plant.set_period(50);
        plant.bridge_fault(0);
        run(&mut plant, 1.0);
        assert_eq!(plant.position_mm(0), 125.0, "bridge error latched");
        plant.set_clear_error(0, true);
        run(&mut plant, 1.0);
        assert!(plant.position_mm(0) > 190.0, "{}", plant.position_mm(0));
    }

    #[test]
    fn the_counter_wraps_exactly_and_resets_on_a_rising_edge() {
        let p = DriveParams::default();
        let mut plant = Plant::new(&p, &p, None);
        // 125 mm × 7000 counts/mm = 875 000 counts; 875 000 mod 65 536 = 23 032.
        assert_eq!(plant.counter(0), 23_032);
        plant.set_counter_reset(0, true);
        assert_eq!(plant.counter(0), 0);
        plant.set_period(50);
        plant.set_pwm(0, -32767);
        run(&mut plant, 0.5);
        let expected = ((plant.position_mm(0) - 125.0) * 7000.0).round() as i64;
        assert!(expected < -200_000, "moved more than three counter ranges: {expected}");
        let wrap = |c: i64| (c + 32_768).rem_euclid(65_536) - 32_768;
        assert_eq!(i64::from(plant.counter(0)), wrap(expected));
        plant.encoder_glitch(0, 100);
        assert_eq!(i64::from(plant.counter(0)), wrap(expected + 100));
    }
}
