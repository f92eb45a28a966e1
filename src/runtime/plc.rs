//! The scheduler core: task classes, their images, their programs and cycle monitoring.
//!
//! [`Plc`] knows nothing of real or virtual time: a driver (see [`crate::runtime::run`]) asks it for the
//! next release, waits for it in its own way, and calls [`Plc::run_due`] with a [`Clock`]. Classes
//! are never preempted: among the classes that are due, the one with the highest priority runs
//! first (and so the faster one, which configuration checks enforce).

use std::panic::AssertUnwindSafe;

use tracing::warn;

use crate::image::{Declare, Problem, Value, VarIndex, VarTable, Writer};
use crate::program::{AppStatus, Clock, Cycle, CycleInfo, CycleViolation, Program, ProgramArgs, Registry};
use crate::runtime::bus::Bus;
use crate::runtime::config::{self, Config, Reaction};
use crate::runtime::service_mode::{self, ServiceMode};
use crate::runtime::stats::ClassStats;

/// What a recorder sees of one class cycle.
pub struct CycleRecord<'a> {
    /// The task class (configuration order).
    pub class: usize,
    /// The cycle's nominal start (ns since the epoch).
    pub t_ns: u64,
    /// The cycle's number in its class, from 0.
    pub cycle: u64,
    /// The class's image after the cycle: inputs as latched, outputs as written.
    pub image: &'a [Value],
    /// The class's input variables.
    pub inputs: &'a [VarIndex],
    /// The class's output variables.
    pub outputs: &'a [VarIndex],
    /// The main program's state after the cycle.
    pub status: Option<AppStatus<'a>>,
    /// Whether a cycle time violation was delivered to the class's programs in this cycle.
    pub violation: bool,
}

/// Receives every class cycle (a trace recorder). Called on the cyclic path: it must not block
/// for long nor allocate in steady operation.
pub trait CycleSink: Send {
    /// One class cycle has run.
    fn record(&mut self, record: &CycleRecord<'_>);
    /// The run is over: flush, and say what was recorded (or what went wrong).
    fn finish(self: Box<Self>) -> Result<String, SinkError>;
}

/// Why a cycle sink (a trace) could not be finished.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// The thread that wrote it ended by a panic.
    #[error("{file}: the trace writer panicked")]
    WriterPanicked {
        /// The trace file.
        file: String,
    },
    /// Writing failed: recording stopped there, the run went on.
    #[error("{file}: writing the trace failed: {source}; recording stopped there, the run went on: {held}")]
    Write {
        /// The trace file.
        file: String,
        /// The write's error.
        source: std::io::Error,
        /// What the file holds, read back (`the file holds the first 12 records (up to t =
        /// 0.120 s), as replay reads them`, `the file holds no complete record`).
        held: String,
    },
}

/// One program instance in its task class.
struct Slot {
    name: String,
    program: Box<dyn Program>,
    /// The violation sequence number this program has been told about.
    seen_violation: u64,
}

/// A task class at run time.
struct Class {
    name: String,
    period_ns: u64,
    tolerance_ns: u64,
    reaction: Reaction,
    /// This class's private copy of the image.
    image: Vec<Value>,
    /// Variables latched from the global image before each cycle.
    inputs: Vec<VarIndex>,
    /// Variables published to the global image after each cycle.
    outputs: Vec<VarIndex>,
    /// `inputs` and `outputs` as runs of consecutive variables, copied a run at a time
    /// (element by element, latching and publishing took a fifth of a simulated hour).
    input_runs: Vec<std::ops::Range<usize>>,
    output_runs: Vec<std::ops::Range<usize>>,
    programs: Vec<Slot>,
    /// Whether one of its programs reports the application's state ([`Program::status`]),
    /// asked once when the class is built: a program reports a state on every call or never.
    reports_status: bool,
    next_release: u64,
    stats: ClassStats,
    violation_logged: bool,
}

/// The soft-PLC: process image, task classes and their programs, and a bus.
pub struct Plc {
    table: VarTable,
    global: Vec<Value>,
    classes: Vec<Class>,
    /// Class indices in priority order (highest first).
    order: Vec<usize>,
    bus: Box<dyn Bus>,
    violation_seq: u64,
    last_violation: Option<CycleViolation>,
    sink: Option<Box<dyn CycleSink>>,
    /// Index of the `bus_fault` variable.
    bus_fault: VarIndex,
    /// Whether [`Plc::start_bus`] has run.
    bus_started: bool,
    /// The machine the configuration names (`"machine"`), if it names one.
    machine: Option<String>,
    /// Set when a cyclic program panicked: programs no longer run, outputs stay safe.
    service: Option<ServiceMode>,
    /// Whether the application was in ERROR at its last cycle, as the bus is told before each
    /// class's exchange ([`Bus::observe_error`]): looked up when the class that reports the
    /// application's state has run (or a panic put the PLC in ERROR), not on every cycle.
    in_error: bool,
    /// Counts the cycles after which the application's state may have changed
    /// ([`Plc::status_seq`]).
    status_seq: u64,
}

/// A read-only view of one task class, for summaries and status lines.
#[derive(Clone, Copy)]
pub struct ClassView<'a> {
    /// Its name.
    pub name: &'a str,
    /// Its cycle time (ns).
    pub period_ns: u64,
    /// Its tolerance (ns).
    pub tolerance_ns: u64,
    /// What it has measured.
    pub stats: &'a ClassStats,
    /// The variables its cycles latch.
    pub inputs: &'a [VarIndex],
    /// The variables its cycles publish.
    pub outputs: &'a [VarIndex],
}

impl Plc {
    /// Builds the PLC from a configuration: checks it as a whole, lets the bus and every program
    /// declare their variables, and returns every problem found at once.
    pub fn build(config: &Config, registry: &Registry, bus: Box<dyn Bus>) -> Result<Plc, Vec<Problem>> {
        Plc::build_with(config, registry, bus, None)
    }

    /// [`Plc::build`] with NC programs for the programs to run (`run --program`, `--programs`).
    pub fn build_with(
        config: &Config,
        registry: &Registry,
        mut bus: Box<dyn Bus>,
        nc: Option<&pkm_api::library::NcLibrary>,
    ) -> Result<Plc, Vec<Problem>> {
        // A program's panic names where it was raised.
        service_mode::install_hook();
        let mut issues = config::check(config);
        let mut table = VarTable::new();
        bus.declare(&mut table);
        // Every bus reports its fault status; the fastest class latches it (any class may read it).
        let fastest = (0..config.task_classes.len())
            .min_by_key(|&c| config.task_classes[c].cycle_us)
            .unwrap_or(0);
        let bus_fault = table.declare_writer(
            crate::runtime::bus::BUS_FAULT,
            crate::image::VarType::Bool,
            Writer::Bus {
                class: fastest,
                at: "the runtime (bus status)".into(),
            },
            Value::Bool(false),
        );
        let mut classes = Vec::with_capacity(config.task_classes.len());
        for (ci, tc) in config.task_classes.iter().enumerate() {
            let mut programs = Vec::with_capacity(tc.programs.len());
            for (pi, entry) in tc.programs.iter().enumerate() {
                let at = format!("task_classes[{ci}].programs[{pi}]");
                let Some(info) = registry.get(&entry.program) else {
                    let known: Vec<&str> = registry.programs().iter().map(|p| p.name).collect();
                    issues.push(Problem {
                        at: format!("{at}.program"),
                        message: format!(
                            "unknown program \"{}\"; known programs: {}",
                            entry.program,
                            known.join(", ")
                        ),
                    });
                    continue;
                };
                let mut decl = Declare::new(&mut table, ci, info.name, &at);
                let args = ProgramArgs {
                    params: entry.params.as_ref(),
                    kinematics: config.kinematics.as_ref(),
                    cycle_us: tc.cycle_us,
                    fastest_class: config.task_classes.iter().all(|o| o.cycle_us >= tc.cycle_us),
                    nc,
                };
                let program = (info.factory)(&args, &mut decl);
                programs.push(Slot {
                    name: info.name.to_string(),
                    program,
                    seen_violation: 0,
                });
            }
            let reports_status = programs.iter().any(|slot| slot.program.status().is_some());
            classes.push(Class {
                reports_status,
                name: tc.name.clone(),
                period_ns: u64::from(tc.cycle_us.max(1)) * 1000,
                tolerance_ns: u64::from(tc.tolerance_us) * 1000,
                reaction: tc.on_violation,
                image: Vec::new(),
                inputs: Vec::new(),
                outputs: Vec::new(),
                input_runs: Vec::new(),
                output_runs: Vec::new(),
                programs,
                next_release: 0,
                stats: ClassStats::default(),
                violation_logged: false,
            });
        }
        let class_cycles: Vec<(&str, u32)> = config
            .task_classes
            .iter()
            .map(|c| (c.name.as_str(), c.cycle_us))
            .collect();
        issues.extend(table.exchange_problems(&class_cycles));
        let table = match table.finish() {
            Ok(t) if issues.is_empty() => t,
            Ok(_) => return Err(issues),
            Err(decl_issues) => {
                issues.extend(decl_issues);
                return Err(issues);
            }
        };
        let global = table.initial_image();
        for (ci, class) in classes.iter_mut().enumerate() {
            class.image = global.clone();
            for (vi, var) in table.vars().iter().enumerate() {
                let index = VarIndex::try_from(vi).unwrap_or(VarIndex::MAX);
                let written_here = matches!(&var.writer, Some(Writer::Program { class, .. }) if *class == ci);
                if written_here {
                    class.outputs.push(index);
                } else if var.readers.iter().any(|r| r.class == ci) {
                    class.inputs.push(index);
                }
            }
            class.input_runs = runs(&class.inputs);
            class.output_runs = runs(&class.outputs);
        }
        let mut order: Vec<usize> = (0..classes.len()).collect();
        order.sort_by_key(|&c| (config.task_classes[c].priority, c));
        Ok(Plc {
            table,
            global,
            classes,
            order,
            bus,
            violation_seq: 0,
            last_violation: None,
            sink: None,
            bus_fault,
            bus_started: false,
            machine: config.machine.clone(),
            service: None,
            in_error: false,
            status_seq: 0,
        })
    }

    /// The machine the configuration names (`"machine"`): a trace's header records it.
    pub fn machine(&self) -> Option<&str> {
        self.machine.as_deref()
    }

    /// The variable table.
    pub fn vars(&self) -> &VarTable {
        &self.table
    }

    /// The published (global) image.
    pub fn global_image(&self) -> &[Value] {
        &self.global
    }

    /// The variable `name` as its writer last wrote it: a program's output from its class's
    /// image (which [`Plc::shutdown`] leaves alone), anything else from the global image.
    pub fn last_written(&self, name: &str) -> Option<Value> {
        let index = usize::from(self.table.index_of(name)?);
        let image = match &self.table.vars().get(index)?.writer {
            Some(Writer::Program { class, .. }) => &self.classes.get(*class)?.image,
            _ => &self.global,
        };
        image.get(index).copied()
    }

    /// The bus.
    pub fn bus(&self) -> &dyn Bus {
        self.bus.as_ref()
    }

    /// Writes the application's error `reason` to `out`, completed where it is the bus fault: the
    /// application knows only that the bus failed, the bus knows why (`bus fault: tcp:…: the
    /// link is too slow: …`). Allocates nothing once `out` has grown to the longest reason.
    pub fn write_reason(&self, reason: &str, out: &mut String) {
        out.push_str(reason);
        if reason.starts_with(pkm_api::bus::BUS_FAULT_REASON) {
            let mark = out.len();
            out.push_str(": ");
            if !self.write_bus_fault(out) {
                out.truncate(mark);
            }
        }
    }

    /// Writes the bus's name to `out` and, where the bus can tell, why it is (or last was)
    /// faulty (`tcp:10.0.0.5:502: 4 failed exchanges in a row, …`); whether it told why.
    /// Allocates nothing once `out` has grown to the longest.
    pub fn write_bus_fault(&self, out: &mut String) -> bool {
        out.push_str(self.bus.name());
        let named = out.len();
        out.push_str(": ");
        let told = self.bus.write_fault_cause(out);
        if !told {
            out.truncate(named);
        }
        told
    }

    /// The application's error reason, completed as [`Plc::write_reason`] does; `None` without
    /// one.
    pub fn error_reason(&self) -> Option<String> {
        let status = self.app_status()?;
        let reason = status.reason?;
        let mut out = String::new();
        self.write_reason(reason, &mut out);
        Some(out)
    }

    /// The bus, to act on the simulated machine (tests).
    pub fn bus_mut(&mut self) -> &mut dyn Bus {
        self.bus.as_mut()
    }

    /// The bus's name.
    pub fn bus_name(&self) -> &str {
        self.bus.name()
    }

    /// The task classes in configuration order.
    pub fn classes(&self) -> impl Iterator<Item = ClassView<'_>> {
        self.classes.iter().map(|c| ClassView {
            name: &c.name,
            period_ns: c.period_ns,
            tolerance_ns: c.tolerance_ns,
            stats: &c.stats,
            inputs: &c.inputs,
            outputs: &c.outputs,
        })
    }

    /// The main program's status: the first program (in priority order) that reports one; in
    /// service mode, ERROR with the panic's reason.
    pub fn app_status(&self) -> Option<AppStatus<'_>> {
        if let Some(service) = &self.service {
            return Some(AppStatus {
                state: service_mode::STATE,
                reason: Some(&service.reason),
                note: Some(service_mode::NOTE),
                values: &[],
            });
        }
        self.order
            .iter()
            .filter(|&&c| self.classes[c].reports_status)
            .flat_map(|&c| self.classes[c].programs.iter())
            .find_map(|slot| slot.program.status())
    }

    /// A number that changes whenever the application's state ([`Plc::app_status`]) may have
    /// changed: after each cycle of the class that reports it, and in service mode after every
    /// cycle. An observer that saw the state at one number need not look again until it
    /// changes (the state, its note and reason are the status program's, and change only when
    /// it runs).
    pub fn status_seq(&self) -> u64 {
        self.status_seq
    }

    /// The cycle time (ns) of the task class whose program reports [`Plc::app_status`]: the
    /// main program's, at whose rate the operator's screen is updated.
    pub fn app_period_ns(&self) -> Option<u64> {
        self.order
            .iter()
            .find(|&&c| self.classes[c].reports_status)
            .map(|&c| self.classes[c].period_ns)
    }

    /// Whether the bus reported a fault at the latest cycle (the `bus_fault` input it published).
    pub fn bus_faulted(&self) -> bool {
        self.global[usize::from(self.bus_fault)] == Value::Bool(true)
    }

    /// The name of the program whose status [`Plc::app_status`] reports.
    pub fn app_program(&self) -> Option<&str> {
        self.order
            .iter()
            .flat_map(|&c| self.classes[c].programs.iter())
            .find(|slot| slot.program.status().is_some())
            .map(|slot| slot.name.as_str())
    }

    /// Opens the bus's link ([`Bus::start`]): a real bus connects and waits, bounded, for its
    /// first input image. A real-time driver calls this before it fixes its schedule's epoch, so
    /// the wait does not make the first cycles late; [`Plc::init`] calls it if nobody did. An
    /// error is the bus's refusal of its station (nothing was written to it); a second call does
    /// nothing.
    pub fn start_bus(&mut self) -> Result<(), String> {
        if self.bus_started {
            return Ok(());
        }
        self.bus_started = true;
        self.bus.start()
    }

    /// Starts the bus if that has not been done ([`Plc::start_bus`]), runs every program's init
    /// part (classes in priority order) and sets the first release of every class to `start_ns`.
    pub fn init(&mut self, start_ns: u64, clock: &mut dyn Clock) {
        // A driver that can refuse a station starts the bus itself first (the real-time run
        // does); here a refusal leaves the bus faulted, which the programs see.
        if let Err(why) = self.start_bus() {
            tracing::error!("bus {}: {why}", self.bus.name());
        }
        for ci in self.order.clone() {
            let class = &mut self.classes[ci];
            self.bus.read_inputs(ci, start_ns, &mut self.global);
            copy_runs(&class.input_runs, &self.global, &mut class.image);
            let serving = self.service.is_some();
            for slot in &mut class.programs {
                if self.service.is_some() {
                    break;
                }
                let info = CycleInfo {
                    time_ns: start_ns,
                    cycle: 0,
                    period_ns: class.period_ns,
                    violation: None,
                };
                let mut ctx = Cycle::new(&mut class.image, info, &mut *clock);
                let program = &mut slot.program;
                if let Err(payload) = std::panic::catch_unwind(AssertUnwindSafe(|| program.init(&mut ctx))) {
                    self.service = Some(ServiceMode::from_panic(&slot.name, &class.name, payload.as_ref()));
                }
            }
            if !serving && self.service.is_some() {
                self.enter_service_mode();
            }
            let class = &mut self.classes[ci];
            copy_runs(&class.output_runs, &class.image, &mut self.global);
            self.bus.write_outputs(ci, start_ns, &self.global);
            class.next_release = start_ns;
        }
    }

    /// The earliest next release of any class (ns since the epoch).
    pub fn next_release(&self) -> u64 {
        self.classes.iter().map(|c| c.next_release).min().unwrap_or(u64::MAX)
    }

    /// One pass over the classes in priority order: each class that is due when its turn comes
    /// runs one cycle. The driver calls this again while [`Plc::next_release`] has passed, so a
    /// class that became due meanwhile runs next, highest priority first. Returning after one pass
    /// lets the driver check for a stop between cycles, and keeps a class that overruns every cycle
    /// from starving the others (they run between its late cycles, late themselves). Releases at
    /// or after `end_ns` (the end of the run) are not run.
    pub fn run_due(&mut self, clock: &mut dyn Clock, end_ns: u64) {
        for k in 0..self.order.len() {
            let ci = self.order[k];
            let release = self.classes[ci].next_release;
            if release < end_ns && release <= clock.now_ns() {
                self.run_class(ci, clock);
            }
        }
    }

    /// Runs the programs of class `ci` on its image. With `replayed` the violation events are
    /// the recorded ones; otherwise each program gets the runtime's pending one. Returns whether a
    /// violation was delivered.
    fn execute(&mut self, ci: usize, release: u64, clock: &mut dyn Clock, replayed: Option<bool>) -> bool {
        if self.service.is_some() {
            // Service mode: no program runs; the outputs stay at their safe values.
            return false;
        }
        let class = &mut self.classes[ci];
        let cycle = class.stats.cycles;
        let mut delivered = false;
        let mut panicked = None;
        for slot in &mut class.programs {
            let violation = match replayed {
                Some(true) => Some(CycleViolation {
                    class: ci,
                    late_by_ns: 0,
                }),
                Some(false) => None,
                None if slot.seen_violation != self.violation_seq => {
                    slot.seen_violation = self.violation_seq;
                    self.last_violation
                }
                None => None,
            };
            delivered |= violation.is_some();
            let info = CycleInfo {
                time_ns: release,
                cycle,
                period_ns: class.period_ns,
                violation,
            };
            let mut ctx = Cycle::new(&mut class.image, info, &mut *clock);
            // A panic is caught here, where the program was called (the cycle allocates
            // nothing for it: the catch costs nothing until something is thrown).
            let program = &mut slot.program;
            if let Err(payload) = std::panic::catch_unwind(AssertUnwindSafe(|| program.cycle(&mut ctx))) {
                panicked = Some(ServiceMode::from_panic(&slot.name, &class.name, payload.as_ref()));
                break;
            }
        }
        if let Some(service) = panicked {
            self.service = Some(service);
            self.enter_service_mode();
        }
        delivered
    }

    /// Service mode from now on: every program's output at its safe value in every class's
    /// image (so that what each class publishes from here on is safe), the bus given the safe
    /// image, and the reason logged.
    fn enter_service_mode(&mut self) {
        for (i, var) in self.table.vars().iter().enumerate() {
            if let Some(Writer::Program { class, .. }) = var.writer {
                if let Some(c) = self.classes.get_mut(class) {
                    c.image[i] = var.safe;
                }
                self.global[i] = var.safe;
            }
        }
        self.bus.write_safe(&self.global);
        if let Some(service) = &self.service {
            tracing::error!("{}; {}", service.reason, service_mode::NOTE);
        }
    }

    /// Why the PLC is in service mode, if it is: a cyclic program panicked.
    pub fn service_mode(&self) -> Option<&ServiceMode> {
        self.service.as_ref()
    }

    /// Publishes class `ci`'s outputs to the global image.
    fn publish(&mut self, ci: usize) {
        let class = &self.classes[ci];
        copy_runs(&class.output_runs, &class.image, &mut self.global);
    }

    /// Hands the cycle just run to the recorder, if there is one.
    fn record(&mut self, ci: usize, release: u64, cycle: u64, violation: bool) {
        if let Some(mut sink) = self.sink.take() {
            let class = &self.classes[ci];
            sink.record(&CycleRecord {
                class: ci,
                t_ns: release,
                cycle,
                image: &class.image,
                inputs: &class.inputs,
                outputs: &class.outputs,
                status: self.app_status(),
                violation,
            });
            self.sink = Some(sink);
        }
    }

    /// Runs one cycle of class `ci` with recorded inputs instead of latched ones and the
    /// recorded violation event; the outputs are then in [`Plc::class_image`] (and not in the
    /// global image). Used by replay: no bus, no statistics but the cycle count.
    ///
    /// `changed` holds the inputs that changed since the class's previous cycle, each one of
    /// the class's inputs ([`ClassView::inputs`]): the others keep their values in the class's
    /// image, which only latching writes (programs write their own outputs only).
    pub fn replay_cycle(
        &mut self,
        ci: usize,
        release: u64,
        changed: &[(VarIndex, Value)],
        violation: bool,
        clock: &mut dyn Clock,
    ) {
        let class = &mut self.classes[ci];
        for &(i, v) in changed {
            debug_assert!(
                class.inputs.contains(&i),
                "replayed input {i} is not an input of class {ci}"
            );
            class.image[usize::from(i)] = v;
        }
        self.execute(ci, release, clock, Some(violation));
        // Not published to the global image: in a replay every class's inputs come from the
        // trace, so nothing reads it.
        self.classes[ci].stats.cycles += 1;
    }

    /// Class `ci`'s private image (its inputs as latched, its outputs as last written).
    pub fn class_image(&self, ci: usize) -> &[Value] {
        &self.classes[ci].image
    }

    /// Installs a recorder that sees every class cycle.
    pub fn set_recorder(&mut self, sink: Box<dyn CycleSink>) {
        self.sink = Some(sink);
    }

    /// Removes the recorder (to finish it after the run).
    pub fn take_recorder(&mut self) -> Option<Box<dyn CycleSink>> {
        self.sink.take()
    }

    fn run_class(&mut self, ci: usize, clock: &mut dyn Clock) {
        self.bus.observe_error(self.in_error);
        let class = &mut self.classes[ci];
        let release = class.next_release;
        let start = clock.now_ns();
        self.bus.read_inputs(ci, release, &mut self.global);
        // The bus's fault status is an input like any other: latched below by the classes that read it.
        self.global[usize::from(self.bus_fault)] = Value::Bool(self.bus.fault());
        copy_runs(&class.input_runs, &self.global, &mut class.image);
        let cycle = class.stats.cycles;
        let violation = self.execute(ci, release, clock, None);
        // The state is the status program's (or service mode's): it changes only when they run.
        if self.service.is_some() || self.classes[ci].reports_status {
            self.in_error = self.app_status().is_some_and(|s| s.state == "ERROR");
            self.status_seq += 1;
        }
        self.publish(ci);
        self.bus.write_outputs(ci, release, &self.global);
        self.record(ci, release, cycle, violation);
        let class = &mut self.classes[ci];
        let end = clock.now_ns();

        let stats = &mut class.stats;
        stats.cycles += 1;
        stats.lateness.record(start.saturating_sub(release));
        stats.exec.record(end.saturating_sub(start));
        let deadline = release + class.period_ns;
        if end > deadline {
            stats.overruns += 1;
            let late_by = end - deadline;
            if late_by > class.tolerance_ns {
                stats.violations += 1;
                if !class.violation_logged {
                    // Logged once per class from here; the count is in the statistics, and the
                    // real-time monitor reports further violations off the cyclic thread.
                    class.violation_logged = true;
                    warn!(
                        task_class = %class.name,
                        "cycle time violation: cycle {cycle} ended {:.3} ms past its deadline (tolerance {:.3} ms); reaction: {}",
                        late_by as f64 / 1e6,
                        class.tolerance_ns as f64 / 1e6,
                        match class.reaction { Reaction::Log => "log", Reaction::Error => "error (the application is told)" },
                    );
                }
                if class.reaction == Reaction::Error {
                    self.violation_seq += 1;
                    self.last_violation = Some(CycleViolation {
                        class: ci,
                        late_by_ns: late_by,
                    });
                }
            }
        }
        // Absolute deadlines: the next release is a multiple of the period from the epoch, so
        // lateness never accumulates. Releases whose whole window has passed are skipped.
        let mut next = release + class.period_ns;
        while next + class.period_ns <= end {
            next += class.period_ns;
            stats.missed += 1;
        }
        class.next_release = next;
    }

    /// Sets every output to its safe value and hands that image to the bus. Call once, at the end.
    pub fn shutdown(&mut self) {
        for (i, var) in self.table.vars().iter().enumerate() {
            if matches!(var.writer, Some(Writer::Program { .. })) {
                self.global[i] = var.safe;
            }
        }
        self.bus.write_safe(&self.global);
    }
}

/// The ascending variable indexes `vars` as runs of consecutive indexes.
fn runs(vars: &[VarIndex]) -> Vec<std::ops::Range<usize>> {
    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
    for &v in vars {
        let v = usize::from(v);
        match runs.last_mut() {
            Some(last) if last.end == v => last.end = v + 1,
            _ => runs.push(v..v + 1),
        }
    }
    runs
}

/// Copies the variables of `runs` from `from` to `to` (images of one table: same length).
fn copy_runs(runs: &[std::ops::Range<usize>], from: &[Value], to: &mut [Value]) {
    for r in runs {
        to[r.clone()].copy_from_slice(&from[r.clone()]);
    }
}
