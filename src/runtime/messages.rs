//! The NC programs' message comments as a run reaches them: `(MSG,…)`, `(DEBUG,…)` and
//! `(PRINT,…)` become process-image counters in the cycle (`NC_MESSAGE`, `NC_MESSAGES`, written
//! by the drive program), and a [`MessageWatch`] off the cyclic path turns them back into the
//! program's texts: for the log (every run), and for the screen (MSG).

use pkm_api::library::NcLibrary;
use pkm_api::trajectory::{NcMessage, vars};
use tracing::info;

use crate::image::{Value, VarTable};

/// The most messages taken from one look (a program that reaches more between two looks has
/// the latest ones shown and logged, and a line saying how many were passed over).
pub const MAX_PER_LOOK: usize = 64;
/// The most messages logged per second of the PLC's time (a loop of DEBUG comments would fill
/// the log); the others are counted, and the count logged.
pub const MAX_LOGGED_PER_S: u32 = 50;
/// A message's text is logged (and shown) cut to this many characters.
pub const MAX_TEXT_CHARS: usize = 300;

/// Where a run's messages are read from: the loaded program's number, the last message's index
/// in it, and the count of messages reached since the start.
pub struct MessageWatch {
    library: NcLibrary,
    at: [usize; 3],
    /// `NC_MESSAGES` at the last look.
    seen: i32,
    /// The second of the PLC's time messages are being logged in, how many were, and how many
    /// were left out.
    second: u64,
    logged: u32,
    left_out: u64,
}

impl MessageWatch {
    /// A watch of the run's `library` through `vars`; `None` without a library or without the
    /// variables (a machine without NC programs).
    pub fn new(vars: &VarTable, library: Option<&NcLibrary>) -> Option<MessageWatch> {
        MessageWatch::at(|name| vars.index_of(name).map(usize::from), library)
    }

    /// [`MessageWatch::new`] from the variables' names, in the image's order (with their types).
    pub fn of_names(names: &[(String, String)], library: Option<&NcLibrary>) -> Option<MessageWatch> {
        MessageWatch::at(|name| names.iter().position(|(n, _)| n == name), library)
    }

    fn at(index: impl Fn(&str) -> Option<usize>, library: Option<&NcLibrary>) -> Option<MessageWatch> {
        Some(MessageWatch {
            library: library?.clone(),
            at: [
                index(vars::NC_PROGRAM.name())?,
                index(vars::NC_MESSAGE.name())?,
                index(vars::NC_MESSAGES.name())?,
            ],
            seen: 0,
            second: 0,
            logged: 0,
            left_out: 0,
        })
    }

    /// The messages reached since the last look at `image` (the published process image), in
    /// order, and how many were passed over beyond [`MAX_PER_LOOK`].
    pub fn take(&mut self, image: &[Value]) -> (Vec<NcMessage>, usize) {
        let int = |i: usize| match image.get(i) {
            Some(Value::Int(v)) => i32::from(*v),
            Some(Value::Dint(v)) => *v,
            _ => 0,
        };
        let [program, last, count] = self.at.map(int);
        if count <= self.seen {
            return (Vec::new(), 0);
        }
        let new = usize::try_from(count - self.seen).unwrap_or(0);
        self.seen = count;
        let Some(trajectory) = i16::try_from(program).ok().and_then(|k| self.library.trajectory(k)) else {
            return (Vec::new(), 0);
        };
        let messages = trajectory.messages();
        let end = usize::try_from(last).unwrap_or(0).min(messages.len());
        // The newest `new` up to the last one reached (a run restarted between two looks
        // counts on from its own first).
        let start = end.saturating_sub(new.min(MAX_PER_LOOK));
        let passed = new.saturating_sub(MAX_PER_LOOK);
        (messages[start..end].to_vec(), passed)
    }

    /// Takes the new messages of `image` (published at `t_ns` of the PLC's time) and writes
    /// them to the log, at most [`MAX_LOGGED_PER_S`] a second; returns them.
    pub fn log(&mut self, image: &[Value], t_ns: u64) -> Vec<NcMessage> {
        let (messages, passed) = self.take(image);
        let second = t_ns / 1_000_000_000;
        if second != self.second {
            if self.left_out > 0 {
                info!(
                    "NC: {} messages not logged in the second before t={} s (more than {MAX_LOGGED_PER_S} a second)",
                    self.left_out, second
                );
            }
            (self.second, self.logged, self.left_out) = (second, 0, 0);
        }
        self.left_out += passed as u64;
        for m in &messages {
            if self.logged < MAX_LOGGED_PER_S {
                self.logged += 1;
                info!("NC line {} ({}): {}", m.line, m.kind.keyword(), shown(&m.text));
            } else {
                self.left_out += 1;
            }
        }
        messages
    }
}

/// A message's text as it is logged and shown: without blanks around it, cut to
/// [`MAX_TEXT_CHARS`] characters.
pub fn shown(text: &str) -> String {
    let text = text.trim();
    match text.char_indices().nth(MAX_TEXT_CHARS) {
        Some((at, _)) => format!("{}…", &text[..at]),
        None => text.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use pkm_api::trajectory::{MAX_AXES, NcJob, NcMessageKind, Trajectory, TrajectoryEvent, TrajectorySample};

    use super::*;

    /// A program of `n` DEBUG messages and no motion.
    struct Messages(Vec<NcMessage>);

    impl Trajectory for Messages {
        fn dof(&self) -> usize {
            1
        }
        fn duration_s(&self) -> f64 {
            0.0
        }
        fn length_mm(&self) -> f64 {
            0.0
        }
        fn sample(&self, _t: f64, _cursor: &mut usize) -> TrajectorySample {
            TrajectorySample::default()
        }
        fn events(&self) -> &[TrajectoryEvent] {
            &[]
        }
        fn messages(&self) -> &[NcMessage] {
            &self.0
        }
        fn block_end(&self, _s: f64) -> Option<(f64, f64)> {
            None
        }
        fn forward(&self, _j: &[f64], _h: &[f64; MAX_AXES], _p: &mut [f64; MAX_AXES]) -> bool {
            false
        }
        fn path_distance(&self, _p: &[f64; MAX_AXES], _t: f64) -> f64 {
            0.0
        }
    }

    fn watch(n: usize) -> MessageWatch {
        let messages = (0..n)
            .map(|i| NcMessage {
                line: 2,
                kind: NcMessageKind::Debug,
                text: format!("i = {i}"),
            })
            .collect();
        let job = NcJob {
            file: "p.ngc".into(),
            text: String::new(),
            trajectory: Arc::new(Messages(messages)),
        };
        let library = NcLibrary::new(vec![job], true);
        MessageWatch {
            library,
            at: [0, 1, 2],
            seen: 0,
            second: 0,
            logged: 0,
            left_out: 0,
        }
    }

    fn image(program: i16, last: i32, count: i32) -> Vec<Value> {
        vec![Value::Int(program), Value::Dint(last), Value::Dint(count)]
    }

    #[test]
    fn the_messages_reached_are_taken_once_in_order_and_the_log_is_bounded() {
        let mut w = watch(200);
        let (new, passed) = w.take(&image(1, 3, 3));
        assert_eq!(
            new.iter().map(|m| m.text.as_str()).collect::<Vec<_>>(),
            ["i = 0", "i = 1", "i = 2"]
        );
        assert_eq!(passed, 0);
        assert!(w.take(&image(1, 3, 3)).0.is_empty(), "nothing new");
        // 197 more in one look: the newest 64 taken, the rest counted.
        let (new, passed) = w.take(&image(1, 200, 200));
        assert_eq!((new.len(), passed), (MAX_PER_LOOK, 197 - MAX_PER_LOOK));
        assert_eq!(new.last().map(|m| m.text.as_str()), Some("i = 199"));
        // The log: at most 50 a second of the PLC's time.
        let mut w = watch(200);
        let logged = w.log(&image(1, 60, 60), 1_000_000_000);
        assert_eq!(logged.len(), 60, "all returned");
        assert_eq!((w.logged, w.left_out), (MAX_LOGGED_PER_S, 10));
        w.log(&image(1, 61, 61), 2_000_000_000);
        assert_eq!((w.logged, w.left_out), (1, 0), "a new second");
        assert_eq!(shown(&"y".repeat(400)).chars().count(), MAX_TEXT_CHARS + 1);
    }
}
