//! The fast path of the trace reader: a parser for exactly the record lines the recorder writes
//! (keys in its order, no whitespace, no escapes). It reads a line in one pass without building
//! JSON values, and matches variable names against the class's list in header order, which is
//! the order the recorder writes them in.
//!
//! It only ever accepts or declines: on any deviation from that form it returns `None`, and the
//! reader parses the line with serde_json instead, which accepts any equivalent JSON and words
//! the errors. What the fast path accepts it reads exactly as that slow path would (a property
//! test holds the two to it).

use std::collections::HashMap;

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

/// The variables a class latches, or those it publishes, as its records name them.
pub(super) struct Slots {
    /// In header order, the order the recorder writes them in.
    pub list: Vec<Slot>,
    /// Their positions in `list` by name: a record holds only the variables that changed, so
    /// the next name is often not the next in order (a class may have a hundred).
    by_name: HashMap<Box<[u8]>, usize, foldhash::fast::FixedState>,
}

impl Slots {
    /// `list`, in header order, with its index by name.
    pub fn new(list: Vec<Slot>) -> Slots {
        let by_name = list.iter().enumerate().map(|(k, s)| (s.name.clone(), k)).collect();
        Slots { list, by_name }
    }
}

/// A task class as its records look.
pub(super) struct ClassLayout {
    /// Its name.
    pub name: Box<[u8]>,
    /// The variables it latches.
    pub inputs: Slots,
    /// The variables it publishes.
    pub outputs: Slots,
}

/// The fixed part of a record line.
pub(super) struct Fields<'a> {
    /// The task class's index in the header.
    pub class: usize,
    /// Nominal start (µs).
    pub t_us: u64,
    /// The cycle's number in its class.
    pub cycle: u64,
    /// The state's name, as its bytes (not yet checked as UTF-8).
    pub state: Option<&'a [u8]>,
    /// The reason, the same way.
    pub reason: Option<&'a [u8]>,
    /// Whether a cycle time violation was delivered.
    pub violation: bool,
}

struct Cursor<'a> {
    b: &'a [u8],
    i: usize,
}

/// Whether `a` and `b` hold the same bytes: names are a few bytes long, and comparing them in
/// words here costs less than the library's call (a record line matches a dozen). The bytes
/// after the last whole word are compared as the last eight (or four) bytes, overlapping the
/// words before: no loop over single bytes.
#[inline]
pub(crate) fn same_bytes(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let n = a.len();
    let word = |s: &[u8], at: usize| s[at..].first_chunk::<8>().map(|w| u64::from_ne_bytes(*w));
    let half = |s: &[u8], at: usize| s[at..].first_chunk::<4>().map(|w| u32::from_ne_bytes(*w));
    if n >= 8 {
        let (words_a, _) = a.as_chunks::<8>();
        let (words_b, _) = b.as_chunks::<8>();
        words_a
            .iter()
            .zip(words_b)
            .all(|(x, y)| u64::from_ne_bytes(*x) == u64::from_ne_bytes(*y))
            && word(a, n - 8) == word(b, n - 8)
    } else if n >= 4 {
        half(a, 0) == half(b, 0) && half(a, n - 4) == half(b, n - 4)
    } else {
        a == b
    }
}

/// How many of the eight bytes of `word` (in memory order) are ASCII digits before the first
/// that is not. Per byte, `c - '0'` borrows (sets the high bit) below '0' and `c + 0x46` reaches
/// the high bit above '9' (bytes from 0xB0 up have it already in `c - '0'`); a borrow or carry
/// only moves towards later bytes, and only out of a byte that is not a digit, so the first such
/// byte is always flagged and no digit before it is.
#[inline]
fn leading_digits(word: u64) -> usize {
    let below = word.wrapping_sub(0x3030_3030_3030_3030);
    let above = word.wrapping_add(0x4646_4646_4646_4646);
    ((below | above) & 0x8080_8080_8080_8080).trailing_zeros() as usize / 8
}

/// 10⁰ … 10⁸: what a value read so far is multiplied by when `n` more digits follow.
const POWERS_OF_TEN: [u64; 9] = [1, 10, 100, 1_000, 10_000, 100_000, 1_000_000, 10_000_000, 100_000_000];

/// The value of the first `n` bytes of `word` (in memory order), which are ASCII digits
/// (`n` ≤ 8). Shifted so that they end the word, the bytes before them read as leading zeros;
/// then pairs, quads and octets of digits are combined in three multiplications (the method of
/// simdjson and fast_float).
#[inline]
fn digits_value(word: u64, n: usize) -> u64 {
    if n == 0 {
        return 0;
    }
    let w = (word << (8 * (8 - n))) & 0x0F0F_0F0F_0F0F_0F0F;
    let w = (w.wrapping_mul(2561) >> 8) & 0x00FF_00FF_00FF_00FF;
    let w = (w.wrapping_mul(6_553_601) >> 16) & 0x0000_FFFF_0000_FFFF;
    w.wrapping_mul(42_949_672_960_001) >> 32
}

impl<'a> Cursor<'a> {
    /// Takes the literal `s` if it comes next. Its length is known when compiling, so the
    /// comparison is a few word compares, not a call.
    #[inline]
    fn lit<const N: usize>(&mut self, s: &[u8; N]) -> Option<()> {
        if self.b[self.i..].first_chunk::<N>()? == s {
            self.i += N;
            Some(())
        } else {
            None
        }
    }

    fn peek(&self) -> Option<u8> {
        self.b.get(self.i).copied()
    }

    /// The bytes up to the closing quote (the opening one already read); `None` on an escape or
    /// a control character, which only the slow path reads. Not checked as UTF-8 here: the
    /// reader compares them with the names it has seen and checks only a new one.
    fn string(&mut self) -> Option<&'a [u8]> {
        let start = self.i;
        let len = self.b[start..]
            .iter()
            .position(|&c| c == b'"' || c == b'\\' || c < 0x20)?;
        self.i += len;
        self.lit(b"\"")?;
        Some(&self.b[start..start + len])
    }

    /// Skips the ASCII digits from here; how many there were.
    fn digits(&mut self) -> usize {
        let start = self.i;
        // Eight at a time while they last (a fraction has up to 17).
        while let Some(word) = self.b[self.i..].first_chunk::<8>() {
            let n = leading_digits(u64::from_le_bytes(*word));
            self.i += n;
            if n < 8 {
                return self.i - start;
            }
        }
        while self.peek().is_some_and(|c| c.is_ascii_digit()) {
            self.i += 1;
        }
        self.i - start
    }

    /// Reads the ASCII digits from here, eight at a time where the line has eight more bytes:
    /// how many there were, and their value if there were at most 18 (then it is exact).
    fn digits_value(&mut self) -> (usize, Option<i64>) {
        let start = self.i;
        let mut value: u64 = 0;
        loop {
            let Some(word) = self.b[self.i..].first_chunk::<8>() else {
                while let Some(c) = self.peek().filter(u8::is_ascii_digit) {
                    // Wrapping: beyond 18 digits the value is not used.
                    value = value.wrapping_mul(10).wrapping_add(u64::from(c - b'0'));
                    self.i += 1;
                }
                break;
            };
            let word = u64::from_le_bytes(*word);
            let n = leading_digits(word);
            value = value.wrapping_mul(POWERS_OF_TEN[n]).wrapping_add(digits_value(word, n));
            self.i += n;
            if n < 8 {
                break;
            }
        }
        let count = self.i - start;
        (count, (count <= 18).then_some(value as i64))
    }

    /// A JSON number token: its text, whether it is an integer (no fraction, no exponent), and
    /// for an integer of at most 18 digits its value (read while scanning: no second pass).
    fn number(&mut self) -> Option<(&'a str, bool, Option<i64>)> {
        let start = self.i;
        let negative = self.peek() == Some(b'-');
        if negative {
            self.i += 1;
        }
        let whole = match self.peek()? {
            b'0' => {
                self.i += 1;
                Some(0)
            }
            b'1'..=b'9' => self.digits_value().1,
            _ => return None,
        };
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
        let value = whole.filter(|_| integer).map(|w| if negative { -w } else { w });
        let token = &self.b[start..self.i];
        // SAFETY: the token was scanned above and holds only ASCII bytes ('-', '+', '.', 'e',
        // 'E' and digits), so it is UTF-8. Checking it again cost a sixth of reading a trace.
        let text = unsafe { std::str::from_utf8_unchecked(token) };
        Some((text, integer, value))
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
    fn pairs(&mut self, slots: &Slots, out: &mut Vec<(usize, Value)>) -> Option<()> {
        self.lit(b"{")?;
        if self.peek()? == b'}' {
            self.i += 1;
            return Some(());
        }
        let list = &slots.list;
        if list.is_empty() {
            return None;
        }
        // The recorder writes a class's variables in header order: the name is often the one
        // after the last match, which is tried first; otherwise it is looked up.
        let mut next = 0;
        loop {
            self.lit(b"\"")?;
            // Slot names hold no quote, backslash or control character (see `fast_names`): a
            // name that matches one is that name, escapes and all.
            let expected = &list[next].name;
            let k = if self.b.get(self.i + expected.len()) == Some(&b'"')
                && same_bytes(&self.b[self.i..self.i + expected.len()], expected)
            {
                self.i += expected.len() + 1;
                next
            } else {
                let len = memchr::memchr(b'"', &self.b[self.i..])?;
                let name = &self.b[self.i..self.i + len];
                self.i += len + 1;
                *slots.by_name.get(name)?
            };
            self.lit(b":")?;
            next = if k + 1 == list.len() { 0 } else { k + 1 };
            out.push((list[k].index, self.value(list[k].ty)?));
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
        .all(|c| plain(&c.name) && c.inputs.list.iter().chain(&c.outputs.list).all(|s| plain(&s.name)))
}

/// Reads the record at the start of `bytes` if it has exactly the recorder's form; the changed
/// inputs and outputs go to `inputs` and `outputs` (cleared first). Returns its fields and where
/// it ends (just after its closing brace); `None`: not that form (the slow path decides).
///
/// Nothing the fast path accepts holds an end of line, so the record never reaches past the end
/// of its line: the caller decides what must follow it (the line's end, or a `\n` when `bytes`
/// is a reader's buffer holding the lines after it too).
pub(super) fn parse<'a>(
    bytes: &'a [u8],
    classes: &[ClassLayout],
    inputs: &mut Vec<(usize, Value)>,
    outputs: &mut Vec<(usize, Value)>,
) -> Option<(Fields<'a>, usize)> {
    inputs.clear();
    outputs.clear();
    let mut c = Cursor { b: bytes, i: 0 };
    c.lit(b"{\"t_us\":")?;
    let t_us = c.uint()?;
    c.lit(b",\"task\":\"")?;
    // The class's name and its closing quote, matched against the header's names in place.
    let class = classes.iter().position(|k| {
        let end = c.i + k.name.len();
        c.b.get(end) == Some(&b'"') && same_bytes(&c.b[c.i..end], &k.name)
    })?;
    c.i += classes[class].name.len() + 1;
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
    Some((fields, c.i))
}

#[cfg(test)]
mod tests {
    use super::{digits_value, leading_digits, same_bytes};
    use proptest::prelude::*;

    proptest! {
        /// The word-wise count is the byte-wise one, for any bytes (digits made likely).
        #[test]
        fn leading_digits_counts_as_a_byte_loop_does(
            bytes in proptest::array::uniform8(prop_oneof![3 => b'0'..=b'9', 1 => any::<u8>()])
        ) {
            let expected = bytes.iter().take_while(|c| c.is_ascii_digit()).count();
            prop_assert_eq!(leading_digits(u64::from_le_bytes(bytes)), expected);
        }

        /// Word-wise equality is byte-wise equality, at every length and for near misses.
        #[test]
        fn same_bytes_is_slice_equality(a in proptest::collection::vec(b'a'..=b'c', 0..40), flip in any::<prop::sample::Index>(), other in any::<bool>()) {
            let mut b = a.clone();
            if other && !b.is_empty() {
                let at = flip.index(b.len());
                b[at] = if b[at] == b'a' { b'b' } else { b'a' };
            }
            prop_assert_eq!(same_bytes(&a, &b), a == b);
            prop_assert_eq!(same_bytes(&a, &a[..a.len().saturating_sub(1)]), a.is_empty());
        }

        /// The value of a word's leading digits is the one `str::parse` reads, whatever follows.
        #[test]
        fn digits_value_reads_as_parse_does(digits in "[0-9]{0,8}", tail in proptest::collection::vec(any::<u8>(), 8)) {
            let mut bytes = [0u8; 8];
            bytes[..digits.len()].copy_from_slice(digits.as_bytes());
            bytes[digits.len()..].copy_from_slice(&tail[digits.len()..]);
            let expected = if digits.is_empty() { 0 } else { digits.parse::<u64>().expect("digits") };
            prop_assert_eq!(digits_value(u64::from_le_bytes(bytes), digits.len()), expected);
        }
    }
}
