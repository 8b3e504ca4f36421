//! Sampling of quadrangles (Sec. 4.3): longitude and latitude edges in CSF, uniform or
//! projected-uniform (Eqs. 20-22), and how many of each (Eq. 23, or square in the image).
//!
//! Projected-uniform sampling asks that each longitude step project to the same length `h`
//! on the plane normal to the camera direction: `h = 2 sin(dPhi/2) cos(Phi + dPhi/2 - alpha)`
//! (Eq. 20), which is `sin(Phi_{k+1} - alpha) - sin(Phi_k - alpha)`. The implicit equation
//! (Eq. 22) therefore has the closed-form solution
//! `Phi_k = alpha + asin(sin(Phi_min - alpha) + k H / N)`, used here instead of iterating
//! (latitudes: the same with `alpha = 0`).

use super::bounding::Bounds;
use super::pruning::{PRUNED, classify};
use super::settings::{PointBudget, Sampling, Settings, Split};
use super::view::View;
use glam::DVec3;

/// `n + 1` edges spanning `[lo, hi]`.
pub fn edges(lo: f64, hi: f64, n: usize, sampling: Sampling, center: f64) -> Vec<f64> {
    let h = std::f64::consts::FRAC_PI_2;
    let mut e: Vec<f64> = match sampling {
        Sampling::Uniform => (0..=n)
            .map(|k| lo + (hi - lo) * k as f64 / n as f64)
            .collect(),
        Sampling::ProjectedUniform => {
            let a = (lo - center).clamp(-h, h).sin();
            let b = (hi - center).clamp(-h, h).sin();
            (0..=n)
                .map(|k| center + (a + (b - a) * k as f64 / n as f64).clamp(-1.0, 1.0).asin())
                .collect()
        }
    };
    e[0] = lo;
    e[n] = hi;
    e
}

/// Sines and cosines of a grid's edges and midpoints (Eq. 25), computed once per frame.
pub struct GridTrig {
    pub lon: Vec<f64>,
    pub lat: Vec<f64>,
    lon_edge: Vec<(f64, f64)>,
    lat_edge: Vec<(f64, f64)>,
    lon_mid: Vec<(f64, f64)>,
    lat_mid: Vec<(f64, f64)>,
}

impl GridTrig {
    pub fn new(lon: Vec<f64>, lat: Vec<f64>) -> Self {
        let sc = |x: &f64| x.sin_cos();
        let mids = |e: &[f64]| {
            e.windows(2)
                .map(|w| (0.5 * (w[0] + w[1])).sin_cos())
                .collect::<Vec<_>>()
        };
        GridTrig {
            lon_edge: lon.iter().map(sc).collect(),
            lat_edge: lat.iter().map(sc).collect(),
            lon_mid: mids(&lon),
            lat_mid: mids(&lat),
            lon,
            lat,
        }
    }
    pub fn n_lon(&self) -> usize {
        self.lon.len() - 1
    }
    pub fn n_lat(&self) -> usize {
        self.lat.len() - 1
    }
    #[inline(always)]
    fn dir(lo: (f64, f64), la: (f64, f64)) -> DVec3 {
        DVec3::new(la.1 * lo.1, la.1 * lo.0, la.0)
    }
    /// Unit direction of the midpoint of quadrangle `(i, k)`.
    #[inline(always)]
    pub fn mid_dir(&self, i: usize, k: usize) -> DVec3 {
        Self::dir(self.lon_mid[i], self.lat_mid[k])
    }
    /// Unit direction of grid vertex `(i, k)`, `i <= n_lon`, `k <= n_lat`.
    #[inline(always)]
    pub fn vertex_dir(&self, i: usize, k: usize) -> DVec3 {
        Self::dir(self.lon_edge[i], self.lat_edge[k])
    }
    /// Corners in order around the quadrangle (Eq. 24).
    #[inline(always)]
    pub fn corner_dirs(&self, i: usize, k: usize) -> [DVec3; 4] {
        [
            self.vertex_dir(i, k),
            self.vertex_dir(i + 1, k),
            self.vertex_dir(i + 1, k + 1),
            self.vertex_dir(i, k + 1),
        ]
    }
}

/// How many quadrangles to sample along longitude and latitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plan {
    pub n_lon: usize,
    pub n_lat: usize,
    /// Estimated pixels of the final image covered by lit, visible surface.
    pub covered_px: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error(
    "the frame needs {needed} quadrangles ({n_lon} x {n_lat}) but render.max_points is {max}: lower the point budget or raise max_points"
)]
pub struct TooManyPoints {
    pub needed: usize,
    pub n_lon: usize,
    pub n_lat: usize,
    pub max: usize,
}

const PILOT: usize = 32;

/// Plans the grid from a coarse pilot grid over the bounds: the pilot measures the covered
/// pixels (projected area of the kept pilot quadrangles), the fraction kept and the mean
/// image size of a quadrangle along longitude and along latitude.
pub fn plan(view: &View, bounds: &Bounds, settings: &Settings) -> Result<Plan, TooManyPoints> {
    let alpha = view.grid.phase_rad;
    let pilot = GridTrig::new(
        edges(bounds.lon.0, bounds.lon.1, PILOT, settings.sampling, alpha),
        edges(bounds.lat.0, bounds.lat.1, PILOT, settings.sampling, 0.0),
    );
    let px2 = view.m * view.m;
    let (mut kept, mut area, mut len_lon, mut len_lat) = (0usize, 0.0, 0.0, 0.0);
    for k in 0..PILOT {
        for i in 0..PILOT {
            let corners = pilot.corner_dirs(i, k);
            if classify(view, pilot.mid_dir(i, k), corners) == PRUNED {
                continue;
            }
            let px: Vec<Option<[f64; 2]>> = corners
                .iter()
                .map(|&d| view.pixel(view.to_camera(view.surface(d).0)))
                .collect();
            let (Some(a), Some(b), Some(c), Some(d)) = (px[0], px[1], px[2], px[3]) else {
                continue;
            };
            kept += 1;
            let dist =
                |p: [f64; 2], q: [f64; 2]| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
            let (l_lon, l_lat) = (
                0.5 * (dist(a, b) + dist(d, c)),
                0.5 * (dist(a, d) + dist(b, c)),
            );
            // A sliver (a thin crescent's quadrangle, foreshortened at the limb) covers less
            // than a pixel across but touches a pixel per pixel of its length.
            let quad_area =
                0.5 * ((a[0] - c[0]) * (b[1] - d[1]) - (b[0] - d[0]) * (a[1] - c[1])).abs() / px2;
            area += quad_area.max(l_lon.max(l_lat) / view.m);
            len_lon += l_lon;
            len_lat += l_lat;
        }
    }
    // Only part of the image: the covered area cannot exceed the frame.
    let frame_px = view.intrinsics.width_px as f64 * view.intrinsics.height_px as f64;
    let covered_px = area.min(frame_px);
    let (n_lon, n_lat) = if kept == 0 {
        (64, 64)
    } else {
        let target = match settings.points {
            PointBudget::Total(n) => n as f64,
            PointBudget::PerPixel(p) => p * covered_px.max(1.0),
        }
        .max(settings.min_points as f64)
        .max(1.0);
        let kept_frac = kept as f64 / (PILOT * PILOT) as f64;
        match settings.split {
            Split::Aspect => {
                let ratio = (len_lon / len_lat.max(1e-300)).clamp(1e-3, 1e3);
                let a_lat = (target / (kept as f64 * ratio)).sqrt();
                let a_lon = ratio * a_lat;
                (
                    (PILOT as f64 * a_lon).ceil().max(1.0) as usize,
                    (PILOT as f64 * a_lat).ceil().max(1.0) as usize,
                )
            }
            Split::Eq23 => {
                let n = target / kept_frac;
                let lit = 0.5 * (1.0 + alpha.cos());
                let n_lat = (n / lit.max(1e-3)).sqrt();
                (
                    (n_lat * lit).ceil().max(1.0) as usize,
                    n_lat.ceil().max(1.0) as usize,
                )
            }
        }
    };
    let needed = n_lon.saturating_mul(n_lat);
    if needed > settings.max_points {
        return Err(TooManyPoints {
            needed,
            n_lon,
            n_lat,
            max: settings.max_points,
        });
    }
    Ok(Plan {
        n_lon,
        n_lat,
        covered_px,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projected_uniform_edges_have_equal_projections() {
        let alpha = 0.7;
        let e = edges(
            alpha - 1.2,
            alpha + 0.9,
            50,
            Sampling::ProjectedUniform,
            alpha,
        );
        let h: Vec<f64> = e
            .windows(2)
            .map(|w| (w[1] - alpha).sin() - (w[0] - alpha).sin())
            .collect();
        for x in &h {
            assert!((x - h[0]).abs() < 1e-12);
        }
        // Eq. 20 form of the same step.
        let (p, dp) = (e[3], e[4] - e[3]);
        assert!((2.0 * (dp / 2.0).sin() * (p + dp / 2.0 - alpha).cos() - h[0]).abs() < 1e-12);
    }
}
