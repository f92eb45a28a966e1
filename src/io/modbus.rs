//! The Modbus bus driver (TCP, or RTU over a serial line): a station behind the register map of
//! the I/O map.
//!
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

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use tokio_modbus::client::Client as _;
use tokio_modbus::client::{self, Writer as _, rtu, tcp};
use tokio_modbus::{Request, Response, Slave};
use tokio_serial::SerialStream;

use super::catalogue::Direction;
use super::map::IoMap;
use super::registers::{
    INPUT_IMAGE, ImageLayout, MAX_IMAGE_READ, MAX_IMAGE_WRITE, OUTPUT_IMAGE, RegisterMap, Table, decode, encode,
    pack_bits, packed_bit,
};
use super::rx_counter::RxCounter;
use crate::bus::{Bus, MailboxReader, MailboxWriter, image_mailbox};
use crate::image::{Value, VarIndex, VarTable};

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

/// The longest the bus waits for the station's first input image before the first cycle.
pub const STARTUP_WAIT: Duration = Duration::from_secs(5);

/// `image_at_ns` before the first complete input image.
const NO_IMAGE: u64 = u64::MAX;

/// The default bound on the age of the newest input image: five 10 ms cycles, one main cycle.
pub const DEFAULT_MAX_INPUT_AGE: Duration = Duration::from_millis(50);

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
}

impl Default for ModbusOptions {
    fn default() -> Self {
        ModbusOptions {
            exchange: ExchangeMode::Auto,
            period: Duration::from_millis(5),
            timeout: Duration::from_millis(100),
            max_failures: 3,
            max_input_age: DEFAULT_MAX_INPUT_AGE,
        }
    }
}

/// Counters of the exchange loop.
#[derive(Debug)]
pub struct LinkStats {
    /// Successful exchanges.
    pub exchanges: AtomicU64,
    /// Requests that timed out with nothing received.
    pub timeouts: AtomicU64,
    /// Responses that arrived damaged: a bad CRC or bytes no valid frame could be made of.
    pub corrupt: AtomicU64,
    /// Exception responses.
    pub exceptions: AtomicU64,
    /// Lost or refused connections.
    pub disconnects: AtomicU64,
    /// Times the newest input image grew older than the bound (`max_input_age`).
    pub stale: AtomicU64,
    /// Summed duration of the successful exchanges (ns).
    pub exchange_ns_total: AtomicU64,
    /// Longest successful exchange (ns).
    pub exchange_ns_max: AtomicU64,
    /// Shortest successful exchange (ns; `u64::MAX` before the first).
    pub exchange_ns_min: AtomicU64,
}

impl Default for LinkStats {
    fn default() -> Self {
        LinkStats {
            exchanges: AtomicU64::new(0),
            timeouts: AtomicU64::new(0),
            corrupt: AtomicU64::new(0),
            exceptions: AtomicU64::new(0),
            disconnects: AtomicU64::new(0),
            stale: AtomicU64::new(0),
            exchange_ns_total: AtomicU64::new(0),
            exchange_ns_max: AtomicU64::new(0),
            exchange_ns_min: AtomicU64::new(u64::MAX),
        }
    }
}

/// What one exchange puts on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WireLoad {
    /// Request/response transactions.
    pub transactions: u32,
    /// Bytes of all RTU frames, both directions (address, function, data, CRC).
    pub bytes: u32,
}

impl WireLoad {
    /// The load of one exchange in `mode` (not `Auto`) for table sizes `[coils, discrete inputs,
    /// input registers, holding registers]`, as Modbus RTU frames.
    pub fn of(mode: ExchangeMode, sizes: [u16; 4]) -> WireLoad {
        let [coils, discrete, input, holding] = sizes.map(u32::from);
        // Address, function and CRC: 4 bytes around every PDU.
        let read_bits = |n: u32| (n > 0).then(|| (4 + 4) + (4 + 1 + n.div_ceil(8)));
        let read_regs = |n: u32| (n > 0).then(|| (4 + 4) + (4 + 1 + 2 * n));
        let write_bits = |n: u32| (n > 0).then(|| (4 + 5 + n.div_ceil(8)) + (4 + 4));
        let write_regs = |n: u32| (n > 0).then(|| (4 + 5 + 2 * n) + (4 + 4));
        let frames: Vec<u32> = match mode {
            ExchangeMode::Image => {
                let layout = ImageLayout::of(sizes);
                let (i, o) = (u32::from(layout.input_len), u32::from(layout.output_len));
                vec![(4 + 9 + 2 * o) + (4 + 1 + 2 * i)]
            }
            ExchangeMode::Tables | ExchangeMode::Auto => [
                read_bits(discrete),
                read_regs(input),
                write_bits(coils),
                write_regs(holding),
            ]
            .into_iter()
            .flatten()
            .collect(),
        };
        WireLoad {
            transactions: frames.len() as u32,
            bytes: frames.iter().sum(),
        }
    }
}

/// A binding as the driver sees it: where its channel lives and which variable it is.
#[derive(Clone, Copy, Debug)]
struct Slot {
    table: Table,
    address: u16,
    count: u16,
    ty: crate::image::VarType,
    var: VarIndex,
}

/// How the driver reaches the station.
pub enum Transport {
    /// Modbus TCP.
    Tcp(SocketAddr),
    /// Modbus RTU on a serial device at a baud rate (unit 1).
    Serial {
        /// The device (`/dev/ttyUSB0`, a pty, ...).
        path: String,
        /// Baud rate.
        baud: u32,
    },
    /// Modbus RTU on a serial port that is already open (one end of a pty pair, say); it cannot
    /// be reopened after the link is lost.
    Port(Option<serialport::TTYPort>),
}

impl Transport {
    fn describe(&self) -> String {
        match self {
            Transport::Tcp(a) => format!("tcp:{a}"),
            Transport::Serial { path, baud } => format!("serial:{path}@{baud}"),
            Transport::Port(_) => "serial:port".into(),
        }
    }

    /// Connects; every byte received on the link is added to `received`.
    async fn connect(&mut self, received: &Arc<AtomicU64>) -> std::io::Result<client::Context> {
        let serial = match self {
            Transport::Tcp(a) => {
                let stream = tokio::net::TcpStream::connect(*a).await?;
                // Requests are small and each waits for its response: send at once.
                stream.set_nodelay(true)?;
                return Ok(tcp::attach(RxCounter::new(stream, Arc::clone(received))));
            }
            Transport::Serial { path, baud } => SerialStream::open(&tokio_serial::new(path.as_str(), *baud))?,
            Transport::Port(p) => {
                let port = p
                    .take()
                    .ok_or_else(|| std::io::Error::other("the serial port was lost and cannot be reopened"))?;
                // Registered with the reactor here, in the exchange loop's runtime.
                SerialStream::try_from(port).map_err(std::io::Error::other)?
            }
        };
        Ok(rtu::attach_slave(
            RxCounter::new(serial, Arc::clone(received)),
            Slave(1),
        ))
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
}

/// The Modbus bus.
pub struct ModbusBus {
    name: String,
    map: IoMap,
    transport: Option<Transport>,
    options: ModbusOptions,
    inputs: Option<MailboxReader>,
    outputs: Option<MailboxWriter>,
    output_vars: Vec<VarIndex>,
    output_values: Vec<Value>,
    fault: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    /// When the newest complete input image was published, in ns since `epoch`; [`NO_IMAGE`]
    /// before the first.
    image_at_ns: Arc<AtomicU64>,
    epoch: std::time::Instant,
    /// Whether the inputs are stale now (a fault while it lasts, logged once per episode).
    stale: AtomicBool,
    stats: Arc<LinkStats>,
    thread: Option<JoinHandle<()>>,
}

impl ModbusBus {
    /// A bus to the station reached by `transport`, serving `map`'s modules. The exchange loop
    /// starts when the variables are declared (the bus then knows which variable each channel
    /// is). `ExchangeMode::Auto` in `options` is resolved here: the packed image on a serial
    /// line, the standard tables over TCP.
    pub fn new(map: IoMap, transport: Transport, mut options: ModbusOptions) -> Result<Self, ModbusSetupError> {
        if options.exchange == ExchangeMode::Auto {
            options.exchange = match transport {
                Transport::Tcp(_) => ExchangeMode::Tables,
                Transport::Serial { .. } | Transport::Port(_) => ExchangeMode::Image,
            };
        }
        let layout = ImageLayout::of(RegisterMap::of(&map).sizes());
        if options.exchange == ExchangeMode::Image && !layout.fits_one_transaction() {
            return Err(ModbusSetupError::ImageTooLarge {
                input: layout.input_len,
                output: layout.output_len,
                max_read: MAX_IMAGE_READ,
                max_write: MAX_IMAGE_WRITE,
            });
        }
        Ok(ModbusBus {
            name: transport.describe(),
            map,
            transport: Some(transport),
            options,
            inputs: None,
            outputs: None,
            output_vars: Vec::new(),
            output_values: Vec::new(),
            fault: Arc::new(AtomicBool::new(false)),
            stop: Arc::new(AtomicBool::new(false)),
            image_at_ns: Arc::new(AtomicU64::new(NO_IMAGE)),
            epoch: std::time::Instant::now(),
            stale: AtomicBool::new(false),
            stats: Arc::new(LinkStats::default()),
            thread: None,
        })
    }

    /// Blocks until the first complete input image has arrived or the link has failed (a bus
    /// fault), at most [`STARTUP_WAIT`]: the first cycle must see the station's inputs, not the
    /// mailbox's initial zeros (an encoder counter jumping from 0 to its true value would be an
    /// encoder fault).
    fn await_first_image(&self) {
        let deadline = std::time::Instant::now() + STARTUP_WAIT;
        while self.image_at_ns.load(Ordering::Acquire) == NO_IMAGE && !self.fault.load(Ordering::Relaxed) {
            if std::time::Instant::now() >= deadline || self.thread.is_none() {
                self.fault.store(true, Ordering::Relaxed);
                tracing::warn!(
                    "modbus {}: bus fault: no input image within {} s",
                    self.name,
                    STARTUP_WAIT.as_secs()
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
        Arc::clone(&self.stats)
    }
}

impl Bus for ModbusBus {
    fn name(&self) -> &str {
        &self.name
    }

    fn declare(&mut self, table: &mut VarTable) {
        let registers = RegisterMap::of(&self.map);
        let mut inputs = Vec::new();
        let mut outputs = Vec::new();
        for b in &self.map.bindings {
            let entry = registers
                .entries
                .iter()
                .find(|e| e.module == b.module && e.channel == b.channel);
            let var = b.declare(table);
            // A channel off the field bus (the HID joystick) is declared but stays at its zero
            // value here: "not connected" until the joystick driver provides it.
            let Some(e) = entry else { continue };
            let slot = Slot {
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
        let sizes = registers.sizes();
        let Some(transport) = self.transport.take() else { return };
        let link = Link {
            name: self.name.clone(),
            transport,
            options: self.options,
            inputs,
            outputs,
            sizes,
            fault: Arc::clone(&self.fault),
            stop: Arc::clone(&self.stop),
            image_at_ns: Arc::clone(&self.image_at_ns),
            epoch: self.epoch,
            stats: Arc::clone(&self.stats),
            received: Arc::new(AtomicU64::new(0)),
        };
        self.thread = std::thread::Builder::new()
            .name("modbus".into())
            .spawn(move || link.run(in_writer, out_reader))
            .ok();
        self.await_first_image();
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
    }

    fn write_safe(&mut self, image: &[Value]) {
        self.write_outputs(0, 0, image);
        // Give the loop a few exchanges to write the safe outputs, then stop it.
        std::thread::sleep(self.options.period * 4 + self.options.timeout);
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let s = &self.stats;
        let n = s.exchanges.load(Ordering::Relaxed);
        tracing::info!(
            "modbus {}: {n} exchanges ({}), mean {:.0} µs, max {:.0} µs; {} timeouts, {} corrupt, {} exceptions, {} disconnects, {} stale",
            self.name,
            self.options.exchange.name(),
            s.exchange_ns_total.load(Ordering::Relaxed) as f64 / n.max(1) as f64 / 1e3,
            s.exchange_ns_max.load(Ordering::Relaxed) as f64 / 1e3,
            s.timeouts.load(Ordering::Relaxed),
            s.corrupt.load(Ordering::Relaxed),
            s.exceptions.load(Ordering::Relaxed),
            s.disconnects.load(Ordering::Relaxed),
            s.stale.load(Ordering::Relaxed)
        );
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn fault(&self) -> bool {
        self.fault.load(Ordering::Relaxed) || self.inputs_stale()
    }
}

impl ModbusBus {
    /// Whether the newest complete input image is older than `max_input_age` (supervised from
    /// the first image on; before it, the startup wait decides). The bus is the I/O layer, so it
    /// may read the clock; what it decides reaches the programs as the `bus_fault` input, which
    /// traces record and replays reproduce.
    fn inputs_stale(&self) -> bool {
        let image_at = self.image_at_ns.load(Ordering::Acquire);
        if image_at == NO_IMAGE {
            return false;
        }
        let now = self.epoch.elapsed().as_nanos() as u64;
        let age = Duration::from_nanos(now.saturating_sub(image_at));
        let stale = age > self.options.max_input_age;
        if stale && !self.stale.swap(true, Ordering::Relaxed) {
            self.stats.stale.fetch_add(1, Ordering::Relaxed);
            tracing::warn!(
                "modbus {}: bus fault: the newest input image is {} ms old (limit {} ms)",
                self.name,
                age.as_millis(),
                self.options.max_input_age.as_millis()
            );
        } else if !stale {
            self.stale.store(false, Ordering::Relaxed);
        }
        stale
    }
}

/// The exchange loop's state.
struct Link {
    name: String,
    transport: Transport,
    options: ModbusOptions,
    inputs: Vec<Slot>,
    outputs: Vec<Slot>,
    sizes: [u16; 4],
    fault: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    image_at_ns: Arc<AtomicU64>,
    epoch: std::time::Instant,
    stats: Arc<LinkStats>,
    /// Bytes received on the link so far (tells a corrupt response from a silent station).
    received: Arc<AtomicU64>,
}

/// Why one exchange failed.
enum Failure {
    /// No response in time, nothing received.
    Timeout,
    /// A response that could not be decoded: bytes arrived, no valid frame (a bad CRC, garbage).
    Corrupt,
    /// An exception response.
    Exception,
    /// The connection or port is gone.
    Disconnected,
}

impl Link {
    fn run(mut self, mut inputs: MailboxWriter, mut outputs: MailboxReader) {
        let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
            Ok(r) => r,
            Err(e) => {
                tracing::error!("modbus: cannot start the exchange loop: {e}");
                self.fault.store(true, Ordering::Relaxed);
                return;
            }
        };
        runtime.block_on(self.exchange_loop(&mut inputs, &mut outputs));
    }

    async fn exchange_loop(&mut self, inputs: &mut MailboxWriter, outputs: &mut MailboxReader) {
        let mut failures = 0u32;
        let mut backoff = Duration::from_millis(50);
        let mut out_values: Vec<Value> = self.outputs.iter().map(|s| Value::zero(s.ty)).collect();
        let mut in_values: Vec<Value> = self.inputs.iter().map(|s| Value::zero(s.ty)).collect();
        while !self.stop.load(Ordering::Relaxed) {
            let connected = tokio::time::timeout(self.options.timeout, self.transport.connect(&self.received)).await;
            let mut ctx = match connected {
                Ok(Ok(ctx)) => {
                    backoff = Duration::from_millis(50);
                    ctx
                }
                _ => {
                    self.stats.disconnects.fetch_add(1, Ordering::Relaxed);
                    self.failed(&mut failures);
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(2));
                    continue;
                }
            };
            let mut tick = tokio::time::interval(self.options.period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            while !self.stop.load(Ordering::Relaxed) {
                tick.tick().await;
                outputs.take_latest(&mut out_values);
                let started = std::time::Instant::now();
                match self.exchange(&mut ctx, &mut in_values, &out_values).await {
                    Ok(()) => {
                        inputs.publish(&in_values);
                        self.image_at_ns
                            .store(self.epoch.elapsed().as_nanos() as u64, Ordering::Release);
                        let ns = started.elapsed().as_nanos() as u64;
                        self.stats.exchange_ns_total.fetch_add(ns, Ordering::Relaxed);
                        self.stats.exchange_ns_max.fetch_max(ns, Ordering::Relaxed);
                        self.stats.exchange_ns_min.fetch_min(ns, Ordering::Relaxed);
                        self.stats.exchanges.fetch_add(1, Ordering::Relaxed);
                        failures = 0;
                        if self.fault.swap(false, Ordering::Relaxed) {
                            tracing::info!(
                                "modbus {}: the link works again (the machine stays in ERROR until acknowledged)",
                                self.name
                            );
                        }
                    }
                    Err(f) => {
                        match f {
                            Failure::Timeout => self.stats.timeouts.fetch_add(1, Ordering::Relaxed),
                            Failure::Corrupt => self.stats.corrupt.fetch_add(1, Ordering::Relaxed),
                            Failure::Exception => self.stats.exceptions.fetch_add(1, Ordering::Relaxed),
                            Failure::Disconnected => self.stats.disconnects.fetch_add(1, Ordering::Relaxed),
                        };
                        self.failed(&mut failures);
                        // A lost link is opened again. Over TCP a timeout or a damaged response
                        // leaves the stream out of step, so it is opened again too; an RTU
                        // decoder finds the next frame by itself, and a serial port handed over
                        // open could not be reopened.
                        let reconnect = match f {
                            Failure::Disconnected => true,
                            Failure::Timeout | Failure::Corrupt => matches!(self.transport, Transport::Tcp(_)),
                            Failure::Exception => false,
                        };
                        if reconnect {
                            break;
                        }
                    }
                }
            }
        }
    }

    fn failed(&self, failures: &mut u32) {
        *failures += 1;
        if *failures > self.options.max_failures && !self.fault.swap(true, Ordering::Relaxed) {
            tracing::warn!("modbus {}: bus fault after {failures} failed exchanges", self.name);
        }
    }

    /// One exchange: every input read, every output written.
    async fn exchange(
        &self,
        ctx: &mut client::Context,
        in_values: &mut [Value],
        out_values: &[Value],
    ) -> Result<(), Failure> {
        match self.options.exchange {
            ExchangeMode::Image => self.exchange_image(ctx, in_values, out_values).await,
            ExchangeMode::Tables | ExchangeMode::Auto => self.exchange_tables(ctx, in_values, out_values).await,
        }
    }

    /// The packed process image in one read/write-multiple-registers transaction.
    async fn exchange_image(
        &self,
        ctx: &mut client::Context,
        in_values: &mut [Value],
        out_values: &[Value],
    ) -> Result<(), Failure> {
        let layout = ImageLayout::of(self.sizes);
        let (coil_bits, mut holding) = self.output_tables(out_values);
        let mut out_image = vec![0u16; usize::from(layout.output_bits)];
        pack_bits(&coil_bits, &mut out_image);
        out_image.append(&mut holding);
        let request =
            Request::ReadWriteMultipleRegisters(INPUT_IMAGE, layout.input_len, OUTPUT_IMAGE, out_image.into());
        let image = read_exactly(self.options.timeout, &self.received, ctx, request, layout.input_len)
            .await?
            .words()?;
        let (bits, regs) = image.split_at(usize::from(layout.input_bits));
        self.decode_inputs(in_values, |a| packed_bit(bits, a), regs)
    }

    /// The four standard tables, one request each.
    async fn exchange_tables(
        &self,
        ctx: &mut client::Context,
        in_values: &mut [Value],
        out_values: &[Value],
    ) -> Result<(), Failure> {
        let t = self.options.timeout;
        let [coils, discrete, input_regs, holding] = self.sizes;
        let bits = match discrete {
            0 => Vec::new(),
            n => read_exactly(t, &self.received, ctx, Request::ReadDiscreteInputs(0, n), n)
                .await?
                .bits()?,
        };
        let regs = match input_regs {
            0 => Vec::new(),
            n => read_exactly(t, &self.received, ctx, Request::ReadInputRegisters(0, n), n)
                .await?
                .words()?,
        };
        self.decode_inputs(in_values, |a| bits[a], &regs)?;
        let (coil_bits, words) = self.output_tables(out_values);
        if coils > 0 {
            within(t, &self.received, ctx.write_multiple_coils(0, &coil_bits)).await?;
        }
        if holding > 0 {
            within(t, &self.received, ctx.write_multiple_registers(0, &words)).await?;
        }
        Ok(())
    }

    /// The input values from the discrete inputs (by address) and the input registers.
    fn decode_inputs(&self, in_values: &mut [Value], bit: impl Fn(usize) -> bool, regs: &[u16]) -> Result<(), Failure> {
        for (slot, value) in self.inputs.iter().zip(in_values.iter_mut()) {
            let a = usize::from(slot.address);
            *value = match slot.table {
                Table::DiscreteInput => Value::Bool(bit(a)),
                _ => match regs.get(a..a + usize::from(slot.count)) {
                    Some(words) => decode(slot.ty, words),
                    // Lengths were checked on receipt; a register map that does not cover its
                    // own slots is a broken invariant, reported as a corrupt exchange anyway.
                    None => return Err(Failure::Corrupt),
                },
            };
        }
        Ok(())
    }

    /// The coils and holding registers that carry the output values.
    fn output_tables(&self, out_values: &[Value]) -> (Vec<bool>, Vec<u16>) {
        let [coils, _, _, holding] = self.sizes;
        let mut coil_bits = vec![false; usize::from(coils)];
        let mut words = vec![0u16; usize::from(holding)];
        for (slot, value) in self.outputs.iter().zip(out_values) {
            let a = usize::from(slot.address);
            match slot.table {
                Table::Coil => coil_bits[a] = *value == Value::Bool(true),
                _ => encode(*value, &mut words[a..a + usize::from(slot.count)]),
            }
        }
        (coil_bits, words)
    }
}

/// What a read request returned, its length checked.
enum Read {
    /// Bits of a read-bits response (exactly the quantity asked for).
    Bits(Vec<bool>),
    /// Words of a read-registers or read/write-registers response (exactly the quantity asked for).
    Words(Vec<u16>),
}

impl Read {
    fn bits(self) -> Result<Vec<bool>, Failure> {
        match self {
            Read::Bits(b) => Ok(b),
            Read::Words(_) => Err(Failure::Corrupt),
        }
    }

    fn words(self) -> Result<Vec<u16>, Failure> {
        match self {
            Read::Words(w) => Ok(w),
            Read::Bits(_) => Err(Failure::Corrupt),
        }
    }
}

/// Sends a read `request` for `quantity` bits or words and checks that the response carries
/// exactly that many: a response of the wrong length is a corrupt exchange, never "the rest are
/// false" (tokio-modbus's typed readers only `debug_assert` the length, which would panic a
/// debug build and pass a short response in a release build).
async fn read_exactly(
    t: Duration,
    received: &AtomicU64,
    ctx: &mut client::Context,
    request: Request<'_>,
    quantity: u16,
) -> Result<Read, Failure> {
    let n = usize::from(quantity);
    match within(t, received, ctx.call(request)).await? {
        // Bits come packed: the response's byte count times 8, padding included.
        Response::ReadCoils(mut bits) | Response::ReadDiscreteInputs(mut bits) if bits.len() == n.div_ceil(8) * 8 => {
            bits.truncate(n);
            Ok(Read::Bits(bits))
        }
        Response::ReadInputRegisters(words)
        | Response::ReadHoldingRegisters(words)
        | Response::ReadWriteMultipleRegisters(words)
            if words.len() == n =>
        {
            Ok(Read::Words(words))
        }
        _ => Err(Failure::Corrupt),
    }
}

/// A request under a timeout, its outcome sorted into what the loop counts; `received` counts
/// the bytes received on the link.
async fn within<T, E>(
    t: Duration,
    received: &AtomicU64,
    f: impl std::future::Future<Output = Result<Result<T, E>, tokio_modbus::Error>>,
) -> Result<T, Failure> {
    let before = received.load(Ordering::Relaxed);
    match tokio::time::timeout(t, f).await {
        // The RTU decoder drops bytes with a bad CRC and waits on: bytes but no frame.
        Err(_) if received.load(Ordering::Relaxed) != before => Err(Failure::Corrupt),
        Err(_) => Err(Failure::Timeout),
        Ok(Err(tokio_modbus::Error::Transport(e))) if e.kind() == std::io::ErrorKind::InvalidData => {
            Err(Failure::Corrupt)
        }
        Ok(Err(_)) => Err(Failure::Disconnected),
        Ok(Ok(Err(_))) => Err(Failure::Exception),
        Ok(Ok(Ok(v))) => Ok(v),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_load_of_the_trijoint_station() {
        // 18 coils, 18 discrete inputs, 2 input registers, 3 holding registers.
        let sizes = [18, 18, 2, 3];
        assert_eq!(
            WireLoad::of(ExchangeMode::Tables, sizes),
            WireLoad {
                transactions: 4,
                bytes: 76
            }
        );
        assert_eq!(
            WireLoad::of(ExchangeMode::Image, sizes),
            WireLoad {
                transactions: 1,
                bytes: 36
            }
        );
        assert_eq!(WireLoad::of(ExchangeMode::Tables, [0, 0, 2, 0]).transactions, 1);
    }
}
