//! SVG plot of the Pareto frontier (mission utility against energy), the energy budget and the
//! chosen plan, drawn with plotters.

use plotters::prelude::*;

pub struct FrontierPlot<'a> {
    pub title: &'a str,
    /// (energy_wh, utility) of every Pareto-optimal plan, in increasing energy.
    pub frontier: &'a [(f64, f64)],
    pub budget_wh: f64,
    /// The chosen plan, if one fits.
    pub chosen: Option<(f64, f64)>,
}

/// Renders the plot to an SVG document.
pub fn frontier_svg(plot: &FrontierPlot) -> Result<String, String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 600)).into_drawing_area();
        draw(&root, plot).map_err(|error| format!("cannot draw the plot: {error}"))?;
        root.present()
            .map_err(|error| format!("cannot draw the plot: {error}"))?;
    }
    Ok(svg)
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
}
