//! O-X glide: two sliders on horizontal guides at z = ±d carry the tool point P through rods of
//! lengths l1, l2; a serial axis moves y. Joints (s1, s2, s3) in mm; pose (x, y, z) with y the
//! serial axis. The crossed X and the extended O configuration differ only in the sign in front of
//! the square roots. docs/kinematics.md (O-X glide).

use serde::Deserialize;

use pkm_api::problem::Problem;

use super::{KinError, Kinematics, Machine, Mat, check_finite, check_limits, linalg::MAX, positive, travel};

/// The two working configurations of the same hardware.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Configuration {
    /// Crossed rods.
    X,
    /// Extended rods.
    O,
}

impl Configuration {
    /// The sign in front of the square roots of the IK: X −1, O +1.
    fn sigma(self) -> f64 {
        match self {
            Configuration::X => -1.0,
            Configuration::O => 1.0,
        }
    }
}

/// Geometry of the O-X glide (defaults: the first prototype, docs/kinematics.md (O-X glide)).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OxParams {
    /// Rod of slider 1 (mm).
    pub l1: f64,
    /// Rod of slider 2 (mm).
    pub l2: f64,
    /// Platform offset of rod 1 (mm).
    pub p1: f64,
    /// Platform offset of rod 2 (mm).
    pub p2: f64,
    /// Half the distance between the guides (mm).
    pub d: f64,
    /// Reference position of slider 1 (mm).
    pub xr1: f64,
    /// Reference position of slider 2 (mm).
    pub xr2: f64,
    /// Travel of s1, s2, s3 (mm). Our defaults (docs/kinematics.md).
    pub travel: [[f64; 2]; 3],
    /// Smallest angle between a rod and its guide that the workspace analysis keeps (degrees).
    pub min_rod_angle_deg: f64,
}

impl Default for OxParams {
    fn default() -> Self {
        OxParams {
            l1: 391.0,
            l2: 260.0,
            p1: 33.5,
            p2: 26.5,
            d: 65.5,
            xr1: 0.0,
            xr2: 385.0,
            travel: [[-150.0, 150.0], [-150.0, 150.0], [-100.0, 100.0]],
            min_rod_angle_deg: 15.0,
        }
    }
}

impl OxParams {
    /// Defaults for the O configuration: the same rods, with slider references chosen so that
    /// FK(0, 0) is an extended (O) pose — slider 1 to the right of the tool point, slider 2 to
    /// its left. The first prototype's references are the X configuration's.
    pub fn default_o() -> Self {
        OxParams {
            xr1: 470.0,
            xr2: -60.0,
            ..OxParams::default()
        }
    }

    pub(crate) fn check(&self, at: &str, p: &mut Vec<Problem>) {
        for (k, v) in [("l1", self.l1), ("l2", self.l2), ("d", self.d)] {
            positive(p, &format!("{at}.{k}"), v);
        }
        for (k, v) in [("p1", self.p1), ("p2", self.p2), ("xr1", self.xr1), ("xr2", self.xr2)] {
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
        if !(0.0..90.0).contains(&self.min_rod_angle_deg) {
            p.push(Problem::new(
                format!("{at}.min_rod_angle_deg"),
                format!("must be between 0 and 90 degrees, got {}", self.min_rod_angle_deg),
            ));
        }
    }
}

/// O-X glide kinematics in one configuration.
#[derive(Clone, Debug)]
pub struct OxGlide {
    p: OxParams,
    config: Configuration,
}

impl OxGlide {
    /// Builds the kinematics from parameters (assumed checked).
    pub fn new(p: &OxParams, config: Configuration) -> Self {
        OxGlide { p: p.clone(), config }
    }

    /// Whether both rods make at least the configured angle with their guides at `pose`.
    pub fn rod_angles_ok(&self, pose: &[f64]) -> bool {
        let min = self.p.min_rod_angle_deg.to_radians().sin();
        ((pose[2] - self.p.d).abs() / self.p.l1) >= min && ((pose[2] + self.p.d).abs() / self.p.l2) >= min
    }

    /// √(l1² − (z − d)²) and √(l2² − (z + d)²) after checking the pose is reachable in this
    /// configuration's assembly (P the lower intersection of the rods' circles, as FK takes it).
    fn roots(&self, pose: &[f64]) -> Result<(f64, f64), KinError> {
        check_finite(&pose[..3], "the pose")?;
        let (x, z) = (pose[0], pose[2]);
        let p = &self.p;
        let r1 = p.l1 * p.l1 - (z - p.d).powi(2);
        let r2 = p.l2 * p.l2 - (z + p.d).powi(2);
        if r1 < 0.0 {
            return Err(KinError::Unreachable("rod 1 (l1) cannot reach z"));
        }
        if r2 < 0.0 {
            return Err(KinError::Unreachable("rod 2 (l2) cannot reach z"));
        }
        let (s1, s2) = (r1.sqrt(), r2.sqrt());
        // Rod pivots on the sliders: K1 = (x + σ·√r1, d), K2 = (x − σ·√r2, −d). FK takes the lower
        // of the two intersections of the rods' circles; the other one is P mirrored in K1K2.
        let sigma = self.config.sigma();
        let k1 = [x + sigma * s1, p.d];
        let k2 = [x - sigma * s2, -p.d];
        let v = [k2[0] - k1[0], k2[1] - k1[1]];
        let len2 = v[0] * v[0] + v[1] * v[1];
        if len2 == 0.0 {
            return Err(KinError::Unreachable("both rod pivots coincide"));
        }
        // z of the mirror image minus z of P: 2·(normal component), see reflection across a line.
        let w = [x - k1[0], z - k1[1]];
        let t = (w[0] * v[0] + w[1] * v[1]) / len2;
        let foot_z = k1[1] + t * v[1];
        if 2.0 * (foot_z - z) < 0.0 {
            return Err(KinError::Unreachable(
                "the pose is the upper assembly of the rods, which FK does not take",
            ));
        }
        Ok((s1, s2))
    }
}

impl Kinematics for OxGlide {
    fn machine(&self) -> Machine {
        match self.config {
            Configuration::X => Machine::OxX,
            Configuration::O => Machine::OxO,
        }
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

    /// The two guides (z = ±d) over the sliders' travel, the rods from the sliders to their
    /// joints on the platform, and the platform through the tool point (x–z; y is the serial
    /// axis).
    fn links(&self, joints: &[f64], out: &mut Vec<[[f64; 3]; 2]>) -> bool {
        let mut pose = [0.0; 3];
        if self.forward(joints, None, &mut pose).is_err() {
            return false;
        }
        let Ok((r1, r2)) = self.roots(&pose) else {
            return false;
        };
        let (p, sigma) = (&self.p, self.config.sigma());
        let [x, y, z] = pose;
        let at = |px: f64, pz: f64| [px, y, pz];
        // Slider 1 at xr1 + s1 on z = d, slider 2 at xr2 − s2 on z = −d (the IK's frame).
        let [t1, t2] = [p.travel[0], p.travel[1]];
        out.push([at(p.xr1 + t1[0], p.d), at(p.xr1 + t1[1], p.d)]);
        out.push([at(p.xr2 - t2[1], -p.d), at(p.xr2 - t2[0], -p.d)]);
        let (j1, j2) = (at(x + p.p1, z), at(x - p.p2, z));
        out.push([at(x + p.p1 + sigma * r1, p.d), j1]);
        out.push([at(x - p.p2 - sigma * r2, -p.d), j2]);
        out.push([j1, j2]);
        true
    }

    fn inverse(&self, pose: &[f64], joints: &mut [f64]) -> Result<(), KinError> {
        let (r1, r2) = self.roots(pose)?;
        let (p, sigma, x) = (&self.p, self.config.sigma(), pose[0]);
        let q = [x - p.xr1 + p.p1 + sigma * r1, -(x - p.xr2 - p.p2 - sigma * r2), pose[1]];
        check_limits(&p.travel, &q)?;
        joints[..3].copy_from_slice(&q);
        Ok(())
    }

    fn forward(&self, joints: &[f64], _hint: Option<&[f64]>, pose: &mut [f64]) -> Result<(), KinError> {
        check_finite(&joints[..3], "the joints")?;
        check_limits(&self.p.travel, &joints[..3])?;
        let p = &self.p;
        let m1 = p.xr1 - p.p1 + joints[0];
        let m2 = p.xr2 + p.p2 - joints[1];
        let m3 = 2.0 * m2 - 2.0 * m1;
        if m3.abs() < 1e-9 {
            return Err(KinError::Singular("the rod pivots are vertically aligned"));
        }
        let m4 = -4.0 * p.d;
        let m5 = m1 * m1 - m2 * m2 - p.l1 * p.l1 + p.l2 * p.l2;
        let m6 = -m5 / m3;
        let m7 = -m4 / m3;
        let m8 = 1.0 + m7 * m7;
        let m9 = 2.0 * (m6 - m1) * m7 - 2.0 * p.d;
        let m10 = (m6 - m1).powi(2) + p.d * p.d - p.l1 * p.l1;
        let disc = m9 * m9 - 4.0 * m8 * m10;
        if disc < 0.0 {
            return Err(KinError::NoAssembly(
                "the rods cannot meet: the sliders are too far apart",
            ));
        }
        let z = (-m9 - disc.sqrt()) / (2.0 * m8);
        let x = m6 + m7 * z;
        // X: pivot 1 left of P, pivot 2 right of it; O: the other way round.
        let crossed = m1 <= x && m2 >= x;
        let extended = m1 >= x && m2 <= x;
        let ok = match self.config {
            Configuration::X => crossed,
            Configuration::O => extended,
        };
        if !ok {
            return Err(match self.config {
                Configuration::X => KinError::NoAssembly("the sliders' positions do not give crossed (X) rods"),
                Configuration::O => KinError::NoAssembly("the sliders' positions do not give extended (O) rods"),
            });
        }
        pose[0] = x;
        pose[1] = joints[2];
        pose[2] = z;
        Ok(())
    }

    fn inverse_jacobian(&self, pose: &[f64], jinv: &mut Mat) -> Result<(), KinError> {
        let (r1, r2) = self.roots(pose)?;
        if r1 < 1e-9 || r2 < 1e-9 {
            return Err(KinError::Singular("a rod is perpendicular to its guide"));
        }
        let (sigma, z, d) = (self.config.sigma(), pose[2], self.p.d);
        let rows = [
            [1.0, 0.0, -sigma * (z - d) / r1],
            [-1.0, 0.0, -sigma * (z + d) / r2],
            [0.0, 1.0, 0.0],
        ];
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
    fn the_drawing_puts_the_sliders_at_their_joints_and_the_rods_at_their_lengths() {
        for (config, p) in [
            (Configuration::X, OxParams::default()),
            (Configuration::O, OxParams::default_o()),
        ] {
            let k = OxGlide::new(&p, config);
            let joints = [1.0, 1.0, 2.0];
            let mut links = Vec::new();
            assert!(k.links(&joints, &mut links), "{config:?}");
            assert_eq!(links.len(), 5);
            let length = |[a, b]: [[f64; 3]; 2]| ((b[0] - a[0]).powi(2) + (b[2] - a[2]).powi(2)).sqrt();
            assert!((length(links[2]) - p.l1).abs() < 1e-9, "{config:?}: rod 1");
            assert!((length(links[3]) - p.l2).abs() < 1e-9, "{config:?}: rod 2");
            assert!(
                (links[2][0][0] - (p.xr1 + joints[0])).abs() < 1e-9,
                "slider 1 at xr1 + s1"
            );
            assert!(
                (links[3][0][0] - (p.xr2 - joints[1])).abs() < 1e-9,
                "slider 2 at xr2 − s2"
            );
            let mut pose = [0.0; 3];
            k.forward(&joints, None, &mut pose).expect("a pose");
            let [j1, j2] = links[4];
            assert!(
                j1[0] > pose[0] - 1e-9 || j2[0] > pose[0] - 1e-9,
                "the platform spans the tool point"
            );
            assert!((j1[2] - pose[2]).abs() < 1e-9 && (links[0][0][1] - pose[1]).abs() < 1e-9);
        }
    }
}
