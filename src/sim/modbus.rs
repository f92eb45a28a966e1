//! The I/O simulator (`pkm-plc io-sim`): the modules of the I/O map served as a Modbus TCP or RTU slave
//! through the register map, backed by the same plant as the simulated bus. The plant runs in
//! real time: every request first advances it to the time since the server started.
//!
//! Besides the four standard tables the station serves the packed process image
//! ([`ImageLayout`]): the input image from holding register [`INPUT_IMAGE`] (read-only), the
//! output image from [`OUTPUT_IMAGE`], and read/write-multiple-registers (function code 23) to
//! exchange both in one transaction.

use std::time::{Duration, Instant};

use tokio_modbus::{ExceptionCode, Request, Response};

use super::bus::SimBus;
use super::server::{ServerOptions, serve_rtu};
use crate::image::Value;
use crate::io::registers::{
    Entry, INPUT_IMAGE, ImageLayout, OUTPUT_IMAGE, RegisterMap, Table, decode, encode, pack_bits, packed_bit,
};

/// The station: the simulated machine behind its register map.
pub struct Station {
    bus: SimBus,
    registers: RegisterMap,
    /// Per table, per address: (entry index, word within the entry).
    lookup: [Vec<(usize, u16)>; 4],
    /// The last words written to each holding register (a two-register value is decoded once
    /// both words have been written, in one request or two).
    holding: Vec<u16>,
    /// The packed process image's layout (inputs and outputs mirrored into holding registers).
    layout: ImageLayout,
    started: Instant,
    /// The output watchdog's time, if it is on.
    watchdog: Option<Duration>,
    /// When the last write request arrived (the watchdog is armed by the first).
    last_write: Option<Instant>,
    /// Whether the watchdog has put the outputs to their safe values since the last write.
    tripped: bool,
    /// The client that owns the outputs: the one whose write took them last. Only its writes
    /// are carried out and feed the watchdog.
    owner: Option<ClientId>,
}

/// A client of the station: a TCP connection's number, or [`SERIAL_LINE`].
pub type ClientId = u64;

/// The one client of a serial line (its master).
pub const SERIAL_LINE: ClientId = 0;

impl Station {
    /// A station serving `bus`'s I/O map.
    pub fn new(bus: SimBus) -> Station {
        let registers = RegisterMap::of(bus.io_map());
        let mut lookup: [Vec<(usize, u16)>; 4] = Default::default();
        for (i, e) in registers.entries.iter().enumerate() {
            let table = &mut lookup[e.table as usize];
            for w in 0..e.count {
                let address = usize::from(e.address + w);
                if table.len() <= address {
                    table.resize(address + 1, (usize::MAX, 0));
                }
                table[address] = (i, w);
            }
        }
        let holding = vec![0; lookup[Table::HoldingRegister as usize].len()];
        let layout = ImageLayout::of(registers.sizes());
        Station {
            bus,
            registers,
            lookup,
            holding,
            layout,
            started: Instant::now(),
            watchdog: None,
            last_write: None,
            tripped: false,
            owner: None,
        }
    }

    /// Turns the output watchdog on (`Some`) or off: see [`Station::watch`].
    pub fn set_watchdog(&mut self, watchdog: Option<Duration>) {
        self.watchdog = watchdog;
    }

    /// The output watchdog of a real bus coupler: when the client that owns the outputs has sent
    /// no write request for longer than the watchdog time, every output goes to its safe value
    /// (coils off, registers zero: PWM 0, bridges and steppers off) and the outputs are free.
    /// Called periodically. The next write request takes them over again.
    pub fn watch(&mut self) {
        let (Some(limit), Some(last)) = (self.watchdog, self.last_write) else {
            return;
        };
        if self.tripped || last.elapsed() <= limit {
            return;
        }
        self.bus.refresh(self.started.elapsed().as_nanos() as u64);
        self.safe_outputs();
        self.tripped = true;
        self.owner = None;
        tracing::warn!(
            "io-sim: output watchdog: no write for {} ms (limit {} ms); outputs set to their safe values",
            last.elapsed().as_millis(),
            limit.as_millis()
        );
    }

    /// Every output channel to zero, and the holding registers with them.
    fn safe_outputs(&mut self) {
        for e in &self.registers.entries {
            if matches!(e.table, Table::Coil | Table::HoldingRegister) {
                self.bus.set_output(e.module, e.channel, Value::zero(e.ty));
            }
        }
        self.holding.fill(0);
    }

    /// Takes a write request of `client` for the watchdog: the owner's (or, with the outputs
    /// free, the one that takes them) feeds it; another client's is refused (false).
    fn written(&mut self, client: ClientId) -> bool {
        match self.owner {
            Some(owner) if owner != client => return false,
            Some(_) => {}
            None => {
                if self.tripped {
                    tracing::info!("io-sim: outputs written again after the watchdog acted");
                }
                self.owner = Some(client);
            }
        }
        self.last_write = Some(Instant::now());
        self.tripped = false;
        true
    }

    /// Client `client` is gone (its connection closed): if it owned the outputs, they go to
    /// their safe values at once and are free — a real coupler's connection monitoring. No
    /// client that connects later inherits what a departed controller left on the drives.
    pub fn disconnected(&mut self, client: ClientId) {
        if self.owner != Some(client) {
            return;
        }
        self.bus.refresh(self.started.elapsed().as_nanos() as u64);
        self.safe_outputs();
        self.owner = None;
        self.last_write = None;
        tracing::warn!("io-sim: the client that wrote the outputs disconnected; outputs set to their safe values");
    }

    /// The client that owns the outputs, if any.
    pub fn owner(&self) -> Option<ClientId> {
        self.owner
    }

    /// The register map served.
    pub fn registers(&self) -> &RegisterMap {
        &self.registers
    }

    fn entry(&self, table: Table, address: u16) -> Result<(&Entry, u16), ExceptionCode> {
        match self.lookup[table as usize].get(usize::from(address)) {
            Some(&(i, w)) if i != usize::MAX => Ok((&self.registers.entries[i], w)),
            _ => Err(ExceptionCode::IllegalDataAddress),
        }
    }

    fn words(&self, table: Table, address: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
        (address..address.saturating_add(count))
            .map(|a| {
                let (e, w) = self.entry(table, a)?;
                let mut words = [0u16; 2];
                encode(self.bus.channel(e.module, e.channel), &mut words);
                Ok(words[usize::from(w)])
            })
            .collect()
    }

    fn bits(&self, table: Table, address: u16, count: u16) -> Result<Vec<bool>, ExceptionCode> {
        (address..address.saturating_add(count))
            .map(|a| {
                let (e, _) = self.entry(table, a)?;
                Ok(self.bus.channel(e.module, e.channel) == Value::Bool(true))
            })
            .collect()
    }

    fn write_coils(&mut self, address: u16, values: &[bool]) -> Result<(), ExceptionCode> {
        for (a, v) in (address..).zip(values) {
            let (e, _) = self.entry(Table::Coil, a)?;
            let (m, c) = (e.module, e.channel);
            self.bus.set_output(m, c, Value::Bool(*v));
        }
        Ok(())
    }

    fn write_registers(&mut self, address: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        let mut touched = Vec::new();
        for (a, v) in (address..).zip(values) {
            let (e, _) = self.entry(Table::HoldingRegister, a)?;
            let key = (e.module, e.channel);
            self.holding[usize::from(a)] = *v;
            if !touched.contains(&key) {
                touched.push(key);
            }
        }
        for (m, c) in touched {
            let Some(e) = self.registers.entries.iter().find(|e| e.module == m && e.channel == c) else {
                continue;
            };
            let start = usize::from(e.address);
            let value = decode(e.ty, &self.holding[start..start + usize::from(e.count)]);
            self.bus.set_output(m, c, value);
        }
        Ok(())
    }

    /// The packed input image: discrete inputs 16 to a register, then the input registers.
    fn input_image(&self) -> Result<Vec<u16>, ExceptionCode> {
        let [_, discrete, input, _] = self.registers.sizes();
        let mut image = vec![0u16; usize::from(self.layout.input_bits)];
        pack_bits(&self.bits(Table::DiscreteInput, 0, discrete)?, &mut image);
        image.extend(self.words(Table::InputRegister, 0, input)?);
        Ok(image)
    }

    /// The packed output image as last written: coils 16 to a register, then the holding registers.
    fn output_image(&self) -> Result<Vec<u16>, ExceptionCode> {
        let [coils, ..] = self.registers.sizes();
        let mut image = vec![0u16; usize::from(self.layout.output_bits)];
        pack_bits(&self.bits(Table::Coil, 0, coils)?, &mut image);
        image.extend(&self.holding);
        Ok(image)
    }

    /// Reads holding registers: the holding register table, or a part of either image block.
    fn read_holding(&self, address: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
        let part = |base: u16, image: fn(&Self) -> Result<Vec<u16>, ExceptionCode>| {
            let start = usize::from(address - base);
            let image = image(self)?;
            image
                .get(start..start + usize::from(count))
                .map(<[u16]>::to_vec)
                .ok_or(ExceptionCode::IllegalDataAddress)
        };
        match address {
            OUTPUT_IMAGE.. => part(OUTPUT_IMAGE, Self::output_image),
            INPUT_IMAGE.. => part(INPUT_IMAGE, Self::input_image),
            _ => self.words(Table::HoldingRegister, address, count),
        }
    }

    /// Writes holding registers: the holding register table, or a part of the output image.
    fn write_holding(&mut self, address: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        if address < INPUT_IMAGE {
            return self.write_registers(address, values);
        }
        let start = usize::from(
            address
                .checked_sub(OUTPUT_IMAGE)
                .ok_or(ExceptionCode::IllegalDataAddress)?,
        );
        if start + values.len() > usize::from(self.layout.output_len) {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        let bit_words = usize::from(self.layout.output_bits);
        let [coils, ..] = self.registers.sizes();
        // The packed coils this write covers, then its register part in one piece, so that a
        // two-register value is decoded from both of its new words.
        let covered = start..(start + values.len()).min(bit_words);
        if !covered.is_empty() {
            let first = covered.start * 16;
            let last = (covered.end * 16).min(usize::from(coils));
            let bits: Vec<bool> = (first..last).map(|i| packed_bit(values, i - start * 16)).collect();
            self.write_coils(first as u16, &bits)?;
        }
        let registers_from = bit_words.max(start);
        if registers_from < start + values.len() {
            self.write_registers((registers_from - bit_words) as u16, &values[registers_from - start..])?;
        }
        Ok(())
    }

    /// Serves one request of `client`. A write from a client other than the one that owns the
    /// outputs is refused with exception 6 (server device busy): one controller drives a
    /// station at a time.
    pub fn handle(&mut self, request: Request<'_>, client: ClientId) -> Result<Response, ExceptionCode> {
        self.bus.refresh(self.started.elapsed().as_nanos() as u64);
        if matches!(
            request,
            Request::WriteSingleCoil(..)
                | Request::WriteMultipleCoils(..)
                | Request::WriteSingleRegister(..)
                | Request::WriteMultipleRegisters(..)
                | Request::ReadWriteMultipleRegisters(..)
        ) && !self.written(client)
        {
            return Err(ExceptionCode::ServerDeviceBusy);
        }
        Ok(match request {
            Request::ReadCoils(a, n) => Response::ReadCoils(self.bits(Table::Coil, a, n)?),
            Request::ReadDiscreteInputs(a, n) => Response::ReadDiscreteInputs(self.bits(Table::DiscreteInput, a, n)?),
            Request::ReadInputRegisters(a, n) => {
                Response::ReadInputRegisters(self.words(Table::InputRegister, a, n)?)
            }
            Request::ReadHoldingRegisters(a, n) => Response::ReadHoldingRegisters(self.read_holding(a, n)?),
            Request::WriteSingleCoil(a, v) => {
                self.write_coils(a, &[v])?;
                Response::WriteSingleCoil(a, v)
            }
            Request::WriteMultipleCoils(a, v) => {
                self.write_coils(a, &v)?;
                Response::WriteMultipleCoils(a, v.len() as u16)
            }
            Request::WriteSingleRegister(a, v) => {
                self.write_holding(a, &[v])?;
                Response::WriteSingleRegister(a, v)
            }
            Request::WriteMultipleRegisters(a, v) => {
                self.write_holding(a, &v)?;
                Response::WriteMultipleRegisters(a, v.len() as u16)
            }
            // Write first, then read, as the Modbus specification orders it.
            Request::ReadWriteMultipleRegisters(read, n, write, v) => {
                self.write_holding(write, &v)?;
                Response::ReadWriteMultipleRegisters(self.read_holding(read, n)?)
            }
            _ => return Err(ExceptionCode::IllegalFunction),
        })
    }
}

/// A station served as Modbus RTU at the far end of an emulated serial line
/// ([`crate::io::line`]), on its own thread: what `link-bench` and the RTU end-to-end test talk
/// to. Dropping it stops the line and the station.
pub struct StationOnLine {
    line: Option<crate::io::line::PacedLine>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl StationOnLine {
    /// Serves `station` behind a line with `timing` and the server's `options`; returns it with
    /// the driver's end of the line (to be handed to `Transport::Port`).
    pub fn start(
        station: Station,
        timing: crate::io::line::LineTiming,
        options: ServerOptions,
    ) -> std::io::Result<(StationOnLine, serialport::TTYPort)> {
        let (station_end, line_a) = crate::io::line::pty_pair()?;
        let (line_b, driver_end) = crate::io::line::pty_pair()?;
        // Built here, so that a failure is an error of the caller's rather than a silent thread.
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("station-on-line".into())
            .spawn(move || {
                crate::io::line::hardware_priority();
                runtime.block_on(async move {
                    // Registered with the reactor here, in the station's runtime.
                    let Ok(stream) = tokio_serial::SerialStream::try_from(station_end) else {
                        tracing::error!("station on line: cannot use the pseudo-terminal");
                        return;
                    };
                    tokio::select! {
                        _ = serve_rtu(stream, station, options) => {}
                        _ = stopped => {}
                    }
                });
            })?;
        let line = crate::io::line::PacedLine::start(line_a, line_b, timing)?;
        let served = StationOnLine {
            line: Some(line),
            stop: Some(stop),
            thread: Some(thread),
        };
        Ok((served, driver_end))
    }
}

impl Drop for StationOnLine {
    fn drop(&mut self) {
        drop(self.line.take());
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
