//! A ray-cast frame's own error estimate: what it expects its error against the converged
//! reference ([`crate::fidelity::metrics`]) to be, from its own rays, with no reference.
//!
//! Where a pixel is sampled by an `n x n` grid of rays (the edges of the light, the limb, the
//! folds: [`super::sampled`]), the grid holds four interleaved grids of `n/2 x n/2` (rays of
//! even or odd column and row), each a coarser estimate of the same integral, shifted by half
//! a step. Their spread says how far the edge's position between rays leaves the mean:
//! [`pixel_error`], the standard error of their mean times `2 / sqrt(n)` (the regular grid's
//! mean converges faster than its sub-grids' spread says; calibrated on Bennu in
//! `tests/mesh.rs`), is the pixel's error `e`. Where no edge crosses a pixel (tiled by its
//! facets' exact shares, [`super::raster`]), its error is the second-order error of a facet's
//! light read at its fragment's centroid, far below an edge pixel's: [`TILED_FLOOR`].
//!
//! The frame's figures ([`FrameEstimate`]) follow the metric's definitions: quantiles of
//! `MARGIN e / I` over the lit pixels (those at 1 % of the 99th percentile or more, from the
//! frame's own image), and the total as `MARGIN_TOTAL sqrt(sum e^2)` (the edge pixels' errors
//! are of either sign) plus [`TILED_FLOOR_TOTAL`] of the tiled light. At fixed rays per side
//! the margins make the estimate an upper bound of the measured error on the frames it was
//! checked on (`tests/mesh.rs`); a frame refined to its own estimate ([`to_refine`]) leaves
//! the pixels whose estimate happened to be low, and there it is a report, not a bound
//! (docs/performance.md: 0.49 to 3.8 times the measured p99 over 24 frames).

use serde::Serialize;

/// The estimate's factors over the pixels' estimated errors, per pixel and in total (see the
/// module's doc).
pub const MARGIN: f64 = 1.25;
pub const MARGIN_TOTAL: f64 = 3.0;

/// The share of the lit pixels [`to_refine`] leaves above the budget's 99th percentile (half
/// of the 1 % it allows).
pub const P99_ALLOWANCE: f64 = 0.005;

/// The relative error assumed of a pixel tiled by its fragments (no edge crossing it), and of
/// their light in total.
pub const TILED_FLOOR: f64 = 3e-4;
pub const TILED_FLOOR_TOTAL: f64 = 1e-5;

/// The error a ray-cast frame refines its edges to meet (`render.raycast_budget`, which
/// `fidelity = "budget"` sets from `[render.budget]`): relative, at the 99th percentile of
/// the lit pixels and in total.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RaycastBudget {
    pub p99: f64,
    pub total: f64,
}

/// A frame's estimated error against the converged reference: relative, per lit pixel and in
/// total, as [`crate::fidelity::metrics::FrameError`] measures it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrameEstimate {
    pub median: f64,
    pub p99: f64,
    pub total: f64,
}

/// A pixel's estimated error from the sums `sub` of the four interleaved grids of its `n x n`
/// grid of rays (indexed by row parity * 2 + column parity): the standard error of their mean
/// times `2 / sqrt(n)`; NaN under `n = 2`.
pub fn pixel_error(sub: &[f64; 4], n: u32) -> f64 {
    if n < 2 {
        return f64::NAN;
    }
    let (even, odd) = (n.div_ceil(2) as f64, (n / 2) as f64);
    let counts = [even * even, even * odd, odd * even, odd * odd];
    let means: [f64; 4] = std::array::from_fn(|k| sub[k] / counts[k]);
    let mean = means.iter().sum::<f64>() / 4.0;
    let var = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / 3.0;
    (var / 4.0).sqrt() * 2.0 / (n as f64).sqrt()
}

/// What the estimate reads of the whole image: its total, the lit pixels' floor (1 % of the
/// 99th percentile of the non-zero pixels, as the metric's) and their count.
#[derive(Clone, Copy, Debug)]
pub struct Light {
    pub total: f64,
    pub lit_floor: f64,
    pub lit_px: usize,
}

impl Light {
    /// From the image `pl`, in the calling thread pool; the same bits whatever its size.
    pub fn of(pl: &[f64]) -> Light {
        use rayon::prelude::*;
        const RUN: usize = 1 << 16;
        let total = pl
            .par_chunks(RUN)
            .map(|r| r.iter().sum::<f64>())
            .collect::<Vec<f64>>()
            .iter()
            .sum();
        let mut positive: Vec<f64> = pl.par_iter().copied().filter(|&x| x > 0.0).collect();
        if positive.is_empty() {
            return Light {
                total,
                lit_floor: f64::INFINITY,
                lit_px: 0,
            };
        }
        // The nearest rank of `stats::quantiles`, by selection rather than a sort.
        let k = ((positive.len() - 1) as f64 * 0.99).round() as usize;
        let (_, p99, _) = positive.select_nth_unstable_by(k, f64::total_cmp);
        let lit_floor = crate::fidelity::metrics::LIT_FRACTION * *p99;
        let lit_px = positive.par_iter().filter(|&&x| x >= lit_floor).count();
        Light {
            total,
            lit_floor,
            lit_px,
        }
    }
}

/// The frame's figures from its image `pl` (whose [`Light`] is `light`) and the sampled
/// pixels' `(index, e, rays per side)`; every other pixel is taken as tiled.
pub fn frame_estimate(pl: &[f64], light: &Light, sampled: &[(usize, f64, u32)]) -> FrameEstimate {
    let (total, lit, lit_px) = (light.total, light.lit_floor, light.lit_px);
    if total <= 0.0 {
        return FrameEstimate::default();
    }
    // The sampled lit pixels' relative errors, largest first; every other lit pixel is at
    // the tiled floor.
    let mut rel: Vec<f64> = sampled
        .iter()
        .filter(|(p, _, _)| pl[*p] >= lit)
        .map(|&(p, e, _)| (MARGIN * e / pl[p]).max(TILED_FLOOR))
        .collect();
    rel.sort_unstable_by(|a, b| b.total_cmp(a));
    // The value at quantile q of all lit pixels: the k-th largest, k = (1 - q) lit_px.
    let quantile = |q: f64| {
        let k = ((1.0 - q) * lit_px as f64).floor() as usize;
        rel.get(k).copied().unwrap_or(TILED_FLOOR)
    };
    let edge_sq: f64 = sampled.iter().map(|(_, e, _)| e * e).sum();
    let sampled_light: f64 = sampled.iter().map(|&(p, _, _)| pl[p]).sum();
    FrameEstimate {
        median: quantile(0.5),
        p99: quantile(0.99),
        total: (MARGIN_TOTAL * edge_sq.sqrt()
            + TILED_FLOOR_TOTAL * (total - sampled_light).max(0.0))
            / total,
    }
}

/// The rays per side a pixel cast with `n` is cast again with at least: `sqrt 2` times as
/// many (twice the rays: 8, 11, 16, 23, 33, 47, 64), at most `max_n`.
pub fn next_n(n: u32, max_n: u32) -> u32 {
    ((n as f64 * std::f64::consts::SQRT_2).round() as u32).clamp(n + 1, max_n.max(n + 1))
}

/// A pixel's estimated error falls as `n^-1.5` (`standard_error` as `1/n`, times
/// `2/sqrt(n)`): one at `rel` of its light with `n` rays per side reaches `target` with
/// `n (rel / target)^(2/3)`. The jump aims at this share of the budget, the estimate being
/// noisy.
pub const JUMP_TARGET: f64 = 0.8;

/// Which of the sampled pixels `(pixel, e, rays per side)` to cast again, and with how many
/// rays per side, to bring the frame within `budget`, as `(index into sampled, n)`: the lit
/// pixels whose
/// relative error is estimated above the budget's 99th percentile but the largest
/// [`P99_ALLOWANCE`] of the lit pixels, and, while the total is
/// estimated above its budget, the largest errors until the others' add up to half of it.
/// The first are cast with the rays their estimate says they need ([`JUMP_TARGET`]), at
/// least [`next_n`]; the others with [`next_n`]. Pixels at `max_n` rays per side are not
/// chosen.
pub fn to_refine(
    pl: &[f64],
    light: &Light,
    sampled: &[(usize, f64, u32)],
    budget: RaycastBudget,
    max_n: u32,
) -> Vec<(usize, u32)> {
    let (total, lit, lit_px) = (light.total, light.lit_floor, light.lit_px);
    let rel = |k: usize| MARGIN * sampled[k].1 / pl[sampled[k].0];
    let mut above: Vec<usize> = (0..sampled.len())
        .filter(|&k| pl[sampled[k].0] >= lit && rel(k) > budget.p99)
        .collect();
    // The 99th percentile lets 1 % of the lit pixels above it: half of that share, the
    // largest errors, are left as they are, the others cast again (those nearest the
    // budget first fall within it).
    above.sort_unstable_by(|&a, &b| rel(a).total_cmp(&rel(b)).then(a.cmp(&b)));
    let keep = (P99_ALLOWANCE * lit_px as f64).floor() as usize;
    above.truncate(above.len().saturating_sub(keep));
    let mut chosen: Vec<(usize, u32)> = above
        .into_iter()
        .filter(|&k| sampled[k].2 < max_n)
        .map(|k| {
            let n = sampled[k].2;
            let need = n as f64 * (rel(k) / (JUMP_TARGET * budget.p99)).powf(2.0 / 3.0);
            (k, (need.ceil() as u32).clamp(next_n(n, max_n), max_n))
        })
        .collect();
    let sampled_light: f64 = sampled.iter().map(|&(p, _, _)| pl[p]).sum();
    let allowed = (budget.total * total - TILED_FLOOR_TOTAL * (total - sampled_light).max(0.0))
        / MARGIN_TOTAL;
    let sq: f64 = sampled.iter().map(|(_, e, _)| e * e).sum();
    if sq.sqrt() > allowed {
        let mut by_error: Vec<usize> = (0..sampled.len())
            .filter(|&k| sampled[k].2 < max_n)
            .collect();
        by_error.sort_unstable_by(|&a, &b| sampled[b].1.total_cmp(&sampled[a].1).then(a.cmp(&b)));
        let target = (0.5 * allowed.max(0.0)).powi(2);
        let mut rest = sq;
        for k in by_error {
            if rest <= target {
                break;
            }
            rest -= sampled[k].1.powi(2);
            chosen.push((k, next_n(sampled[k].2, max_n)));
        }
    }
    // A pixel chosen twice is cast with the more rays.
    chosen.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.cmp(&a.1)));
    chosen.dedup_by_key(|c| c.0);
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_equal_grids_have_no_spread_and_one_ray_has_no_estimate() {
        assert_eq!(pixel_error(&[2.0, 2.0, 2.0, 2.0], 4), 0.0);
        assert!(pixel_error(&[1.0, 0.0, 0.0, 0.0], 1).is_nan());
        // One grid of four fully lit, the others dark (a 4 x 4 pixel): means 1, 0, 0, 0.
        let e = pixel_error(&[4.0, 0.0, 0.0, 0.0], 4);
        assert!((e - (0.75f64 / 3.0 / 4.0).sqrt()).abs() < 1e-15, "{e}");
    }

    #[test]
    fn refined_pixels_jump_to_the_rays_their_estimate_asks_for() {
        assert_eq!(
            [8, 11, 16, 23, 33, 47, 60].map(|n| next_n(n, 64)),
            [11, 16, 23, 33, 47, 64, 64]
        );
        // 1000 lit pixels of 1.0. Pixels 0-9 at 8 rays per side are estimated at 4 times the
        // budget's p99 (1e-2): each asks for 8 (4 / 0.8)^(2/3) = 23.4 -> 24 per side, but
        // the 5 largest (half a percent of the lit pixels; equal here, the last by index)
        // are left. Pixel 10 is within the budget, pixel 11 at 64 already.
        let pl = vec![1.0; 1000];
        let b = RaycastBudget {
            p99: 1e-2,
            total: 1.0,
        };
        let e = 4.0 * b.p99 / MARGIN;
        let mut sampled: Vec<(usize, f64, u32)> = (0..10).map(|p| (p, e, 8)).collect();
        sampled.extend([(10, 0.5 * b.p99 / MARGIN, 8), (11, e, 64)]);
        let light = Light::of(&pl);
        let want: Vec<(usize, u32)> = (0..6).map(|k| (k, 24)).collect();
        assert_eq!(to_refine(&pl, &light, &sampled, b, 64), want);
        // A total budget the errors exceed: every pixel below 64 is cast again with sqrt 2
        // more rays per side.
        let tight = RaycastBudget {
            p99: 1.0,
            total: 1e-6,
        };
        let want: Vec<(usize, u32)> = (0..11).map(|k| (k, 11)).collect();
        assert_eq!(to_refine(&pl, &light, &sampled, tight, 64), want);
    }

    #[test]
    fn the_frame_quantiles_count_the_tiled_pixels_at_their_floor() {
        // 1000 lit pixels of 1.0; 20 sampled with e = 0.01 (relative 3e-2 with the margin).
        let pl = vec![1.0; 1000];
        let sampled: Vec<(usize, f64, u32)> = (0..20).map(|p| (p, 0.01, 8)).collect();
        let f = frame_estimate(&pl, &Light::of(&pl), &sampled);
        assert!((f.p99 - MARGIN * 0.01).abs() < 1e-15, "{f:?}");
        assert_eq!(f.median, TILED_FLOOR);
        let t = (MARGIN_TOTAL * (20.0f64 * 1e-4).sqrt() + TILED_FLOOR_TOTAL * 980.0) / 1000.0;
        assert!((f.total - t).abs() < 1e-15);
        // 5 sampled: under 1 %, the 99th percentile is a tiled pixel's.
        assert_eq!(
            frame_estimate(&pl, &Light::of(&pl), &sampled[..5]).p99,
            TILED_FLOOR
        );
    }
}
