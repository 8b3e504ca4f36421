//! Reflectance models (BRDFs): one file per model, dispatched by `match` on [`Brdf`].
//!
//! Every model here but Hapke is linear in one scale parameter (`rho` or `w`), so an albedo
//! of any type (normal, geometric, bond) converts to that parameter by one ratio computed with
//! the parameter set to 1; Hapke's albedos rise monotonically with `w`, which is found by
//! bisection ([`Brdf::with_albedo`]).
//!
//! Phase laws (paper Eq. 48, Eq. 11): `p_G Psi(alpha) = integral over the lit, visible unit
//! hemisphere of f_r cos(theta_i) cos(theta_r) dOmega` for a distant sphere. Lambert, Area and
//! Lommel-Seeliger have closed forms; the others are integrated numerically.

pub mod area;
pub mod hapke;
pub mod lambert;
pub mod lommel_seeliger;
pub mod oren_nayar;
pub mod phong;
pub mod specular;

use glam::DVec3;
use serde::{Deserialize, Serialize};

pub use area::Area;
pub use hapke::{Hapke, HapkeParams};
pub use lambert::Lambert;
pub use lommel_seeliger::LommelSeeliger;
pub use oren_nayar::OrenNayar;
pub use phong::Phong;
pub use specular::Specular;

/// Which albedo a configured value means.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlbedoType {
    /// `p_N = pi f_r` at normal incidence and emission, zero phase.
    Normal,
    /// `p_G`: disk brightness at zero phase relative to a Lambert disk (Eq. 11).
    Geometric,
    /// Bond albedo `A = p_G q`, `q = 2 int_0^pi Psi(alpha) sin(alpha) d alpha`.
    Bond,
}

/// The geometry of one surface element: unit normal `n`, unit directions to the Sun `s` and
/// to the camera `c`, and their cosines `mu0 = n.s`, `mu = n.c`.
#[derive(Clone, Copy, Debug)]
pub struct Local {
    pub n: DVec3,
    pub s: DVec3,
    pub c: DVec3,
    pub mu0: f64,
    pub mu: f64,
}

impl Local {
    #[inline(always)]
    pub fn new(n: DVec3, s: DVec3, c: DVec3) -> Self {
        Local {
            n,
            s,
            c,
            mu0: n.dot(s),
            mu: n.dot(c),
        }
    }
}

/// A closed form for `integral of f_r mu0 mu dOmega` over a longitude-latitude quadrangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ExactForm {
    /// `f_r mu0 mu = k mu0 mu` (Lambert): second moments of the normal (Eqs. 35-36).
    Bilinear(f64),
    /// `f_r mu0 mu = k mu` (Area): first moments of the normal.
    Linear(f64),
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Brdf {
    Lambert(Lambert),
    Area(Area),
    LommelSeeliger(LommelSeeliger),
    OrenNayar(OrenNayar),
    Specular(Specular),
    Phong(Phong),
    Hapke(Hapke),
}

impl Brdf {
    pub fn name(&self) -> &'static str {
        match self {
            Brdf::Lambert(_) => "lambert",
            Brdf::Area(_) => "area",
            Brdf::LommelSeeliger(_) => "lommel_seeliger",
            Brdf::OrenNayar(_) => "oren_nayar",
            Brdf::Specular(_) => "specular",
            Brdf::Phong(_) => "phong",
            Brdf::Hapke(_) => "hapke",
        }
    }

    /// `f_r` [1/sr] for a lit, visible element (`mu0 > 0`, `mu > 0`).
    #[inline(always)]
    pub fn eval(&self, g: &Local) -> f64 {
        match self {
            Brdf::Lambert(b) => b.eval(),
            Brdf::Area(b) => b.eval(g.mu0),
            Brdf::LommelSeeliger(b) => b.eval(g.mu0, g.mu),
            Brdf::OrenNayar(b) => b.eval(g.n, g.s, g.c, g.mu0, g.mu),
            Brdf::Specular(b) => b.eval(g.n, g.s, g.c, g.mu0),
            Brdf::Phong(b) => b.eval(g.n, g.s, g.c, g.mu0),
            Brdf::Hapke(b) => b.eval(g.mu0, g.mu, g.s.dot(g.c)),
        }
    }

    /// The closed-form quadrangle integral, where one exists.
    pub fn exact_form(&self) -> Option<ExactForm> {
        match self {
            Brdf::Lambert(b) => Some(ExactForm::Bilinear(b.eval())),
            Brdf::Area(b) => Some(ExactForm::Linear(b.rho * std::f64::consts::FRAC_1_PI)),
            _ => None,
        }
    }

    /// The scale parameter (`rho`, or `w` for Lommel-Seeliger and Hapke).
    pub fn scale(&self) -> f64 {
        match self {
            Brdf::Lambert(b) => b.rho,
            Brdf::Area(b) => b.rho,
            Brdf::LommelSeeliger(b) => b.w,
            Brdf::OrenNayar(b) => b.rho,
            Brdf::Specular(b) => b.rho,
            Brdf::Phong(b) => b.rho,
            Brdf::Hapke(b) => b.w(),
        }
    }

    /// The same model with its scale parameter set to `scale`.
    pub fn with_scale(&self, scale: f64) -> Brdf {
        let mut out = *self;
        match &mut out {
            Brdf::Lambert(b) => b.rho = scale,
            Brdf::Area(b) => b.rho = scale,
            Brdf::LommelSeeliger(b) => b.w = scale,
            Brdf::OrenNayar(b) => b.rho = scale,
            Brdf::Specular(b) => b.rho = scale,
            Brdf::Phong(b) => b.rho = scale,
            Brdf::Hapke(b) => b.set_w(scale),
        }
        out
    }

    /// The same model scaled so that its albedo of `kind` equals `value`. For Hapke, whose
    /// albedos rise with `w` but not in proportion, `w` in [0, 1] is found by the Illinois
    /// variant of regula falsi (to 1e-12 in albedo, a handful of evaluations); an albedo beyond
    /// `w = 1` gives a non-finite scale, which the config refuses.
    pub fn with_albedo(&self, value: f64, kind: AlbedoType) -> Brdf {
        if let Brdf::Hapke(_) = self {
            if value <= 0.0 {
                return self.with_scale(0.0);
            }
            let f = |w: f64| self.with_scale(w).albedo(kind) - value;
            // At w = 0 every albedo is 0 (the Bond albedo's phase integral would be 0/0).
            let (mut a, mut b) = (0.0, 1.0);
            let (mut fa, mut fb) = (-value, f(b));
            if fb < 0.0 {
                return self.with_scale(f64::NAN);
            }
            let mut side = 0;
            for _ in 0..100 {
                let c = (a * fb - b * fa) / (fb - fa);
                let fc = f(c);
                if fc.abs() < 1e-12 || (b - a).abs() < 1e-15 {
                    return self.with_scale(c);
                }
                if fc * fb > 0.0 {
                    (b, fb) = (c, fc);
                    if side == -1 {
                        fa *= 0.5;
                    }
                    side = -1;
                } else {
                    (a, fa) = (c, fc);
                    if side == 1 {
                        fb *= 0.5;
                    }
                    side = 1;
                }
            }
            return self.with_scale(0.5 * (a + b));
        }
        let unit = self.with_scale(1.0);
        let per_unit = unit.albedo(kind);
        self.with_scale(value / per_unit)
    }

    /// The scale parameters whose normal albedos are `values`, for a map of normal albedos.
    /// Linear models take one ratio. Hapke's `p_N(w)` is tabulated once at 4097 values of
    /// `w` (denser towards `w = 1`, where it steepens) and inverted by linear interpolation:
    /// a whole map costs one table, not one root search per texel. A value above `p_N(1)`
    /// is returned as `Err(value)`; NaN (no data) stays NaN.
    pub fn scales_for_normal_albedos(&self, values: &[f64]) -> Result<Vec<f64>, f64> {
        if !matches!(self, Brdf::Hapke(_)) {
            let per_unit = self.with_scale(1.0).albedo(AlbedoType::Normal);
            return Ok(values.iter().map(|v| v / per_unit).collect());
        }
        const N: usize = 4096;
        let w: Vec<f64> = (0..=N)
            .map(|k| {
                let t = 1.0 - k as f64 / N as f64;
                1.0 - t * t
            })
            .collect();
        let p: Vec<f64> = w
            .iter()
            .map(|&w| self.with_scale(w).albedo(AlbedoType::Normal))
            .collect();
        values
            .iter()
            .map(|&v| {
                if v.is_nan() {
                    return Ok(v);
                }
                if v <= 0.0 {
                    return Ok(0.0);
                }
                if v > p[N] {
                    return Err(v);
                }
                let k = p.partition_point(|&x| x < v).clamp(1, N);
                let t = (v - p[k - 1]) / (p[k] - p[k - 1]);
                Ok(w[k - 1] + t * (w[k] - w[k - 1]))
            })
            .collect()
    }

    /// The albedo of `kind` of this model as parametrised.
    pub fn albedo(&self, kind: AlbedoType) -> f64 {
        match kind {
            AlbedoType::Normal => {
                let n = DVec3::Z;
                std::f64::consts::PI * self.eval(&Local::new(n, n, n))
            }
            AlbedoType::Geometric => self.geometric_albedo(),
            AlbedoType::Bond => self.geometric_albedo() * self.phase_integral(),
        }
    }

    /// `p_G = p_G Psi(0)`.
    pub fn geometric_albedo(&self) -> f64 {
        match self {
            Brdf::Lambert(b) => 2.0 * b.rho / 3.0,
            Brdf::Area(b) => b.rho,
            Brdf::LommelSeeliger(b) => b.w / 8.0,
            _ => disk_integral(self, 0.0),
        }
    }

    /// The phase law `Psi(alpha)`, 1 at zero phase (Eq. 48).
    pub fn phase_law(&self, alpha: f64) -> f64 {
        match self {
            Brdf::Lambert(_) => Lambert::phase_law(alpha),
            Brdf::Area(_) => Area::phase_law(alpha),
            Brdf::LommelSeeliger(_) => LommelSeeliger::phase_law(alpha),
            _ => disk_integral(self, alpha) / disk_integral(self, 0.0),
        }
    }

    /// Phase integral `q = 2 int_0^pi Psi(alpha) sin(alpha) d alpha`.
    pub fn phase_integral(&self) -> f64 {
        match self {
            Brdf::Lambert(_) => 1.5,
            Brdf::Area(_) => 2.0,
            Brdf::LommelSeeliger(_) => 16.0 * (1.0 - 2f64.ln()) / 3.0,
            _ => {
                let (x, w) = crate::radiometry::gauss_legendre(48);
                let h = std::f64::consts::FRAC_PI_2;
                let p0 = disk_integral(self, 0.0);
                2.0 * x
                    .iter()
                    .zip(&w)
                    .map(|(x, w)| {
                        let a = h * (x + 1.0);
                        w * h * disk_integral(self, a) / p0 * a.sin()
                    })
                    .sum::<f64>()
            }
        }
    }
}

/// `p_G Psi(alpha)` of a distant sphere by Gauss-Legendre quadrature in CSF coordinates over
/// the lit, visible region `lon in [alpha - pi/2, pi/2]`, `lat in [-pi/2, pi/2]` (Eq. 11).
pub fn disk_integral(brdf: &Brdf, alpha: f64) -> f64 {
    let (x, w) = crate::radiometry::gauss_legendre(96);
    let (lo, hi) = (
        alpha - std::f64::consts::FRAC_PI_2,
        std::f64::consts::FRAC_PI_2,
    );
    if hi <= lo {
        return 0.0;
    }
    let s = DVec3::X;
    let c = DVec3::new(alpha.cos(), alpha.sin(), 0.0);
    let (hl, ml) = (0.5 * (hi - lo), 0.5 * (hi + lo));
    let hb = std::f64::consts::FRAC_PI_2;
    let mut sum = 0.0;
    for (xi, wi) in x.iter().zip(&w) {
        let lon = ml + hl * xi;
        for (xj, wj) in x.iter().zip(&w) {
            let lat = hb * xj;
            let n = crate::geometry::unit_from_lon_lat(lon, lat);
            let g = Local::new(n, s, c);
            if g.mu0 > 0.0 && g.mu > 0.0 {
                sum += wi * wj * brdf.eval(&g) * g.mu0 * g.mu * lat.cos();
            }
        }
    }
    sum * hl * hb
}

#[cfg(test)]
mod tests {
    use super::*;

    fn models() -> Vec<Brdf> {
        vec![
            Brdf::Lambert(Lambert { rho: 0.3 }),
            Brdf::Area(Area { rho: 0.3 }),
            Brdf::LommelSeeliger(LommelSeeliger { w: 0.3 }),
            Brdf::OrenNayar(OrenNayar {
                rho: 0.3,
                sigma_rad: 0.4,
            }),
            Brdf::Specular(Specular {
                rho: 0.3,
                shininess: 10.0,
            }),
            Brdf::Phong(Phong {
                rho: 0.3,
                diffuse_weight: 0.7,
                specular_weight: 0.3,
                shininess: 10.0,
            }),
            Brdf::Hapke(Hapke::new(
                0.3,
                HapkeParams {
                    b: 0.21,
                    c: 0.7,
                    b0_c: 0.5,
                    h_c: 0.1,
                    b0_s: 1.0,
                    h_s: 0.07,
                    theta_rad: 0.4,
                    filling_factor: 0.41,
                },
            )),
        ]
    }

    #[test]
    fn closed_form_phase_laws_match_quadrature() {
        for b in models().into_iter().take(3) {
            let p0 = disk_integral(&b, 0.0);
            assert!(
                (p0 / b.geometric_albedo() - 1.0).abs() < 1e-6,
                "{} p_G",
                b.name()
            );
            for deg in [10.0f64, 30.0, 60.0, 90.0, 120.0, 150.0] {
                let a = deg.to_radians();
                let num = disk_integral(&b, a) / p0;
                let ana = b.phase_law(a);
                assert!(
                    (num / ana - 1.0).abs() < 2e-4,
                    "{} at {deg}: {num} vs {ana}",
                    b.name()
                );
            }
        }
    }

    #[test]
    fn albedo_conversions_round_trip() {
        for b in models() {
            for kind in [AlbedoType::Normal, AlbedoType::Geometric, AlbedoType::Bond] {
                let s = b.with_albedo(0.12, kind);
                assert!(
                    (s.albedo(kind) - 0.12).abs() < 1e-9,
                    "{} {kind:?}",
                    b.name()
                );
            }
        }
        // Lambert: p_G = 2/3 p_N, A = p_N.
        let l = Brdf::Lambert(Lambert { rho: 0.3 });
        assert!((l.albedo(AlbedoType::Geometric) - 0.2).abs() < 1e-12);
        assert!((l.albedo(AlbedoType::Bond) - 0.3).abs() < 1e-12);
    }

    #[test]
    fn diffuse_models_do_not_create_energy() {
        // Directional-hemispherical reflectance <= 1 for albedo-1 diffuse models.
        for b in [
            Brdf::Lambert(Lambert { rho: 1.0 }),
            Brdf::OrenNayar(OrenNayar {
                rho: 1.0,
                sigma_rad: 0.5,
            }),
        ] {
            for inc in [0.0f64, 30.0, 60.0, 85.0] {
                let s = crate::geometry::unit_from_lon_lat(
                    0.0,
                    std::f64::consts::FRAC_PI_2 - inc.to_radians(),
                );
                let n = DVec3::Z;
                let (x, w) = crate::radiometry::gauss_legendre(64);
                let mut r = 0.0;
                for (xi, wi) in x.iter().zip(&w) {
                    let phi = std::f64::consts::PI * (xi + 1.0);
                    for (xj, wj) in x.iter().zip(&w) {
                        let th = std::f64::consts::FRAC_PI_4 * (xj + 1.0);
                        let c = crate::geometry::unit_from_lon_lat(
                            phi,
                            std::f64::consts::FRAC_PI_2 - th,
                        );
                        let g = Local::new(n, s, c);
                        r += wi * wj * b.eval(&g) * g.mu * th.sin();
                    }
                }
                r *= std::f64::consts::PI * std::f64::consts::FRAC_PI_4;
                assert!(r <= 1.0 + 1e-6, "{} at {inc}: {r}", b.name());
            }
        }
    }
}
