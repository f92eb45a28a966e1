//! The run summary: what `pkm-plc run --summary FILE` writes and what the end of a run logs.

use serde::Serialize;

use pkm_api::library::NcLibrary;

use crate::image::Value;
use crate::runtime::plc::Plc;
use crate::runtime::stats::StatSummary;

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
    /// The NC program's last run, if one was loaded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub program: Option<ProgramSummary>,
}

/// The NC program's last run (docs/nc.md, Running), from the executor's process-image
/// variables: what a trace replays, the summary of its replay shows too.
#[derive(Clone, Debug, Serialize)]
pub struct ProgramSummary {
    /// The program's file.
    pub file: String,
    /// The run reached the program's end.
    pub completed: bool,
    /// How long the run lasted, holds and pauses included (s).
    pub duration_s: f64,
    /// The programmed path's length (mm).
    pub path_length_mm: f64,
    /// The planned duration (s), without holds and pauses.
    pub planned_s: f64,
    /// The distance from the measured tool point to the programmed path (mm).
    pub contour_error_mm: ContourError,
    /// The largest following error per joint (mm).
    pub max_following_error_mm: Vec<f64>,
}

/// The contour error's largest and RMS value (mm).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ContourError {
    /// The largest.
    pub max: f64,
    /// The root mean square over the run's fast cycles.
    pub rms: f64,
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
            error_reason: plc.error_reason(),
            note: s.note.map(str::to_string),
            values: s
                .values
                .iter()
                .map(|(name, v)| {
                    // A program line is a whole number.
                    let value = if *name == "line" && v.is_finite() {
                        serde_json::Value::from(*v as i64)
                    } else {
                        serde_json::Number::from_f64(*v).map_or(serde_json::Value::Null, Into::into)
                    };
                    (name.to_string(), value)
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
            program: None,
        }
    }

    /// Adds the loaded NC program's last run, as `plc`'s executor measured it (nothing without
    /// a program).
    pub fn with_program(mut self, plc: &Plc, library: Option<&NcLibrary>) -> Summary {
        use pkm_api::trajectory::vars;
        let value = |name: &str| plc.last_written(name);
        let loaded = match value(vars::NC_PROGRAM.name()) {
            Some(Value::Int(k)) => k,
            _ => 1,
        };
        let Some(library) = library else {
            return self;
        };
        let Some(job) = library.numbered(loaded) else {
            return self;
        };
        let real = |name: &str| match value(name) {
            Some(Value::Real(v)) => v,
            _ => 0.0,
        };
        // A program only offered to the screen, never started, has nothing to report (loading
        // a program clears the last run's figures).
        if !library.autostart && real(vars::NC_RUN_S.name()) == 0.0 {
            return self;
        }
        let n = job.trajectory.dof();
        self.program = Some(ProgramSummary {
            file: job.file.clone(),
            completed: value(vars::NC_COMPLETED.name()) == Some(Value::Bool(true)),
            duration_s: real(vars::NC_RUN_S.name()),
            path_length_mm: job.trajectory.length_mm(),
            planned_s: job.trajectory.duration_s(),
            contour_error_mm: ContourError {
                max: real(vars::NC_CONTOUR_MAX.name()),
                rms: real(vars::NC_CONTOUR_RMS.name()),
            },
            max_following_error_mm: vars::NC_FOLLOWING_MAX[..n].iter().map(|v| real(v.name())).collect(),
        });
        self
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
                    .map(|(k, v)| match (v.as_i64(), v.as_f64()) {
                        (Some(line), _) if k == "line" => format!("{k}={line}"),
                        (_, Some(x)) => format!("{k}={x:.3}"),
                        _ => format!("{k}=-"),
                    })
                    .collect();
                lines.push(format!("final values {}", values.join(" ")));
            }
        }
        if let Some(p) = &self.program {
            let following: Vec<String> = p.max_following_error_mm.iter().map(|e| format!("{e:.4}")).collect();
            lines.push(format!(
                "program {}: {}, {:.3} s (planned {:.3} s), path {:.3} mm, contour error max {:.4} mm rms {:.4} mm, following error max per joint {} mm",
                p.file,
                if p.completed { "completed" } else { "not completed" },
                p.duration_s,
                p.planned_s,
                p.path_length_mm,
                p.contour_error_mm.max,
                p.contour_error_mm.rms,
                following.join("/")
            ));
        }
        lines
    }
}
