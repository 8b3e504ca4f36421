//! Photon shot noise: the collected electrons are Poisson distributed with mean equal to the
//! expected count [71].

use rand::Rng;
use rand_distr::{Distribution, Normal, Poisson};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shot;

/// A Poisson draw of mean `mean_e` (normal approximation above 1e7 electrons, where the
/// relative error of the approximation is below 1e-7).
#[inline]
pub fn poisson(mean_e: f64, rng: &mut impl Rng) -> f64 {
    if mean_e <= 0.0 {
        0.0
    } else if mean_e < 1e7 {
        Poisson::new(mean_e).map_or(mean_e, |p| p.sample(rng))
    } else {
        Normal::new(mean_e, mean_e.sqrt()).map_or(mean_e, |n| n.sample(rng).max(0.0))
    }
}

impl Shot {
    #[inline]
    pub fn apply(&self, electrons: f64, rng: &mut impl Rng) -> f64 {
        poisson(electrons, rng)
    }
}
