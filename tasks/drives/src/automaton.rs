//! The rules of the main automaton that every machine shares (application.md): the states as the
//! process image carries them, which of them drive, and the STOP button's press-and-lockout rule.
//! Each machine's main program builds its own REBOOT → INIT → READY ⇄ MOTION / ERROR automaton
//! (its referencing and jogging differ) on these.

/// The states of the main automaton (application.md).
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
}

impl MainState {
    /// Every state, in code order.
    pub const ALL: [MainState; 5] = [
        MainState::Reboot,
        MainState::Init,
        MainState::Ready,
        MainState::Motion,
        MainState::Error,
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
        }
    }

    /// The states in which the drives may be enabled, and in which STOP and supervision faults
    /// become ERROR (the automaton's superstate `operating`).
    pub fn operating(self) -> bool {
        matches!(self, MainState::Init | MainState::Ready | MainState::Motion)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_only_init_ready_motion_operate() {
        for s in MainState::ALL {
            assert_eq!(MainState::from_code(s.code()), Some(s));
        }
        assert_eq!(MainState::from_code(5), None);
        let operating: Vec<_> = MainState::ALL.into_iter().filter(|s| s.operating()).collect();
        assert_eq!(operating, [MainState::Init, MainState::Ready, MainState::Motion]);
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
