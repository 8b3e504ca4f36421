//! A frame's error against the converged reference of the same scene and pose.
//!
//! - **total**: `|sum I - sum R| / sum R`, the light collected.
//! - **median, p95, p99 per lit pixel**: quantiles of `|I - R| / R` over the *lit pixels*, those
//!   whose reference is at least [`LIT_FRACTION`] of the reference's 99th percentile (over its
//!   non-zero pixels). A pixel the limb or a shadow cuts to a sliver of light holds a few
//!   photons whose relative error says nothing a user sees; one at a hundredth of the bright
//!   surface does.
//! - **ssim**: the mean of SSIM (`l c s`, the Gaussian window of Wang 2004, sigma 1.5 px;
//!   [`crate::compare::ssim_maps`]) over the whole image, at the reference's peak as full scale.

use serde::Serialize;

/// Lit pixels: reference at least this fraction of its 99th percentile.
pub const LIT_FRACTION: f64 = 0.01;

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrameError {
    pub total: f64,
    pub median: f64,
    pub p95: f64,
    pub p99: f64,
    pub ssim: f64,
    pub lit_px: usize,
}

impl FrameError {
    /// Whether this error is at or below `other` on every figure (SSIM: at or above).
    pub fn no_worse_than(&self, other: &FrameError) -> bool {
        self.total <= other.total
            && self.median <= other.median
            && self.p95 <= other.p95
            && self.p99 <= other.p99
            && self.ssim >= other.ssim
    }
}

/// The value from which a pixel of `reference` counts as lit: [`LIT_FRACTION`] of the 99th
/// percentile of its positive pixels (`None` where none is positive).
pub fn lit_floor(reference: &[f64]) -> Option<f64> {
    let mut positive: Vec<f64> = reference.iter().copied().filter(|&r| r > 0.0).collect();
    (!positive.is_empty()).then(|| LIT_FRACTION * crate::stats::quantiles(&mut positive, [0.99])[0])
}

/// The error of `image` against `reference` (same size, row-major, any linear unit).
pub fn frame_error(image: &[f64], reference: &[f64], width: usize, height: usize) -> FrameError {
    assert_eq!(image.len(), reference.len());
    let total_ref: f64 = reference.iter().sum();
    let total_img: f64 = image.iter().sum();
    let total = if total_ref > 0.0 {
        (total_img / total_ref - 1.0).abs()
    } else if total_img == 0.0 {
        0.0
    } else {
        f64::INFINITY
    };
    let mut rel = Vec::new();
    if let Some(lit) = lit_floor(reference) {
        rel = image
            .iter()
            .zip(reference)
            .filter(|(_, r)| **r >= lit)
            .map(|(i, r)| (i / r - 1.0).abs())
            .collect();
    }
    let lit_px = rel.len();
    let [median, p95, p99] = if rel.is_empty() {
        [0.0; 3]
    } else {
        crate::stats::quantiles(&mut rel, [0.5, 0.95, 0.99])
    };
    let peak = reference.iter().copied().fold(0.0, f64::max);
    let ssim = if peak > 0.0 {
        use crate::compare::{Gray, ssim_maps};
        let m = ssim_maps(
            &Gray::new(width, height, image.to_vec()),
            &Gray::new(width, height, reference.to_vec()),
            peak,
        );
        let n = m.luminance.len() as f64;
        m.luminance
            .iter()
            .zip(&m.contrast)
            .zip(&m.structure)
            .map(|((l, c), s)| l * c * s)
            .sum::<f64>()
            / n
    } else {
        1.0
    };
    FrameError {
        total,
        median,
        p95,
        p99,
        ssim,
        lit_px,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_relative_per_lit_pixel_and_in_total() {
        let reference = vec![0.0, 1e-4, 1.0, 1.0, 2.0, 2.0];
        // The 1e-4 pixel is below a hundredth of the p99 (2.0): not lit, its error ignored.
        let image = vec![0.0, 1.0, 1.01, 1.0, 2.0, 1.96];
        let e = frame_error(&image, &reference, 3, 2);
        assert_eq!(e.lit_px, 4);
        assert!((e.median - 0.01).abs() < 1e-12, "{e:?}");
        assert!((e.p99 - 0.02).abs() < 1e-3, "{e:?}");
        let total = image.iter().sum::<f64>() / reference.iter().sum::<f64>() - 1.0;
        assert!((e.total - total.abs()).abs() < 1e-15);
        let same = frame_error(&reference, &reference, 3, 2);
        assert_eq!((same.total, same.median, same.p99), (0.0, 0.0, 0.0));
        assert!((same.ssim - 1.0).abs() < 1e-12);
        assert!(same.no_worse_than(&e) && !e.no_worse_than(&same));
    }
}
