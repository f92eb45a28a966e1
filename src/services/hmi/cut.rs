//! The cut path of the screen's backplot, kept by the server: the measured tool point
//! of every frame while a program runs, so that a page opened (or reloaded) in the middle of a
//! run, or after it, draws what was cut — not only what it saw itself. Bounded: past
//! [`MAX_POINTS`] points every other one is dropped, which keeps the whole path at half the
//! resolution.

use pkm_api::trajectory::vars;
use pkm_drives::nc::RunState;
use serde_json::{Value as Json, json};

use crate::image::Value;

/// The most points kept.
pub const MAX_POINTS: usize = 4000;
/// A point closer than this to the last one kept is not kept (mm).
const MIN_STEP_MM: f64 = 0.005;

/// The executor's states in which the tool cuts (running, holding, held, paused, standing after
/// a line, waiting at an M66).
const CUTTING: [RunState; 6] = [
    RunState::Running,
    RunState::Holding,
    RunState::Held,
    RunState::Paused,
    RunState::BlockDone,
    RunState::Waiting,
];

/// The cut path of the loaded program's current (or last) run.
pub struct CutPath {
    /// Image indices: the measured tool point (x y z; those the machine has), the executor's
    /// state, the loaded program.
    tool: Vec<usize>,
    state: usize,
    program: usize,
    /// The run's program and whether the executor was cutting in the last frame.
    of: i16,
    cutting: bool,
    points: Vec<[f64; 3]>,
}

impl CutPath {
    /// The cut path of a PLC whose image holds `variables` (name, type; in the image's order),
    /// if it runs programs.
    pub fn of(variables: &[(String, String)]) -> Option<CutPath> {
        let index = |name: &str| variables.iter().position(|(n, _)| n == name);
        let tool: Vec<usize> = vars::NC_TOOL[..3].iter().filter_map(|v| index(v.name())).collect();
        Some(CutPath {
            state: index(vars::NC_STATE.name())?,
            program: index(vars::NC_PROGRAM.name())?,
            tool: (!tool.is_empty()).then_some(tool)?,
            of: 0,
            cutting: false,
            points: Vec::with_capacity(MAX_POINTS),
        })
    }

    /// Takes a frame's image: a new run (or another program loaded) starts a new path; while
    /// the tool cuts, its point is added.
    pub fn observe(&mut self, image: &[Value]) {
        let int = |i: usize| match image.get(i) {
            Some(Value::Int(v)) => *v,
            _ => 0,
        };
        let (program, state) = (int(self.program), int(self.state));
        let cutting = RunState::from_code(state).is_some_and(|s| CUTTING.contains(&s));
        if program != self.of || (cutting && !self.cutting) {
            self.points.clear();
            self.of = program;
        }
        self.cutting = cutting;
        if !cutting {
            return;
        }
        let mut p = [0.0; 3];
        for (c, &i) in self.tool.iter().enumerate() {
            p[c] = match image.get(i) {
                Some(Value::Real(x)) if x.is_finite() => *x,
                _ => return,
            };
        }
        let far = self.points.last().is_none_or(|q| {
            let d2: f64 = (0..3).map(|c| (p[c] - q[c]).powi(2)).sum();
            d2 >= MIN_STEP_MM * MIN_STEP_MM
        });
        if far {
            if self.points.len() >= MAX_POINTS {
                let mut k = 0;
                self.points.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
            }
            self.points.push(p);
        }
    }

    /// The path as the page reads it (to the µm: at most about 100 kB).
    pub fn json(&self) -> Json {
        let um = |x: f64| (x * 1000.0).round() / 1000.0;
        let points: Vec<[f64; 3]> = self.points.iter().map(|p| p.map(um)).collect();
        json!({"type": "cut", "program": self.of, "points": points})
    }

    /// The points kept.
    pub fn points(&self) -> &[[f64; 3]] {
        &self.points
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{Declare, VarTable};

    fn table() -> VarTable {
        let mut t = VarTable::new();
        let mut d = Declare::new(&mut t, 0, "p", "p");
        d.write(vars::NC_STATE, 0);
        d.write(vars::NC_PROGRAM, 1);
        for v in &vars::NC_TOOL[..2] {
            d.write(*v, 0.0);
        }
        t
    }

    #[test]
    fn the_path_of_a_run_is_kept_thinned_to_its_bound_and_a_new_run_starts_anew() {
        let t = table();
        let names: Vec<(String, String)> = t.vars().iter().map(|v| (v.name.clone(), v.ty.to_string())).collect();
        let mut cut = CutPath::of(&names).expect("a program's variables");
        let at = |name: &str| usize::from(t.index_of(name).expect("declared"));
        let mut image = t.initial_image();
        let frame = |image: &mut Vec<Value>, state: i16, x: f64| {
            image[at("NC_STATE")] = Value::Int(state);
            image[at("NC_TOOL_X")] = Value::Real(x);
        };
        // Idle: nothing. Running: a point per frame that moved.
        frame(&mut image, 0, 5.0);
        cut.observe(&image);
        assert!(cut.points().is_empty());
        for k in 0..(MAX_POINTS + 10) {
            frame(&mut image, 1, k as f64 * 0.01);
            cut.observe(&image);
            // Standing still adds nothing.
            cut.observe(&image);
        }
        assert!(cut.points().len() <= MAX_POINTS, "{}", cut.points().len());
        assert!(cut.points().len() > MAX_POINTS / 2);
        assert_eq!(cut.points()[0], [0.0, 0.0, 0.0], "the start is kept");
        // Done (kept), then a new start: a new path.
        frame(&mut image, 5, 0.0);
        cut.observe(&image);
        assert!(!cut.points().is_empty());
        frame(&mut image, 1, 1.0);
        cut.observe(&image);
        assert_eq!(cut.points(), [[1.0, 0.0, 0.0]]);
    }
}
