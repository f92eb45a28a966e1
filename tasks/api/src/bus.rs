//! Buses exchange process images with the outside world.
//!
//! A bus declares which variables it produces (physical inputs, each latched by one task class)
//! and which it consumes (outputs). The runtime calls it around every cycle: `read_inputs` before
//! the class's inputs are latched, `write_outputs` after its outputs are published. A simulated bus
//! does its work right there (deterministic); a real bus runs its own exchange loop and hands
//! complete images over, so a cycle never waits on a wire.

use crate::image::{Value, VarTable};

/// A field bus (or a simulated one).
pub trait Bus: Send {
    /// A short name for logs and summaries (`none`, `sim`, `serial:/dev/ttyUSB0`, ...).
    fn name(&self) -> &str;
    /// Declares the bus's inputs (as writers) and outputs (as readers) in the variable table.
    fn declare(&mut self, table: &mut VarTable);
    /// Opens the link, once, after the configuration is accepted and the programs are built and
    /// before the first cycle (the runtime calls it; declaring variables never opens anything).
    /// A real bus connects here and may wait, bounded, for its first input image; a simulated
    /// bus has nothing to do. An error refuses the run before any output was written (a station
    /// whose modules are not the I/O map's): it says why.
    fn start(&mut self) -> Result<(), String> {
        Ok(())
    }
    /// Called before every cycle's [`Bus::read_inputs`] with whether the main program is in its
    /// error state now (as its latest cycle left it): a bus that turns an operator's
    /// acknowledgement into a STOP press does so only then. A bus that wraps another passes it on.
    fn observe_error(&mut self, _in_error: bool) {}
    /// Called at the start of a cycle of task class `class` (nominal time `t_ns`), before its
    /// inputs are latched: updates the global image with the bus inputs that class latches.
    fn read_inputs(&mut self, class: usize, t_ns: u64, image: &mut [Value]);
    /// Called after task class `class` published its outputs into the global image.
    fn write_outputs(&mut self, class: usize, t_ns: u64, image: &[Value]);
    /// Called once at shutdown with every output at its safe value, before the bus closes.
    fn write_safe(&mut self, image: &[Value]);
    /// The bus as `Any`, so that callers who know its type can reach it (tests and status
    /// displays read the simulated machine's true state this way).
    fn as_any(&self) -> &dyn std::any::Any;
    /// The bus as mutable `Any`: tests reach the simulated machine this way to act on it as a
    /// person at the machine would (turning a lead screw by hand with the drives off).
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any;
    /// Whether the link is faulty beyond the configured bound: published every cycle as the
    /// variable [`BUS_FAULT`], so the application can stop the drives and report it.
    fn fault(&self) -> bool {
        false
    }
    /// Why the link is (or last was) faulty, appended to `out`; false when there is nothing to
    /// say. Called by the runtime to complete an application's [`BUS_FAULT_REASON`]; it must
    /// not block (a bus that cannot tell at once says nothing).
    fn write_fault_cause(&self, _out: &mut String) -> bool {
        false
    }
}

/// The variable every bus provides: its fault status.
pub const BUS_FAULT: &str = "bus_fault";

/// The text of an application's error reason for [`BUS_FAULT`]: the runtime appends the bus's
/// name and cause to a reason that starts with it (`bus fault: tcp:10.0.0.5:502: …`).
pub const BUS_FAULT_REASON: &str = "bus fault";
