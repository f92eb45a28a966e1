//! The NC programs of a run: those planned before the PLC is built, and the screen's jobs made
//! while it runs, numbered as `vars::NC_PROGRAM` holds them and looked up without a lock.

use std::sync::Arc;

use crate::screen_jobs::{ScreenJobSpec, ScreenJobs};
use crate::trajectory::{NcJob, Trajectory};

/// A program of an [`NcLibrary`]: one of its programs, or a screen job's plan (shared with its
/// slot, so that it lives while this does).
pub enum JobRef<'a> {
    /// One of the library's programs.
    Program(&'a NcJob),
    /// A screen job.
    Screen(Arc<NcJob>),
}

impl std::ops::Deref for JobRef<'_> {
    type Target = NcJob;

    fn deref(&self) -> &NcJob {
        match self {
            JobRef::Program(job) => job,
            JobRef::Screen(job) => job,
        }
    }
}

/// The NC programs of a run, each read, checked and planned against the machine before the PLC
/// is built: the one loaded at start first, then those the operator may load instead (`run
/// --programs DIR`, from the screen); after them the jobs the operator makes on the screen
/// while the PLC runs ([`ScreenJobs`]: MDI lines, a program run from a chosen line). The main
/// program chooses which one is loaded (`vars::NC_PROGRAM`), never while one runs; the drive
/// program executes that one.
#[derive(Clone, Debug)]
pub struct NcLibrary {
    /// The programs; the first is loaded at start. Shared: the programs that hold the library
    /// (the main program, the drive program, the screen, the recorder) share one copy of the
    /// texts, which may be megabytes.
    pub jobs: Arc<[NcJob]>,
    /// The program loaded at start starts by itself at the first READY (`run --program`).
    pub autostart: bool,
    /// The screen's jobs, numbered after `jobs`.
    pub screen: Arc<ScreenJobs>,
    /// Laser mode: the S word of the beam's full power (`nc.laser.s_max`); `None`: a spindle.
    pub laser_s_max: Option<f64>,
}

impl NcLibrary {
    /// A library of `jobs` (the first starts by itself at the first READY if `autostart`),
    /// with room for the screen's jobs.
    pub fn new(jobs: Vec<NcJob>, autostart: bool) -> NcLibrary {
        NcLibrary {
            jobs: jobs.into(),
            autostart,
            screen: Arc::new(ScreenJobs::new()),
            laser_s_max: None,
        }
    }

    /// The library in laser mode, full power at S = `s_max` (`None`: a spindle).
    pub fn with_laser(mut self, s_max: Option<f64>) -> NcLibrary {
        self.laser_s_max = s_max;
        self
    }

    /// The program of the (1-based) number `k` as `vars::NC_PROGRAM` holds it: one of `jobs`,
    /// or a screen job made and not released. Lock-free and allocation-free (the cyclic programs
    /// call it); dropping what it gives never frees the job.
    pub fn numbered(&self, k: i16) -> Option<JobRef<'_>> {
        match self.screen_slot(k) {
            Some(slot) => self.screen.job(slot).map(JobRef::Screen),
            None => self
                .jobs
                .get(usize::try_from(k).ok()?.checked_sub(1)?)
                .map(JobRef::Program),
        }
    }

    /// The trajectory of program `k` (as [`Self::numbered`]), for the cyclic programs to hold
    /// while they run it: a reference count more, no allocation.
    pub fn trajectory(&self, k: i16) -> Option<Arc<dyn Trajectory>> {
        self.numbered(k).map(|job| Arc::clone(&job.trajectory))
    }

    /// Whether program `k` can be loaded: one of `jobs`, or a screen job made and not
    /// released. Lock-free and allocation-free.
    pub fn has(&self, k: i16) -> bool {
        match self.screen_slot(k) {
            Some(slot) => self.screen.has_job(slot),
            None => usize::try_from(k)
                .ok()
                .and_then(|k| k.checked_sub(1))
                .is_some_and(|i| i < self.jobs.len()),
        }
    }

    /// The slot of screen job number `k` (a number past the library's programs), made or not.
    pub fn screen_slot(&self, k: i16) -> Option<usize> {
        usize::try_from(k).ok()?.checked_sub(self.jobs.len() + 1)
    }

    /// What screen job number `k` was made of, if it was made (kept after its plan is
    /// released).
    pub fn screen_spec(&self, k: i16) -> Option<&ScreenJobSpec> {
        self.screen.spec(self.screen_slot(k)?)
    }

    /// The number `vars::NC_PROGRAM` gives the screen job in slot `slot`.
    pub fn screen_number(&self, slot: usize) -> Option<i16> {
        i16::try_from(self.jobs.len() + slot + 1).ok()
    }
}
