//! io-sim's X20BC0087: the bus controller's own registers as a Modbus client sees them — its
//! module table, process data counts, product data and node number, network settings, the
//! watchdog, the error bits and the X2X counters. The process data itself is the station's
//! ([`super::modbus::Station`]); this part answers the registers around it and decides when
//! the watchdog expires.
//!
//! The watchdog behaves as the bus controller's: it runs from the first telegram that feeds it,
//! while its mode is not "off" and its threshold is not 0; in mode 0xC1 any telegram of the
//! client that controls the outputs resets it, in mode 0xC2 only its writes do. When it
//! expires, every output goes to zero, error bit 5 is set, and process-data writes are ignored
//! until a client writes 0xC1 to register 0x1044.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio_modbus::ExceptionCode;

use crate::services::io::x20bc0087::{
    CLIENTS, ERRORS, ErrorBits, ExpectedModule, GATEWAY, IP_CURRENT, IP_FLASH, MAC, MAX_MODULES, MODULE_TABLE, NODE,
    PORT, PROCESS_COUNTS, PRODUCT, RECORD_LEN, STATUS, SUBNET, WATCHDOG_ANY_ACCESS, WATCHDOG_ELAPSED, WATCHDOG_MODE,
    WATCHDOG_OFF, WATCHDOG_RESET, WATCHDOG_RESET_VALUE, WATCHDOG_STATUS, WATCHDOG_THRESHOLD, WATCHDOG_WRITES,
    X2X_CYCLE, X2X_STATS,
};

/// io-sim's product code and serial number: its own, so that nobody takes it for B&R's hardware.
pub const SIM_PRODUCT_CODE: u16 = 0x5153;
/// The X2X cycle io-sim reports (µs).
pub const SIM_X2X_CYCLE_US: u16 = 500;
/// Register 0x1182, the I/O boundary check (0xC0 switches it off; io-sim keeps what is written).
const BOUNDARY_CHECK: u16 = 0x1182;
/// The telegram counter (2 registers, high word first).
const TELEGRAMS: u16 = 0x10C1;

/// The bus controller's registers and watchdog.
#[derive(Debug)]
pub struct BusControllerSim {
    /// The module table, one record per module in slot order.
    table: Vec<[u16; RECORD_LEN as usize]>,
    /// Module count, then (count, bytes) of analog in, analog out, digital in, digital out.
    counts: [u16; 9],
    node: u16,
    address: Option<SocketAddr>,
    threshold_ms: u16,
    mode: u16,
    boundary_check: u16,
    /// The last telegram that reset the watchdog.
    fed_at: Instant,
    /// Whether a telegram has fed the watchdog since it was set (it runs from then on).
    armed: bool,
    expired: bool,
    errors: u16,
    telegrams: u32,
    clients: u16,
    started: Instant,
}

impl BusControllerSim {
    /// A bus controller holding `modules` (slot order), at node `node`, its watchdog off.
    pub fn new(modules: &[ExpectedModule], node: u16) -> BusControllerSim {
        let table: Vec<[u16; RECORD_LEN as usize]> = modules
            .iter()
            .map(|m| {
                let mut record = m.record();
                // Serial numbers of io-sim's own: the slot.
                record.serial = u32::from(m.slot);
                record.to_words()
            })
            .collect();
        let mut counts = [0u16; 9];
        counts[0] = modules.len() as u16;
        for m in modules {
            let kinds = [
                m.data.analog_in,
                m.data.analog_out,
                m.data.digital_in,
                m.data.digital_out,
            ];
            for (k, data) in kinds.iter().enumerate() {
                if let Some((_, bytes)) = data {
                    counts[1 + 2 * k] += 1;
                    counts[2 + 2 * k] += bytes;
                }
            }
        }
        let now = Instant::now();
        BusControllerSim {
            table,
            counts,
            node,
            address: None,
            threshold_ms: 0,
            mode: WATCHDOG_OFF,
            boundary_check: 0,
            fed_at: now,
            armed: false,
            expired: false,
            errors: 0,
            telegrams: 0,
            clients: 0,
            started: now,
        }
    }

    /// The watchdog's stored setting, as the bus controller starts with it: `watchdog` (`None`:
    /// off) in mode 0xC1 (any telegram resets it), as B&R's client library leaves it.
    pub fn store_watchdog(&mut self, watchdog: Option<Duration>) {
        self.threshold_ms = watchdog.map_or(0, |w| w.as_millis().min(u128::from(u16::MAX)) as u16);
        self.mode = if watchdog.is_some() {
            WATCHDOG_ANY_ACCESS
        } else {
            WATCHDOG_OFF
        };
        self.fed_at = Instant::now();
        self.armed = false;
    }

    /// The address it serves on, for its network registers.
    pub fn set_address(&mut self, address: SocketAddr) {
        self.address = Some(address);
    }

    /// The bytes of analog in, analog out, digital in, digital out: the process images' sizes.
    pub fn image_bytes(&self) -> [u16; 4] {
        [self.counts[2], self.counts[4], self.counts[6], self.counts[8]]
    }

    /// A client connected (`true`) or left.
    pub fn client(&mut self, connected: bool) {
        self.clients = if connected {
            self.clients.saturating_add(1)
        } else {
            self.clients.saturating_sub(1)
        };
    }

    /// A telegram arrived; `write`: it writes; `controlling`: it comes from the client that
    /// controls the outputs (or from any while none does). Counted; a controlling one feeds the
    /// watchdog as its mode says (an expired one only by its reset register).
    pub fn telegram(&mut self, write: bool, controlling: bool) {
        self.telegrams = self.telegrams.wrapping_add(1);
        if !controlling {
            return;
        }
        let feeds = match self.mode {
            WATCHDOG_ANY_ACCESS => true,
            WATCHDOG_WRITES => write,
            _ => false,
        };
        if feeds && !self.expired {
            self.fed_at = Instant::now();
            self.armed = true;
        }
    }

    /// Whether the watchdog has expired: process-data writes are then ignored.
    pub fn expired(&self) -> bool {
        self.expired
    }

    /// Checks the watchdog; true when it expires now (the caller sets the outputs to zero).
    pub fn watch(&mut self) -> bool {
        if self.expired || !self.armed || self.mode == WATCHDOG_OFF || self.threshold_ms == 0 {
            return false;
        }
        if self.fed_at.elapsed() <= Duration::from_millis(u64::from(self.threshold_ms)) {
            return false;
        }
        self.expired = true;
        self.errors |= ErrorBits::WATCHDOG_EXPIRED;
        true
    }

    /// Reads `count` of its registers from `address`; `None` when `address` is not one of its
    /// ranges (the process data's, then).
    pub fn read(&self, address: u16, count: u16) -> Option<Result<Vec<u16>, ExceptionCode>> {
        let end = u32::from(address) + u32::from(count);
        let table_end = u32::from(MODULE_TABLE) + u32::from(MAX_MODULES) * u32::from(RECORD_LEN);
        if address >= MODULE_TABLE {
            if end > table_end {
                return Some(Err(ExceptionCode::IllegalDataAddress));
            }
            let words = (address..address + count)
                .map(|a| {
                    let offset = usize::from(a - MODULE_TABLE);
                    let (slot, word) = (offset / usize::from(RECORD_LEN), offset % usize::from(RECORD_LEN));
                    self.table.get(slot).map_or(0, |r| r[word])
                })
                .collect();
            return Some(Ok(words));
        }
        if !(MAC..0x1200).contains(&address) {
            return None;
        }
        Some(
            (address..address.saturating_add(count))
                .map(|a| self.register(a).ok_or(ExceptionCode::IllegalDataAddress))
                .collect(),
        )
    }

    /// One of its registers (not the module table).
    fn register(&self, a: u16) -> Option<u16> {
        let ip = self.address.map_or([192, 168, 100, 1], |s| match s.ip() {
            std::net::IpAddr::V4(v4) => v4.octets(),
            std::net::IpAddr::V6(_) => [0, 0, 0, 0],
        });
        let subnet = if ip[0] == 127 {
            [255, 0, 0, 0]
        } else {
            [255, 255, 255, 0]
        };
        let in_four = |base: u16, bytes: [u8; 4]| {
            (base..base + 4)
                .contains(&a)
                .then(|| u16::from(bytes[usize::from(a - base)]))
        };
        // B&R's OUI, then the node number.
        let mac = [0x0060, 0x6500, self.node];
        let elapsed_ms = self.fed_at.elapsed().as_millis().min(u128::from(u16::MAX)) as u16;
        let x2x_cycles = (self.started.elapsed().as_micros() / u128::from(SIM_X2X_CYCLE_US)) as u32;
        let value = match a {
            MAC..=0x1002 => mac[usize::from(a - MAC)],
            IP_FLASH..=0x1006 => in_four(IP_FLASH, ip)?,
            SUBNET..=0x100A => in_four(SUBNET, subnet)?,
            GATEWAY..=0x100E => in_four(GATEWAY, [0, 0, 0, 0])?,
            PORT => self.address.map_or(502, |s| s.port()),
            X2X_CYCLE => SIM_X2X_CYCLE_US,
            IP_CURRENT..=0x1016 => in_four(IP_CURRENT, ip)?,
            WATCHDOG_THRESHOLD => self.threshold_ms,
            WATCHDOG_ELAPSED => {
                if self.expired {
                    self.threshold_ms
                } else {
                    elapsed_ms
                }
            }
            WATCHDOG_STATUS => u16::from(self.expired),
            WATCHDOG_MODE => self.mode,
            WATCHDOG_RESET => 0,
            // Serial number (3 registers): io-sim's own, 1.
            PRODUCT | 0x1081 => 0,
            0x1082 => 1,
            0x1083 => SIM_PRODUCT_CODE,
            // Hardware variant and version; firmware 1.0.
            0x1084 | 0x1085 => 0,
            0x1086 => 1,
            0x1087 => 0,
            CLIENTS => self.clients,
            TELEGRAMS => (self.telegrams >> 16) as u16,
            0x10C2 => self.telegrams as u16,
            0x10C3..=0x10D3 => 0,
            PROCESS_COUNTS..=0x1108 => self.counts[usize::from(a - PROCESS_COUNTS)],
            NODE => self.node,
            BOUNDARY_CHECK => self.boundary_check,
            STATUS => u16::from(self.errors != 0),
            ERRORS => self.errors,
            X2X_STATS => (x2x_cycles >> 16) as u16,
            0x11C1 => x2x_cycles as u16,
            0x11C2..=0x11C4 => 0,
            _ => return None,
        };
        Some(value)
    }

    /// Writes one of its registers; `None` when `address` is not one of its ranges. The
    /// watchdog's threshold, mode and reset, and the boundary check, may be written; the rest
    /// are read-only here.
    pub fn write(&mut self, address: u16, values: &[u16]) -> Option<Result<(), ExceptionCode>> {
        if !(MAC..0x1200).contains(&address) && address < MODULE_TABLE {
            return None;
        }
        for (i, v) in values.iter().enumerate() {
            // Past 0xFFFF there is no register (and no u16 to count it in).
            let Ok(a) = u16::try_from(usize::from(address) + i) else {
                return Some(Err(ExceptionCode::IllegalDataAddress));
            };
            match a {
                WATCHDOG_THRESHOLD => self.threshold_ms = *v,
                WATCHDOG_MODE if [WATCHDOG_OFF, WATCHDOG_ANY_ACCESS, WATCHDOG_WRITES].contains(v) => self.mode = *v,
                WATCHDOG_MODE => return Some(Err(ExceptionCode::IllegalDataValue)),
                WATCHDOG_RESET if *v != WATCHDOG_RESET_VALUE => return Some(Err(ExceptionCode::IllegalDataValue)),
                WATCHDOG_RESET => {
                    if self.expired {
                        tracing::info!("io-sim: X20BC0087 watchdog reset by a client: outputs may be written again");
                    }
                    self.expired = false;
                    self.errors &= !ErrorBits::WATCHDOG_EXPIRED;
                    self.fed_at = Instant::now();
                }
                BOUNDARY_CHECK => self.boundary_check = *v,
                _ => return Some(Err(ExceptionCode::IllegalDataAddress)),
            }
        }
        Some(Ok(()))
    }
}
