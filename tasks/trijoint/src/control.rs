//! The drive controller (10 ms class): a PI position regulator with velocity feed-forward per
//! drive, following-error supervision, and the fast interlock — STOP pressed, a limit switch
//! outside INIT, a bus fault, a motor bridge or encoder fault, a following error, or a main state
//! that does not drive: PWM zero in that same cycle. (The original reacted only in its 50 ms task.)

use serde::Deserialize;

use super::state::MainState;
use crate::vars;
use pkm_api::image::{Declare, Input, Output};
use pkm_api::program::{Cycle, Program, ProgramArgs};
use pkm_drives::automaton::StopInputs;
use pkm_drives::interlock::{InterlockInputs, following_error};
use pkm_drives::nc::NcChannel;
use pkm_drives::pi::{Pi, PiGains};

/// The longest cycle of the class that runs the drive programs (µs): the interlock's reaction,
/// and the encoders' unwrap — at the lab model's 80 mm/s a 16-bit counter moves 11 200 counts in
/// 20 ms, well within the ±32 768 that unwrapping can tell apart.
pub const MAX_DRIVE_CYCLE_US: u32 = 20_000;

/// Refuses a drive program (`what`) outside the fastest task class or in one slower than
/// [`MAX_DRIVE_CYCLE_US`].
pub fn fast_class_only(name: &str, what: &str, args: &ProgramArgs<'_>, decl: &mut Declare<'_>) {
    if !args.fastest_class || args.cycle_us > MAX_DRIVE_CYCLE_US {
        decl.issue(
            "program",
            format!(
                "{name} is {what}: it must run in the fastest task class, of at most {} ms; it runs in one of {} ms{}",
                MAX_DRIVE_CYCLE_US / 1000,
                f64::from(args.cycle_us) / 1000.0,
                if args.fastest_class {
                    ""
                } else {
                    " that is not the fastest"
                }
            ),
        );
    }
}

/// Regulator parameters.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControlParams {
    /// Proportional gain: duty (−1…1) per mm of following error.
    pub kp: f64,
    /// Integral gain: duty per mm·s.
    pub ki: f64,
    /// Velocity feed-forward: duty per mm/s of set-point velocity (LinuxCNC's FF1). With it the
    /// duty that moves the carriage at the set-point's speed comes from the set-point itself, so
    /// the integral need not carry it — and need not unwind, overshooting, when the set-point
    /// brakes. 1/80: the lab model's drive runs 80 mm/s at full duty.
    pub velocity_ff: f64,
    /// Acceleration feed-forward: duty per mm/s² of set-point acceleration (the drive's lag τ
    /// times `velocity_ff`; LinuxCNC's FF2). The original's regulator had none.
    pub accel_ff: f64,
    /// Output limit (duty, 0…1).
    pub output_limit: f64,
    /// A following error above this (mm) is a fault.
    pub max_following_error_mm: f64,
}

impl Default for ControlParams {
    fn default() -> Self {
        ControlParams {
            kp: 0.25,
            ki: 1.0,
            velocity_ff: 1.0 / 80.0,
            // The lab model's speed lags the duty by τ = 50 ms: without this, its contour error
            // on the circle and square program was 0.17 mm; with it, 0.013 mm.
            accel_ff: 0.05 / 80.0,
            output_limit: 1.0,
            max_following_error_mm: 5.0,
        }
    }
}

impl ControlParams {
    /// The regulator's gains (duty per mm, per mm·s, per mm/s; duty limit).
    pub fn gains(&self) -> PiGains {
        PiGains {
            kp: self.kp,
            ki: self.ki,
            velocity_ff: self.velocity_ff,
            accel_ff: self.accel_ff,
            output_limit: self.output_limit,
        }
    }
}

struct Drive {
    position: Input<f64>,
    setpoint: Input<f64>,
    setpoint_velocity: Input<f64>,
    fault: Input<bool>,
    bridge_error: Input<bool>,
    switches: [Input<bool>; 2],
    pwm: Output<i16>,
    following_error: Output<bool>,
}

/// The controller program.
pub struct Control {
    p: ControlParams,
    state: Input<i16>,
    enable: Input<bool>,
    bus_fault: Input<bool>,
    setpoint_time: Input<f64>,
    stop: StopInputs,
    interlock: Output<bool>,
    drives: [Drive; 2],
    pi: [Pi; 2],
    /// The loaded NC program's execution: in AUTO it gives the carriages' set-points.
    nc: Option<NcChannel>,
}

impl Control {
    /// Declares the program's variables.
    pub fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p: ControlParams = args.parse(decl);
        decl.within(
            "params.max_following_error_mm",
            p.max_following_error_mm,
            &pkm_api::ranges::FOLLOWING_ERROR_MM,
        );
        p.gains().check(decl, |k| format!("params.{k}"));
        fast_class_only(
            "trijoint.control",
            "the fast interlock (STOP and switches to PWM zero)",
            args,
            decl,
        );
        let drive = |d: usize, decl: &mut Declare<'_>| Drive {
            position: decl.read(vars::POSITION_MM[d]),
            setpoint: decl.read(vars::SETPOINT_MM[d]),
            setpoint_velocity: decl.read(vars::SETPOINT_MM_S[d]),
            fault: decl.read(vars::ENCODER_FAULT[d]),
            bridge_error: decl.read(vars::BRIDGE_ERROR[d]),
            switches: vars::SWITCHES[d].map(|v| decl.read(v)),
            pwm: decl.write(vars::VELOCITY_SET[d], 0),
            following_error: decl.write(vars::FOLLOWING_ERROR[d], false),
        };
        let drives = [drive(0, decl), drive(1, decl)];
        Box::new(Control {
            p,
            state: decl.read(vars::MAIN_STATE),
            enable: decl.read(vars::DRIVES_ENABLE),
            bus_fault: decl.read(vars::BUS_FAULT),
            setpoint_time: decl.read(vars::SETPOINT_TIME_S),
            stop: StopInputs::declare(decl, vars::BUTTON_STOP, vars::JOYSTICK_STOP),
            interlock: decl.write(vars::INTERLOCK, false),
            drives,
            pi: [Pi::default(); 2],
            // M's plane: two pose coordinates, x and y.
            nc: args.nc.map(|library| NcChannel::declare(library, 2, decl)),
        })
    }
}

impl Program for Control {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        let state = MainState::from_code(ctx.get(self.state));
        let in_init = state == Some(MainState::Init);
        let driving_state = state.is_some_and(MainState::operating);
        let enabled = driving_state && ctx.get(self.enable);
        let switch = self.drives.iter().any(|d| d.switches.iter().any(|s| ctx.get(*s)));
        let faults = ctx.get(self.bus_fault) || self.drives.iter().any(|d| ctx.get(d.bridge_error) || ctx.get(d.fault));
        let stop = self.stop.pressed(ctx);
        let interlock = InterlockInputs {
            stop,
            limit_switch: switch,
            switches_expected: in_init,
            fault: faults,
            enabled,
        }
        .engaged();
        // The main program publishes set-points every 50 ms with their velocity and time; between
        // its cycles the set-point moves on at that velocity, so ramps reach the drives smoothly.
        // In AUTO the program sets them, sampled in this cycle.
        let since = (ctx.time_ns() as f64 * 1e-9 - ctx.get(self.setpoint_time)).max(0.0);
        let mut targets = self.drives.each_ref().map(|d| {
            (
                ctx.get(d.setpoint) + ctx.get(d.setpoint_velocity) * since,
                ctx.get(d.setpoint_velocity),
            )
        });
        if let Some(nc) = &mut self.nc {
            let positions = self.drives.each_ref().map(|d| ctx.get(d.position));
            let auto = state == Some(MainState::Auto);
            if let Some((q, v)) = nc.step(ctx, auto, interlock, &positions) {
                targets = [(q[0], v[0]), (q[1], v[1])];
            }
        }
        let errors: [f64; 2] = std::array::from_fn(|i| targets[i].0 - ctx.get(self.drives[i].position));
        // A following error stays latched while the drives are enabled (the main program turns it
        // into ERROR, which disables them) and stops both drives in the cycle it is found.
        let following: [bool; 2] = std::array::from_fn(|i| {
            let latched = ctx.output_value(self.drives[i].following_error);
            following_error(enabled, latched, interlock, errors[i], self.p.max_following_error_mm)
        });
        let interlock = interlock || following.iter().any(|f| *f);
        ctx.set(self.interlock, interlock);
        let dt = ctx.period_ns() as f64 * 1e-9;
        let gains = self.p.gains();
        for (i, (d, pi)) in self.drives.iter().zip(self.pi.iter_mut()).enumerate() {
            let duty = if interlock {
                pi.reset();
                0.0
            } else {
                pi.step(&gains, errors[i], targets[i].1, dt)
            };
            ctx.set(d.pwm, (duty * 32767.0).round() as i16);
            ctx.set(d.following_error, following[i]);
        }
    }
}
