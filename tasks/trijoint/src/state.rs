//! The main program's states as they appear in the process image (`main_state`, INT), so that the
//! 10 ms programs, traces and the status line can see them.

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

    /// The code in the process image.
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
}
