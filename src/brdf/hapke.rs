//! Hapke's bidirectional reflectance of a particulate surface, as used for the Moon (paper
//! Sec. 4.6; Sato et al. 2014):
//!
//! `r = K w/(4 pi) mu0e/(mu0e + mue) [P(g)(1 + B_S(g)) + M(mu0e/K, mue/K)] (1 + B_C(g)) S`,
//! `f_r = r / mu0`,
//!
//! with
//! - `w` the single-scattering albedo;
//! - `P` a two-term Henyey-Greenstein phase function;
//! - `B_S` the shadow-hiding opposition effect (Hapke 1986);
//! - `B_C` coherent backscatter (Hapke 2002, Eq. 34);
//! - `M = H(x) H(y) - 1` with the 2002 approximation of the H function (Hapke 2002, Eq. 13);
//! - `K` the porosity factor of filling factor `phi` (Hapke 2008, Eq. 14);
//! - `mu0e`, `mue`, `S` the effective cosines and shadowing of macroscopic roughness `theta`
//!   (Hapke 1984, Eqs. 46-58).
//!
//! The phase-function convention: `c` in [0, 1] is the weight of the **back**-scattering lobe,
//! `P = (1 - c) HG_forward + c HG_back`, where `HG(b) = (1 - b^2)/(1 -+ 2 b cos g + b^2)^1.5`.
//! This is the convention of eradiate's `hapke` BSDF. Configs written with `c'` in [-1, 1],
//! where `P = (1 + c')/2 HG_back + (1 - c')/2 HG_forward`, convert by `c = (1 + c')/2`.

use std::f64::consts::{FRAC_1_PI, PI};

/// Hapke's parameters besides `w`, in the order of the reference configs
/// (`methodology.md`): `[b, c, B0_C, h_C, B0_S, h_S, theta (rad), filling factor]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HapkeParams {
    /// Henyey-Greenstein asymmetry, [0, 1).
    pub b: f64,
    /// Weight of the back-scattering lobe, [0, 1].
    pub c: f64,
    /// Coherent-backscatter amplitude and angular width.
    pub b0_c: f64,
    pub h_c: f64,
    /// Shadow-hiding amplitude and angular width.
    pub b0_s: f64,
    pub h_s: f64,
    /// Mean slope angle of the macroscopic roughness [rad], [0, pi/2).
    pub theta_rad: f64,
    /// Filling factor (1 - porosity), [0, 0.752); 0 gives K = 1 (Hapke 1981).
    pub filling_factor: f64,
}

/// The Hapke BRDF: `w` and the other parameters, with what depends on them alone computed
/// once ([`Hapke::new`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hapke {
    /// Single-scattering albedo (may be changed: nothing derived depends on it).
    pub w: f64,
    p: HapkeParams,
    /// The porosity factor K, tan(theta) and chi(theta).
    k: f64,
    tan_t: f64,
    chi: f64,
}

impl Hapke {
    pub fn new(w: f64, p: HapkeParams) -> Hapke {
        let x = 1.209 * p.filling_factor.powf(2.0 / 3.0);
        let k = if x < 1e-12 { 1.0 } else { -(1.0 - x).ln() / x };
        let tan_t = p.theta_rad.tan();
        Hapke {
            w,
            p,
            k,
            tan_t,
            chi: 1.0 / (1.0 + PI * tan_t * tan_t).sqrt(),
        }
    }

    /// The porosity factor `K` (Hapke 2008, Eq. 14), 1 at zero filling factor.
    pub fn porosity_factor(&self) -> f64 {
        self.k
    }

    /// `f_r` [1/sr] for cosines `mu0`, `mu` (both > 0) and phase angle cosine `cos_g`.
    #[inline]
    pub fn eval(&self, mu0: f64, mu: f64, cos_g: f64) -> f64 {
        if mu0 <= 0.0 || mu <= 0.0 {
            return 0.0;
        }
        let cos_g = cos_g.clamp(-1.0, 1.0);
        let sin_i = (1.0 - mu0 * mu0).max(0.0).sqrt();
        let sin_e = (1.0 - mu * mu).max(0.0).sqrt();
        // Azimuth between the planes of incidence and emission (0 when either is normal).
        let cos_psi = if sin_i * sin_e > 1e-12 {
            ((cos_g - mu0 * mu) / (sin_i * sin_e)).clamp(-1.0, 1.0)
        } else {
            1.0
        };
        let rough = Roughness::new(self, mu0, sin_i, mu, sin_e, cos_psi);
        let k = self.k;
        // tan(g/2) from cos g.
        let half = ((1.0 - cos_g) / (1.0 + cos_g).max(1e-300)).sqrt();
        let b_s = self.p.b0_s / (1.0 + half / self.p.h_s);
        let b_c = if self.p.b0_c == 0.0 {
            0.0
        } else {
            let z = half / self.p.h_c;
            let t = if z < 1e-8 {
                1.0
            } else {
                (1.0 - (-z).exp()) / z
            };
            self.p.b0_c * (1.0 + t) / (2.0 * (1.0 + z) * (1.0 + z))
        };
        let gamma = (1.0 - self.w).sqrt();
        let r0 = (1.0 - gamma) / (1.0 + gamma);
        let m = h2002_r0(self.w, r0, rough.mu0e / k) * h2002_r0(self.w, r0, rough.mue / k) - 1.0;
        // One division for `... mu0e / (mu0e + mue) ... / mu0` (divisions dominated the profile).
        k * self.w
            * 0.25
            * FRAC_1_PI
            * rough.mu0e
            * (self.phase_function(cos_g) * (1.0 + b_s) + m)
            * (1.0 + b_c)
            * rough.s
            / ((rough.mu0e + rough.mue) * mu0)
    }

    /// The two-term Henyey-Greenstein phase function at phase angle `g` (`cos_g`).
    pub fn phase_function(&self, cos_g: f64) -> f64 {
        let (b, c) = (self.p.b, self.p.c);
        let num = 1.0 - b * b;
        let pow_1_5 = |x: f64| x * x.sqrt();
        let forward = num / pow_1_5(1.0 + 2.0 * b * cos_g + b * b);
        let back = num / pow_1_5(1.0 - 2.0 * b * cos_g + b * b);
        (1.0 - c) * forward + c * back
    }
}

/// Chandrasekhar's H function in Hapke's 2002 approximation (Eq. 13): within 1 % of the exact
/// one for all `w`.
#[inline]
pub fn h2002(w: f64, x: f64) -> f64 {
    let gamma = (1.0 - w).sqrt();
    h2002_r0(w, (1.0 - gamma) / (1.0 + gamma), x)
}

/// [`h2002`] with its `r0 = (1 - sqrt(1 - w)) / (1 + sqrt(1 - w))` given.
#[inline]
fn h2002_r0(w: f64, r0: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    1.0 / (1.0 - w * x * (r0 + 0.5 * (1.0 - 2.0 * r0 * x) * ((1.0 + x) / x).ln()))
}

/// Hapke's (1984) macroscopic roughness: effective cosines and the shadowing function.
struct Roughness {
    mu0e: f64,
    mue: f64,
    s: f64,
}

impl Roughness {
    fn new(h: &Hapke, mu0: f64, sin_i: f64, mu: f64, sin_e: f64, cos_psi: f64) -> Roughness {
        if h.p.theta_rad < 1e-9 {
            return Roughness {
                mu0e: mu0,
                mue: mu,
                s: 1.0,
            };
        }
        let (tan_t, chi) = (h.tan_t, h.chi);
        // cot x of the incidence and emission angles (infinite at normal incidence).
        let cot = |cos: f64, sin: f64| if sin > 0.0 { cos / sin } else { f64::INFINITY };
        let (cot_i, cot_e) = (cot(mu0, sin_i), cot(mu, sin_e));
        let e1 = |cot_x: f64| (-2.0 * FRAC_1_PI * cot_x / tan_t).exp();
        let e2 = |cot_x: f64| (-FRAC_1_PI * cot_x * cot_x / (tan_t * tan_t)).exp();
        let (e1_i, e2_i, e1_e, e2_e) = (e1(cot_i), e2(cot_i), e1(cot_e), e2(cot_e));
        // The effective cosines of each direction alone (eta).
        let eta0 = chi * (mu0 + sin_i * tan_t * e2_i / (2.0 - e1_i));
        let eta = chi * (mu + sin_e * tan_t * e2_e / (2.0 - e1_e));
        // sin^2(psi/2) and tan(psi/2) from cos(psi); f = 0 at psi = pi.
        let sin2_half = 0.5 * (1.0 - cos_psi);
        let f = if cos_psi <= -1.0 + 1e-15 {
            0.0
        } else {
            (-2.0 * (sin2_half / (1.0 - sin2_half)).sqrt()).exp()
        };
        let frac = cos_psi.acos() * FRAC_1_PI;
        let (mu0e, mue, shadow) = if cot_i >= cot_e {
            // i <= e.
            let d = 2.0 - e1_e - frac * e1_i;
            let mu0e = chi * (mu0 + sin_i * tan_t * (cos_psi * e2_e + sin2_half * e2_i) / d);
            let mue = chi * (mu + sin_e * tan_t * (e2_e - sin2_half * e2_i) / d);
            (mu0e, mue, mu0 / eta0)
        } else {
            // e <= i.
            let d = 2.0 - e1_i - frac * e1_e;
            let mu0e = chi * (mu0 + sin_i * tan_t * (e2_i - sin2_half * e2_e) / d);
            let mue = chi * (mu + sin_e * tan_t * (cos_psi * e2_i + sin2_half * e2_e) / d);
            (mu0e, mue, mu / eta)
        };
        let s = mue * mu0 * chi / (eta * eta0 * (1.0 - f + f * chi * shadow));
        Roughness { mu0e, mue, s }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> HapkeParams {
        HapkeParams {
            b: 0.0,
            c: 0.5,
            b0_c: 0.0,
            h_c: 0.1,
            b0_s: 0.0,
            h_s: 0.1,
            theta_rad: 0.0,
            filling_factor: 0.0,
        }
    }

    fn smooth(w: f64) -> Hapke {
        Hapke::new(w, params())
    }

    /// With isotropic scattering, no opposition effects, no roughness and K = 1, single
    /// scattering is Lommel-Seeliger and the rest is `M`.
    #[test]
    fn the_smooth_isotropic_limit_is_lommel_seeliger_plus_multiple_scattering() {
        let h = smooth(0.3);
        for (mu0, mu, cos_g) in [(1.0, 1.0, 1.0), (0.5, 0.8, 0.2), (0.9, 0.1, 0.3)] {
            let m = h2002(0.3, mu0) * h2002(0.3, mu) - 1.0;
            let want = 0.3 / (4.0 * PI * (mu0 + mu)) * (1.0 + m);
            assert!((h.eval(mu0, mu, cos_g) / want - 1.0).abs() < 1e-13);
        }
    }

    /// The 2002 H function against the exact one for isotropic scattering, solved here from
    /// its integral equation `H(x) = 1 / (1 - w/2 x int_0^1 H(t)/(x + t) dt)` by iteration
    /// on Gauss-Legendre nodes: within 1 % (Hapke 2002's claim) for w up to 0.99.
    #[test]
    fn h2002_is_within_one_percent_of_the_exact_h_function() {
        let (nodes, weights) = crate::radiometry::gauss_legendre(64);
        let t: Vec<f64> = nodes.iter().map(|x| 0.5 * (x + 1.0)).collect();
        let wt: Vec<f64> = weights.iter().map(|w| 0.5 * w).collect();
        for w in [0.1, 0.5, 0.9, 0.99] {
            let exact_at = |h: &[f64], x: f64| {
                let integral: f64 = t
                    .iter()
                    .zip(&wt)
                    .zip(h)
                    .map(|((t, q), h)| q * h / (x + t))
                    .sum();
                1.0 / (1.0 - 0.5 * w * x * integral)
            };
            let mut h = vec![1.0; t.len()];
            for _ in 0..2000 {
                h = t.iter().map(|&x| exact_at(&h, x)).collect();
            }
            for x in [0.05, 0.2, 0.5, 1.0] {
                let (approx, exact) = (h2002(w, x), exact_at(&h, x));
                assert!(
                    (approx / exact - 1.0).abs() < 0.01,
                    "w {w} x {x}: H2002 {approx} exact {exact}"
                );
            }
        }
    }

    #[test]
    fn porosity_factor_is_one_at_zero_filling_and_grows_with_it() {
        assert_eq!(smooth(0.3).porosity_factor(), 1.0);
        let lunar = HapkeParams {
            filling_factor: 0.41, // lunar regolith
            ..params()
        };
        let k = Hapke::new(0.3, lunar).porosity_factor();
        assert!(k > 1.5 && k < 2.5, "{k}");
    }
}
