//! `pkm-plc trace path`: the programmed path against the path the tool took, from a trace of a
//! run with a program (the role of LinuxCNC's preview and halscope): the commanded tool point
//! (`NC_X` …, on the programmed path) and the measured one (`NC_TOOL_X` …, the forward
//! kinematics of the measured joints) in the plane of the path's two largest extents, and the
//! contour error against time. The deviation can be magnified: at 0.01 mm it is invisible on a
//! part of 70 mm.

use std::fs::File;
use std::io::Write;
use std::path::Path;

use pkm_api::trajectory::vars;
use plotters::prelude::*;

use super::export::{ExportError, Exported};
use super::read::{ReadAhead, TraceReader};
use crate::image::Value;

/// The points of a run with a program.
#[derive(Default)]
struct Paths {
    /// Commanded and measured tool points (x y z), per fast cycle of the run.
    commanded: Vec<[f64; 3]>,
    measured: Vec<[f64; 3]>,
    /// Contour error against time (s, mm).
    contour: Vec<(f64, f64)>,
    /// The run's largest and RMS contour error, as the executor measured them.
    max: f64,
    rms: f64,
}

/// Draws the programmed against the actual path of `trace` into `out`; the deviation of the
/// actual from the programmed point is drawn `magnify` times as large.
pub fn to_svg(trace: &Path, out: &Path, magnify: f64) -> Result<Exported, ExportError> {
    let err = |e: String| ExportError::Output {
        file: out.display().to_string(),
        message: e,
    };
    let reader = TraceReader::open(trace)?;
    let header = reader.header().clone();
    let Some(program) = header.program.clone() else {
        return Err(ExportError::Nothing {
            trace: trace.display().to_string(),
            why: "recorded without a program: record one with `run --program FILE --trace …`".into(),
        });
    };
    // Opened before the trace is read, so that a path that cannot be written fails at once.
    let mut file = File::create(out).map_err(|e| err(e.to_string()))?;
    let index = |name: &str| reader.variables().iter().position(|(n, _)| n == name);
    let commanded: Vec<Option<usize>> = vars::NC_POSE[..3].iter().map(|v| index(v.name())).collect();
    let measured: Vec<Option<usize>> = vars::NC_TOOL[..3].iter().map(|v| index(v.name())).collect();
    let (state, contour) = (index(vars::NC_STATE.name()), index(vars::NC_CONTOUR_ERROR.name()));
    let (max, rms) = (index(vars::NC_CONTOUR_MAX.name()), index(vars::NC_CONTOUR_RMS.name()));
    let mut values = vec![Value::Real(0.0); reader.variables().len()];
    let mut paths = Paths::default();
    let mut records = 0;
    let mut ahead = ReadAhead::start(reader).map_err(|e| ExportError::Output {
        file: trace.display().to_string(),
        message: format!("cannot start reading: {e}"),
    })?;
    let real = |values: &[Value], i: Option<usize>| match i.and_then(|i| values.get(i)) {
        Some(Value::Real(x)) => *x,
        _ => 0.0,
    };
    while let Some(r) = ahead.next_record()? {
        records += 1;
        let mut changed = false;
        for (i, v) in r.inputs.iter().chain(&r.outputs) {
            values[*i] = *v;
            changed |= commanded.contains(&Some(*i)) || measured.contains(&Some(*i));
        }
        // A program's cycles: running, holding, held or paused.
        let running = matches!(state.and_then(|i| values.get(i)), Some(Value::Int(1..=4)));
        if running && changed {
            paths
                .commanded
                .push(std::array::from_fn(|c| real(&values, commanded[c])));
            paths.measured.push(std::array::from_fn(|c| real(&values, measured[c])));
            paths.contour.push((r.t_us as f64 * 1e-6, real(&values, contour)));
            (paths.max, paths.rms) = (real(&values, max), real(&values, rms));
        }
    }
    if paths.commanded.is_empty() {
        // Nothing to draw: no empty drawing either.
        drop(file);
        let _ = std::fs::remove_file(out);
        return Err(ExportError::Nothing {
            trace: trace.display().to_string(),
            why: format!("the program {} never ran in this trace", program.file),
        });
    }
    let svg = draw(&paths, &program.file, magnify).map_err(err)?;
    file.write_all(svg.as_bytes()).map_err(|e| err(e.to_string()))?;
    Ok(Exported {
        records,
        cut: ahead.cut().cloned(),
    })
}

/// The two coordinates (of x y z) in which the commanded path extends most, in order.
fn plane(points: &[[f64; 3]]) -> [usize; 2] {
    let extent = |c: usize| {
        let (lo, hi) = points.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p[c]), hi.max(p[c]))
        });
        hi - lo
    };
    let mut order = [0, 1, 2];
    order.sort_by(|a, b| extent(*b).total_cmp(&extent(*a)).then(a.cmp(b)));
    let mut two = [order[0], order[1]];
    two.sort_unstable();
    two
}

fn draw(paths: &Paths, file: &str, magnify: f64) -> Result<String, String> {
    const AXES: [&str; 3] = ["x", "y", "z"];
    let [a, b] = plane(&paths.commanded);
    let programmed: Vec<(f64, f64)> = paths.commanded.iter().map(|p| (p[a], p[b])).collect();
    let actual: Vec<(f64, f64)> = paths
        .commanded
        .iter()
        .zip(&paths.measured)
        .map(|(c, m)| (c[a] + magnify * (m[a] - c[a]), c[b] + magnify * (m[b] - c[b])))
        .collect();
    let bounds = programmed.iter().chain(&actual).fold(
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY),
        |(x0, x1, y0, y1), (x, y)| (x0.min(*x), x1.max(*x), y0.min(*y), y1.max(*y)),
    );
    // Equal scales on both axes, with a margin.
    let span = (bounds.1 - bounds.0).max(bounds.3 - bounds.2).max(1e-3) * 1.08;
    let (cx, cy) = ((bounds.0 + bounds.1) / 2.0, (bounds.2 + bounds.3) / 2.0);
    let (max, rms) = (paths.max, paths.rms);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 1140)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let (top, bottom) = root.split_vertically(900);
        let caption = if magnify == 1.0 {
            format!("{file}: programmed (grey) and actual (blue) tool path")
        } else {
            format!("{file}: programmed (grey) and actual (blue) tool path, deviation ×{magnify}")
        };
        let mut chart = ChartBuilder::on(&top)
            .caption(caption, ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(cx - span / 2.0..cx + span / 2.0, cy - span / 2.0..cy + span / 2.0)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(format!("{} [mm, machine frame]", AXES[a]))
            .y_desc(format!("{} [mm]", AXES[b]))
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new(programmed, RGBColor(170, 170, 170).stroke_width(3)))
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new(actual, BLUE.stroke_width(1)))
            .map_err(|e| e.to_string())?;
        let end = paths.contour.last().map_or(1.0, |(t, _)| *t);
        let start = paths.contour.first().map_or(0.0, |(t, _)| *t);
        let mut chart = ChartBuilder::on(&bottom)
            .caption(
                format!("contour error on feed moves: max {max:.4} mm, rms {rms:.4} mm"),
                ("sans-serif", 14),
            )
            .margin(12)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(start..end.max(start + 1e-3), 0.0..(max * 1.1).max(1e-3))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("t [s]")
            .y_desc("mm")
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new(paths.contour.iter().copied(), &BLUE))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(svg)
}
