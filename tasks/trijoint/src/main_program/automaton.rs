//! The TRIJOINT's main automaton: the shared REBOOT → INIT → READY ⇄ MOTION and ERROR state
//! machine of pkm-drives with what the TRIJOINT does in each state (`Main`), the inputs and
//! outputs of a cycle it works on (`Io`). Referencing and jogging are `Main`'s, in their own
//! modules.

use std::sync::Arc;

use pkm_api::trajectory::Trajectory;
use pkm_drives::automaton::Application;
use pkm_drives::nc::{ProgramControl, RunState};
use pkm_kinematics::trijoint::{Trijoint, TrijointParams};

use super::*;

/// The events the automaton handles: the shared automaton's, with the TRIJOINT's reasons.
pub type Event = pkm_drives::automaton::Event<Reason>;

/// The TRIJOINT's main automaton: the shared one with the TRIJOINT's referencing and jog.
pub type Automaton = pkm_drives::automaton::Automaton<Main>;

/// Inputs and outputs of one cycle, shared with the states.
#[derive(Clone, Debug, Default)]
pub struct Io {
    pub(super) now_s: f64,
    pub(super) dt_s: f64,
    pub(super) positions: [f64; 2],
    pub(super) switches: [bool; 4],
    pub(super) captures: [[f64; 2]; 2],
    pub(super) capture_counts: [[i32; 2]; 2],
    pub(super) joystick: [f64; 2],
    pub(super) joystick_connected: bool,
    /// The screen jogs this carriage alone (1: left, 2: right; 0: none); its deflection is the
    /// joystick's x.
    pub(super) screen_carriage: usize,
    pub(super) buttons: [bool; 4],
    // Outputs. A set-point is published with its velocity: the 10 ms controller moves it on at
    // that velocity until the next main cycle.
    pub(super) enable: bool,
    pub(super) setpoints: [f64; 2],
    pub(super) velocities: [f64; 2],
    pub(super) references: [f64; 2],
    pub(super) acknowledge: bool,
    pub(super) referenced: bool,
    /// The loaded program's control: its buttons, start, hold and resume, the command.
    pub(super) program: ProgramControl,
    /// The executor's state, line and place on the program's time line (from the controller).
    pub(super) nc_state: Option<RunState>,
    pub(super) nc_line: i32,
    pub(super) nc_time_s: f64,
}

/// How close the carriages must be to the program's start for a start (mm).
const START_TOLERANCE_MM: f64 = 1e-3;

impl Io {
    /// Holds both drives at their current set-points.
    pub(super) fn hold(&mut self) {
        self.velocities = [0.0; 2];
    }

    /// Moves set-point `i` towards `target` at up to `speed`; true once it is there.
    pub(super) fn ramp_to(&mut self, i: usize, target: f64, speed: f64) -> bool {
        let gap = target - self.setpoints[i];
        self.velocities[i] = (gap / self.dt_s).clamp(-speed, speed);
        gap.abs() < 1e-9
    }
}

/// What the TRIJOINT does in each state of the shared automaton, and what it keeps.
pub struct Main {
    pub(super) p: MainParams,
    pub(super) geometry: TrijointParams,
    pub(super) edges: [[f64; 2]; 2],
    pub(super) limits: Option<Trijoint>,
    /// The software limits of the carriages, [lower, upper] per drive (mm, referenced).
    pub(super) soft: [[f64; 2]; 2],
    pub(super) m_setpoint: [f64; 2],
    pub(super) searches: [Search; 2],
    /// The run's programs (the loaded one is `io.program`'s), and where this program samples
    /// the loaded one.
    pub(super) trajectories: Vec<Arc<dyn Trajectory>>,
    pub(super) cursor: usize,
}

impl Application for Main {
    type Reason = Reason;
    type Io = Io;
    const STOP: Reason = Reason::Stop;

    fn now_s(io: &Io) -> f64 {
        io.now_s
    }

    fn enter_reboot(&mut self, io: &mut Io) {
        self.limits = None;
        io.enable = false;
        io.acknowledge = true;
        io.referenced = false;
        io.references = [0.0; 2];
        io.hold();
    }

    fn enter_init(&mut self, io: &mut Io) {
        io.setpoints = io.positions;
        io.hold();
        self.searches = [0, 1].map(|i| Search::Seek {
            end: End::Upper,
            stage: 0,
            seen: io.capture_counts[i],
            since_s: io.now_s,
        });
    }

    fn init(&mut self, io: &mut Io) -> Result<bool, Reason> {
        io.enable = true;
        io.acknowledge = false;
        for i in 0..2 {
            self.step_search(io, i)?;
        }
        if self.searches.iter().all(|s| *s == Search::Found) {
            self.finish_referencing(io);
        }
        Ok(self.searches.iter().all(|s| *s == Search::Done))
    }

    fn enter_ready(&mut self, io: &mut Io) {
        io.hold();
        io.program.leave();
    }

    fn ready(&mut self, io: &mut Io) -> bool {
        io.hold();
        let jog = self.command(io) != [0.0; 2] || self.carriage_command(io).is_some();
        if jog {
            io.program.forget_refusal();
        }
        jog
    }

    fn start_auto(&mut self, io: &mut Io) -> bool {
        let Some(trajectory) = io.program.trajectory() else {
            return false;
        };
        // A program starts where it was checked and planned from: the start position.
        self.cursor = 0;
        let start = trajectory.sample(0.0, &mut self.cursor).joints;
        let at_start = (0..2).all(|i| (io.setpoints[i] - start[i]).abs() <= START_TOLERANCE_MM);
        io.program.start(at_start)
    }

    fn enter_auto(&mut self, io: &mut Io) {
        io.hold();
        io.program.enter();
    }

    fn auto(&mut self, io: &mut Io) -> bool {
        // No jog in AUTO: the controller takes the set-points from the program; these follow
        // it, so that READY takes over where it ends.
        io.hold();
        let trajectory = io.program.trajectory();
        if let (Some(trajectory), Some(limits)) = (trajectory, &self.limits) {
            let joints = trajectory.sample(io.nc_time_s, &mut self.cursor).joints;
            let mut m = [0.0; 2];
            if limits.forward(&joints[..2], Some(&self.m_setpoint), &mut m).is_ok() {
                io.setpoints = [joints[0], joints[1]];
                self.m_setpoint = m;
            }
        }
        io.program.auto(io.nc_state)
    }

    fn enter_motion(&mut self, _io: &mut Io) {}

    fn motion(&mut self, io: &mut Io) -> bool {
        if let Some((i, v)) = self.carriage_command(io) {
            self.jog_carriage(io, i, v);
            return true;
        }
        let v = self.command(io);
        if v == [0.0; 2] {
            io.hold();
            return false;
        }
        self.jog(io, v);
        true
    }

    fn enter_error(&mut self, _reason: Reason, io: &mut Io) {
        io.program.leave();
        io.enable = false;
        io.setpoints = io.positions;
        io.hold();
    }

    fn error(&mut self, io: &mut Io) {
        // Drives off; the set-points follow the carriages, so that re-enabling is bumpless.
        io.enable = false;
        io.setpoints = io.positions;
        io.hold();
    }
}

impl Main {
    /// The TRIJOINT's part of the automaton, with its parameters and the machine's geometry.
    pub fn new(p: MainParams, geometry: TrijointParams) -> Self {
        Main {
            p,
            geometry,
            edges: [[0.0; 2]; 2],
            limits: None,
            soft: [[0.0; 2]; 2],
            m_setpoint: [0.0; 2],
            searches: [Search::Done; 2],
            trajectories: Vec::new(),
            cursor: 0,
        }
    }

    /// The operator's command as a velocity of M (mm/s): joystick, else direction buttons. A
    /// joystick that is not connected commands nothing, whatever its axes read.
    pub(super) fn command(&self, io: &Io) -> [f64; 2] {
        if io.screen_carriage != 0 {
            return [0.0; 2];
        }
        let dz = self.p.dead_zone;
        let [jx, jy] = if io.joystick_connected { io.joystick } else { [0.0; 2] };
        let (mut x, mut y) = (
            if jx.abs() > dz { jx } else { 0.0 },
            if jy.abs() > dz { jy } else { 0.0 },
        );
        if x == 0.0 && y == 0.0 {
            let [left, right, up, down] = io.buttons.map(|b| f64::from(u8::from(b)));
            x = right - left;
            y = up - down;
        }
        [x * self.p.max_speed_mm_s, y * self.p.max_speed_mm_s]
    }
}

#[cfg(test)]
mod tests {
    //! The automaton alone, as statig's own tests drive a machine: events in, the shared storage
    //! and the context (`Io`) asserted on. No process image, no plant, no runtime.

    use super::*;

    const DT: f64 = 0.05;

    /// A machine in REBOOT at t = 0, carriages at 125 mm, its context after the first tick.
    fn machine() -> (StateMachine<Automaton>, Io) {
        let mut io = Io {
            dt_s: DT,
            positions: [125.0; 2],
            joystick_connected: true,
            ..Io::default()
        };
        let mut m = Automaton::new(Main::new(MainParams::default(), TrijointParams::default())).state_machine();
        m.handle_with_context(&Event::Tick, &mut io);
        (m, io)
    }

    /// One main cycle later, with `event`.
    fn cycle(m: &mut StateMachine<Automaton>, io: &mut Io, event: Event) {
        io.now_s += DT;
        m.handle_with_context(&event, io);
    }

    /// A machine that has finished referencing (its storage set as `finish_referencing` leaves
    /// it) and stands in READY.
    fn ready() -> (StateMachine<Automaton>, Io) {
        let (mut m, mut io) = machine();
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Init);
        // Both drives' switches found: the automaton references and sends them to the start.
        // SAFETY: statig marks `inner_mut` unsafe because a change of the storage can break the
        // machine's own invariants, not memory; this sets exactly what the switch searches of
        // both drives leave behind (`Search::Found`, the switch edges) — the referencing module
        // and the simulated machine's tests cover the searches themselves.
        unsafe {
            let a = &mut m.inner_mut().app;
            a.edges = [[0.0, 250.0]; 2];
            a.searches = [Search::Found; 2];
        }
        for _ in 0..400 {
            // The carriages follow their set-points exactly.
            for i in 0..2 {
                io.setpoints[i] += io.velocities[i] * DT;
                io.positions[i] = io.setpoints[i];
            }
            cycle(&mut m, &mut io, Event::Tick);
            if m.inner().state == MainState::Ready {
                return (m, io);
            }
        }
        panic!("not READY after referencing: {:?}", m.inner().app.searches);
    }

    #[test]
    fn reboot_acknowledges_then_init_enables_and_seeks_the_upper_switches() {
        let (mut m, mut io) = machine();
        assert_eq!(m.inner().state, MainState::Reboot);
        assert!(io.acknowledge && !io.enable && !io.referenced);
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Init);
        assert!(
            io.acknowledge && !io.enable,
            "the cycle that enters INIT still acknowledges, drives still off"
        );
        cycle(&mut m, &mut io, Event::Tick);
        assert!(io.enable, "INIT's first tick enables the drives");
        assert!(!io.acknowledge, "and ends the acknowledge pulse");
        assert!(
            m.inner().app.searches.iter().all(|s| matches!(
                s,
                Search::Seek {
                    end: End::Upper,
                    stage: 0,
                    ..
                }
            )),
            "both drives seek their upper switch first: {:?}",
            m.inner().app.searches
        );
        assert!(io.velocities.iter().all(|v| *v > 0.0), "moving up: {:?}", io.velocities);
    }

    #[test]
    fn stop_and_faults_in_operating_states_are_errors_with_their_reason() {
        for (event, reason) in [
            (Event::Stop, Reason::Stop),
            (Event::Fault(Reason::BusFault), Reason::BusFault),
            (Event::Fault(Reason::EncoderFault(1)), Reason::EncoderFault(1)),
        ] {
            let (mut m, mut io) = machine();
            cycle(&mut m, &mut io, Event::Tick);
            io.positions = [130.0, 120.0];
            cycle(&mut m, &mut io, event);
            assert_eq!(m.inner().state, MainState::Error, "{event:?}");
            assert_eq!(m.inner().reason, Some(reason));
            assert!(!io.enable, "drives off");
            assert_eq!(io.setpoints, io.positions, "set-points follow the carriages (bumpless)");
            assert_eq!(io.velocities, [0.0; 2]);
        }
    }

    #[test]
    fn in_error_only_a_stop_press_acknowledges() {
        let (mut m, mut io) = machine();
        cycle(&mut m, &mut io, Event::Tick);
        cycle(&mut m, &mut io, Event::Fault(Reason::BridgeError(0)));
        for event in [Event::Tick, Event::Fault(Reason::BusFault)] {
            cycle(&mut m, &mut io, event);
            assert_eq!(m.inner().state, MainState::Error);
            assert_eq!(
                m.inner().reason,
                Some(Reason::BridgeError(0)),
                "the first reason is kept"
            );
        }
        cycle(&mut m, &mut io, Event::Stop);
        assert_eq!(m.inner().state, MainState::Reboot);
        assert_eq!(m.inner().reason, None);
        assert!(io.acknowledge, "REBOOT acknowledges the drives' faults");
    }

    #[test]
    fn referencing_ends_in_ready_at_the_start_position_with_references_and_limits() {
        let (m, io) = ready();
        assert!(io.referenced);
        assert_eq!(io.references, [0.0; 2], "0 mm at the lower switches");
        assert_eq!(m.inner().app.soft.len(), 2);
        assert!(m.inner().app.limits.is_some(), "software limits known");
        assert_eq!(io.velocities, [0.0; 2], "READY holds");
    }

    #[test]
    fn a_command_starts_motion_and_releasing_it_returns_to_ready() {
        let (mut m, mut io) = ready();
        io.joystick = [0.5, 0.0];
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Motion);
        cycle(&mut m, &mut io, Event::Tick);
        assert!(io.velocities.iter().any(|v| *v != 0.0), "jogging moves the set-points");
        io.joystick = [0.0, 0.0];
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Ready);
        assert_eq!(io.velocities, [0.0; 2]);
        // Within the dead zone is no command; an unplugged joystick commands nothing.
        io.joystick = [0.01, 0.0];
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Ready);
        io.joystick = [0.8, 0.0];
        io.joystick_connected = false;
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Ready);
        // The panel's direction buttons command too.
        io.joystick_connected = true;
        io.joystick = [0.0; 2];
        io.buttons = [false, false, true, false];
        cycle(&mut m, &mut io, Event::Tick);
        assert_eq!(m.inner().state, MainState::Motion);
    }
}
