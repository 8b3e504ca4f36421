//! Gaussian filter of standard deviation `sigma` [px].

#[inline]
pub fn weight(x: f64, sigma: f64) -> f64 {
    (-0.5 * x * x / (sigma * sigma)).exp()
}
