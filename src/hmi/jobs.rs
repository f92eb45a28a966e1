//! The screen's jobs (issue 27): MDI lines and a program run from a chosen line, made on the
//! operator's command in READY — planned on tokio's blocking pool (never on the cyclic thread,
//! never on the thread that serves the pages), one at a time, from where the tool stands in the
//! newest frame; stored in the run's library ([`ScreenJobs`](pkm_api::trajectory::ScreenJobs)),
//! then loaded and started as a press of the screen's buttons, so that the PLC takes them as
//! inputs (traced, replayed).

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use pkm_api::trajectory::{NcJob, NcLibrary, ScreenJob, ScreenJobKind, ScreenJobSpec};

use crate::compose::Setup;
use crate::image::Value;
use crate::screen_job::{self, StandingPose};

/// What the screen needs to make jobs: the machine, the run's library, where the tool stands.
pub struct JobDesk {
    setup: Setup,
    library: NcLibrary,
    standing: StandingPose,
    /// Where the tool stands commanded while the PLC is READY (from the newest frame).
    here: Mutex<Option<[f64; 6]>>,
    /// The newest frame's main state.
    state: Mutex<String>,
    /// A job is being planned.
    planning: AtomicBool,
}

/// A job made: its number, its file name and its text (as the screen shows it).
pub struct Made {
    /// Its number, as `NC_PROGRAM` holds it.
    pub number: i16,
    /// The job.
    pub job: NcJob,
}

impl JobDesk {
    /// The desk of `setup`'s machine and the run's `library`, reading the tool's pose from
    /// frames through `standing`.
    pub fn new(setup: Setup, library: NcLibrary, standing: StandingPose) -> JobDesk {
        JobDesk {
            setup,
            library,
            standing,
            here: Mutex::new(None),
            state: Mutex::new(String::new()),
            planning: AtomicBool::new(false),
        }
    }

    /// The run's library.
    pub fn library(&self) -> &NcLibrary {
        &self.library
    }

    /// Takes the newest frame: its main state and, in READY, where the tool stands.
    pub fn observe(&self, state: &str, image: &[Value]) {
        let here = (state == "READY").then(|| self.standing.pose(image)).flatten();
        *self.here.lock().unwrap_or_else(|p| p.into_inner()) = here;
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        if *s != state {
            s.clear();
            s.push_str(state);
        }
    }

    /// Makes the job `kind` from where the tool stands: checked and planned off the server's
    /// thread, stored in the library. Refused (with why) outside READY, while another job is
    /// being planned, when the job cannot run, and when the run has made all its jobs.
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
            return Err("another job is being planned".into());
        }
        let mut at = [0.0; pkm_api::trajectory::MAX_AXES];
        at[..6].copy_from_slice(&start);
        let spec = ScreenJobSpec { kind, start: at };
        let (setup, library, asked) = (self.setup.clone(), self.library.clone(), spec.clone());
        let planned = tokio::task::spawn_blocking(move || screen_job::plan(&setup, &library, &asked)).await;
        self.planning.store(false, Ordering::Release);
        let job = match planned {
            Ok(Ok(job)) => job,
            Ok(Err(e)) => return Err(e.message),
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
