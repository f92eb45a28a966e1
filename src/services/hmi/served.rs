//! What the screen serves besides the page: a program's text a window of lines at a time, and
//! each published frame as the JSON the page reads.

use serde_json::{Value as Json, json};

use crate::image::Value;
use crate::runtime::frame::Frame;

/// The most lines of a program's text sent in one answer.
pub const TEXT_WINDOW: usize = 400;
/// A line of a program's text is sent cut to this many characters.
pub(super) const MAX_LINE_CHARS: usize = 300;

/// An NC program as the screen shows it.
#[derive(Clone)]
pub struct ScreenProgram {
    /// Its file.
    pub file: String,
    /// Its text.
    pub text: String,
    /// The programmed tool path (x y z of the commanded pose along the program's time line, and
    /// 1 where the way there is a rapid),
    /// for the page's preview.
    pub path: Vec<[f64; 4]>,
    /// Its planned duration (s): the screen shows the time left.
    pub planned_s: f64,
}

/// The programmed path for the screen's preview: at most 4000 points along the time line, each
/// x y z and whether the way to it is a rapid (1) or a feed move (0), so that the page draws the
/// rapids dashed.
pub fn preview(trajectory: &dyn pkm_api::trajectory::Trajectory) -> Vec<[f64; 4]> {
    const POINTS: usize = 4000;
    let duration = trajectory.duration_s();
    let mut cursor = 0;
    let mut points: Vec<[f64; 4]> = Vec::with_capacity(POINTS + 1);
    for i in 0..=POINTS {
        let sample = trajectory.sample(duration * i as f64 / POINTS as f64, &mut cursor);
        let p = sample.pose;
        let point = [p[0], p[1], p[2], if sample.rapid { 1.0 } else { 0.0 }];
        // Where the tool stands (dwells, stops), one point is enough.
        if points.last() != Some(&point) {
            points.push(point);
        }
    }
    points
}

/// A program as the screen serves it: its text with where every [`TEXT_WINDOW`]-th line starts,
/// so that a window costs at most two windows' lines, not the whole text: the last window of a
/// 16 MB text (500 000 lines) took 18–33 ms when the text was counted and skipped through for
/// every request — which a watching client may send 100 times a second — and takes 29 µs.
#[derive(Clone)]
pub(super) struct Served {
    pub(super) program: ScreenProgram,
    /// How many lines the text has.
    pub(super) total: usize,
    /// Byte offsets of lines 1, 1 + [`TEXT_WINDOW`], 1 + 2·[`TEXT_WINDOW`], …
    checkpoints: Vec<usize>,
}

impl Served {
    pub(super) fn new(program: ScreenProgram) -> Served {
        let base = program.text.as_ptr() as usize;
        let mut total = 0;
        let mut checkpoints = Vec::new();
        for (i, line) in program.text.lines().enumerate() {
            if i % TEXT_WINDOW == 0 {
                // `lines` yields slices of the text: the offset is where this one starts.
                checkpoints.push(line.as_ptr() as usize - base);
            }
            total = i + 1;
        }
        Served {
            program,
            total,
            checkpoints,
        }
    }

    /// Lines `from` … (1-based) of the text, at most [`TEXT_WINDOW`], each cut to
    /// [`MAX_LINE_CHARS`] characters; and how many lines the text has.
    pub(super) fn window(&self, from: usize) -> (Vec<String>, usize) {
        let skip = from.max(1) - 1;
        let Some(&start) = self.checkpoints.get(skip / TEXT_WINDOW) else {
            return (Vec::new(), self.total);
        };
        let lines = self.program.text[start..]
            .lines()
            .skip(skip % TEXT_WINDOW)
            .take(TEXT_WINDOW)
            .map(|l| match l.char_indices().nth(MAX_LINE_CHARS) {
                Some((at, _)) => format!("{}…", &l[..at]),
                None => l.to_string(),
            })
            .collect();
        (lines, self.total)
    }
}

/// A frame as the page reads it.
pub(super) fn frame_json(
    f: &Frame,
    links: Option<&[[[f64; 3]; 2]]>,
    message: Option<&Json>,
    trail: &std::collections::VecDeque<[f64; 4]>,
) -> String {
    let s = &f.status;
    let value = |v: &Value| match *v {
        Value::Bool(b) => json!(b),
        Value::Int(i) => json!(i),
        Value::Uint(u) => json!(u),
        Value::Dint(d) => json!(d),
        Value::Real(x) => serde_json::Number::from_f64(x).map_or(Json::Null, Json::Number),
    };
    json!({
        "type": "frame",
        "seq": f.seq,
        "t_s": s.t_ns as f64 * 1e-9,
        "state": s.state,
        "reason": s.reason,
        "note": s.note,
        "values": s.values.iter().map(|(n, v)| json!([n, serde_json::Number::from_f64(*v).map_or(Json::Null, Json::Number)])).collect::<Vec<_>>(),
        "classes": s.classes.iter().map(|c| json!({
            "name": c.name, "cycles": c.cycles, "overruns": c.overruns, "violations": c.violations,
            "late_mean_us": c.lateness_mean_ns / 1e3, "late_max_us": c.lateness_max_ns as f64 / 1e3,
            "exec_mean_us": c.exec_mean_ns / 1e3, "exec_max_us": c.exec_max_ns as f64 / 1e3,
        })).collect::<Vec<_>>(),
        "bus_fault": f.bus_fault,
        "published_unix_us": f.published_unix_us,
        "message": message,
        "trail": trail.iter().map(|p| json!(p)).collect::<Vec<_>>(),
        "links": links.map(|l| l.iter().map(|[a, b]| json!([a, b])).collect::<Vec<_>>()),
        "image": f.image.iter().map(value).collect::<Vec<_>>(),
    })
    .to_string()
}
