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
/// once ([`Hapke::new`], [`Hapke::set_w`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hapke {
    /// Single-scattering albedo.
    w: f64,
    /// `r0 = (1 - sqrt(1 - w)) / (1 + sqrt(1 - w))` of the H function (Hapke 2002, Eq. 13).
    r0: f64,
    p: HapkeParams,
    /// The porosity factor K and 1/K.
    k: f64,
    inv_k: f64,
    /// tan(theta), chi(theta), and the exponents' factors of Hapke (1984)'s `E1`, `E2`:
    /// `2 / (pi tan theta)` and `1 / (pi tan^2 theta)`.
    tan_t: f64,
    chi: f64,
    e1_per_cot: f64,
    e2_per_cot2: f64,
}

impl Hapke {
    /// The parameters other than `w`.
    pub fn params(&self) -> &HapkeParams {
        &self.p
    }

    pub fn new(w: f64, p: HapkeParams) -> Hapke {
        let x = 1.209 * p.filling_factor.powf(2.0 / 3.0);
        let k = if x < 1e-12 { 1.0 } else { -(1.0 - x).ln() / x };
        let tan_t = p.theta_rad.tan();
        let mut h = Hapke {
            w,
            r0: 0.0,
            p,
            k,
            inv_k: 1.0 / k,
            tan_t,
            chi: 1.0 / (1.0 + PI * tan_t * tan_t).sqrt(),
            e1_per_cot: 2.0 * FRAC_1_PI / tan_t,
            e2_per_cot2: FRAC_1_PI / (tan_t * tan_t),
        };
        h.set_w(w);
        h
    }

    /// The single-scattering albedo.
    pub fn w(&self) -> f64 {
        self.w
    }

    /// Changes the single-scattering albedo (an albedo map's value, per quadrangle).
    pub fn set_w(&mut self, w: f64) {
        let gamma = (1.0 - w).sqrt();
        self.w = w;
        self.r0 = (1.0 - gamma) / (1.0 + gamma);
    }

    /// The porosity factor `K` (Hapke 2008, Eq. 14), 1 at zero filling factor.
    pub fn porosity_factor(&self) -> f64 {
        self.k
    }

    /// `f_r` [1/sr] for cosines `mu0`, `mu` (both > 0) and phase angle cosine `cos_g`.
    /// Reciprocals are shared where one serves several quotients, and sums of quotients are
    /// put over one denominator.
    #[inline]
    pub fn eval(&self, mu0: f64, mu: f64, cos_g: f64) -> f64 {
        if mu0 <= 0.0 || mu <= 0.0 {
            return 0.0;
        }
        let cos_g = cos_g.clamp(-1.0, 1.0);
        let rough = Roughness::new(self, mu0, mu, cos_g);
        let (x, y) = (rough.mu0e * self.inv_k, rough.mue * self.inv_k);
        // tan(g/2) from cos g.
        let half = ((1.0 - cos_g) / (1.0 + cos_g).max(1e-300)).sqrt();
        let b_s = self.p.b0_s * self.p.h_s / (self.p.h_s + half);
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
        // M = H(x) H(y) - 1 with the 2002 H functions, 1/x and 1/y from one reciprocal.
        let (w, r0) = (self.w, self.r0);
        let m = if x > 0.0 && y > 0.0 {
            let inv_xy = 1.0 / (x * y);
            1.0 / (h2002_den(w, r0, x, y * inv_xy) * h2002_den(w, r0, y, x * inv_xy)) - 1.0
        } else {
            h2002_r0(w, r0, x) * h2002_r0(w, r0, y) - 1.0
        };
        self.k
            * self.w
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
        let pow_1_5 = |x: f64| x * x.sqrt();
        let forward = pow_1_5(1.0 + 2.0 * b * cos_g + b * b);
        let back = pow_1_5(1.0 - 2.0 * b * cos_g + b * b);
        // (1 - c) num / forward + c num / back, over one denominator.
        (1.0 - b * b) * ((1.0 - c) * back + c * forward) / (forward * back)
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
    1.0 / h2002_den(w, r0, x, 1.0 / x)
}

/// The denominator of [`h2002_r0`] at `x > 0`, with `1/x` given:
/// `1 - w x (r0 + (1 - 2 r0 x)/2 ln((1 + x)/x))`.
#[inline(always)]
fn h2002_den(w: f64, r0: f64, x: f64, inv_x: f64) -> f64 {
    1.0 - w * x * (r0 + 0.5 * (1.0 - 2.0 * r0 * x) * (1.0 + inv_x).ln())
}

/// Hapke's (1984) macroscopic roughness: effective cosines and the shadowing function.
struct Roughness {
    mu0e: f64,
    mue: f64,
    s: f64,
}

impl Roughness {
    /// At cosines `mu0`, `mu` (both > 0) and phase angle cosine `cos_g`.
    #[inline(always)]
    fn new(h: &Hapke, mu0: f64, mu: f64, cos_g: f64) -> Roughness {
        if h.p.theta_rad < 1e-9 {
            return Roughness {
                mu0e: mu0,
                mue: mu,
                s: 1.0,
            };
        }
        let sin_i = (1.0 - mu0 * mu0).max(0.0).sqrt();
        let sin_e = (1.0 - mu * mu).max(0.0).sqrt();
        // cot of the incidence and emission angles (infinite at normal incidence), from one
        // reciprocal, and the cosine of the azimuth between the planes of incidence and
        // emission (1 when either direction is the normal). The cosine keeps its own division:
        // near psi = 0 the arc cosine below turns its last bit into ~1e-8 of the result.
        let (cot_i, cot_e, cos_psi) = if sin_i * sin_e > 1e-12 {
            let inv = 1.0 / (sin_i * sin_e);
            (
                mu0 * sin_e * inv,
                mu * sin_i * inv,
                ((cos_g - mu0 * mu) / (sin_i * sin_e)).clamp(-1.0, 1.0),
            )
        } else {
            let cot = |cos: f64, sin: f64| if sin > 0.0 { cos / sin } else { f64::INFINITY };
            (cot(mu0, sin_i), cot(mu, sin_e), 1.0)
        };
        let (tan_t, chi) = (h.tan_t, h.chi);
        // Hapke (1984)'s E1 = exp(-2/pi cot(theta) cot x), E2 = exp(-1/pi cot^2(theta) cot^2 x).
        let e1 = |cot_x: f64| (-h.e1_per_cot * cot_x).exp();
        let e2 = |cot_x: f64| (-h.e2_per_cot2 * cot_x * cot_x).exp();
        let (e1_i, e2_i, e1_e, e2_e) = (e1(cot_i), e2(cot_i), e1(cot_e), e2(cot_e));
        // The effective cosines of each direction alone (eta), over one denominator.
        let (two_i, two_e) = (2.0 - e1_i, 2.0 - e1_e);
        let q = 1.0 / (two_i * two_e);
        let eta0 = chi * (mu0 + sin_i * tan_t * e2_i * two_e * q);
        let eta = chi * (mu + sin_e * tan_t * e2_e * two_i * q);
        // sin^2(psi/2) and f = exp(-2 tan(psi/2)); f = 0 at psi = pi.
        let sin2_half = 0.5 * (1.0 - cos_psi);
        let f = if cos_psi <= -1.0 + 1e-15 {
            0.0
        } else {
            (-2.0 * ((1.0 - cos_psi) / (1.0 + cos_psi)).sqrt()).exp()
        };
        let frac = cos_psi.acos() * FRAC_1_PI;
        // The shadowing S = mue mu0 chi / (eta eta0 (1 - f + f chi shadow)), with shadow
        // `mu0 / eta0` (i <= e) or `mu / eta` (e <= i) multiplied through.
        let (mu0e, mue, den) = if cot_i >= cot_e {
            // i <= e.
            let inv_d = 1.0 / (2.0 - e1_e - frac * e1_i);
            let mu0e = chi * (mu0 + sin_i * tan_t * (cos_psi * e2_e + sin2_half * e2_i) * inv_d);
            let mue = chi * (mu + sin_e * tan_t * (e2_e - sin2_half * e2_i) * inv_d);
            (mu0e, mue, eta * (eta0 * (1.0 - f) + f * chi * mu0))
        } else {
            // e <= i.
            let inv_d = 1.0 / (2.0 - e1_i - frac * e1_e);
            let mu0e = chi * (mu0 + sin_i * tan_t * (e2_i - sin2_half * e2_e) * inv_d);
            let mue = chi * (mu + sin_e * tan_t * (cos_psi * e2_i + sin2_half * e2_e) * inv_d);
            (mu0e, mue, eta0 * (eta * (1.0 - f) + f * chi * mu))
        };
        Roughness {
            mu0e,
            mue,
            s: mue * mu0 * chi / den,
        }
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
