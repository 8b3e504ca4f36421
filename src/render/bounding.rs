//! Bounding of the longitude and latitude domains in CSF (Sec. 4.2, Eqs. 13-19).
//!
//! The region to sample is the part of the visible cap that the FOV sees. Longitude and
//! latitude have no extremum inside a region that excludes the CSF poles, and the poles are
//! never visible (the camera lies in the CSF XY plane, so the visible cap, of half-angle
//! `acos(R/d) < 90 deg` around an equatorial point, never reaches them). The extremes therefore
//! lie on the region's boundary, which is made of (a) the FOV perimeter lines of sight that hit
//! the body and (b) the arcs of the tangency (limb) circle inside the FOV. Both are sampled,
//! more densely each iteration until the limits move less than the tolerance. When neither
//! yields a point the body is wholly outside the FOV (the condition of Eq. 19) and the frame is
//! black. The result is intersected with the lit longitudes and padded by a margin.
//!
//! All of it happens in the grid's space ([`super::view::Grid`]): the CSF for a sphere, the
//! parameter space for an ellipsoid, where the ellipsoid is the unit sphere. A displacing DEM's
//! surface lies between two spheres, of its lowest and highest points: the caps are the inner
//! sphere's, and the lines of sight are followed from the outer sphere to the inner one.

use super::view::View;
use crate::geometry::{lon_lat, wrap_pi};
use glam::DVec3;

/// Sampling limits in CSF [rad].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub lon: (f64, f64),
    pub lat: (f64, f64),
}

impl Bounds {
    /// Every direction from the centre.
    pub const WHOLE: Bounds = Bounds {
        lon: (-std::f64::consts::PI, std::f64::consts::PI),
        lat: (-std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2),
    };
}

/// Limits of the region the camera can see, or `None` for a black frame.
pub fn bound(view: &View, tolerance_rad: f64) -> Option<Bounds> {
    let g = &view.grid;
    // A displacing DEM's surface lies between the spheres of its lowest and highest points:
    // it is seen and lit within the caps of the inner one (every limb and terminator point of
    // the surface is, being a tangent point of the sphere of its own radius), and a line of
    // sight meets it between the two.
    let (r, r_min) = (g.radius, g.radius_min);
    let d = g.cam.length();
    let c_hat = g.cam / d;
    let alpha = g.phase_rad;
    let beta = (r_min / d).clamp(-1.0, 1.0).acos(); // visible cap half-angle
    let beta_sun = (r_min / g.sun.length()).clamp(-1.0, 1.0).acos(); // lit cap half-angle
    let (e1, e2) = (DVec3::Z, c_hat.cross(DVec3::Z).normalize());
    let csf_from_camera = view.camera_from_csf.transpose();
    let (w, h) = (
        view.intrinsics.width_px as f64,
        view.intrinsics.height_px as f64,
    );

    let mut prev: Option<Bounds> = None;
    let mut n = 64usize;
    loop {
        let mut acc = Acc::new(alpha);
        // (a) FOV perimeter lines of sight, on the image border (pixel coordinates).
        for k in 0..n {
            let t = k as f64 / n as f64;
            for (u, v) in [
                (t * w, 0.0),
                (w, t * h),
                ((1.0 - t) * w, h),
                (0.0, (1.0 - t) * h),
            ] {
                let (x, y) = view.intrinsics.unproject(u, v);
                let (o, dir) = view.grid_ray((csf_from_camera * DVec3::new(x, y, 1.0)).normalize());
                if let Some(t) = crate::geometry::ray_sphere(o, dir, r) {
                    acc.push(o + dir * t);
                    if r_min < r {
                        // Where it meets the inner sphere, or passes closest to the centre:
                        // the surface point's direction lies between that and the entry's.
                        let t_in = crate::geometry::ray_sphere(o, dir, r_min)
                            .unwrap_or_else(|| -o.dot(dir));
                        acc.push(o + dir * t_in);
                    }
                }
            }
        }
        // (b) The tangency (limb) circle of the inner sphere, where it, or the outer sphere's
        // point over it, is inside the FOV.
        for k in 0..4 * n {
            let tau = std::f64::consts::TAU * k as f64 / (4 * n) as f64;
            let u = beta.cos() * c_hat + beta.sin() * (tau.cos() * e1 + tau.sin() * e2);
            let seen = |radius: f64| view.in_fov(view.to_camera(view.csf_from_grid(u * radius)));
            if seen(r_min) || (r_min < r && seen(r)) {
                acc.push(u);
            }
        }
        let cur = acc.bounds();
        let done = match (prev, cur) {
            (_, None) if n >= 512 => true,
            (Some(a), Some(b)) => {
                (a.lon.0 - b.lon.0)
                    .abs()
                    .max((a.lon.1 - b.lon.1).abs())
                    .max((a.lat.0 - b.lat.0).abs())
                    .max((a.lat.1 - b.lat.1).abs())
                    < tolerance_rad
            }
            _ => false,
        };
        prev = cur.or(prev);
        if done || n >= 8192 {
            break;
        }
        n *= 2;
    }
    let b = prev?;
    // Pad by a few perimeter steps, then clip to the visible cap and to the lit longitudes.
    let pad_lon = (b.lon.1 - b.lon.0) * 8.0 / n as f64 + 1e-9;
    let pad_lat = (b.lat.1 - b.lat.0) * 8.0 / n as f64 + 1e-9;
    let lon = (
        (b.lon.0 - pad_lon).max(alpha - beta).max(-beta_sun),
        (b.lon.1 + pad_lon).min(alpha + beta).min(beta_sun),
    );
    let lat = (
        (b.lat.0 - pad_lat).max(-beta),
        (b.lat.1 + pad_lat).min(beta),
    );
    if lon.1 <= lon.0 || lat.1 <= lat.0 {
        return None;
    }
    Some(Bounds { lon, lat })
}

/// Running extremes, with longitudes unwrapped around the camera's longitude `alpha`.
struct Acc {
    alpha: f64,
    b: Option<Bounds>,
}

impl Acc {
    fn new(alpha: f64) -> Self {
        Acc { alpha, b: None }
    }
    fn push(&mut self, p: DVec3) {
        let (lon, lat) = lon_lat(p);
        let lon = self.alpha + wrap_pi(lon - self.alpha);
        self.b = Some(match self.b {
            None => Bounds {
                lon: (lon, lon),
                lat: (lat, lat),
            },
            Some(b) => Bounds {
                lon: (b.lon.0.min(lon), b.lon.1.max(lon)),
                lat: (b.lat.0.min(lat), b.lat.1.max(lat)),
            },
        });
    }
    fn bounds(&self) -> Option<Bounds> {
        self.b
    }
}
