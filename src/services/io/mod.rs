//! Field I/O: the module catalogue, I/O map files and the Modbus register map derived from them.

pub mod catalogue;
pub mod dry;
pub mod hid;
pub mod joystick;
pub mod line;
pub mod map;
pub mod modbus;
pub mod registers;
pub mod rx_counter;
pub mod x20bc0087;
