//! Readout noise: zero-mean Gaussian electrons added at readout [71].

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Readout {
    /// Standard deviation [e-].
    pub sigma_e: f64,
}

impl Readout {
    #[inline]
    pub fn draw(&self, rng: &mut impl Rng) -> f64 {
        let n: f64 = StandardNormal.sample(rng);
        self.sigma_e * n
    }
}
