//! Specular: an energy-normalised Phong lobe around the mirror direction,
//! `f_r = rho (n + 2) / (2 pi) max(0, r . c)^n` with `r = 2 (n.s) n - s` (paper Sec. 4.6).
//! A true mirror is a Dirac delta that quadrangles cannot integrate; the lobe is its
//! integrable stand-in, `n` sets its width.

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Specular {
    pub rho: f64,
    pub shininess: f64,
}

/// `(n + 2) / (2 pi) max(0, r . c)^n`.
#[inline]
pub fn lobe(normal: DVec3, s: DVec3, c: DVec3, mu0: f64, shininess: f64) -> f64 {
    let r = normal * (2.0 * mu0) - s;
    let cs = r.dot(c);
    if cs <= 0.0 {
        0.0
    } else {
        (shininess + 2.0) / std::f64::consts::TAU * cs.powf(shininess)
    }
}

impl Specular {
    #[inline]
    pub fn eval(&self, n: DVec3, s: DVec3, c: DVec3, mu0: f64) -> f64 {
        self.rho * lobe(n, s, c, mu0, self.shininess)
    }
}
