//! The Modbus bus driver (TCP, or RTU over a serial line): a station behind the register map of
//! the I/O map.
//!
//! An exchange loop on its own thread reads the discrete inputs and input registers and writes the
//! coils and holding registers, every request with a timeout. Complete input sets reach the cycle
//! through a wait-free mailbox, the cycle's outputs reach the loop the same way, so a cycle never
//! waits on the wire. Failed exchanges (timeouts, exceptions, a lost connection) are counted; more
//! consecutive failures than the bound is a bus fault, which the runtime publishes as `bus_fault`.
//! The loop reconnects with backoff; the fault clears when exchanges succeed again (the
//! application keeps its ERROR until it is acknowledged).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use tokio_modbus::Slave;
use tokio_modbus::client::{self, Reader as _, Writer as _, rtu, tcp};
use tokio_serial::SerialStream;

use super::catalogue::Direction;
use super::map::IoMap;
use super::registers::{RegisterMap, Table, decode, encode};
use crate::bus::{Bus, MailboxReader, MailboxWriter, image_mailbox};
use crate::image::{Value, VarIndex, VarTable};

/// Settings of the exchange loop.
#[derive(Clone, Copy, Debug)]
pub struct ModbusOptions {
    /// Time between exchanges.
    pub period: Duration,
    /// Timeout of each request (and of connecting).
    pub timeout: Duration,
    /// More consecutive failed exchanges than this is a bus fault.
    pub max_failures: u32,
}

impl Default for ModbusOptions {
    fn default() -> Self {
        ModbusOptions {
            period: Duration::from_millis(5),
            timeout: Duration::from_millis(100),
            max_failures: 3,
        }
    }
}

/// Counters of the exchange loop.
#[derive(Debug, Default)]
pub struct LinkStats {
    /// Successful exchanges.
    pub exchanges: AtomicU64,
    /// Requests that timed out.
    pub timeouts: AtomicU64,
    /// Exception responses.
    pub exceptions: AtomicU64,
    /// Lost or refused connections.
    pub disconnects: AtomicU64,
    /// Summed duration of the successful exchanges (ns).
    pub exchange_ns_total: AtomicU64,
    /// Longest successful exchange (ns).
    pub exchange_ns_max: AtomicU64,
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

    async fn connect(&mut self) -> std::io::Result<client::Context> {
        match self {
            Transport::Tcp(a) => tcp::connect(*a).await,
            Transport::Serial { path, baud } => {
                let stream = SerialStream::open(&tokio_serial::new(path.as_str(), *baud))?;
                Ok(rtu::attach_slave(stream, Slave(1)))
            }
            Transport::Port(p) => {
                let port = p
                    .take()
                    .ok_or_else(|| std::io::Error::other("the serial port was lost and cannot be reopened"))?;
                // Registered with the reactor here, in the exchange loop's runtime.
                let stream = SerialStream::try_from(port).map_err(std::io::Error::other)?;
                Ok(rtu::attach_slave(stream, Slave(1)))
            }
        }
    }
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
    stats: Arc<LinkStats>,
    thread: Option<JoinHandle<()>>,
}

impl ModbusBus {
    /// A bus to the station reached by `transport`, serving `map`'s modules. The exchange loop
    /// starts when the variables are declared (the bus then knows which variable each channel is).
    pub fn new(map: IoMap, transport: Transport, options: ModbusOptions) -> Self {
        ModbusBus {
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
            stats: Arc::new(LinkStats::default()),
            thread: None,
        }
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
            stats: Arc::clone(&self.stats),
        };
        self.thread = std::thread::Builder::new()
            .name("modbus".into())
            .spawn(move || link.run(in_writer, out_reader))
            .ok();
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
            "modbus {}: {n} exchanges (read inputs, write outputs), mean {:.0} µs, max {:.0} µs; {} timeouts, {} exceptions, {} disconnects",
            self.name,
            s.exchange_ns_total.load(Ordering::Relaxed) as f64 / n.max(1) as f64 / 1e3,
            s.exchange_ns_max.load(Ordering::Relaxed) as f64 / 1e3,
            s.timeouts.load(Ordering::Relaxed),
            s.exceptions.load(Ordering::Relaxed),
            s.disconnects.load(Ordering::Relaxed)
        );
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn fault(&self) -> bool {
        self.fault.load(Ordering::Relaxed)
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
    stats: Arc<LinkStats>,
}

/// Why one exchange failed.
enum Failure {
    Timeout,
    Exception,
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
            let connected = tokio::time::timeout(self.options.timeout, self.transport.connect()).await;
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
                        let ns = started.elapsed().as_nanos() as u64;
                        self.stats.exchange_ns_total.fetch_add(ns, Ordering::Relaxed);
                        self.stats.exchange_ns_max.fetch_max(ns, Ordering::Relaxed);
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
                            Failure::Exception => self.stats.exceptions.fetch_add(1, Ordering::Relaxed),
                            Failure::Disconnected => self.stats.disconnects.fetch_add(1, Ordering::Relaxed),
                        };
                        self.failed(&mut failures);
                        if matches!(f, Failure::Disconnected | Failure::Timeout) {
                            break; // reconnect
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

    /// One exchange: read every input table, write every output table.
    async fn exchange(
        &self,
        ctx: &mut client::Context,
        in_values: &mut [Value],
        out_values: &[Value],
    ) -> Result<(), Failure> {
        let t = self.options.timeout;
        async fn within<T, E>(
            t: Duration,
            f: impl std::future::Future<Output = Result<Result<T, E>, tokio_modbus::Error>>,
        ) -> Result<T, Failure> {
            match tokio::time::timeout(t, f).await {
                Err(_) => Err(Failure::Timeout),
                Ok(Err(_)) => Err(Failure::Disconnected),
                Ok(Ok(Err(_))) => Err(Failure::Exception),
                Ok(Ok(Ok(v))) => Ok(v),
            }
        }
        let [coils, discrete, input_regs, holding] = self.sizes;
        let bits = if discrete > 0 {
            within(t, ctx.read_discrete_inputs(0, discrete)).await?
        } else {
            Vec::new()
        };
        let regs = if input_regs > 0 {
            within(t, ctx.read_input_registers(0, input_regs)).await?
        } else {
            Vec::new()
        };
        for (slot, value) in self.inputs.iter().zip(in_values.iter_mut()) {
            let a = usize::from(slot.address);
            *value = match slot.table {
                Table::DiscreteInput => Value::Bool(bits.get(a).copied().unwrap_or(false)),
                _ => match regs.get(a..a + usize::from(slot.count)) {
                    Some(words) => decode(slot.ty, words),
                    None => return Err(Failure::Exception),
                },
            };
        }
        let mut coil_bits = vec![false; usize::from(coils)];
        let mut words = vec![0u16; usize::from(holding)];
        for (slot, value) in self.outputs.iter().zip(out_values) {
            let a = usize::from(slot.address);
            match slot.table {
                Table::Coil => coil_bits[a] = *value == Value::Bool(true),
                _ => encode(*value, &mut words[a..a + usize::from(slot.count)]),
            }
        }
        if coils > 0 {
            within(t, ctx.write_multiple_coils(0, &coil_bits)).await?;
        }
        if holding > 0 {
            within(t, ctx.write_multiple_registers(0, &words)).await?;
        }
        Ok(())
    }
}
