//! The geometry of a move: its length along the path, and its pose at a fraction of it. Lines
//! are straight in world coordinates; arcs turn about their plane's normal, a helix rises along
//! it, and every other coordinate (a rotation during an arc, say) changes in proportion.

use std::f64::consts::TAU;

use crate::interp::block::{Path, Pose};

/// A move's geometry, ready to be sampled. What only arcs and blends need is boxed: most moves
/// of a CAM program are lines, and a program of a million of them is planned in a third of the
/// memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    from: Pose,
    to: Pose,
    arc: Option<Box<Arc>>,
    /// For a blend: the rates of a b c (per unit of the fraction u) at its start and end, so
    /// that the rotations join the lines' rates without a kink (cubic Hermite); `None`: linear.
    rotation_rates: Option<Box<([f64; 3], [f64; 3])>>,
}

/// The memory an arc's own part of a [`Segment`] takes (bytes).
pub(crate) const ARC_BYTES: usize = size_of::<Arc>();

/// A circular arc in x y z (a helix with `rise`, a spiral with `spiral`):
/// p(φ) = c + r(φ)·(cos φ·u + sin φ·v) + rise·φ/sweep·w for φ from 0 to `sweep`, with
/// r(φ) = radius + spiral·φ/sweep and u, v, w orthonormal. A programmed arc whose end lies a little off its circle is a spiral from the
/// start's radius to the end's, as LinuxCNC traces it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Arc {
    center: [f64; 3],
    u: [f64; 3],
    v: [f64; 3],
    w: [f64; 3],
    radius: f64,
    /// How the radius changes from the start to the end (mm).
    spiral: f64,
    /// The angle it turns (rad, positive).
    sweep: f64,
    /// How far it rises along w (mm).
    rise: f64,
    /// Its length (mm), found once: [`Arc::measured`] sets it.
    length: f64,
}

impl Arc {
    /// How the radius changes per radian, and the part of the speed along the path that is not
    /// the turn's (the radius' change and the rise, per radian): ds/dφ = √(r(φ)² + c²).
    fn rates(&self) -> (f64, f64) {
        let k = self.spiral / self.sweep;
        let h = self.rise / self.sweep;
        (k, (k * k + h * h).sqrt())
    }

    /// The arc with its length found.
    fn measured(mut self) -> Arc {
        self.length = self.length_to(self.sweep);
        self
    }

    /// The length of the path from its start to the angle `phi` (mm): ∫ √(r(ψ)² + c²) dψ, by
    /// eight-point Gauss–Legendre quadrature where the radius changes (its integrand is smooth
    /// and changes little: the closed form, a difference of two large terms, loses the digits a
    /// spiral of a thousandth of a millimetre on a large radius needs).
    fn length_to(&self, phi: f64) -> f64 {
        let (k, c) = self.rates();
        let c2 = c * c;
        if self.spiral == 0.0 {
            return phi * (self.radius * self.radius + c2).sqrt();
        }
        // Nodes and weights on −1 … 1.
        const NODES: [(f64, f64); 4] = [
            (0.183_434_642_495_649_8, 0.362_683_783_378_362),
            (0.525_532_409_916_329, 0.313_706_645_877_887_3),
            (0.796_666_477_413_626_7, 0.222_381_034_453_374_5),
            (0.960_289_856_497_536_3, 0.101_228_536_290_376_3),
        ];
        let half = phi / 2.0;
        let speed = |psi: f64| {
            let r = self.radius + k * psi;
            (r * r + c2).sqrt()
        };
        half * NODES
            .iter()
            .map(|(x, w)| w * (speed(half * (1.0 + x)) + speed(half * (1.0 - x))))
            .sum::<f64>()
    }

    /// The path's length (mm).
    fn length(&self) -> f64 {
        self.length
    }

    /// The angle at which the path has run the fraction `u` of its length: the fraction itself
    /// of the sweep where the speed along the path is the same at every angle (a circle, a
    /// helix), else found by Newton's method (a spiral, whose radius changes).
    fn angle(&self, u: f64) -> f64 {
        let phi = self.sweep * u;
        if self.spiral == 0.0 {
            return phi;
        }
        let (k, c) = self.rates();
        let target = u * self.length;
        let mut phi = phi;
        for _ in 0..8 {
            let r = self.radius + k * phi;
            let speed = (r * r + c * c).sqrt();
            if speed <= 0.0 {
                break;
            }
            let step = (self.length_to(phi) - target) / speed;
            phi -= step;
            if step.abs() <= 1e-15 * self.sweep {
                break;
            }
        }
        phi
    }
}

fn unit(axis: usize) -> [f64; 3] {
    let mut e = [0.0; 3];
    e[axis] = 1.0;
    e
}

impl Segment {
    /// The geometry of a move from `from` to `to` along `path`.
    pub fn new(from: Pose, to: Pose, path: Path) -> Segment {
        let arc = match path {
            Path::Line => None,
            Path::Arc {
                plane,
                center,
                clockwise,
                extra_turns,
            } => {
                let [a0, a1, an] = plane.axes();
                let start_angle = (from[a1] - center[1]).atan2(from[a0] - center[0]);
                let end_angle = (to[a1] - center[1]).atan2(to[a0] - center[0]);
                let radius = (from[a0] - center[0]).hypot(from[a1] - center[1]);
                let end_radius = (to[a0] - center[0]).hypot(to[a1] - center[1]);
                // The sweep in the arc's direction, a full turn when it ends where it starts.
                let mut sweep = if clockwise {
                    start_angle - end_angle
                } else {
                    end_angle - start_angle
                };
                while sweep <= 1e-12 {
                    sweep += TAU;
                }
                while sweep > TAU + 1e-12 {
                    sweep -= TAU;
                }
                sweep += f64::from(extra_turns) * TAU;
                // φ runs from the start point, counter-clockwise for G3 and clockwise for G2
                // (looking down the plane's normal).
                let (e0, e1) = (unit(a0), unit(a1));
                let (c0, s0) = (start_angle.cos(), start_angle.sin());
                let u = [
                    e0[0] * c0 + e1[0] * s0,
                    e0[1] * c0 + e1[1] * s0,
                    e0[2] * c0 + e1[2] * s0,
                ];
                let tangent = [
                    -e0[0] * s0 + e1[0] * c0,
                    -e0[1] * s0 + e1[1] * c0,
                    -e0[2] * s0 + e1[2] * c0,
                ];
                let v = if clockwise { tangent.map(|t| -t) } else { tangent };
                let mut c = [from[0], from[1], from[2]];
                c[a0] = center[0];
                c[a1] = center[1];
                Some(Box::new(
                    Arc {
                        center: c,
                        u,
                        v,
                        w: unit(an),
                        radius,
                        spiral: end_radius - radius,
                        sweep,
                        rise: to[an] - from[an],
                        length: 0.0,
                    }
                    .measured(),
                ))
            }
        };
        Segment {
            from,
            to,
            arc,
            rotation_rates: None,
        }
    }

    /// A blend: the arc of `radius` about `center` from `from` (its x y z on the circle, `u`
    /// pointing there from the centre, `v` the direction of travel there) turning by `sweep` to
    /// `to`; the rotations a b c leave at `rates.0` and arrive at `rates.1` (degrees per mm of
    /// path), the rates of the lines it joins.
    #[allow(clippy::too_many_arguments)] // the arc's geometry, named
    pub fn blend(
        from: Pose,
        to: Pose,
        center: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
        radius: f64,
        sweep: f64,
        rates: ([f64; 3], [f64; 3]),
    ) -> Segment {
        let length = radius * sweep;
        let w = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        Segment {
            from,
            to,
            arc: Some(Box::new(
                Arc {
                    center,
                    u,
                    v,
                    w,
                    radius,
                    spiral: 0.0,
                    sweep,
                    rise: 0.0,
                    length: 0.0,
                }
                .measured(),
            )),
            rotation_rates: Some(Box::new((rates.0.map(|r| r * length), rates.1.map(|r| r * length)))),
        }
    }

    /// The rates of a b c along the path at its ends (degrees per mm; zero where the tool point
    /// does not move).
    pub fn rotation_rates(&self) -> ([f64; 3], [f64; 3]) {
        let len = self.linear_length();
        if len <= 1e-12 {
            return ([0.0; 3], [0.0; 3]);
        }
        match self.rotation_rates.as_deref() {
            Some((m0, m1)) => (m0.map(|m| m / len), m1.map(|m| m / len)),
            None => {
                let r: [f64; 3] = std::array::from_fn(|c| (self.to[c + 3] - self.from[c + 3]) / len);
                (r, r)
            }
        }
    }

    /// The length the feed is measured along (mm): the path in x y z, or where the tool point
    /// does not move, the rotations' (degrees, as LinuxCNC takes them).
    pub fn length(&self) -> f64 {
        let linear = self.linear_length();
        if linear > 1e-12 { linear } else { self.angular() }
    }

    /// The length of the tool point's path (mm).
    pub fn linear_length(&self) -> f64 {
        match self.arc.as_deref() {
            None => (0..3).map(|c| (self.to[c] - self.from[c]).powi(2)).sum::<f64>().sqrt(),
            Some(a) => a.length(),
        }
    }

    /// The part of it from fraction `u0` to `u1` (0 ≤ u0 < u1 ≤ 1): the same line or arc,
    /// shorter. A blend's rotation rates are not kept (only program moves are trimmed).
    pub fn trimmed(&self, u0: f64, u1: f64) -> Segment {
        let (from, to) = (self.at(u0), self.at(u1));
        let arc = self.arc.as_deref().map(|a| {
            let (phi, phi1) = (a.angle(u0), a.angle(u1));
            let (f0, f1) = (phi / a.sweep, phi1 / a.sweep);
            let (cos, sin) = (phi.cos(), phi.sin());
            Box::new(
                Arc {
                    center: std::array::from_fn(|c| a.center[c] + a.rise * f0 * a.w[c]),
                    u: std::array::from_fn(|c| cos * a.u[c] + sin * a.v[c]),
                    v: std::array::from_fn(|c| -sin * a.u[c] + cos * a.v[c]),
                    w: a.w,
                    radius: a.radius + a.spiral * f0,
                    spiral: a.spiral * (f1 - f0),
                    sweep: phi1 - phi,
                    rise: a.rise * (f1 - f0),
                    length: 0.0,
                }
                .measured(),
            )
        });
        Segment {
            from,
            to,
            arc,
            rotation_rates: None,
        }
    }

    /// Whether its rotations a b c stay as they are.
    pub fn keeps_rotations(&self) -> bool {
        (3..6).all(|c| self.from[c] == self.to[c]) && self.rotation_rates.is_none()
    }

    /// The largest change of a rotation a b c (degrees).
    pub fn angular(&self) -> f64 {
        (3..6).map(|c| (self.to[c] - self.from[c]).abs()).fold(0.0, f64::max)
    }

    /// The pose at fraction `u` (0 … 1) of the move.
    pub fn at(&self, u: f64) -> Pose {
        if u >= 1.0 {
            // The end point exactly, not as the circle's formula rounds it.
            return self.to;
        }
        self.at_extended(u)
    }

    /// The pose at fraction `u` of the move, where `u` may lie a little outside 0 … 1: the line
    /// or curve continued (the derivatives at its ends are measured across them).
    pub fn at_extended(&self, u: f64) -> Pose {
        let mut p: Pose = std::array::from_fn(|c| self.from[c] + (self.to[c] - self.from[c]) * u);
        if let Some(a) = self.arc.as_deref() {
            // Along the path in proportion to its length.
            let phi = a.angle(u);
            let f = phi / a.sweep;
            let (cos, sin) = (phi.cos(), phi.sin());
            let r = a.radius + a.spiral * f;
            for (c, x) in p.iter_mut().take(3).enumerate() {
                *x = a.center[c] + r * (cos * a.u[c] + sin * a.v[c]) + a.rise * f * a.w[c];
            }
        }
        if let Some((m0, m1)) = self.rotation_rates.as_deref() {
            // Cubic Hermite: the values at both ends, the rates of the lines at both ends.
            let (u2, u3) = (u * u, u * u * u);
            let (h00, h10, h01, h11) = (
                2.0 * u3 - 3.0 * u2 + 1.0,
                u3 - 2.0 * u2 + u,
                -2.0 * u3 + 3.0 * u2,
                u3 - u2,
            );
            for c in 0..3 {
                p[c + 3] = h00 * self.from[c + 3] + h10 * m0[c] + h01 * self.to[c + 3] + h11 * m1[c];
            }
        }
        p
    }

    /// The pose it starts at.
    pub fn from(&self) -> &Pose {
        &self.from
    }

    /// The pose it ends at.
    pub fn to(&self) -> &Pose {
        &self.to
    }

    /// The angle an arc turns (rad; 0 for a line).
    pub fn sweep(&self) -> f64 {
        self.arc.as_deref().map_or(0.0, |a| a.sweep)
    }

    /// Whether it is an arc (or a blend).
    pub fn is_arc(&self) -> bool {
        self.arc.is_some()
    }

    /// The unit direction of the tool point's travel at fraction `u` (zero when it does not
    /// move).
    pub fn direction(&self, u: f64) -> [f64; 3] {
        let d = match self.arc.as_deref() {
            None => [
                self.to[0] - self.from[0],
                self.to[1] - self.from[1],
                self.to[2] - self.from[2],
            ],
            Some(a) => {
                let phi = a.angle(u);
                let (cos, sin) = (phi.cos(), phi.sin());
                let r = a.radius + a.spiral * phi / a.sweep;
                std::array::from_fn(|c| {
                    r * a.sweep * (-sin * a.u[c] + cos * a.v[c])
                        + a.spiral * (cos * a.u[c] + sin * a.v[c])
                        + a.rise * a.w[c]
                })
            }
        };
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if n > 0.0 { d.map(|x| x / n) } else { [0.0; 3] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interp::Plane;
    use proptest::prelude::*;

    fn arc(clockwise: bool, extra_turns: u32) -> Path {
        Path::Arc {
            plane: Plane::Xy,
            center: [0.0, 0.0],
            clockwise,
            extra_turns,
        }
    }

    #[test]
    fn lengths_of_lines_quarter_circles_full_turns_and_helices() {
        let p = |x: f64, y: f64, z: f64| [x, y, z, 0.0, 0.0, 0.0];
        let line = Segment::new(p(0.0, 0.0, 0.0), p(3.0, 4.0, 0.0), Path::Line);
        assert_eq!(line.length(), 5.0);
        let ccw = Segment::new(p(10.0, 0.0, 0.0), p(0.0, 10.0, 0.0), arc(false, 0));
        assert!((ccw.length() - 5.0 * std::f64::consts::PI).abs() < 1e-9, "a quarter");
        let cw = Segment::new(p(10.0, 0.0, 0.0), p(0.0, 10.0, 0.0), arc(true, 0));
        assert!(
            (cw.length() - 15.0 * std::f64::consts::PI).abs() < 1e-9,
            "three quarters the other way"
        );
        let full = Segment::new(p(10.0, 0.0, 0.0), p(10.0, 0.0, 0.0), arc(false, 1));
        assert!(
            (full.at(0.125)[1] - 10.0).abs() < 1e-9,
            "a quarter into two turns: (0, 10)"
        );
        assert!(
            (full.length() - 40.0 * std::f64::consts::PI).abs() < 1e-9,
            "two full turns"
        );
        let helix = Segment::new(p(10.0, 0.0, 0.0), p(10.0, 0.0, 5.0), arc(false, 0));
        assert!((helix.length() - (20.0 * std::f64::consts::PI).hypot(5.0)).abs() < 1e-9);
        assert!((helix.at(0.5)[2] - 2.5).abs() < 1e-12);
        assert!(
            (cw.at(0.5)[0] + 7.0710678).abs() < 1e-6 && (cw.at(0.5)[1] + 7.0710678).abs() < 1e-6,
            "{:?}",
            cw.at(0.5)
        );
        assert!(
            (ccw.direction(0.0)[1] - 1.0).abs() < 1e-12,
            "G3 from (10, 0) starts along +y"
        );
        assert!(
            (cw.direction(0.0)[1] + 1.0).abs() < 1e-12,
            "G2 from (10, 0) starts along −y"
        );
        let turn_only = Segment::new([0.0; 6], [0.0, 0.0, 0.0, 3.0, -4.0, 0.0], Path::Line);
        assert_eq!(turn_only.length(), 4.0, "rotations alone: the largest, in degrees");
    }

    #[test]
    fn a_trimmed_arc_or_line_runs_on_the_same_path() {
        let p = |x: f64, y: f64, z: f64| [x, y, z, 0.0, 0.0, 0.0];
        let helix = Segment::new(p(10.0, 0.0, 0.0), p(0.0, 10.0, 4.0), arc(false, 0));
        let part = helix.trimmed(0.25, 0.75);
        for i in 0..=10 {
            let u = f64::from(i) / 10.0;
            let (a, b) = (part.at(u), helix.at(0.25 + 0.5 * u));
            assert!((0..3).all(|c| (a[c] - b[c]).abs() < 1e-9), "{a:?} vs {b:?}");
        }
        assert!((part.length() - helix.length() / 2.0).abs() < 1e-9);
        let line = Segment::new(p(0.0, 0.0, 0.0), p(10.0, 0.0, 0.0), Path::Line);
        assert_eq!(line.trimmed(0.1, 1.0).from()[0], 1.0);
    }

    proptest! {
        /// Every sampled point of an arc lies on its circle, and the samples run from its start
        /// to its end.
        #[test]
        fn arcs_are_round(r in 0.1f64..500.0, a0 in -3.2f64..3.2, a1 in -3.2f64..3.2, cw: bool, cx in -100.0f64..100.0) {
            let from = [cx + r * a0.cos(), r * a0.sin(), 0.0, 0.0, 0.0, 0.0];
            let to = [cx + r * a1.cos(), r * a1.sin(), 0.0, 0.0, 0.0, 0.0];
            let s = Segment::new(from, to, Path::Arc { plane: Plane::Xy, center: [cx, 0.0], clockwise: cw, extra_turns: 0 });
            for i in 0..=50 {
                let p = s.at(f64::from(i) / 50.0);
                let radial = ((p[0] - cx).hypot(p[1]) - r).abs();
                prop_assert!(radial < 1e-9 * r.max(1.0), "radial deviation {radial}");
            }
            let start = s.at(0.0);
            prop_assert!((start[0] - from[0]).abs() < 1e-9 && (start[1] - from[1]).abs() < 1e-9);
            prop_assert_eq!(s.at(1.0), to);
        }
    }
}
