//! Reading traces strictly: every problem is an error with the file and line number.

use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::io::{BufRead, BufReader, Lines, Read};
use std::path::Path;

use serde::Deserialize;

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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Line {
    t_us: u64,
    task: String,
    cycle: u64,
    #[serde(rename = "in")]
    inputs: serde_json::Map<String, serde_json::Value>,
    out: serde_json::Map<String, serde_json::Value>,
    #[serde(default)]
    state: Option<String>,
    #[serde(default)]
    reason: Option<String>,
    #[serde(default)]
    violation: bool,
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
    /// Changed inputs.
    pub inputs: Vec<(String, Value)>,
    /// Changed outputs.
    pub outputs: Vec<(String, Value)>,
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
    lines: Lines<BufReader<Box<dyn Read>>>,
    line: usize,
    header: Header,
    classes: HashMap<String, usize>,
    /// Per class: variable name → true for inputs, false for outputs.
    roles: Vec<HashMap<String, bool>>,
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
        let mut lines = BufReader::with_capacity(1 << 16, input).lines();
        let first = match lines.next() {
            None => return Err(err(0, "empty trace: no header".into())),
            Some(Err(e)) => return Err(err(1, format!("cannot read: {e}"))),
            Some(Ok(l)) => l,
        };
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
        let mut roles = Vec::new();
        for c in &header.task_classes {
            let mut m = HashMap::new();
            for (list, input) in [(&c.inputs, true), (&c.outputs, false)] {
                for v in list {
                    if !header.variables.contains_key(v) {
                        return Err(err(
                            1,
                            format!("bad header: variable \"{v}\" of task class \"{}\" has no type", c.name),
                        ));
                    }
                    m.insert(v.clone(), input);
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
            lines,
            line: 1,
            header,
            classes,
            roles,
        })
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The next record, or `None` at the end.
    pub fn next_record(&mut self) -> Result<Option<Record>, TraceError> {
        let text = match self.lines.next() {
            None => return Ok(None),
            Some(r) => {
                self.line += 1;
                r.map_err(|e| self.err(format!("cannot read: {e}")))?
            }
        };
        let l: Line = serde_json::from_str(&text).map_err(|e| self.err(format!("malformed record: {e}")))?;
        let Some(&class) = self.classes.get(&l.task) else {
            let known: Vec<&str> = self.header.task_classes.iter().map(|c| c.name.as_str()).collect();
            return Err(self.err(format!(
                "unknown task class \"{}\" (the header has {})",
                l.task,
                known.join(", ")
            )));
        };
        let mut parts = [Vec::new(), Vec::new()];
        for (k, (map, input)) in [(&l.inputs, true), (&l.out, false)].into_iter().enumerate() {
            for (name, json) in map {
                match self.roles[class].get(name) {
                    Some(&role) if role == input => {}
                    _ => {
                        let what = if input { "input" } else { "output" };
                        return Err(self.err(format!(
                            "variable \"{name}\" is not an {what} of task class \"{}\" in the header",
                            l.task
                        )));
                    }
                }
                let ty = self.header.variables[name];
                let value = value_from_json(json, ty).map_err(|m| self.err(format!("variable \"{name}\": {m}")))?;
                parts[k].push((name.clone(), value));
            }
        }
        let [inputs, outputs] = parts;
        Ok(Some(Record {
            line: self.line,
            class,
            t_us: l.t_us,
            cycle: l.cycle,
            inputs,
            outputs,
            state: l.state,
            reason: l.reason,
            violation: l.violation,
        }))
    }

    fn err(&self, message: String) -> TraceError {
        TraceError {
            file: self.file.clone(),
            line: self.line,
            message,
        }
    }
}
