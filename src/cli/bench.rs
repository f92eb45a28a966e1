//! `pkm-plc bench`: the time sources measured side by side on this machine.
//!
//! Each row runs the real scheduler with one task class (an empty program) for the given time,
//! first with normal scheduling and then with SCHED_FIFO, and reports start lateness and
//! execution time. Rows run one after another so they do not disturb each other.

use serde::Serialize;

use super::args::BenchArgs;
use super::{Failure, OutputFile};
use pkm_plc::compose::selftest;
use pkm_plc::program::Registry;
use pkm_plc::runtime::bus::NoBus;
use pkm_plc::runtime::config;
use pkm_plc::runtime::config::{Config, ProgramEntry, Reaction, TaskClassConfig, TimeSourceKind, TimingConfig};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::{RealTimeOptions, RunError, start_realtime};
use pkm_plc::runtime::stats::StatSummary;
use tracing::info;

/// What to measure.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Seconds per row.
    pub seconds: f64,
    /// The task class's cycle time (µs).
    pub cycle_us: u32,
    /// The sources to measure.
    pub sources: Vec<TimeSourceKind>,
    /// SCHED_FIFO priority for the real-time rows; 0 skips them.
    pub realtime_priority: u8,
    /// If not 0, each source is measured again with this spin margin (µs).
    pub spin_us: u32,
}

/// One measured row.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRow {
    /// The time source.
    pub source: &'static str,
    /// `normal` or `SCHED_FIFO`.
    pub scheduling: &'static str,
    /// Spin margin before each release (µs).
    pub spin_us: u32,
    /// False when SCHED_FIFO was asked for but refused (the row then ran with normal scheduling).
    pub priority_granted: bool,
    /// Cycles measured.
    pub cycles: u64,
    /// Start lateness (µs).
    pub lateness_us: StatSummary,
    /// Execution time of the (empty) cycle (µs).
    pub exec_us: StatSummary,
    /// Cycles that ended after their deadline.
    pub overruns: u64,
}

/// Runs the benchmark, calling `progress` before each row.
pub fn run(options: &BenchOptions, mut progress: impl FnMut(&str)) -> Result<Vec<BenchRow>, RunError> {
    let mut registry = Registry::new();
    selftest::register(&mut registry);
    let config = Config {
        machine: None,
        task_classes: vec![TaskClassConfig {
            name: "bench".into(),
            cycle_us: options.cycle_us,
            tolerance_us: options.cycle_us,
            priority: 1,
            on_violation: Reaction::Log,
            programs: vec![ProgramEntry {
                program: "selftest.idle".into(),
                params: None,
            }],
        }],
        timing: TimingConfig::default(),
        kinematics: None,
        io_map: None,
        plant: Default::default(),
        joystick: Default::default(),
        nc: Default::default(),
        identification: Default::default(),
    };
    let mut rows = Vec::new();
    let fifo_modes: &[bool] = if options.realtime_priority > 0 {
        &[false, true]
    } else {
        &[false]
    };
    let spins: &[u32] = if options.spin_us > 0 {
        &[0, options.spin_us]
    } else {
        &[0]
    };
    for &source in &options.sources {
        for (&spin_us, &fifo) in spins.iter().flat_map(|s| fifo_modes.iter().map(move |f| (s, f))) {
            let scheduling = if fifo { "SCHED_FIFO" } else { "normal" };
            progress(&format!(
                "{} / {scheduling} / spin {spin_us} µs: {} s",
                source.name(),
                options.seconds
            ));
            let plc = match Plc::build(&config, &registry, Box::new(NoBus)) {
                Ok(p) => p,
                Err(issues) => panic!("the built-in benchmark configuration is valid: {issues:?}"),
            };
            let run = start_realtime(
                plc,
                RealTimeOptions {
                    source,
                    realtime_priority: if fifo { options.realtime_priority } else { 0 },
                    lock_memory: false,
                    spin_ns: u64::from(spin_us) * 1000,
                    duration_ns: Some((options.seconds * 1e9) as u64),
                    pace: None,
                },
            )?;
            let outcome = run.join()?;
            let class = outcome
                .plc
                .classes()
                .next()
                .map(|c| c.stats.clone())
                .unwrap_or_default();
            rows.push(BenchRow {
                source: source.name(),
                scheduling,
                spin_us,
                priority_granted: !fifo || outcome.realtime_priority,
                cycles: class.cycles,
                lateness_us: class.lateness.summary_us(),
                exec_us: class.exec.summary_us(),
                overruns: class.overruns,
            });
        }
    }
    Ok(rows)
}

/// The rows as a text table.
pub fn table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<10} {:<11} {:>6} {:>7} {:>10} {:>10} {:>10} {:>10} {:>9}\n",
        "source", "scheduling", "spin", "cycles", "late p50", "late p99", "late max", "exec mean", "overruns"
    );
    for r in rows {
        let sched = if r.priority_granted {
            r.scheduling.to_string()
        } else {
            format!("{}*", r.scheduling)
        };
        out.push_str(&format!(
            "{:<10} {:<11} {:>4}µs {:>7} {:>8.1}µs {:>8.1}µs {:>8.1}µs {:>8.1}µs {:>9}\n",
            r.source,
            sched,
            r.spin_us,
            r.cycles,
            r.lateness_us.p50,
            r.lateness_us.p99,
            r.lateness_us.max,
            r.exec_us.mean,
            r.overruns
        ));
    }
    if rows.iter().any(|r| !r.priority_granted) {
        out.push_str("* SCHED_FIFO was refused: that row ran with normal scheduling\n");
    }
    out
}

/// The `bench` subcommand: runs it as `args` ask and prints its report.
pub fn command(args: BenchArgs) -> Result<(), Failure> {
    let options = BenchOptions {
        seconds: args.seconds,
        cycle_us: args.cycle_us,
        sources: args
            .sources
            .iter()
            .map(|s| TimeSourceKind::from(*s).resolve())
            .collect(),
        realtime_priority: args.realtime_priority,
        spin_us: args.spin_us,
    };
    if !(config::MIN_CYCLE_US..=config::MAX_CYCLE_US).contains(&options.cycle_us) {
        return Err(Failure::usage(format!(
            "--cycle-us must be between {} and {}",
            config::MIN_CYCLE_US,
            config::MAX_CYCLE_US
        )));
    }
    let json_file = args.json.as_deref().map(OutputFile::create).transpose()?;
    let rows = run(&options, |row| info!("measuring {row}")).map_err(|e| Failure::run(e.to_string()))?;
    print!("{}", table(&rows));
    if let Some(file) = json_file {
        let json = serde_json::to_string_pretty(&rows).map_err(|e| Failure::run(e.to_string()))?;
        file.write(&json)?;
    }
    Ok(())
}
