//! Photo-response non-uniformity: a fixed per-pixel gain, normally distributed around one
//! with standard deviation `sigma` [71].

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prnu {
    /// Standard deviation of the gain factor [-].
    pub sigma: f64,
}

impl Prnu {
    #[inline]
    pub fn gain(&self, rng: &mut impl Rng) -> f64 {
        let n: f64 = StandardNormal.sample(rng);
        (1.0 + self.sigma * n).max(0.0)
    }
}
