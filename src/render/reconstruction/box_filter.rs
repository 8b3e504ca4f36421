//! Box filter: each fine pixel goes wholly to the image pixel that contains it.

#[inline]
pub fn weight(x: f64) -> f64 {
    if (-0.5..0.5).contains(&x) { 1.0 } else { 0.0 }
}
