//! Measuring a screen calibration curve: step the screen through a ramp of uniform frames,
//! read the camera's mean response over a central region, convert it back to F_eff
//! (`F = k (DN - offset) / (G_AD t)`, Eqs. 47 and 58), and write the curve in the CSV format of
//! `calibration/README.md`. Points half-way between the ramp's codes are measured too and
//! reported as residuals against the fitted (interpolated) curve.
//!
//! A colour screen before a camera of several bands is stepped one primary at a time (the
//! others at code 0), each band's F_eff read with its own `k`. Over a primary's ramp the
//! bands' F_eff above the dark frame grow in fixed proportions ([`super::colour`]): their
//! least-squares ratios to the band that primary excites most are its column of the
//! cross-talk matrix, and that band's F_eff is its curve. The dark frame (all primaries at 0)
//! is shared out among the primaries through the same matrix.
//!
//! The bench is a trait: [`SimulatedBench`] here, a real screen and camera later.

use super::StimulatorError;
use super::calibration::{Curve, Interp};
use super::camera::SimulatedCamera;
use super::colour::{Crosstalk, PRIMARIES};
use crate::detector::Detector;
use crate::detector::Layout;
use serde::Serialize;

/// A screen and a camera looking at it.
pub trait Bench {
    /// The screen [px].
    fn screen_px(&self) -> [usize; 2];
    /// The camera's frame [px].
    fn camera_px(&self) -> [usize; 2];
    /// The camera's detector: gain, offset and bit depth turn its DN back into electrons; its
    /// bands and layout say which pixels see which band.
    fn detector(&self) -> &Detector;
    /// `k` of Eq. 60 of each of the camera's bands [W m^-2 per e-/s].
    fn ks(&self) -> Vec<f64>;
    /// The screen's primaries: 1 (grey) or 3 (R, G, B).
    fn primaries(&self) -> usize;
    /// Shows a whole screen of DN codes (a colour screen's three planes one after the other)
    /// and returns the camera's image [DN] taken with `exposure_s`.
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
    fn ks(&self) -> Vec<f64> {
        self.camera.ks().to_vec()
    }
    fn primaries(&self) -> usize {
        self.camera.primaries()
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
    /// The primary stepped (0 on a grey screen; 0, 1, 2 for R, G, B).
    pub primary: usize,
    pub code: u32,
    /// The primary's F_eff at this code (the curve's value) [W/m^2].
    pub feff_w_m2: f64,
    pub exposure_s: f64,
    /// The camera's mean over the central quarter [DN] (of the band the primary excites most).
    pub mean_dn: f64,
}

/// A half-way code: measured against the curve through the ramp's points.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Residual {
    pub primary: usize,
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
    /// A colour screen's measured cross-talk: per camera band, its F_eff per unit of each
    /// primary's (empty for a grey screen).
    pub crosstalk: Vec<(String, [f64; PRIMARIES])>,
    /// The curve file's text.
    #[serde(skip)]
    pub csv: String,
}

/// What to write in the curve's provenance header.
pub struct Provenance<'a> {
    pub date: &'a str,
    pub facility: &'a str,
}

/// One uniform frame as the camera saw it.
#[derive(Clone)]
struct Reading {
    /// Each band's F_eff [W/m^2].
    feff_w_m2: Vec<f64>,
    exposure_s: f64,
    mean_dn: Vec<f64>,
}

/// Measures `steps` codes spread over `levels` (and the codes half-way between them), for
/// each primary of a colour screen.
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
    let primaries = bench.primaries();
    let top = levels - 1;
    // Quadratic spacing: screens respond with a gamma-like curve that bends most near the
    // dark end, so the codes crowd there (uniform spacing at 33 of 1024 codes left a 5 %
    // residual at code 16 on the example curve).
    let mut codes: Vec<u32> = (0..steps)
        .map(|i| ((i as f64 / (steps - 1) as f64).powi(2) * top as f64).round() as u32)
        .collect();
    codes.dedup();
    // Each primary's readings along the ramp (code 0: the dark frame, shared).
    let dark = measure(bench, primaries, 0, 0)?;
    let mut ramps: Vec<Vec<Reading>> = Vec::with_capacity(primaries);
    for c in 0..primaries {
        let mut ramp = Vec::with_capacity(codes.len());
        for &code in &codes {
            ramp.push(if code == 0 {
                dark.clone()
            } else {
                measure(bench, primaries, c, code)?
            });
        }
        ramps.push(ramp);
    }
    let model = Model::fit(&dark, &ramps)?;
    let mut points = Vec::new();
    for (c, ramp) in ramps.iter().enumerate() {
        for (&code, r) in codes.iter().zip(ramp) {
            points.push(Point {
                primary: c,
                code,
                feff_w_m2: model.primary_feff(c, r, &dark),
                exposure_s: r.exposure_s,
                mean_dn: r.mean_dn[model.dominant[c]],
            });
        }
    }
    let names = ["r", "g", "b"];
    let columns = if primaries == 1 {
        "feff_w_m2".to_string()
    } else {
        (0..primaries)
            .map(|c| format!("feff_{}_w_m2", names[c]))
            .collect::<Vec<_>>()
            .join(",")
    };
    let mut csv = format!(
        "# optistim screen calibration v1\n# date: {}\n# facility: {}\n# method: uniform \
         full-screen frames at {n} codes of {levels} (quadratic spacing){per}, camera mean over the central quarter \
         of its frame, exposure adapted per code to 10-80 % of full scale, F_eff = k (DN - \
         offset) / (G_AD t){xt}\n# dn_full_scale: {top}\n",
        provenance.date,
        provenance.facility,
        n = codes.len(),
        per = if primaries > 1 {
            ", one primary at a time"
        } else {
            ""
        },
        xt = if primaries > 1 {
            " per band; cross-talk: least-squares ratio of each band's F_eff above the dark \
             frame to the band the primary excites most"
        } else {
            ""
        },
    );
    let bands: Vec<String> = bench
        .detector()
        .bands
        .iter()
        .map(|b| b.name.clone())
        .collect();
    let crosstalk: Vec<(String, [f64; PRIMARIES])> = match &model.crosstalk {
        Some(ct) => bands.iter().cloned().zip(ct.x.iter().copied()).collect(),
        None => Vec::new(),
    };
    for (band, row) in &crosstalk {
        csv.push_str(&format!(
            "# crosstalk {band}: {:.6}, {:.6}, {:.6}\n",
            row[0], row[1], row[2]
        ));
    }
    csv.push_str(&format!("dn,{columns}\n"));
    for (k, &code) in codes.iter().enumerate() {
        csv.push_str(&code.to_string());
        for c in 0..primaries {
            csv.push_str(&format!(",{:.9e}", points[c * codes.len() + k].feff_w_m2));
        }
        csv.push('\n');
    }
    // The curve's own validation refuses a response that does not rise, naming the line.
    let curve = Curve::parse(csv.as_bytes(), "measured", "<measured curve>", interp)?;
    let mut residuals = Vec::new();
    for c in 0..primaries {
        for w in codes.windows(2) {
            let mid = (w[0] + w[1]) / 2;
            if mid == w[0] {
                continue;
            }
            let m = model.primary_feff(c, &measure(bench, primaries, c, mid)?, &dark);
            let f = curve.feff_at(c, mid as f64);
            residuals.push(Residual {
                primary: c,
                code: mid,
                measured_w_m2: m,
                curve_w_m2: f,
                relative: f / m - 1.0,
            });
        }
    }
    let max_abs_residual = residuals
        .iter()
        .map(|r| r.relative.abs())
        .fold(0.0, f64::max);
    Ok(CalibrationRun {
        points,
        residuals,
        max_abs_residual,
        crosstalk,
        csv,
    })
}

/// What the ramps say about the screen: each primary's band, the cross-talk and the share
/// of the dark frame each primary emits.
struct Model {
    /// The band each primary excites most.
    dominant: Vec<usize>,
    crosstalk: Option<Crosstalk>,
    /// Each primary's F_eff at code 0 [W/m^2].
    dark_w_m2: Vec<f64>,
}

impl Model {
    fn fit(dark: &Reading, ramps: &[Vec<Reading>]) -> Result<Model, StimulatorError> {
        if ramps.len() == 1 {
            return Ok(Model {
                dominant: vec![0],
                crosstalk: None,
                dark_w_m2: vec![dark.feff_w_m2[0]],
            });
        }
        let bands = dark.feff_w_m2.len();
        let above = |r: &Reading, b: usize| r.feff_w_m2[b] - dark.feff_w_m2[b];
        let dominant: Vec<usize> = ramps
            .iter()
            .map(|ramp| {
                let last = ramp.last().expect("four codes or more");
                (0..bands)
                    .max_by(|&a, &b| above(last, a).total_cmp(&above(last, b)))
                    .unwrap_or(0)
            })
            .collect();
        let mut x = vec![[0.0; PRIMARIES]; bands];
        for (c, ramp) in ramps.iter().enumerate() {
            let d = dominant[c];
            let norm: f64 = ramp.iter().map(|r| above(r, d).powi(2)).sum();
            for (b, row) in x.iter_mut().enumerate() {
                let dot: f64 = ramp.iter().map(|r| above(r, b) * above(r, d)).sum();
                // Cross-talk is light: a band reading less than the dark frame reads none.
                row[c] = (dot / norm).max(0.0);
            }
        }
        let crosstalk = Crosstalk::new(x).map_err(StimulatorError::Measurement)?;
        let dark_w_m2 = crosstalk
            .primaries(|b| dark.feff_w_m2[b])
            .iter()
            .map(|f| f.max(0.0))
            .collect();
        Ok(Model {
            dominant,
            crosstalk: Some(crosstalk),
            dark_w_m2,
        })
    }

    /// Primary `c`'s F_eff in a reading of a frame where it alone is lit: its dark level plus
    /// what its band reads above the dark frame.
    fn primary_feff(&self, c: usize, r: &Reading, dark: &Reading) -> f64 {
        match self.crosstalk {
            None => r.feff_w_m2[0],
            Some(_) => {
                let d = self.dominant[c];
                self.dark_w_m2[c] + r.feff_w_m2[d] - dark.feff_w_m2[d]
            }
        }
    }
}

/// One frame: primary `lit` at `code`, the others at 0; the camera's mean of each band over
/// the central quarter, the exposure adapted until the brightest band sits in 10-80 % of the
/// ADC range.
fn measure(
    bench: &mut dyn Bench,
    primaries: usize,
    lit: usize,
    code: u32,
) -> Result<Reading, StimulatorError> {
    let [sw, sh] = bench.screen_px();
    let mut frame = vec![0u16; sw * sh * primaries];
    frame[lit * sw * sh..(lit + 1) * sw * sh].fill(code as u16);
    let det = bench.detector().clone();
    let ks = bench.ks();
    let span = det
        .adc_max_dn()
        .min(det.full_well_e * det.adc_gain_dn_per_e + det.offset_dn)
        - det.offset_dn;
    let mut exposure = det.exposure_s;
    for _ in 0..12 {
        let dn = bench.show_and_capture(&frame, exposure)?;
        // Back to ADC units: a camera saving fewer bits hands out its most significant ones.
        let means: Vec<f64> = central_means(&dn, bench.camera_px(), &det)
            .iter()
            .map(|m| m * det.saved_dn_step())
            .collect();
        let fill = means
            .iter()
            .fold(0.0f64, |a, &m| a.max((m - det.offset_dn) / span));
        if (0.1..=0.8).contains(&fill) {
            let feff_w_m2 = means
                .iter()
                .zip(&ks)
                .map(|(m, k)| k * (m - det.offset_dn) / det.adc_gain_dn_per_e / exposure)
                .collect();
            return Ok(Reading {
                feff_w_m2,
                exposure_s: exposure,
                mean_dn: means,
            });
        }
        // Aim at 40 %; a dark or saturated reading moves by a factor of 100 at most.
        exposure *= (0.4 / fill.max(1e-4)).clamp(0.01, 100.0);
    }
    Err(StimulatorError::Measurement(format!(
        "primary {lit} code {code}: no exposure put the camera's mean in 10-80 % of its range"
    )))
}

/// Each band's mean DN over the central quarter (half the width, half the height) of the
/// camera frame: its own plane, or its pixels of the Bayer mosaic.
fn central_means(dn: &[u16], [w, h]: [usize; 2], det: &Detector) -> Vec<f64> {
    let (x0, x1) = (w / 4, (w - w / 4).max(w / 4 + 1).min(w));
    let (y0, y1) = (h / 4, (h - h / 4).max(h / 4 + 1).min(h));
    let bands = det.bands.len();
    let (mut sum, mut count) = (vec![0.0; bands], vec![0usize; bands]);
    for y in y0..y1 {
        for x in x0..x1 {
            match det.layout {
                Layout::Planes => {
                    for b in 0..bands {
                        sum[b] += dn[b * w * h + y * w + x] as f64;
                        count[b] += 1;
                    }
                }
                Layout::Bayer(order) => {
                    let b = order.band_at(x, y);
                    sum[b] += dn[y * w + x] as f64;
                    count[b] += 1;
                }
            }
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &n)| s / n.max(1) as f64)
        .collect()
}
