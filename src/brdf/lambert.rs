//! Lambert: isotropic reflection, `f_r = rho / pi` (paper Sec. 4.6, Eqs. 35-36).

/// `rho` is the normal albedo `p_N`; `p_G = 2 rho / 3`, bond albedo `A = rho`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lambert {
    pub rho: f64,
}

impl Lambert {
    #[inline(always)]
    pub fn eval(&self) -> f64 {
        self.rho * std::f64::consts::FRAC_1_PI
    }

    /// Eq. 48: `Psi = ((pi - alpha) cos alpha + sin alpha) / pi`.
    pub fn phase_law(alpha: f64) -> f64 {
        ((std::f64::consts::PI - alpha) * alpha.cos() + alpha.sin()) / std::f64::consts::PI
    }
}
