//! The fast path of the trace reader: a parser for exactly the record lines the recorder writes
//! (keys in its order, no whitespace, no escapes). It reads a line in one pass without building
//! JSON values, and matches variable names against the class's list in header order, which is
//! the order the recorder writes them in.
//!
//! It only ever accepts or declines: on any deviation from that form it returns `None`, and the
//! reader parses the line with serde_json instead, which accepts any equivalent JSON and words
//! the errors. What the fast path accepts it reads exactly as that slow path would (a property
//! test holds the two to it).

use crate::image::{Value, VarType};

/// A variable as a class's records name it.
pub(super) struct Slot {
    /// Its name as the line spells it.
    pub name: Box<[u8]>,
    /// Its index among the header's variables.
    pub index: usize,
    /// Its type.
    pub ty: VarType,
}

/// A task class as its records look.
pub(super) struct ClassLayout {
    /// Its name.
    pub name: Box<[u8]>,
    /// The variables it latches, in header order.
    pub inputs: Vec<Slot>,
    /// The variables it publishes, in header order.
    pub outputs: Vec<Slot>,
}

/// The fixed part of a record line.
pub(super) struct Fields<'a> {
    pub class: usize,
    pub t_us: u64,
    pub cycle: u64,
    pub state: Option<&'a str>,
    pub reason: Option<&'a str>,
    pub violation: bool,
}

struct Cursor<'a> {
    s: &'a str,
    b: &'a [u8],
    i: usize,
}

/// Whether `a` and `b` hold the same bytes: names are a few bytes long, and comparing them in
/// words here costs less than the library's call (a record line matches a dozen).
#[inline]
fn same_bytes(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let (words_a, rest_a) = a.as_chunks::<8>();
    let (words_b, rest_b) = b.as_chunks::<8>();
    words_a
        .iter()
        .zip(words_b)
        .all(|(x, y)| u64::from_ne_bytes(*x) == u64::from_ne_bytes(*y))
        && rest_a.iter().zip(rest_b).all(|(x, y)| x == y)
}

impl<'a> Cursor<'a> {
    fn lit(&mut self, s: &[u8]) -> Option<()> {
        if self.b.get(self.i..self.i + s.len())? == s {
            self.i += s.len();
            Some(())
        } else {
            None
        }
    }

    fn peek(&self) -> Option<u8> {
        self.b.get(self.i).copied()
    }

    /// The text up to the closing quote (the opening one already read); `None` on an escape or
    /// a control character, which only the slow path reads.
    fn string(&mut self) -> Option<&'a str> {
        let start = self.i;
        let len = self.b[start..]
            .iter()
            .position(|&c| c == b'"' || c == b'\\' || c < 0x20)?;
        self.i += len;
        self.lit(b"\"")?;
        self.s.get(start..start + len)
    }

    fn digits(&mut self) -> usize {
        let start = self.i;
        while self.peek().is_some_and(|c| c.is_ascii_digit()) {
            self.i += 1;
        }
        self.i - start
    }

    /// A JSON number token: its text, whether it is an integer (no fraction, no exponent), and
    /// for an integer of at most 18 digits its value (read while scanning: no second pass).
    fn number(&mut self) -> Option<(&'a str, bool, Option<i64>)> {
        let start = self.i;
        let negative = self.peek() == Some(b'-');
        if negative {
            self.i += 1;
        }
        let mut whole: i64 = 0;
        let digits_from = self.i;
        match self.peek()? {
            b'0' => self.i += 1,
            b'1'..=b'9' => {
                while let Some(c) = self.peek().filter(u8::is_ascii_digit) {
                    // Wrapping: beyond 18 digits the value is not used (see below).
                    whole = whole.wrapping_mul(10).wrapping_add(i64::from(c - b'0'));
                    self.i += 1;
                }
            }
            _ => return None,
        }
        let small = self.i - digits_from <= 18;
        let mut integer = true;
        if self.peek() == Some(b'.') {
            self.i += 1;
            if self.digits() == 0 {
                return None;
            }
            integer = false;
        }
        if matches!(self.peek(), Some(b'e' | b'E')) {
            self.i += 1;
            if matches!(self.peek(), Some(b'+' | b'-')) {
                self.i += 1;
            }
            if self.digits() == 0 {
                return None;
            }
            integer = false;
        }
        // Within 18 digits the value is exact and its negation cannot overflow.
        let value = (integer && small).then(|| if negative { -whole } else { whole });
        Some((self.s.get(start..self.i)?, integer, value))
    }

    /// An unsigned integer field (at most 18 digits: it fits).
    fn uint(&mut self) -> Option<u64> {
        match self.number()? {
            (text, _, Some(v)) if !text.starts_with('-') => u64::try_from(v).ok(),
            _ => None,
        }
    }

    /// A value of type `ty`, read as `value_from_json` reads serde_json's value of the token.
    fn value(&mut self, ty: VarType) -> Option<Value> {
        match (self.peek()?, ty) {
            (b't', VarType::Bool) => return self.lit(b"true").map(|()| Value::Bool(true)),
            (b'f', VarType::Bool) => return self.lit(b"false").map(|()| Value::Bool(false)),
            (b'n', VarType::Real) => return self.lit(b"null").map(|()| Value::Real(f64::NAN)),
            (b'-' | b'0'..=b'9', _) => {}
            _ => return None,
        }
        let (text, integer, int) = self.number()?;
        // serde_json reads "-0" as the float -0.0, and integers beyond 18 digits in ways this
        // path does not repeat: the slow path takes them.
        let int = int.filter(|_| text != "-0");
        match (ty, int) {
            (VarType::Bool, _) => None,
            (VarType::Real, Some(v)) => Some(Value::Real(v as f64)),
            (VarType::Real, None) if integer => None,
            (VarType::Real, None) => text.parse::<f64>().ok().filter(|x| x.is_finite()).map(Value::Real),
            (_, None) => None,
            (VarType::Int, Some(v)) => i16::try_from(v).ok().map(Value::Int),
            (VarType::Uint, Some(v)) => u16::try_from(v).ok().map(Value::Uint),
            (VarType::Dint, Some(v)) => i32::try_from(v).ok().map(Value::Dint),
        }
    }

    /// `{"NAME":VALUE,…}` with every name one of `slots`, pushed as (header index, value).
    fn pairs(&mut self, slots: &[Slot], out: &mut Vec<(usize, Value)>) -> Option<()> {
        self.lit(b"{")?;
        if self.peek()? == b'}' {
            self.i += 1;
            return Some(());
        }
        if slots.is_empty() {
            return None;
        }
        // The recorder writes a class's variables in header order: look from the last match on,
        // comparing lengths first.
        let mut next = 0;
        loop {
            self.lit(b"\"")?;
            // Slot names hold no quote, backslash or control character (see `fast_names`): a
            // name that matches one is that name, escapes and all. Mostly it is the next slot's
            // name, followed by its closing quote.
            let expected = &slots[next].name;
            let mut k = next;
            if self.b.get(self.i + expected.len()) == Some(&b'"')
                && same_bytes(&self.b[self.i..self.i + expected.len()], expected)
            {
                self.i += expected.len() + 1;
            } else {
                let len = memchr::memchr(b'"', &self.b[self.i..])?;
                let name = &self.b[self.i..self.i + len];
                self.i += len + 1;
                let mut left = slots.len();
                while !same_bytes(&slots[k].name, name) {
                    left = left.checked_sub(1).filter(|&l| l > 0)?;
                    k = if k + 1 == slots.len() { 0 } else { k + 1 };
                }
            }
            self.lit(b":")?;
            next = if k + 1 == slots.len() { 0 } else { k + 1 };
            out.push((slots[k].index, self.value(slots[k].ty)?));
            match self.peek()? {
                b',' => self.i += 1,
                b'}' => {
                    self.i += 1;
                    return Some(());
                }
                _ => return None,
            }
        }
    }
}

/// Whether every name in `layouts` can be matched byte for byte: none holds a quote, a
/// backslash or a control character (which JSON escapes). Otherwise only the slow path reads.
pub(super) fn fast_names(layouts: &[ClassLayout]) -> bool {
    let plain = |n: &[u8]| !n.iter().any(|&c| c == b'"' || c == b'\\' || c < 0x20);
    layouts
        .iter()
        .all(|c| plain(&c.name) && c.inputs.iter().chain(&c.outputs).all(|s| plain(&s.name)))
}

/// Reads `line` if it has exactly the recorder's form; the changed inputs and outputs go to
/// `inputs` and `outputs` (cleared first). `None`: not that form (the slow path decides).
pub(super) fn parse<'a>(
    line: &'a str,
    classes: &[ClassLayout],
    inputs: &mut Vec<(usize, Value)>,
    outputs: &mut Vec<(usize, Value)>,
) -> Option<Fields<'a>> {
    inputs.clear();
    outputs.clear();
    let mut c = Cursor {
        s: line,
        b: line.as_bytes(),
        i: 0,
    };
    c.lit(b"{\"t_us\":")?;
    let t_us = c.uint()?;
    c.lit(b",\"task\":\"")?;
    let task = c.string()?;
    let class = classes.iter().position(|k| same_bytes(&k.name, task.as_bytes()))?;
    c.lit(b",\"cycle\":")?;
    let cycle = c.uint()?;
    c.lit(b",\"in\":")?;
    c.pairs(&classes[class].inputs, inputs)?;
    c.lit(b",\"out\":")?;
    c.pairs(&classes[class].outputs, outputs)?;
    let mut fields = Fields {
        class,
        t_us,
        cycle,
        state: None,
        reason: None,
        violation: false,
    };
    if c.lit(b",\"state\":\"").is_some() {
        fields.state = Some(c.string()?);
    }
    if c.lit(b",\"reason\":\"").is_some() {
        fields.reason = Some(c.string()?);
    }
    if c.lit(b",\"violation\":true").is_some() {
        fields.violation = true;
    }
    c.lit(b"}")?;
    (c.i == line.len()).then_some(fields)
}
