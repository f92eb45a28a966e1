//! The jobs the operator makes on the screen while the PLC runs: MDI lines, and a
//! program of the library run from a chosen line. Each is read, checked and planned like a
//! program ([`crate::compose::nc_job`]), off the cyclic path, from where the tool stands — the forward
//! kinematics of the joints' set-points, which is exactly where the main program says the tool
//! is, so the job's start is the tool's pose and the start check passes.

use pkm_api::library::NcLibrary;
use pkm_api::screen_jobs::{ScreenJobKind, ScreenJobSpec};
use pkm_api::trajectory::NcJob;
use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;
use pkm_nc::interp::{Action, Blend, Block, Path, Program, Spindle};

use crate::compose::nc_job::{Deadline, NcFailure, Prepared, fail, machine_of, prepare_from};
use crate::compose::setup::Setup;
use crate::image::Value;
use crate::runtime::plc::Plc;
use crate::services::hmi::jobs::{JobPlanner, Standing};

/// The most bytes of MDI text a job takes (the screen's messages are smaller still).
pub const MAX_MDI_BYTES: usize = 2048;

/// The file name a job of MDI lines is shown and traced with.
pub const MDI_FILE: &str = "MDI";

/// Reads, checks and plans the screen job `spec` against `setup`'s machine (the library's
/// programs for a run from a line), without a time bound (a replay plans again what the run
/// planned in time).
pub fn plan(setup: &Setup, library: &NcLibrary, spec: &ScreenJobSpec) -> Result<NcJob, NcFailure> {
    plan_watched(setup, library, spec, &Deadline::none())
}

/// [`plan`] under `watch`: the configuration's time bound, the operator's cancel.
pub fn plan_watched(
    setup: &Setup,
    library: &NcLibrary,
    spec: &ScreenJobSpec,
    watch: &Deadline<'_>,
) -> Result<NcJob, NcFailure> {
    // Planned with the offsets a touch-off had set and the tool table as it was changed, where
    // they had been.
    let changed;
    let setup = match (spec.offsets, &spec.tool_table) {
        (None, None) => setup,
        (offsets, table) => {
            let mut s = setup.clone();
            if offsets.is_some() {
                s.persistent = offsets;
            }
            if let Some(text) = table {
                let file = setup
                    .tools
                    .as_ref()
                    .map_or_else(|| "tool table".to_string(), |t| t.file.clone());
                s.tools = Some(super::setup::ToolTableFile::parse(file, text.clone()).map_err(|e| fail(2, e))?);
            }
            changed = s;
            &changed
        }
    };
    match &spec.kind {
        ScreenJobKind::Mdi { text } => {
            if text.len() > MAX_MDI_BYTES {
                return Err(fail(2, format!("MDI: more than {MAX_MDI_BYTES} bytes")));
            }
            if text.trim().is_empty() {
                return Err(fail(2, "MDI: no line to run"));
            }
            prepare_from(setup, MDI_FILE.to_string(), mdi_program(text), spec.start, Ok, watch)
                .and_then(Prepared::into_job)
        }
        ScreenJobKind::FromLine { program, line } => {
            // A job that runs a program from a line runs it from another line as well.
            let program = &match library.screen_spec(*program).map(|spec| &spec.kind) {
                Some(ScreenJobKind::FromLine { program, .. }) => *program,
                Some(ScreenJobKind::Mdi { .. }) => {
                    return Err(fail(
                        2,
                        format!("job {program} is MDI lines: it runs whole, not from a line"),
                    ));
                }
                None => *program,
            };
            let job = usize::try_from(*program)
                .ok()
                .and_then(|k| k.checked_sub(1))
                .and_then(|i| library.jobs.get(i))
                .ok_or_else(|| {
                    fail(
                        2,
                        format!(
                            "no program {program} to run from a line: the run has {}",
                            library.jobs.len()
                        ),
                    )
                })?;
            let name = format!("{} from line {line}", job.file);
            let line = usize::try_from(*line).unwrap_or(usize::MAX);
            // Read as the program was (from the reference point): its blocks from the line on
            // are where they were.
            prepare_from(
                setup,
                name,
                job.text.clone(),
                [0.0; 6],
                |p| from_line(p, line, spec.start),
                watch,
            )
            .and_then(Prepared::into_job)
        }
    }
}

pub use crate::services::hmi::jobs::mdi_program;

/// The configured machine plans the screen's jobs: within the configuration's planning time,
/// abandoned when the screen says so.
impl JobPlanner for Setup {
    fn plan(
        &self,
        library: &NcLibrary,
        spec: &ScreenJobSpec,
        abandoned: &(dyn Fn() -> Option<String> + Sync),
    ) -> Result<NcJob, String> {
        let watch = Deadline::of(self).or_abandoned(abandoned);
        plan_watched(self, library, spec, &watch).map_err(|e| e.message)
    }
}

impl Standing for StandingPose {
    fn pose(&self, image: &[Value]) -> Option<[f64; 6]> {
        StandingPose::pose(self, image)
    }
}

/// The blocks of `program` from the first one, in the order they run, of line `line` or a
/// later line on, after a rapid straight from `start` to where that block's motion begins; the
/// spindle as the blocks before left it is switched on there, once the tool has arrived, and the
/// program coordinates they left are in force from the start.
/// Dwells and pauses before the line do not run.
pub fn from_line(program: Program, line: usize, start: [f64; 6]) -> Result<Program, NcFailure> {
    let Program {
        blocks,
        messages,
        per_revolution,
        ..
    } = program;
    let last = blocks
        .iter()
        .filter(|b| !matches!(b.action, Action::End))
        .map(|b| b.line)
        .max()
        .unwrap_or(0);
    let Some(at) = blocks
        .iter()
        .position(|b| b.line >= line && !matches!(b.action, Action::End))
    else {
        return Err(fail(
            2,
            format!("line {line}: the program does nothing from there (its last line that does is {last})"),
        ));
    };
    let first_line = blocks[at].line;
    let Some(target) = blocks[at..].iter().find_map(|b| match b.action {
        Action::Move { from, .. } => Some(from),
        _ => None,
    }) else {
        return Err(fail(2, format!("line {line}: no motion from there on")));
    };
    let spindle = blocks[..at].iter().rev().find_map(|b| match b.action {
        Action::Spindle { direction, speed_rpm } => Some((direction, speed_rpm)),
        _ => None,
    });
    // The program coordinates the blocks before left in force, for the DRO from the start.
    let frame = blocks[..at]
        .iter()
        .rev()
        .find(|b| matches!(b.action, Action::WorkOffset { .. }))
        .map(|b| Block {
            line: first_line,
            column: 1,
            action: b.action,
        });
    let mut run = Vec::with_capacity(blocks.len() - at + 3);
    run.extend(frame);
    if (0..6).any(|c| (target[c] - start[c]).abs() > 1e-9) {
        run.push(Block {
            line: first_line,
            column: 1,
            action: Action::Move {
                from: start,
                to: target,
                path: Path::Line,
                feed_mm_min: None,
                blend: Blend::ExactStop,
            },
        });
    }
    if let Some((direction, speed_rpm)) = spindle.filter(|(d, _)| *d != Spindle::Off) {
        run.push(Block {
            line: first_line,
            column: 1,
            action: Action::Spindle { direction, speed_rpm },
        });
    }
    run.extend_from_slice(&blocks[at..]);
    Ok(Program {
        blocks: run,
        messages,
        start,
        per_revolution,
    })
}

/// Where the tool stands commanded, from a published image: the forward kinematics of the
/// joints' set-points.
pub struct StandingPose {
    frame: MachineFrame,
    /// The image indices of the set-points.
    setpoints: Vec<usize>,
}

impl StandingPose {
    /// For `setup`'s machine as `plc` declares its variables; `None` without a machine whose
    /// set-points the image holds.
    pub fn of(setup: &Setup, plc: &Plc) -> Option<StandingPose> {
        let m = machine_of(setup).ok()?;
        let setpoints = m
            .motion
            .setpoint_vars
            .iter()
            .map(|name| plc.vars().index_of(name).map(usize::from))
            .collect::<Option<Vec<usize>>>()?;
        (setpoints.len() == m.frame.dof()).then_some(StandingPose {
            frame: m.frame,
            setpoints,
        })
    }

    /// The pose (machine frame; unused coordinates 0) at the set-points of `image`, if they
    /// have one.
    pub fn pose(&self, image: &[Value]) -> Option<[f64; 6]> {
        let n = self.frame.dof();
        let mut q = [0.0; MAX_DOF];
        for (q, &i) in q.iter_mut().zip(&self.setpoints) {
            *q = match image.get(i) {
                Some(Value::Real(x)) => *x,
                _ => return None,
            };
        }
        let mut pose = [0.0; 6];
        let mut x = [0.0; MAX_DOF];
        self.frame.forward(&q[..n], None, &mut x[..n]).ok()?;
        pose[..n.min(6)].copy_from_slice(&x[..n.min(6)]);
        Some(pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(line: usize, action: Action) -> Block {
        Block {
            line,
            column: 1,
            action,
        }
    }

    fn line_move(line: usize, from: [f64; 6], to: [f64; 6]) -> Block {
        block(
            line,
            Action::Move {
                from,
                to,
                path: Path::Line,
                feed_mm_min: Some(600.0),
                blend: Blend::ExactStop,
            },
        )
    }

    fn at(x: f64, y: f64) -> [f64; 6] {
        [x, y, 0.0, 0.0, 0.0, 0.0]
    }

    fn program() -> Program {
        Program {
            blocks: vec![
                block(
                    1,
                    Action::Spindle {
                        direction: Spindle::Clockwise,
                        speed_rpm: 1000.0,
                    },
                ),
                line_move(2, at(0.0, 0.0), at(5.0, 0.0)),
                block(3, Action::Dwell(1.0)),
                line_move(4, at(5.0, 0.0), at(5.0, 5.0)),
                line_move(5, at(5.0, 5.0), at(0.0, 5.0)),
                block(6, Action::End),
            ],
            messages: Vec::new(),
            start: [0.0; 6],
            per_revolution: None,
        }
    }

    #[test]
    fn a_run_from_a_line_goes_to_its_start_turns_the_spindle_on_and_runs_the_rest() {
        let p = from_line(program(), 3, at(1.0, 1.0)).unwrap_or_else(|e| panic!("{e}"));
        let lines: Vec<usize> = p.blocks.iter().map(|b| b.line).collect();
        // The rapid and the spindle on the first line run (the dwell's), then lines 3 … 6.
        assert_eq!(lines, [3, 3, 3, 4, 5, 6]);
        assert_eq!(
            p.blocks[0].action,
            Action::Move {
                from: at(1.0, 1.0),
                to: at(5.0, 0.0),
                path: Path::Line,
                feed_mm_min: None,
                blend: Blend::ExactStop,
            }
        );
        assert!(matches!(
            p.blocks[1].action,
            Action::Spindle {
                direction: Spindle::Clockwise,
                ..
            }
        ));
        assert_eq!(p.blocks[2].action, Action::Dwell(1.0));
    }

    #[test]
    fn a_run_from_a_line_starts_in_the_program_coordinates_the_lines_before_left() {
        let frame = |system, x| Action::WorkOffset {
            system,
            offset: [x, 0.0, 0.0, 0.0, 0.0, 0.0],
        };
        let mut p = program();
        p.blocks.insert(0, block(1, frame(1, 0.0)));
        p.blocks.insert(2, block(2, frame(2, 100.0)));
        let run = from_line(p, 4, at(5.0, 0.0)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(run.blocks[0].action, frame(2, 100.0));
        assert_eq!(run.blocks[0].line, 4, "shown from the line it runs from");
    }

    #[test]
    fn a_run_from_where_the_tool_stands_has_no_lead_in_and_a_line_past_the_end_is_refused() {
        let p = from_line(program(), 4, at(5.0, 0.0)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(p.blocks.first().map(|b| b.line), Some(4));
        assert!(matches!(p.blocks[0].action, Action::Spindle { .. }));
        let e = from_line(program(), 6, at(0.0, 0.0)).expect_err("nothing from line 6");
        assert_eq!(
            e.message,
            "line 6: the program does nothing from there (its last line that does is 5)"
        );
    }
}
