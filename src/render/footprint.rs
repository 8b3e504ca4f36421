//! The albedo map read over each pixel's footprint (`render.map_filter = "pixel"`), the step
//! after reconstruction.
//!
//! Paper Sec. 4.4 gives each quadrangle one albedo, the map's at its centre: a quadrangle that
//! spans several pixels paints them all with it, so wherever the map varies within a few
//! pixels (a textured Moon whose texels are a pixel or two across) the image carries the
//! quadrangles' pattern, not the map's. Under `MapFilter::Pixel` the quadrangles are
//! integrated with one reference scale `s_ref` (the map's mean), which gives the geometry,
//! shadows and limb of `(P/L)` as before; then each pixel is scaled by
//!
//! ```text
//! (P/L)_p <- (P/L)_p f_r(a_p) / f_r(s_ref)
//! ```
//!
//! where `a_p` is the map averaged over the pixel's footprint on the surface, and the ratio of
//! BRDFs is taken at the surface's own incidence, emission and phase. For the models linear in
//! their scale (every one but Hapke) the ratio is `a_p / s_ref` whatever the geometry; Hapke's
//! is evaluated, and the pixel takes the mean of the ratios over its reads. The pixel's power
//! is thereby the integral of the geometry times the map over the pixel (Eq. 9 with the
//! albedo inside the pixel integral), to first order in the map's variation over the pixel,
//! however many quadrangles the pixel receives.
//!
//! The mean over the footprint: the bilinear map is read at midpoints of the pixel no more
//! than half a texel apart on the surface (`render.map_read_spacing_texels`, [`Reads`];
//! towards a pole a map column narrows as `cos(lat)` and is not counted as a texel), at most
//! [`READ_SPAN_TEXELS`] of them per side (beyond, each read takes the area-averaged level of
//! [`AlbedoMap::scale_over_lon_lat`] for its share). The midpoints miss the bilinear map's
//! kinks at the texel centres by up to half their spacing: that is most of a far frame's
//! median, which halving the spacing cuts by 2 to 3 for 1.5 to 2.4 times the frame's time
//! ([`Reads::spacing_texels`]). Each read is weighted by `mu0` interpolated there: the reads
//! are spread evenly over the image, not the surface, and a point's share of the pixel's
//! power per unit of image is its radiance, `f_r mu0` (the variation of `f_r` inside a lit
//! pixel is left out). Weighted by `mu0 mu`, the power per unit of surface, the reads
//! undercounted the grazing side of every pixel near the limb. (`tests/maps.rs` measures the step: 2e-3 at the median on a
//! map that changes by 40 % within 4 texels.)
//!
//! Cost. Casting every pixel's line of sight took 75 ms a megapixel on 2 cores, more than the
//! render. The image is therefore cut in blocks of 8 x 8 pixels: lines of sight are cast at
//! the blocks' corners and centre, and a block whose corners all meet the body and whose
//! centre's longitude and latitude the corners' bilinear interpolation predicts within
//! [`TOLERANCE_TEXELS`] (of a texel, or of the footprint where that is larger; under the
//! relief's shadows, of the footprint: [`Step::tolerance_texels`]) has its reads'
//! longitude and latitude interpolated. A block that fails is split in four, down to single
//! pixels, interpolated from the lines of sight through their own four corners
//! ([`Step::own_corners`]; under the relief, each read of every block where its own line
//! of sight meets the shape, [`Placement`]). A single pixel whose neighbours' or corners'
//! lines of sight miss the body (the limb), or whose interpolation is off by a fiftieth of
//! its footprint (near the limb, where the surface a pixel sees stretches to
//! `sqrt(2 R footprint)` and maps to the image like a square root, or at a pole), casts its
//! reads instead ([`CAST`] x [`CAST`] lines of sight, each weighted by its own `f_r mu0`, 0
//! where it misses). Interpolating them there, or one read at the footprint's level, put the
//! lunar limb's last pixels 2.8 % low on the textured Hapke Moon at 71,000 km, and its total
//! 2e-4 low. Those pixels (about 2,000 there) and the second Hapke evaluation of every single
//! pixel cost the NRHO's far frames 13-15 ms (`docs/performance.md`). Under the relief, on a
//! sphere, the pixels the limb cuts are read evenly in `mu_shape` along strips across the
//! limb instead, where the light per unit of image grows without bound
//! ([`Step::limb_pixel`]).
//!
//! Hapke's ratio, which depends on the geometry weakly (a ratio of two BRDFs at the same
//! angles), is tabulated per block over the map's range of `w` at the angles of the block's
//! centre (its most lit and visible corner's where the centre is unlit or unseen) and read
//! by the parabola through the nearest three nodes: linear interpolation set the chord of the
//! ratio, convex in `w`, above it, 1.6e-3 too high over the tabulated pixels at 71,000 km. A
//! single pixel's ratio is taken at its own angles, as the mean of the ratio at
//! `mean(w) -/+ sd(w)` of its reads (exact for a ratio quadratic in `w`): the ratio of the
//! mean `w` left the curvature out, 7e-4 to 8e-4 too low over those pixels, which near a
//! pole (longitude changes too fast to interpolate blocks) are most of the disk.
//!
//! The relief over each pixel (`MapFilter::Relief`, an undisplaced DEM). The quadrangles
//! integrate the relief's light over each quadrangle and spread it over the pixels it covers,
//! so where a pixel spans DEM texels of different slopes, more quadrangles lower the median
//! only slowly (the LOLA Moon at the NRHO's apolune, 2.4 texels a pixel: median 1.0e-2 and
//! 2.6e-3 at 2 and 16 per pixel). Under `Relief` the quadrangles integrate the smooth shape,
//! unshadowed, and each read carries the relief: its light per unit of the shape's projected
//! area, `f_r(a; n_dem) mu0 mu / mu_shape` (Eq. 37, the renderer's integrand and the
//! reference's), 0 where the relief hides the Sun or the camera (Eq. 33, by the frame's
//! `self_shadowing`, each read its own shadow rays) or the shape is unlit; the pixel is
//! scaled by the sum of that over its reads against the sum of the smooth shape's
//! `f_r(s_ref) mu0`, which is what the quadrangles gridded there ([`Step::relief_pixel`]),
//! each read weighted by the midpoint rule's end correction ([`end_weight`]: the midpoint
//! rule alone left the high-phase frames a bright lean). The reads are spaced on the finer of the map's and the DEM's texels, and Hapke's BRDF is
//! evaluated at each read (no table: the relief's angles change from read to read). On the
//! apolune frame: median 8.3e-4 at 1 per pixel, for about a microsecond a read, most of it
//! the shadow rays (`docs/performance.md`, "The relief over each pixel"). Near the terminator
//! (the smooth shape's `mu0` below [`MU0_ABSOLUTE`] at a read) a pixel is its reads' mean
//! light times `A_sun A_cam cos(eps) Omega / d_sun^2` (Eq. 12 over its solid angle,
//! [`Step::absolute_scale`]) instead, where the ratio multiplied the quadrangles' gridding
//! error. Each pixel's reads also estimate their own error against a quarter of them
//! ([`relief_estimate`]), and the frame reports its 99th percentile.
//!
//! A read's shadow is all or nothing, and the Sun a point (as in the reference), so a pixel
//! a shadow's edge crosses converged on its lit part only as the reads' spacing: doubling
//! them per side halved the apolune frame's p99, and a pixel whose reads all fell in shadow
//! was dark however much of it the Sun lit. The reads of a block of pixels therefore lie on
//! one lattice ([`Step::read_lattice`]), and where two neighbours on it disagree, the edge
//! is placed between them by halving ([`EDGE_HALVINGS`]) and each read beside it takes the
//! share of its cell on its own side ([`lit_shares`]), an edge between two pixels' reads
//! included: the apolune frame's p99 0.111 -> 0.084, NRHO row 493's terminator window's
//! 1.0 -> 0.245, for 9 % of the budgeted file's median frame (`docs/performance.md`, "A
//! shadow's edge between the reads").
//!
//! Where even that leaves a pixel's reads disagreeing (`relief_refine` above 1, under which
//! every pixel is read at least [`REFINED_MIN_READS`] times per side, so that its reads can
//! disagree at all), the pixel whose reads' own estimate is above [`REFINE_ABOVE`], or whose
//! reads and the ring around them hold both light and shadow, is read again on a lattice of its
//! own twice as fine per side, and again while its light still moves, up to `relief_refine`
//! times per side ([`Step::refine`]); the blocks' lattices then reach one read beyond each
//! side, and a limb pixel casts `relief_refine` times the lines of sight per side. From the
//! second level on a read takes its shadows from the four reads around it on the level before
//! where they agree. The NRHO's far frames' p99 from 0.10-0.17 to 2.2e-2-2.9e-2 at 8, for 6.1
//! to 8.6 times the time (`docs/performance.md`, "Pixels read again where their reads disagree"
//! and "Finer reads take their shadows from the coarser level").
//!
//! Under the relief nearly every block is a single pixel (the tolerance is a hundredth of
//! the footprint), and its lattice's ring is its neighbours' own reads: a read is a function
//! of its place alone (its line of sight, its shadow rays), so each band keeps the reads its
//! blocks made by their place on the image's lattice of reads ([`Band::shared_reads`]), and
//! a block, or a pixel read again at the first level, takes a read another made there. On
//! NRHO row 349, 3.67 M reads became 2.74 M, the image the same to rounding
//! (`docs/performance.md`, "Reads made once").
//!
//! Several maps over one geometry ([`apply_maps`]: the camera's map and the maps of bands
//! of their own, `[[body.band_map]]`) share the lines of sight, the blocks and the reads'
//! positions and weights, decided on the finest map's texels; only the map reads (and
//! Hapke's tables) are per map. A band's map costs its reads, not the lines of sight (which,
//! through a displaced surface, are most of the step).

use super::settings::SelfShadowing;
use crate::body::{AlbedoMap, Relief, Shape};
use crate::brdf::{Brdf, Local};
use crate::camera::Intrinsics;
use crate::scene::Pose;
use glam::DVec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// The steepest emission cosine the footprint's stretch follows (beyond it, within a few
/// degrees of the limb, it stays at `1/sqrt(0.05)` = 4.5 times the pixel).
const MIN_MU: f64 = 0.05;

/// Side of the interpolation blocks [px].
const BLOCK: usize = 8;

/// How far the block centre's interpolated longitude and latitude may be from the cast ones
/// [texels of the map, or of the pixel's footprint where that is larger], each; under the
/// relief's shadows, of the pixel's footprint whatever the texel
/// ([`Step::tolerance_texels`]). At a hundredth of a texel a footprint ten times finer than
/// the texel was placed to a tenth of a pixel, and a shadow's edge with it: NRHO row 167
/// (129 deg, 0.1 texel a pixel) had its pixels beside fully dark ones at p99 0.15 however
/// finely they were read, 6.1e-2 with the footprint's hundredth (`docs/performance.md`,
/// "Where a pixel's footprint lies").
pub const TOLERANCE_TEXELS: f64 = 0.01;

/// How finely the step reads each pixel: the render settings it takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reads {
    /// The largest spacing of the map reads over a pixel [texels] (`render.
    /// map_read_spacing_texels`, 0.5 by default): a pixel that spans `len` texels along an
    /// axis is read at `ceil(len / spacing)` midpoints along it, at most
    /// `READ_SPAN_TEXELS / spacing`. The midpoint rule integrates the bilinear map exactly
    /// between its kinks at the texel centres and misses each kink by a share of a texel's
    /// change that falls as the spacing squared. The planner's rung of one quadrangle per
    /// pixel, against references at tolerance 1e-4 (`sweeps/map_read_spacing.toml`, 3
    /// repeats beside another job, so the times are comparable with each other only;
    /// `docs/performance.md`, "The map's kinks between the reads"), median (ms):
    ///
    /// | frame | spacing 0.5 | 0.25 | 0.125 |
    /// | --- | --- | --- | --- |
    /// | Lambert Moon, 70,000 km | 2.6e-4 (180) | 1.5e-4 (293) | 1.3e-4 (876) |
    /// | Hapke Moon, NRHO row 0 | 4.3e-4 (182) | 1.9e-4 (270) | 1.6e-4 (704) |
    /// | NRHO apolune, DEM, relief `k` 2 | 5.4e-4 (8045) | 1.8e-4 (19130) | 7.4e-5 (62328) |
    /// | NRHO row 90, DEM, relief `k` 2 | 6.2e-4 (11628) | 2.1e-4 (24687) | 9.8e-5 (71537) |
    ///
    /// The p99 falls too on the DEM frames (2.7e-2 -> 2.1e-2 at `k` 2, 1.6e-2 -> 1.3e-2 at
    /// `k` 4); the totals move by 2.1e-5 at most, either way.
    pub spacing_texels: f64,
    /// Under `MapFilter::Relief`: `render.relief_refine` ([`Step::refine`]).
    pub relief_refine: u32,
    /// Whether a block takes the reads its neighbours made at the same places
    /// ([`Band::shared_reads`]; under `relief_refine` above 1, where their lattices have a
    /// ring); off only to check that the image is the same without.
    pub(crate) share_reads: bool,
}

impl Reads {
    /// The settings' reads.
    pub fn of(settings: &super::Settings) -> Reads {
        Reads {
            spacing_texels: settings.map_read_spacing_texels,
            relief_refine: settings.relief_refine,
            share_reads: true,
        }
    }
}

/// Reads per side of a pixel that spans `len` texels, at most `spacing` [texels] apart and
/// at least `least` ([`Reads::spacing_texels`]).
fn reads_per_side(len: f64, spacing: f64, least: usize) -> usize {
    let most = (READ_SPAN_TEXELS / spacing).ceil() as usize;
    ((len / spacing).ceil() as usize).clamp(least, most.max(least))
}

/// The widest footprint [texels per side] read texel by texel: beyond, each of its reads
/// takes the area-averaged level of its share (8 reads a side at the default spacing).
pub const READ_SPAN_TEXELS: f64 = 4.0;

/// Under `MapFilter::Relief` with `relief_refine` above 1, the fewest reads per pixel side.
/// A pixel finer than half a texel was read once, at its centre, and [`Step::refine`] never
/// read it again: one read has nothing to disagree with. That read is also biased bright:
/// the light of a DEM's slope is concave in `mu0` (Lommel-Seeliger's `mu0 / (mu0 + mu)`), so
/// the centre's light is above the pixel's mean, most towards the terminator, and no level
/// of refinement saw it. Two NRHO frames at `relief_refine` 8 against their references
/// (row 158: 6,105 km, 131.6 deg, 0.1 texel a pixel, depth 8; row 171: 3,781 km, 121.3 deg,
/// depth 6), by the fewest reads per side:
///
/// | reads at least | row 158 median, p99, total | footprint step | row 171 median, p99, total |
/// | --- | --- | --- | --- |
/// | 1 | 6.0e-4, 3.20e-2, +1.34e-4 | 8.7 s | 6.2e-4, 2.04e-2, +1.92e-4 |
/// | 2 | 2.9e-4, 2.26e-2, +3.9e-5 | 11.5 s | 2.2e-4, 1.06e-2, +1.06e-4 |
/// | 3 | 1.8e-4, 2.13e-2, +2.3e-5 | 13.6 s | 1.2e-4, 9.2e-3, +6.3e-5 |
/// | 4 | 1.2e-4, 2.12e-2, +7.4e-6 | 17.8 s | 8.6e-5, 8.8e-3, +4.0e-5 |
///
/// Three is the fewest that meets the default budget (1e-3, 3e-2, 1e-4) on both; a pixel
/// over a texel was read three times per side already (`docs/performance.md`, "At least
/// three reads a side").
const REFINED_MIN_READS: usize = 3;

/// Lines of sight per side of a pixel whose reads are cast ([`Step::cast_pixel`]); under
/// `MapFilter::Relief` times the frame's `relief_refine`, at most [`MAX_CAST`].
const CAST: usize = 8;

/// The most lines of sight per side of a cast pixel under `relief_refine` (8 times
/// [`CAST`]: `relief_refine` 8 casts 64 x 64). Near the limb a read's light per unit of the
/// shape's projected area, `mu0 mu / mu_shape`, grows as the inverse square root of the
/// distance to the limb, and a regular lattice of lines of sight integrates that the worse
/// the nearer its first line falls to the limb: the limb pixels' share of the total of NRHO
/// row 79 (56,562 km, 96 deg, 1,657 pixels beside an unlit one, 2.2 % of the light), against
/// its reference, was -1.5e-4 at 16 x 16, +1.55e-4 at 32 x 32, -4.9e-5 at 64 x 64 and at
/// 96 x 96. At 64 the frame's total went from +1.95e-4 (over the budget) to -5.6e-6 and its
/// p99 from 2.10e-2 to 2.01e-2; the NRHO's apolune frames (rows 0 and 712) from -4.8e-5
/// and -9.8e-5 to -2.8e-5 and -5.4e-5, p99 2.64e-2 and 2.53e-2 to 2.36e-2 and 2.13e-2; for
/// about 1.5 times the footprint step on those far frames, whose limb pixels are most of
/// their reads. A lattice jittered within its cells (deterministically) was no better: it
/// raised the p99 of rows 0, 712 and 356 by 3e-3 to 5e-3 (`docs/performance.md`, "The
/// limb's lines of sight"). Under the relief, on a sphere, the pixels the limb cuts are
/// now read evenly in `mu_shape` instead ([`Step::limb_pixel`]), which that tail does not
/// reach.
const MAX_CAST: usize = 64;

/// Under `MapFilter::Relief` with `relief_refine` above 1: a pixel whose reads' own error
/// estimate ([`relief_estimate`]) exceeds this, or whose reads hold light and shadow
/// ([`mixed`]), is read again on a lattice twice as fine per side, and again while its light
/// moves by more than this between levels, up to `relief_refine` times the first reads per
/// side ([`Step::refine`]). A third of the p99 budget's default (3e-2). On the NRHO's apolune frame, by the estimate alone,
/// 3e-3 re-read 2.9 times the pixels (14,328 of 28,603 against 4,945) for p99 6.7e-2
/// against 6.8e-2 (re-read twice as finely, the limb cast 8 x 8).
pub const REFINE_ABOVE: f64 = 1e-2;

/// The cosine a single pixel's Hapke ratio is taken at, at least, where its line of sight
/// grazes or misses the body or the light.
const GRAZING: f64 = 1e-3;

/// Nodes of the per-block table of Hapke's ratio over the map's range of `w`.
const TABLE: usize = 9;
/// [`relief_estimate`]'s scale: the full reads' own error from their difference to the
/// coarse quarter of them, as for a rule of the second order in the reads' spacing
/// (Richardson: `(fine - coarse) / (2^2 - 1)`). The 99th percentile of the estimate over
/// the lit pixels against the one measured against the reference, on the centres of
/// `config/nrho_textured.toml`'s NRHO frames at their own pixel scale (ray marching):
///
/// | frame | reads a pixel | estimated p99 | measured p99 |
/// | --- | --- | --- | --- |
/// | apolune, 71,222 km, 256 x 256 | 7 x 7 | 0.189 | 0.084-0.110 |
/// | row 232, 31,444 km, 128 x 128 | 3 x 3 | 2.5e-2 | 1.6e-2 |
/// | row 493, 19,661 km, 128 x 128 | 2 x 2 | 2.4e-2 | 6.3e-3 |
/// | row 493, across its terminator | 2 x 2 | 0.56 | 0.245 |
///
/// (With the shadows' edges placed between the reads, [`lit_shares`]; before, the apolune
/// frame's centre 128 x 128 estimated 0.33 against 0.221 measured, and the terminator
/// 0.38 against 1.0: its pixels that no read saw lit.) It is at or above the measured p99
/// on each (1.2 to 3.8 times it), which is what a frame's report of its error needs. It
/// sees the reads' error only: on a frame whose p99 is the limb's and the terminator's (`tests/maps.rs`, hills under a 64 x 64 frame) it is
/// below the measured p99, and the planner's prediction is the larger of it and the
/// model's. The shadows' edges, where a read is lit or not, converge more slowly than a
/// smooth integrand (their error would ask for a scale of about 0.55); the difference
/// between the full and the coarse reads at the 99th percentile was nevertheless 3 to 11
/// times the error measured on the first four.
const READ_ESTIMATE_SCALE: f64 = 1.0 / 3.0;

/// The BRDF scale the geometry is integrated with under `MapFilter::Pixel`: the map's mean
/// (so that Hapke's ratio stays near its value), or `fallback` where that is not positive.
pub fn reference_scale(albedo: &AlbedoMap, fallback: f64) -> f64 {
    let s = albedo.mean_scale();
    if s.is_finite() && s > 0.0 {
        s
    } else {
        fallback
    }
}

/// What one line of sight meets: the map coordinates [rad], the footprint [rad of arc] and
/// the local geometry (Hapke's ratio needs it).
#[derive(Clone, Copy)]
struct Probe {
    lon: f64,
    lat: f64,
    footprint_rad: f64,
    /// Whether the line of sight meets the body (else: the nearest point over the limb).
    hit: bool,
    local: Local,
}

/// One frame's inputs to the step.
struct Step<'a> {
    intrinsics: &'a Intrinsics,
    shape: &'a Shape,
    relief: Option<&'a Relief>,
    brdf_ref: &'a Brdf,
    /// The maps, one per image.
    maps: Vec<&'a AlbedoMap>,
    pose: &'a Pose,
    s_ref: f64,
    linear: bool,
    ifov: f64,
    /// Under `MapFilter::Relief`: the relief whose shading and shadows every read carries
    /// (the quadrangles integrated the smooth shape), and how it hides the Sun and the camera.
    shading: Option<(&'a Relief, SelfShadowing)>,
    /// Under `shading`: the most a pixel's reads are refined per side where they disagree
    /// ([`Step::refine`]), and the factor of a cast pixel's lines of sight (1: off).
    refine: usize,
    /// The largest spacing of a pixel's map reads [texels] ([`Reads::spacing_texels`]).
    spacing_texels: f64,
    /// [`Reads::share_reads`], where the lattices have rings (`relief_refine` above 1).
    share_reads: bool,
    /// `A_sun A_cam` [m^4] of Eq. 12, with which a pixel near the smooth terminator is
    /// taken from its reads alone ([`Step::absolute_scale`]).
    a_sun_cam_m4: f64,
}

/// What [`Step::relief_pixel`] made of a pixel's reads: whether there were any, whether
/// `Band::sums` holds the light per unit of solid angle (`absolute`, to be scaled by
/// [`Step::absolute_scale`]) or the ratio to the quadrangles' light, and the reads' own
/// error estimate.
struct ReliefPixel {
    read: bool,
    absolute: bool,
    estimate: f64,
}

/// Below this `mu0` of the smooth shape at any of a pixel's reads, a pixel under
/// `MapFilter::Relief` is taken from its reads alone ([`Step::absolute_scale`]), not as a
/// ratio to the quadrangles' light: towards the terminator that light goes to 0 while the
/// DEM's slopes facing the Sun keep theirs, and the ratio multiplied the quadrangles'
/// gridding error there. A 128 x 128 window across NRHO row 493's terminator (19,661 km,
/// 0.62 texels a pixel) measured total 1.1e-2 at 1/8 quadrangle per pixel and 6.0e-4 at 16
/// with the ratio, 3.0e-4 at any rung so (SSIM 0.981 -> 0.999); the apolune frame (256 x 256)
/// total 5.7e-4 -> 4.8e-5 and p99 0.37 -> 0.135 at 1/16. Taking every pixel so changes the
/// centre of row 493 by 4e-6 of its total. The smooth shape's night side stays dark, as in
/// the reference (its ground faces away from the Sun however the DEM's normal leans).
const MU0_ABSOLUTE: f64 = 0.1;

/// What one read shows under `MapFilter::Relief`, per unit of the shape's projected area
/// (what a pixel's solid angle covers): `smooth`, the light the quadrangles gridded there
/// (`f_r(s_ref) mu0` on the smooth shape), and the relief's geometry, whose light at scale
/// `a` is `f_r(a; local) k` with `k = mu0 mu / mu_shape` (paper Eq. 37: each area element
/// of the shape weighed by the cosines of the DEM's normal), 0 where the terrain hides the
/// Sun or the camera (Eq. 33) or the shape is unlit.
#[derive(Clone, Copy)]
struct ReliefRead {
    smooth: f64,
    /// The DEM's geometry at the read, unshadowed; its `s` and `c` (body frame, unit) are
    /// the read's shadow rays, towards the Sun and the camera.
    local: Local,
    /// `mu0 mu / mu_shape` where the DEM's facet faces the Sun and the camera, else 0; and
    /// whether the relief casts its shadow on the read (or hides it from the camera), which
    /// [`Step::relief_pixel`] turns into the read's lit share ([`ReliefPixel`]).
    k: f64,
    hidden: [bool; 2],
    /// Whether `hidden[1]` was asked: not where the Sun's ray is already blocked (a read in
    /// a shadow's depth is dark whatever the camera sees), until [`lit_shares`] needs it.
    camera_asked: bool,
    /// The smooth shape's `mu0` and whether the camera sees it there.
    mu0_shape: f64,
    seen: bool,
}

impl ReliefRead {
    /// 1 where neither the Sun's nor the camera's ray is blocked, else 0.
    fn lit(&self) -> f64 {
        if self.hidden[0] || self.hidden[1] {
            0.0
        } else {
            1.0
        }
    }
}

impl Step<'_> {
    /// How far a block's centre may be from its corners' interpolation [texels], for a pixel
    /// footprint of `footprint_texels`: [`TOLERANCE_TEXELS`] of a texel, or of the
    /// footprint where that is larger; of the footprint whatever the texel where the relief
    /// casts shadows on reads whose edges are placed across the blocks' sides (ray marching
    /// or a horizon map, `relief_refine` above 1: [`Step::ring`]). At `relief_refine` 1
    /// a shadow's edge along a block's side is not placed, and splitting the blocks finer
    /// made more of them (the window of NRHO row 167: p99 0.74 against 0.33).
    fn tolerance_texels(&self, footprint_texels: f64) -> f64 {
        let edges = self.refine > 1
            && self
                .shading
                .is_some_and(|(_, shadows)| shadows != SelfShadowing::Off);
        TOLERANCE_TEXELS
            * if edges {
                footprint_texels
            } else {
                footprint_texels.max(1.0)
            }
    }

    /// The line of sight through image point `(u, v)` [px].
    fn probe(&self, u: f64, v: f64) -> Probe {
        let cam = self.pose.camera_position_m;
        let dir = super::depth::line_of_sight(self.intrinsics, self.pose, u, v);
        let hit = match self.relief.filter(|r| r.displaces()) {
            Some(r) => r.intersect_displaced(cam, dir).map(|t| {
                let p = cam + dir * t;
                (t, p, p.normalize())
            }),
            None => self
                .shape
                .intersect_normal(cam, dir)
                .map(|(t, n)| (t, cam + dir * t, n)),
        };
        let (t, p, n_shape, mu, is_hit) = match hit {
            Some((t, p, n)) => (t, p, n, n.dot(-dir), true),
            None => {
                // The point of the line of sight nearest the centre: over the limb.
                let t = (-cam.dot(dir)).max(0.0);
                let (p, n) = self.shape.surface((cam + dir * t).normalize_or_zero());
                (t, p, n, 0.0, false)
            }
        };
        let up = p.normalize_or_zero();
        let (lon, lat) = crate::geometry::lon_lat_unit(up);
        let normal = match self.relief.filter(|_| !self.linear) {
            Some(r) => r.at(up, false).normal,
            None => n_shape,
        };
        Probe {
            lon,
            lat,
            footprint_rad: self.ifov * t / mu.max(MIN_MU).sqrt() / p.length().max(1e-300),
            hit: is_hit,
            local: Local::new(normal, (self.pose.sun_position_m - p).normalize(), -dir),
        }
    }

    /// The read over map coordinates `(lon, lat)` [rad] under `MapFilter::Relief`
    /// ([`ReliefRead`]): the shape's point there, the DEM's normal, and the relief's shadows
    /// by the frame's method, as the quadrangles would have cast them; under ray marching,
    /// the answers in `known` (taken from coarser reads, [`Step::refine`]) are not marched.
    fn relief_read(
        &self,
        relief: &Relief,
        shadows: SelfShadowing,
        (lon, lat): (f64, f64),
        known: Option<Shadowed>,
    ) -> ReliefRead {
        let up = crate::geometry::unit_from_lon_lat(lon, lat);
        let (p, n_shape) = self.shape.surface(up);
        let s = (self.pose.sun_position_m - p).normalize();
        let c = (self.pose.camera_position_m - p).normalize();
        let smooth_local = Local::new(n_shape, s, c);
        let (mu0_shape, mu_shape) = (smooth_local.mu0, smooth_local.mu);
        if mu_shape <= 0.0 || mu0_shape <= 0.0 {
            return ReliefRead {
                smooth: 0.0,
                local: smooth_local,
                k: 0.0,
                hidden: [false; 2],
                camera_asked: true,
                mu0_shape,
                seen: mu_shape > 0.0,
            };
        }
        let smooth = self.brdf_ref.eval(&smooth_local) * mu0_shape;
        let at = relief.at(up, shadows == SelfShadowing::HorizonMap);
        let local = Local::new(at.normal, s, c);
        let faces = local.mu0 > 0.0 && local.mu > 0.0;
        let hidden = if !faces {
            [false; 2]
        } else {
            match shadows {
                SelfShadowing::Off => [false; 2],
                SelfShadowing::RayMarching => {
                    let sun = known.map_or_else(|| relief.occluded(up, s), |k| k.sun);
                    let camera = known.and_then(|k| k.camera);
                    [
                        sun,
                        !sun && camera.unwrap_or_else(|| relief.occluded(up, c)),
                    ]
                }
                SelfShadowing::HorizonMap => match relief.dem_horizon_at(up) {
                    Some(h) => [h.hides(s), h.hides(c)],
                    None => at
                        .horizon_sin
                        .map_or([false; 2], |h| [local.mu0 < h, local.mu < h]),
                },
            }
        };
        let k = if faces {
            local.mu0 * local.mu / mu_shape
        } else {
            0.0
        };
        ReliefRead {
            smooth,
            local,
            k,
            hidden,
            camera_asked: !(shadows == SelfShadowing::RayMarching && hidden[0]),
            mu0_shape,
            seen: true,
        }
    }

    /// The relief's light of read `read` at the map's scale `a` (its [`ReliefRead::k`]
    /// included): `f_r(a; local) k`.
    #[inline]
    fn relief_light(&self, read: &ReliefRead, a: f64, f_ref: f64) -> f64 {
        if read.k <= 0.0 {
            0.0
        } else if self.linear {
            f_ref * a / self.s_ref * read.k
        } else {
            self.brdf_ref.with_scale(a).eval(&read.local) * read.k
        }
    }

    /// A pixel's factor under `MapFilter::Relief` from its reads, `band.reads` (map
    /// coordinates, each standing for `read_rad` of the surface), spread evenly over the
    /// pixel's image, what each shows (`band.relief`) and its lit share (`band.lit`): the
    /// relief's light over the smooth shape's at the reference scale, both summed over the
    /// reads, per map, into `band.sums`. Where no read sees the smooth shape lit (a pixel
    /// the quadrangles' light spills into), the map alone: its mean over the reads. False
    /// where there is no read.
    ///
    /// Every read's shadows are its own: marching a pixel's corners, edges' middles and
    /// centre first and giving the other reads their answer where those agreed made the
    /// step 1.5 times faster on the NRHO's apolune frame (49 reads a pixel), but lost the
    /// shadows smaller than a pixel between them: total 1.9e-4 against 7.3e-5.
    ///
    /// `grid`: the reads' `(columns, rows)` where they lie on a grid over the pixel, row by
    /// row; then the pixel's factor is also taken from every other read of every other row
    /// (a quarter of them), and the relative difference between the two is returned as the
    /// reads' own error estimate, signed (see [`relief_estimate`]); else 0.
    fn relief_pixel(
        &self,
        band: &mut Band,
        read_rad: f64,
        grid: Option<(usize, usize)>,
        slots: usize,
    ) -> ReliefPixel {
        // Per map: the relief's light in `sums`, the map's `a / s_ref` in `squares` (the
        // fallback).
        band.sums.iter_mut().for_each(|x| *x = 0.0);
        band.squares.iter_mut().for_each(|x| *x = 0.0);
        let mut smooth = 0.0;
        // The first map's light and the smooth shape's over the coarser grid.
        let (mut coarse_light, mut coarse_smooth, mut coarse_count) = (0.0, 0.0, 0usize);
        let mut near_night = false;
        // The reads' weights where they cover the grid; else (reads left out beyond the
        // terminator, or not on a grid) each read counts once.
        let grid = grid.filter(|&(ns, nt)| ns * nt == band.relief.len());
        for (j, (read, &(lon, lat))) in band.relief.iter().zip(&band.reads).enumerate() {
            let weight = grid.map_or(1.0, |(ns, nt)| {
                end_weight(j % ns, ns) * end_weight(j / ns, nt)
            });
            smooth += weight * read.smooth;
            near_night |= read.seen && read.mu0_shape < MU0_ABSOLUTE;
            let share = band.lit[j];
            let f_ref = if read.k > 0.0 && share > 0.0 && self.linear {
                self.brdf_ref.eval(&read.local)
            } else {
                0.0
            };
            let coarse = grid.is_some_and(|(ns, _)| (j % ns) % 2 == 0 && (j / ns) % 2 == 0);
            if coarse {
                coarse_count += 1;
                coarse_smooth += read.smooth;
            }
            for (m, map) in self.maps.iter().enumerate() {
                let a = map.scale_over_lon_lat(lon, lat, read_rad, self.s_ref);
                let light = if share > 0.0 {
                    share * self.relief_light(read, a, f_ref)
                } else {
                    0.0
                };
                band.sums[m] += weight * light;
                band.squares[m] += a / self.s_ref;
                if m == 0 && coarse {
                    coarse_light += light;
                }
            }
        }
        let count = band.reads.len() as f64;
        // The pixel's factor, from all the reads and from the coarse quarter: near the
        // terminator the light per unit of solid angle (the pixel's misses counted as dark),
        // else the ratio to the smooth shape's light.
        let (absolute, norm, coarse_norm) = if near_night {
            (true, slots.max(1) as f64, coarse_count.max(1) as f64)
        } else {
            (false, smooth, coarse_smooth)
        };
        let fine = band.sums.first().copied().unwrap_or(0.0);
        let estimate = if grid.is_some() && norm > 0.0 {
            let coarse = if coarse_norm > 0.0 {
                coarse_light / coarse_norm
            } else {
                0.0
            };
            relief_estimate(fine / norm, coarse)
        } else {
            0.0
        };
        for m in 0..self.maps.len() {
            band.sums[m] = if norm > 0.0 {
                band.sums[m] / norm
            } else {
                band.squares[m] / count.max(1.0)
            };
        }
        ReliefPixel {
            read: count > 0.0,
            absolute,
            estimate,
        }
    }

    /// Pixel `(i, r)` (band row) from its reads ([`Step::relief_pixel`], left in
    /// `band.sums`): scaled by them, or taken from them alone.
    fn set_relief_pixel(&self, band: &mut Band, got: &ReliefPixel, i: usize, r: usize) {
        let w = band.width;
        if got.absolute {
            let Some(&(lon, lat)) = band.reads.get(band.reads.len() / 2) else {
                return;
            };
            let (p, _) = self
                .shape
                .surface(crate::geometry::unit_from_lon_lat(lon, lat));
            let k = self.absolute_scale(i as f64, (band.y0 + r) as f64, p);
            for (img, &f) in band.pixels.iter_mut().zip(&band.sums) {
                img[r * w + i] = k * f;
            }
        } else {
            for (img, &f) in band.pixels.iter_mut().zip(&band.sums) {
                img[r * w + i] *= f;
            }
        }
    }

    /// The `(P/L)` [sr m^2] of the pixel whose corners are at `(u, v)` and `(u + 1, v + 1)`
    /// [px] per unit of the light its reads carry (`f_r mu0 mu / mu_shape`, the read at
    /// `p_body` [m]): Eq. 12 summed over the surface the pixel sees, whose `mu dA / d_cam^2`
    /// is the pixel's solid angle `Omega` (from the lines of sight through its corners,
    /// through the camera's distortion), `A_sun A_cam cos(eps) Omega / d_sun^2`.
    fn absolute_scale(&self, u: f64, v: f64, p_body: DVec3) -> f64 {
        let los = |du: f64, dv: f64| {
            super::depth::line_of_sight(self.intrinsics, self.pose, u + du, v + dv)
        };
        let (d00, d10, d01, d11) = (los(0.0, 0.0), los(1.0, 0.0), los(0.0, 1.0), los(1.0, 1.0));
        let omega = 0.5 * (d11 - d00).cross(d10 - d01).length();
        let axis = self.pose.body_from_camera * DVec3::Z;
        let to_p = (p_body - self.pose.camera_position_m).normalize();
        let ds2 = (self.pose.sun_position_m - p_body).length_squared();
        self.a_sun_cam_m4 * to_p.dot(axis).max(0.0) * omega / ds2
    }

    /// `f_r(a) / f_r(s_ref)` at `local`'s angles (`a / s_ref` for the linear models, and where
    /// the point is unlit or unseen).
    fn ratio(&self, a: f64, local: &Local) -> f64 {
        self.ratio_at(local)(a)
    }

    /// [`Step::ratio`] at `local`'s angles as a function of `a`, `f_r(s_ref)` evaluated once.
    fn ratio_at<'s>(&'s self, local: &'s Local) -> impl Fn(f64) -> f64 + 's {
        let f_ref = if !self.linear && local.mu0 > 0.0 && local.mu > 0.0 {
            self.brdf_ref.eval(local)
        } else {
            0.0
        };
        move |a| {
            if f_ref > 0.0 {
                self.brdf_ref.with_scale(a).eval(local) / f_ref
            } else {
                a / self.s_ref
            }
        }
    }

    /// The pixel's factor under map `m` from the line of sight `p` through its centre.
    fn exact(&self, m: usize, p: &Probe) -> f64 {
        let a = self.maps[m].scale_over_lon_lat(p.lon, p.lat, p.footprint_rad, self.s_ref);
        self.ratio(a, &p.local)
    }

    /// Scales pixel `i` of band row `r` (image row centre `v`) from reads cast, not
    /// interpolated: the map read along [`CAST`] x [`CAST`] lines of sight through the pixel,
    /// each weighted by its radiance at the reference scale, `f_r mu0` (0 where it misses the
    /// body or is unlit); Hapke's ratio over them by [`Step::mean_ratio`] at their weighted
    /// mean angles. Falls back to one read at the pixel centre, at its footprint's level,
    /// where none of them meets the lit, seen body.
    fn cast_pixel(&self, band: &mut Band, i: usize, r: usize, v: f64) {
        let w = band.width;
        let k = CAST as f64;
        if let Some(shading) = self.shading {
            let cast = (CAST * self.refine).min(MAX_CAST);
            if self.limb_pixel(band, (i, r, v), shading, cast) {
                return;
            }
            let k = cast as f64;
            // The reads on a `cast x cast` lattice over the pixel (`None` where the line of
            // sight misses the body), a shadow's edge placed between them as over a block
            // ([`lit_shares`]); the block's lattice is free (a lone pixel builds none).
            band.clear_lattice();
            // The reads' footprint: the first hit's (it changes little within a pixel).
            let mut read_rad = None;
            for j in 0..cast * cast {
                let (a, b) = ((j % cast) as f64, (j / cast) as f64);
                let p = self.probe(i as f64 + (a + 0.5) / k, v - 0.5 + (b + 0.5) / k);
                let read = p.hit.then(|| {
                    read_rad.get_or_insert(p.footprint_rad / k);
                    self.relief_read(shading.0, shading.1, (p.lon, p.lat), None)
                });
                band.push_read((p.lon, p.lat), read);
            }
            band.place_edges(shading, (cast, cast));
            band.reads.clear();
            band.relief.clear();
            band.lit.clear();
            for (j, read) in band.lattice.iter().enumerate() {
                if let Some(read) = read {
                    band.reads.push(band.lattice_at[j]);
                    band.relief.push(*read);
                    band.lit.push(band.lattice_lit[j]);
                }
            }
            band.lattice.clear();
            let got = self.relief_pixel(band, read_rad.unwrap_or(0.0), None, cast * cast);
            self.set_cast_pixel(band, &got, (i, r, v));
            return;
        }
        let mut weights = 0.0;
        band.sums.iter_mut().for_each(|x| *x = 0.0);
        band.squares.iter_mut().for_each(|x| *x = 0.0);
        // The reads' weighted sums of normals, Sun and camera directions: Hapke's ratio is
        // taken at their means.
        let (mut n, mut sun, mut cam) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
        for b in 0..CAST {
            for a in 0..CAST {
                let u = i as f64 + (a as f64 + 0.5) / k;
                let p = self.probe(u, v - 0.5 + (b as f64 + 0.5) / k);
                if !p.hit || p.local.mu <= 0.0 || p.local.mu0 <= 0.0 {
                    continue;
                }
                // The read's radiance at the reference scale.
                let weight = self.brdf_ref.eval(&p.local) * p.local.mu0;
                if weight <= 0.0 {
                    continue;
                }
                let read_rad = p.footprint_rad / k;
                for (m, map) in self.maps.iter().enumerate() {
                    let a = map.scale_over_lon_lat(p.lon, p.lat, read_rad, self.s_ref);
                    band.sums[m] += weight * a;
                    band.squares[m] += weight * a * a;
                }
                n += weight * p.local.n;
                sun += weight * p.local.s;
                cam += weight * p.local.c;
                weights += weight;
            }
        }
        if weights > 0.0 {
            let local = Local::new(n.normalize(), sun.normalize(), cam.normalize());
            for ((img, &sum), &square) in band.pixels.iter_mut().zip(&band.sums).zip(&band.squares)
            {
                img[r * w + i] *= self.mean_ratio(sum / weights, square / weights, &local);
            }
        } else {
            let p = self.probe(i as f64 + 0.5, v);
            for (m, img) in band.pixels.iter_mut().enumerate() {
                img[r * w + i] *= self.exact(m, &p);
            }
        }
    }

    /// `q = 1 - b^2 / R^2` of the line of sight through image point `(u, v)` [px], `b` its
    /// distance from the centre of the sphere of radius `radius_m`: the sphere's `mu_shape^2`
    /// where the line meets it, negative beyond the limb (and behind the camera).
    fn limb_q(&self, radius_m: f64, u: f64, v: f64) -> f64 {
        let dir = super::depth::line_of_sight(self.intrinsics, self.pose, u, v);
        let cam = self.pose.camera_position_m;
        let along = cam.dot(dir);
        if along >= 0.0 {
            return -1.0;
        }
        1.0 - (cam.length_squared() - along * along).max(0.0) / (radius_m * radius_m)
    }

    /// Pixel `(i, r)` (band row; `v` its centre's image row) under the relief where the
    /// limb of a sphere the relief does not displace cuts it or comes within a quarter of its
    /// `mu_shape^2`: read evenly in `mu_shape`, not over the image, and false (nothing done)
    /// elsewhere.
    ///
    /// The light per unit of image, `f_r mu0 mu / mu_shape` (Eq. 37), grows as the inverse
    /// square root of the distance from the limb where the relief faces the camera and hides
    /// nothing from it, so a lattice over the image integrates it right on average but with
    /// a heavy tail: a line of sight next to the limb weighs as much as the rest of its pixel.
    /// On Artemis I row 882 (155 deg, the Sun 6 deg and the camera 2-4 deg above the LOLA
    /// relief at the limb) three pixels of the 64 x 64 lattice's carried +1.8e-4 of the
    /// frame's total, one of them 3.6 times its reference. Along `cast` strips across the
    /// pixel (the axis on which `q = mu_shape^2` changes most), `x(mu)` where `q(x) = mu^2`
    /// turns `int g dx` into `int g (2 mu / q'(x)) dmu`, whose `g mu` is bounded; `cast`
    /// reads a strip, each with its own shadows and no edges placed between them, at the
    /// midpoints of even steps of `mu`, each weighing its share of the pixel. The map `x(mu)`
    /// must be `q`'s own along the strip (here the parabola through `q` at its ends and
    /// middle, from the lines of sight there: over a pixel `q` is smooth to a part in the
    /// disk's radius in pixels, cubed): interpolated bilinearly from the pixel's corners, `q`
    /// is off by a few 1e-7 next to the limb, where `mu^2` is that small, and the same reads
    /// on the reference's integrand came out 4.5e-3 of the 1,622 limb pixels' light dark,
    /// against 3.6e-6 of the frame with `x(mu)` from `q` itself (the branch `exp/limb-882`,
    /// `exp_mu_even_limb`, 16 strips of 64 reads).
    fn limb_pixel(
        &self,
        band: &mut Band,
        (i, r, v): (usize, usize, f64),
        shading: (&Relief, SelfShadowing),
        cast: usize,
    ) -> bool {
        let Shape::Sphere(sphere) = self.shape else {
            return false;
        };
        if shading.0.displaces() {
            return false;
        }
        let radius = sphere.radius_m;
        let (u0, v0) = (i as f64, v - 0.5);
        let q = |x: f64, y: f64| self.limb_q(radius, u0 + x, v0 + y);
        let [q00, q10, q01, q11] = [q(0.0, 0.0), q(1.0, 0.0), q(0.0, 1.0), q(1.0, 1.0)];
        let (lo, hi) = [q00, q10, q01, q11]
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        if !(hi > 0.0 && lo < 0.25 * hi) {
            return false;
        }
        let along_x = ((q10 - q00) + (q11 - q01)).abs() >= ((q01 - q00) + (q11 - q10)).abs();
        let strips = cast;
        let wt = 1.0 / strips as f64;
        band.reads.clear();
        band.relief.clear();
        band.lit.clear();
        let mut read_rad = None;
        for it in 0..strips {
            let t = (it as f64 + 0.5) * wt;
            let at = |x: f64| if along_x { (x, t) } else { (t, x) };
            let qx = |x: f64| {
                let (a, b) = at(x);
                q(a, b)
            };
            let strip = Parabola::through(qx(0.0), qx(0.5), qx(1.0));
            let (m0, m1) = (strip.at(0.0).max(0.0).sqrt(), strip.at(1.0).max(0.0).sqrt());
            let (lo, hi) = (m0.min(m1), m0.max(m1));
            if hi <= 0.0 {
                continue;
            }
            let step = (hi - lo) / cast as f64;
            for j in 0..cast {
                let mu = lo + (j as f64 + 0.5) * step;
                let Some((x, slope)) = strip.where_equal(mu * mu) else {
                    continue;
                };
                // The read's share of the pixel: its strip's width times `dx = 2 mu dmu / q'`.
                let weight = wt * 2.0 * mu * step / slope.abs().max(1e-300);
                let (a, b) = at(x);
                let p = self.probe(u0 + a, v0 + b);
                if !p.hit {
                    continue;
                }
                read_rad.get_or_insert(p.footprint_rad / cast as f64);
                let mut read = self.relief_read(shading.0, shading.1, (p.lon, p.lat), None);
                read.k *= weight;
                read.smooth *= weight;
                band.reads.push((p.lon, p.lat));
                band.lit.push(read.lit());
                band.relief.push(read);
            }
        }
        // `slots` 1: the weights are shares of the whole pixel.
        let got = self.relief_pixel(band, read_rad.unwrap_or(0.0), None, 1);
        self.set_cast_pixel(band, &got, (i, r, v));
        true
    }

    /// Cast pixel `(i, r)` (band row; `v` its centre's image row) from its reads under the
    /// relief ([`Step::relief_pixel`]), or, where none met the body, from the map at its
    /// centre's line of sight.
    fn set_cast_pixel(&self, band: &mut Band, got: &ReliefPixel, (i, r, v): (usize, usize, f64)) {
        if got.read {
            self.set_relief_pixel(band, got, i, r);
        } else {
            let w = band.width;
            let p = self.probe(i as f64 + 0.5, v);
            for (m, img) in band.pixels.iter_mut().enumerate() {
                img[r * w + i] *= self.exact(m, &p);
            }
        }
    }

    /// The mean of `f_r(a) / f_r(s_ref)` at `local`'s angles over reads of scale `a` whose
    /// mean is `mean` and mean square `square`: to second order in their spread, the ratio's
    /// mean at `mean -/+ sd` (the BRDF's curvature in its scale, which Hapke's has; exact for
    /// a ratio quadratic in `a`).
    ///
    /// Where `local` is unlit or unseen (a pixel over the terminator or the limb) the ratio is
    /// taken grazing ([`GRAZING`]), its limit there.
    fn mean_ratio(&self, mean: f64, square: f64, local: &Local) -> f64 {
        let local = Local {
            mu0: local.mu0.max(GRAZING),
            mu: local.mu.max(GRAZING),
            ..*local
        };
        let ratio = self.ratio_at(&local);
        let sd = (square - mean * mean).max(0.0).sqrt();
        if self.linear || sd == 0.0 {
            ratio(mean)
        } else {
            0.5 * (ratio((mean - sd).max(0.0)) + ratio(mean + sd))
        }
    }
}

/// The map coordinates [rad] at four probes (top-left, top-right, bottom-left, bottom-right;
/// longitudes unwrapped about the first's) and how far their bilinear function at `(0.5,
/// 0.5)` is from `centre`'s [texels, the larger of the two axes].
fn corner_map(c: &[Probe; 4], centre: &Probe, band: &Band) -> ([f64; 4], [f64; 4], f64) {
    let lon = c.map(|p| c[0].lon + wrapped(p.lon - c[0].lon));
    let lat = c.map(|p| p.lat);
    let miss = (wrapped(lerp(lon, 0.5, 0.5) - centre.lon) / band.dlon)
        .abs()
        .max(((lerp(lat, 0.5, 0.5) - centre.lat) / band.dlat).abs());
    (lon, lat, miss)
}

/// `b - a` brought into (-pi, pi].
fn wrapped(d: f64) -> f64 {
    d + turn(d)
}

/// The whole turn (-2 pi, 0 or 2 pi) that brings the angle `d` into (-pi, pi].
fn turn(d: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    if d > PI {
        -TAU
    } else if d <= -PI {
        TAU
    } else {
        0.0
    }
}

/// A read's place on the image's lattice of `(ns, nt)` reads a pixel: its column and row on
/// that lattice, `ns` and `nt` ([`Band::shared_reads`]).
type ReadPlace = (i64, i64, usize, usize);

/// One band of [`BLOCK`] image rows being scaled: its pixels in every image, and what every
/// block of it reads.
struct Band<'a> {
    /// The band's rows of each image (one per map).
    pixels: Vec<&'a mut [f64]>,
    width: usize,
    rows: usize,
    /// The band's first image row.
    y0: usize,
    /// The finest map's texel size in longitude and latitude [rad].
    dlon: f64,
    dlat: f64,
    /// Each map's range of BRDF scales (Hapke's table spans it).
    ranges: Vec<(f64, f64)>,
    offsets: Vec<(f64, f64)>,
    /// Per map: Hapke's table of the block, and the pixel's sums of weighted ratios (of
    /// weighted scales and their squares for a single pixel's own ratio).
    tables: Vec<[f64; TABLE]>,
    sums: Vec<f64>,
    squares: Vec<f64>,
    /// A pixel's reads under `MapFilter::Relief` (map coordinates [rad]), what each shows
    /// and its lit share; and the shadows' edges between a lattice's reads ([`lit_shares`]).
    reads: Vec<(f64, f64)>,
    relief: Vec<ReliefRead>,
    lit: Vec<f64>,
    crossings: Vec<f64>,
    /// A block's reads on one lattice, row by row (`None` for the pixels it leaves as they
    /// are), their map coordinates and lit shares ([`Step::read_lattice`]).
    lattice: Vec<Option<ReliefRead>>,
    lattice_at: Vec<(f64, f64)>,
    lattice_lit: Vec<f64>,
    /// The reads of the lattices of the band's last blocks that their lines of sight placed
    /// ([`Step::read_lattice`]), by their place on the image's lattice of `(ns, nt)` reads a
    /// pixel (column, row, `ns`, `nt`), with where those lines of sight met the shape: a
    /// block's ring is its neighbours' own reads, read once (NRHO row 349: 40 % of its
    /// lattices' reads were rings).
    shared_reads: FxHashMap<ReadPlace, ((f64, f64), ReliefRead)>,
    /// A block's pixels to be read again ([`Step::refine`]).
    refine: Vec<(usize, usize, f64, bool)>,
    /// The shadow answers of a pixel's reads at the level before the one being read.
    coarse: Vec<Option<Shadowed>>,
    /// Under `MapFilter::Relief`: the band's rows of the reads' own error estimate per pixel,
    /// signed ([`Step::relief_pixel`]); empty otherwise.
    estimate: &'a mut [f64],
}

impl Band<'_> {
    /// Starts a lattice of reads.
    fn clear_lattice(&mut self) {
        self.lattice.clear();
        self.lattice_at.clear();
        self.lattice_lit.clear();
    }

    /// A read of the lattice being built: where, and what it shows (`None`: not read).
    fn push_read(&mut self, at: (f64, f64), read: Option<ReliefRead>) {
        self.lattice_at.push(at);
        self.lattice_lit
            .push(read.as_ref().map_or(0.0, ReliefRead::lit));
        self.lattice.push(read);
    }

    /// A pixel's reads from the lattice (`lw` reads wide), `(ns, nt)` of them from column
    /// `ca` and row `rb`, into `reads`, `lit` and `relief` ([`Step::relief_pixel`]'s input),
    /// the reads not taken (`None`: beyond the terminator) left out of all three. (Left out of
    /// `relief` only, they had shifted the others' places and lit shares against it.)
    fn take_reads(&mut self, lw: usize, (ca, rb): (usize, usize), (ns, nt): (usize, usize)) {
        self.reads.clear();
        self.relief.clear();
        self.lit.clear();
        for b in 0..nt {
            for a in 0..ns {
                let q = (rb + b) * lw + ca + a;
                if let Some(read) = &self.lattice[q] {
                    self.reads.push(self.lattice_at[q]);
                    self.lit.push(self.lattice_lit[q]);
                    self.relief.push(*read);
                }
            }
        }
    }

    /// The lattice's (`(columns, rows)`) lit shares across the shadows' edges between its
    /// reads ([`lit_shares`]), under ray marching.
    fn place_edges(&mut self, (relief, shadows): (&Relief, SelfShadowing), grid: (usize, usize)) {
        if shadows == SelfShadowing::RayMarching {
            lit_shares(
                relief,
                &mut self.lattice,
                &self.lattice_at,
                grid,
                &mut self.lattice_lit,
                &mut self.crossings,
            );
        }
    }
}

impl Step<'_> {
    /// The reads a block's lattice ([`Step::read_lattice`]) takes beyond the block on each
    /// side: one under `relief_refine` (so that a pixel at the block's side sees its
    /// neighbour's reads in the next block, [`mixed`], and a shadow's edge between them is
    /// placed), else none (as before `relief_refine`: the frames the error model was fitted
    /// on).
    fn ring(&self) -> usize {
        usize::from(self.refine > 1)
    }

    /// The reads per row and per column of the lattice of the block of pixels `(x0, y0)` to
    /// `(x1, y1)` (exclusive) at `(ns, nt)` reads a pixel, [`Step::ring`] included.
    fn lattice_size(
        &self,
        (x0, y0): (usize, usize),
        (x1, y1): (usize, usize),
        (ns, nt): (usize, usize),
    ) -> (usize, usize) {
        let ring = self.ring();
        ((x1 - x0) * ns + 2 * ring, (y1 - y0) * nt + 2 * ring)
    }

    /// The reads of the block of pixels `(x0, y0)` to `(x1, y1)` (band rows, exclusive; map
    /// coordinates bilinear in `lon`, `lat` over `n` px) under `MapFilter::Relief`: `(ns, nt)`
    /// per pixel at `band.offsets`, the midpoints of one lattice over the block, into `band.lattice` (`None`
    /// for a pixel that is dark and whose interpolated `mu0`, with `mu0_per_px` of margin,
    /// says it is on the night side), each with its lit share ([`lit_shares`], edges
    /// between the reads of neighbouring pixels included; under the horizon map, each
    /// read's own answer), with [`Step::ring`] reads more around the block on each side.
    #[allow(clippy::too_many_arguments)]
    fn read_lattice(
        &self,
        band: &mut Band,
        shading: (&Relief, SelfShadowing),
        (x0, y0): (usize, usize),
        (x1, y1): (usize, usize),
        place: &Placement,
        (ns, nt): (usize, usize),
        n: f64,
        mu0_per_px: f64,
        mu0: [f64; 4],
    ) {
        let ring = self.ring();
        let (lw, lh) = self.lattice_size((x0, y0), (x1, y1), (ns, nt));
        let w = band.width;
        band.clear_lattice();
        // Read `j` along an axis of `m` reads a pixel: the pixel (from the block's first, -1
        // for the ring before it) and the read within it.
        let split = |j: usize, m: usize| {
            let j = j as isize - ring as isize;
            (j.div_euclid(m as isize), j.rem_euclid(m as isize) as usize)
        };
        for jy in 0..lh {
            let (pr, b) = split(jy, nt);
            let t = pr as f64 / n;
            // The read's row on the image's lattice of `nt` reads a pixel.
            let gy = ((band.y0 + y0) as i64 + pr as i64) * nt as i64 + b as i64;
            for jx in 0..lw {
                let (pc, a) = split(jx, ns);
                let s = pc as f64 / n;
                let gx = (x0 as i64 + pc as i64) * ns as i64 + a as i64;
                let (du, dv) = band.offsets[b * ns + a];
                // A read of the ring (outside the block) is taken as over a dark pixel.
                let dark = match (usize::try_from(pc), usize::try_from(pr)) {
                    (Ok(c), Ok(r)) if x0 + c < x1 && y0 + r < y1 => band
                        .pixels
                        .iter()
                        .all(|img| img[(y0 + r) * w + x0 + c] == 0.0),
                    _ => true,
                };
                let wanted = !(dark && lerp(mu0, s, t) + mu0_per_px <= 0.0);
                let (at, read) = self.shared_read(
                    band,
                    shading,
                    place,
                    (gx, gy, ns, nt),
                    (s + du, t + dv),
                    wanted,
                );
                band.push_read(at, read);
            }
        }
        band.place_edges(shading, (lw, lh));
    }

    /// The read of a block's lattice at `place` on the image's lattice of reads
    /// ([`ReadPlace`]), at block coordinates `(s, t)` of `placement`, if `wanted`: where a
    /// block of the band read it already (the ring of one is its neighbour's own reads, and a
    /// lattice of reads again meets the blocks' where it reads as many a pixel), that read,
    /// a function of its place alone; else read now and kept, where its line of sight
    /// placed it. With where it lies on the map.
    fn shared_read(
        &self,
        band: &mut Band,
        shading: (&Relief, SelfShadowing),
        placement: &Placement,
        place: ReadPlace,
        (s, t): (f64, f64),
        wanted: bool,
    ) -> ((f64, f64), Option<ReliefRead>) {
        if self.share_reads
            && let Some(&(sight, read)) = band.shared_reads.get(&place)
        {
            return (placement.unwrapped(sight, s, t), wanted.then_some(read));
        }
        let (gx, gy, ns, nt) = place;
        // The image point from the place alone: the same bits for every block that reads it.
        let image = |g: i64, m: usize| {
            g.div_euclid(m as i64) as f64 + (g.rem_euclid(m as i64) as f64 + 0.5) / m as f64
        };
        let sight = (placement.sight).and_then(|_| self.sight(image(gx, ns), image(gy, nt)));
        let at = match sight {
            Some(sight) => placement.unwrapped(sight, s, t),
            None => placement.bilinear(s, t),
        };
        let read = wanted.then(|| self.relief_read(shading.0, shading.1, at, None));
        if let (true, Some(sight), Some(read)) = (self.share_reads, sight, read) {
            band.shared_reads.insert(place, (sight, read));
        }
        (at, read)
    }

    /// Where the line of sight through image point `(u, v)` [px] meets the shape: its
    /// longitude and latitude [rad]; `None` where it misses.
    fn sight(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let cam = self.pose.camera_position_m;
        let dir = super::depth::line_of_sight(self.intrinsics, self.pose, u, v);
        let (t, _) = self.shape.intersect_normal(cam, dir)?;
        Some(crate::geometry::lon_lat_unit((cam + dir * t).normalize()))
    }

    /// A single pixel's longitudes, latitudes and `mu0` as [`Step::block`] interpolates them
    /// (at the pixel's centre and its right, lower and diagonal neighbours' centres), taken
    /// from the lines of sight through the pixel's own corners (`(u, v)` its top-left one
    /// [px]): the bilinear function through those, re-expressed at the neighbours' centres.
    /// `None` where a corner's line of sight misses the body, or where the bilinear
    /// function misses the pixel's centre by what `off` says (then the pixel's reads are
    /// cast). A single pixel's block runs from its centre to its neighbours', so its reads
    /// on the pixel's left and upper halves were extrapolated half a pixel beyond the block;
    /// within a few pixels of the limb, where the image maps onto the surface like a square
    /// root, that squeezed the reads towards the pixel's centre. On Artemis I's row 960
    /// (8,786 km, 146 deg) the second pixel from the limb read the surface from 85.70 to
    /// 84.91 deg W where its lines of sight meet it from 85.80 to 84.89 deg W: the ridge
    /// top that the camera sees in its first sixteenth was never read, and a pixel the
    /// reference has at 8 % of the frame's 99th percentile was 0.
    fn own_corners(
        &self,
        u: f64,
        v: f64,
        band: &Band,
        off: impl Fn(f64) -> bool,
    ) -> Option<([f64; 4], [f64; 4], [f64; 4])> {
        let corners = [
            self.probe(u, v),
            self.probe(u + 1.0, v),
            self.probe(u, v + 1.0),
            self.probe(u + 1.0, v + 1.0),
        ];
        if !corners.iter().all(|p| p.hit) {
            return None;
        }
        let (lon, lat, miss) = corner_map(&corners, &self.probe(u + 0.5, v + 0.5), band);
        if off(miss) {
            return None;
        }
        // The same bilinear function at the block's corners, half a pixel on.
        let at_centres = |q: [f64; 4]| {
            [(0.5, 0.5), (1.5, 0.5), (0.5, 1.5), (1.5, 1.5)].map(|(s, t)| lerp(q, s, t))
        };
        Some((
            at_centres(lon),
            at_centres(lat),
            at_centres(corners.map(|p| p.local.mu0)),
        ))
    }

    /// Scales the pixels of the block of `size` px whose top-left pixel is `(x0, y0)` (band
    /// rows), from the lines of sight through its corners' pixel centres (`c`: top-left,
    /// top-right, bottom-left, bottom-right) and its centre (cast here, once the block is
    /// known to hold lit pixels): interpolated if they agree, else split in four, down to
    /// single pixels.
    fn block(&self, band: &mut Band, x0: usize, y0: usize, size: usize, c: [Probe; 4]) {
        let (w, rows) = (band.width, band.rows);
        let (x1, y1) = ((x0 + size).min(w), (y0 + size).min(rows));
        if x0 >= x1 || y0 >= y1 {
            return;
        }
        let lit = band
            .pixels
            .iter()
            .any(|img| (y0..y1).any(|r| img[r * w + x0..r * w + x1].iter().any(|&v| v != 0.0)));
        // Under `MapFilter::Relief` a pixel across the terminator that the quadrangles left
        // dark is read too (its reads on the day side bring their light).
        let day =
            |p: &Probe| self.shading.is_some() && p.hit && p.local.mu > 0.0 && p.local.mu0 > 0.0;
        if !lit && !c.iter().any(day) {
            return;
        }
        let fy = (band.y0 + y0) as f64 + 0.5;
        let fx = x0 as f64 + 0.5;
        let half = 0.5 * size as f64;
        let centre = self.probe(fx + half, fy + half);
        let (lon, lat, miss) = corner_map(&c, &centre, band);
        // The tolerance grows with the pixel's footprint beyond a texel: a shift of the
        // footprint changes its mean by the shift's share of the footprint. Under the
        // relief's shadows, their edges placed across the blocks, it is the footprint's
        // however fine: a shadow's edge is sharp within a texel, and a pixel it crosses
        // changes by the shift's share of the pixel.
        let tolerance = self.tolerance_texels(centre.footprint_rad / band.dlat);
        let hits = c.iter().chain([&centre]).all(|c| c.hit);
        let smooth = hits && miss < tolerance;
        if !smooth && size > 1 {
            // The 3 x 3 lines of sight of the four quarters' corners.
            let h = size / 2;
            let hf = h as f64;
            let top = self.probe(fx + hf, fy);
            let left = self.probe(fx, fy + hf);
            let right = self.probe(fx + 2.0 * hf, fy + hf);
            let bottom = self.probe(fx + hf, fy + 2.0 * hf);
            let quarters = [
                (0, 0, [c[0], top, left, centre]),
                (h, 0, [top, c[1], centre, right]),
                (0, h, [left, centre, c[2], bottom]),
                (h, h, [centre, right, bottom, c[3]]),
            ];
            for (dx, dy, q) in quarters {
                self.block(band, x0 + dx, y0 + dy, h, q);
            }
            return;
        }
        // A pixel (a block of 1) is interpolated still (its reads integrate it, where one read
        // would stand for the whole footprint), unless a line of sight through its or its
        // neighbours' centres misses the body or the interpolation is off by a fiftieth of
        // the footprint: then its reads are cast.
        let off = |miss: f64| miss >= 2.0 * tolerance.max(TOLERANCE_TEXELS * 10.0);
        let far_off = !smooth && off(miss);
        // A pixel that passes is placed from the lines of sight through its own corners
        // instead ([`Step::own_corners`]), and cast where even those miss.
        let placed = (size == 1 && hits && !far_off)
            .then(|| self.own_corners(fx - 0.5, fy - 0.5, band, off));
        if size == 1 && (!hits || far_off || placed.is_some_and(|p| p.is_none())) {
            let (i, r) = (x0, y0);
            let v = (band.y0 + r) as f64 + 0.5;
            if band.pixels.iter().any(|img| img[r * w + i] != 0.0) || c.iter().any(day) {
                self.cast_pixel(band, i, r, v);
            }
            return;
        }
        let n = size as f64;
        // Texels per pixel along the image's two axes, the larger of the block's two edges.
        // Measured on the surface, in texels of latitude: towards a pole a column of the map
        // narrows as `cos(lat)`, and the map is read as finely as the surface needs, not as
        // its columns crowd (which at -79 deg read a pixel from levels 5 times too coarse).
        let cos_lat = centre.lat.cos();
        let texels = |dl: f64, da: f64| (dl * cos_lat).hypot(da) / band.dlat / n;
        let len_s =
            texels(lon[1] - lon[0], lat[1] - lat[0]).max(texels(lon[3] - lon[2], lat[3] - lat[2]));
        let len_t =
            texels(lon[2] - lon[0], lat[2] - lat[0]).max(texels(lon[3] - lon[1], lat[3] - lat[1]));
        // Under the relief's refinement, at least two reads per side: one read has nothing
        // to disagree with.
        let least = if self.shading.is_some() && self.refine > 1 {
            REFINED_MIN_READS
        } else {
            1
        };
        let (ns, nt) = (
            reads_per_side(len_s, self.spacing_texels, least),
            reads_per_side(len_t, self.spacing_texels, least),
        );
        band.offsets.clear();
        for b in 0..nt {
            for a in 0..ns {
                let o = |k: usize, m: usize| ((k as f64 + 0.5) / m as f64 - 0.5) / n;
                band.offsets.push((o(a, ns), o(b, nt)));
            }
        }
        // Each read is weighted by the light it stands for per unit of image, `mu0`
        // interpolated from the corners (clamped at 0): across the terminator a pixel's power
        // comes from its lit part, whose albedo is what it shows.
        let mu0 = [
            c[0].local.mu0,
            c[1].local.mu0,
            c[2].local.mu0,
            c[3].local.mu0,
        ];
        let (lon, lat, mu0) = placed.flatten().unwrap_or((lon, lat, mu0));
        // Under the relief every read is placed by its own line of sight ([`Placement`]).
        // The corners' bilinear function, though checked at the block's centre, still bent
        // the reads of a pixel near the limb; and it missed where they lie by up to the
        // tolerance, which near the terminator, where a pixel is its reads' mean light
        // alone ([`Step::absolute_scale`]), moved `mu0` one way: on Artemis I row 1146
        // (13,350 km, 134 deg) with the relief flattened, those pixels were +1.2e-4 at the
        // median and the frame +5.3e-5 (now +4.5e-6). A relief read's shadow rays cost ten
        // times its line of sight (that frame's footprint step took no longer); a map read
        // alone is cheaper than one, and the map's reads stay interpolated: on the NRHO's
        // far frames under the planner's `pixel` rungs, 1.3 times the frame.
        let place = Placement {
            lon,
            lat,
            sight: self.shading.is_some().then_some((fx, fy, n)),
        };
        // How much `mu0` changes across a pixel of the block (at most).
        let mu0_per_px = (mu0.iter().fold(f64::MIN, |a, &b| a.max(b))
            - mu0.iter().fold(f64::MAX, |a, &b| a.min(b)))
            / n;
        // What each read stands for [rad of latitude]: at most half a texel (the map itself)
        // but where `READ_SPAN_TEXELS` caps the reads (then an area-averaged level).
        let read_rad = (len_s / ns as f64).max(len_t / nt as f64) * band.dlat;
        // Hapke's ratio: tabulated per block, or for a lone pixel (the limb, the terminator)
        // at its own angles.
        let own = !self.linear && size == 1;
        // A single pixel's angles: its centre's, or where that is unlit or unseen (the
        // terminator) its most lit and visible neighbour's; [`Step::mean_ratio`] takes them
        // at least grazing.
        let own_local = if own {
            lit_or_brightest(&c[0], &c).local
        } else {
            c[0].local
        };
        let tabulated = |(a_lo, a_hi): (f64, f64)| !self.linear && !own && a_hi > a_lo;
        if self.shading.is_none() && band.ranges.iter().any(|&r| tabulated(r)) {
            // At the angles of the block's centre, where it is lit and seen (the ratio varies
            // smoothly over the block: the centre's is its mean to second order), else of
            // its most lit and visible corner.
            let ratio = self.ratio_at(&lit_or_brightest(&centre, &c).local);
            for (table, &(a_lo, a_hi)) in band.tables.iter_mut().zip(&band.ranges) {
                for (k, t) in table.iter_mut().enumerate() {
                    *t = ratio(a_lo + (a_hi - a_lo) * k as f64 / (TABLE - 1) as f64);
                }
            }
        }
        band.lattice.clear();
        for r in y0..y1 {
            let t = (r - y0) as f64 / n;
            for i in x0..x1 {
                let s = (i - x0) as f64 / n;
                if band.pixels.iter().all(|img| img[r * w + i] == 0.0)
                    && !(self.shading.is_some() && lerp(mu0, s, t) + mu0_per_px > 0.0)
                {
                    continue;
                }
                if let Some(shading) = self.shading {
                    // The block's lattice of reads, once: its pixels' reads continue one
                    // another's grid, so a shadow's edge is found between two pixels' reads
                    // too.
                    if band.lattice.is_empty() {
                        self.read_lattice(
                            band,
                            shading,
                            (x0, y0),
                            (x1, y1),
                            &place,
                            (ns, nt),
                            n,
                            mu0_per_px,
                            mu0,
                        );
                    }
                    let (lw, lh) = self.lattice_size((x0, y0), (x1, y1), (ns, nt));
                    // The pixel's first read on the lattice, along each axis.
                    let ring = self.ring();
                    let (ca, rb) = ((i - x0) * ns + ring, (r - y0) * nt + ring);
                    band.take_reads(lw, (ca, rb), (ns, nt));
                    let got = self.relief_pixel(band, read_rad, Some((ns, nt)), ns * nt);
                    if self.refine > 1
                        && (got.estimate.abs() > REFINE_ABOVE
                            || mixed(
                                &band.lattice,
                                &band.lattice_lit,
                                lw,
                                (ca.saturating_sub(1), (ca + ns + 1).min(lw)),
                                (rb.saturating_sub(1), (rb + nt + 1).min(lh)),
                            ))
                    {
                        // Read again once the block's lattice has served all its pixels.
                        let factor = band.sums.first().copied().unwrap_or(0.0);
                        band.refine.push((i, r, factor, got.absolute));
                        continue;
                    }
                    self.set_relief_pixel(band, &got, i, r);
                    band.estimate[r * w + i] = got.estimate;
                    continue;
                }
                // The pixel's weighted mean of the BRDF's ratio over each map: the bilinear
                // map at `ns x nt` midpoints of the pixel (at the footprint's level beyond
                // `READ_SPAN_TEXELS`), each read's ratio from the block's table, or a single
                // pixel's over the mean and spread of its reads (Hapke's is not linear in `w`).
                let mut weights = 0.0;
                band.sums.iter_mut().for_each(|x| *x = 0.0);
                band.squares.iter_mut().for_each(|x| *x = 0.0);
                for (a, b) in &band.offsets {
                    let (s, t) = (s + a, t + b);
                    let weight = lerp(mu0, s, t).max(0.0) + 1e-12;
                    let (lon, lat) = (lerp(lon, s, t), lerp(lat, s, t));
                    for (m, map) in self.maps.iter().enumerate() {
                        let a = map.scale_over_lon_lat(lon, lat, read_rad, self.s_ref);
                        let (a_lo, a_hi) = band.ranges[m];
                        if own {
                            band.squares[m] += weight * a * a;
                        }
                        band.sums[m] += weight
                            * if tabulated(band.ranges[m]) {
                                let x = ((a - a_lo) / (a_hi - a_lo) * (TABLE - 1) as f64)
                                    .clamp(0.0, (TABLE - 1) as f64);
                                quadratic(&band.tables[m], x)
                            } else if own {
                                a
                            } else {
                                a / self.s_ref
                            };
                    }
                    weights += weight;
                }
                for ((img, &sum), &square) in
                    band.pixels.iter_mut().zip(&band.sums).zip(&band.squares)
                {
                    img[r * w + i] *= if own {
                        self.mean_ratio(sum / weights, square / weights, &own_local)
                    } else {
                        sum / weights
                    };
                }
            }
        }
        if let Some(shading) = self.shading
            && !band.refine.is_empty()
        {
            let geometry = BlockGeometry {
                origin: (x0, y0),
                place,
                reads: (ns, nt),
                n,
                read_rad,
            };
            self.refine(band, shading, &geometry);
        }
    }

    /// Reads again the pixels of a block left in `band.refine` (their reads' own estimate
    /// above [`REFINE_ABOVE`], or light and none among their reads and the ring around
    /// them: [`mixed`]), each on a lattice of its own twice as fine per side as before
    /// with a ring of reads one spacing beyond its sides, again while its light moves by more
    /// than [`REFINE_ABOVE`] from one level to the next (or between the ratio and the
    /// absolute form) and up to `self.refine` times the block's reads per side, and scales
    /// them. The reads are a block's ([`Step::read_lattice`]: each its own shadow rays, the
    /// shadows' edges placed between them, the ring's included), only denser: the pixels a
    /// shadow's edge crosses, where an all-or-nothing read converges as its spacing. Picked
    /// by the estimate alone, a pixel whose reads all fell in shadow beside a lit neighbour
    /// stayed dark at every level (NRHO row 167, 129 deg: p99 0.166 at `relief_refine` 8,
    /// against 5.1e-2 now); taken to `self.refine` whatever its light did, the apolune
    /// frame and row 167 took 2.8 and 1.9 times as long for the same p99
    /// (`docs/performance.md`, "Pixels read again where their reads disagree").
    ///
    /// From the second level on, a read whose four reads around it on the level before agree
    /// on the Sun's shadow (and on the camera's, where they were asked it), none of them
    /// beside a shadow's edge, takes their answers without marching ([`inherited`]); the
    /// others are marched and the edges placed between all the reads as before. The first
    /// level marches every read: a shadow thinner than the block's spacing is found there.
    /// A shadow that falls wholly between four reads of a level that agree is lost, as the
    /// block's lattice loses one between its own reads. On the NRHO's four far frames at
    /// `relief_refine` 8 the step took 1.13 to 1.23 times less than marching every read,
    /// p99 within 3e-4 of it; inheriting at the first level too was 1.4 to 1.5 times faster
    /// but lost 5e-4 to 1.7e-3 of p99, row 138 going over the budget (3.03e-2)
    /// (`docs/performance.md`, "Finer reads take their shadows from the coarser level").
    fn refine(&self, band: &mut Band, shading: (&Relief, SelfShadowing), g: &BlockGeometry) {
        let w = band.width;
        let mut pending = std::mem::take(&mut band.refine);
        let (ns, nt) = g.reads;
        for &(i, r, mut before, mut absolute) in &pending {
            let (si, ti) = ((i - g.origin.0) as f64 / g.n, (r - g.origin.1) as f64 / g.n);
            let mut f = 2;
            while f <= self.refine {
                let (ms, mt) = (ns * f, nt * f);
                // The pixel's reads and a ring of reads around them, one spacing out.
                let (ls, lt) = (ms + 2, mt + 2);
                let last = 2 * f > self.refine;
                band.clear_lattice();
                for jy in 0..lt {
                    let t = ti + ((jy as f64 - 0.5) / mt as f64 - 0.5) / g.n;
                    for jx in 0..ls {
                        let s = si + ((jx as f64 - 0.5) / ms as f64 - 0.5) / g.n;
                        // The first level marches every read (a shadow thinner than the
                        // block's spacing is found there), a function of its place alone,
                        // which a neighbour read again may have read (its ring); the finer
                        // ones inherit from the level before, each pixel from its own.
                        if f == 2 {
                            let gx = i as i64 * ms as i64 + jx as i64 - 1;
                            let gy = (band.y0 + r) as i64 * mt as i64 + jy as i64 - 1;
                            let place = (gx, gy, ms, mt);
                            let (at, read) =
                                self.shared_read(band, shading, &g.place, place, (s, t), true);
                            band.push_read(at, read);
                            continue;
                        }
                        let at = g.place.at(self, s, t);
                        let known = inherited(&band.coarse, ms / 2 + 2, (jx, jy));
                        let read = self.relief_read(shading.0, shading.1, at, known);
                        band.push_read(at, Some(read));
                    }
                }
                band.place_edges(shading, (ls, lt));
                band.take_reads(ls, (1, 1), (ms, mt));
                let got = self.relief_pixel(band, g.read_rad / f as f64, Some((ms, mt)), ms * mt);
                let factor = band.sums.first().copied().unwrap_or(0.0);
                let again = got.absolute != absolute
                    || (factor - before).abs() > REFINE_ABOVE * factor.abs();
                if last || !again {
                    self.set_relief_pixel(band, &got, i, r);
                    band.estimate[r * w + i] = got.estimate;
                    break;
                }
                (before, absolute) = (factor, got.absolute);
                band.coarse.clear();
                let shadowed = band.lattice.iter().zip(&band.lattice_lit).map(Shadowed::of);
                band.coarse.extend(shadowed);
                f *= 2;
            }
        }
        band.clear_lattice();
        // The list goes back empty, its allocation kept for the next block.
        pending.clear();
        band.refine = pending;
    }
}

/// A read's shadow answers under ray marching, where a finer read can take them without
/// marching ([`Step::refine`]): the Sun's, and the camera's where it was asked.
#[derive(Clone, Copy, PartialEq)]
struct Shadowed {
    sun: bool,
    camera: Option<bool>,
}

impl Shadowed {
    /// A read's answers, given its lit share ([`lit_shares`]); `None` where there is no
    /// read, where its facet does not face the Sun and the camera (it was not marched), or
    /// where a shadow's edge was placed beside it (its share neither 0 nor 1): a finer read
    /// within two spacings of an edge is marched.
    fn of((read, &lit): (&Option<ReliefRead>, &f64)) -> Option<Shadowed> {
        if lit > 0.0 && lit < 1.0 {
            return None;
        }
        read.as_ref().filter(|r| r.k > 0.0).map(|r| Shadowed {
            sun: r.hidden[0],
            camera: r.camera_asked.then_some(r.hidden[1]),
        })
    }
}

/// The shadow answers of read `(jx, jy)` of a refined lattice from the coarser one below it
/// (`coarse`, `cw` reads wide, each coarse read two fine spacings apart, both with a ring;
/// [`Shadowed::of`] each): where the four coarse reads around it agree, theirs; else `None`
/// (it is marched).
fn inherited(coarse: &[Option<Shadowed>], cw: usize, (jx, jy): (usize, usize)) -> Option<Shadowed> {
    let (cx, cy) = (jx / 2, jy / 2);
    let first = coarse[cy * cw + cx]?;
    let mut camera = first.camera;
    for q in [cy * cw + cx + 1, (cy + 1) * cw + cx, (cy + 1) * cw + cx + 1] {
        let other = coarse[q]?;
        if other.sun != first.sun {
            return None;
        }
        if other.camera != camera {
            camera = None;
        }
    }
    Some(Shadowed {
        sun: first.sun,
        camera: if first.sun { None } else { camera },
    })
}

/// Whether the reads of columns `c0..c1` and rows `r0..r1` of a lattice `lw` reads wide (a
/// pixel's and the ring of reads around them) hold both light and none: a read's light is its lit
/// share ([`lit_shares`]) where the DEM's facet faces the Sun and the camera, 0 where it does
/// not (an attached shadow's edge, sharp at the bilinear DEM's texel edges, counts as a cast
/// one's). A pixel whose own reads all lie in shadow next to a lit neighbour's has an
/// estimate of 0 ([`relief_estimate`]) however much of it is lit.
fn mixed(
    lattice: &[Option<ReliefRead>],
    lit: &[f64],
    lw: usize,
    (c0, c1): (usize, usize),
    (r0, r1): (usize, usize),
) -> bool {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for row in r0..r1 {
        for col in c0..c1 {
            let q = row * lw + col;
            if let Some(r) = &lattice[q] {
                let l = if r.k > 0.0 { lit[q] } else { 0.0 };
                lo = lo.min(l);
                hi = hi.max(l);
            }
        }
    }
    lo < 1.0 && hi > 0.0
}

/// A block's top-left pixel, side [px], map coordinates at its corners and reads per
/// pixel, and what each read stands for [rad], for the pixels read again
/// ([`Step::refine`]).
struct BlockGeometry {
    origin: (usize, usize),
    place: Placement,
    reads: (usize, usize),
    n: f64,
    read_rad: f64,
}

/// Where a block's reads lie on the map, at block coordinates `(s, t)` (0 at the top-left
/// pixel's centre, 1 a block's side on): bilinear in the longitudes and latitudes at the
/// block's corners, or, under the relief (`sight`: the image point of `(0, 0)` and the
/// block's side [px]), where each read's own line of sight meets the shape ([`Step::sight`];
/// the bilinear place where it misses, a ring's read beyond the limb).
#[derive(Clone, Copy)]
struct Placement {
    lon: [f64; 4],
    lat: [f64; 4],
    sight: Option<(f64, f64, f64)>,
}

impl Placement {
    fn at(&self, step: &Step, s: f64, t: f64) -> (f64, f64) {
        match self
            .sight
            .and_then(|(u, v, n)| step.sight(u + s * n, v + t * n))
        {
            Some(sight) => self.unwrapped(sight, s, t),
            None => self.bilinear(s, t),
        }
    }

    /// The bilinear place at `(s, t)`.
    fn bilinear(&self, s: f64, t: f64) -> (f64, f64) {
        (lerp(self.lon, s, t), lerp(self.lat, s, t))
    }

    /// A line of sight's place `(lon, lat)` on the block at `(s, t)`, its longitude on the
    /// turn of the bilinear one's, as the lattice's neighbours are (the same bits where no
    /// turn is added).
    fn unwrapped(&self, (lon, lat): (f64, f64), s: f64, t: f64) -> (f64, f64) {
        (lon + turn(lon - lerp(self.lon, s, t)), lat)
    }
}

/// `first` where it is lit and seen, else the most lit and visible of `others` (by
/// `mu0 mu`): the angles a Hapke ratio is taken at.
fn lit_or_brightest<'p>(first: &'p Probe, others: &'p [Probe]) -> &'p Probe {
    let light = |p: &Probe| p.local.mu0.max(0.0) * p.local.mu.max(0.0);
    if light(first) > 0.0 {
        return first;
    }
    others
        .iter()
        .max_by(|a, b| light(a).total_cmp(&light(b)))
        .unwrap_or(first)
}

/// Halvings of the spacing between two reads on either side of a shadow's edge that place
/// the edge between them ([`lit_shares`]): to 1/16 of the spacing. NRHO row 493's
/// terminator window (128 x 128) at 1, 2 and 3 halvings: p99 0.34, 0.28, 0.245, p95 8.3e-2,
/// 6.1e-2, 5.5e-2; the budgeted file's median frame 5, 7.5 and 10 % slower than without
/// the shares (5 NRHO frames; the 25-frame bench: 9 %). More halvings measured no better.
const EDGE_HALVINGS: u32 = 3;

/// The lit share of each read of a lattice (`reads`, at map coordinates `at`, `(ns, nt)`
/// of them row by row; `None` where nothing is read) where a shadow's edge runs between
/// them: `lit` holds 1 or 0 from each read's own shadow rays; where two neighbours on the
/// lattice (both facing the Sun and the camera) are on either side of an edge, the edge is
/// placed between them by halving the segment ([`EDGE_HALVINGS`], each point its own shadow
/// ray), and a read beside an edge takes the share of its cell (the square of the lattice
/// around it) on its own side of the straight line through the edge's nearest crossings of
/// the lattice's two axes ([`cell_share`]), or across a sliver narrower than its cell
/// (edges on both sides along an axis) the rectangle between the crossings ([`CellSide`]).
/// Per shadow ray (the Sun's, the camera's; a read in the Sun's shadow is asked the camera's
/// only beside the Sun's edge); the read's lit share is the part of its cell lit by the Sun
/// and seen by the camera both, clipped exactly ([`lit_part`]): the product of the two
/// shares doubled the strips lit between the Sun's edge and the camera's (Artemis I row 730).
///
/// The reads' own answers converge on a pixel's lit part only as their spacing: doubling
/// them per side on `config/nrho_textured.toml`'s apolune frame halved its p99 (0.135 ->
/// 0.077), median and total alike. Shadows are hard (a point Sun, as in the reference). A
/// clearance angle interpolated linearly between the reads placed the edges poorly (p99
/// 0.124 there): the bilinear DEM's kinks at its cell edges start shadows abruptly. Edges
/// found within each pixel only left a pixel whose reads all lie in shadow dark, however
/// much of it is lit (NRHO row 493's terminator: p99 1.0; over the block's lattice 0.245).
fn lit_shares(
    relief: &Relief,
    reads: &mut [Option<ReliefRead>],
    at: &[(f64, f64)],
    (ns, nt): (usize, usize),
    lit: &mut [f64],
    crossings: &mut Vec<f64>,
) {
    let n = reads.len();
    if n != ns * nt || at.len() != n || n < 2 {
        return;
    }
    let toward = |r: &ReliefRead, ray: usize| if ray == 0 { r.local.s } else { r.local.c };
    // Where the edge crosses from read `j` to read `q` [share of the spacing from `j`].
    let crossing =
        |j: &ReliefRead, q: &ReliefRead, (at_j, at_q): ((f64, f64), (f64, f64)), ray: usize| {
            let hidden = j.hidden[ray];
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..EDGE_HALVINGS {
                let f = 0.5 * (lo + hi);
                let up = crate::geometry::unit_from_lon_lat(
                    at_j.0 + f * (at_q.0 - at_j.0),
                    at_j.1 + f * (at_q.1 - at_j.1),
                );
                let dir = (toward(j, ray) * (1.0 - f) + toward(q, ray) * f).normalize();
                if relief.occluded(up, dir) == hidden {
                    lo = f;
                } else {
                    hi = f;
                }
            }
            0.5 * (lo + hi)
        };
    // Per ray: the crossing from each read to its right neighbour, then to the one below
    // (NaN where none).
    crossings.clear();
    crossings.resize(4 * n, f64::NAN);
    // The edge's distances from read `j` [spacings] along the lattice's rows (before it,
    // after it) and columns, for `ray` (NaN where no edge).
    let distances = |crossings: &[f64], ray: usize, j: usize| {
        let right = &crossings[(2 * ray) * n..(2 * ray + 1) * n];
        let down = &crossings[(2 * ray + 1) * n..(2 * ray + 2) * n];
        let before = |c: &[f64], q: Option<usize>| q.map_or(f64::NAN, |q| 1.0 - c[q]);
        (
            [before(right, (j % ns > 0).then(|| j - 1)), right[j]],
            [before(down, (j >= ns).then(|| j - ns)), down[j]],
        )
    };
    let mut any = false;
    for ray in 0..2 {
        if ray == 1 {
            // A read in the Sun's shadow beside its edge needs the camera's answer too.
            for j in 0..n {
                let (x, y) = distances(crossings, 0, j);
                if let Some(r) = &mut reads[j]
                    && !r.camera_asked
                    && x.iter().chain(&y).any(|d| !d.is_nan())
                {
                    let up = crate::geometry::unit_from_lon_lat(at[j].0, at[j].1);
                    r.hidden[1] = relief.occluded(up, r.local.c);
                    r.camera_asked = true;
                }
            }
        }
        let asked = |j: usize| {
            reads[j]
                .as_ref()
                .filter(|r| r.k > 0.0 && (ray == 0 || r.camera_asked))
        };
        for j in 0..n {
            let Some(rj) = asked(j) else { continue };
            let mut cross = |q: usize, slot: usize| {
                if let Some(rq) = asked(q)
                    && rq.hidden[ray] != rj.hidden[ray]
                {
                    crossings[slot] = crossing(rj, rq, (at[j], at[q]), ray);
                    any = true;
                }
            };
            if j % ns + 1 < ns {
                cross(j + 1, 2 * ray * n + j);
            }
            if j + ns < n {
                cross(j + ns, (2 * ray + 1) * n + j);
            }
        }
    }
    if !any {
        return;
    }
    for j in 0..n {
        let Some(rj) = reads[j].as_ref().filter(|r| r.k > 0.0) else {
            continue;
        };
        // The read's own side of each ray's edge within its cell, and that side's share.
        let mut sides = [CellSide::WHOLE; 2];
        for (ray, side) in sides.iter_mut().enumerate() {
            if ray == 1 && !rj.camera_asked {
                continue; // in the Sun's shadow's depth: its share is 0 already
            }
            let (x, y) = distances(crossings, ray, j);
            *side = CellSide::of(x, y);
        }
        let hidden = [rj.hidden[0], rj.hidden[1] && rj.camera_asked];
        lit[j] = lit_part(&sides, hidden);
    }
}

/// The lit share of a read's cell: the Sun's lit part and the camera's, each the read's
/// own side of that ray's edge ([`CellSide`]), or the rest of the cell where the read is the
/// hidden one.
fn lit_part(sides: &[CellSide; 2], hidden: [bool; 2]) -> f64 {
    let joint = match (sides[0].planes(), sides[1].planes()) {
        (Some(a), Some(b)) => {
            let mut both = [(0.0, 0.0, 0.0); 8];
            both[..a.len()].copy_from_slice(a);
            both[a.len()..a.len() + b.len()].copy_from_slice(b);
            clipped_area(&both[..a.len() + b.len()])
        }
        _ => sides[0].area.min(sides[1].area),
    };
    let (a0, a1) = (sides[0].area, sides[1].area);
    match hidden {
        [false, false] => joint,
        [true, false] => a1 - joint,
        [false, true] => a0 - joint,
        [true, true] => 1.0 - a0 - a1 + joint,
    }
    .clamp(0.0, 1.0)
}

/// A read's own side of one ray's shadow edge within its cell (the square `[-1/2, 1/2]^2`
/// of the lattice around it, in spacings, [`lit_shares`]): the half-planes
/// `m + gx x + gy y > 0` it is the intersection of (none: the whole cell) and its share of
/// the cell.
#[derive(Clone, Copy)]
struct CellSide {
    planes: [(f64, f64, f64); 4],
    n: usize,
    area: f64,
}

impl CellSide {
    const WHOLE: CellSide = CellSide {
        planes: [(0.0, 0.0, 0.0); 4],
        n: 0,
        area: 1.0,
    };

    /// From the edge's distances to the read along the lattice's rows `x` and columns `y`
    /// (before it, after it; NaN where no edge): where edges lie on both sides along an
    /// axis (a sliver narrower than the cell), the rectangle between the nearest crossings
    /// on each axis; else the side of the straight line through them, `1 - x/dx - y/dy`
    /// with the signs of their sides.
    fn of(x: [f64; 2], y: [f64; 2]) -> CellSide {
        let mut side = CellSide::WHOLE;
        if x.iter().chain(&y).all(|d| d.is_nan()) {
            return side;
        }
        let mut push = |plane: (f64, f64, f64)| {
            side.planes[side.n] = plane;
            side.n += 1;
        };
        if x.iter().all(|d| !d.is_nan()) || y.iter().all(|d| !d.is_nan()) {
            // Along each axis the read's side within its cell: `-l < x < r`.
            let half = |d: f64| if d.is_nan() { 0.5 } else { d.min(0.5) };
            let along = |[l, r]: [f64; 2]| half(l) + half(r);
            for (axis, [l, r]) in [(0, x), (1, y)] {
                let g = |s: f64| if axis == 0 { (s, 0.0) } else { (0.0, s) };
                if !l.is_nan() {
                    let (gx, gy) = g(1.0);
                    push((half(l), gx, gy));
                }
                if !r.is_nan() {
                    let (gx, gy) = g(-1.0);
                    push((half(r), gx, gy));
                }
            }
            side.area = along(x) * along(y);
        } else {
            // The nearest crossing on each axis, `+1/l` before the read, `-1/r` after it.
            let slope = |[l, r]: [f64; 2]| {
                if !l.is_nan() {
                    1.0 / l.max(1e-9)
                } else if !r.is_nan() {
                    -1.0 / r.max(1e-9)
                } else {
                    0.0
                }
            };
            let (gx, gy) = (slope(x), slope(y));
            push((1.0, gx, gy));
            side.area = cell_share(1.0, gx, gy);
        }
        side
    }

    /// The half-planes, or `None` for the whole cell.
    fn planes(&self) -> Option<&[(f64, f64, f64)]> {
        (self.n > 0).then(|| &self.planes[..self.n])
    }
}

/// The area of the part of the unit square `[-1/2, 1/2]^2` on which every `m + gx x + gy y`
/// of `planes` is positive (the square clipped by each half-plane in turn, then the shoelace).
/// The lit part of a read's cell where both the Sun's and the camera's edges cross it
/// ([`lit_shares`]): the product of the two shares took them as independent, and a sliver
/// lit between the Sun's shadow and the ground the camera cannot see (Artemis I row 730,
/// 191 km up at 108 deg of phase: lit strips 0.02 px across, one side the Sun's edge, the
/// other the camera's) came out at twice its light.
fn clipped_area(planes: &[(f64, f64, f64)]) -> f64 {
    const MAX: usize = 16;
    let mut poly = [(0.0f64, 0.0f64); MAX];
    let mut next = [(0.0f64, 0.0f64); MAX];
    poly[..4].copy_from_slice(&[(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]);
    let mut len = 4;
    for &(m, gx, gy) in planes {
        let f = |(x, y): (f64, f64)| m + gx * x + gy * y;
        let mut k = 0;
        for i in 0..len {
            let (a, b) = (poly[i], poly[(i + 1) % len]);
            let (fa, fb) = (f(a), f(b));
            if fa > 0.0 && k < MAX {
                next[k] = a;
                k += 1;
            }
            if (fa > 0.0) != (fb > 0.0) && k < MAX {
                let t = fa / (fa - fb);
                next[k] = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                k += 1;
            }
        }
        poly[..k].copy_from_slice(&next[..k]);
        len = k;
        if len < 3 {
            return 0.0;
        }
    }
    let mut twice = 0.0;
    for i in 0..len {
        let (a, b) = (poly[i], poly[(i + 1) % len]);
        twice += a.0 * b.1 - b.0 * a.1;
    }
    0.5 * twice.abs()
}

/// The share of the unit square `[-1/2, 1/2]^2` on which `m + gx x + gy y > 0`: with
/// `p >= q >= 0` the larger and smaller of `|gx|`, `|gy|`, the integral over `x` of
/// `clamp((m + q x) / p + 1/2, 0, 1)`, exact by the antiderivative of the clamp.
fn cell_share(m: f64, gx: f64, gy: f64) -> f64 {
    let (p, q) = (gx.abs().max(gy.abs()), gx.abs().min(gy.abs()));
    if p <= 0.0 || p.is_nan() {
        return if m > 0.0 {
            1.0
        } else if m < 0.0 {
            0.0
        } else {
            0.5
        };
    }
    let alpha = m / p + 0.5;
    let beta = q / p;
    if beta < 1e-9 {
        return alpha.clamp(0.0, 1.0);
    }
    let g = |u: f64| {
        if u <= 0.0 {
            0.0
        } else if u >= 1.0 {
            u - 0.5
        } else {
            0.5 * u * u
        }
    };
    ((g(alpha + 0.5 * beta) - g(alpha - 0.5 * beta)) / beta).clamp(0.0, 1.0)
}

/// The weight of read `k` of `n` at the midpoints of `n` equal cells along a pixel's side
/// (their mean is 1): the midpoint rule with the Euler-Maclaurin term at its ends,
/// `h^2 / 24 (f'(b) - f'(a))`, the difference of slopes taken as `n h` times the reads'
/// mean second difference. Three reads take 3/8, 1/4, 3/8 of the side (the open Maclaurin
/// rule); more, `1 + c, 1 - c, 1, ..., 1, 1 - c, 1 + c` with `c = n / (24 (n - 2))`.
/// Exact for cubics, positive, and unbiased over a kink of the light that falls anywhere
/// between the reads (its mean over the kink's place is a quadratic). The coarser quarter of
/// the reads that [`relief_estimate`] sets against them is left unweighted.
///
/// The midpoint rule alone leaned. The relief's light is concave where it is lit (the product
/// of `mu0` and `mu` as the slope tilts towards one and away from the other) and kinked
/// where a facet turns from the Sun; summed over the frame the two cancel, but the pixels
/// holding the kinks are read again ([`Step::refine`]) and the concave rest kept its bright
/// error: Artemis I row 1146 (13,350 km, 134 deg) +1.45e-4 of the frame's light against its
/// reference (+1.37e-4 without the relief's shadows, -7e-6 with reads 8 times as fine), now
/// +8.3e-6; its median 6.0e-4 -> 2.7e-4.
fn end_weight(k: usize, n: usize) -> f64 {
    if n < 3 {
        return 1.0;
    }
    let c = n as f64 / (24.0 * (n - 2) as f64);
    if n == 3 {
        return if k == 1 { 1.0 - 2.0 * c } else { 1.0 + c };
    }
    if k == 0 || k + 1 == n {
        1.0 + c
    } else if k == 1 || k + 2 == n {
        1.0 - c
    } else {
        1.0
    }
}

/// `q(x) = c0 + c1 x + c2 x^2` on `[0, 1]`: a limb pixel's `mu_shape^2` along a strip
/// ([`Step::limb_pixel`]).
struct Parabola {
    c0: f64,
    c1: f64,
    c2: f64,
}

impl Parabola {
    /// Through `(0, q0)`, `(1/2, qh)` and `(1, q1)`.
    fn through(q0: f64, qh: f64, q1: f64) -> Parabola {
        let c2 = 2.0 * (q1 - 2.0 * qh + q0);
        Parabola {
            c0: q0,
            c1: q1 - q0 - c2,
            c2,
        }
    }

    fn at(&self, x: f64) -> f64 {
        self.c0 + x * (self.c1 + x * self.c2)
    }

    /// The `x` in `[0, 1]` where `q(x) = target`, and `q'(x)` there; None where there is
    /// none. The root is taken in the form without cancellation; `q` is monotonic on a
    /// strip of a limb pixel (its axis is the one `q` changes most along, and the sphere's
    /// centre is far).
    fn where_equal(&self, target: f64) -> Option<(f64, f64)> {
        let d = target - self.c0;
        let x = if self.c2.abs() * 1e12 < self.c1.abs() {
            d / self.c1
        } else {
            let disc = self.c1 * self.c1 + 4.0 * self.c2 * d;
            if disc < 0.0 {
                return None;
            }
            let root = disc.sqrt();
            let den = self.c1 + self.c1.signum() * root;
            if den == 0.0 {
                return None;
            }
            2.0 * d / den
        };
        (-1e-9..=1.0 + 1e-9)
            .contains(&x)
            .then(|| (x.clamp(0.0, 1.0), self.c1 + 2.0 * self.c2 * x))
    }
}

/// The table read at node position `x` in `[0, TABLE - 1]` by the parabola through the
/// nearest node and its two neighbours. Linear interpolation between nodes, which put the chord
/// of Hapke's ratio (convex in `w`) above it, left the tabulated pixels 1.6e-3 too bright on
/// the textured Moon at 71,000 km (`docs/performance.md`); the parabola's error is of the
/// third order in the spacing.
#[inline(always)]
fn quadratic(table: &[f64; TABLE], x: f64) -> f64 {
    let k = (x.round() as usize).clamp(1, TABLE - 2);
    let f = x - k as f64;
    let (a, b, c) = (table[k - 1], table[k], table[k + 1]);
    b + 0.5 * f * (c - a) + 0.5 * f * f * (c - 2.0 * b + a)
}

/// The reads' own estimate of a pixel's relative error under `MapFilter::Relief`, from its
/// factor over all its reads (`fine`) and over a quarter of them on a grid twice as coarse
/// (`coarse`), signed as the error of `fine`: by Richardson's extrapolation the limit is
/// about `fine + (fine - coarse) / 3`, so `fine` is off by `READ_ESTIMATE_SCALE (coarse -
/// fine) / fine` of itself. Its magnitude is the pixel's estimate (the refinement's test,
/// the frame's median and p99); its sign is kept for the frame's signed sum
/// ([`crate::render::FrameStats::relief_read_total`], which on the streams' frames did not
/// track the measured total). Where no read is lit but some of the
/// coarse grid's would be, -1 (all the light missed). It cannot see a pixel none of whose
/// reads is lit (a sliver of light between shadows): across NRHO row 493's terminator (2 x 2
/// reads a pixel) 414 of 10,085 lit pixels, each about 1 % of the median pixel's light, are
/// dark, and the estimated p99 is 0.38 where 1.0 is measured.
#[inline]
fn relief_estimate(fine: f64, coarse: f64) -> f64 {
    if fine > 0.0 {
        READ_ESTIMATE_SCALE * (coarse - fine) / fine
    } else if coarse > 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Bilinear interpolation of the corners' `q` (top-left, top-right, bottom-left,
/// bottom-right) at `(s, t)` in [0, 1]^2.
#[inline(always)]
fn lerp(q: [f64; 4], s: f64, t: f64) -> f64 {
    (1.0 - t) * ((1.0 - s) * q[0] + s * q[1]) + t * ((1.0 - s) * q[2] + s * q[3])
}

/// Scales each non-zero pixel of `image` (row-major, the camera's size) by the albedo over its
/// footprint relative to `brdf_ref`'s scale (see the module's doc).
#[allow(clippy::too_many_arguments)]
pub fn apply(
    intrinsics: &Intrinsics,
    shape: &Shape,
    relief: Option<&Relief>,
    shading: Option<(&Relief, SelfShadowing)>,
    reads: Reads,
    brdf_ref: &Brdf,
    albedo: &AlbedoMap,
    pose: &Pose,
    a_sun_cam_m4: f64,
    image: &mut [f64],
) -> Option<Vec<f64>> {
    let mut layers = [(albedo, image)];
    apply_maps(
        intrinsics,
        shape,
        relief,
        shading,
        reads,
        brdf_ref,
        pose,
        a_sun_cam_m4,
        &mut layers,
    )
}

/// [`apply`] with several maps, each scaling its own image of the same geometry (the
/// camera's map and bands' own maps): one set of lines of sight and reads for all.
///
/// `relief`: the relief the lines of sight meet and whose normals Hapke's ratio is taken
/// at; `shading` (`MapFilter::Relief`, with `relief` then `None`): the relief whose shading
/// and shadows the reads carry, the quadrangles having integrated the smooth shape. Under
/// `shading` it returns the reads' own relative error estimate per pixel of the first
/// layer, signed ([`relief_estimate`]; 0 where a pixel was not read on a grid); else
/// `None`.
/// `a_sun_cam_m4`: `A_sun A_cam` of Eq. 12 (the pixels near the smooth terminator are then
/// taken from their reads alone).
#[allow(clippy::too_many_arguments)]
pub fn apply_maps(
    intrinsics: &Intrinsics,
    shape: &Shape,
    relief: Option<&Relief>,
    shading: Option<(&Relief, SelfShadowing)>,
    reads: Reads,
    brdf_ref: &Brdf,
    pose: &Pose,
    a_sun_cam_m4: f64,
    layers: &mut [(&AlbedoMap, &mut [f64])],
) -> Option<Vec<f64>> {
    let (w, h) = (intrinsics.width_px as usize, intrinsics.height_px as usize);
    let s_ref = brdf_ref.scale();
    if w == 0 || h == 0 || s_ref <= 0.0 || layers.is_empty() {
        return None;
    }
    let (fx, fy) = intrinsics.focal_px();
    let maps: Vec<&AlbedoMap> = layers.iter().map(|(m, _)| *m).collect();
    // The finest map's texels decide the blocks and the reads (the DEM's too, when the
    // reads carry the relief).
    let (dlon, dlat) = maps
        .iter()
        .map(|m| m.map.spacing_rad())
        .chain(shading.map(|(r, _)| r.heights_m.spacing_rad()))
        .fold((f64::INFINITY, f64::INFINITY), |(a, b), (c, d)| {
            (a.min(c), b.min(d))
        });
    let ranges: Vec<(f64, f64)> = maps.iter().map(|m| m.scale_range()).collect();
    // Marched shadows stop where the ground towards this frame's Sun can no longer reach
    // them (the same answers: `body::sun_envelope`); the reads march millions of them.
    let under_sun = shading
        .filter(|(_, s)| *s == SelfShadowing::RayMarching)
        .map(|(r, _)| r.under_sun_now(pose.sun_position_m));
    let shading = match (&under_sun, shading) {
        (Some(r), Some((_, s))) => Some((r, s)),
        (_, shading) => shading,
    };
    let step = Step {
        intrinsics,
        shape,
        relief,
        brdf_ref,
        maps,
        pose,
        s_ref,
        linear: !matches!(brdf_ref, Brdf::Hapke(_)),
        // The pixel's side as an angle [rad] (at the optical axis: distortion changes the
        // footprint by a few percent at most, which only picks the map level).
        ifov: (1.0 / (fx * fy)).sqrt(),
        shading,
        refine: reads.relief_refine.max(1) as usize,
        spacing_texels: reads.spacing_texels,
        // Without `relief_refine` the blocks' lattices have no ring, and no two blocks read
        // at one place.
        share_reads: reads.share_reads && reads.relief_refine > 1,
        a_sun_cam_m4,
    };
    let bw = w.div_ceil(BLOCK);
    // Each image cut in bands of BLOCK rows; band `k` of every image goes to one task.
    let mut bands: Vec<Vec<&mut [f64]>> = Vec::new();
    for (_, image) in layers.iter_mut() {
        for (k, rows) in image.chunks_mut(w * BLOCK).enumerate() {
            if bands.len() <= k {
                bands.push(Vec::with_capacity(step.maps.len()));
            }
            bands[k].push(rows);
        }
    }
    let mut estimate = vec![0.0; if shading.is_some() { w * h } else { 0 }];
    let mut estimate_bands: Vec<&mut [f64]> = estimate.chunks_mut(w * BLOCK).collect();
    estimate_bands.resize_with(bands.len(), Default::default);
    bands
        .into_par_iter()
        .zip(estimate_bands)
        .enumerate()
        .for_each(|(by, (pixels, estimate))| {
            let y0 = by * BLOCK;
            let fy = y0 as f64 + 0.5;
            // The corners' lines of sight, above and below the band.
            let corners: Vec<[Probe; 2]> = (0..=bw)
                .map(|bx| {
                    let x = (bx * BLOCK) as f64 + 0.5;
                    [step.probe(x, fy), step.probe(x, fy + BLOCK as f64)]
                })
                .collect();
            let mut band = Band {
                rows: pixels[0].len() / w,
                tables: vec![[0.0; TABLE]; pixels.len()],
                sums: vec![0.0; pixels.len()],
                squares: vec![0.0; pixels.len()],
                pixels,
                width: w,
                y0,
                dlon,
                dlat,
                ranges: ranges.clone(),
                offsets: Vec::with_capacity(64),
                reads: Vec::with_capacity(CAST * CAST),
                relief: Vec::with_capacity(CAST * CAST),
                lit: Vec::with_capacity(CAST * CAST),
                crossings: Vec::new(),
                lattice: Vec::new(),
                lattice_at: Vec::new(),
                lattice_lit: Vec::new(),
                shared_reads: FxHashMap::default(),
                refine: Vec::new(),
                coarse: Vec::new(),
                estimate,
            };
            for bx in 0..bw {
                // The blocks of a band are read from left to right, each one's pixels before
                // the next's: the reads left of the pixels beside this block are no one's
                // ring now.
                if step.share_reads {
                    let first = (bx * BLOCK) as i64 - 1;
                    band.shared_reads
                        .retain(|&(column, _, ns, _), _| column.div_euclid(ns as i64) >= first);
                }
                let [c00, c01] = corners[bx];
                let [c10, c11] = corners[bx + 1];
                step.block(&mut band, bx * BLOCK, 0, BLOCK, [c00, c10, c01, c11]);
            }
        });
    shading.map(|_| estimate)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A finer read takes the shadows of the four coarser reads around it only where they
    /// agree: the Sun's, and the camera's where all four were asked it.
    #[test]
    fn a_finer_read_takes_the_shadows_its_coarser_neighbours_agree_on() {
        let lit = Some(Shadowed {
            sun: false,
            camera: Some(false),
        });
        let hidden_from_camera = Some(Shadowed {
            sun: false,
            camera: Some(true),
        });
        let in_shadow = Some(Shadowed {
            sun: true,
            camera: None,
        });
        // A 3 x 3 coarse lattice: lit on the left column, the Sun's shadow on the right,
        // the camera hidden at the bottom middle, and a facet turned away at the top right.
        let coarse = [
            lit,
            lit,
            None,
            lit,
            lit,
            in_shadow,
            lit,
            hidden_from_camera,
            in_shadow,
        ];
        // Fine read (1, 1) lies between coarse (0, 0) and (1, 1): all lit.
        assert!(inherited(&coarse, 3, (1, 1)) == lit);
        // Fine (3, 1) between coarse columns 1 and 2 of rows 0 and 1: one is not marched.
        assert!(inherited(&coarse, 3, (3, 1)).is_none());
        // Fine (3, 3) between coarse (1, 1) and (2, 2): the Sun's shadows disagree.
        assert!(inherited(&coarse, 3, (3, 3)).is_none());
        // Fine (1, 3) between coarse (0, 1) and (1, 2): lit by the Sun, the camera unsure.
        let sun_only = inherited(&coarse, 3, (1, 3)).unwrap();
        assert!(!sun_only.sun && sun_only.camera.is_none());
        // All four in the Sun's shadow: in it, the camera not asked.
        let dark = [in_shadow; 4];
        assert!(inherited(&dark, 2, (1, 1)) == in_shadow);
        // What a read passes on: nothing beside a shadow's edge or where it was not marched.
        let up = DVec3::Z;
        let read = |k: f64| ReliefRead {
            smooth: 1.0,
            local: Local::new(up, up, up),
            k,
            hidden: [false, true],
            camera_asked: true,
            mu0_shape: 1.0,
            seen: true,
        };
        let hidden_from_camera = Shadowed::of((&Some(read(1.0)), &0.0)).unwrap();
        assert!(!hidden_from_camera.sun && hidden_from_camera.camera == Some(true));
        assert!(Shadowed::of((&Some(read(1.0)), &0.4)).is_none());
        assert!(Shadowed::of((&Some(read(0.0)), &0.0)).is_none());
        assert!(Shadowed::of((&None, &0.0)).is_none());
    }

    /// The reads' weights along a side integrate cubics exactly, are positive, and keep a
    /// constant's mean; the midpoint rule alone misses `x^2` by `h^2 / 12`.
    #[test]
    fn the_reads_weights_integrate_a_cubic_over_a_pixel() {
        for n in 1..=9 {
            let h = 1.0 / n as f64;
            let rule = |f: &dyn Fn(f64) -> f64, weighted: bool| {
                (0..n)
                    .map(|k| {
                        let w = if weighted { end_weight(k, n) } else { 1.0 };
                        w * f((k as f64 + 0.5) * h) * h
                    })
                    .sum::<f64>()
            };
            assert!((0..n).all(|k| end_weight(k, n) > 0.0));
            assert!((rule(&|_| 1.0, true) - 1.0).abs() < 1e-14, "{n}");
            let cubic = |x: f64| 2.0 - x + 3.0 * x * x - 5.0 * x * x * x;
            // Its integral over [0, 1]: 2 - 1/2 + 1 - 5/4.
            let exact = 1.25;
            let midpoint = rule(&cubic, false) - exact;
            if n >= 3 {
                assert!((rule(&cubic, true) - exact).abs() < 1e-13, "{n}");
                assert!(midpoint.abs() > 1e-3 * h * h, "{n}: {midpoint}");
            }
        }
    }

    /// A limb pixel's strip: the parabola through three values of `q` finds where `q` is
    /// `mu^2` and its slope there, rising or falling, curved or straight, at the limb
    /// (`q` 0) and 1e-12 from it; and reads evenly in `mu` over a strip the limb crosses
    /// weigh up to the strip's length on the disk.
    #[test]
    fn a_strip_of_a_limb_pixel_is_read_evenly_in_mu() {
        for (c0, c1, c2) in [
            (-2e-4, 3e-3, -1e-6),
            (2.8e-3, -3e-3, -1e-6),
            (1e-3, 2e-3, 0.0),
            (0.5, 0.1, -0.01),
        ] {
            let p = Parabola { c0, c1, c2 };
            let through = Parabola::through(p.at(0.0), p.at(0.5), p.at(1.0));
            for x in [0.0, 1e-9, 0.3, 0.999] {
                let target = p.at(x);
                let (found, slope) = through.where_equal(target).unwrap();
                assert!((through.at(found) - target).abs() <= 1e-15 + 1e-12 * target.abs());
                assert!((slope - (c1 + 2.0 * c2 * found)).abs() < 1e-9 * c1.abs());
            }
            // Nothing outside the strip.
            assert!(
                through
                    .where_equal(p.at(0.0).min(p.at(1.0)) - 1e-3)
                    .is_none()
            );
            // The reads' weights add up to the strip's length where `q > 0`.
            let (m0, m1) = (p.at(0.0).max(0.0).sqrt(), p.at(1.0).max(0.0).sqrt());
            let (lo, hi) = (m0.min(m1), m0.max(m1));
            let n = 4096;
            let step = (hi - lo) / n as f64;
            let length: f64 = (0..n)
                .map(|j| {
                    let mu = lo + (j as f64 + 0.5) * step;
                    let (_, slope) = through.where_equal(mu * mu).unwrap();
                    2.0 * mu * step / slope.abs()
                })
                .sum();
            let on_disk = if p.at(0.0) < 0.0 || p.at(1.0) < 0.0 {
                let root = through.where_equal(0.0).unwrap().0;
                if p.at(0.0) < 0.0 { 1.0 - root } else { root }
            } else {
                1.0
            };
            assert!((length - on_disk).abs() < 1e-6, "{length} {on_disk}");
        }
    }

    /// The share of a cell on one side of a line, against the areas drawn by hand.
    #[test]
    fn a_cell_is_cut_by_a_line() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(cell_share(0.25, 1.0, 0.0), 0.75));
        assert!(close(cell_share(0.25, 0.0, -2.0), 0.625));
        assert!(close(cell_share(0.0, 1.0, 1.0), 0.5));
        assert!(close(cell_share(0.5, 1.0, -1.0), 0.875));
        assert!(close(cell_share(-0.5, 1.0, 1.0), 0.125));
        assert!(close(cell_share(0.1, 0.0, 0.0), 1.0));
        // The line through crossings 0.3 along x and 0.5 along y (`1 - x/0.3 - y/0.5`) cuts
        // off the triangle (0, 1/2), (1/2, 1/2), (1/2, -1/3): legs 1/2 and 5/6.
        let near = cell_share(1.0, 1.0 / 0.3, 1.0 / 0.5);
        assert!(close(near, 1.0 - 0.5 * 0.5 * 5.0 / 6.0), "{near}");
        assert!(close(near + cell_share(-1.0, 1.0 / 0.3, 1.0 / 0.5), 1.0));
    }

    /// Where the Sun's edge and the camera's both cross a read's cell, its lit share is the
    /// area between them, not the product of the two shares: a read lit by the Sun 0.41 of
    /// the spacing past the Sun's edge and hidden from the camera 0.33 past the camera's
    /// (Artemis I row 730's slivers) is lit on 0.08 of its cell, where the product said
    /// 0.91 x 0.17 = 0.155. A single line's clipped square is [`cell_share`].
    #[test]
    fn a_sliver_between_the_suns_edge_and_the_cameras_is_their_overlap() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        let nan = f64::NAN;
        let sun = CellSide::of([0.41, nan], [nan, nan]);
        let camera = CellSide::of([0.33, nan], [nan, nan]);
        assert!(close(sun.area, 0.91) && close(camera.area, 0.83));
        let got = lit_part(&[sun, camera], [false, true]);
        assert!(close(got, 0.08), "{got}");
        // Lit by both, and hidden from both: the intersection, and what neither side holds.
        assert!(close(lit_part(&[sun, camera], [false, false]), 0.83));
        assert!(close(lit_part(&[sun, camera], [true, true]), 0.09));
        // One ray's edge alone: its share, as before.
        let whole = CellSide::WHOLE;
        assert!(close(lit_part(&[sun, whole], [true, false]), 0.09));
        assert!(close(lit_part(&[whole, camera], [false, true]), 0.17));
        // A sliver (edges on both sides) crossed by a slanted edge: the rectangle's clipped
        // part, by a fine lattice.
        let band = CellSide::of([0.1, 0.2], [nan, nan]);
        let slant = CellSide::of([nan, 0.15], [0.4, nan]);
        let fine = 2000;
        let inside = (0..fine * fine)
            .filter(|k| {
                let x = ((k % fine) as f64 + 0.5) / fine as f64 - 0.5;
                let y = ((k / fine) as f64 + 0.5) / fine as f64 - 0.5;
                (-0.1 < x && x < 0.2) && (1.0 - x / 0.15 + y / 0.4 > 0.0)
            })
            .count() as f64
            / (fine * fine) as f64;
        let got = lit_part(&[band, slant], [false, false]);
        assert!((got - inside).abs() < 1e-5, "{got} {inside}");
        for (m, gx, gy) in [
            (1.0, 2.0, -3.0),
            (0.2, 0.5, 0.1),
            (-0.3, 1.0, 1.0),
            (1.0, 0.0, 0.0),
        ] {
            let a = clipped_area(&[(m, gx, gy)]);
            assert!((a - cell_share(m, gx, gy)).abs() < 1e-12, "{a}");
        }
    }

    /// Hills some 8 texels across at a Sun 4 deg up: over a lattice of reads 0.3 texels
    /// apart (turned against the map's axes), the lit share of each 4 x 4 block of them (a
    /// pixel) from [`lit_shares`] against the block's lit area sampled 6 x 6 times finer,
    /// and against the reads' own answers: summed over the 12 pixels an edge crosses,
    /// 0.077 against 0.314. (On hills a texel across, roughness the reads cannot resolve,
    /// 0.064 against 0.113.)
    #[test]
    fn a_block_takes_its_neighbours_reads_and_the_image_is_the_same() {
        // Hills and rims under a low Sun, seen whole from 12,000 km on 96 x 96 pixels (about
        // a texel a pixel), read under the relief at `relief_refine` 2, with and without the
        // sharing. (With the reads of neighbouring columns of a pixel confused in the
        // sharing's key, this fails.)
        let relief =
            crate::body::pyramid::test_relief(crate::body::pyramid::plains_rims_spikes, false);
        let radius_m = 1_737_400.0;
        let shape = Shape::Sphere(crate::body::sphere::Sphere { radius_m });
        let hash = crate::body::pyramid::unit_hash;
        let (w, h) = (180usize, 90usize);
        let albedo = crate::body::maps::Map::from_values(
            std::path::Path::new("albedo"),
            w,
            h,
            (0..w * h).map(|i| 0.1 + 0.05 * hash(i)).collect(),
            &crate::body::maps::Encoding::default(),
        )
        .unwrap();
        let albedo = AlbedoMap::new(albedo, 1.0);
        let camera_position_m = 1.2e7 * crate::geometry::unit_from_lon_lat(0.4, 0.3);
        let pose = Pose {
            frame_id: 0,
            camera_position_m,
            body_from_camera: crate::geometry::look_at(camera_position_m, DVec3::ZERO, DVec3::Z),
            sun_position_m: 1.5e11 * crate::geometry::unit_from_lon_lat(0.4 + 1.3, 0.1),
        };
        let intrinsics = Intrinsics {
            width_px: 96,
            height_px: 96,
            pixel_pitch_m: [5.5e-6, 5.5e-6],
            focal_length_m: 5.5e-6 * 1.2e7 / 12_000.0,
            f_number: 4.0,
            principal_point_px: [48.0, 48.0],
            skew_px: 0.0,
            distortion: Default::default(),
        };
        let brdf = Brdf::Lambert(crate::brdf::lambert::Lambert { rho: 0.12 });
        let render = |share_reads: bool| {
            // The quadrangles' light is not needed here: every pixel is scaled from 1.
            let mut image = vec![1.0; 96 * 96];
            let reads = Reads {
                spacing_texels: 0.5,
                relief_refine: 2,
                share_reads,
            };
            let shading = Some((&relief, SelfShadowing::RayMarching));
            let estimate = apply(
                &intrinsics,
                &shape,
                None,
                shading,
                reads,
                &brdf,
                &albedo,
                &pose,
                1.0,
                &mut image,
            );
            (image, estimate.unwrap())
        };
        let (shared, shared_estimate) = render(true);
        let (alone, alone_estimate) = render(false);
        let lit = shared.iter().filter(|&&v| v > 0.0).count();
        assert!(lit > 2000, "{lit} pixels lit");
        for (a, b) in shared
            .iter()
            .zip(&alone)
            .chain(shared_estimate.iter().zip(&alone_estimate))
        {
            assert!(
                (a - b).abs() <= 1e-12 * a.abs().max(b.abs()),
                "{a} against {b}"
            );
        }
    }

    #[test]
    fn a_shadows_edge_is_placed_between_the_reads() {
        let h = 360usize;
        let hash = crate::body::pyramid::unit_hash;
        let relief = crate::body::pyramid::test_relief(
            |c, r, i| 2000.0 * (c * 0.9).sin() * (r * 0.7).cos() + 300.0 * hash(i),
            false,
        );
        let (lon0, lat0) = (0.3, 0.2);
        let centre = crate::geometry::unit_from_lon_lat(lon0, lat0);
        let (east, north) = crate::geometry::east_north(centre);
        let (az, elev) = (0.4f64, 4f64.to_radians());
        let s =
            (elev.cos() * (az.cos() * east + az.sin() * north) + elev.sin() * centre).normalize();
        // Reads 0.3 texels apart, the lattice turned by 0.5 rad against the map's axes.
        let (n, step) = (24usize, 0.3 * std::f64::consts::PI / h as f64);
        let at = |x: f64, y: f64| {
            let (u, v) = (x - 0.5 * n as f64, y - 0.5 * n as f64);
            let (a, b) = (
                u * 0.5f64.cos() - v * 0.5f64.sin(),
                u * 0.5f64.sin() + v * 0.5f64.cos(),
            );
            (lon0 + a * step / lat0.cos(), lat0 + b * step)
        };
        let hidden = |(lon, lat): (f64, f64)| {
            relief.occluded(crate::geometry::unit_from_lon_lat(lon, lat), s)
        };
        let positions: Vec<(f64, f64)> = (0..n * n)
            .map(|j| at((j % n) as f64 + 0.5, (j / n) as f64 + 0.5))
            .collect();
        let mut reads: Vec<Option<ReliefRead>> = positions
            .iter()
            .map(|&p| {
                let up = crate::geometry::unit_from_lon_lat(p.0, p.1);
                Some(ReliefRead {
                    smooth: 1.0,
                    local: Local::new(up, s, up),
                    k: 1.0,
                    hidden: [hidden(p), false],
                    camera_asked: true,
                    mu0_shape: 1.0,
                    seen: true,
                })
            })
            .collect();
        let own: Vec<f64> = reads.iter().map(|r| r.as_ref().unwrap().lit()).collect();
        let mut lit = own.clone();
        lit_shares(
            &relief,
            &mut reads,
            &positions,
            (n, n),
            &mut lit,
            &mut Vec::new(),
        );
        assert!(lit.iter().all(|x| (0.0..=1.0).contains(x)));
        let fine = 6;
        let (mut err_own, mut err_shares, mut edges) = (0.0, 0.0, 0);
        for (bx, by) in (0..n / 4).flat_map(|b| (0..n / 4).map(move |a| (a, b))) {
            let (mut area, mut by_own, mut by_shares) = (0.0, 0.0, 0.0);
            for j in (0..16).map(|k| (4 * by + k / 4) * n + 4 * bx + k % 4) {
                by_own += own[j] / 16.0;
                by_shares += lit[j] / 16.0;
                for f in 0..fine * fine {
                    let x = (j % n) as f64 + ((f % fine) as f64 + 0.5) / fine as f64;
                    let y = (j / n) as f64 + ((f / fine) as f64 + 0.5) / fine as f64;
                    if !hidden(at(x, y)) {
                        area += 1.0 / (16 * fine * fine) as f64;
                    }
                }
            }
            if area > 0.0 && area < 1.0 {
                edges += 1;
            }
            err_own += (by_own - area).abs();
            err_shares += (by_shares - area).abs();
        }
        eprintln!("edges {edges} own {err_own:.4} shares {err_shares:.4}");
        assert!(edges >= 10, "{edges} pixels across an edge");
        assert!(
            err_shares < 0.4 * err_own,
            "lit area off by {err_shares:.3} with the shares, {err_own:.3} by the reads' own answers"
        );
    }
}
