//! Random but ordinary NC programs for the planner's property tests: lines and rapids, arcs of
//! tiny to huge radius by their centre or radius, helices, canned cycles, dwells; feeds from F1
//! to F20000; G61, G61.1, G64, G64 P and G64 P Q; segments from 0.001 mm, reversals,
//! colinear and repeated points, numbers written to three to six decimals as CAM posts write
//! them; on a machine with rotations, tilts of up to 2° a millimetre with the moves, and turns
//! alone; all within a few millimetres of the machine's home.

use proptest::prelude::*;

/// What a machine's programs may move.
#[derive(Clone, Copy, Debug)]
pub struct Axes {
    /// It has a Z axis (the TRIJOINT is planar).
    pub z: bool,
    /// It has rotations A B C (the hexapod).
    pub rotations: bool,
}

/// One move or action of a program, before it is written.
#[derive(Clone, Debug)]
enum Step {
    /// G0 or G1 to a point at an offset from where the tool is.
    Line { rapid: bool, d: [f64; 3], turn: [f64; 3] },
    /// The same point again.
    Repeat,
    /// On along the last direction, by a factor of the last move.
    Colinear(f64),
    /// Back along the last direction, by a factor of the last move.
    Reverse(f64),
    /// An arc (a helix where it rises) of `radius` turning by `sweep` rad from the tool's
    /// position, its centre in direction `toward` (rad in the plane), by I J or by R.
    Arc {
        clockwise: bool,
        radius: f64,
        toward: f64,
        sweep: f64,
        rise: f64,
        by_radius: bool,
    },
    /// A canned cycle at an offset, `code` one of 81 82 83 73 85 89.
    Cycle {
        code: u16,
        d: [f64; 2],
        depth: f64,
        peck: f64,
    },
    /// G4 P.
    Dwell(f64),
    /// A new feed.
    Feed(f64),
    /// A new blending mode.
    Mode(String),
}

fn feed() -> impl Strategy<Value = f64> {
    // Log-uniform from F1 to F20000.
    (0.0f64..1.0).prop_map(|u| (20000f64.ln() * u).exp())
}

fn mode() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("G61".to_string()),
        Just("G61.1".to_string()),
        Just("G64".to_string()),
        (0.0f64..1.0).prop_map(|u| format!("G64 P{:.4}", 0.001 * 1000f64.powf(u))),
        ((0.0f64..1.0), (0.0f64..1.0)).prop_map(|(u, w)| format!(
            "G64 P{:.4} Q{:.4}",
            0.001 * 1000f64.powf(u),
            0.001 * 500f64.powf(w)
        )),
    ]
}

/// A length from 0.001 mm to about 20 mm, log-uniform.
fn length() -> impl Strategy<Value = f64> {
    (0.0f64..1.0).prop_map(|u| 0.001 * 20000f64.powf(u))
}

fn step(axes: Axes) -> impl Strategy<Value = Step> {
    let z = if axes.z { 1.0 } else { 0.0 };
    let r = if axes.rotations { 1.0 } else { 0.0 };
    let line = (
        any::<bool>(),
        length(),
        (0.0f64..std::f64::consts::TAU),
        (-1.0f64..1.0),
        prop::array::uniform3(-2.0f64..2.0),
    )
        .prop_map(move |(rapid, len, angle, tilt, turn)| {
            let tilt = tilt * z;
            let d = [
                len * angle.cos() * (1.0 - tilt * tilt).sqrt(),
                len * angle.sin() * (1.0 - tilt * tilt).sqrt(),
                len * tilt,
            ];
            // A platform turns by degrees over millimetres, as a program of a six-axis machine
            // tilts it: at most 2° a millimetre of a shorter move.
            let share = r * len.min(1.0);
            Step::Line {
                rapid: rapid && len > 1.0,
                d,
                turn: turn.map(|t| t * share),
            }
        });
    // A turn alone (the tool point stands; the feed is in degrees a minute).
    let turn = prop::array::uniform3(-2.0f64..2.0).prop_map(move |turn| Step::Line {
        rapid: false,
        d: [0.0; 3],
        turn,
    });
    let arc = (
        any::<bool>(),
        prop_oneof![(0.001f64..0.05), (0.05f64..5.0), (5.0f64..20.0), (200.0f64..5000.0),],
        (0.0f64..std::f64::consts::TAU),
        (0.0f64..1.0),
        (-1.0f64..1.0),
        any::<bool>(),
    )
        .prop_map(move |(clockwise, radius, toward, sweep_u, rise, by_radius)| {
            // A huge radius turns by little: its chord stays within a few millimetres.
            let most = (6.0 / radius).min(2.0 * std::f64::consts::PI);
            Step::Arc {
                clockwise,
                radius,
                toward,
                sweep: 0.01 + (most - 0.01).max(0.0) * sweep_u,
                rise: rise * z * 2.0,
                by_radius,
            }
        });
    let cycle = (
        prop::sample::select(vec![81u16, 82, 83, 73, 85, 89]),
        prop::array::uniform2(-3.0f64..3.0),
        (0.1f64..3.0),
        (0.05f64..1.0),
    )
        .prop_map(|(code, d, depth, peck)| Step::Cycle { code, d, depth, peck });
    let mut choices: Vec<(u32, BoxedStrategy<Step>)> = vec![
        (10, line.boxed()),
        (1, Just(Step::Repeat).boxed()),
        (2, (0.001f64..2.0).prop_map(Step::Colinear).boxed()),
        (2, (0.001f64..2.0).prop_map(Step::Reverse).boxed()),
        (6, arc.boxed()),
        (1, (0.0f64..0.3).prop_map(Step::Dwell).boxed()),
        (2, feed().prop_map(Step::Feed).boxed()),
        (2, mode().prop_map(Step::Mode).boxed()),
    ];
    if axes.z {
        choices.push((2, cycle.boxed()));
    }
    if axes.rotations {
        choices.push((2, turn.boxed()));
    }
    prop::strategy::Union::new_weighted(choices)
}

/// A program: its mode, its first feed and 1 to `most` steps, written to `decimals` decimals.
pub fn program(axes: Axes, most: usize) -> impl Strategy<Value = String> {
    (mode(), feed(), prop::collection::vec(step(axes), 1..most), 3usize..7)
        .prop_map(move |(mode, f, steps, decimals)| write(axes, &mode, f, &steps, decimals))
}

/// The program's text: the tool starts at home (all zero) and stays within a box of ±5 mm
/// (x y; z from −4 to 1), ±2° in the rotations; a move that would leave it is turned back.
fn write(axes: Axes, mode: &str, feed: f64, steps: &[Step], decimals: usize) -> String {
    let num = |x: f64| {
        let s = format!("{x:.decimals$}");
        // "-0.000" as "0.000".
        if s.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
            format!("{:.decimals$}", 0.0)
        } else {
            s
        }
    };
    let round = |x: f64| {
        let k = 10f64.powi(decimals as i32);
        (x * k).round() / k
    };
    let mut text = format!("G21 G90 G17 {mode}\nG1 F{:.1}\n", feed.max(1.0));
    let mut at = [0.0f64; 6];
    let mut last = [1.0f64, 0.0, 0.0];
    let lo = [-5.0, -5.0, -4.0];
    let hi = [5.0, 5.0, 1.0];
    let inside = |p: &[f64; 6]| (0..3).all(|c| p[c] >= lo[c] && p[c] <= hi[c]) && (3..6).all(|c| p[c].abs() <= 2.0);
    let point = |p: &[f64; 6]| {
        let mut words = format!("X{} Y{}", num(p[0]), num(p[1]));
        if axes.z {
            words.push_str(&format!(" Z{}", num(p[2])));
        }
        if axes.rotations {
            words.push_str(&format!(" A{} B{} C{}", num(p[3]), num(p[4]), num(p[5])));
        }
        words
    };
    for step in steps {
        match step {
            Step::Line { rapid, d, turn } => {
                let mut to = at;
                for c in 0..3 {
                    to[c] = round(at[c] + d[c]);
                    to[c + 3] = round(at[c + 3] + turn[c]);
                }
                if !inside(&to) {
                    for c in 0..3 {
                        to[c] = round(at[c] - d[c]);
                        to[c + 3] = round(at[c + 3] - turn[c]);
                    }
                }
                if !inside(&to) {
                    continue;
                }
                let len = (0..3).map(|c| (to[c] - at[c]).powi(2)).sum::<f64>().sqrt();
                if len > 0.0 {
                    last = std::array::from_fn(|c| (to[c] - at[c]) / len);
                }
                text.push_str(&format!("{} {}\n", if *rapid { "G0" } else { "G1" }, point(&to)));
                at = to;
            }
            Step::Repeat => text.push_str(&format!("G1 {}\n", point(&at))),
            Step::Colinear(k) | Step::Reverse(k) => {
                let sign = if matches!(step, Step::Reverse(_)) { -1.0 } else { 1.0 };
                let mut to = at;
                for c in 0..3 {
                    to[c] = round(at[c] + sign * k * last[c]);
                }
                if !inside(&to) {
                    continue;
                }
                text.push_str(&format!("G1 {}\n", point(&to)));
                at = to;
            }
            Step::Arc {
                clockwise,
                radius,
                toward,
                sweep,
                rise,
                by_radius,
            } => {
                let center = [at[0] + radius * toward.cos(), at[1] + radius * toward.sin()];
                let start = (at[1] - center[1]).atan2(at[0] - center[0]);
                let end = if *clockwise { start - sweep } else { start + sweep };
                let mut to = at;
                to[0] = round(center[0] + radius * end.cos());
                to[1] = round(center[1] + radius * end.sin());
                to[2] = round(at[2] + rise);
                // A full circle back to the start is written by its centre.
                let closed = (to[0] - at[0]).abs() < 1e-9 && (to[1] - at[1]).abs() < 1e-9;
                // The whole arc inside the box: its extreme points are within the radius.
                let arc_inside = inside(&to)
                    && (0..2).all(|c| center[c] - radius >= lo[c] || *radius > 100.0)
                    && (0..2).all(|c| center[c] + radius <= hi[c] || *radius > 100.0);
                if !arc_inside || (to[0] - at[0]).hypot(to[1] - at[1]) < 10f64.powi(-(decimals as i32)) && !closed {
                    continue;
                }
                let code = if *clockwise { "G2" } else { "G3" };
                let mut words = format!("X{} Y{}", num(to[0]), num(to[1]));
                if axes.z && rise.abs() > 0.0 {
                    words.push_str(&format!(" Z{}", num(to[2])));
                }
                if *by_radius && !closed && *sweep < std::f64::consts::PI - 0.01 {
                    text.push_str(&format!("{code} {words} R{}\n", num(*radius)));
                } else if *by_radius && !closed && *sweep > std::f64::consts::PI + 0.01 {
                    text.push_str(&format!("{code} {words} R-{}\n", num(*radius)));
                } else {
                    text.push_str(&format!(
                        "{code} {words} I{} J{}\n",
                        num(center[0] - at[0]),
                        num(center[1] - at[1])
                    ));
                }
                if !axes.z || rise.abs() == 0.0 {
                    to[2] = at[2];
                }
                at = to;
            }
            Step::Cycle { code, d, depth, peck } => {
                let x = round((at[0] + d[0]).clamp(lo[0], hi[0]));
                let y = round((at[1] + d[1]).clamp(lo[1], hi[1]));
                let r = round(at[2].min(0.5));
                let bottom = round((r - depth).max(lo[2]));
                if bottom >= r {
                    continue;
                }
                let extra = match code {
                    82 | 89 => " P0.1".to_string(),
                    83 | 73 => format!(" Q{}", num(*peck)),
                    _ => String::new(),
                };
                text.push_str(&format!(
                    "G99 G{code} X{} Y{} Z{} R{}{extra}\nG80\n",
                    num(x),
                    num(y),
                    num(bottom),
                    num(r)
                ));
                // G99: back to R at the hole.
                at[0] = x;
                at[1] = y;
                at[2] = r;
            }
            Step::Dwell(p) => text.push_str(&format!("G4 P{p:.3}\n")),
            Step::Feed(f) => text.push_str(&format!("F{:.1}\n", f.max(1.0))),
            Step::Mode(m) => text.push_str(&format!("{m}\n")),
        }
    }
    text.push_str("M2\n");
    text
}
