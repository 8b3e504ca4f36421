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
