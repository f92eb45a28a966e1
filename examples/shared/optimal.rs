//! The time-optimal motion along a planned path: the physical limit a planner is judged against.
//!
//! An outside reference, written apart from the planner and sharing none of its code: the plan's
//! path (its elements' geometry, feeds and stops) is sampled on a fine grid, every sample taken
//! through the machine's inverse kinematics, and the joints' and world axes' first and second
//! derivatives along the path estimated from the kinematics a step either side. On that grid the
//! fastest motion that keeps every speed and acceleration limit, and the feed as a limit on the
//! path speed, is found by reachability analysis (TOPP-RA: Pham and Pham, "A new approach to
//! time-optimal path parameterization based on reachability analysis", IEEE T-RO 2018): the
//! largest controllable speed at each sample from the end backwards, then the greedy fastest
//! speed forwards. Between two samples the speed squared changes in proportion to the distance;
//! where the speed changes by more than 2 % from one sample to the next (a ramp from rest or
//! from a slow corner), or the speed is at a cap that changes by more than 2 % (a joint whose
//! rate along the path changes fast), the grid is refined there and the motion found again,
//! until it does not: the time converges as the grid gets finer (a coarse grid can be off
//! either way, by a per cent where a cap curves between two samples).
//!
//! With every limit loosened by a share (0.5 %, say) it is a lower bound of the time any motion
//! along the path takes that keeps the limits to within that share: a planner's time must not
//! fall below it.

use pkm_kinematics::MAX_DOF;
use pkm_kinematics::frame::MachineFrame;
use pkm_nc::plan::{Element, Plan, PlanLimits};

/// The time-optimal motion's duration along `plan`'s path, and per program line.
#[allow(dead_code)] // each user reads what it needs
pub struct Optimal {
    /// Its duration (s), dwells excluded.
    pub time_s: f64,
    /// The same with every limit loosened by the share asked for: a lower bound (s).
    pub lower_bound_s: f64,
    /// Per program line that moves: (line, time spent on it), in path order.
    pub per_line: Vec<(usize, f64)>,
    /// How many samples the final grid had.
    pub samples: usize,
    /// The motion's speed (mm/s) at every sample, by its distance along the path (mm).
    pub speeds: Vec<(f64, f64)>,
}

/// Speeds changing by more than this from one sample to the next refine the grid there.
const SMOOTH: f64 = 1.02;
/// The most refinements.
const ROUNDS: usize = 12;
/// Below this a coordinate does not move along the path.
const STILL: f64 = 1e-12;

/// A sample of the path: where, and the derivatives of every coordinate there.
struct Sample {
    /// Distance along the path (mm).
    s: f64,
    element: usize,
    /// The fraction of its element.
    u: f64,
    /// The tool must stand here (the start, an exact stop, the end).
    stop: bool,
    /// Per bounding coordinate: its first and second derivative along the path.
    d: Vec<(f64, f64)>,
}

/// The speed and acceleration limits per coordinate (world axes first, then joints): only those
/// that bound something.
fn coordinate_limits(limits: &PlanLimits, n: usize) -> Vec<(usize, f64, f64)> {
    let mut out = Vec::new();
    for c in 0..n.min(6) {
        if limits.axis_speed[c].is_finite() || limits.axis_accel[c].is_finite() {
            out.push((c, limits.axis_speed[c], limits.axis_accel[c]));
        }
    }
    for j in 0..n {
        out.push((6 + j, limits.joint_speed[j], limits.joint_accel[j]));
    }
    out
}

/// What the path and the machine are: its elements, where each starts, the kinematics, the
/// bounding coordinates, the grid's step.
struct Path<'a> {
    elements: &'a [Element],
    starts: Vec<f64>,
    frame: &'a MachineFrame,
    coords: Vec<(usize, f64, f64)>,
    spacing: f64,
}

impl Path<'_> {
    /// The sample at fraction `u` of element `k`.
    fn sample(&self, k: usize, u: f64) -> Result<Sample, String> {
        let n = self.frame.dof();
        let e = &self.elements[k];
        let len = e.segment.length();
        let value = |u: f64| -> Result<[f64; 6 + MAX_DOF], String> {
            let pose = e.segment.at_extended(u);
            let mut y = [0.0; 6 + MAX_DOF];
            y[..6].copy_from_slice(&pose);
            self.frame
                .inverse(&pose[..n], &mut y[6..6 + n])
                .map_err(|err| format!("line {}: the path leaves the workspace: {err}", e.line))?;
            Ok(y)
        };
        // The derivatives of the element's own line or curve, from the kinematics a step either
        // side, continued past the element's ends where the point lies near one (a line goes on
        // as the same line, an arc on its circle, a blend's turn as the same polynomial): a step
        // of the grid, at most a thousandth of a radian of a curve. Not shorter for a short
        // element: the second difference's rounding grows as 1/h², and on a millionth of a
        // millimetre of line left between two blends it made the hexapod's strut accelerations
        // noise. One-sided within the element where the mechanism has no pose past its end.
        let sweep = e.segment.sweep();
        let h = self.spacing.min(if sweep > 0.0 {
            0.001 * len / sweep
        } else {
            f64::INFINITY
        });
        let y = value(u)?;
        let mut d = [(0.0, 0.0); 6 + MAX_DOF];
        if let (Ok(a), Ok(b)) = (value(u - h / len), value(u + h / len)) {
            for c in 0..6 + n {
                d[c] = ((b[c] - a[c]) / (2.0 * h), (b[c] - 2.0 * y[c] + a[c]) / (h * h));
            }
        } else {
            // Both to the second order in the step.
            let h = h.min(len / 8.0);
            let du = h / len;
            let sign = if u < 0.5 { 1.0 } else { -1.0 };
            let (a, b, z) = (
                value(u + sign * du)?,
                value(u + sign * 2.0 * du)?,
                value(u + sign * 3.0 * du)?,
            );
            for c in 0..6 + n {
                d[c] = (
                    sign * (-3.0 * y[c] + 4.0 * a[c] - b[c]) / (2.0 * h),
                    (2.0 * y[c] - 5.0 * a[c] + 4.0 * b[c] - z[c]) / (h * h),
                );
            }
        }
        Ok(Sample {
            s: self.starts[k] + len * u,
            element: k,
            u,
            stop: false,
            d: self.coords.iter().map(|&(c, _, _)| d[c]).collect(),
        })
    }

    /// A sample's speed cap (squared) and bounds of the tangential acceleration u at the speed
    /// squared x, −α − β x ≤ u ≤ α − β x, with every limit times `grow`.
    fn constraints(&self, p: &Sample, grow: f64) -> (f64, Vec<(f64, f64)>) {
        let feed = self.elements[p.element].feed;
        let mut cap = feed * feed;
        let mut lines = Vec::with_capacity(self.coords.len());
        for (&(_, v, a), &(d1, d2)) in self.coords.iter().zip(&p.d) {
            let (v, a) = (v * grow, a * grow);
            if d1.abs() > STILL {
                cap = cap.min((v / d1.abs()).powi(2));
                lines.push((a / d1.abs(), d2 * d1.signum() / d1.abs()));
            } else if d2.abs() > STILL {
                cap = cap.min(a / d2.abs());
            }
        }
        // Some u exists: every lower bound below every upper one.
        for &(aj, bj) in &lines {
            for &(ak, bk) in &lines {
                if bk > bj {
                    cap = cap.min((aj + ak) / (bk - bj));
                }
            }
        }
        (cap, lines)
    }

    /// The fastest speed squared at every sample with every limit times `grow`: backwards the
    /// largest controllable one, then forwards as fast as the limits allow within it; and each
    /// sample's speed cap (squared), which the refinement looks at.
    fn solve(&self, samples: &[Sample], grow: f64) -> (Vec<f64>, Vec<f64>) {
        let count = samples.len();
        let constraints: Vec<(f64, Vec<(f64, f64)>)> = samples.iter().map(|p| self.constraints(p, grow)).collect();
        let upper = |i: usize, x: f64| {
            constraints[i]
                .1
                .iter()
                .map(|(a, b)| a - b * x)
                .fold(f64::INFINITY, f64::min)
        };
        let mut top = vec![0.0; count];
        for i in (0..count).rev() {
            let mut x = if samples[i].stop || i + 1 == count {
                0.0
            } else {
                constraints[i].0
            };
            if i + 1 < count {
                let next = top[i + 1];
                let ds = samples[i + 1].s - samples[i].s;
                if ds <= 0.0 {
                    x = x.min(next);
                } else {
                    for (a, b) in &constraints[i].1 {
                        let k = 1.0 - 2.0 * ds * b;
                        if k > 0.0 {
                            x = x.min((next + 2.0 * ds * a) / k);
                        }
                    }
                }
            }
            top[i] = x.max(0.0);
        }
        let mut x = vec![0.0; count];
        for i in 0..count.saturating_sub(1) {
            let ds = samples[i + 1].s - samples[i].s;
            let reach = if ds <= 0.0 {
                x[i]
            } else {
                x[i] + 2.0 * ds * upper(i, x[i])
            };
            x[i + 1] = reach.min(top[i + 1]).max(0.0);
        }
        (x, constraints.into_iter().map(|(cap, _)| cap).collect())
    }

    /// The time along `samples` at the speeds squared `x`, whole and per program line.
    fn time(&self, samples: &[Sample], x: &[f64]) -> Result<(f64, Vec<(usize, f64)>), String> {
        let mut time_s = 0.0;
        let mut per_line: Vec<(usize, f64)> = Vec::new();
        for i in 0..samples.len().saturating_sub(1) {
            let ds = samples[i + 1].s - samples[i].s;
            if ds <= 0.0 {
                continue;
            }
            let (v0, v1) = (x[i].sqrt(), x[i + 1].sqrt());
            let line = self.elements[samples[i].element].line;
            if v0 + v1 <= 0.0 {
                return Err(format!("line {line}: the tool cannot move at {:.4} mm", samples[i].s));
            }
            let dt = 2.0 * ds / (v0 + v1);
            time_s += dt;
            match per_line.last_mut() {
                Some((l, t)) if *l == line => *t += dt,
                _ => per_line.push((line, dt)),
            }
        }
        Ok((time_s, per_line))
    }
}

/// The time-optimal motion along `plan`'s path on `frame` within `limits`, and with every limit
/// loosened by `relax` (0.005 for 0.5 %), its path sampled at most `spacing` mm (and 1° of an
/// arc) apart and at least 64 times an element, finer where the speed changes fast. Dwells and
/// events are left out: the motion alone.
pub fn optimal(
    plan: &Plan,
    frame: &MachineFrame,
    limits: &PlanLimits,
    spacing: f64,
    relax: f64,
) -> Result<Optimal, String> {
    let elements = plan.elements();
    let mut starts = Vec::with_capacity(elements.len());
    let mut s0 = 0.0;
    for e in elements {
        starts.push(s0);
        s0 += e.segment.length();
    }
    let path = Path {
        elements,
        starts,
        frame,
        coords: coordinate_limits(limits, frame.dof()),
        spacing,
    };
    // The first grid: per element at least 64 steps (a short move's profile is a peak, which
    // a few steps would cut off), and near a stop closer and closer to it (each a tenth closer,
    // down to 10⁻¹⁰ mm: there the speed rises from rest as the root of the distance).
    let mut wanted: Vec<(usize, f64)> = Vec::new();
    for (k, e) in elements.iter().enumerate() {
        let len = e.segment.length();
        let steps = ((len / spacing).ceil().max(e.segment.sweep() / 1f64.to_radians()).ceil() as usize).max(64);
        wanted.extend((0..=steps).map(|i| (k, i as f64 / steps as f64)));
        let mut near = |from_start: bool| {
            let mut d = len / steps as f64 / 1.1;
            while d > 1e-10 {
                wanted.push((k, if from_start { d / len } else { 1.0 - d / len }));
                d /= 1.1;
            }
        };
        if k == 0 || elements[k - 1].stop_after {
            near(true);
        }
        if e.stop_after {
            near(false);
        }
    }
    let mut samples: Vec<Sample> = Vec::new();
    let mut x = Vec::new();
    for _ in 0..ROUNDS {
        for (k, u) in wanted.drain(..) {
            samples.push(path.sample(k, u)?);
        }
        samples.sort_by(|a, b| a.element.cmp(&b.element).then(a.u.total_cmp(&b.u)));
        samples.dedup_by(|a, b| a.element == b.element && a.u == b.u);
        let count = samples.len();
        for i in 0..count {
            let (k, last) = (
                samples[i].element,
                i + 1 == count || samples[i + 1].element != samples[i].element,
            );
            samples[i].stop = (k == 0 && i == 0) || (last && elements[k].stop_after);
        }
        let caps;
        (x, caps) = path.solve(&samples, 1.0);
        // Where the speed changes fast between two samples of an element, or the speed is at
        // a cap that changes fast between them, samples between them.
        for i in 0..count.saturating_sub(1) {
            let (p, q) = (&samples[i], &samples[i + 1]);
            let len = elements[p.element].segment.length();
            if q.element != p.element || (q.u - p.u) * len < 1e-9 {
                continue;
            }
            let (lo, hi) = (x[i].min(x[i + 1]).sqrt(), x[i].max(x[i + 1]).sqrt());
            let mut ratio = if lo > 0.0 { hi / lo } else { 1.0 };
            let (c0, c1) = (caps[i].sqrt(), caps[i + 1].sqrt());
            let capped = x[i].sqrt() >= c0 / SMOOTH || x[i + 1].sqrt() >= c1 / SMOOTH;
            if capped && c0.min(c1) > 0.0 && c0.max(c1).is_finite() {
                ratio = ratio.max(c0.max(c1) / c0.min(c1));
            }
            if ratio > SMOOTH {
                let parts = (ratio.ln() / SMOOTH.ln()).ceil().min(64.0) as usize;
                wanted.extend((1..parts).map(|j| (p.element, p.u + (q.u - p.u) * j as f64 / parts as f64)));
            }
        }
        if wanted.is_empty() {
            break;
        }
    }
    let (time_s, per_line) = path.time(&samples, &x)?;
    let (lower_bound_s, _) = path.time(&samples, &path.solve(&samples, 1.0 + relax).0)?;
    Ok(Optimal {
        time_s,
        lower_bound_s,
        per_line,
        samples: samples.len(),
        speeds: samples.iter().zip(&x).map(|(p, x)| (p.s, x.sqrt())).collect(),
    })
}
