//! The TRIJOINT 900H lab model: planar, two carriages on inclined guides, an arm and a rod.
//!
//! Joints (h1, h2): the left and right carriages along their guides (mm). Pose (x, y): the
//! spindle point M in the mechanism frame (mm). Formulas and assembly modes: docs/kinematics.md (TRIJOINT).

use serde::Deserialize;

use pkm_api::problem::Problem;

use super::{KinError, Kinematics, Machine, Mat, check_finite, check_limits, linalg::MAX, positive, travel};

/// Geometry of the TRIJOINT lab model (defaults: docs/kinematics.md (TRIJOINT)).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrijointParams {
    /// Distance between the guides' origins G1 and G2 (mm).
    pub d: f64,
    /// Inclination of guide 1 from the horizontal (degrees).
    pub alpha1_deg: f64,
    /// Inclination of guide 2 from the horizontal (degrees).
    pub alpha2_deg: f64,
    /// Arm: A to B (mm).
    pub l2: f64,
    /// Arm: M along the arm from A (mm).
    pub m_along: f64,
    /// Arm: M perpendicular to the arm (mm).
    pub m_perp: f64,
    /// Rod: C to B (mm).
    pub l3: f64,
    /// Travel of h1 between the lower and upper limit switches (mm).
    pub h1_travel: [f64; 2],
    /// Travel of h2 (mm).
    pub h2_travel: [f64; 2],
}

impl Default for TrijointParams {
    fn default() -> Self {
        TrijointParams {
            d: 600.0,
            alpha1_deg: 60.0,
            alpha2_deg: 60.0,
            l2: 300.0,
            m_along: 350.0,
            m_perp: 0.0,
            l3: 400.0,
            h1_travel: [0.0, 250.0],
            h2_travel: [0.0, 250.0],
        }
    }
}

impl TrijointParams {
    pub(crate) fn check(&self, at: &str, p: &mut Vec<Problem>) {
        positive(p, &format!("{at}.d"), self.d);
        positive(p, &format!("{at}.l2"), self.l2);
        positive(p, &format!("{at}.l3"), self.l3);
        for (k, v) in [("alpha1_deg", self.alpha1_deg), ("alpha2_deg", self.alpha2_deg)] {
            if !(v.is_finite() && v > 0.0 && v < 180.0) {
                p.push(Problem::new(
                    format!("{at}.{k}"),
                    format!("must be an inclination between 0 and 180 degrees, got {v}"),
                ));
            }
        }
        let inside =
            pkm_api::ranges::check_into(p, format!("{at}.m_along"), self.m_along, &pkm_api::ranges::POSITION_MM)
                & pkm_api::ranges::check_into(p, format!("{at}.m_perp"), self.m_perp, &pkm_api::ranges::POSITION_MM);
        if inside && self.m_along.hypot(self.m_perp) == 0.0 {
            p.push(Problem::new(
                format!("{at}.m_along"),
                "the spindle point M must not coincide with the pivot A",
            ));
        }
        travel(p, &format!("{at}.h1_travel"), self.h1_travel);
        travel(p, &format!("{at}.h2_travel"), self.h2_travel);
    }
}

/// The TRIJOINT kinematics with precomputed geometry.
#[derive(Clone, Debug)]
pub struct Trijoint {
    u1: [f64; 2],
    g2: [f64; 2],
    u2: [f64; 2],
    l2: f64,
    l3: f64,
    m: [f64; 2],
    r_am: f64,
    offset: f64,
    limits: [[f64; 2]; 2],
}

/// Parameters t of the two points where the line g + t·u (u a unit vector) meets the circle of
/// radius r around c, smaller first; `None` if it misses.
fn line_circle(g: [f64; 2], u: [f64; 2], c: [f64; 2], r: f64) -> Option<(f64, f64)> {
    let w = [g[0] - c[0], g[1] - c[1]];
    let b = u[0] * w[0] + u[1] * w[1];
    let disc = b * b - (w[0] * w[0] + w[1] * w[1] - r * r);
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    Some((-b - s, -b + s))
}

fn perp(v: [f64; 2]) -> [f64; 2] {
    [-v[1], v[0]]
}

/// The intermediate points of a solved pose.
struct Solved {
    h: [f64; 2],
    a: [f64; 2],
    b: [f64; 2],
    c: [f64; 2],
}

impl Trijoint {
    /// Builds the kinematics from parameters (assumed checked).
    pub fn new(p: &TrijointParams) -> Self {
        let (a1, a2) = (p.alpha1_deg.to_radians(), p.alpha2_deg.to_radians());
        Trijoint {
            u1: [a1.cos(), a1.sin()],
            g2: [p.d, 0.0],
            u2: [-a2.cos(), a2.sin()],
            l2: p.l2,
            l3: p.l3,
            m: [p.m_along, p.m_perp],
            r_am: p.m_along.hypot(p.m_perp),
            offset: p.m_perp.atan2(p.m_along),
            limits: [p.h1_travel, p.h2_travel],
        }
    }

    fn point(g: [f64; 2], u: [f64; 2], t: f64) -> [f64; 2] {
        [g[0] + t * u[0], g[1] + t * u[1]]
    }

    fn solve(&self, pose: &[f64]) -> Result<Solved, KinError> {
        check_finite(pose, "the pose")?;
        let mm = [pose[0], pose[1]];
        // 1. A: guide 2 ∩ circle(M, |AM|), the intersection with the larger x.
        let (t0, t1) = line_circle(self.g2, self.u2, mm, self.r_am).ok_or(KinError::Unreachable(
            "the arm cannot reach M: guide 2 does not meet the circle of radius |AM| around M",
        ))?;
        let (p0, p1) = (Self::point(self.g2, self.u2, t0), Self::point(self.g2, self.u2, t1));
        let (h2, a) = if p0[0] >= p1[0] { (t0, p0) } else { (t1, p1) };
        // 2. The arm angle and B.
        let phi = (mm[1] - a[1]).atan2(mm[0] - a[0]) - self.offset;
        let b = [a[0] + self.l2 * phi.cos(), a[1] + self.l2 * phi.sin()];
        // 3. C: guide 1 ∩ circle(B, l3), the intersection with the smaller x.
        let g1 = [0.0, 0.0];
        let (s0, s1) = line_circle(g1, self.u1, b, self.l3).ok_or(KinError::Unreachable(
            "the rod cannot reach B: guide 1 does not meet the circle of radius l3 around B",
        ))?;
        let (c0, c1) = (Self::point(g1, self.u1, s0), Self::point(g1, self.u1, s1));
        let (h1, c) = if c0[0] <= c1[0] { (s0, c0) } else { (s1, c1) };
        Ok(Solved { h: [h1, h2], a, b, c })
    }
}

impl Kinematics for Trijoint {
    fn machine(&self) -> Machine {
        Machine::Trijoint
    }

    /// The two guides over their travel, the rod C–B, and the arm: the triangle A–B–M.
    fn links(&self, joints: &[f64], out: &mut Vec<[[f64; 3]; 2]>) -> bool {
        let mut pose = [0.0; 2];
        let Ok(s) = self.forward(joints, None, &mut pose).and_then(|()| self.solve(&pose)) else {
            return false;
        };
        let p3 = |p: [f64; 2]| [p[0], p[1], 0.0];
        let guide =
            |g: [f64; 2], u: [f64; 2], [lo, hi]: [f64; 2]| [p3(Self::point(g, u, lo)), p3(Self::point(g, u, hi))];
        out.push(guide([0.0, 0.0], self.u1, self.limits[0]));
        out.push(guide(self.g2, self.u2, self.limits[1]));
        out.push([p3(s.c), p3(s.b)]);
        out.push([p3(s.a), p3(s.b)]);
        out.push([p3(s.b), p3(pose)]);
        out.push([p3(s.a), p3(pose)]);
        true
    }
    fn dof(&self) -> usize {
        2
    }
    fn pose_keys(&self) -> &'static [&'static str] {
        &["x", "y"]
    }
    fn joint_limits(&self) -> &[[f64; 2]] {
        &self.limits
    }

    fn inverse(&self, pose: &[f64], joints: &mut [f64]) -> Result<(), KinError> {
        let s = self.solve(pose)?;
        check_limits(&self.limits, &s.h)?;
        joints[..2].copy_from_slice(&s.h);
        Ok(())
    }

    fn forward(&self, joints: &[f64], _hint: Option<&[f64]>, pose: &mut [f64]) -> Result<(), KinError> {
        check_finite(&joints[..2], "the joints")?;
        check_limits(&self.limits, &joints[..2])?;
        let a = Self::point(self.g2, self.u2, joints[1]);
        let c = Self::point([0.0, 0.0], self.u1, joints[0]);
        let v = [c[0] - a[0], c[1] - a[1]];
        let dist = v[0].hypot(v[1]);
        if dist > self.l2 + self.l3 || dist < (self.l2 - self.l3).abs() || dist == 0.0 {
            return Err(KinError::NoAssembly(
                "arm and rod cannot meet: |AC| is outside [|l2 − l3|, l2 + l3]",
            ));
        }
        let along = (self.l2 * self.l2 - self.l3 * self.l3 + dist * dist) / (2.0 * dist);
        let h = (self.l2 * self.l2 - along * along).max(0.0).sqrt();
        // The assembly mode of docs/kinematics.md: B to the right of the directed line A → C,
        // cross(C − A, B − A) < 0, i.e. the minus side of perp(C − A).
        let n = perp(v);
        let b = [
            a[0] + (along * v[0] - h * n[0]) / dist,
            a[1] + (along * v[1] - h * n[1]) / dist,
        ];
        let phi = (b[1] - a[1]).atan2(b[0] - a[0]);
        let (s, c) = phi.sin_cos();
        pose[0] = a[0] + c * self.m[0] - s * self.m[1];
        pose[1] = a[1] + s * self.m[0] + c * self.m[1];
        Ok(())
    }

    fn inverse_jacobian(&self, pose: &[f64], jinv: &mut Mat) -> Result<(), KinError> {
        let s = self.solve(pose)?;
        // M = A(h2) + R(φ)·m  ⇒  dM = u2·dh2 + perp(M − A)·dφ: a 2×2 system for (dh2, dφ).
        let w = perp([pose[0] - s.a[0], pose[1] - s.a[1]]);
        let det = self.u2[0] * w[1] - w[0] * self.u2[1];
        if det.abs() < 1e-12 * self.r_am {
            return Err(KinError::Singular("the arm is aligned with guide 2"));
        }
        // |B − C|² = l3² ⇒ (B − C)·(dB − u1·dh1) = 0 with dB = u2·dh2 + perp(B − A)·dφ.
        let bc = [s.b[0] - s.c[0], s.b[1] - s.c[1]];
        let den = bc[0] * self.u1[0] + bc[1] * self.u1[1];
        if den.abs() < 1e-12 * self.l3 {
            return Err(KinError::Singular("the rod is perpendicular to guide 1"));
        }
        let pb = perp([s.b[0] - s.a[0], s.b[1] - s.a[1]]);
        for (col, (dh2, dphi)) in [(w[1] / det, -self.u2[1] / det), (-w[0] / det, self.u2[0] / det)]
            .into_iter()
            .enumerate()
        {
            let db = [self.u2[0] * dh2 + pb[0] * dphi, self.u2[1] * dh2 + pb[1] * dphi];
            jinv[col] = (bc[0] * db[0] + bc[1] * db[1]) / den;
            jinv[MAX + col] = dh2;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drawing_joins_the_carriages_rod_and_arm_as_the_geometry_says() {
        let p = TrijointParams::default();
        let k = Trijoint::new(&p);
        let joints = [125.0, 125.0];
        let mut links = Vec::new();
        assert!(k.links(&joints, &mut links));
        assert_eq!(links.len(), 6);
        let length = |[a, b]: [[f64; 3]; 2]| (b[0] - a[0]).hypot(b[1] - a[1]);
        let [_, _, rod, arm_ab, _, _] = links[..] else {
            panic!("six links")
        };
        assert!((length(rod) - p.l3).abs() < 1e-9, "the rod is l3 long");
        assert!((length(arm_ab) - p.l2).abs() < 1e-9, "A–B is l2 long");
        // C is carriage 1 at h1 on guide 1; M is the forward kinematics' pose.
        let c = rod[0];
        let a1 = p.alpha1_deg.to_radians();
        assert!((c[0] - 125.0 * a1.cos()).abs() < 1e-9 && (c[1] - 125.0 * a1.sin()).abs() < 1e-9);
        let mut pose = [0.0; 2];
        k.forward(&joints, None, &mut pose).expect("a pose");
        let m = links[5][1];
        assert!((m[0] - pose[0]).abs() < 1e-9 && (m[1] - pose[1]).abs() < 1e-9);
        // Joints outside the travel draw nothing.
        assert!(!k.links(&[1e6, 0.0], &mut Vec::new()));
    }
}
