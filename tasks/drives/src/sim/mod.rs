//! Simulated drives, the parts the machines' simulated plants are built from.

pub mod dc;
pub mod stepper;
