//! Area: every lit, visible element has the same radiance, so the reflected power is
//! proportional to the projected lit area: `f_r = rho / (pi cos theta_i)` and
//! `f_r cos theta_i cos theta_r = rho cos theta_r / pi` (paper Sec. 4.6, Fig. 16).

/// `rho` equals the normal and the geometric albedo; bond albedo `A = 2 rho` (q = 2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Area {
    pub rho: f64,
}

impl Area {
    #[inline(always)]
    pub fn eval(&self, mu0: f64) -> f64 {
        if mu0 <= 0.0 {
            0.0
        } else {
            self.rho * std::f64::consts::FRAC_1_PI / mu0
        }
    }

    /// Eq. 48: `Psi = (1 + cos alpha) / 2`, the lit fraction of the disk.
    pub fn phase_law(alpha: f64) -> f64 {
        0.5 * (1.0 + alpha.cos())
    }
}
