//! The services the PLC talks through, each in a folder of its own: field I/O ([`io`]: the I/O
//! map, X20-like modules over Modbus TCP or RTU, the joystick), the simulated machine behind an
//! I/O map ([`sim`]), recording, reading, exporting and checking traces ([`trace`]), the
//! operator's web screen ([`hmi`]) and the OPC UA server ([`opcua`]). A service builds on the
//! runtime core and is handed what it needs (a bus, a frame feed, a command sink, a job planner)
//! by the composition; it never builds a PLC itself.

pub mod hmi;
pub mod io;
pub mod opcua;
pub mod sim;
pub mod trace;
