//! NC programs (docs/nc.md): the documented subset of RS274NGC, LinuxCNC's dialect, read into
//! moves in the machine's world coordinates.
//!
//! - [`lexer`]: a program's line as words (`G1`, `X-2.5`, `X[#1 * 2]`) with their values, line
//!   and column, the parameters it sets, or its O-word statement; comments, line numbers, block
//!   delete and `%` delimiters handled; expressions computed as LinuxCNC computes them.
//! - [`flow`]: the order lines run in (O-word subroutines, conditionals, loops) and the
//!   parameters (numbered, named, local to a call or global).
//! - [`interp`]: the modal state (plane, units, distance mode, work offsets, feed, exact stop or
//!   blending, canned cycles) applied block by block: every block becomes a [`interp::Block`] — a rapid, a line,
//!   an arc or helix, a dwell, a pause, a spindle change or the end — with its line. Anything the
//!   subset does not have is refused with its line and column and the reason, before anything
//!   moves.
//! - [`tools`]: the tool table, in LinuxCNC's `tool.tbl` format.
//! - [`params`]: the parameter file, in LinuxCNC's `.var` format (work offsets, G28/G30 homes).
//! - [`path`]: a move's geometry: its length along the path, its pose at a fraction of it.
//! - [`check`]: every point of the path, sampled finely, inside the world limits, reachable with
//!   every joint inside its software limits and away from singularities; the path's length and
//!   bounding box.
//! - [`plan`]: the path with its corners blended and a velocity profile within every axis' and
//!   joint's limits; the program's events (M0, spindle) on its time line.
//! - [`job`]: a plan as the cyclic programs sample it: joints by inverse kinematics, the
//!   distance of a measured tool point to the path.
//!
//! A small parser of our own rather than the `gcode` crate: that one reads values as `f32`
//! (seven digits: a 1 µm step is lost beyond 10 m, and 0.1 µm beyond 1 m), is built to skip what
//! it cannot read and go on, and knows nothing of RS274NGC's parameters, expressions or O-words.

pub mod budget;
pub mod check;
pub mod flow;
pub mod interp;
pub mod job;
pub mod lexer;
pub mod params;
pub mod path;
pub mod plan;
pub mod tools;
pub mod watch;

/// A problem in a program, where it is (1-based line and column, in characters).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{line}:{column}: {message}")]
pub struct NcError {
    /// The line.
    pub line: usize,
    /// The column of the character the problem starts at.
    pub column: usize,
    /// What is wrong and why.
    pub message: String,
}

impl NcError {
    /// A problem at `line`:`column`.
    pub fn new(line: usize, column: usize, message: impl Into<String>) -> NcError {
        NcError {
            line,
            column,
            message: message.into(),
        }
    }
}
