//! A planned program held against the machine and the program, from outside the planner: its
//! duration finite; every joint's and limited world axis' speed and acceleration within the
//! limits, from the plan's poses sampled through the inverse kinematics; every sampled tool point
//! within the blend tolerance of the programmed path; and its motion's time no shorter than the
//! time-optimal motion along its path (`optimal.rs`) and within a goal above it.

use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;
use pkm_nc::interp::{Action, Blend, Program};
use pkm_nc::path::Segment;
use pkm_nc::plan::{PLAIN_G64_MM, Plan, PlanLimits};

use super::optimal;

/// How far past a limit a sampled speed or acceleration may be: 0.5 %.
pub const LIMIT_TOLERANCE: f64 = 0.005;
/// The planned motion's time against the time-optimal one: at most this much above it.
pub const TIME_GOAL: f64 = 1.01;
/// How far the time-optimal lower bound may be off its own grid (a share of it): it refines
/// its grid where the speed or a cap changes fast, and converges to within a few parts in ten
/// thousand (0.5 % was allowed while it did not, on the hexapod's turns on short moves).
pub const REFERENCE_ROUNDING: f64 = 0.001;

/// What the check measured.
#[derive(Clone, Debug, Default)]
pub struct Measured {
    /// The plan's motion time (s, dwells excluded).
    pub planned_s: f64,
    /// The time-optimal motion's (s), and with every limit 0.5 % looser (a lower bound).
    pub optimal_s: f64,
    pub lower_bound_s: f64,
    /// The highest sampled speed and acceleration over their limits (any coordinate).
    pub speed_ratio: f64,
    pub accel_ratio: f64,
    /// The largest distance of a sampled tool point from the programmed path (mm), and what
    /// the program's blending allows.
    pub off_path_mm: f64,
    pub tolerance_mm: f64,
}

/// How far from the programmed path the program lets the tool pass at the most (mm): 0 where
/// every move stops exactly; else the largest G64 P (1 mm without one) and Q (P without one):
/// lines merged within Q of their vertices, and the merged line's corners rounded within P.
fn tolerance(program: &Program) -> f64 {
    program
        .blocks
        .iter()
        .filter_map(|b| match b.action {
            Action::Move {
                blend: Blend::Within { tolerance, merge },
                ..
            } => {
                let p = tolerance.unwrap_or(PLAIN_G64_MM);
                Some(p + merge.unwrap_or(p))
            }
            _ => None,
        })
        .fold(0.0, f64::max)
}

/// A programmed move as the path check sees it: points along it, and the box they lie in.
struct Move {
    segment: Segment,
    points: Vec<[f64; 3]>,
    /// Its box, grown by the most a chord of the points strays from the move.
    low: [f64; 3],
    high: [f64; 3],
}

/// How many of the probes spread over the plan look at its distance from the programmed path
/// (the path is smooth between them; all look at the speeds and accelerations).
const PATH_PROBES: usize = 2000;
/// How many chords a move is looked at in before the nearest point is refined.
const CHORDS: u32 = 64;

impl Move {
    fn new(segment: Segment) -> Move {
        let points: Vec<[f64; 3]> = (0..=CHORDS)
            .map(|i| {
                let p = segment.at(f64::from(i) / f64::from(CHORDS));
                [p[0], p[1], p[2]]
            })
            .collect();
        // A chord of an arc strays at most r (1 − cos(φ / 2)) ≤ (chord length)² / (8 r) from it:
        // the chord length itself bounds it.
        let chord = segment.linear_length() / f64::from(CHORDS);
        let low = std::array::from_fn(|c| points.iter().map(|p| p[c]).fold(f64::INFINITY, f64::min) - chord);
        let high = std::array::from_fn(|c| points.iter().map(|p| p[c]).fold(f64::NEG_INFINITY, f64::max) + chord);
        Move {
            segment,
            points,
            low,
            high,
        }
    }

    /// The distance from `p` to the move's box.
    fn to_box(&self, p: &[f64; 3]) -> f64 {
        (0..3)
            .map(|c| (self.low[c] - p[c]).max(p[c] - self.high[c]).max(0.0).powi(2))
            .sum::<f64>()
            .sqrt()
    }
}

/// The distance from the tool point `p` (x y z) to the programmed path (its moves), exact where
/// it is more than `within`, else at most that.
fn off_path(p: &[f64; 3], moves: &[Move], within: f64) -> f64 {
    let d3 = |q: &[f64; 3]| ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
    let d = |q: &[f64; 6]| d3(&[q[0], q[1], q[2]]);
    let mut best = f64::INFINITY;
    for m in moves {
        if m.to_box(p) > best {
            continue;
        }
        if !m.segment.is_arc() {
            // A line: the distance to it, straight.
            let (a, b) = (m.segment.from(), m.segment.to());
            let d: [f64; 3] = std::array::from_fn(|c| b[c] - a[c]);
            let len2: f64 = d.iter().map(|x| x * x).sum();
            let t = if len2 > 0.0 {
                ((0..3).map(|c| (p[c] - a[c]) * d[c]).sum::<f64>() / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            best = best.min(d3(&std::array::from_fn(|c| a[c] + t * d[c])));
            continue;
        }
        // The nearest of its points, then a golden-section search either side of every point
        // not farther than the nearest by a chord's length (a closed circle's start and end,
        // say): the distance is unimodal within two chords of a point.
        let near = m.points.iter().map(d3).fold(f64::INFINITY, f64::min);
        if near <= within {
            // Within the tolerance already: nothing to refine.
            best = best.min(near);
            continue;
        }
        let chord = m.segment.linear_length() / f64::from(CHORDS);
        let steps = f64::from(CHORDS);
        const INVERSE_PHI: f64 = 0.618_033_988_749_894_9;
        for (k, _) in m.points.iter().enumerate().filter(|(_, q)| d3(q) <= near + chord) {
            let (mut a, mut b) = ((k as f64 - 1.0).max(0.0) / steps, (k as f64 + 1.0).min(steps) / steps);
            let (mut m1, mut m2) = (b - INVERSE_PHI * (b - a), a + INVERSE_PHI * (b - a));
            let (mut d1, mut d2) = (d(&m.segment.at(m1)), d(&m.segment.at(m2)));
            // 30 steps narrow two chords to a millionth of one: far below the tolerances.
            for _ in 0..30 {
                if d1 <= d2 {
                    (b, m2, d2) = (m2, m1, d1);
                    m1 = b - INVERSE_PHI * (b - a);
                    d1 = d(&m.segment.at(m1));
                } else {
                    (a, m1, d1) = (m1, m2, d2);
                    m2 = a + INVERSE_PHI * (b - a);
                    d2 = d(&m.segment.at(m2));
                }
            }
            best = best.min(d1.min(d2));
        }
        best = best.min(near);
    }
    best
}

/// Checks `plan` (of `program`, on `frame` within `limits`), its speeds and accelerations at
/// `probes` instants spread over it (every millisecond of a shorter plan) and around the end of
/// every line's motion; the first failure is the error.
pub fn check(
    plan: &Plan,
    program: &Program,
    frame: &MachineFrame,
    limits: &PlanLimits,
    probes: usize,
) -> Result<Measured, String> {
    let n = frame.dof();
    let mut m = Measured {
        planned_s: plan.duration_s - plan.dwell_s,
        tolerance_mm: tolerance(program),
        ..Measured::default()
    };
    if !plan.duration_s.is_finite() || plan.duration_s < 0.0 {
        return Err(format!("the planned duration is {} s", plan.duration_s));
    }
    let moves: Vec<Move> = program
        .blocks
        .iter()
        .filter_map(|b| match b.action {
            Action::Move { from, to, path, .. } => Some(Move::new(Segment::new(from, to, path))),
            _ => None,
        })
        .collect();
    // Probes: every millisecond of a short plan, at most `probes` evenly spread over a long
    // one, and around every end of a line's motion; at each, the speed and acceleration from
    // the poses half a millisecond either side.
    let h = 0.0005;
    let count = ((plan.duration_s / 0.001).ceil() as usize).min(probes);
    let mut times: Vec<f64> = (0..=count)
        .map(|i| plan.duration_s * i as f64 / count.max(1) as f64)
        .collect();
    let mut s = 0.0;
    while let Some((end, t)) = plan.block_end(s) {
        times.extend((-5..=5).map(|k| t + f64::from(k) * 0.001));
        if end <= s {
            break;
        }
        s = end;
    }
    let coordinates: Vec<(usize, f64, f64)> = (0..n.min(6))
        .filter(|&c| limits.axis_speed[c].is_finite() || limits.axis_accel[c].is_finite())
        .map(|c| (c, limits.axis_speed[c], limits.axis_accel[c]))
        .chain((0..n).map(|j| (6 + j, limits.joint_speed[j], limits.joint_accel[j])))
        .collect();
    let mut cursor = 0;
    let mut at = |t: f64| -> Result<([f64; 6 + MAX_DOF], f64), String> {
        let sample = plan.sample(t.clamp(0.0, plan.duration_s + 1.0), &mut cursor);
        if !sample.pose.iter().all(|x| x.is_finite()) {
            return Err(format!("the pose at {t:.4} s is not a number: {sample:?}"));
        }
        let mut y = [0.0; 6 + MAX_DOF];
        y[..6].copy_from_slice(&sample.pose);
        frame
            .inverse(&sample.pose[..n], &mut y[6..6 + n])
            .map_err(|e| format!("the pose at {t:.4} s has no joints: {e}"))?;
        Ok((y, sample.s))
    };
    let path_every = (count / PATH_PROBES).max(1);
    for (i, &t) in times.iter().enumerate() {
        let ((a, _), (b, s), (c, _)) = (at(t - h)?, at(t)?, at(t + h)?);
        for &(k, speed, accel) in &coordinates {
            let v = (c[k] - a[k]) / (2.0 * h);
            let acc = (c[k] - 2.0 * b[k] + a[k]) / (h * h);
            m.speed_ratio = m.speed_ratio.max(v.abs() / speed);
            m.accel_ratio = m.accel_ratio.max(acc.abs() / accel);
            if v.abs() > speed * (1.0 + LIMIT_TOLERANCE) + 1e-6 || acc.abs() > accel * (1.0 + LIMIT_TOLERANCE) + 1e-3 {
                let name = if k < 6 {
                    format!("axis {}", "XYZABC".as_bytes()[k] as char)
                } else {
                    format!("joint {}", k - 5)
                };
                return Err(format!(
                    "at {t:.4} s ({s:.4} mm along the path) {name} moves at {v:.4}/s (limit {speed}) and accelerates at {acc:.3}/s² (limit {accel})"
                ));
            }
        }
        // The path at most every PATH_EVERY-th probe (and around the ends of lines).
        if moves.is_empty() || (i % path_every != 0 && i <= count) {
            continue;
        }
        let off = off_path(&[b[0], b[1], b[2]], &moves, m.tolerance_mm);
        m.off_path_mm = m.off_path_mm.max(off);
        if off > m.tolerance_mm + 1e-6 {
            return Err(format!(
                "at {t:.4} s ({s:.4} mm along the path) the tool point {:.5} {:.5} {:.5} is {off:.6} mm off the programmed path (tolerance {} mm)",
                b[0], b[1], b[2], m.tolerance_mm
            ));
        }
    }
    let spacing = (plan.length_mm / 20_000.0).clamp(0.005, 0.02);
    let reference = optimal::optimal(plan, frame, limits, spacing, LIMIT_TOLERANCE)?;
    m.optimal_s = reference.time_s;
    m.lower_bound_s = reference.lower_bound_s;
    // The reference's own grid rounds its time, by a few parts in ten thousand at the most.
    if m.planned_s < m.lower_bound_s * (1.0 - REFERENCE_ROUNDING) - 1e-6 {
        return Err(format!(
            "planned {:.6} s, less than the time-optimal lower bound {:.6} s",
            m.planned_s, m.lower_bound_s
        ));
    }
    if m.planned_s > TIME_GOAL * m.optimal_s + 1e-3 {
        return Err(format!(
            "planned {:.6} s, {:.4}× the time-optimal {:.6} s (goal: {TIME_GOAL}×)",
            m.planned_s,
            m.planned_s / m.optimal_s,
            m.optimal_s
        ));
    }
    Ok(m)
}
