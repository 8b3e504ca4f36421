//! Photon shot noise: the collected electrons are Poisson distributed with mean equal to the
//! expected count [71].

use rand::Rng;
use rand_distr::{Distribution, Exp1, Normal, Poisson, StandardNormal, StandardUniform};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shot;

/// A Poisson draw of mean `mean_e` (normal approximation above 1e7 electrons, where the
/// relative error of the approximation is below 1e-7).
///
/// From 12 electrons, `rand_distr`'s own algorithm (Ahrens and Dieter's, 1982), draw for draw
/// and bit for bit ([`poisson_ad`]); below, `rand_distr`'s.
#[inline]
pub fn poisson(mean_e: f64, rng: &mut impl Rng) -> f64 {
    if mean_e <= 0.0 {
        0.0
    } else if mean_e < 12.0 || !mean_e.is_finite() {
        Poisson::new(mean_e).map_or(mean_e, |p| p.sample(rng))
    } else if mean_e < 1e7 {
        poisson_ad(mean_e, rng)
    } else {
        Normal::new(mean_e, mean_e.sqrt()).map_or(mean_e, |n| n.sample(rng).max(0.0))
    }
}

/// `rand_distr::Poisson`'s draw for `lambda >= 12` (Ahrens and Dieter 1982, "Computer
/// generation of Poisson deviates from modified normal distributions", ACM TOMS 8(2); the
/// code follows `rand_distr` 0.6's `RejectionMethod`, MIT/Apache-2.0, step by step, with the
/// same operations in the same order and the same draws from `rng`), with one difference:
/// `rand_distr` computes all ten of the method's constants per distribution, where a pixel
/// has a distribution of its own and the draw ends at its first steps (N, I, S) almost
/// always; here the constants of the later steps are computed only when they are reached.
/// A lit pixel's draw takes 25 ns instead of 42; the test below checks the draws against
/// `rand_distr`'s for 2e6 draws over means from 12 to 1e7.
fn poisson_ad(lambda: f64, rng: &mut impl Rng) -> f64 {
    let s = lambda.sqrt();
    let l = (lambda - 1.1484).floor();
    // Step N: a normal deviate (`Normal::new(lambda, s)`'s draw: `mean + std_dev z`).
    let z: f64 = StandardNormal.sample(rng);
    let g = lambda + s * z;
    let mut u_s = None;
    if g >= 0.0 {
        let k1 = g.floor();
        // Step I.
        if k1 >= l {
            return k1;
        }
        // Step S.
        let u: f64 = StandardUniform.sample(rng);
        if 6.0 * lambda.powi(2) * u >= (lambda - k1).powi(3) {
            return k1;
        }
        u_s = Some((k1, u));
    }
    let ad = LateSteps::new(lambda, s);
    if let Some((k1, u)) = u_s {
        // Step Q (with F).
        let (px, py, fx, fy) = ad.f(k1);
        if fy * (1.0 - u) <= py * (px - fx).exp() {
            return k1;
        }
    }
    loop {
        // Step E.
        let e: f64 = Exp1.sample(rng);
        let u: f64 = StandardUniform.sample(rng);
        let u = u * 2.0 - 1.0;
        let t = 1.8 + e * u.signum();
        if t > -0.6744 {
            let k2 = (lambda + s * t).floor();
            let (px, py, fx, fy) = ad.f(k2);
            // Step H.
            if ad.c * u.abs() <= py * (px + e).exp() - fy * (fx + e).exp() {
                return k2;
            }
        }
    }
}

/// The constants of [`poisson_ad`]'s steps F, Q, E and H.
struct LateSteps {
    lambda: f64,
    s: f64,
    c: f64,
    c0: f64,
    c1: f64,
    c2: f64,
    c3: f64,
    omega: f64,
}

impl LateSteps {
    fn new(lambda: f64, s: f64) -> LateSteps {
        let b1 = (1.0 / 24.0) / lambda;
        let b2 = 0.3 * b1 * b1;
        let c3 = (1.0 / 7.0) * b1 * b2;
        let c2 = b2 - 15.0 * c3;
        let c1 = b1 - 6.0 * b2 + 45.0 * c3;
        let c0 = 1.0 - b1 + 3.0 * b2 - 15.0 * c3;
        LateSteps {
            lambda,
            s,
            c: 0.1069 / lambda,
            c0,
            c1,
            c2,
            c3,
            omega: 1.0 / (2.0 * std::f64::consts::PI).sqrt() / lambda.sqrt(),
        }
    }

    /// Step F at `k`: `(px, py, fx, fy)`.
    fn f(&self, k: f64) -> (f64, f64, f64, f64) {
        const FACT: [f64; 10] = [
            1.0, 1.0, 2.0, 6.0, 24.0, 120.0, 720.0, 5040.0, 40320.0, 362880.0,
        ];
        const A: [f64; 10] = [
            -0.5000000002,
            0.3333333343,
            -0.2499998565,
            0.1999997049,
            -0.1666848753,
            0.1428833286,
            -0.1241963125,
            0.1101687109,
            -0.1142650302,
            0.1055093006,
        ];
        let lambda = self.lambda;
        let (px, py) = if k < 10.0 {
            (-lambda, lambda.powf(k) / FACT[k as usize])
        } else {
            let delta = (12.0 * k).recip();
            let delta = delta - 4.8 * delta.powi(3);
            let v = (lambda - k) / k;
            let px = if v.abs() <= 0.25 {
                k * v.powi(2) * A.iter().rev().fold(0.0, |acc, &a| acc * v + a) - delta
            } else {
                k * (1.0 + v).ln() - (lambda - k) - delta
            };
            (px, 1.0 / (2.0 * std::f64::consts::PI).sqrt() / k.sqrt())
        };
        let x = (k - lambda + 0.5) / self.s;
        let fx = -0.5 * x * x;
        let fy = self.omega * (((self.c3 * x * x + self.c2) * x * x + self.c1) * x * x + self.c0);
        (px, py, fx, fy)
    }
}

impl Shot {
    #[inline]
    pub fn apply(&self, electrons: f64, rng: &mut impl Rng) -> f64 {
        poisson(electrons, rng)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// [`poisson_ad`] is `rand_distr::Poisson`'s draw, bit for bit, leaving the generator
    /// where it leaves it: 2e6 draws over means from 12 (where the later steps are taken most
    /// often) to 1e7.
    #[test]
    fn the_draws_are_rand_distrs() {
        let mut means: Vec<f64> = (0..200).map(|k| 12.0 + k as f64 * 0.37).collect();
        means.extend((0..200).map(|k| 12.0 * 1.037f64.powi(k)));
        means.extend([12.0, 12.5, 13.0, 20.0, 99.5, 1e3, 1e5, 9.99e6]);
        let (mut compared, mut draws) = (0, 0);
        for (seed, &mean) in means.iter().enumerate() {
            let mut a = rand_pcg::Pcg64Mcg::seed_from_u64(seed as u64);
            let mut b = a.clone();
            let p = Poisson::new(mean).unwrap();
            for _ in 0..5000 {
                let (want, got) = (p.sample(&mut a), poisson_ad(mean, &mut b));
                assert_eq!(
                    want.to_bits(),
                    got.to_bits(),
                    "mean {mean}: {want} vs {got}"
                );
                draws += 1;
            }
            assert_eq!(
                a.next_u64(),
                b.next_u64(),
                "mean {mean}: the generators part"
            );
            compared += 1;
        }
        assert!(compared > 400 && draws > 2_000_000, "{compared} {draws}");
    }
}
