//! The screen's jobs: MDI lines and a program run from a chosen line, made on the
//! operator's command in READY — planned on a thread of tokio's blocking pool (never on the
//! cyclic thread, never on the thread that serves the pages), one at a time, from where the tool
//! stands in the newest frame; stored in the run's library
//! ([`ScreenJobs`](pkm_api::screen_jobs::ScreenJobs)), then loaded and started as a press of the
//! screen's buttons, so that the PLC takes them as inputs (traced, replayed).
//!
//! A job's planning is bounded in what it may cost (`nc.max_moves`, `nc.max_plan_mib`) and how
//! long it may take (`nc.max_planning_s`), and is abandoned when the operator cancels it or the
//! machine leaves READY (a STOP). A job's plan is released once another job or program
//! replaces it, and freed on a thread of its own (freeing a gigabyte takes milliseconds).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use pkm_api::library::NcLibrary;
use pkm_api::offsets::WorkOffsets;
use pkm_api::screen_jobs::{ScreenJob, ScreenJobKind, ScreenJobSpec};
use pkm_api::trajectory::NcJob;

use crate::image::Value;

/// What plans the screen's jobs for the machine: the composition gives the configured machine's
/// planner; the desk only schedules, bounds and stores what it plans.
pub trait JobPlanner: Send + Sync + 'static {
    /// Plans `spec` into a job of `library`, within the configuration's bounds, asking
    /// `abandoned` now and then whether to give up (its answer says why); refused with why.
    fn plan(
        &self,
        library: &NcLibrary,
        spec: &ScreenJobSpec,
        abandoned: &(dyn Fn() -> Option<String> + Sync),
    ) -> Result<NcJob, String>;
}

/// Where the tool stands in a frame: the machine's pose at the image's set-points.
pub trait Standing: Send + Sync + 'static {
    /// The pose (machine frame; unused coordinates 0) at the set-points of `image`, if they have
    /// one.
    fn pose(&self, image: &[Value]) -> Option<[f64; 6]>;
}

/// The program MDI lines run as: the lines, then an end (M2).
pub fn mdi_program(lines: &str) -> String {
    format!("{}\nM2\n", lines.trim_end())
}

/// What the screen needs to make jobs: the machine's planner, the run's library, where the tool
/// stands.
pub struct JobDesk {
    planner: Arc<dyn JobPlanner>,
    library: NcLibrary,
    standing: Box<dyn Standing>,
    /// The image index of `NC_PROGRAM`, the loaded program (its job's plan is kept).
    program_var: Option<usize>,
    /// Where the tool stands commanded while the PLC is READY (from the newest frame).
    here: Mutex<Option<[f64; 6]>>,
    /// The newest frame's main state (shared with the watch of a job being planned).
    state: Arc<Mutex<String>>,
    /// A job is being planned.
    planning: AtomicBool,
    /// Why the job being planned is abandoned: the operator's Cancel, a STOP.
    cancel: Arc<Mutex<Option<&'static str>>>,
    /// The work offsets jobs are planned with now (a touch-off changes them).
    offsets: Mutex<WorkOffsets>,
    /// The ones the run's programs were planned with at its start.
    planned_with: WorkOffsets,
    /// Keeps the offsets across runs (writes the parameter file), if the run has a place for
    /// them; says why not.
    keep: Option<Keep>,
    /// Held by a touch-off from start to end: one at a time, each from the offsets the one
    /// before kept.
    touching: tokio::sync::Mutex<()>,
    /// The loaded program's number in the newest frame.
    loaded: Mutex<i16>,
    /// The run's tool table as the screen and the programs change it (`None`: the run has
    /// none).
    tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>,
}

/// What keeps the work offsets across runs: writes them, or says why it could not.
pub type Keep = Arc<dyn Fn(&WorkOffsets) -> Result<(), String> + Send + Sync>;

/// What was loaded before a step of the jog replaced it ([`JobDesk::loaded_for_return`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Loaded {
    /// A program of the run (from 1).
    Program(i16),
    /// A screen job, made again to load it (a run from a line: from where the step left the
    /// tool).
    Job(ScreenJobKind),
}

/// A touch-off made: the coordinate system's origin in the axis before and after.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TouchOff {
    /// The origin's coordinate before (machine frame).
    pub was: f64,
    /// After.
    pub now: f64,
}

/// A job made: its number, its file name and its text (as the screen shows it).
pub struct Made {
    /// Its number, as `NC_PROGRAM` holds it.
    pub number: i16,
    /// The job.
    pub job: NcJob,
}

/// Why the job being planned is abandoned, if it is: the operator's cancel or STOP, or the
/// machine left READY.
fn abandoned(cancel: &Mutex<Option<&'static str>>, state: &Mutex<String>) -> Option<String> {
    if let Some(why) = *cancel.lock().unwrap_or_else(|p| p.into_inner()) {
        return Some(format!("abandoned while it was being planned: {why}"));
    }
    let state = state.lock().unwrap_or_else(|p| p.into_inner());
    (*state != "READY").then(|| format!("abandoned while it was being planned: the machine left READY ({state})"))
}

impl JobDesk {
    /// The desk of a machine's `planner` and the run's `library`, reading the tool's pose from
    /// frames through `standing` and the loaded program from the image index `program_var`
    /// (`NC_PROGRAM`).
    pub fn new(
        planner: impl JobPlanner,
        library: NcLibrary,
        standing: impl Standing,
        program_var: Option<usize>,
        offsets: WorkOffsets,
        keep: Option<Keep>,
    ) -> JobDesk {
        JobDesk {
            planner: Arc::new(planner),
            library,
            standing: Box::new(standing),
            program_var,
            here: Mutex::new(None),
            state: Arc::new(Mutex::new(String::new())),
            planning: AtomicBool::new(false),
            cancel: Arc::new(Mutex::new(None)),
            offsets: Mutex::new(offsets),
            planned_with: offsets,
            keep,
            touching: tokio::sync::Mutex::new(()),
            loaded: Mutex::new(0),
            tools: None,
        }
    }

    /// The desk whose jobs are planned with `tools` as it changes.
    pub fn with_tools(mut self, tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>) -> JobDesk {
        self.tools = tools;
        self
    }

    /// The run's tool table as it changes, if it has one.
    pub fn tools(&self) -> Option<&Arc<crate::runtime::tool_table::ToolTableKeeper>> {
        self.tools.as_ref()
    }

    /// Whether the run's programs are planned again before they are loaded: a touch-off has
    /// changed the work offsets, or the tool table has changed, since they were planned.
    pub fn plans_changed(&self) -> bool {
        self.offsets_changed() || self.tools.as_ref().is_some_and(|t| t.changed())
    }

    /// The work offsets jobs are planned with now.
    pub fn offsets(&self) -> WorkOffsets {
        *self.offsets.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether a touch-off's offsets outlive the run (a parameter file keeps them).
    pub fn keeps_offsets(&self) -> bool {
        self.keep.is_some()
    }

    /// Whether a touch-off has changed the work offsets since the run's programs were planned:
    /// they are then planned again (as a run from their first line) before they are loaded.
    pub fn offsets_changed(&self) -> bool {
        self.offsets() != self.planned_with
    }

    /// The run's program (from 1) the loaded one runs: itself, or the program a run from a line
    /// runs; `None` for MDI lines or nothing loaded.
    pub fn loaded_program(&self) -> Option<i16> {
        match self.loaded_for_return()? {
            Loaded::Program(k) | Loaded::Job(ScreenJobKind::FromLine { program: k, .. }) => Some(k),
            Loaded::Job(ScreenJobKind::Mdi { .. }) => None,
        }
    }

    /// What is loaded now, so that it can be loaded again after a step of the jog (an MDI job
    /// of its own): a program of the run, or the kind of the screen job (a run from a line);
    /// `None` for MDI lines or nothing loaded.
    pub fn loaded_for_return(&self) -> Option<Loaded> {
        let k = self.loaded_number();
        match self.library.screen_spec(k).map(|s| &s.kind) {
            Some(kind @ ScreenJobKind::FromLine { .. }) => Some(Loaded::Job(kind.clone())),
            Some(ScreenJobKind::Mdi { .. }) => None,
            None => {
                (k >= 1 && usize::try_from(k).is_ok_and(|k| k <= self.library.jobs.len())).then_some(Loaded::Program(k))
            }
        }
    }

    /// The loaded program's number (`NC_PROGRAM`) in the newest frame.
    pub fn loaded_number(&self) -> i16 {
        *self.loaded.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Touches off: work coordinate system `system` (0: G54 … 5: G59) is moved in axis `axis`
    /// (0: x … 5: c) so that where the tool stands reads `value`, as G10 L20 would, and the
    /// offsets are kept (the parameter file). In READY only; refused, and nothing changed,
    /// when they cannot be kept. The file is written (and flushed to the disk) on a blocking
    /// thread with no lock held but the touch-offs' own: the screen's and OPC UA's thread, and
    /// whoever reads the offsets, go on meanwhile.
    pub async fn touch_off(&self, system: usize, axis: usize, value: f64) -> Result<TouchOff, String> {
        let _one = self.touching.lock().await;
        let Some(here) = *self.here.lock().unwrap_or_else(|p| p.into_inner()) else {
            let state = self.state.lock().unwrap_or_else(|p| p.into_inner()).clone();
            return Err(format!("a touch-off is made in READY: the machine is {state}"));
        };
        if system >= 6 || axis >= 6 {
            return Err("a touch-off names G54 … G59 and an axis of x y z a b c".into());
        }
        if !value.is_finite() || value.abs() > 1e5 {
            return Err(format!("a touch-off's value is a number within ±100 000, got {value}"));
        }
        let mut changed = self.offsets();
        let was = changed.origins[system][axis];
        let now = here[axis] - value;
        changed.origins[system][axis] = now;
        if let Some(keep) = self.keep.clone() {
            tokio::task::spawn_blocking(move || keep(&changed))
                .await
                .map_err(|e| format!("the parameter file's writer failed: {e}"))??;
        }
        *self.offsets.lock().unwrap_or_else(|p| p.into_inner()) = changed;
        Ok(TouchOff { was, now })
    }

    /// Sets a tool's entry in the run's tool table (`remove`: removes tool `tool.number`'s),
    /// from READY, as LinuxCNC's tool table editor does; written to the file on a blocking
    /// thread, one change at a time. Jobs made from then on, and programs loaded, are planned
    /// with the table as changed.
    pub async fn edit_tool(
        &self,
        tool: pkm_nc::tools::Tool,
        remove: bool,
    ) -> Result<crate::runtime::tool_table::Kept, String> {
        let Some(keeper) = self.tools.clone() else {
            return Err(
                "this run has no tool table (give one with --tool-table or nc.tool_table in the configuration)".into(),
            );
        };
        if self.here.lock().unwrap_or_else(|p| p.into_inner()).is_none() {
            let state = self.state.lock().unwrap_or_else(|p| p.into_inner()).clone();
            return Err(format!("the tool table is edited in READY: the machine is {state}"));
        }
        tokio::task::spawn_blocking(move || {
            if remove {
                keeper.remove(tool.number)
            } else {
                keeper.edit(tool)
            }
        })
        .await
        .map_err(|e| format!("the tool table's writer failed: {e}"))?
    }

    /// The run's library.
    pub fn library(&self) -> &NcLibrary {
        &self.library
    }

    /// Takes the newest frame: its main state, in READY where the tool stands, and the loaded
    /// program, by which the plans of replaced jobs are released (and freed on a thread of
    /// their own once nothing holds them: that thread, if one was started).
    pub fn observe(&self, state: &str, image: &[Value]) -> Option<std::thread::JoinHandle<()>> {
        let here = (state == "READY").then(|| self.standing.pose(image)).flatten();
        *self.here.lock().unwrap_or_else(|p| p.into_inner()) = here;
        {
            let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
            if *s != state {
                s.clear();
                s.push_str(state);
            }
        }
        let number = match self.program_var.and_then(|i| image.get(i)) {
            Some(Value::Int(k)) => *k,
            _ => 0,
        };
        *self.loaded.lock().unwrap_or_else(|p| p.into_inner()) = number;
        let loaded = self.library.screen_slot(number);
        free_elsewhere(self.library.screen.release_replaced(loaded))
    }

    /// Whether a job is being planned now.
    pub fn is_planning(&self) -> bool {
        self.planning.load(Ordering::Acquire)
    }

    /// Abandons the job being planned, if any, for `why` (the operator's Cancel, a STOP): its
    /// planning stops within milliseconds and the job is refused with why. True if one was.
    pub fn cancel(&self, why: &'static str) -> bool {
        let planning = self.is_planning();
        if planning {
            *self.cancel.lock().unwrap_or_else(|p| p.into_inner()) = Some(why);
        }
        planning
    }

    /// Makes the job `kind` from where the tool stands: checked and planned off the server's
    /// thread, stored in the library. Refused (with why) outside READY, while another job is
    /// being planned, when the job cannot run, passes its bounds, is cancelled or abandoned,
    /// and when the run has made all its jobs.
    pub async fn make(&self, kind: ScreenJobKind) -> Result<Made, String> {
        let Some(start) = *self.here.lock().unwrap_or_else(|p| p.into_inner()) else {
            let state = self.state.lock().unwrap_or_else(|p| p.into_inner()).clone();
            return Err(if state.is_empty() {
                "a job runs from READY: the PLC has not published its state yet".to_string()
            } else {
                format!("a job runs from READY: the machine is {state}")
            });
        };
        if self.planning.swap(true, Ordering::AcqRel) {
            return Err("another job is being planned (Cancel abandons it)".into());
        }
        *self.cancel.lock().unwrap_or_else(|p| p.into_inner()) = None;
        let mut at = [0.0; pkm_api::trajectory::MAX_AXES];
        at[..6].copy_from_slice(&start);
        let offsets = self.offsets();
        let spec = ScreenJobSpec {
            kind,
            start: at,
            offsets: (offsets != self.planned_with).then_some(offsets),
            tool_table: self.tools.as_ref().and_then(|t| t.changed_text()),
        };
        let (planner, library, asked) = (Arc::clone(&self.planner), self.library.clone(), spec.clone());
        let (cancel, state) = (Arc::clone(&self.cancel), Arc::clone(&self.state));
        let planned = tokio::task::spawn_blocking(move || {
            let abandon = move || abandoned(&cancel, &state);
            planner.plan(&library, &asked, &abandon)
        })
        .await;
        self.planning.store(false, Ordering::Release);
        let job = match planned {
            Ok(Ok(job)) => job,
            Ok(Err(why)) => return Err(why),
            // A panic of the planner is a bug; the PLC goes on and the job is refused.
            Err(e) => return Err(format!("the planner failed: {e}")),
        };
        let slot = self
            .library
            .screen
            .push(ScreenJob { spec, job: job.clone() })
            .map_err(|e| e.to_string())?;
        let number = self
            .library
            .screen_number(slot)
            .ok_or_else(|| "no number left for another job".to_string())?;
        Ok(Made { number, job })
    }
}

/// Drops `jobs` on a thread of its own and gives the memory back to the system: a plan may
/// take a gigabyte, and freeing it on the thread that serves the screen and OPC UA would hold
/// them up for milliseconds. The thread, if one was started (none for no jobs; without one,
/// the jobs are dropped here).
fn free_elsewhere(jobs: Vec<Arc<NcJob>>) -> Option<std::thread::JoinHandle<()>> {
    if jobs.is_empty() {
        return None;
    }
    let free = move || {
        drop(jobs);
        give_back_memory();
    };
    match std::thread::Builder::new().name("pkm-free-job".into()).spawn(free) {
        Ok(thread) => Some(thread),
        Err(e) => {
            tracing::warn!("freed a replaced job's plan on the screen's thread: no thread of its own ({e})");
            None
        }
    }
}

/// Returns the allocator's free memory to the system. glibc keeps freed blocks below its
/// mapping threshold (which grows to 32 MiB after a large block is freed) in its arenas, so a
/// plan's memory would otherwise stay in the process after it is freed.
fn give_back_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free memory of the allocator's own arenas; it takes no
    // pointer and is safe to call from any thread at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}
