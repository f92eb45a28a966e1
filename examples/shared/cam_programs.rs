//! CAM-like programs of a few thousand lines for the planner's benchmarks, written as CAM
//! post-processors write them (G64 P0.01, three decimals, short G1 chords, plunges and retracts
//! at their own feeds), inside a 40 mm × 30 mm field around the machine's home that the O-X
//! glide and the hexapod both reach.

use std::fmt::Write;

/// Three decimals, as CAM output.
fn p(x: f64) -> String {
    format!("{x:.3}")
}

/// Adaptive clearing: trochoidal loops of radius 2.5 mm, each advancing 0.6 mm, along four
/// slots of 30 mm at F1500, as 0.3–0.5 mm chords; between slots a retract and a rapid.
pub fn adaptive_clearing() -> String {
    let mut t = String::from("G21 G90 G17 G64 P0.01\nG0 Z2\n");
    let (r, step, chords) = (2.5, 0.6, 36);
    for slot in 0..4 {
        let y0 = -12.0 + 8.0 * f64::from(slot);
        let _ = writeln!(t, "G0 X-15 Y{}\nG1 Z-1 F300\nF1500", p(y0));
        let loops = (30.0 / step) as usize;
        for k in 0..loops {
            let cx = -15.0 + r + step * k as f64;
            for c in 0..chords {
                let a = std::f64::consts::TAU * f64::from(c) / f64::from(chords) + std::f64::consts::PI;
                let _ = writeln!(
                    t,
                    "G1 X{} Y{}",
                    p(cx + r * a.cos() + step * f64::from(c) / f64::from(chords)),
                    p(y0 + r * a.sin())
                );
            }
        }
        t.push_str("G0 Z2\n");
    }
    t.push_str("G0 X0 Y0 Z0\nM2\n");
    t
}

/// A 3-D raster finish: lines along X of 0.4 mm chords over a dome (z from 0 to −3 mm), 0.8 mm
/// apart in Y, zig-zag, at F1800.
pub fn raster_finish() -> String {
    let mut t = String::from("G21 G90 G17 G64 P0.01\nG0 Z2\nG0 X-20 Y-12\nG1 Z0 F300\nF1800\n");
    let z = |x: f64, y: f64| -3.0 + 3.0 * ((x / 20.0).powi(2) + (y / 15.0).powi(2)).min(1.0);
    let columns = 100;
    for row in 0..31 {
        let y = -12.0 + 0.8 * f64::from(row);
        for c in 0..=columns {
            let k = if row % 2 == 0 { c } else { columns - c };
            let x = -20.0 + 0.4 * f64::from(k);
            let _ = writeln!(t, "G1 X{} Y{} Z{}", p(x), p(y), p(z(x, y)));
        }
    }
    t.push_str("G0 Z2\nG0 X0 Y0 Z0\nM2\n");
    t
}

/// The strokes of a few capital letters in a 4 mm × 6 mm cell: polylines, and arcs (centre,
/// radius, from and to angle in degrees, counter-clockwise) for the round ones.
enum Stroke {
    Lines(&'static [(f64, f64)]),
    Arc((f64, f64), f64, f64, f64),
}

fn glyph(c: char) -> &'static [Stroke] {
    use Stroke::{Arc, Lines};
    match c {
        'P' => &[
            Lines(&[(0.0, 0.0), (0.0, 6.0), (2.5, 6.0)]),
            Arc((2.5, 4.5), 1.5, 90.0, 270.0),
            Lines(&[(2.5, 3.0), (0.0, 3.0)]),
        ],
        'K' => &[
            Lines(&[(0.0, 0.0), (0.0, 6.0)]),
            Lines(&[(4.0, 6.0), (0.0, 2.5), (4.0, 0.0)]),
        ],
        'M' => &[Lines(&[(0.0, 0.0), (0.0, 6.0), (2.0, 3.0), (4.0, 6.0), (4.0, 0.0)])],
        'L' => &[Lines(&[(0.0, 6.0), (0.0, 0.0), (4.0, 0.0)])],
        'C' => &[Arc((2.5, 3.0), 2.5, 45.0, 315.0)],
        'O' => &[Arc((2.0, 3.0), 2.0, 0.0, 360.0)],
        'X' => &[Lines(&[(0.0, 0.0), (4.0, 6.0)]), Lines(&[(0.0, 6.0), (4.0, 0.0)])],
        'H' => &[
            Lines(&[(0.0, 0.0), (0.0, 6.0)]),
            Lines(&[(4.0, 0.0), (4.0, 6.0)]),
            Lines(&[(0.0, 3.0), (4.0, 3.0)]),
        ],
        _ => &[],
    }
}

/// Text engraving: "PKM PLC OX H" in rows of letters, each stroke plunged to 0.2 mm at F200,
/// engraved at F600 (arcs as G2/G3), lifted and moved by rapids.
pub fn text_engraving() -> String {
    let mut t = String::from("G21 G90 G17 G64 P0.01\nG0 Z1\n");
    let text = "PKM PLC OX H";
    for row in 0..4 {
        for (k, c) in text.chars().cycle().take(36).enumerate() {
            let (ox, oy) = (
                -20.0 + 5.5 * (k % 7) as f64,
                -14.0 + 7.5 * f64::from(row) + 0.01 * (k / 7) as f64,
            );
            for stroke in glyph(c) {
                let start = match stroke {
                    Stroke::Lines(points) => points[0],
                    Stroke::Arc((cx, cy), r, from, _) => {
                        (cx + r * from.to_radians().cos(), cy + r * from.to_radians().sin())
                    }
                };
                let _ = writeln!(t, "G0 X{} Y{}\nG1 Z-0.2 F200", p(ox + start.0), p(oy + start.1));
                match stroke {
                    Stroke::Lines(points) => {
                        for (x, y) in &points[1..] {
                            let _ = writeln!(t, "G1 X{} Y{} F600", p(ox + x), p(oy + y));
                        }
                    }
                    Stroke::Arc((cx, cy), r, from, to) => {
                        // In quarter turns at most, so that the end is written to three decimals.
                        let pieces = ((to - from) / 90.0).ceil().max(1.0) as usize;
                        let mut a0 = *from;
                        for i in 1..=pieces {
                            let a1 = from + (to - from) * i as f64 / pieces as f64;
                            let (sx, sy) = (cx + r * a0.to_radians().cos(), cy + r * a0.to_radians().sin());
                            let (ex, ey) = (cx + r * a1.to_radians().cos(), cy + r * a1.to_radians().sin());
                            let _ = writeln!(
                                t,
                                "G3 X{} Y{} I{} J{} F600",
                                p(ox + ex),
                                p(oy + ey),
                                p(cx - sx),
                                p(cy - sy)
                            );
                            a0 = a1;
                        }
                    }
                }
                t.push_str("G0 Z1\n");
            }
        }
    }
    t.push_str("G0 X0 Y0 Z0\nM2\n");
    t
}

/// Slow feeds with canned cycles: eight rows of ten holes, drilled at F100 (G81), pecked at F60
/// (G83, Q0.5) or spot-faced with a dwell at F150 (G82), and each hole's chamfer circle of
/// radius 1.2 mm in 36 chords at F150, plunged at F60.
pub fn slow_feeds_and_cycles() -> String {
    let mut t = String::from("G21 G90 G17 G64 P0.01\nG0 Z2\n");
    for row in 0..8 {
        let y = -12.25 + 3.5 * f64::from(row);
        let cycle = match row % 3 {
            0 => "G99 G81 R0.5 Z-2 F100",
            1 => "G99 G83 R0.5 Z-3 Q0.5 F60",
            _ => "G99 G82 R0.5 Z-1 P0.2 F150",
        };
        let x = |k: u32| -17.1 + 3.8 * f64::from(k);
        let _ = writeln!(t, "G0 X{} Y{}\n{cycle} X{} Y{}", p(x(0)), p(y), p(x(0)), p(y));
        for k in 1..10 {
            let _ = writeln!(t, "X{}", p(x(k)));
        }
        t.push_str("G80\nG0 Z2\n");
        for k in 0..10 {
            let (cx, r) = (x(k), 1.2);
            let _ = writeln!(t, "G0 X{} Y{}\nG1 Z-0.3 F60\nF150", p(cx + r), p(y));
            for c in 1..=36 {
                let a = std::f64::consts::TAU * f64::from(c) / 36.0;
                let _ = writeln!(t, "G1 X{} Y{}", p(cx + r * a.cos()), p(y + r * a.sin()));
            }
            t.push_str("G0 Z2\n");
        }
    }
    t.push_str("G0 X0 Y0 Z0\nM2\n");
    t
}
