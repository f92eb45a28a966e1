//! One line of a program as LinuxCNC reads it: its words with their values, the parameters it
//! sets, or its O-word statement.
//!
//! RS274NGC as LinuxCNC 2.9 reads it: blanks and case do not matter outside comments (`X1 0.5` is
//! `X10.5`, `#<My Name>` is `#<myname>`); comments in parentheses and after `;`; a line may start
//! with `/` (block delete: skipped while the switch is on, run while it is off, LinuxCNC's
//! default) or be a `%` delimiter. A word's value is a number, a parameter (`#12`, `#<depth>`,
//! `##2`, `#[#2+1]`), an expression in brackets with LinuxCNC's operators (`**`; `*` `/` `MOD`;
//! `+` `-`; `EQ` `NE` `GT` `GE` `LT` `LE`; `AND` `OR` `XOR`, each level left to right) or a
//! function (`ABS` `ACOS` `ASIN` `ATAN[y]/[x]` `COS` `EXP` `EXISTS` `FIX` `FUP` `LN` `ROUND` `SIN`
//! `SQRT` `TAN`, angles in degrees). Values are computed while the line is read, from the
//! parameters as they were before it (a line's own settings take effect after it, "in
//! parallel", as in LinuxCNC).

use pkm_api::trajectory::NcMessage;

use crate::NcError;

mod messages;
use messages::message_of;

/// A letter and its value, where it starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Word {
    /// The letter, upper case.
    pub letter: char,
    /// The value (the number, or what the parameter or expression gave).
    pub value: f64,
    /// The letter's column (1-based, in characters).
    pub column: usize,
}

/// A line of the program that holds words.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// The line (1-based).
    pub line: usize,
    /// Its words, in order (none on a line of only a message comment).
    pub words: Vec<Word>,
    /// The message its last comment asks for (`(MSG,…)`, `(DEBUG,…)`, `(PRINT,…)`).
    pub message: Option<NcMessage>,
}

/// The parameter an assignment sets.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// `#12 = …`.
    Numbered(usize),
    /// `#<name> = …` (the name in lower case, without blanks).
    Named(String),
}

/// `#… = value` on a line.
#[derive(Clone, Debug, PartialEq)]
pub struct Assignment {
    /// What it sets.
    pub target: Target,
    /// The value, computed from the parameters before the line.
    pub value: f64,
    /// The column of its `#`.
    pub column: usize,
}

/// What an O-word statement does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keyword {
    /// `sub`: a subroutine starts.
    Sub,
    /// `endsub [value]`.
    EndSub,
    /// `call [arg] …`.
    Call,
    /// `return [value]`.
    Return,
    /// `do`: a loop tested at its end.
    Do,
    /// `while [condition]`: a loop's test (at its start, or closing a `do`).
    While,
    /// `endwhile`.
    EndWhile,
    /// `repeat [count]`.
    Repeat,
    /// `endrepeat`.
    EndRepeat,
    /// `if [condition]`.
    If,
    /// `elseif [condition]`.
    ElseIf,
    /// `else`.
    Else,
    /// `endif`.
    EndIf,
    /// `break`: leave the loop.
    Break,
    /// `continue`: the loop's next turn.
    Continue,
}

impl Keyword {
    /// The keyword as written.
    pub fn name(self) -> &'static str {
        match self {
            Keyword::Sub => "sub",
            Keyword::EndSub => "endsub",
            Keyword::Call => "call",
            Keyword::Return => "return",
            Keyword::Do => "do",
            Keyword::While => "while",
            Keyword::EndWhile => "endwhile",
            Keyword::Repeat => "repeat",
            Keyword::EndRepeat => "endrepeat",
            Keyword::If => "if",
            Keyword::ElseIf => "elseif",
            Keyword::Else => "else",
            Keyword::EndIf => "endif",
            Keyword::Break => "break",
            Keyword::Continue => "continue",
        }
    }

    /// Longest names first where one starts another (`elseif` before `else`).
    const ALL: [Keyword; 15] = [
        Keyword::EndSub,
        Keyword::EndWhile,
        Keyword::EndRepeat,
        Keyword::EndIf,
        Keyword::ElseIf,
        Keyword::Else,
        Keyword::Sub,
        Keyword::Call,
        Keyword::Return,
        Keyword::Do,
        Keyword::While,
        Keyword::Repeat,
        Keyword::If,
        Keyword::Break,
        Keyword::Continue,
    ];
}

/// An O-word statement: `o100 while [#1 LT 5]`, `o<drill> call [2] [3]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Control {
    /// The line (1-based).
    pub line: usize,
    /// The column of its `o`.
    pub column: usize,
    /// Its label: a number (`100`) or a name in angle brackets (`<drill>`), as `o` is followed.
    pub label: String,
    /// What it does.
    pub keyword: Keyword,
    /// Its bracketed values: a condition, a count, a call's arguments, a returned value (empty
    /// when the statement was only looked at, not read).
    pub values: Vec<f64>,
}

impl Control {
    /// `o100 while`, `o<drill> call`: how messages name it.
    pub fn name(&self) -> String {
        format!("o{} {}", self.label, self.keyword.name())
    }
}

/// What one line holds.
#[derive(Clone, Debug, PartialEq)]
pub enum Line {
    /// Words and parameter settings (either may be empty, not both).
    Words {
        /// The words.
        block: Block,
        /// The parameters the line sets, in order.
        assignments: Vec<Assignment>,
    },
    /// An O-word statement.
    Control(Control),
    /// A `%` delimiter.
    Percent,
    /// Blank, only comments, or skipped by the block-delete switch.
    Nothing,
}

/// Where a line's values come from.
pub trait Parameters {
    /// The value of `#index`, or why it cannot be read.
    fn numbered(&self, index: usize) -> Result<f64, String>;
    /// The value of `#<name>` (lower case, no blanks), `None` while it is not defined.
    fn named(&self, name: &str) -> Option<f64>;
}

/// No parameters at all: every `#` read is refused (for texts that must be plain numbers).
pub struct NoParameters;

impl Parameters for NoParameters {
    fn numbered(&self, index: usize) -> Result<f64, String> {
        Err(format!("#{index} cannot be read here"))
    }
    fn named(&self, _name: &str) -> Option<f64> {
        None
    }
}

/// The largest magnitude of a number in a program: far beyond any coordinate, feed or speed a
/// machine can mean, far below where a float loses whole units.
pub const MAX_NUMBER: f64 = 1e9;

/// Two values closer than this are equal for `EQ`, `NE`, `LE`, `GE` (LinuxCNC 2.9's
/// `TOLERANCE_EQUAL`).
pub const TOLERANCE_EQUAL: f64 = 1e-4;

/// How much a value that must be a whole number (a parameter's number, a label) may differ from
/// one.
const WHOLE: f64 = 1e-4;

/// Reads line `number` (1-based) of a program: `text` without its line end. `block_delete`:
/// the switch (on: a line starting with `/` is skipped). Values are computed from `params`.
pub fn read_line(text: &str, number: usize, block_delete: bool, params: &dyn Parameters) -> Result<Line, NcError> {
    let Some(chars) = clean(text, number, block_delete)? else {
        return Ok(match message_of(text, number, block_delete, params) {
            Some(message) => Line::Words {
                block: Block {
                    line: number,
                    words: Vec::new(),
                    message: Some(message),
                },
                assignments: Vec::new(),
            },
            None => Line::Nothing,
        });
    };
    let mut cursor = Cursor {
        chars: &chars,
        at: 0,
        line: number,
        params: Some(params),
        depth: 0,
    };
    let mut line = cursor.line_items()?;
    if let Line::Words { block, .. } = &mut line {
        block.message = message_of(text, number, block_delete, params);
    }
    Ok(line)
}

/// The O-word statement of line `number`, looked at without reading its values (while lines are
/// skipped to the end of a branch, a loop or a subroutine, as LinuxCNC skips them); `None` for
/// any other line.
pub fn control_of(text: &str, number: usize, block_delete: bool) -> Result<Option<Control>, NcError> {
    let Some(chars) = clean(text, number, block_delete)? else {
        return Ok(None);
    };
    let mut cursor = Cursor {
        chars: &chars,
        at: 0,
        line: number,
        params: None,
        depth: 0,
    };
    cursor.skip_line_number()?;
    if cursor.peek() != Some('o') {
        return Ok(None);
    }
    cursor.control().map(Some)
}

/// A character of a line as it is read: lower case, with its column in the written line.
#[derive(Clone, Copy)]
struct Ch {
    /// Lower case; a whole comment is one `(`.
    c: char,
    /// As written (for messages).
    written: char,
    /// 1-based column.
    column: usize,
}

/// The line without blanks and comments (each comment one `(`, so that it still separates),
/// `%` lines as a single `%`; `None` for a line with nothing to read.
fn clean(text: &str, number: usize, block_delete: bool) -> Result<Option<Vec<Ch>>, NcError> {
    let mut out = Vec::with_capacity(text.len());
    let mut chars = text.chars().enumerate().peekable();
    while let Some((i, c)) = chars.next() {
        let column = i + 1;
        match c {
            c if c.is_whitespace() => {}
            '(' => {
                // A comment ends at the first ')'.
                if !chars.by_ref().any(|(_, c)| c == ')') {
                    return Err(NcError::new(number, column, "comment not closed: ')' is missing"));
                }
                out.push(Ch {
                    c: '(',
                    written: '(',
                    column,
                });
            }
            ';' => break,
            c => out.push(Ch {
                c: c.to_ascii_lowercase(),
                written: c,
                column,
            }),
        }
    }
    // Block delete: with the switch on the line is skipped; off, it runs without its '/'.
    if out.first().is_some_and(|c| c.c == '/') {
        if block_delete {
            return Ok(None);
        }
        out.remove(0);
    }
    if out.iter().all(|c| c.c == '(') {
        return Ok(None);
    }
    if let Some(p) = out.iter().position(|c| c.c == '%') {
        if p == 0 && out[1..].iter().all(|c| c.c == '(') {
            out.truncate(1);
            return Ok(Some(out));
        }
        return Err(NcError::new(
            number,
            out[p].column,
            "'%' stands on a line of its own (it delimits the program)",
        ));
    }
    Ok(Some(out))
}

/// The binary operators, by precedence (LinuxCNC's levels 2 to 6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    And,
    Or,
    Xor,
    Eq,
    Ne,
    Gt,
    Ge,
    Lt,
    Le,
    Plus,
    Minus,
    Times,
    Divide,
    Modulo,
    Power,
}

impl Op {
    fn precedence(self) -> u8 {
        match self {
            Op::And | Op::Or | Op::Xor => 2,
            Op::Eq | Op::Ne | Op::Gt | Op::Ge | Op::Lt | Op::Le => 3,
            Op::Plus | Op::Minus => 4,
            Op::Times | Op::Divide | Op::Modulo => 5,
            Op::Power => 6,
        }
    }

    /// `left op right` as LinuxCNC computes it; the reason it cannot be computed.
    fn apply(self, left: f64, right: f64) -> Result<f64, &'static str> {
        let truth = |b: bool| if b { 1.0 } else { 0.0 };
        let equal = (left - right).abs() < TOLERANCE_EQUAL;
        Ok(match self {
            Op::And => truth(left != 0.0 && right != 0.0),
            Op::Or => truth(left != 0.0 || right != 0.0),
            Op::Xor => truth((left != 0.0) != (right != 0.0)),
            Op::Eq => truth(equal),
            Op::Ne => truth(!equal),
            Op::Gt => truth(left > right),
            Op::Ge => truth(equal || left >= right),
            Op::Lt => truth(left < right),
            Op::Le => truth(equal || left <= right),
            Op::Plus => left + right,
            Op::Minus => left - right,
            Op::Times => left * right,
            Op::Divide => {
                if right == 0.0 {
                    return Err("division by zero");
                }
                left / right
            }
            // Always positive, as LinuxCNC's.
            Op::Modulo => {
                let m = left % right;
                if m < 0.0 { m + right.abs() } else { m }
            }
            Op::Power => {
                if left < 0.0 && right.fract() != 0.0 {
                    return Err("a negative number raised to a power that is not whole");
                }
                left.powf(right)
            }
        })
    }
}

/// The functions, by name.
const FUNCTIONS: [&str; 14] = [
    "abs", "acos", "asin", "atan", "cos", "exists", "exp", "fix", "fup", "ln", "round", "sin", "sqrt", "tan",
];

/// A reader of one cleaned line.
struct Cursor<'a> {
    chars: &'a [Ch],
    at: usize,
    line: usize,
    /// Where values come from; `None` when values are only skipped over.
    params: Option<&'a dyn Parameters>,
    /// How many values are being read inside one another ([`MAX_NESTING`]).
    depth: usize,
}

impl Cursor<'_> {
    fn peek(&self) -> Option<char> {
        self.chars.get(self.at).map(|c| c.c)
    }

    fn peek_at(&self, ahead: usize) -> Option<char> {
        self.chars.get(self.at + ahead).map(|c| c.c)
    }

    /// The column of the character read next (or just past the line's end).
    fn column(&self) -> usize {
        match self.chars.get(self.at) {
            Some(c) => c.column,
            None => self.chars.last().map_or(1, |c| c.column + 1),
        }
    }

    fn error(&self, column: usize, message: impl Into<String>) -> NcError {
        NcError::new(self.line, column, message)
    }

    /// Whether the text ahead starts with `word` (lower case); consumes it if so.
    fn eat(&mut self, word: &str) -> bool {
        let n = word.chars().count();
        let matches =
            self.chars.len() >= self.at + n && self.chars[self.at..self.at + n].iter().map(|c| c.c).eq(word.chars());
        if matches {
            self.at += n;
        }
        matches
    }

    /// The line's items.
    fn line_items(&mut self) -> Result<Line, NcError> {
        if self.peek() == Some('%') {
            return Ok(Line::Percent);
        }
        let mut words = Vec::new();
        let mut assignments = Vec::new();
        let mut first = true;
        while let Some(ch) = self.chars.get(self.at).copied() {
            match ch.c {
                '(' => self.at += 1,
                'o' if first || words.iter().all(|w: &Word| w.letter == 'N') && assignments.is_empty() => {
                    let control = self.control()?;
                    return Ok(Line::Control(control));
                }
                'o' => {
                    return Err(self.error(
                        ch.column,
                        "an O-word statement (sub, call, if, while, …) stands at the start of its line",
                    ));
                }
                '#' => assignments.push(self.assignment()?),
                // Polar coordinates' distance (@) and angle (^) are words as letters are.
                c if c.is_ascii_alphabetic() || c == '@' || c == '^' => {
                    self.at += 1;
                    let letter = c.to_ascii_uppercase();
                    let value = self.value(Some((letter, ch.column)))?;
                    if value.abs() > MAX_NUMBER {
                        return Err(self.error(
                            ch.column,
                            format!("{letter}: the number is out of range (at most {MAX_NUMBER:e} in magnitude)"),
                        ));
                    }
                    words.push(Word {
                        letter,
                        value,
                        column: ch.column,
                    });
                }
                '/' => {
                    return Err(self.error(
                        ch.column,
                        "'/' only starts a line (block delete); a division is written in brackets: [1/2]",
                    ));
                }
                _ => return Err(self.error(ch.column, format!("unexpected character '{}'", ch.written))),
            }
            first = false;
        }
        Ok(Line::Words {
            block: Block {
                line: self.line,
                words,
                message: None,
            },
            assignments,
        })
    }

    /// Skips a leading line number (`N10`), for a look at what follows it.
    fn skip_line_number(&mut self) -> Result<(), NcError> {
        while self.peek() == Some('(') {
            self.at += 1;
        }
        if self.peek() == Some('n') {
            self.at += 1;
            while self.peek().is_some_and(|c| c.is_ascii_digit() || c == '.') {
                self.at += 1;
            }
        }
        Ok(())
    }

    /// `#… = value`.
    fn assignment(&mut self) -> Result<Assignment, NcError> {
        let column = self.column();
        self.at += 1;
        let target = if self.peek() == Some('<') {
            Target::Named(self.name()?)
        } else {
            let index = self.value(None)?;
            Target::Numbered(self.parameter_number(index, column)?)
        };
        if self.peek() != Some('=') {
            return Err(self.error(
                self.column(),
                "a parameter is set with '=' and a value: #1 = 5, #<depth> = [#1 / 2]",
            ));
        }
        self.at += 1;
        let value = self.value(None)?;
        Ok(Assignment { target, value, column })
    }

    /// `<name>`: the name between the brackets.
    fn name(&mut self) -> Result<String, NcError> {
        let column = self.column();
        self.at += 1;
        let mut name = String::new();
        loop {
            match self.chars.get(self.at) {
                Some(c) if c.c == '>' => {
                    self.at += 1;
                    break;
                }
                Some(c) if c.c != '(' => {
                    name.push(c.c);
                    self.at += 1;
                }
                _ => return Err(self.error(column, "a name in '<' is closed by '>'")),
            }
        }
        if name.is_empty() {
            return Err(self.error(column, "a name in '<' '>' has at least one character"));
        }
        Ok(name)
    }

    /// A parameter's number from its value.
    fn parameter_number(&self, value: f64, column: usize) -> Result<usize, NcError> {
        let index = value.round();
        if (value - index).abs() > WHOLE || !(1.0..=MAX_PARAMETER as f64).contains(&index) {
            return Err(self.error(
                column,
                format!("a parameter's number is a whole number from 1 to {MAX_PARAMETER}, got {value}"),
            ));
        }
        Ok(index as usize)
    }

    /// A value: a number, a parameter, an expression, a function, or a sign before any of them.
    /// `word`: the letter and column of the word it belongs to (for the message when there is
    /// none).
    ///
    /// Values nest (`[[1]]`, `--[1]`, `##1`, `SIN[COS[1]]`) and each level is a call of this
    /// function: beyond [`MAX_NESTING`] levels the value is refused where it crosses the bound,
    /// so that no text can overflow the reader's stack (which aborts the whole process).
    fn value(&mut self, word: Option<(char, usize)>) -> Result<f64, NcError> {
        if self.depth >= MAX_NESTING {
            return Err(self.error(
                self.column(),
                format!(
                    "the value nests deeper than {MAX_NESTING} levels (brackets, signs, parameters of parameters and functions, counted together): write it in steps with parameters"
                ),
            ));
        }
        self.depth += 1;
        let value = self.nested_value(word);
        self.depth -= 1;
        value
    }

    /// [`Self::value`] inside the depth's bound.
    fn nested_value(&mut self, word: Option<(char, usize)>) -> Result<f64, NcError> {
        let column = self.column();
        let missing = |this: &Self| match word {
            Some((letter, column)) => this.error(column, format!("{letter} needs a number")),
            None => this.error(
                column,
                "a value is missing here: a number, a parameter (#) or an expression ([…])",
            ),
        };
        let Some(c) = self.peek() else {
            return Err(missing(self));
        };
        let next = self.peek_at(1);
        let value = match c {
            '[' => self.expression()?,
            '#' => {
                self.at += 1;
                if self.peek() == Some('<') {
                    let name = self.name()?;
                    match self.params {
                        None => 0.0,
                        Some(p) => p.named(&name).ok_or_else(|| {
                            self.error(
                                column,
                                format!("#<{name}> is not defined: set it (#<{name}> = …) before reading it"),
                            )
                        })?,
                    }
                } else {
                    let index = self.value(None)?;
                    let index = self.parameter_number(index, column)?;
                    match self.params {
                        None => 0.0,
                        Some(p) => p.numbered(index).map_err(|m| self.error(column, m))?,
                    }
                }
            }
            '+' | '-' if next.is_some_and(|n| !n.is_ascii_digit() && n != '.') => {
                self.at += 1;
                let v = self.value(word)?;
                if c == '-' { -v } else { v }
            }
            c if c.is_ascii_alphabetic() => match FUNCTIONS.iter().find(|f| self.eat(f)) {
                Some(f) => self.function(f, column)?,
                None => return Err(missing(self)),
            },
            c if c.is_ascii_digit() || matches!(c, '.' | '+' | '-') => self.number(word)?,
            _ => return Err(missing(self)),
        };
        if !value.is_finite() {
            return Err(self.error(column, "the calculation gives infinity or not a number"));
        }
        Ok(value)
    }

    /// A number: a sign, digits and one point.
    fn number(&mut self, word: Option<(char, usize)>) -> Result<f64, NcError> {
        let column = self.column();
        let mut text = String::new();
        if let Some(sign @ ('+' | '-')) = self.peek() {
            text.push(sign);
            self.at += 1;
        }
        let (mut dot, mut digits) = (false, false);
        while let Some(c) = self.peek() {
            if c.is_ascii_digit() || (c == '.' && !dot) {
                dot |= c == '.';
                digits |= c.is_ascii_digit();
                text.push(c);
                self.at += 1;
            } else {
                break;
            }
        }
        if !digits {
            return Err(match word {
                Some((letter, column)) => self.error(column, format!("{letter} needs a number")),
                None => self.error(column, "a number has at least one digit"),
            });
        }
        let value = text
            .parse::<f64>()
            .map_err(|_| self.error(column, format!("{text} is not a number")))?;
        // Hundreds of digits parse to infinity: kept finite, so that the word's range check
        // names it.
        Ok(value.clamp(-f64::MAX, f64::MAX))
    }

    /// `[expression]`.
    fn expression(&mut self) -> Result<f64, NcError> {
        let open = self.column();
        self.at += 1;
        let value = self.binary(2, open)?;
        match self.peek() {
            Some(']') => {
                self.at += 1;
                Ok(value)
            }
            // `binary` stops at ']' or at the line's end; anything else is refused there.
            _ => Err(self.error(open, "the expression is not closed: ']' is missing")),
        }
    }

    /// Values joined by operators of at least `min` precedence, each level left to right.
    fn binary(&mut self, min: u8, open: usize) -> Result<f64, NcError> {
        let mut left = self.value(None)?;
        loop {
            let column = self.column();
            let Some((op, len)) = self.operator(open)? else {
                return Ok(left);
            };
            if op.precedence() < min {
                return Ok(left);
            }
            self.at += len;
            let right = self.binary(op.precedence() + 1, open)?;
            left = op.apply(left, right).map_err(|m| self.error(column, m))?;
            if !left.is_finite() {
                return Err(self.error(column, "the calculation gives infinity or not a number"));
            }
        }
    }

    /// The operator ahead and its length; `None` at the closing bracket.
    fn operator(&self, open: usize) -> Result<Option<(Op, usize)>, NcError> {
        let Some(c) = self.peek() else {
            return Err(self.error(open, "the expression is not closed: ']' is missing"));
        };
        let two: String = [c, self.peek_at(1).unwrap_or(' ')].iter().collect();
        let three: String = [c, self.peek_at(1).unwrap_or(' '), self.peek_at(2).unwrap_or(' ')]
            .iter()
            .collect();
        Ok(Some(match c {
            ']' => return Ok(None),
            '+' => (Op::Plus, 1),
            '-' => (Op::Minus, 1),
            '/' => (Op::Divide, 1),
            '*' if two == "**" => (Op::Power, 2),
            '*' => (Op::Times, 1),
            _ => match (two.as_str(), three.as_str()) {
                (_, "and") => (Op::And, 3),
                (_, "mod") => (Op::Modulo, 3),
                (_, "xor") => (Op::Xor, 3),
                ("or", _) => (Op::Or, 2),
                ("eq", _) => (Op::Eq, 2),
                ("ne", _) => (Op::Ne, 2),
                ("gt", _) => (Op::Gt, 2),
                ("ge", _) => (Op::Ge, 2),
                ("lt", _) => (Op::Lt, 2),
                ("le", _) => (Op::Le, 2),
                _ => {
                    return Err(self.error(
                        self.column(),
                        format!(
                            "'{}' is not an operator: + - * / ** MOD EQ NE GT GE LT LE AND OR XOR, or ']' to close",
                            self.chars[self.at].written
                        ),
                    ));
                }
            },
        }))
    }

    /// A function's value, its name read.
    fn function(&mut self, name: &str, column: usize) -> Result<f64, NcError> {
        if self.peek() != Some('[') {
            return Err(self.error(
                column,
                format!(
                    "{} takes its argument in brackets: {}[…]",
                    name.to_uppercase(),
                    name.to_uppercase()
                ),
            ));
        }
        if name == "exists" {
            // EXISTS[#<name>]: whether the parameter is defined.
            self.at += 1;
            let defined = if self.peek() == Some('#') && self.peek_at(1) == Some('<') {
                self.at += 1;
                let name = self.name()?;
                self.params.is_some_and(|p| p.named(&name).is_some())
            } else if self.peek() == Some('#') {
                self.at += 1;
                let index = self.value(None)?;
                (1.0..=MAX_PARAMETER as f64).contains(&index.round())
            } else {
                return Err(self.error(column, "EXISTS takes a parameter: EXISTS[#<name>]"));
            };
            if self.peek() != Some(']') {
                return Err(self.error(column, "EXISTS takes one parameter: EXISTS[#<name>]"));
            }
            self.at += 1;
            return Ok(if defined { 1.0 } else { 0.0 });
        }
        let x = self.expression()?;
        let degrees = |r: f64| r.to_degrees();
        let domain = |ok: bool, why: &str| {
            if ok {
                Ok(())
            } else {
                Err(self.error(column, format!("{}: {why}, got {x}", name.to_uppercase())))
            }
        };
        Ok(match name {
            "abs" => x.abs(),
            "acos" => {
                domain((-1.0..=1.0).contains(&x), "the argument is between -1 and 1")?;
                degrees(x.acos())
            }
            "asin" => {
                domain((-1.0..=1.0).contains(&x), "the argument is between -1 and 1")?;
                degrees(x.asin())
            }
            "atan" => {
                if self.peek() != Some('/') || self.peek_at(1) != Some('[') {
                    return Err(self.error(column, "ATAN takes two arguments: ATAN[y]/[x]"));
                }
                self.at += 1;
                let d = self.expression()?;
                degrees(x.atan2(d))
            }
            "cos" => x.to_radians().cos(),
            "exp" => x.exp(),
            "fix" => x.floor(),
            "fup" => x.ceil(),
            "ln" => {
                domain(x > 0.0, "the argument is positive")?;
                x.ln()
            }
            // Halves away from zero, as LinuxCNC's.
            "round" => x.round(),
            "sin" => x.to_radians().sin(),
            "sqrt" => {
                domain(x >= 0.0, "the argument is zero or positive")?;
                x.sqrt()
            }
            "tan" => x.to_radians().tan(),
            _ => unreachable!("FUNCTIONS lists {name}"),
        })
    }

    /// `o<label> keyword [values]`, at the `o`.
    fn control(&mut self) -> Result<Control, NcError> {
        let column = self.column();
        self.at += 1;
        let label = if self.peek() == Some('<') {
            format!("<{}>", self.name()?)
        } else {
            let at = self.column();
            let n = self.number(None).map_err(|_| {
                self.error(
                    at,
                    "an O-word's label is a number or a name in angle brackets: o100, o<drill>",
                )
            })?;
            if n < 0.0 || n.fract() != 0.0 {
                return Err(self.error(at, format!("an O-word's number is whole and positive, got {n}")));
            }
            format!("{n}")
        };
        let Some(keyword) = Keyword::ALL.iter().copied().find(|k| self.eat(k.name())) else {
            return Err(self.error(
                column,
                format!(
                    "o{label}: an O-word is followed by sub, endsub, call, return, if, elseif, else, endif, do, while, endwhile, repeat, endrepeat, break or continue (Fanuc's bare program numbers are not supported)"
                ),
            ));
        };
        let mut control = Control {
            line: self.line,
            column,
            label,
            keyword,
            values: Vec::new(),
        };
        if self.params.is_none() {
            return Ok(control);
        }
        let needs_one = matches!(
            keyword,
            Keyword::If | Keyword::ElseIf | Keyword::While | Keyword::Repeat
        );
        let takes = match keyword {
            Keyword::Call => MAX_ARGUMENTS,
            _ if needs_one => 1,
            Keyword::EndSub | Keyword::Return => 1,
            _ => 0,
        };
        loop {
            match self.peek() {
                Some('(') => self.at += 1,
                Some('[') if control.values.len() < takes => {
                    let v = self.expression()?;
                    control.values.push(v);
                }
                Some('[') => {
                    return Err(self.error(
                        self.column(),
                        format!(
                            "{} takes {}",
                            control.name(),
                            match takes {
                                0 => "no value".to_string(),
                                1 => "one value in brackets".to_string(),
                                n => format!("at most {n} arguments"),
                            }
                        ),
                    ));
                }
                Some(_) => {
                    let ch = self.chars[self.at];
                    return Err(self.error(
                        ch.column,
                        format!("unexpected character '{}' after {}", ch.written, control.name()),
                    ));
                }
                None => break,
            }
        }
        // A `while` closing a `do` has its condition too: every while needs one.
        if needs_one && control.values.is_empty() {
            return Err(self.error(
                column,
                format!(
                    "{} needs its {} in brackets",
                    control.name(),
                    if keyword == Keyword::Repeat {
                        "count"
                    } else {
                        "condition"
                    }
                ),
            ));
        }
        Ok(control)
    }
}

/// How deep values may nest in one another: brackets, signs before a bracket or parameter,
/// parameters whose number is a parameter (`##1`) and functions, counted together. LinuxCNC
/// sets no bound; programs written by hand or by CAM posts nest a few levels, and 64 levels
/// read in well under 256 KiB of stack (a test's thread has that much), far below the 2 MiB of
/// the threads that read programs.
pub const MAX_NESTING: usize = 64;

/// The highest parameter number (LinuxCNC's table has 5602 entries, from #1).
pub const MAX_PARAMETER: usize = 5601;
/// The most arguments a call passes (#1 … #30).
pub const MAX_ARGUMENTS: usize = 30;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::HashMap;

    /// Parameters for the tests: numbered ones from a map (0 when unset), named ones from another.
    #[derive(Default)]
    struct Table {
        numbered: HashMap<usize, f64>,
        named: HashMap<String, f64>,
    }

    impl Parameters for Table {
        fn numbered(&self, index: usize) -> Result<f64, String> {
            Ok(self.numbered.get(&index).copied().unwrap_or(0.0))
        }
        fn named(&self, name: &str) -> Option<f64> {
            self.named.get(name).copied()
        }
    }

    fn word(letter: char, value: f64, column: usize) -> Word {
        Word { letter, value, column }
    }

    fn read(text: &str) -> Result<Line, NcError> {
        read_line(text, 1, false, &Table::default())
    }

    /// The words of a one-line text.
    fn words(text: &str) -> Vec<Word> {
        match read(text) {
            Ok(Line::Words { block, .. }) => block.words,
            other => panic!("{text}: {other:?}"),
        }
    }

    /// The values of a one-line text's words.
    fn values(text: &str) -> Vec<(char, f64)> {
        words(text).iter().map(|w| (w.letter, w.value)).collect()
    }

    fn refused(text: &str) -> String {
        read(text).expect_err("refused").to_string()
    }

    #[test]
    fn words_comments_line_numbers_and_delimiters() {
        assert_eq!(
            words("N10 G1 x-2.5 Y+3 f 1200 (feed) ; the rest"),
            [
                word('N', 10.0, 1),
                word('G', 1.0, 5),
                word('X', -2.5, 8),
                word('Y', 3.0, 14),
                word('F', 1200.0, 18)
            ]
        );
        // Block delete off (LinuxCNC's default): the line runs without its '/'.
        assert_eq!(words("/G0 X99"), [word('G', 0.0, 2), word('X', 99.0, 5)]);
        // On: it is skipped.
        assert_eq!(read_line("/G0 X99", 1, true, &NoParameters), Ok(Line::Nothing));
        assert_eq!(read("  %  (x)"), Ok(Line::Percent));
        assert_eq!(read("(only a comment)"), Ok(Line::Nothing));
        assert_eq!(read("   "), Ok(Line::Nothing));
    }

    #[test]
    fn spaces_inside_numbers_are_ignored_as_linuxcnc_ignores_them() {
        assert_eq!(
            values("G1 X1 0.5 F1 00 Y- 2 . 5"),
            [('G', 1.0), ('X', 10.5), ('F', 100.0), ('Y', -2.5)]
        );
    }

    /// The values LinuxCNC 2.9's `rs274` computes for the same expressions (checked against it).
    #[test]
    fn expressions_are_computed_as_linuxcnc_computes_them() {
        for (text, expected) in [
            ("X[round[2.5]] Y[round[-2.5]] Z[-7 mod 3]", [3.0, -3.0, 2.0]),
            ("X[2**3**2] Y[1+2*3-4/2] Z[1 lt 2 and 3 gt 4]", [64.0, 5.0, 0.0]),
            ("X[atan[1]/[1]] Y[fix[-1.5]] Z[fup[-1.5]]", [45.0, -2.0, -1.0]),
            ("X[1 eq 1.00009] Y[1 eq 1.00011] Z[-[2]]", [1.0, 0.0, -2.0]),
            ("X[2 - 3 - 4] Y[8/2/2] Z[sqrt[16]+abs[-2]]", [-5.0, 2.0, 6.0]),
            ("X[5 mod -3] Y[1 or 0 xor 1] Z[2*-3]", [2.0, 0.0, -6.0]),
            ("X[exp[0]] Y[ln[1]] Z[acos[0]+asin[1]]", [1.0, 0.0, 180.0]),
            ("X[1 ne 2] Y[3 ge 3] Z[2 le 1]", [1.0, 1.0, 0.0]),
            ("X [ 1 + 2 ] Y[COS[60]] Z 1 0", [3.0, 0.5, 10.0]),
        ] {
            let v = values(text);
            for (i, (letter, value)) in v.iter().enumerate() {
                assert!(
                    (value - expected[i]).abs() < 1e-9,
                    "{text}: {letter} = {value}, expected {}",
                    expected[i]
                );
            }
        }
        assert!((values("X[sin[30]]")[0].1 - 0.5).abs() < 1e-12);
        assert!((values("X[tan[45]]")[0].1 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn parameters_are_read_and_set_in_parallel() {
        let mut t = Table::default();
        t.numbered.insert(1, 5.0);
        t.numbered.insert(2, 3.0);
        t.numbered.insert(3, 1.0);
        t.named.insert("depth".into(), -2.0);
        let Ok(Line::Words { block, assignments }) = read_line(
            "#2 = [#1 + 1] #<my Depth> = #<DEPTH> G1 X#1 Y##3 Z-#<depth> F#[1+1]",
            1,
            false,
            &t,
        ) else {
            panic!("words and settings")
        };
        let v: Vec<f64> = block.words.iter().map(|w| w.value).collect();
        assert_eq!(
            v,
            [1.0, 5.0, 5.0, 2.0, 3.0],
            "the settings do not change the line's own values"
        );
        assert_eq!(
            assignments,
            [
                Assignment {
                    target: Target::Numbered(2),
                    value: 6.0,
                    column: 1
                },
                Assignment {
                    target: Target::Named("mydepth".into()),
                    value: -2.0,
                    column: 15
                },
            ]
        );
        assert_eq!(values("X[exists[#<nope>]]"), [('X', 0.0)]);
        assert_eq!(
            refused("G1 X#<nope>"),
            "1:5: #<nope> is not defined: set it (#<nope> = …) before reading it"
        );
        assert_eq!(
            refused("G1 X#0"),
            "1:5: a parameter's number is a whole number from 1 to 5601, got 0"
        );
        assert_eq!(
            refused("#1.5=2"),
            "1:1: a parameter's number is a whole number from 1 to 5601, got 1.5"
        );
        assert_eq!(
            refused("#1 5"),
            "1:5: a parameter is set with '=' and a value: #1 = 5, #<depth> = [#1 / 2]"
        );
        assert_eq!(
            read_line("G1 X#1", 1, false, &NoParameters)
                .expect_err("no parameters")
                .to_string(),
            "1:5: #1 cannot be read here"
        );
    }

    #[test]
    fn o_words_are_read_with_their_values() {
        let mut t = Table::default();
        t.numbered.insert(1, 2.0);
        let control = |text: &str| match read_line(text, 7, false, &t) {
            Ok(Line::Control(c)) => c,
            other => panic!("{text}: {other:?}"),
        };
        let c = control("o100 while [#1 LT 5] (loop)");
        assert_eq!(
            (c.label.as_str(), c.keyword, c.values.as_slice()),
            ("100", Keyword::While, &[1.0][..])
        );
        assert_eq!(c.name(), "o100 while");
        let c = control("N5 O<Drill> call [1] [#1*2] [3]");
        assert_eq!(
            (c.label.as_str(), c.keyword, c.values.as_slice()),
            ("<drill>", Keyword::Call, &[1.0, 4.0, 3.0][..])
        );
        assert_eq!(control("o0100 elseif [1]").label, "100");
        assert_eq!(control("o1 else").keyword, Keyword::Else);
        assert_eq!(control("o1 endsub [#1]").values, [2.0]);
        // Looked at only: the values are not read.
        let c = control_of("o3 if [#<undefined>]", 1, false)
            .expect("read")
            .expect("a control");
        assert_eq!((c.keyword, c.values.len()), (Keyword::If, 0));
        assert_eq!(control_of("G1 X1", 1, false), Ok(None));
        for (text, message) in [
            ("o100 if", "1:1: o100 if needs its condition in brackets"),
            ("o100 repeat", "1:1: o100 repeat needs its count in brackets"),
            ("o100 else [1]", "1:11: o100 else takes no value"),
            ("o100 endif G1", "1:12: unexpected character 'G' after o100 endif"),
            (
                "o100",
                "1:1: o100: an O-word is followed by sub, endsub, call, return, if, elseif, else, endif, do, while, endwhile, repeat, endrepeat, break or continue (Fanuc's bare program numbers are not supported)",
            ),
            (
                "G1 o100 call",
                "1:4: an O-word statement (sub, call, if, while, …) stands at the start of its line",
            ),
            ("o<a call", "1:2: a name in '<' is closed by '>'"),
        ] {
            assert_eq!(refused(text), message, "{text}");
        }
    }

    #[test]
    fn what_cannot_be_read_is_refused_where_it_stands() {
        for (text, message) in [
            ("G1 X1 (open", "1:7: comment not closed: ')' is missing"),
            ("G1 X", "1:4: X needs a number"),
            ("G1 X Y1", "1:4: X needs a number"),
            ("G1 X1.2.3", "1:8: unexpected character '.'"),
            (
                "G1 X1 % ",
                "1:7: '%' stands on a line of its own (it delimits the program)",
            ),
            (
                "G1 X1/2",
                "1:6: '/' only starts a line (block delete); a division is written in brackets: [1/2]",
            ),
            ("G1 X1 !", "1:7: unexpected character '!'"),
            ("G1 @", "1:4: @ needs a number"),
            ("G1 X-", "1:4: X needs a number"),
            ("G1 X[1+2", "1:5: the expression is not closed: ']' is missing"),
            (
                "G1 X[1 & 2]",
                "1:8: '&' is not an operator: + - * / ** MOD EQ NE GT GE LT LE AND OR XOR, or ']' to close",
            ),
            ("G1 X[1/0]", "1:7: division by zero"),
            ("G1 X[sqrt[-1]]", "1:6: SQRT: the argument is zero or positive, got -1"),
            ("G1 X[ln[0]]", "1:6: LN: the argument is positive, got 0"),
            ("G1 X[acos[2]]", "1:6: ACOS: the argument is between -1 and 1, got 2"),
            ("G1 X[atan[1]]", "1:6: ATAN takes two arguments: ATAN[y]/[x]"),
            ("G1 X[sin 30]", "1:6: SIN takes its argument in brackets: SIN[…]"),
            (
                "G1 X[[-8]**0.5]",
                "1:10: a negative number raised to a power that is not whole",
            ),
            ("G1 X[10**400]", "1:8: the calculation gives infinity or not a number"),
            (
                "G1 X[1e3]",
                "1:7: 'e' is not an operator: + - * / ** MOD EQ NE GT GE LT LE AND OR XOR, or ']' to close",
            ),
            (
                "G1 X[10**10]",
                "1:4: X: the number is out of range (at most 1e9 in magnitude)",
            ),
        ] {
            assert_eq!(refused(text), message, "{text}");
        }
        let huge = format!("G1 X1{} F100", "9".repeat(400));
        assert_eq!(
            refused(&huge),
            "1:4: X: the number is out of range (at most 1e9 in magnitude)"
        );
    }

    #[test]
    fn values_nest_up_to_the_bound_and_are_refused_beyond_it_where_they_cross_it() {
        // X's value is the first level, each bracket one more.
        let brackets = |k: usize| format!("G1 X{}1{} F100", "[".repeat(k), "]".repeat(k));
        assert_eq!(values(&brackets(MAX_NESTING - 1))[1], ('X', 1.0));
        let refusal = format!(
            "the value nests deeper than {MAX_NESTING} levels (brackets, signs, parameters of parameters and functions, counted together): write it in steps with parameters"
        );
        // The level past the bound starts inside the 64th bracket: column 4 + 64 + 1.
        assert_eq!(refused(&brackets(MAX_NESTING)), format!("1:69: {refusal}"));
        // What aborted the process before (a stack overflow), refused the same way.
        assert_eq!(refused(&brackets(16_000)), format!("1:69: {refusal}"));
        let signs = format!("G1 X{}[1]", "-".repeat(32_000));
        assert_eq!(refused(&signs), format!("1:69: {refusal}"));
        let indirect = format!("#1 = {}1", "#".repeat(10_000));
        assert_eq!(refused(&indirect), format!("1:70: {refusal}"));
        let functions = format!("G1 X[{}0{}]", "abs[".repeat(5_000), "]".repeat(5_000));
        assert!(refused(&functions).ends_with(&refusal), "{}", refused(&functions));
        // In O-word values too.
        let condition = format!("o1 if [{}1{}]", "[".repeat(200), "]".repeat(200));
        assert!(refused(&condition).ends_with(&refusal));
    }

    proptest! {
        /// Any finite number written with up to 6 decimals reads back to the same value, at any
        /// case and spacing.
        #[test]
        fn numbers_read_back(value in -1e6f64..1e6, decimals in 0usize..6, lower: bool, space: bool) {
            let text = format!("{:.*}", decimals, value);
            let letter = if lower { "x" } else { "X" };
            let line = format!("{letter}{}{text}", if space { " " } else { "" });
            let v = values(&line);
            prop_assert_eq!(v[0], ('X', text.parse::<f64>().expect("a number")));
        }

        /// Any line of the characters programs are made of is read or refused with a column
        /// inside it (or just past its end); nothing panics.
        #[test]
        fn any_line_is_read_or_refused(line in "[gGxXoO#<>=\\[\\]()+\\-*/.0-9 a-z%;]{0,40}") {
            if let Err(e) = read(&line) {
                prop_assert_eq!(e.line, 1);
                prop_assert!(e.column >= 1 && e.column <= line.chars().count() + 1, "{}: {}", line, e);
            }
        }

        /// An expression of sums and products of small whole numbers has the value Rust computes
        /// with the usual precedence.
        #[test]
        fn sums_and_products_follow_precedence(a in -50i32..50, b in -50i32..50, c in -50i32..50, d in 1i32..50) {
            let text = format!("X[{a} + {b} * {c} - {a} / {d}]");
            let expected = f64::from(a) + f64::from(b) * f64::from(c) - f64::from(a) / f64::from(d);
            let v = values(&text)[0].1;
            prop_assert!((v - expected).abs() < 1e-9, "{} = {} not {}", text, v, expected);
        }
    }
}
