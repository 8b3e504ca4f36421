//! Bilinear (tent) filter of radius one image pixel.

#[inline]
pub fn weight(x: f64) -> f64 {
    (1.0 - x.abs()).max(0.0)
}
