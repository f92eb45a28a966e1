//! M62 … M68: the program's digital and analog outputs, set with the next move's start (M62,
//! M63, M67) or at once with the tool standing (M64, M65, M68), and M66, which waits on a
//! digital input — as LinuxCNC's, with its defaults of four digital outputs and inputs and (here)
//! two analog outputs.

use crate::NcError;
use crate::lexer::Word;

use super::block::{ANALOG_OUTPUTS, Action, Block, DIGITAL_INPUTS, DIGITAL_OUTPUTS, Output, WaitMode};
use super::state::State;
use super::words::{Words, format_code};

impl State<'_> {
    /// The block's M62 … M68 (one a block: a modal group), made before its motion, as LinuxCNC
    /// orders them.
    pub(super) fn io(&self, words: &Words<'_>, out: &mut Vec<Block>) -> Result<(), NcError> {
        let line = words.line;
        for (code, m) in &words.m {
            if matches!(code, 620..=680) {
                self.refuse_while_compensating(line, m, "the program's outputs and inputs (M62 … M68) cannot be used")?;
            }
            let action = match code {
                620 | 630 | 640 | 650 => {
                    let index = number(
                        line,
                        words.get('P'),
                        m,
                        *code,
                        DIGITAL_OUTPUTS,
                        "P",
                        "digital output",
                        "NC_DOUT",
                    )?;
                    Action::Output {
                        output: Output::Digital {
                            index,
                            on: matches!(code, 620 | 640),
                        },
                        synced: matches!(code, 620 | 630),
                    }
                }
                670 | 680 => {
                    let index = number(
                        line,
                        words.get('E'),
                        m,
                        *code,
                        ANALOG_OUTPUTS,
                        "E",
                        "analog output",
                        "NC_AOUT",
                    )?;
                    let Some(q) = words.get('Q') else {
                        return Err(NcError::new(
                            line,
                            m.column,
                            format!("{} needs Q: the output's value", format_code('M', *code)),
                        ));
                    };
                    Action::Output {
                        output: Output::Analog { index, value: q.value },
                        synced: *code == 670,
                    }
                }
                660 => self.wait(words, m)?,
                _ => continue,
            };
            out.push(Block {
                line,
                column: 1,
                action,
            });
        }
        Ok(())
    }

    /// M66: its input (P), its mode (L) and its timeout (Q), checked as LinuxCNC checks them.
    fn wait(&self, words: &Words<'_>, m: &Word) -> Result<Action, NcError> {
        let line = words.line;
        let at = |w: &Word, message: &str| NcError::new(line, w.column, message.to_string());
        const MODES: [WaitMode; 5] = [
            WaitMode::Immediate,
            WaitMode::Rise,
            WaitMode::Fall,
            WaitMode::High,
            WaitMode::Low,
        ];
        let mode = match words.get('L') {
            None => WaitMode::Immediate,
            Some(l) if l.value.fract() == 0.0 && (0.0..5.0).contains(&l.value) => MODES[l.value as usize],
            Some(l) => {
                return Err(at(
                    l,
                    "M66 L is the wait's mode: 0 (none), 1 (the input rises), 2 (falls), 3 (is on), 4 (is off)",
                ));
            }
        };
        if let Some(e) = words.get('E') {
            return Err(at(
                e,
                if mode == WaitMode::Immediate {
                    "M66 E: programs have no analog inputs here; the digital ones are P0 … P3 (NC_DIN_0 … NC_DIN_3)"
                } else {
                    "M66 E waits on no analog input (L1 … L4 are for digital inputs, P), as in LinuxCNC"
                },
            ));
        }
        let input = number(
            line,
            words.get('P'),
            m,
            660,
            DIGITAL_INPUTS,
            "P",
            "digital input",
            "NC_DIN",
        )?;
        let timeout_s = words.get('Q').map_or(0.0, |q| q.value);
        if mode != WaitMode::Immediate && timeout_s <= 0.0 {
            return Err(at(
                words.get('Q').unwrap_or(m),
                "M66 L1 … L4 needs Q: the longest wait in seconds, more than 0 (then the program goes on)",
            ));
        }
        Ok(Action::Wait { input, mode, timeout_s })
    }
}

/// The number `word` gives (P or E, `letter`) of one of `count` inputs or outputs (`what`,
/// variables `var_0` …), checked.
#[allow(clippy::too_many_arguments)]
fn number(
    line: usize,
    word: Option<&Word>,
    m: &Word,
    code: u16,
    count: u8,
    letter: &str,
    what: &str,
    var: &str,
) -> Result<u8, NcError> {
    let name = format_code('M', code);
    let last = count - 1;
    let Some(w) = word else {
        return Err(NcError::new(
            line,
            m.column,
            format!("{name} needs {letter}: the {what} (0 … {last}, {var}_0 … {var}_{last})"),
        ));
    };
    if w.value.fract() != 0.0 || !(0.0..f64::from(count)).contains(&w.value) {
        return Err(NcError::new(
            line,
            w.column,
            format!(
                "{name} {letter}{}: the {what}s are {letter}0 … {letter}{last} ({var}_0 … {var}_{last})",
                w.value
            ),
        ));
    }
    Ok(w.value as u8)
}
