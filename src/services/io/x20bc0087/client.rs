//! The bus controller's registers over a Modbus TCP connection: its module table, its watchdog,
//! its error bits and what `station scan` shows. Each request has a timeout; what fails says
//! which request it was.

use std::time::Duration;

use tokio_modbus::client::Client;
use tokio_modbus::{Request, Response};

use super::{
    CLIENTS, ERRORS, ErrorBits, GATEWAY, IP_CURRENT, IP_FLASH, MAC, MAX_MODULES, MODULE_TABLE, ModuleRecord, NODE,
    PORT, PROCESS_COUNTS, PROCESS_COUNTS_LEN, PRODUCT, PRODUCT_LEN, RECORD_LEN, STATUS, SUBNET, WATCHDOG_ELAPSED,
    WATCHDOG_MODE, WATCHDOG_RESET, WATCHDOG_RESET_VALUE, WATCHDOG_STATUS, WATCHDOG_THRESHOLD, WATCHDOG_WRITES,
    X2X_CYCLE, X2X_STATS, X2X_STATS_LEN,
};

/// The most registers one read-holding-registers request may ask for.
const MAX_READ: u16 = 125;

/// How a request failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestFailure {
    /// No response within the timeout.
    Timeout,
    /// An exception response.
    Exception,
    /// A response that could not be decoded.
    Corrupt,
    /// The connection is gone.
    Disconnected,
}

/// A failed request: which, and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{what}: {cause}")]
pub struct RequestError {
    /// How it failed.
    pub kind: RequestFailure,
    /// The request ("read holding registers 0xA000 … 0xA06F").
    pub what: String,
    /// What happened.
    pub cause: String,
}

/// The bus controller's registers over an open connection, each request under `timeout`.
pub struct Registers<'a> {
    ctx: &'a mut dyn Client,
    timeout: Duration,
}

impl<'a> Registers<'a> {
    /// Requests on `ctx`, each waited for at most `timeout`.
    pub fn new(ctx: &'a mut dyn Client, timeout: Duration) -> Self {
        Registers { ctx, timeout }
    }

    /// Reads `count` holding registers from `address` (at most 125).
    pub async fn read(&mut self, address: u16, count: u16) -> Result<Vec<u16>, RequestError> {
        let what = format!(
            "read holding registers {address:#06X} … {:#06X}",
            address + count.saturating_sub(1)
        );
        let response = call(
            self.timeout,
            &what,
            self.ctx.call(Request::ReadHoldingRegisters(address, count)),
        )
        .await?;
        match response {
            Response::ReadHoldingRegisters(words) if words.len() == usize::from(count) => Ok(words),
            Response::ReadHoldingRegisters(words) => Err(RequestError {
                kind: RequestFailure::Corrupt,
                what,
                cause: format!("{} registers in the response, not {count}", words.len()),
            }),
            other => Err(RequestError {
                kind: RequestFailure::Corrupt,
                what,
                cause: format!("another response: {other:?}"),
            }),
        }
    }

    /// Writes one holding register.
    pub async fn write(&mut self, address: u16, value: u16) -> Result<(), RequestError> {
        let what = format!("write holding register {address:#06X} = {value:#06X}");
        let response = call(
            self.timeout,
            &what,
            self.ctx.call(Request::WriteSingleRegister(address, value)),
        )
        .await?;
        match response {
            Response::WriteSingleRegister(a, v) if (a, v) == (address, value) => Ok(()),
            other => Err(RequestError {
                kind: RequestFailure::Corrupt,
                what,
                cause: format!("a response that does not echo the request: {other:?}"),
            }),
        }
    }

    /// The module table up to its first empty slot (at most [`MAX_MODULES`] modules), read
    /// seven records to a request.
    pub async fn module_table(&mut self) -> Result<Vec<ModuleRecord>, RequestError> {
        const PER_READ: u16 = MAX_READ / RECORD_LEN;
        let mut records = Vec::new();
        let mut next = 0u16;
        while next < MAX_MODULES {
            let n = PER_READ.min(MAX_MODULES - next);
            let words = self.read(MODULE_TABLE + next * RECORD_LEN, n * RECORD_LEN).await?;
            for chunk in words.chunks_exact(usize::from(RECORD_LEN)) {
                let mut w = [0u16; RECORD_LEN as usize];
                w.copy_from_slice(chunk);
                let record = ModuleRecord::from_words(&w);
                if !record.present() {
                    return Ok(records);
                }
                records.push(record);
            }
            next += n;
        }
        Ok(records)
    }

    /// Sets the watchdog as the soft-PLC runs it: `threshold_ms`, reset by writes only; then
    /// reads it back, so that a station that did not take the setting is refused rather than
    /// trusted. It does not reset it ([`Registers::reset_watchdog`]).
    pub async fn configure_watchdog(&mut self, threshold_ms: u16) -> Result<Result<(), String>, RequestError> {
        self.write(WATCHDOG_THRESHOLD, threshold_ms).await?;
        self.write(WATCHDOG_MODE, WATCHDOG_WRITES).await?;
        let back = self.read(WATCHDOG_THRESHOLD, 4).await?;
        let (threshold, mode) = (back[0], back[WATCHDOG_MODE as usize - WATCHDOG_THRESHOLD as usize]);
        if threshold != threshold_ms || mode != WATCHDOG_WRITES {
            return Ok(Err(format!(
                "the bus controller did not take the watchdog setting: threshold {threshold} ms and mode {mode:#04X} \
                 read back, {threshold_ms} ms and {WATCHDOG_WRITES:#04X} (only writes reset it) written"
            )));
        }
        Ok(Ok(()))
    }

    /// Resets the watchdog: an expired one lets its outputs be written again.
    pub async fn reset_watchdog(&mut self) -> Result<(), RequestError> {
        self.write(WATCHDOG_RESET, WATCHDOG_RESET_VALUE).await
    }

    /// The status register and the error bits.
    pub async fn errors(&mut self) -> Result<(u16, ErrorBits), RequestError> {
        let w = self.read(STATUS, ERRORS - STATUS + 1).await?;
        Ok((w[0], ErrorBits(w[1])))
    }

    /// Everything `station scan` shows.
    pub async fn identity(&mut self) -> Result<Identity, RequestError> {
        // Each field on its own or with its neighbours, never across a gap between them.
        let mac_words = self.read(MAC, 3).await?;
        let addresses = self.read(IP_FLASH, GATEWAY + 4 - IP_FLASH).await?;
        let port = self.read(PORT, 1).await?[0];
        let x2x_cycle_us = self.read(X2X_CYCLE, 1).await?[0];
        let current = self.read(IP_CURRENT, 4).await?;
        let four = |words: &[u16]| -> [u8; 4] { std::array::from_fn(|i| words[i] as u8) };
        let at = |address: u16| usize::from(address - IP_FLASH);
        let mac = std::array::from_fn(|i| {
            let w = mac_words[i / 2];
            if i % 2 == 0 { (w >> 8) as u8 } else { w as u8 }
        });
        let watchdog = self
            .read(WATCHDOG_THRESHOLD, WATCHDOG_MODE - WATCHDOG_THRESHOLD + 1)
            .await?;
        let product = self.read(PRODUCT, PRODUCT_LEN).await?;
        let counts = self.read(PROCESS_COUNTS, PROCESS_COUNTS_LEN).await?;
        let clients = self.read(CLIENTS, 1).await?[0];
        let node = self.read(NODE, 1).await?[0];
        let (status, errors) = self.errors().await?;
        let x2x = self.read(X2X_STATS, X2X_STATS_LEN).await?;
        Ok(Identity {
            mac,
            ip_flash: four(&addresses[at(IP_FLASH)..]),
            subnet: four(&addresses[at(SUBNET)..]),
            gateway: four(&addresses[at(GATEWAY)..]),
            ip_current: four(&current),
            port,
            x2x_cycle_us,
            serial: (u64::from(product[0]) << 32) | (u64::from(product[1]) << 16) | u64::from(product[2]),
            product_code: product[3],
            hw_variant: product[4],
            hw_version: product[5],
            firmware: (product[6], product[7]),
            watchdog: Watchdog {
                threshold_ms: watchdog[0],
                elapsed_ms: watchdog[usize::from(WATCHDOG_ELAPSED - WATCHDOG_THRESHOLD)],
                status: watchdog[usize::from(WATCHDOG_STATUS - WATCHDOG_THRESHOLD)],
                mode: watchdog[usize::from(WATCHDOG_MODE - WATCHDOG_THRESHOLD)],
            },
            modules: counts[0],
            process: std::array::from_fn(|i| (counts[1 + 2 * i], counts[2 + 2 * i])),
            clients,
            node,
            status,
            errors,
            x2x_cycles: (u32::from(x2x[0]) << 16) | u32::from(x2x[1]),
            x2x_errors: [x2x[2], x2x[3], x2x[4]],
        })
    }
}

/// A request under `timeout`, its failure sorted and named.
async fn call<T>(
    timeout: Duration,
    what: &str,
    f: impl Future<Output = Result<Result<T, tokio_modbus::ExceptionCode>, tokio_modbus::Error>>,
) -> Result<T, RequestError> {
    let failed = |kind, cause: String| {
        Err(RequestError {
            kind,
            what: what.to_string(),
            cause,
        })
    };
    match tokio::time::timeout(timeout, f).await {
        Err(_) => failed(
            RequestFailure::Timeout,
            format!("no response within {} ms", timeout.as_millis()),
        ),
        Ok(Err(tokio_modbus::Error::Transport(e))) if e.kind() == std::io::ErrorKind::InvalidData => failed(
            RequestFailure::Corrupt,
            format!("a response that could not be decoded: {e}"),
        ),
        Ok(Err(e)) => failed(RequestFailure::Disconnected, e.to_string()),
        Ok(Ok(Err(code))) => failed(
            RequestFailure::Exception,
            format!("exception {} ({code})", u8::from(code)),
        ),
        Ok(Ok(Ok(v))) => Ok(v),
    }
}

/// The watchdog's registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Watchdog {
    /// Threshold (ms).
    pub threshold_ms: u16,
    /// Time since the last reset (ms).
    pub elapsed_ms: u16,
    /// 0 running, 1 expired.
    pub status: u16,
    /// The mode (0xC0 off, 0xC1 any telegram, 0xC2 writes).
    pub mode: u16,
}

impl Watchdog {
    /// The mode for people.
    pub fn mode_name(&self) -> String {
        match self.mode {
            super::WATCHDOG_OFF => "off".into(),
            super::WATCHDOG_ANY_ACCESS => "reset by any telegram".into(),
            WATCHDOG_WRITES => "reset by writes only".into(),
            other => format!("unknown mode {other:#04X}"),
        }
    }
}

/// What a bus controller says about itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Identity {
    /// MAC address.
    pub mac: [u8; 6],
    /// IP address stored in flash.
    pub ip_flash: [u8; 4],
    /// Subnet mask.
    pub subnet: [u8; 4],
    /// Gateway.
    pub gateway: [u8; 4],
    /// IP address in use.
    pub ip_current: [u8; 4],
    /// Modbus TCP port.
    pub port: u16,
    /// X2X cycle time (µs).
    pub x2x_cycle_us: u16,
    /// Serial number.
    pub serial: u64,
    /// Product code.
    pub product_code: u16,
    /// Hardware variant.
    pub hw_variant: u16,
    /// Hardware version.
    pub hw_version: u16,
    /// Firmware version (major, minor).
    pub firmware: (u16, u16),
    /// The watchdog.
    pub watchdog: Watchdog,
    /// Number of modules.
    pub modules: u16,
    /// Analog in, analog out, digital in, digital out: (count, bytes).
    pub process: [(u16, u16); 4],
    /// Connected Modbus clients.
    pub clients: u16,
    /// Node number (the rotary switches).
    pub node: u16,
    /// Status register.
    pub status: u16,
    /// Error bits.
    pub errors: ErrorBits,
    /// X2X cycles counted.
    pub x2x_cycles: u32,
    /// X2X bus-off, sync and frame errors.
    pub x2x_errors: [u16; 3],
}
