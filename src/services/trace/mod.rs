//! IO traces: every class cycle's inputs, outputs and main state, recorded to JSON Lines, read
//! back strictly, and replayed deterministically against the programs.
//!
//! Format (version 1): the first line is a header —
//! `{"format": "pkm-plc trace", "version": 1, "config_digest": …, "bus": …, "task_classes":
//! [{"name", "cycle_us", "inputs": [..], "outputs": [..]}], "variables": {NAME: TYPE}}` — and every
//! further line one class cycle: `{"t_us", "task", "cycle", "in": {VAR: VALUE}, "out": {VAR:
//! VALUE}, "state", "reason"?, "violation"?}`. `in` and `out` hold the variables that changed
//! since that class's previous record; a class's first record holds all of them.

pub mod expected;
pub mod export;
pub mod fast;
mod inflate;
pub mod path;
pub mod read;
pub mod record;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::image::{Value, VarType};

/// The `format` value of a header.
pub const FORMAT: &str = "pkm-plc trace";
/// The format version written and read.
pub const VERSION: u32 = 1;

/// The first line of a trace.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`VERSION`].
    pub version: u32,
    /// Digest of the configuration and I/O map the trace was recorded with.
    pub config_digest: String,
    /// The machine it was recorded on (`replay` without `--config` or `--machine` takes that
    /// machine's own configuration where the digest is its).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<String>,
    /// The bus it was recorded on (`sim`, `none`, …).
    pub bus: String,
    /// The task classes with the variables each latches and publishes.
    pub task_classes: Vec<ClassHeader>,
    /// Every variable that appears, with its type.
    pub variables: BTreeMap<String, VarType>,
    /// The NC program the run executed (`run --program`): a replay plans it again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub program: Option<TraceProgram>,
    /// The programs the operator could load from the screen (`run --programs`), numbered after
    /// `program`: a replay plans them again.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub library: Vec<TraceProgram>,
    /// The tool table the programs were read with (its file and text): a replay reads them
    /// with it again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_table: Option<TraceProgram>,
    /// The work offsets the programs were planned with, where they were not the
    /// configuration's (a parameter file's): a replay plans them with these again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offsets: Option<TraceOffsets>,
}

impl Header {
    /// The header's `program` and `library` of a run with `library`.
    pub fn programs(library: Option<&pkm_api::library::NcLibrary>) -> (Option<TraceProgram>, Vec<TraceProgram>) {
        let Some(l) = library else {
            return (None, Vec::new());
        };
        let mut all = l.jobs.iter().map(|j| TraceProgram {
            file: j.file.clone(),
            text: j.text.clone(),
        });
        let first = if l.autostart { all.next() } else { None };
        (first, all.collect())
    }
}

/// A job the operator made on the screen (MDI lines, a program from a line), as a trace
/// carries it: in the record of the cycle whose `HMI_NC_PROGRAM` first took its number, so
/// that a replay plans it again before that cycle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TraceJob {
    /// Its number, as `NC_PROGRAM` holds it.
    pub number: i16,
    /// Where the tool stood (machine frame).
    pub start: [f64; 6],
    /// The MDI lines.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mdi: Option<String>,
    /// The program and line it runs from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_line: Option<TraceFromLine>,
    /// The work offsets it was planned with, where a touch-off had changed them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offsets: Option<TraceOffsets>,
    /// The tool table it was planned with (its text), where it had changed since the run's
    /// start (an entry edited on the screen, a program's `G10 L1`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_table: Option<String>,
}

/// Work offsets as a trace carries them: G54 … G59's origins and G28's and G30's positions
/// (machine frame; x y z a b c each).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TraceOffsets {
    /// G54 … G59.
    pub origins: [[f64; 6]; 6],
    /// G28, G30.
    pub homes: [[f64; 6]; 2],
}

impl From<pkm_api::offsets::WorkOffsets> for TraceOffsets {
    fn from(o: pkm_api::offsets::WorkOffsets) -> Self {
        TraceOffsets {
            origins: o.origins,
            homes: o.homes,
        }
    }
}

impl From<TraceOffsets> for pkm_api::offsets::WorkOffsets {
    fn from(o: TraceOffsets) -> Self {
        pkm_api::offsets::WorkOffsets {
            origins: o.origins,
            homes: o.homes,
        }
    }
}

/// A program run from a line, in a [`TraceJob`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TraceFromLine {
    /// The program's number.
    pub program: i16,
    /// The line.
    pub line: u32,
}

impl TraceJob {
    /// The job of number `number` made of `spec`.
    pub fn of(number: i16, spec: &pkm_api::screen_jobs::ScreenJobSpec) -> TraceJob {
        use pkm_api::screen_jobs::ScreenJobKind;
        let mut start = [0.0; 6];
        start.copy_from_slice(&spec.start[..6]);
        let (mdi, from_line) = match &spec.kind {
            ScreenJobKind::Mdi { text } => (Some(text.clone()), None),
            ScreenJobKind::FromLine { program, line } => (
                None,
                Some(TraceFromLine {
                    program: *program,
                    line: *line,
                }),
            ),
        };
        TraceJob {
            number,
            start,
            mdi,
            from_line,
            offsets: spec.offsets.map(TraceOffsets::from),
            tool_table: spec.tool_table.clone(),
        }
    }

    /// What the job was made of, or why the record does not say (neither or both kinds).
    pub fn spec(&self) -> Result<pkm_api::screen_jobs::ScreenJobSpec, String> {
        use pkm_api::screen_jobs::{ScreenJobKind, ScreenJobSpec};
        let kind = match (&self.mdi, &self.from_line) {
            (Some(text), None) => ScreenJobKind::Mdi { text: text.clone() },
            (None, Some(f)) => ScreenJobKind::FromLine {
                program: f.program,
                line: f.line,
            },
            _ => return Err(format!("job {}: exactly one of \"mdi\" and \"from_line\"", self.number)),
        };
        let mut start = [0.0; pkm_api::trajectory::MAX_AXES];
        start[..6].copy_from_slice(&self.start);
        Ok(ScreenJobSpec {
            kind,
            start,
            offsets: self.offsets.map(Into::into),
            tool_table: self.tool_table.clone(),
        })
    }
}

/// An NC program as a trace carries it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TraceProgram {
    /// Its file, as the run named it.
    pub file: String,
    /// Its text.
    pub text: String,
}

/// One task class in a header.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassHeader {
    /// Its name.
    pub name: String,
    /// Its cycle time (µs).
    pub cycle_us: u64,
    /// The variables its cycles latch.
    pub inputs: Vec<String>,
    /// The variables its cycles publish.
    pub outputs: Vec<String>,
}

/// A value as JSON: numbers and booleans; a non-finite REAL (which JSON cannot hold) as null.
pub fn value_to_json(v: Value) -> serde_json::Value {
    match v {
        Value::Bool(b) => serde_json::Value::Bool(b),
        Value::Int(i) => i.into(),
        Value::Uint(u) => u.into(),
        Value::Dint(d) => d.into(),
        Value::Real(r) => serde_json::Number::from_f64(r).map_or(serde_json::Value::Null, serde_json::Value::Number),
    }
}

/// Why a JSON value is not a value of a variable's type.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ValueError {
    /// Not true or false.
    #[error("expected BOOL (true or false), got {got}")]
    NotBool {
        /// What the trace holds.
        got: serde_json::Value,
    },
    /// Not an integer in the type's range.
    #[error("expected {ty} ({lo} … {hi}), got {got}")]
    OutOfRange {
        /// The type.
        ty: VarType,
        /// Its smallest value.
        lo: i64,
        /// Its largest value.
        hi: i64,
        /// What the trace holds.
        got: serde_json::Value,
    },
    /// Not a number (nor null, a non-finite REAL).
    #[error("expected REAL (a number), got {got}")]
    NotReal {
        /// What the trace holds.
        got: serde_json::Value,
    },
}

/// A JSON value as a value of type `ty`, or why it is not one.
pub fn value_from_json(v: &serde_json::Value, ty: VarType) -> Result<Value, ValueError> {
    let int = |lo: i64, hi: i64| {
        v.as_i64()
            .filter(|i| (lo..=hi).contains(i))
            .ok_or_else(|| ValueError::OutOfRange {
                ty,
                lo,
                hi,
                got: v.clone(),
            })
    };
    Ok(match ty {
        VarType::Bool => Value::Bool(v.as_bool().ok_or_else(|| ValueError::NotBool { got: v.clone() })?),
        VarType::Int => Value::Int(int(i16::MIN.into(), i16::MAX.into())? as i16),
        VarType::Uint => Value::Uint(int(0, u16::MAX.into())? as u16),
        VarType::Dint => Value::Dint(int(i32::MIN.into(), i32::MAX.into())? as i32),
        VarType::Real => match v {
            serde_json::Value::Null => Value::Real(f64::NAN),
            other => Value::Real(
                other
                    .as_f64()
                    .ok_or_else(|| ValueError::NotReal { got: other.clone() })?,
            ),
        },
    })
}

/// Whether two values are the same for trace purposes (NaN equals NaN, as JSON null).
#[inline]
pub fn same(a: Value, b: Value) -> bool {
    match (a, b) {
        (Value::Real(x), Value::Real(y)) => x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
        (x, y) => x == y,
    }
}

/// A digest of the configuration and the I/O map (FNV-1a, 64 bit, over their JSON with the
/// whitespace normalised): traces say what they were recorded with, replays check it.
pub fn digest(parts: &[&serde_json::Value]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for part in parts {
        for b in part.to_string().bytes().chain([0u8]) {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    format!("fnv1a64:{h:016x}")
}

/// The digest of a loaded configuration together with its I/O map (`embedded`: the machine's
/// built-in map, which the built-in configuration names).
pub fn config_digest(
    loaded: &crate::runtime::config::LoadedConfig,
    embedded: Option<pkm_api::machine::EmbeddedFile>,
) -> Result<String, crate::runtime::config::ConfigError> {
    let map = match crate::services::io::map::io_map_text(loaded, embedded)? {
        Some((text, _)) => serde_json::from_str(&text).unwrap_or(serde_json::Value::String(text)),
        None => serde_json::Value::Null,
    };
    Ok(digest(&[&loaded.json, &map]))
}
