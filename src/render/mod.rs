//! The quadrangle renderer (paper Sec. 4, Fig. 6): one module per pipeline step, called in
//! order by [`Renderer::render`]:
//!
//! ```text
//! pose -> view (CSF) -> bounding -> sampling -> pruning -> integration -> projection
//!      -> gridding (fixed point) -> reconstruction (super-sampling)
//!      -> footprint (the albedo map over each pixel, `map_filter = "pixel"`; and the
//!         relief's shading and shadows, `"relief"`) -> (P/L) image
//!      [+ depth]
//! ```
//!
//! The result is the geometric power-to-radiance image `(P/L)_{u,v}` [sr m^2] (Eq. 9); the
//! [`crate::detector`] turns it into signal and DN. The renderer is a pure function of
//! (scene, pose, settings): same inputs, same bits, whatever the thread count.

pub mod bounding;
pub mod depth;
pub mod footprint;
pub mod gridding;
pub mod integration;
pub mod projection;
pub mod pruning;
pub mod reconstruction;
pub mod sampling;
pub mod settings;
pub mod view;

use crate::scene::{Pose, Scene};
use gridding::{Accum, Gridding, Slope, floor_i64};
use integration::Method;
use pruning::{INTERIOR, PRUNED};
use rayon::prelude::*;
use sampling::GridTrig;
use serde::Serialize;
use settings::SelfShadowing;
pub use settings::{FovShape, Integration, MapFilter, PointBudget, Sampling, Settings, Split};
use std::time::Instant;
use view::View;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RenderError {
    #[error(
        "the camera is inside the body: range {range_m} m from the centre, body radius {radius_m} m"
    )]
    CameraInsideBody { range_m: f64, radius_m: f64 },
    #[error("pose.{field} is not finite or not valid: {value}")]
    BadPose { field: &'static str, value: String },
    #[error(transparent)]
    TooManyPoints(#[from] sampling::TooManyPoints),
    #[error(transparent)]
    NoClosedForm(#[from] integration::NoClosedForm),
    #[error("render.{field} = {value}: {allowed}")]
    BadSettings {
        field: &'static str,
        value: String,
        allowed: &'static str,
    },
    #[error(
        "the {stage} step produced a non-finite value ({value}); this is a bug, please report the scene"
    )]
    NonFinite { stage: &'static str, value: f64 },
    #[error("could not start the render threads: {0}")]
    Threads(String),
}

/// Wall time of each step [ms].
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageTimings {
    pub bounding: f64,
    pub sampling: f64,
    pub pruning: f64,
    pub integration: f64,
    pub projection: f64,
    pub gridding: f64,
    pub reconstruction: f64,
    /// The albedo map over each pixel's footprint (`map_filter = "pixel"`).
    pub footprint: f64,
    pub depth: f64,
    pub total: f64,
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct FrameStats {
    pub phase_deg: f64,
    /// Quadrangles sampled (longitude x latitude).
    pub points_sampled: usize,
    pub points_kept: usize,
    /// Surface samples the integration took (BRDF evaluations, lit or not): its cost.
    pub surface_samples: usize,
    pub grid_lon: usize,
    pub grid_lat: usize,
    /// Estimated pixels covered by lit, visible surface.
    pub covered_px: f64,
    /// Sum of (P/L) over the point cloud [sr m^2].
    pub total_pl_points: f64,
    /// Sum of (P/L) over the image [sr m^2] (less than the cloud only by what fell outside,
    /// unless `map_filter = "pixel"` then scales the pixels: see `total_pl_gridded`).
    pub total_pl_image: f64,
    /// Sum of (P/L) over the image before the footprint step [sr m^2]: the cloud's energy as
    /// gridded (equal to `total_pl_image` unless `map_filter = "pixel"`).
    pub total_pl_gridded: f64,
    pub timings_ms: StageTimings,
    /// The frame's own estimate of its error against the converged reference, where it has
    /// one (ray-cast frames whose pixels are tiled or cast with 2 rays per side or more:
    /// [`crate::raycast::estimate`]).
    pub estimated_error: Option<crate::raycast::estimate::FrameEstimate>,
    /// Under `map_filter = "relief"`: the 99th percentile over the lit pixels of the reads'
    /// own estimate of their error ([`footprint::apply_maps`]), which the planner's
    /// prediction takes where it is the larger ([`crate::fidelity::budget::Plan::observe`]).
    pub relief_read_p99: Option<f64>,
    /// The same estimate's median over the lit pixels: where the map's kinks between the
    /// reads are the frame's median error ([`footprint::Reads`]), what a quarter of the reads
    /// would have missed.
    pub relief_read_median: Option<f64>,
    /// The same estimate, signed, summed over the frame: `sum_i I_i e_i / sum_i I_i` (`I_i`
    /// a pixel's `(P/L)`, `e_i` its reads' signed relative error). A diagnostic, not an
    /// estimate of the frame's total: on 27 frames of the NRHO and Artemis streams, at
    /// `relief_refine` 2 to 8, it had the measured total's sign on about half and did not
    /// correlate with it (`docs/performance.md`, "The reads' own estimates on the streams'
    /// frames").
    pub relief_read_total: Option<f64>,
}

impl FrameStats {
    /// The reads' own estimates `[median, p99, total]` ([`FrameStats::relief_read_median`],
    /// [`FrameStats::relief_read_p99`], [`FrameStats::relief_read_total`]), NaN where the frame
    /// read no relief: the columns of the sweep's and the budget check's CSVs.
    pub fn relief_reads_or_nan(&self) -> [f64; 3] {
        [
            self.relief_read_median,
            self.relief_read_p99,
            self.relief_read_total,
        ]
        .map(|v| v.unwrap_or(f64::NAN))
    }
}

/// One rendered frame.
#[derive(Clone, Debug)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    /// `(P/L)` per pixel [sr m^2], row-major from the top-left.
    pub pl: Vec<f64>,
    /// The `(P/L)` images of the camera's bands whose own distortion (lateral chromatic
    /// aberration) moves them, by band index; every other band sees `pl` ([`Frame::band`]).
    pub band_pl: Vec<(usize, Vec<f64>)>,
    /// Range to the surface per pixel [m], NaN where empty (when `settings.depth`).
    pub depth_m: Option<Vec<f64>>,
    pub stats: FrameStats,
}

impl Frame {
    /// The `(P/L)` image band `b` sees: its own under a distortion of its own, else `pl`.
    pub fn band(&self, b: usize) -> &[f64] {
        self.band_pl
            .iter()
            .find(|(k, _)| *k == b)
            .map_or(&self.pl[..], |(_, img)| &img[..])
    }
}

/// Per-frame buffers, cleared and reused rather than reallocated.
#[derive(Default)]
struct Buffers {
    keep: Vec<u8>,
    pl: Vec<f64>,
    mids: Vec<[f64; 2]>,
    verts: Vec<[f64; 2]>,
    /// Per gridding band: fixed-point rows and the kernel's scratch.
    scratch: Vec<(Vec<i64>, gridding::Scratch)>,
    /// Gridding: (first row, last row) and (first column, last column) of each footprint, per
    /// pixel row a count then its band, and the footprints of each band (flat, from
    /// `band_start[b]`).
    rows: Vec<(u32, u32)>,
    cols: Vec<(u32, u32)>,
    row_band: Vec<u32>,
    band_start: Vec<usize>,
    band_items: Vec<u32>,
    /// Per-quadrangle footprint centroid [px], density [(P/L)/px^2] (NaN: not usable) and
    /// density gradient [(P/L)/px^3] (linear-density gridding only).
    centroid: Vec<[f64; 2]>,
    density: Vec<f64>,
    grad: Vec<[f64; 2]>,
}

/// Owns the worker threads and buffers; render many frames with one.
pub struct Renderer {
    pool: rayon::ThreadPool,
    threads: usize,
    buf: Buffers,
    /// A mesh's form factors (radiosity), with the mesh they belong to (held, so that its
    /// address cannot be reused by another mesh while the cache names it).
    form_factors: Option<(
        std::sync::Arc<crate::body::Mesh>,
        std::sync::Arc<crate::irradiance::FormFactors>,
    )>,
}

impl Renderer {
    /// `threads = 0` uses every core.
    pub fn new(threads: usize) -> Result<Self, RenderError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("optistim-render-{i}"))
            .build()
            .map_err(|e| RenderError::Threads(e.to_string()))?;
        let threads = pool.current_num_threads();
        Ok(Renderer {
            pool,
            threads,
            buf: Buffers::default(),
            form_factors: None,
        })
    }

    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Renders the (P/L) image of `scene` seen from `pose`.
    pub fn render(
        &mut self,
        scene: &Scene,
        pose: &Pose,
        settings: &Settings,
    ) -> Result<Frame, RenderError> {
        check_pose(scene, pose)?;
        check_settings(settings)?;
        // Meshes have no quadrangles: the ray caster renders them, into the same frame.
        if !scene.others.is_empty() && !matches!(scene.body.shape, crate::body::Shape::Mesh(_)) {
            // Several bodies: the ray caster composes them by depth.
            return self.pool.install(|| {
                let mut frame = crate::raycast::sampled::render(scene, pose, settings, None)?;
                with_band_distortions(scene, &mut frame, |s| {
                    Ok(crate::raycast::sampled::render(s, pose, settings, None)?.pl)
                })?;
                Ok(frame)
            });
        }
        if let crate::body::Shape::Mesh(mesh) = &scene.body.shape {
            use std::sync::Arc;
            let orders = settings.scattering_orders;
            let ff = if orders > 0 {
                // The form factors depend on the mesh alone: made once per mesh.
                match &self.form_factors {
                    Some((m, ff)) if Arc::ptr_eq(m, mesh) => Some(ff.clone()),
                    _ => {
                        let ff = Arc::new(
                            self.pool
                                .install(|| crate::irradiance::FormFactors::new(mesh)),
                        );
                        self.form_factors = Some((mesh.clone(), ff.clone()));
                        Some(ff)
                    }
                }
            } else {
                None
            };
            return self.pool.install(|| {
                // The Bond albedo is an integral over the BRDF: only when it is used.
                let scattered = ff.map(|ff| {
                    let rho = scene.body.brdf.albedo(crate::brdf::AlbedoType::Bond);
                    let direct = crate::irradiance::direct(mesh, pose.sun_position_m);
                    (crate::irradiance::scattered(&ff, &direct, rho, orders), rho)
                });
                let scattered = scattered.as_ref().map(|(r, rho)| (&r[..], *rho));
                if settings.raycast_clip
                    && scattered.is_none()
                    && crate::raycast::exact::applies(scene, pose).is_ok()
                {
                    let mut frame = crate::raycast::exact::render_frame(scene, pose, settings)?;
                    with_band_distortions(scene, &mut frame, |s| {
                        Ok(crate::raycast::exact::render_frame(s, pose, settings)?.pl)
                    })?;
                    return Ok(frame);
                }
                let mut frame = crate::raycast::sampled::render(scene, pose, settings, scattered)?;
                with_band_distortions(scene, &mut frame, |s| {
                    Ok(crate::raycast::sampled::render(s, pose, settings, scattered)?.pl)
                })?;
                Ok(frame)
            });
        }
        let (quad_relief, _, _) = relief_roles(scene, settings);
        let method = Method::resolve(settings.integration, &scene.body, quad_relief.is_some())?;
        let threads = self.threads;
        let buf = &mut self.buf;
        self.pool
            .install(|| render_in_pool(scene, pose, settings, method, threads, buf))
    }
}

/// For the renderers that cast rays through the camera (meshes, several bodies, the
/// reference), which have no cloud to grid again: each band with a distortion of its own
/// (lateral chromatic aberration) or an albedo map of its own gets the image of `render`
/// through a copy of the scene whose camera has that distortion and whose body has that map,
/// in `frame.band_pl`. A full render per such band.
pub(crate) fn with_band_distortions(
    scene: &Scene,
    frame: &mut Frame,
    mut render: impl FnMut(&Scene) -> Result<Vec<f64>, RenderError>,
) -> Result<(), RenderError> {
    let own_intr = band_intrinsics(scene);
    for b in 0..scene.camera.detector.bands.len() {
        let intr_b = own_intr.iter().find(|(k, _)| *k == b).map(|(_, i)| i);
        let map_b = scene.body.band_map(b);
        if intr_b.is_none() && map_b.is_none() {
            continue;
        }
        let mut own = scene.clone();
        if let Some(i) = intr_b {
            own.camera.intrinsics = i.clone();
        }
        if let Some(m) = map_b {
            own.body.albedo_map = Some(m.clone());
        }
        frame.band_pl.push((b, render(&own)?));
    }
    Ok(())
}

/// The camera's intrinsics for each band whose own distortion differs from the camera's
/// (lateral chromatic aberration), by band index.
fn band_intrinsics(scene: &Scene) -> Vec<(usize, crate::camera::Intrinsics)> {
    let intr = &scene.camera.intrinsics;
    let bands = scene.camera.detector.bands.iter().enumerate();
    bands
        .filter_map(|(b, band)| {
            let d = band.distortion.filter(|d| *d != intr.distortion)?;
            let own = crate::camera::Intrinsics {
                distortion: d,
                ..intr.clone()
            };
            Some((b, own))
        })
        .collect()
}

/// The view of `scene`'s body through `intr` from `pose` (the camera's, or a band's own);
/// `under_sun`: the quadrangles' relief for this frame's Sun ([`under_sun`]), if any.
fn view_through<'a>(
    intr: &'a crate::camera::Intrinsics,
    scene: &'a Scene,
    pose: &Pose,
    settings: &Settings,
    under_sun: Option<&'a crate::body::Relief>,
) -> View<'a> {
    let (relief, shadows, _) = relief_roles(scene, settings);
    let relief = under_sun.or(relief);
    View::new(
        intr,
        &scene.body.shape,
        relief,
        shadows,
        pose,
        settings.supersampling,
        settings.fov,
    )
}

/// The quadrangles' relief for `pose`'s Sun where they march its shadows
/// ([`crate::body::Relief::under_sun`]: the same answers, found sooner); `None` otherwise.
fn under_sun(scene: &Scene, pose: &Pose, settings: &Settings) -> Option<crate::body::Relief> {
    match relief_roles(scene, settings) {
        (Some(r), SelfShadowing::RayMarching, _) => Some(r.under_sun(pose.sun_position_m)),
        _ => None,
    }
}

/// How the frame's relief is shared between the quadrangles and the footprint step: the
/// relief the quadrangles (and the footprint's lines of sight) see and how it shadows them,
/// and the relief whose shading and shadows the footprint's reads carry. Under
/// `MapFilter::Relief` the quadrangles integrate the smooth shape, unshadowed, and the reads
/// carry the relief with the frame's `self_shadowing`; otherwise the quadrangles carry it.
#[allow(clippy::type_complexity)]
fn relief_roles<'a>(
    scene: &'a Scene,
    settings: &Settings,
) -> (
    Option<&'a crate::body::Relief>,
    SelfShadowing,
    Option<(&'a crate::body::Relief, SelfShadowing)>,
) {
    match scene.body.relief.as_ref() {
        Some(r) if settings.map_filter == MapFilter::Relief => {
            (None, SelfShadowing::Off, Some((r, settings.self_shadowing)))
        }
        r => (r, settings.self_shadowing, None),
    }
}

pub(crate) fn check_pose(scene: &Scene, pose: &Pose) -> Result<(), RenderError> {
    let bad = |field, value: String| Err(RenderError::BadPose { field, value });
    if !pose.camera_position_m.is_finite() {
        return bad("camera_position_m", format!("{:?}", pose.camera_position_m));
    }
    if !pose.sun_position_m.is_finite() || pose.sun_position_m.length() == 0.0 {
        return bad("sun_position_m", format!("{:?}", pose.sun_position_m));
    }
    let q = pose.body_from_camera;
    if !q.is_finite() || (q.length() - 1.0).abs() > 1e-6 {
        return bad("attitude", format!("{q:?} (must be a unit quaternion)"));
    }
    if !scene.body.admits_camera_at(pose.camera_position_m) {
        return Err(RenderError::CameraInsideBody {
            range_m: pose.camera_position_m.length(),
            radius_m: scene
                .body
                .keep_out_radius_m(pose.camera_position_m.normalize_or_zero()),
        });
    }
    if scene.body.shape.contains(pose.sun_position_m) {
        return bad("sun_position_m", "inside the body".into());
    }
    for (k, o) in scene.others.iter().enumerate() {
        if o.contains(pose.sun_position_m) {
            return bad("sun_position_m", format!("inside body {}", k + 1));
        }
        if o.contains(pose.camera_position_m) {
            return bad(
                "camera_position_m",
                format!("{:?} (inside body {})", pose.camera_position_m, k + 1),
            );
        }
    }
    Ok(())
}

fn check_settings(s: &Settings) -> Result<(), RenderError> {
    let bad = |field, value: String, allowed| {
        Err(RenderError::BadSettings {
            field,
            value,
            allowed,
        })
    };
    match s.points {
        PointBudget::Total(0) => return bad("points", "0".into(), "at least 1"),
        PointBudget::PerPixel(p) if !(p.is_finite() && p > 0.0 && p <= 1e4) => {
            return bad("points_per_pixel", p.to_string(), "a number in (0, 10000]");
        }
        _ => {}
    }
    if s.boundary_nodes == 0 || s.boundary_nodes > 32 {
        return bad(
            "boundary_nodes",
            s.boundary_nodes.to_string(),
            "an integer in [1, 32]",
        );
    }
    for (field, n) in [
        ("raycast_samples", s.raycast_samples),
        ("raycast_edge_samples", s.raycast_edge_samples),
    ] {
        if n == 0 || n > 64 {
            return bad(field, n.to_string(), "an integer in [1, 64]");
        }
    }
    if s.supersampling == 0 || s.supersampling > 16 {
        return bad(
            "supersampling",
            s.supersampling.to_string(),
            "an integer in [1, 16]",
        );
    }
    if !(s.antialias_sigma_px.is_finite() && s.antialias_sigma_px >= 0.0) {
        return bad(
            "antialias_sigma_px",
            s.antialias_sigma_px.to_string(),
            "a number >= 0",
        );
    }
    if let Gridding::Gaussian {
        window_px,
        sigma_px,
    } = s.gridding
    {
        if window_px == 0 || window_px > 15 || window_px % 2 == 0 {
            return bad(
                "gaussian_window_px",
                window_px.to_string(),
                "an odd integer in [1, 15]",
            );
        }
        if !(sigma_px.is_finite() && sigma_px > 0.0) {
            return bad("gaussian_sigma_px", sigma_px.to_string(), "a number > 0");
        }
    }
    if let Integration::Trapezoidal { points_per_deg }
    | Integration::Midpoint { points_per_deg }
    | Integration::Auto { points_per_deg } = s.integration
    {
        if !(points_per_deg.is_finite() && points_per_deg > 0.0) {
            return bad(
                "trapezoid_points_per_deg",
                points_per_deg.to_string(),
                "a number > 0",
            );
        }
    }
    Ok(())
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn render_in_pool(
    scene: &Scene,
    pose: &Pose,
    settings: &Settings,
    method: Method,
    threads: usize,
    buf: &mut Buffers,
) -> Result<Frame, RenderError> {
    let t_total = Instant::now();
    let intr = &scene.camera.intrinsics;
    let (width, height) = (intr.width_px as usize, intr.height_px as usize);
    let framed = under_sun(scene, pose, settings);
    let view = view_through(intr, scene, pose, settings, framed.as_ref());
    let band_intr = band_intrinsics(scene);
    let mut stats = FrameStats {
        phase_deg: view.csf.phase_rad.to_degrees(),
        ..Default::default()
    };
    let mut t = StageTimings::default();
    // Under `MapFilter::Pixel` the quadrangles see the map's mean and the footprint step
    // brings the map in per pixel; under `Relief` the DEM's shading too.
    if let Some(allowed) = settings.map_filter.refusal(&scene.body) {
        return Err(RenderError::BadSettings {
            field: "map_filter",
            value: format!("{:?}", settings.map_filter).to_lowercase(),
            allowed,
        });
    }
    let (brdf, quad_albedo, pixel_map) = match (&scene.body.albedo_map, settings.map_filter) {
        (Some(a), MapFilter::Pixel | MapFilter::Relief) => {
            let s_ref = footprint::reference_scale(a, scene.body.brdf.scale());
            (scene.body.brdf.with_scale(s_ref), None, Some(a))
        }
        (map, _) => (scene.body.brdf, map.as_ref(), None),
    };

    let t0 = Instant::now();
    // A sphere, and an ellipsoid in its parameter space, are bounded to the visible cap in the
    // FOV; another shape is sampled over every direction from its centre, uniformly (the
    // visible-cap bounds and the projected-uniform spacing are the sphere's); pruning keeps
    // what is lit, visible and in the FOV.
    let round = view.sphere_like();
    let bounds = if round {
        bounding::bound(&view, settings.bounding_tolerance_rad)
    } else {
        Some(bounding::Bounds::WHOLE)
    };
    let grid_sampling = if round {
        settings.sampling
    } else {
        settings::Sampling::Uniform
    };
    t.bounding = ms(t0);

    let mut pl_image = vec![0.0; width * height];
    let mut band_pl = Vec::new();
    if let Some(bounds) = bounds {
        let t0 = Instant::now();
        let plan = sampling::plan(&view, &bounds, settings)?;
        let alpha = view.grid.phase_rad;
        let trig = GridTrig::new(
            sampling::edges(bounds.lon.0, bounds.lon.1, plan.n_lon, grid_sampling, alpha),
            sampling::edges(bounds.lat.0, bounds.lat.1, plan.n_lat, grid_sampling, 0.0),
        );
        stats.grid_lon = plan.n_lon;
        stats.grid_lat = plan.n_lat;
        stats.points_sampled = plan.n_lon * plan.n_lat;
        stats.covered_px = plan.covered_px;
        t.sampling = ms(t0);

        let t0 = Instant::now();
        stats.points_kept = pruning::prune(&view, &trig, &mut buf.keep);
        t.pruning = ms(t0);

        let t0 = Instant::now();
        let a_sun = scene.sun.area_m2();
        let a_cam = intr.aperture_area_m2();
        let (total, samples) = integration::integrate(
            &view,
            &trig,
            &buf.keep,
            &brdf,
            quad_albedo,
            settings.map_filter,
            method,
            settings.boundary_nodes as usize,
            settings.trapezoid_points_per_px,
            a_sun,
            a_cam,
            &mut buf.pl,
        );
        stats.total_pl_points = total;
        stats.surface_samples = samples;
        t.integration = ms(t0);
        if !total.is_finite() {
            return Err(RenderError::NonFinite {
                stage: "integration",
                value: total,
            });
        }

        // The camera's image, then one per band whose own distortion (lateral chromatic
        // aberration, Sec. 6.1.2) moves the same cloud elsewhere before gridding.
        let mut to_image = |view: &View, t: &mut StageTimings| {
            image_from_cloud(view, &trig, settings, total, threads, buf, t)
        };
        pl_image = to_image(&view, &mut t);
        for (b, intr_b) in &band_intr {
            let view_b = view_through(intr_b, scene, pose, settings, framed.as_ref());
            let img = to_image(&view_b, &mut t);
            band_pl.push((*b, img));
        }
    }
    stats.total_pl_gridded = pl_image.iter().sum();
    if !stats.total_pl_gridded.is_finite() {
        return Err(RenderError::NonFinite {
            stage: "gridding",
            value: stats.total_pl_gridded,
        });
    }
    stats.total_pl_image = stats.total_pl_gridded;
    if let Some(a) = pixel_map {
        let t0 = Instant::now();
        let (relief, _, shading) = relief_roles(scene, settings);
        let shape = &scene.body.shape;
        let a_sun_cam = |i: &crate::camera::Intrinsics| scene.sun.area_m2() * i.aperture_area_m2();
        // A band with a map of its own but the camera's distortion: the gridded geometry,
        // before the camera's map comes in.
        for (b, _) in &scene.body.band_maps {
            if !band_pl.iter().any(|(k, _)| k == b) {
                band_pl.push((*b, pl_image.clone()));
            }
        }
        // Through the camera's distortion: its map and the bands' own maps, in one pass.
        let (own_view, camera_view): (Vec<_>, Vec<_>) = band_pl
            .iter_mut()
            .partition(|(b, _)| band_intr.iter().any(|(k, _)| k == b));
        let mut layers = vec![(a, &mut pl_image[..])];
        for (b, img) in camera_view {
            layers.push((scene.body.band_map(*b).unwrap_or(a), &mut img[..]));
        }
        let estimate = footprint::apply_maps(
            intr,
            shape,
            relief,
            shading,
            footprint::Reads::of(settings),
            &brdf,
            pose,
            a_sun_cam(intr),
            &mut layers,
        );
        if let Some(e) = estimate {
            let [median, p99, total] = read_figures(&e, &pl_image);
            stats.relief_read_median = Some(median);
            stats.relief_read_p99 = Some(p99);
            stats.relief_read_total = Some(total);
        }
        for (b, img) in own_view {
            let intr_b = band_intr
                .iter()
                .find(|(k, _)| k == b)
                .map_or(intr, |(_, i)| i);
            let map = scene.body.band_map(*b).unwrap_or(a);
            footprint::apply(
                intr_b,
                shape,
                relief,
                shading,
                footprint::Reads::of(settings),
                &brdf,
                map,
                pose,
                a_sun_cam(intr_b),
                img,
            );
        }
        stats.total_pl_image = pl_image.iter().sum();
        t.footprint = ms(t0);
        if !stats.total_pl_image.is_finite() {
            return Err(RenderError::NonFinite {
                stage: "footprint",
                value: stats.total_pl_image,
            });
        }
    }

    let depth_m = settings.depth.then(|| {
        let t0 = Instant::now();
        let d = depth::depth_map(intr, &scene.body.shape, scene.body.relief.as_ref(), pose);
        t.depth = ms(t0);
        d
    });
    t.total = ms(t_total);
    stats.timings_ms = t;
    Ok(Frame {
        width,
        height,
        pl: pl_image,
        band_pl,
        depth_m,
        stats,
    })
}

/// The median and the 99th percentile of `estimate`'s magnitude over the pixels lit in
/// `image`, and `estimate` (signed, relative per pixel) weighed by `image`: the relative
/// error it puts on the image's sum (all 0 on a dark image).
fn read_figures(estimate: &[f64], image: &[f64]) -> [f64; 3] {
    let (mut err, mut sum) = (0.0, 0.0);
    let mut lit = Vec::new();
    for (&e, &v) in estimate.iter().zip(image) {
        if v > 0.0 {
            lit.push(e.abs());
            err += e * v;
            sum += v;
        }
    }
    if lit.is_empty() {
        return [0.0; 3];
    }
    let [median, p99] = crate::stats::quantiles(&mut lit, [0.5, 0.99]);
    [median, p99, err / sum]
}

/// The cloud's image through `view`: projection of the midpoints (and the vertices, for
/// kernels that need them), gridding, reconstruction; the stages' times added to `t`.
fn image_from_cloud(
    view: &View,
    trig: &GridTrig,
    settings: &Settings,
    total: f64,
    threads: usize,
    buf: &mut Buffers,
    t: &mut StageTimings,
) -> Vec<f64> {
    let intr = view.intrinsics;
    let (width, height) = (intr.width_px as usize, intr.height_px as usize);
    let m = settings.supersampling as usize;
    let t0 = Instant::now();
    projection::project_midpoints(view, trig, &buf.keep, &mut buf.mids);
    if settings.gridding.needs_corners() {
        projection::project_vertices(view, trig, &mut buf.verts);
    }
    t.projection += ms(t0);

    let t0 = Instant::now();
    let fine = grid(
        settings.gridding,
        trig,
        buf,
        width * m,
        height * m,
        total,
        threads,
    );
    t.gridding += ms(t0);

    let t0 = Instant::now();
    let image = if m == 1 && settings.antialias_sigma_px == 0.0 {
        fine
    } else {
        reconstruction::reconstruct(
            &fine,
            width,
            height,
            m,
            settings.reconstruction,
            settings.antialias_sigma_px,
        )
    };
    t.reconstruction += ms(t0);
    image
}

/// The density slopes of [`Gridding::PolygonLinear`]: for each interior quadrangle, the
/// least-squares gradient of the footprint density against its four grid neighbours' (those
/// that are interior too), limited so that the density stays non-negative at every corner of
/// the footprint (hence over it: it is convex and the density linear). Boundary quadrangles,
/// whose density is not a smooth field's, get none.
fn fit_slopes(trig: &GridTrig, buf: &mut Buffers) {
    let (nl, nk) = (trig.n_lon(), trig.n_lat());
    let n = nl * nk;
    let (keep, pl, verts) = (&buf.keep, &buf.pl, &buf.verts);
    let corners = |i: usize, k: usize| {
        let v = |a: usize, c: usize| verts[c * (nl + 1) + a];
        [v(i, k), v(i + 1, k), v(i + 1, k + 1), v(i, k + 1)]
    };
    buf.centroid.resize(n, [0.0; 2]);
    buf.density.resize(n, f64::NAN);
    buf.centroid
        .par_chunks_mut(nl)
        .zip(buf.density.par_chunks_mut(nl))
        .enumerate()
        .for_each(|(k, (cen, den))| {
            for i in 0..nl {
                let j = k * nl + i;
                den[i] = f64::NAN;
                if keep[j] == INTERIOR && pl[j] > 0.0 {
                    if let Some((c, a)) = gridding::centroid_area(&corners(i, k)) {
                        cen[i] = c;
                        den[i] = pl[j] / a;
                    }
                }
            }
        });
    let (cen, den) = (&buf.centroid, &buf.density);
    buf.grad.resize(n, [0.0; 2]);
    buf.grad
        .par_chunks_mut(nl)
        .enumerate()
        .for_each(|(k, row)| {
            for (i, out) in row.iter_mut().enumerate() {
                let j = k * nl + i;
                *out = [0.0; 2];
                let d0 = den[j];
                if !d0.is_finite() {
                    continue;
                }
                let (mut sxx, mut sxy, mut syy, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
                let neighbours = [
                    (i > 0).then(|| j - 1),
                    (i + 1 < nl).then(|| j + 1),
                    (k > 0).then(|| j - nl),
                    (k + 1 < nk).then(|| j + nl),
                ];
                for nb in neighbours.into_iter().flatten() {
                    if !den[nb].is_finite() {
                        continue;
                    }
                    let (dx, dy) = (cen[nb][0] - cen[j][0], cen[nb][1] - cen[j][1]);
                    let dd = den[nb] - d0;
                    sxx += dx * dx;
                    sxy += dx * dy;
                    syy += dy * dy;
                    bx += dx * dd;
                    by += dy * dd;
                }
                let det = sxx * syy - sxy * sxy;
                // Negated so that a NaN determinant skips the slope too.
                #[allow(clippy::neg_cmp_op_on_partial_ord)]
                if !(det > 1e-9 * (sxx + syy) * (sxx + syy)) {
                    continue;
                }
                let mut g = [(syy * bx - sxy * by) / det, (sxx * by - sxy * bx) / det];
                // Positivity limiter: the density at the lowest corner must not go below zero.
                let low = corners(i, k)
                    .iter()
                    .map(|c| g[0] * (c[0] - cen[j][0]) + g[1] * (c[1] - cen[j][1]))
                    .fold(0.0f64, f64::min);
                if d0 + low < 0.0 {
                    let f = d0 / -low;
                    g = [g[0] * f, g[1] * f];
                }
                if g[0].is_finite() && g[1].is_finite() {
                    *out = g;
                }
            }
        });
}

/// The gridding step. The image is cut into bands of pixel rows with about equal numbers of
/// footprints, a few per thread so that rayon can balance them; each band grids, in fixed
/// point, every footprint whose kernel reaches its rows (clipping the rest away) and writes its
/// own rows of the image. Integer sums do not depend on order, and each pixel is summed by one
/// band only, so the image does not depend on the split or the thread count.
fn grid(
    kernel: Gridding,
    trig: &GridTrig,
    buf: &mut Buffers,
    gw: usize,
    gh: usize,
    total: f64,
    threads: usize,
) -> Vec<f64> {
    let mut out = vec![0.0; gw * gh];
    if total <= 0.0 || gw == 0 || gh == 0 {
        return out;
    }
    // 2^60 units for the whole cloud: no pixel can overflow, and the rounding of one
    // contribution is at most 2^-61 of the total.
    let scale = (1u64 << 60) as f64 / total;
    let nl = trig.n_lon();
    let reach = kernel.reach_px();
    let corners_needed = kernel.needs_corners();
    let linear = kernel == Gridding::PolygonLinear;
    if linear {
        fit_slopes(trig, buf);
    }
    let (keep, pl, mids, verts) = (&buf.keep, &buf.pl, &buf.mids, &buf.verts);
    let corners = |j: usize| -> [[f64; 2]; 4] {
        let (i, k) = (j % nl, j / nl);
        let v = |a: usize, c: usize| verts[c * (nl + 1) + a];
        [v(i, k), v(i + 1, k), v(i + 1, k + 1), v(i, k + 1)]
    };

    // The pixel rows and columns each footprint's kernel can reach (`u32::MAX`: none).
    let (rows, cols) = (&mut buf.rows, &mut buf.cols);
    rows.clear();
    rows.resize(keep.len(), (u32::MAX, 0));
    cols.clear();
    cols.resize(keep.len(), (u32::MAX, 0));
    rows.par_iter_mut()
        .zip(cols.par_iter_mut())
        .enumerate()
        .for_each(|(j, (r, c))| {
            if keep[j] == PRUNED || pl[j] == 0.0 {
                return;
            }
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            let mut grow = |p: [f64; 2]| {
                if p[0].is_finite() && p[1].is_finite() {
                    for a in 0..2 {
                        lo[a] = lo[a].min(p[a]);
                        hi[a] = hi[a].max(p[a]);
                    }
                }
            };
            grow(mids[j]);
            if corners_needed {
                corners(j).into_iter().for_each(&mut grow);
            } else if !mids[j][0].is_finite() {
                return;
            }
            if lo[1] > hi[1] {
                return;
            }
            let span = |a: usize, n: usize| {
                let first = (floor_i64(lo[a]) - reach).max(0);
                let last = (floor_i64(hi[a]) + reach).min(n as i64 - 1);
                (first <= last).then_some((first as u32, last as u32))
            };
            if let (Some(rs), Some(cs)) = (span(1, gh), span(0, gw)) {
                *r = rs;
                *c = cs;
            }
        });
    // The window every footprint falls in: only it is accumulated and converted (at far range
    // a few thousand pixels of the million).
    let union = |spans: &[(u32, u32)]| {
        spans
            .par_iter()
            .copied()
            .reduce(|| (u32::MAX, 0), |a, b| (a.0.min(b.0), a.1.max(b.1)))
    };
    let ((c0, c1), (r0, r1)) = (union(cols), union(rows));
    if c0 == u32::MAX {
        return out;
    }
    let (c0, wc) = (c0 as usize, (c1 - c0) as usize + 1);
    let (r0, r1) = (r0 as usize, r1 as usize + 1);

    let bounds = plan_bands(
        rows,
        &mut buf.row_band,
        &mut buf.band_start,
        &mut buf.band_items,
        gh,
        threads,
    );
    let bands = bounds.len() - 1;

    // Grid each band into its own rows.
    buf.scratch.resize_with(bands, Default::default);
    let mut rows_out = Vec::with_capacity(bands);
    let mut rest = out.as_mut_slice();
    for b in 0..bands {
        let (band, r) = rest.split_at_mut((bounds[b + 1] - bounds[b]) * gw);
        rows_out.push(band);
        rest = r;
    }
    let (centroid, grad, items, starts) =
        (&buf.centroid, &buf.grad, &buf.band_items, &buf.band_start);
    let nan4 = [[f64::NAN; 2]; 4];
    buf.scratch
        .par_iter_mut()
        .zip(rows_out)
        .enumerate()
        .for_each(|(b, ((fixed, scratch), band_out))| {
            // This band's rows within the window.
            let (y0, y1) = (bounds[b].max(r0), bounds[b + 1].min(r1));
            if y0 >= y1 {
                return;
            }
            fixed.clear();
            fixed.resize((y1 - y0) * wc, 0);
            let mut acc = Accum {
                data: fixed,
                scratch,
                x0: c0 as i64,
                y0: y0 as i64,
                w: wc as i64,
                h: (y1 - y0) as i64,
                scale,
            };
            for &j in &items[starts[b]..starts[b + 1]] {
                let j = j as usize;
                let c = if corners_needed { corners(j) } else { nan4 };
                let slope = linear.then(|| Slope {
                    centroid: centroid[j],
                    grad: grad[j],
                });
                kernel.splat(&c, mids[j], pl[j], slope.as_ref(), &mut acc);
            }
            let inv = 1.0 / scale;
            for (y, src) in fixed.chunks_exact(wc).enumerate() {
                let row = (y0 + y - bounds[b]) * gw + c0;
                for (o, &s) in band_out[row..row + wc].iter_mut().zip(src) {
                    *o = s as f64 * inv;
                }
            }
        });
    out
}

/// Cuts the `gh` pixel rows into bands with about equal numbers of footprints starting in
/// them (`rows`: each footprint's first and last row, `u32::MAX` for none), a few per thread,
/// and lists each band's footprints in `items` from `starts[b]` (a counting sort; a footprint
/// reaching several bands is listed in each). Returns the bands' first rows and `gh`.
fn plan_bands(
    rows: &[(u32, u32)],
    row_band: &mut Vec<u32>,
    starts: &mut Vec<usize>,
    items: &mut Vec<u32>,
    gh: usize,
    threads: usize,
) -> Vec<usize> {
    let spans = || {
        rows.iter()
            .enumerate()
            .filter(|(_, r)| r.0 != u32::MAX)
            .map(|(j, &(r0, r1))| (j as u32, r0 as usize, r1 as usize))
    };
    // Footprints starting in each row, then the band of each row.
    row_band.clear();
    row_band.resize(gh, 0);
    let mut n = 0;
    for (_, r0, _) in spans() {
        row_band[r0] += 1;
        n += 1;
    }
    let wanted = (4 * threads.max(1)).min(gh);
    let mut bounds = vec![0usize];
    let mut seen = 0usize;
    for (r, &c) in row_band.iter().enumerate() {
        seen += c as usize;
        if bounds.len() < wanted && seen * wanted >= n * bounds.len() && r + 1 < gh {
            bounds.push(r + 1);
        }
    }
    bounds.push(gh);
    let bands = bounds.len() - 1;
    for b in 0..bands {
        row_band[bounds[b]..bounds[b + 1]].fill(b as u32);
    }
    let band_range = |r0: usize, r1: usize| row_band[r0] as usize..=row_band[r1] as usize;
    starts.clear();
    starts.resize(bands + 1, 0);
    for (_, r0, r1) in spans() {
        for b in band_range(r0, r1) {
            starts[b + 1] += 1;
        }
    }
    for b in 0..bands {
        starts[b + 1] += starts[b];
    }
    items.clear();
    items.resize(starts[bands], 0);
    let mut fill = starts[..bands].to_vec();
    for (j, r0, r1) in spans() {
        for b in band_range(r0, r1) {
            items[fill[b]] = j;
            fill[b] += 1;
        }
    }
    bounds
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reads_total_weighs_each_pixels_signed_estimate_by_its_light() {
        // Two lit pixels off by +10 % and -10 % of themselves, the second three times the
        // first: the frame's total is off by (0.1 - 0.3) / 4; the dark pixel's estimate
        // weighs nothing.
        let [_, _, total] = read_figures(&[0.1, -0.1, 0.5], &[1.0, 3.0, 0.0]);
        assert!((total + 0.05).abs() < 1e-15, "{total}");
        assert_eq!(read_figures(&[0.5], &[0.0])[2], 0.0);
        // The quantiles take the magnitudes, over the lit pixels alone.
        let [median, p99, _] = read_figures(&[-0.2, 0.1, 0.9], &[1.0, 1.0, 0.0]);
        assert!(median >= 0.1 && p99 > 0.15 && p99 <= 0.2, "{median} {p99}");
    }
}
