//! The simulated camera, the bench hardware's stand-in: screen DN -> F_eff emitted through the
//! screen's *true* response (which may differ from the loaded calibration, to simulate
//! mis-calibration), times a non-uniformity gain and the collimator transmittance -> the
//! collimator's mapping of screen pixels onto camera pixels -> signal `S = F_eff / k`
//! (Eq. 58, the screen taken to emit at the wavelength that defines F_eff) -> the same
//! detector model as the renderer (exposure, noise, full well, ADC).
//!
//! A camera of several bands looks at a colour screen: each band gets `F_b = sum_c X[b][c]
//! f_c` of the primaries' emitted F_eff through the screen's *true* cross-talk matrix
//! ([`super::colour`]), its signal is `F_b / k_b` with its own band's `k`, and the detector
//! hands out its planes or its Bayer mosaic as the renderer's camera does.

use super::calibration::Curve;
use super::colour::{Crosstalk, PRIMARIES};
use super::screen::Resampler;
use super::{StimulatorConfig, StimulatorError, feff_factors};
use crate::camera::Intrinsics;
use crate::detector::Detector;

/// What the simulated camera saw.
#[derive(Clone, Debug)]
pub struct Capture {
    /// F_eff reaching each camera pixel [W/m^2], one plane per band.
    pub feff_w_m2: Vec<f64>,
    /// Signal [e-/s], one plane per band.
    pub signal_e_per_s: Vec<f64>,
    /// The camera's image [DN]: one plane per band, or the Bayer mosaic.
    pub dn: Vec<u16>,
}

pub struct SimulatedCamera {
    /// F_eff each primary of the screen emits at each code (its true response, sampled once):
    /// one table for a grey screen, R, G, B for a colour one.
    emitted_per_code: Vec<Vec<f64>>,
    /// A colour screen's true cross-talk with the camera's bands.
    colour: Option<Crosstalk>,
    camera_px: [usize; 2],
    screen_px: [usize; 2],
    origin_px: [usize; 2],
    resampler: Resampler,
    /// Per region pixel: non-uniformity gain times collimator transmittance.
    gain: Vec<f64>,
    detector: Detector,
    /// `k` of Eq. 60 per band.
    ks: Vec<f64>,
}

impl SimulatedCamera {
    /// The camera of `intrinsics` and `detector` looking at the screen of `config` whose true
    /// response is `true_response` (with, for a camera of several bands, its true cross-talk).
    pub fn new(
        config: &StimulatorConfig,
        true_response: Curve,
        intrinsics: &Intrinsics,
        detector: &Detector,
    ) -> Result<SimulatedCamera, StimulatorError> {
        let colour = Crosstalk::of_screen(&true_response, detector)?;
        let camera_px = [intrinsics.width_px as usize, intrinsics.height_px as usize];
        let resampler = Resampler::new(camera_px, config.scale);
        let [rw, rh] = resampler.region_px();
        // Radial falloff: 1 at the region's centre, `corner_gain` at its corners.
        let (cx, cy) = (0.5 * rw as f64, 0.5 * rh as f64);
        let r2_corner = cx * cx + cy * cy;
        let gain = (0..rw * rh)
            .map(|p| {
                let (x, y) = ((p % rw) as f64 + 0.5 - cx, (p / rw) as f64 + 0.5 - cy);
                let r2 = (x * x + y * y) / r2_corner;
                (1.0 - (1.0 - config.corner_gain) * r2) * config.collimator_transmittance
            })
            .collect();
        let primaries = if colour.is_some() { PRIMARIES } else { 1 };
        Ok(SimulatedCamera {
            emitted_per_code: (0..primaries)
                .map(|c| emitted_per_code(&true_response, c, config.levels()))
                .collect(),
            colour,
            camera_px,
            screen_px: config.screen_px,
            origin_px: config.origin_px,
            resampler,
            gain,
            detector: detector.clone(),
            ks: feff_factors(detector, intrinsics),
        })
    }

    /// Loads the true response named by `config` (the calibration when none is named).
    pub fn from_config(
        config: &StimulatorConfig,
        intrinsics: &Intrinsics,
        detector: &Detector,
    ) -> Result<SimulatedCamera, StimulatorError> {
        let path = config.true_response.as_ref().unwrap_or(&config.calibration);
        let curve = Curve::load(path, config.interp)?;
        let mut camera = SimulatedCamera::new(config, curve, intrinsics, detector)?;
        if let Some(file) = &config.non_uniformity_map {
            let bad = |message: String| StimulatorError::NonUniformity {
                file: file.display().to_string(),
                message,
            };
            let map = crate::body::maps::Map::load(file, &Default::default())
                .map_err(|e| bad(e.to_string()))?;
            let region = camera.resampler.region_px();
            if [map.width, map.height] != region {
                return Err(bad(format!(
                    "{} x {} px; the screen region is {} x {}",
                    map.width, map.height, region[0], region[1]
                )));
            }
            let gain: Vec<f64> = map.values.iter().map(|&g| g as f64).collect();
            camera.set_non_uniformity(&gain, config.collimator_transmittance);
        }
        Ok(camera)
    }

    /// Replaces the per-region-pixel non-uniformity map (gains, row-major, region size).
    pub fn set_non_uniformity(&mut self, gain: &[f64], collimator_transmittance: f64) {
        self.gain = gain.iter().map(|g| g * collimator_transmittance).collect();
    }

    pub fn camera_px(&self) -> [usize; 2] {
        self.camera_px
    }

    pub fn detector(&self) -> &Detector {
        &self.detector
    }

    pub fn detector_mut(&mut self) -> &mut Detector {
        &mut self.detector
    }

    /// `k` of Eq. 60 of each of this camera's bands.
    pub fn ks(&self) -> &[f64] {
        &self.ks
    }

    /// The screen's primaries: 1 (grey) or 3 (R, G, B).
    pub fn primaries(&self) -> usize {
        self.emitted_per_code.len()
    }

    /// Images a whole screen of DN codes (`screen_px`, row-major; a colour screen's three
    /// planes R, G, B one after the other).
    pub fn capture(&self, screen_dn: &[u16], frame_id: u64) -> Result<Capture, StimulatorError> {
        self.capture_exposed(screen_dn, frame_id, None)
    }

    /// As [`SimulatedCamera::capture`], with this frame's exposure [s] instead of the
    /// detector's when given.
    pub fn capture_exposed(
        &self,
        screen_dn: &[u16],
        frame_id: u64,
        exposure_s: Option<f64>,
    ) -> Result<Capture, StimulatorError> {
        let [sw, sh] = self.screen_px;
        let primaries = self.emitted_per_code.len();
        if screen_dn.len() != sw * sh * primaries {
            return Err(StimulatorError::ImageSize {
                got: screen_dn.len(),
                want: sw * sh * primaries,
            });
        }
        let [rw, rh] = self.resampler.region_px();
        let [ox, oy] = self.origin_px;
        let tables = &self.emitted_per_code;
        // F_eff emitted by each primary at each region pixel, the non-uniformity applied.
        let emitted: Vec<Vec<f64>> = (0..primaries)
            .map(|c| {
                let table = &tables[c];
                let plane = &screen_dn[c * sw * sh..(c + 1) * sw * sh];
                let mut out = Vec::with_capacity(rw * rh);
                for r in 0..rh {
                    if r % 64 == 0 {
                        crate::background::checkpoint();
                    }
                    let row = &plane[(oy + r) * sw + ox..(oy + r) * sw + ox + rw];
                    for (i, &code) in row.iter().enumerate() {
                        let f = table[(code as usize).min(table.len() - 1)];
                        out.push(f * self.gain[r * rw + i]);
                    }
                }
                out
            })
            .collect();
        // Each band's F_eff on the camera grid: through the cross-talk for a colour screen.
        let n = self.camera_px[0] * self.camera_px[1];
        let mut feff_w_m2 = Vec::with_capacity(n * self.ks.len());
        let mut band_region = Vec::new();
        let mut plane = Vec::new();
        for b in 0..self.ks.len() {
            let region = match &self.colour {
                None => &emitted[0],
                Some(ct) => {
                    band_region.clear();
                    band_region.extend(
                        (0..rw * rh)
                            .map(|p| ct.band(b, &[emitted[0][p], emitted[1][p], emitted[2][p]])),
                    );
                    &band_region
                }
            };
            self.resampler.to_camera(region, &mut plane);
            feff_w_m2.extend_from_slice(&plane);
        }
        crate::background::checkpoint();
        let signal_e_per_s: Vec<f64> = (feff_w_m2.chunks(n.max(1)).zip(&self.ks))
            .flat_map(|(plane, k)| plane.iter().map(move |f| f / k))
            .collect();
        let size = (self.camera_px[0], self.camera_px[1]);
        let mut detector = std::borrow::Cow::Borrowed(&self.detector);
        if let Some(t) = exposure_s {
            detector.to_mut().exposure_s = t;
        }
        let mut dn = Vec::new();
        detector.expose_bands(&signal_e_per_s, size, frame_id, &mut dn);
        Ok(Capture {
            feff_w_m2,
            signal_e_per_s,
            dn,
        })
    }
}

/// F_eff primary `channel` of a screen with response `curve` emits at each of its `levels`
/// codes.
fn emitted_per_code(curve: &Curve, channel: usize, levels: u32) -> Vec<f64> {
    let top = (levels - 1) as f64;
    (0..levels)
        .map(|c| curve.feff_at(channel, c as f64 / top * curve.dn_full_scale))
        .collect()
}
