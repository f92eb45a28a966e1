//! The planner's property test at length: random ordinary programs (`shared/random_programs.rs`)
//! prepared on each machine as shipped (read, checked, planned and verified, as `nc check` does)
//! and held against the machine and the program from outside (`shared/plan_check.rs`): finite,
//! every joint within its limits through the kinematics, the path within the blend tolerance,
//! the time no shorter than the time-optimal lower bound and within the goal above the optimum.
//! A failure is shrunk to its smallest program and printed.
//!
//! `cargo run --release --example plan_soak -- [--cases N] [--threads T] [--seed S] [MACHINE…]`
//! (every machine by default; N programs a machine and thread; the run's counts at the end).

#[path = "shared/optimal.rs"]
mod optimal;
#[path = "shared/plan_check.rs"]
mod plan_check;
#[path = "shared/random_programs.rs"]
mod random_programs;
#[path = "shared/shipped.rs"]
mod shipped;

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};

use pkm_plc::compose::{Setup, nc_job};

/// How often (programs planned on a machine) a long run says how far it is.
const PROGRESS_EVERY: u64 = 10_000;

/// What the run counted, per machine.
#[derive(Default)]
struct Counts {
    planned: AtomicU64,
    unreachable: AtomicU64,
    refused_text: AtomicU64,
    /// The worst ratios seen (×1e6), for the report.
    worst_time: AtomicU64,
    best_time: AtomicU64,
    worst_accel: AtomicU64,
    worst_speed: AtomicU64,
}

fn setup_of(machine: &str) -> Setup {
    shipped::setup(machine).unwrap_or_else(|e| {
        eprintln!("plan_soak: {e}");
        std::process::exit(2);
    })
}

/// One program on `setup`'s machine: Ok with nothing to say, Ok after counting a skip, or the
/// failure.
fn one(setup: &Setup, text: &str, counts: &Counts) -> Result<(), String> {
    let prepared = match nc_job::prepare_text(setup, "random.ngc".into(), text.to_string()) {
        Ok(p) => p,
        Err(e) if e.code == 2 => {
            counts.refused_text.fetch_add(1, Ordering::Relaxed);
            return Ok(());
        }
        Err(e) => return Err(format!("refused: {}", e.message)),
    };
    let Some(plan) = &prepared.plan else {
        counts.unreachable.fetch_add(1, Ordering::Relaxed);
        return Ok(());
    };
    let limits = nc_job::plan_limits(setup, &prepared.motion, prepared.frame.dof());
    let m = plan_check::check(plan, &prepared.program, &prepared.frame, &limits, 10_000)?;
    let planned = counts.planned.fetch_add(1, Ordering::Relaxed) + 1;
    if planned.is_multiple_of(PROGRESS_EVERY) {
        // A long run says how far it is (its counts stand even if it is stopped).
        eprintln!("  … {planned} planned");
    }
    let ratio = if m.optimal_s > 0.0 {
        m.planned_s / m.optimal_s
    } else {
        1.0
    };
    counts.worst_time.fetch_max((ratio * 1e6) as u64, Ordering::Relaxed);
    counts.best_time.fetch_min((ratio * 1e6) as u64, Ordering::Relaxed);
    counts
        .worst_accel
        .fetch_max((m.accel_ratio * 1e6) as u64, Ordering::Relaxed);
    counts
        .worst_speed
        .fetch_max((m.speed_ratio * 1e6) as u64, Ordering::Relaxed);
    Ok(())
}

fn main() {
    let mut args = std::env::args().skip(1);
    let (mut cases, mut threads, mut seed) = (1000u32, 2usize, 1u64);
    let mut names: Vec<String> = Vec::new();
    while let Some(a) = args.next() {
        let mut value = |what: &str| {
            args.next().and_then(|v| v.parse::<u64>().ok()).unwrap_or_else(|| {
                eprintln!("plan_soak: {what} needs a number");
                std::process::exit(2);
            })
        };
        match a.as_str() {
            "--cases" => cases = value("--cases") as u32,
            "--threads" => threads = value("--threads") as usize,
            "--seed" => seed = value("--seed"),
            _ => names.push(a),
        }
    }
    if names.is_empty() {
        names = ["trijoint", "pn101", "ox-x", "ox-o", "hexapod"]
            .map(String::from)
            .to_vec();
    }
    let failures = Mutex::new(Vec::new());
    let started = std::time::Instant::now();
    for name in &names {
        let setup = setup_of(name);
        let axes = random_programs::Axes {
            z: name != "trijoint",
            rotations: name == "hexapod",
        };
        let counts = Counts {
            best_time: AtomicU64::new(u64::MAX),
            ..Counts::default()
        };
        std::thread::scope(|scope| {
            for thread in 0..threads {
                let (setup, counts, failures) = (&setup, &counts, &failures);
                scope.spawn(move || {
                    let mut key = [0u8; 32];
                    key[..8].copy_from_slice(&seed.to_le_bytes());
                    key[8..16].copy_from_slice(&(thread as u64).to_le_bytes());
                    // Every byte of the machine's name (ox-x and ox-o once drew the same programs).
                    let salt = name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
                        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
                    });
                    key[16..24].copy_from_slice(&salt.to_le_bytes());
                    let mut runner = TestRunner::new_with_rng(
                        Config {
                            cases,
                            failure_persistence: None,
                            max_shrink_iters: 2000,
                            ..Config::default()
                        },
                        TestRng::from_seed(RngAlgorithm::ChaCha, &key),
                    );
                    let result = runner.run(&random_programs::program(axes, 14), |text| {
                        one(setup, &text, counts).map_err(TestCaseError::fail)
                    });
                    if let Err(e) = result {
                        failures.lock().map(|mut f| f.push(format!("{name}: {e}"))).ok();
                    }
                });
            }
        });
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        println!(
            "{name:<9} {} planned, {} unreachable, {} refused as text; time ÷ optimum {:.4} … {:.4}; speed ≤ {:.4}, acceleration ≤ {:.4} of the limits ({:.0} s)",
            get(&counts.planned),
            get(&counts.unreachable),
            get(&counts.refused_text),
            get(&counts.best_time) as f64 / 1e6,
            get(&counts.worst_time) as f64 / 1e6,
            get(&counts.worst_speed) as f64 / 1e6,
            get(&counts.worst_accel) as f64 / 1e6,
            started.elapsed().as_secs_f64()
        );
    }
    let failures = failures.into_inner().unwrap_or_default();
    for f in &failures {
        println!("FAILED {f}");
    }
    if !failures.is_empty() {
        std::process::exit(1);
    }
}
