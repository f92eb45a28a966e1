//! The screen's commands on their way into the process image: the web server writes the latest
//! [`Commands`] (under a lock, off the cyclic thread), the [`HmiBus`] laid over the field bus
//! takes them wait-free before each cycle and writes the `HMI_*` variables — so a command from
//! the page is an input like the panel's, traced and replayed.

use std::sync::{Arc, Mutex};

use pkm_api::hmi::{
    HMI_AXES, HMI_JOG, HMI_JOG_AXIS, HMI_NC, HMI_NC_PROGRAM, HMI_REFERENCE, HMI_STOP, HMI_TOOL_CHANGED,
    HMI_TOOL_CONFIRM, JOG_AXIS_RANGE,
};
use pkm_api::trajectory::{OVERRIDE_DEFAULT, vars};

use super::job_news::{JobNews, JobOutcome};
use crate::image::{Value, VarIndex, VarTable, VarType, Writer};
use crate::runtime::bus::Bus;

/// How long a press from the screen holds its variable on (ns): two main cycles of 50 ms, so
/// that the main program sees it whatever its phase.
pub const PRESS_NS: u64 = 100_000_000;

/// What the screen commands now: a count of presses per button (a new count is a new press),
/// the jog's deflection, the program's overrides and single block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Commands {
    /// Presses of STOP, the axis button, the program's start, hold and resume, the tool
    /// change's old confirmation and Reference. A press while the previous one of its button is still held merges
    /// with it (a double click is one press).
    pub presses: [u64; PRESSES],
    /// Acknowledgements of an error: each is a STOP press that starts only once STOP has been
    /// released for the programs' STOP lockout — so an acknowledgement sent right after STOP is
    /// a press of its own, neither merged with the STOP nor ignored by the lockout (OPC UA's
    /// Acknowledge).
    pub acknowledgements: u64,
    /// The jog (x, y in −1 … 1); 0 when nothing is held.
    pub jog: [f64; 2],
    /// Which axis the jog moves (0: the stick's pair; k ≥ 1: the k-th pose coordinate alone;
    /// −k: the k-th joint alone).
    pub jog_axis: i16,
    /// The program to load (its number from 1; 0: no choice made).
    pub program: i16,
    /// The feed override (percent, 0 … 150).
    pub feed_override: i16,
    /// The rapid override (percent, 0 … 100).
    pub rapid_override: i16,
    /// The spindle override (percent, 0 … 150).
    pub spindle_override: i16,
    /// Single block.
    pub single_block: bool,
    /// The tool change the screen confirmed last (its `TOOL_CHANGE_NUMBER`; 0: none).
    pub tool_confirm: i32,
}

impl Default for Commands {
    /// No press, no jog, no program chosen, 100 % overrides, single block off.
    fn default() -> Self {
        Commands {
            presses: [0; PRESSES],
            acknowledgements: 0,
            tool_confirm: 0,
            jog: [0.0; 2],
            jog_axis: 0,
            program: 0,
            feed_override: OVERRIDE_DEFAULT,
            rapid_override: OVERRIDE_DEFAULT,
            spindle_override: OVERRIDE_DEFAULT,
            single_block: false,
        }
    }
}

/// The feed override's range on the screen (percent).
pub const FEED_OVERRIDE_RANGE: std::ops::RangeInclusive<i16> = 0..=150;
/// The rapid override's range on the screen (percent).
pub const RAPID_OVERRIDE_RANGE: std::ops::RangeInclusive<i16> = 0..=100;
/// The spindle override's range on the screen (percent).
pub const SPINDLE_OVERRIDE_RANGE: std::ops::RangeInclusive<i16> = 0..=150;

/// How many buttons the screen presses.
pub const PRESSES: usize = 7;

/// Which of [`Commands::presses`] is which.
pub mod press {
    /// STOP (and the acknowledgement in ERROR).
    pub const STOP: usize = 0;
    /// The axis button.
    pub const AXES: usize = 1;
    /// Program start, hold, resume.
    pub const NC: [usize; 3] = [2, 3, 4];
    /// The old, unnamed confirmation of a manual tool change (`HMI_TOOL_CHANGED`): pressed by
    /// nothing now, its variable declared so that older traces keep their shape; the screen
    /// confirms by [`super::Commands::tool_confirm`], which names the change.
    pub const TOOL_CHANGED: usize = 5;
    /// Reference again (`HMI_REFERENCE`; taken in READY).
    pub const REFERENCE: usize = 6;
}

/// The servers' end: any connection may command (they share it, and the commands as last
/// published, under a lock); and what became of the screen's jobs, for OPC UA's conditions.
#[derive(Clone)]
pub struct CommandSink {
    commands: Arc<Mutex<(triple_buffer::Input<Commands>, Commands)>>,
    jobs: Arc<tokio::sync::watch::Sender<JobNews>>,
}

impl CommandSink {
    /// Changes the commands by `edit` and publishes them.
    pub fn update(&self, edit: impl FnOnce(&mut Commands)) {
        let mut guard = self.commands.lock().unwrap_or_else(|p| p.into_inner());
        let (input, current) = &mut *guard;
        edit(current);
        input.write(*current);
    }

    /// The commands as last published.
    pub fn current(&self) -> Commands {
        self.commands.lock().unwrap_or_else(|p| p.into_inner()).1
    }

    /// Tells what became of a screen job.
    pub fn report_job(&self, outcome: JobOutcome) {
        self.jobs.send_modify(|news| news.tell(outcome));
    }

    /// What became of the screen's jobs: the latest outcome, as it changes.
    pub fn job_news(&self) -> tokio::sync::watch::Receiver<JobNews> {
        self.jobs.subscribe()
    }
}

/// The field bus with the screen's variables laid over it.
pub struct HmiBus {
    inner: Box<dyn Bus>,
    /// The class that latches the screen's variables (the fastest: STOP reaches the interlock).
    class: usize,
    output: triple_buffer::Output<Commands>,
    /// The variables: the first five presses' (in [`press`] order), the jog's x and y, its axis,
    /// the program to load, the feed and rapid overrides, single block, then the tool change's
    /// confirmation and the spindle override (declared last, so that the earlier ones keep their
    /// order in traces).
    vars: [VarIndex; 14],
    /// `HMI_TOOL_CONFIRM`, declared after them all.
    tool_confirm: VarIndex,
    /// Each press's variable, in [`press`] order (`HMI_REFERENCE` declared last of all).
    press_vars: [VarIndex; PRESSES],
    seen: [u64; PRESSES],
    /// Until when each press holds its variable on (ns of the schedule).
    until: [u64; PRESSES],
    /// Acknowledgements seen, and whether one waits for STOP's release.
    acknowledged: u64,
    acknowledgement_waits: bool,
    /// How long STOP must have been released before an acknowledgement presses it (ns).
    acknowledgement_gap_ns: u64,
    /// Whether the machine is in ERROR now ([`Bus::observe_error`]): an acknowledgement presses
    /// STOP only then.
    in_error: bool,
}

impl HmiBus {
    /// Wraps `inner`; the screen's variables are latched by the task class `class`; the programs
    /// ignore STOP for `stop_lockout_ns` after a press is taken.
    pub fn new(inner: Box<dyn Bus>, class: usize, stop_lockout_ns: u64) -> (HmiBus, CommandSink) {
        let (input, output) = triple_buffer::triple_buffer(&Commands::default());
        let bus = HmiBus {
            inner,
            class,
            output,
            vars: [0; 14],
            tool_confirm: 0,
            press_vars: [0; PRESSES],
            seen: [0; PRESSES],
            until: [0; PRESSES],
            acknowledged: 0,
            acknowledgement_waits: false,
            acknowledgement_gap_ns: stop_lockout_ns.max(PRESS_NS),
            in_error: false,
        };
        let sink = CommandSink {
            commands: Arc::new(Mutex::new((input, Commands::default()))),
            jobs: Arc::new(tokio::sync::watch::Sender::new(JobNews::default())),
        };
        (bus, sink)
    }
}

impl Bus for HmiBus {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn declare(&mut self, table: &mut VarTable) {
        self.inner.declare(table);
        let at = "the operator screen (--hmi)";
        let writer = || Writer::Bus {
            class: self.class,
            at: at.to_string(),
        };
        let mut declare = |name: &str, ty: VarType, safe: Value| table.declare_writer(name, ty, writer(), safe);
        self.vars = [
            declare(HMI_STOP.name(), VarType::Bool, Value::Bool(false)),
            declare(HMI_AXES.name(), VarType::Bool, Value::Bool(false)),
            declare(HMI_NC[0].name(), VarType::Bool, Value::Bool(false)),
            declare(HMI_NC[1].name(), VarType::Bool, Value::Bool(false)),
            declare(HMI_NC[2].name(), VarType::Bool, Value::Bool(false)),
            declare(HMI_JOG[0].name(), VarType::Real, Value::Real(0.0)),
            declare(HMI_JOG[1].name(), VarType::Real, Value::Real(0.0)),
            declare(HMI_JOG_AXIS.name(), VarType::Int, Value::Int(0)),
            declare(HMI_NC_PROGRAM.name(), VarType::Int, Value::Int(0)),
            declare(
                vars::NC_FEED_OVERRIDE.name(),
                VarType::Int,
                Value::Int(OVERRIDE_DEFAULT),
            ),
            declare(
                vars::NC_RAPID_OVERRIDE.name(),
                VarType::Int,
                Value::Int(OVERRIDE_DEFAULT),
            ),
            declare(vars::NC_SINGLE_BLOCK.name(), VarType::Bool, Value::Bool(false)),
            declare(HMI_TOOL_CHANGED.name(), VarType::Bool, Value::Bool(false)),
            declare(
                vars::NC_SPINDLE_OVERRIDE.name(),
                VarType::Int,
                Value::Int(OVERRIDE_DEFAULT),
            ),
        ];
        self.tool_confirm = table.declare_writer(HMI_TOOL_CONFIRM.name(), VarType::Dint, writer(), Value::Dint(0));
        let reference = table.declare_writer(HMI_REFERENCE.name(), VarType::Bool, writer(), Value::Bool(false));
        let v = self.vars;
        self.press_vars = [v[0], v[1], v[2], v[3], v[4], v[12], reference];
    }

    fn start(&mut self) -> Result<(), String> {
        self.inner.start()
    }

    fn read_inputs(&mut self, class: usize, t_ns: u64, image: &mut [Value]) {
        self.inner.read_inputs(class, t_ns, image);
        if class != self.class {
            return;
        }
        let c = *self.output.read();
        // An acknowledgement presses STOP only while the machine is in ERROR, as the PLC's own
        // latest cycle left it: the screen and OPC UA judge by frames a cycle or more old, and
        // an acknowledgement sent after the one that ended this error (a double click, the
        // screen and a client at once) is dropped here, never a STOP press in REBOOT or INIT.
        if c.acknowledgements != self.acknowledged {
            self.acknowledged = c.acknowledgements;
            self.acknowledgement_waits = self.in_error;
        }
        let stop = press::STOP;
        if self.acknowledgement_waits && t_ns >= self.until[stop].saturating_add(self.acknowledgement_gap_ns) {
            self.acknowledgement_waits = false;
            if self.in_error {
                self.until[stop] = t_ns + PRESS_NS;
            }
        }
        for k in 0..PRESSES {
            if c.presses[k] != self.seen[k] {
                self.seen[k] = c.presses[k];
                self.until[k] = t_ns + PRESS_NS;
            }
            image[usize::from(self.press_vars[k])] = Value::Bool(t_ns < self.until[k]);
        }
        for (i, v) in c.jog.iter().enumerate() {
            image[usize::from(self.vars[5 + i])] = Value::Real(v.clamp(-1.0, 1.0));
        }
        image[usize::from(self.vars[7])] = Value::Int(c.jog_axis.clamp(*JOG_AXIS_RANGE.start(), *JOG_AXIS_RANGE.end()));
        image[usize::from(self.vars[8])] = Value::Int(c.program.max(0));
        let clamp = |v: i16, r: &std::ops::RangeInclusive<i16>| v.clamp(*r.start(), *r.end());
        image[usize::from(self.vars[9])] = Value::Int(clamp(c.feed_override, &FEED_OVERRIDE_RANGE));
        image[usize::from(self.vars[10])] = Value::Int(clamp(c.rapid_override, &RAPID_OVERRIDE_RANGE));
        image[usize::from(self.vars[11])] = Value::Bool(c.single_block);
        image[usize::from(self.vars[13])] = Value::Int(clamp(c.spindle_override, &SPINDLE_OVERRIDE_RANGE));
        image[usize::from(self.tool_confirm)] = Value::Dint(c.tool_confirm);
    }

    fn write_outputs(&mut self, class: usize, t_ns: u64, image: &[Value]) {
        self.inner.write_outputs(class, t_ns, image);
    }

    fn write_safe(&mut self, image: &[Value]) {
        self.inner.write_safe(image);
    }

    /// The wrapped bus (the wrapper is transparent to callers that look for the bus's type).
    fn as_any(&self) -> &dyn std::any::Any {
        self.inner.as_any()
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self.inner.as_any_mut()
    }

    fn write_fault_cause(&self, out: &mut String) -> bool {
        self.inner.write_fault_cause(out)
    }

    fn observe_error(&mut self, in_error: bool) {
        self.in_error = in_error;
        self.inner.observe_error(in_error);
    }

    fn fault(&self) -> bool {
        self.inner.fault()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::bus::NoBus;

    /// An edit of the commands at a time (ms).
    type Edit = (u64, fn(&mut Commands));

    /// HMI_STOP as the bus writes it at each of `times_ms`, with `edits` applied to the
    /// commands just before the time they are paired with.
    fn stop_at(edits: &[Edit], times_ms: &[u64]) -> Vec<bool> {
        stop_at_in(edits, times_ms, |_| true)
    }

    /// [`stop_at`], the machine in ERROR at the times `in_error` says.
    fn stop_at_in(edits: &[Edit], times_ms: &[u64], in_error: fn(u64) -> bool) -> Vec<bool> {
        let (mut bus, sink) = HmiBus::new(Box::new(NoBus), 0, 500_000_000);
        let mut table = VarTable::new();
        bus.declare(&mut table);
        let stop = usize::from(table.index_of(HMI_STOP.name()).expect("declared"));
        let mut image: Vec<Value> = table.vars().iter().map(|v| v.safe).collect();
        times_ms
            .iter()
            .map(|&t| {
                for (at, edit) in edits {
                    if *at == t {
                        sink.update(edit);
                    }
                }
                bus.observe_error(in_error(t));
                bus.read_inputs(0, t * 1_000_000, &mut image);
                image[stop] == Value::Bool(true)
            })
            .collect()
    }

    #[test]
    fn a_second_stop_while_the_first_is_held_is_the_same_press() {
        let press: fn(&mut Commands) = |c| c.presses[press::STOP] += 1;
        assert_eq!(
            stop_at(&[(1000, press), (1050, press)], &[1000, 1050, 1090, 1100, 1150, 1200]),
            [true, true, true, true, false, false],
            "a double click is one press, held 100 ms from the second click: no release between"
        );
    }

    #[test]
    fn an_acknowledgement_presses_stop_once_the_lockout_after_its_release_has_passed() {
        let press: fn(&mut Commands) = |c| c.presses[press::STOP] += 1;
        let acknowledge: fn(&mut Commands) = |c| c.acknowledgements += 1;
        assert_eq!(
            stop_at(
                &[(1000, press), (1010, acknowledge)],
                &[1000, 1010, 1090, 1100, 1590, 1600, 1690, 1700, 2500]
            ),
            [true, true, true, false, false, true, true, false, false],
            "STOP 1000 … 1100 ms, released for the 500 ms lockout, then the acknowledgement's press"
        );
    }

    /// The acknowledgement's press at 1600 ms ends the error (REBOOT from then on); a second
    /// acknowledgement, sent at 1650 ms on a frame that still showed ERROR, is dropped: no STOP
    /// press in REBOOT or INIT. An acknowledgement outside ERROR presses nothing either.
    #[test]
    fn an_acknowledgement_after_the_error_ended_presses_nothing() {
        let press: fn(&mut Commands) = |c| c.presses[press::STOP] += 1;
        let acknowledge: fn(&mut Commands) = |c| c.acknowledgements += 1;
        assert_eq!(
            stop_at_in(
                &[(1000, press), (1010, acknowledge), (1650, acknowledge)],
                &[1000, 1010, 1100, 1600, 1650, 1700, 2200, 2250, 2300, 3000],
                |t| t < 1610
            ),
            [true, true, false, true, true, false, false, false, false, false],
        );
        assert_eq!(
            stop_at_in(&[(1000, acknowledge)], &[1000, 1500, 1600, 2000], |_| false),
            [false; 4]
        );
    }
}
