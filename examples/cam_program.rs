//! Writes a program as CAM emits it, for the planner's benchmark (README, "NC programs"): a
//! spiral of short G1 segments, 0.05 … 0.5 mm long, blended within 0.01 mm.
//!
//! `cargo run --release --example cam_program -- BLOCKS [FEED_MM_MIN] > cam.ngc`
//! (100 000 blocks by default, at F1200). The spiral runs from a radius of 2 mm out to at most
//! 30 mm in the x–y plane at z = −0.5 mm, so it stays inside the O-X glide's and the hexapod's
//! workspaces.

use std::io::Write;

#[path = "shared/spiral.rs"]
mod spiral;

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
    let text = spiral::program(blocks, feed);
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    if out.write_all(text.as_bytes()).and_then(|_| out.flush()).is_err() {
        std::process::exit(1);
    }
}
