//! Lanczos filter `sinc(x) sinc(x / a)` for `|x| < a`.

#[inline]
pub fn weight(x: f64, a: f64) -> f64 {
    if x.abs() >= a {
        return 0.0;
    }
    if x.abs() < 1e-12 {
        return 1.0;
    }
    let px = std::f64::consts::PI * x;
    a * px.sin() * (px / a).sin() / (px * px)
}
