//! What the runtime does when a cyclic program panics, as B&R's runtime does on a cyclic task's
//! exception (service mode): the panic is caught where the program's cycle was called, every
//! program stops, every output goes to its safe value and stays there, and the PLC reports ERROR
//! with a reason that names the program, its task class and the panic's message (and where in
//! the code it was raised). The screen, OPC UA and the summary go on reporting it; the process
//! does not end. Only a restart leaves it.

use std::any::Any;
use std::cell::RefCell;
use std::panic::PanicHookInfo;
use std::sync::OnceLock;

/// The state the PLC reports in service mode, as every program's error state reads.
pub const STATE: &str = "ERROR";

/// What the operator is told in service mode.
pub const NOTE: &str = "service mode: a cyclic program failed; programs stopped, outputs at their safe values; restart the PLC (the screen, OPC UA and the log stay up)";

/// Why the PLC entered service mode.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServiceMode {
    /// The program that panicked (`ox-x.drives`).
    pub program: String,
    /// Its task class.
    pub class: String,
    /// The panic's message.
    pub message: String,
    /// Where in the code it was raised (`tasks/nc/src/plan/mod.rs:280:17`), if known.
    pub location: Option<String>,
    /// The reason the PLC reports.
    pub reason: String,
}

impl ServiceMode {
    /// The service mode a panic of `program` in task class `class` puts the PLC in, from the
    /// panic's `payload` (what `catch_unwind` returned) and where the hook saw it raised.
    pub fn from_panic(program: &str, class: &str, payload: &(dyn Any + Send)) -> ServiceMode {
        let message = panic_message(payload);
        let location = LAST_PANIC.with(|l| l.borrow_mut().take());
        let at = location.as_deref().map(|l| format!(" at {l}")).unwrap_or_default();
        let reason = format!("cyclic program {program} (task class {class}) panicked{at}: {message}");
        ServiceMode {
            program: program.to_string(),
            class: class.to_string(),
            message,
            location,
            reason,
        }
    }
}

/// The message of a panic, from its `payload` (what `catch_unwind` returned).
pub fn panic_message(payload: &(dyn Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(a panic without a message)".to_string())
}

thread_local! {
    /// Where the last panic on this thread was raised: the hook writes it, the runtime takes it
    /// when it catches the panic.
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Installs (once per process) a panic hook that remembers where each panic was raised, for the
/// service mode's reason, and then does what the hook before it did (the default prints the
/// panic to standard error: the log a systemd service keeps).
pub fn install_hook() {
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info: &PanicHookInfo<'_>| {
            if let Some(l) = info.location() {
                let at = format!("{}:{}:{}", l.file(), l.line(), l.column());
                // A panic while the slot is borrowed (it never is for long) keeps no location.
                LAST_PANIC.with(|slot| {
                    if let Ok(mut s) = slot.try_borrow_mut() {
                        *s = Some(at);
                    }
                });
            }
            previous(info);
        }));
    });
}
