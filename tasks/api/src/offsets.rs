//! What an NC program starts from besides where the tool stands: the origins of the work
//! coordinate systems and the positions G28 and G30 go to. The configuration gives them, a
//! parameter file keeps them across runs, a touch-off on the screen changes them; a screen job
//! and a trace carry the ones they were planned with, so that a replay plans the same.

use crate::trajectory::MAX_AXES;

/// The work offsets and home positions a program starts from (machine frame: mm, degrees; x y
/// z a b c, unused coordinates 0).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WorkOffsets {
    /// The origins of G54 … G59.
    pub origins: [[f64; MAX_AXES]; 6],
    /// The positions G28 and G30 go to.
    pub homes: [[f64; MAX_AXES]; 2],
}
