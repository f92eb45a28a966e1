//! The Modbus register map of a station, derived from its I/O map the way a bus coupler maps its
//! modules: every channel of every field-bus module (not the HID joystick), modules in slot order, channels in catalogue order,
//! each kind of data in its own Modbus table. The map depends only on the modules present, not on
//! the bindings, so rebinding a variable never moves a register.
//!
//! Encodings: BOOL inputs are discrete inputs, BOOL outputs coils; INT and UINT take one register
//! (INT as two's complement); DINT two registers, high word first; REAL two registers holding an
//! IEEE-754 single (f32), high word first. Inputs are input registers, outputs holding registers.
//!
//! The same data is also mirrored as a packed process image in two blocks of holding registers
//! ([`ImageLayout`]), so that a slow serial line can exchange everything in one transaction.

use std::fmt;

use super::catalogue::Direction;
use super::map::IoMap;
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
    /// The first address (0-based, as on the wire).
    pub address: u16,
    /// Bits or registers it takes.
    pub count: u16,
    /// The channel's type.
    pub ty: VarType,
}

/// The register map of a station.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RegisterMap {
    /// Every channel, in slot order.
    pub entries: Vec<Entry>,
}

/// How many registers (or bits) a value of `ty` takes.
pub fn width(ty: VarType) -> u16 {
    match ty {
        VarType::Bool | VarType::Int | VarType::Uint => 1,
        VarType::Dint | VarType::Real => 2,
    }
}

impl RegisterMap {
    /// Derives the map from the modules of an I/O map.
    pub fn of(map: &IoMap) -> RegisterMap {
        let mut order: Vec<usize> = (0..map.modules.len())
            .filter(|&m| map.modules[m].ty.field_bus)
            .collect();
        order.sort_by_key(|&m| map.modules[m].slot);
        let mut next = [0u16; 4];
        let mut entries = Vec::new();
        for m in order {
            for (c, ch) in map.modules[m].ty.channels.iter().enumerate() {
                let table = match (ch.ty, ch.direction) {
                    (VarType::Bool, Direction::Input) => Table::DiscreteInput,
                    (VarType::Bool, Direction::Output) => Table::Coil,
                    (_, Direction::Input) => Table::InputRegister,
                    (_, Direction::Output) => Table::HoldingRegister,
                };
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
        RegisterMap { entries }
    }

    /// The number of bits or registers used in each table (coils, discrete inputs, input
    /// registers, holding registers).
    pub fn sizes(&self) -> [u16; 4] {
        let mut sizes = [0u16; 4];
        for e in &self.entries {
            let s = &mut sizes[e.table as usize];
            *s = (*s).max(e.address + e.count);
        }
        sizes
    }

    /// The map as a table for people: module, slot, channel, type, table, address.
    pub fn describe(&self, map: &IoMap) -> String {
        let mut out = format!(
            "{:<10} {:>4}  {:<24} {:<5} {:<17} {:>7}\n",
            "module", "slot", "channel", "type", "table", "address"
        );
        for e in &self.entries {
            let m = &map.modules[e.module];
            let address = if e.count == 1 {
                e.address.to_string()
            } else {
                format!("{}–{}", e.address, e.address + e.count - 1)
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
