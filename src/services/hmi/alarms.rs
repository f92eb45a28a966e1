//! The screen's alarm and message history: every ERROR with its reason, every bus fault, every
//! acknowledgement and who made it (a screen's address, or the panel or OPC UA), every message
//! (MSG) a program reached — with the PLC's time and the wall clock's — the latest
//! [`MAX_ENTRIES`] kept for pages that connect later.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use serde_json::{Value as Json, json};

use crate::runtime::frame::Frame;

/// The most entries kept.
pub const MAX_ENTRIES: usize = 200;
/// An acknowledgement from a screen counts as the one that left ERROR within this long.
const ACKNOWLEDGED_WITHIN: Duration = Duration::from_secs(2);

/// The history and what it needs to tell what happened.
#[derive(Default)]
pub struct Alarms {
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    entries: VecDeque<Json>,
    /// The state and bus fault of the last frame looked at.
    state: String,
    bus_fault: bool,
    /// The last acknowledgement a screen sent: when, and from where.
    acknowledged: Option<(Instant, String)>,
}

impl Alarms {
    /// A screen at `peer` acknowledges (its press may take a moment to leave ERROR).
    pub fn acknowledging(&self, peer: String) {
        self.lock().acknowledged = Some((Instant::now(), peer));
    }

    /// The history, oldest first.
    pub fn history(&self) -> Vec<Json> {
        self.lock().entries.iter().cloned().collect()
    }

    /// Takes `frame` (and `message`, the text of a MSG the run reached, with its line): the
    /// entries it adds, each `{"type": "alarm", "t_s", "unix_ms", "kind", "text", "by"?}`.
    pub fn observe(&self, frame: &Frame, message: Option<(u32, &str)>) -> Vec<Json> {
        let mut inner = self.lock();
        let (t_s, unix_ms) = (frame.status.t_ns as f64 * 1e-9, frame.published_unix_us / 1000);
        let entry = |kind: &str, text: String, by: Option<String>| json!({"type": "alarm", "t_s": t_s, "unix_ms": unix_ms, "kind": kind, "text": text, "by": by});
        let mut new = Vec::new();
        let state = frame.status.state.as_str();
        if state == "ERROR" && inner.state != "ERROR" {
            new.push(entry("error", frame.status.reason.clone(), None));
        }
        if inner.state == "ERROR" && state != "ERROR" && !state.is_empty() {
            let by = match inner.acknowledged.take() {
                Some((at, peer)) if at.elapsed() <= ACKNOWLEDGED_WITHIN => format!("screen {peer}"),
                _ => "the panel or OPC UA".to_string(),
            };
            new.push(entry(
                "acknowledged",
                format!("{state} after the acknowledgement"),
                Some(by),
            ));
        }
        if frame.bus_fault && !inner.bus_fault {
            new.push(entry("bus fault", "the field bus reports a fault".to_string(), None));
        }
        if !frame.bus_fault && inner.bus_fault {
            new.push(entry(
                "bus fault cleared",
                "the field bus answers again".to_string(),
                None,
            ));
        }
        if let Some((line, text)) = message {
            new.push(entry("message", format!("line {line}: {text}"), None));
        }
        inner.state.clear();
        inner.state.push_str(state);
        inner.bus_fault = frame.bus_fault;
        for e in &new {
            if inner.entries.len() == MAX_ENTRIES {
                inner.entries.pop_front();
            }
            inner.entries.push_back(e.clone());
        }
        new
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }
}
