//! Buses exchange process images with the outside world.
//!
//! A bus declares which variables it produces (physical inputs, each latched by one task class)
//! and which it consumes (outputs). The runtime calls it around every cycle: `read_inputs` before
//! the class's inputs are latched, `write_outputs` after its outputs are published. A simulated bus
//! does its work right there (deterministic); a real bus runs its own exchange loop and hands
//! complete images over through an [`ImageMailbox`], so a cycle never waits on a wire.

use std::sync::Mutex;

use crate::image::{Value, VarIndex, VarTable};

/// A field bus (or a simulated one).
pub trait Bus: Send {
    /// A short name for logs and summaries (`none`, `sim`, `serial:/dev/ttyUSB0`, ...).
    fn name(&self) -> &str;
    /// Declares the bus's inputs (as writers) and outputs (as readers) in the variable table.
    fn declare(&mut self, table: &mut VarTable);
    /// Called at the start of a cycle of task class `class` (nominal time `t_ns`), before its
    /// inputs are latched: updates the global image with the bus inputs that class latches.
    fn read_inputs(&mut self, class: usize, t_ns: u64, image: &mut [Value]);
    /// Called after task class `class` published its outputs into the global image.
    fn write_outputs(&mut self, class: usize, t_ns: u64, image: &[Value]);
    /// Called once at shutdown with every output at its safe value, before the bus closes.
    fn write_safe(&mut self, image: &[Value]);
}

/// No field I/O: programs exchange variables among themselves only.
#[derive(Debug, Default)]
pub struct NoBus;

impl Bus for NoBus {
    fn name(&self) -> &str {
        "none"
    }
    fn declare(&mut self, _table: &mut VarTable) {}
    fn read_inputs(&mut self, _class: usize, _t_ns: u64, _image: &mut [Value]) {}
    fn write_outputs(&mut self, _class: usize, _t_ns: u64, _image: &[Value]) {}
    fn write_safe(&mut self, _image: &[Value]) {}
}

/// Hands complete input sets from a bus's exchange thread to the cyclic thread.
///
/// The producer publishes a whole set at once; the consumer copies the latest complete set into
/// the image. The consumer never blocks: if the producer holds the lock at that instant, the cycle
/// keeps the previous (complete) set. So a cycle sees either the old or the new set, never a mix.
#[derive(Debug)]
pub struct ImageMailbox {
    slots: Vec<VarIndex>,
    latest: Mutex<Latest>,
}

#[derive(Debug)]
struct Latest {
    values: Vec<Value>,
    sequence: u64,
}

impl ImageMailbox {
    /// A mailbox for the variables `slots`, initially holding `initial` (one value per slot).
    pub fn new(slots: Vec<VarIndex>, initial: Vec<Value>) -> Self {
        assert_eq!(slots.len(), initial.len(), "one initial value per mailbox slot");
        ImageMailbox {
            slots,
            latest: Mutex::new(Latest {
                values: initial,
                sequence: 0,
            }),
        }
    }

    /// Publishes a complete set (producer side; one value per slot, in slot order).
    pub fn publish(&self, values: &[Value]) {
        assert_eq!(values.len(), self.slots.len(), "a published set covers every slot");
        let mut latest = self.latest.lock().unwrap_or_else(|p| p.into_inner());
        latest.values.copy_from_slice(values);
        latest.sequence += 1;
    }

    /// Copies the latest complete set into `image` (consumer side, never blocks). Returns the
    /// set's sequence number, or `None` when the producer was busy and `image` was left as it was.
    pub fn take_latest(&self, image: &mut [Value]) -> Option<u64> {
        let latest = match self.latest.try_lock() {
            Ok(g) => g,
            Err(std::sync::TryLockError::Poisoned(p)) => p.into_inner(),
            Err(std::sync::TryLockError::WouldBlock) => return None,
        };
        for (slot, value) in self.slots.iter().zip(&latest.values) {
            image[usize::from(*slot)] = *value;
        }
        Some(latest.sequence)
    }
}
