//! Workspace sampling: the reachable set of a machine as data and as an SVG picture.
//!
//! Planar and 3-DOF machines are sampled over their joint travel (FK of a grid); the hexapod over
//! a grid of positions at its home height and orientation (IK). A sample counts as reachable when
//! its transformation succeeds, every joint is inside its travel and the singularity measure is
//! at least the threshold (for the O-X glide also the minimum rod angle).

use std::collections::BTreeMap;

use serde::Serialize;

use super::ox::{Configuration, OxGlide};
use super::{KinError, KinematicsConfig, Machine};

/// One reachable sample.
#[derive(Clone, Debug, Serialize)]
pub struct Sample {
    /// Joint values (mm).
    pub joints: Vec<f64>,
    /// Pose (mm, degrees).
    pub pose: Vec<f64>,
    /// Singularity measure at the pose.
    pub measure: f64,
}

/// The result of sampling.
#[derive(Clone, Debug, Serialize)]
pub struct Workspace {
    /// The machine.
    pub machine: &'static str,
    /// The pose coordinates the picture shows (horizontal, vertical).
    pub plot_axes: [&'static str; 2],
    /// Samples tried.
    pub samples: usize,
    /// Why samples were rejected, with counts.
    pub rejected: BTreeMap<String, usize>,
    /// Per pose coordinate: [min, max] over the reachable samples.
    pub bounds: BTreeMap<&'static str, [f64; 2]>,
    /// Smallest singularity measure among the reachable samples.
    pub min_measure: f64,
    /// The reachable samples.
    pub points: Vec<Sample>,
}

fn reason(e: &KinError) -> String {
    match e {
        KinError::JointOutOfRange { .. } => "joint out of travel".into(),
        other => other.to_string(),
    }
}

/// Samples `machine`'s workspace with `per_axis` samples along each sampled axis.
pub fn sample(config: &KinematicsConfig, machine: Machine, per_axis: usize, threshold: f64) -> Workspace {
    let kin = config.build(machine);
    let n = kin.dof();
    let per_axis = per_axis.max(2);
    let ox = match machine {
        Machine::OxX => Some(OxGlide::new(&config.ox_x, Configuration::X)),
        Machine::OxO => Some(OxGlide::new(&config.ox_o, Configuration::O)),
        _ => None,
    };
    let plot_axes: [usize; 2] = match machine {
        Machine::Trijoint | Machine::Hexapod => [0, 1],
        Machine::Pn101 => [1, 2],
        Machine::OxX | Machine::OxO => [0, 2],
    };
    let mut ws = Workspace {
        machine: machine.name(),
        plot_axes: [kin.pose_keys()[plot_axes[0]], kin.pose_keys()[plot_axes[1]]],
        samples: 0,
        rejected: BTreeMap::new(),
        bounds: BTreeMap::new(),
        min_measure: f64::INFINITY,
        points: Vec::new(),
    };
    let lerp = |[lo, hi]: [f64; 2], i: usize| lo + (hi - lo) * i as f64 / (per_axis - 1) as f64;
    let mut candidates: Vec<([f64; 6], [f64; 6])> = Vec::new();
    match machine {
        Machine::Hexapod => {
            // Positions at the home height and orientation, ±400 mm around the home pose.
            let home = config.hexapod.home;
            for i in 0..per_axis {
                for j in 0..per_axis {
                    let mut pose = home;
                    pose[0] += lerp([-400.0, 400.0], i);
                    pose[1] += lerp([-400.0, 400.0], j);
                    let mut q = [0.0; 6];
                    ws.samples += 1;
                    match kin.inverse(&pose, &mut q) {
                        Ok(()) => candidates.push((q, pose)),
                        Err(e) => *ws.rejected.entry(reason(&e)).or_default() += 1,
                    }
                }
            }
        }
        _ => {
            // A grid over the joint travel; the O-X glide's serial axis stays at mid travel.
            let limits = kin.joint_limits();
            let sampled = if ox.is_some() { 2 } else { n };
            let total = per_axis.pow(sampled as u32);
            for k in 0..total {
                let mut q = [0.0; 6];
                let mut rest = k;
                for (axis, limit) in limits.iter().enumerate().take(n) {
                    q[axis] = if axis < sampled {
                        let i = rest % per_axis;
                        rest /= per_axis;
                        lerp(*limit, i)
                    } else {
                        (limit[0] + limit[1]) / 2.0
                    };
                }
                let mut pose = [0.0; 6];
                ws.samples += 1;
                match kin.forward(&q[..n], None, &mut pose[..n]) {
                    Ok(()) => candidates.push((q, pose)),
                    Err(e) => *ws.rejected.entry(reason(&e)).or_default() += 1,
                }
            }
        }
    }
    for (q, pose) in candidates {
        if let Some(ox) = &ox
            && !ox.rod_angles_ok(&pose)
        {
            *ws.rejected.entry("rod angle below the minimum".into()).or_default() += 1;
            continue;
        }
        match kin.singularity_measure(&pose[..n]) {
            Ok(m) if m >= threshold => {
                ws.min_measure = ws.min_measure.min(m);
                for (k, key) in kin.pose_keys().iter().enumerate() {
                    let b = ws.bounds.entry(key).or_insert([f64::INFINITY, f64::NEG_INFINITY]);
                    b[0] = b[0].min(pose[k]);
                    b[1] = b[1].max(pose[k]);
                }
                ws.points.push(Sample {
                    joints: q[..n].to_vec(),
                    pose: pose[..n].to_vec(),
                    measure: m,
                });
            }
            Ok(_) => {
                *ws.rejected
                    .entry("singularity measure below the threshold".into())
                    .or_default() += 1
            }
            Err(e) => *ws.rejected.entry(reason(&e)).or_default() += 1,
        }
    }
    if ws.points.is_empty() {
        ws.min_measure = 0.0;
    }
    ws
}
