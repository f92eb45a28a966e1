//! pn101: three sliders on parallel guides along x carry a platform through two strut pairs and a
//! translational-rotational link. Joints q1..q3: slider displacements from their reference
//! positions (mm). Pose (x, y, z): the platform reference point P2 (mm). docs/kinematics.md (pn101).

use serde::Deserialize;

use pkm_api::problem::Problem;

use super::{KinError, Kinematics, Machine, Mat, check_finite, check_limits, linalg::MAX, positive, travel};

/// Geometry of pn101 (defaults: the 1:5 physical model's controller, docs/kinematics.md (pn101)).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Pn101Params {
    /// Strut pair 1 (averaged) length (mm).
    pub c1: f64,
    /// Strut pair 2 length (mm).
    pub c2: f64,
    /// Used for dx1 = c3·cos α (mm).
    pub c3: f64,
    /// Link of slider 3 (mm).
    pub c4: f64,
    /// α (degrees); dx1 = c3·cos α.
    pub alpha_deg: f64,
    /// Offset d (mm).
    pub d: f64,
    /// Slider 3 offset along x (mm).
    pub dx3: f64,
    /// Slider 3 offset along y (mm); part of the model's data, not used by the formulas.
    pub dy3: f64,
    /// Slider 3 offset along z (mm).
    pub dz3: f64,
    /// Height of slider 3's guide (mm).
    pub zz3: f64,
    /// Reference positions of the sliders (mm): p_i = xr_i + q_i.
    pub xr: [f64; 3],
    /// Travel of q1, q2, q3 (mm). Our default (docs/kinematics.md).
    pub travel: [[f64; 2]; 3],
}

impl Default for Pn101Params {
    fn default() -> Self {
        Pn101Params {
            c1: 200.63,
            c2: 205.18,
            c3: 205.90,
            c4: 100.0,
            alpha_deg: 8.37742,
            d: 30.0,
            dx3: 100.0,
            dy3: 5.0,
            dz3: 55.0,
            zz3: 120.0,
            xr: [265.0, 366.0, 395.0],
            travel: [[-60.0, 60.0]; 3],
        }
    }
}

impl Pn101Params {
    pub(crate) fn check(&self, at: &str, p: &mut Vec<Problem>) {
        for (k, v) in [("c1", self.c1), ("c2", self.c2), ("c3", self.c3), ("c4", self.c4)] {
            positive(p, &format!("{at}.{k}"), v);
        }
        for (k, v) in [
            ("alpha_deg", self.alpha_deg),
            ("d", self.d),
            ("dx3", self.dx3),
            ("dy3", self.dy3),
            ("dz3", self.dz3),
            ("zz3", self.zz3),
        ] {
            if !v.is_finite() {
                p.push(Problem::new(
                    format!("{at}.{k}"),
                    format!("must be a finite number, got {v}"),
                ));
            }
        }
        for (i, t) in self.travel.iter().enumerate() {
            travel(p, &format!("{at}.travel[{i}]"), *t);
        }
    }
}

/// pn101 kinematics.
#[derive(Clone, Debug)]
pub struct Pn101 {
    p: Pn101Params,
    dx1: f64,
}

impl Pn101 {
    /// Builds the kinematics from parameters (assumed checked).
    pub fn new(p: &Pn101Params) -> Self {
        Pn101 {
            dx1: p.c3 * p.alpha_deg.to_radians().cos(),
            p: p.clone(),
        }
    }

    /// The three square roots of the IK, after checking the pose is in the assembly mode.
    fn roots(&self, pose: &[f64]) -> Result<[f64; 3], KinError> {
        check_finite(&pose[..3], "the pose")?;
        let (y, z) = (pose[1], pose[2]);
        let p = &self.p;
        // The FK formulas take y = −d − √…, z = (zz3 − dz3) − √…: poses on the other side are the
        // mirrored assembly, which this mechanism cannot reach without passing a singularity.
        if y + p.d > 0.0 {
            return Err(KinError::Unreachable(
                "y must be at most −d (the platform hangs below the strut pivots)",
            ));
        }
        if z + p.dz3 - p.zz3 > 0.0 {
            return Err(KinError::Unreachable(
                "z must be at most zz3 − dz3 (the link of slider 3 points down)",
            ));
        }
        let rho2 = (y + p.d).powi(2) + z * z;
        let r1 = p.c1 * p.c1 - rho2;
        let r2 = p.c2 * p.c2 - rho2;
        let r3 = p.c4 * p.c4 - (z + p.dz3 - p.zz3).powi(2);
        if r1 < 0.0 {
            return Err(KinError::Unreachable("strut pair 1 (c1) is too short for the pose"));
        }
        if r2 < 0.0 {
            return Err(KinError::Unreachable("strut pair 2 (c2) is too short for the pose"));
        }
        if r3 < 0.0 {
            return Err(KinError::Unreachable(
                "the link of slider 3 (c4) is too short for the pose",
            ));
        }
        Ok([r1.sqrt(), r2.sqrt(), r3.sqrt()])
    }
}

impl Kinematics for Pn101 {
    fn machine(&self) -> Machine {
        Machine::Pn101
    }
    fn dof(&self) -> usize {
        3
    }
    fn pose_keys(&self) -> &'static [&'static str] {
        &["x", "y", "z"]
    }
    fn joint_limits(&self) -> &[[f64; 2]] {
        &self.p.travel
    }

    /// The three guides along x over the sliders' travel (sliders 1 and 2 at y = −d, z = 0;
    /// slider 3 at z = zz3), strut pairs 1 and 2 and the link of slider 3 to their joints on the
    /// platform, and the platform between those joints (P2 is the tool point).
    fn links(&self, joints: &[f64], out: &mut Vec<[[f64; 3]; 2]>) -> bool {
        let mut pose = [0.0; 3];
        if self.forward(joints, None, &mut pose).is_err() {
            return false;
        }
        let p = &self.p;
        let [x, y, z] = pose;
        let guide = |i: usize, at: [f64; 2]| {
            let [lo, hi] = p.travel[i];
            [[p.xr[i] + lo, at[0], at[1]], [p.xr[i] + hi, at[0], at[1]]]
        };
        out.push(guide(0, [-p.d, 0.0]));
        out.push(guide(1, [-p.d, 0.0]));
        out.push(guide(2, [y, p.zz3]));
        let slider = |i: usize, at: [f64; 2]| [p.xr[i] + joints[i], at[0], at[1]];
        let (j1, j2, j3) = ([x + self.dx1, y, z], [x, y, z], [x + p.dx3, y, z + p.dz3]);
        out.push([slider(0, [-p.d, 0.0]), j1]);
        out.push([slider(1, [-p.d, 0.0]), j2]);
        out.push([slider(2, [y, p.zz3]), j3]);
        out.push([j1, j2]);
        out.push([j2, j3]);
        true
    }

    fn inverse(&self, pose: &[f64], joints: &mut [f64]) -> Result<(), KinError> {
        let [s1, s2, s3] = self.roots(pose)?;
        let x = pose[0];
        let q = [
            x + self.dx1 - s1 - self.p.xr[0],
            x + s2 - self.p.xr[1],
            x + self.p.dx3 + s3 - self.p.xr[2],
        ];
        check_limits(&self.p.travel, &q)?;
        joints[..3].copy_from_slice(&q);
        Ok(())
    }

    fn forward(&self, joints: &[f64], _hint: Option<&[f64]>, pose: &mut [f64]) -> Result<(), KinError> {
        check_finite(&joints[..3], "the joints")?;
        check_limits(&self.p.travel, &joints[..3])?;
        let p = &self.p;
        let (p1, p2, p3) = (p.xr[0] + joints[0], p.xr[1] + joints[1], p.xr[2] + joints[2]);
        let s1 = self.dx1 - p1;
        let s2 = p.c1 * p.c1 - p.c2 * p.c2;
        let s3 = p.dx3 - p3;
        let s4 = p.dz3 - p.zz3;
        let den = 2.0 * (s1 + p2);
        if den.abs() < 1e-9 {
            return Err(KinError::Singular("sliders 1 and 2 are at the same effective position"));
        }
        let x = (s2 - s1 * s1 + p2 * p2) / den;
        // The square roots of the IK are non-negative: x + s1 = √(c1² − ρ²), p2 − x = √(c2² − ρ²),
        // −(x + s3) = √(c4² − …). Other signs belong to another assembly.
        if x + s1 < 0.0 || p2 - x < 0.0 {
            return Err(KinError::NoAssembly(
                "sliders 1 and 2 are in an order the strut pairs cannot assemble",
            ));
        }
        if x + s3 > 0.0 {
            return Err(KinError::NoAssembly(
                "slider 3 is behind the platform: its link cannot assemble",
            ));
        }
        let r3 = p.c4 * p.c4 - (x + s3).powi(2);
        if r3 < 0.0 {
            return Err(KinError::NoAssembly(
                "slider 3 is too far from the platform for its link (c4)",
            ));
        }
        let z = -s4 - r3.sqrt();
        let r2 = p.c2 * p.c2 - z * z - (x - p2).powi(2);
        if r2 < 0.0 {
            return Err(KinError::NoAssembly("strut pair 2 cannot reach the platform"));
        }
        pose[0] = x;
        pose[1] = -p.d - r2.sqrt();
        pose[2] = z;
        Ok(())
    }

    fn inverse_jacobian(&self, pose: &[f64], jinv: &mut Mat) -> Result<(), KinError> {
        let [s1, s2, s3] = self.roots(pose)?;
        if s1 < 1e-9 || s2 < 1e-9 || s3 < 1e-9 {
            return Err(KinError::Singular(
                "a strut or link is parallel to the guides' normal plane",
            ));
        }
        let (y, z) = (pose[1] + self.p.d, pose[2]);
        let zz = pose[2] + self.p.dz3 - self.p.zz3;
        let rows = [[1.0, y / s1, z / s1], [1.0, -y / s2, -z / s2], [1.0, 0.0, -zz / s3]];
        for (r, row) in rows.iter().enumerate() {
            jinv[r * MAX..r * MAX + 3].copy_from_slice(row);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drawing_s_struts_and_link_have_their_lengths() {
        let p = Pn101Params::default();
        let k = Pn101::new(&p);
        let joints = [2.0, -1.0, 3.0];
        let mut links = Vec::new();
        assert!(k.links(&joints, &mut links));
        assert_eq!(links.len(), 8);
        let length =
            |[a, b]: [[f64; 3]; 2]| ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt();
        assert!((length(links[3]) - p.c1).abs() < 1e-9, "strut pair 1");
        assert!((length(links[4]) - p.c2).abs() < 1e-9, "strut pair 2");
        assert!((length(links[5]) - p.c4).abs() < 1e-9, "the link of slider 3");
        for i in 0..3 {
            assert!(
                (links[3 + i][0][0] - (p.xr[i] + joints[i])).abs() < 1e-9,
                "slider {i} at xr + q"
            );
        }
    }
}
