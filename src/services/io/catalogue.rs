//! The module catalogue: X20-like I/O modules and their channels, as in the original I/O mapping
//! table, an X20-like stepper module for the stepper-driven machines (pn101, O-X glide), plus the
//! operator's joystick (an HID device on the real machine).

pub use crate::image::Direction;
use crate::image::VarType;

/// One channel of a module type.
#[derive(Clone, Copy, Debug)]
pub struct Channel {
    /// The channel's name (B&R spelling).
    pub name: &'static str,
    /// Its direction.
    pub direction: Direction,
    /// Its type.
    pub ty: VarType,
}

/// A module type.
#[derive(Clone, Copy, Debug)]
pub struct ModuleType {
    /// The order number (X20DI9371, ...).
    pub name: &'static str,
    /// What it is.
    pub description: &'static str,
    /// Its channels.
    pub channels: &'static [Channel],
    /// Whether it sits on the field bus (and so in the Modbus register map); the joystick does not.
    pub field_bus: bool,
    /// The module's hardware ID (the data sheet's "B&R ID code"), which an X20 bus controller
    /// reports in its module table; `None` where no public source this project could read gives
    /// it (the I/O map then says it: `"id"`, as `station scan` reads it from the station).
    pub hardware_id: Option<u16>,
}

impl ModuleType {
    /// Looks a channel up by name.
    pub fn channel(&self, name: &str) -> Option<(usize, &Channel)> {
        self.channels.iter().enumerate().find(|(_, c)| c.name == name)
    }
}

const fn ch(name: &'static str, direction: Direction, ty: VarType) -> Channel {
    Channel { name, direction, ty }
}

use Direction::{Input as I, Output as O};
use VarType::{Bool as B, Int, Real, Uint};

const DI9371: &[Channel] = &[
    ch("DigitalInput01", I, B),
    ch("DigitalInput02", I, B),
    ch("DigitalInput03", I, B),
    ch("DigitalInput04", I, B),
    ch("DigitalInput05", I, B),
    ch("DigitalInput06", I, B),
    ch("DigitalInput07", I, B),
    ch("DigitalInput08", I, B),
    ch("DigitalInput09", I, B),
    ch("DigitalInput10", I, B),
    ch("DigitalInput11", I, B),
    ch("DigitalInput12", I, B),
];

const DO9322: &[Channel] = &[
    ch("DigitalOutput01", O, B),
    ch("DigitalOutput02", O, B),
    ch("DigitalOutput03", O, B),
    ch("DigitalOutput04", O, B),
    ch("DigitalOutput05", O, B),
    ch("DigitalOutput06", O, B),
    ch("DigitalOutput07", O, B),
    ch("DigitalOutput08", O, B),
    ch("DigitalOutput09", O, B),
    ch("DigitalOutput10", O, B),
    ch("DigitalOutput11", O, B),
    ch("DigitalOutput12", O, B),
];

const DC1196: &[Channel] = &[ch("Counter01", I, Int), ch("CounterReset01", O, B)];

const MM2436: &[Channel] = &[
    ch("PeriodDurationPWM01", O, Uint),
    ch("PulseWidthCurrentPWM01", O, Int),
    ch("PulseWidthCurrentPWM02", O, Int),
    ch("ClearError01", O, B),
    ch("ClearError02", O, B),
    ch("DitherDisable01", O, B),
    ch("DitherDisable02", O, B),
    ch("StatusInput01", I, B),
    ch("StatusInput02", I, B),
    ch("StatusInput03", I, B),
    ch("StatusInput04", I, B),
    ch("Error01", I, B),
    ch("Error02", I, B),
];

const SM2436: &[Channel] = &[
    ch("Enable01", O, B),
    ch("SpeedSetpoint01", O, Int),
    ch("StepCounter01", I, Int),
    ch("Enable02", O, B),
    ch("SpeedSetpoint02", O, Int),
    ch("StepCounter02", I, Int),
];

const JOYSTICK: &[Channel] = &[
    ch("AxisX", I, Real),
    ch("AxisY", I, Real),
    ch("Stop", I, B),
    ch("Button01", I, B),
    ch("Button02", I, B),
    ch("Button03", I, B),
    ch("Button04", I, B),
    ch("Connected", I, B),
];

/// Every module type known.
pub const CATALOGUE: &[ModuleType] = &[
    ModuleType {
        name: "X20DI9371",
        description: "12 digital inputs, 24 V",
        channels: DI9371,
        field_bus: true,
        hardware_id: Some(0x1B95),
    },
    ModuleType {
        name: "X20DO9322",
        description: "12 digital outputs, 24 V / 0.5 A",
        channels: DO9322,
        field_bus: true,
        hardware_id: Some(0x1B9A),
    },
    ModuleType {
        name: "X20DC1196",
        description: "1 ABR incremental counter, 16-bit signed, wraps; counter reset",
        channels: DC1196,
        field_bus: true,
        hardware_id: None,
    },
    ModuleType {
        name: "X20MM2436",
        description: "2 PWM motor bridges 3 A (period µs, signed pulse width ±32767 = ±100 %, clear error, \
                      dither disable), 4 digital inputs, per-bridge error (overcurrent, overtemperature)",
        channels: MM2436,
        field_bus: true,
        hardware_id: None,
    },
    ModuleType {
        name: "X20SM2436",
        description: "X20-like 2-channel stepper module (after B&R's X20SM modules): per channel an enable, \
                      a speed set-point (INT, steps/s) and a 16-bit wrapping counter of the steps emitted",
        channels: SM2436,
        field_bus: true,
        hardware_id: None,
    },
    ModuleType {
        name: "Joystick",
        description: "the operator's joystick: axes −1..1, its STOP button, buttons, connected (HID on the real machine)",
        channels: JOYSTICK,
        field_bus: false,
        hardware_id: None,
    },
];

/// Looks a module type up by name.
pub fn module_type(name: &str) -> Option<&'static ModuleType> {
    CATALOGUE.iter().find(|m| m.name == name)
}

/// Looks a field-bus module type up by its hardware ID (what a bus controller reports).
pub fn by_hardware_id(id: u16) -> Option<&'static ModuleType> {
    CATALOGUE.iter().find(|m| m.hardware_id == Some(id))
}
