//! The main program (50 ms class, HW_obsluha of the original): the REBOOT → INIT → READY ⇄ MOTION
//! and ERROR automaton of docs/trijoint.md — the shared statig state machine of pkm-drives with the
//! TRIJOINT's referencing and jog.
//!
//! Every cycle dispatches one event: an accepted STOP press, else a supervision fault, else a tick.
//! The superstate `operating` (INIT, READY, MOTION) turns STOP and faults into ERROR; ERROR turns
//! an accepted STOP press into REBOOT (acknowledgement). STOP acts on the press (the rising edge),
//! not the level: with the original's level semantics, holding STOP longer than the lockout would
//! acknowledge the error and restart INIT while the button is still held.

mod automaton;
mod jog;
mod params;
mod reason;
mod referencing;

pub use automaton::{Automaton, Event, Io, Main};
pub use params::MainParams;
pub use reason::Reason;

use params::{MAX_MAIN_CYCLE_US, check_ranges};
use reason::SWITCHES;
use referencing::{End, Search};

use pkm_api::image::{Declare, Input, Output};
use pkm_api::program::{AppStatus, Cycle, Program, ProgramArgs};
use pkm_kinematics::trijoint::{Trijoint, TrijointParams};
use pkm_kinematics::{Kinematics, KinematicsConfig};

use crate::state::MainState;
use crate::vars;
use pkm_drives::automaton::{StopButton, StopInputs, event as automaton_event};
use pkm_drives::nc;
use statig::prelude::*;

struct Vars {
    stop: StopInputs,
    bus_fault: Input<bool>,
    switches: [Input<bool>; 4],
    buttons: [Input<bool>; 4],
    joystick: [Input<f64>; 2],
    joystick_connected: Input<bool>,
    positions: [Input<f64>; 2],
    captures: [[Input<f64>; 2]; 2],
    capture_counts: [[Input<i32>; 2]; 2],
    encoder_faults: [Input<bool>; 2],
    bridge_errors: [Input<bool>; 2],
    following_errors: [Input<bool>; 2],
    state: Output<i16>,
    reason: Output<i16>,
    enable: Output<bool>,
    setpoints: [Output<f64>; 2],
    velocities: [Output<f64>; 2],
    setpoint_time: Output<f64>,
    references: [Output<f64>; 2],
    acknowledge: Output<bool>,
    clear_errors: [Output<bool>; 2],
    period: Output<u16>,
    referenced: Output<bool>,
    m: [Output<f64>; 2],
    nc: Option<NcVars>,
    hmi_jog: [Input<f64>; 2],
    hmi_jog_axis: Input<i16>,
    hmi_nc: [Input<bool>; 3],
    /// The screen's Reference (a press, taken in READY).
    hmi_reference: Input<bool>,
}

/// The variables of program execution, declared when a program is loaded.
struct NcVars {
    /// The screen's request to load another of the run's programs.
    request: Input<i16>,
    /// The loaded program's number.
    program: Output<i16>,
    buttons: [Input<bool>; 3],
    state: Input<i16>,
    line: Input<i32>,
    time: Input<f64>,
    fault: Input<bool>,
    command: Output<i16>,
}

/// The main program.
pub struct MainProgram {
    machine: StateMachine<Automaton>,
    io: Io,
    vars: Vars,
    stop: StopButton,
    display: Trijoint,
    /// M and the carriage positions, for the status line (the program line first in AUTO).
    shown: [(&'static str, f64); 7],
    shown_len: usize,
    /// The reason with the program line executing when ERROR was entered from AUTO.
    line_reason: nc::LineReason,
    /// The screen's Reference as the last cycle saw it (a press is its rising edge).
    reference_was_pressed: bool,
}

impl MainProgram {
    /// Declares the program's variables.
    pub fn create(args: &ProgramArgs<'_>, decl: &mut Declare<'_>) -> Box<dyn Program> {
        let p: MainParams = args.parse(decl);
        let geometry = args
            .kinematics
            .and_then(|k| serde_json::from_value::<KinematicsConfig>(k.clone()).ok())
            .unwrap_or_default()
            .trijoint;
        check_ranges(&p, &geometry, decl);
        if args.cycle_us > MAX_MAIN_CYCLE_US {
            decl.issue(
                "program",
                format!(
                    "trijoint.main runs in a class of {} ms; at most {} ms: STOP, limit switches and faults \
                     become ERROR in its cycle",
                    args.cycle_us / 1000,
                    MAX_MAIN_CYCLE_US / 1000
                ),
            );
        }
        let vars = Vars {
            stop: StopInputs::declare(decl, vars::BUTTON_STOP, vars::JOYSTICK_STOP),
            bus_fault: decl.read(vars::BUS_FAULT),
            switches: SWITCHES.map(|v| decl.read(v)),
            buttons: vars::BUTTONS.map(|v| decl.read(v)),
            joystick: vars::JOYSTICK.map(|v| decl.read(v)),
            joystick_connected: decl.read(vars::JOYSTICK_CONNECTED),
            positions: vars::POSITION_MM.map(|v| decl.read(v)),
            captures: vars::CAPTURE_MM.map(|d| d.map(|v| decl.read(v))),
            capture_counts: vars::CAPTURES.map(|d| d.map(|v| decl.read(v))),
            encoder_faults: vars::ENCODER_FAULT.map(|v| decl.read(v)),
            bridge_errors: vars::BRIDGE_ERROR.map(|v| decl.read(v)),
            following_errors: vars::FOLLOWING_ERROR.map(|v| decl.read(v)),
            state: decl.write(vars::MAIN_STATE, MainState::Reboot.code()),
            reason: decl.write(vars::ERROR_REASON, 0),
            enable: decl.write(vars::DRIVES_ENABLE, false),
            setpoints: vars::SETPOINT_MM.map(|v| decl.write(v, 0.0)),
            velocities: vars::SETPOINT_MM_S.map(|v| decl.write(v, 0.0)),
            setpoint_time: decl.write(vars::SETPOINT_TIME_S, 0.0),
            references: vars::REFERENCE_MM.map(|v| decl.write(v, 0.0)),
            acknowledge: decl.write(vars::ENCODER_FAULT_ACK, false),
            clear_errors: vars::CLEAR_ERROR.map(|v| decl.write(v, false)),
            period: decl.write(vars::PERIOD_DURATION, 0),
            referenced: decl.write(vars::REFERENCED, false),
            m: vars::M.map(|v| decl.write(v, 0.0)),
            nc: args.nc.map(|_| NcVars {
                request: decl.read_optional(pkm_api::hmi::HMI_NC_PROGRAM),
                program: decl.write(nc::vars::NC_PROGRAM, 1),
                buttons: [nc::vars::NC_START, nc::vars::NC_HOLD, nc::vars::NC_RESUME].map(|v| decl.read_optional(v)),
                state: decl.read(nc::vars::NC_STATE),
                line: decl.read(nc::vars::NC_LINE),
                time: decl.read(nc::vars::NC_TIME_S),
                fault: decl.read(nc::vars::NC_FAULT),
                command: decl.write(nc::vars::NC_COMMAND, nc::Command::Off as i16),
            }),
            hmi_jog: pkm_api::hmi::HMI_JOG.map(|v| decl.read_optional(v)),
            hmi_jog_axis: decl.read_optional(pkm_api::hmi::HMI_JOG_AXIS),
            hmi_nc: pkm_api::hmi::HMI_NC.map(|v| decl.read_optional(v)),
            hmi_reference: decl.read_optional(pkm_api::hmi::HMI_REFERENCE),
        };
        let lockout_s = p.stop_lockout_ms as f64 * 1e-3;
        let display = Trijoint::new(&TrijointParams {
            h1_travel: [-1e6, 1e6],
            h2_travel: [-1e6, 1e6],
            ..geometry.clone()
        });
        let mut main = Main::new(p, geometry);
        main.trajectories = args
            .nc
            .map_or(&[][..], |l| &l.jobs)
            .iter()
            .map(|job| std::sync::Arc::clone(&job.trajectory))
            .collect();
        let io = Io {
            program: nc::ProgramControl::of(args.nc),
            ..Io::default()
        };
        Box::new(MainProgram {
            machine: Automaton::new(main).state_machine(),
            io,
            vars,
            stop: StopButton::new(lockout_s),
            display,
            shown: [("", f64::NAN); 7],
            shown_len: 0,
            line_reason: nc::LineReason::default(),
            reference_was_pressed: false,
        })
    }

    /// Reads the inputs into `io` and advances the set-points to where the controller has taken
    /// them since the last cycle.
    fn read(&mut self, ctx: &Cycle<'_>) {
        let (v, io) = (&self.vars, &mut self.io);
        io.now_s = ctx.time_ns() as f64 * 1e-9;
        io.dt_s = ctx.period_ns() as f64 * 1e-9;
        io.positions = v.positions.map(|p| ctx.get(p));
        io.switches = v.switches.map(|s| ctx.get(s));
        io.buttons = v.buttons.map(|b| ctx.get(b));
        io.joystick = v.joystick.map(|j| ctx.get(j));
        io.joystick_connected = ctx.get(v.joystick_connected);
        // The screen's jog, while held, in place of the joystick.
        let screen = v.hmi_jog.map(|j| ctx.get(j));
        io.screen_carriage = 0;
        if screen != [0.0; 2] {
            // The screen's button of one axis (1: x, 2: y) moves M along that axis alone; that
            // of one carriage (−1: left, −2: right) moves that carriage alone.
            let axis = ctx.get(v.hmi_jog_axis);
            io.joystick = match axis {
                1 | -1 | -2 => [screen[0], 0.0],
                2 => [0.0, screen[0]],
                _ => screen,
            };
            if axis < 0 {
                io.screen_carriage = axis.unsigned_abs() as usize;
            }
            io.joystick_connected = true;
        }
        io.captures = v.captures.map(|c| c.map(|x| ctx.get(x)));
        io.capture_counts = v.capture_counts.map(|c| c.map(|x| ctx.get(x)));
        for i in 0..2 {
            io.setpoints[i] += io.velocities[i] * io.dt_s;
        }
        if let Some(nc) = &v.nc {
            let auto = self.machine.inner().state == MainState::Auto;
            io.program.select(ctx.get(nc.request), auto);
            let screen = v.hmi_nc.map(|b| ctx.get(b));
            let panel = nc.buttons.map(|b| ctx.get(b));
            io.program.buttons(std::array::from_fn(|i| panel[i] || screen[i]));
            io.nc_state = nc::RunState::from_code(ctx.get(nc.state));
            io.nc_line = ctx.get(nc.line);
            io.nc_time_s = ctx.get(nc.time);
        }
    }

    /// The event of this cycle (the shared rule; the TRIJOINT's supervision faults in order).
    fn event(&mut self, ctx: &Cycle<'_>) -> Event {
        let (v, io) = (&self.vars, &self.io);
        let state = self.machine.inner().state;
        let searches = &self.machine.inner().app.searches;
        let pressed = v.stop.pressed(ctx);
        let asked = ctx.get(v.hmi_reference);
        let reference = asked && !self.reference_was_pressed;
        self.reference_was_pressed = asked;
        automaton_event(&mut self.stop, pressed, reference, io.now_s, state, || {
            if ctx.violation().is_some() {
                return Some(Reason::CycleTimeViolation);
            }
            if ctx.get(v.bus_fault) {
                return Some(Reason::BusFault);
            }
            if v.nc.as_ref().is_some_and(|nc| ctx.get(nc.fault)) {
                return Some(Reason::ProgramFault);
            }
            for (d, search) in searches.iter().enumerate() {
                if ctx.get(v.encoder_faults[d]) {
                    return Some(Reason::EncoderFault(d));
                }
                if ctx.get(v.bridge_errors[d]) {
                    return Some(Reason::BridgeError(d));
                }
                if ctx.get(v.following_errors[d]) {
                    // While seeking a switch in INIT a following error says the carriage lags its
                    // set-point: blocked (a switch stuck off leaves it at its hard stop), or its
                    // drive or the link too slow. Named as such, with the switch it sought.
                    let seeking = match search {
                        Search::Seek { end, .. } if state == MainState::Init => Some(end.switch(d)),
                        _ => None,
                    };
                    return Some(seeking.map_or(Reason::FollowingError(d), Reason::InitFollowingError));
                }
            }
            if state != MainState::Init {
                return io.switches.iter().position(|s| *s).map(Reason::LimitSwitch);
            }
            None
        })
    }

    fn write(&mut self, ctx: &mut Cycle<'_>) {
        let automaton = self.machine.inner();
        let (v, io) = (&self.vars, &self.io);
        ctx.set(v.state, automaton.state.code());
        ctx.set(v.reason, automaton.reason.map_or(0, Reason::code));
        ctx.set(v.enable, io.enable);
        for i in 0..2 {
            ctx.set(v.setpoints[i], io.setpoints[i]);
            ctx.set(v.velocities[i], io.velocities[i]);
            ctx.set(v.references[i], io.references[i]);
            ctx.set(v.clear_errors[i], io.acknowledge);
        }
        ctx.set(v.setpoint_time, io.now_s);
        ctx.set(v.acknowledge, io.acknowledge);
        ctx.set(v.period, self.machine.inner().app.p.pwm_period_us);
        ctx.set(v.referenced, io.referenced);
        if let (Some(nc), Some(command)) = (&v.nc, io.program.command()) {
            ctx.set(nc.command, command as i16);
            ctx.set(nc.program, io.program.number());
        }
        let mut m = [f64::NAN; 2];
        if io.referenced && self.display.forward(&io.positions, None, &mut m).is_ok() {
            ctx.set(v.m[0], m[0]);
            ctx.set(v.m[1], m[1]);
        }
        let line = (automaton.state == MainState::Auto).then_some(("line", f64::from(io.nc_line)));
        let shown = [
            // As every machine shows them: the tool point, then the joints.
            ("x", m[0]),
            ("y", m[1]),
            ("q1", io.positions[0]),
            ("q2", io.positions[1]),
            // The joystick's axes; "-" while it is not connected.
            (
                "jx",
                if io.joystick_connected {
                    io.joystick[0]
                } else {
                    f64::NAN
                },
            ),
            (
                "jy",
                if io.joystick_connected {
                    io.joystick[1]
                } else {
                    f64::NAN
                },
            ),
        ];
        self.shown_len = 0;
        for value in line.into_iter().chain(shown) {
            self.shown[self.shown_len] = value;
            self.shown_len += 1;
        }
    }
}

impl Program for MainProgram {
    fn cycle(&mut self, ctx: &mut Cycle<'_>) {
        self.read(ctx);
        let event = self.event(ctx);
        let before = self.machine.inner().state;
        self.machine.handle_with_context(&event, &mut self.io);
        // The program line executing goes with an ERROR's reason.
        let a = self.machine.inner();
        self.line_reason
            .observe(before, a.state, a.reason.map(Reason::text), self.io.nc_line);
        self.write(ctx);
    }

    fn status(&self) -> Option<AppStatus<'_>> {
        let a = self.machine.inner();
        let note = match a.state {
            MainState::Auto | MainState::Ready => self.io.program.note(a.state == MainState::Auto, self.io.nc_state),
            _ => None,
        };
        Some(AppStatus {
            state: a.state.name(),
            reason: a.reason.map(|r| self.line_reason.text(r.text())),
            note,
            values: &self.shown[..self.shown_len],
        })
    }
}
