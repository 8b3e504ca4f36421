//! The ray caster's frame, what mesh bodies render with (SLIM Sec. 6.1: rays from the camera,
//! facet by facet, shadow rays to the Sun): each pixel's `(P/L)` is the mean of a regular
//! `n x n` grid of ray casts over its footprint ([`super::Tracer::cast`], per px^2, so the
//! mean is the footprint's integral: energy-conserving at any `n`), with
//! `n = render.raycast_samples`; pixels where the light changes, the limb or the edge of the
//! light and of shadows, are cast again with `render.raycast_edge_samples` per side.
//!
//! Which pixels are edges: a pixel whose own rays, or its eight neighbours' rays, fall in more
//! than one class (missing the body, meeting it unlit or shadowed, meeting it lit). An edge
//! that passes between the rays of neighbouring pixels is found this way; one that enters and
//! leaves a pixel interior to a region of one class between its rays is not (a shadow
//! narrower than `1/n` px), which `raycast_samples` bounds.
//!
//! A mesh body alone seen through a pinhole casts the same lines of sight without searching
//! for their first facets: those come from rasterisation at the same sample positions
//! ([`super::raster`], per tile, and per pixel at the edges), and a closed mesh's shadow rays
//! go through a grid seen from the Sun ([`super::sun_grid`]).
//!
//! There, a pixel that one facet covers at every point (the projected fronts' exact shares of
//! it add up to its area: [`super::raster::Rasteriser::fragments`]) is not sampled but tiled:
//! each facet's fragment is cast once at its centroid and weighted by its area. A flat-faceted
//! body's light steps from facet to facet, and a pixel across such a step took the light of
//! whichever facet its ray met (on Bennu at 1 km, facets about 12 px across, 40 % of the lit
//! pixels). Where every fragment's facet is lit all over ([`super::sun_grid`]) or faces away
//! from the Sun, no edge of the light crosses the pixel: it is exact (to the second order of the
//! light's variation within a facet) and is not cast again as an edge. At the limb a pixel
//! partly covered is tiled the same way when no two of its fragments overlap (what they
//! leave uncovered is then where lines of sight miss the body); folds (two fronts over one
//! point) are cast at once with the edges' rays, their samples' facets rasterised from the
//! pixel's own fragments ([`raster::Rasteriser::fill_pixel`]): the light steps from facet to
//! facet inside a fold, and one ray read one facet's light for all of it (on Bennu 42 px
//! across, facets 2 px, such pixels were 5-18 % off and held the 99th percentile at 5.5e-2
//! whatever the edges' rays: now 1.7e-2 at 16 per side, 2.1e-3 at 64). A tiled pixel's
//! coverage is exact, so it is cast again only where lit and dark meet in its neighbourhood
//! (a shadow's edge, the terminator), not for the limb beside it; a pixel that no front
//! covers at all is exact and casts nothing.
//!
//! Each pixel is cast by one thread in a fixed order: the same scene, pose and settings give
//! the same image, bit for bit, whatever the thread count.

use super::facet_light::FacetLights;
use super::raster::{self, COVERED};
use super::{Coverage, Hit, Tracer};
use crate::render::{Frame, FrameStats, RenderError, Settings, StageTimings};
use crate::scene::{Pose, Scene};
use rayon::prelude::*;
use std::time::Instant;

/// Side of the square tiles [px] whose coverage of the body is tested before any ray.
const TILE: usize = 8;

/// Classes of rays, as bits of a pixel's mask.
const MISS: u8 = 1;
const DARK: u8 = 2;
const LIT: u8 = 4;

/// How a pixel was cast in the first pass: sampled (`n x n` rays), tiled by its fragments
/// (its coverage exact, its shadows sampled at their centroids), or exact (tiled with no edge
/// of the light crossing it, or not covered at all): never cast again.
const SAMPLED: u8 = 0;
const TILED: u8 = 1;
const EXACT: u8 = 2;
/// A fold (two fronts over one point), cast in the first pass with the edges' rays: never
/// cast again.
const FOLD: u8 = 3;

/// With `render.raycast_budget`: the most rays per pixel side, and rounds of refinement.
const MAX_SAMPLES: u32 = 64;
const MAX_REFINEMENTS: usize = 6;

/// The first facet at each sample of a region of pixels ([`super::raster`]): the region's
/// buffer, the index in it of a pixel's sample `(0, 0)`, and its row stride.
type Seen<'a> = (&'a [u32], usize, usize);

/// A pixel tiled by `fragments` ([`raster::Rasteriser::fragments`]): each cast once at its
/// centroid and weighted by its area (a facet's light varies smoothly across it, so the
/// centroid gives the mean over the fragment to second order, while the steps between
/// facets, and the limb, are where they are). Returns what [`cast_pixel`] does but the rays
/// (the depth: the mean range over the covered part), and whether
/// the pixel is exact: every fragment on a facet lit all over or facing away from the Sun,
/// so that no edge of the light crosses it.
fn shade_fragments(
    tracer: &Tracer,
    lights: Lights,
    fragments: &[raster::Fragment],
) -> (f64, f64, u8, bool) {
    let (mut sum, mut range, mut met, mut mask, mut exact) = (0.0, 0.0, 0.0, 0u8, true);
    for f in fragments {
        let h = cast_onto(tracer, lights, f.centroid.x, f.centroid.y, f.facet);
        if h.range_m.is_nan() {
            // The plane met behind the camera: not a tiling after all.
            mask |= MISS;
            exact = false;
            continue;
        }
        range += f.area_px2 * h.range_m;
        met += f.area_px2;
        if h.pl_per_px2 > 0.0 {
            mask |= LIT;
            sum += f.area_px2 * h.pl_per_px2;
        } else {
            mask |= DARK;
        }
        exact &= tracer.lit_all_over_or_unlit(f.facet);
    }
    let depth = if met > 0.0 { range / met } else { f64::NAN };
    (sum, depth, mask, exact)
}

/// The large facets' interpolated light ([`FacetLights`]) and whether the frame keeps its
/// depth (else a lit-all-over facet's sample casts nothing).
#[derive(Clone, Copy)]
struct Lights<'a> {
    lights: Option<&'a FacetLights>,
    depth: bool,
}

/// [`Tracer::cast_onto`], with the facet's light read from `lights` where it is interpolated.
#[inline]
fn cast_onto(tracer: &Tracer, lights: Lights, u: f64, v: f64, facet: u32) -> Hit {
    match lights.lights.and_then(|l| l.at(facet, u, v)) {
        Some(light) => tracer.cast_onto_with(u, v, facet, light, lights.depth),
        None => tracer.cast_onto(u, v, facet),
    }
}

/// Pixel `p`'s mean range `d` [m] into `depth`, where the frame keeps its depth (else
/// `depth` is empty).
#[inline]
fn keep_depth(depth: &mut [f64], p: usize, d: f64) {
    if let Some(x) = depth.get_mut(p) {
        *x = d;
    }
}

/// `len` copies of `value`, written by the pool's threads.
fn filled<T: Copy + Send + Sync>(value: T, len: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(len);
    v.par_extend(rayon::iter::repeat_n(value, len));
    v
}

/// What one pixel's rays gave ([`cast_pixel`]).
#[derive(Clone, Copy, Debug)]
struct Cast {
    /// The mean `(P/L)` per px^2 (the pixel's `(P/L)`).
    pl: f64,
    /// The mean range of the rays that met the body [m] (NaN for none).
    depth: f64,
    /// The classes met.
    mask: u8,
    rays: u64,
    /// The estimated error of `pl` (same unit; NaN under 2 rays per side): the standard
    /// error of the means of the four interleaved half-resolution grids the `n x n` grid
    /// holds (rays of even or odd column and row), whose mean `pl` is ([`super::estimate`]).
    err: f64,
}

/// One pixel cast `n x n` times ([`Cast`]). With `seen`, the first facet at each of its
/// samples.
fn cast_pixel(
    tracer: &Tracer,
    lights: Lights,
    u0: f64,
    v0: f64,
    n: u32,
    seen: Option<Seen>,
) -> Cast {
    let step = 1.0 / n as f64;
    let (mut range, mut hits, mut mask) = (0.0, 0u32, 0u8);
    // Sums of the four interleaved grids, by (row parity, column parity).
    let mut sub = [0.0f64; 4];
    for j in 0..n {
        let v = v0 + (j as f64 + 0.5) * step;
        for i in 0..n {
            let u = u0 + (i as f64 + 0.5) * step;
            let h = match seen.map(|(buf, at, stride)| buf[at + j as usize * stride + i as usize]) {
                Some(raster::NONE) => Hit {
                    pl_per_px2: 0.0,
                    range_m: f64::NAN,
                },
                Some(raster::UNDECIDED) | None => tracer.cast(u, v),
                Some(facet) => cast_onto(tracer, lights, u, v, facet),
            };
            if h.range_m.is_nan() {
                mask |= MISS;
                continue;
            }
            hits += 1;
            range += h.range_m;
            if h.pl_per_px2 > 0.0 {
                mask |= LIT;
                sub[((j & 1) * 2 + (i & 1)) as usize] += h.pl_per_px2;
            } else {
                mask |= DARK;
            }
        }
    }
    let rays = (n * n) as u64;
    let depth = if hits > 0 {
        range / hits as f64
    } else {
        f64::NAN
    };
    let pl = sub.iter().sum::<f64>() / rays as f64;
    Cast {
        pl,
        depth,
        mask,
        rays,
        err: super::estimate::pixel_error(&sub, n),
    }
}

/// Renders the `(P/L)` image of `scene` from `pose` by sampled ray casting, in the calling
/// thread pool.
///
/// `scattered`: a mesh's scattered irradiance per facet (fractions of the solar irradiance at
/// the body's centre) and the Bond albedo reflecting it ([`crate::irradiance`]).
pub fn render(
    scene: &Scene,
    pose: &Pose,
    settings: &Settings,
    scattered: Option<(&[f64], f64)>,
) -> Result<Frame, RenderError> {
    let t0 = Instant::now();
    let intr = &scene.camera.intrinsics;
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let tracer = match scattered {
        Some((r, rho)) => Tracer::new(scene, pose).with_scattered(r, rho),
        None => Tracer::new(scene, pose),
    };
    // A mesh body alone through a pinhole: the first facet of every line of sight by
    // rasterisation, so that only shadow rays (and undecided samples) go through the BVH.
    let rasteriser = tracer.rasteriser(TILE);
    // With a budget, every pixel cast by samples has its error estimated: 2 rays per side
    // at least.
    let n = match (&settings.raycast_budget, &rasteriser) {
        (Some(_), None) => settings.raycast_samples.max(2),
        _ => settings.raycast_samples,
    };
    let edge_n = settings.raycast_edge_samples.max(n);
    // Large facets' light from a quadratic over their image.
    let lights = match (&rasteriser, &scene.body.shape) {
        (Some(r), crate::body::Shape::Mesh(m)) if settings.raycast_quadratic_light => {
            FacetLights::new(&tracer, r, m.facets().len())
        }
        _ => None,
    };
    let lights = Lights {
        lights: lights.as_ref(),
        depth: settings.depth,
    };
    let t_raster = t0.elapsed();
    // Tiles of TILE x TILE pixels some line of sight of which may meet a body's bounding
    // sphere, or, rasterised, a facet's box: the others cast nothing.
    let (tiles_w, tiles_h) = (w.div_ceil(TILE), h.div_ceil(TILE));
    let covered: Vec<bool> = (0..tiles_w * tiles_h)
        .into_par_iter()
        .map(|t| match &rasteriser {
            Some(r) => !r.tile_is_empty(t % tiles_w, t / tiles_w),
            None => {
                let (u0, v0) = ((t % tiles_w) * TILE, (t / tiles_w) * TILE);
                tracer.coverage(u0 as f64, v0 as f64, TILE as f64) != Coverage::Empty
            }
        })
        .collect();
    // Flat per-pixel buffers, filled in bands of TILE rows, tile by tile.
    // (Filled by the pool's threads: 10 MB at 1024 x 1024, which the allocator hands back as
    // they were freed. The depth, 8 MB more, only where the frame keeps it.)
    let mut pl = filled(0.0, w * h);
    let mut depth = filled(f64::NAN, if settings.depth { w * h } else { 0 });
    let mut class = filled(MISS, w * h);
    let mut state = filled(EXACT, w * h);
    let depth_bands: Vec<&mut [f64]> = if settings.depth {
        depth.chunks_mut(TILE * w).collect()
    } else {
        (0..h.div_ceil(TILE)).map(|_| &mut [][..]).collect()
    };
    let first: Vec<(u64, Vec<(usize, f64)>)> = pl
        .par_chunks_mut(TILE * w)
        .zip(depth_bands)
        .zip(class.par_chunks_mut(TILE * w))
        .zip(state.par_chunks_mut(TILE * w))
        .enumerate()
        .map_init(
            || (Vec::new(), Vec::new(), raster::TileFragments::default()),
            |(facets, scratch, tile_fragments), (band, (((pl, depth), class), state))| {
                let rows = pl.len() / w;
                let mut rays = 0;
                // The pixels cast with two rays or more per side, and their estimated errors.
                let mut sampled = Vec::new();
                for tile in 0..w.div_ceil(TILE) {
                    let (u0, v0) = (tile * TILE, band * TILE);
                    if !covered[band * tiles_w + tile] {
                        continue;
                    }
                    let cols = TILE.min(w - u0);
                    if let Some(r) = &rasteriser {
                        r.tile_fragments((u0, v0), (cols, rows), tile_fragments);
                    }
                    for j in 0..rows {
                        for i in u0..u0 + cols {
                            let p = j * w + i;
                            if let Some(r) = &rasteriser {
                                // One facet over every point of the pixel, or over every
                                // point of the part the body covers (the limb): its
                                // fragments.
                                let local = j * cols + (i - u0);
                                let (fragments, area) =
                                    (tile_fragments.of(local), tile_fragments.area(local));
                                if fragments.is_empty() {
                                    // No front covers any of it: every line of sight misses
                                    // (exact, as the pixels of tiles that cast nothing).
                                    continue;
                                }
                                let tiled = (area - 1.0).abs() <= COVERED
                                    || (area < 1.0 && r.single_layer((i, v0 + j), fragments));
                                if tiled {
                                    let (v, d, mut c, e) =
                                        shade_fragments(&tracer, lights, fragments);
                                    if area < 1.0 - COVERED {
                                        c |= MISS;
                                    }
                                    (pl[p], class[p]) = (v, c);
                                    keep_depth(depth, p, d);
                                    state[p] = if e { EXACT } else { TILED };
                                    rays += fragments.len() as u64;
                                    continue;
                                }
                                // A fold: cast at once with the edges' rays, its samples'
                                // facets from its own fragments.
                                let ne = edge_n as usize;
                                r.fill_pixel((i, v0 + j), ne, fragments, facets, scratch);
                                let seen = Some((&facets[..], 0, ne));
                                let c = cast_pixel(
                                    &tracer,
                                    lights,
                                    i as f64,
                                    (v0 + j) as f64,
                                    edge_n,
                                    seen,
                                );
                                (pl[p], class[p], state[p]) = (c.pl, c.mask, FOLD);
                                keep_depth(depth, p, c.depth);
                                rays += c.rays;
                                sampled.push((band * TILE * w + p, c.err));
                                continue;
                            }
                            let c = cast_pixel(&tracer, lights, i as f64, (v0 + j) as f64, n, None);
                            (pl[p], class[p], state[p]) = (c.pl, c.mask, SAMPLED);
                            keep_depth(depth, p, c.depth);
                            rays += c.rays;
                            if c.mask != MISS {
                                sampled.push((band * TILE * w + p, c.err));
                            }
                        }
                    }
                }
                (rays, sampled)
            },
        )
        .collect();
    let first_rays: u64 = first.iter().map(|(r, _)| r).sum();
    let t_first = t0.elapsed();
    // Pixels where the light changes: their own class or a neighbour's differs. A tiled
    // pixel's coverage is exact: there only a change between lit and dark counts (a shadow's
    // or the terminator's edge), not the limb beside it. A fold was cast with the edges'
    // rays already.
    let mixed = |p: usize| {
        let (i, j) = (p % w, p / w);
        let (x0, x1) = (i.saturating_sub(1), (i + 1).min(w - 1));
        let mut mask = 0u8;
        for y in j.saturating_sub(1)..=(j + 1).min(h - 1) {
            mask = class[y * w + x0..=y * w + x1]
                .iter()
                .fold(mask, |m, &c| m | c);
        }
        if state[p] == TILED {
            mask & (LIT | DARK) == LIT | DARK
        } else {
            mask.count_ones() > 1
        }
    };
    let edges: Vec<usize> = if edge_n > n {
        // Only pixels cast by samples or tiled with shadows may be cast again (every other
        // pixel is exact, those of tiles that cast nothing included): a scan of their states.
        state
            .par_chunks(TILE * w)
            .enumerate()
            .flat_map_iter(|(band, states)| {
                let first = band * TILE * w;
                states
                    .iter()
                    .enumerate()
                    .filter(|&(_, &s)| s == SAMPLED || s == TILED)
                    .map(move |(k, _)| first + k)
                    .filter(|&p| mixed(p))
            })
            .collect()
    } else {
        Vec::new()
    };
    // Pixel `p` cast again with `n x n` rays.
    let recast = |(facets, scratch): &mut (Vec<u32>, Vec<f64>), p: usize, n: u32| {
        let (i, j) = (p % w, p / w);
        if let Some(r) = &rasteriser {
            r.fill((i, j), (1, 1), n as usize, facets, scratch);
        }
        let seen = rasteriser.as_ref().map(|_| (&facets[..], 0, n as usize));
        cast_pixel(&tracer, lights, i as f64, j as f64, n, seen)
    };
    let refined: Vec<Cast> = edges
        .par_iter()
        .map_init(|| (Vec::new(), Vec::new()), |s, &p| recast(s, p, edge_n))
        .collect();
    let mut rays = first_rays;
    for (&p, c) in edges.iter().zip(&refined) {
        pl[p] = c.pl;
        keep_depth(&mut depth, p, c.depth);
        rays += c.rays;
    }
    // Every pixel cast with rays, with its estimated error and rays per side: the first
    // pass's (the folds; every covered pixel without the rasteriser), the edges' casts
    // replacing theirs.
    let mut sampled: Vec<(usize, f64, u32)> = first
        .into_iter()
        .flat_map(|(_, s)| s)
        .map(|(p, e)| (p, e, if state[p] == FOLD { edge_n } else { n }))
        .collect();
    sampled.extend(edges.iter().zip(&refined).map(|(&p, c)| (p, c.err, edge_n)));
    sampled.sort_by_key(|&(p, _, _)| p); // stable: an edge's entry after its first pass's
    let mut merged: Vec<(usize, f64, u32)> = Vec::with_capacity(sampled.len());
    for x in sampled {
        match merged.last_mut() {
            Some(last) if last.0 == x.0 => *last = x,
            _ => merged.push(x),
        }
    }
    let has_estimate = !merged.iter().any(|(_, e, _)| e.is_nan());
    // The frame's estimate ([`super::estimate::frame_estimate`]) over the lit pixels and the
    // total of its image as first cast: the refinement below moves only edge pixels, by far
    // less than the estimate's own uncertainty, so they are read once.
    let light = has_estimate.then(|| super::estimate::Light::of(&pl));
    let mut estimated_error = light
        .as_ref()
        .map(|light| super::estimate::frame_estimate(&pl, light, &merged));
    // With a budget, the pixels whose estimated error keeps the frame from it are cast again
    // with the rays their estimate says they need ([`super::estimate::to_refine`]), until
    // the frame's estimate meets it or they reach MAX_SAMPLES.
    if let (Some(b), Some(light), Some(estimate)) =
        (settings.raycast_budget, &light, &mut estimated_error)
    {
        for _ in 0..MAX_REFINEMENTS {
            if estimate.p99 <= b.p99 && estimate.total <= b.total {
                break;
            }
            let chosen = super::estimate::to_refine(&pl, light, &merged, b, MAX_SAMPLES);
            if chosen.is_empty() {
                break;
            }
            let again: Vec<Cast> = chosen
                .par_iter()
                .map_init(
                    || (Vec::new(), Vec::new()),
                    |s, &(k, n)| recast(s, merged[k].0, n),
                )
                .collect();
            for (&(k, n), c) in chosen.iter().zip(&again) {
                let p = merged[k].0;
                pl[p] = c.pl;
                keep_depth(&mut depth, p, c.depth);
                rays += c.rays;
                (merged[k].1, merged[k].2) = (c.err, n);
            }
            *estimate = super::estimate::frame_estimate(&pl, light, &merged);
        }
    }
    // The total and the lit pixels, by fixed runs of pixels summed in order: the same bits
    // whatever the thread count.
    let (total, covered_px) = pl
        .par_chunks(1 << 16)
        .map(|run| (run.iter().sum(), run.iter().filter(|&&x| x > 0.0).count()))
        .collect::<Vec<(f64, usize)>>()
        .into_iter()
        .fold((0.0, 0), |(t, c), (rt, rc)| (t + rt, c + rc));
    if !total.is_finite() {
        return Err(RenderError::NonFinite {
            stage: "ray casting",
            value: total,
        });
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let stats = FrameStats {
        phase_deg: pose
            .sun_position_m
            .normalize()
            .dot(pose.camera_position_m.normalize())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees(),
        points_sampled: w * h,
        // The pixels cast with the edges' rays: the edges and the folds.
        points_kept: edges.len() + state.par_iter().filter(|&&s| s == FOLD).count(),
        surface_samples: rays as usize,
        covered_px: covered_px as f64,
        total_pl_points: total,
        total_pl_image: total,
        total_pl_gridded: total,
        timings_ms: StageTimings {
            // The tracer's set-up with the facets' projections (sun grid, raster bins) is the
            // projection stage; the casts are the integration.
            projection: t_raster.as_secs_f64() * 1e3,
            integration: (t_first - t_raster).as_secs_f64() * 1e3,
            total: ms,
            ..Default::default()
        },
        estimated_error,
        ..Default::default()
    };
    Ok(Frame {
        width: w,
        height: h,
        depth_m: settings.depth.then_some(depth),
        pl,
        band_pl: Vec::new(),
        stats,
    })
}
