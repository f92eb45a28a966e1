//! History of the main variables, kept in memory for HistoryRead (raw values, OPC UA Part 11):
//! every change of a historized variable — `MainState`, `BusFault`, `NC_LINE`, `NC_STATE` and
//! every process-image variable with a unit (positions, speeds, feeds, overrides, times) — over
//! the last [`WINDOW_S`] seconds, at most [`MAX_SAMPLES`] a variable (the main cycle's rate over
//! the window). A value is kept as its time and a number (16 bytes; a Boolean as 0 or 1) and
//! read back in its node's data type, so the history of a run holds at most
//! 16 B × [`MAX_SAMPLES`] × the variables: 7.7 MB for 40 of them.
//!
//! This is the window a SCADA's trend or an operator's "what happened just now" needs; a
//! historian that keeps days subscribes instead (docs/opcua.md gives the recipe).

use std::collections::{HashMap, VecDeque};

use opcua::types::{DataTypeId, DataValue, DateTime, NodeId, StatusCode, Variant};

/// How far back the history reaches (s).
pub const WINDOW_S: f64 = 600.0;
/// The most values kept of one variable: one per main cycle (50 ms) over the window.
pub const MAX_SAMPLES: usize = 12_000;
/// The most values one read returns for a node; the rest come with its continuation point.
pub const MAX_VALUES_PER_READ: usize = 10_000;

/// 100 ns ticks in a second.
const TICKS_PER_S: i64 = 10_000_000;

/// How a series' numbers are read back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ValueKind {
    /// Boolean.
    Bool,
    /// Int16.
    Int16,
    /// UInt16.
    UInt16,
    /// Int32.
    Int32,
    /// UInt32.
    UInt32,
    /// Double.
    Double,
}

impl ValueKind {
    /// The kind of values of `data_type`, if it is kept.
    pub fn of(data_type: DataTypeId) -> Option<ValueKind> {
        Some(match data_type {
            DataTypeId::Boolean => ValueKind::Bool,
            DataTypeId::Int16 => ValueKind::Int16,
            DataTypeId::UInt16 => ValueKind::UInt16,
            DataTypeId::Int32 => ValueKind::Int32,
            DataTypeId::UInt32 => ValueKind::UInt32,
            DataTypeId::Double => ValueKind::Double,
            _ => return None,
        })
    }

    fn number(v: &Variant) -> Option<f64> {
        Some(match v {
            Variant::Boolean(b) => f64::from(u8::from(*b)),
            Variant::Int16(i) => f64::from(*i),
            Variant::UInt16(u) => f64::from(*u),
            Variant::Int32(i) => f64::from(*i),
            Variant::UInt32(u) => f64::from(*u),
            Variant::Double(d) => *d,
            _ => return None,
        })
    }

    fn variant(self, x: f64) -> Variant {
        match self {
            ValueKind::Bool => Variant::Boolean(x != 0.0),
            ValueKind::Int16 => Variant::Int16(x as i16),
            ValueKind::UInt16 => Variant::UInt16(x as u16),
            ValueKind::Int32 => Variant::Int32(x as i32),
            ValueKind::UInt32 => Variant::UInt32(x as u32),
            ValueKind::Double => Variant::Double(x),
        }
    }
}

/// One variable's values: (time in ticks, value), oldest first.
struct Series {
    kind: ValueKind,
    samples: VecDeque<(i64, f64)>,
}

/// Where a read goes on: the node, and the time after (or before, reading backwards) the last
/// value it returned.
#[derive(Clone, Debug, PartialEq)]
pub struct Continuation {
    node: NodeId,
    after_ticks: i64,
}

/// Why a read is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The node keeps no history.
    NotHistorized,
    /// Neither a start nor an end, or only one of them without a count.
    InvalidTimes,
    /// The continuation point is another node's.
    InvalidContinuation,
}

impl Refusal {
    /// The status a client is answered with.
    pub fn status(self) -> StatusCode {
        match self {
            Refusal::NotHistorized => StatusCode::BadHistoryOperationUnsupported,
            Refusal::InvalidTimes => StatusCode::BadInvalidTimestampArgument,
            Refusal::InvalidContinuation => StatusCode::BadContinuationPointInvalid,
        }
    }
}

/// The historized variables' values.
#[derive(Default)]
pub struct History {
    series: HashMap<NodeId, Series>,
}

impl History {
    /// Keeps the history of `node`, whose values are of `kind`.
    pub fn keep(&mut self, node: NodeId, kind: ValueKind) {
        self.series.insert(
            node,
            Series {
                kind,
                samples: VecDeque::new(),
            },
        );
    }

    /// Whether `node` is historized.
    pub fn keeps(&self, node: &NodeId) -> bool {
        self.series.contains_key(node)
    }

    /// Records `value` of `node` (if historized) at `at`, and forgets what fell out of the
    /// window.
    pub fn record(&mut self, node: &NodeId, at: DateTime, value: &Variant) {
        let (Some(series), Some(x)) = (self.series.get_mut(node), ValueKind::number(value)) else {
            return;
        };
        let ticks = at.checked_ticks();
        let oldest = ticks - (WINDOW_S * TICKS_PER_S as f64) as i64;
        while series
            .samples
            .front()
            .is_some_and(|(t, _)| *t < oldest || series.samples.len() >= MAX_SAMPLES)
        {
            series.samples.pop_front();
        }
        series.samples.push_back((ticks, x));
    }

    /// The raw values of `node` from `start` to `end` (either may be null: then `count` values
    /// from the other; `start` after `end` reads backwards), at most `count` (0: all) and
    /// [`MAX_VALUES_PER_READ`]; where more remain, where to go on. `from` is a continuation
    /// point of an earlier read.
    pub fn read_raw(
        &self,
        node: &NodeId,
        start: DateTime,
        end: DateTime,
        count: usize,
        from: Option<&Continuation>,
    ) -> Result<(Vec<DataValue>, Option<Continuation>), Refusal> {
        let series = self.series.get(node).ok_or(Refusal::NotHistorized)?;
        if from.is_some_and(|c| c.node != *node) {
            return Err(Refusal::InvalidContinuation);
        }
        let (start, end) = (
            (!start.is_null()).then(|| start.checked_ticks()),
            (!end.is_null()).then(|| end.checked_ticks()),
        );
        let backwards = match (start, end) {
            (Some(s), Some(e)) => s > e,
            (None, Some(_)) => true,
            (Some(_), None) => false,
            (None, None) => return Err(Refusal::InvalidTimes),
        };
        if (start.is_none() || end.is_none()) && count == 0 {
            return Err(Refusal::InvalidTimes);
        }
        let limit = if count == 0 {
            MAX_VALUES_PER_READ
        } else {
            count.min(MAX_VALUES_PER_READ)
        };
        let (low, high) = match (start, end) {
            (Some(s), Some(e)) => (s.min(e), s.max(e)),
            (Some(s), None) => (s, i64::MAX),
            (None, Some(e)) => (i64::MIN, e),
            (None, None) => (i64::MIN, i64::MAX),
        };
        // Where the read goes on, or begins: values strictly past the continuation's time.
        let within = |t: i64| {
            t >= low
                && t <= high
                && from.is_none_or(|c| {
                    if backwards {
                        t < c.after_ticks
                    } else {
                        t > c.after_ticks
                    }
                })
        };
        let picked: Vec<(i64, f64)> = if backwards {
            series
                .samples
                .iter()
                .rev()
                .copied()
                .filter(|(t, _)| within(*t))
                .take(limit + 1)
                .collect()
        } else {
            series
                .samples
                .iter()
                .copied()
                .filter(|(t, _)| within(*t))
                .take(limit + 1)
                .collect()
        };
        let more = picked.len() > limit;
        let values: Vec<DataValue> = picked
            .iter()
            .take(limit)
            .map(|(t, x)| {
                let at = DateTime::from(*t);
                DataValue {
                    value: Some(series.kind.variant(*x)),
                    status: Some(StatusCode::Good),
                    source_timestamp: Some(at),
                    source_picoseconds: None,
                    server_timestamp: Some(at),
                    server_picoseconds: None,
                }
            })
            .collect();
        let next = more.then(|| Continuation {
            node: node.clone(),
            after_ticks: picked[limit - 1].0,
        });
        Ok((values, next))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(s: f64) -> DateTime {
        DateTime::from(1_000_000 * TICKS_PER_S + (s * TICKS_PER_S as f64) as i64)
    }

    fn times(values: &[DataValue]) -> Vec<f64> {
        values
            .iter()
            .map(|v| {
                (v.source_timestamp.expect("a time").checked_ticks() - 1_000_000 * TICKS_PER_S) as f64
                    / TICKS_PER_S as f64
            })
            .collect()
    }

    fn history() -> (History, NodeId) {
        let node = NodeId::new(2, "ox-x.TOOL_X");
        let mut h = History::default();
        h.keep(node.clone(), ValueKind::Double);
        for k in 0..10 {
            h.record(&node, at(f64::from(k)), &Variant::Double(f64::from(k) * 1.5));
        }
        (h, node)
    }

    #[test]
    fn raw_values_are_read_forwards_backwards_and_in_parts() {
        let (h, node) = history();
        let (v, next) = h.read_raw(&node, at(2.0), at(5.0), 0, None).expect("read");
        assert_eq!(times(&v), [2.0, 3.0, 4.0, 5.0]);
        assert_eq!(v[0].value, Some(Variant::Double(3.0)));
        assert!(next.is_none());
        // Backwards: the start after the end.
        let (v, _) = h.read_raw(&node, at(5.0), at(2.0), 0, None).expect("read");
        assert_eq!(times(&v), [5.0, 4.0, 3.0, 2.0]);
        // Three at a time, going on from the continuation point.
        let (v, next) = h.read_raw(&node, at(0.0), at(9.0), 3, None).expect("read");
        assert_eq!(times(&v), [0.0, 1.0, 2.0]);
        let (v, next) = h.read_raw(&node, at(0.0), at(9.0), 3, next.as_ref()).expect("read");
        assert_eq!(times(&v), [3.0, 4.0, 5.0]);
        let (v, next) = h.read_raw(&node, at(0.0), at(9.0), 3, next.as_ref()).expect("read");
        assert_eq!(times(&v), [6.0, 7.0, 8.0]);
        let (v, next) = h.read_raw(&node, at(0.0), at(9.0), 3, next.as_ref()).expect("read");
        assert_eq!((times(&v), next), (vec![9.0], None));
        // The last three before a time: no start.
        let (v, _) = h.read_raw(&node, DateTime::null(), at(7.5), 3, None).expect("read");
        assert_eq!(times(&v), [7.0, 6.0, 5.0]);
        // Refusals.
        assert_eq!(
            h.read_raw(&node, DateTime::null(), DateTime::null(), 3, None)
                .map(|_| ()),
            Err(Refusal::InvalidTimes)
        );
        assert_eq!(
            h.read_raw(&node, at(1.0), DateTime::null(), 0, None).map(|_| ()),
            Err(Refusal::InvalidTimes)
        );
        assert_eq!(
            h.read_raw(&NodeId::new(2, "ox-x.Note"), at(0.0), at(1.0), 0, None)
                .map(|_| ()),
            Err(Refusal::NotHistorized)
        );
    }

    #[test]
    fn the_window_and_the_count_bound_what_is_kept() {
        let node = NodeId::new(2, "ox-x.MainState");
        let mut h = History::default();
        h.keep(node.clone(), ValueKind::UInt32);
        // Two hours of a value a second: only the last ten minutes stay.
        for k in 0..7200 {
            h.record(&node, at(f64::from(k)), &Variant::UInt32(k % 6));
        }
        let (v, _) = h.read_raw(&node, at(0.0), at(7200.0), 0, None).expect("read");
        assert_eq!(v.len(), 601);
        assert_eq!(times(&v)[0], 6599.0);
        assert_eq!(v[0].value, Some(Variant::UInt32(6599 % 6)));
        // A value every millisecond: at most MAX_SAMPLES.
        let fast = NodeId::new(2, "ox-x.TOOL_Y");
        h.keep(fast.clone(), ValueKind::Double);
        for k in 0..(MAX_SAMPLES + 500) {
            h.record(&fast, at(k as f64 * 1e-3), &Variant::Double(0.0));
        }
        assert_eq!(h.series[&fast].samples.len(), MAX_SAMPLES);
    }
}
