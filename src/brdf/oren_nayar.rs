//! Oren-Nayar (1994, qualitative model): rough diffuse surface of Gaussian facet slopes with
//! standard deviation `sigma` [rad]:
//! `f_r = rho/pi (A + B max(0, cos(phi_i - phi_r)) sin(a) tan(b))`, `a = max(theta_i, theta_r)`,
//! `b = min(theta_i, theta_r)`, `A = 1 - 0.5 s^2/(s^2 + 0.33)`, `B = 0.45 s^2/(s^2 + 0.09)`.

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrenNayar {
    pub rho: f64,
    pub sigma_rad: f64,
}

impl OrenNayar {
    #[inline]
    pub fn eval(&self, n: DVec3, s: DVec3, c: DVec3, mu0: f64, mu: f64) -> f64 {
        let s2 = self.sigma_rad * self.sigma_rad;
        let a = 1.0 - 0.5 * s2 / (s2 + 0.33);
        let b = 0.45 * s2 / (s2 + 0.09);
        // Azimuth difference from the tangent-plane projections of s and c.
        let sp = s - n * mu0;
        let cp = c - n * mu;
        let denom = (sp.length_squared() * cp.length_squared()).sqrt();
        let cos_dphi = if denom > 1e-24 {
            (sp.dot(cp) / denom).max(0.0)
        } else {
            0.0
        };
        let (ti, tr) = (mu0.clamp(-1.0, 1.0).acos(), mu.clamp(-1.0, 1.0).acos());
        let (alpha, beta) = (ti.max(tr), ti.min(tr));
        self.rho * std::f64::consts::FRAC_1_PI * (a + b * cos_dphi * alpha.sin() * beta.tan())
    }
}
