//! The tool table, in LinuxCNC's `tool.tbl` format: one tool a line, its words in any order —
//! `T` the tool's number (required, 1 … 99 999), `P` its pocket, `X Y Z A B C` its offsets
//! (machine units: mm, degrees), `D` its diameter, `I J Q` a lathe tool's angles and orientation
//! (read, not used) — and a comment after `;` (the name the manual tool change shows). Blank
//! lines and lines of only a comment are skipped. `U V W` offsets are refused (this machine has
//! no such axes), as is anything else LinuxCNC would not read, with its line and column.
//!
//! G43 applies a tool's offsets, `T… M6` asks for a tool by its number, and G10 L1 / L10 change
//! an entry for the rest of the program (docs/nc.md, Tools).

use crate::NcError;
use crate::interp::Pose;

/// The largest tool number accepted (LinuxCNC's tables are searched by number; a number this
/// large is a typing error).
pub const MAX_TOOL: u32 = 99_999;
/// The most tools a table holds (LinuxCNC's default pocket count, `CANON_POCKETS_MAX`, less
/// the spindle's).
pub const MAX_TOOLS: usize = 1000;

/// One tool.
#[derive(Clone, Debug, PartialEq)]
pub struct Tool {
    /// Its number (`T`).
    pub number: u32,
    /// Its pocket (`P`; the number when the table gives none).
    pub pocket: u32,
    /// Its offsets per pose coordinate (machine units: mm, degrees), as G43 applies them.
    pub offsets: Pose,
    /// Its diameter (mm; 0 when not given).
    pub diameter: f64,
    /// A lathe tool's orientation (`Q`, 1 … 9; 0 for a mill's tool): cutter compensation takes
    /// only tools of orientation 0 or 9, whose centre is the point it controls.
    pub orientation: u8,
    /// A lathe tool's front and back angles (`I`, `J`; degrees), as the table gives them: kept
    /// so that the table is written back whole, unused by a mill.
    pub angles: [Option<f64>; 2],
    /// The comment after `;` (trimmed; empty when none).
    pub comment: String,
}

impl Tool {
    /// Tool `number` in pocket `number`, without offsets, diameter or comment.
    pub fn new(number: u32) -> Tool {
        Tool {
            number,
            pocket: number,
            offsets: [0.0; 6],
            diameter: 0.0,
            orientation: 0,
            angles: [None; 2],
            comment: String::new(),
        }
    }

    /// The tool's line in LinuxCNC's format, as LinuxCNC writes it: `T` and `P`, the offsets
    /// that are not zero, the diameter, a lathe tool's angles and orientation (six decimals,
    /// signed offsets), the comment after `;`.
    pub fn line(&self) -> String {
        let mut line = format!("T{} P{}", self.number, self.pocket);
        for (letter, v) in crate::interp::AXES.iter().zip(self.offsets) {
            if v != 0.0 {
                line += &format!(" {letter}{v:+.6}");
            }
        }
        if self.diameter != 0.0 {
            line += &format!(" D{:.6}", self.diameter);
        }
        for (letter, v) in ['I', 'J'].iter().zip(self.angles) {
            if let Some(v) = v {
                line += &format!(" {letter}{v:+.6}");
            }
        }
        if self.orientation != 0 {
            line += &format!(" Q{}", self.orientation);
        }
        if !self.comment.is_empty() {
            line += &format!(" ;{}", self.comment);
        }
        line
    }
}

/// A tool table: its tools in the file's order, numbers unique.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ToolTable {
    /// The tools.
    pub tools: Vec<Tool>,
}

impl ToolTable {
    /// Reads a table in LinuxCNC's format; a problem names its line and column (the file's name
    /// is the caller's to add).
    pub fn parse(text: &str) -> Result<ToolTable, NcError> {
        let mut tools: Vec<Tool> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let number = i + 1;
            let (words, comment) = match raw.split_once(';') {
                Some((w, c)) => (w, c.trim()),
                None => (raw, ""),
            };
            if words.trim().is_empty() {
                continue;
            }
            let tool = parse_line(words, comment, number)?;
            if tools.len() == MAX_TOOLS {
                return Err(NcError::new(
                    number,
                    1,
                    format!("more than {MAX_TOOLS} tools: a table holds at most {MAX_TOOLS}, as LinuxCNC's"),
                ));
            }
            if tools.iter().any(|t| t.number == tool.number) {
                return Err(NcError::new(
                    number,
                    column_of(raw, 'T'),
                    format!("tool {} is in the table twice", tool.number),
                ));
            }
            tools.push(tool);
        }
        Ok(ToolTable { tools })
    }

    /// The table in LinuxCNC's format, one tool a line in the table's order, as LinuxCNC writes
    /// it back (its comment lines and blank lines are not kept, as in LinuxCNC).
    pub fn format(&self) -> String {
        self.tools.iter().map(|t| t.line() + "\n").collect()
    }

    /// The tool numbered `number`.
    pub fn get(&self, number: u32) -> Option<&Tool> {
        self.tools.iter().find(|t| t.number == number)
    }

    /// The tool numbered `number`, to change (a new entry with no offsets where the table has
    /// none, as LinuxCNC's G10 L1 makes one); `None` when the table is full ([`MAX_TOOLS`]).
    pub fn entry(&mut self, number: u32) -> Option<&mut Tool> {
        let at = match self.tools.iter().position(|t| t.number == number) {
            Some(at) => at,
            None if self.tools.len() >= MAX_TOOLS => return None,
            None => {
                self.tools.push(Tool::new(number));
                self.tools.len() - 1
            }
        };
        self.tools.get_mut(at)
    }
}

/// The 1-based column of the first `letter` (either case) in `text`, 1 if none.
fn column_of(text: &str, letter: char) -> usize {
    text.chars()
        .position(|c| c.eq_ignore_ascii_case(&letter))
        .map_or(1, |p| p + 1)
}

/// One line's words (its comment apart).
fn parse_line(words: &str, comment: &str, line: usize) -> Result<Tool, NcError> {
    let chars: Vec<char> = words.chars().collect();
    let mut at = 0;
    let mut tool = Tool {
        comment: comment.to_string(),
        ..Tool::new(0)
    };
    let (mut number, mut pocket) = (None, None);
    let mut seen = String::new();
    while at < chars.len() {
        if chars[at].is_whitespace() {
            at += 1;
            continue;
        }
        let column = at + 1;
        let letter = chars[at].to_ascii_uppercase();
        at += 1;
        let start = at;
        while at < chars.len() && !chars[at].is_whitespace() {
            at += 1;
        }
        let text: String = chars[start..at].iter().collect();
        let err = |m: String| NcError::new(line, column, m);
        if !letter.is_ascii_alphabetic() {
            return Err(err(format!(
                "'{}' does not start a word of a tool table",
                chars[column - 1]
            )));
        }
        if seen.contains(letter) {
            return Err(err(format!("{letter} twice on one line")));
        }
        seen.push(letter);
        let value: f64 = text
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| err(format!("{letter} needs a number")))?;
        let whole = |what: &str, max: u32| -> Result<u32, NcError> {
            if value.fract() == 0.0 && value >= 0.0 && value <= f64::from(max) {
                Ok(value as u32)
            } else {
                Err(err(format!("{what} is a whole number 0 … {max}, got {text}")))
            }
        };
        match letter {
            'T' => number = Some(whole("T (the tool's number)", MAX_TOOL)?),
            'P' => pocket = Some(whole("P (the pocket)", MAX_TOOL)?),
            'X' | 'Y' | 'Z' | 'A' | 'B' | 'C' => {
                let c = crate::interp::AXES
                    .iter()
                    .position(|a| *a == letter)
                    .unwrap_or_default();
                if value.abs() > 10_000.0 {
                    return Err(err(format!(
                        "the {letter} offset must be within ±10 000 (mm or degrees), got {value}"
                    )));
                }
                tool.offsets[c] = value;
            }
            'D' => {
                if !(0.0..=1000.0).contains(&value) {
                    return Err(err(format!("the diameter D must be 0 … 1000 mm, got {value}")));
                }
                tool.diameter = value;
            }
            'Q' => {
                if !(value.fract() == 0.0 && (0.0..=9.0).contains(&value)) {
                    return Err(err(format!("the orientation Q is a whole number 0 … 9, got {value}")));
                }
                tool.orientation = value as u8;
            }
            // A lathe tool's front and back angles: read as LinuxCNC reads them, kept, unused by
            // a mill.
            'I' => tool.angles[0] = Some(value),
            'J' => tool.angles[1] = Some(value),
            'U' | 'V' | 'W' => {
                return Err(err(format!("{letter}: offsets of axes U V W are not supported")));
            }
            other => {
                return Err(err(format!(
                    "{other} is not a word of a tool table (T P X Y Z A B C D I J Q)"
                )));
            }
        }
    }
    let number = number.ok_or_else(|| NcError::new(line, 1, "a tool's line needs T, its number"))?;
    if number == 0 {
        return Err(NcError::new(
            line,
            column_of(words, 'T'),
            "T0 is no tool (the empty spindle): it has no line in the table",
        ));
    }
    tool.number = number;
    tool.pocket = pocket.unwrap_or(number);
    Ok(tool)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linuxcncs_lines_are_read_with_their_comments() {
        let t = ToolTable::parse(
            "T1 P1 Z50.0 D6.0 ;6 mm end mill\n\n; a comment line\nt2 p3 z30.5 x-0.1 d3 i0 j0 q0\nT3 ;probe\n",
        )
        .expect("a table");
        assert_eq!(t.tools.len(), 3);
        assert_eq!(
            t.get(1).map(|t| (t.offsets[2], t.diameter, t.comment.as_str())),
            Some((50.0, 6.0, "6 mm end mill"))
        );
        assert_eq!(
            t.get(2).map(|t| (t.pocket, t.offsets[0], t.offsets[2])),
            Some((3, -0.1, 30.5))
        );
        assert_eq!(t.get(3).map(|t| (t.pocket, t.comment.as_str())), Some((3, "probe")));
        assert!(t.get(4).is_none());
    }

    #[test]
    fn problems_name_their_line_and_column() {
        let cases = [
            ("T1 Z1\nT1 Z2\n", "2:1: tool 1 is in the table twice"),
            ("P1 Z1\n", "1:1: a tool's line needs T, its number"),
            (
                "T0 Z1\n",
                "1:1: T0 is no tool (the empty spindle): it has no line in the table",
            ),
            ("T1 Z1 Z2\n", "1:7: Z twice on one line"),
            ("T1 Zabc\n", "1:4: Z needs a number"),
            (
                "T1.5\n",
                "1:1: T (the tool's number) is a whole number 0 … 99999, got 1.5",
            ),
            ("T1 U3\n", "1:4: U: offsets of axes U V W are not supported"),
            (
                "T1 R3\n",
                "1:4: R is not a word of a tool table (T P X Y Z A B C D I J Q)",
            ),
            ("T1 D-2\n", "1:4: the diameter D must be 0 … 1000 mm, got -2"),
            (
                "T1 Z1e9\n",
                "1:4: the Z offset must be within ±10 000 (mm or degrees), got 1000000000",
            ),
            ("T1 %\n", "1:4: '%' does not start a word of a tool table"),
        ];
        let many: String = (1..=1001).map(|t| format!("T{t} Z1\n")).collect();
        assert_eq!(
            ToolTable::parse(&many).map_err(|e| e.to_string()),
            Err("1001:1: more than 1000 tools: a table holds at most 1000, as LinuxCNC's".to_string())
        );
        for (text, want) in cases {
            assert_eq!(
                ToolTable::parse(text).map_err(|e| e.to_string()),
                Err(want.to_string()),
                "{text}"
            );
        }
    }

    proptest::proptest! {
        /// Any table written in LinuxCNC's format reads back as the same table (to the six
        /// decimals LinuxCNC writes).
        #[test]
        fn a_written_table_reads_back_the_same(
            tools in proptest::collection::vec(
                (1u32..=MAX_TOOL, 0u32..=MAX_TOOL, proptest::collection::vec(-9999.0f64..9999.0, 6), 0.0f64..1000.0,
                 proptest::option::of(-90.0f64..90.0), 0u8..=9, "[a-zA-Z0-9 .,/()-]{0,30}"),
                0..20,
            ),
        ) {
            let round = |v: f64| (v * 1e6).round() / 1e6;
            let mut table = ToolTable::default();
            for (number, pocket, offsets, diameter, angle, orientation, comment) in tools {
                if table.get(number).is_some() {
                    continue;
                }
                table.tools.push(Tool {
                    number,
                    pocket,
                    offsets: std::array::from_fn(|c| round(offsets[c])),
                    diameter: round(diameter),
                    orientation,
                    angles: [angle.map(round), None],
                    comment: comment.trim().to_string(),
                });
            }
            let text = table.format();
            let back = ToolTable::parse(&text).map_err(|e| proptest::test_runner::TestCaseError::fail(format!("{e}\n{text}")))?;
            proptest::prop_assert_eq!(back, table, "{}", text);
        }
    }

    #[test]
    fn an_entry_is_made_where_the_table_has_none() {
        let mut t = ToolTable::parse("T1 Z5\n").expect("a table");
        t.entry(7).expect("room").offsets[2] = 3.0;
        t.entry(1).expect("there").offsets[2] = 4.0;
        assert_eq!(t.get(7).map(|t| (t.pocket, t.offsets[2])), Some((7, 3.0)));
        assert_eq!(t.get(1).map(|t| t.offsets[2]), Some(4.0));
    }
}
