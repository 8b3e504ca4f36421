//! `optistim exposure TRAJ --scene S --out DIR`: exposure planning along a trajectory
//! (Sec. 6.3.2, Eqs. 61-62, Figs. 40-41).
//!
//! Each frame is rendered once; from its noise-free signal `S` [e-/s] every active pixel
//! (`S > 0`) has a time before saturation `dt_sat = FWC / S` (Eq. 61) and a time before
//! noise `dt_noise = (FWC / 10^(DNR/20)) / S` (Eq. 62), `DNR` the detector's dynamic range
//! [dB] (`20 log10(FWC / readout sigma)` unless given). At an exposure `t` a pixel is lost
//! to saturation when `S t > FWC` and to noise when `S t < FWC / 10^(DNR/20)`. The optimal
//! bracket for `X` (the paper's X %) is the range of `t` that keeps at least `X` of the
//! active pixels above the noise threshold and at most `1 - X` of them saturated:
//! `[t_lo, t_hi]` with `t_lo` the `X`-quantile of `dt_noise` (its empirical CDF, the paper's
//! "CCDF of the time before noise") and `t_hi` the `(1 - X)`-quantile of `dt_sat`; empty when
//! `t_lo > t_hi`. Over the trajectory the bracket is the intersection of the frames'.
//!
//! Writes `frames.csv` (per frame: the bracket, the loss at the scene's exposure), `loss.csv`
//! (per frame and exposure on a log grid: saturated and under-noise fractions) and the chart
//! `exposure.png` / `exposure.svg` (Fig. 41: the loss over exposure and time with the
//! bracket's edges; the whole trajectory's loss against exposure).

use super::AppError;
use super::products;
use crate::config::Config;
use crate::render::Renderer;
use crate::scene::Pose;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;
use std::path::Path;

/// What to plan for.
#[derive(Clone, Copy, Debug)]
pub struct ExposurePlan {
    /// The fraction `X` (0.5..1) of active pixels to keep above noise and below saturation.
    pub keep: f64,
    /// The dynamic range [dB]; `None`: `20 log10(FWC / readout sigma)` of the scene's detector.
    pub dnr_db: Option<f64>,
    /// Render threads (0: all).
    pub threads: usize,
}

/// Fractions of a frame's active pixels lost at one exposure.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Loss {
    /// `S t > FWC`.
    pub saturated: f64,
    /// `S t < FWC / 10^(DNR/20)`.
    pub under_noise: f64,
}

impl Loss {
    pub fn total(&self) -> f64 {
        self.saturated + self.under_noise
    }
}

/// One frame's exposure figures.
#[derive(Clone, Debug, Serialize)]
pub struct FrameExposure {
    pub index: u64,
    pub t_s: f64,
    pub phase_deg: f64,
    pub range_m: f64,
    /// Pixels with signal (`S > 0`).
    pub active_px: usize,
    /// The bracket's ends [s] (`t_lo`: at least `X` above noise from here; `t_hi`: at most
    /// `1 - X` saturated up to here). NaN without active pixels.
    pub t_lo_s: f64,
    pub t_hi_s: f64,
    /// Whether `t_lo <= t_hi`.
    pub bracketed: bool,
    /// The loss at the scene's own exposure.
    pub at_scene_exposure: Loss,
}

/// The whole plan.
#[derive(Clone, Debug, Serialize)]
pub struct ExposureReport {
    pub keep: f64,
    pub dnr_db: f64,
    pub full_well_e: f64,
    /// `FWC / 10^(DNR/20)` [e-].
    pub noise_floor_e: f64,
    pub scene_exposure_s: f64,
    pub frames: Vec<FrameExposure>,
    /// The intersection of the frames' brackets [s]: `(max t_lo, min t_hi)`; `None` when no
    /// single exposure serves every frame.
    pub bracket_s: Option<(f64, f64)>,
    /// The exposure grid of `loss` [s] (log-spaced).
    #[serde(skip)]
    pub exposures_s: Vec<f64>,
    /// Per frame, the loss at each exposure of the grid.
    #[serde(skip)]
    pub loss: Vec<Vec<Loss>>,
    /// Over every active pixel of every frame, the loss at each exposure of the grid.
    #[serde(skip)]
    pub pooled: Vec<Loss>,
}

/// The exposure grid: 1e-10 to 100 s, 24 points per decade.
pub fn exposure_grid() -> Vec<f64> {
    (0..=12 * 24)
        .map(|i| 10f64.powf(-10.0 + i as f64 / 24.0))
        .collect()
}

/// The dynamic range of the scene's detector [dB] (Eq. 62's DNR), or `given`.
pub fn dynamic_range_db(config: &Config, given: Option<f64>) -> Result<f64, AppError> {
    let det = &config.scene.camera.detector;
    if let Some(d) = given {
        if d.is_finite() && d > 0.0 {
            return Ok(d);
        }
        return Err(AppError::Exposure(format!(
            "--dnr-db {d}: a dynamic range is a positive number of dB"
        )));
    }
    match &det.noise.readout {
        Some(r) if r.sigma_e > 0.0 => Ok(20.0 * (det.full_well_e / r.sigma_e).log10()),
        _ => Err(AppError::Exposure(
            "the detector has no readout noise to set its dynamic range: give --dnr-db".into(),
        )),
    }
}

/// The active pixels' signals of a frame, ascending.
pub fn active_signals(signal_e_per_s: &[f64]) -> Vec<f64> {
    let mut s: Vec<f64> = signal_e_per_s
        .iter()
        .copied()
        .filter(|&x| x > 0.0)
        .collect();
    s.sort_by(f64::total_cmp);
    s
}

/// The loss at exposure `t` of the ascending active signals `s`.
pub fn loss_at(s: &[f64], t: f64, full_well_e: f64, noise_floor_e: f64) -> Loss {
    if s.is_empty() {
        return Loss::default();
    }
    let n = s.len() as f64;
    let not_saturated = s.partition_point(|&v| v * t <= full_well_e);
    let under_noise = s.partition_point(|&v| v * t < noise_floor_e);
    Loss {
        saturated: (s.len() - not_saturated) as f64 / n,
        under_noise: under_noise as f64 / n,
    }
}

/// The bracket `(t_lo, t_hi)` of the ascending active signals `s` for `keep` (Eqs. 61-62).
pub fn bracket(s: &[f64], keep: f64, full_well_e: f64, noise_floor_e: f64) -> (f64, f64) {
    let n = s.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    // At most k = floor((1 - X) n) saturated: t_hi is the (k+1)-th smallest dt_sat = FWC / S,
    // that is FWC over the (k+1)-th largest signal.
    let k = ((1.0 - keep) * n as f64 + 1e-9).floor() as usize;
    // The quotients are rounded: step them by ulps until the pixel that sets each end sits on
    // the right side of its threshold in the products the counts use (`S t`).
    let t_hi = if k >= n {
        f64::INFINITY
    } else {
        let mut t = full_well_e / s[n - 1 - k];
        while s[n - 1 - k] * t > full_well_e {
            t = f64::from_bits(t.to_bits() - 1);
        }
        t
    };
    // At least m = ceil(X n) above noise: t_lo is the m-th smallest dt_noise.
    let m = ((keep * n as f64) - 1e-9).ceil().max(0.0) as usize;
    let t_lo = if m == 0 {
        0.0
    } else {
        let mut t = noise_floor_e / s[n - m];
        while s[n - m] * t < noise_floor_e {
            t = f64::from_bits(t.to_bits() + 1);
        }
        t
    };
    (t_lo, t_hi)
}

/// Plans the exposure over `poses` (time [s] and pose).
pub fn run(
    config: &Config,
    poses: &[(f64, Pose)],
    plan: ExposurePlan,
    on_frame: &mut dyn FnMut(usize, usize),
) -> Result<ExposureReport, AppError> {
    if !(plan.keep > 0.5 && plan.keep < 1.0) {
        return Err(AppError::Exposure(format!(
            "--keep {}: a fraction between 0.5 and 1 (0.95 keeps 95 % of the active pixels)",
            plan.keep
        )));
    }
    let dnr_db = dynamic_range_db(config, plan.dnr_db)?;
    let det = &config.scene.camera.detector;
    let fwc = det.full_well_e;
    let floor = fwc / 10f64.powf(dnr_db / 20.0);
    let grid = exposure_grid();
    let mut renderer = Renderer::new(plan.threads)?;
    let planner = config.planner();
    let k_signal = config.scene.signal_factor();
    let mut frames = Vec::with_capacity(poses.len());
    let mut loss = Vec::with_capacity(poses.len());
    let mut pooled_counts = vec![(0.0, 0.0); grid.len()];
    let mut pooled_n = 0.0;
    for (i, (t_s, pose)) in poses.iter().enumerate() {
        let (frame, _, _) = products::render_frame(config, planner.as_ref(), pose, &mut renderer)?;
        let s = active_signals(&det.signal(&frame.pl, k_signal));
        let (t_lo, t_hi) = bracket(&s, plan.keep, fwc, floor);
        let row: Vec<Loss> = grid.iter().map(|&t| loss_at(&s, t, fwc, floor)).collect();
        let n = s.len() as f64;
        for (acc, l) in pooled_counts.iter_mut().zip(&row) {
            acc.0 += l.saturated * n;
            acc.1 += l.under_noise * n;
        }
        pooled_n += n;
        frames.push(FrameExposure {
            index: pose.frame_id,
            t_s: *t_s,
            phase_deg: frame.stats.phase_deg,
            range_m: pose.camera_position_m.length(),
            active_px: s.len(),
            t_lo_s: t_lo,
            t_hi_s: t_hi,
            bracketed: t_lo <= t_hi,
            at_scene_exposure: loss_at(&s, det.exposure_s, fwc, floor),
        });
        loss.push(row);
        on_frame(i + 1, poses.len());
    }
    let lit: Vec<&FrameExposure> = frames.iter().filter(|f| f.active_px > 0).collect();
    let lo = lit
        .iter()
        .map(|f| f.t_lo_s)
        .fold(f64::NEG_INFINITY, f64::max);
    let hi = lit.iter().map(|f| f.t_hi_s).fold(f64::INFINITY, f64::min);
    let pooled = pooled_counts
        .iter()
        .map(|&(a, b)| Loss {
            saturated: a / pooled_n.max(1.0),
            under_noise: b / pooled_n.max(1.0),
        })
        .collect();
    Ok(ExposureReport {
        keep: plan.keep,
        dnr_db,
        full_well_e: fwc,
        noise_floor_e: floor,
        scene_exposure_s: det.exposure_s,
        bracket_s: (!lit.is_empty() && lo <= hi).then_some((lo, hi)),
        frames,
        exposures_s: grid,
        loss,
        pooled,
    })
}

/// Writes `frames.csv`, `loss.csv`, `exposure.png` and `exposure.svg` into `out`.
pub fn write(report: &ExposureReport, out: &Path) -> Result<(), AppError> {
    std::fs::create_dir_all(out).map_err(|source| AppError::OutDir {
        path: out.display().to_string(),
        source,
    })?;
    let mut frames = String::from(
        "index,t_s,phase_deg,range_m,active_px,t_lo_s,t_hi_s,bracketed,saturated_at_scene_exposure,under_noise_at_scene_exposure\n",
    );
    for f in &report.frames {
        frames += &format!(
            "{},{},{},{},{},{:e},{:e},{},{},{}\n",
            f.index,
            f.t_s,
            f.phase_deg,
            f.range_m,
            f.active_px,
            f.t_lo_s,
            f.t_hi_s,
            f.bracketed,
            f.at_scene_exposure.saturated,
            f.at_scene_exposure.under_noise
        );
    }
    let mut loss = String::from("index,exposure_s,saturated,under_noise\n");
    for (f, row) in report.frames.iter().zip(&report.loss) {
        for (t, l) in report.exposures_s.iter().zip(row) {
            loss += &format!("{},{t:e},{},{}\n", f.index, l.saturated, l.under_noise);
        }
    }
    let mut pooled = String::from("exposure_s,saturated,under_noise\n");
    for (t, l) in report.exposures_s.iter().zip(&report.pooled) {
        pooled += &format!("{t:e},{},{}\n", l.saturated, l.under_noise);
    }
    products::write_atomically(
        out,
        &[
            ("frames.csv", frames.into_bytes()),
            ("loss.csv", loss.into_bytes()),
            ("pooled.csv", pooled.into_bytes()),
        ],
    )?;
    let _ =
        plotters::style::register_font("sans-serif", FontStyle::Normal, super::sweep::chart::FONT);
    let size = (900, 900);
    let png = out.join("exposure.png");
    let svg = out.join("exposure.svg");
    let chart_err = |e: String| AppError::Exposure(format!("chart: {e}"));
    draw_on(BitMapBackend::new(&png, size).into_drawing_area(), report).map_err(chart_err)?;
    draw_on(SVGBackend::new(&svg, size).into_drawing_area(), report).map_err(chart_err)
}

/// The chart's exposure range: a decade around every frame's bracket.
fn x_range(report: &ExposureReport) -> (f64, f64) {
    let ends = report
        .frames
        .iter()
        .flat_map(|f| [f.t_lo_s, f.t_hi_s])
        .chain([report.scene_exposure_s])
        .filter(|t| t.is_finite() && *t > 0.0);
    let (a, b) = ends.fold((f64::MAX, f64::MIN), |(a, b), t| (a.min(t), b.max(t)));
    if a > b {
        (1e-6, 1.0)
    } else {
        (a / 10.0, b * 10.0)
    }
}

type Chart<'a, DB> =
    ChartContext<'a, DB, Cartesian2d<LogCoord<f64>, plotters::coord::types::RangedCoordf64>>;

/// Draws `points` as a line of `colour`, with its legend entry.
fn line<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB>,
    points: Vec<(f64, f64)>,
    colour: RGBColor,
    label: String,
) -> Result<(), String> {
    chart
        .draw_series(LineSeries::new(points, colour.stroke_width(2)))
        .map_err(|e| e.to_string())?
        .label(label)
        .legend(move |(x, y)| {
            PathElement::new(vec![(x - 8, y), (x + 8, y)], colour.stroke_width(2))
        });
    Ok(())
}

/// A panel with exposure time [s] on a log axis over `x`, `y` linear, its mesh drawn.
fn panel<'a, DB: DrawingBackend + 'a>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
    x: (f64, f64),
    y: std::ops::Range<f64>,
    y_desc: &str,
) -> Result<Chart<'a, DB>, String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 16).into_font())
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d((x.0..x.1).log_scale(), y)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("exposure time [s]")
        .y_desc(y_desc)
        .x_label_formatter(&|x| format!("{x:.0e}"))
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(e)?;
    Ok(chart)
}

/// The chart's legend box.
fn legend<'a, DB: DrawingBackend + 'a>(chart: &mut Chart<'a, DB>) -> Result<(), String> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(|e| e.to_string())
}

fn draw_on<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    r: &ExposureReport,
) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let (top, bottom) = root.split_vertically(560);
    let (x0, x1) = x_range(r);
    let (t0, t1) = r.frames.iter().fold((f64::MAX, f64::MIN), |(a, b), f| {
        (a.min(f.t_s), b.max(f.t_s))
    });
    let (t0, t1) = if t0 < t1 {
        (t0, t1)
    } else {
        (t0 - 0.5, t0 + 0.5)
    };
    let pct = (r.keep * 100.0).round();
    let caption = format!("Information loss along the trajectory; optimal bracket for X = {pct} %");
    let mut chart = panel(&top, &caption, (x0, x1), t0..t1, "trajectory time [s]")?;
    // The loss as a heat map: one cell per frame and grid exposure, each frame's row
    // reaching half-way to its neighbours' times.
    let times: Vec<f64> = r.frames.iter().map(|f| f.t_s).collect();
    let edge = |i: usize| -> (f64, f64) {
        let below = if i > 0 {
            (times[i - 1] + times[i]) / 2.0
        } else {
            t0
        };
        let above = if i + 1 < times.len() {
            (times[i] + times[i + 1]) / 2.0
        } else {
            t1
        };
        (below, above)
    };
    let g = &r.exposures_s;
    let step = g.get(1).map_or(10f64.powf(1.0 / 24.0), |b| b / g[0]).sqrt();
    chart
        .draw_series(r.loss.iter().enumerate().flat_map(|(i, row)| {
            let (y0, y1) = edge(i);
            g.iter()
                .zip(row)
                .filter(|(t, _)| **t >= x0 / step && **t <= x1 * step)
                .map(move |(t, l)| {
                    let v = l.total().clamp(0.0, 1.0);
                    // White (nothing lost) to dark red (everything lost).
                    let c = RGBColor(255, (255.0 * (1.0 - v)) as u8, (255.0 * (1.0 - v)) as u8);
                    Rectangle::new([(t / step, y0), (t * step, y1)], c.filled())
                })
        }))
        .map_err(e)?;
    let lo: Vec<(f64, f64)> = r
        .frames
        .iter()
        .filter(|f| f.t_lo_s.is_finite() && f.t_lo_s > 0.0)
        .map(|f| (f.t_lo_s, f.t_s))
        .collect();
    let hi: Vec<(f64, f64)> = r
        .frames
        .iter()
        .filter(|f| f.t_hi_s.is_finite())
        .map(|f| (f.t_hi_s, f.t_s))
        .collect();
    line(
        &mut chart,
        lo,
        BLUE,
        format!("t_lo: {pct} % above noise (Eq. 62)"),
    )?;
    line(
        &mut chart,
        hi,
        BLACK,
        format!("t_hi: {} % saturated (Eq. 61)", 100.0 - pct),
    )?;
    let te = r.scene_exposure_s;
    line(
        &mut chart,
        vec![(te, t0), (te, t1)],
        GREEN,
        "the scene's exposure".into(),
    )?;
    legend(&mut chart)?;

    let caption = "Over the whole trajectory: active pixels lost against exposure";
    let mut pooled = panel(
        &bottom,
        caption,
        (x0, x1),
        0.0..1.0,
        "fraction of active pixels",
    )?;
    let curve = |f: fn(&Loss) -> f64| -> Vec<(f64, f64)> {
        g.iter()
            .zip(&r.pooled)
            .filter(|(t, _)| **t >= x0 && **t <= x1)
            .map(|(t, l)| (*t, f(l)))
            .collect()
    };
    if let Some((a, b)) = r.bracket_s {
        pooled
            .draw_series(std::iter::once(Rectangle::new(
                [(a.max(x0), 0.0), (b.min(x1), 1.0)],
                GREEN.mix(0.15).filled(),
            )))
            .map_err(e)?
            .label("every frame's bracket holds")
            .legend(|(x, y)| {
                Rectangle::new([(x - 8, y - 5), (x + 8, y + 5)], GREEN.mix(0.3).filled())
            });
    }
    line(
        &mut pooled,
        curve(|l| l.saturated),
        BLACK,
        "saturated".into(),
    )?;
    line(
        &mut pooled,
        curve(|l| l.under_noise),
        BLUE,
        "under noise".into(),
    )?;
    line(&mut pooled, curve(Loss::total), RED, "lost".into())?;
    legend(&mut pooled)?;
    root.present().map_err(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bracket's ends against a direct count of the pixels lost just inside and just
    /// outside them.
    #[test]
    fn bracket_ends_hold_the_fraction() {
        let s: Vec<f64> = (1..=1000).map(|i| (i as f64).powf(1.7) * 1e3).collect();
        let (fwc, floor) = (2e4, 3.0);
        for keep in [0.6, 0.9, 0.95, 0.99] {
            let (lo, hi) = bracket(&s, keep, fwc, floor);
            let count_sat = |t: f64| s.iter().filter(|&&v| v * t > fwc).count() as f64 / 1e3;
            let count_noise = |t: f64| s.iter().filter(|&&v| v * t < floor).count() as f64 / 1e3;
            assert!(count_sat(hi) <= 1.0 - keep + 1e-12, "{keep}");
            assert!(count_sat(hi * 1.0001) > 1.0 - keep, "{keep}");
            assert!(1.0 - count_noise(lo) >= keep - 1e-12, "{keep}");
            assert!(1.0 - count_noise(lo * 0.9999) < keep, "{keep}");
            assert_eq!(loss_at(&s, hi, fwc, floor).saturated, count_sat(hi));
            assert_eq!(loss_at(&s, lo, fwc, floor).under_noise, count_noise(lo));
        }
    }
}
