//! `qosrt ptu-stereo tables --svg-dir`: the error fields of seed 001's Figures 8–10, as SVG
//! heat maps and CSV.

use super::*;

/// Why the figures could not be written.
#[derive(Debug, thiserror::Error)]
pub(super) enum FigureError {
    #[error("cannot create {}: {source}", dir.display())]
    CreateDir {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("figure {figure}: {source}")]
    Field {
        figure: u8,
        #[source]
        source: TriangulationError,
    },
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// Writes `fig8.svg`, `fig8.csv`, … into `dir`.
pub(super) fn write_figures(dir: &Path, glide_deg: f64) -> Result<Vec<PathBuf>, FigureError> {
    std::fs::create_dir_all(dir).map_err(|source| FigureError::CreateDir {
        dir: dir.to_path_buf(),
        source,
    })?;
    let mut written = Vec::new();
    for mut spec in seed_figures() {
        spec.glide_angle_rad = glide_deg.to_radians();
        let field = error_field(&spec).map_err(|source| FigureError::Field {
            figure: spec.figure,
            source,
        })?;
        let svg_path = dir.join(format!("fig{}.svg", spec.figure));
        write_text(&svg_path, &field_svg(&field)?)?;
        written.push(svg_path);
        let csv_path = dir.join(format!("fig{}.csv", spec.figure));
        write_text(&csv_path, &field_csv(&field))?;
        written.push(csv_path);
    }
    Ok(written)
}

fn field_csv(field: &ErrorField) -> String {
    let mut out = String::from(
        "lateral_m,distance_m,height_m,disturbance_x_m,disturbance_y_m,disturbance_z_m,std_x_m,std_y_m,std_z_m\n",
    );
    for c in &field.cells {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{}",
            c.lateral_m,
            c.distance_m,
            c.height_m,
            c.disturbance_error_m[0],
            c.disturbance_error_m[1],
            c.disturbance_error_m[2],
            c.std_m[0],
            c.std_m[1],
            c.std_m[2]
        );
    }
    out
}

/// A perceptual-ish blue → green → yellow ramp for t in [0, 1].
pub(super) fn ramp(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [68.0, 1.0, 84.0]),
        (0.25, [59.0, 82.0, 139.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (0.75, [94.0, 201.0, 98.0]),
        (1.0, [253.0, 231.0, 37.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    let i = STOPS
        .iter()
        .rposition(|s| s.0 <= t)
        .unwrap_or(0)
        .min(STOPS.len() - 2);
    let (t0, c0) = STOPS[i];
    let (t1, c1) = STOPS[i + 1];
    let f = (t - t0) / (t1 - t0);
    let mix = |k: usize| (c0[k] + (c1[k] - c0[k]) * f).round() as u8;
    RGBColor(mix(0), mix(1), mix(2))
}

/// Six heat maps of |error| (log colour scale, per panel): the 1 mrad disturbance of the
/// tables' model and the 1σ of N(0, 1 mrad), on X, Y and Z.
fn field_svg(field: &ErrorField) -> Result<String, PlotError> {
    render_svg((1500, 1000), |root| draw_field(root, field))
}

fn draw_field<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    field: &ErrorField,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let spec = &field.spec;
    let title = format!(
        "Figure {}: D = {} m, f = 100 mm, 1 mrad, glide {:.0} deg: |error| (m), log colour scale per panel",
        spec.figure,
        spec.baseline_m,
        spec.glide_angle_rad.to_degrees()
    );
    let root = root.titled(&title, ("sans-serif", 22))?;
    let panels = root.split_evenly((2, 3));
    let half_x = step(&field.lateral_m) / 2.0;
    let half_y = step(&field.distance_m) / 2.0;
    let (x_lo, x_hi) = (
        field.lateral_m[0] - half_x,
        field.lateral_m[field.lateral_m.len() - 1] + half_x,
    );
    let (y_lo, y_hi) = (
        field.distance_m[0] - half_y,
        field.distance_m[field.distance_m.len() - 1] + half_y,
    );
    for (index, panel) in panels.iter().enumerate() {
        let (row, axis) = (index / 3, index % 3);
        let value = |c: &algorithms::stereo::error_analysis::FieldCell| {
            if row == 0 {
                c.disturbance_error_m[axis].abs()
            } else {
                c.std_m[axis]
            }
        };
        let logs: Vec<f64> = field
            .cells
            .iter()
            .map(|c| value(c).max(1e-6).log10())
            .collect();
        let lo = logs.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let caption = format!(
            "{} {}: {:.3} to {:.1} m",
            AXES[axis],
            if row == 0 {
                "1 mrad disturbance"
            } else {
                "1 sigma"
            },
            10f64.powf(lo),
            10f64.powf(hi)
        );
        let mut chart = ChartBuilder::on(panel)
            .caption(caption, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("lateral (m)")
            .y_desc("distance (m)")
            .draw()?;
        chart.draw_series(field.cells.iter().zip(&logs).map(|(c, &l)| {
            let t = if hi > lo { (l - lo) / (hi - lo) } else { 0.5 };
            Rectangle::new(
                [
                    (c.lateral_m - half_x, c.distance_m - half_y),
                    (c.lateral_m + half_x, c.distance_m + half_y),
                ],
                ramp(t).filled(),
            )
        }))?;
    }
    Ok(())
}

fn step(values: &[f64]) -> f64 {
    if values.len() < 2 {
        1.0
    } else {
        values[1] - values[0]
    }
}
