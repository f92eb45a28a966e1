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

/// Where a run's messages are read from: the loaded program's number, the last message's index
/// in it, and the count of messages reached since the start.
pub struct MessageWatch {
    library: NcLibrary,
    at: [usize; 3],
    /// `NC_MESSAGES` at the last look.
    seen: i32,
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

    /// Takes the new messages of `image` and writes them to the log; returns them.
    pub fn log(&mut self, image: &[Value]) -> Vec<NcMessage> {
        let (messages, passed) = self.take(image);
        if passed > 0 {
            info!("NC: {passed} messages passed over (more than {MAX_PER_LOOK} since the last look)");
        }
        for m in &messages {
            log_one(m);
        }
        messages
    }
}

/// One message in the log, with its line and kind: `NC line 12 (MSG): change the clamp`.
fn log_one(m: &NcMessage) {
    info!("NC line {} ({}): {}", m.line, m.kind.keyword(), m.text.trim());
}
