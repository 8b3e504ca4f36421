//! Comparing a rendered image with a real one (paper Sec. 5.3, Table 4): the rendered image is
//! aligned on the real one by normalised cross-correlation (NCC), the foreground is separated
//! from the background, and SSIM's three terms (Wang et al. 2004) are averaged over it.
//!
//! - **Alignment**: the integer shift of the rendered image, within `max_shift_px`, that
//!   maximises the zero-mean NCC with the real image over the rendered body's box, widened by
//!   the search and the SSIM window.
//! - **Foreground**: the paper's threshold, the median plus one standard deviation of the real
//!   image over its *inactive* pixels (where the aligned rendering collects no light); the
//!   foreground is every pixel where the real image is above it **or** the rendering has light,
//!   so light missing from either image counts against the match.
//! - **SSIM**: Wang et al.'s Gaussian window, sigma 1.5 px truncated to 11 x 11 (MATLAB's
//!   `ssim` default; the 7 x 7 uniform window with sample covariance reads about 0.03
//!   differently), `C1 = (0.01 L)^2`, `C2 = (0.03 L)^2`, `C3 = C2 / 2`, `L` the images' full
//!   scale; the maps of luminance `l = (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1)`, contrast
//!   `c = (2 s_x s_y + C2) / (s_x^2 + s_y^2 + C2)` and structure
//!   `s = (s_xy + C3) / (s_x s_y + C3)` are averaged over the foreground (mean and standard
//!   deviation, as Table 4 gives them).

use serde::Serialize;

/// A grayscale image in DN, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Gray {
    pub width: usize,
    pub height: usize,
    pub dn: Vec<f64>,
}

impl Gray {
    pub fn new(width: usize, height: usize, dn: Vec<f64>) -> Gray {
        assert_eq!(dn.len(), width * height, "a {width} x {height} image");
        Gray { width, height, dn }
    }

    fn at(&self, x: i64, y: i64) -> f64 {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            0.0
        } else {
            self.dn[y as usize * self.width + x as usize]
        }
    }

    /// This image moved by `(dx, dy)` pixels (right, down), zeros where nothing moves in.
    pub fn shifted(&self, dx: i64, dy: i64) -> Gray {
        let (w, h) = (self.width as i64, self.height as i64);
        let dn = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| self.at(x - dx, y - dy))
            .collect();
        Gray::new(self.width, self.height, dn)
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CompareError {
    #[error("the images differ in size: real {real:?}, rendered {rendered:?}")]
    Size {
        real: (usize, usize),
        rendered: (usize, usize),
    },
    #[error("the {0} image has no light above its background")]
    Empty(&'static str),
}

/// Mean and standard deviation of an SSIM term over the foreground.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct MeanStd {
    pub mean: f64,
    pub std: f64,
}

/// SSIM's three terms, each averaged over the foreground.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct SsimTerms {
    pub luminance: MeanStd,
    pub contrast: MeanStd,
    pub structure: MeanStd,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Comparison {
    /// The shift applied to the rendered image [px] (right, down).
    pub shift_px: [i64; 2],
    /// NCC at that shift, and with no shift.
    pub ncc: f64,
    pub ncc_unshifted: f64,
    /// The background threshold [DN] and the foreground's size [px].
    pub threshold_dn: f64,
    pub foreground_px: usize,
    /// SSIM's terms over the foreground.
    pub ssim: SsimTerms,
    /// Total DN over the foreground, real / rendered.
    pub total_dn_ratio: f64,
    /// A diagnostic, not the result: the terms with the rendering multiplied by
    /// `total_dn_ratio` (capped at full scale), i.e. with the absolute radiometric scale
    /// (camera gain, atmosphere, albedo level) taken from the photograph: what is left is the
    /// match of shape, shading and texture.
    pub ssim_at_matched_total: SsimTerms,
    /// How the real DN follow the rendered ones, from the sorted values of the pixels lit in
    /// both: `None` with too few usable quantiles.
    pub quantile_response: Option<QuantileResponse>,
    /// Pixels at full scale in each image.
    pub saturated_real_px: usize,
    pub saturated_rendered_px: usize,
    /// Intersection over union of the two lit masks (real above the threshold, rendered lit).
    pub lit_iou: f64,
}

/// The real image's DN against the rendered image's, quantile by quantile over the pixels lit
/// in both (sorted values, so misregistration and texture errors do not enter): `real = scale *
/// rendered^exponent` fitted in logs to the 10th to 90th percentiles (quantiles at zero or at
/// full scale left out), and the ratio real / rendered at three of them. A camera whose response
/// is linear but whose gain differs from the model's gives an exponent of 1 and equal ratios; a
/// gamma (a power law on the DN) gives its exponent and ratios that fall with brightness.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct QuantileResponse {
    pub exponent: f64,
    pub scale: f64,
    pub ratio_p10: f64,
    pub ratio_p50: f64,
    pub ratio_p90: f64,
}

impl QuantileResponse {
    /// From the foreground values of both images (same count), in any order.
    pub fn fit(mut real: Vec<f64>, mut rendered: Vec<f64>, full_scale: f64) -> Option<Self> {
        if real.len() != rendered.len() || real.len() < 100 {
            return None;
        }
        real.sort_by(f64::total_cmp);
        rendered.sort_by(f64::total_cmp);
        let at = |q: f64| {
            let i = ((real.len() - 1) as f64 * q).round() as usize;
            (real[i], rendered[i])
        };
        let usable = |(r, y): (f64, f64)| r > 0.0 && y > 0.0 && r < full_scale && y < full_scale;
        let points: Vec<(f64, f64)> = (10..=90)
            .map(|p| at(p as f64 / 100.0))
            .filter(|&p| usable(p))
            .map(|(r, y)| (y.ln(), r.ln()))
            .collect();
        if points.len() < 10 {
            return None;
        }
        let n = points.len() as f64;
        let (mx, my) = points
            .iter()
            .fold((0.0, 0.0), |(a, b), &(x, y)| (a + x / n, b + y / n));
        let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
            (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
        });
        if sxx <= 0.0 {
            return None;
        }
        let exponent = sxy / sxx;
        let ratio = |q: f64| {
            let (r, y) = at(q);
            r / y
        };
        Some(QuantileResponse {
            exponent,
            scale: (my - exponent * mx).exp(),
            ratio_p10: ratio(0.10),
            ratio_p50: ratio(0.50),
            ratio_p90: ratio(0.90),
        })
    }
}

/// The values where `mask` is set, in order.
fn masked<'a>(values: &'a [f64], mask: &'a [bool]) -> impl Iterator<Item = f64> + 'a {
    values.iter().zip(mask).filter(|p| *p.1).map(|p| *p.0)
}

/// Aligns `rendered` on `real` and compares them; `full_scale` is `L` [DN] (255 at 8 bit).
pub fn compare(
    real: &Gray,
    rendered: &Gray,
    full_scale: f64,
    max_shift_px: i64,
) -> Result<Comparison, CompareError> {
    if (real.width, real.height) != (rendered.width, rendered.height) {
        return Err(CompareError::Size {
            real: (real.width, real.height),
            rendered: (rendered.width, rendered.height),
        });
    }
    let (w, h) = (real.width, real.height);
    // The box: the rendered body's light, widened by the shifts searched and the SSIM
    // window (a stray hot pixel or star far from the body must not widen it).
    let rb = bounding_box(rendered, |v| v > 0.0).ok_or(CompareError::Empty("rendered"))?;
    let m = max_shift_px + 6;
    let bx = rb.moved((-m, -m), (m, m)).clipped(w, h);
    let sky = median(&real.dn);
    if !real.dn.iter().any(|&v| v > sky) {
        return Err(CompareError::Empty("real"));
    }

    let ncc_at = |dx: i64, dy: i64| ncc(real, rendered, &bx, dx, dy);
    let ncc_unshifted = ncc_at(0, 0);
    let (mut best, mut shift) = (f64::NEG_INFINITY, (0, 0));
    for dy in -max_shift_px..=max_shift_px {
        for dx in -max_shift_px..=max_shift_px {
            let c = ncc_at(dx, dy);
            if c > best {
                (best, shift) = (c, (dx, dy));
            }
        }
    }
    let aligned = rendered.shifted(shift.0, shift.1);
    let bx = bx.moved(shift, shift).clipped(w, h);

    // Work on the box only: crop both images.
    let crop = |img: &Gray| -> Gray {
        let dn = (bx.y0..=bx.y1)
            .flat_map(|y| (bx.x0..=bx.x1).map(move |x| (x, y)))
            .map(|(x, y)| img.at(x, y))
            .collect();
        Gray::new(bx.width(), bx.height(), dn)
    };
    let (x, y) = (crop(real), crop(&aligned));

    let inactive: Vec<f64> =
        x.dn.iter()
            .zip(&y.dn)
            .filter(|&(_, &r)| r <= 0.0)
            .map(|(&v, _)| v)
            .collect();
    let threshold_dn = median(&inactive) + mean_std(&inactive).std;
    let real_lit: Vec<bool> = x.dn.iter().map(|&v| v > threshold_dn).collect();
    let fg: Vec<bool> = real_lit
        .iter()
        .zip(&y.dn)
        .map(|(&a, &r)| a || r > 0.0)
        .collect();
    // Lit in both images: the lit masks' intersection, and where the quantile response is
    // fitted (the halo the rendering lacks, and its own 8-bit zeros, would pile up at the low
    // quantiles).
    let lit_in_both: Vec<bool> = real_lit
        .iter()
        .zip(&y.dn)
        .map(|(&a, &r)| a && r > 0.0)
        .collect();
    let both = lit_in_both.iter().filter(|&&b| b).count();
    let foreground_px = fg.iter().filter(|&&f| f).count();

    let terms = |y: &Gray| {
        let maps = ssim_maps(&x, y, full_scale);
        let over_fg = |m: &[f64]| mean_std(&masked(m, &fg).collect::<Vec<_>>());
        SsimTerms {
            luminance: over_fg(&maps.luminance),
            contrast: over_fg(&maps.contrast),
            structure: over_fg(&maps.structure),
        }
    };
    let sum_fg = |img: &Gray| -> f64 { masked(&img.dn, &fg).sum() };
    let total_dn_ratio = sum_fg(&x) / sum_fg(&y);
    let matched = Gray::new(
        y.width,
        y.height,
        y.dn.iter()
            .map(|v| (v * total_dn_ratio).min(full_scale))
            .collect(),
    );
    let saturated = |img: &Gray| img.dn.iter().filter(|&&v| v >= full_scale).count();
    let on_both = |img: &Gray| -> Vec<f64> { masked(&img.dn, &lit_in_both).collect() };
    Ok(Comparison {
        shift_px: [shift.0, shift.1],
        ncc: best,
        ncc_unshifted,
        threshold_dn,
        foreground_px,
        ssim: terms(&y),
        total_dn_ratio,
        ssim_at_matched_total: terms(&matched),
        quantile_response: QuantileResponse::fit(on_both(&x), on_both(&y), full_scale),
        saturated_real_px: saturated(real),
        saturated_rendered_px: saturated(rendered),
        lit_iou: both as f64 / foreground_px.max(1) as f64,
    })
}

/// SSIM's three term maps (see the module's doc), same size as the inputs.
pub struct SsimMaps {
    pub luminance: Vec<f64>,
    pub contrast: Vec<f64>,
    pub structure: Vec<f64>,
}

/// The three SSIM term maps of `x` and `y` with the Gaussian window (sigma 1.5 px, 11 x 11,
/// edges replicated).
pub fn ssim_maps(x: &Gray, y: &Gray, full_scale: f64) -> SsimMaps {
    let c1 = (0.01 * full_scale).powi(2);
    let c2 = (0.03 * full_scale).powi(2);
    let c3 = c2 / 2.0;
    let blur = |v: Vec<f64>| gaussian_blur(&Gray::new(x.width, x.height, v), 1.5, 5).dn;
    let mx = blur(x.dn.clone());
    let my = blur(y.dn.clone());
    let mxx = blur(x.dn.iter().map(|a| a * a).collect());
    let myy = blur(y.dn.iter().map(|a| a * a).collect());
    let mxy = blur(x.dn.iter().zip(&y.dn).map(|(a, b)| a * b).collect());
    let n = x.dn.len();
    let (mut l, mut c, mut s) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        let (ux, uy) = (mx[i], my[i]);
        let vx = (mxx[i] - ux * ux).max(0.0);
        let vy = (myy[i] - uy * uy).max(0.0);
        let cxy = mxy[i] - ux * uy;
        let (sx, sy) = (vx.sqrt(), vy.sqrt());
        l[i] = (2.0 * ux * uy + c1) / (ux * ux + uy * uy + c1);
        c[i] = (2.0 * sx * sy + c2) / (vx + vy + c2);
        s[i] = (cxy + c3) / (sx * sy + c3);
    }
    SsimMaps {
        luminance: l,
        contrast: c,
        structure: s,
    }
}

/// Gaussian filter of `img` (the detector's PSF filter: normalised, edges replicated).
pub fn gaussian_blur(img: &Gray, sigma: f64, radius: usize) -> Gray {
    let dn = crate::detector::psf::gaussian_blur(&img.dn, img.width, img.height, sigma, radius);
    Gray::new(img.width, img.height, dn)
}

struct Box2 {
    x0: i64,
    y0: i64,
    x1: i64,
    y1: i64,
}

impl Box2 {
    fn width(&self) -> usize {
        (self.x1 - self.x0 + 1) as usize
    }
    fn height(&self) -> usize {
        (self.y1 - self.y0 + 1) as usize
    }

    /// This box with `low` added to its low corner and `high` to its high one.
    fn moved(&self, low: (i64, i64), high: (i64, i64)) -> Box2 {
        Box2 {
            x0: self.x0 + low.0,
            y0: self.y0 + low.1,
            x1: self.x1 + high.0,
            y1: self.y1 + high.1,
        }
    }

    /// This box within a `w x h` image.
    fn clipped(&self, w: usize, h: usize) -> Box2 {
        Box2 {
            x0: self.x0.max(0),
            y0: self.y0.max(0),
            x1: self.x1.min(w as i64 - 1),
            y1: self.y1.min(h as i64 - 1),
        }
    }
}

fn bounding_box(img: &Gray, lit: impl Fn(f64) -> bool) -> Option<Box2> {
    let mut b: Option<Box2> = None;
    for (i, &v) in img.dn.iter().enumerate() {
        if !lit(v) {
            continue;
        }
        let (x, y) = ((i % img.width) as i64, (i / img.width) as i64);
        b = Some(match b {
            None => Box2 {
                x0: x,
                y0: y,
                x1: x,
                y1: y,
            },
            Some(b) => Box2 {
                x0: b.x0.min(x),
                y0: b.y0.min(y),
                x1: b.x1.max(x),
                y1: b.y1.max(y),
            },
        });
    }
    b
}

/// Zero-mean NCC of `real` and `rendered` moved by `(dx, dy)`, over the box.
fn ncc(real: &Gray, rendered: &Gray, b: &Box2, dx: i64, dy: i64) -> f64 {
    let n = (b.width() * b.height()) as f64;
    let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for y in b.y0..=b.y1 {
        for x in b.x0..=b.x1 {
            let a = real.at(x, y);
            let r = rendered.at(x - dx, y - dy);
            sa += a;
            sb += r;
            saa += a * a;
            sbb += r * r;
            sab += a * r;
        }
    }
    let cov = sab - sa * sb / n;
    let va = saa - sa * sa / n;
    let vb = sbb - sb * sb / n;
    if va <= 0.0 || vb <= 0.0 {
        return 0.0;
    }
    cov / (va * vb).sqrt()
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

fn mean_std(v: &[f64]) -> MeanStd {
    if v.is_empty() {
        return MeanStd {
            mean: f64::NAN,
            std: 0.0,
        };
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    MeanStd {
        mean,
        std: var.sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lit disk with a darker "mare" in it, on a black sky.
    fn moon(cx: f64, cy: f64, gain: f64) -> Gray {
        let (w, h) = (160, 120);
        let dn = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (dx, dy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                let r2 = dx * dx + dy * dy;
                if r2 > 30.0 * 30.0 {
                    0.0
                } else if (dx - 8.0).powi(2) + (dy + 5.0).powi(2) < 100.0 {
                    (80.0 * gain).round()
                } else {
                    ((150.0 + dx) * gain).round()
                }
            })
            .collect();
        Gray::new(w, h, dn)
    }

    #[test]
    fn identical_images_score_one() {
        let a = moon(80.0, 60.0, 1.0);
        let c = compare(&a, &a, 255.0, 5).unwrap();
        assert_eq!(c.shift_px, [0, 0]);
        for t in [c.ssim.luminance, c.ssim.contrast, c.ssim.structure] {
            assert!((t.mean - 1.0).abs() < 1e-12, "{t:?}");
        }
        assert!((c.total_dn_ratio - 1.0).abs() < 1e-12);
        assert!((c.lit_iou - 1.0).abs() < 1e-12);
    }

    #[test]
    fn alignment_finds_the_shift_and_terms_see_gain() {
        let real = moon(83.0, 56.0, 1.0);
        let rendered = moon(80.0, 60.0, 1.0);
        let c = compare(&real, &rendered, 255.0, 8).unwrap();
        assert_eq!(c.shift_px, [3, -4]);
        assert!(c.ncc > 0.999 && c.ncc_unshifted < 0.9, "{c:?}");
        assert!(c.ssim.structure.mean > 0.999, "{c:?}");
        // A rendering twice too dark: structure stays, luminance and the DN ratio see it.
        let dark = moon(83.0, 56.0, 0.5);
        let c = compare(&real, &dark, 255.0, 8).unwrap();
        assert_eq!(c.shift_px, [0, 0]);
        assert!(c.ssim.luminance.mean < 0.85, "{c:?}");
        assert!(c.ssim.structure.mean > 0.99, "{c:?}");
        assert!((c.total_dn_ratio - 2.0).abs() < 0.02, "{c:?}");
        // Matched in total, the gain error is gone.
        assert!(c.ssim_at_matched_total.luminance.mean > 0.999, "{c:?}");
        // The quantiles see a gain: exponent 1, the same ratio at every brightness.
        let q = c.quantile_response.unwrap();
        assert!((q.exponent - 1.0).abs() < 0.02, "{q:?}");
        for r in [q.ratio_p10, q.ratio_p50, q.ratio_p90] {
            assert!((r - 2.0).abs() < 0.05, "{q:?}");
        }
    }

    /// A gamma on the real image's DN shows as the quantile response's exponent, with ratios
    /// that fall with brightness; shuffling the rendered pixels (a misregistration of the
    /// texture) does not change it.
    #[test]
    fn the_quantile_response_sees_a_gamma() {
        // The disk's pixels of a rendering and of a camera applying a gamma of 0.8 to them.
        let rendered: Vec<f64> = moon(80.0, 60.0, 0.5)
            .dn
            .into_iter()
            .filter(|&v| v > 0.0)
            .collect();
        let real: Vec<f64> = rendered
            .iter()
            .map(|v| (255.0 * (v / 255.0).powf(0.8)).round())
            .collect();
        let q = QuantileResponse::fit(real.clone(), rendered.clone(), 255.0).unwrap();
        assert!((q.exponent - 0.8).abs() < 0.01, "{q:?}");
        assert!(q.ratio_p10 > q.ratio_p90 * 1.05, "{q:?}");
        let mut shuffled = rendered;
        shuffled.reverse();
        assert_eq!(QuantileResponse::fit(real, shuffled, 255.0), Some(q));
    }

    #[test]
    fn the_window_is_wangs() {
        // The Gaussian window is normalised and keeps a constant image.
        let g = gaussian_blur(&Gray::new(20, 20, vec![7.0; 400]), 1.5, 5);
        assert!(g.dn.iter().all(|v| (v - 7.0).abs() < 1e-12));
        // Structure of an image against its negative is -1 where there is texture.
        let x = moon(80.0, 60.0, 1.0);
        let y = Gray::new(x.width, x.height, x.dn.iter().map(|v| 255.0 - v).collect());
        let m = ssim_maps(&x, &y, 255.0);
        let i = 60 * 160 + 88 - 10; // inside, near the mare's edge
        assert!(m.structure[i] < -0.9, "{}", m.structure[i]);
    }

    #[test]
    fn mismatched_or_empty_images_are_errors() {
        let a = moon(80.0, 60.0, 1.0);
        let b = Gray::new(10, 10, vec![0.0; 100]);
        assert!(matches!(
            compare(&a, &b, 255.0, 2),
            Err(CompareError::Size { .. })
        ));
        let dark = Gray::new(160, 120, vec![0.0; 160 * 120]);
        assert_eq!(
            compare(&a, &dark, 255.0, 2),
            Err(CompareError::Empty("rendered"))
        );
    }
}
