//! Hapke parameter inversion (SLIM Secs. 10-11; `optistim invert`): from one or more images
//! of a body of known shape and pose, the parameters `w, b, c, B0, h, theta` of its Hapke
//! BRDF (SLIM Eqs. 11-13; here the shadow-hiding `B0_S`, `h_S`, no coherent backscatter, no
//! porosity), with their uncertainties, and the chi-square of the radiance histograms
//! (SLIM Eq. 15).
//!
//! The forward model is the renderer's own: each used pixel is an `n x n` grid of lines of
//! sight ([`crate::raycast::Tracer::photometry`]: `mu0`, `mu`, `cos g` and the `(P/L)` per
//! unit of `f_r`), or, for a lone mesh through a pinhole, the line of sight through each of
//! its facets' fragments' centroids weighted by the fragment's area (as
//! [`crate::raycast::sampled`] renders it), the geometry cast once, so that a trial set of
//! parameters costs only the BRDF's evaluations. A pixel is used when all its lines of sight
//! and its eight neighbours' meet the body in direct sunlight (limb, terminator and shadow
//! edges are left out, where the image depends on sub-pixel geometry), it is not a mesh's
//! fold (two fronts over one point, which the renderer casts with its edges' rays: there too
//! the image depends on which facet each sub-pixel ray sees) and it is not saturated.
//!
//! Observed DN become electrons, `e = (DN step - offset) / gain`, with the variance
//! `m + sigma_read^2 + (step / gain)^2 / 12` (shot noise on the model's electrons `m`, read
//! noise, quantisation). The fit is Levenberg-Marquardt on the weighted squared residuals
//! (numerical Jacobian, parameters kept in their domains); the uncertainties are the square
//! roots of the diagonal of `(J^T W J)^-1`, scaled by the reduced chi-square where it exceeds
//! 1 (a model that does not fit widens them). Where the images do not constrain a parameter
//! (the opposition surge's `B0` and `h` without images near zero phase), its uncertainty says
//! so: large, or infinite when the normal matrix is singular.

use crate::brdf::{Hapke, HapkeParams};
use crate::raycast::Tracer;
use crate::raycast::raster::COVERED;
use crate::scene::{Pose, Scene};
use rayon::prelude::*;
use serde::Serialize;

/// The fitted parameters, in this order.
pub const NAMES: [&str; 6] = ["w", "b", "c", "B0", "h", "theta_rad"];
/// Their domains.
const LOWER: [f64; 6] = [1e-4, 0.0, 0.0, 0.0, 1e-3, 0.0];
const UPPER: [f64; 6] = [0.9999, 0.99, 1.0, 5.0, 2.0, 1.2];

/// One image to fit: what it shows, from where, and its DN.
pub struct Image<'a> {
    pub scene: &'a Scene,
    pub pose: Pose,
    /// Saved DN, row-major, the scene's camera's size.
    pub dn: &'a [u16],
}

/// The data of the used pixels of all images: per pixel its observed electrons, its noise
/// variance's fixed part, and its lines of sight (`mu0, mu, cos g, k * e-per-(P/L)`).
struct Data {
    observed_e: Vec<f64>,
    fixed_var: Vec<f64>,
    start: Vec<usize>,
    samples: Vec<[f64; 4]>,
}

/// The result.
#[derive(Clone, Debug, Serialize)]
pub struct Inversion {
    /// `w, b, c, B0, h, theta_rad`.
    pub params: [f64; 6],
    pub sigma: [f64; 6],
    pub pixels: usize,
    pub iterations: u32,
    /// Weighted residuals: chi-square and per degree of freedom.
    pub chi2: f64,
    pub chi2_per_dof: f64,
    /// SLIM Eq. 15 on the radiance histograms (observed against model, 32 bins over the
    /// observed range, bins the model leaves empty skipped), and divided by the pixels.
    pub chi2_histogram: f64,
    pub chi2_histogram_per_px: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum InversionError {
    #[error("invert: {0}")]
    Input(String),
}

fn hapke(p: &[f64; 6]) -> Hapke {
    Hapke::new(
        p[0],
        HapkeParams {
            b: p[1],
            c: p[2],
            b0_c: 0.0,
            h_c: 1.0,
            b0_s: p[3],
            h_s: p[4],
            theta_rad: p[5],
            filling_factor: 0.0,
        },
    )
}

/// Gathers the used pixels of `images`, cast `n x n` times each.
fn gather(images: &[Image], n: u32) -> Result<Data, InversionError> {
    let mut d = Data {
        observed_e: Vec::new(),
        fixed_var: Vec::new(),
        start: vec![0],
        samples: Vec::new(),
    };
    for (k, im) in images.iter().enumerate() {
        let intr = &im.scene.camera.intrinsics;
        let (w, h) = (intr.width_px as usize, intr.height_px as usize);
        if im.dn.len() != w * h {
            return Err(InversionError::Input(format!(
                "image {k}: {} pixels for a {w} x {h} camera",
                im.dn.len()
            )));
        }
        let det = &im.scene.camera.detector;
        if det.psf_sigma_px > 0.0 {
            return Err(InversionError::Input(format!(
                "image {k}: the camera has a PSF (psf_sigma_px > 0): pixels are not independent"
            )));
        }
        if im.scene.body.albedo_map.is_some() {
            return Err(InversionError::Input(format!(
                "image {k}: the body has an albedo map; the inversion fits one set of \
                 parameters for the whole surface"
            )));
        }
        let tracer = Tracer::new(im.scene, &im.pose);
        let e_per_pl = im.scene.signal_factor() * det.exposure_s;
        let step = 1.0 / n as f64;
        // Every pixel's lines of sight, or None when one is not on the lit first body.
        // A lone mesh seen through a pinhole: a pixel one facet covers at every point is
        // its facets' fragments, as the renderer takes it.
        let rasteriser = tracer.rasteriser(8);
        let per_px: Vec<Option<Vec<[f64; 4]>>> = (0..w * h)
            .into_par_iter()
            .map_init(Vec::new, |fragments, p| {
                let (u0, v0) = ((p % w) as f64, (p / w) as f64);
                if let Some(r) = &rasteriser {
                    let area = r.fragments((p % w, p / w), fragments);
                    if (area - 1.0).abs() <= COVERED {
                        let mut out = Vec::with_capacity(fragments.len());
                        for f in fragments.iter() {
                            let (mu0, mu, cg, kk) =
                                tracer.photometry(f.centroid.x, f.centroid.y)?;
                            out.push([mu0, mu, cg, kk * e_per_pl * f.area_px2]);
                        }
                        return Some(out);
                    }
                }
                // A fold (two fronts over one point, `area > 1`): the renderer casts it with
                // the edges' rays, its value set by which facet each sees. It is left out
                // (empty) once its lines of sight are known to be lit.
                let fold = rasteriser.is_some();
                let mut out = Vec::with_capacity((n * n) as usize);
                for j in 0..n {
                    for i in 0..n {
                        let (mu0, mu, cg, kk) = tracer.photometry(
                            u0 + (i as f64 + 0.5) * step,
                            v0 + (j as f64 + 0.5) * step,
                        )?;
                        out.push([mu0, mu, cg, kk * e_per_pl / (n * n) as f64]);
                    }
                }
                if fold {
                    out.clear();
                }
                Some(out)
            })
            .collect();
        let read = det.noise.readout.as_ref().map_or(0.0, |r| r.sigma_e);
        let e_step = det.saved_dn_step() / det.adc_gain_dn_per_e;
        let fixed_var = read * read + e_step * e_step / 12.0;
        let max_dn = det.max_dn() as u16;
        for p in 0..w * h {
            let (i, j) = (p % w, p / w);
            let border = i == 0 || j == 0 || i + 1 == w || j + 1 == h;
            let interior = !border && crate::raycast::around(p, w, h).all(|q| per_px[q].is_some());
            if !interior || im.dn[p] >= max_dn || per_px[p].as_ref().is_some_and(Vec::is_empty) {
                continue;
            }
            let e = (im.dn[p] as f64 * det.saved_dn_step() - det.offset_dn) / det.adc_gain_dn_per_e;
            d.observed_e.push(e);
            d.fixed_var.push(fixed_var);
            d.samples.extend(per_px[p].as_ref().expect("interior"));
            d.start.push(d.samples.len());
        }
    }
    if d.observed_e.len() < 100 {
        return Err(InversionError::Input(format!(
            "{} usable pixels (lit, away from edges, not saturated): at least 100",
            d.observed_e.len()
        )));
    }
    Ok(d)
}

/// The model's electrons of every used pixel for parameters `p`.
fn model(d: &Data, p: &[f64; 6]) -> Vec<f64> {
    let h = hapke(p);
    (0..d.observed_e.len())
        .into_par_iter()
        .map(|i| {
            d.samples[d.start[i]..d.start[i + 1]]
                .iter()
                .map(|s| s[3] * h.eval(s[0], s[1], s[2]))
                .sum()
        })
        .collect()
}

fn chi2(d: &Data, m: &[f64]) -> f64 {
    m.iter()
        .zip(&d.observed_e)
        .zip(&d.fixed_var)
        .map(|((m, o), v)| (o - m) * (o - m) / (m.max(0.0) + v))
        .sum()
}

/// Solves the symmetric positive system `a x = b` (6 x 6) by Cholesky; `None` if singular.
fn solve(a: &[[f64; 6]; 6], b: &[f64; 6]) -> Option<[f64; 6]> {
    let mut l = [[0.0; 6]; 6];
    for i in 0..6 {
        for j in 0..=i {
            let s: f64 = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s.is_nan() || s <= 0.0 {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; 6];
    for i in 0..6 {
        y[i] = (b[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    let mut x = [0.0; 6];
    for i in (0..6).rev() {
        x[i] = (y[i] - (i + 1..6).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    Some(x)
}

/// The weighted normal matrix `J^T W J` and gradient `J^T W r` at `p`.
fn normal_equations(d: &Data, p: &[f64; 6], m: &[f64]) -> ([[f64; 6]; 6], [f64; 6]) {
    let mut cols: Vec<Vec<f64>> = Vec::with_capacity(6);
    for k in 0..6 {
        let mut q = *p;
        // Forward or backward difference, whichever stays in the domain.
        let dk = 1e-5 * (UPPER[k] - LOWER[k]);
        q[k] = if p[k] + dk <= UPPER[k] {
            p[k] + dk
        } else {
            p[k] - dk
        };
        let h = q[k] - p[k];
        let mq = model(d, &q);
        cols.push(mq.iter().zip(m).map(|(a, b)| (a - b) / h).collect());
    }
    let mut a = [[0.0; 6]; 6];
    let mut g = [0.0; 6];
    for i in 0..m.len() {
        let wgt = 1.0 / (m[i].max(0.0) + d.fixed_var[i]);
        let r = d.observed_e[i] - m[i];
        for r_ in 0..6 {
            let jr = cols[r_][i];
            g[r_] += wgt * jr * r;
            for c in 0..=r_ {
                a[r_][c] += wgt * jr * cols[c][i];
            }
        }
    }
    // The upper triangle mirrors the lower.
    let lower = a;
    for (r_, row) in lower.iter().enumerate() {
        for (c, &v) in row.iter().enumerate().take(r_) {
            a[c][r_] = v;
        }
    }
    (a, g)
}

/// Fits the Hapke parameters to `images`, starting from `start` (`w, b, c, B0, h, theta`),
/// casting each pixel `n x n` times.
pub fn invert(images: &[Image], start: [f64; 6], n: u32) -> Result<Inversion, InversionError> {
    let d = gather(images, n.max(1))?;
    let clamp = |p: [f64; 6]| {
        let mut q = p;
        for k in 0..6 {
            q[k] = q[k].clamp(LOWER[k], UPPER[k]);
        }
        q
    };
    let mut p = clamp(start);
    let mut m = model(&d, &p);
    let mut c2 = chi2(&d, &m);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for _ in 0..200 {
        iterations += 1;
        let (a, g) = normal_equations(&d, &p, &m);
        let mut improved = false;
        for _ in 0..20 {
            let mut damped = a;
            for k in 0..6 {
                damped[k][k] = a[k][k] * (1.0 + lambda) + 1e-300;
            }
            let Some(step) = solve(&damped, &g) else {
                lambda *= 10.0;
                continue;
            };
            let mut q = p;
            for k in 0..6 {
                q[k] += step[k];
            }
            let q = clamp(q);
            let mq = model(&d, &q);
            let cq = chi2(&d, &mq);
            if cq < c2 {
                let gain = (c2 - cq) / c2;
                p = q;
                m = mq;
                c2 = cq;
                lambda = (lambda / 10.0).max(1e-12);
                improved = gain > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let dof = (d.observed_e.len() - 6) as f64;
    let per_dof = c2 / dof;
    let (a, _) = normal_equations(&d, &p, &m);
    let mut sigma = [f64::INFINITY; 6];
    for (k, s) in sigma.iter_mut().enumerate() {
        let mut unit = [0.0; 6];
        unit[k] = 1.0;
        if let Some(col) = solve(&a, &unit) {
            *s = (col[k] * per_dof.max(1.0)).sqrt();
        }
    }
    let (hist, hist_px) = histogram_chi2(&d.observed_e, &m);
    Ok(Inversion {
        params: p,
        sigma,
        pixels: d.observed_e.len(),
        iterations,
        chi2: c2,
        chi2_per_dof: per_dof,
        chi2_histogram: hist,
        chi2_histogram_per_px: hist_px,
    })
}

/// SLIM Eq. 15: `sum_k (f_k - N p_k)^2 / (N p_k)` with `f_k` the observed counts and `p_k`
/// the model's relative frequencies in 32 bins over the observed range.
pub fn histogram_chi2(observed: &[f64], model: &[f64]) -> (f64, f64) {
    const BINS: usize = 32;
    let lo = observed.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = observed.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let width = ((hi - lo) / BINS as f64).max(f64::MIN_POSITIVE);
    let bin = |x: f64| (((x - lo) / width) as usize).min(BINS - 1);
    let (mut f, mut q) = ([0.0; BINS], [0.0; BINS]);
    for &x in observed {
        f[bin(x)] += 1.0;
    }
    for &x in model {
        if x >= lo && x <= hi {
            q[bin(x)] += 1.0;
        }
    }
    let n = observed.len() as f64;
    let inside: f64 = q.iter().sum();
    let chi: f64 = (0..BINS)
        .filter(|&k| q[k] > 0.0)
        .map(|k| {
            let expected = n * q[k] / inside;
            (f[k] - expected).powi(2) / expected
        })
        .sum();
    (chi, chi / n)
}
