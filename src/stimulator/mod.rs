//! The stimulator chain's numeric part (paper Sec. 6.3.1): the rendered signal becomes the
//! effective flux density at the flight camera, `F_eff = k S` with
//! `k = h c / (A_cam max(QE T lambda))` (Eqs. 58-60), and F_eff becomes screen DN through the
//! inverse of the screen's measured calibration curve ([`calibration`]), with optional
//! dithering ([`dither`]) at the screen's DN depth.
//!
//! Still to come here (issue 4): the `[stimulator]` config section (screen geometry,
//! collimator), the wgpu presenter, the simulated camera and `optistim calibrate`.

pub mod calibration;
pub mod dither;

use crate::camera::Intrinsics;
use crate::detector::Detector;
use crate::radiometry::{C, H, max_qe_t_lambda};

/// `k` of Eq. 60 [W m^-2 per e-/s]: `h c / (A_cam max(QE T lambda))`.
pub fn feff_factor(detector: &Detector, intrinsics: &Intrinsics) -> f64 {
    H * C / (intrinsics.aperture_area_m2() * max_qe_t_lambda(&detector.qe, &detector.transmittance))
}

/// F_eff per pixel [W/m^2] from the signal per pixel [e-/s] (Eq. 58).
pub fn feff(signal_e_per_s: &[f64], k: f64, out: &mut Vec<f64>) {
    out.clear();
    out.extend(signal_e_per_s.iter().map(|s| s * k));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::radiometry::SpectralTable;

    /// A monochromatic flux F at the wavelength of max QE T lambda gives S = F A QE T lambda/(hc)
    /// electrons per second, and F_eff = k S gives F back.
    #[test]
    fn feff_inverts_the_signal_of_a_monochromatic_flux() {
        let qe = SpectralTable::new(
            vec![400e-9, 600e-9, 800e-9],
            vec![0.3, 0.6, 0.4],
            (0.0, 1.0),
        )
        .unwrap();
        let t = SpectralTable::flat(400e-9, 800e-9, 0.9);
        let m = max_qe_t_lambda(&qe, &t);
        let intr = Intrinsics {
            width_px: 4,
            height_px: 4,
            pixel_pitch_m: [5.5e-6; 2],
            focal_length_m: 0.03,
            f_number: 4.0,
            principal_point_px: [2.0; 2],
            skew_px: 0.0,
            distortion: Default::default(),
        };
        let det = Detector {
            exposure_s: 1e-3,
            full_well_e: 1e4,
            adc_gain_dn_per_e: 0.1,
            offset_dn: 0.0,
            bit_depth: 12,
            qe,
            transmittance: t,
            noise: Default::default(),
            seed: 0,
        };
        let k = feff_factor(&det, &intr);
        let flux = 2.5e-9; // W/m^2
        let s = flux * intr.aperture_area_m2() * m / (H * C);
        assert!((k * s / flux - 1.0).abs() < 1e-12);
    }
}
