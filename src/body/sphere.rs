//! A sphere of uniform surface properties (paper Sec. 4), and its exactly known lit and
//! visible region, which the integration step uses on limb and terminator quadrangles.

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Radius [m].
    pub radius_m: f64,
}

/// The lit and visible part of a sphere in longitude and latitude, in a frame with the Sun on
/// +X and the camera in the XY plane at longitude `alpha` (the CSF of Sec. 4.1): lit where
/// `cos(lat) cos(lon) > R/d_sun`, visible where `cos(lat) cos(lon - alpha) > R/d_cam` (the
/// illumination and observability conditions, Eqs. 29 and 31, at finite distances).
#[derive(Clone, Copy, Debug)]
pub struct LitVisible {
    /// `R / d_sun`: lit where `cos(lat) cos(lon) > eps_sun`.
    eps_sun: f64,
    /// `R / d_cam`: visible where `cos(lat) cos(lon - alpha) > eps_cam`.
    eps_cam: f64,
    alpha: f64,
}

impl LitVisible {
    /// The region of a sphere of `radius_m` for a Sun at `sun_m` (on +X) and a camera at
    /// `camera_m` (in the XY plane), both from the centre [m].
    pub fn new(radius_m: f64, sun_m: DVec3, camera_m: DVec3) -> Self {
        LitVisible {
            eps_sun: radius_m / sun_m.length(),
            eps_cam: radius_m / camera_m.length(),
            alpha: camera_m.y.atan2(camera_m.x),
        }
    }

    /// Whether the longitude interval closes (its width goes to zero like a square root) at
    /// `cos(lat)`: the lit or the visible cap's edge in latitude.
    #[inline]
    pub fn closes_at(&self, cos_lat: f64) -> bool {
        const TOL: f64 = 1e-12;
        (cos_lat - self.eps_sun).abs() < TOL || (cos_lat - self.eps_cam).abs() < TOL
    }

    /// The lit and visible longitude interval at `cos(lat)` within `[p0, p1]` (CSF longitudes
    /// within (-pi, pi]); `None` when empty.
    #[inline(always)]
    pub fn lon_interval(&self, cos_lat: f64, p0: f64, p1: f64) -> Option<(f64, f64)> {
        if cos_lat <= self.eps_sun || cos_lat <= self.eps_cam {
            return None;
        }
        let a_s = (self.eps_sun / cos_lat).acos();
        let a_c = (self.eps_cam / cos_lat).acos();
        let lo = p0.max(-a_s).max(self.alpha - a_c);
        let hi = p1.min(a_s).min(self.alpha + a_c);
        (hi > lo).then_some((lo, hi))
    }

    /// Latitudes in `(l0, l1)` where an end of the interval switches curves, sorted, into
    /// `out` (at most 16).
    pub fn breaks(&self, p0: f64, p1: f64, l0: f64, l1: f64, out: &mut [f64; 16]) -> usize {
        let mut n = 0;
        let mut push = |cos_lat: f64| {
            if cos_lat > 0.0 && cos_lat < 1.0 {
                let lat = cos_lat.acos();
                for l in [lat, -lat] {
                    if l > l0 && l < l1 && n < out.len() {
                        out[n] = l;
                        n += 1;
                    }
                }
            }
        };
        // Where an interval end reaches a side of the quadrangle: a = |p| on either curve.
        for p in [p0, p1] {
            push(self.eps_sun / p.cos());
            push(self.eps_cam / (p - self.alpha).cos());
        }
        // Where the limb crosses the terminator (the crossing lies at |lon| < pi/2, where the
        // terminator is).
        let (sa, ca) = self.alpha.sin_cos();
        if sa.abs() > 1e-12 {
            let lon = ((self.eps_cam / self.eps_sun - ca) / sa).atan();
            push(self.eps_sun / lon.cos());
        }
        // Where either interval closes.
        push(self.eps_sun);
        push(self.eps_cam);
        out[..n].sort_by(f64::total_cmp);
        n
    }
}
