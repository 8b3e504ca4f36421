//! Phong: a weighted sum of the Lambert and Specular models (paper Sec. 4.6),
//! `f_r = rho (k_d / pi + k_s (n + 2) / (2 pi) max(0, r . c)^n)`.

use super::specular::lobe;
use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phong {
    pub rho: f64,
    pub diffuse_weight: f64,
    pub specular_weight: f64,
    pub shininess: f64,
}

impl Phong {
    #[inline]
    pub fn eval(&self, n: DVec3, s: DVec3, c: DVec3, mu0: f64) -> f64 {
        self.rho
            * (self.diffuse_weight * std::f64::consts::FRAC_1_PI
                + self.specular_weight * lobe(n, s, c, mu0, self.shininess))
    }
}
