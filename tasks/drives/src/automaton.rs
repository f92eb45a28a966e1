//! The main automaton every machine shares (docs/trijoint.md), written once: the states as the
//! process image carries them, the STOP button's press-and-lockout rule, which event a cycle
//! dispatches, and the REBOOT → INIT → READY ⇄ MOTION / ERROR state machine (statig) with its
//! rules — REBOOT lasts one cycle; in INIT, READY and MOTION a STOP press or a supervision fault is
//! ERROR with its reason; ERROR is left only by an accepted STOP press, to REBOOT. What a machine
//! does in each state (its referencing, its jog) is its [`Application`]. READY ⇄ AUTO runs an NC
//! program (docs/nc.md), for the machines that start one.

use pkm_api::image::{Declare, Input, Var};
use pkm_api::program::Cycle;
use statig::prelude::*;

/// The states of the main automaton (docs/trijoint.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MainState {
    /// (Re)initialising after power-on or an acknowledged error.
    Reboot,
    /// Referencing the machine.
    Init,
    /// Ready; drives hold their position.
    Ready,
    /// The operator moves the machine.
    Motion,
    /// Drives stopped; an error reason is kept.
    Error,
    /// An NC program runs (entered from READY, back to READY at its end).
    Auto,
}

impl MainState {
    /// Every state, in code order.
    pub const ALL: [MainState; 6] = [
        MainState::Reboot,
        MainState::Init,
        MainState::Ready,
        MainState::Motion,
        MainState::Error,
        MainState::Auto,
    ];

    /// The code in the process image (`main_state`).
    pub fn code(self) -> i16 {
        self as i16
    }

    /// The state with this code, if any.
    pub fn from_code(code: i16) -> Option<MainState> {
        MainState::ALL.into_iter().find(|s| s.code() == code)
    }

    /// The name shown to users.
    pub fn name(self) -> &'static str {
        match self {
            MainState::Reboot => "REBOOT",
            MainState::Init => "INIT",
            MainState::Ready => "READY",
            MainState::Motion => "MOTION",
            MainState::Error => "ERROR",
            MainState::Auto => "AUTO",
        }
    }

    /// The states in which the drives may be enabled, and in which STOP and supervision faults
    /// become ERROR (the automaton's superstate `operating`).
    pub fn operating(self) -> bool {
        matches!(
            self,
            MainState::Init | MainState::Ready | MainState::Motion | MainState::Auto
        )
    }
}

/// The STOP button as the main automaton takes it: a press (the rising edge, not the level) is
/// accepted unless one was accepted less than the lockout ago. With the original's level
/// semantics, holding STOP longer than the lockout would acknowledge the error it caused and
/// restart INIT while the button is still held; the lockout keeps a bouncing contact from doing
/// the same.
#[derive(Clone, Copy, Debug)]
pub struct StopButton {
    lockout_s: f64,
    was_pressed: bool,
    accepted_at: Option<f64>,
}

impl StopButton {
    /// A released button whose accepted presses lock it for `lockout_s` seconds.
    pub fn new(lockout_s: f64) -> StopButton {
        StopButton {
            lockout_s,
            was_pressed: false,
            accepted_at: None,
        }
    }

    /// The button's level at `now_s` (either STOP: the joystick's acts in addition to the
    /// panel's, never instead of it); true for an accepted press. A press in REBOOT (`ignore`)
    /// is seen but not accepted.
    pub fn press(&mut self, pressed: bool, now_s: f64, ignore: bool) -> bool {
        let press = pressed && !self.was_pressed;
        self.was_pressed = pressed;
        let enabled = self.accepted_at.is_none_or(|t| now_s - t >= self.lockout_s);
        if press && enabled && !ignore {
            self.accepted_at = Some(now_s);
            true
        } else {
            false
        }
    }
}

/// Every STOP an operator has, read as one: the panel's button, the joystick's and the
/// operator screen's act in addition to each other, never instead of each other. The main
/// program takes the presses (through [`StopButton`]), the drive program's fast interlock the
/// level.
#[derive(Clone, Copy, Debug)]
pub struct StopInputs {
    panel: Input<bool>,
    joystick: Input<bool>,
    screen: Input<bool>,
}

impl StopInputs {
    /// Declares the reads: the panel's STOP `panel` (which the I/O map must bind), the
    /// joystick's `joystick` and the screen's (`HMI_STOP`), which may be left out.
    pub fn declare(decl: &mut Declare<'_>, panel: Var<bool>, joystick: Var<bool>) -> StopInputs {
        StopInputs {
            panel: decl.read(panel),
            joystick: decl.read_optional(joystick),
            screen: decl.read_optional(pkm_api::hmi::HMI_STOP),
        }
    }

    /// Whether any STOP is pressed in this cycle.
    pub fn pressed(&self, ctx: &Cycle<'_>) -> bool {
        ctx.get(self.panel) || ctx.get(self.joystick) || ctx.get(self.screen)
    }
}

/// The events the automaton handles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event<R> {
    /// An accepted STOP press.
    Stop,
    /// A supervision fault, with its reason.
    Fault(R),
    /// The operator asks to reference the machine again (the screen's Reference): taken in
    /// READY (→ REBOOT → INIT, as after an acknowledged error), ignored elsewhere.
    Reference,
    /// A cycle without any of these.
    Tick,
}

/// The event of a cycle: an accepted STOP press first; outside INIT, READY and MOTION nothing
/// else; else the first supervision fault `faults` finds (the machine's checks, in its order),
/// else the operator's request to reference again (`reference`: its press, the rising edge),
/// else a tick.
pub fn event<R>(
    stop: &mut StopButton,
    pressed: bool,
    reference: bool,
    now_s: f64,
    state: MainState,
    faults: impl FnOnce() -> Option<R>,
) -> Event<R> {
    if stop.press(pressed, now_s, state == MainState::Reboot) {
        return Event::Stop;
    }
    if !state.operating() {
        return Event::Tick;
    }
    match faults() {
        Some(reason) => Event::Fault(reason),
        None if reference => Event::Reference,
        None => Event::Tick,
    }
}

/// What a machine does in each state of the shared automaton, which decides when.
pub trait Application: 'static {
    /// Why the machine is in ERROR.
    type Reason: Copy + PartialEq + 'static;
    /// The inputs and outputs of one cycle.
    type Io: 'static;
    /// The reason an accepted STOP press gives.
    const STOP: Self::Reason;
    /// The cycle's time (s).
    fn now_s(io: &Self::Io) -> f64;
    /// REBOOT entered (power-on, acknowledgement): drives off, the acknowledge pulse.
    fn enter_reboot(&mut self, io: &mut Self::Io);
    /// INIT entered.
    fn enter_init(&mut self, io: &mut Self::Io);
    /// One cycle of INIT: `Ok(true)` when the machine is referenced (→ READY), an error reason
    /// when referencing failed (→ ERROR).
    fn init(&mut self, io: &mut Self::Io) -> Result<bool, Self::Reason>;
    /// READY entered.
    fn enter_ready(&mut self, io: &mut Self::Io);
    /// One cycle of READY: true when the operator commands motion (→ MOTION).
    fn ready(&mut self, io: &mut Self::Io) -> bool;
    /// MOTION entered.
    fn enter_motion(&mut self, io: &mut Self::Io);
    /// One cycle of MOTION: false when the motion has ended (→ READY).
    fn motion(&mut self, io: &mut Self::Io) -> bool;
    /// In READY, before [`Application::ready`]: true when an NC program starts (→ AUTO). A
    /// machine without programs never starts one.
    fn start_auto(&mut self, _io: &mut Self::Io) -> bool {
        false
    }
    /// AUTO entered.
    fn enter_auto(&mut self, _io: &mut Self::Io) {}
    /// One cycle of AUTO: false when the program has ended (→ READY).
    fn auto(&mut self, _io: &mut Self::Io) -> bool {
        false
    }
    /// ERROR entered with `reason`: drives off.
    fn enter_error(&mut self, reason: Self::Reason, io: &mut Self::Io);
    /// One cycle of ERROR: drives stay off.
    fn error(&mut self, io: &mut Self::Io);
}

/// The shared automaton's storage: the machine's application, the state and the reason.
pub struct Automaton<A: Application> {
    /// The machine's application.
    pub app: A,
    /// The state, as the process image and the status show it.
    pub state: MainState,
    /// Why the machine is in ERROR, while it is.
    pub reason: Option<A::Reason>,
    /// When the current state was entered (s); REBOOT lasts one cycle.
    entered_s: f64,
}

impl<A: Application> Automaton<A> {
    /// The automaton of `app`, in REBOOT once it handles its first event.
    pub fn new(app: A) -> Automaton<A> {
        Automaton {
            app,
            state: MainState::Reboot,
            reason: None,
            entered_s: 0.0,
        }
    }
}

#[state_machine(initial = "State::reboot()", context_identifier = "io")]
impl<A: Application> Automaton<A> {
    #[state(entry_action = "enter_reboot")]
    fn reboot(&mut self, io: &mut A::Io, event: &Event<A::Reason>) -> Outcome<State<A>> {
        match event {
            // The acknowledge pulse goes out for the one cycle REBOOT lasts; then reference.
            Event::Tick if A::now_s(io) > self.entered_s => Transition(State::init()),
            _ => Handled,
        }
    }

    #[action]
    fn enter_reboot(&mut self, io: &mut A::Io) {
        self.state = MainState::Reboot;
        self.entered_s = A::now_s(io);
        self.reason = None;
        self.app.enter_reboot(io);
    }

    #[superstate]
    fn operating(event: &Event<A::Reason>) -> Outcome<State<A>> {
        match event {
            Event::Stop => Transition(State::error(A::STOP)),
            Event::Fault(reason) => Transition(State::error(*reason)),
            Event::Reference | Event::Tick => Handled,
        }
    }

    #[state(superstate = "operating", entry_action = "enter_init")]
    fn init(&mut self, io: &mut A::Io, event: &Event<A::Reason>) -> Outcome<State<A>> {
        if *event != Event::Tick {
            return Super;
        }
        match self.app.init(io) {
            Err(reason) => Transition(State::error(reason)),
            Ok(true) => Transition(State::ready()),
            Ok(false) => Handled,
        }
    }

    #[action]
    fn enter_init(&mut self, io: &mut A::Io) {
        self.state = MainState::Init;
        self.app.enter_init(io);
    }

    #[state(superstate = "operating", entry_action = "enter_ready")]
    fn ready(&mut self, io: &mut A::Io, event: &Event<A::Reason>) -> Outcome<State<A>> {
        // Standing still: the machine may reference again (drives off for REBOOT's cycle).
        if *event == Event::Reference {
            return Transition(State::reboot());
        }
        if *event != Event::Tick {
            return Super;
        }
        if self.app.start_auto(io) {
            Transition(State::auto())
        } else if self.app.ready(io) {
            Transition(State::motion())
        } else {
            Handled
        }
    }

    #[action]
    fn enter_ready(&mut self, io: &mut A::Io) {
        self.state = MainState::Ready;
        self.app.enter_ready(io);
    }

    #[state(superstate = "operating", entry_action = "enter_motion")]
    fn motion(&mut self, io: &mut A::Io, event: &Event<A::Reason>) -> Outcome<State<A>> {
        if *event != Event::Tick {
            return Super;
        }
        if self.app.motion(io) {
            Handled
        } else {
            Transition(State::ready())
        }
    }

    #[action]
    fn enter_motion(&mut self, io: &mut A::Io) {
        self.state = MainState::Motion;
        self.app.enter_motion(io);
    }

    #[state(superstate = "operating", entry_action = "enter_auto")]
    fn auto(&mut self, io: &mut A::Io, event: &Event<A::Reason>) -> Outcome<State<A>> {
        if *event != Event::Tick {
            return Super;
        }
        if self.app.auto(io) {
            Handled
        } else {
            Transition(State::ready())
        }
    }

    #[action]
    fn enter_auto(&mut self, io: &mut A::Io) {
        self.state = MainState::Auto;
        self.app.enter_auto(io);
    }

    #[state(entry_action = "enter_error")]
    fn error(&mut self, reason: &mut A::Reason, io: &mut A::Io, event: &Event<A::Reason>) -> Outcome<State<A>> {
        // The reason is kept in the state (and in shared storage for the status, on entry).
        let _ = reason;
        self.app.error(io);
        match event {
            Event::Stop => Transition(State::reboot()),
            _ => Handled,
        }
    }

    #[action]
    fn enter_error(&mut self, reason: &mut A::Reason, io: &mut A::Io) {
        self.state = MainState::Error;
        self.reason = Some(*reason);
        self.app.enter_error(*reason, io);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_states_names_and_codes_are_the_ones_the_interface_publishes() {
        for state in MainState::ALL {
            assert_eq!(pkm_api::machine::MAIN_STATES[state.code() as usize], state.name());
        }
        assert_eq!(pkm_api::machine::MAIN_STATES.len(), MainState::ALL.len());
    }

    /// An application that records what the automaton asked of it, and answers as told.
    #[derive(Default)]
    struct Probe {
        calls: Vec<&'static str>,
        referenced: bool,
        commanded: bool,
        program: bool,
    }

    #[derive(Default)]
    struct Clock {
        now_s: f64,
    }

    impl Application for Probe {
        type Reason = u8;
        type Io = Clock;
        const STOP: u8 = 1;
        fn now_s(io: &Clock) -> f64 {
            io.now_s
        }
        fn enter_reboot(&mut self, _: &mut Clock) {
            self.calls.push("enter_reboot");
        }
        fn enter_init(&mut self, _: &mut Clock) {
            self.calls.push("enter_init");
        }
        fn init(&mut self, _: &mut Clock) -> Result<bool, u8> {
            self.calls.push("init");
            Ok(self.referenced)
        }
        fn enter_ready(&mut self, _: &mut Clock) {
            self.calls.push("enter_ready");
        }
        fn ready(&mut self, _: &mut Clock) -> bool {
            self.calls.push("ready");
            self.commanded
        }
        fn enter_motion(&mut self, _: &mut Clock) {
            self.calls.push("enter_motion");
        }
        fn motion(&mut self, _: &mut Clock) -> bool {
            self.calls.push("motion");
            self.commanded
        }
        fn start_auto(&mut self, _: &mut Clock) -> bool {
            self.calls.push("start_auto");
            self.program
        }
        fn enter_auto(&mut self, _: &mut Clock) {
            self.calls.push("enter_auto");
        }
        fn auto(&mut self, _: &mut Clock) -> bool {
            self.calls.push("auto");
            self.program
        }
        fn enter_error(&mut self, _: u8, _: &mut Clock) {
            self.calls.push("enter_error");
        }
        fn error(&mut self, _: &mut Clock) {
            self.calls.push("error");
        }
    }

    fn step(m: &mut StateMachine<Automaton<Probe>>, io: &mut Clock, event: Event<u8>) -> MainState {
        io.now_s += 0.05;
        m.handle_with_context(&event, io);
        m.inner().state
    }

    #[test]
    fn the_automaton_runs_reboot_init_ready_motion_and_back() {
        let mut io = Clock::default();
        let mut m = Automaton::new(Probe::default()).state_machine();
        m.handle_with_context(&Event::Tick, &mut io);
        assert_eq!(
            m.inner().state,
            MainState::Reboot,
            "REBOOT for the cycle it is entered in"
        );
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Init);
        assert_eq!(
            step(&mut m, &mut io, Event::Tick),
            MainState::Init,
            "not referenced yet"
        );
        // SAFETY: the probe's answers are not part of the automaton's invariants.
        unsafe { m.inner_mut().app.referenced = true };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Ready);
        unsafe { m.inner_mut().app.commanded = true };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Motion);
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Motion);
        unsafe { m.inner_mut().app.commanded = false };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Ready);
        assert_eq!(
            m.inner().app.calls,
            [
                "enter_reboot",
                "enter_init",
                "init",
                "init",
                "enter_ready",
                "start_auto",
                "ready",
                "enter_motion",
                "motion",
                "motion",
                "enter_ready"
            ]
        );
    }

    #[test]
    fn a_program_runs_from_ready_in_auto_and_returns_to_ready_and_stop_is_an_error_there() {
        let mut io = Clock::default();
        let mut m = Automaton::new(Probe::default()).state_machine();
        m.handle_with_context(&Event::Tick, &mut io);
        step(&mut m, &mut io, Event::Tick);
        unsafe { m.inner_mut().app.referenced = true };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Ready);
        // SAFETY: the probe's answers are not part of the automaton's invariants.
        unsafe {
            m.inner_mut().app.program = true;
            m.inner_mut().app.commanded = true;
        };
        assert_eq!(
            step(&mut m, &mut io, Event::Tick),
            MainState::Auto,
            "a start before a jog"
        );
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Auto);
        unsafe { m.inner_mut().app.program = false };
        assert_eq!(
            step(&mut m, &mut io, Event::Tick),
            MainState::Ready,
            "the program's end"
        );
        unsafe { m.inner_mut().app.program = true };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Auto);
        assert_eq!(step(&mut m, &mut io, Event::Stop), MainState::Error);
        assert_eq!(m.inner().reason, Some(1));
        let calls = &m.inner().app.calls;
        let from = calls.iter().position(|c| *c == "enter_ready").unwrap_or(0);
        assert_eq!(
            calls[from..],
            [
                "enter_ready",
                "start_auto",
                "enter_auto",
                "auto",
                "auto",
                "enter_ready",
                "start_auto",
                "enter_auto",
                "enter_error"
            ]
        );
    }

    #[test]
    fn stop_and_faults_are_errors_in_operating_states_and_only_stop_leaves_error() {
        for fault in [Event::Stop, Event::Fault(7)] {
            let mut io = Clock::default();
            let mut m = Automaton::new(Probe::default()).state_machine();
            m.handle_with_context(&Event::Tick, &mut io);
            step(&mut m, &mut io, Event::Tick);
            assert_eq!(step(&mut m, &mut io, fault), MainState::Error);
            let reason = if fault == Event::Stop { 1 } else { 7 };
            assert_eq!(m.inner().reason, Some(reason));
            assert_eq!(step(&mut m, &mut io, Event::Fault(9)), MainState::Error);
            assert_eq!(m.inner().reason, Some(reason), "the first reason is kept");
            assert_eq!(step(&mut m, &mut io, Event::Stop), MainState::Reboot);
            assert_eq!(m.inner().reason, None);
        }
    }

    #[test]
    fn a_reference_request_references_again_from_ready_only_and_gives_way_to_stop_and_faults() {
        let mut stop = StopButton::new(0.5);
        assert_eq!(
            event(&mut stop, true, true, 0.0, MainState::Ready, || Some(3)),
            Event::Stop
        );
        assert_eq!(
            event(&mut stop, false, true, 0.1, MainState::Ready, || Some(3)),
            Event::Fault(3)
        );
        assert_eq!(
            event::<u8>(&mut stop, false, true, 0.2, MainState::Ready, || None),
            Event::Reference
        );
        assert_eq!(
            event::<u8>(&mut stop, false, true, 0.3, MainState::Error, || None),
            Event::Tick
        );
        // READY: REBOOT (one cycle, the acknowledge pulse), then INIT references again.
        let mut io = Clock::default();
        let mut m = Automaton::new(Probe::default()).state_machine();
        m.handle_with_context(&Event::Tick, &mut io);
        step(&mut m, &mut io, Event::Tick);
        // SAFETY: the probe's answers are not part of the automaton's invariants.
        unsafe { m.inner_mut().app.referenced = true };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Ready);
        assert_eq!(step(&mut m, &mut io, Event::Reference), MainState::Reboot);
        assert_eq!(m.inner().reason, None, "not an error");
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Init);
        // Elsewhere it changes nothing: in MOTION, in AUTO, in INIT.
        for (state, set) in [(MainState::Motion, (false, true)), (MainState::Auto, (true, false))] {
            assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Ready);
            unsafe {
                m.inner_mut().app.program = set.0;
                m.inner_mut().app.commanded = set.1;
            };
            assert_eq!(step(&mut m, &mut io, Event::Tick), state);
            assert_eq!(step(&mut m, &mut io, Event::Reference), state);
            unsafe {
                m.inner_mut().app.program = false;
                m.inner_mut().app.commanded = false;
            };
        }
        unsafe { m.inner_mut().app.referenced = false };
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Ready);
        assert_eq!(step(&mut m, &mut io, Event::Reference), MainState::Reboot);
        assert_eq!(step(&mut m, &mut io, Event::Tick), MainState::Init);
        assert_eq!(step(&mut m, &mut io, Event::Reference), MainState::Init);
    }

    #[test]
    fn the_event_is_stop_first_and_faults_only_while_operating() {
        let mut stop = StopButton::new(0.5);
        assert_eq!(
            event(&mut stop, true, false, 0.0, MainState::Ready, || Some(3)),
            Event::Stop
        );
        assert_eq!(
            event(&mut stop, true, false, 0.05, MainState::Error, || Some(3)),
            Event::Tick
        );
        assert_eq!(
            event(&mut stop, false, false, 0.1, MainState::Ready, || Some(3)),
            Event::Fault(3)
        );
        assert_eq!(
            event::<u8>(&mut stop, false, false, 0.15, MainState::Ready, || None),
            Event::Tick
        );
        assert_eq!(
            event(&mut stop, false, false, 0.2, MainState::Error, || Some(3)),
            Event::Tick
        );
        assert_eq!(
            event(&mut stop, false, false, 0.2, MainState::Reboot, || Some(3)),
            Event::Tick
        );
    }

    #[test]
    fn codes_round_trip_and_only_init_ready_motion_auto_operate() {
        for s in MainState::ALL {
            assert_eq!(MainState::from_code(s.code()), Some(s));
        }
        assert_eq!(MainState::from_code(6), None);
        let operating: Vec<_> = MainState::ALL.into_iter().filter(|s| s.operating()).collect();
        assert_eq!(
            operating,
            [MainState::Init, MainState::Ready, MainState::Motion, MainState::Auto]
        );
    }

    #[test]
    fn a_press_is_accepted_once_and_not_again_within_the_lockout() {
        let mut b = StopButton::new(0.5);
        assert!(b.press(true, 0.0, false), "the press");
        assert!(!b.press(true, 0.05, false), "holding is not a second press");
        assert!(!b.press(false, 0.1, false));
        assert!(!b.press(true, 0.15, false), "a bounce within the lockout");
        assert!(!b.press(false, 0.2, false));
        assert!(b.press(true, 0.5, false), "a press after the lockout");
        assert!(!b.press(false, 0.55, false));
        assert!(!b.press(true, 1.5, true), "ignored (REBOOT)");
        assert!(!b.press(false, 1.55, false));
        assert!(b.press(true, 1.6, false), "an ignored press did not start a lockout");
    }
}
