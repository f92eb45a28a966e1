//! SVG drawing of a sampled workspace for `pkm-plc kin MACHINE workspace --svg` (the command
//! line draws; the kinematics crate only samples).

use plotters::prelude::*;

use pkm_kinematics::workspace::Workspace;

/// A path to draw over a workspace: poses in the mechanism frame.
pub struct Polyline {
    /// Its points.
    pub points: Vec<Vec<f64>>,
    /// A rapid (drawn thin and grey) or a feed move (black).
    pub rapid: bool,
}

/// Draws the reachable samples (coloured by singularity measure) as an SVG document.
pub fn draw(ws: &Workspace, keys: &[&str]) -> Result<String, String> {
    let ia = keys.iter().position(|k| *k == ws.plot_axes[0]).unwrap_or(0);
    let ib = keys.iter().position(|k| *k == ws.plot_axes[1]).unwrap_or(1);
    draw_with(ws, keys, [ia, ib], None, &[])
}

/// Draws the reachable samples projected onto the pose coordinates `[ia, ib]` and, over them,
/// `paths` (an NC program's tool path), with `caption` instead of the workspace's own.
pub fn draw_with(
    ws: &Workspace,
    keys: &[&str],
    [ia, ib]: [usize; 2],
    caption: Option<&str>,
    paths: &[Polyline],
) -> Result<String, String> {
    // Over the workspace's samples and the paths' points.
    let range = |i: usize| {
        let (lo, hi) = ws
            .points
            .iter()
            .map(|p| p.pose[i])
            .chain(paths.iter().flat_map(|p| p.points.iter().map(move |q| q[i])))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
        if lo.is_finite() {
            let pad = ((hi - lo) * 0.05).max(1.0);
            (lo - pad)..(hi + pad)
        } else {
            -1.0..1.0
        }
    };
    let (mut xr, mut yr) = (range(ia), range(ib));
    if !paths.is_empty() {
        // A tool path at its true shape: one scale on both axes (the plot area is about 1.2
        // times as wide as high).
        let (xs, ys) = (xr.end - xr.start, yr.end - yr.start);
        let aspect = 1.2;
        if xs > ys * aspect {
            let grow = (xs / aspect - ys) / 2.0;
            yr = (yr.start - grow)..(yr.end + grow);
        } else {
            let grow = (ys * aspect - xs) / 2.0;
            xr = (xr.start - grow)..(xr.end + grow);
        }
    }
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (800, 700)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let caption = caption.map(str::to_string).unwrap_or_else(|| {
            format!(
                "{} workspace: {} of {} samples reachable (measure >= threshold)",
                ws.machine,
                ws.points.len(),
                ws.samples
            )
        });
        let mut chart = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 18))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(xr, yr)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(format!("{} [mm]", keys[ia]))
            .y_desc(format!("{} [mm]", keys[ib]))
            .draw()
            .map_err(|e| e.to_string())?;
        let (mlo, mhi) = ws
            .points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.measure), hi.max(p.measure))
            });
        let span = (mhi - mlo).max(1e-12);
        chart
            .draw_series(ws.points.iter().map(|p| {
                // Blue (near the threshold) to red (best conditioned).
                let t = (p.measure - mlo) / span;
                let colour = RGBColor((255.0 * t) as u8, 60, (255.0 * (1.0 - t)) as u8);
                Circle::new((p.pose[ia], p.pose[ib]), 2, colour.filled())
            }))
            .map_err(|e| e.to_string())?;
        for path in paths {
            let style = if path.rapid {
                RGBColor(140, 140, 140).stroke_width(1)
            } else {
                BLACK.stroke_width(2)
            };
            chart
                .draw_series(std::iter::once(PathElement::new(
                    path.points.iter().map(|p| (p[ia], p[ib])).collect::<Vec<_>>(),
                    style,
                )))
                .map_err(|e| e.to_string())?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(out)
}
