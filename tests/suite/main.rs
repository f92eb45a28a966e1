//! The integration tests that need no wire, no real-time schedule and no other process's timing,
//! in one test binary (as ripgrep's `tests/tests.rs`): one link instead of twelve, and one
//! 60 MB executable instead of twelve. The tests that run real time, serial lines, TCP stations,
//! FIFOs or the scheduler's timing keep their own binaries (`tests/*.rs`), so they never share a
//! process with these CPU-bound virtual-time runs.

#[path = "../common/mod.rs"]
mod common;

mod architecture;
mod cli;
mod config_errors;
mod config_ranges;
mod hmi;
mod io_sim_station;
mod joint_machines;
mod joint_machines_soak;
mod joystick;
mod joystick_app;
mod kinematics;
mod nc;
mod nc_bounds;
mod nc_entry_points;
mod nc_jobs;
mod nc_operate;
mod nc_run;
mod planner_properties;
mod registers;
mod simulated_machine;
mod traces;
mod trijoint_app;
mod trijoint_drives;
mod trijoint_soak;
