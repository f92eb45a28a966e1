//! `pkm-plc kin MACHINE ...`: forward and inverse kinematics, workspace, benchmark and the
//! hexapod's Newton convergence, from the command line.

use std::time::Instant;

use serde_json::{Map, Value, json};

use pkm_kinematics::hexapod::Hexapod;
use pkm_kinematics::{Kinematics, KinematicsConfig, Machine, workspace};
use pkm_plc::runtime::config::ConfigError;

use super::Failure;
use super::args::{ConfigArg, KinArgs, KinOp};

/// A failure with exit code `code` (1 an input the model does not reach, 2 usage).
fn fail(code: u8, message: impl Into<String>) -> Failure {
    Failure {
        code,
        message: message.into(),
    }
}

/// Runs `pkm-plc kin`.
pub fn run(args: KinArgs) -> Result<(), Failure> {
    let loaded = super::load_config(&ConfigArg {
        config: args.config.clone(),
        machine: None,
    })
    .map_err(|e| fail(2, e.to_string()))?;
    let config = KinematicsConfig::from_section(loaded.config.kinematics.as_ref()).map_err(|problems| {
        fail(
            2,
            ConfigError::Invalid {
                file: loaded.origin.clone(),
                problems,
            }
            .to_string(),
        )
    })?;
    let kin = config.build(args.machine);
    let n = kin.dof();
    match args.op {
        KinOp::Fk { joints } => {
            expect_len(&joints, n, "joint values")?;
            let mut pose = [0.0; 6];
            kin.forward(&joints, None, &mut pose[..n])
                .map_err(|e| fail(1, e.to_string()))?;
            print_result(args.machine, kin.as_ref(), &joints, &pose[..n]);
        }
        KinOp::Ik { pose } => {
            expect_len(&pose, n, "pose values")?;
            let mut joints = [0.0; 6];
            kin.inverse(&pose, &mut joints[..n])
                .map_err(|e| fail(1, e.to_string()))?;
            print_result(args.machine, kin.as_ref(), &joints[..n], &pose);
        }
        KinOp::Workspace {
            svg,
            json,
            samples,
            threshold,
        } => {
            let ws = workspace::sample(&config, args.machine, samples, threshold);
            let picture = crate::cli::kin_svg::draw(&ws, kin.pose_keys())
                .map_err(|e| fail(1, format!("drawing the workspace: {e}")))?;
            std::fs::write(&svg, picture).map_err(|e| fail(1, format!("{}: cannot write: {e}", svg.display())))?;
            if let Some(path) = json {
                let text = serde_json::to_string(&ws).map_err(|e| fail(1, e.to_string()))?;
                std::fs::write(&path, text).map_err(|e| fail(1, format!("{}: cannot write: {e}", path.display())))?;
            }
            let summary = json!({
                "machine": ws.machine, "samples": ws.samples, "reachable": ws.points.len(),
                "rejected": ws.rejected, "bounds": ws.bounds, "min_measure": ws.min_measure,
                "svg": svg.display().to_string(),
            });
            println!("{summary}");
        }
        KinOp::Bench { seconds } => println!("{}", bench(&config, args.machine, kin.as_ref(), seconds)),
        KinOp::Convergence {
            samples,
            translation,
            rotation,
            seed,
        } => {
            if args.machine != Machine::Hexapod {
                return Err(fail(2, "convergence applies to the hexapod only"));
            }
            println!("{}", convergence(&config, samples, translation, rotation, seed));
        }
    }
    Ok(())
}

fn expect_len(values: &[f64], n: usize, what: &str) -> Result<(), Failure> {
    if values.len() == n {
        Ok(())
    } else {
        Err(fail(2, format!("expected {n} {what}, got {}", values.len())))
    }
}

fn print_result(machine: Machine, kin: &dyn Kinematics, joints: &[f64], pose: &[f64]) {
    let mut p = Map::new();
    for (k, v) in kin.pose_keys().iter().zip(pose) {
        p.insert((*k).to_string(), json!(v));
    }
    println!(
        "{}",
        json!({"machine": machine.name(), "joints": joints, "pose": Value::Object(p)})
    );
}

/// Calls per second of IK, FK and IK+FK over up to 1000 reachable poses of the workspace (for
/// the hexapod: 1000 random poses within ±50 mm / ±10° of home, as in `convergence`).
fn bench(config: &KinematicsConfig, machine: Machine, kin: &dyn Kinematics, seconds: f64) -> Value {
    let poses: Vec<[f64; 6]> = if machine == Machine::Hexapod {
        let mut uniform = xorshift(7);
        (0..1000)
            .map(|_| {
                let mut pose = config.hexapod.home;
                for (k, p) in pose.iter_mut().enumerate() {
                    *p += uniform() * if k < 3 { 50.0 } else { 10.0 };
                }
                pose
            })
            .collect()
    } else {
        let ws = workspace::sample(config, machine, 40, 0.0);
        ws.points
            .iter()
            .step_by((ws.points.len() / 1000).max(1))
            .map(|s| {
                let mut p = [0.0; 6];
                p[..s.pose.len()].copy_from_slice(&s.pose);
                p
            })
            .collect()
    };
    let n = kin.dof();
    let measure = |f: &mut dyn FnMut(&[f64; 6]) -> bool| {
        let start = Instant::now();
        let mut calls = 0u64;
        let mut failures = 0u64;
        while start.elapsed().as_secs_f64() < seconds {
            for p in &poses {
                if !f(std::hint::black_box(p)) {
                    failures += 1;
                }
            }
            calls += poses.len() as u64;
        }
        (calls as f64 / start.elapsed().as_secs_f64(), failures)
    };
    let joints: Vec<[f64; 6]> = poses
        .iter()
        .map(|p| {
            let mut q = [0.0; 6];
            let _ = kin.inverse(&p[..n], &mut q[..n]);
            q
        })
        .collect();
    let mut index = 0usize;
    let (ik, ik_fail) = measure(&mut |p| {
        let mut q = [0.0; 6];
        kin.inverse(&p[..n], &mut q[..n]).is_ok()
    });
    let (fk, fk_fail) = measure(&mut |_| {
        index = (index + 1) % joints.len();
        let mut x = [0.0; 6];
        // A hint near the answer, as a cyclic caller has: the previous cycle's pose, here 0.05 mm
        // and 0.01° away on every coordinate.
        let mut hint = poses[index];
        for (k, h) in hint.iter_mut().enumerate().take(n) {
            *h += if k < 3 { 0.05 } else { 0.01 };
        }
        kin.forward(&joints[index][..n], Some(&hint[..n]), &mut x[..n]).is_ok()
    });
    let (fk_home, _) = measure(&mut |_| {
        index = (index + 1) % joints.len();
        let mut x = [0.0; 6];
        kin.forward(&joints[index][..n], None, &mut x[..n]).is_ok()
    });
    let (pair, _) = measure(&mut |p| {
        let mut q = [0.0; 6];
        let mut x = [0.0; 6];
        kin.inverse(&p[..n], &mut q[..n]).is_ok() && kin.forward(&q[..n], None, &mut x[..n]).is_ok()
    });
    json!({
        "machine": machine.name(), "poses": poses.len(),
        "ik_per_s": ik.round(), "fk_per_s": fk.round(), "fk_from_home_per_s": fk_home.round(),
        "ik_plus_fk_per_s": pair.round(), "failures": ik_fail + fk_fail,
    })
}

/// The distribution of Newton iterations for FK from the home pose.
pub fn convergence(config: &KinematicsConfig, samples: usize, translation: f64, rotation: f64, seed: u64) -> Value {
    let hex = Hexapod::new(&config.hexapod);
    let home = config.hexapod.home;
    let mut uniform = xorshift(seed);
    let mut histogram = std::collections::BTreeMap::<usize, usize>::new();
    let mut failures = std::collections::BTreeMap::<String, usize>::new();
    let mut worst_error = 0.0f64;
    for _ in 0..samples {
        let mut pose = home;
        for (k, p) in pose.iter_mut().enumerate() {
            *p += uniform() * if k < 3 { translation } else { rotation };
        }
        let mut q = [0.0; 6];
        if let Err(e) = hex.inverse(&pose, &mut q) {
            *failures.entry(format!("ik: {e}")).or_default() += 1;
            continue;
        }
        let mut x = [0.0; 6];
        match hex.forward_counted(&q, None, &mut x) {
            Ok(it) => {
                *histogram.entry(it).or_default() += 1;
                worst_error = x.iter().zip(&pose).fold(worst_error, |w, (a, b)| w.max((a - b).abs()));
            }
            Err(e) => *failures.entry(e.to_string()).or_default() += 1,
        }
    }
    json!({
        "machine": "hexapod", "samples": samples, "translation_mm": translation, "rotation_deg": rotation,
        "iterations": histogram, "failures": failures, "worst_pose_error": worst_error,
    })
}

/// A seeded xorshift generator of numbers uniform in [−1, 1): reproducible pose sets.
fn xorshift(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed.max(1);
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}
