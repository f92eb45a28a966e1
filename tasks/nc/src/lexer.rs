//! A program's text as words with their positions.
//!
//! RS274NGC as LinuxCNC reads it, in the subset of motion.md: a line holds words — a letter
//! (either case) and a number (`G1`, `x-2.5`, `F 1200`; spaces are allowed anywhere in a word,
//! `X1 0.5` is 10.5, as LinuxCNC ignores them) —, comments in parentheses and after `;`, and may
//! start with `/` (block delete: the line is skipped while the block-delete switch is on, run
//! while it is off, LinuxCNC's default) or be a `%` delimiter. What the subset does not have is refused here, where it
//! stands: parameters `#…`, expressions `[…]`, O-words (subroutines, loops, conditionals) and any
//! other character.

use crate::NcError;

/// A letter and its number, where it starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Word {
    /// The letter, upper case.
    pub letter: char,
    /// The number.
    pub value: f64,
    /// The letter's column (1-based, in characters).
    pub column: usize,
}

/// A line of the program that holds words.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// The line (1-based).
    pub line: usize,
    /// Its words, in order.
    pub words: Vec<Word>,
}

/// The blocks of `text`: its lines with words, in order, the block-delete switch off (lines with
/// only comments, blank lines and `%` delimiters have none and are left out). A UTF-8 byte order
/// mark (Windows editors write one) is not part of the program.
pub fn lex(text: &str) -> Result<Vec<Block>, NcError> {
    lines(text, false)
        .filter_map(|l| match l {
            Ok(Line::Words(b)) => Some(Ok(b)),
            Ok(_) => None,
            Err(e) => Some(Err(e)),
        })
        .collect()
}

/// A line of a program as the interpreter takes it.
#[derive(Clone, Debug, PartialEq)]
pub enum Line {
    /// A line with words.
    Words(Block),
    /// A `%` delimiter (its line).
    Percent(usize),
    /// A line with only comments, or one the block-delete switch skips.
    Nothing,
}

/// The lines of `text` one at a time (blank lines are left out): a program of a million lines
/// is read without holding the words of all its lines at once, and what follows its end is never
/// read. `block_delete`: the block-delete switch, on (lines starting with `/` are skipped) or off
/// (they run, the `/` ignored).
pub fn lines(text: &str, block_delete: bool) -> impl Iterator<Item = Result<Line, NcError>> + '_ {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.lines().enumerate().filter_map(move |(i, line)| {
        if line.trim().is_empty() {
            return None;
        }
        Some(lex_line(line, i + 1, block_delete).map(|l| match l {
            Lexed::Words(words) if words.is_empty() => Line::Nothing,
            Lexed::Words(words) => Line::Words(Block { line: i + 1, words }),
            Lexed::Percent => Line::Percent(i + 1),
            Lexed::Deleted => Line::Nothing,
        }))
    })
}

/// What one line holds.
enum Lexed {
    Words(Vec<Word>),
    Percent,
    Deleted,
}

/// The words of one line.
fn lex_line(line: &str, number: usize, block_delete: bool) -> Result<Lexed, NcError> {
    let chars: Vec<char> = line.chars().collect();
    let err = |column: usize, message: String| Err(NcError::new(number, column, message));
    let mut words = Vec::new();
    let mut i = 0;
    let skip_blanks = |i: &mut usize| {
        while *i < chars.len() && chars[*i].is_whitespace() {
            *i += 1;
        }
    };
    skip_blanks(&mut i);
    // Block delete: with the switch on the line is skipped; off, it runs without its '/'.
    if chars.get(i) == Some(&'/') {
        if block_delete {
            return Ok(Lexed::Deleted);
        }
        i += 1;
    }
    if chars[i..].first() == Some(&'%') {
        if chars[i + 1..].iter().all(|c| c.is_whitespace()) {
            return Ok(Lexed::Percent);
        }
        return err(
            i + 1,
            "'%' stands on a line of its own (it delimits the program)".into(),
        );
    }
    while i < chars.len() {
        let c = chars[i];
        let column = i + 1;
        match c {
            c if c.is_whitespace() => i += 1,
            '(' => match chars[i + 1..].iter().position(|c| *c == ')') {
                Some(end) => i += end + 2,
                None => return err(column, "comment not closed: ')' is missing".into()),
            },
            ';' => break,
            '%' => {
                return err(
                    column,
                    "'%' stands on a line of its own (it delimits the program)".into(),
                );
            }
            '#' => return err(column, "parameters (#) are not supported: write the number".into()),
            '[' => return err(column, "expressions ([…]) are not supported: write the number".into()),
            '/' => {
                return err(
                    column,
                    "'/' only starts a line (block delete); expressions are not supported".into(),
                );
            }
            'o' | 'O' => {
                return err(
                    column,
                    "O-words (subroutines, loops, conditionals) are not supported".into(),
                );
            }
            c if c.is_ascii_alphabetic() => {
                let letter = c.to_ascii_uppercase();
                i += 1;
                skip_blanks(&mut i);
                let start = i;
                let mut text = String::new();
                if let Some(sign @ ('+' | '-')) = chars.get(i) {
                    text.push(*sign);
                    i += 1;
                    skip_blanks(&mut i);
                }
                let mut dot = false;
                let mut has_digit = false;
                // Digits and a point, spaces between them ignored (`X1 0.5` is 10.5).
                while i < chars.len() {
                    let c = chars[i];
                    if c.is_ascii_digit() || (c == '.' && !dot) {
                        dot |= c == '.';
                        has_digit |= c.is_ascii_digit();
                        text.push(c);
                        i += 1;
                    } else if c.is_whitespace()
                        && !text.is_empty()
                        && chars[i..]
                            .iter()
                            .find(|c| !c.is_whitespace())
                            .is_some_and(|n| n.is_ascii_digit() || (*n == '.' && !dot))
                    {
                        i += 1;
                    } else {
                        break;
                    }
                }
                match chars.get(start) {
                    Some('#') => {
                        return err(start + 1, "parameters (#) are not supported: write the number".into());
                    }
                    Some('[') => {
                        return err(
                            start + 1,
                            "expressions ([…]) are not supported: write the number".into(),
                        );
                    }
                    _ => {}
                }
                if !has_digit {
                    return err(column, format!("{letter} needs a number"));
                }
                let value = text
                    .parse::<f64>()
                    .map_err(|_| NcError::new(number, column, format!("{letter}{text} is not a number")))?;
                // A number of hundreds of digits parses to infinity (or to a value no machine
                // can mean): refused where it is written.
                if !(value.is_finite() && value.abs() <= MAX_NUMBER) {
                    return err(
                        column,
                        format!("{letter}: the number is out of range (at most {MAX_NUMBER:e} in magnitude)"),
                    );
                }
                words.push(Word { letter, value, column });
            }
            other => return err(column, format!("unexpected character '{other}'")),
        }
    }
    Ok(Lexed::Words(words))
}

/// The largest magnitude of a number in a program: far beyond any coordinate, feed or speed a
/// machine can mean, far below where a float loses whole units.
pub const MAX_NUMBER: f64 = 1e9;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn word(letter: char, value: f64, column: usize) -> Word {
        Word { letter, value, column }
    }

    #[test]
    fn words_comments_line_numbers_and_delimiters() {
        let text = "%\n(a program)\nN10 G1 x-2.5 Y+3 f 1200 (feed) ; the rest\n/G0 X99\n\n  g2x.5 I-1.25\n%\n";
        let blocks = lex(text).expect("lexes");
        assert_eq!(
            blocks,
            [
                Block {
                    line: 3,
                    words: vec![
                        word('N', 10.0, 1),
                        word('G', 1.0, 5),
                        word('X', -2.5, 8),
                        word('Y', 3.0, 14),
                        word('F', 1200.0, 18)
                    ]
                },
                // Block delete off (LinuxCNC's default): the line runs without its '/'.
                Block {
                    line: 4,
                    words: vec![word('G', 0.0, 2), word('X', 99.0, 5)]
                },
                Block {
                    line: 6,
                    words: vec![word('G', 2.0, 3), word('X', 0.5, 5), word('I', -1.25, 9)]
                },
            ]
        );
        // Block delete on: it is skipped.
        let on: Vec<Line> = lines(text, true).collect::<Result<_, _>>().expect("lexes");
        assert_eq!(on[0], Line::Percent(1));
        assert_eq!(on[3], Line::Nothing);
        assert_eq!(on[5], Line::Percent(7));
    }

    #[test]
    fn spaces_inside_numbers_are_ignored_as_linuxcnc_ignores_them() {
        let blocks = lex("G1 X1 0.5 F1 00 Y- 2 . 5").expect("lexes");
        let values: Vec<(char, f64)> = blocks[0].words.iter().map(|w| (w.letter, w.value)).collect();
        assert_eq!(values, [('G', 1.0), ('X', 10.5), ('F', 100.0), ('Y', -2.5)]);
    }

    #[test]
    fn what_the_subset_lacks_is_refused_where_it_stands() {
        let refused = |text: &str| lex(text).expect_err("refused").to_string();
        assert_eq!(
            refused("G1 X#1"),
            "1:5: parameters (#) are not supported: write the number"
        );
        assert_eq!(
            refused("#1=5"),
            "1:1: parameters (#) are not supported: write the number"
        );
        assert_eq!(
            refused("G1 X[1+2]"),
            "1:5: expressions ([…]) are not supported: write the number"
        );
        assert_eq!(
            refused("o100 sub"),
            "1:1: O-words (subroutines, loops, conditionals) are not supported"
        );
        assert_eq!(refused("G1\nG1 X1 (open"), "2:7: comment not closed: ')' is missing");
        assert_eq!(refused("G1 X"), "1:4: X needs a number");
        assert_eq!(refused("G1 X1.2.3"), "1:8: unexpected character '.'");
        assert_eq!(
            refused("G1 X1 % "),
            "1:7: '%' stands on a line of its own (it delimits the program)"
        );
        assert_eq!(
            refused("G1 X1/2"),
            "1:6: '/' only starts a line (block delete); expressions are not supported"
        );
        assert_eq!(refused("G1 X1 @"), "1:7: unexpected character '@'");
        assert_eq!(refused("G1 X-"), "1:4: X needs a number");
    }

    proptest! {
        /// Any finite number written with up to 6 decimals reads back to the same value, at any
        /// case and spacing.
        #[test]
        fn numbers_read_back(value in -1e6f64..1e6, decimals in 0usize..6, lower: bool, space: bool) {
            let text = format!("{:.*}", decimals, value);
            let letter = if lower { "x" } else { "X" };
            let line = format!("{letter}{}{text}", if space { " " } else { "" });
            let blocks = lex(&line).expect("lexes");
            prop_assert_eq!(blocks[0].words[0].letter, 'X');
            prop_assert_eq!(blocks[0].words[0].value, text.parse::<f64>().expect("a number"));
        }
    }
}
