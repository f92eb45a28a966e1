//! The run's state as the status line, the screen and OPC UA show it: the main program's state,
//! reason, note and values, and per task class its figures — copied from the cyclic thread after
//! a cycle without allocating once its texts have grown to the longest seen.

use pkm_api::program::MAX_STATUS_VALUES;

use crate::runtime::plc::Plc;

/// The state of the run for status lines: copied from the cyclic thread without allocating.
#[derive(Clone, Debug, Default)]
pub struct Snapshot {
    /// Time since the start of the schedule (ns).
    pub t_ns: u64,
    /// Per task class, in configuration order.
    pub classes: Vec<ClassSnapshot>,
    /// The main program's state, if a program reports one.
    pub state: String,
    /// Its error reason, empty when there is none.
    pub reason: String,
    /// Its note to the operator, empty when there is none.
    pub note: String,
    /// The values the main program shows with its state.
    pub values: Vec<(&'static str, f64)>,
    /// Whether the bus reported a fault at the latest cycle.
    pub bus_fault: bool,
}

/// One task class in a [`Snapshot`].
#[derive(Clone, Debug, Default)]
pub struct ClassSnapshot {
    /// The class's name.
    pub name: String,
    /// Cycles run.
    pub cycles: u64,
    /// Overruns so far.
    pub overruns: u64,
    /// Cycle time violations so far.
    pub violations: u64,
    /// Mean start lateness (ns).
    pub lateness_mean_ns: f64,
    /// Largest start lateness (ns).
    pub lateness_max_ns: u64,
    /// Mean execution time (ns).
    pub exec_mean_ns: f64,
    /// Largest execution time (ns).
    pub exec_max_ns: u64,
}

impl Snapshot {
    /// A snapshot sized for `plc` (allocates; call once, outside the cyclic path).
    pub fn for_plc(plc: &Plc) -> Snapshot {
        let mut s = Snapshot {
            t_ns: 0,
            classes: plc
                .classes()
                .map(|c| ClassSnapshot {
                    name: c.name.to_string(),
                    ..Default::default()
                })
                .collect(),
            state: String::with_capacity(64),
            reason: String::with_capacity(256),
            note: String::with_capacity(256),
            values: Vec::with_capacity(MAX_STATUS_VALUES),
            bus_fault: false,
        };
        s.update(plc, 0);
        s
    }

    /// Copies the PLC's current figures in. Allocates only if a state or reason is longer than
    /// anything seen before.
    pub fn update(&mut self, plc: &Plc, t_ns: u64) {
        self.t_ns = t_ns;
        self.bus_fault = plc.bus_faulted();
        for (snap, class) in self.classes.iter_mut().zip(plc.classes()) {
            snap.cycles = class.stats.cycles;
            snap.overruns = class.stats.overruns;
            snap.violations = class.stats.violations;
            snap.lateness_mean_ns = class.stats.lateness.mean_ns();
            snap.lateness_max_ns = class.stats.lateness.max_ns();
            snap.exec_mean_ns = class.stats.exec.mean_ns();
            snap.exec_max_ns = class.stats.exec.max_ns();
        }
        self.state.clear();
        self.reason.clear();
        self.note.clear();
        self.values.clear();
        if let Some(status) = plc.app_status() {
            self.values.extend(status.values.iter().take(MAX_STATUS_VALUES));
            self.state.push_str(status.state);
            if let Some(r) = status.reason {
                plc.write_reason(r, &mut self.reason);
            }
            if let Some(n) = status.note {
                self.note.push_str(n);
            }
        }
    }
}
