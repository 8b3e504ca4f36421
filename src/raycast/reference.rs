//! The converged reference of any scene (`optistim render --reference`): each pixel's `(P/L)`
//! integrated over its footprint by adaptive cubature of ray casts ([`super::Tracer`]).
//!
//! On each square cell of a pixel two tensor Gauss-Legendre rules are compared, 2 x 2 and
//! 3 x 3 points (13 rays). The 3 x 3 value is kept when the two agree within
//! `tau * side` (`side` the cell's side in pixels, so the tolerances of the cells along a limb
//! or a shadow edge add up to about `tau` for the pixel), and the cell is cut in four otherwise,
//! down to `max_depth` halvings. `tau = tolerance * max(|I|, floor)` with `I` the pixel's first
//! estimate and `floor` a thousandth of the 99th percentile of the image's first estimates
//! (pixels darker than that are held to the same absolute error).
//!
//! Edges are where quadrature fails silently, so they are refined whatever the rules say:
//! - cells that may straddle the silhouette ([`Coverage::Edge`]) are cut down to `edge_depth`
//!   halvings (on a displaced DEM, whose silhouette test only bounds a band, only those whose
//!   rays partly meet the body): a sliver of limb between the rays, or a corner beyond the
//!   limb while every ray meets the body, was 8.8e-6 of a flat (Area) disk's light;
//! - cells whose rays are partly lit and partly dark (terminator, shadows) are cut down to
//!   `light_depth` halvings;
//! - every cell of a pixel whose own rays or a neighbour's disagree (hit and miss, lit and
//!   dark) is cut `near_depth` times: a lit crescent entering the pixel from a neighbour
//!   between its rays was lost (3.4e-3 of the light at 170 deg of phase before); so is every
//!   cell of a pixel around which the first rays are dark for different reasons, the Sun
//!   alone keeping some dark and the camera alone others ([`Tracer::dark_because`]): a strip
//!   lit between the Sun's shadow and the ground a ridge hides from the camera, thinner than
//!   the rays' spacing, was lost from whole pixels (Artemis I row 730, 191 km up at 108 deg:
//!   3 of 17 lit pixels of `tests/data/sliver_730.toml` at 0, its total 18.5 % dark); and
//!   every cell of a pixel whose rays or a neighbour's are lit where another's are dark: an
//!   edge running along a column of pixels between two pixels' rays (within 0.11 px of
//!   their common side) left the pixel on its dark side dark however much of it was lit
//!   (on 730, pixels 9 % lit);
//! - in those pixels, a cell whose 13 rays all agree (all lit, all dark) has its four corners
//!   cast as well, down to `corner_depth` halvings, and is cut when one of them disagrees: the
//!   terminator side of a lune of light thinner than a pixel slips between the rule's points,
//!   where a straight edge crossing the cell still shows at a corner. Without it the reference
//!   of a crescent 0.1-0.3 px wide (Artemis I row 852, 161 deg) lost 2.6e-4 of its light and
//!   3e-3 of its edge pixels', beyond its own estimate; with it, it agrees with the
//!   quadrangle renderer's exact Lambert integration to 6e-6 (3e-6 at 10 halvings);
//! - in those pixels, a cell accepted with its rays and corners agreeing is read by a lattice
//!   of `lattice_per_px` midpoints a pixel side over it, and takes the lattice's mean where one
//!   of its points disagrees ([`lattice_mean`]). Refining the cells whose rays catch a sliver
//!   and keeping those whose rays miss one loses slivers on average, however deep the cells
//!   go: on a 40 x 64 window of Artemis I row 882's grazing limb (lit ridge tops 0.01-0.05
//!   px across) the reference was 6.5e-4 of the window's light dark (9.3e-3 of its limb
//!   pixels') against brute-force lattices of 64, 128 and 256 points a pixel side, which
//!   agree to 1e-6, and 8 and 10 halvings agreed on it; with the lattice, 6e-6. A lattice
//!   catches a sliver in proportion to its width, so its errors change sign from sliver to
//!   sliver.
//!
//! A pixel the shape's limb cuts, where a DEM tilts the normals of an undisplaced sphere or
//! ellipsoid, is not read by cells: its light per unit of the image grows as the inverse
//! square root of the distance to the limb (Eq. 37's `mu / mu_shape`), where a cell at the
//! limb keeps an error of the order of the square root of its side whatever the rules say.
//! It is read by lattices warped at the limb ([`super::limb`]) of 32, 64, ... lines a side,
//! doubled until two agree within the pixel's tolerance or `limb_lattice_max` is reached: the
//! last is kept and their difference is its error estimate (bound and signed). Cells (model
//! 9, 6 halvings) had left Artemis I row 852's reference 6.1e-4 of its light off warped
//! lattices of 512 a side, where their signed estimate said 4.6e-5 (model 10: 1.8e-4 off, its
//! estimate 1.35e-4), and row 882's limb pixels 7-9e-5 of the frame's light off those of 64
//! and 128 (`docs/performance.md`, "The reference reads the limb warped").
//!
//! Cells whose lines of sight all miss the body's bounding volume are empty without a ray.
//! What remains is known: below `corner_depth`, a cell whose rays and corners are all lit
//! while the terminator cuts a side between them is taken as lit, which matters for a BRDF
//! whose radiance steps there (the Area model: 6.5e-6 of the total at 60 deg, beyond the
//! estimate, before the corners were asked).
//!
//! The error estimate of a pixel is the sum over its accepted cells of `|G3 - G2|`: an upper
//! estimate (it is the 2 x 2 rule's error; the kept 3 x 3 value is more accurate on smooth
//! cells). Cells still above their tolerance at `max_depth` are counted as unconverged.
//!
//! That bound is far above the error where shadows' edges cut many cells at the deepest
//! level: each such cell's `|G3 - G2|` is large, but their errors lie on both sides of the
//! edge and do not add up in one direction. The report therefore also gives the estimate
//! with the cells' signs kept ([`ReferenceReport::signed_error_total`] and
//! [`ReferenceReport::signed_error_p99`]: `|sum (G3 - G2)|` over the frame's, or a pixel's,
//! cells), an estimate, not a bound. On NRHO row 158 of the textured Moon with its DEM's
//! shadows (1024 x 1024, tolerance 1e-4), the reference at depth 6 against the one at
//! depth 8 measured total 1.0e-5 and p99 2.2e-4, its bound 1.4e-3 and 1.17e-2
//! (`docs/performance.md`, "A reference's error with its signs kept").
//!
//! Each pixel's cells are summed in a fixed order by one thread: the same scene and pose give
//! the same image, bit for bit, whatever the thread count.

use super::{Coverage, Tracer};
use crate::render::{Frame, FrameStats, RenderError, StageTimings};
use crate::scene::{Pose, Scene};
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

/// How far the reference integrates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ReferenceSettings {
    /// Relative tolerance per pixel (see the module's documentation).
    pub tolerance: f64,
    /// Most halvings of a pixel's side (10: cells of 1/1024 px).
    pub max_depth: u32,
    /// Halvings of cells that may straddle the silhouette before any is accepted.
    pub edge_depth: u32,
    /// Halvings of cells that straddle the edge of the light before any is accepted.
    pub light_depth: u32,
    /// Halvings down to which a cell of such a pixel whose rays all agree (all lit, all dark)
    /// has its four corners cast too, and is cut when one disagrees: a sliver of light
    /// thinner than the rule's spacing (the terminator side of a sub-pixel lune) is found.
    pub corner_depth: u32,
    /// Halvings of every cell of a pixel next to the silhouette or the edge of the light
    /// (the pixel or one of its eight neighbours has rays that disagree), before any is
    /// accepted: a lit sliver entering from a neighbour between the rule's points is found.
    pub near_depth: u32,
    /// Points per pixel side of the lattice that reads a cell of a pixel near an edge whose
    /// rays and corners all agree (all lit, all dark): where one of the lattice's midpoints
    /// over the cell disagrees, the cell takes their mean instead of its rule (0: no lattice,
    /// the reference before model 7). 32 left 9.7e-5 of 882's window dark, 64 6e-6.
    pub lattice_per_px: u32,
    /// Most lines of sight a side of the lattices warped at the limb that read a pixel the limb
    /// cuts where a DEM tilts the normals ([`super::limb`]): 32, 64, ... up to this, until two
    /// agree within the pixel's tolerance (below 64: none, the pixel is read by cells, the
    /// reference before model 10).
    pub limb_lattice_max: u32,
    /// Most cells accepted in one pixel: past it the pixel's remaining cells are accepted
    /// as they are (and counted unconverged), so that no pixel runs away.
    pub max_cells_per_px: u64,
    /// Worker threads (0 = all cores).
    pub threads: usize,
}

impl Default for ReferenceSettings {
    fn default() -> Self {
        ReferenceSettings {
            tolerance: 1e-6,
            max_depth: 10,
            edge_depth: 10,
            light_depth: 5,
            corner_depth: 7,
            near_depth: 3,
            lattice_per_px: 64,
            limb_lattice_max: 256,
            max_cells_per_px: 1 << 18,
            threads: 0,
        }
    }
}

/// Which reference a frame gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum ReferenceMethod {
    /// The exact one ([`super::exact`]) where it applies (a lone mesh body through an
    /// undistorted camera), else the adaptive cubature of ray casts of this module.
    #[default]
    Auto,
    /// The adaptive cubature of ray casts, whatever the scene.
    Cubature,
    /// The exact one, or an error naming why it does not apply.
    Exact,
}

impl ReferenceMethod {
    /// The method that `scene` seen from `pose` gets: [`ReferenceMethod::Cubature`] or
    /// [`ReferenceMethod::Exact`].
    pub fn resolve(self, scene: &Scene, pose: &Pose) -> ReferenceMethod {
        match self {
            ReferenceMethod::Auto if super::exact::applies(scene, pose).is_ok() => {
                ReferenceMethod::Exact
            }
            ReferenceMethod::Auto => ReferenceMethod::Cubature,
            m => m,
        }
    }
}

/// The reference of `scene` seen from `pose` by `method` (the cubature with `settings`).
pub fn render_by(
    scene: &Scene,
    pose: &Pose,
    settings: &ReferenceSettings,
    method: ReferenceMethod,
) -> Result<ReferenceFrame, RenderError> {
    match method.resolve(scene, pose) {
        ReferenceMethod::Exact => super::exact::render(scene, pose),
        _ => render(scene, pose, settings),
    }
}

/// How converged a reference frame is.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReferenceReport {
    /// `"cubature"` (with its settings) or `"exact"` ([`super::exact`]).
    pub method: &'static str,
    pub settings: Option<ReferenceSettings>,
    /// Rays cast.
    pub rays: u64,
    /// Cells accepted (leaves of the subdivision).
    pub cells: u64,
    /// Cells above their tolerance at the deepest level, and the pixels holding any.
    pub unconverged_cells: u64,
    pub unconverged_px: u64,
    /// The estimated error of the total (sum of the pixels' estimates over the total).
    pub est_error_total: f64,
    /// The estimated relative error per lit pixel (pixels above the floor): median, p99, max.
    pub est_error_median: f64,
    pub est_error_p99: f64,
    pub est_error_max: f64,
    /// The estimated error of the total with the cells' signs kept (`|sum (G3 - G2)|` over
    /// the total): an estimate, not a bound (the module's documentation). The exact
    /// reference's equals its bound.
    pub signed_error_total: f64,
    /// The 99th percentile per lit pixel of `|sum (G3 - G2)|` over each pixel's cells,
    /// relative to the pixel.
    pub signed_error_p99: f64,
    pub seconds: f64,
}

/// A reference frame: the image (and depth at the pixels' centres), each pixel's estimated
/// absolute error [sr m^2] and the report.
pub struct ReferenceFrame {
    pub frame: Frame,
    pub error_pl: Vec<f64>,
    pub report: ReferenceReport,
}

/// The 2 x 2 and 3 x 3 Gauss-Legendre nodes on [0, 1] and their weights.
const G2: [(f64, f64); 2] = [
    (0.211_324_865_405_187_1, 0.5),
    (0.788_675_134_594_812_9, 0.5),
];
const G3: [(f64, f64); 3] = [
    (0.112_701_665_379_258_3, 5.0 / 18.0),
    (0.5, 8.0 / 18.0),
    (0.887_298_334_620_741_7, 5.0 / 18.0),
];

/// One cell: its top-left corner [px], side [px] and depth.
#[derive(Clone, Copy)]
struct Cell {
    u: f64,
    v: f64,
    side: f64,
    depth: u32,
}

/// The two rules on a cell: `G2` and `G3` [sr m^2], the range at its centre, and how many of
/// its 13 rays met the body and how many brought light back.
fn rules(tracer: &Tracer, c: &Cell) -> (f64, f64, f64, u32, u32) {
    let (g2, g3, range, hits, lit, _) = rules_with(tracer, c, false);
    (g2, g3, range, hits, lit)
}

/// What a pixel's first rays found ([`rules_with`]'s bits): some lit, some meeting the body
/// dark, and of those, one the Sun alone keeps dark (it lights the point not, the camera sees
/// it) and one the camera alone keeps dark ([`Tracer::dark_because`]).
const LIT: u8 = 1;
const DARK: u8 = 2;
const SUN_ONLY: u8 = 4;
const CAMERA_ONLY: u8 = 8;

/// [`rules`], and with `ask_dark` the [`LIT`], [`DARK`], [`SUN_ONLY`] and [`CAMERA_ONLY`]
/// bits of its rays.
fn rules_with(tracer: &Tracer, c: &Cell, ask_dark: bool) -> (f64, f64, f64, u32, u32, u8) {
    let area = c.side * c.side;
    let (mut hits, mut lit, mut found) = (0, 0, 0u8);
    let mut cast = |u: f64, v: f64| {
        let hit = tracer.cast(u, v);
        hits += u32::from(hit.range_m.is_finite());
        lit += u32::from(hit.pl_per_px2 > 0.0);
        if ask_dark && hit.range_m.is_finite() {
            found |= if hit.pl_per_px2 > 0.0 {
                LIT
            } else {
                DARK | match tracer.dark_because(u, v) {
                    Some((true, false)) => SUN_ONLY,
                    Some((false, true)) => CAMERA_ONLY,
                    _ => 0,
                }
            };
        }
        hit
    };
    let mut g2 = 0.0;
    for &(a, wa) in &G2 {
        for &(b, wb) in &G2 {
            g2 += wa * wb * cast(c.u + a * c.side, c.v + b * c.side).pl_per_px2;
        }
    }
    let (mut g3, mut range) = (0.0, f64::NAN);
    for (i, &(a, wa)) in G3.iter().enumerate() {
        for (j, &(b, wb)) in G3.iter().enumerate() {
            let hit = cast(c.u + a * c.side, c.v + b * c.side);
            g3 += wa * wb * hit.pl_per_px2;
            if i == 1 && j == 1 {
                range = hit.range_m;
            }
        }
    }
    (g2 * area, g3 * area, range, hits, lit, found)
}

/// Whether any corner of cell `c` is lit when its rays are dark (`lit` false), or dark when
/// they are lit.
fn corners_disagree(tracer: &Tracer, c: &Cell, lit: bool) -> bool {
    [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
        .iter()
        .any(|&(a, b)| (tracer.cast(c.u + a * c.side, c.v + b * c.side).pl_per_px2 > 0.0) != lit)
}

/// The mean of `points` x `points` midpoints over cell `c`, times its area [sr m^2], where
/// one of them is dark when `lit` (the cell's rays are all lit), or lit when not; else None,
/// and the cell keeps its rule, which is the more accurate where the light is smooth.
///
/// Where a pixel near an edge holds slivers of light (or shadow) thinner than the rule's
/// spacing, an adaptive rule that cuts the cells whose rays catch a sliver and keeps those
/// whose rays miss it loses the slivers on average (the module's documentation: Artemis I
/// row 882's limb). A lattice's mean does not depend on what its points find, so a sliver
/// is caught in proportion to its width and its error changes sign from sliver to sliver
/// instead of adding up; where every point agrees with the rays, the mean is the rule's
/// value but for the rule's better accuracy on smooth light, which is kept. Reading every
/// such cell by its lattice instead (32 a pixel) put the pixels one to three from 882's limb
/// (rows 448-511) +1.5e-4, +1.6e-5 and +2.2e-5 of their light off a brute force, where
/// keeping the rule left -2.2e-5, +5e-6 and +6e-6: the midpoints are the poorer rule where
/// the light does not step.
fn lattice_mean(tracer: &Tracer, c: &Cell, points: usize, lit: bool) -> Option<f64> {
    let step = c.side / points as f64;
    let (mut sum, mut other) = (0.0, false);
    for b in 0..points {
        for a in 0..points {
            let (u, v) = (a as f64 + 0.5, b as f64 + 0.5);
            let x = tracer.cast(c.u + u * step, c.v + v * step).pl_per_px2;
            sum += x;
            other |= (x > 0.0) != lit;
        }
    }
    other.then_some(sum * step * step)
}

/// One pixel's integral and what its cells say of it ([`pixel`]).
#[derive(Clone, Copy, Default)]
struct PixelSum {
    /// The sum of the accepted cells' `G3` [sr m^2].
    value: f64,
    /// The sum of their `|G3 - G2|`: the pixel's error bound [sr m^2].
    bound: f64,
    /// The sum of their `G3 - G2`: the estimate with the signs kept [sr m^2].
    signed: f64,
    rays: u64,
    cells: u64,
    /// Cells accepted above their tolerance (at the deepest level or out of cells).
    unconverged: u64,
}

/// One pixel, adaptively. `near_edge`: the pixel or a neighbour straddles the silhouette or
/// the edge of the light, so its cells are all cut `near_depth` times before any is accepted.
#[allow(clippy::too_many_arguments)]
fn pixel(
    tracer: &Tracer,
    s: &ReferenceSettings,
    i: usize,
    j: usize,
    tau: f64,
    near_edge: bool,
    stack: &mut Vec<Cell>,
) -> PixelSum {
    stack.clear();
    stack.push(Cell {
        u: i as f64,
        v: j as f64,
        side: 1.0,
        depth: 0,
    });
    let mut sum = PixelSum::default();
    while let Some(c) = stack.pop() {
        let coverage = tracer.coverage(c.u, c.v, c.side);
        if coverage == Coverage::Empty {
            continue;
        }
        sum.rays += 13;
        let (g2, g3, _, hits, lit) = rules(tracer, &c);
        // A cell that may straddle the silhouette is not trusted where the silhouette test is
        // tight (elsewhere, in the band between a DEM's lowest and highest spheres, only a cell
        // whose rays partly meet the body is: cutting every cell of the band to the deepest
        // level would take hours), and one that straddles the
        // edge of the light (terminator, shadow) only when its rays are all lit or all dark:
        // a sliver may hide between the rays, or a corner stick out beyond the limb.
        let edge = coverage == Coverage::Edge
            && if tracer.tight_silhouette() {
                true
            } else {
                hits > 0 && hits < 13
            };
        let mut must_cut = (edge && c.depth < s.edge_depth)
            || (lit > 0 && lit < 13 && c.depth < s.light_depth)
            || (near_edge && c.depth < s.near_depth);
        // Near an edge, a cell whose rays all agree (all lit or all dark) may still hold a
        // sliver of the other between them: a thin lune of light along the limb at high phase
        // loses its terminator side there (3e-3 of an edge pixel's light at 161 deg). Its
        // corners, where a straight edge crossing the cell shows first, are asked too.
        let agree = lit == 0 || lit == 13;
        if !must_cut && near_edge && c.depth < s.corner_depth && agree {
            sum.rays += 4;
            must_cut = corners_disagree(tracer, &c, lit == 13);
        }
        let e = (g3 - g2).abs();
        let exhausted = sum.cells + stack.len() as u64 >= s.max_cells_per_px;
        if exhausted || (!must_cut && (e <= tau * c.side || c.depth >= s.max_depth)) {
            // A cell of a pixel near an edge whose rays agree may still hold slivers of the
            // other between them, and the cells that catch one are cut while those that miss
            // it are kept: that loses slivers on average. A lattice's midpoints, whose mean
            // does not depend on what they find, lose almost none ([`lattice_mean`]).
            let points = (c.side * f64::from(s.lattice_per_px)).round() as usize;
            let value = if near_edge && !exhausted && agree && points > 1 {
                sum.rays += (points * points) as u64;
                lattice_mean(tracer, &c, points, lit == 13).unwrap_or(g3)
            } else {
                g3
            };
            sum.value += value;
            sum.bound += e.max((value - g3).abs());
            sum.signed += g3 - g2;
            sum.cells += 1;
            if e > tau * c.side {
                sum.unconverged += 1;
            }
            continue;
        }
        let h = 0.5 * c.side;
        // Pushed in reverse so that cells are summed top-left first.
        for (du, dv) in [(h, h), (0.0, h), (h, 0.0), (0.0, 0.0)] {
            stack.push(Cell {
                u: c.u + du,
                v: c.v + dv,
                side: h,
                depth: c.depth + 1,
            });
        }
    }
    sum
}

/// One pixel the limb cuts where its light grows as the inverse square root of the distance
/// to it, by lattices warped at the limb ([`super::limb::warped_mean`]) of 32, 64, ... lines a
/// side until two agree within `tau` [sr m^2] or `limb_lattice_max` is reached.
fn limb_pixel(tracer: &Tracer, s: &ReferenceSettings, i: usize, j: usize, tau: f64) -> PixelSum {
    let (mut value, mut rays) = super::limb::warped_mean(tracer, i, j, 32);
    let mut n = 64;
    let last = loop {
        let (next, cast) = super::limb::warped_mean(tracer, i, j, n);
        rays += cast;
        let difference = next - value;
        value = next;
        if difference.abs() <= tau || 2 * n > s.limb_lattice_max as usize {
            break difference;
        }
        n *= 2;
    };
    PixelSum {
        value,
        bound: last.abs(),
        signed: last,
        rays,
        cells: 1,
        unconverged: u64::from(last.abs() > tau),
    }
}

/// Renders the converged reference of `scene` seen from `pose`.
pub fn render(
    scene: &Scene,
    pose: &Pose,
    settings: &ReferenceSettings,
) -> Result<ReferenceFrame, RenderError> {
    let mut r = render_camera(scene, pose, settings)?;
    // A band with a distortion of its own: its own converged image (its error estimate is
    // the camera's image's).
    crate::render::with_band_distortions(scene, &mut r.frame, |s| {
        Ok(render_camera(s, pose, settings)?.frame.pl)
    })?;
    Ok(r)
}

/// [`render`] through the camera's own distortion.
fn render_camera(
    scene: &Scene,
    pose: &Pose,
    settings: &ReferenceSettings,
) -> Result<ReferenceFrame, RenderError> {
    if !(settings.tolerance.is_finite() && settings.tolerance > 0.0) {
        return Err(RenderError::BadSettings {
            field: "reference.tolerance",
            value: settings.tolerance.to_string(),
            allowed: "a number > 0",
        });
    }
    if settings.max_depth > 20 {
        return Err(RenderError::BadSettings {
            field: "reference.max_depth",
            value: settings.max_depth.to_string(),
            allowed: "at most 20",
        });
    }
    // The forced depths go no deeper than the deepest level.
    let settings = &ReferenceSettings {
        edge_depth: settings.edge_depth.min(settings.max_depth),
        light_depth: settings.light_depth.min(settings.max_depth),
        corner_depth: settings.corner_depth.min(settings.max_depth),
        near_depth: settings.near_depth.min(settings.max_depth),
        ..*settings
    };
    crate::render::check_pose(scene, pose)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(settings.threads)
        .build()
        .map_err(|e| RenderError::Threads(e.to_string()))?;
    let t0 = Instant::now();
    let intr = &scene.camera.intrinsics;
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let tracer = Tracer::new(scene, pose);

    // First estimates: the 3 x 3 rule over each pixel, the range at its centre, whether its
    // rays disagree (some meet the body and some miss, or some are lit and some dark), and
    // what they found ([`LIT`], [`DARK`], [`SUN_ONLY`], [`CAMERA_ONLY`]).
    let firsts: Vec<(f64, f64, bool, u8)> = pool.install(|| {
        (0..w * h)
            .into_par_iter()
            .map(|p| {
                let c = Cell {
                    u: (p % w) as f64,
                    v: (p / w) as f64,
                    side: 1.0,
                    depth: 0,
                };
                let coverage = tracer.coverage(c.u, c.v, 1.0);
                if coverage == Coverage::Empty {
                    return (0.0, f64::NAN, false, 0);
                }
                let (_, g3, range, hits, lit, found) = rules_with(&tracer, &c, true);
                let mixed = (coverage == Coverage::Edge && hits < 13) || (lit > 0 && lit < 13);
                (g3, range, mixed, found)
            })
            .collect()
    });
    let first: Vec<f64> = firsts.iter().map(|f| f.0).collect();
    let depth: Vec<f64> = firsts.iter().map(|f| f.1).collect();
    // Near an edge: a pixel around which rays disagree, within a pixel or from one pixel to
    // the next (an edge between two pixels' rays), or around which the Sun alone keeps some
    // rays dark and the camera alone others (a lit sliver may run between them).
    let near_edge = |p: usize| {
        let mut found = 0;
        super::around(p, w, h).any(|q| {
            found |= firsts[q].3;
            firsts[q].2
        }) || found & (LIT | DARK) == LIT | DARK
            || found & (SUN_ONLY | CAMERA_ONLY) == SUN_ONLY | CAMERA_ONLY
    };
    let mut lit: Vec<f64> = first.iter().copied().filter(|&x| x > 0.0).collect();
    let floor = if lit.is_empty() {
        f64::MIN_POSITIVE
    } else {
        1e-3 * crate::stats::quantiles(&mut lit, [0.99])[0]
    };

    let singular_limb = settings.limb_lattice_max >= 64 && super::limb::is_singular(&tracer);
    let results: Vec<PixelSum> = pool.install(|| {
        (0..w * h)
            .into_par_iter()
            .map_init(Vec::new, |stack, p| {
                let tau = settings.tolerance * first[p].abs().max(floor);
                let (i, j) = (p % w, p / w);
                if singular_limb && super::limb::cuts(&tracer, i, j) {
                    limb_pixel(&tracer, settings, i, j, tau)
                } else {
                    pixel(&tracer, settings, i, j, tau, near_edge(p), stack)
                }
            })
            .collect()
    });
    let pl: Vec<f64> = results.iter().map(|r| r.value).collect();
    let error_pl: Vec<f64> = results.iter().map(|r| r.bound).collect();
    let total: f64 = pl.iter().sum();
    if !total.is_finite() {
        return Err(RenderError::NonFinite {
            stage: "reference",
            value: total,
        });
    }
    let [median, p99, max] = relative_quantiles(&pl, &error_pl, floor);
    let signed_pl: Vec<f64> = results.iter().map(|r| r.signed.abs()).collect();
    let [_, signed_p99, _] = relative_quantiles(&pl, &signed_pl, floor);
    let seconds = t0.elapsed().as_secs_f64();
    let report = ReferenceReport {
        method: "cubature",
        settings: Some(*settings),
        rays: results.iter().map(|r| r.rays).sum::<u64>() + 9 * (w * h) as u64,
        cells: results.iter().map(|r| r.cells).sum(),
        unconverged_cells: results.iter().map(|r| r.unconverged).sum(),
        unconverged_px: results.iter().filter(|r| r.unconverged > 0).count() as u64,
        est_error_total: if total > 0.0 {
            error_pl.iter().sum::<f64>() / total
        } else {
            0.0
        },
        est_error_median: median,
        est_error_p99: p99,
        est_error_max: max,
        signed_error_total: if total > 0.0 {
            results.iter().map(|r| r.signed).sum::<f64>().abs() / total
        } else {
            0.0
        },
        signed_error_p99: signed_p99,
        seconds,
    };
    Ok(ReferenceFrame {
        frame: reference_frame(pose, (w, h), pl, Some(depth), seconds),
        error_pl,
        report,
    })
}

/// A reference's frame: its image, depth and the stats a reference has (the phase, the
/// total, the time it took).
pub(super) fn reference_frame(
    pose: &Pose,
    (width, height): (usize, usize),
    pl: Vec<f64>,
    depth_m: Option<Vec<f64>>,
    seconds: f64,
) -> Frame {
    let total: f64 = pl.iter().sum();
    let stats = FrameStats {
        phase_deg: phase_deg(pose),
        total_pl_points: total,
        total_pl_image: total,
        total_pl_gridded: total,
        timings_ms: StageTimings {
            total: seconds * 1e3,
            ..Default::default()
        },
        ..Default::default()
    };
    Frame {
        width,
        height,
        pl,
        band_pl: Vec::new(),
        depth_m,
        stats,
    }
}

/// The median, 99th percentile and largest of the pixels' estimated errors `error_pl` over
/// their values `pl`, over the pixels brighter than `floor` (zeros when none is).
pub(super) fn relative_quantiles(pl: &[f64], error_pl: &[f64], floor: f64) -> [f64; 3] {
    let mut rel: Vec<f64> = pl
        .iter()
        .zip(error_pl)
        .filter(|(v, _)| **v > floor)
        .map(|(v, e)| e / v)
        .collect();
    if rel.is_empty() {
        [0.0; 3]
    } else {
        crate::stats::selected_quantiles(&mut rel, [0.5, 0.99, 1.0])
    }
}

/// The phase angle of `pose` at the body's centre [deg].
pub(super) fn phase_deg(pose: &Pose) -> f64 {
    (pose.sun_position_m.normalize())
        .dot(pose.camera_position_m.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}
