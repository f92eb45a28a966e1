//! The Modbus bus driver (TCP, or RTU over a serial line): a station behind the register map of
//! the I/O map. [`ModbusBus`] is the cyclic side; `link` runs the exchange loop, `exchange` does
//! one exchange, `stats` counts.
//!
//! Declaring the variables only lays out the slots; the link opens when the runtime starts the
//! bus ([`Bus::start`]), after the configuration is accepted and before the first cycle.
//! An exchange loop on its own thread reads the discrete inputs and input registers and writes the
//! coils and holding registers — four requests on the standard tables, or one
//! read/write-multiple-registers request on the packed process image ([`ExchangeMode`]) — every
//! request with a timeout. The first cycle waits for the first complete input image (or a bus
//! fault), so programs never see inputs the station did not send. Complete input sets reach the cycle
//! through a wait-free mailbox, the cycle's outputs reach the loop the same way, so a cycle never
//! waits on the wire. Failed exchanges (timeouts, corrupt responses such as a bad CRC, exceptions,
//! a lost connection) are counted; more
//! consecutive failures than the bound is a bus fault, which the runtime publishes as `bus_fault`.
//! The loop reconnects with backoff; the fault clears when exchanges succeed again (the
//! application keeps its ERROR until it is acknowledged).

mod exchange;
mod link;
mod mbap;
mod stats;
pub mod wire;

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;
use std::time::Duration;

pub use exchange::WireLoad;
pub use link::Transport;
pub use stats::LinkStats;

use super::catalogue::Direction;
use super::map::{IoMap, StationKind};
use super::registers::{ImageLayout, MAX_IMAGE_READ, MAX_IMAGE_WRITE, RegisterMap};
use crate::image::{Value, VarIndex, VarTable};
use crate::runtime::bus::{Bus, MailboxReader, MailboxWriter, image_mailbox};
use exchange::{BusController, Exchange, Slot};
use link::{Link, NO_IMAGE, Shared};

/// How one exchange talks to the station.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExchangeMode {
    /// `image` on a serial line, `tables` over TCP.
    #[default]
    Auto,
    /// Four requests on the standard tables: read discrete inputs (2), read input registers
    /// (4), write coils (15), write holding registers (16). Any Modbus server with the
    /// register map will do.
    Tables,
    /// One read/write-multiple-registers transaction (23) on the packed process image. Needs a
    /// station that mirrors it (io-sim does); 36 bytes on the wire for the TRIJOINT station
    /// against 76 for `tables`, which is what makes a 10 ms cycle at 115 200 baud.
    Image,
}

impl ExchangeMode {
    /// The mode's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ExchangeMode::Auto => "auto",
            ExchangeMode::Tables => "tables",
            ExchangeMode::Image => "image",
        }
    }
}

/// How many request timeouts the safe stop waits for an exchange that confirms the safe outputs
/// (beyond a few exchange periods).
const SAFE_WRITE_ATTEMPTS: u32 = 3;

/// The longest the bus waits for the station's first input image before the first cycle.
pub const STARTUP_WAIT: Duration = Duration::from_secs(5);

/// The default bound on the age of the newest input image: five 10 ms cycles, one main cycle.
pub const DEFAULT_MAX_INPUT_AGE: Duration = Duration::from_millis(50);

/// The default bound on the exchange time (the median of the last five): the TRIJOINT's regulators,
/// tuned on the simulated bus, still reference over a link with 7.3 ms `tables` or 11.4 ms
/// `image` exchanges and oscillate from 9 and 14.5 ms (measured through a delaying proxy); an
/// RTU `image` exchange at 115 200 baud takes 6.94 ms.
pub const DEFAULT_MAX_EXCHANGE: Duration = Duration::from_millis(8);

/// Settings of the exchange loop.
#[derive(Clone, Copy, Debug)]
pub struct ModbusOptions {
    /// How each exchange talks to the station.
    pub exchange: ExchangeMode,
    /// Time between exchanges.
    pub period: Duration,
    /// Timeout of each request (and of connecting).
    pub timeout: Duration,
    /// More consecutive failed exchanges than this is a bus fault.
    pub max_failures: u32,
    /// The newest complete input image older than this is a bus fault, whatever the pattern of
    /// failures behind it (slow responses that never time out, most exchanges failing but never
    /// more than `max_failures` in a row): the programs must not act on stale inputs.
    pub max_input_age: Duration,
    /// The median time of the last exchanges above this is a bus fault: the drive regulators were
    /// tuned for inputs this fresh, and a slower link makes them oscillate long before the
    /// inputs are stale.
    pub max_exchange: Duration,
    /// SCHED_FIFO priority of the exchange thread, 0 for normal scheduling: the run gives it one
    /// below the cyclic thread's, so that it carries the cycle's outputs on time beside other
    /// processes.
    pub priority: u8,
    /// The shortest task class period: every class's cycle hands the outputs over, so the
    /// newest are at most this old while the cycles run. Outputs older than three of these (and
    /// than twice `max_input_age`) are not written: a hung cycle stops feeding the station's
    /// watchdog.
    pub fastest_cycle: Duration,
}

impl ModbusOptions {
    /// Outputs older than this are not written ([`ModbusOptions::fastest_cycle`]).
    pub fn max_output_age(&self) -> Duration {
        (self.max_input_age * 2).max(self.fastest_cycle * 3)
    }
}

impl Default for ModbusOptions {
    fn default() -> Self {
        ModbusOptions {
            exchange: ExchangeMode::Auto,
            period: Duration::from_millis(5),
            timeout: Duration::from_millis(100),
            max_failures: 3,
            max_input_age: DEFAULT_MAX_INPUT_AGE,
            max_exchange: DEFAULT_MAX_EXCHANGE,
            priority: 0,
            fastest_cycle: Duration::from_millis(10),
        }
    }
}

/// Why a Modbus bus cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum ModbusSetupError {
    /// The packed image is too large (or empty) for one function-code-23 transaction.
    #[error(
        "the packed process image ({input} input and {output} output registers) does not fit one \
         read/write-multiple-registers request (1–{max_read} read, 1–{max_write} written): use --exchange tables"
    )]
    ImageTooLarge {
        /// Registers in the input image.
        input: u16,
        /// Registers in the output image.
        output: u16,
        /// The request's read limit.
        max_read: u16,
        /// The request's write limit.
        max_write: u16,
    },
    /// The X20BC0087 has no packed image.
    #[error(
        "the X20BC0087 exchanges its process data on the standard Modbus tables only: --exchange image needs a \
         generic station (io-sim's, with \"station\": \"generic\" in the I/O map); use --exchange tables"
    )]
    NoImageOnBusController,
    /// The serial line is too slow for the exchange (see [`wire::WireTime::check`]).
    #[error("{0}")]
    LineTooSlow(String),
}

/// The Modbus bus.
pub struct ModbusBus {
    name: String,
    map: IoMap,
    /// The layout spoken: the map's station over TCP; the generic one on a serial line (an
    /// X20BC0087 has no serial interface).
    station: StationKind,
    options: ModbusOptions,
    /// The exchange loop, laid out by `declare`, until `start` spawns it.
    pending: Option<(Link, MailboxWriter, MailboxReader)>,
    transport: Option<Transport>,
    inputs: Option<MailboxReader>,
    outputs: Option<MailboxWriter>,
    output_vars: Vec<VarIndex>,
    output_values: Vec<Value>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl ModbusBus {
    /// A bus to the station reached by `transport`, serving `map`'s modules. Nothing is opened
    /// here: `declare` lays out which variable each channel is, `start` opens the link.
    /// `ExchangeMode::Auto` in `options` is resolved here: the packed image on a serial line, the
    /// standard tables over TCP.
    pub fn new(map: IoMap, transport: Transport, mut options: ModbusOptions) -> Result<Self, ModbusSetupError> {
        let station = match transport {
            Transport::Tcp(_) => map.station,
            Transport::Serial { .. } | Transport::Stream(_) => {
                if map.station == StationKind::X20bc0087 {
                    tracing::info!(
                        "modbus: {}'s station is an X20BC0087, a Modbus TCP bus controller; on a serial line the \
                         station is the generic one with the same modules (as io-sim serves it there)",
                        map.origin
                    );
                }
                StationKind::Generic
            }
        };
        if station == StationKind::X20bc0087 {
            match options.exchange {
                ExchangeMode::Image => return Err(ModbusSetupError::NoImageOnBusController),
                ExchangeMode::Auto => options.exchange = ExchangeMode::Tables,
                ExchangeMode::Tables => {}
            }
        }
        if options.exchange == ExchangeMode::Auto {
            options.exchange = match transport {
                Transport::Tcp(_) => ExchangeMode::Tables,
                Transport::Serial { .. } | Transport::Stream(_) => ExchangeMode::Image,
            };
        }
        let sizes = RegisterMap::laid_out(&map, station).sizes();
        let layout = ImageLayout::of(sizes);
        if options.exchange == ExchangeMode::Image && !layout.fits_one_transaction() {
            return Err(ModbusSetupError::ImageTooLarge {
                input: layout.input_len,
                output: layout.output_len,
                max_read: MAX_IMAGE_READ,
                max_write: MAX_IMAGE_WRITE,
            });
        }
        if let Transport::Serial { baud, .. } = &transport {
            let wire = wire::WireTime::of(options.exchange, sizes, *baud);
            if let Some(warning) = wire
                .check(options.max_exchange)
                .map_err(ModbusSetupError::LineTooSlow)?
            {
                tracing::warn!("modbus {}: {warning}", transport.describe());
            }
        }
        Ok(ModbusBus {
            name: transport.describe(),
            map,
            station,
            options,
            pending: None,
            transport: Some(transport),
            inputs: None,
            outputs: None,
            output_vars: Vec::new(),
            output_values: Vec::new(),
            shared: Arc::new(Shared::new()),
            thread: None,
        })
    }

    /// Blocks until the first complete input image has arrived or the link has failed (a bus
    /// fault), at most [`STARTUP_WAIT`]: the first cycle must see the station's inputs, not the
    /// mailbox's initial zeros (an encoder counter jumping from 0 to its true value would be an
    /// encoder fault).
    fn await_first_image(&self) {
        let deadline = std::time::Instant::now() + STARTUP_WAIT;
        let shared = &self.shared;
        while shared.image_at_ns.load(Ordering::Acquire) == NO_IMAGE && !shared.fault.load(Ordering::Relaxed) {
            if std::time::Instant::now() >= deadline || self.thread.is_none() {
                shared.declare_fault(
                    &self.name,
                    format!("no input image within {} s", STARTUP_WAIT.as_secs()),
                );
                return;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// The exchange in use (never `Auto`).
    pub fn exchange(&self) -> ExchangeMode {
        self.options.exchange
    }

    /// The link's counters.
    pub fn stats(&self) -> Arc<LinkStats> {
        Arc::clone(&self.shared.stats)
    }

    /// Whether the newest complete input image is older than `max_input_age` (supervised from
    /// the first image on; before it, the startup wait decides). The bus is the I/O layer, so it
    /// may read the clock; what it decides reaches the programs as the `bus_fault` input, which
    /// traces record and replays reproduce.
    fn inputs_stale(&self) -> bool {
        let image_at = self.shared.image_at_ns.load(Ordering::Acquire);
        if image_at == NO_IMAGE {
            return false;
        }
        let age = Duration::from_nanos(self.shared.now_ns().saturating_sub(image_at));
        let stale = age > self.options.max_input_age;
        if stale && !self.shared.stale.swap(true, Ordering::AcqRel) {
            // Once per episode: formatting a fault's cause is the only allocation here.
            self.shared.stats.stale.fetch_add(1, Ordering::Relaxed);
            let mut cause = format!(
                "the newest input image is {} ms old (limit {} ms, --max-input-age-ms)",
                age.as_millis(),
                self.options.max_input_age.as_millis()
            );
            // The exchanges' first failure, where they fail: why the inputs stopped.
            if let Ok(first) = self.shared.first_failure.try_lock()
                && let Some(first) = first.as_deref()
            {
                cause.push_str(link::FAILING_SINCE);
                cause.push_str(first);
            }
            tracing::warn!("modbus {}: bus fault: {cause}", self.name);
            self.shared.latch(&cause);
        } else if !stale && self.shared.stale.swap(false, Ordering::AcqRel) {
            self.shared.episode_over();
        }
        stale
    }
}

impl Bus for ModbusBus {
    fn name(&self) -> &str {
        &self.name
    }

    /// Lays out the slots and mailboxes; opens nothing (that is [`Bus::start`]).
    fn declare(&mut self, table: &mut VarTable) {
        let registers = RegisterMap::laid_out(&self.map, self.station);
        let mut inputs = Vec::new();
        let mut outputs = Vec::new();
        for b in &self.map.bindings {
            let entry = registers
                .entries
                .iter()
                .position(|e| e.module == b.module && e.channel == b.channel);
            let var = b.declare(table);
            // A channel off the field bus (the HID joystick) is declared but stays at its zero
            // value here: "not connected" until the joystick driver provides it.
            let Some(entry) = entry else { continue };
            let e = &registers.entries[entry];
            let slot = Slot {
                entry,
                table: e.table,
                address: e.address,
                count: e.count,
                ty: e.ty,
                var,
            };
            match b.direction {
                Direction::Input => inputs.push(slot),
                Direction::Output => outputs.push(slot),
            }
        }
        let (in_writer, in_reader) = image_mailbox(
            inputs.iter().map(|s| s.var).collect(),
            inputs.iter().map(|s| Value::zero(s.ty)).collect(),
        );
        let (out_writer, out_reader) = image_mailbox(
            (0..outputs.len() as VarIndex).collect(),
            outputs.iter().map(|s| Value::zero(s.ty)).collect(),
        );
        self.inputs = Some(in_reader);
        self.outputs = Some(out_writer);
        self.output_vars = outputs.iter().map(|s| s.var).collect();
        self.output_values = outputs.iter().map(|s| Value::zero(s.ty)).collect();
        let Some(transport) = self.transport.take() else { return };
        let link = Link {
            name: self.name.clone(),
            transport,
            exchange: Exchange {
                mode: self.options.exchange,
                requests: self.map.requests,
                refused_pipelining: std::cell::Cell::new(false),
                timeout: self.options.timeout,
                inputs,
                outputs,
                sizes: registers.sizes(),
                holding_base: registers.holding_base,
                bus_controller: (self.station == StationKind::X20bc0087).then(|| BusController {
                    expected: crate::services::io::x20bc0087::expected_modules(&self.map, &registers),
                    watchdog_ms: self.map.watchdog_ms,
                    registers: registers.clone(),
                }),
            },
            max_output_age: self.options.max_output_age(),
            period: self.options.period,
            max_failures: self.options.max_failures,
            max_exchange: self.options.max_exchange,
            priority: self.options.priority,
            shared: Arc::clone(&self.shared),
        };
        self.pending = Some((link, in_writer, out_reader));
    }

    /// Opens the link: spawns the exchange loop and waits for the first input image (at most
    /// [`STARTUP_WAIT`]; a bus fault after that). An X20BC0087 whose modules are not the I/O
    /// map's, or that does not take the watchdog setting, is refused here: nothing was written
    /// to its outputs. Called once; a second call does nothing.
    fn start(&mut self) -> Result<(), String> {
        let Some((link, in_writer, out_reader)) = self.pending.take() else {
            return Ok(());
        };
        self.thread = link.spawn(in_writer, out_reader);
        self.await_first_image();
        let refused = self.shared.refused.lock().unwrap_or_else(|p| p.into_inner()).take();
        match refused {
            Some(why) => {
                if let Some(thread) = self.thread.take() {
                    // The loop ended when it refused.
                    let _ = thread.join();
                }
                Err(why)
            }
            None => Ok(()),
        }
    }

    fn read_inputs(&mut self, _class: usize, _t_ns: u64, image: &mut [Value]) {
        if let Some(inputs) = &mut self.inputs {
            inputs.take_latest(image);
        }
    }

    fn write_outputs(&mut self, _class: usize, _t_ns: u64, image: &[Value]) {
        for (value, var) in self.output_values.iter_mut().zip(&self.output_vars) {
            *value = image[usize::from(*var)];
        }
        if let Some(outputs) = &mut self.outputs {
            outputs.publish(&self.output_values);
        }
        // When the cycle published last: the loop writes outputs only while they are fresh, so
        // that a hung cycle stops feeding the station's watchdog.
        self.shared.outputs_at_ns.store(self.shared.now_ns(), Ordering::Release);
    }

    fn write_safe(&mut self, image: &[Value]) {
        let shared = Arc::clone(&self.shared);
        let exchanges = || shared.stats.exchanges.load(Ordering::Relaxed);
        let before = exchanges();
        self.write_outputs(0, 0, image);
        let Some(thread) = self.thread.take() else { return };
        // The safe outputs are at the station once an exchange that began after they were handed
        // to the loop has succeeded: the one under way may have taken the outputs before, the
        // next cannot. Waited for up to a few failed exchanges' time, then the loop stops.
        let bound = self.options.period * 4 + self.options.timeout * SAFE_WRITE_ATTEMPTS;
        let start = std::time::Instant::now();
        let confirmed = loop {
            if exchanges() >= before + 2 {
                break true;
            }
            if start.elapsed() >= bound {
                break false;
            }
            std::thread::sleep(Duration::from_millis(1));
        };
        self.shared.stop.store(true, Ordering::Relaxed);
        let _ = thread.join();
        if confirmed {
            tracing::info!(
                "modbus {}: the safe outputs reached the station ({:.0} ms after they were set)",
                self.name,
                start.elapsed().as_secs_f64() * 1e3
            );
        } else {
            let mut cause = String::new();
            let cause = if self.write_fault_cause(&mut cause) {
                format!(": {cause}")
            } else {
                String::new()
            };
            tracing::warn!(
                "modbus {}: the safe outputs could not be confirmed at the station: no exchange succeeded within {} ms after they were set{cause}; the station's own watchdog or connection monitoring must set its outputs safe",
                self.name,
                bound.as_millis()
            );
        }
        tracing::info!(
            "modbus {}: {}",
            self.name,
            self.shared.stats.summary(self.options.exchange)
        );
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn fault(&self) -> bool {
        self.shared.fault.load(Ordering::Relaxed) || self.inputs_stale()
    }

    fn write_fault_cause(&self, out: &mut String) -> bool {
        match self.shared.cause.try_lock() {
            Ok(cause) if !cause.is_empty() => {
                out.push_str(&cause);
                true
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_written_while_a_few_of_the_fastest_cycles_old() {
        assert_eq!(ModbusOptions::default().max_output_age(), Duration::from_millis(100));
        let slow = ModbusOptions {
            fastest_cycle: Duration::from_millis(200),
            ..Default::default()
        };
        assert_eq!(
            slow.max_output_age(),
            Duration::from_millis(600),
            "a 200 ms class alone"
        );
    }
}
