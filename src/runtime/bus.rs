//! Buses exchange process images with the outside world.
//!
//! A bus declares which variables it produces (physical inputs, each latched by one task class)
//! and which it consumes (outputs). The runtime calls it around every cycle: `read_inputs` before
//! the class's inputs are latched, `write_outputs` after its outputs are published. A simulated bus
//! does its work right there (deterministic); a real bus runs its own exchange loop and hands
//! complete images over through an [`image_mailbox`], so a cycle never waits on a wire.

pub use pkm_api::bus::{BUS_FAULT, Bus};

use crate::image::{Value, VarIndex, VarTable};

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
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

/// Stands in for a bus whose I/O map is invalid while the rest of the configuration is checked,
/// so that one run of `check` reports the problems of both files. Its inputs are unknown: a
/// variable nobody writes is not reported. A PLC built on it is never run.
#[derive(Debug, Default)]
pub struct UnknownBus;

impl Bus for UnknownBus {
    fn name(&self) -> &str {
        "unknown"
    }
    fn declare(&mut self, table: &mut VarTable) {
        table.set_inputs_unknown();
    }
    fn read_inputs(&mut self, _class: usize, _t_ns: u64, _image: &mut [Value]) {}
    fn write_outputs(&mut self, _class: usize, _t_ns: u64, _image: &[Value]) {}
    fn write_safe(&mut self, _image: &[Value]) {}
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

/// Creates a mailbox that hands complete input sets from a bus's exchange thread to the cyclic
/// thread, for the variables `slots` (initially `initial`, one value per slot).
///
/// It is a triple buffer: the writer fills a private buffer and publishes it as a whole; the
/// reader takes the latest published buffer. Both sides are wait-free — the cyclic thread never
/// blocks and never fails to get the latest complete set — and neither allocates after creation.
/// So a cycle sees either the previous or the newest set, never a mix.
pub fn image_mailbox(slots: Vec<VarIndex>, initial: Vec<Value>) -> (MailboxWriter, MailboxReader) {
    assert_eq!(slots.len(), initial.len(), "one initial value per mailbox slot");
    let (input, output) = triple_buffer::triple_buffer(&initial);
    (MailboxWriter { input }, MailboxReader { slots, output })
}

/// The exchange thread's end of a mailbox.
pub struct MailboxWriter {
    input: triple_buffer::Input<Vec<Value>>,
}

impl MailboxWriter {
    /// Publishes a complete set: one value per slot, in slot order.
    pub fn publish(&mut self, values: &[Value]) {
        let buffer = self.input.input_buffer_mut();
        assert_eq!(values.len(), buffer.len(), "a published set covers every slot");
        buffer.copy_from_slice(values);
        self.input.publish();
    }
}

/// The cyclic thread's end of a mailbox.
pub struct MailboxReader {
    slots: Vec<VarIndex>,
    output: triple_buffer::Output<Vec<Value>>,
}

impl MailboxReader {
    /// Copies the latest complete set into `image`. Returns whether a new set arrived since the
    /// last call (if not, `image` gets the same set again).
    pub fn take_latest(&mut self, image: &mut [Value]) -> bool {
        let updated = self.output.update();
        for (slot, value) in self.slots.iter().zip(self.output.output_buffer()) {
            image[usize::from(*slot)] = *value;
        }
        updated
    }
}
