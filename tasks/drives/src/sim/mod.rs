//! Simulated drives, the parts the machines' simulated plants are built from.

pub mod stepper;
