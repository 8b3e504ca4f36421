//! The sweep's chart (`front.png`, `front.svg`, with `plotters`): frame time against error,
//! log-log. One column of panels per scene, one row per figure (median, p99 per lit pixel,
//! total); every setting a dot, the Pareto front of that panel (the settings no other beats
//! on both time and that figure) joined by a line, peer renderers as labelled crosses.
//!
//! Text is drawn with DejaVu Sans, embedded (`assets/fonts/`, its licence beside it), so the
//! PNG looks the same on a machine without fonts.

use super::{Peer, Row};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// One scene's settings and peers.
pub struct Panel {
    pub scene: String,
    pub rows: Vec<Row>,
    pub peers: Vec<Peer>,
}

pub const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

type Figure = (&'static str, fn(&Row) -> f64, fn(&Peer) -> Option<f64>);

const FIGURES: [Figure; 3] = [
    ("median error per lit pixel", |r| r.err_median, |p| p.median),
    ("p99 error per lit pixel", |r| r.err_p99, |p| p.p99),
    ("total error", |r| r.err_total, |p| p.total),
];

/// The time-error points of the panel that can be drawn on log axes: (ms, error, setting).
fn points(panel: &Panel, fig: &Figure) -> Vec<(f64, f64, String)> {
    panel
        .rows
        .iter()
        .filter(|r| r.failure.is_empty())
        .map(|r| (r.time_ms_median, fig.1(r).max(1e-12), r.setting.clone()))
        .filter(|p| p.0.is_finite() && p.0 > 0.0 && p.1.is_finite())
        .collect()
}

/// The 2-D Pareto front of `pts` (faster and more accurate), sorted by time.
fn front(pts: &[(f64, f64, String)]) -> Vec<(f64, f64)> {
    let mut f: Vec<(f64, f64)> = pts
        .iter()
        .filter(|a| {
            !pts.iter()
                .any(|b| b.0 <= a.0 && b.1 <= a.1 && (b.0 < a.0 || b.1 < a.1))
        })
        .map(|a| (a.0, a.1))
        .collect();
    f.sort_by(|a, b| a.0.total_cmp(&b.0));
    f
}

/// A frame time's tick label [ms]: only the ticks at 1, 2 and 5 times a power of ten are
/// named (a panel spanning less than a decade gets a tick every 10 ms or every 1 ms, and
/// named every one, their labels ran into each other); the others keep their grid line.
fn time_label(ms: f64) -> String {
    if !(ms.is_finite() && ms > 0.0) {
        return String::new();
    }
    let decade = 10f64.powf(ms.log10().floor());
    // In [1, 10), or 10 less a rounding for a tick a hair below a power of ten.
    let leading = ms / decade;
    if ![1.0, 2.0, 5.0, 10.0]
        .iter()
        .any(|m| (leading - m).abs() < 1e-6 * m)
    {
        return String::new();
    }
    if ms >= 10.0 {
        format!("{ms:.0}")
    } else if ms >= 1.0 {
        format!("{ms:.1}")
    } else {
        format!("{ms:.2}")
    }
}

fn panel_on<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    fig: &Figure,
) -> Result<(), String> {
    let pts = points(panel, fig);
    let peers: Vec<(f64, f64, &str)> = panel
        .peers
        .iter()
        .filter_map(|p| fig.2(p).map(|e| (p.time_s * 1e3, e.max(1e-12), p.name.as_str())))
        .collect();
    let xs = pts.iter().map(|p| p.0).chain(peers.iter().map(|p| p.0));
    let ys = pts.iter().map(|p| p.1).chain(peers.iter().map(|p| p.1));
    let (x0, x1) = xs.fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x), b.max(x)));
    let (y0, y1) = ys.fold((f64::MAX, f64::MIN), |(a, b), y| (a.min(y), b.max(y)));
    if x0 > x1 {
        return Ok(());
    }
    let mut chart = ChartBuilder::on(area)
        .caption(
            format!("{}: {}", panel.scene, fig.0),
            ("sans-serif", 15).into_font(),
        )
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(64)
        .build_cartesian_2d(
            (x0 / 2.0..x1 * 2.0).log_scale(),
            (y0 / 3.0..y1 * 3.0).log_scale(),
        )
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("frame time [ms]")
        .y_desc(fig.0)
        .y_label_formatter(&|y| format!("{y:.0e}"))
        .x_label_formatter(&|x| time_label(*x))
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(|e| e.to_string())?;
    chart
        .draw_series(
            pts.iter()
                .map(|p| Circle::new((p.0, p.1), 3, BLUE.mix(0.6).filled())),
        )
        .map_err(|e| e.to_string())?
        .label("optistim settings")
        .legend(|(x, y)| Circle::new((x, y), 3, BLUE.filled()));
    let f = front(&pts);
    chart
        .draw_series(LineSeries::new(f.clone(), RED.stroke_width(2)))
        .map_err(|e| e.to_string())?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], RED.stroke_width(2)));
    chart
        .draw_series(f.iter().map(|p| Circle::new(*p, 4, RED.filled())))
        .map_err(|e| e.to_string())?;
    // The front's settings by name.
    for p in pts.iter().filter(|p| f.contains(&(p.0, p.1))) {
        chart
            .draw_series(std::iter::once(Text::new(
                p.2.clone(),
                (p.0, p.1),
                ("sans-serif", 11).into_font(),
            )))
            .map_err(|e| e.to_string())?;
    }
    for (x, y, name) in &peers {
        chart
            .draw_series(std::iter::once(Cross::new(
                (*x, *y),
                6,
                BLACK.stroke_width(2),
            )))
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(std::iter::once(Text::new(
                name.to_string(),
                (*x, *y),
                ("sans-serif", 11).into_font().color(&BLACK),
            )))
            .map_err(|e| e.to_string())?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 11))
        .draw()
        .map_err(|e| e.to_string())
}

fn draw_on<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    panels: &[Panel],
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let areas = root.split_evenly((FIGURES.len(), panels.len().max(1)));
    for (row, fig) in FIGURES.iter().enumerate() {
        for (col, panel) in panels.iter().enumerate() {
            panel_on(&areas[row * panels.len() + col], panel, fig)?;
        }
    }
    root.present().map_err(|e| e.to_string())
}

/// Draws `panels` into `png` and `svg`.
pub fn draw(panels: &[Panel], png: &Path, svg: &Path) -> Result<(), String> {
    // Registering twice (a second sweep in one process) is harmless.
    let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    let size = (520 * panels.len().max(1) as u32, 1260);
    draw_on(BitMapBackend::new(png, size).into_drawing_area(), panels)?;
    draw_on(SVGBackend::new(svg, size).into_drawing_area(), panels)
}

#[cfg(test)]
mod tests {
    use super::time_label;

    #[test]
    fn only_one_two_and_five_times_a_power_of_ten_are_named() {
        let named: Vec<String> = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 100.0, 200.0, 500.0]
            .iter()
            .map(|&x| time_label(x))
            .collect();
        assert_eq!(named, ["10", "20", "", "", "50", "", "100", "200", "500"]);
        assert_eq!(time_label(2.0), "2.0");
        assert_eq!(time_label(3.0), "");
        assert_eq!(time_label(0.5), "0.50");
        assert_eq!(time_label(1e4), "10000");
        assert_eq!(time_label(f64::NAN), "");
        assert_eq!(time_label(0.0), "");
    }
}
