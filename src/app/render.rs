//! `optistim render SCENE.toml --out DIR`: one frame to `power.fits` (W), `signal.fits`
//! (e-/s), `depth.fits` (m, NaN where empty), `image.png` (DN), and a JSON summary.

use super::AppError;
use super::products;
use crate::config::Config;
use crate::fidelity::budget::Plan;
use crate::io::fits::{self, Bitpix};
use crate::raycast::reference::{self, ReferenceMethod, ReferenceReport, ReferenceSettings};
use crate::render::Renderer;
use crate::stimulator::calibration::ClipCounts;
use crate::stimulator::camera::SimulatedCamera;
use crate::stimulator::{Stimulator, StimulatorTimings};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// One band's share of a frame.
#[derive(Debug, Serialize)]
pub struct BandTotals {
    pub name: String,
    /// Collected power over the band's half-maximum range [W].
    pub total_power_w: f64,
    /// The band's signal [e-/s].
    pub total_signal_e_per_s: f64,
}

#[derive(Debug, Serialize)]
pub struct RenderSummary {
    pub scene: String,
    /// Total collected power in `power_band_nm` (or bolometric) [W]; over every band's own
    /// range, summed, for a camera of several.
    pub total_power_w: f64,
    /// Total signal [e-/s] (summed over the bands).
    pub total_signal_e_per_s: f64,
    /// A camera of several bands: each band's name and totals.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub bands: Vec<BandTotals>,
    pub points_sampled: usize,
    pub points_kept: usize,
    pub phase_deg: f64,
    pub covered_px: f64,
    pub saturated_px: usize,
    /// Time per stage [ms]: the renderer's steps, then the detector and the file writes.
    pub timings_ms: serde_json::Value,
    /// With `--reference`: how converged the reference is (its own error estimate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<ReferenceReport>,
    /// With a `[stimulator]` section: the screen frame's report.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stimulator: Option<StimulatorSummary>,
    /// With `fidelity = "budget"`: the settings chosen and the error predicted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<Plan>,
    /// A ray-cast frame's own estimate of its error ([`crate::raycast::estimate`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimated_error: Option<crate::raycast::estimate::FrameEstimate>,
    /// A mesh body's load report (what was repaired, the BVH's build time and bytes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<crate::body::mesh::MeshReport>,
}

#[derive(Debug, Serialize)]
pub struct StimulatorSummary {
    pub calibration_id: String,
    pub calibration_sha256: String,
    /// Pixels with no light (`black`), below the screen's dark level or above its maximum.
    pub clipped: ClipCounts,
    /// Total F_eff over the camera frame [W/m^2 summed over pixels].
    pub total_feff_w_m2: f64,
    /// The simulated camera's total signal [e-/s] (compare with `total_signal_e_per_s`).
    pub camera_total_signal_e_per_s: f64,
    pub timings_ms: StimulatorTimings,
}

/// Which renderer makes the frame.
#[derive(Clone, Copy, Debug)]
pub enum Method {
    /// The quadrangle pipeline with the scene's `[render]` settings.
    Quadrangle,
    /// The converged reference ([`crate::raycast::reference`], by the method given); it also
    /// writes `error.fits`, each pixel's estimated error [W].
    Reference(ReferenceSettings, ReferenceMethod),
}

/// `pose` of `config` rendered as `optistim render` renders it: at the scene's settings, or
/// as the fidelity planner plans it ([`products::render_frame`]). (The compatible endpoints
/// render with this too, so that their images equal `optistim render`'s.)
pub fn frame(
    config: &Config,
    pose: &crate::scene::Pose,
    renderer: &mut crate::render::Renderer,
) -> Result<crate::render::Frame, crate::render::RenderError> {
    products::render_frame(config, config.planner().as_ref(), pose, renderer).map(|(f, _, _)| f)
}

/// Renders the scene of `config` and writes the outputs into `out`.
pub fn run(
    config: &Config,
    scene_name: &str,
    out: &Path,
    method: Method,
) -> Result<RenderSummary, AppError> {
    std::fs::create_dir_all(out).map_err(|source| AppError::OutDir {
        path: out.display().to_string(),
        source,
    })?;
    let pose = &config.pose;
    let ((meta, images), reference) = match method {
        Method::Quadrangle => {
            let mut renderer = Renderer::new(config.settings.threads)?;
            let planner = config.planner();
            (
                products::make(config, planner.as_ref(), pose, &mut renderer)?,
                None,
            )
        }
        Method::Reference(s, m) => {
            let r = reference::render_by(&config.scene, pose, &s, m)?;
            let mut settings = config.settings.clone();
            settings.depth = true;
            (
                products::detect(config, pose, r.frame, settings, None),
                Some((r.error_pl, r.report)),
            )
        }
    };
    let det = &config.scene.camera.detector;
    let detector_ms = meta.detector_ms;

    let t0 = Instant::now();
    products::write_atomically(out, &products::encode(config, &meta, images.view())?)?;
    let cards = products::cards(config, &meta);
    let with = |unit: &str, what: &str| products::with_unit(&cards, unit, what);
    let (w, h) = (meta.width, meta.height);
    let signal = &images.signal_e_per_s;
    if let Some((error_pl, _)) = &reference {
        // In the first band's W for a camera of several (the estimate is the (P/L) image's).
        let error_w: Vec<f64> = error_pl
            .iter()
            .map(|x| x * meta.band_radiance_w[0])
            .collect();
        fits::write(
            &out.join("error.fits"),
            w,
            h,
            &error_w,
            Bitpix::F64,
            &with("W", "reference: estimated error per pixel"),
        )?;
    }
    let mut write_ms = t0.elapsed().as_secs_f64() * 1e3;

    let stimulator = match &config.stimulator {
        None => None,
        Some(st) => {
            let intr = &config.scene.camera.intrinsics;
            let stim = Stimulator::new(st, intr, det)?;
            let frame_st = stim.process(signal)?;
            let camera = SimulatedCamera::from_config(st, intr, det)?;
            let seen = camera.capture(&frame_st.screen_dn, pose.frame_id)?;
            let t0 = Instant::now();
            fits::write(
                &out.join("feff.fits"),
                w,
                h,
                &frame_st.feff_w_m2,
                Bitpix::F64,
                &with("W/m2", "effective flux density at the camera (Eq. 58)"),
            )?;
            // A colour screen's three planes as an RGB PNG of its codes; the camera's image as
            // image.png is (planes, or the raw mosaic with its pattern).
            let [sw, sh] = st.screen_px;
            let screen = &frame_st.screen_dn;
            crate::io::write_png_planes(&out.join("screen.png"), sw, sh, screen, 16, &[])?;
            let text = products::png_text(det);
            let camera = out.join("camera.png");
            crate::io::write_png_planes(&camera, w, h, &seen.dn, det.saved_bits, &text)?;
            write_ms += t0.elapsed().as_secs_f64() * 1e3;
            Some(StimulatorSummary {
                calibration_id: frame_st.calibration_id,
                calibration_sha256: frame_st.calibration_sha256,
                clipped: frame_st.clips,
                total_feff_w_m2: frame_st.feff_w_m2.iter().sum(),
                camera_total_signal_e_per_s: seen.signal_e_per_s.iter().sum(),
                timings_ms: frame_st.timings_ms,
            })
        }
    };

    let mut timings = serde_json::to_value(meta.stats.timings_ms).unwrap_or_default();
    if let Some(o) = timings.as_object_mut() {
        o.insert("detector".into(), detector_ms.into());
        o.insert("write".into(), write_ms.into());
    }
    let max_dn = det.max_dn() as u16;
    let n = w * h;
    let bands = if det.bands.len() > 1 {
        let plane = |v: &[f64], b: usize| v[b * n..(b + 1) * n].iter().sum();
        let bands = det.bands.iter().enumerate();
        bands
            .map(|(b, band)| BandTotals {
                name: band.name.clone(),
                total_power_w: plane(&images.power_w, b),
                total_signal_e_per_s: plane(signal, b),
            })
            .collect()
    } else {
        Vec::new()
    };
    Ok(RenderSummary {
        scene: scene_name.to_string(),
        total_power_w: images.power_w.iter().sum(),
        total_signal_e_per_s: signal.iter().sum(),
        bands,
        points_sampled: meta.stats.points_sampled,
        points_kept: meta.stats.points_kept,
        phase_deg: meta.stats.phase_deg,
        covered_px: meta.stats.covered_px,
        saturated_px: images.dn.iter().filter(|&&x| x >= max_dn).count(),
        timings_ms: timings,
        reference: reference.map(|r| r.1),
        stimulator,
        fidelity: meta.plan,
        estimated_error: meta.stats.estimated_error,
        mesh: match &config.scene.body.shape {
            crate::body::Shape::Mesh(m) => Some(m.report().clone()),
            _ => None,
        },
    })
}
