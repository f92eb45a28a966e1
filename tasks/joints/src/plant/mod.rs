//! The simulated joint-driven machine, built from the parts every plant shares (pkm-drives'
//! stepper and DC-driven carriage): per joint a motor and a carriage between hard stops, limit
//! and reference switches (each joint's own, or pn101's shared inputs, which say only that some
//! joint tripped one), counters, the operator panel and joystick, and the mechanism's jam where
//! the forward kinematics has no assembly. Time advances in fixed steps, so a run depends only on
//! its inputs.

pub mod config;
pub mod harness;

use pkm_api::image::Value;
use pkm_api::machine::{Action, Signal};
use pkm_drives::counter::{round_count, wrap};
use pkm_drives::sim::dc::{DcAxis, SpanEnd};
use pkm_drives::sim::stepper::{Stepper, StepperParams};
use pkm_kinematics::{Kinematics, MAX_DOF};

use config::{DcMotor, JointPlant, PlantConfig};
use harness::{PANEL, Wire};

/// A joint's motor and what its module channel holds.
#[derive(Clone, Debug)]
enum Drive {
    Stepper {
        motor: Stepper,
        enable: bool,
        speed: i16,
        /// Whether enable or speed was written since the motor last took them.
        written: bool,
    },
    Dc {
        axis: DcAxis,
        counts_per_mm: f64,
        pwm: i16,
        clear_error: bool,
        bridge_error: bool,
    },
}

#[derive(Clone, Debug)]
struct Joint {
    p: JointPlant,
    drive: Drive,
    /// Added to the counter (glitches).
    counter_offset: i64,
    /// The motor stopped responding (a broken wire): DC gets no duty, a stepper loses every step.
    dead: bool,
}

// Inlined: the exchange reads every switch and counter of every joint each fast cycle.
impl Joint {
    #[inline]
    fn position_mm(&self) -> f64 {
        match &self.drive {
            Drive::Stepper { motor, .. } => motor.position_mm(),
            Drive::Dc { axis, .. } => axis.position_mm(),
        }
    }

    #[inline]
    fn counter(&self) -> i16 {
        let raw = match &self.drive {
            Drive::Stepper { motor, .. } => i64::from(motor.counter()),
            Drive::Dc {
                axis, counts_per_mm, ..
            } => round_count(axis.position_mm() * counts_per_mm),
        };
        wrap(raw + self.counter_offset)
    }
}

/// How an input signal is read, resolved from its wire when the plant is built (the exchange
/// reads some twenty signals a hundred times a simulated second).
#[derive(Clone, Copy, Debug)]
enum Reader {
    /// A joint's own switch: on where `(q − at)·side ≥ 0` — a limit's negative end is
    /// `q ≤ at` (side −1), its positive end `q ≥ at` (side 1), a reference switch is on beyond
    /// its point in its direction.
    Switch { joint: usize, at: f64, side: f64 },
    /// Any other wire: read by matching it.
    Wire,
}

/// The plant.
pub struct Plant {
    signals: Vec<Signal>,
    wires: Vec<Wire>,
    /// Per signal, how it is read.
    readers: Vec<Reader>,
    joints: Vec<Joint>,
    /// Per signal: a switch stuck on (`Some(true)`), off (`Some(false)`), or working (`None`).
    stuck: Vec<Option<bool>>,
    buttons: [bool; PANEL.len()],
    joystick: [f64; 2],
    joystick_connected: bool,
    pwm_period: [u16; 3],
    mechanism: Option<Box<dyn Kinematics>>,
    /// The last assembled pose, the Newton start of the next check.
    pose: [f64; MAX_DOF],
    /// The joints where the mechanism was last found to assemble.
    checked: [f64; MAX_DOF],
    jams: u64,
}

/// The linkage is checked (by the forward kinematics) once a joint has moved this far from where
/// it was last found to assemble (mm): a jam is found at most this much late, and a machine
/// that stands — its DC axes trembling by micrometres around their set-points — costs no check
/// at all (the hexapod's forward kinematics at every 1 ms step was 3/4 of its simulation).
pub const JAM_CHECK_MM: f64 = 0.01;

/// The duty (−1 … 1) a DC joint's bridge applies: its pulse width, once the bridge module has a
/// PWM period, has no latched error and the motor is connected; none otherwise.
#[inline]
fn dc_duty(pwm_period: u16, pwm: i16, bridge_error: bool, dead: bool) -> f64 {
    if pwm_period > 0 && !bridge_error && !dead {
        f64::from(pwm) / 32767.0
    } else {
        0.0
    }
}

/// The drives' names in scenario files, by joint.
const DRIVES: [&str; 6] = ["joint1", "joint2", "joint3", "joint4", "joint5", "joint6"];

impl Plant {
    /// A plant from its (checked) configuration; `mechanism` is the machine's kinematics, whose
    /// forward transformation says where the mechanism jams (`None`: the joints are independent).
    pub fn new(config: &PlantConfig, signals: Vec<(Signal, Wire)>, mechanism: Option<Box<dyn Kinematics>>) -> Plant {
        let joints: Vec<Joint> = config
            .joints
            .iter()
            .map(|p| Joint {
                p: p.clone(),
                drive: match (p.motor.stepper, p.motor.dc) {
                    (Some(m), _) => Drive::Stepper {
                        motor: Stepper::new(
                            StepperParams {
                                steps_per_mm: m.steps_per_mm,
                                pull_out_speed_mm_s: m.pull_out_speed_mm_s,
                                pull_out_accel_mm_s2: m.pull_out_accel_mm_s2,
                                pull_in_speed_mm_s: m.pull_in_speed_mm_s,
                            },
                            p.start_mm,
                        ),
                        enable: false,
                        speed: 0,
                        written: false,
                    },
                    (None, dc) => {
                        // The check allows exactly one motor; its default is the DC one.
                        let m = dc.unwrap_or(DcMotor {
                            v_max_mm_s: 40.0,
                            tau_s: 0.05,
                            counts_per_mm: 1000.0,
                        });
                        Drive::Dc {
                            axis: DcAxis::new(m.v_max_mm_s, m.tau_s, p.hard_stops_mm, p.start_mm),
                            counts_per_mm: m.counts_per_mm,
                            pwm: 0,
                            clear_error: false,
                            bridge_error: false,
                        }
                    }
                },
                counter_offset: 0,
                dead: false,
            })
            .collect();
        let mut pose = [0.0; MAX_DOF];
        let mut checked = [0.0; MAX_DOF];
        for (c, j) in checked.iter_mut().zip(&joints) {
            *c = j.position_mm();
        }
        let mechanism = mechanism.filter(|m| {
            let starts: Vec<f64> = joints.iter().map(Joint::position_mm).collect();
            // A mechanism that cannot assemble at power-on would jam at once: the check
            // (`check_start`) refuses such a configuration before a plant is built.
            m.forward(&starts, None, &mut pose[..m.dof()]).is_ok()
        });
        let (signals, wires): (Vec<Signal>, Vec<Wire>) = signals.into_iter().unzip();
        let readers = wires
            .iter()
            .map(|wire| match *wire {
                Wire::Limit(Some(joint), end) => Reader::Switch {
                    joint,
                    at: joints[joint].p.limit_switches_mm[end.min(1)],
                    side: if end == 0 { -1.0 } else { 1.0 },
                },
                Wire::Reference(Some(joint)) => Reader::Switch {
                    joint,
                    at: joints[joint].p.reference_switch_mm,
                    side: joints[joint].p.reference_direction,
                },
                _ => Reader::Wire,
            })
            .collect();
        Plant {
            stuck: vec![None; signals.len()],
            signals,
            wires,
            readers,
            joints,
            buttons: [false; PANEL.len()],
            joystick: [0.0; 2],
            joystick_connected: true,
            pwm_period: [0; 3],
            mechanism,
            pose,
            checked,
            jams: 0,
        }
    }

    /// Advances the plant by `n` steps of `dt_s`: in one span where the span is clear of hard
    /// stops for the DC joints and of jams, else step by step.
    pub fn steps(&mut self, dt_s: f64, n: u64) {
        if n > 1 && self.span(dt_s, n) {
            return;
        }
        for _ in 0..n {
            self.step(dt_s);
        }
    }

    /// The joints' `n` steps as one span — a DC joint's by [`DcAxis::span`], a stepper's by
    /// [`Stepper::steps`], which is its `n` steps to the last bit — taken only if no DC carriage
    /// may reach a hard stop within it and the mechanism assembles at its end; `false`
    /// (nothing changed) otherwise. The linkage is checked where the span ends, as
    /// [`Plant::step`] checks it where a step ends once the joints are [`JAM_CHECK_MM`] from
    /// the last check: a span is a cycle's few steps (tenths of a millimetre at most), and
    /// one the mechanism refuses is stepped, so a jam still halts the joints at the step
    /// that meets it.
    fn span(&mut self, dt_s: f64, n: u64) -> bool {
        let mut ends = [SpanEnd {
            position_mm: 0.0,
            velocity_mm_s: 0.0,
        }; MAX_DOF];
        let mut stepped: [Option<Stepper>; MAX_DOF] = Default::default();
        let mut next = [0.0; MAX_DOF];
        let mut moved = false;
        for (j, joint) in self.joints.iter_mut().enumerate() {
            next[j] = match &mut joint.drive {
                Drive::Dc {
                    axis,
                    pwm,
                    bridge_error,
                    ..
                } => {
                    let duty = dc_duty(self.pwm_period[j / 2], *pwm, *bridge_error, joint.dead);
                    let Some(end) = axis.span(duty, dt_s, n) else {
                        return false;
                    };
                    ends[j] = end;
                    end.position_mm
                }
                Drive::Stepper { motor, .. } => {
                    let mut m = motor.clone();
                    m.steps(dt_s, n, joint.p.hard_stops_mm, joint.dead);
                    let at = m.position_mm();
                    stepped[j] = Some(m);
                    at
                }
            };
            moved |= next[j] != joint.position_mm();
        }
        if !self.linkage_allows(&next, moved) {
            return false;
        }
        for ((joint, end), m) in self.joints.iter_mut().zip(ends).zip(&mut stepped) {
            match &mut joint.drive {
                Drive::Dc { axis, .. } => axis.commit_span(end),
                Drive::Stepper { motor, .. } => {
                    if let Some(m) = m.take() {
                        *motor = m;
                    }
                }
            }
        }
        true
    }

    /// Whether the mechanism lets the joints go to `next` (`moved`: whether any joint would
    /// move): checked by forward kinematics from the last assembled pose once a joint is
    /// [`JAM_CHECK_MM`] from where the linkage was last checked, which then becomes `next`.
    /// Shared by [`Plant::step`] and [`Plant::span`], so that a span and its steps check alike.
    fn linkage_allows(&mut self, next: &[f64; MAX_DOF], moved: bool) -> bool {
        let n = self.joints.len();
        let far = (0..n).any(|j| (next[j] - self.checked[j]).abs() > JAM_CHECK_MM);
        if !(moved && far) {
            return true;
        }
        if let Some(m) = &self.mechanism {
            let hint = self.pose;
            if m.forward(&next[..n], Some(&hint[..n]), &mut self.pose[..n]).is_err() {
                // The last assembled pose stays the next check's start (the models write the
                // pose only when they find one; this keeps it so whatever a model does).
                self.pose = hint;
                return false;
            }
        }
        self.checked[..n].copy_from_slice(&next[..n]);
        true
    }

    /// Advances the plant by `dt_s` seconds.
    pub fn step(&mut self, dt_s: f64) {
        let mut next = [0.0; MAX_DOF];
        let mut moved = false;
        // Each motor's step, computed on a copy: the mechanism decides whether it is taken.
        let mut stepped: [Option<Stepper>; MAX_DOF] = Default::default();
        for (j, joint) in self.joints.iter_mut().enumerate() {
            let travel = joint.p.hard_stops_mm;
            next[j] = match &mut joint.drive {
                Drive::Stepper { motor, .. } => {
                    let mut m = motor.clone();
                    m.step(dt_s, travel, joint.dead);
                    let at = m.position_mm();
                    stepped[j] = Some(m);
                    at
                }
                Drive::Dc {
                    axis,
                    pwm,
                    bridge_error,
                    ..
                } => axis.advance(dc_duty(self.pwm_period[j / 2], *pwm, *bridge_error, joint.dead), dt_s),
            };
            moved |= next[j] != joint.position_mm();
        }
        let jammed = !self.linkage_allows(&next, moved);
        if jammed {
            self.jams += 1;
        }
        for (j, joint) in self.joints.iter_mut().enumerate() {
            let travel = joint.p.hard_stops_mm;
            match &mut joint.drive {
                Drive::Stepper { motor, .. } => {
                    if jammed {
                        // The motor runs into the jam: its steps are lost.
                        motor.step(dt_s, travel, true);
                    } else if let Some(m) = stepped[j].take() {
                        *motor = m;
                    }
                }
                Drive::Dc { axis, .. } => {
                    if jammed {
                        axis.halt();
                    } else {
                        axis.commit(next[j]);
                    }
                }
            }
        }
    }

    /// The value of limit or reference switch `wire` now (before a stuck fault).
    #[inline]
    fn switch(&self, wire: Wire) -> bool {
        let limit = |j: &Joint, end: usize| {
            let q = j.position_mm();
            if end == 0 {
                q <= j.p.limit_switches_mm[0]
            } else {
                q >= j.p.limit_switches_mm[1]
            }
        };
        let reference = |j: &Joint| (j.position_mm() - j.p.reference_switch_mm) * j.p.reference_direction >= 0.0;
        match wire {
            Wire::Limit(Some(j), end) => limit(&self.joints[j], end),
            Wire::Limit(None, end) => self.joints.iter().any(|j| limit(j, end)),
            Wire::Reference(Some(j)) => reference(&self.joints[j]),
            Wire::Reference(None) => self.joints.iter().any(reference),
            _ => false,
        }
    }

    /// Hands a stepper channel's enable and speed, as last written, to its motor.
    fn command_steppers(&mut self) {
        for joint in &mut self.joints {
            if let Drive::Stepper {
                motor,
                enable,
                speed,
                written,
            } = &mut joint.drive
                && *written
            {
                motor.command(*enable, *speed);
                *written = false;
            }
        }
    }

    /// Joint `j`'s true position (mm): for tests and displays, not for the PLC.
    pub fn position_mm(&self, j: usize) -> f64 {
        self.joints[j].position_mm()
    }

    /// Steps joint `j`'s stepper emitted but did not make (0 for a DC joint).
    pub fn lost_steps(&self, j: usize) -> f64 {
        match &self.joints[j].drive {
            Drive::Stepper { motor, .. } => motor.lost_steps(),
            Drive::Dc { .. } => 0.0,
        }
    }

    /// How often joint `j`'s stepper fell out of step (0 for a DC joint).
    pub fn stalls(&self, j: usize) -> u64 {
        match &self.joints[j].drive {
            Drive::Stepper { motor, .. } => motor.stalls(),
            Drive::Dc { .. } => 0,
        }
    }

    /// Joint `j`'s position at power-on (mm).
    pub fn start_mm(&self, j: usize) -> f64 {
        self.joints[j].p.start_mm
    }

    /// Joint `j`'s limit switches' trip points [negative, positive] (mm).
    pub fn limit_switches_mm(&self, j: usize) -> [f64; 2] {
        self.joints[j].p.limit_switches_mm
    }

    /// Joint `j`'s hard stops (mm).
    pub fn hard_stops_mm(&self, j: usize) -> [f64; 2] {
        self.joints[j].p.hard_stops_mm
    }

    /// Joint `j`'s carriage turned by hand to `to_mm` (within its hard stops), as an operator
    /// does with the drives off: an encoder sees it, a stepper module counts nothing.
    pub fn move_by_hand(&mut self, j: usize, to_mm: f64) {
        let joint = &mut self.joints[j];
        let [lo, hi] = joint.p.hard_stops_mm;
        let to = to_mm.clamp(lo, hi);
        let by = to - joint.position_mm();
        match &mut joint.drive {
            Drive::Stepper { motor, .. } => motor.turn_by_hand(by, [lo, hi]),
            Drive::Dc { axis, .. } => axis.commit(to),
        }
    }

    /// Joint `j`'s reference switch: where it trips (mm) and the direction in which it is on
    /// beyond that point (1 or −1).
    pub fn reference_switch(&self, j: usize) -> (f64, f64) {
        (
            self.joints[j].p.reference_switch_mm,
            self.joints[j].p.reference_direction,
        )
    }

    /// How many steps the mechanism jammed.
    pub fn jams(&self) -> u64 {
        self.jams
    }
}

impl pkm_api::machine::Plant for Plant {
    fn signals(&self) -> &[Signal] {
        &self.signals
    }

    fn drives(&self) -> &[&'static str] {
        &DRIVES[..self.joints.len()]
    }

    fn step(&mut self, dt_s: f64) {
        Plant::step(self, dt_s);
    }

    fn steps(&mut self, dt_s: f64, n: u64) {
        Plant::steps(self, dt_s, n);
    }

    fn read(&self, signal: usize) -> Value {
        self.value(signal)
    }

    fn read_into(&self, signals: &[usize], values: &mut [Value]) {
        // The exchange's loop with the reading inlined (the trait's default calls `read` once
        // per signal: a tenth of a simulated hour went to those calls).
        for &s in signals {
            values[s] = self.value(s);
        }
    }

    fn write(&mut self, signal: usize, value: Value) {
        self.apply_output(signal, value);
        self.command_steppers();
    }

    fn write_from(&mut self, signals: &[usize], values: &[Value]) {
        // Enable and speed of a channel are one command to the motor: apply every output of the
        // exchange, then hand the steppers theirs once.
        for &s in signals {
            self.apply_output(s, values[s]);
        }
        self.command_steppers();
    }

    fn apply(&mut self, action: Action) {
        match action {
            Action::Press { signal, pressed } => {
                if let Wire::Button(b) = self.wires[signal] {
                    self.buttons[b] = pressed;
                }
            }
            Action::Joystick(x, y) => self.joystick = [x.clamp(-1.0, 1.0), y.clamp(-1.0, 1.0)],
            Action::StickSwitch { signal, stuck } => {
                if matches!(self.wires[signal], Wire::Limit(..) | Wire::Reference(_)) {
                    self.stuck[signal] = stuck;
                }
            }
            Action::EncoderGlitch { drive, counts } => {
                if let Some(j) = self.joints.get_mut(drive) {
                    j.counter_offset += counts;
                }
            }
            Action::BridgeError { drive } => {
                if let Some(Drive::Dc { bridge_error, .. }) = self.joints.get_mut(drive).map(|j| &mut j.drive) {
                    *bridge_error = true;
                }
            }
            Action::DriveDead { drive, dead } => {
                if let Some(j) = self.joints.get_mut(drive) {
                    j.dead = dead;
                }
            }
            Action::JoystickConnected(c) => {
                self.joystick_connected = c;
                if !c {
                    self.joystick = [0.0; 2];
                }
            }
        }
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn joints(&self) -> Vec<pkm_api::machine::JointTruth> {
        (0..self.joints.len())
            .map(|j| pkm_api::machine::JointTruth {
                position_mm: self.position_mm(j),
                stepper: matches!(self.joints[j].drive, Drive::Stepper { .. }),
                lost_steps: self.lost_steps(j),
                stalls: self.stalls(j),
            })
            .collect()
    }

    fn jams(&self) -> u64 {
        self.jams
    }
}

impl Plant {
    /// The value of input signal `signal` now.
    #[inline(always)]
    fn value(&self, signal: usize) -> Value {
        if let Reader::Switch { joint, at, side } = self.readers[signal] {
            // As `switch`: (q − at)·side has the sign of q − at (exact) turned by the side.
            let on = (self.joints[joint].position_mm() - at) * side >= 0.0;
            return Value::Bool(self.stuck[signal].unwrap_or(on));
        }
        let wire = self.wires[signal];
        match wire {
            Wire::Button(b) => Value::Bool(self.buttons[b]),
            Wire::Limit(..) | Wire::Reference(_) => {
                Value::Bool(self.stuck[signal].unwrap_or_else(|| self.switch(wire)))
            }
            Wire::Counter(j) => Value::Int(self.joints[j].counter()),
            Wire::BridgeError(j) => Value::Bool(matches!(self.joints[j].drive, Drive::Dc { bridge_error: true, .. })),
            Wire::JoystickAxis(a) => Value::Real(self.joystick[a]),
            Wire::JoystickConnected => Value::Bool(self.joystick_connected),
            // Outputs read back as the bus's zero: the runtime reads input signals only.
            Wire::Enable(_) | Wire::ClearError(_) => Value::Bool(false),
            Wire::Speed(_) | Wire::Pwm(_) => Value::Int(0),
            Wire::PwmPeriod(_) => Value::Uint(0),
        }
    }

    fn apply_output(&mut self, signal: usize, value: Value) {
        match (self.wires[signal], value) {
            (Wire::Enable(j), Value::Bool(v)) => {
                if let Drive::Stepper { enable, written, .. } = &mut self.joints[j].drive {
                    *enable = v;
                    *written = true;
                }
            }
            (Wire::Speed(j), Value::Int(v)) => {
                if let Drive::Stepper { speed, written, .. } = &mut self.joints[j].drive {
                    *speed = v;
                    *written = true;
                }
            }
            (Wire::Pwm(j), Value::Int(v)) => {
                if let Drive::Dc { pwm, .. } = &mut self.joints[j].drive {
                    *pwm = v;
                }
            }
            (Wire::ClearError(j), Value::Bool(on)) => {
                if let Drive::Dc {
                    clear_error,
                    bridge_error,
                    ..
                } = &mut self.joints[j].drive
                {
                    // A rising edge clears a latched bridge error.
                    if on && !*clear_error {
                        *bridge_error = false;
                    }
                    *clear_error = on;
                }
            }
            (Wire::PwmPeriod(m), Value::Uint(v)) => self.pwm_period[m] = v,
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkm_api::machine::Plant as _;

    /// pn101's plant with `edit` applied to its defaults, no mechanism; and the index of each
    /// signal key.
    fn pn101(edit: impl FnOnce(&mut PlantConfig)) -> (Plant, impl Fn(&str) -> usize) {
        let mut config = crate::PN101.default_plant();
        edit(&mut config);
        built(&crate::PN101, &config, None)
    }

    /// The plant of `spec` with `config` and `mechanism`, and the index of each signal key.
    fn built(
        spec: &crate::spec::Spec,
        config: &PlantConfig,
        mechanism: Option<Box<dyn Kinematics>>,
    ) -> (Plant, impl Fn(&str) -> usize + use<>) {
        let signals = harness::signals(spec);
        let keys: Vec<&'static str> = signals.iter().map(|(s, _, _)| s.key).collect();
        let plant = Plant::new(config, signals.into_iter().map(|(s, w, _)| (s, w)).collect(), mechanism);
        (plant, move |key: &str| {
            keys.iter().position(|k| *k == key).expect("a signal")
        })
    }

    #[test]
    fn a_shared_input_is_on_when_any_joint_is_on_its_switch() {
        let (plant, at) = pn101(|c| c.joints[1].start_mm = 60.5);
        assert_eq!(plant.read(at("limit_pos")), Value::Bool(true), "joint 2 past +60 mm");
        assert_eq!(plant.read(at("limit_neg")), Value::Bool(false));
        assert_eq!(
            plant.read(at("reference")),
            Value::Bool(true),
            "and past its reference switch"
        );
        let (plant, at) = pn101(|c| c.joints[2].start_mm = -56.0);
        assert_eq!(plant.read(at("limit_pos")), Value::Bool(false));
        assert_eq!(
            plant.read(at("reference")),
            Value::Bool(true),
            "joint 3's switch is at its negative end"
        );
    }

    #[test]
    fn a_stepper_takes_enable_and_speed_of_one_exchange_together() {
        let (mut plant, at) = pn101(|_| {});
        let mut values = vec![Value::Bool(false); plant.signals().len()];
        let (enable, speed) = (at("joint1_enable"), at("joint1_speed"));
        values[enable] = Value::Bool(true);
        values[speed] = Value::Int(400);
        // Within the start-stop speed (2 mm/s): 1 mm/s at once, for 1 s in 10 ms exchanges.
        for _ in 0..100 {
            plant.write_from(&[speed, enable], &values);
            plant.steps(0.001, 10);
        }
        assert!((plant.position_mm(0) - (-9.0)).abs() < 1e-9, "{}", plant.position_mm(0));
        assert_eq!(plant.read(at("joint1_counter")), Value::Int(400));
        assert_eq!(plant.lost_steps(0), 0.0);
        // Disabled, it emits nothing whatever the speed.
        values[enable] = Value::Bool(false);
        plant.write_from(&[speed, enable], &values);
        plant.steps(0.001, 100);
        assert_eq!(plant.read(at("joint1_counter")), Value::Int(400));
    }

    #[test]
    fn every_switch_reads_as_its_definition_on_every_machine() {
        let mut shared_wires = 0;
        for crate::JointMachine(spec) in &crate::MACHINES {
            let config = spec.default_plant();
            let signals = harness::signals(spec);
            let mut plant = Plant::new(&config, signals.into_iter().map(|(s, w, _)| (s, w)).collect(), None);
            let n = config.joints.len();
            // The definition, from the configuration alone (not the plant's own `switch`): a
            // limit switch is on at or beyond its point, a reference switch at or beyond its
            // point in its direction, and a wire that joints share (pn101) when any is on.
            let expected = |plant: &Plant, wire: Wire| {
                let on = |j: usize| {
                    let (q, c) = (plant.position_mm(j), &config.joints[j]);
                    match wire {
                        Wire::Limit(_, 0) => q <= c.limit_switches_mm[0],
                        Wire::Limit(_, _) => q >= c.limit_switches_mm[1],
                        _ => (q - c.reference_switch_mm) * c.reference_direction >= 0.0,
                    }
                };
                match wire {
                    Wire::Limit(Some(j), _) | Wire::Reference(Some(j)) => on(j),
                    _ => (0..n).any(on),
                }
            };
            for j in 0..n {
                let [lo, hi] = plant.hard_stops_mm(j);
                // Every switch point, a hair either side, and the travel between the stops.
                let mut at: Vec<f64> = (0..=40).map(|k| lo + (hi - lo) * f64::from(k) / 40.0).collect();
                let c = &config.joints[j];
                for x in c.limit_switches_mm.into_iter().chain([c.reference_switch_mm]) {
                    at.extend([x, x - 1e-9, x + 1e-9, x.next_up(), x.next_down()]);
                }
                for q in at {
                    plant.move_by_hand(j, q);
                    for (signal, wire) in plant.wires.clone().into_iter().enumerate() {
                        if matches!(wire, Wire::Limit(..) | Wire::Reference(_)) {
                            shared_wires += usize::from(matches!(wire, Wire::Limit(None, _) | Wire::Reference(None)));
                            assert_eq!(
                                plant.read(signal),
                                Value::Bool(expected(&plant, wire)),
                                "{}: {wire:?} with joint {} at {q} mm",
                                spec.name,
                                j + 1
                            );
                        }
                    }
                }
                // Back where it started, for the next joint's sweep of a shared wire.
                plant.move_by_hand(j, c.start_mm);
            }
        }
        assert!(shared_wires > 0, "pn101's shared inputs are among those read");
    }

    /// The hexapod's plant with its kinematics as the mechanism (their joint limits, narrower
    /// than the hard stops: beyond them the mechanism does not assemble), and the signal index
    /// of each key.
    fn hexapod() -> (Plant, impl Fn(&str) -> usize) {
        let spec = &crate::HEXAPOD;
        let kinematics = pkm_kinematics::KinematicsConfig::from_section(None).expect("the defaults");
        built(spec, &spec.default_plant(), Some(kinematics.build(spec.model)))
    }

    #[test]
    fn spans_end_where_the_steps_do_through_a_jam() {
        let (mut spanned, at) = hexapod();
        let (mut stepped, _) = hexapod();
        let mut values = vec![Value::Int(0); spanned.signals().len()];
        let mut outputs = Vec::new();
        for k in ["pwm_period1", "pwm_period2", "pwm_period3"] {
            values[at(k)] = Value::Uint(50);
            outputs.push(at(k));
        }
        // Joint 1 out at full duty, joint 4 in at half: they move until the mechanism refuses.
        values[at("joint1_pwm")] = Value::Int(32767);
        values[at("joint4_pwm")] = Value::Int(-16384);
        outputs.extend([at("joint1_pwm"), at("joint4_pwm")]);
        spanned.write_from(&outputs, &values);
        stepped.write_from(&outputs, &values);
        for cycle in 0..2000 {
            spanned.steps(0.001, 10);
            for _ in 0..10 {
                stepped.step(0.001);
            }
            for j in 0..6 {
                let (a, b) = (spanned.position_mm(j), stepped.position_mm(j));
                assert!(
                    (a - b).abs() < 1e-9,
                    "cycle {cycle}, joint {}: {a} spanned, {b} stepped",
                    j + 1
                );
            }
        }
        assert!(spanned.jams() > 0, "the mechanism refused the motion");
        assert_eq!(spanned.jams(), stepped.jams());
        assert!(
            spanned.position_mm(0) > spanned.start_mm(0) + 10.0,
            "joint 1 moved out first"
        );
    }
}
