//! Trace export: VCD for GTKWave and SVG time plots.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use plotters::prelude::*;

use super::read::{Cut, ReadAhead, TraceError, TraceReader};
use crate::image::{Value, VarType};

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The trace is malformed.
    #[error("{0}")]
    Trace(#[from] TraceError),
    /// The output could not be written.
    #[error("{file}: {message}")]
    Output {
        /// The output file.
        file: String,
        /// What went wrong.
        message: String,
    },
    /// The trace holds nothing of what was asked (no program ran in it, say).
    #[error("{trace}: {why}")]
    Nothing {
        /// The trace.
        trace: String,
        /// What it lacks.
        why: String,
    },
    /// A requested variable is not in the trace.
    #[error("{trace}: no variable \"{name}\" in the trace (it has {known})")]
    UnknownVariable {
        /// The trace.
        trace: String,
        /// The variable asked for.
        name: String,
        /// Some of the variables it has.
        known: String,
    },
}

/// What an export read.
#[derive(Debug, Clone)]
pub struct Exported {
    /// Records read.
    pub records: u64,
    /// Where the trace was cut short, if it was: the export holds every record before that.
    pub cut: Option<Cut>,
}

/// Starts reading a trace's records ahead on a thread of its own.
fn read_ahead(trace: &Path, reader: TraceReader) -> Result<ReadAhead, ExportError> {
    ReadAhead::start(reader).map_err(|e| ExportError::Output {
        file: trace.display().to_string(),
        message: format!("cannot start reading: {e}"),
    })
}

fn bits(v: u64, width: u32) -> Vec<vcd::Value> {
    (0..width)
        .rev()
        .map(|i| {
            if (v >> i) & 1 == 1 {
                vcd::Value::V1
            } else {
                vcd::Value::V0
            }
        })
        .collect()
}

/// Converts a trace to VCD (timescale 1 µs): every variable, plus the main state and reason as
/// strings.
pub fn to_vcd(trace: &Path, out: &Path) -> Result<Exported, ExportError> {
    let output = |e: std::io::Error| ExportError::Output {
        file: out.display().to_string(),
        message: e.to_string(),
    };
    let reader = TraceReader::open(trace)?;
    let header = reader.header().clone();
    let names: Vec<String> = reader.variables().iter().map(|(n, _)| n.clone()).collect();
    let mut w = vcd::Writer::new(BufWriter::new(File::create(out).map_err(output)?));
    w.timescale(1, vcd::TimescaleUnit::US).map_err(output)?;
    w.add_module("pkm_plc").map_err(output)?;
    let mut ids = HashMap::new();
    for (name, ty) in &header.variables {
        let (kind, width) = match ty {
            VarType::Bool => (vcd::VarType::Wire, 1),
            VarType::Int | VarType::Uint => (vcd::VarType::Integer, 16),
            VarType::Dint => (vcd::VarType::Integer, 32),
            VarType::Real => (vcd::VarType::Real, 64),
        };
        ids.insert(name.clone(), w.add_var(kind, width, name, None).map_err(output)?);
    }
    let state_id = w
        .add_var(vcd::VarType::String, 1, "main_state_name", None)
        .map_err(output)?;
    let reason_id = w
        .add_var(vcd::VarType::String, 1, "error_reason_text", None)
        .map_err(output)?;
    w.upscope().map_err(output)?;
    w.enddefinitions().map_err(output)?;
    let mut current: HashMap<usize, Value> = HashMap::new();
    let (mut state, mut reason) = (String::new(), String::new());
    let mut time = None;
    let mut records = 0;
    let mut ahead = read_ahead(trace, reader)?;
    while let Some(r) = ahead.next_record()? {
        records += 1;
        let changes: Vec<&(usize, Value)> = r
            .inputs
            .iter()
            .chain(&r.outputs)
            .filter(|(k, v)| current.get(k).is_none_or(|c| !super::same(*c, *v)))
            .collect();
        let new_state = r.state.as_deref().unwrap_or_default().to_string();
        let new_reason = r.reason.as_deref().unwrap_or_default().to_string();
        if changes.is_empty() && new_state == state && new_reason == reason {
            continue;
        }
        if time != Some(r.t_us) {
            w.timestamp(r.t_us).map_err(output)?;
            time = Some(r.t_us);
        }
        for (k, v) in changes {
            let id = ids[&names[*k]];
            match *v {
                Value::Bool(b) => w.change_scalar(id, b).map_err(output)?,
                Value::Int(i) => w.change_vector(id, bits(u64::from(i as u16), 16)).map_err(output)?,
                Value::Uint(u) => w.change_vector(id, bits(u64::from(u), 16)).map_err(output)?,
                Value::Dint(d) => w.change_vector(id, bits(u64::from(d as u32), 32)).map_err(output)?,
                Value::Real(x) => w.change_real(id, x).map_err(output)?,
            }
            current.insert(*k, *v);
        }
        if new_state != state {
            // VCD strings cannot hold spaces.
            w.change_string(state_id, &new_state.replace(' ', "_"))
                .map_err(output)?;
            state = new_state;
        }
        if new_reason != reason {
            let text = if new_reason.is_empty() {
                "-".to_string()
            } else {
                new_reason.replace(' ', "_")
            };
            w.change_string(reason_id, &text).map_err(output)?;
            reason = new_reason;
        }
    }
    w.flush().map_err(output)?;
    w.writer().flush().map_err(output)?;
    Ok(Exported {
        records,
        cut: ahead.cut().cloned(),
    })
}

/// What `to_svg` plots when it is given no variables: those of these the trace has — every
/// machine's joints and tool pose (the TRIJOINT's two carriages and spindle point too).
const DEFAULT_PLOT: [&str; 12] = [
    "JOINT1_POSITION",
    "JOINT2_POSITION",
    "JOINT3_POSITION",
    "JOINT4_POSITION",
    "JOINT5_POSITION",
    "JOINT6_POSITION",
    "TOOL_X",
    "TOOL_Y",
    "TOOL_Z",
    "TOOL_A",
    "TOOL_B",
    "TOOL_C",
];

/// Plots `vars` (none given: [`DEFAULT_PLOT`]) and the main state against time into an SVG
/// file, one panel each.
///
/// Long, and kept whole: it draws one picture from top to bottom (the panels, their axes and
/// curves, the state's band), and its parts share the plot's scales and the drawing area.
pub fn to_svg(trace: &Path, out: &Path, vars: &[String]) -> Result<Exported, ExportError> {
    let err = |e: String| ExportError::Output {
        file: out.display().to_string(),
        message: e,
    };
    let reader = TraceReader::open(trace)?;
    // Opened before the trace is read, so that a path that cannot be written fails at once.
    let mut file = File::create(out).map_err(|e| err(e.to_string()))?;
    let header = reader.header().clone();
    let defaults: Vec<String>;
    let vars = if vars.is_empty() {
        defaults = DEFAULT_PLOT
            .iter()
            .filter(|n| header.variables.contains_key(**n))
            .map(|n| n.to_string())
            .collect();
        &defaults[..]
    } else {
        vars
    };
    for name in vars {
        if !header.variables.contains_key(name) {
            let known: Vec<&str> = header.variables.keys().take(12).map(String::as_str).collect();
            return Err(ExportError::UnknownVariable {
                trace: trace.display().to_string(),
                name: name.clone(),
                known: format!("{}, …", known.join(", ")),
            });
        }
    }
    let as_f64 = |v: Value| match v {
        Value::Bool(b) => f64::from(u8::from(b)),
        Value::Int(i) => f64::from(i),
        Value::Uint(u) => f64::from(u),
        Value::Dint(d) => f64::from(d),
        Value::Real(x) => x,
    };
    // Per header variable: its panel, if it is plotted.
    let wanted: Vec<Option<usize>> = reader
        .variables()
        .iter()
        .map(|(n, _)| vars.iter().position(|v| v == n))
        .collect();
    // Step series: a point before and after every change.
    let mut series: Vec<Vec<(f64, f64)>> = vec![Vec::new(); vars.len()];
    let mut states: Vec<(f64, String)> = Vec::new();
    let mut end = 0.0f64;
    let mut records = 0;
    let mut ahead = read_ahead(trace, reader)?;
    while let Some(r) = ahead.next_record()? {
        records += 1;
        let t = r.t_us as f64 * 1e-6;
        end = end.max(t);
        for (i, v) in r.inputs.iter().chain(&r.outputs) {
            if let Some(k) = wanted[*i] {
                let y = as_f64(*v);
                let s = &mut series[k];
                if s.last().is_none_or(|&(_, last)| last != y) {
                    if let Some(&(_, last)) = s.last() {
                        s.push((t, last));
                    }
                    s.push((t, y));
                }
            }
        }
        if let Some(state) = &r.state
            && states.last().is_none_or(|(_, s)| **s != **state)
        {
            states.push((t, state.to_string()));
        }
    }
    let names: Vec<String> = {
        let mut n: Vec<String> = Vec::new();
        for (_, s) in &states {
            if !n.contains(s) {
                n.push(s.clone());
            }
        }
        n
    };
    let mut state_series = Vec::new();
    for (t, s) in &states {
        let y = names.iter().position(|n| n == s).unwrap_or(0) as f64;
        if let Some(&(_, last)) = state_series.last() {
            state_series.push((*t, last));
        }
        state_series.push((*t, y));
    }
    let panels = vars.len() + 1;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1000, 170 * panels as u32)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
        let areas = root.split_evenly((panels, 1));
        let mut all: Vec<(String, Vec<(f64, f64)>)> = vars.iter().cloned().zip(series).collect();
        all.push((format!("state ({})", names.join(" / ")), state_series));
        for (area, (name, mut points)) in areas.iter().zip(all) {
            if let Some(&(_, last)) = points.last() {
                points.push((end, last));
            }
            // A REAL may hold NaN or ±inf (null in the trace): no point of the line.
            points.retain(|(_, y)| y.is_finite());
            let (lo, hi) = y_range(&points);
            let mut chart = ChartBuilder::on(area)
                .caption(&name, ("sans-serif", 14))
                .margin(8)
                .x_label_area_size(25)
                .y_label_area_size(60)
                .build_cartesian_2d(0.0..end.max(1e-3), lo..hi)
                .map_err(|e| err(e.to_string()))?;
            chart
                .configure_mesh()
                .x_desc("t [s]")
                .draw()
                .map_err(|e| err(e.to_string()))?;
            chart
                .draw_series(LineSeries::new(points, &BLUE))
                .map_err(|e| err(e.to_string()))?;
        }
        root.present().map_err(|e| err(e.to_string()))?;
    }
    file.write_all(svg.as_bytes()).map_err(|e| err(e.to_string()))?;
    Ok(Exported {
        records,
        cut: ahead.cut().cloned(),
    })
}

/// The y axis of a panel: the values' range with a margin of a tenth (at least 0.5), kept within
/// ±f64::MAX/4 so that its span stays finite (values of ±1e308 would make it infinite, and the
/// axis ticks would never end).
fn y_range(points: &[(f64, f64)]) -> (f64, f64) {
    let (lo, hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(_, y)| {
            (lo.min(y), hi.max(y))
        });
    if lo > hi {
        // No finite value at all.
        return (-0.5, 1.5);
    }
    let limit = f64::MAX / 4.0;
    let (lo, hi) = (lo.clamp(-limit, limit), hi.clamp(-limit, limit));
    let pad = ((hi - lo) * 0.1).max(0.5);
    ((lo - pad).max(-limit), (hi + pad).min(limit))
}
