//! The watch over the time a program's preparation takes. This crate reads no clock: reading,
//! checking and planning ask a [`Watch`] now and then whether to go on — the runtime's answers
//! are a deadline and the operator's cancel — and stop with its reason when it says no.

/// Asked now and then by long work (reading, checking, planning a program): whether to go on.
/// The runtime answers with its deadline and the operator's cancel.
pub trait Watch {
    /// `Err(why)` stops the work, which then fails with `why`.
    fn go_on(&self) -> Result<(), String>;
}

/// Work stopped by its [`Watch`]: where it was, and the watch's reason.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {why}")]
pub struct Stopped {
    /// The program line of the move at hand.
    pub line: usize,
    /// The watch's reason.
    pub why: String,
}

/// No watch: the work goes on to its end.
pub struct Unwatched;

impl Watch for Unwatched {
    fn go_on(&self) -> Result<(), String> {
        Ok(())
    }
}

/// How many steps of work pass between two questions to the [`Watch`]: a few milliseconds of
/// the slowest (the hexapod's kinematics), a negligible share of its cost.
pub const WATCH_EVERY: u64 = 1024;

/// Work that asks its watch every [`WATCH_EVERY`] steps.
pub(crate) struct Watched<'a> {
    watch: &'a dyn Watch,
    steps: u64,
}

impl<'a> Watched<'a> {
    pub(crate) fn new(watch: &'a dyn Watch) -> Watched<'a> {
        Watched { watch, steps: 0 }
    }

    /// One step done: the watch's answer every [`WATCH_EVERY`] steps.
    pub(crate) fn step(&mut self) -> Result<(), String> {
        self.steps += 1;
        if self.steps.is_multiple_of(WATCH_EVERY) {
            self.watch.go_on()
        } else {
            Ok(())
        }
    }
}
