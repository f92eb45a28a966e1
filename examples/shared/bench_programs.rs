//! The programs the planner's benchmarks compare on (`time_optimal`, `planner_vs_linuxcnc`):
//! a line, the 40 mm square in each blending mode, circles, a CAM spiral, the O-X target part,
//! slow feeds with G81, and four CAM-like programs of a thousand lines and more.

#[path = "cam_programs.rs"]
mod cam_programs;
#[path = "spiral.rs"]
mod spiral;

fn square(mode: &str) -> String {
    format!("G21 G90 G17 {mode}\nG0 X-20 Y-20\nG1 X20 F1200\nY20\nX-20\nY-20\nG0 X0 Y0\nM2\n")
}

const CIRCLES: &str = "G21 G90 G17 G64 P0.01\nG0 X20 Y0\nG2 I-20 F1200\nG0 X5 Y0\nG2 I-5\nG0 X0 Y0\nM2\n";

/// XY lines at F60 … F1200 and five G81 holes at F100: slow feeds, which once ramped over the
/// profile's grid spacing whatever their speed.
fn slow_feeds() -> String {
    let mut t = String::from("G21 G90 G17 G64 P0.01\nG0 X-20 Y-10\n");
    for (i, f) in [60, 150, 300, 600, 1200].iter().enumerate() {
        let y = -10.0 + 5.0 * i as f64;
        t.push_str(&format!("G1 X20 Y{y} F{f}\nG1 X-20 Y{}\n", y + 2.5));
    }
    t.push_str("G0 Z0\nG99 G81 X-10 Y10 Z-3 R-0.5 F100\nX-5\nX0\nX5\nX10\nG80\nG0 X0 Y0 Z0\nM2\n");
    t
}

/// The programs, by name.
pub fn programs() -> Vec<(&'static str, String)> {
    vec![
        // The set-up checked: 10 mm at F1200 on a slider's limits is 0.2 + 0.3 + 0.2 s.
        ("line 10 mm F1200", "G21 G90 G61 G1 X10 F1200\nM2\n".to_string()),
        ("square G61", square("G61")),
        ("square G64", square("G64")),
        ("square G64 P0.01", square("G64 P0.01")),
        ("circles R20, R5", CIRCLES.to_string()),
        ("CAM spiral, 2000 lines", spiral::program(2000, 1200.0)),
        (
            "ox-x-target.ngc",
            include_str!("../../programs/ox-x-target.ngc").to_string(),
        ),
        ("slow feeds + G81", slow_feeds()),
        ("adaptive clearing", cam_programs::adaptive_clearing()),
        ("3-D raster finish", cam_programs::raster_finish()),
        ("text engraving", cam_programs::text_engraving()),
        ("slow feeds + cycles", cam_programs::slow_feeds_and_cycles()),
    ]
}
