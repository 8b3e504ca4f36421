//! `optistim render SCENE.toml --out DIR`: one frame to `power.fits` (W), `signal.fits`
//! (e-/s), `depth.fits` (m, NaN where empty), `image.png` (DN), and a JSON summary.

use super::AppError;
use crate::config::Config;
use crate::fidelity::budget::Plan;
use crate::io::fits::{self, Bitpix, Card, Value};
use crate::raycast::reference::{self, ReferenceReport, ReferenceSettings};
use crate::render::{FrameStats, Renderer};
use crate::stimulator::calibration::ClipCounts;
use crate::stimulator::camera::SimulatedCamera;
use crate::stimulator::{Stimulator, StimulatorTimings};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

#[derive(Debug, Serialize)]
pub struct RenderSummary {
    pub scene: String,
    /// Total collected power in `power_band_nm` (or bolometric) [W].
    pub total_power_w: f64,
    /// Total signal [e-/s].
    pub total_signal_e_per_s: f64,
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
    /// The converged reference ([`crate::raycast::reference`]); it also writes `error.fits`,
    /// each pixel's estimated error [W].
    Reference(ReferenceSettings),
}

/// The settings `optistim render` renders `pose` of `config` with: the scene's, or what the
/// fidelity planner chooses for the pose; depth on. (The compatible endpoints render with
/// these too, so that their images equal `optistim render`'s.)
pub fn frame_settings(config: &Config, pose: &crate::scene::Pose) -> crate::render::Settings {
    let mut settings = config.planner().map_or_else(
        || config.settings.clone(),
        |p| p.plan(&config.scene, pose).settings,
    );
    settings.depth = true;
    settings
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
    let mut plan = None;
    let (frame, reference) = match method {
        Method::Quadrangle => {
            plan = config
                .planner()
                .map(|p| p.plan(&config.scene, &config.pose));
            let mut settings = plan
                .as_ref()
                .map_or_else(|| config.settings.clone(), |p| p.settings.clone());
            settings.depth = true;
            debug_assert_eq!(settings, frame_settings(config, &config.pose));
            let mut renderer = Renderer::new(settings.threads)?;
            (
                renderer.render(&config.scene, &config.pose, &settings)?,
                None,
            )
        }
        Method::Reference(s) => {
            let r = reference::render(&config.scene, &config.pose, &s)?;
            (r.frame, Some((r.error_pl, r.report)))
        }
    };
    let det = &config.scene.camera.detector;

    let t0 = Instant::now();
    let radiance = config.scene.sun.radiance_integral(config.power_band_m);
    let k_signal = det.signal_factor(&config.scene.sun);
    let power: Vec<f64> = frame.pl.iter().map(|x| x * radiance).collect();
    let size = (frame.width, frame.height);
    let (signal, dn) = det.image(&frame.pl, size, &config.scene.sun, config.pose.frame_id);
    let detector_ms = t0.elapsed().as_secs_f64() * 1e3;

    let t0 = Instant::now();
    let mut cards = header(config, &frame.stats, radiance, k_signal);
    if let Some(p) = &plan {
        cards.extend(plan_cards(p));
    }
    let with = |unit: &str, what: &str| {
        let mut c = vec![Card::new("BUNIT", Value::Str(unit.into()), what)];
        c.extend(cards.iter().cloned());
        c
    };
    let (w, h) = (frame.width, frame.height);
    fits::write(
        &out.join("power.fits"),
        w,
        h,
        &power,
        Bitpix::F64,
        &with("W", "collected power per pixel"),
    )?;
    fits::write(
        &out.join("signal.fits"),
        w,
        h,
        &signal,
        Bitpix::F64,
        &with("electron/s", "signal per pixel"),
    )?;
    let depth = frame.depth_m.as_deref().unwrap_or(&[]);
    fits::write(
        &out.join("depth.fits"),
        w,
        h,
        depth,
        Bitpix::F32,
        &with("m", "range to the surface, NaN = empty"),
    )?;
    crate::io::write_png_gray(&out.join("image.png"), w, h, &dn, det.saved_bits)?;
    if let Some((error_pl, _)) = &reference {
        let error_w: Vec<f64> = error_pl.iter().map(|x| x * radiance).collect();
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
            let frame_st = stim.process(&signal)?;
            let camera = SimulatedCamera::from_config(st, intr, det)?;
            let seen = camera.capture(&frame_st.screen_dn, config.pose.frame_id)?;
            let t0 = Instant::now();
            fits::write(
                &out.join("feff.fits"),
                w,
                h,
                &frame_st.feff_w_m2,
                Bitpix::F64,
                &with("W/m2", "effective flux density at the camera (Eq. 58)"),
            )?;
            let [sw, sh] = st.screen_px;
            crate::io::write_png_gray(&out.join("screen.png"), sw, sh, &frame_st.screen_dn, 16)?;
            crate::io::write_png_gray(&out.join("camera.png"), w, h, &seen.dn, det.saved_bits)?;
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

    let mut timings = serde_json::to_value(frame.stats.timings_ms).unwrap_or_default();
    if let Some(o) = timings.as_object_mut() {
        o.insert("detector".into(), detector_ms.into());
        o.insert("write".into(), write_ms.into());
    }
    let max_dn = det.max_dn() as u16;
    Ok(RenderSummary {
        scene: scene_name.to_string(),
        total_power_w: power.iter().sum(),
        total_signal_e_per_s: signal.iter().sum(),
        points_sampled: frame.stats.points_sampled,
        points_kept: frame.stats.points_kept,
        phase_deg: frame.stats.phase_deg,
        covered_px: frame.stats.covered_px,
        saturated_px: dn.iter().filter(|&&x| x >= max_dn).count(),
        timings_ms: timings,
        reference: reference.map(|r| r.1),
        stimulator,
        fidelity: plan,
        mesh: match &config.scene.body.shape {
            crate::body::Shape::Mesh(m) => Some(m.report().clone()),
            _ => None,
        },
    })
}

/// The FITS cards of a budgeted frame: what the planner chose and the error it predicts.
pub fn plan_cards(p: &Plan) -> Vec<Card> {
    let f = |k: &str, v: f64, c: &str| Card::new(k, Value::Float(v), c);
    let shadows = serde_json::to_value(p.self_shadowing)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    vec![
        Card::new(
            "FIDELITY",
            Value::Str("budget".into()),
            "settings chosen per frame",
        ),
        f("PPP", p.points_per_pixel, "chosen: quadrangles per pixel"),
        Card::new(
            "BNODES",
            Value::Int(p.boundary_nodes as i64),
            "chosen: boundary Gauss nodes",
        ),
        Card::new("SHADOWS", Value::Str(shadows), "chosen: self-shadowing"),
        f(
            "PREDMED",
            p.predicted.median,
            "predicted median rel. error/lit px",
        ),
        f(
            "PREDP99",
            p.predicted.p99,
            "predicted p99 rel. error/lit px",
        ),
        f("PREDTOT", p.predicted.total, "predicted total rel. error"),
        f(
            "BUDMED",
            p.budget.median,
            "budget: median rel. error/lit px",
        ),
        f("BUDP99", p.budget.p99, "budget: p99 rel. error/lit px"),
        f("BUDTOT", p.budget.total, "budget: total rel. error"),
        Card::new(
            "BUDMET",
            Value::Bool(p.meets_budget),
            "predicted to meet the budget",
        ),
    ]
}

fn header(config: &Config, stats: &FrameStats, radiance: f64, k_signal: f64) -> Vec<Card> {
    let s = &config.scene;
    let i = &s.camera.intrinsics;
    let p = &config.pose;
    let q = crate::geometry::wxyz(p.body_from_camera);
    let f = |k: &str, v: f64, c: &str| Card::new(k, Value::Float(v), c);
    vec![
        Card::new(
            "CREATOR",
            Value::Str(format!("optistim {}", env!("CARGO_PKG_VERSION"))),
            "software",
        ),
        Card::new("BODY", Value::Str(s.body.name.clone()), "target body"),
        f(
            "RADIUS",
            s.body.shape.bounding_radius_m(),
            "body radius [m]",
        ),
        Card::new(
            "BRDF",
            Value::Str(s.body.brdf.name().into()),
            "reflectance model",
        ),
        f(
            "BRDFSCAL",
            s.body.brdf.scale(),
            "BRDF scale parameter (rho or w)",
        ),
        f(
            "GEOALB",
            s.body.brdf.geometric_albedo(),
            "geometric albedo p_G",
        ),
        f("PHASE", stats.phase_deg, "phase angle [deg]"),
        f(
            "CAMX",
            p.camera_position_m.x,
            "camera position, body frame [m]",
        ),
        f(
            "CAMY",
            p.camera_position_m.y,
            "camera position, body frame [m]",
        ),
        f(
            "CAMZ",
            p.camera_position_m.z,
            "camera position, body frame [m]",
        ),
        f("SUNX", p.sun_position_m.x, "Sun position, body frame [m]"),
        f("SUNY", p.sun_position_m.y, "Sun position, body frame [m]"),
        f("SUNZ", p.sun_position_m.z, "Sun position, body frame [m]"),
        f("QW", q[0], "camera->body quaternion, scalar first"),
        f("QX", q[1], "camera->body quaternion"),
        f("QY", q[2], "camera->body quaternion"),
        f("QZ", q[3], "camera->body quaternion"),
        f("FOCAL", i.focal_length_m, "focal length [m]"),
        f("FNUMBER", i.f_number, "f-number"),
        f("PIXSIZEU", i.pixel_pitch_m[0], "pixel pitch u [m]"),
        f("PIXSIZEV", i.pixel_pitch_m[1], "pixel pitch v [m]"),
        f("EXPTIME", s.camera.detector.exposure_s, "exposure [s]"),
        f("PL2W", radiance, "W per sr m^2 of (P/L): int L_e dlambda"),
        f("PL2SIG", k_signal, "e-/s per sr m^2 of (P/L) (Eq. 45)"),
        Card::new(
            "NPOINTS",
            Value::Int(stats.points_kept as i64),
            "quadrangles kept",
        ),
        f("ASUN", s.sun.area_m2(), "Sun frontal area [m^2]"),
        f("ACAM", i.aperture_area_m2(), "camera pupil area [m^2]"),
    ]
}
