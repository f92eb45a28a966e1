//! A planned path for TOPP-RA (`tools/toppra_bench.py`): its elements sampled densely, every
//! sample's joints and world axes with limits through the machine's inverse kinematics, with its
//! program line and programmed feed, in pieces from stop to stop; and the limits.

use pkm_kinematics::frame::MachineFrame;
use pkm_nc::plan::{Plan, PlanLimits};
use serde_json::json;

/// Samples at most this far apart along an element (mm, or degrees where only rotations move).
const SPACING: f64 = 0.02;
/// Samples an element has at the least: a blend of a few hundredths of a millimetre keeps its
/// curvature.
const LEAST: usize = 16;

/// `plan`'s path on `frame` within `limits`, as JSON for `tools/toppra_bench.py`.
pub fn export(plan: &Plan, frame: &MachineFrame, limits: &PlanLimits) -> Result<serde_json::Value, String> {
    let n = frame.dof();
    // The coordinates that bound the motion: world axes with limits, then the joints.
    let axes: Vec<usize> = (0..6)
        .filter(|&c| limits.axis_speed[c].is_finite() || limits.axis_accel[c].is_finite())
        .collect();
    let mut speed: Vec<f64> = axes.iter().map(|&c| limits.axis_speed[c]).collect();
    let mut accel: Vec<f64> = axes.iter().map(|&c| limits.axis_accel[c]).collect();
    speed.extend(&limits.joint_speed[..n]);
    accel.extend(&limits.joint_accel[..n]);
    let finite = |v: &[f64]| {
        v.iter()
            .map(|x| if x.is_finite() { *x } else { 1e9 })
            .collect::<Vec<_>>()
    };
    let mut pieces = Vec::new();
    let (mut s_all, mut q_all, mut lines, mut feeds) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut s0 = 0.0;
    let mut joints = vec![0.0; n];
    for e in plan.elements() {
        let len = e.segment.length();
        let count = ((len / SPACING).ceil() as usize).max(LEAST);
        for i in 0..=count {
            let u = i as f64 / count as f64;
            let pose = e.segment.at(u);
            frame
                .inverse(&pose[..n], &mut joints)
                .map_err(|err| format!("line {}: {err}", e.line))?;
            let mut q: Vec<f64> = axes.iter().map(|&c| pose[c]).collect();
            q.extend(&joints);
            s_all.push(s0 + len * u);
            q_all.push(q);
            lines.push(e.line);
            feeds.push(e.feed.is_finite().then_some(e.feed));
        }
        s0 += len;
        if e.stop_after {
            pieces.push(json!({
                "s": std::mem::take(&mut s_all),
                "q": std::mem::take(&mut q_all),
                "line": std::mem::take(&mut lines),
                "feed": std::mem::take(&mut feeds),
            }));
        }
    }
    if !s_all.is_empty() {
        pieces.push(json!({"s": s_all, "q": q_all, "line": lines, "feed": feeds}));
    }
    Ok(json!({"speed": finite(&speed), "accel": finite(&accel), "pieces": pieces}))
}
