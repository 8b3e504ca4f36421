//! The detector: (P/L) per pixel -> signal S [e-/s] (Eq. 45) -> electrons with noises, capped
//! at the full well (Eq. 46) -> digital numbers (Eq. 47).
//!
//! A camera has one or more [`Band`]s, each with its own QE and transmittance, hence its own
//! factor of Eq. 45 (the paper's Sec. 4.9: "for a multi-channel image, if (P/L) is
//! spectral-independent, the values in each channel can be obtained simply by computing the
//! correct spectral integral along the corresponding waveband"): the geometry is rendered
//! once and every band is a multiplication. How the bands reach the pixels is the
//! [`Layout`]: a full image per band (three-chip cameras, filter wheels), or a Bayer mosaic
//! whose every pixel records its own band. The camera hands out what the sensor records: a
//! mosaic stays a mosaic (no demosaicing).

pub mod noise;
pub mod psf;

use crate::radiometry::{Reflectance, SpectralTable, SunSpectrum};
use noise::{Noise, Stream, rng};
use rayon::prelude::*;

/// One waveband of a camera (`[[camera.band]]`; a camera with one `qe` curve has one band).
#[derive(Clone, Debug, PartialEq)]
pub struct Band {
    /// Its name in headers and files (`"R"`, `"G"`, `"B"`, `"F550"`, ...).
    pub name: String,
    pub qe: SpectralTable,
    pub transmittance: SpectralTable,
    /// Longitudinal chromatic aberration (Sec. 6.1.2): the band's own Gaussian PSF [px],
    /// replacing the camera's `psf_sigma_px` on the camera's own images.
    pub psf_sigma_px: Option<f64>,
    /// Lateral chromatic aberration (Sec. 6.1.2): the band's own Brown coefficients (Eq. 39),
    /// replacing the camera's in the projection before gridding.
    pub distortion: Option<crate::camera::Brown>,
}

impl Band {
    /// The band's wavelengths [m]: where its response `QE T` is at least half its peak (the
    /// full width at half maximum; a flat band's whole range), found on 4000 steps over
    /// where both curves are tabulated, the edges interpolated. The range of its plane of
    /// `power.fits` and of its `BANDkLO` / `BANDkHI` header cards.
    pub fn range_m(&self) -> (f64, f64) {
        let (lo, hi) = self.support_m();
        let n = 4000;
        let at = |k: usize| lo + (hi - lo) * k as f64 / n as f64;
        let r = |l: f64| self.qe.at(l) * self.transmittance.at(l);
        let peak = (0..=n).map(|k| r(at(k))).fold(0.0, f64::max);
        if peak <= 0.0 {
            return (lo, hi);
        }
        let half = 0.5 * peak;
        // The crossing of half the peak between two steps, linearly.
        let cross = |k0: usize, k1: usize| {
            let (l0, l1) = (at(k0), at(k1));
            let (r0, r1) = (r(l0), r(l1));
            if r1 == r0 {
                l1
            } else {
                l0 + (half - r0) / (r1 - r0) * (l1 - l0)
            }
        };
        let first = (0..=n).find(|&k| r(at(k)) >= half).unwrap_or(0);
        let last = (0..=n).rev().find(|&k| r(at(k)) >= half).unwrap_or(n);
        let from = if first == 0 {
            lo
        } else {
            cross(first - 1, first)
        };
        let to = if last == n { hi } else { cross(last + 1, last) };
        (from, to)
    }

    /// Where both the QE and the transmittance are tabulated [m].
    fn support_m(&self) -> (f64, f64) {
        let (a, b) = self.qe.range_m();
        let (c, d) = self.transmittance.range_m();
        (a.max(c), b.min(d).max(a.max(c)))
    }

    /// The band's effective wavelength [m]: the mean of lambda weighted by the band's response
    /// to a spectrum flat in energy, `QE T lambda`, over its whole support (a header value,
    /// not used in any integral).
    pub fn centre_m(&self) -> f64 {
        let (lo, hi) = self.support_m();
        let w = |l: f64| self.qe.at(l) * self.transmittance.at(l) * l;
        let knots = self.qe.wavelengths_m();
        let n = crate::radiometry::integrate(|l| w(l) * l, lo, hi, knots);
        let d = crate::radiometry::integrate(w, lo, hi, knots);
        if d > 0.0 { n / d } else { 0.5 * (lo + hi) }
    }
}

/// The order of a Bayer mosaic's 2 x 2 cell, read left to right, top to bottom, from the
/// image's top-left pixel: `Rggb` puts R at (0, 0), G at (1, 0) and (0, 1), B at (1, 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bayer {
    Rggb,
    Bggr,
    Grbg,
    Gbrg,
}

impl Bayer {
    pub const ALL: [Bayer; 4] = [Bayer::Rggb, Bayer::Bggr, Bayer::Grbg, Bayer::Gbrg];

    pub fn name(self) -> &'static str {
        match self {
            Bayer::Rggb => "RGGB",
            Bayer::Bggr => "BGGR",
            Bayer::Grbg => "GRBG",
            Bayer::Gbrg => "GBRG",
        }
    }

    /// The band (0 = R, 1 = G, 2 = B) pixel `(x, y)` records.
    #[inline]
    pub fn band_at(self, x: usize, y: usize) -> usize {
        let cells = match self {
            Bayer::Rggb => [0, 1, 1, 2],
            Bayer::Bggr => [2, 1, 1, 0],
            Bayer::Grbg => [1, 0, 2, 1],
            Bayer::Gbrg => [1, 2, 0, 1],
        };
        cells[(y & 1) * 2 + (x & 1)]
    }
}

/// How the bands reach the pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Layout {
    /// A full image per band (a monochrome camera's one band, three-chip cameras, filter
    /// wheels).
    #[default]
    Planes,
    /// One image, each pixel behind its own filter of a Bayer mosaic; bands R, G, B in order.
    Bayer(Bayer),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Detector {
    pub exposure_s: f64,
    pub full_well_e: f64,
    /// ADC gain `G_AD` [DN/e-].
    pub adc_gain_dn_per_e: f64,
    /// ADC offset `DN^(0)` [DN].
    pub offset_dn: f64,
    /// The ADC's bit depth.
    pub bit_depth: u32,
    /// The bits the camera hands out: the ADC's `bit_depth` most significant ones
    /// (`saved_bits <= bit_depth`; a 12-bit ADC saved at 8 bit gives `DN_12 >> 4`).
    pub saved_bits: u32,
    /// The wavebands, at least one; the first is a monochrome camera's only band.
    pub bands: Vec<Band>,
    pub layout: Layout,
    /// The optics' (and, from the ground, the seeing's) Gaussian PSF [px], 0 = none. Applied
    /// by [`Detector::expose`] only: the signal handed to a stimulator stays sharp, since the
    /// flight camera's own optics blur the screen.
    pub psf_sigma_px: f64,
    pub noise: Noise,
    pub seed: u64,
}

impl Detector {
    /// A monochrome detector's one band (the first band of any).
    pub fn band(&self) -> &Band {
        &self.bands[0]
    }

    /// The signal factor of Eq. 45 of every band [e- s^-1 per sr m^2 of (P/L)] for light
    /// reflected by a surface of spectral shape `reflectance` (grey when `None`).
    pub fn band_factors(&self, sun: &SunSpectrum, reflectance: Option<&Reflectance>) -> Vec<f64> {
        self.bands
            .iter()
            .map(|b| sun.reflected_signal_integral(&b.qe, &b.transmittance, reflectance))
            .collect()
    }

    /// How many images the camera hands out: one per band, or one mosaic.
    pub fn dn_planes(&self) -> usize {
        match self.layout {
            Layout::Planes => self.bands.len(),
            Layout::Bayer(_) => 1,
        }
    }

    /// The PSF sigma [px] of band `b` on the camera's own images.
    pub fn band_psf_sigma_px(&self, b: usize) -> f64 {
        self.bands[b].psf_sigma_px.unwrap_or(self.psf_sigma_px)
    }

    /// Signal `S = (P/L) * signal_factor` per pixel [e-/s] (Eq. 45).
    pub fn signal(&self, pl: &[f64], signal_factor: f64) -> Vec<f64> {
        pl.par_iter().map(|&x| x * signal_factor).collect()
    }

    /// Every band's signal `pl(b) * factors[b]` [e-/s] (Eq. 45 per band), band after band,
    /// into `signal` (appended in parallel: no zeroing of the cube first).
    pub fn signal_into<'a>(
        pl: impl Fn(usize) -> &'a [f64],
        factors: &[f64],
        signal: &mut Vec<f64>,
    ) {
        signal.clear();
        for (b, &k) in factors.iter().enumerate() {
            signal.par_extend(pl(b).par_iter().map(|&x| x * k));
        }
    }

    /// A rendered frame through this detector: band `b`'s signal is `pl(b) * factors[b]`
    /// [e-/s] (Eq. 45 per band; `pl(b)` is the band's (P/L) image of `size`, the same image
    /// for every band unless a band's own distortion moved it). Returns the signal of every
    /// band, band after band (`bands x height x width`), and the DN the camera hands out
    /// ([`Detector::expose`]): one image per band, or the mosaic (`height x width`).
    pub fn image<'a>(
        &self,
        pl: impl Fn(usize) -> &'a [f64] + Sync,
        size: (usize, usize),
        factors: &[f64],
        frame_id: u64,
    ) -> (Vec<f64>, Vec<u16>) {
        let (mut signal, mut dn) = (Vec::new(), Vec::new());
        self.image_into(pl, size, factors, frame_id, &mut signal, &mut dn);
        (signal, dn)
    }

    /// [`Detector::image`] into buffers kept from frame to frame (no allocation once they
    /// have grown: a stream of frames, `optistim bench`).
    pub fn image_into<'a>(
        &self,
        pl: impl Fn(usize) -> &'a [f64] + Sync,
        size: (usize, usize),
        factors: &[f64],
        frame_id: u64,
        signal: &mut Vec<f64>,
        dn: &mut Vec<u16>,
    ) {
        Detector::signal_into(&pl, factors, signal);
        self.expose_bands(signal, size, frame_id, dn);
    }

    /// The DN alone of [`Detector::image_into`] (what the SurRender and CORTO endpoints and
    /// the bench hand out), bit for bit the same, without the signal planes in between: each
    /// pixel is exposed straight from `pl(b)[i] * factors[b]`, its band's for a Bayer mosaic
    /// (for three bands behind a mosaic, three planes of 8 bytes a pixel not written), and
    /// only a band its PSF blurs makes its plane.
    pub fn dn_into<'a>(
        &self,
        pl: impl Fn(usize) -> &'a [f64] + Sync,
        size: (usize, usize),
        factors: &[f64],
        frame_id: u64,
        dn: &mut Vec<u16>,
    ) {
        self.expose_from(|b| (pl(b), factors[b]), size, frame_id, dn);
    }

    /// The DN the camera hands out for every band's signal (`bands x height x width`, band
    /// after band) [e-/s]: one image per band, each blurred by its band's PSF, its noises from
    /// streams of its own; or the Bayer mosaic, each pixel its band's.
    pub fn expose_bands(
        &self,
        signal: &[f64],
        size: (usize, usize),
        frame_id: u64,
        dn: &mut Vec<u16>,
    ) {
        let n = size.0 * size.1;
        // (Times 1: exact, the same bits.)
        self.expose_from(|b| (&signal[b * n..(b + 1) * n], 1.0), size, frame_id, dn);
    }

    /// [`Detector::expose_bands`] of the signal `band(b).0[i] * band(b).1` [e-/s] of band `b`
    /// at pixel `i`, read where it is needed: a band its PSF blurs is made into a plane and
    /// blurred ([`source`]), the others are read pixel by pixel.
    fn expose_from<'a>(
        &self,
        band: impl Fn(usize) -> (&'a [f64], f64),
        size: (usize, usize),
        frame_id: u64,
        dn: &mut Vec<u16>,
    ) {
        let n = size.0 * size.1;
        dn.clear();
        dn.resize(n * self.dn_planes(), 0);
        match self.layout {
            Layout::Planes => {
                for (b, out) in dn.chunks_mut(n.max(1)).enumerate() {
                    let (plane, k) = band(b);
                    let sigma = self.band_psf_sigma_px(b);
                    self.expose_into((plane, k), size, frame_id, sigma, b as u64, out);
                }
            }
            Layout::Bayer(order) => {
                // Each band blurred by its own optics, then each pixel keeps its filter's.
                let sources: Vec<_> = (0..self.bands.len())
                    .map(|b| source(band(b), size, self.band_psf_sigma_px(b)))
                    .collect();
                let planes: Vec<(&[f64], f64)> =
                    sources.iter().map(|(s, k)| (&s[..], *k)).collect();
                let w = size.0.max(1);
                // Row by row, the bands of its even and odd columns: no division per pixel.
                let mosaic = |base: usize, out: &mut [f64]| {
                    let mut done = 0;
                    while done < out.len() {
                        let i = base + done;
                        let (x0, y) = (i % w, i / w);
                        let run = (w - x0).min(out.len() - done);
                        let cols = [planes[order.band_at(0, y)], planes[order.band_at(1, y)]];
                        for (j, o) in out[done..done + run].iter_mut().enumerate() {
                            let (s, k) = cols[(x0 + j) & 1];
                            *o = s[i + j] * k;
                        }
                        done += run;
                    }
                };
                self.expose_pixels(mosaic, frame_id, 0, dn);
            }
        }
    }

    /// The ADC's largest DN (at `bit_depth`).
    pub fn adc_max_dn(&self) -> f64 {
        ((1u64 << self.bit_depth) - 1) as f64
    }

    /// ADC DN per saved DN: `2^(bit_depth - saved_bits)`.
    pub fn saved_dn_step(&self) -> f64 {
        (1u64 << (self.bit_depth - self.saved_bits)) as f64
    }

    /// The largest DN the camera hands out (at `saved_bits`).
    pub fn max_dn(&self) -> f64 {
        ((1u64 << self.saved_bits) - 1) as f64
    }

    /// Exposes one frame: noises on the electrons, full-well cap (Eq. 46), ADC with rounding to
    /// the nearest integer and the bit-depth cap (Eq. 47). Writes DN into `dn_out`.
    /// `size` is the image's `(width, height)`, which the PSF needs.
    pub fn expose(
        &self,
        signal_e_per_s: &[f64],
        size: (usize, usize),
        frame_id: u64,
        dn_out: &mut Vec<u16>,
    ) {
        dn_out.clear();
        dn_out.resize(signal_e_per_s.len(), 0);
        let sigma = self.psf_sigma_px;
        // (Times 1: exact, the same bits.)
        self.expose_into((signal_e_per_s, 1.0), size, frame_id, sigma, 0, dn_out);
    }

    /// [`Detector::expose`] of one image, `plane[i] * k` [e-/s], into a slice of the image's
    /// size: blurred by `psf_sigma_px` ([`source`]), its noises drawn from streams of its own
    /// (`plane_id`; plane 0's are a monochrome camera's), so that a multi-band camera's bands
    /// have independent noises.
    fn expose_into(
        &self,
        (plane, k): (&[f64], f64),
        size: (usize, usize),
        frame_id: u64,
        psf_sigma_px: f64,
        plane_id: u64,
        dn_out: &mut [u16],
    ) {
        let (s, k) = source((plane, k), size, psf_sigma_px);
        let plane = |base: usize, out: &mut [f64]| {
            let n = out.len();
            for (o, &x) in out.iter_mut().zip(&s[base..base + n]) {
                *o = x * k;
            }
        };
        self.expose_pixels(plane, frame_id, plane_id, dn_out);
    }

    /// The exposure of every pixel of `dn_out`, whose signal [e-/s] `signal(i, out)` writes
    /// into `out` for the run of pixels from `i` (a Bayer mosaic reads each pixel from its
    /// band's image without making the mosaic).
    fn expose_pixels(
        &self,
        signal_e_per_s: impl Fn(usize, &mut [f64]) + Sync,
        frame_id: u64,
        plane: u64,
        dn_out: &mut [u16],
    ) {
        let t = self.exposure_s;
        let noise = &self.noise;
        let seed = self.seed;
        let fixed = noise.prnu.is_some() || noise.dark.is_some();
        let temporal = noise.shot.is_some() || noise.dark.is_some() || noise.readout.is_some();
        // Without fixed patterns a pixel that collects nothing sees the readout noise alone.
        let dark_dn = if fixed { None } else { self.dark_dn() };
        dn_out
            .par_chunks_mut(4096)
            .enumerate()
            .for_each_init(Vec::new, |signal, (chunk, out)| {
                // A watcher's capture pauses here while a frame is in flight (a no-op on
                // the frame's own threads).
                crate::background::checkpoint();
                let base = chunk * 4096;
                // One generator per stream for each fixed block of 4096 pixels (the fixed
                // patterns' independent of the frame, the temporal noises' seeded by it); draws
                // are taken in pixel order, so a pixel gets the same draws whatever the thread
                // count. Seeding per block rather than per pixel: seeding cost most of the time.
                let c = chunk as u64 | plane << 40;
                let mut fixed_rng = fixed.then(|| rng(seed, Stream::Fixed, None, c));
                let mut temporal_rng =
                    temporal.then(|| rng(seed, Stream::Temporal, Some(frame_id), c));
                signal.resize(out.len(), 0.0);
                signal_e_per_s(base, signal);
                for (dn, &s) in out.iter_mut().zip(signal.iter()) {
                    let mut s = s;
                    if s == 0.0
                        && let (Some(d), Some(r)) = (&dark_dn, temporal_rng.as_mut())
                    {
                        *dn = d.draw(r);
                        continue;
                    }
                    if let (Some(prnu), Some(r)) = (&noise.prnu, fixed_rng.as_mut()) {
                        s *= prnu.gain(r);
                    }
                    let mut e = s * t;
                    if let Some(r) = temporal_rng.as_mut() {
                        if noise.shot.is_some() {
                            e = noise::shot::poisson(e, r);
                        }
                        if let (Some(dark), Some(f)) = (&noise.dark, fixed_rng.as_mut()) {
                            e += noise::shot::poisson(dark.pixel_rate(f) * t, r);
                        }
                        if let Some(ro) = &noise.readout {
                            e += ro.draw(r);
                        }
                    }
                    *dn = self.dn(e);
                }
            });
    }

    /// The DN of `e` collected electrons: the ADC's code ([`Detector::adc_code`]) at the saved
    /// bits.
    #[inline]
    fn dn(&self, e: f64) -> u16 {
        (self.adc_code(e) >> (self.bit_depth - self.saved_bits)) as u16
    }

    /// The ADC's code for `e` collected electrons: full-well cap (Eq. 46), then gain and offset
    /// with rounding to the nearest integer (half up) and the bit-depth cap (Eq. 47).
    #[inline]
    fn adc_code(&self, e: f64) -> u32 {
        let max_dn = self.adc_max_dn();
        let e = e.clamp(0.0, self.full_well_e);
        // The value is clamped to >= 0 first, so `+ 0.5` and truncation round half up (libm's
        // `round` is not inlined).
        ((self.offset_dn + self.adc_gain_dn_per_e * e).clamp(0.0, max_dn) + 0.5).min(max_dn) as u32
    }

    /// The DN distribution of a pixel that collects no electrons and sees readout noise alone
    /// (`max(0, sigma n)` electrons, `n` standard normal; shot noise on nothing is nothing),
    /// for [`DarkDn::draw`]. `None` when such a pixel's DN spreads over more than 64 values.
    fn dark_dn(&self) -> Option<DarkDn> {
        let sigma = self.noise.readout.map_or(0.0, |r| r.sigma_e);
        let gain = self.adc_gain_dn_per_e;
        let last = self.adc_code(self.full_well_e);
        let drop = self.bit_depth - self.saved_bits;
        let (mut below, mut values) = (Vec::new(), Vec::new());
        let mut code = self.adc_code(0.0);
        loop {
            // P(code at most `code`): the electrons stay below the next code's edge.
            let p = if code == last || sigma <= 0.0 || gain <= 0.0 {
                1.0
            } else {
                let edge_e = (code as f64 + 0.5 - self.offset_dn) / gain;
                0.5 * libm::erfc(-edge_e / sigma / std::f64::consts::SQRT_2)
            };
            let b = if p >= 1.0 {
                u64::MAX
            } else {
                (p * 18_446_744_073_709_551_616.0) as u64
            };
            below.push(b);
            values.push((code >> drop) as u16);
            if b == u64::MAX {
                return Some(DarkDn::new(below, values));
            }
            if below.len() == 64 {
                return None;
            }
            code += 1;
        }
    }
}

/// The exact DN distribution of a pixel that collects nothing ([`Detector::dark_dn`]): most
/// of a frame's pixels. One uniform draw and a few comparisons give its DN, instead of a
/// normal draw and the ADC (which cost most of an exposure).
struct DarkDn {
    /// `P(DN <= values[k])` in units of 2^-64; the last is `u64::MAX`.
    below: Vec<u64>,
    values: Vec<u16>,
    /// By the draw's top [`DarkDn::BUCKET_BITS`] bits: the DN of every draw with those bits,
    /// or [`DarkDn::SEARCH`] where a step of `below` falls among them. The same DN as the
    /// search, without its unpredictable branches (most draws end at the first or second
    /// step, at random).
    bucket: [u16; 1 << DarkDn::BUCKET_BITS],
}

impl DarkDn {
    const BUCKET_BITS: u32 = 8;
    const SEARCH: u16 = u16::MAX;

    #[inline]
    fn draw(&self, r: &mut impl rand::Rng) -> u16 {
        if self.values.len() == 1 {
            return self.values[0];
        }
        let u = r.next_u64();
        let v = self.bucket[(u >> (64 - Self::BUCKET_BITS)) as usize];
        if v != Self::SEARCH {
            return v;
        }
        self.search(u)
    }

    /// The DN of the draw `u`: the first step of `below` above it.
    #[inline]
    fn search(&self, u: u64) -> u16 {
        let k = self.below.iter().position(|&b| u < b);
        self.values[k.unwrap_or(self.values.len() - 1)]
    }

    /// `below` and `values` with their buckets.
    fn new(below: Vec<u64>, values: Vec<u16>) -> DarkDn {
        let mut dark = DarkDn {
            below,
            values,
            bucket: [Self::SEARCH; 1 << Self::BUCKET_BITS],
        };
        let shift = 64 - Self::BUCKET_BITS;
        for b in 0..1u64 << Self::BUCKET_BITS {
            // The bucket's least and greatest draws.
            let (lo, hi) = (b << shift, (b << shift) | ((1u64 << shift) - 1));
            let v = dark.search(lo);
            if v == dark.search(hi) {
                dark.bucket[b as usize] = v;
            }
        }
        dark
    }
}

/// An image `plane[i] * k` [e-/s] as the pixels read it: blurred by a PSF of `sigma` [px]
/// (the plane times `k` first, unless `k` is 1; then read times 1), or the plane as it is with
/// its factor.
fn source(
    (plane, k): (&[f64], f64),
    size: (usize, usize),
    sigma: f64,
) -> (std::borrow::Cow<'_, [f64]>, f64) {
    if sigma <= 0.0 {
        return (plane.into(), k);
    }
    let r = psf::radius(sigma);
    let blurred = if k == 1.0 {
        psf::gaussian_blur(plane, size.0, size.1, sigma, r)
    } else {
        let signal: Vec<f64> = plane.par_iter().map(|&x| x * k).collect();
        psf::gaussian_blur(&signal, size.0, size.1, sigma, r)
    };
    (blurred.into(), 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(noise: Noise) -> Detector {
        Detector {
            exposure_s: 1e-3,
            full_well_e: 10_000.0,
            adc_gain_dn_per_e: 0.4,
            offset_dn: 10.0,
            bit_depth: 12,
            saved_bits: 12,
            bands: vec![Band {
                name: "mono".into(),
                qe: SpectralTable::flat(400e-9, 700e-9, 0.5),
                transmittance: SpectralTable::flat(400e-9, 700e-9, 1.0),
                psf_sigma_px: None,
                distortion: None,
            }],
            layout: Layout::Planes,
            psf_sigma_px: 0.0,
            noise,
            seed: 3,
        }
    }

    /// A band's range is its half-maximum width: 525-575 nm for a triangle peaking at 550 nm,
    /// the whole table for a flat band.
    #[test]
    fn a_bands_range_is_its_half_maximum_width() {
        let tri = SpectralTable::new(
            vec![500e-9, 550e-9, 600e-9],
            vec![0.0, 0.8, 0.0],
            (0.0, 1.0),
        );
        let band = Band {
            name: "F550".into(),
            qe: tri.unwrap(),
            transmittance: SpectralTable::flat(400e-9, 700e-9, 0.9),
            psf_sigma_px: None,
            distortion: None,
        };
        let (lo, hi) = band.range_m();
        assert!(
            (lo - 525e-9).abs() < 1e-13 && (hi - 575e-9).abs() < 1e-13,
            "{lo} {hi}"
        );
        // Weighted by lambda too: (mu^2 + sigma^2) / mu, sigma^2 = 50^2 / 6 nm^2.
        let c = band.centre_m();
        assert!(
            (c - (550e-9 + 2500e-18 / 6.0 / 550e-9)).abs() < 1e-12,
            "{c}"
        );
        let flat = &det(Noise::default()).bands[0];
        assert_eq!(flat.range_m(), (400e-9, 700e-9));
    }

    #[test]
    fn noiseless_adc_follows_eq_47() {
        let d = det(Noise::default());
        let mut out = Vec::new();
        d.expose(&[0.0, 1e6, 5e6, 1e9], (4, 1), 0, &mut out);
        // 1e6 e-/s * 1 ms = 1000 e- -> 10 + 400 DN; 5000 e- -> 2010; capped at FWC -> 4010.
        assert_eq!(out, vec![10, 410, 2010, 4010]);
        // Saved at 8 bit: the ADC's 8 most significant bits.
        let d8 = Detector { saved_bits: 8, ..d };
        d8.expose(&[0.0, 1e6, 5e6, 1e9], (4, 1), 0, &mut out);
        assert_eq!(out, vec![0, 25, 125, 250]);
        assert_eq!(d8.max_dn(), 255.0);
    }

    #[test]
    fn shot_noise_has_poisson_statistics_and_is_reproducible() {
        let d = det(Noise {
            shot: Some(noise::Shot),
            ..Default::default()
        });
        let s = vec![1e6; 20_000]; // 1000 e- mean
        let (mut a, mut b) = (Vec::new(), Vec::new());
        d.expose(&s, (200, 100), 7, &mut a);
        d.expose(&s, (200, 100), 7, &mut b);
        assert_eq!(a, b);
        let e: Vec<f64> = a.iter().map(|&x| (x as f64 - 10.0) / 0.4).collect();
        let m = e.iter().sum::<f64>() / e.len() as f64;
        let v = e.iter().map(|x| (x - m).powi(2)).sum::<f64>() / e.len() as f64;
        assert!((m - 1000.0).abs() < 2.0, "{m}");
        // Quantisation (1/0.4 e- steps) adds 2.5^2/12 to the variance.
        assert!((v - 1000.0 - 0.52).abs() < 60.0, "{v}");
        let mut c = Vec::new();
        d.expose(&s, (200, 100), 8, &mut c);
        assert_ne!(a, c, "temporal noise must change with the frame");
    }

    /// Pixels that collect nothing get their DN from the exact table ([`Detector::dark_dn`]);
    /// pixels with a vanishing signal take the general path (a normal draw, then the ADC).
    /// Both histograms match the analytic one: `P(DN <= d) = Phi(edge_d / sigma)`.
    #[test]
    fn dark_pixels_follow_the_readout_noise_distribution() {
        let d = Detector {
            adc_gain_dn_per_e: 0.2,
            offset_dn: 8.0,
            ..det(Noise {
                shot: Some(noise::Shot),
                readout: Some(noise::Readout { sigma_e: 3.0 }),
                ..Default::default()
            })
        };
        let n = 400_000;
        let (mut table, mut general) = (Vec::new(), Vec::new());
        d.expose(&vec![0.0; n], (1000, 400), 1, &mut table);
        d.expose(&vec![1e-300; n], (1000, 400), 1, &mut general);
        let histogram = |dn: &[u16]| {
            let mut h = [0usize; 16];
            dn.iter().for_each(|&v| h[(v as usize).min(15)] += 1);
            h
        };
        let phi = |x: f64| 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
        let cdf = |dn: usize| {
            if dn < 8 {
                0.0
            } else {
                phi((dn as f64 + 0.5 - 8.0) / 0.2 / 3.0)
            }
        };
        for (name, h) in [
            ("table", histogram(&table)),
            ("general", histogram(&general)),
        ] {
            for (dn, &count) in h.iter().enumerate() {
                let p = cdf(dn) - if dn == 0 { 0.0 } else { cdf(dn - 1) };
                let expected = n as f64 * p;
                let tolerance = 5.0 * (expected * (1.0 - p)).sqrt() + 1.0;
                assert!(
                    (count as f64 - expected).abs() < tolerance,
                    "{name}: DN {dn}: {count} vs {expected:.0}"
                );
            }
        }
        assert!(
            histogram(&table)[8] > n / 2,
            "most dark pixels at the offset"
        );
    }

    /// The dark DN's buckets give the search's DN for every draw: at each step of the table,
    /// either side of it, at each bucket's ends, and at draws spread over the whole range.
    #[test]
    fn the_dark_dns_buckets_are_its_search() {
        for (gain, sigma) in [(0.2, 3.0), (1.0, 3.0), (0.05, 1.0), (4.0, 0.1)] {
            let d = Detector {
                adc_gain_dn_per_e: gain,
                offset_dn: 8.0,
                ..det(Noise {
                    readout: Some(noise::Readout { sigma_e: sigma }),
                    ..Default::default()
                })
            };
            let dark = d.dark_dn().expect("a narrow dark distribution");
            let shift = 64 - DarkDn::BUCKET_BITS;
            let steps = dark
                .below
                .iter()
                .flat_map(|&b| [b.wrapping_sub(1), b, b.wrapping_add(1)]);
            let ends = (0..1u64 << DarkDn::BUCKET_BITS)
                .flat_map(|b| [b << shift, (b << shift) | ((1 << shift) - 1)]);
            let spread = (0..100_000u64).map(|k| k.wrapping_mul(0x9e37_79b9_7f4a_7c15));
            let mut buckets_used = 0;
            for u in steps.chain(ends).chain(spread) {
                let v = dark.bucket[(u >> shift) as usize];
                if v != DarkDn::SEARCH {
                    assert_eq!(v, dark.search(u), "gain {gain} sigma {sigma} draw {u}");
                    buckets_used += 1;
                }
            }
            assert!(buckets_used > 90_000, "{buckets_used}");
        }
    }

    /// The DN alone ([`Detector::dn_into`]) are the DN of the signal planes' path
    /// ([`Detector::image_into`]), bit for bit, noises on: one band, three full images, every
    /// Bayer order, and a PSF on the full images and on the mosaic.
    #[test]
    fn the_dn_alone_are_the_images_dn() {
        let noisy = det(Noise {
            shot: Some(noise::Shot),
            readout: Some(noise::Readout { sigma_e: 3.0 }),
            ..Default::default()
        });
        let band = |name: &str| Band {
            name: name.into(),
            ..noisy.bands[0].clone()
        };
        let three = Detector {
            bands: vec![band("R"), band("G"), band("B")],
            ..noisy.clone()
        };
        let (w, h) = (96, 64);
        // Each band its own image: a ramp, a dark half and another ramp.
        let planes: Vec<Vec<f64>> = (0..3)
            .map(|b| {
                (0..w * h)
                    .map(|i| {
                        if b == 1 && i % w < w / 2 {
                            0.0
                        } else {
                            1e3 * (i % 97 + b) as f64
                        }
                    })
                    .collect()
            })
            .collect();
        let factors = [2.0e3, 1.5e3, 0.7e3];
        let mut cameras = vec![noisy.clone(), three.clone()];
        cameras.extend(Bayer::ALL.map(|o| Detector {
            layout: Layout::Bayer(o),
            ..three.clone()
        }));
        for layout in [Layout::Planes, Layout::Bayer(Bayer::Grbg)] {
            cameras.push(Detector {
                psf_sigma_px: 0.8,
                layout,
                ..three.clone()
            });
        }
        for d in cameras {
            let k = &factors[..d.bands.len()];
            let (mut signal, mut via_planes, mut alone) = (Vec::new(), Vec::new(), Vec::new());
            d.image_into(
                |b| &planes[b][..],
                (w, h),
                k,
                5,
                &mut signal,
                &mut via_planes,
            );
            d.dn_into(|b| &planes[b][..], (w, h), k, 5, &mut alone);
            assert_eq!(alone, via_planes, "{:?} {}", d.layout, d.bands.len());
            assert!(alone.iter().any(|&x| x > 100));
        }
    }
}
