//! Gaussian-weighted gridding (Eqs. 42-43): weights `exp(-(d_u^2 + d_v^2) / (2 sigma^2))` at the
//! pixel centres of a square window around the point's pixel, normalised to sum to one. The
//! Gaussian is separable, so the normalisation is the product of the two 1-D sums.

use super::Accum;

const MAX_WINDOW: usize = 15;

#[inline]
pub fn splat(p: [f64; 2], value: f64, window: u32, sigma: f64, acc: &mut Accum) {
    let n = (window as usize).clamp(1, MAX_WINDOW);
    let half = (n / 2) as i64;
    let (pi, pj) = (p[0].floor() as i64, p[1].floor() as i64);
    let k = -0.5 / (sigma * sigma);
    let mut wu = [0.0; MAX_WINDOW];
    let mut wv = [0.0; MAX_WINDOW];
    let (mut su, mut sv) = (0.0, 0.0);
    for a in 0..n {
        let du = (pi - half + a as i64) as f64 + 0.5 - p[0];
        let dv = (pj - half + a as i64) as f64 + 0.5 - p[1];
        wu[a] = (k * du * du).exp();
        wv[a] = (k * dv * dv).exp();
        su += wu[a];
        sv += wv[a];
    }
    let norm = value / (su * sv);
    for (b, &wv_b) in wv[..n].iter().enumerate() {
        let row = wv_b * norm;
        for (a, &wu_a) in wu[..n].iter().enumerate() {
            acc.add(pi - half + a as i64, pj - half + b as i64, wu_a * row);
        }
    }
}
