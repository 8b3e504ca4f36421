//! Lommel-Seeliger: single scattering in a semi-infinite particulate medium,
//! `f_r = w / (4 pi (cos theta_i + cos theta_r))` (paper Sec. 4.6).

/// `w` is the single-scattering albedo; `p_N = p_G = w / 8`, `q = 16 (1 - ln 2) / 3`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LommelSeeliger {
    pub w: f64,
}

impl LommelSeeliger {
    #[inline(always)]
    pub fn eval(&self, mu0: f64, mu: f64) -> f64 {
        let s = mu0 + mu;
        if s <= 0.0 {
            0.0
        } else {
            self.w / (4.0 * std::f64::consts::PI * s)
        }
    }

    /// Eq. 48: `Psi = 1 + sin(alpha/2) tan(alpha/2) ln(tan(alpha/4))`.
    pub fn phase_law(alpha: f64) -> f64 {
        if alpha < 1e-9 {
            return 1.0;
        }
        1.0 + (alpha / 2.0).sin() * (alpha / 2.0).tan() * (alpha / 4.0).tan().ln()
    }
}
