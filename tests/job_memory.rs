//! The memory of the screen's jobs: each MDI job of fifty thousand moves plans about 20 MB; a
//! run that kept every job's plan would hold more than half a gigabyte after thirty of them. Here
//! the O-X glide runs in virtual time as the screen drives it — a job made from where the tool stands,
//! loaded and started, the program stopped, the error acknowledged, the machine READY again —
//! and after thirty jobs the process holds no more than 50 MB above what it held after the
//! third: each job's plan is released once the next replaces it, and freed.
//!
//! A binary of its own (no test harness): its resident memory is its own, not that of other
//! tests running beside it. `PKM_JOB_MEMORY_JOBS` and `PKM_JOB_MEMORY_PAIRS` change the number
//! of jobs and each job's pairs of moves (the default: 30 jobs of 25 000 pairs).

#[path = "common/mod.rs"]
mod common;

use pkm_api::screen_jobs::ScreenJobKind;
use pkm_plc::compose::screen_job::StandingPose;
use pkm_plc::compose::{self, Built, Options, Setup};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::VirtualClock;
use pkm_plc::services::hmi::commands::{CommandSink, press};
use pkm_plc::services::hmi::jobs::JobDesk;

/// Jobs made (`PKM_JOB_MEMORY_JOBS` makes more: the hundred, in a release build).
const JOBS: usize = 30;
/// The job after which the memory is first measured (the allocator and the runtime warmed up).
const BASELINE_AFTER: usize = 3;
/// The most the memory may grow from there (bytes): the bound for a hundred jobs.
const MAX_GROWTH: u64 = 50 << 20;
/// Each job's pairs of moves from where the tool stands and back (`PKM_JOB_MEMORY_PAIRS` makes
/// larger jobs, up to the bound of a million moves).
const PAIRS: usize = 25_000;

/// A number from the environment variable `name`, or `default`.
fn setting(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// The process's resident memory (bytes).
fn resident() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .expect("VmRSS in kB")
        * 1024
}

/// The PLC in virtual time with the screen's desk looking at every main cycle's image, as the
/// screen's server does with every frame.
struct Run {
    plc: Plc,
    clock: VirtualClock,
    desk: JobDesk,
    sink: CommandSink,
}

impl Run {
    /// Runs until the main state is `state` (at most `max_s` of simulated time).
    fn until(&mut self, state: &str, max_s: u64) {
        let end = self.plc.next_release() + max_s * 1_000_000_000;
        while common::state(&self.plc) != state {
            assert!(
                self.plc.next_release() < end,
                "not {state} within {max_s} s: {}",
                common::state(&self.plc)
            );
            let t = self.plc.next_release();
            self.clock.advance_to(t);
            self.plc.run_due(&mut self.clock, u64::MAX);
            if let Some(freeing) = self.desk.observe(common::state(&self.plc), self.plc.global_image()) {
                freeing.join().expect("the plan is freed");
            }
        }
    }
}

fn main() {
    let setup = Setup::new(common::machine_config("ox-x", |_| {})).expect("ox-x");
    let options = Options {
        hmi: true,
        ..Options::default()
    };
    let Built {
        setup,
        plc,
        library,
        hmi,
        ..
    } = compose::build(setup, options).unwrap_or_else(|e| panic!("{e}"));
    let (library, sink) = (library.expect("a library"), hmi.expect("the screen's inputs"));
    let standing = StandingPose::of(&setup, &plc).expect("the set-points");
    let loaded = plc
        .vars()
        .index_of(pkm_api::trajectory::vars::NC_PROGRAM.name())
        .map(usize::from);
    let desk = JobDesk::new(
        setup.clone(),
        library.clone(),
        standing,
        loaded,
        setup.persistent(3),
        None,
    );
    let mut run = Run {
        plc,
        clock: VirtualClock::default(),
        desk,
        sink,
    };
    run.plc.init(0, &mut run.clock);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    run.until("READY", 30);
    let (jobs, pairs) = (
        setting("PKM_JOB_MEMORY_JOBS", JOBS),
        setting("PKM_JOB_MEMORY_PAIRS", PAIRS),
    );
    let job = format!("F6000\no1 repeat [{pairs}]\nG91 G1 X1\nG1 X-1\no1 endrepeat\nG90");
    let mut baseline = 0;
    let mut peak = 0;
    for k in 1..=jobs {
        let made = runtime
            .block_on(run.desk.make(ScreenJobKind::Mdi { text: job.clone() }))
            .unwrap_or_else(|e| panic!("job {k}: {e}"));
        peak = peak.max(resident());
        run.sink.update(|c| {
            c.program = made.number;
            c.presses[press::NC[0]] += 1;
        });
        drop(made);
        run.until("AUTO", 5);
        // STOP in the program's first moves, the error acknowledged: READY again.
        run.sink.update(|c| c.presses[press::STOP] += 1);
        run.until("ERROR", 5);
        run.sink.update(|c| c.acknowledgements += 1);
        run.until("READY", 60);
        let held = library.screen.held();
        assert!(
            held <= 2,
            "after job {k}: {held} plans held (the loaded job's, and at most the one before)"
        );
        if k == BASELINE_AFTER {
            baseline = resident();
        }
    }
    let end = resident();
    let growth = end.saturating_sub(baseline);
    println!(
        "job_memory: {jobs} jobs of {} moves; resident {} MB after job {BASELINE_AFTER}, {} MB after job {jobs} ({:+.1} MB), at most {} MB with a job just planned",
        2 * pairs,
        baseline >> 20,
        end >> 20,
        (end as f64 - baseline as f64) / (1 << 20) as f64,
        peak >> 20
    );
    assert!(
        growth <= MAX_GROWTH,
        "the resident memory grew by {} MB over {} jobs (at most {} MB)",
        growth >> 20,
        jobs - BASELINE_AFTER,
        MAX_GROWTH >> 20
    );
}
