//! An NC program prepared against the configured machine, once, for `nc check` and for
//! `run --program` alike: its text read and interpreted, every point of its path checked, and
//! — where every point is reachable — planned within the machine's limits. A program that is
//! refused, or leaves what the machine can reach, or cannot be planned, never reaches the PLC.

use std::cell::Cell;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use pkm_api::library::NcLibrary;
use pkm_api::machine::{Home, Machine, Motion};
use pkm_api::trajectory::NcJob;
use pkm_kinematics::frame::{Home as FrameHome, MachineFrame};
use pkm_kinematics::{KinematicsConfig, Machine as Model};
use pkm_nc::check::{Limits, Report, check_watched, format_pose};
use pkm_nc::interp::{self, Program};
use pkm_nc::job::PlannedProgram;
use pkm_nc::plan::{Checked, PlanLimits, plan_watched, verify};
use pkm_nc::watch::Watch;

use crate::compose::setup::Setup;
use crate::runtime::config::ConfigError;

/// Why a program cannot run: the exit code and the message.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct NcFailure {
    /// 1: the program cannot run on the machine (unreachable, unplannable); 2: usage,
    /// configuration or program text.
    pub code: u8,
    /// What to print.
    pub message: String,
}

pub(crate) fn fail(code: u8, message: impl Into<String>) -> NcFailure {
    NcFailure {
        code,
        message: message.into(),
    }
}

/// A program read and checked against a machine.
pub struct Prepared {
    /// The program's file as the user named it.
    pub name: String,
    /// Its text.
    pub text: String,
    /// The machine.
    pub machine: &'static dyn Machine,
    /// The machine's motion limits and home.
    pub motion: Motion,
    /// Its geometry.
    pub kinematics: KinematicsConfig,
    /// Its kinematic model.
    pub model: Model,
    /// Its machine frame (origin at the reference pose).
    pub frame: MachineFrame,
    /// The interpreted program.
    pub program: Program,
    /// The check of every point of its path.
    pub report: Report,
    /// The plan, where every point is reachable: checked finite and within the machine's
    /// limits as the fast class will sample it.
    pub plan: Option<Checked>,
}

impl Prepared {
    /// The unreachable points, one per line as `FILE:LINE: at POSE: why`.
    pub fn unreachable_lines(&self) -> Vec<String> {
        let n = self.frame.dof();
        self.report
            .unreachable
            .iter()
            .map(|u| format!("{}:{}: at {}: {}", self.name, u.line, format_pose(&u.pose, n), u.why))
            .collect()
    }

    /// The program ready to run, or why it cannot (exit code 1: unreachable).
    pub fn into_job(self) -> Result<NcJob, NcFailure> {
        let Some(plan) = self.plan else {
            return Err(fail(
                1,
                format!(
                    "{}: the program leaves what {} can reach; nothing moves:\n{}",
                    self.name,
                    self.machine.name(),
                    self.unreachable_lines().join("\n")
                ),
            ));
        };
        Ok(NcJob {
            file: self.name,
            text: self.text,
            trajectory: Arc::new(PlannedProgram::new(plan, self.frame)),
        })
    }
}

/// The watch over one program's preparation (reading, check, plan): its time bound
/// (`nc.max_planning_s`) and, for a screen job, what else abandons it (the operator's cancel,
/// the machine leaving READY). It remembers whether it stopped the work.
pub struct Deadline<'a> {
    start: Instant,
    /// The time bound; `None`: none (a replay plans again what the run planned in time).
    bound: Option<Duration>,
    /// Why the job is abandoned, if it is.
    abandon: Option<&'a (dyn Fn() -> Option<String> + Sync)>,
    stopped: Cell<bool>,
}

impl<'a> Deadline<'a> {
    /// From now on, within `setup`'s `nc.max_planning_s`.
    pub fn of(setup: &Setup) -> Deadline<'a> {
        Deadline {
            start: Instant::now(),
            bound: Some(setup.loaded.config.nc.max_planning()),
            abandon: None,
            stopped: Cell::new(false),
        }
    }

    /// No bound: the work goes on to its end.
    pub fn none() -> Deadline<'a> {
        Deadline {
            start: Instant::now(),
            bound: None,
            abandon: None,
            stopped: Cell::new(false),
        }
    }

    /// The same, and abandoned when `abandon` gives a reason.
    pub fn or_abandoned(self, abandon: &'a (dyn Fn() -> Option<String> + Sync)) -> Deadline<'a> {
        Deadline {
            abandon: Some(abandon),
            ..self
        }
    }

    /// Whether it stopped the work.
    pub fn stopped(&self) -> bool {
        self.stopped.get()
    }

    /// Whether its time is up (work that would start now would be stopped at once).
    fn expired(&self) -> bool {
        self.bound.is_some_and(|b| self.start.elapsed() > b)
    }
}

impl Watch for Deadline<'_> {
    fn go_on(&self) -> Result<(), String> {
        if let Some(why) = self.abandon.and_then(|f| f()) {
            self.stopped.set(true);
            return Err(why);
        }
        if let Some(bound) = self.bound.filter(|b| self.start.elapsed() > *b) {
            self.stopped.set(true);
            return Err(format!(
                "stopped: reading, checking and planning the program took longer than {} s (the bound: nc.max_planning_s)",
                bound.as_secs_f64()
            ));
        }
        Ok(())
    }
}

/// Reads the program `file` and checks and plans it against `setup`'s machine, within the
/// configuration's time bound.
pub fn prepare(setup: &Setup, file: &Path) -> Result<Prepared, NcFailure> {
    prepare_file(setup, file, &Deadline::of(setup))
}

/// [`prepare`] under `watch`.
fn prepare_file(setup: &Setup, file: &Path, watch: &Deadline<'_>) -> Result<Prepared, NcFailure> {
    let name = file.display().to_string();
    let text = crate::runtime::files::read_text(file, crate::runtime::files::MAX_TEXT_BYTES)
        .map_err(|e| fail(2, format!("{name}: cannot read the program: {e}")))?;
    prepare_watched(setup, name, text, watch)
}

/// Checks and plans the program `text` (from the file `name`) against `setup`'s machine,
/// without a time bound (a replay plans again what the run planned in time).
pub fn prepare_text(setup: &Setup, name: String, text: String) -> Result<Prepared, NcFailure> {
    prepare_watched(setup, name, text, &Deadline::none())
}

/// Checks and plans the program `text` (from the file `name`) against `setup`'s machine, under
/// `watch`.
pub fn prepare_watched(setup: &Setup, name: String, text: String, watch: &Deadline<'_>) -> Result<Prepared, NcFailure> {
    prepare_from(setup, name, text, [0.0; 6], Ok, watch)
}

/// `setup`'s machine with its motion, kinematics and machine frame.
pub struct MachineOf {
    /// The machine.
    pub machine: &'static dyn Machine,
    /// Its motion limits and home.
    pub motion: Motion,
    /// Its geometry.
    pub kinematics: KinematicsConfig,
    /// Its kinematic model.
    pub model: Model,
    /// Its machine frame (origin at the reference pose).
    pub frame: MachineFrame,
}

/// `setup`'s configuration refused for `problems` (exit code 2).
fn invalid(setup: &Setup, problems: Vec<pkm_api::problem::Problem>) -> NcFailure {
    fail(
        2,
        ConfigError::Invalid {
            file: setup.origin().to_string(),
            problems,
        }
        .to_string(),
    )
}

/// `setup`'s machine, or why programs cannot run on it.
pub fn machine_of(setup: &Setup) -> Result<MachineOf, NcFailure> {
    let origin = setup.origin().to_string();
    let invalid = |problems| invalid(setup, problems);
    let machine = setup.machine.ok_or_else(|| {
        fail(
            2,
            format!("{origin}: the configuration names no machine to run the program on"),
        )
    })?;
    let motion = machine.motion(&setup.loaded.json).map_err(invalid)?;
    let kinematics = KinematicsConfig::from_section(setup.loaded.config.kinematics.as_ref()).map_err(invalid)?;
    let model = Model::from_name(motion.model).ok_or_else(|| {
        fail(
            2,
            format!("{}: no kinematic model \"{}\"", machine.name(), motion.model),
        )
    })?;
    let home = match &motion.home {
        Home::Joints(q) => FrameHome::Joints(q),
        Home::Pose(x) => FrameHome::Pose(x),
    };
    let frame = MachineFrame::new(kinematics.build(model), home).map_err(|e| {
        fail(
            2,
            format!("{origin}: the machine's home is not a pose of its kinematics: {e}"),
        )
    })?;
    Ok(MachineOf {
        machine,
        motion,
        kinematics,
        model,
        frame,
    })
}

/// The cycle of `setup`'s fastest task class (s), where the drives are fed a plan's samples.
pub fn fast_cycle_s(setup: &Setup) -> f64 {
    let fastest = setup
        .loaded
        .config
        .task_classes
        .iter()
        .map(|c| c.cycle_us)
        .min()
        .unwrap_or(10_000);
    f64::from(fastest.max(1)) * 1e-6
}

/// The limits `setup`'s programs are planned within on a machine of `n` coordinates with
/// `motion`: the joints' speeds and accelerations, the world axes' where the configuration gives
/// them (else the joints' bound every move, rapids included), the accelerations times
/// `nc.accel_share`.
pub fn plan_limits(setup: &Setup, motion: &Motion, n: usize) -> PlanLimits {
    let nc = &setup.loaded.config.nc;
    let per_axis = |v: &Option<Vec<f64>>| {
        let mut a = [f64::INFINITY; 6];
        if let Some(v) = v {
            a[..n].copy_from_slice(v);
        }
        a
    };
    let share = nc.accel_share();
    PlanLimits {
        joint_speed: motion.joint_speed.clone(),
        joint_accel: motion.joint_accel.iter().map(|a| a * share).collect(),
        axis_speed: per_axis(&nc.axis_speed),
        axis_accel: per_axis(&nc.axis_accel).map(|a| a * share),
    }
}

/// Reads `text` (from the file `name`) with the tool at `start` (machine frame), gives the
/// program read to `edit`, then checks and plans what `edit` makes of it.
///
/// A panic on the way (of the interpreter, the check, the planner: a bug) refuses the program
/// and goes no further: a file of `--programs`, a screen job or `run --program` must never end
/// the process, nor keep the PLC from starting.
pub(crate) fn prepare_from(
    setup: &Setup,
    name: String,
    text: String,
    start: [f64; 6],
    edit: impl FnOnce(Program) -> Result<Program, NcFailure>,
    watch: &Deadline<'_>,
) -> Result<Prepared, NcFailure> {
    let named = name.clone();
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        prepare_unguarded(setup, name, text, start, edit, watch)
    }))
    .unwrap_or_else(|payload| {
        Err(fail(
            1,
            format!(
                "{named}: the planner failed on this program (a fault of the planner: please report it with the program): {}",
                crate::runtime::service_mode::panic_message(payload.as_ref())
            ),
        ))
    })
}

/// [`prepare_from`] without its guard.
fn prepare_unguarded(
    setup: &Setup,
    name: String,
    text: String,
    start: [f64; 6],
    edit: impl FnOnce(Program) -> Result<Program, NcFailure>,
    watch: &Deadline<'_>,
) -> Result<Prepared, NcFailure> {
    let MachineOf {
        machine,
        motion,
        kinematics,
        model,
        frame,
    } = machine_of(setup)?;
    let n = frame.dof();
    let keys = frame.kinematics().pose_keys();
    let nc = &setup.loaded.config.nc;
    let problems = nc.check(keys);
    if !problems.is_empty() {
        return Err(invalid(setup, problems));
    }
    let persistent = setup.persistent(n);
    let program = interp::read_bounded(
        &text,
        &interp::Machine {
            axes: keys,
            // A program starts at the reference point, the origin of the machine frame; a
            // screen job where the tool stands.
            start,
            work_offsets: persistent.origins,
            homes: persistent.homes,
            block_delete: nc.block_delete,
            tools: setup.tools.as_ref().map(|t| &t.table),
        },
        &nc.bounds(),
        watch,
    )
    .map_err(|e| fail(2, format!("{name}:{e}")))?;
    // A laser's S is its power: there is no spindle turning for G95 to feed by.
    if let (Some(_), Some((line, column))) = (&nc.laser, program.per_revolution) {
        return Err(fail(
            2,
            format!(
                "{name}:{line}:{column}: G95 (feed per revolution) is refused in laser mode (nc.laser): S is the beam's power, not a spindle's speed; feed per minute (G94)"
            ),
        ));
    }
    let program = edit(program)?;
    let report = check_watched(
        &program,
        &Limits {
            frame: &frame,
            soft: &motion.soft_limits,
            world: &motion.world_limits,
            singularity_threshold: motion.singularity_threshold,
        },
        watch,
    )
    .map_err(|s| fail(2, format!("{name}:{}: {}", s.line, s.why)))?;
    // Planned only where every point is reachable: the planner needs the joints everywhere.
    let planned = if report.unreachable.is_empty() {
        let limits = plan_limits(setup, &motion, n);
        // A plan the watch stopped is refused like a program too large (2); one the machine
        // cannot follow, or that fails its check, as an unreachable one (1).
        let refused = |e: pkm_nc::plan::PlanError| fail(if watch.stopped() { 2 } else { 1 }, format!("{name}: {e}"));
        let plan = plan_watched(&program, &frame, &limits, watch).map_err(refused)?;
        let plan = verify(plan, &frame, &limits, fast_cycle_s(setup), watch).map_err(refused)?;
        let bound_s = nc.max_duration_s();
        if plan.duration_s > bound_s {
            return Err(fail(2, too_long(&name, &plan, bound_s)));
        }
        Some(plan)
    } else {
        None
    };
    Ok(Prepared {
        name,
        text,
        machine,
        motion,
        kinematics,
        model,
        frame,
        program,
        report,
        plan: planned,
    })
}

/// Why program `name`, planned to take longer than `bound_s`, is refused: its planned time
/// (and how much of it is dwells), the bound, and the line whose move takes longest.
fn too_long(name: &str, plan: &pkm_nc::plan::Plan, bound_s: f64) -> String {
    let dwells = if plan.dwell_s > 0.0 {
        format!(" ({} of it dwells)", clock(plan.dwell_s))
    } else {
        String::new()
    };
    let longest = plan
        .longest_move()
        .map(|(line, t)| format!("; the longest move is line {line}'s, {}", clock(t)))
        .unwrap_or_default();
    format!(
        "{name}: planned to run {}{dwells}, longer than the {} a program may (nc.max_duration_h){longest}. A feed or a dwell mistyped is the usual cause (F is per minute, G4 P in seconds); else split the program or raise the bound",
        clock(plan.duration_s),
        clock(bound_s),
    )
}

/// A duration as a machinist reads it: `55 h 12 min`, `12 h`, `3 min 20 s`, `4.5 s`.
fn clock(seconds: f64) -> String {
    let whole = seconds.round() as u64;
    let (h, min, s) = (whole / 3600, whole / 60 % 60, whole % 60);
    match (h, min) {
        (0, 0) => format!("{seconds:.1} s"),
        (0, _) => format!("{min} min {s} s"),
        (_, 0) => format!("{h} h"),
        _ => format!("{h} h {min} min"),
    }
}

/// The run's programs: the one to run (`run --program`), and those the operator may load
/// instead from the screen (`run --programs DIR`), each checked and planned now.
#[derive(Debug, Default)]
pub struct Programs {
    /// The library, if there is any program at all.
    pub library: Option<NcLibrary>,
    /// The programs of the directory that cannot run on this machine: file and why.
    pub refused: Vec<(String, String)>,
}

/// `e` (why `file` cannot run on `setup`'s machine) with the machines it runs on, if any: each
/// tried within what is left of `watch`'s time (none when `watch` stopped the program).
fn with_hint(setup: &Setup, file: &Path, mut e: NcFailure, watch: &Deadline<'_>) -> NcFailure {
    if watch.stopped() || watch.expired() {
        return e;
    }
    let Ok(text) = crate::runtime::files::read_text(file, crate::runtime::files::MAX_TEXT_BYTES) else {
        return e;
    };
    let current = setup.machine.map(|m| m.name());
    let runs_on: Vec<&str> = crate::compose::machines::BUILTIN
        .iter()
        .map(|m| m.name())
        .filter(|name| Some(*name) != current)
        .filter(|name| {
            crate::compose::setup::of_machine(name).is_some_and(|other| {
                !watch.expired()
                    && prepare_watched(&other, file.display().to_string(), text.clone(), watch)
                        .and_then(Prepared::into_job)
                        .is_ok()
            })
        })
        .collect();
    match runs_on.as_slice() {
        [] => {}
        [one] => e
            .message
            .push_str(&format!("\n(it runs on machine {one}: --machine {one})")),
        more => e
            .message
            .push_str(&format!("\n(it runs on machines {}: --machine NAME)", more.join(", "))),
    }
    e
}

/// The extension of the programs a directory offers.
pub const PROGRAM_EXTENSION: &str = "ngc";

/// Reads, checks and plans `program` (refused with its reason if it cannot run) and every
/// `*.ngc` of `dir` (in name order; one that cannot run is listed in [`Programs::refused`]).
///
/// With the operator's `screen` the run has a library even without programs: the screen makes
/// jobs (MDI, a program from a line) into it.
pub fn programs(
    setup: &Setup,
    program: Option<&Path>,
    dir: Option<&Path>,
    screen: bool,
) -> Result<Programs, NcFailure> {
    let first = program
        .map(|p| {
            let watch = Deadline::of(setup);
            prepare_file(setup, p, &watch)
                .and_then(Prepared::into_job)
                .map_err(|e| with_hint(setup, p, e, &watch))
        })
        .transpose()?;
    let mut offered = Vec::new();
    let mut refused = Vec::new();
    if let Some(dir) = dir {
        let entries = std::fs::read_dir(dir).map_err(|e| {
            fail(
                2,
                format!("--programs {}: cannot list the directory: {e}", dir.display()),
            )
        })?;
        let mut files = program_files(dir, entries);
        files.sort();
        for file in files {
            // The program given to run is not offered twice.
            if program.is_some_and(|p| same_file(p, &file)) {
                continue;
            }
            match prepare(setup, &file).and_then(Prepared::into_job) {
                Ok(job) => offered.push(job),
                Err(e) => refused.push((file.display().to_string(), e.message)),
            }
        }
    }
    Ok(Programs {
        library: library(
            first,
            offered,
            screen && setup.machine.is_some(),
            setup.loaded.config.nc.laser,
        ),
        refused,
    })
}

/// The programs of `dir` to offer: its `*.ngc` regular files, and symbolic links to regular
/// files inside it. Every other `*.ngc` entry is skipped and logged with why — a link out of the
/// directory (the screen would offer files the operator never put there), a directory, a FIFO
/// (reading it would wait for a writer), a device, a socket; other names are counted.
fn program_files(dir: &Path, entries: std::fs::ReadDir) -> Vec<std::path::PathBuf> {
    let root = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    let mut files = Vec::new();
    let mut others = 0;
    for entry in entries {
        let path = match entry {
            Ok(e) => e.path(),
            Err(e) => {
                tracing::warn!("--programs {}: an entry could not be read: {e}", dir.display());
                continue;
            }
        };
        if path.extension().is_none_or(|x| x != PROGRAM_EXTENSION) {
            others += 1;
            continue;
        }
        let skip = |why: String| tracing::warn!("--programs: skipped {}: {why}", path.display());
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            skip("cannot be read".into());
            continue;
        };
        let target = if meta.file_type().is_symlink() {
            match path.canonicalize() {
                Ok(t) if t.starts_with(&root) => t,
                Ok(t) => {
                    skip(format!(
                        "a symbolic link out of the directory (to {}): only the directory's own programs are offered",
                        t.display()
                    ));
                    continue;
                }
                Err(e) => {
                    skip(format!("a symbolic link that leads nowhere ({e})"));
                    continue;
                }
            }
        } else {
            path.clone()
        };
        match std::fs::metadata(&target) {
            Ok(m) if m.is_file() => files.push(path),
            Ok(m) => skip(format!(
                "{}, not a program file",
                crate::runtime::files::kind(m.file_type())
            )),
            Err(e) => skip(format!("cannot be read ({e})")),
        }
    }
    if others > 0 {
        tracing::info!(
            "--programs {}: {others} entries without the .{PROGRAM_EXTENSION} extension ignored",
            dir.display()
        );
    }
    files
}

/// The library of `first` (run by itself at the first READY) and `offered` (loaded from the
/// screen), if there is any program or the run has a `screen` (which makes jobs into it).
pub fn library(
    first: Option<NcJob>,
    offered: Vec<NcJob>,
    screen: bool,
    laser: Option<crate::runtime::config::LaserConfig>,
) -> Option<NcLibrary> {
    let autostart = first.is_some();
    let jobs: Vec<NcJob> = first.into_iter().chain(offered).collect();
    (screen || !jobs.is_empty()).then(|| NcLibrary::new(jobs, autostart).with_laser(laser.map(|l| l.s_max)))
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ox_x() -> Setup {
        let machine = crate::compose::machines::find("ox-x").expect("built in");
        let file = machine.configuration();
        let loaded = crate::runtime::config::parse(file.text, file.name).unwrap_or_else(|e| panic!("{e}"));
        Setup::new(loaded).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn a_panic_while_a_program_is_prepared_refuses_it_and_goes_on() {
        let setup = ox_x();
        let refused = prepare_from(
            &setup,
            "bug.ngc".into(),
            "G1 X1 F600\nM2\n".into(),
            [0.0; 6],
            |_| panic!("an invariant broken"),
            &Deadline::none(),
        )
        .err()
        .expect("refused");
        assert_eq!(refused.code, 1);
        assert_eq!(
            refused.message,
            "bug.ngc: the planner failed on this program (a fault of the planner: please report it with the program): an invariant broken"
        );
        // The next one is prepared as ever.
        let next = prepare_text(&setup, "next.ngc".into(), "G1 X1 F600\nM2\n".into());
        assert!(next.is_ok_and(|p| p.plan.is_some()));
    }
}
