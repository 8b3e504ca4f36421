//! `optistim bench [TRAJECTORY]`: renders every pose of a stream (render + detector, no file
//! output) and reports per-frame time statistics. Without a trajectory it renders the scene's
//! own pose repeatedly: the first frame (cold buffers) and the steady state are both reported.
//! With `--against` two scene files take turns pose by pose ([`compare`]).

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
    /// Surface samples (BRDF evaluations) per frame, summed over the run: the integration's
    /// cost independent of the machine's load.
    pub surface_samples_total: usize,
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
    pub surface_samples: usize,
    pub phase_deg: f64,
    pub covered_px: f64,
    /// The renderer's stages [ms].
    pub timings_ms: crate::render::StageTimings,
    pub detector_ms: f64,
    /// With `fidelity = "budget"`: the settings chosen and the error predicted (the frame's
    /// `ms` includes the planning).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<crate::fidelity::budget::Plan>,
    /// A ray-cast frame's own estimate of its error ([`crate::raycast::estimate`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimated_error: Option<crate::raycast::estimate::FrameEstimate>,
}

/// Renders up to `max_frames` poses of `trajectory` (default: the scene's own pose, 20 times)
/// with `config`'s scene and settings.
pub fn run(
    config: &Config,
    trajectory: Option<&Path>,
    max_frames: Option<usize>,
    mut per_frame: impl FnMut(&FrameRow),
) -> Result<BenchReport, AppError> {
    let mut reports = run_interleaved(&[config], trajectory, max_frames, |_, row| per_frame(row))?;
    Ok(reports.remove(0))
}

/// Two scene files over the same poses, pose by pose in turn ([`run_interleaved`]): `scene`
/// against `against`, and how many times faster `scene` is at the median frame and at the
/// slowest (the issue-15 speed bar: `config/nrho_textured_budget.toml` against
/// `config/nrho_textured.toml`).
#[derive(Debug, Serialize)]
pub struct Comparison {
    pub scene: BenchReport,
    pub against: BenchReport,
    /// `against`'s median frame time over `scene`'s.
    pub speedup_median: f64,
    /// `against`'s slowest frame time over `scene`'s.
    pub speedup_slowest: f64,
}

/// [`run`] for `scene` and `against` interleaved pose by pose, so that the machine's drift
/// (load, clocks, caches) hits both alike; `per_frame` is told which (0: `scene`,
/// 1: `against`).
pub fn compare(
    scene: &Config,
    against: &Config,
    trajectory: Option<&Path>,
    max_frames: Option<usize>,
    per_frame: impl FnMut(usize, &FrameRow),
) -> Result<Comparison, AppError> {
    let mut reports = run_interleaved(&[scene, against], trajectory, max_frames, per_frame)?;
    let against = reports.remove(1);
    let scene = reports.remove(0);
    Ok(Comparison {
        speedup_median: against.median_ms / scene.median_ms,
        speedup_slowest: against.max_ms / scene.max_ms,
        scene,
        against,
    })
}

/// Renders each pose with every one of `configs` in turn (one renderer, its buffers shared),
/// one report per config; the poses and the camera are the first config's.
fn run_interleaved(
    configs: &[&Config],
    trajectory: Option<&Path>,
    max_frames: Option<usize>,
    mut per_frame: impl FnMut(usize, &FrameRow),
) -> Result<Vec<BenchReport>, AppError> {
    let Some(first) = configs.first() else {
        return Ok(Vec::new());
    };
    let (poses, label) = match trajectory {
        Some(t) => (crate::trajectory::read(t)?, t.display().to_string()),
        None => {
            let n = max_frames.unwrap_or(20);
            let poses = (0..n)
                .map(|i| {
                    let mut p = first.pose;
                    p.frame_id = i as u64;
                    (0.0, p)
                })
                .collect();
            (poses, "<the scene's pose>".to_string())
        }
    };
    let n = max_frames.unwrap_or(usize::MAX).min(poses.len());
    let mut renderer = Renderer::new(first.settings.threads)?;
    let mut runs: Vec<Run> = configs.iter().map(|c| Run::new(c, n)).collect();
    for (t_s, pose) in poses.iter().take(n) {
        for (which, run) in runs.iter_mut().enumerate() {
            let row = run.frame(&mut renderer, *t_s, pose)?;
            per_frame(which, &row);
        }
    }
    let threads = renderer.threads();
    Ok(runs
        .into_iter()
        .map(|r| r.report(label.clone(), threads))
        .collect())
}

/// One scene's frames of a bench run, measured as they come.
struct Run<'c> {
    config: &'c Config,
    planner: Option<crate::fidelity::budget::Planner>,
    /// Every band's factor of Eq. 45, once: the bands cost a multiplication and an exposure.
    factors: Vec<f64>,
    dn: Vec<u16>,
    times: Vec<(f64, u64)>,
    points: Vec<usize>,
    surface_samples_total: usize,
    stage_sum: serde_json::Map<String, serde_json::Value>,
}

impl<'c> Run<'c> {
    fn new(config: &'c Config, n: usize) -> Run<'c> {
        Run {
            config,
            planner: config.planner(),
            factors: config.scene.band_factors(),
            dn: Vec::new(),
            times: Vec::with_capacity(n),
            points: Vec::with_capacity(n),
            surface_samples_total: 0,
            stage_sum: serde_json::Map::new(),
        }
    }

    /// One frame at `pose`: planned (under a budget), rendered and read out to DN, timed.
    fn frame(
        &mut self,
        renderer: &mut Renderer,
        t_s: f64,
        pose: &crate::scene::Pose,
    ) -> Result<FrameRow, AppError> {
        let config = self.config;
        let det = &config.scene.camera.detector;
        let t0 = Instant::now();
        let (plan, frame) = crate::fidelity::budget::render_as_planned(
            self.planner.as_ref(),
            &config.scene,
            pose,
            &config.settings,
            |s| renderer.render(&config.scene, pose, s),
        )?;
        let td = Instant::now();
        let size = (frame.width, frame.height);
        let band = |b| frame.band(b);
        det.dn_into(band, size, &self.factors, pose.frame_id, &mut self.dn);
        let detector_ms = td.elapsed().as_secs_f64() * 1e3;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if let serde_json::Value::Object(o) =
            serde_json::to_value(frame.stats.timings_ms).unwrap_or_default()
        {
            for (key, v) in o
                .into_iter()
                .chain([("detector".to_string(), detector_ms.into())])
            {
                let e = self.stage_sum.entry(key).or_insert(0.0.into());
                *e = (e.as_f64().unwrap_or(0.0) + v.as_f64().unwrap_or(0.0)).into();
            }
        }
        self.times.push((ms, pose.frame_id));
        self.points.push(frame.stats.points_kept);
        self.surface_samples_total += frame.stats.surface_samples;
        Ok(FrameRow {
            frame: pose.frame_id,
            t_s,
            ms,
            points_kept: frame.stats.points_kept,
            surface_samples: frame.stats.surface_samples,
            phase_deg: frame.stats.phase_deg,
            covered_px: frame.stats.covered_px,
            timings_ms: frame.stats.timings_ms,
            detector_ms,
            fidelity: plan,
            estimated_error: frame.stats.estimated_error,
        })
    }

    /// The run's statistics over its frames.
    fn report(mut self, trajectory: String, threads: usize) -> BenchReport {
        let n = self.times.len();
        for v in self.stage_sum.values_mut() {
            *v = (v.as_f64().unwrap_or(0.0) / n.max(1) as f64).into();
        }
        let mut ms: Vec<f64> = self.times.iter().map(|t| t.0).collect();
        let [median, p95, max] = crate::stats::quantiles(&mut ms, [0.5, 0.95, 1.0]);
        self.points.sort_unstable();
        let slowest = self
            .times
            .iter()
            .fold((0.0, 0), |a, &t| if t.0 > a.0 { t } else { a });
        BenchReport {
            trajectory,
            frames: n,
            first_ms: self.times.first().map_or(0.0, |t| t.0),
            threads,
            median_ms: median,
            p95_ms: p95,
            max_ms: max,
            fps_median: 1e3 / median,
            fps_slowest: 1e3 / max,
            points_kept_median: self.points.get(n / 2).copied().unwrap_or(0),
            points_kept_max: self.points.last().copied().unwrap_or(0),
            surface_samples_total: self.surface_samples_total,
            mean_stage_ms: serde_json::Value::Object(self.stage_sum),
            slowest_frame: slowest.1,
        }
    }
}

/// `optistim bench-display`: the stimulator's per-frame path after rendering, F_eff -> screen
/// region -> GPU LUT pass -> presented (off-screen, read back), timed per stage.
#[derive(Debug, Serialize)]
pub struct DisplayBenchReport {
    pub adapter: String,
    pub screen_px: [usize; 2],
    pub region_px: [usize; 2],
    pub screen_bits: u32,
    pub frames: usize,
    /// The GPU table's interpolation error against the exact inverse [codes].
    pub table_max_code_error: f64,
    /// Median time per stage [ms]: `feff`, `resample` and `clip_count` on the CPU, then
    /// `upload`, `lut_pass` and `readback` (which waits for the GPU) of the presenter; `total`
    /// is their sum per frame. `cpu_reference` is the whole chain on the CPU
    /// (`Stimulator::process`), for comparison.
    pub median_ms: serde_json::Value,
    pub p99_total_ms: f64,
    pub max_total_ms: f64,
    /// Pixels whose GPU code differs from the CPU reference by 0, 1, and more than 1 LSB
    /// (last frame).
    pub lsb_equal: usize,
    pub lsb_one: usize,
    pub lsb_worse: usize,
}

/// Times `frames` passes of the scene's stimulator frame through the GPU presenter, with the
/// screen set to `screen_px` when given (the image centred, one-to-one).
pub fn run_display(
    config: &Config,
    scene_name: &str,
    screen_px: Option<[usize; 2]>,
    frames: usize,
) -> Result<DisplayBenchReport, AppError> {
    let mut config = config.clone();
    let st = config
        .stimulator
        .as_mut()
        .ok_or_else(|| AppError::NoStimulator(scene_name.to_string()))?;
    if let Some(s) = screen_px {
        let cam = &config.scene.camera.intrinsics;
        let cam = [cam.width_px as usize, cam.height_px as usize];
        st.screen_px = s;
        st.scale = [1.0, 1.0];
        st.origin_px = [
            s[0].saturating_sub(cam[0]) / 2,
            s[1].saturating_sub(cam[1]) / 2,
        ];
    }
    let region = crate::stimulator::screen::Resampler::region_px_for(
        [
            config.scene.camera.intrinsics.width_px as usize,
            config.scene.camera.intrinsics.height_px as usize,
        ],
        st.scale,
    );
    if (0..2).any(|a| st.origin_px[a] + region[a] > st.screen_px[a]) {
        return Err(AppError::Stimulator(
            crate::stimulator::StimulatorError::Measurement(format!(
                "the {region:?} px image region does not fit the {:?} px screen",
                st.screen_px
            )),
        ));
    }
    let st = st.clone();
    let mut maker = crate::pipeline::FrameMaker::new(&config)?;
    let signal = maker.render(&config.pose)?.signal_e_per_s;
    let stim = maker.stimulator().expect("has a [stimulator] section");
    let region_px = stim.resampler().region_px();
    let mut presenter = crate::display::Presenter::new_headless(st.screen_bits)?;
    presenter.set_drive(&stim.drive())?;
    let mut screen = Vec::new();
    let mut rows: Vec<[f64; 8]> = Vec::with_capacity(frames);
    for _ in 0..frames.max(1) + 1 {
        let f = stim.prepare(&signal)?;
        let t = presenter.draw_offscreen(&st, region_px, &f.region_feff_w_m2, &mut screen)?;
        let s = &f.timings_ms;
        let total = s.feff + s.resample + s.invert + t.total();
        let t0 = Instant::now();
        stim.process(&signal)?;
        let cpu_ms = t0.elapsed().as_secs_f64() * 1e3;
        rows.push([
            s.feff, s.resample, s.invert, t.upload, t.lut_pass, t.readback, total, cpu_ms,
        ]);
    }
    rows.remove(0); // the first pass builds pipelines and targets
    let column = |k: usize| rows.iter().map(|r| r[k]).collect::<Vec<f64>>();
    let median = |k: usize| crate::stats::quantiles(&mut column(k), [0.5])[0];
    let names = [
        "feff",
        "resample",
        "clip_count",
        "upload",
        "lut_pass",
        "readback",
        "total",
        "cpu_reference",
    ];
    let median_ms = names
        .iter()
        .enumerate()
        .map(|(k, n)| (n.to_string(), median(k).into()))
        .collect::<serde_json::Map<_, _>>();
    let cpu = stim.process(&signal)?.screen_dn;
    let (mut equal, mut one, mut worse) = (0, 0, 0);
    for (&g, &c) in screen.iter().zip(&cpu) {
        match g.abs_diff(c) {
            0 => equal += 1,
            1 => one += 1,
            _ => worse += 1,
        }
    }
    let [p99_total, max_total] = crate::stats::quantiles(&mut column(6), [0.99, 1.0]);
    Ok(DisplayBenchReport {
        adapter: presenter.adapter(),
        screen_px: st.screen_px,
        region_px,
        screen_bits: st.screen_bits,
        frames: rows.len(),
        table_max_code_error: presenter.table_error(),
        median_ms: serde_json::Value::Object(median_ms),
        p99_total_ms: p99_total,
        max_total_ms: max_total,
        lsb_equal: equal,
        lsb_one: one,
        lsb_worse: worse,
    })
}

#[cfg(test)]
mod tests {
    use crate::config::Config;

    fn small(render: &str) -> Config {
        let text = super::DEFAULT_SCENE
            .replace("resolution_px = [1024, 1024]", "resolution_px = [64, 64]")
            .replace("pixel_pitch_m = 5.5e-6", "pixel_pitch_m = 8.8e-5")
            .replace("preset = \"default\"", render);
        crate::config::parse(&text, "<bench test>").unwrap()
    }

    /// Two scenes over the same poses take turns pose by pose, each keeps its own frames
    /// (what it rendered, not the other's), and the speed-ups are the other's times over
    /// the scene's.
    #[test]
    fn two_scenes_take_turns_and_keep_their_own_frames() {
        let coarse = small("preset = \"default\"\npoints_per_pixel = 0.25");
        let fine = small("preset = \"default\"\npoints_per_pixel = 4.0");
        let mut order = Vec::new();
        let mut kept = [Vec::new(), Vec::new()];
        let c = super::compare(&coarse, &fine, None, Some(3), |which, row| {
            order.push((which, row.frame));
            kept[which].push(row.points_kept);
        })
        .unwrap();
        assert_eq!(order, [(0, 0), (1, 0), (0, 1), (1, 1), (0, 2), (1, 2)]);
        assert_eq!((c.scene.frames, c.against.frames), (3, 3));
        assert!(kept[0].iter().all(|&k| k == kept[0][0]));
        assert!(kept[0][0] * 4 < kept[1][0], "{kept:?}");
        assert_eq!(c.scene.points_kept_max, kept[0][0]);
        assert_eq!(c.against.points_kept_max, kept[1][0]);
        assert_eq!(c.speedup_median, c.against.median_ms / c.scene.median_ms);
        assert_eq!(c.speedup_slowest, c.against.max_ms / c.scene.max_ms);
    }
}
