//! The screen's commands that make jobs: MDI lines, a run from a line, a step of the
//! incremental jog, a touch-off (and the loaded program planned again after it), a Load that
//! plans the program again with the offsets a touch-off set.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use serde_json::{Value as Json, json};
use tracing::info;

use super::super::commands::press;
use super::super::jobs::{JobDesk, Loaded};
use super::{Command, MAX_STEP_MM, Shared};

/// Said of a touch-off that no parameter file keeps: the next start would lose it silently.
const NOT_KEPT: &str = ", kept until the PLC stops only: no parameter file (--var-file, nc.var_file)";

/// A step of the jog that replaced a loaded program, to load that again once it has run.
pub(super) struct StepReturn {
    /// The step's job (its `NC_PROGRAM` number).
    job: i16,
    /// What it replaced.
    before: Loaded,
    /// Whether it has run (AUTO seen with it loaded).
    ran: bool,
    /// Who asked for the step (the log names them).
    peer: SocketAddr,
}

impl Shared {
    /// Makes a screen job (MDI, a program from a line) and has it loaded and started; the
    /// reply says its number, or why not.
    pub(super) async fn make_job(&self, peer: SocketAddr, command: Command) -> Json {
        let Some(desk) = &self.jobs else {
            return json!({"type": "refused", "why": "this run makes no jobs: it has no machine to plan them for", "job": true});
        };
        let kind = match command {
            Command::Mdi { text } => {
                info!(
                    "screen {peer}: MDI {}",
                    crate::runtime::config::shorten(&text.replace('\n', " / "))
                );
                pkm_api::screen_jobs::ScreenJobKind::Mdi { text }
            }
            Command::RunFrom { program, line } => {
                info!("screen {peer}: run program {program} from line {line}");
                pkm_api::screen_jobs::ScreenJobKind::FromLine { program, line }
            }
            Command::Step { axis, mm } => {
                let Some(c) = self.axes.iter().position(|a| a.eq_ignore_ascii_case(&axis)) else {
                    return json!({"type": "refused", "why": format!("no axis {axis:?}: this machine's are {}", self.axes.join(" ")), "job": true});
                };
                if !(mm.is_finite() && mm != 0.0 && mm.abs() <= MAX_STEP_MM) {
                    return json!({"type": "refused", "why": format!("a step is 0 < |mm| ≤ {MAX_STEP_MM}, got {mm}"), "job": true});
                }
                let text = format!("G91 G0 {}{mm}", self.axes[c].to_uppercase());
                info!("screen {peer}: step {text}");
                // The step is a job of its own: what it replaces is loaded again once it is done.
                let before = desk.loaded_for_return();
                let reply = self
                    .make_and_load(peer, desk, pkm_api::screen_jobs::ScreenJobKind::Mdi { text }, true)
                    .await;
                if let (Some(before), Some(job)) = (before, reply["program"].as_i64()) {
                    *self.step_return.lock().unwrap_or_else(|p| p.into_inner()) = Some(StepReturn {
                        job: job as i16,
                        before,
                        ran: false,
                        peer,
                    });
                }
                return reply;
            }
            Command::TouchOff { axis, value, system } => return self.touch_off(peer, desk, &axis, value, system).await,
            Command::Tool {
                number,
                pocket,
                offsets,
                diameter,
                comment,
            } => {
                let tool = pkm_nc::tools::Tool {
                    pocket: pocket.unwrap_or(number),
                    offsets,
                    diameter,
                    comment: comment.trim().to_string(),
                    ..pkm_nc::tools::Tool::new(number)
                };
                return self.edit_tool(peer, desk, tool, false).await;
            }
            Command::ToolRemove { number } => {
                return self.edit_tool(peer, desk, pkm_nc::tools::Tool::new(number), true).await;
            }
            Command::Load { program } => {
                // Planned again with the offsets a touch-off set, then loaded (not started).
                if let Err(why) = self.may_load(program) {
                    return json!({"type": "refused", "why": why, "job": true});
                }
                info!("screen {peer}: load program {program}, planned again with the touched-off offsets");
                let kind = pkm_api::screen_jobs::ScreenJobKind::FromLine { program, line: 1 };
                return self.make_and_load(peer, desk, kind, false).await;
            }
            _ => return json!({"type": "refused", "why": "not a job"}),
        };
        self.make_and_load(peer, desk, kind, true).await
    }

    /// Takes a frame's state: once the step of the jog that replaced a program has run (AUTO,
    /// then no longer), what it replaced is loaded again (a job made again where it was one:
    /// planned on a task of its own).
    pub(super) fn step_watch(self: &Arc<Self>, state: &str) {
        let Some(desk) = &self.jobs else { return };
        let done = {
            let mut pending = self.step_return.lock().unwrap_or_else(|p| p.into_inner());
            match pending.as_mut() {
                Some(r) if state == "AUTO" && desk.loaded_number() == r.job => {
                    r.ran = true;
                    None
                }
                Some(r) if r.ran && state != "AUTO" => pending.take(),
                _ => None,
            }
        };
        let Some(StepReturn { before, peer, .. }) = done else {
            return;
        };
        let shared = Arc::clone(self);
        tokio::spawn(async move {
            let Some(desk) = &shared.jobs else { return };
            match before {
                Loaded::Program(k) if !desk.plans_changed() => {
                    info!("screen {peer}: the step done, program {k} loaded again");
                    shared.sink.update(|c| c.program = k);
                }
                // Planned again with the touched-off offsets, as a Load does.
                Loaded::Program(k) => {
                    let kind = pkm_api::screen_jobs::ScreenJobKind::FromLine { program: k, line: 1 };
                    shared.make_and_load(peer, desk, kind, false).await;
                }
                Loaded::Job(kind) => {
                    shared.make_and_load(peer, desk, kind, false).await;
                }
            }
        });
    }

    /// Whether program `program` may be loaded now: one of the run's, and no program runs.
    pub(super) fn may_load(&self, program: i16) -> Result<(), String> {
        let known = usize::try_from(program).is_ok_and(|k| (1..=self.programs.len()).contains(&k));
        if !known {
            return Err(format!("no program {program}: the run has {}", self.programs.len()));
        }
        if self.running.load(Ordering::Relaxed) {
            return Err("a program runs: another is loaded once it has ended or stopped".into());
        }
        Ok(())
    }

    /// Whether a Load plans the program again first: a touch-off has changed the work offsets,
    /// or the tool table has changed, since the run's programs were planned.
    pub(super) fn replans_on_load(&self) -> bool {
        self.jobs.as_ref().is_some_and(JobDesk::plans_changed)
    }

    /// A touch-off (see [`Command::TouchOff`]): the offsets changed and kept, then the loaded
    /// program (or the program a loaded run from a line runs) planned again with them and
    /// loaded in its place, not started.
    async fn touch_off(&self, peer: SocketAddr, desk: &JobDesk, axis: &str, value: f64, system: Option<u8>) -> Json {
        let refused = |why: String| json!({"type": "refused", "why": why, "job": true});
        let system = usize::from(system.unwrap_or(1));
        if !(1..=6).contains(&system) {
            return refused(format!("a touch-off's system is 1 … 6 (G54 … G59), got {system}"));
        }
        let Some(c) = self.axes.iter().position(|a| a.eq_ignore_ascii_case(axis)) else {
            return refused(format!("no axis {axis:?}: this machine's are {}", self.axes.join(" ")));
        };
        let name = format!("G{}", 53 + system);
        let t = match desk.touch_off(system - 1, c, value).await {
            Ok(t) => t,
            Err(why) => {
                info!("screen {peer}: touch-off {name} {axis} = {value} refused: {why}");
                return refused(why);
            }
        };
        let kept = desk.keeps_offsets();
        info!(
            "screen {peer}: touch-off {name} {} = {value:.4}: its origin {:.4} → {:.4} mm{}",
            axis.to_uppercase(),
            t.was,
            t.now,
            if kept { "" } else { NOT_KEPT }
        );
        // Every page's DRO shows the new origin.
        if self.frames.receiver_count() > 0 {
            let origins = json!({"type": "origins", "origins": desk.offsets().origins}).to_string();
            let _ = self.frames.send(Arc::from(origins.as_str()));
        }
        let mut reply = json!({"type": "touch_off", "system": name, "axis": axis, "value": value, "was": t.was, "now": t.now, "kept": kept});
        if let Some(job) = self.replan_loaded(peer, desk).await {
            reply["job"] = job;
        }
        reply
    }

    /// A tool table edit (see [`Command::Tool`], [`Command::ToolRemove`]): the entry set or
    /// removed and kept, then the loaded program (or the program a loaded run from a line runs)
    /// planned again with the table and loaded in its place, not started. Every page is sent the
    /// table as it is now (by the keeper's watch, [`super::tool_table_news`]).
    async fn edit_tool(&self, peer: SocketAddr, desk: &JobDesk, tool: pkm_nc::tools::Tool, remove: bool) -> Json {
        let what = if remove {
            format!("tool {} removed", tool.number)
        } else {
            format!("tool {}: {}", tool.number, tool.line())
        };
        let kept = match desk.edit_tool(tool, remove).await {
            Ok(kept) => kept,
            Err(why) => {
                info!("screen {peer}: tool table edit refused ({what}): {why}");
                return json!({"type": "refused", "why": why, "job": true});
            }
        };
        let written = kept == crate::runtime::tool_table::Kept::Written;
        info!(
            "screen {peer}: tool table: {what}{}",
            if written {
                String::new()
            } else {
                " (kept for this simulation: a simulation does not write the tool table)".to_string()
            }
        );
        let mut reply = json!({"type": "tool", "what": what, "written": written});
        if let Some(job) = self.replan_loaded(peer, desk).await {
            reply["job"] = job;
        }
        reply
    }

    /// Plans the loaded program (or the program a loaded run from a line runs) again from its
    /// first line, with the offsets and the tool table as they are now, and loads it in its
    /// place, not started: the reply of [`Shared::make_and_load`]; `None` where no program is
    /// loaded.
    async fn replan_loaded(&self, peer: SocketAddr, desk: &JobDesk) -> Option<Json> {
        let k = desk.loaded_program()?;
        let kind = pkm_api::screen_jobs::ScreenJobKind::FromLine { program: k, line: 1 };
        Some(self.make_and_load(peer, desk, kind, false).await)
    }

    /// Makes job `kind` and loads it, and starts it if `start`: the reply says its number, file,
    /// lines, planned time and whether it started, or why it was refused.
    async fn make_and_load(
        &self,
        peer: SocketAddr,
        desk: &JobDesk,
        kind: pkm_api::screen_jobs::ScreenJobKind,
        start: bool,
    ) -> Json {
        match desk.make(kind).await {
            Ok(made) => {
                info!(
                    "screen {peer}: job {} ({}, {:.2} s planned) loaded{}",
                    made.number,
                    made.job.file,
                    made.job.trajectory.duration_s(),
                    if start { " and started" } else { "" }
                );
                let number = made.number;
                self.sink.update(|c| {
                    c.program = number;
                    if start {
                        c.presses[press::NC[0]] += 1;
                    }
                });
                json!({
                    "type": "job",
                    "program": number,
                    "file": made.job.file,
                    "lines": made.job.text.lines().count(),
                    "planned_s": made.job.trajectory.duration_s(),
                    "started": start,
                })
            }
            Err(why) => {
                info!("screen {peer}: job refused: {}", why.lines().next().unwrap_or_default());
                json!({"type": "refused", "why": why, "job": true})
            }
        }
    }
}
