//! Dark current: a fixed pattern (Gaussian across pixels, relative standard deviation
//! `fpn_sigma`, [72]) and its own shot noise (Poisson on the dark charge) [71].

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DarkCurrent {
    /// Mean dark current [e-/s].
    pub rate_e_per_s: f64,
    /// Relative standard deviation of the per-pixel dark current [-].
    pub fpn_sigma: f64,
}

impl DarkCurrent {
    /// This pixel's dark current [e-/s].
    #[inline]
    pub fn pixel_rate(&self, rng: &mut impl Rng) -> f64 {
        let n: f64 = StandardNormal.sample(rng);
        (self.rate_e_per_s * (1.0 + self.fpn_sigma * n)).max(0.0)
    }
}
