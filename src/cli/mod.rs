//! The command line: one module per subcommand. Each turns its arguments into the composition's
//! options and reports the outcome; none holds the PLC's logic.

pub mod bench;
pub mod enums;
pub mod kin;
pub mod kin_svg;
pub mod link_bench;
pub mod nc;
pub mod opcua;
pub mod station;
