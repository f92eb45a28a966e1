//! The I/O simulator (`pkm-plc io-sim`): the modules of the I/O map served as a Modbus TCP or RTU slave
//! through the register map, backed by the same plant as the simulated bus. The plant runs in
//! real time: every request first advances it to the time since the server started.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use tokio::net::TcpListener;
use tokio_modbus::server::tcp::{Server, accept_tcp_connection};
use tokio_modbus::{ExceptionCode, Request, Response};

use super::bus::SimBus;
use crate::image::Value;
use crate::io::registers::{Entry, RegisterMap, Table, decode, encode};

/// The station: the simulated machine behind its register map.
pub struct Station {
    bus: SimBus,
    registers: RegisterMap,
    /// Per table, per address: (entry index, word within the entry).
    lookup: [Vec<(usize, u16)>; 4],
    /// The last words written to each holding register (a two-register value is decoded once
    /// both words have been written, in one request or two).
    holding: Vec<u16>,
    started: Instant,
}

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
        Station {
            bus,
            registers,
            lookup,
            holding,
            started: Instant::now(),
        }
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

    /// Serves one request.
    pub fn handle(&mut self, request: Request<'_>) -> Result<Response, ExceptionCode> {
        self.bus.refresh(self.started.elapsed().as_nanos() as u64);
        Ok(match request {
            Request::ReadCoils(a, n) => Response::ReadCoils(self.bits(Table::Coil, a, n)?),
            Request::ReadDiscreteInputs(a, n) => Response::ReadDiscreteInputs(self.bits(Table::DiscreteInput, a, n)?),
            Request::ReadInputRegisters(a, n) => {
                Response::ReadInputRegisters(self.words(Table::InputRegister, a, n)?)
            }
            Request::ReadHoldingRegisters(a, n) => {
                Response::ReadHoldingRegisters(self.words(Table::HoldingRegister, a, n)?)
            }
            Request::WriteSingleCoil(a, v) => {
                self.write_coils(a, &[v])?;
                Response::WriteSingleCoil(a, v)
            }
            Request::WriteMultipleCoils(a, v) => {
                self.write_coils(a, &v)?;
                Response::WriteMultipleCoils(a, v.len() as u16)
            }
            Request::WriteSingleRegister(a, v) => {
                self.write_registers(a, &[v])?;
                Response::WriteSingleRegister(a, v)
            }
            Request::WriteMultipleRegisters(a, v) => {
                self.write_registers(a, &v)?;
                Response::WriteMultipleRegisters(a, v.len() as u16)
            }
            _ => return Err(ExceptionCode::IllegalFunction),
        })
    }
}

/// One connection's view of the shared station.
#[derive(Clone)]
struct Service(Arc<Mutex<Station>>);

impl tokio_modbus::server::Service for Service {
    type Request = Request<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, request: Self::Request) -> Self::Future {
        let result = match self.0.lock() {
            Ok(mut station) => station.handle(request),
            Err(_) => Err(ExceptionCode::ServerDeviceFailure),
        };
        std::future::ready(result)
    }
}

/// Serves `station` as Modbus RTU (any unit) on a serial stream until the future is dropped.
pub async fn serve_rtu(serial: tokio_serial::SerialStream, station: Station) -> std::io::Result<()> {
    let service = Service(Arc::new(Mutex::new(station)));
    tokio_modbus::server::rtu::Server::new(serial)
        .serve_forever(service)
        .await
}

/// Serves `station` on `listener` until the future is dropped.
pub async fn serve(listener: TcpListener, station: Station) -> std::io::Result<()> {
    let service = Service(Arc::new(Mutex::new(station)));
    let server = Server::new(listener);
    let new_service = move |_peer: SocketAddr| Ok(Some(service.clone()));
    let on_connected = move |stream, peer| {
        let new_service = new_service.clone();
        async move { accept_tcp_connection(stream, peer, new_service) }
    };
    let on_process_error = |e| tracing::warn!("io-sim: connection error: {e}");
    server.serve(&on_connected, on_process_error).await
}
