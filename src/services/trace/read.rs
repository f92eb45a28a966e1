//! Reading traces strictly: every problem is an error with the file and line number, and a trace
//! cut short by a crash (an incomplete last line, a gzip stream without its trailer) yields every
//! complete record and then says where it was cut.
//!
//! Lines are bounded ([`MAX_LINE_BYTES`]) and only regular files are opened, so a corrupt or
//! hostile file is an error, not a hang or an out-of-memory abort. Record lines in the form the
//! recorder writes take a fast path (`fast.rs`); any other valid JSON is read by serde_json.

use std::collections::HashMap;
use std::fmt;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use serde::Deserialize;
use serde::de::{MapAccess, Visitor};

use super::fast::{self, ClassLayout, Slot, Slots};
use super::{FORMAT, Header, VERSION, value_from_json};
use crate::image::{Value, VarType};
use crate::runtime::config::{MAX_CYCLE_US, MIN_CYCLE_US};

/// The longest line a trace may hold (4 MiB). A header of a thousand variables is about 40 kB,
/// a record line a few kB; anything longer is not a trace.
pub const MAX_LINE_BYTES: usize = 4 << 20;

/// The latest cycle start a trace may hold (µs): its nanoseconds must fit the runtime's clock.
pub const MAX_T_US: u64 = u64::MAX / 1000;

/// A problem with a trace file.
#[derive(Debug, Clone, PartialEq)]
pub struct TraceError {
    /// The file.
    pub file: String,
    /// 1-based line (0: the file as a whole).
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for TraceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 {
            write!(f, "{}: {}", self.file, self.message)
        } else {
            write!(f, "{}:{}: {}", self.file, self.line, self.message)
        }
    }
}

impl std::error::Error for TraceError {}

/// Where a trace that a crash cut short ends: every record up to here was read.
#[derive(Debug, Clone, PartialEq)]
pub struct Cut {
    /// The last complete line.
    pub after_line: usize,
    /// The time of the last complete record (µs), if there was one.
    pub last_t_us: Option<u64>,
    /// What was found instead of the rest.
    pub why: String,
}

impl fmt::Display for Cut {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "the trace is cut after line {}", self.after_line)?;
        if let Some(t) = self.last_t_us {
            write!(f, " (t = {:.3} s)", t as f64 * 1e-6)?;
        }
        write!(f, ": {}", self.why)
    }
}

/// A record line, parsed without copying names out of the line (the slow path).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Line<'a> {
    t_us: u64,
    task: &'a str,
    cycle: u64,
    #[serde(rename = "in", borrow)]
    inputs: Pairs<'a>,
    #[serde(borrow)]
    out: Pairs<'a>,
    #[serde(default, borrow)]
    state: Option<std::borrow::Cow<'a, str>>,
    #[serde(default, borrow)]
    reason: Option<std::borrow::Cow<'a, str>>,
    #[serde(default)]
    violation: bool,
    #[serde(default)]
    job: Option<super::TraceJob>,
}

/// A JSON object as (key, value) pairs borrowing the keys from the line.
struct Pairs<'a>(Vec<(&'a str, serde_json::Value)>);

impl<'de: 'a, 'a> Deserialize<'de> for Pairs<'a> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Pairs<'de>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an object of variable names and values")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
                let mut pairs = Vec::with_capacity(map.size_hint().unwrap_or(8));
                while let Some(pair) = map.next_entry::<&'de str, serde_json::Value>()? {
                    pairs.push(pair);
                }
                Ok(Pairs(pairs))
            }
        }
        d.deserialize_map(V)
    }
}

/// One class cycle of a trace, checked against the header.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Record {
    /// Its line in the file.
    pub line: usize,
    /// The task class's index in the header.
    pub class: usize,
    /// Nominal start (µs).
    pub t_us: u64,
    /// The cycle's number in its class.
    pub cycle: u64,
    /// Changed inputs: (index into [`TraceReader::variables`], value).
    pub inputs: Vec<(usize, Value)>,
    /// Changed outputs, the same way.
    pub outputs: Vec<(usize, Value)>,
    /// The main state after the cycle.
    pub state: Option<Arc<str>>,
    /// The error reason, if any.
    pub reason: Option<Arc<str>>,
    /// Whether a cycle time violation was delivered in this cycle.
    pub violation: bool,
    /// A job the operator made on the screen, loaded in this cycle.
    pub job: Option<Box<super::TraceJob>>,
}

/// What reading one line found.
enum Read1 {
    /// A whole line (without its end of line) is in the buffer.
    Line,
    /// The end of the trace.
    End,
    /// The trace ends early; the buffer holds what there is of the last line.
    Cut(String),
}

/// Reads a trace record by record.
pub struct TraceReader {
    file: String,
    input: Box<dyn BufRead + Send>,
    buffer: Vec<u8>,
    line: usize,
    header: Header,
    classes: HashMap<String, usize>,
    /// The header's variables in order, with their types.
    variables: Vec<(String, VarType)>,
    /// Per class: variable name → (true for inputs, false for outputs; index in `variables`).
    roles: Vec<HashMap<String, (bool, usize)>>,
    /// The classes as the fast path matches them.
    layouts: Vec<ClassLayout>,
    /// Whether the fast path can read this trace's records.
    fast: bool,
    /// An error the input gave while a record was read in place, for the line reader to report.
    failed: Option<std::io::Error>,
    /// Per class: the previous record's time (µs).
    last_t: Vec<Option<u64>>,
    /// The newest record's time.
    newest_t: Option<u64>,
    /// State and reason names seen so far, shared by the records that carry them.
    names: Vec<Arc<str>>,
    /// Where the trace was cut, once that was found.
    cut: Option<Cut>,
}

impl TraceReader {
    /// Opens a trace (a regular file; gzip-compressed when the name ends in `.gz`) and reads its
    /// header.
    pub fn open(path: &Path) -> Result<TraceReader, TraceError> {
        let name = path.display().to_string();
        let err = |line: usize, message: String| TraceError {
            file: name.clone(),
            line,
            message,
        };
        let file = crate::runtime::files::open_regular(path).map_err(|e| err(0, format!("cannot open: {e}")))?;
        // A name ending in .gz is a gzip-compressed trace.
        // The inflated blocks are read in place; a plain file through a buffer.
        let input: Box<dyn BufRead + Send> = if path.extension().is_some_and(|e| e == "gz") {
            Box::new(super::inflate::Inflated::start(file).map_err(|e| err(0, format!("cannot start reading: {e}")))?)
        } else {
            Box::new(BufReader::with_capacity(1 << 18, file))
        };
        let mut reader = TraceReader {
            file: name.clone(),
            input,
            buffer: Vec::new(),
            line: 0,
            header: Header {
                format: String::new(),
                version: 0,
                config_digest: String::new(),
                machine: None,
                bus: String::new(),
                task_classes: Vec::new(),
                variables: Default::default(),
                program: None,
                library: Vec::new(),
                tool_table: None,
                offsets: None,
            },
            classes: HashMap::new(),
            variables: Vec::new(),
            roles: Vec::new(),
            layouts: Vec::new(),
            fast: false,
            failed: None,
            last_t: Vec::new(),
            newest_t: None,
            names: Vec::new(),
            cut: None,
        };
        let read = reader.read_line()?;
        let parsed = serde_json::from_slice::<Header>(&reader.buffer);
        let header = match (read, parsed) {
            (Read1::End, _) => return Err(err(0, "empty trace: no header".into())),
            // An unterminated header that is whole (a hand-made file) still counts.
            (Read1::Line | Read1::Cut(_), Ok(header)) => header,
            (Read1::Line, Err(e)) => return Err(err(1, format!("bad header: {e}"))),
            (Read1::Cut(why), Err(_)) => return Err(err(1, format!("the header is incomplete: {why}"))),
        };
        if header.format != FORMAT {
            return Err(err(
                1,
                format!("bad header: format \"{}\" is not \"{FORMAT}\"", header.format),
            ));
        }
        if header.version != VERSION {
            return Err(err(
                1,
                format!(
                    "bad header: format version {} (this build reads version {VERSION})",
                    header.version
                ),
            ));
        }
        let variables: Vec<(String, VarType)> = header.variables.iter().map(|(n, t)| (n.clone(), *t)).collect();
        let position: HashMap<&str, usize> = variables
            .iter()
            .enumerate()
            .map(|(i, (n, _))| (n.as_str(), i))
            .collect();
        for c in &header.task_classes {
            if reader.classes.insert(c.name.clone(), reader.roles.len()).is_some() {
                return Err(err(1, format!("bad header: task class \"{}\" appears twice", c.name)));
            }
            if !(u64::from(MIN_CYCLE_US)..=u64::from(MAX_CYCLE_US)).contains(&c.cycle_us) {
                return Err(err(
                    1,
                    format!(
                        "bad header: task class \"{}\" has cycle_us {}: a cycle time is {MIN_CYCLE_US} … {MAX_CYCLE_US} µs",
                        c.name, c.cycle_us
                    ),
                ));
            }
            let mut roles = HashMap::new();
            let mut slots = [Vec::new(), Vec::new()];
            for (k, (list, is_input)) in [(&c.inputs, true), (&c.outputs, false)].into_iter().enumerate() {
                for v in list {
                    let Some(&i) = position.get(v.as_str()) else {
                        return Err(err(
                            1,
                            format!("bad header: variable \"{v}\" of task class \"{}\" has no type", c.name),
                        ));
                    };
                    roles.insert(v.clone(), (is_input, i));
                    slots[k].push(Slot {
                        name: v.as_bytes().into(),
                        index: i,
                        ty: variables[i].1,
                    });
                }
            }
            let [inputs, outputs] = slots;
            reader.layouts.push(ClassLayout {
                name: c.name.as_bytes().into(),
                inputs: Slots::new(inputs),
                outputs: Slots::new(outputs),
            });
            reader.roles.push(roles);
        }
        reader.fast = fast::fast_names(&reader.layouts);
        reader.last_t = vec![None; header.task_classes.len()];
        reader.variables = variables;
        reader.header = header;
        Ok(reader)
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The header's variables in order (records refer to them by index).
    pub fn variables(&self) -> &[(String, VarType)] {
        &self.variables
    }

    /// Where the trace was cut short, once the reading reached that point (`next_record` then
    /// returned `None`).
    pub fn cut(&self) -> Option<&Cut> {
        self.cut.as_ref()
    }

    /// The next line into `buffer`, bounded by [`MAX_LINE_BYTES`].
    fn read_line(&mut self) -> Result<Read1, TraceError> {
        self.buffer.clear();
        let read = match self.failed.take() {
            Some(e) => Err(e),
            None => (&mut self.input)
                .take(MAX_LINE_BYTES as u64 + 1)
                .read_until(b'\n', &mut self.buffer),
        };
        self.line += 1;
        match read {
            Ok(0) => Ok(Read1::End),
            Ok(_) if self.buffer.last() == Some(&b'\n') => {
                self.buffer.pop();
                Ok(Read1::Line)
            }
            Ok(_) if self.buffer.len() > MAX_LINE_BYTES => Err(self.err(format!(
                "the line is longer than {} MiB: not a trace line",
                MAX_LINE_BYTES >> 20
            ))),
            Ok(n) => Ok(Read1::Cut(format!(
                "the last line is incomplete ({n} bytes, no end of line)"
            ))),
            // A gzip stream without its end: what was flushed before the crash has been read.
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(Read1::Cut(match self.buffer.len() {
                0 => "the gzip stream ends without its trailer".to_string(),
                n => format!("the gzip stream ends without its trailer, {n} bytes into the next line"),
            })),
            Err(e) => Err(self.err(format!("cannot read: {e}"))),
        }
    }

    /// The next record, or `None` at the end (see [`TraceReader::cut`] for whether the trace was
    /// whole).
    pub fn next_record(&mut self) -> Result<Option<Record>, TraceError> {
        let mut record = Record::default();
        Ok(self.read_into(&mut record)?.then_some(record))
    }

    /// Reads the next record into `record`, reusing its buffers: `false` at the end (see
    /// [`TraceReader::cut`] for whether the trace was whole).
    pub fn read_into(&mut self, record: &mut Record) -> Result<bool, TraceError> {
        if self.cut.is_some() {
            return Ok(false);
        }
        if self.fast && self.read_in_place(record) {
            self.check_time(record)?;
            return Ok(true);
        }
        let cut = match self.read_line()? {
            Read1::End => return Ok(false),
            Read1::Line => None,
            Read1::Cut(why) => Some(why),
        };
        match (self.parse(record), cut) {
            (Ok(()), None) => {}
            (Err(e), None) => return Err(e),
            // An unterminated last line that is whole (a hand-edited file) still counts.
            (Ok(()), Some(_)) if !self.buffer.is_empty() => {}
            (_, Some(why)) => {
                self.cut = Some(Cut {
                    after_line: self.line - 1,
                    last_t_us: self.newest_t,
                    why,
                });
                return Ok(false);
            }
        }
        self.check_time(record)?;
        Ok(true)
    }

    /// Reads the next line by the fast path where it lies in the input's buffer, if it is whole
    /// there: no copy into a line buffer, no search for its end before reading it, no check of
    /// the whole line's encoding. `false` (nothing consumed): the line is not whole in the buffer
    /// (it straddles the buffer's end; about one line in a thousand), the fast path declines it,
    /// or the input failed (the error is kept for [`TraceReader::read_line`] to report). A line
    /// read here lies within one buffer (256 KiB), far below [`MAX_LINE_BYTES`].
    fn read_in_place(&mut self, record: &mut Record) -> bool {
        let bytes = match self.input.fill_buf() {
            Ok(bytes) => bytes,
            Err(e) => {
                self.failed = Some(e);
                return false;
            }
        };
        let Some((f, end)) = fast::parse(bytes, &self.layouts, &mut record.inputs, &mut record.outputs) else {
            return false;
        };
        if bytes.get(end) != Some(&b'\n') {
            return false;
        }
        if !Self::set_fields(&mut self.names, record, f) {
            return false;
        }
        self.line += 1;
        record.line = self.line;
        self.input.consume(end + 1);
        true
    }

    /// Takes the fast path's fields into `record` (its inputs and outputs are already there);
    /// `false` if a state or reason is not UTF-8 text (the slow path words the error).
    fn set_fields(names: &mut Vec<Arc<str>>, record: &mut Record, f: fast::Fields<'_>) -> bool {
        let name = |names: &mut Vec<Arc<str>>, s: Option<&[u8]>| match s {
            Some(s) => Self::intern(names, s).map(Some),
            None => Some(None),
        };
        let (Some(state), Some(reason)) = (name(names, f.state), name(names, f.reason)) else {
            return false;
        };
        record.class = f.class;
        record.t_us = f.t_us;
        record.cycle = f.cycle;
        record.state = state;
        record.reason = reason;
        record.violation = f.violation;
        record.job = None;
        true
    }

    /// A cycle's time must be a release of its class (a multiple of its cycle time), after the
    /// class's previous one, and within what the runtime's clock holds.
    fn check_time(&mut self, r: &Record) -> Result<(), TraceError> {
        let c = &self.header.task_classes[r.class];
        let problem = if r.t_us > MAX_T_US {
            Some(format!(
                "t_us {} is beyond the latest time a trace can hold ({MAX_T_US})",
                r.t_us
            ))
        } else if !r.t_us.is_multiple_of(c.cycle_us) {
            Some(format!(
                "t_us {} is not a release of task class \"{}\" (a multiple of its cycle time, {} µs)",
                r.t_us, c.name, c.cycle_us
            ))
        } else {
            self.last_t[r.class].filter(|&last| r.t_us <= last).map(|last| {
                format!(
                    "t_us {} is not after the previous cycle of task class \"{}\" (t_us {last})",
                    r.t_us, c.name
                )
            })
        };
        if let Some(message) = problem {
            return Err(self.err(message));
        }
        self.last_t[r.class] = Some(r.t_us);
        self.newest_t = Some(self.newest_t.map_or(r.t_us, |t| t.max(r.t_us)));
        Ok(())
    }

    /// The state or reason name `s`, shared with earlier records that had it; the one found
    /// last is looked at first (record after record has the same state). Only a name not seen
    /// before is checked as UTF-8 text: `None` if it is not.
    fn intern(names: &mut Vec<Arc<str>>, s: &[u8]) -> Option<Arc<str>> {
        if let Some(last) = names.last()
            && fast::same_bytes(last.as_bytes(), s)
        {
            return Some(Arc::clone(last));
        }
        let n = match names.iter().position(|n| n.as_bytes() == s) {
            Some(k) => names.remove(k),
            None => std::str::from_utf8(s).ok()?.into(),
        };
        names.push(Arc::clone(&n));
        Some(n)
    }

    /// Parses the line in the buffer into `record`.
    fn parse(&mut self, record: &mut Record) -> Result<(), TraceError> {
        record.line = self.line;
        if let Some((f, _)) = self
            .fast
            .then(|| fast::parse(&self.buffer, &self.layouts, &mut record.inputs, &mut record.outputs))
            .flatten()
            .filter(|&(_, end)| end == self.buffer.len())
            && Self::set_fields(&mut self.names, record, f)
        {
            return Ok(());
        }
        let text = std::str::from_utf8(&self.buffer)
            .map_err(|e| self.err(format!("malformed record: not UTF-8 text: {e}")))?;
        let l: Line<'_> = serde_json::from_str(text).map_err(|e| self.err(format!("malformed record: {e}")))?;
        let Some(&class) = self.classes.get(l.task) else {
            let known: Vec<&str> = self.header.task_classes.iter().map(|c| c.name.as_str()).collect();
            return Err(self.err(format!(
                "unknown task class \"{}\" (the header has {})",
                l.task,
                known.join(", ")
            )));
        };
        record.inputs.clear();
        record.outputs.clear();
        for (pairs, input) in [(&l.inputs, true), (&l.out, false)] {
            for (name, json) in &pairs.0 {
                let i = match self.roles[class].get(*name) {
                    Some(&(role, i)) if role == input => i,
                    _ => {
                        let what = if input { "input" } else { "output" };
                        return Err(self.err(format!(
                            "variable \"{name}\" is not an {what} of task class \"{}\" in the header",
                            l.task
                        )));
                    }
                };
                let value = value_from_json(json, self.variables[i].1)
                    .map_err(|m| self.err(format!("variable \"{name}\": {m}")))?;
                if input { &mut record.inputs } else { &mut record.outputs }.push((i, value));
            }
        }
        record.class = class;
        record.t_us = l.t_us;
        record.cycle = l.cycle;
        // Text from serde_json is UTF-8: interning it always finds or makes a name.
        record.state = l.state.and_then(|s| Self::intern(&mut self.names, s.as_bytes()));
        record.reason = l.reason.and_then(|s| Self::intern(&mut self.names, s.as_bytes()));
        record.violation = l.violation;
        record.job = l.job.map(Box::new);
        Ok(())
    }

    fn err(&self, message: String) -> TraceError {
        TraceError {
            file: self.file.clone(),
            line: self.line,
            message,
        }
    }
}

/// Records read in one go by [`ReadAhead`].
const BATCH: usize = 512;

/// What the read-ahead thread hands over.
enum Batch {
    Records(Vec<Record>),
    Error(TraceError),
}

/// Reads a trace on a thread of its own, batches ahead of its consumer: parsing the next records
/// overlaps with whatever the consumer does with the previous ones (replay runs the programs).
pub struct ReadAhead {
    rx: Receiver<Batch>,
    back: SyncSender<Vec<Record>>,
    current: Vec<Record>,
    pos: usize,
    thread: Option<JoinHandle<Option<Cut>>>,
    cut: Option<Cut>,
}

impl ReadAhead {
    /// Starts reading `reader`'s records (after its header) on a new thread.
    pub fn start(mut reader: TraceReader) -> std::io::Result<ReadAhead> {
        let (tx, rx) = sync_channel::<Batch>(4);
        let (back, returned) = sync_channel::<Vec<Record>>(8);
        let thread = std::thread::Builder::new().name("trace-reader".into()).spawn(move || {
            loop {
                let mut batch = returned.try_recv().unwrap_or_default();
                batch.resize_with(BATCH, Record::default);
                let mut n = 0;
                let mut failed = None;
                while n < BATCH {
                    match reader.read_into(&mut batch[n]) {
                        Ok(true) => n += 1,
                        Ok(false) => break,
                        Err(e) => {
                            failed = Some(e);
                            break;
                        }
                    }
                }
                batch.truncate(n);
                let more = n == BATCH;
                // A consumer that stopped early has dropped its end: then this ends too.
                if n > 0 && tx.send(Batch::Records(batch)).is_err() {
                    return None;
                }
                if let Some(e) = failed {
                    let _ = tx.send(Batch::Error(e));
                    return None;
                }
                if !more {
                    return reader.cut().cloned();
                }
            }
        })?;
        Ok(ReadAhead {
            rx,
            back,
            current: Vec::new(),
            pos: 0,
            thread: Some(thread),
            cut: None,
        })
    }

    /// The next record, or `None` at the end (then [`ReadAhead::cut`] says whether the trace was
    /// whole).
    pub fn next_record(&mut self) -> Result<Option<&Record>, TraceError> {
        if self.pos == self.current.len() {
            let done = std::mem::take(&mut self.current);
            // Back to the reader for reuse; should it be gone, the buffers are simply freed.
            let _ = self.back.try_send(done);
            self.pos = 0;
            match self.rx.recv() {
                Ok(Batch::Records(batch)) => self.current = batch,
                Ok(Batch::Error(e)) => return Err(e),
                Err(_) => {
                    if let Some(thread) = self.thread.take() {
                        // A panic in the reader is a bug; it is reported as such by the join.
                        self.cut = thread.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
                    }
                    return Ok(None);
                }
            }
        }
        self.pos += 1;
        Ok(Some(&self.current[self.pos - 1]))
    }

    /// Where the trace was cut short, once [`ReadAhead::next_record`] returned `None`.
    pub fn cut(&self) -> Option<&Cut> {
        self.cut.as_ref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A header of two classes with a variable of every type (one with a name JSON escapes
    /// differently is left out: such traces never take the fast path, see `fast_names`).
    fn header() -> String {
        serde_json::json!({
            "format": FORMAT, "version": VERSION, "config_digest": "x", "bus": "sim",
            "task_classes": [
                {"name": "fast", "cycle_us": 10000, "inputs": ["b", "i", "u"], "outputs": ["d", "r", "position_mm"]},
                {"name": "main", "cycle_us": 50000, "inputs": ["r"], "outputs": ["b"]}
            ],
            "variables": {"b": "BOOL", "i": "INT", "u": "UINT", "d": "DINT", "r": "REAL", "position_mm": "REAL"}
        })
        .to_string()
    }

    /// Reads `line` (a record of class "fast" or "main" at t = 0) with the fast path on or off.
    fn read(line: &str, fast: bool) -> Result<Option<Record>, TraceError> {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.jsonl");
        std::fs::write(&path, format!("{}\n{line}\n", header())).expect("write");
        let mut reader = TraceReader::open(&path).expect("header");
        reader.fast &= fast;
        let mut r = Record::default();
        reader.read_into(&mut r).map(|more| more.then_some(r))
    }

    /// A JSON value token of any type, in the forms the recorder writes and some it does not.
    fn token() -> impl Strategy<Value = String> {
        prop_oneof![
            Just("true".to_string()),
            Just("false".to_string()),
            Just("null".to_string()),
            any::<i64>().prop_map(|i| i.to_string()),
            (-40_000i32..70_000).prop_map(|i| i.to_string()),
            any::<f64>().prop_map(|x| serde_json::json!(x).to_string()),
            (-1e6f64..1e6).prop_map(|x| serde_json::json!(x).to_string()),
            // Decimals of few digits and exponents near the ends of the exact powers of ten.
            (any::<i32>(), 0u64..10_000_000, 1usize..12).prop_map(|(a, b, k)| format!("{a}.{b:0k$}")),
            (any::<i64>(), -40i32..40).prop_map(|(m, e)| format!("{m}e{e}")),
            // Significands on both sides of 2^53, where `str::parse` changes method.
            (0u64..1 << 54, 1usize..19, any::<bool>()).prop_map(|(m, k, neg)| {
                let digits = format!("{m:020}");
                let whole = digits[..20 - k].trim_start_matches('0');
                let whole = if whole.is_empty() { "0" } else { whole };
                format!("{}{whole}.{}", if neg { "-" } else { "" }, &digits[20 - k..])
            }),
            prop::sample::select(vec![
                "-0",
                "0.0",
                "-0.0",
                "1e2",
                "1E+2",
                "2.5e-3",
                "01",
                "1.",
                ".5",
                "+1",
                "1e400",
                "-1e400",
                "123456789012345678901",
                "18446744073709551615",
                "-9223372036854775808",
                "9007199254740993",
                "9007199254740992.0",
                "9007199254740993.0",
                "0.000123",
                "-0.5",
                "123.456e-7",
                "4.5E+21",
                "0.1e23",
                "1e22",
                "1e-22",
                "1.7976931348623157e308",
                "5e-324",
                "2.2250738585072014e-308",
                "1.00000000000000000001",
                "12345678901234567.89",
                "\"x\"",
                "[]",
                "1 ",
            ])
            .prop_map(str::to_string),
        ]
    }

    proptest! {
        /// Whatever the fast path accepts, it reads exactly as serde_json does; whatever it
        /// declines, the outcome (record or error message) is serde_json's.
        #[test]
        fn the_fast_path_reads_every_line_as_the_slow_path_does(
            main in any::<bool>(),
            values in proptest::collection::vec((0usize..6, token()), 0..6),
            extra in prop::sample::select(vec![
                "", ",\"state\":\"READY\"", ",\"state\":\"MOTION\",\"reason\":\"x\"", ",\"violation\":true",
                ",\"violation\":false", ",\"state\":\"RE\\u0041DY\"", " ", ",\"state\":\"\\\"\"",
            ]),
            space in any::<bool>(),
        ) {
            let names = ["b", "i", "u", "d", "r", "position_mm"];
            let (task, inputs, outputs): (&str, &[usize], &[usize]) =
                if main { ("main", &[4], &[0]) } else { ("fast", &[0, 1, 2], &[3, 4, 5]) };
            let sep = if space { ", " } else { "," };
            let pairs = |wanted: &[usize]| {
                values
                    .iter()
                    .filter(|(k, _)| wanted.contains(k) || *k == 5 && main)
                    .map(|(k, v)| format!("\"{}\":{v}", names[*k]))
                    .collect::<Vec<_>>()
                    .join(sep)
            };
            let line = format!(
                "{{\"t_us\":0,\"task\":\"{task}\",\"cycle\":0,\"in\":{{{}}},\"out\":{{{}}}{extra}}}",
                pairs(inputs),
                pairs(outputs)
            );
            let (fast, slow) = (read(&line, true), read(&line, false));
            // NaN == NaN for this comparison, as the trace's `same` has it.
            let key = |r: &Result<Option<Record>, TraceError>| {
                format!("{:?}", r.as_ref().map_err(|e| (e.line, &e.message)))
            };
            prop_assert_eq!(key(&fast), key(&slow), "{}", line);
        }
    }

    /// Every record of `path`, read with the fast path on or off.
    fn read_all(path: &Path, fast: bool) -> Vec<Record> {
        let mut reader = TraceReader::open(path).expect("header");
        reader.fast &= fast;
        let mut records = Vec::new();
        while let Some(r) = reader.next_record().expect("valid") {
            records.push(r);
        }
        assert!(reader.cut().is_none(), "whole");
        records
    }

    #[test]
    fn records_read_in_place_are_those_read_line_by_line_across_buffer_ends() {
        // About 2 MB of lines of varying length: some straddle the ends of the plain reader's
        // and the inflater's 256 KiB buffers, which the in-place reading leaves to the line
        // reader; some take the slow path (spaces) in between.
        let mut text = header();
        for n in 0..20_000u64 {
            let (t, c) = (n * 10_000, n);
            let x = (n as f64 * 0.37).sin() * 10f64.powi((n % 7) as i32);
            let line = match n % 5 {
                0 => format!(
                    r#"{{"t_us":{t},"task":"fast","cycle":{c},"in":{{"b":true,"u":{}}},"out":{{"r":{x},"position_mm":{}}},"state":"READY"}}"#,
                    n % 65_536,
                    -x
                ),
                1 => format!(
                    r#"{{"t_us":{t},"task":"fast","cycle":{c},"in":{{}},"out":{{"d":{}}},"state":"MOTION","reason":"r{}"}}"#,
                    n as i64 - 9_000,
                    n % 3
                ),
                2 => format!(
                    r#"{{"t_us":{t},"task":"fast","cycle":{c},"in":{{"i":-{}}},"out":{{"position_mm":null}},"violation":true}}"#,
                    n % 30_000
                ),
                3 => format!(
                    r#"{{"t_us": {t}, "task": "fast", "cycle": {c}, "in": {{"b": false}}, "out": {{"r": {x}}}}}"#
                ),
                _ => format!(
                    r#"{{"t_us":{t},"task":"fast","cycle":{c},"in":{{"u":7,"b":false}},"out":{{"position_mm":{x},"r":1e-3,"d":0}}}}"#
                ),
            };
            text.push('\n');
            text.push_str(&line);
        }
        text.push('\n');
        let dir = tempfile::tempdir().expect("tempdir");
        let plain = dir.path().join("t.jsonl");
        std::fs::write(&plain, &text).expect("write");
        let gz = dir.path().join("t.jsonl.gz");
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        std::io::Write::write_all(&mut e, text.as_bytes()).expect("in memory");
        std::fs::write(&gz, e.finish().expect("in memory")).expect("write");
        let slow = read_all(&plain, false);
        assert_eq!(slow.len(), 20_000);
        assert_eq!(slow.last().map(|r| r.line), Some(20_001));
        // NaN (null) compares unequal to itself: compare as the debug form shows it.
        let key = |records: &[Record]| format!("{records:?}");
        assert_eq!(key(&read_all(&plain, true)), key(&slow));
        assert_eq!(key(&read_all(&gz, true)), key(&slow));
    }

    #[test]
    fn the_fast_path_takes_the_recorders_lines() {
        let line = r#"{"t_us":0,"task":"fast","cycle":0,"in":{"b":true,"u":7},"out":{"r":-1.5,"position_mm":null},"state":"READY"}"#;
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.jsonl");
        std::fs::write(&path, header()).expect("write");
        let reader = TraceReader::open(&path).expect("header");
        assert!(reader.fast);
        let (mut inputs, mut outputs) = (Vec::new(), Vec::new());
        let (_, end) = fast::parse(line.as_bytes(), &reader.layouts, &mut inputs, &mut outputs).expect("fast");
        assert_eq!(end, line.len());
        let mut record = read(line, true).expect("valid").expect("a record");
        record.line = 0;
        assert_eq!(record.inputs, vec![(0, Value::Bool(true)), (5, Value::Uint(7))]);
        // The header's variables are in name order: b d i position_mm r u.
        assert_eq!(record.outputs[0], (4, Value::Real(-1.5)));
        assert!(matches!(record.outputs[1], (3, Value::Real(x)) if x.is_nan()));
        assert_eq!(record.state.as_deref(), Some("READY"));
    }
}
