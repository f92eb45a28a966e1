//! The main program's states as they appear in the process image (`main_state`, INT), so that the
//! 10 ms programs, traces and the status line can see them: the states every machine shares.

pub use pkm_drives::automaton::MainState;
