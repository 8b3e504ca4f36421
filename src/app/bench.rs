//! `optistim bench [TRAJECTORY]`: renders every pose of a stream (render + detector, no file
//! output) and reports per-frame time statistics. Without a trajectory it renders the scene's
//! own pose repeatedly: the first frame (cold buffers) and the steady state are both reported.

use super::AppError;
use crate::config::Config;
use crate::render::Renderer;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The scene the benchmark uses unless told otherwise: a Lambert Moon seen by the NRHO
/// stream's camera (1024x1024, 5.5 um, 30 mm).
pub const DEFAULT_SCENE: &str = include_str!("../../config/nrho_bench.toml");

#[derive(Debug, Serialize)]
pub struct BenchReport {
    pub trajectory: String,
    pub frames: usize,
    /// The first frame's time [ms] (buffers allocated and first touched).
    pub first_ms: f64,
    pub threads: usize,
    pub median_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
    pub fps_median: f64,
    pub fps_slowest: f64,
    pub points_kept_median: usize,
    pub points_kept_max: usize,
    /// Mean time per stage [ms].
    pub mean_stage_ms: serde_json::Value,
    pub slowest_frame: u64,
}

#[derive(Debug, Serialize)]
pub struct FrameRow {
    pub frame: u64,
    pub t_s: f64,
    pub ms: f64,
    pub points_kept: usize,
    pub phase_deg: f64,
    pub covered_px: f64,
}

/// Renders up to `max_frames` poses of `trajectory` (default: the scene's own pose, 20 times)
/// with `config`'s scene and settings.
pub fn run(
    config: &Config,
    trajectory: Option<&Path>,
    max_frames: Option<usize>,
    mut per_frame: impl FnMut(&FrameRow),
) -> Result<BenchReport, AppError> {
    let (poses, label) = match trajectory {
        Some(t) => (crate::trajectory::read(t)?, t.display().to_string()),
        None => {
            let n = max_frames.unwrap_or(20);
            let poses = (0..n)
                .map(|i| {
                    let mut p = config.pose;
                    p.frame_id = i as u64;
                    (0.0, p)
                })
                .collect();
            (poses, "<the scene's pose>".to_string())
        }
    };
    let n = max_frames.unwrap_or(usize::MAX).min(poses.len());
    let mut renderer = Renderer::new(config.settings.threads)?;
    let det = &config.scene.camera.detector;
    let k = det.signal_factor(&config.scene.sun);
    let mut dn = Vec::new();
    let (mut times, mut points) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut stage_sum = serde_json::Map::new();
    for (t_s, pose) in poses.iter().take(n) {
        let t0 = Instant::now();
        let frame = renderer.render(&config.scene, pose, &config.settings)?;
        let td = Instant::now();
        let signal = det.signal(&frame.pl, k);
        det.expose(&signal, pose.frame_id, &mut dn);
        let detector_ms = td.elapsed().as_secs_f64() * 1e3;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if let serde_json::Value::Object(o) =
            serde_json::to_value(frame.stats.timings_ms).unwrap_or_default()
        {
            for (key, v) in o
                .into_iter()
                .chain([("detector".to_string(), detector_ms.into())])
            {
                let e = stage_sum.entry(key).or_insert(0.0.into());
                *e = (e.as_f64().unwrap_or(0.0) + v.as_f64().unwrap_or(0.0)).into();
            }
        }
        per_frame(&FrameRow {
            frame: pose.frame_id,
            t_s: *t_s,
            ms,
            points_kept: frame.stats.points_kept,
            phase_deg: frame.stats.phase_deg,
            covered_px: frame.stats.covered_px,
        });
        times.push((ms, pose.frame_id));
        points.push(frame.stats.points_kept);
    }
    for v in stage_sum.values_mut() {
        *v = (v.as_f64().unwrap_or(0.0) / n.max(1) as f64).into();
    }
    let mut sorted: Vec<f64> = times.iter().map(|t| t.0).collect();
    sorted.sort_by(f64::total_cmp);
    points.sort_unstable();
    let q = |p: f64| sorted[((sorted.len() - 1) as f64 * p).round() as usize];
    let slowest = times
        .iter()
        .fold((0.0, 0), |a, &t| if t.0 > a.0 { t } else { a });
    Ok(BenchReport {
        trajectory: label,
        frames: n,
        first_ms: times.first().map_or(0.0, |t| t.0),
        threads: renderer.threads(),
        median_ms: q(0.5),
        p95_ms: q(0.95),
        max_ms: q(1.0),
        fps_median: 1e3 / q(0.5),
        fps_slowest: 1e3 / q(1.0),
        points_kept_median: points[points.len() / 2],
        points_kept_max: *points.last().unwrap_or(&0),
        mean_stage_ms: serde_json::Value::Object(stage_sum),
        slowest_frame: slowest.1,
    })
}
