//! `--bus none` with an I/O map: a dry run of the programs without field I/O. Every input the
//! map binds is declared with this bus as its writer and holds its start value (zero, false),
//! as a module that is not plugged in reads; every output is accepted and goes nowhere.

use crate::image::{Value, VarTable};
use crate::runtime::bus::Bus;
use crate::services::io::catalogue::Direction;
use crate::services::io::map::IoMap;

/// The dry-run bus.
#[derive(Debug)]
pub struct DryBus {
    map: IoMap,
}

impl DryBus {
    /// A dry run over the bindings of `map`.
    pub fn new(map: IoMap) -> DryBus {
        DryBus { map }
    }

    /// The variables of the map's input channels: they hold zero / false for the whole run.
    /// (A valid map binds each variable to one channel, so each is named once.)
    pub fn held_inputs(&self) -> Vec<&str> {
        self.map
            .bindings
            .iter()
            .filter(|b| b.direction == Direction::Input)
            .map(|b| b.variable.as_str())
            .collect()
    }
}

impl Bus for DryBus {
    fn name(&self) -> &str {
        "none"
    }
    fn declare(&mut self, table: &mut VarTable) {
        for b in &self.map.bindings {
            b.declare(table);
        }
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
