//! The operator screen's inputs: what the web page commands enters the process image
//! as these variables, written by the runtime's HMI bus before each cycle, so that it is traced
//! and replayed like the panel. Programs read them as optional inputs: without a screen they read
//! zero and nothing changes.

use crate::image::Var;

/// STOP pressed on the screen (a press, held 100 ms): in addition to the panel's STOP, never
/// instead of it. In ERROR a press acknowledges, as the panel's does.
pub const HMI_STOP: Var<bool> = Var::new("HMI_STOP");
/// The screen's jog: a deflection in −1 … 1 per stick axis (x, y), 0 when released. The page
/// refreshes it while a jog button or the drag pad is held; a release, a lost connection, a
/// hidden tab or a silent page brings it to 0 (the dead-man).
pub const HMI_JOG: [Var<f64>; 2] = [Var::new("HMI_JOG_X"), Var::new("HMI_JOG_Y")];
/// Which axis the screen's jog moves: 0 the stick's (the selected pair: `HMI_JOG` x and y), `k`
/// ≥ 1 the k-th pose coordinate of the machine alone (x y z a b c), `-k` the k-th joint alone,
/// each at `HMI_JOG` x's deflection. A joint is jogged from the screen only once the machine is
/// referenced (world mode), inside its software limits and the allowed region of the tool:
/// before referencing, single joints move from the panel alone, where a person stands at the
/// machine.
pub const HMI_JOG_AXIS: Var<i16> = Var::new("HMI_JOG_AXIS");
/// The values `HMI_JOG_AXIS` may take: −6 (the sixth joint) … 6 (the sixth pose coordinate).
pub const JOG_AXIS_RANGE: std::ops::RangeInclusive<i16> = -6..=6;

/// The screen's axis button: selects the next joint (joint mode) or pair of world axes (a press).
pub const HMI_AXES: Var<bool> = Var::new("HMI_AXES");
/// The screen's program buttons: start, feed hold, resume (presses), in addition to the panel's
/// `NC_START`, `NC_HOLD`, `NC_RESUME`.
pub const HMI_NC: [Var<bool>; 3] = [
    Var::new("HMI_NC_START"),
    Var::new("HMI_NC_HOLD"),
    Var::new("HMI_NC_RESUME"),
];
/// The screen's Reference (a press): in READY the machine references again — REBOOT for a
/// cycle (drives off, the acknowledge pulse), then INIT, as after an acknowledged error; ignored
/// in every other state.
pub const HMI_REFERENCE: Var<bool> = Var::new("HMI_REFERENCE");
/// The screen's confirmation of a manual tool change as a press, named by nothing: no longer
/// pressed (a late press confirmed the next change) and read by no program; declared so that
/// traces recorded before keep their shape. [`HMI_TOOL_CONFIRM`] replaced it.
pub const HMI_TOOL_CHANGED: Var<bool> = Var::new("HMI_TOOL_CHANGED");
/// The tool change the screen confirmed last: its `TOOL_CHANGE_NUMBER` (0: none). A level: the
/// change of that number is confirmed while it waits, and no other.
pub const HMI_TOOL_CONFIRM: Var<i32> = Var::new("HMI_TOOL_CONFIRM");
/// The program the screen asks to load: its (1-based) number in the run's
/// [`NcLibrary`](crate::library::NcLibrary); 0 asks for nothing. Taken by the main program
/// outside AUTO (a level: the last choice stands).
pub const HMI_NC_PROGRAM: Var<i16> = Var::new("HMI_NC_PROGRAM");
