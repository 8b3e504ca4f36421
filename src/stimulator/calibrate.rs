//! Measuring a screen calibration curve: step the screen through a ramp of uniform frames,
//! read the camera's mean response over a central region, convert it back to F_eff
//! (`F = k (DN - offset) / (G_AD t)`, Eqs. 47 and 58), and write the curve in the CSV format of
//! `calibration/README.md`. Points half-way between the ramp's codes are measured too and
//! reported as residuals against the fitted (interpolated) curve.
//!
//! The bench is a trait: [`SimulatedBench`] here, a real screen and camera later.

use super::StimulatorError;
use super::calibration::{Curve, Interp};
use super::camera::SimulatedCamera;
use crate::detector::Detector;
use serde::Serialize;

/// A screen and a camera looking at it.
pub trait Bench {
    /// The screen [px].
    fn screen_px(&self) -> [usize; 2];
    /// The camera's frame [px].
    fn camera_px(&self) -> [usize; 2];
    /// The camera's detector: gain, offset and bit depth turn its DN back into electrons.
    fn detector(&self) -> &Detector;
    /// `k` of Eq. 60 for the camera [W m^-2 per e-/s].
    fn k(&self) -> f64;
    /// Shows a whole screen of DN codes and returns the camera's image [DN] taken with
    /// `exposure_s`.
    fn show_and_capture(
        &mut self,
        screen_dn: &[u16],
        exposure_s: f64,
    ) -> Result<Vec<u16>, StimulatorError>;
}

/// The simulated camera as a bench.
pub struct SimulatedBench {
    pub camera: SimulatedCamera,
    pub screen_px: [usize; 2],
    frame: u64,
}

impl SimulatedBench {
    pub fn new(camera: SimulatedCamera, screen_px: [usize; 2]) -> SimulatedBench {
        SimulatedBench {
            camera,
            screen_px,
            frame: 0,
        }
    }
}

impl Bench for SimulatedBench {
    fn screen_px(&self) -> [usize; 2] {
        self.screen_px
    }
    fn camera_px(&self) -> [usize; 2] {
        self.camera.camera_px()
    }
    fn detector(&self) -> &Detector {
        self.camera.detector()
    }
    fn k(&self) -> f64 {
        self.camera.k()
    }
    fn show_and_capture(
        &mut self,
        screen_dn: &[u16],
        exposure_s: f64,
    ) -> Result<Vec<u16>, StimulatorError> {
        self.camera.detector_mut().exposure_s = exposure_s;
        self.frame += 1;
        Ok(self.camera.capture(screen_dn, self.frame)?.dn)
    }
}

/// One measured code.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Point {
    pub code: u32,
    pub feff_w_m2: f64,
    pub exposure_s: f64,
    pub mean_dn: f64,
}

/// A half-way code: measured against the curve through the ramp's points.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Residual {
    pub code: u32,
    pub measured_w_m2: f64,
    pub curve_w_m2: f64,
    /// `curve / measured - 1`.
    pub relative: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct CalibrationRun {
    pub points: Vec<Point>,
    pub residuals: Vec<Residual>,
    pub max_abs_residual: f64,
    /// The curve file's text.
    #[serde(skip)]
    pub csv: String,
}

/// What to write in the curve's provenance header.
pub struct Provenance<'a> {
    pub date: &'a str,
    pub facility: &'a str,
}

/// Measures `steps` codes spread over `levels` (and the codes half-way between them).
pub fn calibrate(
    bench: &mut dyn Bench,
    levels: u32,
    steps: usize,
    interp: Interp,
    provenance: Provenance,
) -> Result<CalibrationRun, StimulatorError> {
    if steps < 4 || steps > levels as usize / 4 {
        return Err(StimulatorError::Measurement(format!(
            "{steps} steps: need 4 to {}",
            levels / 4
        )));
    }
    let top = levels - 1;
    // Quadratic spacing: screens respond with a gamma-like curve that bends most near the
    // dark end, so the codes crowd there (uniform spacing at 33 of 1024 codes left a 5 %
    // residual at code 16 on the example curve).
    let mut codes: Vec<u32> = (0..steps)
        .map(|i| ((i as f64 / (steps - 1) as f64).powi(2) * top as f64).round() as u32)
        .collect();
    codes.dedup();
    let mut points = Vec::with_capacity(steps);
    for &c in &codes {
        points.push(measure(bench, c)?);
    }
    let mut csv = format!(
        "# optistim screen calibration v1\n# date: {}\n# facility: {}\n# method: uniform \
         full-screen frames at {n} codes of {levels} (quadratic spacing), camera mean over the central quarter \
         of its frame, exposure adapted per code to 10-80 % of full scale, F_eff = k (DN - \
         offset) / (G_AD t)\n# dn_full_scale: {top}\ndn,feff_w_m2\n",
        provenance.date,
        provenance.facility,
        n = codes.len()
    );
    for p in &points {
        csv.push_str(&format!("{},{:.9e}\n", p.code, p.feff_w_m2));
    }
    // The curve's own validation refuses a response that does not rise, naming the line.
    let curve = Curve::parse(csv.as_bytes(), "measured", "<measured curve>", interp)?;
    let mut residuals = Vec::new();
    for w in codes.windows(2) {
        let mid = (w[0] + w[1]) / 2;
        if mid == w[0] {
            continue;
        }
        let m = measure(bench, mid)?;
        let c = curve.feff_at(0, mid as f64);
        residuals.push(Residual {
            code: mid,
            measured_w_m2: m.feff_w_m2,
            curve_w_m2: c,
            relative: c / m.feff_w_m2 - 1.0,
        });
    }
    let max_abs_residual = residuals
        .iter()
        .map(|r| r.relative.abs())
        .fold(0.0, f64::max);
    Ok(CalibrationRun {
        points,
        residuals,
        max_abs_residual,
        csv,
    })
}

/// One code: a uniform frame, the camera's mean over the central quarter, the exposure
/// adapted until that mean sits in 10-80 % of the ADC range.
fn measure(bench: &mut dyn Bench, code: u32) -> Result<Point, StimulatorError> {
    let [sw, sh] = bench.screen_px();
    let frame = vec![code as u16; sw * sh];
    let det = bench.detector().clone();
    let span = det
        .adc_max_dn()
        .min(det.full_well_e * det.adc_gain_dn_per_e + det.offset_dn)
        - det.offset_dn;
    let mut exposure = det.exposure_s;
    for _ in 0..12 {
        let dn = bench.show_and_capture(&frame, exposure)?;
        // Back to ADC units: a camera saving fewer bits hands out its most significant ones.
        let mean = central_mean(&dn, bench.camera_px()) * det.saved_dn_step();
        let fill = (mean - det.offset_dn) / span;
        if (0.1..=0.8).contains(&fill) {
            let electrons = (mean - det.offset_dn) / det.adc_gain_dn_per_e;
            return Ok(Point {
                code,
                feff_w_m2: bench.k() * electrons / exposure,
                exposure_s: exposure,
                mean_dn: mean,
            });
        }
        // Aim at 40 %; a dark or saturated reading moves by a factor of 100 at most.
        exposure *= (0.4 / fill.max(1e-4)).clamp(0.01, 100.0);
    }
    Err(StimulatorError::Measurement(format!(
        "code {code}: no exposure put the camera's mean in 10-80 % of its range"
    )))
}

/// Mean DN over the central quarter (half the width, half the height) of the camera frame.
fn central_mean(dn: &[u16], [w, h]: [usize; 2]) -> f64 {
    let (x0, x1) = (w / 4, (w - w / 4).max(w / 4 + 1).min(w));
    let (y0, y1) = (h / 4, (h - h / 4).max(h / 4 + 1).min(h));
    let mut sum = 0.0;
    for y in y0..y1 {
        sum += dn[y * w + x0..y * w + x1]
            .iter()
            .map(|&v| v as f64)
            .sum::<f64>();
    }
    sum / ((x1 - x0) * (y1 - y0)) as f64
}
