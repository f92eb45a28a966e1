//! pkm-plc: a soft-PLC for parallel-kinematic machine models.
//!
//! The runtime (this crate's `src/`) is the counterpart of B&R Automation Runtime: task classes,
//! the process image, buses, time, cycle monitoring, configuration and the command line. It knows
//! no machine; application programs plug in through [`program::Program`].

pub mod bench;
pub mod bus;
pub mod config;
pub mod files;
pub mod image;
pub mod io;
pub mod link_bench;
pub mod plc;
pub mod program;
pub mod run;
pub mod selftest;
pub mod signals;
pub mod sim;
pub mod stats;
pub mod status;
pub mod strict_json;
pub mod summary;
pub mod timing;
pub mod trace;

/// The application programs and machine models (the `tasks/` directory).
#[path = "../tasks/mod.rs"]
pub mod tasks;

/// Parses and checks the application's sections of a configuration (the kinematic parameters);
/// problems are reported with their JSON paths like the runtime's own.
pub fn application_config(
    config: &config::Config,
) -> Result<tasks::kinematics::KinematicsConfig, Vec<image::DeclIssue>> {
    let kinematics = match &config.kinematics {
        None => tasks::kinematics::KinematicsConfig::default(),
        Some(v) => strict_json::from_value(v).map_err(|e| {
            let inner = e.path().to_string();
            let at = if inner == "." {
                "kinematics".to_string()
            } else {
                format!("kinematics.{inner}")
            };
            vec![image::DeclIssue {
                at,
                message: e.into_inner().to_string(),
            }]
        })?,
    };
    let problems: Vec<image::DeclIssue> = kinematics
        .check()
        .into_iter()
        .map(|(at, message)| image::DeclIssue {
            at: format!("kinematics.{at}"),
            message,
        })
        .collect();
    if problems.is_empty() {
        Ok(kinematics)
    } else {
        Err(problems)
    }
}

/// The program types this build knows: the runtime's self-test programs and the TRIJOINT
/// application's.
pub fn registry() -> program::Registry {
    let mut registry = program::Registry::new();
    selftest::register(&mut registry);
    tasks::trijoint::register(&mut registry);
    registry
}
