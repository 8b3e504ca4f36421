//! Every accuracy/speed knob of the renderer, in one plain struct that a sweep can vary.

use super::gridding::Gridding;
use super::reconstruction::Reconstruction;
use serde::{Deserialize, Serialize};

/// How many quadrangles to sample.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PointBudget {
    /// A fixed number of quadrangles kept after pruning (approximately).
    Total(usize),
    /// Quadrangles per pixel the body covers (of the final image, before super-sampling).
    PerPixel(f64),
}

/// Longitude/latitude sampling (Sec. 4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Sampling {
    Uniform,
    /// Uniform in the projection on the plane normal to the camera direction (Eqs. 20-22).
    ProjectedUniform,
}

/// How the budget is split between longitude and latitude.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Eq. 23: `N_lat = sqrt(N / ((1 + cos a)/2))`, `N_lon = N_lat (1 + cos a)/2`.
    Eq23,
    /// Quadrangles about square in the image, measured on a pilot grid.
    Aspect,
}

/// Integration of the BRDF over each quadrangle (Sec. 4.6).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "method")]
pub enum Integration {
    /// Exact where a closed form exists (Lambert, Area), trapezoidal otherwise.
    Auto { points_per_deg: f64 },
    /// Closed form (Eqs. 34-36); an error for BRDFs without one.
    Exact,
    /// Trapezoidal rule with `points_per_deg` points per degree of quadrangle span (at least 2
    /// per side); each sample uses its own Sun and camera directions and distances.
    Trapezoidal { points_per_deg: f64 },
    /// The composite midpoint rule on the same sub-grid (nodes at the cells' centres, at least
    /// 1 per side): no node on a shared edge, so fewer evaluations for the same order.
    Midpoint { points_per_deg: f64 },
    /// BRDF at the midpoint times the quadrangle's area (Eqs. 37-38).
    Pointwise,
}

/// FOV shape for pruning (Eqs. 26-27).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FovShape {
    /// The image rectangle (Eq. 27), distortion included.
    Frustum,
    /// The cone circumscribing the image (Eq. 26): cheaper, keeps a little more.
    Cone,
}

/// How the relief shadows itself (Sec. 4.5, item 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SelfShadowing {
    Off,
    /// Rays marched over the DEM towards the Sun and the camera (Eq. 33), from the points
    /// where the terrain could block them: exact to the DEM, about a microsecond a point.
    RayMarching,
    /// The body's horizon: the direction is blocked when it rises less than the local
    /// horizon's elevation angle. One lookup a point. From a horizon map, the same in every
    /// azimuth (an approximation), or computed from the DEM in azimuth bins
    /// (`body.horizon_azimuths`, close to ray marching once computed; see `docs/scene.md`).
    HorizonMap,
}

/// How a quadrangle reads the albedo map (paper Sec. 4.4 samples it at the centre).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapFilter {
    /// The map's value at the quadrangle's centre (bilinear between texels): aliases once a
    /// quadrangle spans several texels.
    Point,
    /// The mean over the quadrangle, from the map's area-averaged levels
    /// ([`crate::body::AlbedoMap::scale_over`]); the point value while a quadrangle is no
    /// wider than a texel.
    Area,
    /// The quadrangles integrate the geometry with the map's mean; each pixel then reads the
    /// map over its own footprint on the surface ([`super::footprint`]): the map within the
    /// pixel however many quadrangles the pixel receives.
    Pixel,
    /// As `Pixel`, and the relief too (an undisplaced DEM): the quadrangles integrate the
    /// smooth shape, unshadowed, and each pixel's reads carry the DEM's normal and the
    /// shadows of `self_shadowing` ([`super::footprint`]): the relief's shading within the
    /// pixel, where the quadrangles' grid spread each one's mean over the pixels it covers.
    Relief,
}

impl MapFilter {
    /// Whether each pixel reads the map over its own footprint (`Pixel` and `Relief`).
    pub fn per_pixel(self) -> bool {
        matches!(self, MapFilter::Pixel | MapFilter::Relief)
    }

    /// Why this filter cannot read `body`'s maps (the filters that can, as the typed errors
    /// of the config and the renderer name them), or `None` where it can.
    pub fn refusal(self, body: &crate::body::Body) -> Option<&'static str> {
        if !body.band_maps.is_empty() && !self.per_pixel() {
            return Some(
                "\"pixel\" or \"relief\" for a body with maps of its own per band \
                 (body.band_map): they are read over each pixel's footprint",
            );
        }
        if self != MapFilter::Relief {
            return None;
        }
        if body.albedo_map.is_none() {
            return Some(
                "\"relief\" only for a body with an albedo map (body.albedo_map), whose reads \
                 over each pixel carry the relief",
            );
        }
        if body.relief.as_ref().is_some_and(|r| r.displaces()) {
            return Some(
                "\"pixel\" or \"area\" for a displaced DEM (body.dem_map with displace): \
                 \"relief\" reads the shading of a relief that leaves the shape's surface \
                 where it is",
            );
        }
        None
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Settings {
    pub points: PointBudget,
    /// At least this many quadrangles kept (a body a few pixels wide still gets its shape).
    pub min_points: usize,
    /// Hard cap on sampled quadrangles (memory guard); the frame errors beyond it.
    pub max_points: usize,
    pub sampling: Sampling,
    pub split: Split,
    pub integration: Integration,
    /// The sub-grid rules' cap in image space (trapezoidal and midpoint): at most this many
    /// points per pixel that a quadrangle spans along each side (0 = no cap; `points_per_deg`
    /// alone).
    pub trapezoid_points_per_px: f64,
    /// Gauss-Legendre nodes per dimension (and per piece) on quadrangles that straddle the
    /// limb or the terminator, integrated over their exact lit and visible part.
    pub boundary_nodes: u32,
    pub fov: FovShape,
    pub gridding: Gridding,
    /// Super-sampling factor (1 = off): gridding runs on a grid this many times finer.
    pub supersampling: u32,
    pub reconstruction: Reconstruction,
    /// Anti-aliasing Gaussian applied on the fine grid before reconstruction [fine px], 0 = off.
    pub antialias_sigma_px: f64,
    /// Worker threads (0 = all cores).
    pub threads: usize,
    /// Stop refining the FOV-perimeter bounding when the limits move less than this [rad].
    pub bounding_tolerance_rad: f64,
    /// Also ray-cast the range to the surface per pixel.
    pub depth: bool,
    /// With a DEM: whether and how the relief hides the Sun and the camera from the surface
    /// (off by default; ray marching costs about a micro-second per point in the terminator
    /// and limb bands, the horizon map one lookup).
    pub self_shadowing: SelfShadowing,
    /// How quadrangles read the albedo map.
    pub map_filter: MapFilter,
    /// Under `MapFilter::Relief`: how much finer, per side, the reads of a pixel a shadow's
    /// edge crosses may get (1: never; 2, 4, 8: a pixel whose reads disagree, by their own
    /// estimate above [`super::footprint::REFINE_ABOVE`] or light and shadow among them, is
    /// read again twice as finely while its light still moves), and the factor of the lines
    /// of sight a limb pixel casts (8 x 8 times it, at most 64 x 64: `footprint::MAX_CAST`).
    pub relief_refine: u32,
    /// Under `MapFilter::Pixel` and `Relief`: the largest spacing of a pixel's map reads
    /// [texels] (0.5; 0.0625 to 1). Finer reads lower the median a textured frame keeps
    /// whatever its quadrangles ([`super::footprint::Reads`]).
    pub map_read_spacing_texels: f64,
    /// Mesh bodies ([`crate::raycast::sampled`]): rays per pixel side everywhere.
    pub raycast_samples: u32,
    /// Mesh bodies: rays per pixel side in pixels at the limb and at the edges of the light.
    pub raycast_edge_samples: u32,
    /// Mesh bodies seen through a pinhole: a large facet's light read from a quadratic over its
    /// image, through six evaluations and checked at two more, instead of evaluated at every
    /// sample
    /// ([`crate::raycast::facet_light`]; kept per facet only where it reproduces the light to
    /// 1e-6 of the facet's brightest at the check points).
    pub raycast_quadratic_light: bool,
    /// Ray-cast frames: the error to refine the edges' rays to (each pixel whose estimated
    /// error keeps the frame from it cast again with twice the rays, up to 64 per side;
    /// [`crate::raycast::estimate`]); `None`: `raycast_edge_samples` everywhere.
    pub raycast_budget: Option<crate::raycast::estimate::RaycastBudget>,
    /// A mesh body alone seen through a pinhole, without scattered light: each facet's lit and
    /// seen part clipped exactly as polygons, its light read from a quadratic element
    /// ([`crate::raycast::exact::render_frame`]): no edge rays, no sampling error (elsewhere
    /// the rays of the settings above).
    pub raycast_clip: bool,
    /// Mesh bodies: orders of light scattered between facets that enter the image (0: direct
    /// light only; [`crate::irradiance`]).
    pub scattering_orders: u32,
}

impl Default for Settings {
    /// Fast and accurate: on the analytic scene (tests/analytic.rs) median per-pixel error
    /// 2.7e-5 and total 6.5e-6 (bars 1e-3 and 2e-5), thanks to second-order (linear-density)
    /// polygon gridding. 0.25 quadrangles per pixel halves the error but missed the 10 fps
    /// floor at perilune (113 ms); 0.125 renders that frame in about 80 ms.
    fn default() -> Self {
        Settings {
            points: PointBudget::PerPixel(0.125),
            min_points: 256,
            max_points: 40_000_000,
            sampling: Sampling::ProjectedUniform,
            split: Split::Aspect,
            integration: Integration::Auto {
                points_per_deg: 5.0,
            },
            trapezoid_points_per_px: 2.0,
            boundary_nodes: 4,
            fov: FovShape::Frustum,
            gridding: Gridding::PolygonLinear,
            supersampling: 1,
            reconstruction: Reconstruction::Box,
            antialias_sigma_px: 0.0,
            threads: 0,
            bounding_tolerance_rad: 1e-7,
            depth: false,
            self_shadowing: SelfShadowing::Off,
            map_filter: MapFilter::Area,
            relief_refine: 1,
            map_read_spacing_texels: 0.5,
            raycast_samples: 1,
            raycast_edge_samples: 4,
            raycast_quadratic_light: true,
            raycast_budget: None,
            raycast_clip: false,
            scattering_orders: 0,
        }
    }
}

impl Settings {
    /// The high-accuracy preset: four times the quadrangles and more boundary nodes; on the
    /// analytic scene median per-pixel error 3.3e-6 and total 8.3e-7.
    pub fn high_accuracy() -> Self {
        Settings {
            points: PointBudget::PerPixel(1.0),
            boundary_nodes: 6,
            ..Settings::default()
        }
    }

    /// A preset by name: `default` or `high_accuracy`.
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "default" => Some(Settings::default()),
            "high_accuracy" => Some(Settings::high_accuracy()),
            _ => None,
        }
    }
}
