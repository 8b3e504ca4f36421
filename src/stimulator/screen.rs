//! Where the image sits on the screen and how camera pixels map onto screen pixels.
//!
//! Through the collimator (focal length `f_col`) a screen pixel of pitch `p_scr` subtends
//! `p_scr / f_col` rad; a flight-camera pixel of pitch `p_cam` behind a lens of focal length
//! `f_cam` subtends `p_cam / f_cam`. One screen pixel therefore covers
//! `scale = (p_scr / f_col) / (p_cam / f_cam)` camera pixels along each axis.
//!
//! F_eff is a per-camera-pixel quantity (what the camera pixel would collect: Eq. 58), so a
//! screen pixel must show the *mean* F_eff of the camera pixels it covers, weighted by the
//! overlapping area, and a camera pixel receives the area-weighted mean of the screen pixels
//! it sees. Both directions conserve `sum F_eff x area` ([`Resampler`]). With `scale = 1`
//! (the `one_to_one` mapping) both are the identity.

/// Separable area-overlap resampling between the camera grid and the screen region.
#[derive(Clone, Debug, PartialEq)]
pub struct Resampler {
    camera_px: [usize; 2],
    region_px: [usize; 2],
    /// Camera pixels per screen pixel, per axis.
    scale: [f64; 2],
    /// Per axis, per screen pixel: `(first camera pixel, overlaps [camera px])`.
    weights: [Vec<(usize, Vec<f64>)>; 2],
    identity: bool,
}

impl Resampler {
    /// `scale[a]` camera pixels per screen pixel along axis `a` (u, v). The region is the
    /// smallest that covers the camera frame: `ceil(camera / scale)` screen pixels.
    pub fn new(camera_px: [usize; 2], scale: [f64; 2]) -> Resampler {
        let identity = scale == [1.0, 1.0];
        let region_px = Resampler::region_px_for(camera_px, scale);
        let weights = [0, 1].map(|a| {
            (0..region_px[a])
                .map(|j| {
                    let (lo, hi) = (j as f64 * scale[a], (j + 1) as f64 * scale[a]);
                    let first = lo.floor() as usize;
                    let last = (hi.ceil() as usize).min(camera_px[a]);
                    let w = (first..last)
                        .map(|i| (hi.min((i + 1) as f64) - lo.max(i as f64)).max(0.0))
                        .collect();
                    (first, w)
                })
                .collect()
        });
        Resampler {
            camera_px,
            region_px,
            scale,
            weights,
            identity,
        }
    }

    pub fn region_px(&self) -> [usize; 2] {
        self.region_px
    }

    /// One screen pixel per camera pixel.
    pub fn is_identity(&self) -> bool {
        self.identity
    }

    /// The region, in screen pixels, that covers a camera frame: `ceil(camera / scale)`.
    pub fn region_px_for(camera_px: [usize; 2], scale: [f64; 2]) -> [usize; 2] {
        // A hair under the exact quotient so that 1024 / (1024 / 512) is 512, not 513.
        [0, 1].map(|a| ((camera_px[a] as f64 / scale[a]) * (1.0 - 1e-12)).ceil() as usize)
    }

    /// Camera-grid F_eff -> screen-region F_eff times `gain`: each screen pixel gets the
    /// area-weighted mean of the camera pixels it covers (the part outside the camera frame
    /// counts as dark). In parallel over region rows.
    pub fn to_screen(&self, camera: &[f64], gain: f64, out: &mut Vec<f64>) {
        use rayon::prelude::*;
        if self.identity {
            camera.par_iter().map(|f| f * gain).collect_into_vec(out);
            return;
        }
        let [cw, _] = self.camera_px;
        let rw = self.region_px[0];
        let norm = gain / (self.scale[0] * self.scale[1]);
        out.clear();
        out.resize(rw * self.region_px[1], 0.0);
        out.par_chunks_mut(rw)
            .zip(self.weights[1].par_iter())
            .for_each(|(row_out, (v0, wv))| {
                for (o, (u0, wu)) in row_out.iter_mut().zip(&self.weights[0]) {
                    let mut sum = 0.0;
                    for (dv, &a) in wv.iter().enumerate() {
                        let row = &camera[(v0 + dv) * cw + u0..];
                        for (du, &b) in wu.iter().enumerate() {
                            sum += a * b * row[du];
                        }
                    }
                    *o = sum * norm;
                }
            });
    }

    /// Screen-region F_eff -> camera-grid F_eff: each camera pixel gets the area-weighted mean
    /// of the screen pixels it sees.
    pub fn to_camera(&self, screen: &[f64], out: &mut Vec<f64>) {
        out.clear();
        if self.identity {
            out.extend_from_slice(screen);
            return;
        }
        let [cw, ch] = self.camera_px;
        let rw = self.region_px[0];
        out.resize(cw * ch, 0.0);
        for (j, (v0, wv)) in self.weights[1].iter().enumerate() {
            for (i, (u0, wu)) in self.weights[0].iter().enumerate() {
                let f = screen[j * rw + i];
                for (dv, &a) in wv.iter().enumerate() {
                    let row = &mut out[(v0 + dv) * cw + u0..];
                    for (du, &b) in wu.iter().enumerate() {
                        row[du] += a * b * f;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Vec<f64> {
        (0..w * h)
            .map(|k| 1.0 + (k % w) as f64 * 0.3 + (k / w) as f64 * 0.1)
            .collect()
    }

    #[test]
    fn one_to_one_is_the_identity() {
        let r = Resampler::new([5, 3], [1.0, 1.0]);
        assert_eq!(r.region_px(), [5, 3]);
        let cam = ramp(5, 3);
        let (mut s, mut c) = (Vec::new(), Vec::new());
        r.to_screen(&cam, 1.0, &mut s);
        r.to_camera(&s, &mut c);
        assert_eq!(cam, c);
    }

    /// Integer and fractional scales: the flux `sum F x area` is the same on both grids.
    #[test]
    fn resampling_conserves_flux() {
        for scale in [[2.0, 2.0], [1.5, 0.75], [0.6, 2.5]] {
            let (w, h) = (12, 9);
            let r = Resampler::new([w, h], scale);
            let cam = ramp(w, h);
            let (mut s, mut c) = (Vec::new(), Vec::new());
            r.to_screen(&cam, 1.0, &mut s);
            let [rw, rh] = r.region_px();
            assert_eq!(s.len(), rw * rh);
            let cam_flux: f64 = cam.iter().sum();
            let scr_flux: f64 = s.iter().sum::<f64>() * scale[0] * scale[1];
            assert!((scr_flux / cam_flux - 1.0).abs() < 1e-12, "{scale:?}");
            // Back to the camera: a uniform screen gives a uniform camera image wherever the
            // screen covers the camera pixel fully.
            let uniform = vec![2.0; rw * rh];
            r.to_camera(&uniform, &mut c);
            for (k, &x) in c.iter().enumerate() {
                assert!((x - 2.0).abs() < 1e-12, "{scale:?} px {k}: {x}");
            }
        }
    }

    /// 2 x 2 binning: each screen pixel is the mean of its four camera pixels.
    #[test]
    fn a_scale_of_two_averages_blocks() {
        let r = Resampler::new([4, 2], [2.0, 2.0]);
        let cam = vec![1.0, 3.0, 5.0, 7.0, 1.0, 3.0, 5.0, 7.0];
        let mut s = Vec::new();
        r.to_screen(&cam, 1.0, &mut s);
        assert_eq!(s, vec![2.0, 6.0]);
    }
}
