//! SVG drawing of a sampled workspace for `pkm-plc kin MACHINE workspace --svg` (the command
//! line draws; the kinematics crate only samples).

use plotters::prelude::*;

use pkm_kinematics::workspace::Workspace;

/// Draws the reachable samples (coloured by singularity measure) as an SVG document.
pub fn draw(ws: &Workspace, keys: &[&str]) -> Result<String, String> {
    let ia = keys.iter().position(|k| *k == ws.plot_axes[0]).unwrap_or(0);
    let ib = keys.iter().position(|k| *k == ws.plot_axes[1]).unwrap_or(1);
    let range = |i: usize| {
        let (lo, hi) = ws
            .points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.pose[i]), hi.max(p.pose[i]))
            });
        if lo.is_finite() {
            let pad = ((hi - lo) * 0.05).max(1.0);
            (lo - pad)..(hi + pad)
        } else {
            -1.0..1.0
        }
    };
    let (xr, yr) = (range(ia), range(ib));
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (800, 700)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let caption = format!(
            "{} workspace: {} of {} samples reachable (measure >= threshold)",
            ws.machine,
            ws.points.len(),
            ws.samples
        );
        let mut chart = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 18))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(xr, yr)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(format!("{} [mm]", ws.plot_axes[0]))
            .y_desc(format!("{} [mm]", ws.plot_axes[1]))
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
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(out)
}
