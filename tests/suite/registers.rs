//! The Modbus register map derived from the I/O map, and its value encodings.

use crate::common;

use common::{pkm, stderr, stdout};
use pkm_plc::image::{Value, VarType};
use pkm_plc::services::io::map::{IoMap, StationKind};
use pkm_plc::services::io::registers::{RegisterMap, Table, decode, encode};
use proptest::prelude::*;

fn map(text: &str) -> IoMap {
    IoMap::parse(text, "map.json", &["fast".into(), "main".into()]).expect("valid map")
}

fn default_map() -> IoMap {
    map(&std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/io-map/trijoint.json")).expect("map"))
}

/// (module, channel) → (table, address, count).
fn find(m: &IoMap, r: &RegisterMap, module: &str, channel: &str) -> (Table, u16, u16) {
    let e = r
        .entries
        .iter()
        .find(|e| m.modules[e.module].name == module && m.modules[e.module].ty.channels[e.channel].name == channel)
        .unwrap_or_else(|| panic!("{module}.{channel} not in the register map"));
    (e.table, e.address, e.count)
}

#[test]
fn a_stepper_module_has_its_enables_as_coils_its_set_points_as_holding_and_its_counters_as_input_registers() {
    let m = map(
        r#"{"modules": [{"name": "SM", "type": "X20SM2436", "slot": 1}, {"name": "SM2", "type": "X20SM2436", "slot": 2}],
            "bindings": [{"variable": "steps_3", "module": "SM2", "channel": "StepCounter01", "task_class": "fast"}]}"#,
    );
    let r = RegisterMap::of(&m);
    assert_eq!(find(&m, &r, "SM", "Enable02"), (Table::Coil, 1, 1));
    assert_eq!(find(&m, &r, "SM", "SpeedSetpoint02"), (Table::HoldingRegister, 1, 1));
    assert_eq!(find(&m, &r, "SM", "StepCounter02"), (Table::InputRegister, 1, 1));
    assert_eq!(find(&m, &r, "SM2", "StepCounter01"), (Table::InputRegister, 2, 1));
    assert_eq!(
        r.sizes(),
        [4, 0, 4, 4],
        "coils, discrete inputs, input registers, holding registers"
    );
}

#[test]
fn the_trijoint_modules_on_a_generic_station() {
    let m = default_map();
    // What a serial line's station serves, and io-sim with "station": "generic".
    let r = RegisterMap::laid_out(&m, StationKind::Generic);
    assert_eq!(
        find(&m, &r, "DI", "DigitalInput01"),
        (Table::DiscreteInput, 0, 1),
        "BUTTON_STOP"
    );
    assert_eq!(
        find(&m, &r, "DI", "DigitalInput06"),
        (Table::DiscreteInput, 5, 1),
        "SWITCH_LEFT_UPPER"
    );
    assert_eq!(find(&m, &r, "DC_LEFT", "Counter01"), (Table::InputRegister, 0, 1));
    assert_eq!(find(&m, &r, "DC_RIGHT", "Counter01"), (Table::InputRegister, 1, 1));
    assert_eq!(find(&m, &r, "DC_RIGHT", "CounterReset01"), (Table::Coil, 13, 1));
    assert_eq!(
        find(&m, &r, "MM", "PeriodDurationPWM01"),
        (Table::HoldingRegister, 0, 1)
    );
    assert_eq!(
        find(&m, &r, "MM", "PulseWidthCurrentPWM02"),
        (Table::HoldingRegister, 2, 1),
        "velocity_left_set"
    );
    assert_eq!(find(&m, &r, "MM", "Error02"), (Table::DiscreteInput, 17, 1));
    assert_eq!(
        r.sizes(),
        [18, 18, 2, 3],
        "coils, discrete inputs, input registers, holding registers"
    );
    assert!(
        !r.entries.iter().any(|e| m.modules[e.module].name == "JOY"),
        "the HID joystick is not on the field bus"
    );
}

#[test]
fn the_lab_station_behind_its_x20bc0087() {
    let m = default_map();
    assert_eq!(m.station, StationKind::X20bc0087);
    let r = RegisterMap::of(&m);
    assert_eq!(
        find(&m, &r, "DI", "DigitalInput06"),
        (Table::DiscreteInput, 5, 1),
        "SWITCH_LEFT_UPPER"
    );
    // The MM's digital inputs start on byte 2 of the digital input image: bit 16.
    assert_eq!(
        find(&m, &r, "MM", "Error02"),
        (Table::DiscreteInput, 21, 1),
        "bridge_error_left"
    );
    assert_eq!(find(&m, &r, "DC_LEFT", "Counter01"), (Table::InputRegister, 0, 1));
    assert_eq!(find(&m, &r, "DC_RIGHT", "Counter01"), (Table::InputRegister, 1, 1));
    // Digital outputs: the DO's 12 bits in bytes 0–1, each counter's reset in a byte of its own.
    assert_eq!(find(&m, &r, "DC_LEFT", "CounterReset01"), (Table::Coil, 16, 1));
    assert_eq!(find(&m, &r, "DC_RIGHT", "CounterReset01"), (Table::Coil, 24, 1));
    assert_eq!(
        find(&m, &r, "MM", "ClearError02"),
        (Table::Coil, 33, 1),
        "clear_error_left"
    );
    let pwm = r
        .entries
        .iter()
        .find(|e| {
            m.modules[e.module].name == "MM"
                && m.modules[e.module].ty.channels[e.channel].name == "PulseWidthCurrentPWM02"
        })
        .expect("velocity_left_set");
    assert_eq!(r.wire_address(pwm), 0x0802, "holding registers from 0x0800");
    assert_eq!(
        r.sizes(),
        [36, 22, 2, 3],
        "coils, discrete inputs, input registers, holding registers"
    );
}

#[test]
fn registers_follow_slots_not_bindings_or_file_order() {
    let a = map(
        r#"{"modules": [{"name": "A", "type": "X20DI9371", "slot": 1}, {"name": "B", "type": "X20DC1196", "slot": 2}, {"name": "C", "type": "X20DC1196", "slot": 3}],
            "bindings": [{"module": "B", "channel": "Counter01", "variable": "x", "task_class": "fast"}]}"#,
    );
    let b = map(
        r#"{"modules": [{"name": "C", "type": "X20DC1196", "slot": 3}, {"name": "A", "type": "X20DI9371", "slot": 1}, {"name": "B", "type": "X20DC1196", "slot": 2}],
            "bindings": []}"#,
    );
    let (ra, rb) = (RegisterMap::of(&a), RegisterMap::of(&b));
    for (module, channel) in [
        ("A", "DigitalInput12"),
        ("B", "Counter01"),
        ("C", "Counter01"),
        ("C", "CounterReset01"),
    ] {
        assert_eq!(
            find(&a, &ra, module, channel),
            find(&b, &rb, module, channel),
            "{module}.{channel}"
        );
    }
    assert_eq!(find(&a, &ra, "C", "Counter01"), (Table::InputRegister, 1, 1));
}

proptest! {
    #[test]
    fn integer_encodings_round_trip(i in any::<i16>(), u in any::<u16>(), d in any::<i32>(), b in any::<bool>()) {
        for v in [Value::Int(i), Value::Uint(u), Value::Dint(d), Value::Bool(b)] {
            let mut w = [0u16; 2];
            encode(v, &mut w);
            prop_assert_eq!(decode(v.ty(), &w), v);
        }
    }

    #[test]
    fn reals_travel_as_ieee_singles(x in -1e30f64..1e30) {
        let mut w = [0u16; 2];
        encode(Value::Real(x), &mut w);
        prop_assert_eq!(decode(VarType::Real, &w), Value::Real(f64::from(x as f32)));
        prop_assert_eq!((u32::from(w[0]) << 16) | u32::from(w[1]), (x as f32).to_bits());
    }
}

#[test]
fn the_registers_command_prints_the_map() {
    let o = pkm(&["registers"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(
        out.contains("   5  MM         X20MM2436  ?                -     0 (6 B)     2 (1 B)      4 (1 B)\n"),
        "{out}"
    );
    assert!(
        out.contains("MM            5  PulseWidthCurrentPWM02   INT   holding register     2050\n"),
        "{out}"
    );
    assert!(
        out.ends_with(
            "io-map/trijoint.json: 36 coils, 22 discrete inputs, 2 input registers, 3 holding registers (from 0x0800)\n\
             no packed process image on an X20BC0087: --exchange tables; on a serial line the generic layout applies\n"
        ),
        "{out}"
    );
    let o = pkm(&["registers", "--machine", "ox-x"]);
    assert!(
        stdout(&o).ends_with(
            "packed process image (holding registers): inputs at 4096 (2 packed discrete inputs + 4), outputs at 8192 \
             (1 packed coils + 4)\n"
        ),
        "{}",
        stdout(&o)
    );
}

proptest! {
    /// Packing bits into the image's registers and reading them back is lossless.
    #[test]
    fn packed_bits_round_trip(bits in proptest::collection::vec(any::<bool>(), 0..300)) {
        let mut words = vec![0u16; bits.len().div_ceil(16)];
        pkm_plc::services::io::registers::pack_bits(&bits, &mut words);
        for (i, b) in bits.iter().enumerate() {
            prop_assert_eq!(pkm_plc::services::io::registers::packed_bit(&words, i), *b);
        }
    }
}
