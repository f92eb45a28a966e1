//! The Modbus register map of a station, derived from its I/O map the way a bus coupler maps its
//! modules: every channel of every field-bus module (not the HID joystick), modules in slot order, channels in catalogue order,
//! each kind of data in its own Modbus table. The map depends only on the modules present, not on
//! the bindings, so rebinding a variable never moves a register.
//!
//! Two layouts ([`StationKind`]):
//! - **generic** (the project's own station): each table from address 0, channel after channel;
//! - **X20BC0087** (B&R's Modbus TCP bus controller, function model 254): the bus controller
//!   gives each module a *byte index* into each of its four images, in slot order, each module's
//!   bits starting on a byte: digital inputs are discrete input `index·8 + bit`, digital outputs
//!   coil `index·8 + bit`, 16-bit inputs input register `index/2 + word`, 16-bit outputs holding
//!   register `0x0800 + index/2 + word` ([`ModuleData`]).
//!
//! Encodings: BOOL inputs are discrete inputs, BOOL outputs coils; INT and UINT take one register
//! (INT as two's complement); DINT two registers, high word first; REAL two registers holding an
//! IEEE-754 single (f32), high word first. Inputs are input registers, outputs holding registers.
//!
//! The same data is also mirrored as a packed process image in two blocks of holding registers
//! ([`ImageLayout`]), so that a slow serial line can exchange everything in one transaction.

use std::fmt;

use super::catalogue::Direction;
use super::map::{IoMap, StationKind};
use crate::image::{Value, VarType};

/// The Modbus tables.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Table {
    /// Read/write bits (function codes 1, 5, 15): BOOL outputs.
    Coil,
    /// Read-only bits (function code 2): BOOL inputs.
    DiscreteInput,
    /// Read-only registers (function code 4): numeric inputs.
    InputRegister,
    /// Read/write registers (function codes 3, 6, 16): numeric outputs.
    HoldingRegister,
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Table::Coil => "coil",
            Table::DiscreteInput => "discrete input",
            Table::InputRegister => "input register",
            Table::HoldingRegister => "holding register",
        })
    }
}

/// Where one channel lives.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Index into the I/O map's modules.
    pub module: usize,
    /// Index into the module type's channels.
    pub channel: usize,
    /// The table.
    pub table: Table,
    /// The first address (0-based, as on the wire; a holding register's from
    /// [`RegisterMap::holding_base`]).
    pub address: u16,
    /// Bits or registers it takes.
    pub count: u16,
    /// The channel's type.
    pub ty: VarType,
}

/// The register map of a station.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RegisterMap {
    /// The layout.
    pub station: StationKind,
    /// Every channel, in slot order.
    pub entries: Vec<Entry>,
    /// The wire address of holding register 0 of [`Entry::address`]: 0 on the generic station,
    /// [`BC_HOLDING_BASE`] on an X20BC0087.
    pub holding_base: u16,
    /// On an X20BC0087, each field-bus module's data as the bus controller assigns it, in slot
    /// order; empty on the generic station.
    pub modules: Vec<ModuleData>,
}

/// The first holding register of the numeric outputs on an X20BC0087.
pub const BC_HOLDING_BASE: u16 = 0x0800;

/// A module's data on an X20BC0087: a byte index into each image (`None`: no data of that kind,
/// `0xFFFF` in the bus controller's module table) and the bytes it takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModuleData {
    /// Index into the I/O map's modules.
    pub module: usize,
    /// Analog (16-bit word) inputs: byte index, bytes.
    pub analog_in: Option<(u16, u16)>,
    /// Analog (16-bit word) outputs: byte index, bytes.
    pub analog_out: Option<(u16, u16)>,
    /// Digital inputs: byte index, bytes.
    pub digital_in: Option<(u16, u16)>,
    /// Digital outputs: byte index, bytes.
    pub digital_out: Option<(u16, u16)>,
}

/// The table a channel of `ty` and `direction` lives in.
fn table_of(ty: VarType, direction: Direction) -> Table {
    match (ty, direction) {
        (VarType::Bool, Direction::Input) => Table::DiscreteInput,
        (VarType::Bool, Direction::Output) => Table::Coil,
        (_, Direction::Input) => Table::InputRegister,
        (_, Direction::Output) => Table::HoldingRegister,
    }
}

/// How many registers (or bits) a value of `ty` takes.
pub fn width(ty: VarType) -> u16 {
    match ty {
        VarType::Bool | VarType::Int | VarType::Uint => 1,
        VarType::Dint | VarType::Real => 2,
    }
}

impl RegisterMap {
    /// Derives the map from the modules of an I/O map, in the layout of the map's station.
    pub fn of(map: &IoMap) -> RegisterMap {
        RegisterMap::laid_out(map, map.station)
    }

    /// Derives the map from the modules of an I/O map in the layout of `station`.
    pub fn laid_out(map: &IoMap, station: StationKind) -> RegisterMap {
        match station {
            StationKind::Generic => RegisterMap::generic(map),
            StationKind::X20bc0087 => RegisterMap::bus_controller(map),
        }
    }

    /// The field-bus modules in slot order (indexes into the map's modules).
    fn slot_order(map: &IoMap) -> Vec<usize> {
        let mut order: Vec<usize> = (0..map.modules.len())
            .filter(|&m| map.modules[m].ty.field_bus)
            .collect();
        order.sort_by_key(|&m| map.modules[m].slot);
        order
    }

    /// The X20BC0087's layout: byte indexes per module and image, in slot order.
    fn bus_controller(map: &IoMap) -> RegisterMap {
        // Bytes used so far in each image, by table.
        let mut used = [0u16; 4];
        let mut entries = Vec::new();
        let mut modules = Vec::new();
        for m in RegisterMap::slot_order(map) {
            let channels = map.modules[m].ty.channels;
            let mut data = ModuleData {
                module: m,
                analog_in: None,
                analog_out: None,
                digital_in: None,
                digital_out: None,
            };
            for table in [
                Table::DiscreteInput,
                Table::Coil,
                Table::InputRegister,
                Table::HoldingRegister,
            ] {
                let start = used[table as usize];
                // Within the module: bits or words taken so far in this table.
                let mut taken = 0u16;
                for (c, ch) in channels.iter().enumerate() {
                    if table_of(ch.ty, ch.direction) != table {
                        continue;
                    }
                    let count = width(ch.ty);
                    let address = match table {
                        Table::DiscreteInput | Table::Coil => start * 8 + taken,
                        Table::InputRegister | Table::HoldingRegister => start / 2 + taken,
                    };
                    entries.push(Entry {
                        module: m,
                        channel: c,
                        table,
                        address,
                        count,
                        ty: ch.ty,
                    });
                    taken += count;
                }
                if taken == 0 {
                    continue;
                }
                let bytes = match table {
                    Table::DiscreteInput | Table::Coil => taken.div_ceil(8),
                    Table::InputRegister | Table::HoldingRegister => taken * 2,
                };
                used[table as usize] += bytes;
                let slot = match table {
                    Table::DiscreteInput => &mut data.digital_in,
                    Table::Coil => &mut data.digital_out,
                    Table::InputRegister => &mut data.analog_in,
                    Table::HoldingRegister => &mut data.analog_out,
                };
                *slot = Some((start, bytes));
            }
            modules.push(data);
        }
        RegisterMap {
            station: StationKind::X20bc0087,
            entries,
            holding_base: BC_HOLDING_BASE,
            modules,
        }
    }

    /// The generic layout: each table from address 0, channel after channel.
    fn generic(map: &IoMap) -> RegisterMap {
        let mut next = [0u16; 4];
        let mut entries = Vec::new();
        for m in RegisterMap::slot_order(map) {
            for (c, ch) in map.modules[m].ty.channels.iter().enumerate() {
                let table = table_of(ch.ty, ch.direction);
                let count = width(ch.ty);
                let slot = &mut next[table as usize];
                entries.push(Entry {
                    module: m,
                    channel: c,
                    table,
                    address: *slot,
                    count,
                    ty: ch.ty,
                });
                *slot += count;
            }
        }
        RegisterMap {
            station: StationKind::Generic,
            entries,
            holding_base: 0,
            modules: Vec::new(),
        }
    }

    /// The wire address of entry `e`'s first register or bit.
    pub fn wire_address(&self, e: &Entry) -> u16 {
        match e.table {
            Table::HoldingRegister => self.holding_base + e.address,
            _ => e.address,
        }
    }

    /// The number of bits or registers used in each table (coils, discrete inputs, input
    /// registers, holding registers; the holding registers counted from `holding_base`).
    pub fn sizes(&self) -> [u16; 4] {
        let mut sizes = [0u16; 4];
        for e in &self.entries {
            let s = &mut sizes[e.table as usize];
            *s = (*s).max(e.address + e.count);
        }
        sizes
    }

    /// What the `registers` command prints: for an X20BC0087 the modules' data indexes, then
    /// every channel's place ([`RegisterMap::describe`]), the tables' sizes, and the packed
    /// image of a generic station.
    pub fn report(&self, map: &IoMap) -> String {
        let mut out = String::new();
        if self.station == StationKind::X20bc0087 {
            out.push_str(
                "X20BC0087 station: each module's data by byte index (function model 254), as its module table at \
                 0xA000 must say
",
            );
            out.push_str(&format!(
                "{:>4}  {:<10} {:<10} {:<7} {:>10} {:>11} {:>11} {:>12}\n",
                "slot", "module", "type", "ID", "analog in", "analog out", "digital in", "digital out"
            ));
            let show =
                |d: Option<(u16, u16)>| d.map_or("-".to_string(), |(index, bytes)| format!("{index} ({bytes} B)"));
            for d in &self.modules {
                let m = &map.modules[d.module];
                let id = m.id.map_or("?".to_string(), |id| format!("{id:#06X}"));
                out.push_str(&format!(
                    "{:>4}  {:<10} {:<10} {:<7} {:>10} {:>11} {:>11} {:>12}\n",
                    m.slot,
                    m.name,
                    m.ty.name,
                    id,
                    show(d.analog_in),
                    show(d.analog_out),
                    show(d.digital_in),
                    show(d.digital_out)
                ));
            }
            out.push('\n');
        }
        out.push_str(&self.describe(map));
        let [coils, discrete, input, holding] = self.sizes();
        out.push_str(&format!(
            "{}: {coils} coils, {discrete} discrete inputs, {input} input registers, {holding} holding registers",
            map.origin
        ));
        match self.station {
            StationKind::X20bc0087 => out.push_str(&format!(
                " (from {:#06X})\nno packed process image on an X20BC0087: --exchange tables; on a serial line the \
                 generic layout applies\n",
                self.holding_base
            )),
            StationKind::Generic => {
                let image = ImageLayout::of(self.sizes());
                out.push_str(&format!(
                    "\npacked process image (holding registers): inputs at {INPUT_IMAGE} ({} packed discrete inputs + \
                     {input}), outputs at {OUTPUT_IMAGE} ({} packed coils + {holding})\n",
                    image.input_bits, image.output_bits,
                ));
            }
        }
        out
    }

    /// The map as a table for people: module, slot, channel, type, table, address.
    pub fn describe(&self, map: &IoMap) -> String {
        let mut out = format!(
            "{:<10} {:>4}  {:<24} {:<5} {:<17} {:>7}\n",
            "module", "slot", "channel", "type", "table", "address"
        );
        for e in &self.entries {
            let m = &map.modules[e.module];
            let first = self.wire_address(e);
            let address = if e.count == 1 {
                first.to_string()
            } else {
                format!("{}–{}", first, first + e.count - 1)
            };
            out.push_str(&format!(
                "{:<10} {:>4}  {:<24} {:<5} {:<17} {:>7}\n",
                m.name,
                m.slot,
                m.ty.channels[e.channel].name,
                e.ty.to_string(),
                e.table.to_string(),
                address
            ));
        }
        out
    }
}

/// First holding register of the packed input image (read with function code 3 or 23).
pub const INPUT_IMAGE: u16 = 0x1000;
/// First holding register of the packed output image (written with function code 16 or 23).
pub const OUTPUT_IMAGE: u16 = 0x2000;
/// The most registers one read/write-multiple-registers request (function code 23) may read.
pub const MAX_IMAGE_READ: u16 = 125;
/// The most registers one read/write-multiple-registers request (function code 23) may write.
pub const MAX_IMAGE_WRITE: u16 = 121;

/// The packed process image: the station's inputs and outputs mirrored into two blocks of
/// holding registers, so that a single read/write-multiple-registers transaction (function
/// code 23) exchanges everything. Each block holds its bits first, packed 16 to a register
/// (bit *i* of the block's register *k* is bit 16*k*+*i* of the table, least significant bit
/// first), then its registers in table order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageLayout {
    /// Registers holding the packed discrete inputs (the input image starts with them).
    pub input_bits: u16,
    /// Length of the input image: packed discrete inputs, then the input registers.
    pub input_len: u16,
    /// Registers holding the packed coils (the output image starts with them).
    pub output_bits: u16,
    /// Length of the output image: packed coils, then the holding registers.
    pub output_len: u16,
}

impl ImageLayout {
    /// The layout for table sizes `[coils, discrete inputs, input registers, holding registers]`.
    pub fn of(sizes: [u16; 4]) -> ImageLayout {
        let [coils, discrete, input, holding] = sizes;
        let input_bits = discrete.div_ceil(16);
        let output_bits = coils.div_ceil(16);
        ImageLayout {
            input_bits,
            input_len: input_bits + input,
            output_bits,
            output_len: output_bits + holding,
        }
    }

    /// Whether one function-code-23 transaction can carry both images.
    pub fn fits_one_transaction(&self) -> bool {
        (1..=MAX_IMAGE_READ).contains(&self.input_len) && (1..=MAX_IMAGE_WRITE).contains(&self.output_len)
    }
}

/// Packs bits 16 to a register, least significant bit first.
pub fn pack_bits(bits: &[bool], out: &mut [u16]) {
    out.fill(0);
    for (i, _) in bits.iter().enumerate().filter(|(_, b)| **b) {
        out[i / 16] |= 1 << (i % 16);
    }
}

/// Bit `i` of registers packed by [`pack_bits`].
pub fn packed_bit(words: &[u16], i: usize) -> bool {
    words.get(i / 16).is_some_and(|w| w & (1 << (i % 16)) != 0)
}

/// Encodes a numeric value into registers (1 or 2; high word first).
pub fn encode(v: Value, out: &mut [u16]) {
    match v {
        Value::Bool(b) => out[0] = u16::from(b),
        Value::Int(i) => out[0] = i as u16,
        Value::Uint(u) => out[0] = u,
        Value::Dint(d) => {
            let u = d as u32;
            out[0] = (u >> 16) as u16;
            out[1] = u as u16;
        }
        Value::Real(x) => {
            let u = (x as f32).to_bits();
            out[0] = (u >> 16) as u16;
            out[1] = u as u16;
        }
    }
}

/// Decodes registers (1 or 2; high word first) into a value of type `ty`.
pub fn decode(ty: VarType, words: &[u16]) -> Value {
    let pair = || (u32::from(words[0]) << 16) | u32::from(words[1]);
    match ty {
        VarType::Bool => Value::Bool(words[0] != 0),
        VarType::Int => Value::Int(words[0] as i16),
        VarType::Uint => Value::Uint(words[0]),
        VarType::Dint => Value::Dint(pair() as i32),
        VarType::Real => Value::Real(f64::from(f32::from_bits(pair()))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodings_round_trip() {
        for v in [
            Value::Int(-32768),
            Value::Int(32767),
            Value::Uint(65535),
            Value::Dint(-2),
            Value::Dint(i32::MAX),
            Value::Bool(true),
        ] {
            let mut w = [0u16; 2];
            encode(v, &mut w);
            assert_eq!(decode(v.ty(), &w), v);
        }
        let mut w = [0u16; 2];
        encode(Value::Real(-0.25), &mut w);
        assert_eq!(w, [0xBE80, 0x0000], "IEEE-754 single, high word first");
        assert_eq!(decode(VarType::Real, &w), Value::Real(-0.25));
        encode(Value::Dint(0x1234_5678), &mut w);
        assert_eq!(w, [0x1234, 0x5678]);
    }

    #[test]
    fn bits_pack_sixteen_to_a_register_lsb_first() {
        let mut bits = vec![false; 18];
        bits[0] = true;
        bits[15] = true;
        bits[17] = true;
        let mut words = [0xFFFF; 2];
        pack_bits(&bits, &mut words);
        assert_eq!(words, [0x8001, 0x0002]);
        let back: Vec<bool> = (0..18).map(|i| packed_bit(&words, i)).collect();
        assert_eq!(back, bits);
        assert!(!packed_bit(&words, 40), "beyond the image reads false");
    }

    #[test]
    fn image_layout_of_the_trijoint_station() {
        // 18 coils, 18 discrete inputs, 2 input registers, 3 holding registers.
        let layout = ImageLayout::of([18, 18, 2, 3]);
        assert_eq!(
            layout,
            ImageLayout {
                input_bits: 2,
                input_len: 4,
                output_bits: 2,
                output_len: 5
            }
        );
        assert!(layout.fits_one_transaction());
        assert!(!ImageLayout::of([0, 0, 126, 1]).fits_one_transaction());
        assert!(
            !ImageLayout::of([0, 1, 0, 0]).fits_one_transaction(),
            "nothing to write"
        );
    }
}
