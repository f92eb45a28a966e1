//! Field I/O: the module catalogue and I/O map files.

pub mod catalogue;
pub mod map;
