//! Where program coordinates are: the work coordinate systems' origins with G92's offset on top,
//! and G92 itself (the tool's position reads as the given values from now on).

use crate::NcError;
use crate::lexer::Word;

use super::block::Pose;
use super::state::State;
use super::words::Words;

impl State<'_> {
    /// G92: the program coordinates the tool is at, for the axes the block names.
    pub(super) fn set_origin(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let axis_words = words.axis_words();
        // A length in machine units: mm for X Y Z, degrees for A B C.
        let unit = self.unit();
        let scale = |c: usize| if c < 3 { unit } else { 1.0 };
        if let Some(w) = words.g_word(920) {
            if axis_words.is_empty() {
                return Err(at(
                    w,
                    "G92 needs at least one axis word: the program coordinates the tool is at".into(),
                ));
            }
            // The tool's position reads as the given values from now on.
            let work = self.machine.work_offsets[self.system];
            for (c, w) in &axis_words {
                self.g92[*c] = self.position[*c] - work[*c] - w.value * scale(*c);
            }
        }
        Ok(())
    }

    /// The offset from program to machine coordinates now.
    pub(super) fn offset(&self) -> Pose {
        let w = self.machine.work_offsets[self.system];
        std::array::from_fn(|c| w[c] + self.g92[c])
    }

    /// The tool's position in program coordinates and units.
    pub(super) fn program_position(&self) -> Pose {
        let offset = self.offset();
        std::array::from_fn(|c| (self.position[c] - offset[c]) / self.scale(c))
    }

    /// Machine coordinates of a point given in program coordinates and units.
    pub(super) fn machine_position(&self, program: &Pose) -> Pose {
        let offset = self.offset();
        std::array::from_fn(|c| program[c] * self.scale(c) + offset[c])
    }
}
