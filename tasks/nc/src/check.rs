//! The check of a program before it moves (docs/nc.md): every point of its path, sampled at most
//! 0.1 mm and 0.1° apart, must lie inside the world limits, be reachable by the inverse
//! kinematics with every joint inside its software limits, and keep the singularity measure at
//! or above the threshold. A failure names the program line, the point and the condition. The
//! report also gives the path length and the bounding box. (Whether the joints' speed and
//! acceleration suffice at the programmed feed is the planner's to say.)

use pkm_kinematics::frame::MachineFrame;
use pkm_kinematics::{LIMIT_TOLERANCE_MM, MAX_DOF};

use crate::interp::block::{AXES, Action, Pose, Program};
use crate::path::Segment;
use crate::watch::{Stopped, Unwatched, Watch, Watched};

/// Samples of a path lie at most this far apart (mm, and degrees for rotations).
pub const SAMPLE_SPACING: f64 = 0.1;

/// Where the tool may go.
pub struct Limits<'a> {
    /// The machine's kinematics in its machine frame.
    pub frame: &'a MachineFrame,
    /// The joints' software limits, `[min, max]` (mm).
    pub soft: &'a [[f64; 2]],
    /// The world limits per coordinate of the machine frame, `[min, max]`.
    pub world: &'a [[f64; 2]],
    /// The singularity measure's lower bound.
    pub singularity_threshold: f64,
}

/// A point of the path the machine cannot take.
#[derive(Clone, Debug, PartialEq)]
pub struct Unreachable {
    /// The program line of the move.
    pub line: usize,
    /// The point (machine world coordinates).
    pub pose: Pose,
    /// Which condition fails.
    pub why: String,
}

/// What the check found.
#[derive(Clone, Debug, PartialEq)]
pub struct Report {
    /// The moves.
    pub moves: usize,
    /// Their length along the path (mm): feed moves, and rapids.
    pub feed_length_mm: f64,
    /// … rapids.
    pub rapid_length_mm: f64,
    /// The smallest and largest value of each coordinate over the path (the machine's
    /// coordinates; `None` without moves).
    pub bounding_box: Option<Vec<[f64; 2]>>,
    /// The first unreachable point of each move that has one, in program order.
    pub unreachable: Vec<Unreachable>,
}

/// Why `pose` is not allowed, if it is not: the first condition that fails.
pub fn why_not(limits: &Limits<'_>, pose: &Pose) -> Option<String> {
    let n = limits.frame.dof();
    let keys = limits.frame.kinematics().pose_keys();
    for (c, [lo, hi]) in limits.world.iter().enumerate().take(n) {
        if !(*lo..=*hi).contains(&pose[c]) {
            return Some(format!(
                "{} = {:.3} is outside the world limits {lo} … {hi}",
                keys[c].to_uppercase(),
                pose[c]
            ));
        }
    }
    let mut joints = [0.0; MAX_DOF];
    if let Err(e) = limits.frame.inverse(&pose[..n], &mut joints[..n]) {
        return Some(e.to_string());
    }
    for (j, (q, [lo, hi])) in joints[..n].iter().zip(limits.soft).enumerate() {
        // As the kinematics do: a limit reached to rounding is inside.
        if !(lo - LIMIT_TOLERANCE_MM..=hi + LIMIT_TOLERANCE_MM).contains(q) {
            return Some(format!(
                "joint {} = {q:.3} mm is outside its software limits {lo} … {hi} mm",
                j + 1
            ));
        }
    }
    match limits.frame.singularity_measure(&pose[..n]) {
        Ok(s) if s >= limits.singularity_threshold => None,
        Ok(s) => Some(format!(
            "the singularity measure {s:.4} is below the threshold {}",
            limits.singularity_threshold
        )),
        Err(e) => Some(e.to_string()),
    }
}

/// Checks every point of `program`'s path against `limits`.
pub fn check(program: &Program, limits: &Limits<'_>) -> Report {
    match check_watched(program, limits, &Unwatched) {
        Ok(report) => report,
        Err(_) => unreachable!("an unwatched check is never stopped"),
    }
}

/// [`check`], asking `watch` every [`crate::watch::WATCH_EVERY`] samples whether to go on.
pub fn check_watched(program: &Program, limits: &Limits<'_>, watch: &dyn Watch) -> Result<Report, Stopped> {
    let mut watched = Watched::new(watch);
    let n = limits.frame.dof();
    let mut report = Report {
        moves: 0,
        feed_length_mm: 0.0,
        rapid_length_mm: 0.0,
        bounding_box: None,
        unreachable: Vec::new(),
    };
    let mut bbox: Vec<[f64; 2]> = Vec::new();
    let mut first = true;
    for block in &program.blocks {
        let Action::Move {
            from,
            to,
            path,
            feed_mm_min,
            ..
        } = block.action
        else {
            continue;
        };
        report.moves += 1;
        let segment = Segment::new(from, to, path);
        let length = segment.length();
        if feed_mm_min.is_some() {
            report.feed_length_mm += length;
        } else {
            report.rapid_length_mm += length;
        }
        let samples = ((segment.linear_length().max(segment.angular()) / SAMPLE_SPACING).ceil() as usize).max(1);
        let begin = if first { 0 } else { 1 };
        first = false;
        // The box takes every sample of the path; a move is reported at its first unreachable
        // one.
        let mut reported = false;
        for i in begin..=samples {
            watched.step().map_err(|why| Stopped { line: block.line, why })?;
            let pose = segment.at(i as f64 / samples as f64);
            if bbox.is_empty() {
                bbox = (0..n).map(|c| [pose[c], pose[c]]).collect();
            }
            for (c, b) in bbox.iter_mut().enumerate() {
                b[0] = b[0].min(pose[c]);
                b[1] = b[1].max(pose[c]);
            }
            if reported {
                continue;
            }
            if let Some(why) = why_not(limits, &pose) {
                report.unreachable.push(Unreachable {
                    line: block.line,
                    pose,
                    why,
                });
                reported = true;
            }
        }
    }
    if !bbox.is_empty() {
        report.bounding_box = Some(bbox);
    }
    Ok(report)
}

/// A pose as `X1.000 Y2.000 Z3.000` over the machine's `n` coordinates.
pub fn format_pose(pose: &Pose, n: usize) -> String {
    let parts: Vec<String> = (0..n).map(|c| format!("{}{:.3}", AXES[c], pose[c])).collect();
    parts.join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interp::{Machine, read};

    fn frame(model: pkm_kinematics::Machine) -> MachineFrame {
        MachineFrame::default_for(model).expect("the default home is a pose")
    }

    fn report(model: pkm_kinematics::Machine, text: &str) -> Report {
        let f = frame(model);
        let soft: Vec<[f64; 2]> = f
            .kinematics()
            .joint_limits()
            .iter()
            .map(|[l, h]| [l + 2.0, h - 2.0])
            .collect();
        let n = f.dof();
        let world = vec![[-1000.0, 1000.0]; n];
        let program = read(
            // A program ends (M2); what follows an end is never read.
            &format!("{text}\nM2"),
            &Machine {
                block_delete: false,
                axes: f.kinematics().pose_keys(),
                start: [0.0; 6],
                work_offsets: [[0.0; 6]; 6],
                homes: [[0.0; 6]; 2],
                tools: None,
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        check(
            &program,
            &Limits {
                frame: &f,
                soft: &soft,
                world: &world,
                singularity_threshold: 0.05,
            },
        )
    }

    #[test]
    fn a_circle_inside_the_workspace_passes_with_its_length_and_box() {
        let r = report(
            pkm_kinematics::Machine::OxX,
            "G0 X10 Y0\nG1 Z-5 F300\nG3 X10 Y0 I-10 J0\nG0 Z0\nM2\n",
        );
        assert!(r.unreachable.is_empty(), "{:?}", r.unreachable);
        assert_eq!(r.moves, 4);
        assert!(
            (r.feed_length_mm - (5.0 + 20.0 * std::f64::consts::PI)).abs() < 1e-9,
            "{}",
            r.feed_length_mm
        );
        assert!((r.rapid_length_mm - 15.0).abs() < 1e-9);
        let b = r.bounding_box.expect("a box");
        // The box of the samples: within r(1 − cos(Δ/2r)) ≈ 0.000125 mm of the circle's.
        assert!((b[0][0] + 10.0).abs() < 1e-3 && (b[0][1] - 10.0).abs() < 1e-9, "{b:?}");
        assert!((b[1][0] + 10.0).abs() < 1e-3 && (b[1][1] - 10.0).abs() < 1e-3, "{b:?}");
        assert_eq!(b[2], [-5.0, 0.0]);
    }

    #[test]
    fn an_unreachable_point_is_named_with_its_line_and_condition() {
        // pn101's first joint leaves its travel long before x = 200 mm. Every move with such a
        // point is named: here the way out and the way back.
        let r = report(pkm_kinematics::Machine::Pn101, "G1 X1 F100\nG1 X200\nG1 X0\n");
        let lines: Vec<usize> = r.unreachable.iter().map(|u| u.line).collect();
        assert_eq!(lines, [2, 3], "{:?}", r.unreachable);
        let u = &r.unreachable[0];
        assert!(
            (u.pose[0] - 58.1).abs() < 1e-9,
            "the first sample past the border: {:?}",
            u.pose
        );
        assert_eq!(u.why, "joint 1 = 58.100 mm is outside its software limits -58 … 58 mm");
        assert_eq!(format_pose(&u.pose, 3), "X58.100 Y0.000 Z0.000");
        // The hexapod's tilts: reachable a few degrees, not 80.
        let r = report(pkm_kinematics::Machine::Hexapod, "G1 A5 B-5 F100\nG1 A80\n");
        assert_eq!(r.unreachable.len(), 1, "{:?}", r.unreachable);
        assert_eq!(r.unreachable[0].line, 2);
    }

    #[test]
    fn the_box_is_the_whole_paths_where_it_leaves_the_workspace() {
        // Out to x = 500 mm (the O-X glide reaches ±120), then back to y = 40.
        let r = report(
            pkm_kinematics::Machine::OxX,
            "G0 X10 Y5\nG1 X500 Y-30 F600\nG1 X20 Y40\n",
        );
        assert_eq!(r.unreachable.len(), 2, "{:?}", r.unreachable);
        let b = r.bounding_box.expect("a box");
        assert_eq!([b[0], b[1]], [[0.0, 500.0], [-30.0, 40.0]], "{b:?}");
    }
}
