//! The body being rendered: its shape and its reflectance.
//!
//! Shapes sit behind [`Shape`] so that later shapes (ellipsoids, DEM-displaced spheres,
//! triangle meshes) stand beside the sphere without touching the renderer's steps: the
//! renderer asks a shape for its bounding radius, the surface point and normal in a direction
//! from the centre, and the first intersection of a ray.

pub mod maps;
pub mod sphere;

use crate::brdf::Brdf;
use glam::DVec3;
pub use sphere::{LitVisible, Sphere};

#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Sphere(Sphere),
}

impl Shape {
    /// Radius of a sphere centred on the body that contains the whole surface [m].
    pub fn bounding_radius_m(&self) -> f64 {
        match self {
            Shape::Sphere(s) => s.radius_m,
        }
    }

    /// Radius of a sphere centred on the body that the surface contains [m].
    pub fn inner_radius_m(&self) -> f64 {
        match self {
            Shape::Sphere(s) => s.radius_m,
        }
    }

    /// Surface point [m] and outward unit normal in the direction `dir` (unit, from the centre).
    #[inline(always)]
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        match self {
            Shape::Sphere(s) => (dir * s.radius_m, dir),
        }
    }

    /// Distance to the first intersection of the ray `origin + t dir` (`dir` unit) with `t > 0`.
    #[inline]
    pub fn intersect(&self, origin: DVec3, dir: DVec3) -> Option<f64> {
        match self {
            Shape::Sphere(s) => crate::geometry::ray_sphere(origin, dir, s.radius_m),
        }
    }

    /// The exactly known lit and visible region in longitude and latitude, for a Sun at
    /// `sun_m` on +X and a camera at `camera_m` in the XY plane (CSF); `None` for shapes
    /// without one (the integrator then clamps a trapezoidal rule instead).
    pub fn lit_visible(&self, sun_m: DVec3, camera_m: DVec3) -> Option<LitVisible> {
        match self {
            Shape::Sphere(s) => Some(LitVisible::new(s.radius_m, sun_m, camera_m)),
        }
    }

    /// Whether a point [m] (body frame) lies inside the body.
    pub fn contains(&self, p: DVec3) -> bool {
        match self {
            Shape::Sphere(s) => p.length() < s.radius_m,
        }
    }
}

/// A body: name, shape and reflectance model, with an optional albedo map.
#[derive(Clone, Debug, PartialEq)]
pub struct Body {
    pub name: String,
    pub shape: Shape,
    /// The reflectance model, scaled to the body's configured albedo (used where there is no
    /// map, or outside a regional one).
    pub brdf: Brdf,
    pub albedo_map: Option<AlbedoMap>,
    /// Surface relief from a DEM: it tilts the normals the BRDF sees (shading). It does not
    /// yet displace the surface or cast shadows (issue 3).
    pub relief: Option<Relief>,
}

/// The slopes of a DEM, as maps of `dh/d(east)` and `dh/d(north)` [m/m] on the DEM's grid,
/// by central differences (wrapping in longitude); the normal at a point is
/// `normalize(up - s_e east - s_n north)`, which is the average of the neighbouring facet
/// normals of the paper (Sec. 4.4) in the limit of a fine grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Relief {
    pub heights_m: std::sync::Arc<maps::Map>,
    slope_east: std::sync::Arc<maps::Map>,
    slope_north: std::sync::Arc<maps::Map>,
}

impl Relief {
    /// Slopes of `heights_m` (a DEM in metres above a sphere of `radius_m`).
    pub fn new(heights_m: maps::Map, radius_m: f64) -> Result<Relief, maps::MapError> {
        let (w, h) = (heights_m.width, heights_m.height);
        let v = |r: usize, c: usize| heights_m.values[r * w + c] as f64;
        let (dlon, dlat) = heights_m.spacing_rad();
        let wraps = heights_m.wraps();
        let mut east = Vec::with_capacity(w * h);
        let mut north = Vec::with_capacity(w * h);
        for r in 0..h {
            let lat = heights_m.row_lat(r);
            let (rn, rs) = (r.saturating_sub(1), (r + 1).min(h - 1));
            for c in 0..w {
                let (cw, ce) = if wraps {
                    ((c + w - 1) % w, (c + 1) % w)
                } else {
                    (c.saturating_sub(1), (c + 1).min(w - 1))
                };
                // Two texels across, one at the edge of a regional map.
                let texels = if wraps { 2.0 } else { (ce - cw).max(1) as f64 };
                let metres_e = radius_m * lat.cos().max(1e-6) * texels * dlon;
                east.push((v(r, ce) - v(r, cw)) / metres_e);
                let metres_n = radius_m * (rs - rn).max(1) as f64 * dlat;
                north.push((v(rn, c) - v(rs, c)) / metres_n);
            }
        }
        let slope = |values| heights_m.with_values(values).map(std::sync::Arc::new);
        Ok(Relief {
            slope_east: slope(east)?,
            slope_north: slope(north)?,
            heights_m: std::sync::Arc::new(heights_m),
        })
    }

    /// The surface normal (body frame) over the unit direction `up` from the centre.
    #[inline]
    pub fn normal(&self, up: DVec3) -> DVec3 {
        let (lon, lat) = crate::geometry::lon_lat(up);
        let (Some(se), Some(sn)) = (
            self.slope_east.sample(lon, lat),
            self.slope_north.sample(lon, lat),
        ) else {
            return up;
        };
        let e = DVec3::Z.cross(up);
        let east = if e.length_squared() > 1e-24 {
            e.normalize()
        } else {
            DVec3::Y
        };
        let north = up.cross(east);
        (up - se * east - sn * north).normalize()
    }
}

/// An albedo map and how its values become the BRDF's scale parameter.
#[derive(Clone, Debug, PartialEq)]
pub struct AlbedoMap {
    pub map: std::sync::Arc<maps::Map>,
    /// BRDF scale per unit map value: the albedo of the configured type that a scale of 1
    /// gives, inverted (1 where the map holds Hapke's or Lommel-Seeliger's `w` itself).
    pub scale_per_value: f64,
}

impl AlbedoMap {
    /// The BRDF scale at the body-frame unit direction `n_body`, or `fallback` outside the map.
    #[inline]
    pub fn scale_at(&self, n_body: DVec3, fallback: f64) -> f64 {
        let (lon, lat) = crate::geometry::lon_lat(n_body);
        self.map
            .sample(lon, lat)
            .map_or(fallback, |v| v * self.scale_per_value)
    }
}
