//! The jobs the operator makes on the screen while the PLC runs (MDI lines, a program run from
//! a chosen line), each planned off the cyclic path and stored in a slot of its own.
//!
//! What a job was made of (its [`ScreenJobSpec`] and file name) stays for the whole run: a trace
//! records it, a replay plans it again, the screen shows it. Its plan, which may take hundreds
//! of megabytes, is released once the job is replaced: another job was made after it, or another
//! program was loaded after it had been (see [`ScreenJobs::release_replaced`]). Until then the
//! cyclic programs take it from its slot without a lock and without allocating
//! ([`arc_swap`]).
//!
//! No job is ever freed on the cyclic thread. A released plan waits in the slots' keeping until
//! nothing else holds it (the executor and the main program keep a reference to the loaded
//! program until they load another); the runtime looks again off the cyclic path and frees it
//! there. The cyclic programs only ever drop a reference that is not the last.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use arc_swap::ArcSwapOption;

use crate::trajectory::{MAX_AXES, NcJob};

/// The most jobs the screen makes in one run (their specs stay until the run ends; their plans
/// only while they may run): MDI lines, runs from a line, the steps of the incremental jog and the
/// programs planned again after a touch-off count. About 600 bytes of slot each, made at start.
pub const MAX_SCREEN_JOBS: usize = 10_000;

/// What a screen job is made of: enough to plan it again (a replay does).
#[derive(Clone, Debug, PartialEq)]
pub struct ScreenJobSpec {
    /// MDI lines, or a program of the library from a line.
    pub kind: ScreenJobKind,
    /// Where the tool stood when the job was made: where it starts (machine frame).
    pub start: [f64; MAX_AXES],
    /// The work offsets it was planned with, where they were not the run's at its start (a
    /// touch-off changed them).
    pub offsets: Option<crate::offsets::WorkOffsets>,
    /// The tool table it was planned with (its text, LinuxCNC's format), where it was not the
    /// run's at its start (an entry edited on the screen, a program's `G10 L1`).
    pub tool_table: Option<String>,
}

/// The kinds of screen jobs.
#[derive(Clone, Debug, PartialEq)]
pub enum ScreenJobKind {
    /// Lines typed on the screen (MDI), run as a program that ends after them.
    Mdi {
        /// The lines.
        text: String,
    },
    /// A program of the library from a line on: the tool goes to where that line's motion
    /// begins first.
    FromLine {
        /// The program's number (from 1; one of the library's programs).
        program: i16,
        /// The line (1-based).
        line: u32,
    },
}

/// A planned screen job, as it is stored.
#[derive(Clone, Debug)]
pub struct ScreenJob {
    /// What it was made of.
    pub spec: ScreenJobSpec,
    /// The job.
    pub job: NcJob,
}

/// One job's slot.
struct Slot {
    /// What the job was made of and its file name: kept for the run.
    made: OnceLock<(ScreenJobSpec, String)>,
    /// Its plan while it may run; empty before it is made and once it is released.
    job: ArcSwapOption<NcJob>,
    /// It was the loaded program in a frame the runtime looked at.
    was_loaded: AtomicBool,
}

/// The jobs the operator makes while the PLC runs (see the module's documentation).
pub struct ScreenJobs {
    slots: Box<[Slot]>,
    /// The next free slot (only the makers of jobs take it).
    next: Mutex<usize>,
    /// Released plans that something may still hold: freed off the cyclic path once nothing
    /// else does.
    released: Mutex<Vec<Arc<NcJob>>>,
}

/// Why a screen job was not stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ScreenJobsError {
    /// Every slot is taken.
    Full,
    /// The slot was taken already (a replay's trace that gives a job twice).
    Taken(usize),
}

impl std::fmt::Display for ScreenJobsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ScreenJobsError::Full => write!(
                f,
                "the run has made its {MAX_SCREEN_JOBS} screen jobs: restart the PLC for more"
            ),
            ScreenJobsError::Taken(i) => write!(f, "screen job {} was made already", i + 1),
        }
    }
}

impl std::error::Error for ScreenJobsError {}

impl Default for ScreenJobs {
    fn default() -> Self {
        ScreenJobs::new()
    }
}

impl ScreenJobs {
    /// Room for [`MAX_SCREEN_JOBS`] jobs, none made.
    pub fn new() -> ScreenJobs {
        ScreenJobs {
            slots: (0..MAX_SCREEN_JOBS)
                .map(|_| Slot {
                    made: OnceLock::new(),
                    job: ArcSwapOption::empty(),
                    was_loaded: AtomicBool::new(false),
                })
                .collect(),
            next: Mutex::new(0),
            released: Mutex::new(Vec::new()),
        }
    }

    /// The plan of the job in slot `i`, if it was made and is not released. Lock-free and
    /// allocation-free (the cyclic programs call it); dropping what it gives never frees the
    /// job (the slot, or the keeping of released plans, holds it too).
    pub fn job(&self, i: usize) -> Option<Arc<NcJob>> {
        self.slots.get(i)?.job.load_full()
    }

    /// Whether slot `i` holds a plan (made and not released). Lock-free and allocation-free.
    pub fn has_job(&self, i: usize) -> bool {
        self.slots.get(i).is_some_and(|s| s.job.load().is_some())
    }

    /// What the job in slot `i` was made of, if it was made (kept after its plan is released).
    pub fn spec(&self, i: usize) -> Option<&ScreenJobSpec> {
        self.slots.get(i)?.made.get().map(|(spec, _)| spec)
    }

    /// The file name the job in slot `i` is shown with, if it was made.
    pub fn file(&self, i: usize) -> Option<&str> {
        self.slots.get(i)?.made.get().map(|(_, file)| file.as_str())
    }

    /// Stores `job` in the next free slot; its slot.
    pub fn push(&self, job: ScreenJob) -> Result<usize, ScreenJobsError> {
        let mut next = self.next.lock().unwrap_or_else(|p| p.into_inner());
        let i = *next;
        self.set(i, job)?;
        *next = i + 1;
        Ok(i)
    }

    /// Stores `job` in slot `i` (a replay puts each job where the run had it).
    pub fn set(&self, i: usize, job: ScreenJob) -> Result<(), ScreenJobsError> {
        let slot = self.slots.get(i).ok_or(ScreenJobsError::Full)?;
        slot.made
            .set((job.spec, job.job.file.clone()))
            .map_err(|_| ScreenJobsError::Taken(i))?;
        slot.job.store(Some(Arc::new(job.job)));
        Ok(())
    }

    /// How many slots are filled, from the first.
    pub fn made(&self) -> usize {
        self.slots.iter().take_while(|s| s.made.get().is_some()).count()
    }

    /// How many plans are held: in their slots, and released ones that something still holds.
    pub fn held(&self) -> usize {
        let kept = self.released.lock().unwrap_or_else(|p| p.into_inner()).len();
        kept + self.slots.iter().filter(|s| s.job.load().is_some()).count()
    }

    /// Releases the plans of the jobs that were replaced, as a frame in which the loaded program
    /// is in slot `loaded` (`None`: a program of the library, or none) shows them: a job is
    /// replaced when a later job was made, or when another program is loaded after it had been.
    /// The job loaded now, and the newest job before it was ever loaded, keep theirs.
    ///
    /// Returns the plans that nothing else holds any more, for the caller to drop off the cyclic
    /// path (freeing hundreds of megabytes takes milliseconds); the others are kept until a
    /// later call finds them free.
    pub fn release_replaced(&self, loaded: Option<usize>) -> Vec<Arc<NcJob>> {
        if let Some(slot) = loaded.and_then(|i| self.slots.get(i)) {
            slot.was_loaded.store(true, Ordering::Relaxed);
        }
        let newest = self.made().checked_sub(1);
        let mut released = self.released.lock().unwrap_or_else(|p| p.into_inner());
        for (i, slot) in self.slots.iter().enumerate().take(newest.map_or(0, |n| n + 1)) {
            let replaced = Some(i) != loaded && (Some(i) != newest || slot.was_loaded.load(Ordering::Relaxed));
            if replaced && let Some(job) = slot.job.swap(None) {
                released.push(job);
            }
        }
        // Free once nothing else holds the job or its trajectory: holding neither, nobody can
        // take a new reference (the slot is empty), so this one is the last.
        let (free, kept): (Vec<_>, Vec<_>) = std::mem::take(&mut *released)
            .into_iter()
            .partition(|job| Arc::strong_count(job) == 1 && Arc::strong_count(&job.trajectory) == 1);
        *released = kept;
        free
    }
}

impl std::fmt::Debug for ScreenJobs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScreenJobs")
            .field("made", &self.made())
            .field("held", &self.held())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::{Trajectory, TrajectoryEvent, TrajectorySample};

    /// A trajectory that stands still.
    struct Still;

    impl Trajectory for Still {
        fn dof(&self) -> usize {
            2
        }
        fn duration_s(&self) -> f64 {
            1.0
        }
        fn length_mm(&self) -> f64 {
            0.0
        }
        fn sample(&self, _t: f64, _cursor: &mut usize) -> TrajectorySample {
            TrajectorySample::default()
        }
        fn events(&self) -> &[TrajectoryEvent] {
            &[]
        }
        fn block_end(&self, _s: f64) -> Option<(f64, f64)> {
            None
        }
        fn forward(&self, _joints: &[f64], _hint: &[f64; MAX_AXES], _pose: &mut [f64; MAX_AXES]) -> bool {
            false
        }
        fn path_distance(&self, _pose: &[f64; MAX_AXES], _t: f64) -> f64 {
            0.0
        }
    }

    fn job(text: &str) -> ScreenJob {
        ScreenJob {
            spec: ScreenJobSpec {
                kind: ScreenJobKind::Mdi { text: text.into() },
                start: [0.0; MAX_AXES],
                offsets: None,
                tool_table: None,
            },
            job: NcJob {
                file: "MDI".into(),
                text: text.into(),
                trajectory: Arc::new(Still),
            },
        }
    }

    #[test]
    fn a_job_is_released_once_replaced_and_freed_once_nothing_holds_it() {
        let jobs = ScreenJobs::new();
        let first = jobs.push(job("G1 X1")).expect("room");
        // Made, not yet loaded: the newest keeps its plan.
        assert!(jobs.release_replaced(None).is_empty());
        assert!(jobs.has_job(first));
        // Loaded: the executor takes its trajectory.
        assert!(jobs.release_replaced(Some(first)).is_empty());
        let executing = jobs.job(first).map(|j| Arc::clone(&j.trajectory)).expect("a plan");
        // A second job is made and loaded: the first is released, but the executor still
        // holds its trajectory, so it is kept.
        let second = jobs.push(job("G1 X2")).expect("room");
        assert!(jobs.release_replaced(Some(second)).is_empty());
        assert!(!jobs.has_job(first) && jobs.job(first).is_none());
        assert_eq!(jobs.held(), 2);
        // What it was made of stays.
        assert_eq!(
            jobs.spec(first).map(|s| &s.kind),
            Some(&ScreenJobKind::Mdi { text: "G1 X1".into() })
        );
        assert_eq!(jobs.file(first), Some("MDI"));
        // The executor loads the second: the first is free, and handed over to be dropped.
        drop(executing);
        let free = jobs.release_replaced(Some(second));
        assert_eq!(free.len(), 1);
        assert_eq!(free[0].text, "G1 X1");
        assert_eq!(jobs.held(), 1);
        // A library program loaded after the second: the second is released too.
        assert_eq!(jobs.release_replaced(None).len(), 1);
        assert_eq!((jobs.held(), jobs.made()), (0, 2));
    }

    #[test]
    fn a_job_made_after_one_that_never_loaded_replaces_it() {
        let jobs = ScreenJobs::new();
        let first = jobs.push(job("G1 X1")).expect("room");
        let second = jobs.push(job("G1 X2")).expect("room");
        assert_eq!(jobs.release_replaced(None).len(), 1);
        assert!(!jobs.has_job(first) && jobs.has_job(second));
        // A replay puts a job where the run had it, once.
        assert_eq!(
            jobs.set(second, job("G1 X3")).err(),
            Some(ScreenJobsError::Taken(second))
        );
    }
}
