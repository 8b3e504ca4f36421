//! `optistim stability --out docs/stability.md`: the renderer where methods fail. Each case
//! (extreme ranges and phases, the body half out of view or behind the camera, degenerate
//! poses, broken maps, DEM cliffs, extreme Hapke parameters, a 10:1 ellipsoid, 1 x 1 and
//! 8192 x 8192 images) is rendered with the default settings on its own thread under a time
//! limit, then
//! - it renders: every pixel finite and non-negative, the detector's DN in range, the light
//!   conserved from the point cloud to the image (to 1e-9, where the body is wholly in view),
//!   and its error against the converged reference ([`crate::raycast::reference`]) set beside
//!   the default budget (median 1e-3, p99 3e-2, total 1e-4 per lit pixel);
//! - or it is refused with a typed error naming the cause;
//! - never a NaN, a panic or a hang, which the suite reports as failures.
//!
//! Each case that renders is rendered again as `fidelity = "budget"` plans it (the default
//! budget, the shipped error model): the settings chosen, the error the frame predicts for
//! itself and the one measured against the same reference. A frame must be within the
//! budget or say that it is not (`meets_budget: false`): never silently over it.
//!
//! The same cases run as a test (`tests/stability.rs`); the report is the table written to
//! `docs/stability.md`.

use super::AppError;
use crate::config::Config;
use crate::fidelity::metrics::{FrameError, frame_error};
use crate::raycast::reference::{self, ReferenceSettings};
use crate::render::Renderer;
use glam::{DQuat, DVec3};
use serde::Serialize;
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The suite's reference: converged well below the budget at 128 x 128 (cells down to
/// 1/256 px, at most 2048 a pixel, a lattice of 32 x 32 a pixel near the edges and warped
/// lattices of at most 128 a side at a limb, half the default's), so that a DEM cliff's
/// grazing rays stay affordable.
const REFERENCE: ReferenceSettings = ReferenceSettings {
    tolerance: 1e-6,
    max_depth: 8,
    edge_depth: 8,
    light_depth: 5,
    corner_depth: 7,
    near_depth: 3,
    lattice_per_px: 32,
    limb_lattice_max: 128,
    max_cells_per_px: 2048,
    threads: 0,
};

/// The default error budget of a frame (relative, per lit pixel and in total).
pub const BUDGET: (f64, f64, f64) = (1e-3, 3e-2, 1e-4);

const AU: f64 = 1.495978707e11;
const R: f64 = 1737400.0;

/// How a case ended.
#[derive(Clone, Debug, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Outcome {
    /// Rendered: finite, in range.
    Rendered,
    /// Refused with this typed error.
    Refused { error: String },
    /// A defect: NaN or out-of-range values, a panic, or no answer within the limit.
    Defect { what: String },
}

#[derive(Clone, Debug, Serialize)]
pub struct CaseReport {
    pub case: String,
    /// What the case must do: render, or be refused.
    pub expected: &'static str,
    pub outcome: Outcome,
    /// `|image - cloud| / cloud` of the total `(P/L)`, where the body is wholly in view.
    pub energy: Option<f64>,
    pub error: Option<FrameError>,
    /// The reference's own estimated error (total).
    pub reference_est_total: Option<f64>,
    /// Whether the error is within [`BUDGET`] (median, p99, total).
    pub within_budget: Option<bool>,
    /// The same frame under `fidelity = "budget"` (where it renders and has a reference).
    pub budgeted: Option<Budgeted>,
    pub ms: f64,
}

/// A case's frame as `fidelity = "budget"` plans it.
#[derive(Clone, Debug, Serialize)]
pub struct Budgeted {
    /// The settings chosen: quadrangles per pixel (0 for a ray-cast frame), self-shadowing
    /// and map filter.
    pub points_per_pixel: f64,
    pub self_shadowing: String,
    pub map_filter: String,
    /// What the frame said of itself: its predicted error and whether that meets the budget.
    pub predicted: (f64, f64, f64),
    pub meets_budget: bool,
    /// Why the frame lies outside the error model's domain, where it does.
    pub outside_model: Option<&'static str>,
    /// Measured against the reference.
    pub error: FrameError,
    pub ms: f64,
}

impl Budgeted {
    /// Within [`BUDGET`] (median, p99, total) as measured.
    pub fn within(&self) -> bool {
        within_budget(&self.error)
    }

    /// Within the budget, or the frame said it would not be.
    pub fn honest(&self) -> bool {
        self.within() || !self.meets_budget
    }
}

/// Whether `e` is within [`BUDGET`] (median, p99, total).
fn within_budget(e: &FrameError) -> bool {
    e.median <= BUDGET.0 && e.p99 <= BUDGET.1 && e.total <= BUDGET.2
}

/// One case: its name, scene text (a full scene TOML), and what to do to the pose after
/// loading (degenerate attitudes cannot be written in a valid file).
struct Case {
    name: &'static str,
    text: String,
    pose: Option<fn(&mut crate::scene::Pose)>,
    /// The body is wholly in the frame (energy must be conserved).
    whole: bool,
    /// Compare with the reference (not for the 8192 x 8192 image).
    reference: bool,
    /// Whether it must render (else be refused).
    renders: bool,
}

/// A scene: a Lambert sphere of the Moon's radius, a 128 x 128 camera, `body` and `pose` as
/// extra text. The camera's focal length is chosen so that the FOV is `fov_deg` wide.
fn scene(body: &str, camera: &str, pose: &str, sun: [f64; 3], fov_deg: f64, n: u32) -> String {
    let pitch = 5.5e-6 * 128.0 / n as f64;
    let focal = 0.5 * n as f64 * pitch / (0.5 * fov_deg).to_radians().tan();
    format!(
        r#"
[sun]
spectrum = "blackbody"
temperature_k = 5782.0
radius_m = 6.957e8
position_m = {sun:?}

[body]
name = "Case"
{body}

[camera]
resolution_px = [{n}, {n}]
pixel_pitch_m = {pitch}
focal_length_m = {focal}
f_number = 4.0
exposure_s = 1e-4
full_well_e = 30000.0
adc_gain_dn_per_e = 0.1
bit_depth = 12
qe = {{ wavelength_nm = [400, 700, 1000], value = [0.5, 0.6, 0.2] }}
{camera}

[camera.noise]
seed = 3
shot = true
readout_sigma_e = 2.0

[pose]
{pose}
"#
    )
}

const SPHERE: &str =
    "radius_m = 1737400.0\nbrdf = \"lambert\"\nalbedo = 0.12\nalbedo_type = \"normal\"";

fn sun_at(phase_deg: f64) -> [f64; 3] {
    let a = phase_deg.to_radians();
    [AU * a.cos(), AU * a.sin(), 0.0]
}

fn look(camera: [f64; 3]) -> String {
    format!("camera_position_m = {camera:?}\nlook_at_body = true")
}

/// A pose that looks from `camera` along `boresight` (body frame), +Y of the image towards
/// `down`.
fn looking(camera: [f64; 3], boresight: [f64; 3], down: [f64; 3]) -> String {
    let z = DVec3::from(boresight).normalize();
    let x = DVec3::from(down).cross(z).normalize();
    let y = z.cross(x);
    let q = DQuat::from_mat3(&glam::DMat3::from_cols(x, y, z));
    format!(
        "camera_position_m = {camera:?}\nattitude_wxyz = [{}, {}, {}, {}]",
        q.w, q.x, q.y, q.z
    )
}

fn hapke(w: f64, h: f64, theta_rad: f64) -> String {
    format!(
        "radius_m = 1737400.0\nbrdf = \"hapke\"\nhapke = [0.21, 0.85, 0.0, {h}, 1.8, {h}, {theta_rad}, 0.0]\nalbedo = {w}\nalbedo_type = \"single_scattering\""
    )
}

/// Writes a 36 x 18 float TIFF of `values(col, row)` into `dir` and returns its path.
fn map(dir: &Path, name: &str, values: impl Fn(usize, usize) -> f32) -> Result<String, AppError> {
    let (w, h) = (36u32, 18u32);
    let data: Vec<f32> = (0..h as usize)
        .flat_map(|r| (0..w as usize).map(move |c| (r, c)))
        .map(|(r, c)| values(c, r))
        .collect();
    let path = dir.join(name);
    let fail = |e: String| AppError::Stability(format!("{}: {e}", path.display()));
    let file = std::fs::File::create(&path).map_err(|e| fail(e.to_string()))?;
    tiff::encoder::TiffEncoder::new(file)
        .map_err(|e| fail(e.to_string()))?
        .write_image::<tiff::encoder::colortype::Gray32Float>(w, h, &data)
        .map_err(|e| fail(e.to_string()))?;
    Ok(path.display().to_string().replace('\\', "/"))
}

fn cases(dir: &Path) -> Result<Vec<Case>, AppError> {
    let s = |name, text: String| Case {
        name,
        text,
        pose: None,
        whole: true,
        reference: true,
        renders: true,
    };
    let cut = |c: Case| Case { whole: false, ..c };
    let refused = |c: Case| Case {
        renders: false,
        ..c
    };
    let far = [3.0 * R, 0.0, 0.0];
    let wide = |pose: &str, sun| scene(SPHERE, "", pose, sun, 60.0, 128);
    let nan_map = map(dir, "albedo_nan.tif", |c, r| {
        if (c + r) % 5 == 0 {
            f32::NAN
        } else if (c + 2 * r) % 7 == 0 {
            f32::INFINITY
        } else {
            0.1
        }
    })?;
    let constant = map(dir, "albedo_constant.tif", |_, _| 0.12)?;
    let flat = map(dir, "dem_flat.tif", |_, _| 0.0)?;
    let cliff = map(dir, "dem_cliff.tif", |c, _| if c < 18 { 0.0 } else { 50.0 })?;
    let spike = map(dir, "dem_spike.tif", |c, r| {
        if c == 18 && r == 9 { 300.0 } else { 0.0 }
    })?;
    let dem = |file: &str| {
        format!("{SPHERE}\ndem_map = {{ path = \"{file}\", scale = 1000.0 }}\ndisplacement = true")
    };
    let out = vec![
        // Range.
        cut(s(
            "camera 1 m above the surface",
            scene(
                SPHERE,
                "",
                &looking([R + 1.0, 0.0, 0.0], [-1.0, 0.0, 0.2], [0.0, 0.0, -1.0]),
                sun_at(30.0),
                60.0,
                128,
            ),
        )),
        s(
            "camera at 1e12 m",
            scene(SPHERE, "", &look([1e12, 0.0, 0.0]), sun_at(30.0), 0.01, 128),
        ),
        // Phase.
        s("phase 0", wide(&look(far), sun_at(0.0))),
        s("phase 90", wide(&look(far), sun_at(90.0))),
        s("phase 179.9", wide(&look(far), sun_at(179.9))),
        s(
            "phase 180 (Sun behind the body)",
            wide(&look(far), sun_at(180.0)),
        ),
        s(
            "Sun and camera aligned (Sun behind the camera, same line)",
            wide(&look(far), [AU, 0.0, 0.0]),
        ),
        // The body against the FOV.
        cut(s(
            "body outside the FOV",
            wide(
                &looking(far, [-1.0, 2.0, 0.0], [0.0, 0.0, -1.0]),
                sun_at(30.0),
            ),
        )),
        cut(s(
            "body in a corner",
            wide(
                &looking(far, [-1.0, 0.42, 0.42], [0.0, 0.0, -1.0]),
                sun_at(30.0),
            ),
        )),
        cut(s(
            "body cut by one edge",
            wide(
                &looking(far, [-1.0, 0.55, 0.0], [0.0, 0.0, -1.0]),
                sun_at(30.0),
            ),
        )),
        cut(s(
            "body behind the camera",
            wide(
                &looking(far, [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
                sun_at(30.0),
            ),
        )),
        refused(s(
            "camera inside the body",
            wide(
                &looking([0.5 * R, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
                sun_at(30.0),
            ),
        )),
        // Poles and the limb.
        s(
            "pole-on view",
            wide(&look([0.0, 0.0, 3.0 * R]), sun_at(60.0)),
        ),
        s(
            "terminator through a pole",
            wide(&look([3.0 * R, 0.0, 0.0]), [0.0, AU, 0.0]),
        ),
        cut(s(
            "line of sight tangent to the limb",
            wide(
                &looking(far, [-(8.0f64).sqrt(), 1.0, 0.0], [0.0, 0.0, -1.0]),
                sun_at(30.0),
            ),
        )),
        // Poses no valid file can hold.
        Case {
            pose: Some(|p| p.body_from_camera = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0)),
            ..refused(s(
                "degenerate quaternion (0, 0, 0, 0)",
                wide(&look(far), sun_at(30.0)),
            ))
        },
        Case {
            pose: Some(|p| p.body_from_camera *= 2.0),
            ..refused(s(
                "non-unit quaternion (norm 2)",
                wide(&look(far), sun_at(30.0)),
            ))
        },
        Case {
            pose: Some(|p| p.camera_position_m = DVec3::new(f64::NAN, 0.0, 0.0)),
            ..refused(s("NaN camera position", wide(&look(far), sun_at(30.0))))
        },
        // Exposure.
        refused(s(
            "zero exposure",
            scene(SPHERE, "", &look(far), sun_at(30.0), 60.0, 128)
                .replace("exposure_s = 1e-4", "exposure_s = 0.0"),
        )),
        s(
            "huge exposure (1e6 s)",
            scene(SPHERE, "", &look(far), sun_at(30.0), 60.0, 128)
                .replace("exposure_s = 1e-4", "exposure_s = 1e6"),
        ),
        // Image size.
        s(
            "1 x 1 image",
            scene(SPHERE, "", &look(far), sun_at(30.0), 60.0, 1),
        ),
        Case {
            reference: false,
            ..s(
                "8192 x 8192 image",
                scene(SPHERE, "", &look(far), sun_at(30.0), 60.0, 8192),
            )
        },
        // Maps.
        refused(s(
            "albedo map with NaN and infinite cells",
            wide(&look(far), sun_at(30.0)).replace(
                "albedo = 0.12\n",
                &format!("albedo = 0.12\nalbedo_map = {{ path = \"{nan_map}\" }}\n"),
            ),
        )),
        s(
            "constant albedo map",
            wide(&look(far), sun_at(30.0)).replace(
                "albedo = 0.12\n",
                &format!("albedo = 0.12\nalbedo_map = {{ path = \"{constant}\" }}\n"),
            ),
        ),
        s(
            "flat DEM",
            scene(&dem(&flat), "", &look(far), sun_at(60.0), 60.0, 128),
        ),
        s(
            "vertical DEM step (50 km cliff)",
            scene(&dem(&cliff), "", &look(far), sun_at(60.0), 60.0, 128)
                + "\n[render]\nself_shadowing = \"ray_marching\"\n",
        ),
        s(
            "overhanging DEM step (300 km one-texel spike)",
            scene(&dem(&spike), "", &look(far), sun_at(60.0), 60.0, 128)
                + "\n[render]\nself_shadowing = \"ray_marching\"\n",
        ),
        // Hapke at its extremes.
        s(
            "Hapke w = 0.001",
            wide(&look(far), sun_at(30.0)).replace(SPHERE, &hapke(0.001, 0.07, 0.4)),
        ),
        s(
            "Hapke w = 0.999",
            wide(&look(far), sun_at(30.0)).replace(SPHERE, &hapke(0.999, 0.07, 0.4)),
        ),
        s(
            "Hapke h = 1e-6 (opposition spike)",
            wide(&look(far), sun_at(0.0)).replace(SPHERE, &hapke(0.3, 1e-6, 0.4)),
        ),
        s(
            "Hapke theta = 0",
            wide(&look(far), sun_at(60.0)).replace(SPHERE, &hapke(0.3, 0.07, 0.0)),
        ),
        s(
            "Hapke theta = 60 deg",
            wide(&look(far), sun_at(60.0)).replace(SPHERE, &hapke(0.3, 0.07, 60f64.to_radians())),
        ),
        // Shape.
        s(
            "ellipsoid of axis ratio 10",
            scene(
                "shape = \"ellipsoid\"\nsemi_axes_m = [1737400.0, 173740.0, 173740.0]\nbrdf = \"lambert\"\nalbedo = 0.12\nalbedo_type = \"normal\"",
                "",
                &look([0.0, 3.0 * R, 0.6 * R]),
                sun_at(60.0),
                60.0,
                128,
            ),
        ),
    ];
    Ok(out)
}

/// Runs one case: renders (and exposes) on its own thread, within `limit`.
fn run_case(case: Case, limit: Duration, dir: &Path) -> CaseReport {
    let name = case.name.to_string();
    let expected = if case.renders { "render" } else { "refusal" };
    let t0 = Instant::now();
    let report = |outcome, energy, error: Option<FrameError>, est, budgeted, ms| CaseReport {
        case: name.clone(),
        expected,
        budgeted,
        within_budget: error.as_ref().map(within_budget),
        outcome,
        energy,
        error,
        reference_est_total: est,
        ms,
    };
    // Each case's scene is written out, so a failing one can be rendered again by hand.
    let slug: String = case
        .name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let path = dir.join(format!("{slug}.toml"));
    let _ = std::fs::write(&path, &case.text);
    let file = path.display().to_string();
    let cfg: Config = match crate::config::parse(&case.text, &file) {
        Ok(mut c) => {
            if let Some(f) = case.pose {
                f(&mut c.pose);
            }
            c
        }
        Err(e) => {
            return report(
                Outcome::Refused {
                    error: e.to_string(),
                },
                None,
                None,
                None,
                None,
                0.0,
            );
        }
    };
    let (tx, rx) = mpsc::channel();
    let (whole, with_reference) = (case.whole, case.reference);
    std::thread::spawn(move || {
        let result = std::panic::catch_unwind(move || -> Result<_, String> {
            let mut renderer = Renderer::new(0).map_err(|e| e.to_string())?;
            let frame = renderer
                .render(&cfg.scene, &cfg.pose, &cfg.settings)
                .map_err(|e| e.to_string())?;
            let det = &cfg.scene.camera.detector;
            let size = (frame.width, frame.height);
            let (signal, dn) = cfg.scene.record(|b| frame.band(b), size, cfg.pose.frame_id);
            let bad_px = frame
                .pl
                .iter()
                .filter(|x| !(x.is_finite() && **x >= 0.0))
                .count()
                + signal.iter().filter(|x| !x.is_finite()).count();
            let max_dn = det.max_dn();
            let dn_over = dn.iter().filter(|&&d| d as f64 > max_dn as f64).count();
            let reference = if with_reference {
                let r = reference::render(&cfg.scene, &cfg.pose, &REFERENCE)
                    .map_err(|e| format!("the reference: {e}"))?;
                let e = frame_error(&frame.pl, &r.frame.pl, frame.width, frame.height);
                let budgeted = budgeted(&mut renderer, &cfg, &r.frame.pl)?;
                Some((e, r.report.est_error_total, budgeted))
            } else {
                None
            };
            Ok((frame.stats, bad_px, dn_over, reference))
        });
        let _ = tx.send(result);
    });
    let ms = || t0.elapsed().as_secs_f64() * 1e3;
    match rx.recv_timeout(limit) {
        Err(_) => report(
            Outcome::Defect {
                what: format!("no answer within {} s", limit.as_secs()),
            },
            None,
            None,
            None,
            None,
            ms(),
        ),
        Ok(Err(panic)) => {
            let what = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            report(
                Outcome::Defect {
                    what: format!("panic: {what}"),
                },
                None,
                None,
                None,
                None,
                ms(),
            )
        }
        Ok(Ok(Err(error))) => report(Outcome::Refused { error }, None, None, None, None, ms()),
        Ok(Ok(Ok((stats, bad_px, dn_over, reference)))) => {
            let cloud = stats.total_pl_points;
            let energy =
                (whole && cloud > 0.0).then(|| ((stats.total_pl_gridded - cloud) / cloud).abs());
            let outcome = if bad_px > 0 || dn_over > 0 {
                Outcome::Defect {
                    what: format!(
                        "{bad_px} non-finite or negative pixels, {dn_over} DN over range"
                    ),
                }
            } else if energy.is_some_and(|e| e > 1e-9) {
                Outcome::Defect {
                    what: format!("light not conserved: {:.2e}", energy.unwrap_or(0.0)),
                }
            } else {
                Outcome::Rendered
            };
            let (error, est, budgeted) = match reference {
                Some((e, est, b)) => (Some(e), Some(est), Some(b)),
                None => (None, None, None),
            };
            report(outcome, energy, error, est, budgeted, ms())
        }
    }
}

/// The frame of `cfg` as `fidelity = "budget"` plans it (the default budget, the shipped
/// model), against `reference`.
fn budgeted(renderer: &mut Renderer, cfg: &Config, reference: &[f64]) -> Result<Budgeted, String> {
    use crate::fidelity::budget::{Budget, ErrorModel, Planner};
    let model = ErrorModel::shipped().map_err(|e| e.to_string())?;
    let planner = Planner::new(&cfg.scene, &cfg.settings, Budget::default(), model);
    let t0 = Instant::now();
    let (plan, frame) = planner
        .render(&cfg.scene, &cfg.pose, |s| {
            renderer.render(&cfg.scene, &cfg.pose, s)
        })
        .map_err(|e| format!("under the budget: {e}"))?;
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let p = plan.predicted;
    Ok(Budgeted {
        points_per_pixel: plan.points_per_pixel,
        self_shadowing: format!("{:?}", plan.self_shadowing),
        map_filter: format!("{:?}", plan.map_filter),
        predicted: (p.median, p.p99, p.total),
        meets_budget: plan.meets_budget,
        outside_model: plan.outside_model,
        error: frame_error(&frame.pl, reference, frame.width, frame.height),
        ms,
    })
}

/// Runs every case (each within `limit`), writing its temporary maps under `work`.
pub fn run(
    work: &Path,
    limit: Duration,
    mut progress: impl FnMut(&CaseReport),
) -> Result<Vec<CaseReport>, AppError> {
    std::fs::create_dir_all(work)
        .map_err(|e| AppError::Stability(format!("{}: {e}", work.display())))?;
    let mut out = Vec::new();
    for case in cases(work)? {
        let r = run_case(case, limit, work);
        progress(&r);
        out.push(r);
    }
    Ok(out)
}

impl CaseReport {
    /// Whether the case did what it must: rendered without defect, or was refused.
    pub fn as_expected(&self) -> bool {
        match self.outcome {
            Outcome::Rendered => self.expected == "render",
            Outcome::Refused { .. } => self.expected == "refusal",
            Outcome::Defect { .. } => false,
        }
    }
}

/// The report as the Markdown page `docs/stability.md`; `work` (where the cases' scenes were
/// written) is shown as `<work>`, so the page does not change from run to run.
pub fn markdown(reports: &[CaseReport], work: &Path) -> String {
    let work = work.display().to_string();
    let mut s = String::from(
        "# Stability suite\n\n\
         Generated by `cargo run --release -- stability --out docs/stability.md` (the same cases\n\
         run as `tests/stability.rs`). Each case renders with the default settings, on its own\n\
         thread under a time limit; \"energy\" is the point cloud's light against the image's\n\
         (where the body is wholly in view: it must match to 1e-9), the errors are against the\n\
         converged reference (per lit pixel: median / p99; total), and \"budget\" says whether\n\
         they are within the default budget (median 1e-3, p99 3e-2, total 1e-4). A case either\n\
         renders or is refused with a typed error, as it must (\"expected\"); a defect (NaN,\n\
         panic, hang, light lost) or the other outcome fails the test.\n\n\
         | case | expected | outcome | energy | median | p99 | total | reference's estimate | budget | ms |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    let f = |x: Option<f64>| x.map_or("".to_string(), |v| format!("{v:.1e}"));
    for r in reports {
        let outcome = match &r.outcome {
            Outcome::Rendered => "rendered".to_string(),
            Outcome::Refused { error } => {
                format!(
                    "refused: {}",
                    error.replace(&work, "<work>").replace('|', "/")
                )
            }
            Outcome::Defect { what } => format!("**DEFECT**: {}", what.replace('|', "/")),
        };
        let e = r.error.as_ref();
        s += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.0} |\n",
            r.case,
            r.expected,
            outcome,
            f(r.energy),
            f(e.map(|e| e.median)),
            f(e.map(|e| e.p99)),
            f(e.map(|e| e.total)),
            f(r.reference_est_total),
            match r.within_budget {
                Some(true) => "within",
                Some(false) => "**over**",
                None => "",
            },
            r.ms
        );
    }
    s += "\n## Under the budget\n\n\
          Each case that renders, rendered again as `fidelity = \"budget\"` plans it (the\n\
          default budget, the shipped error model): the settings it chose (quadrangles per\n\
          pixel, 0 for a ray-cast frame; self-shadowing; map filter), the error it predicted\n\
          for itself and whether that meets the budget (\"said\"; outside the error model's\n\
          domain, why), and the error measured against the same reference. A frame is within\n\
          the budget or says it is not; one over it that said it met it (**silent**) fails\n\
          the test.\n\n\
          | case | settings | predicted median / p99 / total | said | measured median / p99 / total | budget | ms |\n\
          | --- | --- | --- | --- | --- | --- | --- |\n";
    for r in reports {
        let Some(b) = &r.budgeted else { continue };
        let (pm, pp, pt) = b.predicted;
        let e = &b.error;
        s += &format!(
            "| {} | {}, {}, {} | {:.1e} / {:.1e} / {:.1e} | {} | {:.1e} / {:.1e} / {:.1e} | {} | {:.0} |\n",
            r.case,
            b.points_per_pixel,
            b.self_shadowing,
            b.map_filter,
            pm,
            pp,
            pt,
            match (b.meets_budget, b.outside_model) {
                (true, _) => "meets".to_string(),
                (false, Some(why)) => format!("over: {why}"),
                (false, None) => "over".to_string(),
            },
            e.median,
            e.p99,
            e.total,
            match (b.within(), b.honest()) {
                (true, _) => "within",
                (false, true) => "over, as said",
                (false, false) => "**silent**",
            },
            b.ms
        );
    }
    s
}
