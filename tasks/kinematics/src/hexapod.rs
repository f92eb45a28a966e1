//! Stewart–Gough hexapod: six struts between base joints b_i and platform joints a_i.
//! Joints: strut lengths L_i (mm). Pose (x, y, z, a, b, c): platform origin (mm) and rotations
//! about x, y, z (degrees) with R = Rz(c)·Ry(b)·Rx(a). docs/kinematics.md (hexapod).

use serde::Deserialize;

use pkm_api::problem::Problem;

use super::{KinError, Kinematics, Machine, Mat, check_finite, check_limits, linalg, linalg::MAX, travel};

const INCH: f64 = 25.4;

/// Geometry and solver settings of the hexapod (defaults: LinuxCNC's genhexkins, in mm).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HexapodParams {
    /// Base joints b_i (mm).
    pub base: [[f64; 3]; 6],
    /// Platform joints a_i in the platform frame (mm).
    pub platform: [[f64; 3]; 6],
    /// Home pose (x, y, z mm; a, b, c degrees): FK starts here without a hint.
    pub home: [f64; 6],
    /// Travel of every strut (mm). Our default (docs/kinematics.md).
    pub strut_travel: [f64; 2],
    /// Newton: give up after this many iterations.
    pub max_iterations: usize,
    /// Newton: converged when every strut-length error is at most this (mm).
    pub tolerance_mm: f64,
    /// Newton: give up when the summed strut-length error exceeds this (mm).
    pub divergence_bound_mm: f64,
}

impl Default for HexapodParams {
    fn default() -> Self {
        let base = [
            [-22.95, 13.25, 0.0],
            [22.95, 13.25, 0.0],
            [22.95, 13.25, 0.0],
            [0.0, -26.5, 0.0],
            [0.0, -26.5, 0.0],
            [-22.95, 13.25, 0.0],
        ];
        let platform = [
            [-1.0, 11.5, 0.0],
            [1.0, 11.5, 0.0],
            [10.459, -4.884, 0.0],
            [9.459, -6.616, 0.0],
            [-9.459, -6.616, 0.0],
            [-10.459, -4.884, 0.0],
        ];
        let mm = |p: [[f64; 3]; 6]| p.map(|v| v.map(|c| c * INCH));
        HexapodParams {
            base: mm(base),
            platform: mm(platform),
            home: [0.0, 0.0, 20.0 * INCH, 0.0, 0.0, 0.0],
            strut_travel: [400.0, 1000.0],
            max_iterations: 120,
            tolerance_mm: 1e-9,
            divergence_bound_mm: 500.0,
        }
    }
}

impl HexapodParams {
    pub(crate) fn check(&self, at: &str, p: &mut Vec<Problem>) {
        travel(p, &format!("{at}.strut_travel"), self.strut_travel);
        if self.strut_travel[0] <= 0.0 {
            p.push(Problem::new(
                format!("{at}.strut_travel"),
                "strut lengths must be positive",
            ));
        }
        if self.max_iterations == 0 {
            p.push(Problem::new(format!("{at}.max_iterations"), "must be at least 1"));
        }
        if !(self.tolerance_mm > 0.0 && self.tolerance_mm.is_finite()) {
            p.push(Problem::new(
                format!("{at}.tolerance_mm"),
                format!("must be positive, got {}", self.tolerance_mm),
            ));
        }
        if !(self.divergence_bound_mm > 0.0 && self.divergence_bound_mm.is_finite()) {
            p.push(Problem::new(
                format!("{at}.divergence_bound_mm"),
                format!("must be positive, got {}", self.divergence_bound_mm),
            ));
        }
        let finite = |v: &[[f64; 3]; 6]| v.iter().flatten().all(|c| c.is_finite());
        if !finite(&self.base) || !finite(&self.platform) || !self.home.iter().all(|c| c.is_finite()) {
            p.push(Problem::new(
                at.to_string(),
                "base, platform and home must be finite numbers",
            ));
        }
    }
}

/// Hexapod kinematics.
#[derive(Clone, Debug)]
pub struct Hexapod {
    p: HexapodParams,
    limits: [[f64; 2]; 6],
    /// Mean distance of the platform joints from the platform origin: weights the angles in the
    /// singularity measure.
    radius: f64,
}

type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// R = Rz(c)·Ry(b)·Rx(a) applied to v, and its derivatives with respect to a, b and c.
fn rotate(angles: [f64; 3], v: V3) -> [V3; 4] {
    let (sa, ca) = angles[0].sin_cos();
    let (sb, cb) = angles[1].sin_cos();
    let (sc, cc) = angles[2].sin_cos();
    let rx = [v[0], ca * v[1] - sa * v[2], sa * v[1] + ca * v[2]];
    let drx = [0.0, -sa * v[1] - ca * v[2], ca * v[1] - sa * v[2]];
    let ry = |w: V3| [cb * w[0] + sb * w[2], w[1], -sb * w[0] + cb * w[2]];
    let dry = |w: V3| [-sb * w[0] + cb * w[2], 0.0, -cb * w[0] - sb * w[2]];
    let rz = |w: V3| [cc * w[0] - sc * w[1], sc * w[0] + cc * w[1], w[2]];
    let drz = |w: V3| [-sc * w[0] - cc * w[1], cc * w[0] - sc * w[1], 0.0];
    let ryx = ry(rx);
    [rz(ryx), rz(ry(drx)), rz(dry(rx)), drz(ryx)]
}

impl Hexapod {
    /// Builds the kinematics from parameters (assumed checked).
    pub fn new(p: &HexapodParams) -> Self {
        let radius = p.platform.iter().map(|a| a[0].hypot(a[1]).hypot(a[2])).sum::<f64>() / 6.0;
        Hexapod {
            limits: [p.strut_travel; 6],
            radius: radius.max(1.0),
            p: p.clone(),
        }
    }

    /// Strut lengths at a pose (angles in radians), and optionally ∂L/∂pose (angles in radians).
    fn lengths(&self, pose: &[f64; 6], lengths: &mut [f64; 6], jac: Option<&mut Mat>) -> Result<(), KinError> {
        let angles = [pose[3], pose[4], pose[5]];
        let mut jac = jac;
        for i in 0..6 {
            let [ra, da, db, dc] = rotate(angles, self.p.platform[i]);
            let v = [
                pose[0] + ra[0] - self.p.base[i][0],
                pose[1] + ra[1] - self.p.base[i][1],
                pose[2] + ra[2] - self.p.base[i][2],
            ];
            let l = dot(v, v).sqrt();
            if l < 1e-9 {
                return Err(KinError::Singular("a strut has zero length"));
            }
            lengths[i] = l;
            if let Some(j) = jac.as_deref_mut() {
                let u = [v[0] / l, v[1] / l, v[2] / l];
                j[i * MAX..i * MAX + 6].copy_from_slice(&[u[0], u[1], u[2], dot(u, da), dot(u, db), dot(u, dc)]);
            }
        }
        Ok(())
    }

    fn to_internal(pose: &[f64]) -> [f64; 6] {
        [
            pose[0],
            pose[1],
            pose[2],
            pose[3].to_radians(),
            pose[4].to_radians(),
            pose[5].to_radians(),
        ]
    }

    /// FK that also reports the number of Newton steps taken. Once every strut-length error is
    /// within the tolerance, one more step polishes the pose (Newton converges quadratically, so
    /// this takes the pose error from ~1e-9 to rounding level); it is counted.
    pub fn forward_counted(&self, joints: &[f64], hint: Option<&[f64]>, pose: &mut [f64]) -> Result<usize, KinError> {
        check_finite(&joints[..6], "the joints")?;
        check_limits(&self.limits, &joints[..6])?;
        if let Some(h) = hint {
            check_finite(&h[..6], "the hint pose")?;
        }
        let mut x = Self::to_internal(hint.unwrap_or(&self.p.home));
        let mut lengths = [0.0; 6];
        let mut jac: Mat = [0.0; MAX * MAX];
        let mut residual = f64::INFINITY;
        for iteration in 0..=self.p.max_iterations {
            self.lengths(&x, &mut lengths, Some(&mut jac))?;
            let mut f = [0.0; MAX];
            let (mut largest, mut sum) = (0.0f64, 0.0);
            for i in 0..6 {
                f[i] = joints[i] - lengths[i];
                largest = largest.max(f[i].abs());
                sum += f[i].abs();
            }
            residual = largest;
            if sum > self.p.divergence_bound_mm {
                return Err(KinError::Diverged {
                    error: sum,
                    bound: self.p.divergence_bound_mm,
                });
            }
            if largest <= self.p.tolerance_mm {
                let mut steps = iteration;
                if largest > 0.0 && linalg::solve(6, &mut jac, &mut f, 1e-12) {
                    for k in 0..6 {
                        x[k] += f[k];
                    }
                    steps += 1;
                }
                pose[..3].copy_from_slice(&x[..3]);
                for k in 3..6 {
                    pose[k] = x[k].to_degrees();
                }
                return Ok(steps);
            }
            if iteration == self.p.max_iterations {
                break;
            }
            if !linalg::solve(6, &mut jac, &mut f, 1e-12) {
                return Err(KinError::Singular("the Jacobian of the strut lengths is singular"));
            }
            for k in 0..6 {
                x[k] += f[k];
            }
        }
        Err(KinError::NotConverged {
            iterations: self.p.max_iterations,
            residual,
        })
    }
}

impl Kinematics for Hexapod {
    fn machine(&self) -> Machine {
        Machine::Hexapod
    }

    /// The six struts from their base joints to their platform joints, the base's and the
    /// platform's outlines (joints in order).
    fn links(&self, joints: &[f64], out: &mut Vec<[[f64; 3]; 2]>) -> bool {
        let mut pose = [0.0; 6];
        if self.forward(joints, None, &mut pose).is_err() {
            return false;
        }
        let internal = Self::to_internal(&pose);
        let angles = [internal[3], internal[4], internal[5]];
        let top: [V3; 6] = std::array::from_fn(|i| {
            let [r, ..] = rotate(angles, self.p.platform[i]);
            [pose[0] + r[0], pose[1] + r[1], pose[2] + r[2]]
        });
        for i in 0..6 {
            out.push([self.p.base[i], top[i]]);
            out.push([self.p.base[i], self.p.base[(i + 1) % 6]]);
            out.push([top[i], top[(i + 1) % 6]]);
        }
        // The spindle: from the tool point along the platform's axis, away from the base, as
        // long as the platform is wide — so that a drawing shows the tool's tilt.
        let radius = self.p.platform.iter().map(|a| a[0].hypot(a[1])).sum::<f64>() / 6.0;
        let [axis, ..] = rotate(angles, [0.0, 0.0, radius]);
        out.push([
            [pose[0], pose[1], pose[2]],
            [pose[0] + axis[0], pose[1] + axis[1], pose[2] + axis[2]],
        ]);
        true
    }
    fn dof(&self) -> usize {
        6
    }
    fn pose_keys(&self) -> &'static [&'static str] {
        &["x", "y", "z", "a", "b", "c"]
    }
    fn joint_limits(&self) -> &[[f64; 2]] {
        &self.limits
    }

    fn inverse(&self, pose: &[f64], joints: &mut [f64]) -> Result<(), KinError> {
        check_finite(&pose[..6], "the pose")?;
        let mut l = [0.0; 6];
        self.lengths(&Self::to_internal(pose), &mut l, None)?;
        check_limits(&self.limits, &l)?;
        joints[..6].copy_from_slice(&l);
        Ok(())
    }

    fn forward(&self, joints: &[f64], hint: Option<&[f64]>, pose: &mut [f64]) -> Result<(), KinError> {
        self.forward_counted(joints, hint, pose).map(|_| ())
    }

    fn inverse_jacobian(&self, pose: &[f64], jinv: &mut Mat) -> Result<(), KinError> {
        check_finite(&pose[..6], "the pose")?;
        let mut l = [0.0; 6];
        self.lengths(&Self::to_internal(pose), &mut l, Some(jinv))?;
        // Angles are degrees at the interface.
        for r in 0..6 {
            for c in 3..6 {
                jinv[r * MAX + c] = jinv[r * MAX + c].to_radians();
            }
        }
        Ok(())
    }

    fn measure_scale(&self, coordinate: usize) -> f64 {
        // mm per degree at the platform's radius: makes rotations and translations comparable.
        if coordinate >= 3 {
            (1.0f64).to_radians() * self.radius
        } else {
            1.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drawing_s_struts_are_as_long_as_the_joints_say() {
        let p = HexapodParams::default();
        let k = Hexapod::new(&p);
        let mut joints = [0.0; 6];
        let h = p.home;
        let pose = [h[0] + 5.0, h[1] - 3.0, h[2] + 10.0, h[3] + 2.0, h[4] - 1.0, h[5] + 3.0];
        k.inverse(&pose, &mut joints).expect("a reachable pose");
        let mut links = Vec::new();
        assert!(k.links(&joints, &mut links));
        assert_eq!(links.len(), 19);
        // The spindle starts at the tool point, square to the tilted platform's every edge.
        let [s0, s1] = links[18];
        assert!(
            (0..3).all(|c| (s0[c] - pose[c]).abs() < 1e-9),
            "{s0:?} against {pose:?}"
        );
        let axis = [s1[0] - s0[0], s1[1] - s0[1], s1[2] - s0[2]];
        for i in 0..6 {
            let [a, b] = links[3 * i + 2];
            let edge = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let dot: f64 = (0..3).map(|c| axis[c] * edge[c]).sum();
            assert!(dot.abs() < 1e-6, "edge {i}: {dot}");
        }
        assert!(axis[2] > 0.0, "away from the base: {axis:?}");
        for (i, q) in joints.iter().enumerate() {
            let [a, b] = links[3 * i];
            let l = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt();
            assert!((l - q).abs() < 1e-6, "strut {i}: {l} against {q}");
            assert_eq!(a, p.base[i]);
        }
    }
}
