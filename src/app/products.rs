//! A frame's products: what one pose of a scene yields, made once and written the same way by
//! `optistim render`, `optistim render-trajectory` and the Python package.
//!
//! [`make`] renders the pose (with the planner's settings under `fidelity = "budget"`) and
//! runs the detector: collected power [W], signal [e-/s], range [m] and DN per pixel.
//! [`encode`] turns them into the files of a frame in memory (`power.fits`, `signal.fits`,
//! `depth.fits`, `image.png`), whose bytes depend on the scene, the pose and the images only
//! (no clock, no host): the same frame gives the same files on any machine and thread count.
//! [`write_atomically`] puts files into a folder so that a killed writer never leaves a
//! truncated file under a final name. [`FrameRecord`] is a frame's line in a dataset's
//! manifest; `frame.json`, written after the images, marks a dataset frame finished.

use super::AppError;
use crate::config::Config;
use crate::detector::Layout;
use crate::fidelity::budget::{Plan, Planner};
use crate::io::fits::{self, Bitpix, Card, Value};
use crate::render::{Frame, FrameStats, Renderer, Settings};
use crate::scene::Pose;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// The files of a frame, in the order they are written.
pub const FILES: [&str; 4] = ["power.fits", "signal.fits", "depth.fits", "image.png"];

/// Everything about a rendered frame but its images.
#[derive(Clone, Debug)]
pub struct FrameMeta {
    pub width: usize,
    pub height: usize,
    pub pose: Pose,
    pub stats: FrameStats,
    /// The settings the frame was rendered with (the planner's under a budget).
    pub settings: Settings,
    /// Under `fidelity = "budget"`: what the planner chose and the error it predicts.
    pub plan: Option<Plan>,
    /// Per band, W per sr m^2 of (P/L): the Sun's radiance after reflection by the body
    /// (its spectral shape), integrated over `power_band_m` for a monochrome camera, over
    /// each band's half-maximum range for several.
    pub band_radiance_w: Vec<f64>,
    /// Per band, e-/s per sr m^2 of (P/L) (Eq. 45 per band).
    pub band_factors: Vec<f64>,
    /// The detector's time [ms] (noise, quantisation).
    pub detector_ms: f64,
}

/// A frame's images, row-major from the top-left, `width x height` each; a multi-band
/// camera's power and signal hold one image per band, one after the other, and its DN one
/// per band or the one mosaic ([`crate::detector::Detector::dn_planes`]).
#[derive(Clone, Debug)]
pub struct ImageSet {
    /// Collected power [W], per band.
    pub power_w: Vec<f64>,
    /// Signal [e-/s], per band.
    pub signal_e_per_s: Vec<f64>,
    /// Range to the surface [m], NaN where the pixel sees no body.
    pub depth_m: Vec<f64>,
    /// Saved DN, per band or the mosaic.
    pub dn: Vec<u16>,
}

/// Borrowed images (from an [`ImageSet`], or from arrays held elsewhere: NumPy's).
#[derive(Clone, Copy, Debug)]
pub struct Images<'a> {
    pub power_w: &'a [f64],
    pub signal_e_per_s: &'a [f64],
    pub depth_m: &'a [f64],
    pub dn: &'a [u16],
}

impl ImageSet {
    pub fn view(&self) -> Images<'_> {
        Images {
            power_w: &self.power_w,
            signal_e_per_s: &self.signal_e_per_s,
            depth_m: &self.depth_m,
            dn: &self.dn,
        }
    }
}

/// Renders `pose` of `config` at the scene's settings, or as `planner` plans it (rendered
/// again while over its own estimate, [`Planner::render`]); depth on: the frame, the
/// settings it was rendered with last, and the plan.
pub fn render_frame(
    config: &Config,
    planner: Option<&Planner>,
    pose: &Pose,
    renderer: &mut Renderer,
) -> Result<(Frame, Settings, Option<Plan>), crate::render::RenderError> {
    let with_depth = |s: &Settings| Settings {
        depth: true,
        ..s.clone()
    };
    let (plan, frame) = crate::fidelity::budget::render_as_planned(
        planner,
        &config.scene,
        pose,
        &config.settings,
        |s| renderer.render(&config.scene, pose, &with_depth(s)),
    )?;
    let settings = with_depth(plan.as_ref().map_or(&config.settings, |p| &p.settings));
    Ok((frame, settings, plan))
}

/// Renders `pose` of `config` ([`render_frame`]) and runs the detector. `planner` is
/// `config.planner()`, made once per scene by the caller (it probes the scene).
pub fn make(
    config: &Config,
    planner: Option<&Planner>,
    pose: &Pose,
    renderer: &mut Renderer,
) -> Result<(FrameMeta, ImageSet), AppError> {
    let (frame, settings, plan) = render_frame(config, planner, pose, renderer)?;
    Ok(detect(config, pose, frame, settings, plan))
}

/// The detector's half of [`make`], for a frame rendered elsewhere (the reference).
pub fn detect(
    config: &Config,
    pose: &Pose,
    frame: crate::render::Frame,
    settings: Settings,
    plan: Option<Plan>,
) -> (FrameMeta, ImageSet) {
    let scene = &config.scene;
    let det = &scene.camera.detector;
    let t0 = Instant::now();
    let band_radiance_w = band_radiances(config);
    let band_factors = scene.band_factors();
    let power_w: Vec<f64> = band_radiance_w
        .iter()
        .enumerate()
        .flat_map(|(b, r)| frame.band(b).iter().map(move |x| x * r))
        .collect();
    let size = (frame.width, frame.height);
    let (signal_e_per_s, dn) = det.image(|b| frame.band(b), size, &band_factors, pose.frame_id);
    let depth_m = frame
        .depth_m
        .unwrap_or_else(|| vec![f64::NAN; frame.width * frame.height]);
    let meta = FrameMeta {
        width: frame.width,
        height: frame.height,
        pose: *pose,
        stats: frame.stats,
        settings,
        plan,
        band_radiance_w,
        band_factors,
        detector_ms: t0.elapsed().as_secs_f64() * 1e3,
    };
    let images = ImageSet {
        power_w,
        signal_e_per_s,
        depth_m,
        dn,
    };
    (meta, images)
}

/// Per band, W per sr m^2 of (P/L) after reflection by the body: over `power_band_m` for a
/// monochrome camera (the whole spectrum without one), over each band's half-maximum range
/// ([`crate::detector::Band::range_m`]) for several.
pub fn band_radiances(config: &Config) -> Vec<f64> {
    let scene = &config.scene;
    let bands = &scene.camera.detector.bands;
    if bands.len() == 1 {
        return vec![scene.radiance_w(config.power_band_m)];
    }
    bands
        .iter()
        .map(|b| scene.radiance_w(Some(b.range_m())))
        .collect()
}

/// The FITS cards every image of the frame carries: scene, pose, camera, and the plan.
pub fn cards(config: &Config, meta: &FrameMeta) -> Vec<Card> {
    let mut c = header(config, meta);
    c.extend(band_cards(config, meta));
    if let Some(p) = &meta.plan {
        c.extend(plan_cards(p));
    }
    if let Some(e) = meta.stats.estimated_error {
        let f = |k: &str, v: f64, what: &str| Card::new(k, Value::Float(v), what);
        c.extend([
            f(
                "ESTMED",
                e.median,
                "frame's own est. median rel. error/lit px",
            ),
            f("ESTP99", e.p99, "frame's own est. p99 rel. error/lit px"),
            f("ESTTOT", e.total, "frame's own est. total rel. error"),
        ]);
    }
    c
}

/// The FITS cards with `BUNIT` first.
pub fn with_unit(cards: &[Card], unit: &str, what: &str) -> Vec<Card> {
    let mut c = vec![Card::new("BUNIT", Value::Str(unit.into()), what)];
    c.extend(cards.iter().cloned());
    c
}

/// The tEXt chunks of a camera's PNG: its bands' names and its mosaic's pattern. None for a
/// monochrome camera, whose image.png stays the plain grey PNG (the CORTO server's bytes).
pub fn png_text(det: &crate::detector::Detector) -> Vec<(&'static str, String)> {
    let mut text = Vec::new();
    if det.bands.len() > 1 {
        text.push(("bands", band_names(det)));
    }
    if let Layout::Bayer(order) = det.layout {
        text.push(("bayer_pattern", order.name().to_string()));
    }
    text
}

/// The frame's files in memory, named as in [`FILES`].
pub fn encode(
    config: &Config,
    meta: &FrameMeta,
    images: Images<'_>,
) -> Result<Vec<(&'static str, Vec<u8>)>, AppError> {
    let (w, h) = (meta.width, meta.height);
    let n = w * h;
    let det = &config.scene.camera.detector;
    let bands = det.bands.len();
    let lens = [
        (images.power_w.len(), bands),
        (images.signal_e_per_s.len(), bands),
        (images.depth_m.len(), 1),
        (images.dn.len(), det.dn_planes()),
    ];
    if let Some((i, (len, planes))) = lens.iter().enumerate().find(|(_, (l, p))| *l != n * p) {
        return Err(AppError::Images(format!(
            "{}: {len} pixels, the frame is {w} x {h} x {planes}",
            FILES[i]
        )));
    }
    let cards = cards(config, meta);
    let text = png_text(det);
    let png =
        crate::io::encode_png_planes(w, h, images.dn, det.saved_bits, &text).map_err(|source| {
            crate::io::IoError::Png {
                path: FILES[3].into(),
                source,
            }
        })?;
    Ok(vec![
        (
            FILES[0],
            fits::encode(
                w,
                h,
                images.power_w,
                Bitpix::F64,
                &with_unit(&cards, "W", "collected power per pixel"),
            ),
        ),
        (
            FILES[1],
            fits::encode(
                w,
                h,
                images.signal_e_per_s,
                Bitpix::F64,
                &with_unit(&cards, "electron/s", "signal per pixel"),
            ),
        ),
        (
            FILES[2],
            fits::encode(
                w,
                h,
                images.depth_m,
                Bitpix::F32,
                &with_unit(&cards, "m", "range to the surface, NaN = empty"),
            ),
        ),
        (FILES[3], png),
    ])
}

/// Writes `files` into `dir` (created if missing), each first as `.NAME.partial` then renamed:
/// a file under its final name is always whole.
pub fn write_atomically(dir: &Path, files: &[(&str, Vec<u8>)]) -> Result<(), AppError> {
    std::fs::create_dir_all(dir).map_err(|source| AppError::OutDir {
        path: dir.display().to_string(),
        source,
    })?;
    for (name, bytes) in files {
        let path = dir.join(name);
        let partial = dir.join(format!(".{name}.partial"));
        let err = |source| crate::io::IoError::File {
            path: path.display().to_string(),
            source,
        };
        std::fs::write(&partial, bytes).map_err(err)?;
        std::fs::rename(&partial, &path).map_err(err)?;
    }
    Ok(())
}

/// A frame's row in a dataset's manifest (`frame.json`, `manifest.jsonl`, the Parquet
/// manifest of `optistim.dataset`). Deterministic: no timings, no host.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// The frame's index in the trajectory (from 0); it names the frame's folder.
    pub index: u64,
    /// The pose's time [s].
    pub t_s: f64,
    /// Camera position in the body frame [m].
    pub camera_position_m: [f64; 3],
    /// camera -> body quaternion, scalar first (`docs/conventions.md`).
    pub quaternion_wxyz: [f64; 4],
    /// Sun position in the body frame [m].
    pub sun_position_m: [f64; 3],
    pub phase_deg: f64,
    /// Camera to body centre [m].
    pub range_m: f64,
    /// Summed over the image (and over the bands of a multi-band camera).
    pub total_power_w: f64,
    /// Summed like `total_power_w`.
    pub total_signal_e_per_s: f64,
    pub saturated_px: u64,
    /// "budget" or "fixed".
    pub fidelity: String,
    /// The settings the frame was rendered with, as JSON (every knob; `docs/scene.md`).
    pub settings_json: String,
    /// Predicted relative errors under a budget (`null` with fixed settings: no model ran).
    pub predicted_median: Option<f64>,
    pub predicted_p99: Option<f64>,
    pub predicted_total: Option<f64>,
    /// The frame's files, relative to the dataset's root.
    pub files: Vec<String>,
}

/// The folder of frame `index` in a dataset, relative to its root.
pub fn frame_dir(index: u64) -> String {
    format!("frames/{index:06}")
}

impl FrameRecord {
    pub fn new(
        config: &Config,
        meta: &FrameMeta,
        images: Images<'_>,
        index: u64,
        t_s: f64,
    ) -> FrameRecord {
        let p = &meta.pose;
        let max_dn = config.scene.camera.detector.max_dn() as u16;
        let dir = frame_dir(index);
        let predicted = meta.plan.as_ref().map(|p| p.predicted);
        FrameRecord {
            index,
            t_s,
            camera_position_m: p.camera_position_m.to_array(),
            quaternion_wxyz: crate::geometry::wxyz(p.body_from_camera),
            sun_position_m: p.sun_position_m.to_array(),
            phase_deg: meta.stats.phase_deg,
            range_m: p.camera_position_m.length(),
            total_power_w: images.power_w.iter().sum(),
            total_signal_e_per_s: images.signal_e_per_s.iter().sum(),
            saturated_px: images.dn.iter().filter(|&&x| x >= max_dn).count() as u64,
            fidelity: if meta.plan.is_some() {
                "budget"
            } else {
                "fixed"
            }
            .into(),
            settings_json: serde_json::to_string(&meta.settings).unwrap_or_default(),
            predicted_median: predicted.map(|p| p.median),
            predicted_p99: predicted.map(|p| p.p99),
            predicted_total: predicted.map(|p| p.total),
            files: FILES.iter().map(|f| format!("{dir}/{f}")).collect(),
        }
    }

    /// The record as one JSON line.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }
}

/// The FITS cards of a budgeted frame: what the planner chose and the error it predicts.
pub fn plan_cards(p: &Plan) -> Vec<Card> {
    let f = |k: &str, v: f64, c: &str| Card::new(k, Value::Float(v), c);
    let shadows = crate::config::spelled(&p.self_shadowing);
    let map_filter = crate::config::spelled(&p.map_filter);
    vec![
        Card::new(
            "FIDELITY",
            Value::Str("budget".into()),
            "settings chosen per frame",
        ),
        f("PPP", p.points_per_pixel, "chosen: quadrangles per pixel"),
        Card::new(
            "EDGERAYS",
            Value::Int(p.raycast_edge_samples as i64),
            "chosen: first rays/px side at edges (ray cast)",
        ),
        Card::new(
            "CLIPPED",
            Value::Bool(p.raycast_clip),
            "chosen: mesh facets clipped exactly",
        ),
        Card::new(
            "BNODES",
            Value::Int(p.boundary_nodes as i64),
            "chosen: boundary Gauss nodes",
        ),
        Card::new("SHADOWS", Value::Str(shadows), "chosen: self-shadowing"),
        Card::new(
            "MAPFILT",
            Value::Str(map_filter),
            "chosen: map (and relief) read per area or pixel",
        ),
        Card::new(
            "RREFINE",
            Value::Int(p.relief_refine as i64),
            "relief reads refined up to this per side",
        ),
        Card::new(
            "RENDERS",
            Value::Int(p.renders as i64),
            "times rendered: again while over own estimate",
        ),
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

/// The bands' names, comma-separated (in the order of the cubes' planes).
fn band_names(det: &crate::detector::Detector) -> String {
    let names: Vec<&str> = det.bands.iter().map(|b| b.name.as_str()).collect();
    names.join(",")
}

/// The cards naming a multi-band camera's bands: `NBANDS`; per band `k` (from 1) `BANDk` its name, `BANDkLO`
/// and `BANDkHI` its wavelengths [nm], `BANDkC` its effective wavelength [nm], `PL2Wk` and
/// `PL2SIGk` its factors; `BAYERPAT` for a mosaic (the DN image is the raw mosaic).
fn band_cards(config: &Config, meta: &FrameMeta) -> Vec<Card> {
    let det = &config.scene.camera.detector;
    let f = |k: String, v: f64, c: &str| Card::new(&k, Value::Float(v), c);
    let mut c = Vec::new();
    // A monochrome camera's headers stay as they were (PL2W and PL2SIG say it all).
    let bands = if det.bands.len() > 1 {
        &det.bands[..]
    } else {
        &[]
    };
    if !bands.is_empty() {
        c.push(Card::new(
            "NBANDS",
            Value::Int(bands.len() as i64),
            "bands (NAXIS3 of power and signal)",
        ));
    }
    for (k, b) in bands.iter().enumerate() {
        let i = k + 1;
        let (lo, hi) = b.range_m();
        c.push(Card::new(
            &format!("BAND{i}"),
            Value::Str(b.name.clone()),
            "band name",
        ));
        c.push(f(
            format!("BAND{i}LO"),
            lo * 1e9,
            "band's shortest wavelength [nm]",
        ));
        c.push(f(
            format!("BAND{i}HI"),
            hi * 1e9,
            "band's longest wavelength [nm]",
        ));
        c.push(f(
            format!("BAND{i}C"),
            b.centre_m() * 1e9,
            "effective wavelength [nm]",
        ));
        c.push(f(
            format!("PL2W{i}"),
            meta.band_radiance_w[k],
            "W per sr m^2 of (P/L)",
        ));
        c.push(f(
            format!("PL2SIG{i}"),
            meta.band_factors[k],
            "e-/s per sr m^2 of (P/L)",
        ));
    }
    if let Layout::Bayer(order) = det.layout {
        c.push(Card::new(
            "BAYERPAT",
            Value::Str(order.name().into()),
            "image.png is the raw mosaic",
        ));
    }
    if let Some(r) = &config.scene.body.spectrum {
        c.push(Card::new(
            "REFLSPEC",
            Value::Str(r.name.clone()),
            "albedo's spectral shape",
        ));
        c.push(f(
            "REFLREF".into(),
            r.reference_m * 1e9,
            "albedo holds at [nm]",
        ));
    }
    c
}

fn header(config: &Config, meta: &FrameMeta) -> Vec<Card> {
    let s = &config.scene;
    let i = &s.camera.intrinsics;
    let p = &meta.pose;
    let stats = &meta.stats;
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
        Card::new(
            "FRAMEID",
            Value::Int(p.frame_id as i64),
            "frame id (seeds the noises)",
        ),
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
        f(
            "PL2W",
            meta.band_radiance_w[0],
            "W per sr m^2 of (P/L): int L_e dlambda",
        ),
        f(
            "PL2SIG",
            meta.band_factors[0],
            "e-/s per sr m^2 of (P/L) (Eq. 45)",
        ),
        Card::new(
            "NPOINTS",
            Value::Int(stats.points_kept as i64),
            "quadrangles kept",
        ),
        f("ASUN", s.sun.area_m2(), "Sun frontal area [m^2]"),
        f("ACAM", i.aperture_area_m2(), "camera pupil area [m^2]"),
    ]
}
