//! The body being rendered: its shape and its reflectance.
//!
//! Shapes sit behind [`Shape`] so that shapes (the sphere, the triaxial ellipsoid, later
//! triangle meshes) stand beside each other without touching the renderer's steps: the
//! renderer asks a shape for its bounding radius, the surface point and normal in a direction
//! from the centre (the area element follows from them), and the first intersection of a ray;
//! only the sphere has closed-form integrals. The sphere's exact lit-and-visible region serves
//! an undisplaced ellipsoid too, in its parameter space (`render::view::Grid`). A DEM's relief,
//! its horizons ([`horizon`]) and the albedo map are looked up along the surface point's
//! direction from the centre.

pub mod clearance;
pub mod ellipsoid;
pub mod horizon;
pub mod maps;
pub mod mesh;
pub mod pyramid;
pub mod sphere;
pub mod sun_envelope;

use crate::brdf::Brdf;
pub use ellipsoid::Ellipsoid;
pub use mesh::Mesh;

use glam::DVec3;
pub use sphere::{LitVisible, Sphere};

#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Sphere(Sphere),
    /// A triaxial ellipsoid (semi-axes along the body axes).
    Ellipsoid(Ellipsoid),
    /// A triangle mesh (rendered by the ray caster, [`crate::raycast`]), shared between the
    /// copies of a scene.
    Mesh(std::sync::Arc<Mesh>),
}

impl Shape {
    /// Radius of a sphere centred on the body that contains the whole surface [m].
    pub fn bounding_radius_m(&self) -> f64 {
        match self {
            Shape::Sphere(s) => s.radius_m,
            Shape::Ellipsoid(e) => e.max_axis_m(),
            Shape::Mesh(m) => m.bounding_radius_m(),
        }
    }

    /// Radius of a sphere centred on the body that the surface contains [m] (none is known
    /// for a mesh: 0).
    pub fn inner_radius_m(&self) -> f64 {
        match self {
            Shape::Sphere(s) => s.radius_m,
            Shape::Ellipsoid(e) => e.min_axis_m(),
            Shape::Mesh(_) => 0.0,
        }
    }

    /// Whether the shape looks the same in every frame centred on the body (a sphere): its
    /// surface may then be asked in the CSF directly.
    pub fn is_round(&self) -> bool {
        matches!(self, Shape::Sphere(_))
    }

    /// Surface point [m] and outward unit normal in the direction `dir` (unit, from the
    /// centre), in the body frame (in any body-centred frame for a round shape); for a mesh,
    /// the outermost point along `dir` and its facet's normal.
    #[inline(always)]
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        match self {
            Shape::Sphere(s) => (dir * s.radius_m, dir),
            Shape::Ellipsoid(e) => e.surface(dir),
            Shape::Mesh(m) => m.surface(dir),
        }
    }

    /// Distance to the first intersection of the ray `origin + t dir` (`dir` unit) with `t > 0`.
    #[inline]
    pub fn intersect(&self, origin: DVec3, dir: DVec3) -> Option<f64> {
        match self {
            Shape::Sphere(s) => crate::geometry::ray_sphere(origin, dir, s.radius_m),
            Shape::Ellipsoid(e) => e.intersect(origin, dir),
            Shape::Mesh(m) => m.intersect(origin, dir, f64::INFINITY).map(|h| h.t_m),
        }
    }

    /// The first intersection of the ray `origin + t dir` (`dir` unit, `t > 0`): its distance
    /// [m] and the shape's outward unit normal there (a facet's for a mesh).
    #[inline]
    pub fn intersect_normal(&self, origin: DVec3, dir: DVec3) -> Option<(f64, DVec3)> {
        match self {
            Shape::Mesh(m) => m
                .intersect(origin, dir, f64::INFINITY)
                .map(|h| (h.t_m, m.normals()[h.triangle as usize])),
            Shape::Sphere(_) => {
                let t = self.intersect(origin, dir)?;
                Some((t, (origin + dir * t).normalize()))
            }
            Shape::Ellipsoid(_) => {
                let t = self.intersect(origin, dir)?;
                Some((t, self.surface((origin + dir * t).normalize()).1))
            }
        }
    }

    /// The exactly known lit and visible region in longitude and latitude, for a Sun at
    /// `sun_m` on +X and a camera at `camera_m` in the XY plane (CSF); `None` for shapes
    /// without one (the integrator then clamps a trapezoidal rule instead).
    pub fn lit_visible(&self, sun_m: DVec3, camera_m: DVec3) -> Option<LitVisible> {
        match self {
            Shape::Sphere(s) => Some(LitVisible::new(s.radius_m, sun_m, camera_m)),
            Shape::Ellipsoid(_) | Shape::Mesh(_) => None,
        }
    }

    /// Whether a point [m] (body frame) lies inside the body.
    pub fn contains(&self, p: DVec3) -> bool {
        match self {
            Shape::Sphere(s) => p.length() < s.radius_m,
            Shape::Ellipsoid(e) => e.contains(p),
            Shape::Mesh(m) => m.contains(p),
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
    /// Surface relief from a DEM: it tilts the normals the BRDF sees (shading, or a normal
    /// map's), with `body.displacement` moves the surface to `R + h`, and with
    /// `render.self_shadowing` hides the Sun and the camera (ray marching or a horizon map).
    pub relief: Option<Relief>,
    /// The albedo's spectral shape (`body.reflectance_spectrum`): the albedo and its map hold
    /// at the spectrum's reference wavelength; grey when `None`.
    pub spectrum: Option<crate::radiometry::Reflectance>,
    /// A map of its own for some of the camera's bands (`[[body.band_map]]`), by band index:
    /// that band's albedo over its waveband, in place of `albedo_map`, read over each pixel's
    /// footprint (`render.map_filter = "pixel"`; `render::footprint`).
    pub band_maps: Vec<(usize, AlbedoMap)>,
}

impl Body {
    /// Band `b`'s own albedo map, when it has one.
    pub fn band_map(&self, b: usize) -> Option<&AlbedoMap> {
        self.band_maps.iter().find(|(k, _)| *k == b).map(|(_, m)| m)
    }
}

/// The radius of the sphere bounding the surface as rendered [m]: the shape's, or a
/// displacing relief's highest point where that is higher.
pub fn rendered_radius_m(shape: &Shape, relief: Option<&Relief>) -> f64 {
    match relief {
        Some(r) if r.displaces() => r.bounding_radius_m().max(shape.bounding_radius_m()),
        _ => shape.bounding_radius_m(),
    }
}

impl Body {
    /// How far from the centre a camera in the unit direction `dir` (body frame) must stay
    /// [m]: the radius of the sphere bounding the surface as rendered ([`rendered_radius_m`]),
    /// since the renderer bounds its grid to the visible cap of that sphere; for an undisplaced
    /// ellipsoid, bounded in its parameter space, only its own radius along `dir`.
    pub fn keep_out_radius_m(&self, dir: DVec3) -> f64 {
        let relief = self.relief.as_ref();
        match &self.shape {
            Shape::Ellipsoid(e) if !relief.is_some_and(|r| r.displaces()) => {
                e.surface(dir).0.length()
            }
            // The ray caster needs no keep-out sphere: outside the surface is enough.
            Shape::Mesh(_) => 0.0,
            shape => rendered_radius_m(shape, relief),
        }
    }

    /// Whether a camera may stand at `p` [m, body frame]: outside the body and beyond
    /// [`Body::keep_out_radius_m`].
    pub fn admits_camera_at(&self, p: DVec3) -> bool {
        let range = p.length();
        !self.shape.contains(p) && range > self.keep_out_radius_m(p / range) * (1.0 + 1e-12)
    }
}

/// How far above the ground a shadow ray leaves it, in body radii (1.7 m on the Moon): in
/// the pipeline's marcher ([`Relief::occluded`]) and the reference's sphere tracing alike,
/// one model. The reference needs it clear of its own hit tolerance; a ray leaving from the
/// ground itself, under a Sun grazing a concave slope, meets ground that a ray from this
/// height clears, and the Artemis I close approach's frame was 7e-4 darker than its
/// reference in total (p99 3.2e-2) for that alone (1.3e-4, 2.0e-2 with it).
pub const SHADOW_RAY_LIFT: f64 = 1e-6;

/// Where a marched ray is tested within its first step, in steps ([`Relief::occluded`]).
pub(crate) const NEAR_FIELD_STEPS: [f64; 4] = [0.0625, 0.125, 0.25, 0.5];

/// How many times an interval of a marched ray over which it may dip below the ground is
/// halved at most ([`Relief::dips`]): to 1/512 of a step.
const DIP_HALVINGS: u32 = 9;

/// Whether a ray rising by `rise` (the sine of its elevation) from the ground rises more
/// steeply than `slope` (the ground's, per metre of arc at the lowest radius), with a margin
/// of a thousandth: then, where `slope` bounds the ground, nothing can hide it.
pub(crate) fn rises_above(rise: f64, slope: f64) -> bool {
    rise > 0.0 && rise > 1.001 * slope * (1.0 - rise * rise).max(0.0).sqrt()
}

/// A point of a marched ray: its distance from the start [m], its radius [m], its gap above
/// the ground there [m] (infinite where no height is known or above the highest point), and
/// where it is (with its texel coordinates where the gap is finite).
struct RayProbe {
    t: f64,
    r: f64,
    gap: f64,
    /// With its texel coordinates on the DEM where `gap` is finite.
    at: pyramid::RayPoint,
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
    radius_m: f64,
    /// The highest and lowest points above `radius_m` [m].
    top_m: f64,
    bottom_m: f64,
    /// The steepest slope anywhere (tan of its angle).
    max_slope: f64,
    /// The 99th percentile of the slopes (tan of their angle, every 16th texel's).
    steep_slope: f64,
    /// The steepest slope of the bilinear surface in each cell between four texel centres,
    /// per metre of arc at the lowest radius ([`pyramid::cell_slopes`]), and anywhere: the
    /// bounds of a marched ray's dips ([`Relief::dips`]).
    cell_slope: std::sync::Arc<Vec<f32>>,
    max_cell_slope: f64,
    /// Per cell of a global DEM, the steepest of [`Relief::cell_slope`] within the arc
    /// beyond which a rising ray from the ground clears the highest point
    /// ([`pyramid::window_max`]); `None` for a regional DEM.
    reach_slope: Option<std::sync::Arc<Vec<f32>>>,
    /// A global DEM's bounds on the elevation above which a ray from the ground clears all
    /// the terrain, the slopes near it and the heights beyond ([`clearance::Clearance`]).
    clearance: Option<std::sync::Arc<clearance::Clearance>>,
    /// Ray-marching step [m]: a quarter texel in latitude.
    step_m: f64,
    /// Block maxima of a global DEM (`None` for a regional one), over which a marched ray
    /// skips the steps that cannot meet the ground.
    pyramid: Option<std::sync::Arc<pyramid::MaxPyramid>>,
    /// The sine of the local horizon's elevation angle (one value per texel, every azimuth),
    /// taken once at load from the horizon map [rad].
    pub horizon_sin: Option<std::sync::Arc<maps::Map>>,
    horizon_sin_max: f64,
    horizon_on_dem_grid: bool,
    /// The horizon computed from the DEM itself in azimuth bins, filled as frames ask.
    pub dem_horizon: Option<std::sync::Arc<horizon::DemHorizon>>,
    /// Whether the heights displace the surface (`r = R + h`).
    displaces: bool,
    /// A normal map, which replaces the normals of the slopes where it has a value.
    pub normal_map: Option<NormalMap>,
    /// The frame's bound on the ground towards the Sun ([`Relief::under_sun`]), which stops
    /// a marched Sun ray once nothing farther can meet it.
    sun: Option<std::sync::Arc<sun_envelope::SunRays>>,
}

/// A normal map (paper Sec. 4.4): the three components on one grid, in the body frame B or in
/// the local frame O (x east, y north, z up).
#[derive(Clone, Debug, PartialEq)]
pub struct NormalMap {
    pub components: [std::sync::Arc<maps::Map>; 3],
    pub frame: NormalFrame,
    on_dem_grid: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NormalFrame {
    Body,
    Local,
}

/// The DEM at one point: see [`Relief::at`].
#[derive(Clone, Copy, Debug)]
pub struct ReliefSample {
    /// Height above the reference radius [m] (0 without displacement).
    pub height_m: f64,
    /// The surface normal (body frame).
    pub normal: DVec3,
    pub horizon_sin: Option<f64>,
    /// The slope of the displaced ground's bilinear heights, `(dh/dlon, dh/dlat)` [m/rad]
    /// ((0, 0) without displacement): [`Relief::ground_from`] makes it the ground's normal.
    pub ground_slope: (f64, f64),
}

/// The DEM's own horizon at one surface point: see [`Relief::dem_horizon_at`].
pub struct HorizonAt<'a> {
    horizon: &'a horizon::DemHorizon,
    taps: maps::Taps,
    up: DVec3,
}

impl HorizonAt<'_> {
    /// Whether direction `toward` (unit, body frame) rises less than the horizon in its
    /// azimuth. Like ray marching, a direction below the horizontal is left to the BRDF's
    /// cosines, and one rising more steeply than the steepest slope (here the steepest within
    /// reach) cannot be hidden.
    pub fn hides(&self, toward: DVec3) -> bool {
        let rise = toward.dot(self.up);
        if rise <= 0.0 || !self.horizon.may_hide(&self.taps, rise) {
            return false;
        }
        let (east, north) = crate::geometry::east_north(self.up);
        let azimuth = toward.dot(north).atan2(toward.dot(east));
        rise < self.horizon.sin_at(&self.taps, azimuth)
    }
}

impl Relief {
    /// Slopes of `heights_m` (a DEM in metres above a sphere of `radius_m`).
    /// With `displaces`, the surface is moved to `R + h` and the slopes are taken along arcs
    /// at that radius, which makes the normals exact for the displaced surface.
    pub fn new(
        heights_m: maps::Map,
        radius_m: f64,
        displaces: bool,
    ) -> Result<Relief, maps::MapError> {
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
                // Two texels across, one at the edge of a regional map.
                let (cw, ce, texels) = if wraps {
                    ((c + w - 1) % w, (c + 1) % w, 2)
                } else {
                    let (cw, ce) = (c.saturating_sub(1), (c + 1).min(w - 1));
                    (cw, ce, ce - cw)
                };
                let arc_r = if displaces {
                    radius_m + v(r, c)
                } else {
                    radius_m
                };
                let metres_e = arc_r * lat.cos().max(1e-6) * texels as f64 * dlon;
                east.push((v(r, ce) - v(r, cw)) / metres_e);
                let metres_n = arc_r * (rs - rn).max(1) as f64 * dlat;
                north.push((v(rn, c) - v(rs, c)) / metres_n);
            }
        }
        let max_slope = east
            .iter()
            .zip(&north)
            .map(|(e, n)| (e * e + n * n).sqrt())
            .fold(0.0, f64::max);
        // The 99th percentile of the slopes (every 16th texel's): where the camera may often
        // be hidden (Relief::below_steep_slopes), and the planner's steepness.
        let mut sampled: Vec<f64> = east
            .iter()
            .zip(&north)
            .step_by(16)
            .map(|(e, n)| (e * e + n * n).sqrt())
            .collect();
        let steep_slope = if sampled.is_empty() {
            0.0
        } else {
            crate::stats::quantiles(&mut sampled, [0.99])[0]
        };
        let (bottom, top) = heights_m
            .values
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        let (bottom_m, top_m) = (bottom as f64, top as f64);
        let slope = |values| heights_m.with_values(values).map(std::sync::Arc::new);
        let cell_slope = pyramid::cell_slopes(&heights_m, radius_m + bottom_m.min(0.0));
        let pyramid =
            pyramid::MaxPyramid::new(&heights_m, radius_m, &cell_slope).map(std::sync::Arc::new);
        let max_cell_slope = cell_slope.iter().fold(0.0f64, |a, &b| a.max(b as f64));
        // A ray rising from the ground (at least the lowest point's radius) is above the
        // tangent plane there, which is above the highest point beyond this arc.
        let clear_arc = ((radius_m + bottom_m) / (radius_m + top_m))
            .clamp(-1.0, 1.0)
            .acos();
        let reach_slope = pyramid
            .is_some()
            .then(|| std::sync::Arc::new(pyramid::window_max(&cell_slope, &heights_m, clear_arc)));
        let clearance = clearance::Clearance::new(&heights_m, radius_m, &cell_slope, clear_arc)
            .map(std::sync::Arc::new);
        Ok(Relief {
            slope_east: slope(east)?,
            slope_north: slope(north)?,
            heights_m: std::sync::Arc::new(heights_m),
            radius_m,
            top_m,
            bottom_m,
            max_slope,
            steep_slope,
            cell_slope: std::sync::Arc::new(cell_slope),
            max_cell_slope,
            reach_slope,
            clearance,
            step_m: 0.25 * radius_m * dlat,
            pyramid,
            horizon_sin: None,
            horizon_sin_max: -1.0,
            horizon_on_dem_grid: false,
            dem_horizon: None,
            displaces,
            normal_map: None,
            sun: None,
        })
    }

    /// The same relief for one frame, with the Sun at `sun_position_m` (body frame): once the
    /// frame has marched enough Sun rays to pay for it ([`sun_envelope::SunRays::envelope`]),
    /// they stop where the ground towards the Sun can no longer reach them
    /// ([`sun_envelope::SunEnvelope`]; the answers are the same). For a global DEM only; the
    /// relief as it is otherwise.
    pub fn under_sun(&self, sun_position_m: DVec3) -> Relief {
        let global = self.pyramid.is_some() && self.heights_m.pole_values().is_some();
        let sun = global.then(|| std::sync::Arc::new(sun_envelope::SunRays::new(sun_position_m)));
        Relief {
            sun,
            ..self.clone()
        }
    }

    /// [`Relief::under_sun`] with the envelope built now, for a frame known to march many
    /// Sun rays (the relief's reads: millions on an NRHO frame), which then all take it.
    pub fn under_sun_now(&self, sun_position_m: DVec3) -> Relief {
        let framed = self.under_sun(sun_position_m);
        if let Some(sun) = framed.sun.as_deref() {
            sun.built(&framed, true);
        }
        framed
    }

    /// The same relief with a horizon map: elevation angles [rad] of the local horizon above
    /// the tangent plane of the DEM's normal (see [`Relief::at`]).
    pub fn with_horizon(self, horizon_rad: maps::Map) -> Result<Relief, maps::MapError> {
        let top = horizon_rad.values.iter().fold(f32::MIN, |a, &v| a.max(v)) as f64;
        let sines: Vec<f64> = horizon_rad
            .values
            .iter()
            .map(|&v| (v as f64).clamp(-1.5, 1.5).sin())
            .collect();
        let on_grid = horizon_rad.same_grid(&self.heights_m);
        let horizon_sin = horizon_rad.with_values(sines)?;
        Ok(Relief {
            horizon_sin_max: top.clamp(-1.5, 1.5).sin(),
            horizon_on_dem_grid: on_grid,
            horizon_sin: Some(std::sync::Arc::new(horizon_sin)),
            ..self
        })
    }

    /// The same relief with its horizon computed from the DEM in `azimuths` bins
    /// ([`horizon::DemHorizon`]), instead of a horizon map.
    pub fn with_dem_horizon(self, azimuths: usize) -> Relief {
        let range = (self.bottom_m, self.top_m);
        let h = horizon::DemHorizon::new(self.heights_m.clone(), self.radius_m, range, azimuths);
        Relief {
            dem_horizon: Some(std::sync::Arc::new(h)),
            ..self
        }
    }

    /// Whether there is a horizon to look up (a map, or the DEM's own by azimuth).
    pub fn has_horizon(&self) -> bool {
        self.horizon_sin.is_some() || self.dem_horizon.is_some()
    }

    /// Whether the DEM's own horizon hides direction `toward` (unit, body frame) from the
    /// surface point over the unit direction `up` ([`HorizonAt::hides`]); false without a DEM
    /// horizon.
    pub fn horizon_hides(&self, up: DVec3, toward: DVec3) -> bool {
        self.dem_horizon_at(up).is_some_and(|h| h.hides(toward))
    }

    /// The DEM's own horizon ([`horizon::DemHorizon`]) at the surface point over the unit
    /// direction `up`, looked up once for any number of directions; `None` without one or off
    /// a regional DEM.
    pub fn dem_horizon_at(&self, up: DVec3) -> Option<HorizonAt<'_>> {
        let horizon = self.dem_horizon.as_deref()?;
        let (lon, lat) = crate::geometry::lon_lat(up);
        let taps = self.heights_m.taps(lon, lat)?;
        Some(HorizonAt { horizon, taps, up })
    }

    /// The DEM's block maxima (`None` for a regional DEM).
    pub fn pyramid(&self) -> Option<std::sync::Arc<pyramid::MaxPyramid>> {
        self.pyramid.clone()
    }

    /// The sine of the highest horizon in the map: directions rising more steeply than that
    /// need no lookup.
    pub fn horizon_sin_max(&self) -> f64 {
        self.horizon_sin_max
    }

    /// Whether the terrain hides direction `toward` (unit, body frame) from the surface point
    /// over the unit direction `up` (Eq. 33: the ray from the point, [`SHADOW_RAY_LIFT`] above
    /// the ground, meets the surface). Only rays that rise more slowly than the steepest slope
    /// are marched (at [`NEAR_FIELD_STEPS`] within the first step, then a quarter texel a step,
    /// until the ray is above the highest point); the others cannot be blocked. Between two
    /// points above the ground, the ray may still dip below it (a grazing ray over a hilltop):
    /// where the slopes of the cells it crosses allow that, the lowest gap between its chord
    /// and the bilinear ground is found and tested ([`Relief::dips`]). A direction below the
    /// horizontal is left to the BRDF's cosine on an undisplaced surface, and marched on a
    /// displaced one, whose points beyond their own limb or terminator (a peak seen or lit
    /// over the horizon) may still see the camera or the Sun.
    pub fn occluded(&self, up: DVec3, toward: DVec3) -> bool {
        self.march(up, toward, true)
    }

    /// [`Relief::occluded`], with the shortcuts of the DEM's bounds (`leaps`: a ray the bounds
    /// clear is clear at once, [`Relief::rises_clear`]; one clear of every height beyond the
    /// near arc is marched only that far, [`clearance::Clearance::far_clears`], and a Sun ray
    /// of a relief [`Relief::under_sun`] only until the ground towards the Sun can no longer
    /// reach it, [`sun_envelope::SunEnvelope::clear_beyond_m`]; the pyramid's leaps) or
    /// without: the points are those of one sequence (the start, the near field's
    /// [`NEAR_FIELD_STEPS`], then step `n` at `n` steps from the start). A leap skips the
    /// points of the sequence within the reach over which the ray clears the highest ground,
    /// tests the last of them, and checks no dip between the two; every other pair of
    /// consecutive points is checked alike either way, so the answer is the same.
    fn march(&self, up: DVec3, toward: DVec3, leaps: bool) -> bool {
        let rise = toward.dot(up);
        if rise <= 0.0 && !self.displaces {
            return false; // below the horizontal: the BRDF's cosine is already <= 0
        }
        let horizontal = (1.0 - rise * rise).max(0.0).sqrt();
        if rise > 0.0 && rise >= self.max_slope * horizontal {
            return false;
        }
        let (lon, lat) = crate::geometry::lon_lat(up);
        if leaps && self.rises_clear(rise, lon, lat) {
            return false;
        }
        let h0 = self.heights_m.sample(lon, lat).unwrap_or(0.0);
        // The ray leaves the ground SHADOW_RAY_LIFT above it, as the reference's does.
        let lift = SHADOW_RAY_LIFT * self.radius_m;
        let start = up * (self.radius_m + h0 + lift);
        let ceiling = self.radius_m + self.top_m;
        // Below every point of the surface (a regional map's surroundings at the reference
        // radius), a ray descending from a displaced point is inside the body.
        let floor = self.radius_m + self.bottom_m.min(0.0);
        let pyramid = self.pyramid.as_deref().filter(|_| leaps);
        // The point at `t` along the ray: `Some(true)` below the ground (or the floor),
        // `Some(false)` above the highest point (the ray's radius is convex along it and
        // started below, so it stays above), `None` above the ground there.
        let test = |t: f64| -> (Option<bool>, RayProbe) {
            let q = start + toward * t;
            let r = q.length();
            let up = q / r;
            let probe = |gap, at| RayProbe { t, r, gap, at };
            if r > ceiling || r < floor {
                let at = pyramid::RayPoint {
                    up,
                    lon: 0.0,
                    lat: 0.0,
                    x: 0.0,
                    y: 0.0,
                };
                return match r > ceiling {
                    true => (Some(false), probe(f64::INFINITY, at)),
                    false => (Some(true), probe(f64::NEG_INFINITY, at)),
                };
            }
            let (lon, lat) = crate::geometry::lon_lat_fast(q);
            let at = pyramid::RayPoint::on(&self.heights_m, up, lon, lat);
            match self.heights_m.sample(lon, lat) {
                Some(h) if r < self.radius_m + h => (Some(true), probe(r - self.radius_m - h, at)),
                Some(h) => (None, probe(r - self.radius_m - h, at)),
                None => (None, probe(f64::INFINITY, at)),
            }
        };
        // The sequence's points [m from the start]: the near field, within the first step (a
        // ray leaving the ground at a low Sun meets the bilinear ground rising within a
        // fraction of a texel: the NRHO perilune frame's shadows were short by 8.9e-4 of its
        // light against the reference, 1.4e-4 with these points), then whole steps.
        let near = NEAR_FIELD_STEPS.len();
        let point = |j: usize| match NEAR_FIELD_STEPS.get(j) {
            Some(f) => f * self.step_m,
            None => (j + 1 - near) as f64 * self.step_m,
        };
        // The last point of the sequence at or before `t`.
        let last_within = |t: f64| -> Option<usize> {
            let steps = crate::geometry::floor_i64(t / self.step_m) as f64;
            if steps >= 1.0 {
                Some(near - 1 + steps as usize)
            } else {
                (0..near).rev().find(|&j| point(j) <= t)
            }
        };
        let mut prev = RayProbe {
            t: 0.0,
            r: start.length(),
            gap: lift,
            at: pyramid::RayPoint::on(&self.heights_m, up, lon, lat),
        };
        let mut j = 0;
        // Clear of every height beyond the near arc ([`clearance::Clearance`]): the ray is
        // marched only until its point is that far round (a tested point there, every point
        // before it tested or leapt over). On the six NRHO frames of
        // [`Relief::rises_clear`] this stopped 5.5 M rays early; with both, the points tested
        // fell from 705 M to 600 M, 15 %; on the perilune (row 174) from 273 M to 210 M.
        let beyond_m = self
            .clearance
            .as_ref()
            .filter(|c| leaps && c.far_clears(rise, prev.at.x, prev.at.y))
            .and_then(|c| {
                let tan_near = c.near_rad().tan();
                let denominator = horizontal - tan_near * rise;
                (denominator > 0.0).then(|| tan_near * prev.r / denominator)
            });
        // Beyond where the ground towards the Sun can still reach the ray, it is clear.
        let sun_beyond_m = (self.sun.as_deref().filter(|_| leaps))
            .and_then(|sun| sun.envelope(self))
            .and_then(|envelope| envelope.clear_beyond_m(start, toward));
        let beyond_m = match (beyond_m, sun_beyond_m) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        // From the ground, rising more steeply than the ground within reach: clear so far.
        let mut clear_to = match pyramid.filter(|_| rise > 0.0) {
            Some(p) => p.rise_clear(&self.heights_m, &prev.at, rise),
            None => 0.0,
        };
        loop {
            if beyond_m.is_some_and(|t| prev.t >= t) {
                return false;
            }
            // The points the ray clears over: the last of them is tested, with no dip check.
            if let Some(last) = last_within(clear_to).filter(|&last| last >= j) {
                let (hit, p) = test(point(last));
                if let Some(hit) = hit {
                    return hit;
                }
                (prev, j) = (p, last + 1);
            }
            let (hit, p) = test(point(j));
            if let Some(hit) = hit {
                return hit;
            }
            if self.dips(&test, &prev, &p, 0) {
                return true;
            }
            if let Some(pyr) = pyramid.filter(|_| j >= near) {
                // Points within the leap cannot meet the ground (nor go below the floor).
                clear_to = p.t + pyr.leap(&self.heights_m, start, toward, p.t, &p.at);
            }
            (prev, j) = (p, j + 1);
        }
    }

    /// The steepest slope a ray rising from the ground at `(lon, lat)` can pass over before
    /// it clears the highest point ([`Relief::reach_slope`]), per metre of arc at the lowest
    /// radius: a ray rising more steeply than that, by the tangent of its elevation
    /// ([`rises_above`]), is never below the ground, since the ground under it rises more
    /// slowly than it does ([`pyramid::MaxPyramid::rise_clear`]'s argument, out to the arc
    /// where nothing is higher). The steepest cell anywhere for a regional DEM.
    pub(crate) fn slope_within_reach(&self, lon: f64, lat: f64) -> f64 {
        self.slope_within_reach_at(self.heights_m.texel_coords(lon, lat))
    }

    /// Whether a ray rising by `rise` (the sine of its elevation) from the ground at `(lon,
    /// lat)` is clear of all the terrain by the DEM's bounds alone: it rises more steeply
    /// than every slope within reach ([`Relief::slope_within_reach`]), or than the slopes
    /// near it and the elevation of all the heights beyond ([`clearance::Clearance`]). Over
    /// six NRHO frames (rows 0, 105, 174, 290, 435 and 580 of `nrho_2orbits.csv` at 1024 x
    /// 1024, 2 quadrangles a pixel, the relief read at `relief_refine` 2 with marched
    /// shadows) the first cleared 19.9 M of the 72.7 M rays asked, the second 15.2 M of the
    /// 52.5 M left, with the same images bit for bit.
    pub(crate) fn rises_clear(&self, rise: f64, lon: f64, lat: f64) -> bool {
        let at = self.heights_m.texel_coords(lon, lat);
        rises_above(rise, self.slope_within_reach_at(at))
            || self
                .clearance
                .as_ref()
                .is_some_and(|c| c.clears(rise, at.0, at.1))
    }

    /// [`Relief::slope_within_reach`] at texel coordinates `(x, y)`.
    fn slope_within_reach_at(&self, (x, y): (f64, f64)) -> f64 {
        let Some(reach) = self.reach_slope.as_deref() else {
            return self.max_cell_slope;
        };
        let (w, h) = (self.heights_m.width as i64, self.heights_m.height as i64);
        let r = crate::geometry::floor_i64(y).clamp(0, h - 1);
        let c = crate::geometry::floor_i64(x).rem_euclid(w);
        reach[(r * w + c) as usize] as f64
    }

    /// The lowest gap between the chord of a marched ray from its point `a` to `b` and the
    /// bilinear ground beneath it, and where along the ray [m]: along the straight line
    /// between their texel coordinates (which the ray's track follows to well under a metre
    /// over a quarter texel), the ground within each cell it crosses is a quadratic in the
    /// line's parameter, so the gap is too, and its lowest point is one of the pieces' ends or
    /// a vertex. `None` near a pole's rows (where the map blends towards the pole), off a
    /// regional map, or across more than 8 cell edges.
    fn chord_over_cells(&self, a: &RayProbe, b: &RayProbe) -> Option<(f64, f64)> {
        let map = &self.heights_m;
        let (w, h) = (map.width, map.height);
        let (xa, ya) = (a.at.x, a.at.y);
        let (xb, yb) = (self.same_turn(xa, b.at.x), b.at.y);
        let rows = 0.0..(h - 1) as f64;
        let columns = 0.0..(w - 1) as f64;
        if !(rows.contains(&ya) && rows.contains(&yb))
            || !(map.wraps() || (columns.contains(&xa) && columns.contains(&xb)))
        {
            return None;
        }
        let (dx, dy) = (xb - xa, yb - ya);
        // The pieces' ends: where the line crosses a column or a row of texel centres.
        let mut ends = [0.0f64; 10];
        ends[1] = 1.0;
        let mut n = 2;
        for (from, d) in [(xa, dx), (ya, dy)] {
            let (lo, hi) = (from.min(from + d), from.max(from + d));
            let mut edge = crate::geometry::floor_i64(lo) as f64 + 1.0;
            while edge < hi {
                if n == ends.len() {
                    return None;
                }
                ends[n] = (edge - from) / d;
                n += 1;
                edge += 1.0;
            }
        }
        let ends = &mut ends[..n];
        ends.sort_unstable_by(f64::total_cmp);
        let v = |r: usize, c: i64| map.values[r * w + c.rem_euclid(w as i64) as usize] as f64;
        let dr = b.r - a.r;
        let (mut lowest, mut at) = (f64::INFINITY, 0.0);
        for piece in ends.windows(2) {
            let (u0, u1) = (piece[0], piece[1]);
            let mid = 0.5 * (u0 + u1);
            let c = crate::geometry::floor_i64(xa + dx * mid) as f64;
            let r = crate::geometry::floor_i64(ya + dy * mid) as f64;
            let (row, col) = (r as usize, c as i64);
            let (v00, v01) = (v(row, col), v(row, col + 1));
            let (v10, v11) = (v(row + 1, col), v(row + 1, col + 1));
            let (east, south, twist) = (v01 - v00, v10 - v00, v00 - v01 - v10 + v11);
            let (fx, fy) = (xa - c, ya - r);
            // The ground at `u`: h0 + h1 u + h2 u^2; the gap: g0 + g1 u - h2 u^2.
            let h0 = v00 + east * fx + south * fy + twist * fx * fy;
            let h1 = east * dx + south * dy + twist * (fx * dy + fy * dx);
            let h2 = twist * dx * dy;
            let (g0, g1) = (a.r - self.radius_m - h0, dr - h1);
            let gap = |u: f64| g0 + g1 * u - h2 * u * u;
            let vertex = if h2 < 0.0 { g1 / (2.0 * h2) } else { u0 };
            for u in [u0, u1, vertex.clamp(u0, u1)] {
                let g = gap(u);
                if g < lowest {
                    (lowest, at) = (g, u);
                }
            }
        }
        Some((lowest, a.t + at * (b.t - a.t)))
    }

    /// A bound on the ground's slope along a marched ray between its points `a` and `b`, `s`
    /// metres apart: the steepest of the cells between their texel coordinates (over a
    /// quarter texel the ray's track departs from the straight line between its ends by well
    /// under a metre), or where those are more than 16 cells or near a pole's rows, the
    /// pyramid's block within reach, or the steepest cell anywhere.
    fn slope_between(&self, a: &RayProbe, b: &RayProbe, s: f64) -> f64 {
        let map = &self.heights_m;
        let (w, h) = (map.width as i64, map.height as i64);
        let (xa, ya) = (a.at.x, a.at.y);
        let (xb, yb) = (self.same_turn(xa, b.at.x), b.at.y);
        let (x0, x1) = (
            crate::geometry::floor_i64(xa.min(xb)),
            crate::geometry::floor_i64(xa.max(xb)),
        );
        let (y0, y1) = (
            crate::geometry::floor_i64(ya.min(yb)),
            crate::geometry::floor_i64(ya.max(yb)),
        );
        let inside = y0 >= 0 && y1 < h - 1 && (map.wraps() || (x0 >= 0 && x1 < w - 1));
        if inside && (x1 - x0 + 1) * (y1 - y0 + 1) <= 16 {
            let mut most = 0.0f32;
            for r in y0..=y1 {
                for c in x0..=x1 {
                    let c = if c < 0 {
                        c + w
                    } else if c >= w {
                        c - w
                    } else {
                        c
                    };
                    most = most.max(self.cell_slope[(r * w + c) as usize]);
                }
            }
            return most as f64;
        }
        self.pyramid
            .as_deref()
            .and_then(|p| p.slope_within(map, &a.at, s))
            .unwrap_or(self.max_cell_slope)
    }

    /// The texel column `x` on the same turn of a global map's longitudes as `from`'s.
    #[inline]
    fn same_turn(&self, from: f64, x: f64) -> f64 {
        let w = self.heights_m.width as f64;
        if !self.heights_m.wraps() {
            x
        } else if x - from > 0.5 * w {
            x - w
        } else if from - x > 0.5 * w {
            x + w
        } else {
            x
        }
    }

    /// Whether the marched ray dips below the ground between its points `a` and `b`, both
    /// above it. Over the interval (length `s`) the ray's radius lies at most `s^2 / (8 r)`
    /// below its chord (its curvature is at most `1 / r`), which rises at `k` per metre, and
    /// the ground rises at most `S` per metre (the steepest slope of the cells it crosses,
    /// [`Relief::slope_between`]); so the gap is at least the larger of
    /// `gap_a + (k - S) x` and `gap_b - (k + S) (s - x)`, less that sag. Where that can
    /// reach zero, the chord's lowest gap over the bilinear cells it crosses is found exactly
    /// ([`Relief::chord_over_cells`]) and the ray tested there; where the chord comes within
    /// the sag of the ground but the ray is not below it there (it may dip elsewhere), or
    /// where the cells are not plain (a pole's rows), the midpoint is tested and both halves
    /// checked, to [`DIP_HALVINGS`] halvings of a step (4 m on the Moon's LOLA grid at 4
    /// px/deg). Testing the chord's lowest point alone lit points whose Sun ray passed a few
    /// centimetres below a ridge elsewhere in the interval: 137 of 416,457 beside the limb of
    /// Artemis I row 861, that frame +1.7e-4 too bright (`raycast::terrain`'s
    /// `the_marcher_finds_rays_a_few_centimetres_below_a_ridge`). The reference's sphere
    /// tracing finds such hits by its own steps ([`crate::raycast`]); with the steps alone
    /// the marcher had lit 0.5 % of the points it shadows on hills at a low Sun and 0.7 % on
    /// the LOLA DEM (`raycast::terrain`'s tests).
    fn dips(
        &self,
        test: &dyn Fn(f64) -> (Option<bool>, RayProbe),
        a: &RayProbe,
        b: &RayProbe,
        halvings: u32,
    ) -> bool {
        if !(a.gap.is_finite() && b.gap.is_finite()) {
            return false;
        }
        let s = b.t - a.t;
        let slope = self.slope_between(a, b, s);
        let k = (b.r - a.r) / s;
        let sag = s * s / (8.0 * (self.radius_m + self.bottom_m.min(0.0)));
        let x = if slope > 0.0 {
            ((a.gap - b.gap + (k + slope) * s) / (2.0 * slope)).clamp(0.0, s)
        } else {
            0.0
        };
        let lowest = (a.gap + (k - slope) * x).max(b.gap - (k + slope) * (s - x)) - sag;
        if lowest > 0.0 || halvings >= DIP_HALVINGS {
            return false;
        }
        if let Some((chord_gap, t)) = self.chord_over_cells(a, b) {
            // The ray lies between its chord and the chord less the sag: clear of the ground
            // with it, or tested where the chord comes lowest, and where it is not below the
            // ground there, halved: it may dip elsewhere by up to the sag.
            if chord_gap > sag {
                return false;
            }
            if let (Some(hit), _) = test(t) {
                return hit;
            }
        }
        let (hit, m) = test(a.t + 0.5 * s);
        if let Some(hit) = hit {
            return hit;
        }
        self.dips(test, a, &m, halvings + 1) || self.dips(test, &m, b, halvings + 1)
    }

    /// The first intersection `t > 0` of the ray `origin + t dir` (`dir` unit, body frame)
    /// with the displaced surface `r = R + h`: the ray enters the sphere of the highest point,
    /// is marched a quarter texel a step until it is below the surface (a grazing ray may
    /// skip a ridge thinner than that), and the crossing is refined by bisection (to about a
    /// micrometre). `None` if it leaves that sphere without
    /// meeting the surface.
    pub fn intersect_displaced(&self, origin: DVec3, dir: DVec3) -> Option<f64> {
        let ceiling = self.bounding_radius_m();
        let b = origin.dot(dir);
        let disc = b * b - (origin.length_squared() - ceiling * ceiling);
        if disc < 0.0 {
            return None;
        }
        let (t_in, t_out) = (-b - disc.sqrt(), -b + disc.sqrt());
        if t_out <= 0.0 {
            return None;
        }
        let below = |t: f64| {
            let q = origin + dir * t;
            let r = q.length();
            let (lon, lat) = crate::geometry::lon_lat(q / r);
            r < self.radius_m + self.heights_m.sample(lon, lat).unwrap_or(0.0)
        };
        let mut prev = t_in.max(0.0);
        if below(prev) {
            return Some(prev);
        }
        while prev < t_out {
            let t = (prev + self.step_m).min(t_out);
            if below(t) {
                let (mut lo, mut hi) = (prev, t);
                for _ in 0..40 {
                    let mid = 0.5 * (lo + hi);
                    if below(mid) {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                return Some(hi);
            }
            prev = t;
        }
        None
    }

    /// The DEM over the unit direction `up` (body frame): height, normal and, when `horizon` is
    /// asked and there is a horizon map, the sine of the local horizon's elevation there. One
    /// longitude/latitude and, when the maps share a grid (the DEM's slopes always do; the
    /// shared lunar horizon map does), one bilinear tap set for every value.
    ///
    /// The horizon's elevation is measured from the local tangent plane, normal to the DEM's
    /// normal (the paper's frame O): on `config/moon.toml` that reading catches 89 % of the
    /// pixels ray marching shadows, the sphere's tangent plane 69 %. A direction whose cosine
    /// with the DEM normal is below the sine is hidden (the fast alternative to
    /// [`Relief::occluded`]).
    #[inline]
    pub fn at(&self, up: DVec3, horizon: bool) -> ReliefSample {
        debug_assert!((up.length_squared() - 1.0).abs() < 1e-9);
        let (lon, lat) = crate::geometry::lon_lat_unit(up);
        let Some(taps) = self.slope_east.taps(lon, lat) else {
            return ReliefSample {
                height_m: 0.0,
                normal: up,
                horizon_sin: None,
                ground_slope: (0.0, 0.0),
            };
        };
        let (se, sn) = (self.slope_east.at(&taps), self.slope_north.at(&taps));
        let horizon_sin = match (&self.horizon_sin, horizon) {
            (Some(h), true) if self.horizon_on_dem_grid => Some(h.at(&taps)),
            (Some(h), true) => h.sample(lon, lat),
            _ => None,
        };
        let (height_m, ground_slope) = if self.displaces {
            (
                self.heights_m.at(&taps),
                self.ground_slope_at((lon, lat), &taps),
            )
        } else {
            (0.0, (0.0, 0.0))
        };
        let (east, north) = crate::geometry::east_north(up);
        let mut normal = (up - se * east - sn * north).normalize();
        if let Some(nm) = &self.normal_map {
            let local_taps;
            let t = if nm.on_dem_grid {
                Some(&taps)
            } else {
                local_taps = nm.components[0].taps(lon, lat);
                local_taps.as_ref()
            };
            if let Some(t) = t {
                let [x, y, z] = [0, 1, 2].map(|k| nm.components[k].at(t));
                let n = match nm.frame {
                    NormalFrame::Body => DVec3::new(x, y, z),
                    NormalFrame::Local => x * east + y * north + z * up,
                };
                if n.length_squared() > 1e-12 {
                    normal = n.normalize();
                }
            }
        }
        ReliefSample {
            height_m,
            normal,
            horizon_sin,
            ground_slope,
        }
    }

    /// Whether direction `toward` (unit, body frame) rises over the horizontal of the point
    /// over the unit direction `up` less steeply than the DEM's steep slopes (their 99th
    /// percentile): where the terrain may often hide it.
    #[inline]
    pub fn below_steep_slopes(&self, up: DVec3, toward: DVec3) -> bool {
        // rise < k sqrt(1 - rise^2), without the root.
        let (rise, k2) = (toward.dot(up), self.steep_slope * self.steep_slope);
        rise < 0.0 || rise * rise * (1.0 + k2) < k2
    }

    /// The normal of the displaced ground itself at the point over the unit direction `up`
    /// (body frame), unnormalised so that its component along `up` is 1:
    /// `up - dh/dlon / (rho cos lat) east - dh/dlat / rho north`, with `h` the bilinear
    /// heights and `rho = R + h` (the surface `r = rho(lon, lat)`). It is the surface a line
    /// of sight meets: `(n . c) rho^2 dOmega` is the area it shows the camera along unit
    /// direction `c`. [`Relief::at`]'s normal, which the BRDF sees, interpolates the texels'
    /// central-difference slopes instead (smooth across the cells' edges) and regresses
    /// towards the mean slope: where the terrain may hide the camera (near the limb), which
    /// keeps the ground facing it, weighing the visible ground by it left the displaced Moon
    /// at 20,000 km 1.3e-3 of the frame's light short of the reference's lines of sight
    /// (`render::integration`, `tests/maps.rs`). `up` itself without displacement or off the
    /// map.
    pub fn ground_normal(&self, up: DVec3) -> DVec3 {
        if !self.displaces {
            return up;
        }
        self.ground_from(up, &self.at(up, false))
    }

    /// [`Relief::ground_normal`] from the point's [`Relief::at`] sample.
    #[inline]
    pub fn ground_from(&self, up: DVec3, at: &ReliefSample) -> DVec3 {
        let (dh_dlon, dh_dlat) = at.ground_slope;
        let inv_rho = 1.0 / (self.radius_m + at.height_m);
        // cos(lat) of the unit `up`, without a libm call.
        let cos_lat = (up.x * up.x + up.y * up.y).sqrt().max(1e-9);
        let (east, north) = crate::geometry::east_north(up);
        up - (dh_dlon * inv_rho / cos_lat) * east - (dh_dlat * inv_rho) * north
    }

    /// The slope of the bilinear heights `(dh/dlon, dh/dlat)` [m/rad] at longitude and
    /// latitude `lon`, `lat` [rad], its taps on the DEM's grid found.
    #[inline]
    fn ground_slope_at(&self, (lon, lat): (f64, f64), taps: &maps::Taps) -> (f64, f64) {
        let map = &self.heights_m;
        let (dlon, dlat) = map.spacing_rad();
        match map.gradient(taps) {
            // Texel columns run east, rows south.
            Some((dx, dy)) => (dx / dlon, -dy / dlat),
            None => {
                // Towards a pole the map blends to the pole's value: central differences a
                // thousandth of a texel wide.
                let (dl, dp) = (1e-3 * dlon, 1e-3 * dlat);
                let h = |lon: f64, lat: f64| map.sample(lon, lat).unwrap_or(0.0);
                (
                    (h(lon + dl, lat) - h(lon - dl, lat)) / (2.0 * dl),
                    (h(lon, lat + dp) - h(lon, lat - dp)) / (2.0 * dp),
                )
            }
        }
    }

    /// The same relief with a normal map (three maps of one grid; any scale and shift already
    /// applied, so the values are the components, normalised here).
    pub fn with_normal_map(
        self,
        components: [maps::Map; 3],
        frame: NormalFrame,
    ) -> Result<Relief, maps::MapError> {
        let [x, y, z] = components;
        for other in [&y, &z] {
            if !x.same_grid(other) {
                return Err(maps::MapError::Format {
                    file: x.file.display().to_string(),
                    message: "the normal map's components on different grids".into(),
                });
            }
        }
        let on_dem_grid = x.same_grid(&self.heights_m);
        let arc = std::sync::Arc::new;
        Ok(Relief {
            normal_map: Some(NormalMap {
                components: [arc(x), arc(y), arc(z)],
                frame,
                on_dem_grid,
            }),
            ..self
        })
    }

    /// The sphere's radius the heights are measured from [m].
    pub fn reference_radius_m(&self) -> f64 {
        self.radius_m
    }

    /// What the slopes look like, for the fidelity planner: the mean change of slope between
    /// neighbouring texels (east and north together, unitless) and the 99th percentile of
    /// the slope's magnitude (tan of its angle).
    pub fn slope_statistics(&self) -> (f64, f64) {
        let (e, n) = (&self.slope_east.values, &self.slope_north.values);
        let w = self.slope_east.width;
        let (mut sum, mut count) = (0.0, 0usize);
        for i in 0..e.len() {
            if i % w + 1 < w {
                sum += ((e[i + 1] - e[i]).abs() + (n[i + 1] - n[i]).abs()) as f64;
                count += 1;
            }
        }
        (sum / count.max(1) as f64, self.steep_slope)
    }

    /// The DEM's highest height less its lowest [m].
    pub fn height_span_m(&self) -> f64 {
        self.top_m - self.bottom_m
    }

    /// Whether the DEM displaces the surface (else it only tilts the normals).
    pub fn displaces(&self) -> bool {
        self.displaces
    }

    /// The radius of a sphere the displaced surface contains [m] (the reference radius without
    /// displacement; a regional map's surroundings are at the reference radius).
    pub fn lowest_radius_m(&self) -> f64 {
        self.radius_m + self.displacing(self.bottom_m.min(0.0))
    }

    /// The radius of a sphere containing the displaced surface [m] (the reference radius
    /// without displacement).
    pub fn bounding_radius_m(&self) -> f64 {
        self.radius_m + self.displacing(self.top_m.max(0.0))
    }

    /// `height_m` where the DEM displaces the surface, else 0.
    fn displacing(&self, height_m: f64) -> f64 {
        if self.displaces { height_m } else { 0.0 }
    }
}

/// An albedo map and how its values become the BRDF's scale parameter, with its
/// area-averaged levels of detail.
#[derive(Clone, Debug, PartialEq)]
pub struct AlbedoMap {
    pub map: std::sync::Arc<maps::Map>,
    /// BRDF scale per unit map value: the albedo of the configured type that a scale of 1
    /// gives, inverted (1 where the map holds Hapke's or Lommel-Seeliger's `w` itself).
    pub scale_per_value: f64,
    /// The coarser levels ([`maps::Map::halved`]): `levels[k]` has texels `2^(k+1)` times
    /// the map's.
    levels: std::sync::Arc<Vec<maps::Map>>,
    /// The map's area-weighted mean times `scale_per_value`.
    mean_scale: f64,
    /// The map's least and greatest finite values times `scale_per_value`.
    scale_range: (f64, f64),
}

impl AlbedoMap {
    /// `map` with its pyramid of area-averaged levels (a third more memory).
    pub fn new(map: maps::Map, scale_per_value: f64) -> AlbedoMap {
        let mut levels: Vec<maps::Map> = Vec::new();
        while let Some(next) = levels.last().unwrap_or(&map).halved() {
            levels.push(next);
        }
        let (lo, hi) = map
            .values
            .iter()
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v as f64), hi.max(v as f64))
            });
        let (a, b) = (lo * scale_per_value, hi * scale_per_value);
        AlbedoMap {
            mean_scale: map.mean() * scale_per_value,
            scale_range: (a.min(b), a.max(b)),
            map: std::sync::Arc::new(map),
            scale_per_value,
            levels: std::sync::Arc::new(levels),
        }
    }

    /// The BRDF scale of the map's area-weighted mean value.
    pub fn mean_scale(&self) -> f64 {
        self.mean_scale
    }

    /// The mean relative change between neighbouring texels (in longitude) at each level,
    /// the map's first: how much a pixel spanning `2^k` texels differs from the next.
    pub fn contrast_by_level(&self) -> Vec<f64> {
        std::iter::once(&*self.map)
            .chain(self.levels.iter())
            .map(|m| {
                let mean = m.mean().abs().max(1e-30);
                let w = m.width;
                let (mut s, mut n) = (0.0, 0usize);
                for (i, pair) in m.values.windows(2).enumerate() {
                    if i % w + 1 < w {
                        s += (pair[1] - pair[0]).abs() as f64;
                        n += 1;
                    }
                }
                s / n.max(1) as f64 / mean
            })
            .collect()
    }

    /// The BRDF scale at the body-frame unit direction `n_body`, or `fallback` outside the map.
    #[inline]
    pub fn scale_at(&self, n_body: DVec3, fallback: f64) -> f64 {
        let (lon, lat) = crate::geometry::lon_lat(n_body);
        self.scale_at_lon_lat(lon, lat, fallback)
    }

    /// [`AlbedoMap::scale_at`] at body longitude and latitude [rad].
    #[inline]
    fn scale_at_lon_lat(&self, lon: f64, lat: f64, fallback: f64) -> f64 {
        self.map
            .sample(lon, lat)
            .map_or(fallback, |v| v * self.scale_per_value)
    }

    /// The BRDF scale averaged over a patch about `footprint_rad` across (radians of arc on
    /// the unit sphere) centred on `n_body`: the map itself where the patch is no wider than
    /// a texel of latitude (exactly [`AlbedoMap::scale_at`]), else interpolated between the
    /// two area-averaged levels whose texels bracket the patch (trilinear mip-mapping), so
    /// that a quadrangle spanning many texels reads their mean rather than one of them.
    #[inline]
    pub fn scale_over(&self, n_body: DVec3, footprint_rad: f64, fallback: f64) -> f64 {
        let (lon, lat) = crate::geometry::lon_lat(n_body);
        self.scale_over_lon_lat(lon, lat, footprint_rad, fallback)
    }

    /// [`AlbedoMap::scale_over`] at body longitude and latitude [rad].
    #[inline]
    pub fn scale_over_lon_lat(&self, lon: f64, lat: f64, footprint_rad: f64, fallback: f64) -> f64 {
        let ratio = footprint_rad / self.map.spacing_rad().1;
        // (NaN reads the map itself too.)
        if ratio.is_nan() || ratio <= 1.0 || self.levels.is_empty() {
            return self.scale_at_lon_lat(lon, lat, fallback);
        }
        let lod = ratio.log2();
        let k = lod.floor() as usize;
        let t = lod - k as f64;
        let level = |k: usize| match k {
            0 => &*self.map,
            k => &self.levels[(k - 1).min(self.levels.len() - 1)],
        };
        let (a, b) = (level(k).sample(lon, lat), level(k + 1).sample(lon, lat));
        match (a, b) {
            (Some(a), Some(b)) => ((1.0 - t) * a + t * b) * self.scale_per_value,
            (Some(v), None) | (None, Some(v)) => v * self.scale_per_value,
            (None, None) => fallback,
        }
    }

    /// The smallest and largest BRDF scale the map holds.
    pub fn scale_range(&self) -> (f64, f64) {
        self.scale_range
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use maps::{Encoding, Map};

    /// A checkerboard of 0 and 1 read over a patch: the point value while the patch is no
    /// wider than a texel, the block mean (1/2) once it spans two texels or more, and never
    /// outside [0, 1] in between.
    #[test]
    fn an_albedo_map_read_over_a_patch_gives_its_mean() {
        let (w, h) = (64usize, 32usize);
        let v = (0..w * h).map(|i| ((i % w + i / w) % 2) as f64).collect();
        let map =
            Map::from_values(std::path::Path::new("chess"), w, h, v, &Encoding::default()).unwrap();
        let (lon, lat) = map.texel_centre(10, 12);
        let texel = map.spacing_rad().1;
        let a = AlbedoMap::new(map, 1.0);
        let n = crate::geometry::unit_from_lon_lat(lon, lat);
        assert_eq!(a.scale_over(n, 0.5 * texel, -1.0), a.scale_at(n, -1.0));
        for k in [2.0, 3.0, 4.0, 8.0] {
            let v = a.scale_over(n, k * texel, -1.0);
            assert!((v - 0.5).abs() < 1e-6, "{k} texels: {v}");
        }
        for f in [1.2, 1.5, 1.9] {
            let v = a.scale_over(n, f * texel, -1.0);
            assert!(
                (0.0..=1.0).contains(&v) && v != a.scale_at(n, -1.0),
                "{f}: {v}"
            );
        }
    }

    /// A DEM of a constant 5 km displaces the sphere into the bigger sphere: rays meet it
    /// there to a millimetre, and a ray passing above the highest point misses.
    #[test]
    fn a_ray_meets_the_displaced_surface_where_the_bigger_sphere_is() {
        let radius = 1.0e6;
        let (w, h) = (360, 180);
        let dem = maps::Map::from_values(
            std::path::Path::new("flat"),
            w,
            h,
            vec![5000.0; w * h],
            &maps::Encoding::default(),
        )
        .unwrap();
        let relief = Relief::new(dem, radius, true).unwrap();
        let origin = DVec3::new(3.0e6, 2.0e5, -1.0e5);
        for target in [DVec3::ZERO, DVec3::new(0.0, 9.0e5, 3.0e5)] {
            let dir = (target - origin).normalize();
            let t = relief.intersect_displaced(origin, dir).unwrap();
            let want = crate::geometry::ray_sphere(origin, dir, radius + 5000.0).unwrap();
            assert!((t - want).abs() < 1e-3, "{t} vs {want}");
        }
        // A ray passing above the highest point misses.
        let miss = DVec3::new(0.0, 1.0, 0.0);
        assert!(
            relief
                .intersect_displaced(DVec3::new(0.0, 0.0, 1.006e6), miss)
                .is_none()
        );
    }

    /// The ground's normal is the displaced surface's own: perpendicular to the surface's
    /// tangents (differences of the displaced points over a millionth of a texel, inside a
    /// cell), and `up` without displacement.
    #[test]
    fn the_grounds_normal_is_perpendicular_to_the_displaced_surface() {
        let (w, h) = (360usize, 180usize);
        let v = (0..w * h)
            .map(|i| 3000.0 * (((i * 7919) % 101) as f64 / 101.0 - 0.5))
            .collect();
        let dem =
            Map::from_values(std::path::Path::new("rough"), w, h, v, &Encoding::default()).unwrap();
        let relief = Relief::new(dem.clone(), MOON_R_M, true).unwrap();
        let (dlon, dlat) = dem.spacing_rad();
        let point = |lon: f64, lat: f64| {
            crate::geometry::unit_from_lon_lat(lon, lat)
                * (MOON_R_M + dem.sample(lon, lat).unwrap())
        };
        for (lon, lat) in [(0.3, 0.2), (-2.0, -1.1), (2.9, 1.3), (1.0, 0.004)] {
            let up = crate::geometry::unit_from_lon_lat(lon, lat);
            let n = relief.ground_normal(up);
            assert!((n.dot(up) - 1.0).abs() < 1e-12);
            let (el, ep) = (1e-6 * dlon, 1e-6 * dlat);
            let east = point(lon + el, lat) - point(lon - el, lat);
            let north = point(lon, lat + ep) - point(lon, lat - ep);
            let n = n.normalize();
            assert!(n.dot(east.normalize()).abs() < 1e-6, "{lon} {lat}");
            assert!(n.dot(north.normalize()).abs() < 1e-6, "{lon} {lat}");
            // The ground is tilted there: the checks above are not vacuous.
            assert!(n.dot(up) < 1.0 - 1e-6);
        }
        let flat = Relief::new(dem, MOON_R_M, false).unwrap();
        let up = crate::geometry::unit_from_lon_lat(0.3, 0.2);
        assert_eq!(flat.ground_normal(up), up);
    }

    /// A 1000 m wall running north-south at longitude 0-0.05 deg on a flat 4 x 4 deg DEM
    /// (400 x 400), and its cell [m].
    fn wall() -> (Relief, f64) {
        let (n, span_deg) = (400usize, 4.0);
        let cell_deg = span_deg / n as f64;
        let values = (0..n * n)
            .map(|i| {
                let lon = -2.0 + ((i % n) as f64 + 0.5) * cell_deg;
                if (0.0..0.05).contains(&lon) {
                    WALL_M
                } else {
                    0.0
                }
            })
            .collect();
        (
            square_dem("wall", n, values),
            MOON_R_M * cell_deg.to_radians(),
        )
    }

    /// A relief (not displacing, on the Moon's radius) of an `n x n` DEM of heights [m] over
    /// 4 x 4 deg around (0, 0).
    fn square_dem(name: &str, n: usize, values: Vec<f64>) -> Relief {
        let enc = Encoding {
            lon_limits_deg: [-2.0, 2.0],
            lat_limits_deg: [-2.0, 2.0],
            ..Default::default()
        };
        let dem = Map::from_values(std::path::Path::new(name), n, n, values, &enc).unwrap();
        Relief::new(dem, MOON_R_M, false).unwrap()
    }

    const MOON_R_M: f64 = 1_737_400.0;
    const WALL_M: f64 = 1000.0;

    /// Walks west from the wall's foot with the Sun 10 deg above the eastern horizon; the
    /// shadow's end is the last point `hidden` says the Sun is hidden from, against
    /// `height / tan(elevation)`.
    fn shadow_end(hidden: impl Fn(DVec3, DVec3) -> bool, cell_m: f64) {
        let elevation = 10f64.to_radians();
        let mut end_m = 0.0;
        for k in 1..200 {
            let x_m = k as f64 * cell_m / 4.0;
            let up = crate::geometry::unit_from_lon_lat(-x_m / MOON_R_M, 0.0);
            let (east, _) = crate::geometry::east_north(up);
            let sun = east * elevation.cos() + up * elevation.sin();
            if hidden(up, sun) {
                end_m = x_m;
            }
        }
        let want = WALL_M / elevation.tan();
        eprintln!("shadow length {end_m:.0} m, analytic {want:.0} m, cell {cell_m:.0} m");
        assert!((end_m - want).abs() <= cell_m, "{end_m} vs {want}");
    }

    /// A 1000 m wall along the meridian at longitude 0 on a regional DEM (0.01 deg = 303 m
    /// texels) and the Sun 10 deg above the eastern horizon: the wall's shadow on flat ground
    /// west of it is `H / tan(10 deg) = 5671 m` long. The marched shadow ends there to within
    /// one DEM cell. (Measured: 5382 m. Two known effects shorten it: the surface curving
    /// away, 9 m of drop over 5.6 km, about 53 m of shadow; and bilinear interpolation, which
    /// reaches the wall's full height only at the first texel centre, half a cell east of the
    /// face.)
    #[test]
    fn a_wall_casts_the_shadow_length_of_its_height_over_the_sun_elevation() {
        let (relief, cell_m) = wall();
        shadow_end(|up, sun| relief.occluded(up, sun), cell_m);
        // Sun higher than the steepest slope: nothing is marched, nothing is shadowed.
        let up = crate::geometry::unit_from_lon_lat(-0.001, 0.0);
        assert!(!relief.occluded(up, up));
    }

    /// Warming the whole cache up gives the values a lookup computes on demand.
    #[test]
    fn a_warmed_dem_horizon_equals_one_filled_on_demand() {
        // A 3 km hill on a 64 x 64 DEM of 4 x 4 deg.
        let n = 64usize;
        let values = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64 - 31.5, (i / n) as f64 - 31.5);
                3000.0 * (-(x * x + y * y) / 40.0).exp()
            })
            .collect();
        let relief = square_dem("hill", n, values);
        let (lazy, warm) = (
            relief.clone().with_dem_horizon(8),
            relief.with_dem_horizon(8),
        );
        let dh = warm.dem_horizon.as_ref().unwrap();
        let texels = warm.heights_m.width * warm.heights_m.height;
        assert_eq!(dh.warm(|| false), texels);
        assert_eq!(dh.computed_texels(), texels);
        assert_eq!(dh.warm(|| false), 0);
        let elevation = 5f64.to_radians();
        let mut hidden = 0;
        for k in 0..400 {
            let up = crate::geometry::unit_from_lon_lat(-0.03 + k as f64 * 1.5e-4, 0.001);
            let (east, _) = crate::geometry::east_north(up);
            let sun = east * elevation.cos() + up * elevation.sin();
            let h = lazy.horizon_hides(up, sun);
            assert_eq!(h, warm.horizon_hides(up, sun));
            hidden += h as usize;
        }
        // West of the hill, the low Sun in the east is behind it.
        assert!(hidden > 100, "{hidden}");
    }

    /// The DEM's own horizon (16 azimuths) casts the same shadow, within one cell; the Sun
    /// from the west of the wall, the wall at its back, is not hidden.
    #[test]
    fn the_dem_horizon_casts_the_wall_shadow_and_knows_the_sun_azimuth() {
        let (relief, cell_m) = wall();
        let relief = relief.with_dem_horizon(16);
        shadow_end(|up, sun| relief.horizon_hides(up, sun), cell_m);
        let up = crate::geometry::unit_from_lon_lat(-0.002, 0.0);
        let (east, _) = crate::geometry::east_north(up);
        let elevation = 3f64.to_radians();
        assert!(relief.horizon_hides(up, east * elevation.cos() + up * elevation.sin()));
        assert!(!relief.horizon_hides(up, -east * elevation.cos() + up * elevation.sin()));
    }
}
