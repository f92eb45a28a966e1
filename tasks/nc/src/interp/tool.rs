//! Tools, as LinuxCNC converts them: T selects a tool of the table, M6 changes it by hand (the
//! program stands until the operator confirms), M61 says which tool is in the spindle without a
//! change, G43 H / G43.1 / G49 set and cancel the tool offsets, G10 L1 and L10 change a tool's
//! entry for the rest of the program; and a block's message comment.

use crate::NcError;
use crate::lexer::{self, Word};
use crate::tools::{MAX_TOOL, Tool};
use pkm_api::trajectory::{NcMessage, NcMessageKind};

use super::block::{Action, Block, Pose};
use super::state::State;
use super::words::Words;

impl State<'_> {
    /// A line's message comment (`(MSG,…)`, `(DEBUG,…)`, `(PRINT,…)`), first of all its block
    /// does, as in LinuxCNC.
    pub(super) fn message(&mut self, block: &lexer::Block, out: &mut Vec<Block>) {
        if let Some(message) = &block.message {
            self.push_message(message.clone(), block.line, out);
        }
    }

    /// Adds `message` of line `line` to the program's messages, and the action that reaches it.
    fn push_message(&mut self, message: NcMessage, line: usize, out: &mut Vec<Block>) {
        let index = u32::try_from(self.messages.len()).unwrap_or(u32::MAX);
        // Counted against the program's memory bound: a loop of long messages is refused
        // where it passes it, as a loop of moves is.
        self.cost.add_message(message.text.len());
        self.messages.push(message);
        out.push(Block {
            line,
            column: 1,
            action: Action::Message(index),
        });
    }

    /// T: selects a tool of the table for the next M6 (T0: none, the spindle emptied).
    pub(super) fn select_tool(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        if let Some(t) = words.get('T') {
            self.selected = Some(self.tool_number(words.line, t, "T")?);
        }
        Ok(())
    }

    /// M6 (a manual tool change to the selected tool; the spindle stops first, as LinuxCNC
    /// stops it) and M61 Q (the tool in the spindle is Q, without a change).
    pub(super) fn change_tool(&mut self, words: &Words<'_>, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        for (code, w) in &words.m {
            match code {
                60 => {
                    self.refuse_while_compensating(line, w, "the tool cannot change (M6)")?;
                    let tool = self.selected.ok_or_else(|| {
                        at(
                            w,
                            "M6 needs a tool selected first: T… (T0 empties the spindle); the tool a program before this one left is not known here".into(),
                        )
                    })?;
                    out.push(Block {
                        line,
                        column: 1,
                        action: Action::Spindle {
                            direction: super::block::Spindle::Off,
                            speed_rpm: self.speed_rpm,
                        },
                    });
                    out.push(Block {
                        line,
                        column: 1,
                        action: Action::ToolChange { tool },
                    });
                    self.in_spindle = Some(tool);
                }
                610 => {
                    let q = words
                        .get('Q')
                        .ok_or_else(|| at(w, "M61 needs Q: the number of the tool in the spindle".into()))?;
                    self.in_spindle = Some(self.tool_number(line, q, "Q")?);
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// A tool's number from `word` (`letter` names it in messages): a whole number, 0 or a tool
    /// of the table.
    fn tool_number(&self, line: usize, word: &Word, letter: &str) -> Result<u32, NcError> {
        let at = |message: String| NcError::new(line, word.column, message);
        let v = word.value;
        if !(v.fract() == 0.0 && (0.0..=f64::from(MAX_TOOL)).contains(&v)) {
            return Err(at(format!(
                "{letter} is a tool's number, a whole number 0 … {MAX_TOOL}; got {v}"
            )));
        }
        let number = v as u32;
        if number != 0 {
            self.tool_entry(line, word, &format!("{letter}{number}"), number)?;
        }
        Ok(number)
    }

    /// Tool `number`'s entry in the table; where there is none, the error at `word`, `asked`
    /// (the words that asked for it: `T7`, `G41 D7`) and why: the run has no table, or no such
    /// tool.
    pub(super) fn tool_entry(&self, line: usize, word: &Word, asked: &str, number: u32) -> Result<&Tool, NcError> {
        self.tools.get(number).ok_or_else(|| {
            NcError::new(
                line,
                word.column,
                if self.machine.tools.is_none() {
                    format!(
                        "{asked}: there is no tool table (give one with --tool-table or nc.tool_table in the configuration)"
                    )
                } else {
                    format!("{asked}: tool {number} is not in the tool table")
                },
            )
        })
    }

    /// G43 (the offsets of tool H, or of the tool in the spindle), G43.1 (the offsets of the
    /// axes its words name replaced by their values, the others kept) and G49 (none). The tool does not move; where it is reads
    /// differently from here on.
    pub(super) fn tool_length(&mut self, words: &Words<'_>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        if let Some((_, w)) = words.g.iter().find(|(c, _)| matches!(c, 430 | 431 | 490)) {
            self.refuse_while_compensating(line, w, "the tool length offset (G43, G43.1, G49) cannot change")?;
        }
        if let Some(g43) = words.g_word(430) {
            let number = match words.get('H') {
                Some(h) => self.tool_number(line, h, "H")?,
                None => self.in_spindle.ok_or_else(|| {
                    at(
                        g43,
                        "G43 without H applies the tool in the spindle, and this program has not put one there (T… M6, or M61 Q…): write G43 H…".into(),
                    )
                })?,
            };
            let offsets = self.tools.get(number).map_or([0.0; 6], |t| t.offsets);
            self.tool_offset = self.on_machine(offsets);
        }
        if words.has_g(431) {
            let given = words.axis_words();
            if given.is_empty() {
                return Err(at(
                    words.first,
                    "G43.1 needs at least one axis word: the tool's offsets".into(),
                ));
            }
            for (c, w) in given {
                self.tool_offset[c] = w.value * self.scale(c);
            }
        }
        if words.has_g(490) {
            self.tool_offset = [0.0; 6];
        }
        Ok(())
    }

    /// `offsets` with the coordinates the machine does not have left out (a mill's Z length on a
    /// planar machine changes nothing).
    pub(super) fn on_machine(&self, offsets: Pose) -> Pose {
        let n = self.machine.axes.len();
        std::array::from_fn(|c| if c < n { offsets[c] } else { 0.0 })
    }

    /// G10 L1 (tool P's offsets to the values the axis words give, R its radius) and L10 (its
    /// offsets so that where the tool is reads as the values given, in the work system in force,
    /// G92 included), for the rest of the program: the tool table's file is not written. L11
    /// (relative to G59.3, which this interpreter has not) is refused.
    pub(super) fn set_tool_entry(&mut self, words: &Words<'_>, l: &Word, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = words.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        if l.value == 11.0 {
            return Err(at(
                l,
                "G10 L11 is not supported: it measures a tool against G59.3, a coordinate system this interpreter does not have (G54 … G59); L10 measures it in the system in force".into(),
            ));
        }
        let name = if l.value == 1.0 { "G10 L1" } else { "G10 L10" };
        let p = words
            .get('P')
            .ok_or_else(|| at(l, format!("{name} needs P: the tool's number")))?;
        let number = match p.value {
            v if v.fract() == 0.0 && (1.0..=f64::from(MAX_TOOL)).contains(&v) => v as u32,
            v => return Err(at(p, format!("P is the tool's number, 1 … {MAX_TOOL}; got {v}"))),
        };
        if self.machine.tools.is_none() {
            return Err(at(
                p,
                format!(
                    "{name}: there is no tool table (give one with --tool-table or nc.tool_table in the configuration)"
                ),
            ));
        }
        let diameter = match words.get('R') {
            Some(r) if r.value < 0.0 => {
                return Err(at(
                    r,
                    format!("R is the tool's radius, zero or positive; got {}", r.value),
                ));
            }
            Some(r) => Some(2.0 * r.value * self.unit()),
            None => None,
        };
        let orientation = match words.get('Q') {
            Some(q) if !(q.value.fract() == 0.0 && (0.0..=9.0).contains(&q.value)) => {
                return Err(at(
                    q,
                    format!("Q is a lathe tool's orientation, a whole number 0 … 9; got {}", q.value),
                ));
            }
            Some(q) => Some(q.value as u8),
            None => None,
        };
        let values: Vec<(usize, f64)> = words
            .axis_words()
            .into_iter()
            .map(|(c, w)| {
                let v = w.value * self.scale(c);
                if l.value == 1.0 {
                    (c, v)
                } else {
                    (c, self.position[c] - self.work[self.system][c] - self.g92[c] - v)
                }
            })
            .collect();
        let entry = self.tools.entry(number).ok_or_else(|| {
            at(
                p,
                format!(
                    "{name}: the tool table holds {} tools already, its most",
                    crate::tools::MAX_TOOLS
                ),
            )
        })?;
        for (c, v) in values {
            entry.offsets[c] = v;
        }
        if let Some(d) = diameter {
            entry.diameter = d;
        }
        if let Some(q) = orientation {
            entry.orientation = q;
        }
        // The run writes the entry back to the tool table when it reaches this line.
        let text = entry.line();
        self.push_message(
            NcMessage {
                line: u32::try_from(line).unwrap_or(u32::MAX),
                kind: NcMessageKind::ToolEntry,
                text,
            },
            line,
            out,
        );
        Ok(())
    }
}
