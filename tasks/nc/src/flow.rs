//! The order a program's lines run in, and its parameters: O-word subroutines (`sub`, `endsub`,
//! `call`, `return`), conditionals (`if`, `elseif`, `else`, `endif`) and loops (`while`,
//! `do` … `while`, `repeat`, `break`, `continue`), as LinuxCNC 2.9 runs them.
//!
//! Lines are read one at a time, when they run (a loop reads its lines again; what follows the
//! program's end is never read): a program of a million lines is not held as words. A line
//! skipped over (a branch not taken, a subroutine's body where it is defined) is only looked at
//! for its O-word, as LinuxCNC skips it.
//!
//! Parameters: `#1` … `#30` are a call's arguments, the caller's are back after the call;
//! `#31` … `#5000` are the program's; from `#5001` on they describe the machine's state and are
//! read-only (the interpreter gives the ones it keeps, [`System`]). A named parameter
//! (`#<depth>`) belongs to the subroutine (or main program) that sets it; one whose name starts
//! with `_` is global. Reading a named parameter before it is set is refused, as LinuxCNC does.

use std::collections::HashMap;

use crate::NcError;
use crate::lexer::{self, Assignment, Control, Keyword, Line, MAX_ARGUMENTS, Parameters, Target};
use crate::watch::{Unwatched, Watch, Watched};

/// The interpreter's state as parameters (`#5220`, `#5420`, `#<_x>`, …).
pub trait System {
    /// The value of system parameter `#index` (from 5001), `None` for one it does not keep.
    fn numbered(&self, index: usize) -> Option<f64>;
    /// Why system parameter `#index` cannot be read now, where it cannot.
    fn refusal(&self, _index: usize) -> Option<&'static str> {
        None
    }
    /// The value of the predefined named parameter `#<name>` (`_x`, `_feed`, …), `None` if
    /// there is none of that name.
    fn named(&self, name: &str) -> Option<f64>;
}

/// The highest parameter a program may set.
pub const MAX_USER_PARAMETER: usize = 5000;
/// How deep calls nest (LinuxCNC's limit).
pub const MAX_CALL_DEPTH: usize = 10;
/// How many conditionals and loops may be open at once in one call (or the main program): a
/// bound of the interpreter's memory that no program written by hand or by a CAM post
/// approaches (LinuxCNC has none; its own examples nest three or four).
pub const MAX_OPEN: usize = 64;
/// The most lines a program may read, loops and skipped lines included: a loop that never ends
/// is refused instead of read for ever.
pub const MAX_LINES_READ: u64 = 20_000_000;

/// What the next line that does something holds.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A line's words, their values computed; its parameter settings are made.
    Block(lexer::Block),
    /// A `%` delimiter on this line.
    Percent(usize),
    /// The text has no more lines; the last one that held anything.
    End(usize),
}

/// A running program's position, open statements and parameters.
pub struct Flow<'t> {
    text: &'t str,
    /// Where each line starts (byte offset).
    starts: Vec<usize>,
    /// The line read next (0-based).
    next: usize,
    /// The last line that held anything (1-based).
    last: usize,
    block_delete: bool,
    /// `#1` … `#5000` (index 0 unused).
    numbered: Vec<f64>,
    /// Named parameters whose name starts with `_`.
    globals: HashMap<String, f64>,
    /// The main program, then one frame per call in progress.
    frames: Vec<Frame>,
    /// Subroutines found so far: the line index of their `sub`.
    subs: HashMap<String, usize>,
    /// Lines read so far (skipped ones too).
    read: u64,
    /// The most lines it may read ([`MAX_LINES_READ`]).
    limit: u64,
    /// Asked every [`crate::watch::WATCH_EVERY`] lines whether to go on.
    watch: Watched<'t>,
}

/// The main program or a call in progress.
struct Frame {
    /// The call (none for the main program).
    call: Option<Call>,
    /// Its named parameters.
    named: HashMap<String, f64>,
    /// Its conditionals and loops that are open, innermost last.
    open: Vec<Open>,
}

/// A call in progress.
struct Call {
    /// The subroutine's label.
    label: String,
    /// The line read after it returns (0-based).
    return_to: usize,
    /// The caller's `#1` … `#30`.
    saved: [f64; MAX_ARGUMENTS],
}

/// A conditional or loop that is open.
#[derive(Debug)]
struct Open {
    label: String,
    kind: Opened,
    /// The line index of its statement.
    index: usize,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Opened {
    If,
    While,
    Do,
    /// The turns left, this one included.
    Repeat(u64),
}

impl Opened {
    fn is_loop(self) -> bool {
        !matches!(self, Opened::If)
    }
}

/// Parameters as a line reads them.
struct Scope<'a, 't> {
    flow: &'a Flow<'t>,
    system: &'a dyn System,
}

impl Parameters for Scope<'_, '_> {
    fn numbered(&self, index: usize) -> Result<f64, String> {
        if index <= MAX_USER_PARAMETER {
            return Ok(self.flow.numbered[index]);
        }
        if index == 5399 {
            return Err("#5399 is the input M66 read: known only as the program runs, and this interpreter reads the whole program before it runs (M66 waits here, its value cannot steer the program)".to_string());
        }
        if let Some(why) = self.system.refusal(index) {
            return Err(why.to_string());
        }
        self.system.numbered(index).ok_or_else(|| {
            format!(
                "#{index} is part of LinuxCNC's machine state that this interpreter does not keep (it keeps #5161-#5166, #5181-#5186, #5210-#5216, #5220, #5221-#5326, #5400-#5406 once known, #5420-#5425)"
            )
        })
    }

    fn named(&self, name: &str) -> Option<f64> {
        if name.starts_with('_') {
            self.system.named(name).or_else(|| self.flow.globals.get(name).copied())
        } else {
            self.flow.frame().named.get(name).copied()
        }
    }
}

impl<'t> Flow<'t> {
    /// The program `text` from its first line; `block_delete`: the switch.
    pub fn new(text: &'t str, block_delete: bool) -> Flow<'t> {
        // A UTF-8 byte order mark (Windows editors write one) is not part of the program.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut starts = vec![0];
        starts.extend(text.match_indices('\n').map(|(i, _)| i + 1));
        if starts.last() == Some(&text.len()) && starts.len() > 1 {
            starts.pop();
        }
        Flow {
            text,
            starts,
            next: 0,
            last: 1,
            block_delete,
            numbered: vec![0.0; MAX_USER_PARAMETER + 1],
            // What the last subroutine returned: nothing yet (LinuxCNC's defaults).
            globals: HashMap::from([("_value".to_string(), 0.0), ("_value_returned".to_string(), 0.0)]),
            frames: vec![Frame {
                call: None,
                named: HashMap::new(),
                open: Vec::new(),
            }],
            subs: HashMap::new(),
            read: 0,
            limit: MAX_LINES_READ,
            watch: Watched::new(&Unwatched),
        }
    }

    /// The same flow, asking `watch` now and then whether to go on.
    pub fn watched(mut self, watch: &'t dyn Watch) -> Flow<'t> {
        self.watch = Watched::new(watch);
        self
    }

    fn frame(&self) -> &Frame {
        self.frames.last().expect("the main program's frame is never left")
    }

    fn frame_mut(&mut self) -> &mut Frame {
        self.frames.last_mut().expect("the main program's frame is never left")
    }

    /// Line `index` (0-based) without its line end.
    fn line(&self, index: usize) -> &'t str {
        let start = self.starts[index];
        let end = self.starts.get(index + 1).map_or(self.text.len(), |e| e - 1);
        let line = &self.text[start..end.max(start)];
        line.strip_suffix('\r').unwrap_or(line)
    }

    /// Counts a line read; refuses a program that reads too many.
    fn count(&mut self, index: usize) -> Result<(), NcError> {
        self.watch.step().map_err(|why| NcError::new(index + 1, 1, why))?;
        self.read += 1;
        if self.read > self.limit {
            let innermost = self
                .frames
                .iter()
                .flat_map(|f| f.open.iter())
                .rev()
                .find(|o| o.kind.is_loop())
                .map(|o| format!(" (the innermost open loop: o{} at line {})", o.label, o.index + 1))
                .unwrap_or_default();
            return Err(NcError::new(
                index + 1,
                1,
                format!(
                    "the program read {} lines without ending: a loop that does not end?{innermost}",
                    self.limit
                ),
            ));
        }
        Ok(())
    }

    /// The next line that does something, its O-word statements and parameter settings done;
    /// `system`: the interpreter's state now.
    pub fn next(&mut self, system: &dyn System) -> Result<Event, NcError> {
        loop {
            let index = self.next;
            if index >= self.starts.len() {
                return Ok(Event::End(self.last));
            }
            self.next += 1;
            self.count(index)?;
            let text = self.line(index);
            let line = lexer::read_line(text, index + 1, self.block_delete, &Scope { flow: self, system })?;
            if line != Line::Nothing {
                self.last = index + 1;
            }
            match line {
                Line::Nothing => {}
                Line::Percent => return Ok(Event::Percent(index + 1)),
                Line::Words { block, assignments } => {
                    self.assign(&assignments, index, system)?;
                    if !block.words.is_empty() || block.message.is_some() {
                        return Ok(Event::Block(block));
                    }
                }
                Line::Control(control) => self.control(control, index, system)?,
            }
        }
    }

    /// A line's parameter settings, in order (its values were computed before any of them).
    fn assign(&mut self, assignments: &[Assignment], index: usize, system: &dyn System) -> Result<(), NcError> {
        for a in assignments {
            match &a.target {
                Target::Numbered(n) if *n > MAX_USER_PARAMETER => {
                    return Err(NcError::new(
                        index + 1,
                        a.column,
                        format!(
                            "#{n} is read-only here: parameters from #{} on describe the machine's state (work offsets, position)",
                            MAX_USER_PARAMETER + 1
                        ),
                    ));
                }
                Target::Numbered(n) => self.numbered[*n] = a.value,
                Target::Named(name) if name.starts_with('_') => {
                    if system.named(name).is_some() {
                        return Err(NcError::new(
                            index + 1,
                            a.column,
                            format!("#<{name}> is read-only: it describes the machine's state"),
                        ));
                    }
                    self.globals.insert(name.clone(), a.value);
                }
                Target::Named(name) => {
                    self.frame_mut().named.insert(name.clone(), a.value);
                }
            }
        }
        Ok(())
    }

    /// An O-word statement at line `index`, by its keyword.
    fn control(&mut self, c: Control, index: usize, system: &dyn System) -> Result<(), NcError> {
        let value = c.values.first().copied().unwrap_or(0.0);
        match c.keyword {
            Keyword::Sub => self.define(&c, index),
            Keyword::EndSub | Keyword::Return => self.return_from_call(&c, value),
            Keyword::Call => self.call(&c),
            Keyword::Do => self.begin_do(&c, index),
            Keyword::While => self.test_while(&c, index, value),
            Keyword::EndWhile => self.end_while(&c),
            Keyword::Repeat => self.repeat(&c, index, value),
            Keyword::EndRepeat => self.end_repeat(&c),
            Keyword::If => self.test_if(&c, index, value, system),
            Keyword::ElseIf | Keyword::Else => self.leave_branch(&c, index),
            Keyword::EndIf => self.end_if(&c),
            Keyword::Break | Keyword::Continue => self.break_or_continue(&c, index),
        }
    }

    /// A subroutine's definition: noted, its body skipped (it runs when called).
    fn define(&mut self, c: &Control, index: usize) -> Result<(), NcError> {
        let at = |message: String| NcError::new(c.line, c.column, message);
        if let Some(first) = self.subs.get(&c.label)
            && *first != index
        {
            return Err(at(format!(
                "o{} is defined twice (first at line {})",
                c.label,
                first + 1
            )));
        }
        self.subs.insert(c.label.clone(), index);
        // Its body runs when it is called.
        let (end, _) = self.skip(index + 1, c, |k| k == Keyword::EndSub)?;
        self.next = end + 1;
        Ok(())
    }

    /// The end of the call in progress (`endsub`, `return`): the caller's arguments back, the value returned.
    fn return_from_call(&mut self, c: &Control, value: f64) -> Result<(), NcError> {
        let at = |message: String| NcError::new(c.line, c.column, message);
        // Any endsub or return ends the call in progress, whatever its label, as in
        // LinuxCNC (its own examples return from o1000 with `o1010 return`).
        if self.frame().call.is_none() {
            return Err(at(format!("{} outside a call of o{}", c.name(), c.label)));
        }
        let frame = self.frames.pop().expect("a call's frame");
        let call = frame.call.expect("a call's frame has its call");
        self.numbered[1..=MAX_ARGUMENTS].copy_from_slice(&call.saved);
        self.globals.insert("_value".into(), value);
        self.globals
            .insert("_value_returned".into(), if c.values.is_empty() { 0.0 } else { 1.0 });
        self.next = call.return_to;
        Ok(())
    }

    /// A call: the arguments in #1 … #30 (the caller's kept), a frame of its own.
    fn call(&mut self, c: &Control) -> Result<(), NcError> {
        let at = |message: String| NcError::new(c.line, c.column, message);
        if self.frames.len() > MAX_CALL_DEPTH {
            return Err(at(format!(
                "calls nest deeper than {MAX_CALL_DEPTH} levels (LinuxCNC's limit): does a subroutine call itself without end?"
            )));
        }
        let sub = match self.subs.get(&c.label) {
            Some(s) => *s,
            None => {
                let s = self.find_sub(c)?;
                self.subs.insert(c.label.clone(), s);
                s
            }
        };
        let mut saved = [0.0; MAX_ARGUMENTS];
        saved.copy_from_slice(&self.numbered[1..=MAX_ARGUMENTS]);
        for (i, slot) in self.numbered[1..=MAX_ARGUMENTS].iter_mut().enumerate() {
            *slot = c.values.get(i).copied().unwrap_or(0.0);
        }
        self.frames.push(Frame {
            call: Some(Call {
                label: c.label.clone(),
                return_to: self.next,
                saved,
            }),
            named: HashMap::new(),
            open: Vec::new(),
        });
        self.next = sub + 1;
        Ok(())
    }

    /// The start of a `do` loop.
    fn begin_do(&mut self, c: &Control, index: usize) -> Result<(), NcError> {
        let again = self
            .frame()
            .open
            .last()
            .is_some_and(|o| o.kind == Opened::Do && o.index == index);
        if !again {
            self.open(c, Opened::Do, index)?;
        }
        Ok(())
    }

    /// A `while`: the end of a `do` loop, or the test of a `while` loop.
    fn test_while(&mut self, c: &Control, index: usize, value: f64) -> Result<(), NcError> {
        let top = self.frame().open.last();
        if let Some(o) = top.filter(|o| o.kind == Opened::Do && o.label == c.label) {
            // The end of a do loop.
            let start = o.index;
            if value != 0.0 {
                self.next = start + 1;
            } else {
                self.frame_mut().open.pop();
            }
            return Ok(());
        }
        let again = top.is_some_and(|o| o.kind == Opened::While && o.index == index);
        if value != 0.0 {
            if !again {
                self.open(c, Opened::While, index)?;
            }
        } else {
            if again {
                self.frame_mut().open.pop();
            }
            let (end, _) = self.skip(index + 1, c, |k| k == Keyword::EndWhile)?;
            self.next = end + 1;
        }
        Ok(())
    }

    /// The end of a `while` loop's body: back to its test.
    fn end_while(&mut self, c: &Control) -> Result<(), NcError> {
        let start = self.close(c, |k| k == Opened::While, "while")?.index;
        // Back to the test, which opens it again while it holds.
        self.frame_mut().open.push(Open {
            label: c.label.clone(),
            kind: Opened::While,
            index: start,
        });
        self.next = start;
        Ok(())
    }

    /// A `repeat`: its count, rounded as LinuxCNC rounds it.
    fn repeat(&mut self, c: &Control, index: usize, value: f64) -> Result<(), NcError> {
        let count = value.round();
        if count >= 1.0 {
            self.open(c, Opened::Repeat(count as u64), index)?;
        } else {
            let (end, _) = self.skip(index + 1, c, |k| k == Keyword::EndRepeat)?;
            self.next = end + 1;
        }
        Ok(())
    }

    /// The end of a `repeat` body: another turn while any is left.
    fn end_repeat(&mut self, c: &Control) -> Result<(), NcError> {
        let open = self.close(c, |k| matches!(k, Opened::Repeat(_)), "repeat")?;
        if let Opened::Repeat(left) = open.kind
            && left > 1
        {
            self.next = open.index + 1;
            self.frame_mut().open.push(Open {
                kind: Opened::Repeat(left - 1),
                ..open
            });
        }
        Ok(())
    }

    /// An `if`: its branch, or the next one that holds.
    fn test_if(&mut self, c: &Control, index: usize, value: f64, system: &dyn System) -> Result<(), NcError> {
        if value != 0.0 {
            self.open(c, Opened::If, index)?;
        } else {
            self.branch(index + 1, c, system)?;
        }
        Ok(())
    }

    /// An `elseif` or `else` reached by the branch that ran: on past the `endif`.
    fn leave_branch(&mut self, c: &Control, index: usize) -> Result<(), NcError> {
        // The branch that ran ends here.
        self.close(c, |k| k == Opened::If, "if")?;
        let (end, _) = self.skip(index + 1, c, |k| k == Keyword::EndIf)?;
        self.next = end + 1;
        Ok(())
    }

    /// An `endif`.
    fn end_if(&mut self, c: &Control) -> Result<(), NcError> {
        self.close(c, |k| k == Opened::If, "if")?;
        Ok(())
    }

    /// A `break` or `continue` of the innermost loop with its label.
    fn break_or_continue(&mut self, c: &Control, index: usize) -> Result<(), NcError> {
        let at = |message: String| NcError::new(c.line, c.column, message);
        let frame = self.frame();
        let Some(position) = frame.open.iter().rposition(|o| o.label == c.label && o.kind.is_loop()) else {
            return Err(at(format!("{} outside a loop o{}", c.name(), c.label)));
        };
        let (kind, start) = (frame.open[position].kind, frame.open[position].index);
        let end = |k: Keyword| match kind {
            Opened::While => k == Keyword::EndWhile,
            Opened::Repeat(_) => k == Keyword::EndRepeat,
            Opened::Do => k == Keyword::While,
            Opened::If => false,
        };
        let opening = Control {
            line: start + 1,
            column: 1,
            ..c.clone()
        };
        if c.keyword == Keyword::Break {
            self.frame_mut().open.truncate(position);
            let (stop, _) = self.skip(index + 1, &opening, end)?;
            self.next = stop + 1;
        } else {
            self.frame_mut().open.truncate(position + 1);
            match kind {
                Opened::While => {
                    self.frame_mut().open.pop();
                    self.next = start;
                }
                Opened::Do => self.next = start + 1,
                // The endrepeat counts the turn.
                _ => self.next = self.skip(index + 1, &opening, end)?.0,
            }
        }
        Ok(())
    }

    /// At the end of the text: a conditional, loop or call still open, as an error at its line.
    pub fn unclosed(&self) -> Option<NcError> {
        if let Some(o) = self.frames.iter().flat_map(|f| f.open.iter()).next_back() {
            let what = match o.kind {
                Opened::If => "if",
                Opened::While => "while",
                Opened::Do => "do",
                Opened::Repeat(_) => "repeat",
            };
            return Some(NcError::new(
                o.index + 1,
                1,
                format!("the file ended with o{} {what} open", o.label),
            ));
        }
        self.frames.last().and_then(|f| f.call.as_ref()).map(|call| {
            NcError::new(
                self.last,
                1,
                format!("the file ended inside a call of o{}: its endsub is missing", call.label),
            )
        })
    }

    /// Opens a conditional or loop at line `index`; refused past [`MAX_OPEN`] in one call.
    fn open(&mut self, c: &Control, kind: Opened, index: usize) -> Result<(), NcError> {
        if self.frame().open.len() >= MAX_OPEN {
            return Err(NcError::new(
                c.line,
                c.column,
                format!(
                    "{} would be the {}th conditional or loop open at once: they nest at most {MAX_OPEN} deep in a subroutine or the main program",
                    c.name(),
                    MAX_OPEN + 1
                ),
            ));
        }
        self.frame_mut().open.push(Open {
            label: c.label.clone(),
            kind,
            index,
        });
        Ok(())
    }

    /// Closes the innermost open statement, which must be `what` with `c`'s label.
    fn close(&mut self, c: &Control, kind: impl Fn(Opened) -> bool, what: &str) -> Result<Open, NcError> {
        let frame = self.frame_mut();
        match frame.open.last() {
            Some(o) if o.label == c.label && kind(o.kind) => Ok(frame.open.pop().expect("the last one")),
            Some(o) => Err(NcError::new(
                c.line,
                c.column,
                format!(
                    "{} does not close what is open: o{} at line {} (statements close innermost first)",
                    c.name(),
                    o.label,
                    o.index + 1
                ),
            )),
            None => Err(NcError::new(
                c.line,
                c.column,
                format!("{} without its o{} {what}", c.name(), c.label),
            )),
        }
    }

    /// Skips from line `from` to the first statement with `opening`'s label that `end` wants;
    /// its line index and the statement.
    fn skip(
        &mut self,
        from: usize,
        opening: &Control,
        end: impl Fn(Keyword) -> bool,
    ) -> Result<(usize, Control), NcError> {
        for index in from..self.starts.len() {
            self.count(index)?;
            if let Some(c) = lexer::control_of(self.line(index), index + 1, self.block_delete)?
                && c.label == opening.label
                && end(c.keyword)
            {
                return Ok((index, c));
            }
        }
        let closing = match opening.keyword {
            Keyword::Sub => "endsub",
            Keyword::If | Keyword::ElseIf => "endif",
            Keyword::While => "endwhile",
            Keyword::Repeat => "endrepeat",
            Keyword::Do => "while",
            _ => "end",
        };
        Err(NcError::new(
            opening.line,
            opening.column,
            format!("{} has no o{} {closing} after it", opening.name(), opening.label),
        ))
    }

    /// After an `if` or `elseif` that does not hold: on to the branch that runs (the first
    /// `elseif` that holds, the `else`), or past the `endif`.
    fn branch(&mut self, from: usize, opening: &Control, system: &dyn System) -> Result<(), NcError> {
        let mut from = from;
        loop {
            let (index, found) = self.skip(from, opening, |k| {
                matches!(k, Keyword::ElseIf | Keyword::Else | Keyword::EndIf)
            })?;
            self.next = index + 1;
            match found.keyword {
                Keyword::EndIf => return Ok(()),
                Keyword::Else => {
                    self.open(&found, Opened::If, index)?;
                    return Ok(());
                }
                _ => {
                    // Read now, with its condition.
                    let text = self.line(index);
                    let line = lexer::read_line(text, index + 1, self.block_delete, &Scope { flow: self, system })?;
                    let Line::Control(elseif) = line else {
                        unreachable!("line {} was an elseif a moment ago", index + 1)
                    };
                    if elseif.values.first().is_some_and(|v| *v != 0.0) {
                        self.open(&elseif, Opened::If, index)?;
                        return Ok(());
                    }
                    from = index + 1;
                }
            }
        }
    }

    /// The line index of subroutine `c.label`'s `sub`, looked for in the whole text.
    fn find_sub(&mut self, c: &Control) -> Result<usize, NcError> {
        for index in 0..self.starts.len() {
            self.count(index)?;
            if let Some(s) = lexer::control_of(self.line(index), index + 1, self.block_delete)?
                && s.keyword == Keyword::Sub
                && s.label == c.label
            {
                return Ok(index);
            }
        }
        Err(NcError::new(
            c.line,
            c.column,
            format!(
                "{}: the program has no o{} sub (subroutines are defined in the program's file; files of their own are not searched)",
                c.name(),
                c.label
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A state without system parameters but `_x` (always 7).
    struct Plain;

    impl System for Plain {
        fn numbered(&self, _index: usize) -> Option<f64> {
            None
        }
        fn named(&self, name: &str) -> Option<f64> {
            (name == "_x").then_some(7.0)
        }
    }

    /// The values of the X words of `text`'s lines as they run, in order.
    fn xs(text: &str) -> Result<Vec<f64>, NcError> {
        let mut flow = Flow::new(text, false);
        let mut out = Vec::new();
        loop {
            match flow.next(&Plain)? {
                Event::Block(b) => out.extend(b.words.iter().filter(|w| w.letter == 'X').map(|w| w.value)),
                Event::Percent(_) => {}
                Event::End(_) => return Ok(out),
            }
        }
    }

    fn refused(text: &str) -> String {
        xs(text).expect_err("refused").to_string()
    }

    #[test]
    fn conditionals_take_the_first_branch_that_holds() {
        let text = |n: i32| {
            format!(
                "#1={n}\no1 if [#1 EQ 1]\nX1\no1 elseif [#1 EQ 2]\nX2\no1 elseif [#1 EQ 3]\nX3\no1 else\nX4\no1 endif\nX5\n"
            )
        };
        assert_eq!(xs(&text(1)), Ok(vec![1.0, 5.0]));
        assert_eq!(xs(&text(2)), Ok(vec![2.0, 5.0]));
        assert_eq!(xs(&text(3)), Ok(vec![3.0, 5.0]));
        assert_eq!(xs(&text(9)), Ok(vec![4.0, 5.0]));
        // Without else, nothing runs; nested conditionals.
        assert_eq!(
            xs("o1 if [0]\nX1\no1 endif\no2 if [1]\no3 if [0]\nX2\no3 else\nX3\no3 endif\no2 endif\n"),
            Ok(vec![3.0])
        );
    }

    #[test]
    fn loops_run_their_turns() {
        assert_eq!(
            xs("#1=0\no1 while [#1 LT 3]\nX#1\n#1=[#1+1]\no1 endwhile\nX9\n"),
            Ok(vec![0.0, 1.0, 2.0, 9.0])
        );
        // A do loop runs once even when its test fails.
        assert_eq!(xs("o2 do\nX1\no2 while [0]\nX2\n"), Ok(vec![1.0, 2.0]));
        // repeat rounds its count (LinuxCNC: 2.6 turns are 3); 0 skips.
        assert_eq!(
            xs("o3 repeat [2.6]\nX1\no3 endrepeat\no4 repeat [0]\nX2\no4 endrepeat\n"),
            Ok(vec![1.0, 1.0, 1.0])
        );
        // break and continue, from inside a conditional.
        assert_eq!(
            xs(
                "#1=0\no1 while [1]\n#1=[#1+1]\no2 if [#1 EQ 2]\no1 continue\no2 endif\no3 if [#1 GT 4]\no1 break\no3 endif\nX#1\no1 endwhile\nX0\n"
            ),
            Ok(vec![1.0, 3.0, 4.0, 0.0])
        );
        assert_eq!(
            xs("#1=0\no1 repeat [4]\n#1=[#1+1]\no2 if [#1 EQ 2]\no1 continue\no2 endif\nX#1\no1 endrepeat\n"),
            Ok(vec![1.0, 3.0, 4.0])
        );
        // Nested loops.
        assert_eq!(
            xs("#1=0\no1 repeat [2]\no2 repeat [2]\n#1=[#1+1]\nX#1\no2 endrepeat\no1 endrepeat\n"),
            Ok(vec![1.0, 2.0, 3.0, 4.0])
        );
    }

    #[test]
    fn subroutines_take_arguments_and_give_back_the_callers_parameters() {
        let text = "#1=5\n#<a>=1\no<square> call [2] [3]\nX#1\nX#<_value>\nM2\no<square> sub\n#<a>=9\nX[#1*#2]\no<square> return [#1+#2]\nX99\no<square> endsub\n";
        assert_eq!(xs(text), Ok(vec![6.0, 5.0, 5.0]));
        // Named parameters are local: the caller's #<a> is not seen in the subroutine.
        assert_eq!(
            refused("#<a>=1\no1 call\nM2\no1 sub\nX#<a>\no1 endsub\n"),
            "5:2: #<a> is not defined: set it (#<a> = …) before reading it"
        );
        // Global ones (_) are.
        assert_eq!(xs("#<_a>=4\no1 call\nM2\no1 sub\nX#<_a>\no1 endsub\n"), Ok(vec![4.0]));
        // A subroutine defined before its call is skipped where it stands.
        assert_eq!(xs("o1 sub\nX#1\no1 endsub\no1 call [8]\nX1\n"), Ok(vec![8.0, 1.0]));
        // Recursion, within the depth.
        assert_eq!(
            xs("o1 call [3]\nM2\no1 sub\nX#1\no2 if [#1 GT 1]\no1 call [#1-1]\no2 endif\no1 endsub\n"),
            Ok(vec![3.0, 2.0, 1.0])
        );
    }

    #[test]
    fn system_parameters_are_read_only() {
        assert_eq!(xs("X#<_x>\n"), Ok(vec![7.0]));
        assert_eq!(
            xs("X#<_value> X#<_value_returned>\n"),
            Ok(vec![0.0, 0.0]),
            "before any call"
        );
        assert_eq!(
            refused("#<_x>=1\n"),
            "1:1: #<_x> is read-only: it describes the machine's state"
        );
        assert_eq!(
            refused("#5221=1\n"),
            "1:1: #5221 is read-only here: parameters from #5001 on describe the machine's state (work offsets, position)"
        );
        assert_eq!(
            refused("X#5063\n"),
            "1:2: #5063 is part of LinuxCNC's machine state that this interpreter does not keep (it keeps #5161-#5166, #5181-#5186, #5210-#5216, #5220, #5221-#5326, #5400-#5406 once known, #5420-#5425)"
        );
    }

    #[test]
    fn what_does_not_nest_or_end_is_refused_with_its_line() {
        for (text, message) in [
            ("o1 if [1]\nX1\n", "1:1: the file ended with o1 if open"),
            ("o1 if [0]\nX1\n", "1:1: o1 if has no o1 endif after it"),
            ("o1 endif\n", "1:1: o1 endif without its o1 if"),
            (
                "o1 if [1]\no2 while [1]\no1 endif\n",
                "3:1: o1 endif does not close what is open: o2 at line 2 (statements close innermost first)",
            ),
            (
                "o1 call\n",
                "1:1: o1 call: the program has no o1 sub (subroutines are defined in the program's file; files of their own are not searched)",
            ),
            ("o1 sub\nX1\n", "1:1: o1 sub has no o1 endsub after it"),
            ("o1 endsub\n", "1:1: o1 endsub outside a call of o1"),
            ("o1 break\n", "1:1: o1 break outside a loop o1"),
            (
                "o1 call\nM2\no1 sub\no1 call\no1 endsub\n",
                "4:1: calls nest deeper than 10 levels (LinuxCNC's limit): does a subroutine call itself without end?",
            ),
            (
                "o1 sub\no1 endsub\no1 sub\no1 endsub\n",
                "3:1: o1 is defined twice (first at line 1)",
            ),
            (
                &"o1 if [1]\n".repeat(MAX_OPEN + 1),
                "65:1: o1 if would be the 65th conditional or loop open at once: they nest at most 64 deep in a subroutine or the main program",
            ),
        ] {
            let mut flow = Flow::new(text, false);
            let got = loop {
                match flow.next(&Plain) {
                    Err(e) => break e.to_string(),
                    // Open statements at the end are the interpreter's to refuse (it knows
                    // whether the program ended before).
                    Ok(Event::End(_)) => break flow.unclosed().map(|e| e.to_string()).unwrap_or_default(),
                    Ok(_) => {}
                }
            };
            assert_eq!(got, message, "{text}");
        }
    }

    proptest::proptest! {
        /// Any text made of O-word statements, parameter settings and moves is run or refused
        /// with a line and a message; nothing panics and every run ends.
        #[test]
        fn any_program_runs_or_is_refused(lines in proptest::collection::vec(proptest::sample::select(vec![
            "o1 if [#1 LT 3]", "o1 elseif [#2]", "o1 else", "o1 endif", "o2 while [#1 LT 3]", "o2 endwhile",
            "o3 do", "o3 while [#1 LT 2]", "o4 repeat [2]", "o4 endrepeat", "o2 break", "o2 continue",
            "o5 sub", "o5 endsub [#1]", "o5 call [#1 + 1]", "o5 return", "#1 = [#1 + 1]", "#<a> = #1",
            "X#<a>", "X#1", "M2", "%", "/X1", "(comment)", "N5 o1 if [1]",
        ]), 0..24)) {
            let text = lines.join("\n");
            let mut flow = Flow::new(&text, false);
            flow.limit = 10_000;
            // Each call reads at least one line, and the flow reads at most its limit: the run
            // ends (or is refused) within that many calls.
            let mut ended = false;
            for _ in 0..=10_001 {
                match flow.next(&Plain) {
                    Ok(Event::End(_)) | Err(_) => {
                        ended = true;
                        break;
                    }
                    Ok(_) => {}
                }
            }
            proptest::prop_assert!(ended, "{} lines read and still running:\n{}", flow.read, text);
        }
    }

    #[test]
    fn a_loop_that_does_not_end_is_refused() {
        let mut flow = Flow::new("#1=0\no1 while [1]\n#1=[#1+1]\no1 endwhile\n", false);
        flow.limit = 1000;
        let e = loop {
            match flow.next(&Plain) {
                Err(e) => break e,
                Ok(Event::End(_)) => panic!("the loop ended"),
                Ok(_) => {}
            }
        };
        assert_eq!(
            e.to_string(),
            "2:1: the program read 1000 lines without ending: a loop that does not end? (the innermost open loop: o1 at line 2)"
        );
    }
}
