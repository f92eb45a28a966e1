//! The drive program (fast class) of a joint-driven machine: per joint the counter unwrap to a
//! position (a stepper module's emitted steps — open loop: the commanded position is the
//! feedback — or an encoder's counts), the touch-probe capture at the reference input's edge,
//! the set-point interpolation between main cycles, the regulator (PI with feed-forward to a
//! PWM bridge, or a speed command to a stepper channel, ramped within the motor's limits),
//! following-error supervision and the fast interlock: STOP, a limit input (unless overridden in
//! joint mode), a fault, a following error or a main state that does not drive zero every drive
//! output in that same cycle.

use pkm_api::image::{Declare, Input, Output};
use pkm_api::program::{Cycle, Program, ProgramArgs};
use pkm_drives::automaton::{MainState, StopInputs};
use pkm_drives::counter::{round_count, unwrap};
use pkm_drives::interlock::{InterlockInputs, following_error};
use pkm_drives::nc::NcChannel;
use pkm_drives::pi::{Pi, PiGains};
use pkm_kinematics::MAX_DOF;

use crate::params::{self, DcDrive, DrivesParams, StepperDrive};
use crate::spec::{DriveKind, Spec};
use crate::switches::Switches;
use crate::vars;

/// The longest cycle the drive program may run in (µs): the interlock's reaction, the unwrap
/// (at 25 mm/s and 1000 counts/mm a counter moves 500 counts in 20 ms) and the stepper ramp.
pub const MAX_DRIVE_CYCLE_US: u32 = 20_000;

/// A joint's drive outputs.
enum Outputs {
    Stepper {
        p: StepperDrive,
        enable: Output<bool>,
        speed: Output<i16>,
        /// The speed commanded last cycle (mm/s), from which the ramp goes on.
        commanded: f64,
    },
    Dc {
        p: DcDrive,
        gains: PiGains,
        pwm: Output<i16>,
        bridge_error: Input<bool>,
        clear_error: Output<bool>,
        pi: Pi,
    },
}

struct Joint {
    counter: Input<i16>,
    reference_input: Input<bool>,
    offset: Input<f64>,
    setpoint: Input<f64>,
    setpoint_velocity: Input<f64>,
    position: Output<f64>,
    capture: Output<f64>,
    captures: Output<i32>,
    following: Output<bool>,
    encoder_fault: Output<bool>,
    outputs: Outputs,
    units_per_mm: f64,
    /// Counter state: started, last raw value, absolute count, latched fault, last reference.
    started: bool,
    last_raw: i16,
    counts: i64,
    fault: bool,
    last_reference: bool,
}

/// The drive program.
pub struct Drives {
    joints: Vec<Joint>,
    limits: Vec<Input<bool>>,
    state: Input<i16>,
    enable: Input<bool>,
    bus_fault: Input<bool>,
    setpoint_time: Input<f64>,
    stop: StopInputs,
    limit_override: Input<bool>,
    ack: Input<bool>,
    last_ack: bool,
    interlock: Output<bool>,
    periods: Vec<Output<u16>>,
    pwm_period_us: u16,
    /// The loaded NC program's execution: in AUTO it gives the joints' set-points.
    nc: Option<NcChannel>,
}

/// Checks the drive parameters of `spec`'s joints (every number within its range of
/// [`pkm_api::ranges`]); problems against `params.…`.
fn check(spec: &Spec, p: &DrivesParams, decl: &mut Declare<'_>) {
    use pkm_api::ranges;
    let n = spec.joints();
    let (list, len) = match spec.drive {
        DriveKind::Stepper => ("steppers", p.steppers.len()),
        DriveKind::Dc => ("dc", p.dc.len()),
    };
    if len != n {
        decl.issue(
            &format!("params.{list}"),
            format!("{} has {n} joints, so {n} drives; got {len}", spec.name),
        );
    }
    let other = match spec.drive {
        DriveKind::Stepper => (!p.dc.is_empty()).then_some(("dc", "stepper")),
        DriveKind::Dc => (!p.steppers.is_empty()).then_some(("steppers", "DC")),
    };
    if let Some((key, kind)) = other {
        decl.issue(
            &format!("params.{key}"),
            format!("{} has {kind} drives only", spec.name),
        );
    }
    for (i, s) in p.steppers.iter().enumerate() {
        let at = |k: &str| format!("params.steppers[{i}].{k}");
        let steps = decl.within(&at("steps_per_mm"), s.steps_per_mm, &ranges::COUNTS_PER_MM);
        let speed = decl.within(&at("max_speed_mm_s"), s.max_speed_mm_s, &ranges::SPEED_MM_S);
        decl.within(&at("max_accel_mm_s2"), s.max_accel_mm_s2, &ranges::ACCEL_MM_S2);
        decl.within(
            &at("max_following_error_mm"),
            s.max_following_error_mm,
            &ranges::FOLLOWING_ERROR_MM,
        );
        decl.within(&at("kp_per_s"), s.kp_per_s, &ranges::PROPORTIONAL_GAIN);
        if steps && speed && s.max_speed_mm_s * s.steps_per_mm > f64::from(i16::MAX) {
            decl.issue(
                &at("max_speed_mm_s"),
                format!(
                    "{} mm/s at {} steps/mm is more than the module's 32767 steps/s",
                    s.max_speed_mm_s, s.steps_per_mm
                ),
            );
        }
    }
    for (i, d) in p.dc.iter().enumerate() {
        let at = |k: &str| format!("params.dc[{i}].{k}");
        decl.within(&at("counts_per_mm"), d.counts_per_mm, &ranges::COUNTS_PER_MM);
        decl.within(
            &at("max_following_error_mm"),
            d.max_following_error_mm,
            &ranges::FOLLOWING_ERROR_MM,
        );
        d.gains().check(decl, at);
        if d.max_counts_per_cycle == 0 || d.max_counts_per_cycle >= 32_768 {
            decl.issue(
                &at("max_counts_per_cycle"),
                format!(
                    "must be 1 … 32767 (half the counter range), got {}",
                    d.max_counts_per_cycle
                ),
            );
        }
    }
    match (spec.drive, p.pwm_period_us) {
        (DriveKind::Dc, Some(us)) => {
            decl.within("params.pwm_period_us", f64::from(us), &pkm_api::ranges::PWM_PERIOD_US);
        }
        (DriveKind::Dc, None) => decl.issue(
            "params.pwm_period_us",
            "a DC machine needs the bridges' PWM period (µs)",
        ),
        (DriveKind::Stepper, Some(_)) => {
            decl.issue("params.pwm_period_us", format!("{} has no motor bridges", spec.name))
        }
        _ => {}
    }
}

impl Drives {
    /// Declares the program's variables for `spec`'s joints.
    pub fn create(spec: &'static Spec, args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p = params::parse(args, decl, spec.default_drives());
        check(spec, &p, decl);
        if !args.fastest_class || args.cycle_us > MAX_DRIVE_CYCLE_US {
            decl.issue(
                "program",
                format!(
                    "{} is the encoder unwrap, the stepper ramp and the fast interlock: it must run in the fastest task class, of at most {} ms; it runs in one of {} ms{}",
                    spec.programs[0].name,
                    MAX_DRIVE_CYCLE_US / 1000,
                    f64::from(args.cycle_us) / 1000.0,
                    if args.fastest_class { "" } else { " that is not the fastest" }
                ),
            );
        }
        let switches = Switches::of(spec);
        let n = spec.joints();
        let joints = (0..n)
            .map(|j| {
                let (outputs, units_per_mm) = match spec.drive {
                    DriveKind::Stepper => {
                        let s = p
                            .steppers
                            .get(j)
                            .cloned()
                            .unwrap_or_else(|| spec.default_drives().steppers[j].clone());
                        let units = s.steps_per_mm;
                        (
                            Outputs::Stepper {
                                p: s,
                                enable: decl.write(vars::ENABLE[j], false),
                                speed: decl.write(vars::SPEED[j], 0),
                                commanded: 0.0,
                            },
                            units,
                        )
                    }
                    DriveKind::Dc => {
                        let d =
                            p.dc.get(j)
                                .cloned()
                                .unwrap_or_else(|| spec.default_drives().dc[j].clone());
                        let units = d.counts_per_mm;
                        (
                            Outputs::Dc {
                                gains: d.gains(),
                                p: d,
                                pwm: decl.write(vars::PWM[j], 0),
                                bridge_error: decl.read(vars::BRIDGE_ERROR[j]),
                                clear_error: decl.write(vars::CLEAR_ERROR[j], false),
                                pi: Pi::default(),
                            },
                            units,
                        )
                    }
                };
                Joint {
                    counter: decl.read(vars::COUNTER[j]),
                    reference_input: decl.read(switches.reference(j)),
                    offset: decl.read(vars::OFFSET[j]),
                    setpoint: decl.read(vars::SETPOINT[j]),
                    setpoint_velocity: decl.read(vars::SETPOINT_VELOCITY[j]),
                    position: decl.write(vars::JOINT_POSITION[j], 0.0),
                    capture: decl.write(vars::CAPTURE[j], 0.0),
                    captures: decl.write(vars::CAPTURES[j], 0),
                    following: decl.write(vars::FOLLOWING_ERROR[j], false),
                    encoder_fault: decl.write(vars::ENCODER_FAULT[j], false),
                    outputs,
                    units_per_mm,
                    started: false,
                    last_raw: 0,
                    counts: 0,
                    fault: false,
                    last_reference: false,
                }
            })
            .collect();
        let periods = match spec.drive {
            DriveKind::Dc => vars::PWM_PERIOD[..n.div_ceil(2)]
                .iter()
                .map(|v| decl.write(*v, 0))
                .collect(),
            DriveKind::Stepper => Vec::new(),
        };
        Box::new(Drives {
            joints,
            limits: switches.limits().iter().map(|l| decl.read(l.var)).collect(),
            state: decl.read(vars::MAIN_STATE),
            enable: decl.read(vars::DRIVES_ENABLE),
            bus_fault: decl.read(vars::BUS_FAULT),
            setpoint_time: decl.read(vars::SETPOINT_TIME_S),
            stop: StopInputs::declare(decl, vars::BUTTON_STOP, vars::JOYSTICK_STOP),
            limit_override: decl.read(vars::LIMIT_OVERRIDE),
            ack: decl.read(vars::FAULT_ACK),
            last_ack: false,
            interlock: decl.write(vars::INTERLOCK, false),
            periods,
            pwm_period_us: p.pwm_period_us.unwrap_or(0),
            nc: args.nc.map(|library| NcChannel::declare(library, n, decl)),
        })
    }
}

impl Program for Drives {
    // Long, and kept whole: the fast interlock's cycle reads every joint's feedback, decides
    // once whether the drives may move, then writes every joint's output; the order is the
    // safety rule, and one place shows it.
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let dt = ctx.period_ns() as f64 * 1e-9;
        let ack = ctx.get(self.ack);
        let ack_edge = ack && !self.last_ack;
        self.last_ack = ack;
        // Feedback first: positions, encoder faults and captures of every joint.
        for j in &mut self.joints {
            let raw = ctx.get(j.counter);
            if !j.started {
                j.started = true;
                j.last_raw = raw;
                j.counts = 0;
            }
            let (counts, delta) = unwrap(j.counts, j.last_raw, raw);
            j.last_raw = raw;
            if ack_edge {
                j.fault = false;
            }
            let bound = match &j.outputs {
                Outputs::Dc { p, .. } => u64::from(p.max_counts_per_cycle),
                // A stepper module counts the steps it emits itself: no jump to suspect.
                Outputs::Stepper { .. } => u64::MAX,
            };
            if delta.unsigned_abs() > bound {
                // Not a plausible motion: keep the last good count and report the fault.
                j.fault = true;
            } else {
                j.counts = counts;
            }
            let absolute = j.counts as f64 / j.units_per_mm;
            ctx.set(j.position, absolute - ctx.get(j.offset));
            ctx.set(j.encoder_fault, j.fault);
            let on = ctx.get(j.reference_input);
            if on && !j.last_reference {
                ctx.set(j.capture, absolute);
                let n = ctx.output_value(j.captures).wrapping_add(1);
                ctx.set(j.captures, n);
            }
            j.last_reference = on;
        }
        let state = MainState::from_code(ctx.get(self.state));
        let enabled = state.is_some_and(MainState::operating) && ctx.get(self.enable);
        let limit = self.limits.iter().any(|l| ctx.get(*l));
        let fault = ctx.get(self.bus_fault)
            || self.joints.iter().any(|j| {
                j.fault
                    || match &j.outputs {
                        Outputs::Dc { bridge_error, .. } => ctx.get(*bridge_error),
                        Outputs::Stepper { .. } => false,
                    }
            });
        let stop = self.stop.pressed(ctx);
        let interlock = InterlockInputs {
            stop,
            limit_switch: limit,
            switches_expected: ctx.get(self.limit_override) && state == Some(MainState::Init),
            fault,
            enabled,
        }
        .engaged();
        // Between main cycles the set-point moves on at its velocity; in AUTO the program sets
        // it, sampled in this cycle.
        let since = (ctx.time_ns() as f64 * 1e-9 - ctx.get(self.setpoint_time)).max(0.0);
        let mut targets = [(0.0, 0.0); MAX_DOF];
        for (t, j) in targets.iter_mut().zip(&self.joints) {
            let velocity = ctx.get(j.setpoint_velocity);
            *t = (ctx.get(j.setpoint) + velocity * since, velocity);
        }
        if let Some(nc) = &mut self.nc {
            let mut positions = [0.0; MAX_DOF];
            for (p, j) in positions.iter_mut().zip(&self.joints) {
                *p = ctx.output_value(j.position);
            }
            let auto = state == Some(MainState::Auto);
            let n = self.joints.len();
            if let Some((q, v)) = nc.step(ctx, auto, interlock, &positions[..n]) {
                for (t, (q, v)) in targets.iter_mut().zip(q.iter().zip(&v)) {
                    *t = (*q, *v);
                }
            }
        }
        let mut following = false;
        for (j, (target, _)) in self.joints.iter_mut().zip(targets) {
            let error = target - ctx.output_value(j.position);
            let bound = match &j.outputs {
                Outputs::Stepper { p, .. } => p.max_following_error_mm,
                Outputs::Dc { p, .. } => p.max_following_error_mm,
            };
            let latched = ctx.output_value(j.following);
            let f = following_error(enabled, latched, interlock, error, bound);
            ctx.set(j.following, f);
            following |= f;
        }
        let interlock = interlock || following;
        ctx.set(self.interlock, interlock);
        for (j, (target, velocity)) in self.joints.iter_mut().zip(targets) {
            let error = target - ctx.output_value(j.position);
            match &mut j.outputs {
                Outputs::Stepper {
                    p,
                    enable,
                    speed,
                    commanded,
                } => {
                    let v = if interlock {
                        0.0
                    } else {
                        // The set-point's velocity plus a correction of the remaining error,
                        // within the joint's speed and ramped within its acceleration.
                        let wanted = (velocity + p.kp_per_s * error).clamp(-p.max_speed_mm_s, p.max_speed_mm_s);
                        let step = p.max_accel_mm_s2 * dt;
                        wanted.clamp(*commanded - step, *commanded + step)
                    };
                    *commanded = v;
                    let rate = round_count(v * p.steps_per_mm).clamp(-32767, 32767) as i16;
                    ctx.set(*enable, !interlock);
                    ctx.set(*speed, rate);
                }
                Outputs::Dc {
                    gains,
                    pwm,
                    clear_error,
                    pi,
                    ..
                } => {
                    let duty = if interlock {
                        pi.reset();
                        0.0
                    } else {
                        pi.step(gains, error, velocity, dt)
                    };
                    // As `f64 as i16` would: saturated at the type's ends.
                    ctx.set(*pwm, round_count(duty * 32767.0).clamp(-32768, 32767) as i16);
                    ctx.set(*clear_error, ack);
                }
            }
        }
        for period in &self.periods {
            ctx.set(*period, self.pwm_period_us);
        }
    }
}
