//! The geometry of a move: its length along the path, and its pose at a fraction of it. Lines
//! are straight in world coordinates; arcs turn about their plane's normal, a helix rises along
//! it, and every other coordinate (a rotation during an arc, say) changes in proportion.

use std::f64::consts::TAU;

use crate::interp::{Path, Pose};

/// A move's geometry, ready to be sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    from: Pose,
    to: Pose,
    arc: Option<Arc>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Arc {
    axes: [usize; 3],
    center: [f64; 2],
    radius: f64,
    start_angle: f64,
    /// Signed sweep (rad): positive counter-clockwise.
    sweep: f64,
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
                let axes = plane.axes();
                let [a0, a1, _] = axes;
                let start_angle = (from[a1] - center[1]).atan2(from[a0] - center[0]);
                let end_angle = (to[a1] - center[1]).atan2(to[a0] - center[0]);
                let radius = (from[a0] - center[0]).hypot(from[a1] - center[1]);
                // The sweep in the arc's direction, a full turn when it ends where it starts.
                let mut sweep = end_angle - start_angle;
                if clockwise {
                    while sweep >= -1e-12 {
                        sweep -= TAU;
                    }
                    if sweep < -TAU - 1e-12 {
                        sweep += TAU;
                    }
                } else {
                    while sweep <= 1e-12 {
                        sweep += TAU;
                    }
                    if sweep > TAU + 1e-12 {
                        sweep -= TAU;
                    }
                }
                let turns = f64::from(extra_turns) * TAU;
                sweep += if clockwise { -turns } else { turns };
                Some(Arc {
                    axes,
                    center,
                    radius,
                    start_angle,
                    sweep,
                })
            }
        };
        Segment { from, to, arc }
    }

    /// The length the feed is measured along (mm): the path in x y z, or where the tool point
    /// does not move, the rotations' (degrees, as LinuxCNC takes them).
    pub fn length(&self) -> f64 {
        let linear = match self.arc {
            None => (0..3).map(|c| (self.to[c] - self.from[c]).powi(2)).sum::<f64>().sqrt(),
            Some(a) => {
                let rise = self.to[a.axes[2]] - self.from[a.axes[2]];
                (a.radius * a.sweep).hypot(rise)
            }
        };
        if linear > 1e-12 { linear } else { self.angular() }
    }

    /// The largest change of a rotation a b c (degrees).
    pub fn angular(&self) -> f64 {
        (3..6).map(|c| (self.to[c] - self.from[c]).abs()).fold(0.0, f64::max)
    }

    /// The pose at fraction `u` (0 … 1) of the move.
    pub fn at(&self, u: f64) -> Pose {
        let mut p: Pose = std::array::from_fn(|c| self.from[c] + (self.to[c] - self.from[c]) * u);
        if let Some(a) = self.arc {
            let angle = a.start_angle + a.sweep * u;
            p[a.axes[0]] = a.center[0] + a.radius * angle.cos();
            p[a.axes[1]] = a.center[1] + a.radius * angle.sin();
        }
        if u >= 1.0 {
            // The end point exactly, not as the circle's formula rounds it.
            p = self.to;
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

    /// The arc's radius (mm), for arcs.
    pub fn radius(&self) -> Option<f64> {
        self.arc.map(|a| a.radius)
    }

    /// The arc's centre in its plane's axes, and the axes' indices, for arcs.
    pub fn center(&self) -> Option<([usize; 3], [f64; 2])> {
        self.arc.map(|a| (a.axes, a.center))
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
            (full.length() - 40.0 * std::f64::consts::PI).abs() < 1e-9,
            "two full turns"
        );
        let helix = Segment::new(p(10.0, 0.0, 0.0), p(10.0, 0.0, 5.0), arc(false, 0));
        assert!((helix.length() - (20.0 * std::f64::consts::PI).hypot(5.0)).abs() < 1e-9);
        assert!((helix.at(0.5)[2] - 2.5).abs() < 1e-12);
        let turn_only = Segment::new([0.0; 6], [0.0, 0.0, 0.0, 3.0, -4.0, 0.0], Path::Line);
        assert_eq!(turn_only.length(), 4.0, "rotations alone: the largest, in degrees");
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
