//! B&R's X20BC0087, the Modbus TCP bus controller that takes an X20 CPU's place in front of its
//! I/O modules: its registers, its module table, its error bits, and what the soft-PLC expects
//! to find in them for an I/O map (`"station": "X20BC0087"`). The process data's layout is
//! [`RegisterMap`]'s; [`client`] reads and sets these registers over a Modbus connection.
//!
//! Addresses are 0-based, as on the wire (unit 0); every register here is a holding register.
//! They follow the public register description of the bus controller (the X20 system user's
//! manual and B&R's own Modbus TCP client library for it).

pub mod client;

use std::fmt;

use super::catalogue;
use super::map::IoMap;
use super::registers::{ModuleData, RegisterMap, Table};

/// First register of the module table: 16 registers per module, module *n* (from 0) at
/// `MODULE_TABLE + 16·n`.
pub const MODULE_TABLE: u16 = 0xA000;
/// Registers per module in the module table.
pub const RECORD_LEN: u16 = 16;
/// The most modules an X2X link carries; a table is read no further.
pub const MAX_MODULES: u16 = 253;
/// The function model whose data a Modbus client can address: 16-bit values.
pub const FUNCTION_MODEL_BUS_CONTROLLER: u16 = 254;
/// A data index that means "no data of this kind".
pub const NO_DATA: u16 = 0xFFFF;
/// The hardware ID io-sim reports for a module whose ID its I/O map does not pin (0xFFFF).
pub use crate::services::io::map::SIMULATED_UNPINNED_ID;

/// MAC address (3 registers).
pub const MAC: u16 = 0x1000;
/// IP address in flash (4 registers, one byte each).
pub const IP_FLASH: u16 = 0x1003;
/// Subnet mask (4 registers).
pub const SUBNET: u16 = 0x1007;
/// Gateway (4 registers).
pub const GATEWAY: u16 = 0x100B;
/// The Modbus TCP port.
pub const PORT: u16 = 0x100F;
/// The X2X link's cycle time (µs).
pub const X2X_CYCLE: u16 = 0x1012;
/// The IP address in use (4 registers).
pub const IP_CURRENT: u16 = 0x1013;

/// Watchdog threshold (ms).
pub const WATCHDOG_THRESHOLD: u16 = 0x1040;
/// Time since the watchdog was last reset (ms).
pub const WATCHDOG_ELAPSED: u16 = 0x1041;
/// Watchdog status: 0 running, 1 expired (outputs held at their safe values).
pub const WATCHDOG_STATUS: u16 = 0x1042;
/// Watchdog mode ([`WATCHDOG_OFF`], [`WATCHDOG_ANY_ACCESS`], [`WATCHDOG_WRITES`]).
pub const WATCHDOG_MODE: u16 = 0x1043;
/// Written with [`WATCHDOG_RESET_VALUE`]: resets the watchdog (and lets an expired one's
/// outputs be written again).
pub const WATCHDOG_RESET: u16 = 0x1044;
/// Watchdog mode: off.
pub const WATCHDOG_OFF: u16 = 0xC0;
/// Watchdog mode: any telegram resets it (a client that only reads keeps it fed).
pub const WATCHDOG_ANY_ACCESS: u16 = 0xC1;
/// Watchdog mode: only writes reset it — the soft-PLC's: its writes stop when its cycle stops.
pub const WATCHDOG_WRITES: u16 = 0xC2;
/// What [`WATCHDOG_RESET`] is written with.
pub const WATCHDOG_RESET_VALUE: u16 = 0xC1;

/// Serial number (3 registers), then product code and versions ([`PRODUCT_LEN`] in all).
pub const PRODUCT: u16 = 0x1080;
/// Registers of product data from [`PRODUCT`]: serial (3), product code, hardware variant,
/// hardware version, firmware version (2: major, minor).
pub const PRODUCT_LEN: u16 = 8;
/// Connected Modbus clients.
pub const CLIENTS: u16 = 0x10C0;
/// Number of modules, then analog in count/size, analog out count/size, digital in
/// count/size, digital out count/size ([`PROCESS_COUNTS_LEN`] in all; sizes in bytes).
pub const PROCESS_COUNTS: u16 = 0x1100;
/// Registers from [`PROCESS_COUNTS`].
pub const PROCESS_COUNTS_LEN: u16 = 9;
/// The node number (the rotary switches).
pub const NODE: u16 = 0x1180;
/// Bus controller status.
pub const STATUS: u16 = 0x1186;
/// Error bits ([`ErrorBits`]).
pub const ERRORS: u16 = 0x1187;
/// X2X statistics: cycle count (2 registers, high word first), bus-off, sync errors, frame
/// errors ([`X2X_STATS_LEN`] in all).
pub const X2X_STATS: u16 = 0x11C0;
/// Registers from [`X2X_STATS`].
pub const X2X_STATS_LEN: u16 = 5;

/// The bus controller's error bits (register [`ERRORS`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ErrorBits(pub u16);

impl ErrorBits {
    /// Bit 3: a module differs from the stored configuration (and does not start).
    pub const MODULE_MISMATCH: u16 = 1 << 3;
    /// Bit 4: a module reports an error while running.
    pub const MODULE_RUNTIME: u16 = 1 << 4;
    /// Bit 5: no telegram reset the watchdog within its threshold; the outputs are held at their
    /// safe values until a client resets it.
    pub const WATCHDOG_EXPIRED: u16 = 1 << 5;
    /// Each bit's name, bit 0 first.
    pub const NAMES: [&'static str; 6] = [
        "configuration data error",
        "flash read error",
        "IP address conflict",
        "module mismatch",
        "module runtime error",
        "watchdog expired",
    ];

    /// The bits that end a running cycle's trust in the station: a bus fault each.
    pub const FAULTS: u16 = Self::MODULE_MISMATCH | Self::MODULE_RUNTIME | Self::WATCHDOG_EXPIRED;

    /// Whether `bit` is set.
    pub fn has(self, bit: u16) -> bool {
        self.0 & bit != 0
    }

    /// The names of the bits set, bit 0 first; unknown bits as "bit N".
    pub fn names(self) -> Vec<String> {
        (0..16)
            .filter(|b| self.0 & (1 << b) != 0)
            .map(|b| match Self::NAMES.get(b) {
                Some(name) => (*name).to_string(),
                None => format!("bit {b}"),
            })
            .collect()
    }
}

impl fmt::Display for ErrorBits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 == 0 {
            return f.write_str("none");
        }
        write!(f, "{} ({:#06x})", self.names().join(", "), self.0)
    }
}

/// One module's record in the module table.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ModuleRecord {
    /// 0: no module in this slot (the end of the table).
    pub status: u16,
    /// The module's hardware ID (B&R ID code).
    pub id: u16,
    /// Serial number (registers +2, +3, high word first).
    pub serial: u32,
    /// Analog input index (bytes; [`NO_DATA`]: none).
    pub analog_in: u16,
    /// Analog output index.
    pub analog_out: u16,
    /// Digital input index.
    pub digital_in: u16,
    /// Digital output index.
    pub digital_out: u16,
    /// The hardware ID the bus controller's stored configuration expects in this slot (0: none
    /// stored); a module that differs does not start.
    pub configured_id: u16,
    /// The function model the module runs.
    pub function_model: u16,
    /// Configuration index and size.
    pub config: (u16, u16),
    /// Firmware version.
    pub firmware: u16,
    /// Hardware variant.
    pub hw_variant: u16,
}

impl ModuleRecord {
    /// A record from its 16 registers.
    pub fn from_words(w: &[u16; RECORD_LEN as usize]) -> ModuleRecord {
        ModuleRecord {
            status: w[0],
            id: w[1],
            serial: (u32::from(w[2]) << 16) | u32::from(w[3]),
            analog_in: w[4],
            analog_out: w[5],
            digital_in: w[6],
            digital_out: w[7],
            configured_id: w[8],
            function_model: w[9],
            config: (w[10], w[11]),
            firmware: w[12],
            hw_variant: w[13],
        }
    }

    /// The record's 16 registers.
    pub fn to_words(&self) -> [u16; RECORD_LEN as usize] {
        [
            self.status,
            self.id,
            (self.serial >> 16) as u16,
            self.serial as u16,
            self.analog_in,
            self.analog_out,
            self.digital_in,
            self.digital_out,
            self.configured_id,
            self.function_model,
            self.config.0,
            self.config.1,
            self.firmware,
            self.hw_variant,
            0,
            0,
        ]
    }

    /// Whether a module sits in this slot.
    pub fn present(&self) -> bool {
        self.status != 0
    }

    /// The module's type name from its ID: the catalogue's, or "unknown ID 0x…".
    pub fn type_name(&self) -> String {
        type_name(self.id)
    }
}

/// A module type's name from its hardware ID: the catalogue's, or "unknown ID 0x…" (io-sim's
/// stand-in for an unpinned ID: "no ID (io-sim)").
pub fn type_name(id: u16) -> String {
    match catalogue::by_hardware_id(id) {
        Some(t) => t.name.to_string(),
        None if id == SIMULATED_UNPINNED_ID => "no ID (io-sim)".to_string(),
        None => format!("unknown ID {id:#06X}"),
    }
}

/// A data index as the table writes it.
fn index_of(data: Option<(u16, u16)>) -> u16 {
    data.map_or(NO_DATA, |(index, _)| index)
}

/// What one slot of the station must hold, from the I/O map.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExpectedModule {
    /// The slot (1-based, as the I/O map and the backplane count).
    pub slot: u16,
    /// The module's name in the I/O map.
    pub name: String,
    /// Its type.
    pub type_name: &'static str,
    /// Its hardware ID: the map's or the catalogue's; `None` when neither pins it.
    pub id: Option<u16>,
    /// Its data as the project's layout assigns it (what io-sim serves).
    pub data: ModuleData,
}

impl ExpectedModule {
    /// The record a bus controller holding exactly this module reports (serial 0, firmware 0;
    /// an unpinned ID as [`SIMULATED_UNPINNED_ID`], with no configured ID).
    pub fn record(&self) -> ModuleRecord {
        let id = self.id.unwrap_or(SIMULATED_UNPINNED_ID);
        ModuleRecord {
            status: 1,
            id,
            serial: 0,
            analog_in: index_of(self.data.analog_in),
            analog_out: index_of(self.data.analog_out),
            digital_in: index_of(self.data.digital_in),
            digital_out: index_of(self.data.digital_out),
            // No stored configuration names a module the map leaves open.
            configured_id: self.id.unwrap_or(0),
            function_model: FUNCTION_MODEL_BUS_CONTROLLER,
            config: (0, 0),
            firmware: 0,
            hw_variant: 0,
        }
    }

    /// What the slot is, for messages: `slot 3: the I/O map expects X20DC1196 (ID 0x…, module "DC")`.
    fn what(&self) -> String {
        let id = self
            .id
            .map_or_else(|| "ID not pinned".to_string(), |id| format!("ID {id:#06X}"));
        format!(
            "slot {}: the I/O map expects {} ({id}, module \"{}\")",
            self.slot, self.type_name, self.name
        )
    }
}

/// The modules an X20BC0087 station of `map` holds, in slot order. `registers` is the map's
/// X20BC0087 layout.
pub fn expected_modules(map: &IoMap, registers: &RegisterMap) -> Vec<ExpectedModule> {
    registers
        .modules
        .iter()
        .map(|data| {
            let m = &map.modules[data.module];
            ExpectedModule {
                slot: m.slot,
                name: m.name.clone(),
                type_name: m.ty.name,
                id: m.id,
                data: *data,
            }
        })
        .collect()
}

/// Why the station is not the I/O map's: one line per slot that differs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mismatch {
    /// The differences, slot by slot.
    pub slots: Vec<String>,
}

impl fmt::Display for Mismatch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.slots.join("; "))
    }
}

/// Compares the station's module table (`reported`, the records up to the first empty slot)
/// with what the map expects: the order and types (by hardware ID), the stored configuration's
/// ID, the function model, and that each module has data of the kinds its channels need. A
/// module whose ID the map does not pin must not report another catalogued type's ID; it is
/// accepted with a note (returned) that names the ID it reports, to be pinned.
pub fn compare(expected: &[ExpectedModule], reported: &[ModuleRecord]) -> Result<Vec<String>, Mismatch> {
    let mut slots = Vec::new();
    let mut notes = Vec::new();
    for (i, want) in expected.iter().enumerate() {
        let what = want.what();
        let Some(got) = reported.get(i) else {
            slots.push(format!("{what}, the station reports no module there"));
            continue;
        };
        let reports = || format!("the station reports {} (ID {:#06X})", got.type_name(), got.id);
        match want.id {
            Some(id) if got.id != id => {
                slots.push(format!("{what}, {}", reports()));
                continue;
            }
            Some(_) => {}
            None => match catalogue::by_hardware_id(got.id) {
                Some(other) if other.name != want.type_name => {
                    slots.push(format!("{what}, {}", reports()));
                    continue;
                }
                _ if got.id == SIMULATED_UNPINNED_ID => notes.push(format!(
                    "slot {}: {} (module \"{}\"): the station reports ID {SIMULATED_UNPINNED_ID:#06X}, io-sim's stand-in \
                     for an ID its map does not pin, no module's own; the real station reports the module's ID \
                     (`pkm-plc station scan`): pin that one",
                    want.slot, want.type_name, want.name
                )),
                _ => notes.push(format!(
                    "slot {}: {} (module \"{}\") is taken to be the module of ID {:#06X} the station reports there: \
                     pin it in the I/O map (\"id\": \"{:#06X}\") so that another module is refused",
                    want.slot, want.type_name, want.name, got.id, got.id
                )),
            },
        }
        if got.configured_id != 0 && got.configured_id != got.id {
            slots.push(format!(
                "{what}: the station's stored configuration expects ID {:#06X} there, so the module (ID {:#06X}) does \
                 not start (module mismatch; erase the bus controller's stored configuration)",
                got.configured_id, got.id
            ));
            continue;
        }
        if got.function_model != FUNCTION_MODEL_BUS_CONTROLLER {
            slots.push(format!(
                "{what}: the module runs function model {}, the soft-PLC addresses function model \
                 {FUNCTION_MODEL_BUS_CONTROLLER} (bus controller) data",
                got.function_model
            ));
            continue;
        }
        let kinds = [
            ("analog inputs", want.data.analog_in, got.analog_in),
            ("analog outputs", want.data.analog_out, got.analog_out),
            ("digital inputs", want.data.digital_in, got.digital_in),
            ("digital outputs", want.data.digital_out, got.digital_out),
        ];
        let missing: Vec<&str> = kinds
            .iter()
            .filter(|(_, needed, index)| needed.is_some() && *index == NO_DATA)
            .map(|(kind, ..)| *kind)
            .collect();
        if !missing.is_empty() {
            slots.push(format!(
                "{what}: the station's module (ID {:#06X}) has no {}, which the map's channels need",
                got.id,
                missing.join(" and ")
            ));
        }
    }
    for (i, got) in reported.iter().enumerate().skip(expected.len()) {
        slots.push(format!(
            "slot {}: the station reports {} (ID {:#06X}), which the I/O map does not have",
            i + 1,
            got.type_name(),
            got.id
        ));
    }
    if slots.is_empty() {
        Ok(notes)
    } else {
        Err(Mismatch { slots })
    }
}

/// The map's layout with each module's data where the station assigns it: every channel keeps
/// its place within its module's data, the module's data starts at the index the station's
/// table gives (a module with more data than the catalogue models moves the ones after it).
/// `reported` must have passed [`compare`] with `registers`' modules; an index that puts a
/// channel beyond the 16-bit address space is refused, naming the slot.
pub fn rebase(registers: &RegisterMap, reported: &[ModuleRecord]) -> Result<RegisterMap, Mismatch> {
    let mut rebased = registers.clone();
    let mut slots = Vec::new();
    for e in &mut rebased.entries {
        let Some((p, data)) = registers.modules.iter().enumerate().find(|(_, d)| d.module == e.module) else {
            continue;
        };
        let Some(got) = reported.get(p) else { continue };
        let (ours, theirs) = match e.table {
            Table::DiscreteInput => (data.digital_in, got.digital_in),
            Table::Coil => (data.digital_out, got.digital_out),
            Table::InputRegister => (data.analog_in, got.analog_in),
            Table::HoldingRegister => (data.analog_out, got.analog_out),
        };
        let (Some((ours, _)), false) = (ours, theirs == NO_DATA) else {
            continue;
        };
        // Analog data lies in registers of two bytes: an odd byte index splits one (a broken or
        // hostile table), and halving it would put every channel a byte off.
        if matches!(e.table, Table::InputRegister | Table::HoldingRegister) && theirs % 2 != 0 {
            slots.push(format!(
                "slot {}: the station puts the module's analog data at byte index {theirs}, which is odd: registers are two bytes each",
                p + 1
            ));
            continue;
        }
        // The channel's place within its module's data, then where the station puts that data.
        let moved = match e.table {
            Table::DiscreteInput | Table::Coil => (u32::from(e.address) - u32::from(ours) * 8) + u32::from(theirs) * 8,
            Table::InputRegister | Table::HoldingRegister => {
                (u32::from(e.address) - u32::from(ours) / 2) + u32::from(theirs) / 2
            }
        };
        let limit = match e.table {
            Table::HoldingRegister => u32::from(u16::MAX - registers.holding_base),
            _ => u32::from(u16::MAX),
        };
        match u16::try_from(moved) {
            Ok(address) if moved + u32::from(e.count) <= limit => e.address = address,
            _ => slots.push(format!(
                "slot {}: the station puts the module's data at byte index {theirs}, beyond what Modbus can address",
                p + 1
            )),
        }
    }
    if !slots.is_empty() {
        slots.dedup();
        return Err(Mismatch { slots });
    }
    // One request per table reads or writes it from address 0: within Modbus's quantities.
    let [coils, discrete, input, holding] = rebased.sizes();
    for (what, n, max) in [
        ("coils", coils, 1968),
        ("discrete inputs", discrete, 2000),
        ("input registers", input, 125),
        ("holding registers", holding, 123),
    ] {
        if n > max {
            slots.push(format!(
                "the station's data indexes spread the map's channels over {n} {what}, more than one request carries ({max})"
            ));
        }
    }
    if !slots.is_empty() {
        return Err(Mismatch { slots });
    }
    for (p, data) in rebased.modules.iter_mut().enumerate() {
        if let Some(got) = reported.get(p) {
            let moved = |ours: Option<(u16, u16)>, theirs: u16| ours.map(|(_, bytes)| (theirs, bytes));
            data.analog_in = moved(data.analog_in, got.analog_in);
            data.analog_out = moved(data.analog_out, got.analog_out);
            data.digital_in = moved(data.digital_in, got.digital_in);
            data.digital_out = moved(data.digital_out, got.digital_out);
        }
    }
    Ok(rebased)
}

/// A data index for people: its number, or "none".
pub fn show_index(index: u16) -> String {
    if index == NO_DATA {
        "none".into()
    } else {
        index.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trijoint() -> (IoMap, RegisterMap) {
        let text = include_str!("../../../../io-map/trijoint.json");
        let classes = ["fast", "main", "spare"].map(String::from);
        let map = IoMap::parse(text, "trijoint.json", &classes).expect("the TRIJOINT map is valid");
        let registers = RegisterMap::of(&map);
        (map, registers)
    }

    #[test]
    fn the_lab_station_is_laid_out_by_byte_index_in_slot_order() {
        let (map, registers) = trijoint();
        let expected = expected_modules(&map, &registers);
        let rows: Vec<(u16, &str, [u16; 4])> = expected
            .iter()
            .map(|e| {
                let r = e.record();
                (
                    e.slot,
                    e.type_name,
                    [r.analog_in, r.analog_out, r.digital_in, r.digital_out],
                )
            })
            .collect();
        assert_eq!(
            rows,
            [
                // 12 inputs: 2 bytes from 0.
                (1, "X20DI9371", [NO_DATA, NO_DATA, 0, NO_DATA]),
                // 12 outputs: 2 bytes from 0.
                (2, "X20DO9322", [NO_DATA, NO_DATA, NO_DATA, 0]),
                // The counter (a word) from byte 0, its reset bit in byte 2.
                (3, "X20DC1196", [0, NO_DATA, NO_DATA, 2]),
                (4, "X20DC1196", [2, NO_DATA, NO_DATA, 3]),
                // Period and two pulse widths (6 bytes), 4 output bits, 6 input bits.
                (5, "X20MM2436", [NO_DATA, 0, 2, 4]),
            ]
        );
        assert_eq!(
            registers.sizes(),
            [36, 22, 2, 3],
            "coils, discrete inputs, input registers, holding registers"
        );
        let right_pwm = registers
            .entries
            .iter()
            .find(|e| map.modules[e.module].name == "MM" && e.channel == 1)
            .expect("PulseWidthCurrentPWM01");
        assert_eq!(
            registers.wire_address(right_pwm),
            0x0801,
            "the second word of the MM's outputs"
        );
    }

    #[test]
    fn swapped_modules_are_named_by_slot_with_what_the_station_reports() {
        let (map, registers) = trijoint();
        let expected = expected_modules(&map, &registers);
        let mut reported: Vec<ModuleRecord> = expected.iter().map(ExpectedModule::record).collect();
        reported.swap(0, 1);
        let mismatch = compare(&expected, &reported).expect_err("DI and DO swapped");
        assert_eq!(
            mismatch.slots,
            [
                "slot 1: the I/O map expects X20DI9371 (ID 0x1B95, module \"DI\"), the station reports X20DO9322 (ID 0x1B9A)",
                "slot 2: the I/O map expects X20DO9322 (ID 0x1B9A, module \"DO\"), the station reports X20DI9371 (ID 0x1B95)",
            ]
        );
        // io-sim's station: the three unpinned IDs reported as its stand-in, each note saying
        // that it is no ID to pin.
        let same: Vec<ModuleRecord> = expected.iter().map(ExpectedModule::record).collect();
        assert_eq!(same[2].id, SIMULATED_UNPINNED_ID);
        let notes = compare(&expected, &same).expect("io-sim's own station");
        assert_eq!(notes.len(), 3, "three IDs not pinned: notes");
        assert_eq!(
            notes[0],
            "slot 3: X20DC1196 (module \"DC_LEFT\"): the station reports ID 0xFFFF, io-sim's stand-in for an ID its map \
             does not pin, no module's own; the real station reports the module's ID (`pkm-plc station scan`): pin that one"
        );
    }

    #[test]
    fn missing_extra_and_misconfigured_modules_are_refused() {
        let (map, registers) = trijoint();
        let expected = expected_modules(&map, &registers);
        let mut reported: Vec<ModuleRecord> = expected.iter().map(ExpectedModule::record).collect();
        let last = reported.pop().expect("five");
        let m = compare(&expected, &reported).expect_err("one missing");
        assert!(m.slots[0].ends_with("the station reports no module there"), "{m}");
        reported.push(last);
        reported.push(expected[0].record());
        let m = compare(&expected, &reported).expect_err("one extra");
        assert_eq!(
            m.slots,
            ["slot 6: the station reports X20DI9371 (ID 0x1B95), which the I/O map does not have"]
        );
        reported.pop();
        reported[2].function_model = 0;
        reported[3].analog_in = NO_DATA;
        let m = compare(&expected, &reported).expect_err("wrong model and data");
        assert!(m.slots[0].contains("function model 0"), "{m}");
        assert!(
            m.slots[1].ends_with("has no analog inputs, which the map's channels need"),
            "{m}"
        );
    }

    #[test]
    fn an_unpinned_module_takes_any_id_but_a_catalogued_other_type() {
        let (map, registers) = trijoint();
        let expected = expected_modules(&map, &registers);
        assert_eq!(expected[2].id, None, "the X20DC1196's ID is not in the catalogue");
        let mut reported: Vec<ModuleRecord> = expected.iter().map(ExpectedModule::record).collect();
        reported[2].id = 0x2345;
        reported[2].configured_id = 0x2345;
        let notes = compare(&expected, &reported).expect("accepted");
        assert!(
            notes[0].starts_with("slot 3: X20DC1196 (module \"DC_LEFT\") is taken to be the module of ID 0x2345"),
            "{notes:?}"
        );
        reported[2].id = 0x1B95;
        reported[2].configured_id = 0x1B95;
        let m = compare(&expected, &reported).expect_err("a DI module where the counter should be");
        assert_eq!(
            m.slots,
            [
                "slot 3: the I/O map expects X20DC1196 (ID not pinned, module \"DC_LEFT\"), the station reports X20DI9371 (ID 0x1B95)"
            ]
        );
    }

    #[test]
    fn a_module_with_more_data_moves_the_ones_after_it() {
        let (map, registers) = trijoint();
        let expected = expected_modules(&map, &registers);
        let mut reported: Vec<ModuleRecord> = expected.iter().map(ExpectedModule::record).collect();
        // The left counter's module has a second word (a status word, say): the right one's
        // counter moves one word on.
        reported[3].analog_in = 4;
        let rebased = rebase(&registers, &reported).expect("addressable");
        let counter = |r: &RegisterMap, name: &str| {
            r.entries
                .iter()
                .find(|e| map.modules[e.module].name == name && e.table == Table::InputRegister)
                .map(|e| e.address)
        };
        assert_eq!(counter(&registers, "DC_RIGHT"), Some(1));
        assert_eq!(counter(&rebased, "DC_RIGHT"), Some(2));
        assert_eq!(counter(&rebased, "DC_LEFT"), Some(0));
        assert_eq!(rebased.sizes()[2], 3, "input registers read up to the moved counter");
        // A station that puts data beyond the address space (a broken or hostile one) is refused,
        // not added past u16.
        reported[4].digital_in = 0xFFF0;
        let m = rebase(&registers, &reported).expect_err("beyond the addresses");
        assert_eq!(
            m.slots,
            ["slot 5: the station puts the module's data at byte index 65520, beyond what Modbus can address"]
        );
        reported[4].digital_in = 2;
        reported[3].analog_in = 3;
        let m = rebase(&registers, &reported).expect_err("an odd analog index");
        assert_eq!(
            m.slots,
            [
                "slot 4: the station puts the module's analog data at byte index 3, which is odd: registers are two bytes each"
            ]
        );
        reported[3].analog_in = 4;
        reported[4].digital_in = 300;
        let m = rebase(&registers, &reported).expect_err("beyond one request");
        assert_eq!(
            m.slots,
            [
                "the station's data indexes spread the map's channels over 2406 discrete inputs, more than one request carries (2000)"
            ]
        );
    }

    #[test]
    fn records_round_trip_through_their_registers() {
        let record = ModuleRecord {
            status: 1,
            id: 0x1B95,
            serial: 0x0123_4567,
            analog_in: NO_DATA,
            analog_out: 4,
            digital_in: 2,
            digital_out: NO_DATA,
            configured_id: 0x1B95,
            function_model: 254,
            config: (3, 4),
            firmware: 0x0102,
            hw_variant: 5,
        };
        assert_eq!(ModuleRecord::from_words(&record.to_words()), record);
    }

    #[test]
    fn error_bits_say_their_names() {
        let bits = ErrorBits(ErrorBits::WATCHDOG_EXPIRED | ErrorBits::MODULE_MISMATCH);
        assert_eq!(bits.to_string(), "module mismatch, watchdog expired (0x0028)");
        assert_eq!(ErrorBits(1 << 9).names(), ["bit 9"]);
        assert_eq!(ErrorBits(0).to_string(), "none");
    }
}
