//! The stimulator chain's numeric part (paper Sec. 6.3.1): the rendered signal becomes the
//! effective flux density at the flight camera, `F_eff = k S` with
//! `k = h c / (A_cam max(QE T lambda))` (Eqs. 58-60), and F_eff becomes screen DN through the
//! inverse of the screen's measured calibration curve ([`calibration`]), with optional
//! dithering ([`dither`]) at the screen's DN depth.
//!
//! Layout: [`screen`] maps camera pixels onto screen pixels (collimator geometry);
//! [`Stimulator`] turns one rendered signal image into a full screen of DN codes, reporting
//! clipped pixels and the curve that made it; [`camera::SimulatedCamera`] is the bench's
//! stand-in (screen DN -> the screen's true response -> collimator -> detector);
//! [`calibrate`] measures a curve through any [`calibrate::Bench`]. The GPU does the inversion
//! step again for the screen in [`crate::display`].
//!
//! A camera of several bands looks at a colour screen ([`colour`]): each band's signal gives
//! that band's F_eff (its own `k`), the F_eff planes are mapped onto the screen region band by
//! band, and per pixel the three primaries' F_eff are solved through the cross-talk matrix and
//! inverted through each primary's curve. The screen's DN are then three planes (R, G, B).

pub mod calibrate;
pub mod calibration;
pub mod camera;
pub mod colour;
pub mod dither;
pub mod screen;

use crate::camera::Intrinsics;
use crate::detector::Detector;
use crate::radiometry::{C, H, max_qe_t_lambda};
use calibration::{CalibrationError, ClipCounts, Curve, Interp, Inverse};
use colour::Crosstalk;
use dither::Dither;
use screen::Resampler;
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

/// The `[stimulator]` scene section, validated (`docs/scene.md`).
#[derive(Clone, Debug, PartialEq)]
pub struct StimulatorConfig {
    /// The calibration curve the stimulator inverts (`calibration/README.md`).
    pub calibration: PathBuf,
    pub interp: Interp,
    /// Screen DN depth: 8 or 10 bit.
    pub screen_bits: u32,
    pub dither: Dither,
    /// Whole screen [px].
    pub screen_px: [usize; 2],
    /// Top-left screen pixel of the image region.
    pub origin_px: [usize; 2],
    /// Camera pixels per screen pixel, per axis (`screen` module docs); `[1, 1]` for the
    /// `one_to_one` mapping.
    pub scale: [f64; 2],
    /// Collimator transmittance: the screen emits `F_eff / T` so that the camera gets `F_eff`.
    /// The curves give F_eff behind a lossless collimator; for a curve measured through the
    /// collimator in use, set 1.
    pub collimator_transmittance: f64,
    /// The simulated camera's screen: its true response (the calibration when `None`) and
    /// its non-uniformity, the gain at the region's corners (radial, 1 at the centre).
    pub true_response: Option<PathBuf>,
    pub corner_gain: f64,
    /// A measured non-uniformity map instead of the radial model: a one-band TIFF of the
    /// region's size, each pixel the gain of that screen pixel (integers normalised to their
    /// full scale, floats as they are).
    pub non_uniformity_map: Option<PathBuf>,
}

impl StimulatorConfig {
    pub fn levels(&self) -> u32 {
        1 << self.screen_bits
    }
}

#[derive(Debug, thiserror::Error)]
pub enum StimulatorError {
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    #[error("signal image has {got} pixels, the camera {want}")]
    ImageSize { got: usize, want: usize },
    #[error("calibration: {0}")]
    Measurement(String),
    #[error("screen non-uniformity map {file}: {message}")]
    NonUniformity { file: String, message: String },
    #[error("colour screen: {0}")]
    Colour(String),
}

/// Time per stimulator stage [ms]. With the one-to-one mapping `feff` includes the region
/// (one pass for both) and `resample` is 0.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StimulatorTimings {
    pub feff: f64,
    pub resample: f64,
    pub invert: f64,
}

/// One frame through the stimulator chain.
#[derive(Clone, Debug)]
pub struct StimulatorFrame {
    /// F_eff per camera pixel [W/m^2] (Eq. 58): one plane per camera band, band after band.
    pub feff_w_m2: Vec<f64>,
    /// F_eff the screen region must emit [W/m^2]: mapped onto screen pixels and divided by
    /// the collimator transmittance (what the GPU presenter's LUT pass takes), one plane per
    /// camera band.
    pub region_feff_w_m2: Vec<f64>,
    /// The whole screen in DN codes (`screen_px`, row-major; the image in its region, the
    /// rest at code 0): one plane for a grey screen, three (R, G, B) for a colour one.
    pub screen_dn: Vec<u16>,
    pub clips: ClipCounts,
    /// The curve that made this frame: its id and the SHA-256 of its file.
    pub calibration_id: String,
    pub calibration_sha256: String,
    pub timings_ms: StimulatorTimings,
}

/// What a presenter uploads to turn a frame's region F_eff into screen codes: a grey
/// screen's inverse, or a colour screen's three, its cross-talk and the dither shift
/// ([`Stimulator::drive`]).
#[derive(Clone, Debug)]
pub enum Drive {
    Grey(Inverse),
    Colour {
        inverses: Vec<Inverse>,
        crosstalk: Crosstalk,
        dither_shift: u32,
    },
}

/// The stimulator: F_eff (Eq. 60) -> screen region (collimator mapping) -> DN through the
/// inverse calibration curve. The curve can be replaced between frames ([`Stimulator::replay`]).
pub struct Stimulator {
    config: StimulatorConfig,
    curve: Arc<Curve>,
    /// The inverse of each primary the screen drives (one for a grey screen, R, G, B for a
    /// colour one) at the screen's depth, rebuilt when the curve changes.
    inverses: Vec<Inverse>,
    /// `k` of Eq. 60 per camera band.
    ks: Vec<f64>,
    /// A colour screen's cross-talk with the camera's bands (cameras of several bands).
    colour: Option<Crosstalk>,
    /// The camera's bands (for replayed curves' cross-talk).
    detector: Detector,
    camera_px: [usize; 2],
    resampler: Resampler,
}

impl Stimulator {
    /// Loads the calibration curve named by `config`.
    pub fn new(
        config: &StimulatorConfig,
        intrinsics: &Intrinsics,
        detector: &Detector,
    ) -> Result<Stimulator, StimulatorError> {
        let curve = Curve::load(&config.calibration, config.interp)?;
        Stimulator::with_curve(config, intrinsics, detector, Arc::new(curve))
    }

    /// A camera of one band on a grey screen (a colour curve's first column), or of several
    /// bands on a colour screen whose curve carries the cross-talk with every band.
    pub fn with_curve(
        config: &StimulatorConfig,
        intrinsics: &Intrinsics,
        detector: &Detector,
        curve: Arc<Curve>,
    ) -> Result<Stimulator, StimulatorError> {
        let camera_px = [intrinsics.width_px as usize, intrinsics.height_px as usize];
        let (colour, inverses) = Stimulator::primaries(&curve, detector, config.levels())?;
        Ok(Stimulator {
            config: config.clone(),
            inverses,
            colour,
            curve,
            ks: feff_factors(detector, intrinsics),
            detector: detector.clone(),
            camera_px,
            resampler: Resampler::new(camera_px, config.scale),
        })
    }

    /// What `curve` drives for `detector`'s bands: a grey screen's one inverse, or a colour
    /// screen's cross-talk and three inverses.
    fn primaries(
        curve: &Curve,
        detector: &Detector,
        levels: u32,
    ) -> Result<(Option<Crosstalk>, Vec<Inverse>), StimulatorError> {
        let colour = Crosstalk::of_screen(curve, detector)?;
        let primaries = if colour.is_some() {
            colour::PRIMARIES
        } else {
            1
        };
        let inverses = (0..primaries).map(|c| curve.inverse(c, levels)).collect();
        Ok((colour, inverses))
    }

    pub fn config(&self) -> &StimulatorConfig {
        &self.config
    }

    /// `k` of Eq. 60 for the flight camera [W m^-2 per e-/s] (its first band's).
    pub fn k(&self) -> f64 {
        self.ks[0]
    }

    /// `k` of Eq. 60 of each camera band.
    pub fn ks(&self) -> &[f64] {
        &self.ks
    }

    /// A colour screen's cross-talk with the camera's bands.
    pub fn colour(&self) -> Option<&Crosstalk> {
        self.colour.as_ref()
    }

    pub fn resampler(&self) -> &Resampler {
        &self.resampler
    }

    /// The current curve's inverse at the screen's depth (what the GPU presenter tabulates;
    /// a colour screen's red primary).
    pub fn inverse(&self) -> &Inverse {
        &self.inverses[0]
    }

    /// How far the dither pattern is spread ([`calibration::apply_colour`]): 1 for a Bayer
    /// camera on a colour screen, so that each of its bands sees the whole pattern; else 0.
    pub fn dither_shift(&self) -> u32 {
        match (&self.colour, self.detector.layout) {
            (Some(_), crate::detector::Layout::Bayer(_)) => 1,
            _ => 0,
        }
    }

    /// What a presenter needs to show this stimulator's frames (again after a replay).
    pub fn drive(&self) -> Drive {
        match &self.colour {
            None => Drive::Grey(self.inverses[0].clone()),
            Some(ct) => Drive::Colour {
                inverses: self.inverses.clone(),
                crosstalk: ct.clone(),
                dither_shift: self.dither_shift(),
            },
        }
    }

    /// The inverse of each primary the screen drives: one, or R, G, B.
    pub fn inverses(&self) -> &[Inverse] {
        &self.inverses
    }

    /// The curve in use.
    pub fn curve(&self) -> &Arc<Curve> {
        &self.curve
    }

    /// Replays another curve from the next frame on, without a restart; returns the old one.
    /// Refused (the old curve stays) when a colour camera's curve lacks its cross-talk.
    pub fn replay(&mut self, curve: Arc<Curve>) -> Result<Arc<Curve>, StimulatorError> {
        (self.colour, self.inverses) =
            Stimulator::primaries(&curve, &self.detector, self.config.levels())?;
        Ok(std::mem::replace(&mut self.curve, curve))
    }

    /// One frame: `signal_e_per_s` is the flight camera's signal image (row-major).
    pub fn process(&self, signal_e_per_s: &[f64]) -> Result<StimulatorFrame, StimulatorError> {
        let mut frame = self.region(signal_e_per_s)?;
        self.invert(&mut frame);
        Ok(frame)
    }

    /// The CPU inversion of a prepared frame: fills `screen_dn` and the clip counts.
    pub fn invert(&self, frame: &mut StimulatorFrame) {
        let t0 = Instant::now();
        let [rw, rh] = self.resampler.region_px();
        let mut region = Vec::new();
        frame.clips = match &self.colour {
            None => {
                self.inverses[0].apply(&frame.region_feff_w_m2, rw, self.config.dither, &mut region)
            }
            Some(ct) => calibration::apply_colour(
                ct,
                &self.inverses,
                &frame.region_feff_w_m2,
                rw,
                (self.config.dither, self.dither_shift()),
                &mut region,
            ),
        };
        let [sw, sh] = self.config.screen_px;
        let [ox, oy] = self.config.origin_px;
        let planes = self.inverses.len();
        frame.screen_dn = vec![0u16; sw * sh * planes];
        for (c, plane) in region.chunks(rw * rh).enumerate() {
            for (r, row) in plane.chunks(rw).enumerate() {
                let dst = c * sw * sh + (oy + r) * sw + ox;
                frame.screen_dn[dst..dst + rw].copy_from_slice(row);
            }
        }
        frame.timings_ms.invert = ms(t0);
    }

    /// One frame up to the screen region's F_eff, for a presenter that inverts on the GPU:
    /// `screen_dn` is empty; the clip counts are those the inversion will meet.
    pub fn prepare(&self, signal_e_per_s: &[f64]) -> Result<StimulatorFrame, StimulatorError> {
        let mut frame = self.region(signal_e_per_s)?;
        let t0 = Instant::now();
        frame.clips = match &self.colour {
            None => self.inverses[0].count_clips(&frame.region_feff_w_m2),
            Some(ct) => {
                calibration::count_colour_clips(ct, &self.inverses, &frame.region_feff_w_m2)
            }
        };
        frame.timings_ms.invert = ms(t0);
        Ok(frame)
    }

    /// F_eff (Eq. 58) and the region's F_eff, divided by the collimator transmittance, band
    /// after band.
    fn region(&self, signal_e_per_s: &[f64]) -> Result<StimulatorFrame, StimulatorError> {
        let n = self.camera_px[0] * self.camera_px[1];
        let want = n * self.ks.len();
        if signal_e_per_s.len() != want {
            return Err(StimulatorError::ImageSize {
                got: signal_e_per_s.len(),
                want,
            });
        }
        let mut t = StimulatorTimings::default();
        let t0 = Instant::now();
        // The screen emits F_eff / T so that the camera, behind the collimator, gets F_eff.
        let gain = 1.0 / self.config.collimator_transmittance;
        let (mut feff_w_m2, mut region_feff_w_m2) = (Vec::new(), Vec::new());
        if self.resampler.is_identity() {
            // One to one: the region is F_eff / T. Band after band, appended in parallel.
            use rayon::prelude::*;
            feff_w_m2.reserve(want);
            region_feff_w_m2.reserve(want);
            for (s, &k) in signal_e_per_s.chunks(n.max(1)).zip(&self.ks) {
                feff_w_m2.par_extend(s.par_iter().map(|s| s * k));
                region_feff_w_m2.par_extend(s.par_iter().map(|s| s * k * gain));
            }
            t.feff = ms(t0);
        } else {
            use rayon::prelude::*;
            feff_w_m2.reserve(want);
            for (s, &k) in signal_e_per_s.chunks(n.max(1)).zip(&self.ks) {
                feff_w_m2.par_extend(s.par_iter().map(|s| s * k));
            }
            t.feff = ms(t0);
            let t0 = Instant::now();
            let mut plane = Vec::new();
            for f in feff_w_m2.chunks(n.max(1)) {
                self.resampler.to_screen(f, gain, &mut plane);
                region_feff_w_m2.extend_from_slice(&plane);
            }
            t.resample = ms(t0);
        }
        Ok(StimulatorFrame {
            feff_w_m2,
            region_feff_w_m2,
            screen_dn: Vec::new(),
            clips: ClipCounts::default(),
            calibration_id: self.curve.id.clone(),
            calibration_sha256: self.curve.sha256.clone(),
            timings_ms: t,
        })
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// `k` of Eq. 60 [W m^-2 per e-/s], `h c / (A_cam max(QE T lambda))`, of each of the camera's
/// bands, with that band's QE and transmittance: each band's F_eff is the flux at its own
/// peak of `QE T lambda` that gives its signal.
pub fn feff_factors(detector: &Detector, intrinsics: &Intrinsics) -> Vec<f64> {
    let area = intrinsics.aperture_area_m2();
    detector
        .bands
        .iter()
        .map(|b| H * C / (area * max_qe_t_lambda(&b.qe, &b.transmittance)))
        .collect()
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
            saved_bits: 12,
            bands: vec![crate::detector::Band {
                name: "mono".into(),
                qe,
                transmittance: t,
                psf_sigma_px: None,
                distortion: None,
            }],
            layout: Default::default(),
            psf_sigma_px: 0.0,
            noise: Default::default(),
            seed: 0,
        };
        let k = feff_factors(&det, &intr)[0];
        let flux = 2.5e-9; // W/m^2
        let s = flux * intr.aperture_area_m2() * m / (H * C);
        assert!((k * s / flux - 1.0).abs() < 1e-12);
    }
}
