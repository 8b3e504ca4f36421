//! Super-sampling reconstruction (Sec. 4.8, Fig. 19b): the fine grid (factor `m`) is resized
//! to the image with a reconstruction filter, one file per filter, after an optional
//! anti-aliasing Gaussian.
//!
//! Energy is conserved: resizing is a *scatter* in which every fine pixel hands its value to
//! the image pixels within the filter's reach with weights normalised to sum to one over the
//! pixels inside the frame. Filters are separable: rows then columns.

mod bilinear;
mod box_filter;
mod gaussian;
mod lanczos;

use rayon::prelude::*;
use serde::Serialize;

#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "filter")]
pub enum Reconstruction {
    Box,
    Bilinear,
    /// Lanczos with `a` lobes.
    Lanczos {
        a: u32,
    },
    /// Gaussian of `sigma_px` image pixels.
    Gaussian {
        sigma_px: f64,
    },
}

impl Reconstruction {
    /// Filter weight at a distance `x` [image px] from an image pixel centre.
    fn weight(&self, x: f64) -> f64 {
        match self {
            Reconstruction::Box => box_filter::weight(x),
            Reconstruction::Bilinear => bilinear::weight(x),
            Reconstruction::Lanczos { a } => lanczos::weight(x, *a as f64),
            Reconstruction::Gaussian { sigma_px } => gaussian::weight(x, *sigma_px),
        }
    }

    /// Reach of the filter [image px].
    fn radius(&self) -> f64 {
        match self {
            Reconstruction::Box => 0.5,
            Reconstruction::Bilinear => 1.0,
            Reconstruction::Lanczos { a } => *a as f64,
            Reconstruction::Gaussian { sigma_px } => 4.0 * sigma_px,
        }
    }
}

/// For each source index, the destination indices and normalised weights of a 1-D scatter
/// from `n_src` samples at `(f + 0.5) / m` to `n_dst` pixels centred at `j + 0.5`.
/// Returned transposed (per destination) so that the sums run in a fixed order.
fn scatter_table(
    n_src: usize,
    n_dst: usize,
    m: f64,
    weight: impl Fn(f64) -> f64,
    radius: f64,
) -> Vec<Vec<(usize, f64)>> {
    let mut per_dst: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n_dst];
    let mut tmp: Vec<(usize, f64)> = Vec::new();
    for f in 0..n_src {
        let x = (f as f64 + 0.5) / m;
        let lo = ((x - radius - 0.5).floor().max(0.0)) as usize;
        let hi = ((x + radius - 0.5).ceil().max(0.0) as usize).min(n_dst.saturating_sub(1));
        tmp.clear();
        let mut sum = 0.0;
        for j in lo..=hi {
            let w = weight(x - (j as f64 + 0.5));
            if w != 0.0 {
                tmp.push((j, w));
                sum += w;
            }
        }
        if sum == 0.0 {
            // Nothing in reach inside the frame (edge with a narrow filter): nearest pixel.
            let j = (x.floor() as usize).min(n_dst - 1);
            per_dst[j].push((f, 1.0));
            continue;
        }
        for &(j, w) in &tmp {
            per_dst[j].push((f, w / sum));
        }
    }
    per_dst
}

/// Separable conservative resampling of a `w_src x h_src` image to `w_dst x h_dst`.
#[allow(clippy::too_many_arguments)]
fn resample(
    src: &[f64],
    w_src: usize,
    h_src: usize,
    w_dst: usize,
    h_dst: usize,
    m: f64,
    weight: impl Fn(f64) -> f64 + Copy,
    radius: f64,
) -> Vec<f64> {
    let tu = scatter_table(w_src, w_dst, m, weight, radius);
    let tv = scatter_table(h_src, h_dst, m, weight, radius);
    let mut rows = vec![0.0; w_dst * h_src];
    rows.par_chunks_mut(w_dst).enumerate().for_each(|(y, out)| {
        let line = &src[y * w_src..(y + 1) * w_src];
        for (j, o) in out.iter_mut().enumerate() {
            *o = tu[j].iter().map(|&(f, w)| w * line[f]).sum();
        }
    });
    let mut dst = vec![0.0; w_dst * h_dst];
    dst.par_chunks_mut(w_dst).enumerate().for_each(|(j, out)| {
        for &(f, w) in &tv[j] {
            let line = &rows[f * w_dst..(f + 1) * w_dst];
            for (o, &x) in out.iter_mut().zip(line) {
                *o += w * x;
            }
        }
    });
    dst
}

/// Resizes the fine grid (`m` times the image in each axis) to the image, after an optional
/// anti-aliasing Gaussian of `antialias_sigma` fine pixels.
pub fn reconstruct(
    fine: &[f64],
    width: usize,
    height: usize,
    m: usize,
    filter: Reconstruction,
    antialias_sigma: f64,
) -> Vec<f64> {
    let (wf, hf) = (width * m, height * m);
    let blurred;
    let src = if antialias_sigma > 0.0 {
        let s = antialias_sigma;
        blurred = resample(
            fine,
            wf,
            hf,
            wf,
            hf,
            1.0,
            move |x| gaussian::weight(x, s),
            4.0 * s,
        );
        &blurred[..]
    } else {
        fine
    };
    if m == 1 {
        return src.to_vec();
    }
    resample(
        src,
        wf,
        hf,
        width,
        height,
        m as f64,
        move |x| filter.weight(x),
        filter.radius(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_filter_conserves_energy() {
        let (w, h, m) = (7, 5, 3);
        let fine: Vec<f64> = (0..w * m * h * m)
            .map(|i| ((i * 7919) % 101) as f64 + 0.5)
            .collect();
        let total: f64 = fine.iter().sum();
        for f in [
            Reconstruction::Box,
            Reconstruction::Bilinear,
            Reconstruction::Lanczos { a: 3 },
            Reconstruction::Gaussian { sigma_px: 0.6 },
        ] {
            for aa in [0.0, 1.0] {
                let out = reconstruct(&fine, w, h, m, f, aa);
                let s: f64 = out.iter().sum();
                assert!(
                    (s / total - 1.0).abs() < 1e-12,
                    "{f:?} aa {aa}: {s} vs {total}"
                );
            }
        }
    }

    #[test]
    fn box_filter_sums_blocks() {
        let fine = vec![1.0; 4 * 4];
        let out = reconstruct(&fine, 2, 2, 2, Reconstruction::Box, 0.0);
        assert_eq!(out, vec![4.0; 4]);
    }
}
