//! The I/O simulator (`pkm-plc io-sim`): the modules of the I/O map served as a Modbus TCP or RTU slave
//! through the register map, backed by the same plant as the simulated bus. The plant runs in
//! real time: every request first advances it to the time since the server started.
//!
//! A generic station (the project's own layout) serves, besides the four standard tables, the
//! packed process image ([`ImageLayout`]): the input image from holding register
//! [`INPUT_IMAGE`] (read-only), the output image from [`OUTPUT_IMAGE`], and
//! read/write-multiple-registers (function code 23) to exchange both in one transaction.
//!
//! An X20BC0087 station ([`Station::bus_controller`]) lays the data out as that bus controller
//! does and answers its registers around it ([`BusControllerSim`]): module table, watchdog,
//! error bits. Within a process image a bit or word no module uses reads as 0, as the bus
//! controller's does; beyond the image is an illegal address.

use std::time::{Duration, Instant};

use tokio_modbus::{ExceptionCode, Request, Response};

use super::bus::SimBus;
use super::bus_controller::BusControllerSim;
use crate::image::Value;
use crate::services::io::map::StationKind;
use crate::services::io::registers::{
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
    /// An X20BC0087's own registers and watchdog (`None`: a generic station).
    bc: Option<BusControllerSim>,
    /// Per table, the size of the process image (bits or registers): on an X20BC0087 an
    /// address below it that no module uses reads as 0.
    image_size: [u16; 4],
}

/// What the simulated machine truly did while the station served it: what `io-sim --summary`
/// writes when it stops, and what tests hold the PLC's view against.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StationReport {
    /// Seconds since the station started.
    pub t_s: f64,
    /// Each joint, in the PLC's joint order.
    pub joints: Vec<pkm_api::machine::JointTruth>,
    /// Time steps in which the mechanism jammed.
    pub jams: u64,
}

impl StationReport {
    /// One line per joint for the log: where it stands and, for a stepper, the steps it lost.
    pub fn lines(&self) -> Vec<String> {
        self.joints
            .iter()
            .enumerate()
            .map(|(j, truth)| {
                let lost = if truth.stepper {
                    format!(", {} steps lost in {} stalls", truth.lost_steps, truth.stalls)
                } else {
                    String::new()
                };
                format!("joint {} at {:.4} mm{lost}", j + 1, truth.position_mm)
            })
            .collect()
    }
}

/// A client of the station: a TCP connection's number, or [`SERIAL_LINE`].
pub type ClientId = u64;

/// The one client of a serial line (its master).
pub const SERIAL_LINE: ClientId = 0;

impl Station {
    /// A generic station serving `bus`'s I/O map (whatever station the map names: this is the
    /// one a serial line has).
    pub fn new(bus: SimBus) -> Station {
        Station::laid_out(bus, StationKind::Generic, 0)
    }

    /// The station the map names, as served over TCP: an X20BC0087 at node `node`, or a
    /// generic one.
    pub fn of_map(bus: SimBus, node: u16) -> Station {
        let station = bus.io_map().station;
        Station::laid_out(bus, station, node)
    }

    /// An X20BC0087 station serving `bus`'s I/O map, at node `node`.
    pub fn bus_controller(bus: SimBus, node: u16) -> Station {
        Station::laid_out(bus, StationKind::X20bc0087, node)
    }

    fn laid_out(bus: SimBus, station: StationKind, node: u16) -> Station {
        let registers = RegisterMap::laid_out(bus.io_map(), station);
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
        let bc = (station == StationKind::X20bc0087).then(|| {
            let expected = crate::services::io::x20bc0087::expected_modules(bus.io_map(), &registers);
            BusControllerSim::new(&expected, node)
        });
        let image_size = match &bc {
            // Coils, discrete inputs, input registers, holding registers.
            Some(bc) => {
                let [analog_in, analog_out, digital_in, digital_out] = bc.image_bytes();
                [digital_out * 8, digital_in * 8, analog_in / 2, analog_out / 2]
            }
            None => registers.sizes(),
        };
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
            bc,
            image_size,
        }
    }

    /// Whether this is an X20BC0087 station.
    pub fn is_bus_controller(&self) -> bool {
        self.bc.is_some()
    }

    /// The address the station is served on (an X20BC0087 reports it in its network registers).
    pub fn set_address(&mut self, address: std::net::SocketAddr) {
        if let Some(bc) = &mut self.bc {
            bc.set_address(address);
        }
    }

    /// Turns the output watchdog on (`Some`) or off: see [`Station::watch`]. On an X20BC0087
    /// this is its stored setting (mode 0xC1, any telegram resets it), which clients change.
    pub fn set_watchdog(&mut self, watchdog: Option<Duration>) {
        self.watchdog = watchdog;
        if let Some(bc) = &mut self.bc {
            bc.store_watchdog(watchdog);
        }
    }

    /// A client connected.
    pub fn connected(&mut self, _client: ClientId) {
        if let Some(bc) = &mut self.bc {
            bc.client(true);
        }
    }

    /// The output watchdog of a real bus coupler: when the client that owns the outputs has sent
    /// no write request for longer than the watchdog time, every output goes to its safe value
    /// (coils off, registers zero: PWM 0, bridges and steppers off) and the outputs are free.
    /// Called periodically. The next write request takes them over again.
    pub fn watch(&mut self) {
        if let Some(bc) = &mut self.bc {
            if bc.watch() {
                self.bus.refresh(self.started.elapsed().as_nanos() as u64);
                self.safe_outputs();
                self.owner = None;
                tracing::warn!(
                    "io-sim: X20BC0087 watchdog expired: outputs set to zero and held until a client resets the watchdog \
                     (register 0x1044 = 0xC1)"
                );
            }
            return;
        }
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
                tracing::info!("io-sim: client {client} writes: it owns the outputs");
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
        if let Some(bc) = &mut self.bc {
            bc.client(false);
        }
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

    /// The machine as it truly is now (the plant advanced to the present): its joints'
    /// positions and the steps its steppers lost, for the report a station gives when it stops.
    pub fn report(&mut self) -> StationReport {
        let t_ns = self.started.elapsed().as_nanos() as u64;
        self.bus.refresh(t_ns);
        let plant = self.bus.plant();
        StationReport {
            t_s: t_ns as f64 * 1e-9,
            joints: plant.joints(),
            jams: plant.jams(),
        }
    }

    /// The channel at `address` of `table` and the word of it there; `None` for an address
    /// within an X20BC0087's process image that no module uses (it reads as 0).
    fn entry(&self, table: Table, address: u16) -> Result<Option<(&Entry, u16)>, ExceptionCode> {
        match self.lookup[table as usize].get(usize::from(address)) {
            Some(&(i, w)) if i != usize::MAX => Ok(Some((&self.registers.entries[i], w))),
            _ if self.bc.is_some() && address < self.image_size[table as usize] => Ok(None),
            _ => Err(ExceptionCode::IllegalDataAddress),
        }
    }

    fn words(&self, table: Table, address: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
        (address..address.saturating_add(count))
            .map(|a| {
                let Some((e, w)) = self.entry(table, a)? else {
                    return Ok(0);
                };
                let mut words = [0u16; 2];
                encode(self.bus.channel(e.module, e.channel), &mut words);
                Ok(words[usize::from(w)])
            })
            .collect()
    }

    fn bits(&self, table: Table, address: u16, count: u16) -> Result<Vec<bool>, ExceptionCode> {
        (address..address.saturating_add(count))
            .map(|a| {
                let Some((e, _)) = self.entry(table, a)? else {
                    return Ok(false);
                };
                Ok(self.bus.channel(e.module, e.channel) == Value::Bool(true))
            })
            .collect()
    }

    /// Whether process-data writes are ignored now: an X20BC0087 whose watchdog expired holds
    /// its outputs at zero until a client resets it.
    fn outputs_held(&self) -> bool {
        self.bc.as_ref().is_some_and(BusControllerSim::expired)
    }

    fn write_coils(&mut self, address: u16, values: &[bool]) -> Result<(), ExceptionCode> {
        // Every address is checked before anything is written.
        for a in address..address.saturating_add(values.len() as u16) {
            self.entry(Table::Coil, a)?;
        }
        if self.outputs_held() {
            return Ok(());
        }
        for (a, v) in (address..).zip(values) {
            let Some((e, _)) = self.entry(Table::Coil, a)? else {
                continue;
            };
            let (m, c) = (e.module, e.channel);
            self.bus.set_output(m, c, Value::Bool(*v));
        }
        Ok(())
    }

    fn write_registers(&mut self, address: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        for a in address..address.saturating_add(values.len() as u16) {
            self.entry(Table::HoldingRegister, a)?;
        }
        if self.outputs_held() {
            return Ok(());
        }
        let mut touched = Vec::new();
        for (a, v) in (address..).zip(values) {
            let Some((e, _)) = self.entry(Table::HoldingRegister, a)? else {
                continue;
            };
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

    /// Reads holding registers: the holding register table, or a part of either image block;
    /// on an X20BC0087 its own registers, or the outputs from 0x0800.
    fn read_holding(&self, address: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
        if let Some(bc) = &self.bc {
            if let Some(read) = bc.read(address, count) {
                return read;
            }
            let base = self.registers.holding_base;
            let relative = address.checked_sub(base).ok_or(ExceptionCode::IllegalDataAddress)?;
            return self.words(Table::HoldingRegister, relative, count);
        }
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

    /// Writes holding registers: the holding register table, or a part of the output image; on
    /// an X20BC0087 its own registers, or the outputs from 0x0800.
    fn write_holding(&mut self, address: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        if let Some(bc) = &mut self.bc {
            if let Some(written) = bc.write(address, values) {
                return written;
            }
            let base = self.registers.holding_base;
            let relative = address.checked_sub(base).ok_or(ExceptionCode::IllegalDataAddress)?;
            return self.write_registers(relative, values);
        }
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
        let write = matches!(
            request,
            Request::WriteSingleCoil(..)
                | Request::WriteMultipleCoils(..)
                | Request::WriteSingleRegister(..)
                | Request::WriteMultipleRegisters(..)
                | Request::ReadWriteMultipleRegisters(..)
        );
        // The X20BC0087 has no packed image to exchange in one transaction.
        if self.bc.is_some() && matches!(request, Request::ReadWriteMultipleRegisters(..)) {
            return Err(ExceptionCode::IllegalFunction);
        }
        let refused = write && !self.written(client);
        if let Some(bc) = &mut self.bc {
            // Every telegram counts; only the controlling client's feeds the watchdog (or any
            // client's while no one controls the outputs): a write refused with exception 6 was
            // not carried out, and another client — a monitor that polls, a second controller
            // held off — must not keep the outputs alive after the controller is gone.
            bc.telegram(write, !refused && self.owner.is_none_or(|owner| owner == client));
        }
        if refused {
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
