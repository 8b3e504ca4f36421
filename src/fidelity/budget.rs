//! Error-budgeted fidelity (`[render] fidelity = "budget"`): per frame, the cheapest settings
//! predicted to keep the frame's error (against the converged reference,
//! [`super::metrics`]) inside a [`Budget`], from what the frame shows ([`Features`]), never
//! from the scene's name.
//!
//! The prediction is an [`ErrorModel`] fitted by the sweep (`optistim sweep ... --fit`,
//! `optistim fit-model`): for each figure (median and 99th percentile per lit pixel, total)
//! a sum of terms,
//!
//! ```text
//! e(p) = margin * sum_t exp(k_t . x_t)
//! edge:        x = (1, ln p, ln(max(E - 0.01, 0) + 1e-4), ln(sin(g / 2) + 0.05))
//! inside:      x = (1, ln p, ln(T + 1e-4), ln p ln(T + 1e-4))
//! reflectance: x = (1, ln p, ln(H + 1e-6))
//! relief:      x = (1, ln p, ln(S + 1e-3), ln(R + 1e-3), ln(sin(g / 2) + 0.05), P, P ln p,
//!                   P ln k)
//!              (frames with a DEM alone)
//! ```
//!
//! with `p` the quadrangles per pixel, `T` the texture (the relative change of albedo and of
//! the DEM's shading between neighbouring pixels), `E` the share of lit pixels on the limb or
//! the terminator, `g` the phase and `H` 1 where the albedo enters the reflectance
//! non-linearly ([`Features::nonlinear_albedo`]). The limb's and terminator's pixels fall
//! steeply with `p` and dominate the 99th percentile once they are more than 1 % of the lit
//! pixels; then the inside's floor remains (the map read over each pixel's footprint leaves a
//! textured frame an error that more quadrangles do not reduce, while a plain body's falls
//! with `p`), and Hapke's ratio adds its own. One linear term read the steep edge and the
//! flat floor as one slope and needed a margin of 37 on the p99; the sum needs 4.5. The terms
//! are fitted by least squares in logarithms (Levenberg-Marquardt, `fit_terms`), and `margin`
//! is the largest ratio of measured to modelled error over the sweep's frames, so that the
//! model is an upper bound on every frame it was fitted on.
//!
//! A frame with a DEM adds the relief term (`S` the share of the lit surface where the Sun or
//! the camera is lower than the DEM's steep slopes, `R` the DEM's shading between pixels where
//! the quadrangles carry it, 0 where each pixel reads it, `P` 1 where each pixel reads it,
//! [`Features::modelled`], and `k` how much more finely a pixel's reads may get where they
//! disagree, [`Features::refined`]). It is fitted on the sweep's frames with a DEM alone
//! (`sweeps/budget_dem.toml`: the planner's own rungs, `rung = p`) over the three terms held
//! fixed, and those frames get their own margins, one for each thing that carries the
//! relief ([`ReliefKind`]: the quadrangles, each pixel's reads from one quadrangle per pixel
//! up, and below it; [`FigureModel::margin_at`]): the model of every frame without a DEM is
//! what it was without them.
//!
//! The planner predicts a ladder of settings ([`Planner::rung`]: 1/16 to 16 quadrangles per
//! pixel, the midpoint rule, more boundary nodes at the top) and takes the cheapest rung whose
//! prediction meets the budget. Where each pixel reads the relief, the ladder is predicted
//! again at each refinement of those reads (`relief_refine` 1, 2, 4, 8: `k` in the relief
//! term, [`Features::relief_refine`]); where a pixel is finer than that and the relief casts
//! shadows, both the quadrangles' ladder and those reads' are candidates, and what each
//! costs ([`relative_cost`]: marched shadows on the quadrangles, the reads at their
//! refinement) decides between them. It models
//! no more than the frame needs: shadows are cast only when the Sun is low enough over enough
//! of the lit surface for the relief to hide it ([`Planner::shadowing`]), and the albedo map
//! is read over each pixel's footprint at the level of detail it spans
//! ([`crate::render::MapFilter::Pixel`]).
//!
//! A frame that reads the relief over each pixel also estimates its reads' error once it is
//! rendered ([`Plan::observe`]); where that estimate is over the budget's p99, the frame is
//! rendered again with its reads refined twice as finely, up to 8 times
//! ([`Planner::render`], [`Planner::refined_again`]), and reports how many times it was
//! rendered (`renders`).
//!
//! A frame outside what the model was fitted on ([`Planner::outside_model`]: the camera
//! within 0.05 radii of the body, a body more elongated than 2 : 1, a DEM taller than 0.02
//! radii, an opposition surge narrower than 0.01) is not predicted: it is rendered at the
//! ladder's top rung, its shadows marched, and says it does not claim the budget
//! (`meets_budget: false`, and why in `outside_model`).

use crate::raycast::{Coverage, Tracer};
use crate::render::settings::SelfShadowing;
use crate::render::{Integration, MapFilter, PointBudget, Settings};
use crate::scene::{Pose, Scene};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The error a frame may have: relative, per lit pixel (median, 99th percentile) and in
/// total, as [`super::metrics::FrameError`] measures it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Budget {
    pub median: f64,
    pub p99: f64,
    pub total: f64,
}

impl Default for Budget {
    /// 1e-3 per pixel at the median (a tenth of a 12-bit camera's DN at mid-scale), 3e-2 at
    /// the 99th percentile (limb and terminator pixels), 1e-4 of the total light.
    fn default() -> Self {
        Budget {
            median: 1e-3,
            p99: 3e-2,
            total: 1e-4,
        }
    }
}

/// What a frame shows, as the error model reads it (from a grid of 64 x 64 probe rays
/// against the undisplaced shape, and the maps' statistics).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Features {
    /// The body's bounding sphere's apparent radius [px].
    pub radius_px: f64,
    /// Lit, visible pixels in the frame.
    pub lit_px: f64,
    /// Pixels along the limb and the terminator within the frame.
    pub edge_px: f64,
    pub phase_deg: f64,
    pub range_m: f64,
    /// A pixel's footprint at the nearest surface point, in albedo-map texels (0 without).
    pub footprint_texels: f64,
    /// The relative change of the surface's brightness between neighbouring pixels due to the
    /// albedo map and the DEM's slopes (0 on a plain body).
    pub texture: f64,
    /// The share of the lit surface in view where the Sun or the camera is low enough for
    /// the DEM's steep slopes (99th percentile) to hide it (0 without a DEM).
    pub shadow_share: f64,
    /// 1 when the albedo enters the reflectance non-linearly (Hapke's single-scattering
    /// albedo: the footprint step reads the map through a ratio of reflectances, which
    /// leaves a floor of about 1e-4 to 7e-4 at the median, 0 on a Lambertian body), else 0.
    #[serde(default)]
    pub nonlinear_albedo: f64,
    /// The DEM's share of [`Features::texture`]: its shading's change between neighbouring
    /// pixels (0 without a DEM). Where the relief is read over each pixel's footprint
    /// ([`MapFilter::Relief`]) it is read as the albedo map is, and the model sees only the
    /// rest ([`Features::modelled`]).
    #[serde(default)]
    pub relief_texture: f64,
    /// 1 where the body has a DEM that is not flat, else 0: the model's
    /// [`Regressors::Relief`] term and its own margin apply to such frames alone.
    #[serde(default)]
    pub relief: f64,
    /// 1 where each pixel reads the relief over its footprint ([`MapFilter::Relief`], set by
    /// [`Features::modelled`]), else 0: the relief's error is then the reads' (flat in the
    /// quadrangles per pixel), not the quadrangles'.
    #[serde(default)]
    pub relief_per_pixel: f64,
    /// Where each pixel reads the relief, how many times finer its reads may get where they
    /// disagree (`render.relief_refine`: 1, 2, 4 or 8, set by [`Features::refined`]); 1
    /// elsewhere (0 in older files reads as 1).
    #[serde(default)]
    pub relief_refine: f64,
}

impl Features {
    /// The features the error model reads for a frame rendered with `map_filter`: under
    /// [`MapFilter::Relief`] the footprint step reads the DEM's shading over each pixel as it
    /// reads the albedo map under [`MapFilter::Pixel`], so the relief's texture leaves
    /// [`Features::texture`] and the map's alone is left, as on the frames of a body without
    /// a DEM the model was fitted on (whose map was read over each pixel).
    pub fn modelled(&self, map_filter: MapFilter) -> Features {
        match map_filter {
            MapFilter::Relief => Features {
                texture: (self.texture - self.relief_texture).max(0.0),
                relief_texture: 0.0,
                relief_per_pixel: self.relief,
                ..*self
            },
            _ => *self,
        }
    }

    /// Whether the lit surface is on average thinner than a pixel: fewer lit pixels than
    /// pixels along the limb and the terminator (a lune at high phase).
    pub fn thinner_than_a_pixel(&self) -> bool {
        self.lit_px > 0.0 && self.lit_px < self.edge_px
    }

    /// The features the error model reads for a frame whose pixels, where each reads the
    /// relief ([`Features::relief_per_pixel`]), may be read again up to `relief_refine` times
    /// as finely; elsewhere the setting changes nothing and is read as 1.
    pub fn refined(&self, relief_refine: u32) -> Features {
        Features {
            relief_refine: if self.relief_per_pixel > 0.0 {
                f64::from(relief_refine.max(1))
            } else {
                1.0
            },
            ..*self
        }
    }

    /// The share of lit pixels on the limb or the terminator.
    pub fn edge_share(&self) -> f64 {
        if self.lit_px > 0.0 {
            (self.edge_px / self.lit_px).min(1.0)
        } else {
            0.0
        }
    }
}

/// What a model term reads of a frame (see the module's doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Regressors {
    /// `(1, ln p, ln(max(E - 0.01, 0) + 1e-4), ln(sin(g / 2) + 0.05))`: the limb's and the
    /// terminator's pixels, which a per-pixel figure sees once they are more than 1 % of the
    /// lit ones, and whose error grows with the terminator's share (the phase `g`).
    Edge,
    /// `(1, ln p, ln(T + 1e-4), ln p ln(T + 1e-4))`: the inside of the disk, where the map's
    /// and the quadrangles' errors are.
    Inside,
    /// `(1, ln p, ln(H + 1e-6))`, `H` [`Features::nonlinear_albedo`]: the floor a reflectance
    /// that is not linear in the albedo leaves (nothing on a Lambertian body).
    Reflectance,
    /// `(1, ln p, ln(S + 1e-3), ln(R + 1e-3), ln(sin(g / 2) + 0.05), P, P ln p, P ln k)`,
    /// `S` [`Features::shadow_share`], `R` [`Features::relief_texture`] as modelled (0 where
    /// the relief is read over each pixel), `g` the phase, `P`
    /// [`Features::relief_per_pixel`] and `k` [`Features::relief_refine`]: what a DEM adds,
    /// its shadows' edges (more of them towards the terminator) and its shading where the
    /// quadrangles carry it, or the pixels' reads' error where they carry it, which falls as
    /// the pixels a shadow's edge crosses are read again more finely. It is summed only on
    /// frames with a DEM ([`Features::relief`]), fitted on them alone after the other terms,
    /// and bounded by its own margin ([`FigureModel::relief_margin`]).
    Relief,
}

impl Regressors {
    fn values(self, points_per_px: f64, f: &Features) -> Vec<f64> {
        let (p, t) = (points_per_px.ln(), (f.texture + 1e-4).ln());
        match self {
            Regressors::Edge => vec![
                1.0,
                p,
                ((f.edge_share() - 0.01).max(0.0) + 1e-4).ln(),
                ((0.5 * f.phase_deg.to_radians()).sin() + 0.05).ln(),
            ],
            Regressors::Inside => vec![1.0, p, t, p * t],
            Regressors::Reflectance => vec![1.0, p, (f.nonlinear_albedo + 1e-6).ln()],
            Regressors::Relief => vec![
                1.0,
                p,
                (f.shadow_share + 1e-3).ln(),
                (f.relief_texture + 1e-3).ln(),
                ((0.5 * f.phase_deg.to_radians()).sin() + 0.05).ln(),
                f.relief_per_pixel,
                f.relief_per_pixel * p,
                f.relief_per_pixel * f.relief_refine.max(1.0).ln(),
            ],
        }
    }

    /// Every kind with its regressors as written in the model file's header.
    pub const ALL: [(Regressors, &'static str); 4] = [
        (
            Regressors::Edge,
            "edge:   (1, ln p, ln(max(E - 0.01, 0) + 1e-4), ln(sin(phase / 2) + 0.05))",
        ),
        (
            Regressors::Inside,
            "inside: (1, ln p, ln(T + 1e-4), ln p ln(T + 1e-4))",
        ),
        (
            Regressors::Reflectance,
            "reflectance: (1, ln p, ln(H + 1e-6))",
        ),
        (
            Regressors::Relief,
            "relief: (1, ln p, ln(S + 1e-3), ln(R + 1e-3), ln(sin(phase / 2) + 0.05), P, P ln p, P ln k), with a DEM alone",
        ),
    ];

    fn len(self) -> usize {
        self.values(1.0, &Features::default()).len()
    }
}

/// One term of a figure's model: `exp(k . x)` over the regressors `x`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Term {
    pub x: Regressors,
    pub k: Vec<f64>,
}

/// One figure's model: `e = margin * sum over terms of exp(k . x)`; on a frame with a DEM
/// ([`Features::relief`]) the [`Regressors::Relief`] terms join the sum and `relief_margin`
/// replaces `margin`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FigureModel {
    pub margin: f64,
    /// The margin that bounds every frame with a DEM the model was fitted on whose
    /// quadrangles carry the relief ([`ReliefKind::Quadrangles`]), and every frame with a DEM
    /// where the margin of its kind is not set; `None` where it was fitted on no frame with a
    /// DEM (then such a frame's prediction is `margin`'s extrapolation, and the planner does
    /// not claim it: [`UNFITTED_DEM`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relief_margin: Option<f64>,
    /// The margin that bounds every fitted frame whose pixels read the relief from one
    /// quadrangle per pixel up ([`ReliefKind::Reads`]): the rungs the planner takes on such
    /// frames. Their error is their reads', a law of its own. Kept with the others, the
    /// relief margin was set by frames of the other kinds: on this build's sweeps the p99's
    /// at 2.9 by NRHO row 167 at 130 deg with its shadows' edges left to 2 quadrangles per
    /// pixel (0.43), where the reads need 1.46 (`docs/performance.md`, "The planner refitted
    /// on the weighted reads"). `None` in the model files written before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relief_margin_reads: Option<f64>,
    /// The margin of the frames whose pixels read the relief below one quadrangle per pixel
    /// ([`ReliefKind::CoarseReads`]): their total is the coarse quadrangles' gridding at the
    /// limb, which changes sign from frame to frame and which no smooth law in `ln p`
    /// follows (NRHO row 138 at 1/16 per pixel: 1.7e-4 against 1.6e-5 modelled, a margin of
    /// 10.7 where the reads need 3.6 and the quadrangles' frames 4.8). `None` in the model
    /// files written before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relief_margin_coarse: Option<f64>,
    pub term: Vec<Term>,
}

/// From this many quadrangles per pixel up a frame whose pixels read the relief is
/// [`ReliefKind::Reads`], below it [`ReliefKind::CoarseReads`].
pub const READS_FROM_PPP: f64 = 1.0;

/// What carries a frame with a DEM's relief, each kind with its own margin
/// ([`FigureModel::margin_at`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReliefKind {
    /// The quadrangles ([`MapFilter::Pixel`] and the others): [`FigureModel::relief_margin`].
    Quadrangles,
    /// Each pixel's reads ([`MapFilter::Relief`]) from [`READS_FROM_PPP`] quadrangles per
    /// pixel up: [`FigureModel::relief_margin_reads`].
    Reads,
    /// Each pixel's reads below [`READS_FROM_PPP`]: [`FigureModel::relief_margin_coarse`].
    CoarseReads,
}

impl ReliefKind {
    pub const ALL: [ReliefKind; 3] = [
        ReliefKind::Quadrangles,
        ReliefKind::Reads,
        ReliefKind::CoarseReads,
    ];

    /// The kind of a frame showing `f` (modelled, [`Features::modelled`]) at
    /// `points_per_px`.
    pub fn of(points_per_px: f64, f: &Features) -> ReliefKind {
        match (f.relief_per_pixel > 0.0, points_per_px >= READS_FROM_PPP) {
            (false, _) => ReliefKind::Quadrangles,
            (true, true) => ReliefKind::Reads,
            (true, false) => ReliefKind::CoarseReads,
        }
    }

    /// The field of the model file that holds this kind's margin.
    pub fn field(self) -> &'static str {
        match self {
            ReliefKind::Quadrangles => "relief_margin",
            ReliefKind::Reads => "relief_margin_reads",
            ReliefKind::CoarseReads => "relief_margin_coarse",
        }
    }
}

impl FigureModel {
    pub fn predict(&self, points_per_px: f64, f: &Features) -> f64 {
        self.margin_at(points_per_px, f) * self.modelled(points_per_px, f)
    }

    /// The margin a frame showing `f` at `points_per_px` takes: on a frame with a DEM its
    /// kind's ([`ReliefKind`]), or `relief_margin` where the model has none of that kind;
    /// else the plain one.
    pub fn margin_at(&self, points_per_px: f64, f: &Features) -> f64 {
        match self.relief_margin {
            Some(m) if f.relief > 0.0 => self
                .relief_margin_of(self.bounding_kind(points_per_px, f))
                .unwrap_or(m),
            _ => self.margin,
        }
    }

    /// The kind whose relief margin bounds a frame with a DEM showing `f` at
    /// `points_per_px`: its own where the model has one for it, else the quadrangles'
    /// (`relief_margin`).
    pub fn bounding_kind(&self, points_per_px: f64, f: &Features) -> ReliefKind {
        let kind = ReliefKind::of(points_per_px, f);
        match self.relief_margin_of(kind) {
            Some(_) => kind,
            None => ReliefKind::Quadrangles,
        }
    }

    /// The margin the model holds for frames of `kind` (None where it has none of its own).
    pub fn relief_margin_of(&self, kind: ReliefKind) -> Option<f64> {
        match kind {
            ReliefKind::Quadrangles => self.relief_margin,
            ReliefKind::Reads => self.relief_margin_reads,
            ReliefKind::CoarseReads => self.relief_margin_coarse,
        }
    }

    /// The fitted law without the margin.
    fn modelled(&self, points_per_px: f64, f: &Features) -> f64 {
        self.term
            .iter()
            .filter(|t| t.x != Regressors::Relief || f.relief > 0.0)
            .map(|t| dot(&t.k, &t.x.values(points_per_px, f)).exp())
            .sum()
    }
}

/// The three figures' models, fitted by the sweep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorModel {
    pub median: FigureModel,
    pub p99: FigureModel,
    pub total: FigureModel,
    /// Frames the fit saw.
    pub frames: usize,
    /// How a frame that reads the relief over each pixel turns its own estimate of its reads'
    /// p99 into a bound, per refinement ([`ErrorModel::read_scale`]); empty in a model
    /// fitted on no such frame.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub relief_read: Vec<ReadScale>,
}

/// The largest ratio of measured p99 to the frame's own estimate of its reads' p99
/// ([`crate::render::FrameStats::relief_read_p99`]) over the sweep's frames that read the
/// relief over each pixel at one `relief_refine`, from [`READS_FROM_PPP`] quadrangles per
/// pixel up ([`ReliefKind::Reads`]): that estimate times `scale` bounds every such frame the
/// model was fitted on. Below one a pixel the p99 grows with the limb's quadrangles, which
/// the reads do not see (the NRHO's apolune at `k` 1: p99 0.125 at 1/16 per pixel, 0.077 at
/// 1, the reads' estimate 0.164 at both); the model's own prediction, whose margin bounds
/// every fitted frame, covers those rungs. The estimate (each pixel's reads against a quarter of them) is far from the measured
/// p99 both ways: 4 times above it and more at `k` 2 to 8 from 1 quadrangle per pixel up,
/// 3.4 times below it at `k` 1 at 130 deg of phase on the build before the reads' weights
/// (`docs/performance.md`, "The model refitted on this build's frames", "The planner
/// refitted on the weighted reads").
///
/// At `relief_refine` 1 the frames whose lit surface lies mostly under the steep slopes'
/// shadows ([`Features::shadow_share`] at least [`SHADOWED_SHARE`]) get a factor of their own
/// (`shadowed`), as do the others. A pixel finer than a texel is read once there, and the
/// quarter its estimate compares it with lies on its neighbours, so under long shadows both
/// miss the slivers of light between them and the estimate reads 3 times below the measured
/// p99 (NRHO rows 152 and 167, shadow share 0.96 and 1.0: 3.09, 3.07); elsewhere it reads
/// the shading's change from pixel to pixel and is twice the measured (NRHO apolune and rows
/// 90, 120 and 138, shadow share 0.38-0.67: 0.25-0.50). One factor for both asked the second
/// kind to re-render frames that met the budget (Artemis I row 470, `docs/performance.md`,
/// "The reads' factor at one read a pixel, by shadow"). From `relief_refine` 2 every pixel
/// is read at least 3 times a side and again where its reads disagree, and one factor holds
/// (0.05-0.21 measured against estimated either way).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReadScale {
    pub relief_refine: u32,
    /// At `relief_refine` 1: whether it is the factor of the frames mostly under shadows
    /// (`true`) or of the others (`false`); `None` (and in files fitted before the split):
    /// every frame at that refinement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadowed: Option<bool>,
    pub scale: f64,
    /// The frames it was fitted on.
    pub frames: usize,
}

/// Fewest frames at one refinement for a [`ReadScale`] of its own.
const READ_SCALE_MIN_FRAMES: usize = 4;

/// The share of the lit surface under the steep slopes' shadows ([`Features::shadow_share`])
/// from which a frame read once a pixel (`relief_refine` 1) takes the shadowed frames'
/// factor on its own estimate ([`ReadScale`]). The fitted frames leave it between 0.67 (NRHO
/// row 138, estimate twice the measured) and 0.96 (row 152, a third of it); of the streams'
/// verified frames, NRHO row 565 at 0.84 measured 6 times its estimate at one read a pixel,
/// and every frame at 0.52 or less at most 0.96 times it.
pub const SHADOWED_SHARE: f64 = 0.75;

impl ReadScale {
    /// The class a frame at `relief_refine` showing `features` takes its factor from: at 1,
    /// whether it is mostly under shadows ([`SHADOWED_SHARE`]); `None` from 2 up.
    pub fn class(relief_refine: u32, features: &Features) -> Option<bool> {
        (relief_refine <= 1).then_some(features.shadow_share >= SHADOWED_SHARE)
    }
}

/// The model fitted on the sweep of `docs/performance.md` (`config/error_model.toml`).
const DEFAULT_MODEL: &str = include_str!("../../config/error_model.toml");

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("error model {file}: {message}")]
    Parse { file: String, message: String },
    #[error("error model fit: {0}")]
    Fit(String),
}

/// Predicted errors of a frame at its chosen settings.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Predicted {
    pub median: f64,
    pub p99: f64,
    pub total: f64,
}

/// What the planner chose for one frame, and why.
///
/// A ray-cast frame (a mesh, several bodies) has no rung (`points_per_pixel` 0). A mesh body
/// alone through a pinhole, without scattered light, is clipped exactly (`raycast_clip`:
/// each facet's lit and seen part as polygons, [`crate::raycast::exact::render_frame`]; no
/// edge rays, `raycast_edge_samples` 0). Any other is cast with `raycast_edge_samples` rays
/// per side at its edges and refines them to the budget itself
/// ([`crate::raycast::estimate`]). Either way its `predicted` error is the frame's own
/// estimate, filled in once it is rendered ([`Plan::observe`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Plan {
    /// Quadrangles per pixel, boundary nodes and shadows of the chosen rung.
    pub points_per_pixel: f64,
    /// Ray-cast frames: the edges' first rays per pixel side (0 for quadrangle frames).
    pub raycast_edge_samples: u32,
    /// Ray-cast frames: the facets clipped exactly, no edge rays (`render.raycast_clip`).
    pub raycast_clip: bool,
    pub boundary_nodes: u32,
    pub self_shadowing: SelfShadowing,
    /// How the albedo map is read ([`Planner::map_filter`]; a ray-cast frame reports the
    /// scene's own setting, its rays reading the map where they land).
    pub map_filter: MapFilter,
    /// Under the relief filter, how much finer a pixel's reads may get where they disagree
    /// (`render.relief_refine`): chosen with the rung, at least the base's; 1 elsewhere,
    /// where it changes nothing.
    pub relief_refine: u32,
    /// The factor on the frame's own estimate of its reads' p99 at its refinement
    /// ([`ErrorModel::read_scale`], [`Plan::observe`]).
    #[serde(skip)]
    pub relief_read_scale: f64,
    pub predicted: Predicted,
    /// Whether the prediction meets the budget (false: no rung is predicted to meet it; the
    /// frame is rendered at the cheapest rung that meets the figures some rung can meet and
    /// comes within 1.5x of the ladder's best prediction on the others, else the top rung;
    /// or the frame is outside the model's domain, `outside_model`).
    pub meets_budget: bool,
    /// Why the frame lies outside what the error model was fitted on, where it does
    /// ([`Planner::outside_model`]): its prediction is then an extrapolation, the frame is
    /// rendered at the ladder's top rung and does not claim to meet the budget. A frame that
    /// reads a DEM ([`UNFITTED_DEM`]) keeps the model's rung and its prediction, and does
    /// not claim them either.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub outside_model: Option<&'static str>,
    /// How many times the frame was rendered: 1, and one more each time its own estimate of
    /// its reads' p99 came out over the budget and it was rendered again with its reads
    /// refined twice as finely ([`Planner::refined_again`]).
    pub renders: u32,
    pub budget: Budget,
    pub features: Features,
    #[serde(skip)]
    pub settings: Settings,
}

impl Plan {
    /// A ray-cast frame's own estimate of its error becomes its prediction, and whether it
    /// meets the budget is read from it (a quadrangle frame's plan is left as it is).
    ///
    /// A frame that read the relief over each pixel ([`MapFilter::Relief`]) knows how well
    /// its reads sampled the shadows' edges and the shading ([`FrameStats::relief_read_p99`],
    /// from each pixel's reads against a quarter of them): that estimate, times the factor
    /// that makes it bound the sweep's frames at the same refinement
    /// ([`Plan::relief_read_scale`]), is its predicted p99 where it is the larger, and
    /// whether it meets the budget is judged again.
    ///
    /// A frame planned with nothing lit is predicted exact; rendered with light after all,
    /// its prediction becomes unknown (NaN) and it does not claim the budget.
    ///
    /// [`FrameStats::relief_read_p99`]: crate::render::FrameStats::relief_read_p99
    pub fn observe(&mut self, stats: &crate::render::FrameStats) {
        // Planned with nothing lit, rendered with light: the probe missed it (a sliver
        // between its rays), so the plan's "no error" is unfounded and not claimed.
        let quadrangles = self.raycast_edge_samples == 0 && !self.raycast_clip;
        if quadrangles && self.features.lit_px == 0.0 && stats.total_pl_image > 0.0 {
            self.predicted = Predicted {
                median: f64::NAN,
                p99: f64::NAN,
                total: f64::NAN,
            };
            self.meets_budget = false;
            return;
        }
        if let Some(p99) = self.own_read_p99(stats) {
            if p99 > self.predicted.p99 {
                self.predicted.p99 = p99;
                self.meets_budget &= p99 <= self.budget.p99;
            }
            return;
        }
        if quadrangles {
            return;
        }
        match stats.estimated_error {
            Some(e) => {
                self.predicted = Predicted {
                    median: e.median,
                    p99: e.p99,
                    total: e.total,
                };
                let b = self.budget;
                self.meets_budget = e.median <= b.median && e.p99 <= b.p99 && e.total <= b.total;
            }
            None => {
                self.predicted = Predicted {
                    median: f64::NAN,
                    p99: f64::NAN,
                    total: f64::NAN,
                };
                self.meets_budget = false;
            }
        }
    }

    /// The frame's own estimate of its p99 where it read the relief over each pixel: its
    /// reads' estimate ([`FrameStats::relief_read_p99`]) times the factor at its refinement
    /// ([`Plan::relief_read_scale`]); `None` for any other frame.
    ///
    /// [`FrameStats::relief_read_p99`]: crate::render::FrameStats::relief_read_p99
    pub fn own_read_p99(&self, stats: &crate::render::FrameStats) -> Option<f64> {
        stats
            .relief_read_p99
            .filter(|_| self.map_filter == MapFilter::Relief)
            .map(|estimate| estimate * self.relief_read_scale)
    }
}

/// A sweep frame for the fit: its features, the rung's points per pixel and its measured
/// error figures.
#[derive(Clone, Copy, Debug)]
pub struct FitRow {
    pub points_per_px: f64,
    pub features: Features,
    pub median: f64,
    pub p99: f64,
    pub total: f64,
    /// The frame's own estimate of its relief reads' p99 (NaN where it has none).
    pub relief_read_p99: f64,
}

impl ErrorModel {
    /// The fitted model shipped with optistim.
    pub fn shipped() -> Result<ErrorModel, ModelError> {
        ErrorModel::parse(DEFAULT_MODEL, "config/error_model.toml")
    }

    pub fn parse(text: &str, file: &str) -> Result<ErrorModel, ModelError> {
        let m: ErrorModel = toml::from_str(text).map_err(|e| ModelError::Parse {
            file: file.into(),
            message: e.to_string(),
        })?;
        for (name, f) in [("median", &m.median), ("p99", &m.p99), ("total", &m.total)] {
            let ok = !f.term.is_empty()
                && f.term
                    .iter()
                    .all(|t| t.k.len() == t.x.len() && t.k.iter().all(|x| x.is_finite()))
                && f.margin >= 1.0
                && f.margin.is_finite()
                && [
                    f.relief_margin,
                    f.relief_margin_reads,
                    f.relief_margin_coarse,
                ]
                .iter()
                .all(|m| m.is_none_or(|m| m >= 1.0 && m.is_finite()));
            if !ok {
                return Err(ModelError::Parse {
                    file: file.into(),
                    message: format!(
                        "{name}: terms with one finite k per regressor and a finite margin >= 1 expected"
                    ),
                });
            }
        }
        Ok(m)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// Fits each figure on `rows` (see the module's documentation): the terms by least
    /// squares in logarithms (`fit_terms`), then the margin that bounds every row. Each
    /// figure is an [`Regressors::Edge`], an [`Regressors::Inside`] and a
    /// [`Regressors::Reflectance`] term, fitted on the frames without a DEM; then, where
    /// there are frames with one, a [`Regressors::Relief`] term fitted on those alone over
    /// the first three held fixed, with its own margin. The first three, and so every frame
    /// without a DEM, are what they would be without the frames with one.
    pub fn fit(rows: &[FitRow]) -> Result<ErrorModel, ModelError> {
        let (relief, plain): (Vec<FitRow>, Vec<FitRow>) =
            rows.iter().partition(|r| r.features.relief > 0.0);
        let terms = [
            Regressors::Edge,
            Regressors::Inside,
            Regressors::Reflectance,
        ];
        let figure = |get: fn(&FitRow) -> f64, name: &str| {
            let mut m = fit_figure(&plain, get, name, &terms)?;
            if !relief.is_empty() {
                fit_relief(&mut m, &relief, get, name)?;
            }
            Ok::<_, ModelError>(m)
        };
        Ok(ErrorModel {
            median: figure(|r| r.median, "median")?,
            p99: figure(|r| r.p99, "p99")?,
            total: figure(|r| r.total, "total")?,
            frames: rows.len(),
            relief_read: fit_read_scales(&relief),
        })
    }

    /// The factor on a frame's own estimate of its reads' p99 at `relief_refine`
    /// ([`Plan::observe`]) for a frame showing `features`: the [`ReadScale`] fitted at that
    /// refinement, at 1 the one of the frame's class ([`ReadScale::class`]) where the fit has
    /// it, else the one of every frame there; at one the fit did not see, the largest fitted
    /// (at least 1); 1 (the estimate as it is) in a model fitted on none.
    pub fn read_scale(&self, relief_refine: u32, features: &Features) -> f64 {
        let class = ReadScale::class(relief_refine, features);
        let at = |class: Option<bool>| {
            self.relief_read
                .iter()
                .find(|s| s.relief_refine == relief_refine && s.shadowed == class)
        };
        match at(class).or_else(|| at(None)) {
            Some(s) => s.scale,
            None => self.relief_read.iter().map(|s| s.scale).fold(1.0, f64::max),
        }
    }

    /// Whether every figure was fitted on frames with a DEM (has its relief margin).
    pub fn fitted_on_relief(&self) -> bool {
        [&self.median, &self.p99, &self.total]
            .iter()
            .all(|f| f.relief_margin.is_some())
    }

    pub fn predict(&self, points_per_px: f64, f: &Features) -> Predicted {
        Predicted {
            median: self.median.predict(points_per_px, f),
            p99: self.p99.predict(points_per_px, f),
            total: self.total.predict(points_per_px, f),
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Per refinement, the factor that makes the frames' own estimates of their reads' p99 bound
/// what they measured, over the `rows` whose pixels read the relief from one quadrangle per
/// pixel up ([`ReliefKind::Reads`], [`ReadScale`]; at 1, per class, [`ReadScale::class`]; a
/// refinement or class with fewer than [`READ_SCALE_MIN_FRAMES`] such frames gets none).
fn fit_read_scales(rows: &[FitRow]) -> Vec<ReadScale> {
    let mut scales: Vec<ReadScale> = Vec::new();
    for r in rows.iter().filter(|r| {
        ReliefKind::of(r.points_per_px, &r.features) == ReliefKind::Reads
            && r.relief_read_p99.is_finite()
            && r.relief_read_p99 > 0.0
            && r.p99.is_finite()
    }) {
        let k = r.features.relief_refine.max(1.0) as u32;
        let shadowed = ReadScale::class(k, &r.features);
        let ratio = r.p99 / r.relief_read_p99;
        match scales
            .iter_mut()
            .find(|s| s.relief_refine == k && s.shadowed == shadowed)
        {
            Some(s) => {
                s.scale = s.scale.max(ratio);
                s.frames += 1;
            }
            None => scales.push(ReadScale {
                relief_refine: k,
                shadowed,
                scale: ratio,
                frames: 1,
            }),
        }
    }
    scales.retain(|s| s.frames >= READ_SCALE_MIN_FRAMES);
    scales.sort_by_key(|s| (s.relief_refine, s.shadowed));
    scales
}

/// One figure of the model fitted on `rows`, with the margin that bounds every usable row.
fn fit_figure(
    rows: &[FitRow],
    get: fn(&FitRow) -> f64,
    name: &str,
    terms: &[Regressors],
) -> Result<FigureModel, ModelError> {
    let usable: Vec<&FitRow> = rows
        .iter()
        .filter(|r| get(r).is_finite() && get(r) > 0.0 && r.points_per_px > 0.0)
        .collect();
    let n: usize = terms.iter().map(|t| t.len()).sum();
    if usable.len() < n {
        return Err(ModelError::Fit(format!(
            "{name}: {} usable frames, at least {n} needed",
            usable.len()
        )));
    }
    let x: Vec<Vec<Vec<f64>>> = usable
        .iter()
        .map(|r| {
            terms
                .iter()
                .map(|t| t.values(r.points_per_px, &r.features))
                .collect()
        })
        .collect();
    let y: Vec<f64> = usable.iter().map(|r| get(r).ln()).collect();
    let k = fit_terms(&x, &y, &vec![0.0; y.len()])
        .ok_or_else(|| ModelError::Fit(format!("{name}: singular regressors")))?;
    let mut m = FigureModel {
        margin: 1.0,
        relief_margin: None,
        relief_margin_reads: None,
        relief_margin_coarse: None,
        term: terms.iter().zip(k).map(|(&x, k)| Term { x, k }).collect(),
    };
    let worst = usable
        .iter()
        .zip(&y)
        .map(|(r, y)| y - m.modelled(r.points_per_px, &r.features).ln())
        .fold(0.0f64, f64::max);
    m.margin = worst.exp();
    Ok(m)
}

/// The [`Regressors::Relief`] term of the figure `m` (its other terms fitted), fitted on the
/// frames with a DEM `rows` over those terms held fixed, and the margin that bounds them.
fn fit_relief(
    m: &mut FigureModel,
    rows: &[FitRow],
    get: fn(&FitRow) -> f64,
    name: &str,
) -> Result<(), ModelError> {
    let usable: Vec<&FitRow> = rows
        .iter()
        .filter(|r| get(r).is_finite() && get(r) > 0.0 && r.points_per_px > 0.0)
        .collect();
    let n = Regressors::Relief.len();
    if usable.len() < 2 * n {
        return Err(ModelError::Fit(format!(
            "{name}: {} usable frames with a DEM, at least {} needed",
            usable.len(),
            2 * n
        )));
    }
    let x: Vec<Vec<Vec<f64>>> = usable
        .iter()
        .map(|r| vec![Regressors::Relief.values(r.points_per_px, &r.features)])
        .collect();
    let y: Vec<f64> = usable.iter().map(|r| get(r).ln()).collect();
    let base: Vec<f64> = usable
        .iter()
        .map(|r| m.modelled(r.points_per_px, &r.features))
        .collect();
    let k = fit_terms(&x, &y, &base)
        .ok_or_else(|| ModelError::Fit(format!("{name}: singular relief regressors")))?;
    m.term.push(Term {
        x: Regressors::Relief,
        k: k.into_iter().next().unwrap_or_default(),
    });
    // Each kind's margin bounds its frames; `relief_margin` the quadrangles' (all of them
    // where there are none of that kind).
    let worst = |kind: Option<ReliefKind>| {
        let of_kind: Vec<f64> = usable
            .iter()
            .zip(&y)
            .filter(|(r, _)| kind.is_none_or(|k| ReliefKind::of(r.points_per_px, &r.features) == k))
            .map(|(r, y)| y - m.modelled(r.points_per_px, &r.features).ln())
            .collect();
        (!of_kind.is_empty()).then(|| of_kind.iter().fold(0.0f64, |a, &b| a.max(b)).exp())
    };
    let margins = (
        worst(Some(ReliefKind::Quadrangles)).or(worst(None)),
        worst(Some(ReliefKind::Reads)),
        worst(Some(ReliefKind::CoarseReads)),
    );
    (
        m.relief_margin,
        m.relief_margin_reads,
        m.relief_margin_coarse,
    ) = margins;
    Ok(())
}

/// Least squares of `y = ln(base + sum_t exp(k_t . x_t))` (`x[row][term]`, `base` per row, 0
/// but where terms fitted before are held fixed): a single term over no base is linear
/// ([`solve`] on the normal equations); otherwise Levenberg-Marquardt from deterministic
/// starts (each term alone fitted to all rows, then shifted so that one or another
/// dominates, and 40 fixed pseudo-random ones), keeping the best.
fn fit_terms(x: &[Vec<Vec<f64>>], y: &[f64], base: &[f64]) -> Option<Vec<Vec<f64>>> {
    let sizes: Vec<usize> = x.first()?.iter().map(Vec::len).collect();
    // Each term alone, fitted to what the base leaves (at least a tenth of each row).
    let left: Vec<f64> = y
        .iter()
        .zip(base)
        .map(|(&y, &b)| {
            if b == 0.0 {
                y
            } else {
                (y.exp() - b).max(0.1 * y.exp()).ln()
            }
        })
        .collect();
    let alone: Vec<Vec<f64>> = (0..sizes.len())
        .map(|t| {
            let rows: Vec<&[f64]> = x.iter().map(|r| r[t].as_slice()).collect();
            linear_fit(&rows, &left)
        })
        .collect::<Option<_>>()?;
    if sizes.len() == 1 && base.iter().all(|&b| b == 0.0) {
        return Some(alone);
    }
    let flat = |k: &[Vec<f64>]| k.concat();
    let mut starts: Vec<Vec<f64>> = Vec::new();
    for shift in [0.0, 1.0, 3.0] {
        for lead in 0..sizes.len() {
            let start: Vec<Vec<f64>> = alone
                .iter()
                .enumerate()
                .map(|(t, k)| {
                    let mut k = k.clone();
                    k[0] -= if t == lead { 0.7 } else { 0.7 + shift };
                    k
                })
                .collect();
            starts.push(flat(&start));
        }
    }
    // And 40 starts drawn uniformly in [-2, 2] (a fixed xorshift sequence: the fit is
    // deterministic), for the valleys the others miss.
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    for _ in 0..40 {
        starts.push(
            (0..sizes.iter().sum::<usize>())
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    4.0 * (state >> 11) as f64 / (1u64 << 53) as f64 - 2.0
                })
                .collect(),
        );
    }
    let mut best: Option<(f64, Vec<f64>)> = None;
    for start in starts {
        let k = levenberg_marquardt(x, y, base, start, &sizes);
        let cost = cost(x, y, base, &split(&k, &sizes));
        if cost.is_finite() && best.as_ref().is_none_or(|(c, _)| cost < *c) {
            best = Some((cost, k));
        }
    }
    best.map(|(_, k)| split(&k, &sizes))
}

/// The flat parameter vector `v` cut into the terms' `sizes`.
fn split(v: &[f64], sizes: &[usize]) -> Vec<Vec<f64>> {
    let mut out = Vec::with_capacity(sizes.len());
    let mut at = 0;
    for &n in sizes {
        out.push(v[at..at + n].to_vec());
        at += n;
    }
    out
}

/// The sum of squared residuals in logarithms.
fn cost(x: &[Vec<Vec<f64>>], y: &[f64], base: &[f64], k: &[Vec<f64>]) -> f64 {
    x.iter()
        .zip(y)
        .zip(base)
        .map(|((row, y), b)| {
            let m: f64 = b + row.iter().zip(k).map(|(x, k)| dot(k, x).exp()).sum::<f64>();
            (y - m.ln()).powi(2)
        })
        .sum()
}

fn levenberg_marquardt(
    x: &[Vec<Vec<f64>>],
    y: &[f64],
    base: &[f64],
    mut k: Vec<f64>,
    sizes: &[usize],
) -> Vec<f64> {
    let n = k.len();
    let split = |v: &[f64]| split(v, sizes);
    let mut lambda = 1e-3;
    let mut c = cost(x, y, base, &split(&k));
    for _ in 0..2000 {
        let kk = split(&k);
        let mut jtj = vec![vec![0.0; n]; n];
        let mut jtr = vec![0.0; n];
        for ((row, y), b) in x.iter().zip(y).zip(base) {
            let parts: Vec<f64> = row.iter().zip(&kk).map(|(x, k)| dot(k, x).exp()).collect();
            let m: f64 = b + parts.iter().sum::<f64>();
            let r = y - m.ln();
            let j: Vec<f64> = row
                .iter()
                .zip(&parts)
                .flat_map(|(x, part)| x.iter().map(move |v| v * part / m))
                .collect();
            for a in 0..n {
                jtr[a] += j[a] * r;
                for b in 0..n {
                    jtj[a][b] += j[a] * j[b];
                }
            }
        }
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj.clone();
            for (i, row) in a.iter_mut().enumerate() {
                row[i] += lambda * (jtj[i][i] + 1e-12);
            }
            let Some(step) = solve(&a, &jtr) else {
                lambda *= 10.0;
                continue;
            };
            let trial: Vec<f64> = k.iter().zip(&step).map(|(k, s)| k + s).collect();
            let ct = cost(x, y, base, &split(&trial));
            if ct < c {
                let done = (c - ct) < 1e-12 * c.max(1e-300);
                k = trial;
                c = ct;
                lambda = (lambda * 0.3).max(1e-12);
                improved = !done;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    k
}

/// Ordinary least squares of `y` on the rows of `x`.
fn linear_fit(x: &[&[f64]], y: &[f64]) -> Option<Vec<f64>> {
    let n = x.first()?.len();
    let mut ata = vec![vec![0.0f64; n]; n];
    let mut atb = vec![0.0f64; n];
    for (x, y) in x.iter().zip(y) {
        for i in 0..n {
            atb[i] += x[i] * y;
            for j in 0..n {
                ata[i][j] += x[i] * x[j];
            }
        }
    }
    // A regressor constant over the rows (no textured frame, say) is left out.
    solve(&ata, &atb)
}

/// The least-squares solution of the normal equations `a x = b` (Gauss-Jordan with partial
/// pivoting; a pivot below 1e-9 of the largest diagonal drops its regressor: 0).
fn solve(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let (mut m, mut v) = (a.to_vec(), b.to_vec());
    let scale = (0..n).map(|i| m[i][i].abs()).fold(0.0f64, f64::max);
    if scale.is_nan() || scale <= 0.0 {
        return None;
    }
    let mut dropped = vec![false; n];
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))?;
        if m[piv][col].abs() < 1e-9 * scale {
            dropped[col] = true;
            continue;
        }
        m.swap(col, piv);
        v.swap(col, piv);
        let pivot_row = m[col].clone();
        for row in 0..n {
            if row != col {
                let f = m[row][col] / pivot_row[col];
                for (x, p) in m[row].iter_mut().zip(&pivot_row) {
                    *x -= f * p;
                }
                v[row] -= f * v[col];
            }
        }
    }
    let x: Vec<f64> = (0..n)
        .map(|i| if dropped[i] { 0.0 } else { v[i] / m[i][i] })
        .collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Where no rung is predicted to meet a figure's budget, a rung whose prediction of that
/// figure is within this factor of the ladder's best is good enough for it.
const NEAR_BEST: f64 = 1.5;

/// The refinements of a pixel's relief reads the planner may take (`render.relief_refine`):
/// at the NRHO's far frames 1 left the 99th percentile at 0.10 to 0.17 and 8 brought it to
/// 2.2e-2 to 2.9e-2 (`docs/performance.md`, "Pixels read again where their reads disagree").
pub const RELIEF_REFINES: [u32; 4] = [1, 2, 4, 8];

/// A ray-cast frame's first rays per pixel side at its edges under a budget: with 4, pixels
/// whose 4 x 4 rays all met one class hid errors the estimate could not see (on Bennu at
/// phase 100, the total 1.3e-4 measured against 6.5e-5 estimated); with 8, every frame
/// checked kept within its estimate (`tests/mesh.rs`).
pub const RAYCAST_FIRST_EDGE_SAMPLES: u32 = 8;

/// The error model's domain ([`Planner::outside_model`]), with some room beyond the frames it
/// was fitted and checked on: the camera's height over the body's bounding sphere [radii]
/// (fitted down to 0.075, Artemis I's close approach), the body's largest over its smallest
/// semi-axis (fitted: 1.56), the DEM's highest less lowest point [radii] (the LOLA Moon's
/// 20 km: 0.011) and the narrowest opposition surge's width `h` (fitted: 0.07).
const MIN_ALTITUDE_RADII: f64 = 0.05;
const MAX_ELONGATION: f64 = 2.0;
const MAX_RELIEF_RADII: f64 = 0.02;
const MIN_OPPOSITION_WIDTH: f64 = 0.01;

/// Why a frame that reads a DEM (its shading by the DEM's normals, its shadows; per
/// quadrangle or per pixel) does not claim the budget where the error model was not fitted
/// on frames with such a DEM ([`ErrorModel::fitted_on_relief`]; a DEM that displaces the
/// surface is never in its fit). A model fitted without a DEM (`sweeps/budget.toml`,
/// `sweeps/budget_hapke.toml` alone) predicted the NRHO's perilune frame at 1024 x 1024 at
/// p99 2.3e-2 where it measured 6.3e-2 at the rung it took, and the Artemis I close approach
/// at total 3.7e-5 where it measured 1.8e-4 (`sweeps/issue15_dem_1024.toml`;
/// `docs/performance.md`, "The DEM at 1024 x 1024"). The frame keeps the model's rung and
/// prediction: the top rung, which other frames outside the model take, costs a hundred
/// times more there (16 per pixel at perilune; 4 per pixel took 18.6 s).
pub const UNFITTED_DEM: &str = "the error model was not fitted on frames with this kind of DEM: its rung is taken, its prediction not claimed";

/// One of the planner's candidates and the error the model predicts for it.
#[derive(Clone, Copy)]
struct Candidate {
    map_filter: MapFilter,
    points_per_px: f64,
    relief_refine: u32,
    predicted: Predicted,
}

impl Candidate {
    fn cost(&self, shadows: SelfShadowing) -> f64 {
        relative_cost(
            self.map_filter,
            self.points_per_px,
            self.relief_refine,
            shadows,
        )
    }
}

/// What rendering a frame at `points_per_px` quadrangles per pixel through `map_filter` (at
/// `relief_refine` under [`MapFilter::Relief`]) with `shadows` costs, relative to one
/// quadrangle per pixel whose shadows are marched, per lit pixel
/// ([`QUADRANGLE_COST_UNSHADOWED`], [`RELIEF_READ_COST`]): `p` such quadrangles cost `p`;
/// quadrangles whose shadows are not marched (the horizon map, none, or under the relief's
/// reads, where the quadrangles integrate the smooth shape unshadowed) cost less; each
/// pixel's reads of the relief add their cost at their refinement. Both scale with the lit
/// pixels, so the frame's size leaves their ratio; the map's reads over each pixel, which
/// every candidate of a frame shares, are left out.
pub fn relative_cost(
    map_filter: MapFilter,
    points_per_px: f64,
    relief_refine: u32,
    shadows: SelfShadowing,
) -> f64 {
    let quadrangle = if map_filter != MapFilter::Relief && shadows == SelfShadowing::RayMarching {
        1.0
    } else {
        QUADRANGLE_COST_UNSHADOWED
    };
    let reads = match map_filter {
        MapFilter::Relief => RELIEF_REFINES
            .iter()
            .position(|&k| k >= relief_refine)
            .map_or(RELIEF_READ_COST[RELIEF_READ_COST.len() - 1], |i| {
                RELIEF_READ_COST[i]
            }),
        _ => 0.0,
    };
    points_per_px * quadrangle + reads
}

/// The cost of one quadrangle per pixel whose shadows are not marched, against one whose
/// shadows are ([`relative_cost`]). The fixed rungs of the budget checks at 1024 x 1024
/// (the horizon map's shadows, against the planner's marched ones on the same frames, per
/// quadrangle per pixel): NRHO rows 178 and 180 0.36 and 0.39, Artemis I rows 700 and 647
/// 0.53 and 0.68; the relief's quadrangles, unshadowed, cost less than the horizon map's.
const QUADRANGLE_COST_UNSHADOWED: f64 = 0.5;

/// The cost of each pixel's reads of the relief at `relief_refine` 1, 2, 4 and 8
/// ([`RELIEF_REFINES`]), in marched quadrangles per pixel ([`relative_cost`]). The relief
/// rungs of the budget checks at 2 per pixel (their quadrangles at
/// [`QUADRANGLE_COST_UNSHADOWED`] taken off) against the planner's marched quadrangles on
/// the same frames (`docs/performance.md`, "Between the two ladders by cost"):
///
/// | frame | `k` 1 | 2 | 4 | 8 |
/// | --- | --- | --- | --- | --- |
/// | NRHO 178 (3,249 km, 94 deg) | 0.87 | 11.5 | 16.5 | 31 |
/// | NRHO 180 (3,297 km, 85 deg) | 1.16 | 12.3 | 17.5 | 21 |
/// | Artemis I 700 (49 deg) | 0.38 | 10.1 | 12.2 | 17.7 |
/// | Artemis I 647 (3 deg) | 0.59 | 9.4 | 13.5 | 22.3 |
///
/// The largest of each column, so that a candidate's cost is not understated.
const RELIEF_READ_COST: [f64; 4] = [1.2, 12.5, 17.5, 31.0];

/// The quadrangles per pixel of the ladder's rungs, cheapest first.
pub const LADDER: [f64; 9] = [0.0625, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0];

/// Of the horizon map's shadows, the share that differ from ray marching on the displaced
/// lunar DEM (`docs/performance.md`: 89 % of the pixels the same).
const HORIZON_MAP_MISSES: f64 = 0.11;

/// What a scene's maps are like (read once), to tell what each of its frames shows
/// ([`FrameProbe::features`]): the planner's eyes, and the sweep's, which needs no model.
pub struct FrameProbe {
    /// The albedo map's texel [m] and its contrast per level ([`crate::body::AlbedoMap`]).
    albedo: Option<(f64, Vec<f64>)>,
    /// The DEM's texel [m], its mean change of slope between neighbours and its steep slope.
    relief: Option<(f64, f64, f64)>,
    /// [`Features::nonlinear_albedo`].
    nonlinear_albedo: f64,
}

impl FrameProbe {
    pub fn new(scene: &Scene) -> FrameProbe {
        let body = &scene.body;
        let r = body.shape.bounding_radius_m();
        let albedo = body
            .albedo_map
            .as_ref()
            .map(|a| (r * a.map.spacing_rad().1, a.contrast_by_level()));
        let relief = body.relief.as_ref().map(|rel| {
            let (change, steep) = rel.slope_statistics();
            (r * rel.heights_m.spacing_rad().1, change, steep)
        });
        let nonlinear_albedo = match body.brdf {
            crate::brdf::Brdf::Hapke(_) => 1.0,
            _ => 0.0,
        };
        FrameProbe {
            albedo,
            relief,
            nonlinear_albedo,
        }
    }

    /// What the frame of `scene` seen from `pose` shows.
    pub fn features(&self, scene: &Scene, pose: &Pose) -> Features {
        const G: usize = 64;
        let intr = &scene.camera.intrinsics;
        let (w, h) = (intr.width_px as f64, intr.height_px as f64);
        let (fu, fv) = intr.focal_px();
        let f_px = fu.max(fv);
        let radius_m = scene.body.shape.bounding_radius_m();
        let range_m = pose.camera_position_m.length();
        let tracer = Tracer::new(scene, pose);
        let steep = self.relief.map_or(0.0, |r| r.2);
        // Corner classes: 0 misses, 1 dark, 2 lit ([`probe_class`]; `low`: the Sun under the
        // DEM's steep slopes there).
        let (du, dv) = (w / G as f64, h / G as f64);
        let classes: Vec<(u8, bool)> = (0..(G + 1) * (G + 1))
            .map(|k| {
                probe_class(
                    &tracer,
                    pose,
                    steep,
                    (k % (G + 1)) as f64 * du,
                    (k / (G + 1)) as f64 * dv,
                )
            })
            .collect();
        // Each cell's lit area, its share under the steep slopes and the length of the limb
        // and the terminator in it [px], read at its top-left corner (and edges where its
        // corners disagree). Where fewer than REFINE_BELOW cells are lit that is too coarse:
        // a crescent a pixel or two thick, or a body a few pixels across, lies between the
        // corners, and seen from them alone the frame showed nothing lit and took the
        // cheapest rung (an Artemis I frame at 161 deg, 1.3 off at the 99th percentile). Its
        // cells that may hold an edge (corners that disagree, or lines of sight that may meet
        // the limb between them) are then read on a grid of a pixel or less
        // ([`refined_cell`]). A ray-cast frame (a mesh) plans from its own estimate, not from
        // these, and is not refined.
        let coarse = |corners: &[(u8, bool); 4]| -> [f64; 3] {
            let (top_left, low) = corners[0];
            let a = if top_left == 2 { du * dv } else { 0.0 };
            let edge = holds_edge(corners.map(|c| c.0));
            [
                a,
                if low { a } else { 0.0 },
                if edge { (du * dv).sqrt() } else { 0.0 },
            ]
        };
        let corners_of = |i: usize, j: usize| {
            let c = |di: usize, dj: usize| classes[(j + dj) * (G + 1) + i + di];
            [c(0, 0), c(1, 0), c(0, 1), c(1, 1)]
        };
        let lit_cells = (0..G * G)
            .filter(|&k| classes[(k / G) * (G + 1) + k % G].0 == 2)
            .count();
        let refine = lit_cells < REFINE_BELOW && !scene.is_ray_cast();
        let cell = |k: usize| {
            let (i, j) = (k % G, k / G);
            let corners = corners_of(i, j);
            let (u0, v0) = (i as f64 * du, j as f64 * dv);
            if refine
                && (corners.iter().any(|x| x.0 != corners[0].0)
                    || tracer.coverage(u0, v0, du.max(dv)) == Coverage::Edge)
            {
                refined_cell(&tracer, pose, steep, u0, v0, du, dv)
            } else {
                coarse(&corners)
            }
        };
        let cells: Vec<[f64; 3]> = if refine {
            (0..G * G).into_par_iter().map(cell).collect()
        } else {
            (0..G * G).map(cell).collect()
        };
        let [lit_px, low_px, edge_px] = cells
            .iter()
            .fold([0.0; 3], |s, c| [s[0] + c[0], s[1] + c[1], s[2] + c[2]]);
        let phase_deg = pose
            .sun_position_m
            .angle_between(pose.camera_position_m)
            .to_degrees();
        // A pixel's footprint at the nearest surface point [m].
        let footprint_m = (range_m - radius_m).max(0.0) / f_px;
        let mut texture = 0.0;
        let mut relief_texture = 0.0;
        let mut footprint_texels = 0.0;
        if let Some((texel_m, contrast)) = &self.albedo {
            footprint_texels = footprint_m / texel_m;
            texture += level_contrast(contrast, footprint_texels);
        }
        if let Some((texel_m, change, _)) = self.relief {
            let fp = footprint_m / texel_m;
            // A slope's change moves the shading by about tan(incidence) times as much; a
            // pixel over several texels sees their changes average down as 1/sqrt.
            let per_px = if fp <= 1.0 {
                change * fp
            } else {
                change / fp.sqrt()
            };
            let incidence = (0.5 * phase_deg).min(80.0).to_radians();
            relief_texture = per_px * (1.0 + incidence.tan());
            texture += relief_texture;
        }
        Features {
            radius_px: (radius_m / range_m).min(1.0).asin() * f_px,
            lit_px,
            edge_px,
            phase_deg,
            range_m,
            footprint_texels,
            texture,
            shadow_share: if lit_px > 0.0 { low_px / lit_px } else { 0.0 },
            nonlinear_albedo: self.nonlinear_albedo,
            relief_texture,
            relief: if self
                .relief
                .is_some_and(|(_, change, steep)| change > 0.0 || steep > 0.0)
            {
                1.0
            } else {
                0.0
            },
            relief_per_pixel: 0.0,
            relief_refine: 1.0,
        }
    }
}

/// Below this many lit cells of the 64 x 64 probe, [`FrameProbe::features`] reads the cells
/// that may hold an edge a pixel apart.
const REFINE_BELOW: usize = 256;

/// A probe ray's class at `(u, v)` [px]: 0 misses the body, 1 dark, 2 lit; and whether the
/// Sun or the camera there is lower than the DEM's steep slope `steep` (a tangent): the
/// terrain may then hide the point from either (Eq. 33 marches both). With the Sun alone, the
/// NRHO's perilune frame (the Sun 21 to 52 deg up, the limb in view) showed no shadows,
/// and the planner took its shadows off and said it met the budget, where without them its
/// total is 1.1e-2 (`docs/performance.md`, "The DEM at 1024 x 1024").
fn probe_class(tracer: &Tracer, pose: &Pose, steep: f64, u: f64, v: f64) -> (u8, bool) {
    let tan_elevation = |mu: f64| mu / (1.0 - mu * mu).max(1e-30).sqrt();
    match tracer.shape_at(u, v) {
        None => (0, false),
        Some((p, n)) => {
            let s = (pose.sun_position_m - p).normalize();
            let mu0 = n.dot(s);
            if mu0 > 0.0 {
                let mu = n.dot((pose.camera_position_m - p).normalize());
                (2, tan_elevation(mu0) < steep || tan_elevation(mu) < steep)
            } else {
                (1, false)
            }
        }
    }
}

/// Whether a cell whose corners have these [`probe_class`]es holds the limb or the terminator:
/// a lit corner and another.
fn holds_edge(corners: [u8; 4]) -> bool {
    corners.contains(&2) && corners.iter().any(|&x| x != 2)
}

/// A probe cell `du` x `dv` [px] at `(u0, v0)` on a grid of a pixel or less: its lit area,
/// the part of it under the steep slopes and the length of the limb and the terminator in it
/// [px] (sub-cells with a lit corner and another class), each sub-cell read at its top-left
/// corner as the coarse grid reads its cells.
fn refined_cell(
    tracer: &Tracer,
    pose: &Pose,
    steep: f64,
    u0: f64,
    v0: f64,
    du: f64,
    dv: f64,
) -> [f64; 3] {
    let (nu, nv) = (du.ceil().max(1.0) as usize, dv.ceil().max(1.0) as usize);
    let (su, sv) = (du / nu as f64, dv / nv as f64);
    let mut class = vec![(0u8, false); (nu + 1) * (nv + 1)];
    for (k, c) in class.iter_mut().enumerate() {
        let (i, j) = (k % (nu + 1), k / (nu + 1));
        *c = probe_class(tracer, pose, steep, u0 + i as f64 * su, v0 + j as f64 * sv);
    }
    let mut out = [0.0; 3];
    for j in 0..nv {
        for i in 0..nu {
            let k = j * (nu + 1) + i;
            let c = [
                class[k].0,
                class[k + 1].0,
                class[k + nu + 1].0,
                class[k + nu + 2].0,
            ];
            if class[k].0 == 2 {
                out[0] += su * sv;
                if class[k].1 {
                    out[1] += su * sv;
                }
            }
            if holds_edge(c) {
                out[2] += (su * sv).sqrt();
            } else if c.contains(&0) && !c.contains(&2) {
                // A lune of light along the limb thinner than the grid (a crescent at high
                // phase): the limb itself, found between the sub-cell's top corners or its
                // left ones, is lit there. Counted as an edge sub-cell a quarter lit, and, over
                // a DEM, under its steep slopes: the camera grazes the limb there, lower than
                // any slope (counted lit alone, Artemis I row 850's lune, 161.8 deg, was
                // planned without shadows and measured 52 times its reference's light).
                let (u, v) = (u0 + i as f64 * su, v0 + j as f64 * sv);
                let hit = c[0] != 0;
                if (c[0] != c[1] && lit_at_limb(tracer, pose, (u, v), (u + su, v), hit))
                    || (c[0] != c[2] && lit_at_limb(tracer, pose, (u, v), (u, v + sv), hit))
                {
                    out[0] += 0.25 * su * sv;
                    if steep > 0.0 {
                        out[1] += 0.25 * su * sv;
                    }
                    out[2] += (su * sv).sqrt();
                }
            }
        }
    }
    out
}

/// Whether the surface is lit where the limb crosses the segment from `a` to `b` [px], whose
/// line of sight meets the body at `a` (`hit_at_a`) and misses it at `b`, or the reverse:
/// the limb is found by bisection to a thousandth of the segment.
fn lit_at_limb(tracer: &Tracer, pose: &Pose, a: (f64, f64), b: (f64, f64), hit_at_a: bool) -> bool {
    let (mut hit, mut miss) = if hit_at_a { (a, b) } else { (b, a) };
    let mut surface = tracer.shape_at(hit.0, hit.1);
    for _ in 0..10 {
        let m = (0.5 * (hit.0 + miss.0), 0.5 * (hit.1 + miss.1));
        match tracer.shape_at(m.0, m.1) {
            Some(s) => {
                hit = m;
                surface = Some(s);
            }
            None => miss = m,
        }
    }
    surface.is_some_and(|(p, n)| n.dot((pose.sun_position_m - p).normalize()) > 0.0)
}

/// The per-scene state of the planner: the budget, the model and the scene's probe.
pub struct Planner {
    budget: Budget,
    model: ErrorModel,
    base: Settings,
    probe: FrameProbe,
    has_horizon: bool,
    /// The finer of the DEM's and the albedo map's texels over the map's, where the relief's
    /// shading may be read over each pixel's footprint with the map ([`MapFilter::Relief`]:
    /// an undisplaced DEM and an albedo map); `None` elsewhere.
    finest_over_map_texels: Option<f64>,
    /// Whether the model was fitted on frames with a DEM of the scene's kind (one that
    /// tilts the normals and casts shadows without displacing the surface), so that such a
    /// frame may claim the budget ([`UNFITTED_DEM`]).
    relief_fitted: bool,
}

/// The footprint, in the finer of the map's and the DEM's texels, from which the planner
/// reads the relief over each pixel ([`MapFilter::Relief`]): the footprint step then reads a
/// pixel at 2 x 2 points or more (half a texel apart). On `config/nrho_textured.toml` (the
/// centres of NRHO frames at their own pixel scale, 256 x 256 at apolune and 128 x 128 else,
/// against the reference; the quadrangles at the rung the planner took before):
///
/// | frame | footprint | quadrangles: median / p99 / total | relief |
/// | --- | --- | --- | --- |
/// | apolune, 71,222 km | 3.4 texels | 1.0e-2 / 0.47 / 4.6e-5 (2 per px) | 8.3e-4 / 0.12 / 4.8e-5 |
/// | 31,444 km | 1.0 | 2.2e-2 / 0.44 / 5.2e-4 (1/4) | 9.3e-4 / 2.6e-2 / 1.5e-5 (1/16) |
/// | 19,661 km | 0.62 | 1.6e-2 / 0.16 / 4.2e-4 (1/16) | 5.1e-4 / 6.3e-3 / 3.4e-6 (1/16) |
/// | 9,876 km, 125 deg | 0.28 | 2.9e-3 / 0.80 / 5.2e-5 (2) | 2.0e-3 / 1.0 / 1.2e-3 (1/4) |
///
/// With one read a pixel (the last row) a pixel whose read is in shadow is dark however much
/// of it is lit: 433 of its 11,385 lit pixels. Below this footprint the quadrangles resolve
/// the relief's shading better, and each pixel's own shadow rays would cost more than theirs
/// (a million lit pixels at perilune).
const RELIEF_FOOTPRINT_TEXELS: f64 = 0.5;

impl Planner {
    /// `base`: the scene's own `[render]` settings, whose other knobs (threads, depth,
    /// gridding) every plan keeps.
    pub fn new(scene: &Scene, base: &Settings, budget: Budget, model: ErrorModel) -> Planner {
        Planner {
            budget,
            relief_fitted: model.fitted_on_relief()
                && scene.body.relief.as_ref().is_none_or(|r| !r.displaces()),
            model,
            base: base.clone(),
            probe: FrameProbe::new(scene),
            has_horizon: scene.body.relief.as_ref().is_some_and(|r| r.has_horizon()),
            finest_over_map_texels: match (&scene.body.relief, &scene.body.albedo_map) {
                (Some(r), Some(a)) if !r.displaces() => {
                    Some((r.heights_m.spacing_rad().1 / a.map.spacing_rad().1).min(1.0))
                }
                _ => None,
            },
        }
    }

    pub fn budget(&self) -> Budget {
        self.budget
    }

    /// The error model the planner predicts with.
    pub fn model(&self) -> &ErrorModel {
        &self.model
    }

    /// Whether the planner may read the relief over each pixel ([`MapFilter::Relief`]) on
    /// this scene's frames: a DEM of the kind the model was fitted on, under an albedo map.
    pub fn may_read_relief(&self) -> bool {
        self.relief_fitted && self.finest_over_map_texels.is_some()
    }

    /// The settings of the ladder's rung at `points_per_px` over `base`.
    pub fn rung(base: &Settings, points_per_px: f64) -> Settings {
        Settings {
            points: PointBudget::PerPixel(points_per_px),
            integration: Integration::Midpoint {
                points_per_deg: 5.0,
            },
            boundary_nodes: if points_per_px >= 4.0 {
                8
            } else if points_per_px >= 2.0 {
                6
            } else {
                4
            },
            map_filter: MapFilter::Pixel,
            ..base.clone()
        }
    }

    /// The ladder's rung at `points_per_px` over `base` as the planner renders a frame
    /// showing `features` within the model's domain: with the shadows
    /// ([`Planner::shadowing`]) and the map filter ([`Planner::map_filter`], or `map_filter`
    /// where given: the relief read over each pixel where the quadrangles' ladder falls short,
    /// [`Planner::plan`]) it takes for that frame. The sweep renders these (`rung = p` in a
    /// sweep file, over the setting's own keys, and `rung_map_filter`) to fit the model on
    /// what the planner renders.
    pub fn planned(
        &self,
        base: &Settings,
        features: &Features,
        points_per_px: f64,
        map_filter: Option<MapFilter>,
    ) -> Settings {
        Settings {
            self_shadowing: self.shadowing(features),
            map_filter: map_filter.unwrap_or_else(|| self.map_filter(features)),
            ..Planner::rung(base, points_per_px)
        }
    }

    /// A ray-cast frame's plan: clipped exactly where `clip` (a lone mesh through a pinhole,
    /// no scattered light: as fast as the edges' rays at 8 per side on Bennu at 1024 x 1024,
    /// faster at smaller sizes, and without their sampling error, which at high phase stayed
    /// above the budget at 64 per side); else at least [`RAYCAST_FIRST_EDGE_SAMPLES`] rays
    /// per side at the edges, then refined to the budget's 99th percentile and total as the
    /// frame estimates its own error. Its prediction waits for the frame ([`Plan::observe`]).
    fn ray_cast_plan(&self, features: Features, clip: bool) -> Plan {
        let b = self.budget;
        let settings = if clip {
            Settings {
                raycast_clip: true,
                raycast_budget: None,
                ..self.base.clone()
            }
        } else {
            Settings {
                raycast_edge_samples: self
                    .base
                    .raycast_edge_samples
                    .max(RAYCAST_FIRST_EDGE_SAMPLES),
                raycast_budget: Some(crate::raycast::estimate::RaycastBudget {
                    p99: b.p99,
                    total: b.total,
                }),
                ..self.base.clone()
            }
        };
        Plan {
            points_per_pixel: 0.0,
            raycast_edge_samples: if clip {
                0
            } else {
                settings.raycast_edge_samples
            },
            raycast_clip: clip,
            boundary_nodes: 0,
            self_shadowing: settings.self_shadowing,
            map_filter: settings.map_filter,
            relief_refine: 1,
            relief_read_scale: 1.0,
            predicted: Predicted {
                median: f64::NAN,
                p99: f64::NAN,
                total: f64::NAN,
            },
            meets_budget: false,
            outside_model: None,
            renders: 1,
            budget: b,
            features,
            settings,
        }
    }

    /// How the frame's shadows are cast: none when the Sun is above the DEM's steep slopes
    /// everywhere in view; the horizon map (one lookup a point) when the pixels it gets wrong
    /// stay a tenth of the 1 % the 99th percentile allows; else ray marching (exact to the
    /// DEM).
    pub fn shadowing(&self, f: &Features) -> SelfShadowing {
        if self.probe.relief.is_none() || f.shadow_share < 1e-3 {
            SelfShadowing::Off
        } else if self.has_horizon && f.shadow_share * HORIZON_MAP_MISSES < 1e-3 {
            SelfShadowing::HorizonMap
        } else {
            SelfShadowing::RayMarching
        }
    }

    /// How the frame reads the albedo map: over each pixel's footprint
    /// ([`MapFilter::Pixel`]), unless the lit surface is on average thinner than a pixel
    /// (fewer lit pixels than pixels along the limb and the terminator: a crescent at high
    /// phase), where it is read per quadrangle ([`MapFilter::Area`]). The footprint step
    /// casts 8 x 8 lines of sight over such a pixel, of which one or two columns meet a lune
    /// 0.1-0.3 px wide that spans a hundred texels from the limb to the terminator: on
    /// Artemis I row 852 (161 deg) it measured median 1.1e-2, p99 0.14, total 1.0e-3 at 16
    /// quadrangles per pixel, where the quadrangles' own reads measure 1.2e-4, 1.8e-3 and
    /// 7.4e-5 (`docs/performance.md`, "A crescent thinner than a pixel"). Over an
    /// undisplaced DEM [`Planner::plan`] weighs the relief's reads against these
    /// quadrangles, and takes the reads on the Artemis I lunes.
    ///
    /// With an undisplaced DEM, where a pixel's footprint spans at least
    /// [`RELIEF_FOOTPRINT_TEXELS`] of the finer texels, the relief's shading and shadows are
    /// read over each pixel too ([`MapFilter::Relief`]): the quadrangles, which spread a
    /// quadrangle's light over the pixels it covers, left the LOLA Moon at the NRHO's apolune
    /// (2.4 DEM texels a pixel) at median 1.0e-2 and 2.6e-3 with 2 and 16 quadrangles per
    /// pixel; read over each pixel, 8.3e-4 at 1 (`docs/performance.md`, "The relief over
    /// each pixel"). Nearer, [`Planner::plan`] takes those reads where they are predicted
    /// to meet the budget at a lower cost than the quadrangles.
    pub fn map_filter(&self, f: &Features) -> MapFilter {
        if f.thinner_than_a_pixel() {
            MapFilter::Area
        } else if self
            .finest_over_map_texels
            .is_some_and(|k| f.footprint_texels >= RELIEF_FOOTPRINT_TEXELS * k)
        {
            MapFilter::Relief
        } else {
            MapFilter::Pixel
        }
    }

    /// Why the frame of `scene` from `pose` lies outside what the error model was fitted on
    /// (`config/error_model.toml`: spheres, a 1.25 : 1 : 0.8 ellipsoid and the LOLA Moon,
    /// Lambert and Hapke with lunar parameters, from 70,000 km down to Artemis I's close
    /// approach 131 km over the Moon, 0.075 radii), or `None`. Found by the stability suite
    /// (`docs/stability.md`, "Under the budget"): frames there that the model said met the
    /// budget measured, at 1 m over the ground, total 2.5e-4 (predicted 1.5e-6); on a 10 : 1
    /// ellipsoid, p99 0.13 (2.3e-2); under a 50 km cliff, total 6.5e-4 (3.8e-5); beside a
    /// 300 km spike, p99 0.34 (3.0e-2); with an opposition surge 1e-6 wide, p99 3.0e-2 at
    /// phase 0 (2.7e-2).
    pub fn outside_model(&self, scene: &Scene, pose: &Pose) -> Option<&'static str> {
        let shape = &scene.body.shape;
        let r = shape.bounding_radius_m();
        if (pose.camera_position_m.length() - r) / r < MIN_ALTITUDE_RADII {
            return Some("the camera is nearer the body than the model was fitted at");
        }
        let inner = shape.inner_radius_m();
        if inner > 0.0 && r / inner > MAX_ELONGATION {
            return Some("the body is more elongated than the model was fitted on");
        }
        if let Some(relief) = &scene.body.relief
            && relief.height_span_m() > MAX_RELIEF_RADII * r
        {
            return Some("the DEM's relief is taller than the model was fitted on");
        }
        if let crate::brdf::Brdf::Hapke(h) = &scene.body.brdf {
            let p = h.params();
            let narrow = |b0: f64, width: f64| b0 > 0.0 && width < MIN_OPPOSITION_WIDTH;
            if narrow(p.b0_s, p.h_s) || narrow(p.b0_c, p.h_c) {
                return Some("Hapke's opposition surge is narrower than the model was fitted on");
            }
        }
        None
    }

    /// The ladder's predictions for a frame showing `features` read through `map_filter`:
    /// every rung, and where each pixel reads the relief every rung again with its pixels
    /// read more finely where their reads disagree (`relief_refine`, at least the base's),
    /// cheapest first, the reads' refinement costing more than the quadrangles (at the NRHO's
    /// apolune 0.8 s at 1 per pixel, 4.4 s read again 4 times as finely).
    fn ladder(&self, features: &Features, map_filter: MapFilter) -> Vec<Candidate> {
        let modelled = features.modelled(map_filter);
        let refines: Vec<u32> = if map_filter == MapFilter::Relief {
            let finest = RELIEF_REFINES[RELIEF_REFINES.len() - 1];
            // A lune thinner than a pixel is read at the finest refinement at once: its
            // reads' own estimates, which refine a frame again ([`Planner::refined_again`]),
            // miss light that both of a pixel's reads miss. On Artemis I rows 852, 853, 854
            // and 856 (160-161 deg) the reads at `k` 2 measured medians 7.6e-3 to 5.0e-2 and
            // p99s 0.85 to 1.6 where their own estimates said the p99 met the budget; on
            // 852-858 at 8, 3.7e-4 to 3.6e-3 and 3.8e-2 to 0.75 (`docs/performance.md`, "The
            // crescents read over each pixel").
            let floor = if features.thinner_than_a_pixel() {
                finest
            } else {
                self.base.relief_refine.min(finest)
            };
            RELIEF_REFINES
                .iter()
                .copied()
                .filter(|&k| k >= floor)
                .collect()
        } else {
            vec![self.base.relief_refine]
        };
        refines
            .iter()
            .flat_map(|&k| {
                let f = modelled.refined(k);
                LADDER.iter().map(move |&ppp| Candidate {
                    map_filter,
                    points_per_px: ppp,
                    relief_refine: k,
                    predicted: self.model.predict(ppp, &f),
                })
            })
            .collect()
    }

    /// The cheapest rung ([`relative_cost`]) predicted to meet the budget for the frame of
    /// `scene` from `pose`; for a ray-cast frame, its edges refined to the budget as it is
    /// cast.
    pub fn plan(&self, scene: &Scene, pose: &Pose) -> Plan {
        let features = self.probe.features(scene, pose);
        if scene.is_ray_cast() {
            let clip = self.base.scattering_orders == 0
                && crate::raycast::exact::applies(scene, pose).is_ok();
            return self.ray_cast_plan(features, clip);
        }
        let outside = self.outside_model(scene, pose);
        // Outside the model, its features are not trusted either: shadows are marched.
        let shadows = match outside {
            Some(_) if self.probe.relief.is_some() => SelfShadowing::RayMarching,
            _ => self.shadowing(&features),
        };
        let map_filter = self.map_filter(&features);
        let b = self.budget;
        let fits = |p: &Predicted| p.median <= b.median && p.p99 <= b.p99 && p.total <= b.total;
        let mut predicted = self.ladder(&features, map_filter);
        // Where a pixel is finer than the relief's texels and the Sun casts its shadows, the
        // quadrangles leave the shadows' edges coarse: on the NRHO at 130 deg of phase (rows
        // 152 and 167, 0.19 and 0.09 texels a pixel) they measured p99 0.12 at 16 per pixel,
        // where each pixel's reads, refined 8 times, measured 2.9e-2 and 2.8e-2 at 1/16
        // (`docs/performance.md`, "The relief over each pixel at 130 degrees"). Those reads
        // cost about a second a frame and more (a shadow ray a read), and the quadrangles'
        // marched shadows about as much per quadrangle per pixel, so both ladders are
        // candidates and the cheapest predicted to meet the budget is taken
        // ([`relative_cost`]): beside the first perilune (NRHO row 180) the quadrangles at 16
        // per pixel met it in 17.3 s (p99 6.95e-3), the reads at 1/16, `k` 2, which the
        // planner now takes, in 15.6 s (1.41e-3); at `k` 1 they met it in 2.4 s, which the
        // model, fitted at `k` 1 on frames at 86-130 deg alone, does not predict
        // (`docs/performance.md`, "Between the two ladders by cost").
        //
        // A lune thinner than a pixel (`MapFilter::Area`) is a candidate for the reads too:
        // they read the pixels the limb cuts in strips along it, where the quadrangles
        // spread a lune over the pixels it crosses. Against references read warped at the
        // limb (model 10), Artemis I rows 854, 856 and 858 (160-161 deg) measured totals
        // 1.9e-2, 1.5e-2, 1.0e-2 and p99s 1.0, 1.0, 0.64 planned `Area` at 16 per pixel;
        // the reads at 2 per pixel, `k` 8, 8.4e-5, 1.8e-4, 1.2e-4 and 0.14, 6.9e-2, 3.8e-2
        // (`docs/performance.md`, "The crescents read over each pixel").
        if matches!(map_filter, MapFilter::Pixel | MapFilter::Area)
            && outside.is_none()
            && self.relief_fitted
            && self.finest_over_map_texels.is_some()
            && shadows != SelfShadowing::Off
        {
            predicted.extend(self.ladder(&features, MapFilter::Relief));
        }
        // A figure no rung is predicted to meet (a textured frame's median, which more
        // quadrangles do not lower) does not hold back the others: a rung is then taken when
        // it meets the figures that can be met and comes within NEAR_BEST of the ladder's best
        // prediction on the others.
        let best = |get: fn(&Predicted) -> f64| {
            predicted
                .iter()
                .map(|c| get(&c.predicted))
                .fold(f64::INFINITY, f64::min)
        };
        let (best_median, best_p99, best_total) =
            (best(|q| q.median), best(|q| q.p99), best(|q| q.total));
        let near = |value: f64, budget: f64, best: f64| {
            value <= budget || (best > budget && value <= NEAR_BEST * best)
        };
        let good_enough = |q: &Predicted| {
            near(q.median, b.median, best_median)
                && near(q.p99, b.p99, best_p99)
                && near(q.total, b.total, best_total)
        };
        let top = predicted[predicted.len() - 1];
        // A frame with nothing lit has no error to budget: the cheapest rung, predicted
        // exact (the model's figures there are an extrapolation to no lit pixel at all:
        // Artemis I rows 764-823 reported p99 2.0e-2 to 4.7e-2 with nothing to err on).
        let (chosen, meets) = if features.lit_px == 0.0 {
            (
                Candidate {
                    predicted: Predicted::default(),
                    ..predicted[0]
                },
                true,
            )
        } else if outside.is_some() {
            (top, false)
        } else if let Some(&chosen) = predicted
            // The cheapest candidate predicted to meet the budget (the first of equals).
            .iter()
            .filter(|c| fits(&c.predicted))
            .min_by(|a, b| a.cost(shadows).total_cmp(&b.cost(shadows)))
        {
            (chosen, true)
        } else {
            // Where no candidate is good enough on every figure (the relief's reads at 130
            // deg, predicted over the median's budget where the quadrangles are not, and
            // under the p99's where they are far over it), the first whose worst figure,
            // over its budget, is within NEAR_BEST of the least.
            let over = |q: &Predicted| {
                (q.median / b.median)
                    .max(q.p99 / b.p99)
                    .max(q.total / b.total)
            };
            let least = predicted
                .iter()
                .map(|c| over(&c.predicted))
                .fold(f64::INFINITY, f64::min);
            let chosen = predicted
                .iter()
                .find(|c| good_enough(&c.predicted))
                .or_else(|| {
                    predicted
                        .iter()
                        .find(|c| over(&c.predicted) <= NEAR_BEST * least)
                })
                .copied()
                .unwrap_or(top);
            (chosen, false)
        };
        // A DEM the model has not seen: its prediction is not claimed (a flat DEM's changes
        // nothing).
        let unfitted = (outside.is_none()
            && features.relief > 0.0
            && features.lit_px > 0.0
            && !self.relief_fitted)
            .then_some(UNFITTED_DEM);
        let meets = meets && unfitted.is_none();
        let outside = outside.or(unfitted);
        let settings = Settings {
            self_shadowing: shadows,
            relief_refine: chosen.relief_refine,
            ..self.planned(
                &self.base,
                &features,
                chosen.points_per_px,
                Some(chosen.map_filter),
            )
        };
        Plan {
            points_per_pixel: chosen.points_per_px,
            raycast_edge_samples: 0,
            raycast_clip: false,
            boundary_nodes: settings.boundary_nodes,
            self_shadowing: shadows,
            map_filter: settings.map_filter,
            relief_refine: if settings.map_filter == MapFilter::Relief {
                settings.relief_refine
            } else {
                1
            },
            relief_read_scale: self.model.read_scale(settings.relief_refine, &features),
            predicted: chosen.predicted,
            meets_budget: meets,
            outside_model: outside,
            renders: 1,
            budget: b,
            features,
            settings,
        }
    }

    /// The plan of a frame rendered at `plan` (with `stats`) again with its reads refined
    /// twice as finely, where its own estimate of its reads' p99 (times the factor at its
    /// refinement, [`Plan::observe`]) is over the budget's and a finer refinement is left; else
    /// `None`. The quadrangles, the shadows and the map filter stay; the prediction is the
    /// model's at the new refinement until that frame is observed in turn.
    ///
    /// The model plans from features probed on a coarse grid, which can miss what only the
    /// rendered reads see: on Artemis I row 730 (191 km up, 108 deg of phase) the Sun's
    /// shadows and the ridges' hiding leave the light in strips 0.02-0.03 px across, and
    /// the plan (1 quadrangle per pixel, `relief_refine` 2) measured p99 7.0e-2, where its
    /// reads' own estimate said 5.4e-2; rendered again at 4, then 8, it measured 1.67e-2
    /// (`docs/performance.md`, "A frame over its own estimate renders again"). A frame
    /// outside the model (`outside_model`) is at the ladder's top already and is left.
    pub fn refined_again(&self, plan: &Plan, stats: &crate::render::FrameStats) -> Option<Plan> {
        if plan.outside_model.is_some() {
            return None;
        }
        let own_p99 = plan.own_read_p99(stats)?;
        if own_p99.is_nan() || own_p99 <= plan.budget.p99 {
            return None;
        }
        let k = RELIEF_REFINES
            .iter()
            .copied()
            .find(|&k| k > plan.relief_refine)?;
        let f = plan.features.modelled(MapFilter::Relief).refined(k);
        let predicted = self.model.predict(plan.points_per_pixel, &f);
        let b = plan.budget;
        Some(Plan {
            relief_refine: k,
            relief_read_scale: self.model.read_scale(k, &plan.features),
            predicted,
            meets_budget: predicted.median <= b.median
                && predicted.p99 <= b.p99
                && predicted.total <= b.total,
            renders: plan.renders + 1,
            settings: Settings {
                relief_refine: k,
                ..plan.settings.clone()
            },
            ..plan.clone()
        })
    }

    /// Plans the frame of `scene` from `pose`, renders it with `render` and observes it,
    /// rendering it again while it is over its own estimate ([`Planner::refined_again`]):
    /// the last frame and its plan. `render` renders the frame at the settings it is given
    /// (a caller may add to them, such as the depth plane).
    pub fn render<E>(
        &self,
        scene: &Scene,
        pose: &Pose,
        mut render: impl FnMut(&Settings) -> Result<crate::render::Frame, E>,
    ) -> Result<(Plan, crate::render::Frame), E> {
        let mut plan = self.plan(scene, pose);
        loop {
            let frame = render(&plan.settings)?;
            plan.observe(&frame.stats);
            match self.refined_again(&plan, &frame.stats) {
                Some(next) => plan = next,
                None => return Ok((plan, frame)),
            }
        }
    }
}

/// The frame of `scene` from `pose` as `planner` plans and renders it ([`Planner::render`]),
/// or at `settings` without a planner (`fidelity = "fixed"`): the frame and its plan.
pub fn render_as_planned<E>(
    planner: Option<&Planner>,
    scene: &Scene,
    pose: &Pose,
    settings: &Settings,
    mut render: impl FnMut(&Settings) -> Result<crate::render::Frame, E>,
) -> Result<(Option<Plan>, crate::render::Frame), E> {
    match planner {
        Some(p) => p
            .render(scene, pose, render)
            .map(|(plan, frame)| (Some(plan), frame)),
        None => render(settings).map(|frame| (None, frame)),
    }
}

/// A map's relative change between neighbouring pixels whose footprint spans `fp` texels:
/// a fraction of a texel's change while texels are larger than pixels, else the contrast of
/// the level whose texels match the footprint (interpolated in `log2 fp`).
fn level_contrast(contrast: &[f64], fp: f64) -> f64 {
    if contrast.is_empty() {
        return 0.0;
    }
    if fp <= 1.0 {
        return contrast[0] * fp;
    }
    let lod = fp.log2();
    let k = (lod.floor() as usize).min(contrast.len() - 1);
    let t = (lod - k as f64).min(1.0);
    let next = contrast[(k + 1).min(contrast.len() - 1)];
    (1.0 - t) * contrast[k] + t * next
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(ppp: f64, texture: f64, median: f64) -> FitRow {
        FitRow {
            points_per_px: ppp,
            features: Features {
                texture,
                lit_px: 1000.0,
                edge_px: 10.0,
                ..Default::default()
            },
            median,
            p99: 10.0 * median,
            total: 0.1 * median,
            relief_read_p99: f64::NAN,
        }
    }

    /// Frames made by a known law (an edge, an inside and a reflectance term for each
    /// figure) are fitted back to that law with a margin of 1; a noisy row raises the margin
    /// so that the prediction still bounds every row.
    #[test]
    fn the_fit_recovers_the_law_that_made_the_frames() {
        let two = |scale: f64| FigureModel {
            margin: 1.0,
            relief_margin: None,
            relief_margin_reads: None,
            relief_margin_coarse: None,
            term: vec![
                Term {
                    x: Regressors::Edge,
                    k: vec![scale.ln() - 1.0, -1.2, 0.9, 0.8],
                },
                Term {
                    x: Regressors::Inside,
                    k: vec![scale.ln() - 2.0, -0.3, 1.1, -0.05],
                },
                Term {
                    x: Regressors::Reflectance,
                    k: vec![scale.ln() - 3.0, -0.1, 0.5],
                },
            ],
        };
        let law = ErrorModel {
            median: two(0.05),
            p99: two(1.0),
            total: two(1e-4),
            frames: 0,
            relief_read: Vec::new(),
        };
        let mut rows = Vec::new();
        for &t in &[0.0, 0.01, 0.1] {
            for &edge in &[5.0, 20.0, 50.0, 200.0] {
                for (phase, h) in [0.0, 60.0, 120.0]
                    .into_iter()
                    .flat_map(|g| [(g, 0.0), (g, 1.0)])
                {
                    for &p in &LADDER {
                        let mut r = row(p, t, 0.0);
                        r.features.edge_px = edge;
                        r.features.phase_deg = phase;
                        r.features.nonlinear_albedo = h;
                        let e = law.predict(p, &r.features);
                        (r.median, r.p99, r.total) = (e.median, e.p99, e.total);
                        rows.push(r);
                    }
                }
            }
        }
        let m = ErrorModel::fit(&rows).unwrap();
        for r in &rows {
            let (a, b) = (
                m.predict(r.points_per_px, &r.features),
                law.predict(r.points_per_px, &r.features),
            );
            for (x, y) in [(a.median, b.median), (a.p99, b.p99), (a.total, b.total)] {
                assert!((x / y - 1.0).abs() < 1e-6, "{a:?} against {b:?}");
            }
        }
        assert!(m.median.margin < 1.0 + 1e-6 && m.total.margin < 1.0 + 1e-6);
        let mut noisy = rows[5];
        noisy.median *= 3.0;
        rows.push(noisy);
        let m = ErrorModel::fit(&rows).unwrap();
        for r in &rows {
            assert!(m.median.predict(r.points_per_px, &r.features) >= r.median * (1.0 - 1e-9));
        }
        // The shipped model parses and round-trips.
        let shipped = ErrorModel::shipped().unwrap();
        assert_eq!(ErrorModel::parse(&shipped.to_toml(), "x").unwrap(), shipped);
    }

    /// Frames with a DEM fit the relief term over the other terms held fixed: those terms,
    /// and so every prediction for a frame without a DEM, are the same as when fitted
    /// without them; a law's relief term is recovered, and a noisy DEM frame raises the
    /// relief margin alone.
    #[test]
    fn frames_with_a_dem_fit_their_own_term_and_margin_and_leave_the_rest() {
        let plain = |p: f64, t: f64, edge: f64| {
            let mut r = row(p, t, 1e-3 * (t + 1e-3) / p.sqrt() + 1e-5 * edge / p);
            r.features.edge_px = edge;
            r.p99 = 30.0 * r.median;
            r.total = 0.05 * r.median;
            r
        };
        let mut rows: Vec<FitRow> = Vec::new();
        for &t in &[0.0, 0.01, 0.1] {
            for &edge in &[5.0, 50.0, 200.0] {
                for &p in &LADDER {
                    rows.push(plain(p, t, edge));
                }
            }
        }
        let without = ErrorModel::fit(&rows).unwrap();
        assert!(!without.fitted_on_relief());
        // The relief's own law: k . (1, ln p, ln(S + 1e-3), ln(R + 1e-3), ln(sin(g / 2) +
        // 0.05), P, P ln p, P ln refine).
        let k = [-3.0, -0.6, 0.8, 0.4, 0.5, 1.0, 0.3, -0.7];
        let mut with = rows.clone();
        for &s in &[0.01, 0.1, 0.3] {
            for (rt, per_px, refine) in [
                (0.0, 1.0, 1),
                (0.0, 1.0, 2),
                (0.0, 1.0, 8),
                (0.02, 0.0, 1),
                (0.2, 0.0, 1),
            ] {
                for &g in &[30.0, 90.0, 130.0] {
                    for &p in &LADDER {
                        let mut r = plain(p, 0.05, 50.0);
                        r.features.relief = 1.0;
                        r.features.shadow_share = s;
                        r.features.relief_texture = rt;
                        r.features.relief_per_pixel = per_px;
                        r.features.phase_deg = g;
                        r.features = r.features.refined(refine);
                        let base = without.median.modelled(p, &r.features);
                        let x = Regressors::Relief.values(p, &r.features);
                        r.median = base + dot(&k, &x).exp();
                        with.push(r);
                    }
                }
            }
        }
        let m = ErrorModel::fit(&with).unwrap();
        assert!(m.fitted_on_relief());
        let first_three = |f: &FigureModel| f.term[..3].to_vec();
        for (a, b) in [
            (&m.median, &without.median),
            (&m.p99, &without.p99),
            (&m.total, &without.total),
        ] {
            assert_eq!(first_three(a), first_three(b));
            assert_eq!(a.margin, b.margin);
        }
        for r in &rows {
            assert_eq!(
                m.predict(r.points_per_px, &r.features),
                without.predict(r.points_per_px, &r.features)
            );
        }
        let relief = &m.median.term[3];
        assert_eq!(relief.x, Regressors::Relief);
        assert_eq!(relief.k.len(), k.len());
        for (a, b) in relief.k.iter().zip(k) {
            assert!((a - b).abs() < 1e-4, "{:?} against {k:?}", relief.k);
        }
        assert!(m.median.relief_margin.unwrap() < 1.0 + 1e-6);
        let mut noisy = with.clone();
        let last = noisy.len() - 1;
        noisy[last].median *= 3.0;
        let n = ErrorModel::fit(&noisy).unwrap();
        assert_eq!(n.median.margin, m.median.margin);
        assert!(n.median.relief_margin.unwrap() > 2.0);
        for r in &noisy {
            assert!(n.median.predict(r.points_per_px, &r.features) >= r.median * (1.0 - 1e-9));
        }
        // A frame whose pixels read the relief off the law sets the reads' margin alone; the
        // other frames with a DEM keep theirs.
        let reads = noisy
            .iter()
            .rposition(|r| {
                r.features.relief > 0.0
                    && ReliefKind::of(r.points_per_px, &r.features) == ReliefKind::Reads
            })
            .unwrap();
        assert!(n.median.relief_margin_reads.unwrap() < 1.5);
        noisy[reads].median *= 8.0;
        let c = ErrorModel::fit(&noisy).unwrap();
        let (reads_margin_c, other_c) = (
            c.median.relief_margin_reads.unwrap(),
            c.median.relief_margin.unwrap(),
        );
        assert!(reads_margin_c > 6.0, "{reads_margin_c}");
        assert!(
            other_c < 0.6 * reads_margin_c,
            "{other_c} against {reads_margin_c}"
        );
        for r in &noisy {
            let p = c.median.predict(r.points_per_px, &r.features);
            assert!(p >= r.median * (1.0 - 1e-9));
            if r.features.relief > 0.0 {
                let kind = ReliefKind::of(r.points_per_px, &r.features);
                let want = c.median.relief_margin_of(kind).or(c.median.relief_margin);
                assert_eq!(
                    c.median.margin_at(r.points_per_px, &r.features),
                    want.unwrap()
                );
            }
        }
        // The model with its relief term round-trips through its file.
        assert_eq!(ErrorModel::parse(&m.to_toml(), "x").unwrap(), m);
    }

    /// Under `MapFilter::Relief` the model reads the map's texture alone (the relief is read
    /// over each pixel as the map is); under the other filters the frame's whole texture.
    #[test]
    fn the_relief_read_over_each_pixel_leaves_the_models_texture() {
        let f = Features {
            texture: 0.12,
            relief_texture: 0.1,
            lit_px: 1000.0,
            ..Default::default()
        };
        let under = |m| f.modelled(m).texture;
        assert!((under(MapFilter::Relief) - 0.02).abs() < 1e-12);
        for m in [MapFilter::Pixel, MapFilter::Area, MapFilter::Point] {
            assert_eq!(under(m), 0.12);
        }
        let model = ErrorModel::shipped().unwrap();
        let p = |m| model.predict(1.0, &f.modelled(m)).median;
        assert!(p(MapFilter::Relief) < p(MapFilter::Pixel));
    }

    /// A relief frame's own estimate of its reads' p99 raises its prediction where it is the
    /// larger, and judges the budget again; it never lowers the model's.
    #[test]
    fn a_relief_frame_takes_its_reads_estimate_of_the_p99() {
        let plan = |map_filter| Plan {
            points_per_pixel: 1.0,
            raycast_edge_samples: 0,
            raycast_clip: false,
            boundary_nodes: 4,
            self_shadowing: SelfShadowing::RayMarching,
            map_filter,
            relief_refine: 1,
            relief_read_scale: 1.0,
            predicted: Predicted {
                median: 5e-4,
                p99: 1e-2,
                total: 1e-5,
            },
            meets_budget: true,
            outside_model: None,
            renders: 1,
            budget: Budget::default(),
            features: Features::default(),
            settings: Settings::default(),
        };
        let observed = |map_filter, p99: f64| {
            let mut p = plan(map_filter);
            p.observe(&crate::render::FrameStats {
                relief_read_p99: Some(p99),
                ..Default::default()
            });
            (p.predicted.p99, p.meets_budget)
        };
        assert_eq!(observed(MapFilter::Relief, 0.2), (0.2, false));
        assert_eq!(observed(MapFilter::Relief, 2e-2), (2e-2, true));
        assert_eq!(observed(MapFilter::Relief, 1e-3), (1e-2, true));
        assert_eq!(observed(MapFilter::Pixel, 0.2), (1e-2, true));
        // Scaled by the model's factor at its refinement.
        let mut p = plan(MapFilter::Relief);
        p.relief_read_scale = 0.25;
        p.observe(&crate::render::FrameStats {
            relief_read_p99: Some(0.1),
            ..Default::default()
        });
        assert_eq!((p.predicted.p99, p.meets_budget), (0.025, true));
    }

    /// Per refinement, the factor on the frames' own p99 estimates is the largest ratio of
    /// measured to estimated over the fitted frames that read the relief per pixel at one
    /// quadrangle per pixel or more (those that do not, have fewer quadrangles or have no
    /// estimate, do not count); a refinement with too few frames has none and takes the
    /// largest fitted, at least 1.
    #[test]
    fn the_reads_estimate_is_scaled_to_bound_the_fitted_frames() {
        let read = |k: f64, p99: f64, estimate: f64| FitRow {
            points_per_px: 1.0,
            features: Features {
                relief: 1.0,
                relief_per_pixel: 1.0,
                relief_refine: k,
                ..Default::default()
            },
            median: 1e-4,
            p99,
            total: 1e-5,
            relief_read_p99: estimate,
        };
        let mut rows: Vec<FitRow> = [0.25, 0.5, 1.0, 2.0]
            .iter()
            .map(|&e| read(8.0, 0.0625, e))
            .collect();
        rows.extend([0.25, 0.5, 1.0].iter().map(|&e| read(2.0, 0.0625, e)));
        rows.push(read(8.0, 0.5, f64::NAN));
        // Below one quadrangle per pixel the limb's quadrangles carry the p99: not fitted.
        rows.push(FitRow {
            points_per_px: 0.0625,
            ..read(8.0, 0.5, 0.1)
        });
        rows.push(FitRow {
            features: Features {
                relief_per_pixel: 0.0,
                ..rows[0].features
            },
            p99: 1.0,
            ..rows[0]
        });
        let scales = fit_read_scales(&rows);
        assert_eq!(
            scales,
            vec![ReadScale {
                relief_refine: 8,
                shadowed: None,
                scale: 0.25,
                frames: 4
            }]
        );
        let model = ErrorModel {
            relief_read: scales,
            ..ErrorModel::shipped().unwrap()
        };
        let plain = Features::default();
        assert_eq!(model.read_scale(8, &plain), 0.25);
        assert_eq!(model.read_scale(2, &plain), 1.0);
        let model = ErrorModel {
            relief_read: vec![ReadScale {
                relief_refine: 1,
                shadowed: None,
                scale: 3.0,
                frames: 5,
            }],
            ..model
        };
        assert_eq!(model.read_scale(4, &plain), 3.0);
        // The model file keeps them.
        let text = model.to_toml();
        assert_eq!(ErrorModel::parse(&text, "t").unwrap(), model);
    }

    /// At one read a pixel the frames mostly under shadows and the others get a factor each;
    /// a class the fit has too few frames of takes the largest factor fitted (at least 1),
    /// never the other class's; from 2 up, one factor for all.
    #[test]
    fn one_read_a_pixel_is_scaled_by_how_much_of_the_frame_is_shadowed() {
        let read = |k: f64, shadow_share: f64, p99: f64, estimate: f64| FitRow {
            points_per_px: 1.0,
            features: Features {
                relief: 1.0,
                relief_per_pixel: 1.0,
                relief_refine: k,
                shadow_share,
                ..Default::default()
            },
            median: 1e-4,
            p99,
            total: 1e-5,
            relief_read_p99: estimate,
        };
        let sunny: Vec<FitRow> = [(0.2, 0.125), (0.4, 0.25), (0.5, 0.5), (0.6, 0.5)]
            .iter()
            .map(|&(s, estimate)| read(1.0, s, 0.05, estimate))
            .collect();
        let shadowed: Vec<FitRow> = [0.8, 0.9, 0.95, 1.0]
            .iter()
            .map(|&s| read(1.0, s, 0.375, 0.125))
            .collect();
        let refined: Vec<FitRow> = [0.3, 0.5, 0.9, 1.0]
            .iter()
            .map(|&s| read(2.0, s, 0.03125, 0.25))
            .collect();
        let rows: Vec<FitRow> = [sunny.clone(), shadowed, refined.clone()].concat();
        let scales = fit_read_scales(&rows);
        let scale = |k: u32, shadowed: Option<bool>| {
            scales
                .iter()
                .find(|s| s.relief_refine == k && s.shadowed == shadowed)
                .map(|s| (s.scale, s.frames))
        };
        assert_eq!(scale(1, Some(false)), Some((0.4, 4)));
        assert_eq!(scale(1, Some(true)), Some((3.0, 4)));
        assert_eq!(scale(2, None), Some((0.125, 4)));
        assert_eq!(scales.len(), 3);
        let model = ErrorModel {
            relief_read: scales,
            ..ErrorModel::shipped().unwrap()
        };
        let share = |s: f64| Features {
            shadow_share: s,
            ..Default::default()
        };
        assert_eq!(model.read_scale(1, &share(0.3)), 0.4);
        assert_eq!(model.read_scale(1, &share(SHADOWED_SHARE)), 3.0);
        assert_eq!(model.read_scale(2, &share(1.0)), 0.125);
        assert_eq!(model.read_scale(2, &share(0.0)), 0.125);
        let text = model.to_toml();
        assert_eq!(ErrorModel::parse(&text, "t").unwrap(), model);
        // Without the shadowed frames, a shadowed frame is not given the others' factor.
        let model = ErrorModel {
            relief_read: fit_read_scales(&[sunny, refined].concat()),
            ..model
        };
        assert_eq!(model.read_scale(1, &share(0.9)), 1.0);
        assert_eq!(model.read_scale(1, &share(0.1)), 0.4);
    }

    #[test]
    fn contrast_follows_the_footprint() {
        let c = [0.2, 0.1, 0.05];
        assert_eq!(level_contrast(&c, 0.5), 0.1);
        assert_eq!(level_contrast(&c, 2.0), 0.1);
        assert!((level_contrast(&c, 2f64.sqrt() * 2.0) - 0.075).abs() < 1e-12);
        assert_eq!(level_contrast(&c, 100.0), 0.05);
    }
}
