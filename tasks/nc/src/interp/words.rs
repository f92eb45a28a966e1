//! Reading a block's words: the G and M codes by their modal groups (one per group, each at most
//! once), the value letters (each at most once), and everything the subset lacks refused with
//! its column — then whether each value belongs to what the block does.

use crate::NcError;
use crate::lexer::{self, Word};

use super::block::{AXES, Machine};

/// A block's words, sorted: its G codes and M codes (in tenths: G64.1 is 641) with their words,
/// and the word of each value letter.
pub(super) struct Words<'b> {
    /// The block's line.
    pub line: usize,
    /// The G codes, in the block's order.
    pub g: Vec<(u16, &'b Word)>,
    /// The M codes, in the block's order.
    pub m: Vec<(u16, &'b Word)>,
    /// The word of each letter A … Z that carries a value.
    values: [Option<&'b Word>; 26],
    /// The polar coordinates' words: the distance (@) and the angle (^).
    polar: [Option<&'b Word>; 2],
    /// The block's first word (where an error about the whole block points).
    pub first: &'b Word,
}

impl<'b> Words<'b> {
    /// Sorts the words of `block`, refusing what the subset lacks and what a block may not hold
    /// twice.
    pub fn sort(block: &'b lexer::Block) -> Result<Words<'b>, NcError> {
        let line = block.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let mut g: Vec<(u16, &Word)> = Vec::new();
        let mut m: Vec<(u16, &Word)> = Vec::new();
        let mut values: [Option<&Word>; 26] = [None; 26];
        let mut polar: [Option<&Word>; 2] = [None; 2];
        for (i, w) in block.words.iter().enumerate() {
            match w.letter {
                'G' | 'M' => {
                    let tenths = w.value * 10.0;
                    if !(0.0..=9999.0).contains(&tenths) || (tenths - tenths.round()).abs() > 1e-6 {
                        return Err(at(w, format!("{}{} is not a code", w.letter, w.value)));
                    }
                    let code = tenths.round() as u16;
                    if w.letter == 'G' {
                        let group = g_group(code).ok_or_else(|| at(w, g_refusal(code)))?;
                        if let Some((other, _)) = g.iter().find(|(c, _)| g_group(*c) == Some(group) && group != 0) {
                            return Err(at(
                                w,
                                format!(
                                    "{} and {} are in one modal group: a block holds one of them",
                                    format_code('G', *other),
                                    format_code('G', code)
                                ),
                            ));
                        }
                        if g.iter().any(|(c, _)| *c == code) {
                            return Err(at(w, format!("{} twice in one block", format_code('G', code))));
                        }
                        g.push((code, w));
                    } else {
                        let group = match m_group(code) {
                            Some(group) => group,
                            None => {
                                let why = match code {
                                    480..=530 => " (overrides)",
                                    600..=990 => " (subprograms, user codes)",
                                    1000..=1999 => " (user-defined M codes)",
                                    _ => "",
                                };
                                return Err(at(w, format!("{} is not supported{why}", format_code('M', code))));
                            }
                        };
                        if let Some((other, _)) = m.iter().find(|(c, _)| m_group(*c) == Some(group)) {
                            return Err(at(
                                w,
                                format!(
                                    "{} and {} are in one modal group: a block holds one of them",
                                    format_code('M', *other),
                                    format_code('M', code)
                                ),
                            ));
                        }
                        m.push((code, w));
                    }
                }
                'N' => {
                    if i != 0 {
                        return Err(at(w, "a line number (N) comes first in its block".into()));
                    }
                }
                'X' | 'Y' | 'Z' | 'A' | 'B' | 'C' | 'D' | 'E' | 'I' | 'J' | 'K' | 'R' | 'F' | 'S' | 'P' | 'Q' | 'L'
                | 'T' | 'H' => {
                    let slot = &mut values[(w.letter as u8 - b'A') as usize];
                    if slot.is_some() {
                        return Err(at(w, format!("{} twice in one block", w.letter)));
                    }
                    *slot = Some(w);
                }
                '@' | '^' => {
                    let slot = &mut polar[usize::from(w.letter == '^')];
                    if slot.is_some() {
                        return Err(at(w, format!("{} twice in one block", w.letter)));
                    }
                    *slot = Some(w);
                }
                'U' | 'V' | 'W' => {
                    return Err(at(w, format!("{}: axes U V W are not supported", w.letter)));
                }
                other => return Err(at(w, format!("{other} is not a word of RS274NGC"))),
            }
        }
        Ok(Words {
            line,
            g,
            m,
            values,
            polar,
            first: &block.words[0],
        })
    }

    /// The polar coordinates' words: the distance (@) and the angle (^), where the block has
    /// them.
    pub fn polar(&self) -> [Option<&'b Word>; 2] {
        self.polar
    }

    /// The word of value letter `letter`, if the block has it.
    pub fn get(&self, letter: char) -> Option<&'b Word> {
        self.values[(letter as u8 - b'A') as usize]
    }

    /// Whether the block holds M code `code` (tenths).
    pub fn has_m(&self, code: u16) -> bool {
        self.m.iter().any(|(c, _)| *c == code)
    }

    /// Whether the block holds G code `code` (tenths).
    pub fn has_g(&self, code: u16) -> bool {
        self.g.iter().any(|(c, _)| *c == code)
    }

    /// The word of G code `code` (tenths), if the block holds it.
    pub fn g_word(&self, code: u16) -> Option<&'b Word> {
        self.g.iter().find(|(c, _)| *c == code).map(|(_, w)| *w)
    }

    /// Whether a code takes the block's axis words (G10, G28, G30, G43.1, G52, G92), so that the
    /// motion mode makes no move with them.
    pub fn uses_axis_words(&self) -> bool {
        self.axis_word_taker().is_some()
    }

    /// The code that takes the block's axis words (G10, G28, G30, G43.1, G52, G92), if any.
    pub fn axis_word_taker(&self) -> Option<u16> {
        self.g
            .iter()
            .map(|(c, _)| *c)
            .find(|c| matches!(c, 100 | 280 | 300 | 431 | 520 | 920))
    }

    /// The block's motion code (G0 G1 G2 G3, a canned cycle) with its word, if it has one.
    pub fn motion_word(&self) -> Option<(u16, &'b Word)> {
        self.g
            .iter()
            .find(|(c, _)| matches!(c, 0 | 10 | 20 | 30 | 50 | 51) || is_cycle(*c))
            .map(|(c, w)| (*c, *w))
    }

    /// The axis words (X Y Z A B C) with their coordinate's index, in pose order.
    pub fn axis_words(&self) -> Vec<(usize, &'b Word)> {
        AXES.iter()
            .enumerate()
            .filter_map(|(c, l)| self.get(*l).map(|w| (c, w)))
            .collect()
    }

    /// Refuses an axis word of a coordinate `machine` does not have.
    pub fn check_axes(&self, machine: &Machine<'_>) -> Result<(), NcError> {
        let line = self.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        for (c, letter) in AXES.iter().enumerate() {
            if let Some(w) = self.get(*letter)
                && !machine
                    .axes
                    .get(c)
                    .is_some_and(|k| k.eq_ignore_ascii_case(&letter.to_string()))
            {
                let axes: Vec<String> = machine.axes.iter().map(|a| a.to_uppercase()).collect();
                return Err(at(w, format!("{letter}: this machine's axes are {}", axes.join(" "))));
            }
        }
        Ok(())
    }

    /// Refuses a value that does not belong to what the block does: P to G4, G64, an arc or G82;
    /// Q to G64 or G83; I, J, K to an arc; R to an arc or a canned cycle, L to a canned cycle or
    /// G10.
    /// `motion` is the motion the block makes, if any.
    pub fn check_owners(&self, motion: Option<u16>) -> Result<(), NcError> {
        let line = self.line;
        let at = |w: &Word, message: String| NcError::new(line, w.column, message);
        let arc_now = matches!(motion, Some(20 | 30));
        // A spline's I J (G5, G5.1) and P Q (G5) are its control points' offsets.
        let spline_now = matches!(motion, Some(50 | 51));
        let cycle_now = motion.is_some_and(is_cycle);
        // The program's inputs and outputs: P the digital one (M62 … M66), E the analog one
        // (M66 … M68), Q the value (M67, M68) or the timeout (M66), L the wait's mode (M66).
        let digital_io = [620, 630, 640, 650, 660].iter().any(|c| self.has_m(*c));
        let analog_io = [660, 670, 680].iter().any(|c| self.has_m(*c));
        if let Some(w) = self.get('P')
            && !(self.has_g(40)
                || self.has_g(100)
                || self.has_g(640)
                || arc_now
                || digital_io
                || matches!(motion, Some(50 | 820 | 890)))
        {
            return Err(at(
                w,
                "P belongs to G4 (dwell), G10 (the coordinate system), G64 (tolerance), an arc (turns), G5 (a control point), G82, G89 (dwell) or M62 … M66 (a digital input or output)"
                    .into(),
            ));
        }
        if let Some(w) = self.get('Q')
            && !(self.has_g(640)
                || self.has_g(100)
                || self.has_m(610)
                || analog_io
                || matches!(motion, Some(50 | 730 | 830)))
        {
            return Err(at(
                w,
                "Q belongs to G64 (merging lines within it), G73, G83 (the peck depth), G5 (a control point), M61 (the tool), M66 (a timeout), M67, M68 (a value) or G10 L1 (a lathe tool's orientation)".into(),
            ));
        }
        if let Some(w) = self.get('E')
            && !analog_io
        {
            return Err(at(
                w,
                "E belongs to M66 (an analog input), M67, M68 (an analog output); extruders are not supported".into(),
            ));
        }
        if let Some(w) = self.get('D')
            && ![410, 411, 420, 421].iter().any(|c| self.has_g(*c))
        {
            return Err(at(
                w,
                "D belongs to G41, G42 (the tool whose diameter cutter compensation takes) or G41.1, G42.1 (the diameter)".into(),
            ));
        }
        if let Some(w) = self.get('H')
            && !self.has_g(430)
        {
            return Err(at(w, "H belongs to G43 (the tool whose offsets apply)".into()));
        }
        for letter in ['I', 'J', 'K'] {
            if let Some(w) = self.get(letter)
                && !(arc_now || (spline_now && letter != 'K'))
            {
                return Err(at(
                    w,
                    format!("{letter} belongs to an arc (G2, G3) or a spline (G5, G5.1)"),
                ));
            }
        }
        // With G10, R (a rotation) is refused there, with its reason.
        if let Some(w) = self.get('R')
            && !(arc_now || cycle_now || self.has_g(100))
        {
            return Err(at(
                w,
                "R belongs to an arc (G2, G3) or a canned cycle (G73, G81 … G89)".into(),
            ));
        }
        if let Some(w) = self.get('L')
            && !(cycle_now || self.has_g(100) || self.has_m(660))
        {
            return Err(at(
                w,
                "L belongs to a canned cycle (its repeats), G10 (L2, L20) or M66 (the wait's mode)".into(),
            ));
        }
        Ok(())
    }
}

/// The modal groups of the supported G codes (RS274NGC's numbering), for the one-per-group rule.
pub(super) fn g_group(code: u16) -> Option<u8> {
    match code {
        0 | 10 | 20 | 30 | 50 | 51 | 800 => Some(1),
        c if is_cycle(c) => Some(1),
        40 => Some(0),
        170 | 180 | 190 => Some(2),
        200 | 210 => Some(6),
        530 => Some(0),
        // Going home, storing a home, and G52/G92's offset: non-modal, one of them a block.
        100 | 280 | 281 | 300 | 301 | 520 | 920 | 921 | 922 | 923 => Some(14),
        540..=590 => Some(12),
        610 | 611 | 640 => Some(13),
        900 | 910 => Some(3),
        901 | 911 => Some(4),
        930 | 940 | 950 => Some(5),
        400 | 410 | 411 | 420 | 421 => Some(7),
        430 | 431 | 490 => Some(8),
        980 | 990 => Some(10),
        _ => None,
    }
}

/// The modal groups of the supported M codes (RS274NGC's numbering): stops, the spindle, the
/// tool change, the coolant.
fn m_group(code: u16) -> Option<u8> {
    match code {
        0 | 10 | 20 | 300 => Some(4),
        30 | 40 | 50 => Some(7),
        60 | 610 => Some(6),
        70 | 80 | 90 => Some(8),
        // The program's inputs and outputs (LinuxCNC's group 5): one a block.
        620 | 630 | 640 | 650 | 660 | 670 | 680 => Some(5),
        _ => None,
    }
}

/// Whether G code `code` (tenths) is one of the canned cycles: G73, G81, G82, G83, G85, G89.
pub(super) fn is_cycle(code: u16) -> bool {
    matches!(code, 730 | 810 | 820 | 830 | 850 | 890)
}

/// Why a G code is not in the subset.
pub(super) fn g_refusal(code: u16) -> String {
    let name = format_code('G', code);
    let why = match code {
        52 | 53 => "NURBS blocks: a CAM program can write them as cubic splines (G5) or as lines and arcs",
        70 | 80 => "lathe diameter and radius modes",
        500 | 510 => "scaling",
        110 => "G11 (retraction)",
        282..=299 | 302..=309 => "G28 and G30 variants other than G28.1, G30.1",
        330 | 331 | 760 => "threading",
        382..=385 => "probing",
        432 => "adding tool offsets",
        430..=499 => "tool length compensation other than G43, G43.1, G49",
        730..=899 => "canned cycles other than G73, G81, G82, G83, G85, G89",
        960 | 970 => "spindle speed modes",
        _ => "",
    };
    if why.is_empty() {
        format!("{name} is not supported")
    } else {
        format!("{name} is not supported ({why})")
    }
}

/// A word that counts (an arc's turns, a cycle's repeats): a whole number from 1 to `max`, 1
/// where the block has none; the word when it is not such a number.
pub(super) fn count(word: Option<&Word>, max: u32) -> Result<u32, &Word> {
    match word {
        None => Ok(1),
        Some(w) if w.value >= 1.0 && w.value.fract() == 0.0 && w.value <= f64::from(max) => Ok(w.value as u32),
        Some(w) => Err(w),
    }
}

/// `G1`, `G64`, `G92.1` from a code in tenths.
pub(super) fn format_code(letter: char, code: u16) -> String {
    if code.is_multiple_of(10) {
        format!("{letter}{}", code / 10)
    } else {
        format!("{letter}{}.{}", code / 10, code % 10)
    }
}
