//! The interpreter: RS274NGC's modal state applied block by block, in LinuxCNC's order of
//! execution, each block becoming at most a few [`Block`]s in the machine's world coordinates.
//!
//! Supported (docs/nc.md): G0 G1 G2 G3 (centre by I J K, incremental as in LinuxCNC, or by R;
//! helical with the axis normal to the plane; P full turns), G4 P (dwell, s), G17 G18 G19,
//! G20 G21, G28 G30 with G28.1 G30.1 (going home), G52, G53 (machine coordinates, this block),
//! G54–G59 (work offsets), G61, G64 \[P\], G90 G91, G92 G92.1 G92.2 G92.3, the canned cycles
//! G81 G82 G83 with G98 G99 and G80, F (per minute), S, M0 M1 M2 M30 M3 M4 M5, N, axis words
//! X Y Z and A B C (degrees) as far as the machine has them; parameters, expressions and O-words
//! ([`crate::flow`]). Everything else is refused with its line, column and reason.
//!
//! The conversion goes group by group as LinuxCNC's does (`convert_*`): [`words`] sorts and
//! checks a block's words, [`modes`] the modal settings, [`offsets`] the coordinate systems, G92
//! and G52 and going home, [`motion`] the moves and arcs, [`cycles`] the canned cycles; [`state`]
//! holds the modal state and runs a block through them; the O-word control flow and expressions
//! are [`crate::flow`]'s.

pub mod block;
mod comp;
mod compensation;
mod cycles;
mod io;
mod modes;
mod motion;
mod offsets;
mod spline;
mod state;
mod tool;
mod words;

pub use block::{
    ANALOG_OUTPUTS, AXES, Action, Blend, Block, DIGITAL_INPUTS, DIGITAL_OUTPUTS, MAX_DWELL_S, MAX_SPINDLE_RPM,
    MIN_FEED, Machine, Output, Path, Plane, Pose, Program, Spindle, WaitMode,
};

use crate::NcError;
use crate::budget::Bounds;
use crate::flow::{Event, Flow};
use crate::watch::{Unwatched, Watch};
use state::State;

/// Reads `text` for `machine` within the default [`Bounds`]; the first problem is returned with
/// its position.
pub fn read(text: &str, machine: &Machine<'_>) -> Result<Program, NcError> {
    read_bounded(text, machine, &Bounds::default(), &Unwatched)
}

/// Reads `text` for `machine`; the first problem is returned with its position. The program is
/// refused at the line where its moves or the memory of its plan pass `bounds`, and stops with
/// `watch`'s reason when the watch says so.
pub fn read_bounded(text: &str, machine: &Machine<'_>, bounds: &Bounds, watch: &dyn Watch) -> Result<Program, NcError> {
    let mut state = State::new(machine);
    state.bounds = *bounds;
    let mut blocks = Vec::new();
    let mut flow = Flow::new(text, machine.block_delete).watched(watch);
    // A '%' before any other line opens the program, and the next closes it; without it the
    // program ends at M2 or M30. What follows the end is never read (LinuxCNC ignores it).
    let (mut seen, mut opened) = (false, false);
    // The program coordinates as the last WorkOffset action gave them.
    let mut shown_frame: Option<(u8, [f64; 6])> = None;
    loop {
        match flow.next(&state)? {
            Event::Percent(number) => {
                if !seen {
                    opened = true;
                } else if opened {
                    blocks.push(Block {
                        line: number,
                        column: 1,
                        action: Action::End,
                    });
                    break;
                } else {
                    return Err(NcError::new(
                        number,
                        1,
                        "'%' opens a program only on its first line (and then closes it)".to_string(),
                    ));
                }
            }
            Event::Block(block) => {
                let before = blocks.len();
                state.block(&block, &mut blocks)?;
                // The program coordinates, where they are new: before the block's motion,
                // which runs in them.
                let frame = state.frame();
                if shown_frame != Some(frame) {
                    shown_frame = Some(frame);
                    let (system, offset) = frame;
                    blocks.insert(
                        before,
                        Block {
                            line: block.line,
                            column: 1,
                            action: Action::WorkOffset { system, offset },
                        },
                    );
                    state.inserted_action(before);
                }
                let column = made_by(&block);
                for made in &mut blocks[before..] {
                    made.column = column;
                    state.cost.add(made);
                }
                if let Some(why) = state.cost.beyond(bounds) {
                    return Err(NcError::new(block.line, 1, why));
                }
                if matches!(
                    blocks.last(),
                    Some(Block {
                        action: Action::End,
                        ..
                    })
                ) {
                    break;
                }
            }
            Event::End(last_line) => {
                if let Some(open) = flow.unclosed() {
                    return Err(open);
                }
                return Err(NcError::new(
                    last_line,
                    1,
                    if opened {
                        "the file ended without the closing '%' (or M2, M30): is the program complete?"
                    } else {
                        "the file ended with no program end (M2, M30) and no '%' delimiters: is the program complete?"
                    },
                ));
            }
        }
        seen = true;
    }
    // Grown by doubling: the memory past the last block is given back.
    blocks.shrink_to_fit();
    Ok(Program {
        blocks,
        messages: state.messages,
        start: machine.start,
        per_revolution: state.per_revolution,
    })
}

/// The column of the word that makes a line's actions: its first axis word (a move's end), else
/// its first word.
fn made_by(block: &crate::lexer::Block) -> usize {
    block
        .words
        .iter()
        .find(|w| block::AXES.contains(&w.letter))
        .or(block.words.first())
        .map_or(1, |w| w.column)
}

#[cfg(test)]
mod tests;
