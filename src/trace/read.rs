//! Reading traces strictly: every problem is an error with the file and line number.

use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use serde::Deserialize;
use serde::de::{MapAccess, Visitor};

use super::{FORMAT, Header, VERSION, value_from_json};
use crate::image::Value;

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

/// A record line, parsed without copying names out of the line.
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
    #[serde(default)]
    state: Option<String>,
    #[serde(default)]
    reason: Option<String>,
    #[serde(default)]
    violation: bool,
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
#[derive(Debug, Clone, PartialEq)]
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
    pub state: Option<String>,
    /// The error reason, if any.
    pub reason: Option<String>,
    /// Whether a cycle time violation was delivered in this cycle.
    pub violation: bool,
}

/// Reads a trace record by record.
pub struct TraceReader {
    file: String,
    input: BufReader<Box<dyn Read>>,
    buffer: String,
    line: usize,
    header: Header,
    classes: HashMap<String, usize>,
    /// The header's variables in order, with their types.
    variables: Vec<(String, crate::image::VarType)>,
    /// Per class: variable name → (true for inputs, false for outputs; index in `variables`).
    roles: Vec<HashMap<String, (bool, usize)>>,
}

impl TraceReader {
    /// Opens a trace and reads its header.
    pub fn open(path: &Path) -> Result<TraceReader, TraceError> {
        let name = path.display().to_string();
        let err = |line: usize, message: String| TraceError {
            file: name.clone(),
            line,
            message,
        };
        let file = File::open(path).map_err(|e| err(0, format!("cannot open: {e}")))?;
        // A name ending in .gz is a gzip-compressed trace.
        let input: Box<dyn Read> = if path.extension().is_some_and(|e| e == "gz") {
            Box::new(flate2::read::MultiGzDecoder::new(file))
        } else {
            Box::new(file)
        };
        let mut input = BufReader::with_capacity(1 << 16, input);
        let mut first = String::new();
        match input.read_line(&mut first) {
            Ok(0) => return Err(err(0, "empty trace: no header".into())),
            Err(e) => return Err(err(1, format!("cannot read: {e}"))),
            Ok(_) => {}
        }
        let header: Header = serde_json::from_str(&first).map_err(|e| err(1, format!("bad header: {e}")))?;
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
        let variables: Vec<(String, crate::image::VarType)> =
            header.variables.iter().map(|(n, t)| (n.clone(), *t)).collect();
        let position: HashMap<&str, usize> = variables
            .iter()
            .enumerate()
            .map(|(i, (n, _))| (n.as_str(), i))
            .collect();
        let mut roles = Vec::new();
        for c in &header.task_classes {
            let mut m = HashMap::new();
            for (list, is_input) in [(&c.inputs, true), (&c.outputs, false)] {
                for v in list {
                    let Some(&i) = position.get(v.as_str()) else {
                        return Err(err(
                            1,
                            format!("bad header: variable \"{v}\" of task class \"{}\" has no type", c.name),
                        ));
                    };
                    m.insert(v.clone(), (is_input, i));
                }
            }
            roles.push(m);
        }
        let classes = header
            .task_classes
            .iter()
            .enumerate()
            .map(|(i, c)| (c.name.clone(), i))
            .collect();
        Ok(TraceReader {
            file: name,
            input,
            buffer: String::new(),
            line: 1,
            header,
            classes,
            variables,
            roles,
        })
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The header's variables in order (records refer to them by index).
    pub fn variables(&self) -> &[(String, crate::image::VarType)] {
        &self.variables
    }

    /// The next record, or `None` at the end.
    pub fn next_record(&mut self) -> Result<Option<Record>, TraceError> {
        let mut buffer = std::mem::take(&mut self.buffer);
        buffer.clear();
        let result = match self.input.read_line(&mut buffer) {
            Ok(0) => Ok(None),
            Ok(_) => {
                self.line += 1;
                self.parse(&buffer).map(Some)
            }
            Err(e) => {
                self.line += 1;
                Err(self.err(format!("cannot read: {e}")))
            }
        };
        self.buffer = buffer;
        result
    }

    fn parse(&self, text: &str) -> Result<Record, TraceError> {
        let l: Line<'_> = serde_json::from_str(text).map_err(|e| self.err(format!("malformed record: {e}")))?;
        let Some(&class) = self.classes.get(l.task) else {
            let known: Vec<&str> = self.header.task_classes.iter().map(|c| c.name.as_str()).collect();
            return Err(self.err(format!(
                "unknown task class \"{}\" (the header has {})",
                l.task,
                known.join(", ")
            )));
        };
        let mut parts = [Vec::with_capacity(l.inputs.0.len()), Vec::with_capacity(l.out.0.len())];
        for (k, (pairs, input)) in [(&l.inputs, true), (&l.out, false)].into_iter().enumerate() {
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
                parts[k].push((i, value));
            }
        }
        let [inputs, outputs] = parts;
        Ok(Record {
            line: self.line,
            class,
            t_us: l.t_us,
            cycle: l.cycle,
            inputs,
            outputs,
            state: l.state,
            reason: l.reason,
            violation: l.violation,
        })
    }

    fn err(&self, message: String) -> TraceError {
        TraceError {
            file: self.file.clone(),
            line: self.line,
            message,
        }
    }
}
