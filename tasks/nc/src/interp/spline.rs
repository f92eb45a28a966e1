//! G5 (a cubic spline) and G5.1 (a quadratic one) in the XY plane, made as LinuxCNC 2.9 makes
//! them: the Bézier curve of the control points (the start, the start plus I J, the end plus P Q
//! for G5, the end) sampled at four points per control point, each pair of samples joined by a
//! biarc — two arcs that leave the first sample along the curve's tangent there and reach the
//! second along its tangent there (LinuxCNC's `NURBS_FEED` and `biarc`). The tool follows arcs,
//! so the path is tangent-continuous and within a few microns of the curve.
//!
//! Where LinuxCNC makes no biarc (tangents that admit none) it leaves the piece out and the next
//! arc starts where the tool is not; here that piece is a straight line, so the path stays whole.

use crate::NcError;
use crate::lexer::Word;

use super::block::{Action, Block, Path, Plane, Pose};
use super::state::State;
use super::words::Words;

/// Samples per control point (LinuxCNC's `NURBS_FEED`: `div = points × 4`).
const SAMPLES_PER_POINT: usize = 4;

/// The step of the tangent's finite difference in the curve's parameter (LinuxCNC's `DU`).
const TANGENT_STEP: f64 = 1e-5;

/// A piece of a spline: to `end`, straight or around `center` (clockwise or not).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Piece {
    Line {
        end: [f64; 2],
    },
    Arc {
        end: [f64; 2],
        center: [f64; 2],
        clockwise: bool,
    },
}

impl State<'_> {
    /// The block's spline from where the tool stands to `to` (X and Y: G5 when `cubic`, else
    /// G5.1), at the feed in force, as arcs (and, rarely, lines) blended as the path mode says.
    pub(super) fn spline(
        &mut self,
        line: usize,
        words: &Words<'_>,
        cubic: bool,
        to: Pose,
        first: &Word,
        out: &mut Vec<Block>,
    ) -> Result<(), NcError> {
        let at = |w: &Word, message: &str| NcError::new(line, w.column, message.to_string());
        let name = if cubic { "G5" } else { "G5.1" };
        // Where the block says G5 (or, modal, where its first axis word is).
        let code = words.motion_word().map_or(first, |(_, w)| w);
        if self.plane != Plane::Xy {
            return Err(at(
                code,
                &format!("{name}: splines are taken in the XY plane only (G17)"),
            ));
        }
        for letter in ['Z', 'A', 'B', 'C'] {
            if let Some(w) = words.get(letter) {
                return Err(at(
                    w,
                    &format!("{name}: a spline moves in X and Y only, not in {letter}"),
                ));
            }
        }
        let unit = self.unit();
        let offset = |letters: [char; 2]| words.get(letters[0]).zip(words.get(letters[1]));
        let start = [self.position[0], self.position[1]];
        let end = [to[0], to[1]];
        let mut points = vec![start];
        if cubic {
            // I J: the first control point's offset from the start, or neither (the last G5's
            // P Q reversed, 0 before any: LinuxCNC's).
            let ij = match (offset(['I', 'J']), words.get('I').or(words.get('J'))) {
                (Some((i, j)), _) => [i.value, j.value],
                (None, Some(w)) => {
                    return Err(at(
                        w,
                        "G5: I and J both, or neither (then the last G5's P and Q, reversed)",
                    ));
                }
                (None, None) => self.spline_ij,
            };
            let Some((p, q)) = offset(['P', 'Q']) else {
                return Err(at(
                    words.get('P').or(words.get('Q')).unwrap_or(code),
                    "G5: P and Q are both needed (the second control point's offset from the end)",
                ));
            };
            points.push([start[0] + ij[0] * unit, start[1] + ij[1] * unit]);
            points.push([end[0] + p.value * unit, end[1] + q.value * unit]);
            self.spline_ij = [-p.value, -q.value];
        } else {
            let Some((i, j)) = offset(['I', 'J']) else {
                return Err(at(
                    words.get('I').or(words.get('J')).unwrap_or(code),
                    "G5.1: I and J are both needed (the control point's offset from the start)",
                ));
            };
            points.push([start[0] + i.value * unit, start[1] + j.value * unit]);
        }
        points.push(end);
        let pieces = pieces(&points);
        // The feed over the whole curve (in inverse time the spline takes 1/F minutes).
        let mut length = 0.0;
        let mut from = start;
        for piece in &pieces {
            let (e, path) = self.piece_path(*piece);
            length += crate::path::Segment::new(self.at_xy(from), self.at_xy(e), path).length();
            from = e;
        }
        let feed = self.feed_of(length, first, line, "G5 or G5.1")?;
        for piece in pieces {
            let (e, path) = self.piece_path(piece);
            let target = self.at_xy(e);
            // A piece that goes nowhere is left out: an arc to its own start would be a circle.
            if (0..2).all(|c| (target[c] - self.position[c]).abs() < 1e-9) {
                continue;
            }
            out.push(Block {
                line,
                column: 1,
                action: Action::Move {
                    from: self.position,
                    to: target,
                    path,
                    feed_mm_min: Some(feed),
                    blend: self.blend,
                },
            });
            self.position = target;
        }
        // The end exactly where the block says, whatever the pieces' rounding.
        self.position[0] = to[0];
        self.position[1] = to[1];
        Ok(())
    }

    /// The tool's position with X and Y at `xy`.
    fn at_xy(&self, xy: [f64; 2]) -> Pose {
        let mut p = self.position;
        p[0] = xy[0];
        p[1] = xy[1];
        p
    }

    /// A piece's end and path.
    fn piece_path(&self, piece: Piece) -> ([f64; 2], Path) {
        match piece {
            Piece::Line { end } => (end, Path::Line),
            Piece::Arc { end, center, clockwise } => (
                end,
                Path::Arc {
                    plane: Plane::Xy,
                    center,
                    clockwise,
                    extra_turns: 0,
                },
            ),
        }
    }
}

/// The Bézier curve of `points` at `t` (0 … 1).
fn bezier(points: &[[f64; 2]], t: f64) -> [f64; 2] {
    // De Casteljau: exact for any number of points, stable.
    let mut p = points.to_vec();
    for k in (1..p.len()).rev() {
        for i in 0..k {
            p[i] = [
                p[i][0] + (p[i + 1][0] - p[i][0]) * t,
                p[i][1] + (p[i + 1][1] - p[i][1]) * t,
            ];
        }
    }
    p[0]
}

/// The curve's direction at `t` (a unit vector; zero where the curve stands), by LinuxCNC's
/// finite difference.
fn tangent(points: &[[f64; 2]], t: f64) -> [f64; 2] {
    let (lo, hi) = ((t - TANGENT_STEP).max(0.0), (t + TANGENT_STEP).min(1.0));
    let (a, b) = (bezier(points, lo), bezier(points, hi));
    unit([(b[0] - a[0]) / (hi - lo), (b[1] - a[1]) / (hi - lo)])
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let h = v[0].hypot(v[1]);
    if h == 0.0 { v } else { [v[0] / h, v[1] / h] }
}

/// The pieces of the spline of `points`: a biarc between each pair of samples.
fn pieces(points: &[[f64; 2]]) -> Vec<Piece> {
    let samples = points.len() * SAMPLES_PER_POINT;
    let mut out = Vec::with_capacity(2 * samples);
    let (mut p0, mut t0) = (bezier(points, 0.0), tangent(points, 0.0));
    for i in 1..=samples {
        let u = i as f64 / samples as f64;
        let (p1, t1) = (bezier(points, u), tangent(points, u));
        biarc(p0, t0, p1, t1, &mut out);
        (p0, t0) = (p1, t1);
    }
    out
}

/// The equal-ratio biarc from `p0` leaving along `t0` to `p4` arriving along `t4` (LinuxCNC's
/// `biarc` with r = 1): two pieces; one straight line where the tangents admit no biarc.
fn biarc(p0: [f64; 2], t0: [f64; 2], p4: [f64; 2], t4: [f64; 2], out: &mut Vec<Piece>) {
    let v = [p0[0] - p4[0], p0[1] - p4[1]];
    let c = v[0] * v[0] + v[1] * v[1];
    let b = 2.0 * (v[0] * (t0[0] + t4[0]) + v[1] * (t0[1] + t4[1]));
    let a = 2.0 * (t0[0] * t4[0] + t0[1] * t4[1] - 1.0);
    let discriminant = b * b - 4.0 * a * c;
    // Parallel tangents (a straight stretch: a = 0) or none that meet: a line.
    if a.abs() < 1e-12 || discriminant < 0.0 {
        out.push(Piece::Line { end: p4 });
        return;
    }
    let root = discriminant.sqrt();
    let (beta1, beta2) = ((-b - root) / 2.0 / a, (-b + root) / 2.0 / a);
    if beta1 > 0.0 && beta2 > 0.0 {
        out.push(Piece::Line { end: p4 });
        return;
    }
    let beta = beta1.max(beta2);
    let alpha = beta;
    let ab = alpha + beta;
    if !(ab.is_finite() && ab != 0.0) {
        out.push(Piece::Line { end: p4 });
        return;
    }
    let p1 = [p0[0] + alpha * t0[0], p0[1] + alpha * t0[1]];
    let p3 = [p4[0] - beta * t4[0], p4[1] - beta * t4[1]];
    let p2 = [(p1[0] * beta + p3[0] * alpha) / ab, (p1[1] * beta + p3[1] * alpha) / ab];
    let tm = unit([p3[0] - p2[0], p3[1] - p2[1]]);
    out.push(arc(p0, p2, t0));
    out.push(arc(p2, p4, tm));
}

/// The arc from `p0` to `p1` leaving `p0` along `d` (LinuxCNC's `arc`); a line where it is
/// straight.
fn arc(p0: [f64; 2], p1: [f64; 2], d: [f64; 2]) -> Piece {
    let (x, y) = (p1[0] - p0[0], p1[1] - p0[1]);
    let den = 2.0 * (y * d[0] - x * d[1]);
    if den.abs() <= 1e-6 {
        return Piece::Line { end: p1 };
    }
    let r = -(x * x + y * y) / den;
    let center = [p0[0] + d[1] * r, p0[1] - d[0] * r];
    Piece::Arc {
        end: p1,
        center,
        clockwise: r >= 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every piece starts where the one before ended and stays within `tolerance` of the
    /// Bézier curve (sampled at 50 points of each piece, against the curve sampled at 4 000).
    fn close_to_curve(points: &[[f64; 2]], tolerance: f64) {
        let curve: Vec<[f64; 2]> = (0..=4_000).map(|i| bezier(points, f64::from(i) / 4_000.0)).collect();
        let near = |p: [f64; 2]| {
            curve
                .iter()
                .map(|c| (c[0] - p[0]).hypot(c[1] - p[1]))
                .fold(f64::INFINITY, f64::min)
        };
        let mut from = points[0];
        for piece in pieces(points) {
            let samples: Vec<[f64; 2]> = match piece {
                Piece::Line { end } => (0..=50)
                    .map(|k| {
                        let s = f64::from(k) / 50.0;
                        [from[0] + (end[0] - from[0]) * s, from[1] + (end[1] - from[1]) * s]
                    })
                    .collect(),
                Piece::Arc { end, center, clockwise } => {
                    let r = (from[0] - center[0]).hypot(from[1] - center[1]);
                    assert!(
                        ((end[0] - center[0]).hypot(end[1] - center[1]) - r).abs() < 1e-9,
                        "an arc's end on its circle"
                    );
                    let a0 = (from[1] - center[1]).atan2(from[0] - center[0]);
                    let mut a1 = (end[1] - center[1]).atan2(end[0] - center[0]);
                    if clockwise && a1 > a0 {
                        a1 -= std::f64::consts::TAU;
                    }
                    if !clockwise && a1 < a0 {
                        a1 += std::f64::consts::TAU;
                    }
                    (0..=50)
                        .map(|k| {
                            let a = a0 + (a1 - a0) * f64::from(k) / 50.0;
                            [center[0] + r * a.cos(), center[1] + r * a.sin()]
                        })
                        .collect()
                }
            };
            for p in samples {
                let d = near(p);
                assert!(d < tolerance, "{piece:?} strays {d} from the curve");
            }
            from = match piece {
                Piece::Line { end } | Piece::Arc { end, .. } => end,
            };
        }
        let last = points[points.len() - 1];
        assert!(
            (from[0] - last[0]).hypot(from[1] - last[1]) < 1e-12,
            "ends at the last point"
        );
    }

    #[test]
    fn the_pieces_follow_the_curve_within_microns() {
        // LinuxCNC's documentation's G5 example, a quadratic, an S, a straight one and a cusp-free
        // loop-like curve of 50 mm.
        close_to_curve(&[[0.0, 0.0], [0.0, 1.0], [-1.0, 1.0], [1.0, 1.0]], 0.002);
        close_to_curve(&[[0.0, 0.0], [5.0, 10.0], [10.0, 0.0]], 0.005);
        close_to_curve(&[[0.0, 0.0], [10.0, 20.0], [0.0, -20.0], [10.0, 0.0]], 0.05);
        close_to_curve(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]], 1e-9);
        close_to_curve(&[[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]], 0.05);
    }

    proptest::proptest! {
        /// Whatever the control points (a few microns to a metre apart, coinciding, in a line),
        /// every piece is finite, arcs end on their circles, and the pieces end at the curve's end.
        #[test]
        fn any_spline_is_whole_and_finite(
            coords in proptest::collection::vec(-1000.0f64..1000.0, 8),
            scale in proptest::sample::select(vec![1e-3, 1.0, 1e3]),
            cubic in proptest::bool::ANY,
        ) {
            let n = if cubic { 4 } else { 3 };
            let points: Vec<[f64; 2]> = (0..n).map(|k| [coords[2 * k] * scale / 1000.0, coords[2 * k + 1] * scale / 1000.0]).collect();
            let mut from = points[0];
            for piece in pieces(&points) {
                let (Piece::Line { end } | Piece::Arc { end, .. }) = piece;
                proptest::prop_assert!(end[0].is_finite() && end[1].is_finite(), "{piece:?}");
                if let Piece::Arc { center, .. } = piece {
                    proptest::prop_assert!(center[0].is_finite() && center[1].is_finite(), "{piece:?}");
                    let (r0, r1) = ((from[0] - center[0]).hypot(from[1] - center[1]), (end[0] - center[0]).hypot(end[1] - center[1]));
                    proptest::prop_assert!((r0 - r1).abs() <= 1e-9 * r0.max(1.0), "{piece:?} from {from:?}");
                }
                from = end;
            }
            let last = points[n - 1];
            proptest::prop_assert!((from[0] - last[0]).hypot(from[1] - last[1]) <= 1e-9 * scale.max(1.0));
        }
    }

    #[test]
    fn a_straight_spline_is_lines_and_never_a_number_that_is_not() {
        for piece in pieces(&[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]) {
            match piece {
                Piece::Line { end } => assert!(end[0].is_finite() && end[1] == 0.0),
                Piece::Arc { .. } => panic!("an arc on a straight spline: {piece:?}"),
            }
        }
        // All control points in one place: nothing moves, nothing is NaN.
        for piece in pieces(&[[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]) {
            let (Piece::Line { end } | Piece::Arc { end, .. }) = piece;
            assert_eq!(end, [1.0, 1.0]);
        }
    }
}
