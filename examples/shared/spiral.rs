//! The CAM-like spiral of the planner's benchmarks: short G1 segments, 0.05 … 0.5 mm long,
//! blended within 0.01 mm, from a radius of 2 mm out to at most 30 mm in the x–y plane at
//! z = −0.5 mm (inside the O-X glide's and the hexapod's workspaces).

/// The program of `blocks` segments at `feed_mm_min`.
pub fn program(blocks: usize, feed_mm_min: f64) -> String {
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
        let f = if i == 0 {
            format!(" F{feed_mm_min}")
        } else {
            String::new()
        };
        text.push_str(&format!(
            "G1 X{:.4} Y{:.4}{f}\n",
            radius * angle.cos(),
            radius * angle.sin()
        ));
    }
    text.push_str("G0 Z2\nG0 X0 Y0\nG0 Z0\nM2\n%\n");
    text
}
