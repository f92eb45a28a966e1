//! Writes a program as CAM emits it, for the planner's benchmark (README, "NC programs"): a
//! spiral of short G1 segments, 0.05 … 0.5 mm long, blended within 0.01 mm.
//!
//! `cargo run --release --example cam_program -- BLOCKS [FEED_MM_MIN] > cam.ngc`
//! (100 000 blocks by default, at F1200). The spiral runs from a radius of 2 mm out to at most
//! 30 mm in the x–y plane at z = −0.5 mm, so it stays inside the O-X glide's and the hexapod's
//! workspaces.

use std::io::Write;

fn main() {
    let mut args = std::env::args().skip(1);
    let parse = |a: Option<String>, default: f64, what: &str| match a {
        None => default,
        Some(s) => s.parse().unwrap_or_else(|_| {
            eprintln!("cam_program: {what} must be a number, got {s}");
            std::process::exit(2)
        }),
    };
    let blocks = parse(args.next(), 100_000.0, "BLOCKS") as usize;
    let feed = parse(args.next(), 1200.0, "FEED_MM_MIN");
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut text = format!(
        "%\n(CAM-like spiral: {blocks} segments of 0.05 to 0.5 mm)\nG21 G90 G17 G64 P0.01\nG0 X2 Y0\nG0 Z-0.5\n"
    );
    // The radius grows by `pitch` per turn, so that `blocks` segments of 0.275 mm on average
    // end at most at 30 mm: length ≈ π (r1² − r0²) / pitch.
    let length = blocks as f64 * 0.275;
    let pitch = (std::f64::consts::PI * (30.0f64.powi(2) - 2.0f64.powi(2)) / length).max(1e-3);
    let (mut angle, mut radius) = (0.0f64, 2.0f64);
    // A deterministic spread of segment lengths (a linear congruential sequence).
    let mut seed: u32 = 12345;
    for i in 0..blocks {
        seed = seed.wrapping_mul(1_103_515_245).wrapping_add(12345);
        let chord = 0.05 + 0.45 * f64::from(seed >> 16) / 65_535.0;
        angle += chord / radius;
        radius = 2.0 + pitch * angle / std::f64::consts::TAU;
        let f = if i == 0 { format!(" F{feed}") } else { String::new() };
        text.push_str(&format!(
            "G1 X{:.4} Y{:.4}{f}\n",
            radius * angle.cos(),
            radius * angle.sin()
        ));
    }
    text.push_str("G0 Z2\nG0 X0 Y0\nG0 Z0\nM2\n%\n");
    if out.write_all(text.as_bytes()).and_then(|_| out.flush()).is_err() {
        std::process::exit(1);
    }
}
