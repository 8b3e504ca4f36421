//! `optistim sweep SWEEP.toml --out DIR`: the speed-accuracy front. A grid of scenes x
//! settings; per setting the frame time (median of `repeats`, the settings interleaved so that
//! a machine's drift falls on all of them alike) and the error against the scene's converged
//! reference ([`crate::raycast::reference`]; total, median / p95 / p99 per lit pixel, SSIM:
//! [`crate::fidelity::metrics`]). Writes `sweep.csv`, and `front.png` / `front.svg`
//! ([`chart`]): time against each error, one column of panels per scene, the Pareto front
//! marked, the peer renderers of a scene beside it.
//!
//! The sweep file (see `sweeps/issue15.toml`):
//!
//! ```toml
//! repeats = 5                       # timed renders per setting
//! [reference]                       # the reference's settings (optional)
//! tolerance = 1e-6
//! max_depth = 10
//!
//! [[scene]]
//! name = "analytic"
//! file = "../config/analytic.toml"  # relative to the sweep file
//! trajectory = "../../shared/trajectories/nrho_2orbits.csv"   # optional: a pose of it,
//! pose = "closest"                  # "closest" | "farthest" | a row index
//! [scene.patch.camera]              # merged into the scene file's tables (optional)
//! resolution_px = [256, 256]
//! [[scene.peer]]                    # other renderers measured on this scene (optional)
//! name = "Mitsuba 3 LLVM, 128 spp"
//! time_s = 4.75
//! median = 5.4e-5
//! p99 = 1.8e-3
//! total = 5.6e-6
//!
//! [[setting]]
//! name = "default"
//! render = { preset = "default" }   # the frame's [render] table, over the scene's
//!                                   # patch.render (the scene file's own [render] is not used)
//! [[setting]]
//! name = "planned 1"
//! rung = 1.0                        # the fidelity planner's rung, with the shadows and map
//!                                   # filter it takes for each scene (Planner::planned)
//! rung_map_filter = "relief"        # optional: the rung read through this map filter
//! ```
//!
//! References are kept in `DIR/references/` under the SHA-256 of the scene text, the pose and
//! the reference's settings, so a sweep run again (more settings, more repeats) reuses them;
//! a scene without a `patch` is keyed by its file's own text, as `verify-budget` keys it, so
//! the references of a budget check can be copied into a sweep's folder and back.

pub mod chart;

use super::AppError;
use crate::config::Config;
use crate::fidelity::budget::{
    Budget, ErrorModel, Features, FigureModel, FitRow, FrameProbe, Planner,
};
use crate::fidelity::metrics::{FrameError, frame_error};
use crate::raycast::reference::{self, ReferenceMethod, ReferenceSettings};
use crate::render::{MapFilter, Renderer};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSweep {
    repeats: Option<usize>,
    reference: Option<RawReference>,
    scene: Vec<RawScene>,
    setting: Vec<RawSetting>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawReference {
    tolerance: Option<f64>,
    max_depth: Option<u32>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: String,
    file: String,
    trajectory: Option<String>,
    pose: Option<toml::Value>,
    patch: Option<toml::Table>,
    #[serde(default)]
    peer: Vec<Peer>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSetting {
    name: String,
    #[serde(default)]
    render: toml::Table,
    /// The fidelity planner's rung at this many quadrangles per pixel, with the shadows and
    /// the map filter the planner takes for each scene ([`Planner::planned`]), over
    /// `render`: the rows the error model is fitted on for frames with a DEM.
    rung: Option<f64>,
    /// The rung's map filter where it is not the one the planner takes first for the scene:
    /// "relief" for the pixels' own relief reads the planner falls back on where the
    /// quadrangles' ladder does not meet the budget ([`Planner::plan`]).
    rung_map_filter: Option<MapFilter>,
}

/// Another renderer measured on a scene (quoted in the sweep file with its source).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Peer {
    pub name: String,
    pub time_s: f64,
    pub median: Option<f64>,
    pub p99: Option<f64>,
    pub total: Option<f64>,
}

/// One row of `sweep.csv`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub scene: String,
    pub setting: String,
    /// The setting's `[render]` keys, as TOML.
    pub render: String,
    pub time_ms_median: f64,
    pub time_ms_min: f64,
    pub err_total: f64,
    pub err_median: f64,
    pub err_p95: f64,
    pub err_p99: f64,
    pub ssim: f64,
    pub lit_px: usize,
    pub points_kept: usize,
    pub surface_samples: usize,
    /// On the scene's Pareto front: no other setting is as fast and as accurate on every
    /// figure, and better on one.
    pub front: bool,
    /// The reference's own error bound: total, and p99 per lit pixel.
    pub ref_est_total: f64,
    pub ref_est_p99: f64,
    /// The reference's estimate with its cells' signs kept
    /// ([`CachedReference::signed_total`]): what `verify-budget` judges a figure by. NaN in
    /// the CSVs written before the columns existed.
    #[serde(default = "nan")]
    pub ref_signed_total: f64,
    #[serde(default = "nan")]
    pub ref_signed_p99: f64,
    /// Why the setting could not render this scene (then the figures are NaN).
    pub failure: String,
    /// Quadrangles per pixel (NaN for a fixed count), and whether the setting is that rung of
    /// the fidelity planner's ladder ([`crate::fidelity::budget::Planner::rung`]): the rows
    /// `--fit` fits the error model on.
    pub points_per_px: f64,
    pub ladder: bool,
    /// The setting's map filter ("pixel" in the CSVs written before the column existed, none
    /// of whose ladder rows read the relief per pixel): under "relief" the model reads the
    /// map's texture alone ([`Features::modelled`]).
    #[serde(default = "pixel")]
    pub map_filter: MapFilter,
    /// What the frame shows ([`crate::fidelity::budget::Features`]).
    pub f_radius_px: f64,
    pub f_lit_px: f64,
    pub f_edge_px: f64,
    pub f_phase_deg: f64,
    pub f_footprint_texels: f64,
    pub f_texture: f64,
    pub f_shadow_share: f64,
    /// 0 in the CSVs written before the feature existed, whose bodies are all Lambertian.
    #[serde(default)]
    pub f_nonlinear_albedo: f64,
    /// 0 in the CSVs written before the feature existed.
    #[serde(default)]
    pub f_relief_texture: f64,
    /// 0 in the CSVs written before the feature existed, none of whose frames had a DEM.
    #[serde(default)]
    pub f_relief: f64,
    /// The frame's own estimate of its reads' p99 under `map_filter = "relief"`
    /// ([`crate::render::FrameStats::relief_read_p99`]), beside the measured `err_p99`; NaN
    /// for other settings and in older CSVs.
    #[serde(default = "nan")]
    pub est_relief_p99: f64,
    /// The setting's `render.relief_refine` (absent in the CSVs written before the column
    /// existed: [`Row::relief_refine`] reads it from `render`).
    #[serde(default)]
    pub relief_refine: Option<u32>,
    /// The median of the same estimate ([`crate::render::FrameStats::relief_read_median`]),
    /// beside the measured `err_median`; NaN for other settings and in older CSVs.
    #[serde(default = "nan")]
    pub est_relief_median: f64,
    /// The same estimate, signed and summed over the frame
    /// ([`crate::render::FrameStats::relief_read_total`]), beside the measured `err_total`;
    /// NaN for other settings and in older CSVs.
    #[serde(default = "nan")]
    pub est_relief_total: f64,
}

pub(crate) fn nan() -> f64 {
    f64::NAN
}

fn pixel() -> MapFilter {
    MapFilter::Pixel
}

impl Row {
    /// The frame's features, as the planner computed them.
    pub fn features(&self) -> Features {
        Features {
            radius_px: self.f_radius_px,
            lit_px: self.f_lit_px,
            edge_px: self.f_edge_px,
            phase_deg: self.f_phase_deg,
            range_m: f64::NAN,
            footprint_texels: self.f_footprint_texels,
            texture: self.f_texture,
            shadow_share: self.f_shadow_share,
            nonlinear_albedo: self.f_nonlinear_albedo,
            relief_texture: self.f_relief_texture,
            relief: self.f_relief,
            relief_per_pixel: 0.0,
            relief_refine: 1.0,
        }
    }

    /// The features the error model reads for this row's setting ([`Features::modelled`],
    /// [`Features::refined`]).
    pub fn modelled_features(&self) -> Features {
        self.features()
            .modelled(self.map_filter)
            .refined(self.relief_refine())
    }

    /// The setting's `render.relief_refine`: the column, or in the CSVs written before it
    /// existed, the `render` keys' (1 where they do not set it).
    pub fn relief_refine(&self) -> u32 {
        self.relief_refine.unwrap_or_else(|| {
            self.render
                .split(';')
                .filter_map(|kv| kv.split_once('='))
                .find(|(k, _)| k.trim() == "relief_refine")
                .and_then(|(_, v)| v.trim().parse().ok())
                .unwrap_or(1)
        })
    }
}

/// Fits the planner's error model on the ladder rows of one or more `sweep.csv` files; also
/// returns the rows, for [`margins_set_by`].
pub fn fit_csv(csv_paths: &[impl AsRef<Path>]) -> Result<(ErrorModel, Vec<Row>), AppError> {
    let rows = read_csv(csv_paths)?;
    Ok((fit(&rows)?, rows))
}

/// The rows of one or more `sweep.csv` files, in order.
pub fn read_csv(csv_paths: &[impl AsRef<Path>]) -> Result<Vec<Row>, AppError> {
    let mut rows: Vec<Row> = Vec::new();
    for csv_path in csv_paths {
        let csv_path = csv_path.as_ref();
        let mut r = csv::Reader::from_path(csv_path).map_err(|e| bad(csv_path, e))?;
        for row in r.deserialize() {
            rows.push(row.map_err(|e| bad(csv_path, e))?);
        }
    }
    Ok(rows)
}

/// The sweep frame that sets one of the error model's margins ([`margins_set_by`]).
#[derive(Clone, Debug, Serialize)]
pub struct MarginSetBy {
    /// "median", "p99" or "total".
    pub figure: &'static str,
    /// The relief margin (frames with a DEM) rather than the plain one.
    pub relief: bool,
    /// The model file's field of the margin: `margin`, or the relief's of one kind
    /// ([`crate::fidelity::budget::ReliefKind::field`]).
    pub field: &'static str,
    pub margin: f64,
    pub scene: String,
    pub setting: String,
    /// The frame's measured error, and its share of the model's prediction (1 for the frame
    /// that sets the margin, the largest over the rows).
    pub measured: f64,
    pub share: f64,
}

impl std::fmt::Display for MarginSetBy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {} {:.3}: {} / {} (measured {:.3e})",
            self.figure, self.field, self.margin, self.scene, self.setting, self.measured
        )
    }
}

/// For each figure's margin (and relief margin), the sweep frame that sets it: of the rows
/// the fit used, the one whose measured error is the largest share of the model's
/// prediction (1, the margin being the bound on every row). The model file names them, so
/// that a margin that grows after a sweep points at the frame to look at.
pub fn margins_set_by(m: &ErrorModel, rows: &[Row]) -> Vec<MarginSetBy> {
    type Figure<'a> = (&'static str, &'a FigureModel, fn(&Row) -> f64);
    let figures: [Figure; 3] = [
        ("median", &m.median, |r| r.err_median),
        ("p99", &m.p99, |r| r.err_p99),
        ("total", &m.total, |r| r.err_total),
    ];
    let mut set_by = Vec::new();
    for (figure, model, get) in figures {
        use crate::fidelity::budget::ReliefKind;
        let mut margins = vec![(false, None, "margin", Some(model.margin))];
        for kind in ReliefKind::ALL {
            let own = model.relief_margin_of(kind);
            if kind == ReliefKind::Quadrangles || own.is_some() {
                margins.push((true, Some(kind), kind.field(), own));
            }
        }
        for (relief, kind, field, margin) in margins {
            let Some(margin) = margin else { continue };
            let binding = rows
                .iter()
                .filter(|r| r.ladder && r.failure.is_empty() && (r.f_relief > 0.0) == relief)
                .filter(|r| {
                    // Where a kind has no margin of its own, `relief_margin` bounds it.
                    kind.is_none_or(|k| {
                        model.bounding_kind(r.points_per_px, &r.modelled_features()) == k
                    })
                })
                .filter(|r| get(r).is_finite() && get(r) > 0.0 && r.points_per_px > 0.0)
                .map(|r| {
                    let predicted = model.predict(r.points_per_px, &r.modelled_features());
                    (get(r) / predicted, r)
                })
                .max_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((share, r)) = binding {
                set_by.push(MarginSetBy {
                    figure,
                    relief,
                    field,
                    margin,
                    scene: r.scene.clone(),
                    setting: r.setting.clone(),
                    measured: get(r),
                    share,
                });
            }
        }
    }
    set_by
}

/// The model file's text: a header saying how it was made and which of the sweep's `rows`
/// set its margins ([`margins_set_by`]), then the model.
pub fn model_text(m: &ErrorModel, how: &str, rows: &[Row]) -> String {
    let set_by: String = margins_set_by(m, rows)
        .iter()
        .map(|l| format!("#   {l}\n"))
        .collect();
    let kinds: String = crate::fidelity::budget::Regressors::ALL
        .iter()
        .map(|(_, formula)| format!("#   {formula}\n"))
        .collect();
    format!(
        "# The fidelity planner's error model (src/fidelity/budget.rs), fitted by\n\
         #   {how}\n\
         # on {} ladder frames. Each figure is e = margin * sum over its terms of exp(k . x), x one of\n\
         {kinds}\
         # (p quadrangles per pixel, T the texture, E the share of lit pixels on the limb or terminator,\n\
         # H 1 where the albedo enters the reflectance non-linearly, as Hapke's w; with a DEM, S the\n\
         # share of the lit surface under its steep slopes' shadows, R its shading between pixels\n\
         # where the quadrangles carry it, P 1 where each pixel reads it, k how much more finely its\n\
         # reads may get, relief_refine: each figure's relief term and relief_margin are fitted on\n\
         # the frames with a DEM alone, relief_margin_reads and relief_margin_coarse\n\
         # on those whose pixels read it from 1 quadrangle per pixel up and below).\n\
         # The frames that set the margins (their measured error is the model's prediction):\n\
         {set_by}\n{}",
        m.frames,
        m.to_toml()
    )
}

/// Fits the planner's error model on the ladder rows of `rows` that rendered.
pub fn fit(rows: &[Row]) -> Result<ErrorModel, AppError> {
    let fit_rows: Vec<FitRow> = rows
        .iter()
        .filter(|r| r.ladder && r.failure.is_empty())
        .map(|r| FitRow {
            points_per_px: r.points_per_px,
            features: r.modelled_features(),
            median: r.err_median,
            p99: r.err_p99,
            total: r.err_total,
            relief_read_p99: r.est_relief_p99,
        })
        .collect();
    ErrorModel::fit(&fit_rows).map_err(|e| AppError::Sweep(e.to_string()))
}

#[derive(Debug, Serialize)]
pub struct SweepReport {
    /// The error model fitted (with `--fit`).
    pub model: Option<ErrorModel>,
    pub rows: usize,
    pub scenes: Vec<SceneSummary>,
    pub csv: String,
    pub charts: Vec<String>,
}

#[derive(Debug, Serialize)]
pub struct SceneSummary {
    pub name: String,
    pub width: usize,
    pub height: usize,
    pub phase_deg: f64,
    pub range_m: f64,
    pub reference_s: f64,
    pub reference_reused: bool,
    pub front: Vec<String>,
}

/// A scene of the sweep, ready: its text (with the patch), config and peers.
pub struct SweepScene {
    pub name: String,
    /// The scene file's path (relative map paths are found from it).
    pub label: String,
    pub text: String,
    /// The `[render]` keys every setting starts from (the scene's `patch.render`).
    pub base_render: toml::Table,
    pub config: Config,
    pub peers: Vec<Peer>,
}

fn bad(file: &Path, what: impl std::fmt::Display) -> AppError {
    AppError::Sweep(format!("{}: {what}", file.display()))
}

/// Reads the scene of `raw`, patched, with its pose (from a trajectory when named).
fn load_scene(dir: &Path, raw: &RawScene, sweep_file: &Path) -> Result<SweepScene, AppError> {
    let path = dir.join(&raw.file);
    let text = std::fs::read_to_string(&path).map_err(|e| bad(&path, e))?;
    // Unpatched, the file's own text: the references it keys are those `verify-budget`
    // caches for the same file, pose and settings.
    let text = match &raw.patch {
        Some(p) => {
            let mut table: toml::Table = toml::from_str(&text).map_err(|e| bad(&path, e))?;
            crate::config::merge_toml(&mut table, p);
            toml::to_string(&table).map_err(|e| bad(sweep_file, e))?
        }
        None => text,
    };
    let label = path.display().to_string();
    let mut config = crate::config::parse(&text, &label)?;
    if let Some(t) = &raw.trajectory {
        let poses = crate::trajectory::read(&dir.join(t))?;
        let range = |i: &usize| poses[*i].1.camera_position_m.length();
        let index = match &raw.pose {
            Some(toml::Value::Integer(i)) if (*i as usize) < poses.len() => *i as usize,
            Some(toml::Value::String(s)) if s == "closest" => {
                { (0..poses.len()).min_by(|a, b| range(a).total_cmp(&range(b))) }.unwrap_or(0)
            }
            Some(toml::Value::String(s)) if s == "farthest" => {
                { (0..poses.len()).max_by(|a, b| range(a).total_cmp(&range(b))) }.unwrap_or(0)
            }
            other => {
                return Err(bad(
                    sweep_file,
                    format!(
                        "scene {:?}: pose = {other:?}: \"closest\", \"farthest\" or a row index below {}",
                        raw.name,
                        poses.len()
                    ),
                ));
            }
        };
        config.pose = poses[index].1;
    }
    let base_render = match raw.patch.as_ref().and_then(|p| p.get("render")) {
        Some(toml::Value::Table(t)) => t.clone(),
        _ => toml::Table::new(),
    };
    Ok(SweepScene {
        name: raw.name.clone(),
        label,
        text,
        base_render,
        config,
        peers: raw.peer.clone(),
    })
}

/// The scene's text with its `[render]` table replaced by the setting's keys over the scene's
/// `patch.render` (the scene file's own `[render]` is not used: every setting starts from the
/// same defaults, whatever preset the file names), validated.
fn with_setting(scene: &SweepScene, render: &toml::Table) -> Result<Config, AppError> {
    let mut table: toml::Table = toml::from_str(&scene.text)
        .map_err(|e| AppError::Sweep(format!("scene {:?}: {e}", scene.name)))?;
    let mut base = scene.base_render.clone();
    crate::config::merge_toml(&mut base, render);
    table.insert("render".into(), toml::Value::Table(base));
    let text = toml::to_string(&table).map_err(|e| AppError::Sweep(e.to_string()))?;
    let mut cfg = crate::config::parse(&text, &scene.label)?;
    cfg.pose = scene.config.pose;
    Ok(cfg)
}

/// The reference of `scene`, from the cache in `dir` or rendered (and cached).
fn reference_of(
    scene: &SweepScene,
    settings: &ReferenceSettings,
    dir: &Path,
) -> Result<CachedReference, AppError> {
    let c = &scene.config;
    cached_reference(
        &scene.text,
        &c.scene,
        &c.pose,
        settings,
        ReferenceMethod::Auto,
        dir,
    )
}

/// What the reference computes, in the cache's key: raised whenever a change of the reference
/// changes its images, so that no cache made before is read as its image. 2 and 3: a DEM that
/// tilts the normals only weighs the light by the DEM normal's `cos(theta_r)` (Eq. 37) and
/// hides what the terrain hides from the camera (Eq. 33). 4: cells near an edge whose rays
/// agree ask their corners too (`corner_depth`), which finds a sub-pixel lune's light. 5: a
/// DEM that tilts the normals only is dark past the shape's own terminator, where a normal
/// leaning towards the Sun had lit it. 6: the terrain's shadow rays are tested at the DEM's
/// creases too, where a grazing ray dips below a ridge between two of its shortest steps.
/// 7: the cells near an edge whose rays agree are read by a lattice
/// (`ReferenceSettings::lattice_per_px`), which does not lose the slivers between the rays.
/// 8: a pixel around which the Sun alone keeps some first rays dark and the camera alone
/// others is near an edge (`Tracer::dark_because`): the slivers lit between the two were lost
/// from whole pixels. 9: so is a pixel whose first rays or a neighbour's are lit where
/// another pixel's around it are dark: an edge between two pixels' rays was lost. 10: a pixel
/// the limb cuts where a DEM tilts the normals is read by lattices warped at the limb
/// (`ReferenceSettings::limb_lattice_max`), where the light grows as the inverse square root
/// of the distance to it.
pub(crate) const REFERENCE_MODEL: u32 = 10;

/// [`REFERENCE_MODEL`] for the exact mesh reference ([`crate::raycast::exact`]).
const EXACT_MODEL: u32 = 1;

/// A reference image and what it says of itself ([`cached_reference`]).
pub struct CachedReference {
    pub pl: Vec<f64>,
    /// What it took to render [s].
    pub seconds: f64,
    /// Its own error bound: total and p99 per lit pixel, relative
    /// ([`reference::ReferenceReport::est_error_total`]).
    pub bound_total: f64,
    pub bound_p99: f64,
    /// Its estimate with the cells' signs kept
    /// ([`reference::ReferenceReport::signed_error_total`]); the bound's in a cache written
    /// before the estimate was kept.
    pub signed_total: f64,
    pub signed_p99: f64,
    /// Read from the cache.
    pub reused: bool,
}

impl CachedReference {
    /// From a cache file's head (five values, or the three written before the signed
    /// estimate, whose bound then stands for it) and its image.
    fn of(head: &[f64], pl: Vec<f64>, reused: bool) -> CachedReference {
        let signed = if head.len() == 5 {
            [head[3], head[4]]
        } else {
            [head[1], head[2]]
        };
        CachedReference {
            pl,
            seconds: head[0],
            bound_total: head[1],
            bound_p99: head[2],
            signed_total: signed[0],
            signed_p99: signed[1],
            reused,
        }
    }
}

/// The reference of `scene` from `pose` by `method`, from the cache in `dir` (keyed by the
/// SHA-256 of `text`, the scene file's text, the pose, and the cubature's settings and
/// [`REFERENCE_MODEL`] or the exact reference's [`EXACT_MODEL`]) or rendered and cached.
/// A cache file is the image after a head of five little-endian f64: seconds, the bound's
/// total and p99, the signed estimate's total and p99 (three in the files written before
/// the signed estimate: the bound then stands for it).
pub fn cached_reference(
    text: &str,
    scene: &crate::scene::Scene,
    p: &crate::scene::Pose,
    settings: &ReferenceSettings,
    method: ReferenceMethod,
    dir: &Path,
) -> Result<CachedReference, AppError> {
    let method = method.resolve(scene, p);
    let how = if method == ReferenceMethod::Exact {
        format!("exact model {EXACT_MODEL}")
    } else {
        format!(
            "{:?}{}",
            settings,
            // Model 1 (no suffix) keeps the caches made before the model was numbered.
            if REFERENCE_MODEL == 1 {
                String::new()
            } else {
                format!(" model {REFERENCE_MODEL}")
            }
        )
    };
    let key = crate::io::sha256_hex(
        format!(
            "{}\n{:?} {:?} {:?}\n{}",
            text, p.camera_position_m, p.body_from_camera, p.sun_position_m, how,
        )
        .as_bytes(),
    );
    let file = dir.join(format!("{}.f64", &key[..16]));
    let n = {
        let i = &scene.camera.intrinsics;
        (i.width_px * i.height_px) as usize
    };
    if let Ok(bytes) = std::fs::read(&file)
        && let Some(head) = [5, 3].into_iter().find(|k| bytes.len() == 8 * (n + k))
    {
        let v: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect();
        return Ok(CachedReference::of(&v[..head], v[head..].to_vec(), true));
    }
    let r = reference::render_by(scene, p, settings, method)?;
    let head = [
        r.report.seconds,
        r.report.est_error_total,
        r.report.est_error_p99,
        r.report.signed_error_total,
        r.report.signed_error_p99,
    ];
    std::fs::create_dir_all(dir).map_err(|e| bad(dir, e))?;
    let bytes: Vec<u8> = head
        .iter()
        .chain(&r.frame.pl)
        .flat_map(|x| x.to_le_bytes())
        .collect();
    std::fs::write(&file, bytes).map_err(|e| bad(&file, e))?;
    Ok(CachedReference::of(&head, r.frame.pl, false))
}

/// Marks the rows of one scene that are on its Pareto front (time and every error figure).
pub fn mark_front(rows: &mut [Row]) {
    let err = |r: &Row| FrameError {
        total: r.err_total,
        median: r.err_median,
        p95: r.err_p95,
        p99: r.err_p99,
        ssim: r.ssim,
        lit_px: 0,
    };
    let ok: Vec<bool> = rows.iter().map(|r| r.failure.is_empty()).collect();
    let front: Vec<bool> = (0..rows.len())
        .map(|a| {
            ok[a]
                && !(0..rows.len()).any(|b| {
                    b != a
                        && ok[b]
                        && rows[b].time_ms_median <= rows[a].time_ms_median
                        && err(&rows[b]).no_worse_than(&err(&rows[a]))
                        && (rows[b].time_ms_median < rows[a].time_ms_median
                            || err(&rows[b]) != err(&rows[a]))
                })
        })
        .collect();
    for (r, f) in rows.iter_mut().zip(front) {
        r.front = f;
    }
}

/// Runs the sweep of `file` and writes its outputs into `out`; `progress` hears each line.
pub fn run(
    file: &Path,
    out: &Path,
    fit_to: Option<&Path>,
    mut progress: impl FnMut(&str),
) -> Result<SweepReport, AppError> {
    let text = std::fs::read_to_string(file).map_err(|e| bad(file, e))?;
    let raw: RawSweep = toml::from_str(&text).map_err(|e| bad(file, e))?;
    let dir = file.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(out).map_err(|e| bad(out, e))?;
    let repeats = raw.repeats.unwrap_or(5).max(1);
    let rr = raw.reference.unwrap_or_default();
    let ref_settings = ReferenceSettings {
        tolerance: rr.tolerance.unwrap_or(1e-6),
        max_depth: rr.max_depth.unwrap_or(10),
        ..Default::default()
    };
    let mut rows = Vec::new();
    let mut scenes = Vec::new();
    let mut panels = Vec::new();
    for raw_scene in &raw.scene {
        let scene = load_scene(dir, raw_scene, file)?;
        let intr = &scene.config.scene.camera.intrinsics;
        let (w, h) = (intr.width_px as usize, intr.height_px as usize);
        progress(&format!("{}: reference ...", scene.name));
        let CachedReference {
            pl: reference,
            seconds: ref_s,
            bound_total: ref_total,
            bound_p99: ref_p99,
            signed_total,
            signed_p99,
            reused,
        } = reference_of(&scene, &ref_settings, &out.join("references"))?;
        progress(&format!(
            "{}: reference {:.1} s{} (its error bound: total {ref_total:.1e}, p99 {ref_p99:.1e}; \
             with the signs kept: {signed_total:.1e}, {signed_p99:.1e})",
            scene.name,
            ref_s,
            if reused { ", reused" } else { "" }
        ));
        // Each setting's config, or why it cannot render this scene.
        let c = &scene.config;
        let features = FrameProbe::new(&c.scene).features(&c.scene, &c.pose);
        // The planner of the scene, for the settings that are its rungs (`rung = p`).
        let planner = if raw.setting.iter().any(|s| s.rung.is_some()) {
            let model = ErrorModel::shipped().map_err(|e| AppError::Sweep(e.to_string()))?;
            Some(Planner::new(
                &c.scene,
                &c.settings,
                Budget::default(),
                model,
            ))
        } else {
            None
        };
        let configs: Vec<Result<Config, String>> = raw
            .setting
            .iter()
            .map(|s| {
                let mut cfg = with_setting(&scene, &s.render).map_err(|e| e.to_string())?;
                if let (Some(p), Some(planner)) = (s.rung, &planner) {
                    cfg.settings = planner.planned(&cfg.settings, &features, p, s.rung_map_filter);
                }
                Ok(cfg)
            })
            .collect();
        let mut renderer = Renderer::new(scene.config.settings.threads)?;
        let mut times = vec![Vec::new(); configs.len()];
        let mut frames: Vec<Option<Result<crate::render::Frame, String>>> =
            vec![None; configs.len()];
        for _ in 0..repeats {
            for (k, cfg) in configs.iter().enumerate() {
                let Ok(cfg) = cfg else { continue };
                if matches!(frames[k], Some(Err(_))) {
                    continue;
                }
                let t0 = Instant::now();
                let f = renderer.render(&cfg.scene, &cfg.pose, &cfg.settings);
                times[k].push(t0.elapsed().as_secs_f64() * 1e3);
                if frames[k].is_none() || f.is_err() {
                    frames[k] = Some(f.map_err(|e| e.to_string()));
                }
            }
        }
        let mut scene_rows = Vec::new();
        for (k, s) in raw.setting.iter().enumerate() {
            let render = toml::to_string(&s.render)
                .unwrap_or_default()
                .trim()
                .replace('\n', "; ");
            let failure = match (&configs[k], &frames[k]) {
                (Err(e), _) | (_, Some(Err(e))) => e.clone(),
                _ => String::new(),
            };
            let [est_relief_median, est_relief_p99, est_relief_total] = match &frames[k] {
                Some(Ok(f)) => f.stats.relief_reads_or_nan(),
                _ => [f64::NAN; 3],
            };
            let (e, kept, samples) = match &frames[k] {
                Some(Ok(f)) => (
                    frame_error(&f.pl, &reference, w, h),
                    f.stats.points_kept,
                    f.stats.surface_samples,
                ),
                _ => (
                    FrameError {
                        total: f64::NAN,
                        median: f64::NAN,
                        p95: f64::NAN,
                        p99: f64::NAN,
                        ssim: f64::NAN,
                        lit_px: 0,
                    },
                    0,
                    0,
                ),
            };
            let [t_med, t_min] = if failure.is_empty() {
                crate::stats::quantiles(&mut times[k], [0.5, 0.0])
            } else {
                [f64::NAN; 2]
            };
            let (points_per_px, ladder) = match &configs[k] {
                Ok(c) => match c.settings.points {
                    crate::render::PointBudget::PerPixel(p) => (
                        p,
                        s.rung.is_some() || c.settings == Planner::rung(&c.settings, p),
                    ),
                    _ => (f64::NAN, false),
                },
                Err(_) => (f64::NAN, false),
            };
            let map_filter = configs[k]
                .as_ref()
                .map_or(MapFilter::Pixel, |c| c.settings.map_filter);
            let relief_refine = configs[k].as_ref().ok().map(|c| c.settings.relief_refine);
            let row = Row {
                points_per_px,
                ladder,
                map_filter,
                f_radius_px: features.radius_px,
                f_lit_px: features.lit_px,
                f_edge_px: features.edge_px,
                f_phase_deg: features.phase_deg,
                f_footprint_texels: features.footprint_texels,
                f_texture: features.texture,
                f_shadow_share: features.shadow_share,
                f_nonlinear_albedo: features.nonlinear_albedo,
                f_relief_texture: features.relief_texture,
                f_relief: features.relief,
                est_relief_p99,
                relief_refine,
                est_relief_median,
                est_relief_total,
                scene: scene.name.clone(),
                setting: s.name.clone(),
                render,
                time_ms_median: t_med,
                time_ms_min: t_min,
                err_total: e.total,
                err_median: e.median,
                err_p95: e.p95,
                err_p99: e.p99,
                ssim: e.ssim,
                lit_px: e.lit_px,
                points_kept: kept,
                surface_samples: samples,
                front: false,
                ref_est_total: ref_total,
                ref_est_p99: ref_p99,
                ref_signed_total: signed_total,
                ref_signed_p99: signed_p99,
                failure,
            };
            progress(&format!(
                "{}: {:24} {:9.2} ms  total {:.2e}  median {:.2e}  p95 {:.2e}  p99 {:.2e}  ssim {:.6}{}{}",
                row.scene,
                row.setting,
                row.time_ms_median,
                row.err_total,
                row.err_median,
                row.err_p95,
                row.err_p99,
                row.ssim,
                if row.est_relief_p99.is_nan() {
                    String::new()
                } else {
                    format!(
                        "  (its reads' own estimate: median {:.2e}, p99 {:.2e}, total {:+.2e})",
                        row.est_relief_median, row.est_relief_p99, row.est_relief_total
                    )
                },
                if row.failure.is_empty() {
                    String::new()
                } else {
                    format!("  ({})", row.failure)
                }
            ));
            scene_rows.push(row);
        }
        mark_front(&mut scene_rows);
        scenes.push(SceneSummary {
            name: scene.name.clone(),
            width: w,
            height: h,
            phase_deg: scene
                .config
                .pose
                .sun_position_m
                .angle_between(scene.config.pose.camera_position_m)
                .to_degrees(),
            range_m: scene.config.pose.camera_position_m.length(),
            reference_s: ref_s,
            reference_reused: reused,
            front: scene_rows
                .iter()
                .filter(|r| r.front)
                .map(|r| r.setting.clone())
                .collect(),
        });
        panels.push(chart::Panel {
            scene: scene.name.clone(),
            rows: scene_rows.clone(),
            peers: scene.peers.clone(),
        });
        rows.extend(scene_rows);
    }
    let csv_path = out.join("sweep.csv");
    let mut w = csv::Writer::from_path(&csv_path).map_err(|e| bad(&csv_path, e))?;
    for r in &rows {
        w.serialize(r).map_err(|e| bad(&csv_path, e))?;
    }
    w.flush().map_err(|e| bad(&csv_path, e))?;
    let charts: Vec<PathBuf> = vec![out.join("front.png"), out.join("front.svg")];
    chart::draw(&panels, &charts[0], &charts[1]).map_err(|e| bad(&charts[0], e))?;
    let model = match fit_to {
        Some(path) => {
            let m = fit(&rows)?;
            let text = model_text(
                &m,
                &format!("optistim sweep {} --fit {}", file.display(), path.display()),
                &rows,
            );
            std::fs::write(path, text).map_err(|e| bad(path, e))?;
            Some(m)
        }
        None => None,
    };
    Ok(SweepReport {
        model,
        rows: rows.len(),
        scenes,
        csv: csv_path.display().to_string(),
        charts: charts.iter().map(|p| p.display().to_string()).collect(),
    })
}
