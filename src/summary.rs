//! The run summary: what `pkm-plc run --summary FILE` writes and what the end of a run logs.

use serde::Serialize;

use crate::plc::Plc;
use crate::stats::StatSummary;

/// The whole summary of a run.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// `virtual` or `real-time`.
    pub mode: &'static str,
    /// The time source (real time only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_source: Option<&'static str>,
    /// Whether the cyclic thread had SCHED_FIFO (real time only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub realtime_priority: Option<bool>,
    /// The configuration file.
    pub config: String,
    /// The bus.
    pub bus: String,
    /// Time covered by the schedule, in seconds (simulated in virtual time).
    pub duration_s: f64,
    /// Per task class, in configuration order.
    pub task_classes: Vec<ClassSummary>,
    /// The main program's final state, if a program reports one.
    pub main: Option<MainSummary>,
}

/// One task class's figures.
#[derive(Clone, Debug, Serialize)]
pub struct ClassSummary {
    /// Its name.
    pub name: String,
    /// Its cycle time (µs).
    pub cycle_us: u64,
    /// Its tolerance (µs).
    pub tolerance_us: u64,
    /// Cycles run.
    pub cycles: u64,
    /// Releases skipped after long overruns.
    pub missed: u64,
    /// Cycles that ended after their deadline.
    pub overruns: u64,
    /// Overruns beyond the tolerance.
    pub violations: u64,
    /// Execution time (µs).
    pub exec_us: StatSummary,
    /// Start lateness (µs).
    pub lateness_us: StatSummary,
}

/// The main program's final state.
#[derive(Clone, Debug, Serialize)]
pub struct MainSummary {
    /// The program reporting it.
    pub program: String,
    /// Its state.
    pub state: String,
    /// Why it is in its error state, if it is.
    pub error_reason: Option<String>,
    /// Its note to the operator at the end of the run (what INIT waits for), if it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The values it shows with its state at the end of the run (positions: the tool pose and
    /// the joints), by name; a value it could not compute is null.
    pub values: serde_json::Map<String, serde_json::Value>,
}

impl Summary {
    /// Collects the summary from a PLC at the end of a run.
    pub fn collect(plc: &Plc, mode: &'static str, config: &str, duration_ns: u64) -> Summary {
        let task_classes = plc
            .classes()
            .map(|c| ClassSummary {
                name: c.name.to_string(),
                cycle_us: c.period_ns / 1000,
                tolerance_us: c.tolerance_ns / 1000,
                cycles: c.stats.cycles,
                missed: c.stats.missed,
                overruns: c.stats.overruns,
                violations: c.stats.violations,
                exec_us: c.stats.exec.summary_us(),
                lateness_us: c.stats.lateness.summary_us(),
            })
            .collect();
        let main = plc.app_status().map(|s| MainSummary {
            program: plc.app_program().unwrap_or_default().to_string(),
            state: s.state.to_string(),
            error_reason: s.reason.map(str::to_string),
            note: s.note.map(str::to_string),
            values: s
                .values
                .iter()
                .map(|(name, v)| {
                    (
                        name.to_string(),
                        serde_json::Number::from_f64(*v).map_or(serde_json::Value::Null, Into::into),
                    )
                })
                .collect(),
        });
        Summary {
            mode,
            time_source: None,
            realtime_priority: None,
            config: config.to_string(),
            bus: plc.bus_name().to_string(),
            duration_s: duration_ns as f64 / 1e9,
            task_classes,
            main,
        }
    }

    /// The summary as pretty JSON.
    pub fn to_json(&self) -> String {
        // Serializing plain structs of strings and numbers cannot fail.
        serde_json::to_string_pretty(self).unwrap_or_else(|e| panic!("summary serialization: {e}"))
    }

    /// Human-readable lines, one per task class plus the main state.
    pub fn lines(&self) -> Vec<String> {
        let mut lines: Vec<String> = self
            .task_classes
            .iter()
            .map(|c| {
                format!(
                    "task class {:<8} {:>6} µs: {} cycles, lateness p50/p99/max {:.1}/{:.1}/{:.1} µs, \
                     exec mean/max {:.1}/{:.1} µs, {} overruns, {} violations, {} missed",
                    c.name,
                    c.cycle_us,
                    c.cycles,
                    c.lateness_us.p50,
                    c.lateness_us.p99,
                    c.lateness_us.max,
                    c.exec_us.mean,
                    c.exec_us.max,
                    c.overruns,
                    c.violations,
                    c.missed
                )
            })
            .collect();
        if let Some(m) = &self.main {
            match &m.error_reason {
                Some(r) => lines.push(format!("final state {} ({}): {r}", m.state, m.program)),
                None => lines.push(format!("final state {} ({})", m.state, m.program)),
            }
            if let Some(note) = &m.note {
                lines.push(format!("final note: {note}"));
            }
            if !m.values.is_empty() {
                let values: Vec<String> = m
                    .values
                    .iter()
                    .map(|(k, v)| match v.as_f64() {
                        Some(x) => format!("{k}={x:.3}"),
                        None => format!("{k}=-"),
                    })
                    .collect();
                lines.push(format!("final values {}", values.join(" ")));
            }
        }
        lines
    }
}
