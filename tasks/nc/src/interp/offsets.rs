//! Where program coordinates are: the work coordinate systems' origins (G10 L2 and L20 set them)
//! with G92's offset on top;
//! G92 (the tool's position reads as the given values from now on), G92.1, G92.2, G92.3 and G52
//! (which set that offset as LinuxCNC does: G52 shares it); and going home by G28 and G30 to the
//! positions G28.1 and G30.1 store.

use crate::NcError;
use crate::lexer::Word;

use super::block::{Blend, Block, Path, Pose};
use super::state::State;
use super::words::{Words, format_code};

impl State<'_> {
    /// G92, G92.1, G92.2, G92.3 and G52: the offset on top of the work coordinate system. G92
    /// makes the tool's position read as the given values (for the axes named), G52 sets the
    /// offset to the given values, G92.1 clears it and its parameters, G92.2 suspends it (its
    /// parameters kept), G92.3 brings it back from them.
    pub(super) fn set_origin(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let axis_words = words.axis_words();
        if let (Some(taker), Some((code, w)), false) =
            (words.axis_word_taker(), words.motion_word(), axis_words.is_empty())
        {
            return Err(at(
                w,
                format!(
                    "{} and {} both use the block's axis words: a block holds one of them",
                    format_code('G', code),
                    format_code('G', taker)
                ),
            ));
        }
        for (code, needs) in [
            (920, "the program coordinates the tool is at"),
            (520, "the offset of the local coordinate system"),
        ] {
            if let Some(w) = words.g_word(code)
                && axis_words.is_empty()
            {
                return Err(at(
                    w,
                    format!("{} needs at least one axis word: {needs}", format_code('G', code)),
                ));
            }
        }
        if let Some((code, w)) = words.g.iter().find(|(c, _)| matches!(c, 520 | 920..=923)) {
            self.refuse_while_compensating(
                line,
                w,
                &format!("{} cannot change the offsets", format_code('G', *code)),
            )?;
        }
        if words.has_g(920) {
            // The tool's position reads as the given values from now on.
            let work = self.work[self.system];
            for (c, w) in &axis_words {
                self.g92[*c] = self.position[*c] - work[*c] - self.tool_offset[*c] - w.value * self.scale(*c);
            }
            self.g92_kept = self.g92;
        }
        if words.has_g(520) {
            for (c, w) in &axis_words {
                self.g92[*c] = w.value * self.scale(*c);
            }
            self.g92_kept = self.g92;
        }
        if words.has_g(921) {
            (self.g92, self.g92_kept) = ([0.0; 6], [0.0; 6]);
        }
        if words.has_g(922) {
            self.g92 = [0.0; 6];
        }
        if words.has_g(923) {
            self.g92 = self.g92_kept;
        }
        Ok(())
    }

    /// G10 L2 and L20: a work coordinate system's origin (P1 … P6 for G54 … G59, P0 the one in
    /// force) set for the axes named — L2 to the machine coordinates given, L20 so that the
    /// tool's position reads as the values given. L1 and L10 (a tool's offsets) are
    /// [`State::set_tool_entry`]'s.
    pub(super) fn set_coordinate_system(&mut self, words: &Words<'_>, out: &mut Vec<Block>) -> Result<(), NcError> {
        let Some(g10) = words.g_word(100) else {
            return Ok(());
        };
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let l = words.get('L').ok_or_else(|| {
            at(
                g10,
                "G10 needs L: L1 or L10 (a tool's offsets), L2 or L20 (a work coordinate system)".into(),
            )
        })?;
        if l.value == 1.0 || l.value == 10.0 || l.value == 11.0 {
            return self.set_tool_entry(words, l, out);
        }
        if l.value != 2.0 && l.value != 20.0 {
            return Err(at(
                l,
                format!(
                    "G10 L{} is not supported: L1 and L10 set a tool's offsets, L2 and L20 a work coordinate system",
                    l.value
                ),
            ));
        }
        let p = words.get('P').ok_or_else(|| {
            at(
                g10,
                "G10 L2 and L20 need P: the coordinate system (1 … 6 for G54 … G59, 0 the one in force)".into(),
            )
        })?;
        let system = match p.value {
            0.0 => self.system,
            v if v.fract() == 0.0 && (1.0..=6.0).contains(&v) => v as usize - 1,
            v => {
                return Err(at(
                    p,
                    format!("P is the coordinate system, 1 … 6 for G54 … G59 or 0 for the one in force; got {v}"),
                ));
            }
        };
        if let Some(r) = words.get('R') {
            return Err(at(r, "R (a coordinate system's rotation) is not supported".into()));
        }
        if system == self.system {
            self.refuse_while_compensating(line, g10, "G10 cannot change the coordinate system in force")?;
        }
        for (c, w) in words.axis_words() {
            let v = w.value * self.scale(c);
            self.work[system][c] = if l.value == 2.0 {
                v
            } else {
                self.position[c] - self.g92[c] - self.tool_offset[c] - v
            };
        }
        Ok(())
    }

    /// G28 and G30: a rapid to the point the block's axis words give (if any), then a rapid to
    /// the stored position — of the axes named, or of every axis without any. G28.1 and G30.1
    /// store where the tool is.
    pub(super) fn go_home(&mut self, words: &Words<'_>, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let axis_words = words.axis_words();
        if let Some((code, w)) = words.g.iter().find(|(c, _)| matches!(c, 280 | 281 | 300 | 301)) {
            let what = if code % 10 == 0 {
                "cannot go home"
            } else {
                "cannot store a position"
            };
            self.refuse_while_compensating(line, w, &format!("{} {what}", format_code('G', *code)))?;
        }
        for (k, code) in [281u16, 301].into_iter().enumerate() {
            if words.has_g(code) {
                if let Some((_, a)) = axis_words.first() {
                    return Err(at(
                        a,
                        format!(
                            "{} stores where the tool is: axis words cannot go with it",
                            format_code('G', code)
                        ),
                    ));
                }
                self.stored[k] = self.position;
            }
        }
        let Some(k) = [280u16, 300].iter().position(|c| words.has_g(*c)) else {
            return Ok(());
        };
        let via = self.target(&axis_words, false);
        let home: Pose = std::array::from_fn(|c| {
            if axis_words.is_empty() || axis_words.iter().any(|(a, _)| *a == c) {
                self.stored[k][c]
            } else {
                self.position[c]
            }
        });
        for to in [via, home] {
            self.line_to(line, to, None, self.blend, out);
        }
        self.cycle_initial = None;
        Ok(())
    }

    /// Where the block's axis words put the tool (machine coordinates): at the machine
    /// coordinates they give (G53, `machine_coords`), that far from where it is (G91), or there
    /// in program coordinates; the other axes stay.
    pub(super) fn target(&self, axis_words: &[(usize, &Word)], machine_coords: bool) -> Pose {
        let offset = self.offset();
        // While cutter compensation offsets the moves, from the programmed point.
        let base = self.base();
        let mut to = base;
        for (c, w) in axis_words {
            let v = w.value * self.scale(*c);
            to[*c] = if machine_coords {
                v
            } else if self.incremental {
                base[*c] + v
            } else {
                v + offset[*c]
            };
        }
        to
    }

    /// A straight move of line `line` to `to` at `feed` (`None`: a rapid), ending as `blend`
    /// says; none where the tool is there already (LinuxCNC writes such moves, and they change
    /// nothing).
    pub(super) fn line_to(&mut self, line: usize, to: Pose, feed: Option<f64>, blend: Blend, out: &mut Vec<Block>) {
        if to != self.position {
            self.push_move(line, to, Path::Line, feed, blend, out);
        }
    }

    /// The offset from program to machine coordinates now: the work system's origin, G92's
    /// offset and the tool's (G43).
    pub(super) fn offset(&self) -> Pose {
        let w = self.work[self.system];
        std::array::from_fn(|c| w[c] + self.g92[c] + self.tool_offset[c])
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
