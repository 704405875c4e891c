//! SVG plot of the Pareto frontier (mission utility against energy), the energy budget and the
//! chosen plan, drawn with plotters.

use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Why a plot could not be drawn or written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("cannot draw the plot: {0}")]
    Draw(#[from] DrawingAreaErrorKind<std::io::Error>),
    #[error("the run recorded no track")]
    NoTrack,
    #[error("cannot write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

type SvgArea<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;

/// Draws one SVG document of `size_px` (width, height).
pub(crate) fn render_svg(
    size_px: (u32, u32),
    draw: impl FnOnce(&SvgArea) -> Result<(), DrawingAreaErrorKind<std::io::Error>>,
) -> Result<String, PlotError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size_px).into_drawing_area();
        draw(&root)?;
        root.present()?;
    }
    Ok(svg)
}

/// Writes a drawn document (or its data) to `path`.
pub fn write_text(path: &Path, text: &str) -> Result<(), PlotError> {
    std::fs::write(path, text).map_err(|source| PlotError::Write {
        path: path.to_path_buf(),
        source,
    })
}

pub struct FrontierPlot<'a> {
    pub title: &'a str,
    /// (energy_wh, utility) of every Pareto-optimal plan, in increasing energy.
    pub frontier: &'a [(f64, f64)],
    pub budget_wh: f64,
    /// The chosen plan, if one fits.
    pub chosen: Option<(f64, f64)>,
}

/// Renders the plot to an SVG document.
pub fn frontier_svg(plot: &FrontierPlot) -> Result<String, PlotError> {
    render_svg((900, 600), |root| draw(root, plot))
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    plot: &FrontierPlot,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let energies = plot.frontier.iter().map(|p| p.0).chain([plot.budget_wh]);
    let (min_wh, max_wh) = energies.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), e| {
        (lo.min(e), hi.max(e))
    });
    let pad_wh = ((max_wh - min_wh) * 0.05).max(0.01);
    let max_utility = plot
        .frontier
        .iter()
        .map(|p| p.1)
        .fold(0.0_f64, f64::max)
        .max(1e-9);
    let mut chart = ChartBuilder::on(root)
        .caption(plot.title, ("sans-serif", 22))
        .margin(20)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(
            (min_wh - pad_wh)..(max_wh + pad_wh),
            0.0..(max_utility * 1.08),
        )?;
    chart
        .configure_mesh()
        .x_desc("mission energy (Wh)")
        .y_desc("weighted QoS utility")
        .draw()?;
    chart
        .draw_series(LineSeries::new(plot.frontier.iter().copied(), &BLUE))?
        .label("Pareto frontier")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
    chart.draw_series(
        plot.frontier
            .iter()
            .map(|&(e, u)| Circle::new((e, u), 3, BLUE.filled())),
    )?;
    chart
        .draw_series(LineSeries::new(
            [(plot.budget_wh, 0.0), (plot.budget_wh, max_utility * 1.08)],
            RED.stroke_width(2),
        ))?
        .label("energy budget")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
    if let Some((e, u)) = plot.chosen {
        chart
            .draw_series([Circle::new((e, u), 7, GREEN.filled())])?
            .label("chosen plan")
            .legend(|(x, y)| Circle::new((x + 10, y), 5, GREEN.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// The simulated mission: vehicle and tractor tracks (north against east) on the left, the
/// battery's state of charge over time on the right.
pub fn mission_svg(outcome: &sitl::outcome::SimOutcome) -> Result<String, PlotError> {
    if outcome.track.is_empty() {
        return Err(PlotError::NoTrack);
    }
    render_svg((1200, 560), |root| draw_mission(root, outcome))
}

fn draw_mission<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    outcome: &sitl::outcome::SimOutcome,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(620);
    let track = &outcome.track;
    let points = track.iter().flat_map(|s| [s.vehicle_ne_m, s.tractor_ne_m]);
    let (mut n_lo, mut n_hi, mut e_lo, mut e_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for [n, e] in points {
        (n_lo, n_hi, e_lo, e_hi) = (n_lo.min(n), n_hi.max(n), e_lo.min(e), e_hi.max(e));
    }
    // Equal scales on both axes so turns look like turns.
    let span = (n_hi - n_lo).max(e_hi - e_lo).max(1.0) * 1.1;
    let (n_mid, e_mid) = ((n_hi + n_lo) / 2.0, (e_hi + e_lo) / 2.0);
    let mut chart = ChartBuilder::on(&left)
        .caption("vehicle and tractor (north up)", ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(
            (e_mid - span / 2.0)..(e_mid + span / 2.0),
            (n_mid - span / 2.0)..(n_mid + span / 2.0),
        )?;
    chart
        .configure_mesh()
        .x_desc("east (m)")
        .y_desc("north (m)")
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            track.iter().map(|s| (s.tractor_ne_m[1], s.tractor_ne_m[0])),
            RGBColor(200, 120, 0).stroke_width(3),
        ))?
        .label("tractor")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RGBColor(200, 120, 0)));
    chart
        .draw_series(LineSeries::new(
            track.iter().map(|s| (s.vehicle_ne_m[1], s.vehicle_ne_m[0])),
            BLUE,
        ))?
        .label("vehicle")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;

    let end_s = track.last().map_or(1.0, |s| s.time_s).max(1.0);
    let soc_lo = track.iter().map(|s| s.battery_soc).fold(1.0, f64::min);
    let mut battery = ChartBuilder::on(&right)
        .caption("battery state of charge", ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..end_s, (soc_lo - 0.05).max(0.0)..1.0)?;
    battery
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("state of charge")
        .draw()?;
    battery.draw_series(LineSeries::new(
        track.iter().map(|s| (s.time_s, s.battery_soc)),
        GREEN.stroke_width(2),
    ))?;
    Ok(())
}

/// The simulated mission's QoS levels and battery over time: the battery's state of charge
/// above, every task's level (0 = its lowest) below, as the governor set them.
pub fn qos_svg(outcome: &sitl::outcome::SimOutcome) -> Result<String, PlotError> {
    if outcome.track.is_empty() || outcome.qos_track.is_empty() {
        return Err(PlotError::NoTrack);
    }
    render_svg((1000, 640), |root| draw_qos(root, outcome))
}

fn draw_qos<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    outcome: &sitl::outcome::SimOutcome,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(260);
    let end_s = outcome.mission_time_s.max(1.0);
    let mut battery = ChartBuilder::on(&top)
        .caption("battery", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(30)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..end_s, 0.0..100.0)?;
    battery
        .configure_mesh()
        .y_desc("state of charge (%)")
        .draw()?;
    battery.draw_series(LineSeries::new(
        outcome
            .track
            .iter()
            .map(|s| (s.time_s, 100.0 * s.battery_soc)),
        RED.stroke_width(2),
    ))?;
    // Every task that ever had a level (a task joins when its first phase is planned).
    let mut tasks: Vec<&str> = Vec::new();
    for (task, _, _) in outcome.qos_track.iter().flat_map(|s| &s.levels) {
        if !tasks.contains(&task.as_str()) {
            tasks.push(task);
        }
    }
    let top_level = outcome
        .qos_track
        .iter()
        .flat_map(|s| s.levels.iter().map(|l| l.1))
        .max()
        .unwrap_or(0);
    let mut levels = ChartBuilder::on(&bottom)
        .caption("QoS level of every task", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..end_s, -0.3..(top_level as f64 + 0.5))?;
    levels
        .configure_mesh()
        .x_desc("mission time (s)")
        .y_desc("level (0 = lowest)")
        .draw()?;
    for (index, task) in tasks.iter().enumerate() {
        // A step line through every change, each task a little apart so equal levels show.
        let offset = 0.06 * index as f64;
        let mut points = Vec::new();
        for (i, sample) in outcome.qos_track.iter().enumerate() {
            let Some(&(_, level, _)) = sample.levels.iter().find(|l| l.0 == *task) else {
                continue;
            };
            let y = level as f64 + offset;
            if i > 0 {
                if let Some(&(_, last_y)) = points.last() {
                    points.push((sample.time_s, last_y));
                }
            }
            points.push((sample.time_s, y));
        }
        if let Some(&(_, last_y)) = points.last() {
            points.push((end_s, last_y));
        }
        let colour = Palette99::pick(index).to_rgba();
        levels
            .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
            .label(*task)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
    }
    levels
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_svg_shows_frontier_budget_and_choice() {
        let frontier = [(50.0, 1.0), (52.0, 3.0), (55.0, 4.0)];
        let svg = frontier_svg(&FrontierPlot {
            title: "test",
            frontier: &frontier,
            budget_wh: 53.0,
            chosen: Some((52.0, 3.0)),
        })
        .unwrap();
        assert!(svg.starts_with("<svg"));
        assert!(svg.contains("Pareto frontier"));
        assert!(svg.contains("energy budget"));
        assert!(svg.contains("chosen plan"));
        // one small circle per frontier point plus the chosen one and its legend marker
        assert!(svg.matches("<circle").count() > frontier.len());
    }

    #[test]
    fn the_mission_svg_draws_both_tracks_and_refuses_an_empty_one() {
        let mut outcome = sitl::outcome::SimOutcome::default();
        assert!(mission_svg(&outcome).is_err());
        outcome.track = (0..10)
            .map(|i| sitl::outcome::TrackSample {
                time_s: i as f64,
                vehicle_ne_m: [i as f64, 0.5],
                altitude_m: 8.0,
                tractor_ne_m: [i as f64, 0.0],
                battery_soc: 1.0 - 0.01 * i as f64,
            })
            .collect();
        let svg = mission_svg(&outcome).unwrap();
        assert!(svg.contains("tractor") && svg.contains("vehicle"));
        assert!(svg.contains("state of charge"));
        assert!(
            svg.matches("<polyline").count() >= 3,
            "two tracks and the battery"
        );
    }

    #[test]
    fn the_qos_svg_draws_every_task_that_had_a_level_and_the_battery() {
        let mut outcome = sitl::outcome::SimOutcome {
            mission_time_s: 10.0,
            ..Default::default()
        };
        outcome.track = (0..10)
            .map(|i| sitl::outcome::TrackSample {
                time_s: i as f64,
                vehicle_ne_m: [0.0, 0.0],
                altitude_m: 8.0,
                tractor_ne_m: [0.0, 0.0],
                battery_soc: 1.0 - 0.02 * i as f64,
            })
            .collect();
        assert!(qos_svg(&outcome).is_err(), "no levels: nothing to plot");
        let sample = |time_s: f64, levels: &[(&str, usize)]| sitl::outcome::QosSample {
            time_s,
            levels: levels
                .iter()
                .map(|&(task, level)| (task.to_string(), level, level as f64))
                .collect(),
        };
        // The detector joins at 2 s (its phase) and steps down at 5 s.
        outcome.qos_track = vec![
            sample(0.0, &[("hazard", 3)]),
            sample(2.0, &[("hazard", 3), ("detection", 3)]),
            sample(5.0, &[("hazard", 3), ("detection", 1)]),
        ];
        let svg = qos_svg(&outcome).unwrap();
        for label in ["hazard", "detection", "state of charge", "QoS level"] {
            assert!(svg.contains(label), "no {label}");
        }
        // The battery and one line per task are drawn 2 px wide (axes and legend marks, 1 px).
        assert_eq!(svg.matches(r#"stroke-width="2""#).count(), 3);
        // The detector's line steps: from (2 s, 3) along to (5 s, 3), down to (5 s, 1).
        let detection = svg
            .split("<polyline")
            .filter(|line| line.contains(r#"stroke-width="2""#))
            .nth(2)
            .expect("the detector's line");
        let points = detection
            .split("points=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap();
        assert_eq!(points.split_whitespace().count(), 4, "{points}");
    }
}
