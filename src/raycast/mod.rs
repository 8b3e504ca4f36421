//! Per-pixel ray casting, the sibling of the quadrangle pipeline ([`crate::render`]): what a
//! line of sight through the camera meets, and the light it brings back. It serves the
//! converged reference of any scene ([`reference`]), which the sweep, the stability suite and
//! the tests measure the quadrangle pipeline against. A lone mesh body seen through a pinhole
//! needs no rays to decide what is lit and seen: [`exact`] clips its facets as polygons, for
//! its reference and, with `render.raycast_clip`, for its frames.
//!
//! It shares no integration, bounding or gridding code with the pipeline: only the body's
//! shape (ray intersections), its maps (albedo, DEM normals) and the BRDFs. Shadows cast by a
//! DEM, and a displaced surface itself, are met here by their own sphere tracing
//! ([`Terrain`]), which no grazing ray skips through, unlike the pipeline's fixed-step marching.
//!
//! The quantity cast along a ray is the integrand of Eq. 11 written per unit solid angle of
//! the line of sight: with `mu dA / d_cam^2 = dOmega`,
//!
//! ```text
//! d(P/L) = A_sun A_cam f_r mu0 cos(eps) / d_sun^2 dOmega,     dOmega = cos^3(eps) dx dy
//! ```
//!
//! where `(x, y, 1)` is the undistorted line of sight in the camera frame and `eps` its angle
//! from the boresight. A pixel's `(P/L)` is that integrated over the pixel's footprint: in pixel
//! coordinates `dx dy = du dv / (f_u f_v det J_Brown(x, y))` (Eqs. 39-40).

mod bins;
pub mod estimate;
pub mod exact;
pub mod facet_light;
pub mod limb;
pub mod raster;
pub mod reference;
pub mod sampled;
pub mod sun_grid;
mod terrain;

use terrain::Terrain;

use crate::body::Shape;
use crate::brdf::Local;
use crate::camera::Intrinsics;
use crate::scene::{Pose, Scene};
use glam::{DMat3, DVec3};

/// One scene seen from one pose, ready to cast rays.
pub struct Tracer<'a> {
    scene: &'a Scene,
    intrinsics: &'a Intrinsics,
    camera_m: DVec3,
    sun_m: DVec3,
    body_from_camera: DMat3,
    /// `A_sun A_cam / (f_u f_v)` [m^4 / px^2]: turns the integrand into `(P/L)` per px^2.
    k_px: f64,
    /// The shape's surface is moved by the DEM (rays meet [`Terrain`], which is then set).
    displaced: bool,
    terrain: Option<Terrain>,
    /// The silhouette test's space: the body frame scaled by `scale` (the unit sphere's for an
    /// undisplaced ellipsoid, `x' = A^-1 x`, else the body frame) where directions turn by at
    /// most `kappa` times their angle in the body frame; there, the unit direction from the
    /// camera to the centre and the angular radii [rad] of the spheres that contain the
    /// surface and that the surface contains.
    scale: DVec3,
    kappa: f64,
    to_centre: DVec3,
    outer_rad: f64,
    inner_rad: f64,
    /// A mesh's scattered irradiance per facet and `rho / pi` ([`Tracer::with_scattered`]).
    scattered: Option<(&'a [f64], f64)>,
    /// Per placed body: the unit direction (B) from the camera to its centre and the angular
    /// radius of its bounding sphere [rad].
    others: Vec<(DVec3, f64)>,
    /// A closed mesh body's sun-facing facets binned across the Sun's direction: its shadows
    /// on itself without the BVH ([`sun_grid`]).
    sun_grid: Option<sun_grid::SunGrid>,
}

/// A line of sight's point on the first body ([`Tracer::first_body_at`]): the line of sight
/// (B) with its `cos(eps)` and solid-angle factor ([`Tracer::line_of_sight`]), the point [m]
/// and its unit direction from the centre (B), the shape's outward normal and the normal the
/// BRDF sees (the DEM's where there is one), and a mesh's facet.
struct FirstBodyPoint {
    dir: DVec3,
    cos_eps: f64,
    solid: f64,
    p: DVec3,
    up: DVec3,
    shape_normal: DVec3,
    normal: DVec3,
    facet: Option<u32>,
}

/// The light of a point of the first body as if nothing hid the Sun from it
/// ([`Tracer::first_body_light`]), and what its shadow test needs.
struct FirstBodyLight {
    /// Direct sunlight and light scattered onto it by the rest of the body, `(P/L)` per px^2.
    direct: f64,
    scattered: f64,
    /// Its unit direction from the centre, the normal the BRDF sees, the unit direction to
    /// the Sun (B).
    up: DVec3,
    normal: DVec3,
    s: DVec3,
}

/// What one line of sight meets.
#[derive(Clone, Copy, Debug, Default)]
pub struct Hit {
    /// `(P/L)` per px^2 of image area at this point of the image plane [sr m^2 / px^2].
    pub pl_per_px2: f64,
    /// Range to the surface [m], NaN when the ray misses.
    pub range_m: f64,
}

/// Where an image-plane region lies against the body's silhouette.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coverage {
    /// Every line of sight misses the body's bounding sphere.
    Empty,
    /// Every line of sight meets the sphere the surface contains.
    Inside,
    /// The region may straddle the limb.
    Edge,
}

impl<'a> Tracer<'a> {
    pub fn new(scene: &'a Scene, pose: &Pose) -> Tracer<'a> {
        let intr = &scene.camera.intrinsics;
        let (fu, fv) = intr.focal_px();
        let relief = scene.body.relief.as_ref();
        let displaced = relief.filter(|r| r.displaces());
        // The silhouette test's space and the radii bounding the surface there.
        let (scale, kappa, outer, inner) = match (&scene.body.shape, displaced) {
            (Shape::Ellipsoid(e), None) => (
                DVec3::ONE / e.semi_axes_m,
                e.max_axis_m() / e.min_axis_m(),
                1.0,
                1.0,
            ),
            (shape, Some(r)) => (
                DVec3::ONE,
                1.0,
                crate::body::rendered_radius_m(shape, relief),
                r.lowest_radius_m().min(shape.inner_radius_m()),
            ),
            (shape, None) => (
                DVec3::ONE,
                1.0,
                shape.bounding_radius_m(),
                shape.inner_radius_m(),
            ),
        };
        let camera = pose.camera_position_m * scale;
        let d = camera.length();
        Tracer {
            scene,
            intrinsics: intr,
            camera_m: pose.camera_position_m,
            sun_m: pose.sun_position_m,
            body_from_camera: DMat3::from_quat(pose.body_from_camera),
            k_px: scene.sun.area_m2() * intr.aperture_area_m2() / (fu * fv),
            displaced: displaced.is_some(),
            terrain: relief.map(Terrain::new),
            scale,
            kappa,
            to_centre: -camera / d,
            outer_rad: if d > outer {
                (outer / d).asin()
            } else {
                std::f64::consts::PI
            },
            inner_rad: (inner / d).min(1.0).asin(),
            scattered: None,
            sun_grid: match &scene.body.shape {
                Shape::Mesh(m) => sun_grid::SunGrid::new(m, pose.sun_position_m),
                _ => None,
            },
            others: scene
                .others
                .iter()
                .map(|o| {
                    let to = o.position_m - pose.camera_position_m;
                    let (d, r) = (to.length(), o.body.shape.bounding_radius_m());
                    let rad = if d > r {
                        (r / d).asin()
                    } else {
                        std::f64::consts::PI
                    };
                    (to / d, rad)
                })
                .collect(),
        }
    }

    /// Unit line of sight (body frame) through pixel position `(u, v)` and the factor
    /// `cos^3(eps) / det J_Brown` that turns `du dv / (f_u f_v)` into its solid angle.
    #[inline]
    fn line_of_sight(&self, u: f64, v: f64) -> (DVec3, f64, f64) {
        let (x, y) = self.intrinsics.unproject(u, v);
        let ray = DVec3::new(x, y, 1.0);
        let inv_len = 1.0 / ray.length();
        let jac = self.intrinsics.distortion.jacobian_det(x, y);
        let cos_eps = inv_len;
        (
            self.body_from_camera * (ray * inv_len),
            cos_eps,
            cos_eps * cos_eps * cos_eps / jac,
        )
    }

    /// Where the square `[u0, u0 + side] x [v0, v0 + side]` of the image plane lies against the
    /// body: from the cone around its centre's line of sight through its corners (widened by a
    /// tenth for the curvature of distorted edges), in the silhouette test's space.
    pub fn coverage(&self, u0: f64, v0: f64, side: f64) -> Coverage {
        let (c, _, _) = self.line_of_sight(u0 + 0.5 * side, v0 + 0.5 * side);
        let mut spread: f64 = 0.0;
        for (du, dv) in [(0.0, 0.0), (side, 0.0), (0.0, side), (side, side)] {
            let (d, _, _) = self.line_of_sight(u0 + du, v0 + dv);
            spread = spread.max(angle(d, c));
        }
        let spread_b = 1.1 * spread + 1e-12;
        // Placed bodies: the cone misses all of them, or the region is an edge.
        let near_other = self
            .others
            .iter()
            .any(|&(to, rad)| angle(c, to) - spread_b <= rad);
        let spread = self.kappa * spread_b;
        let c = (c * self.scale).normalize();
        let off = angle(c, self.to_centre);
        if off - spread > self.outer_rad {
            if near_other {
                Coverage::Edge
            } else {
                Coverage::Empty
            }
        } else if off + spread < self.inner_rad && self.others.is_empty() {
            Coverage::Inside
        } else {
            Coverage::Edge
        }
    }

    /// Whether [`Coverage::Edge`] cells lie close to the silhouette (a sphere, or an
    /// undisplaced ellipsoid in its parameter space), rather than anywhere between the
    /// spheres bounding a displaced DEM.
    pub fn tight_silhouette(&self) -> bool {
        !self.displaced && self.others.is_empty()
    }

    /// Where the line of sight through pixel position `(u, v)` meets the undisplaced shape:
    /// the point [m] and the shape's outward normal there (body frame). A cheap probe of what
    /// a frame shows ([`crate::fidelity::budget`]).
    pub fn shape_at(&self, u: f64, v: f64) -> Option<(DVec3, DVec3)> {
        let (dir, _, _) = self.line_of_sight(u, v);
        let (t, normal) = self.scene.body.shape.intersect_normal(self.camera_m, dir)?;
        Some((self.camera_m + dir * t, normal))
    }

    /// Whether the first body's mesh facet `facet` is lit all over by the Sun ([`sun_grid`])
    /// or faces away from it at every corner: no edge of the light crosses it.
    pub fn lit_all_over_or_unlit(&self, facet: u32) -> bool {
        let Shape::Mesh(m) = &self.scene.body.shape else {
            return false;
        };
        if self.sun_grid.as_ref().is_some_and(|g| g.clear(facet)) {
            return true;
        }
        let n = m.normals()[facet as usize];
        m.facets()[facet as usize]
            .iter()
            .all(|&k| n.dot(self.sun_m - m.vertices_m()[k as usize]) <= 0.0)
    }

    /// The first body's mesh projected for rasterised primary visibility ([`raster`]),
    /// binned by tiles of `tile` px, where that is exact: a mesh body alone (no relief, no
    /// placed bodies) seen through an undistorted camera from outside its bounding sphere.
    pub fn rasteriser(&self, tile: usize) -> Option<raster::Rasteriser> {
        let Shape::Mesh(m) = &self.scene.body.shape else {
            return None;
        };
        if self.terrain.is_some() || !self.others.is_empty() {
            return None;
        }
        if self.camera_m.length() <= m.bounding_radius_m() {
            return None;
        }
        raster::Rasteriser::new(
            m,
            self.camera_m,
            self.body_from_camera.transpose(),
            self.intrinsics,
            tile,
        )
    }

    /// Casts the line of sight through pixel position `(u, v)`.
    #[inline]
    pub fn cast(&self, u: f64, v: f64) -> Hit {
        let (dir, cos_eps, solid) = self.line_of_sight(u, v);
        self.bring_back(dir, cos_eps, solid, self.nearest(dir))
    }

    /// [`Tracer::cast`] where the first surface on the line of sight is known to be the
    /// first body's mesh facet `facet` ([`raster`]): the ray meets that facet's plane, no BVH.
    #[inline]
    pub fn cast_onto(&self, u: f64, v: f64, facet: u32) -> Hit {
        match self.onto_facet(u, v, facet) {
            Some((dir, cos_eps, solid, t, normal)) => {
                self.bring_back(dir, cos_eps, solid, Some((t, normal, Some(facet), 0)))
            }
            // Not a mesh, or edge-on to the line of sight: the BVH decides.
            None => self.cast(u, v),
        }
    }

    /// The light the line of sight `dir` (with its `cos(eps)` and solid-angle factor) brings
    /// back from the surface `nearest` ([`Tracer::nearest`]) it meets.
    #[inline]
    fn bring_back(
        &self,
        dir: DVec3,
        cos_eps: f64,
        solid: f64,
        nearest: Option<(f64, DVec3, Option<u32>, usize)>,
    ) -> Hit {
        let miss = Hit {
            pl_per_px2: 0.0,
            range_m: f64::NAN,
        };
        let Some((t, shape_normal, facet, which)) = nearest else {
            return miss;
        };
        let p = self.camera_m + dir * t;
        let hit = |pl| Hit {
            pl_per_px2: pl,
            range_m: t,
        };
        if which > 0 {
            let to_sun = self.sun_m - p;
            let d_sun2 = to_sun.length_squared();
            let s = to_sun / d_sun2.sqrt();
            return hit(self.shade_other(which - 1, p, dir, s, shape_normal, d_sun2)
                * cos_eps
                * solid);
        }
        let light = self.first_body_light(p, dir, cos_eps, solid, shape_normal, facet);
        if light.direct > 0.0 && !self.sees_sun(p, light.up, light.normal, light.s, facet) {
            return hit(light.scattered);
        }
        hit(light.direct + light.scattered)
    }

    /// The light the first body's surface point `p` (B; `shape_normal` the shape's outward
    /// normal there, `facet` a mesh's facet) sends back along the line of sight `dir` (with its
    /// `cos(eps)` and solid-angle factor), as if nothing hid the Sun from it: the direct
    /// sunlight it reflects and the light scattered onto it, both `(P/L)` per px^2.
    #[inline]
    fn first_body_light(
        &self,
        p: DVec3,
        dir: DVec3,
        cos_eps: f64,
        solid: f64,
        shape_normal: DVec3,
        facet: Option<u32>,
    ) -> FirstBodyLight {
        let to_sun = self.sun_m - p;
        let d_sun2 = to_sun.length_squared();
        let s = to_sun / d_sun2.sqrt();
        let body = &self.scene.body;
        let up = p.normalize();
        let normal = match &body.relief {
            Some(r) => r.at(up, false).normal,
            None => shape_normal,
        };
        let mut light = FirstBodyLight {
            direct: 0.0,
            scattered: 0.0,
            up,
            normal,
            s,
        };
        let g = Local::new(normal, s, -dir);
        if g.mu <= 0.0 {
            return light;
        }
        // Light scattered onto the facet by the others, reflected as by a Lambertian surface
        // of the body's Bond albedo ([`crate::irradiance`]): `(rho / pi) R_i`, with `R_i` in
        // units of the solar irradiance at the body's centre (`A_sun / d_0^2` here).
        if let (Some((r, rho_over_pi)), Some(f)) = (self.scattered, facet) {
            light.scattered = self.k_px * rho_over_pi * r[f as usize] / self.sun_m.length_squared()
                * cos_eps
                * solid;
        }
        if g.mu0 <= 0.0 {
            return light;
        }
        if self.past_shape_terminator(shape_normal, s) {
            return light;
        }
        let f_r = match &body.albedo_map {
            Some(m) => body
                .brdf
                .with_scale(m.scale_at(up, body.brdf.scale()))
                .eval(&g),
            None => body.brdf.eval(&g),
        };
        // A DEM that tilts the normals only (no displacement) leaves the shape's surface
        // where it is: the paper's Eq. 37 weighs each area element of the shape by the cosines
        // of the DEM's normal, `f_r cos(theta_i) cos(theta_r) A`, as the facets beneath a pixel
        // show their light (a facet turned towards the camera shows more of it). Per unit of
        // the shape's projected area, which is what a ray's solid angle covers, that is the
        // radiance times `cos(theta_r) / mu_shape` (the renderer's integrand,
        // `render::integration`).
        // Weighed so, the facets' projected areas overlap where the terrain hides one from the
        // camera behind another, and the hidden one shows nothing (Eq. 33's occlusion, as the
        // renderer marches it towards the camera).
        let foreshortening = match (&body.relief, &self.terrain) {
            (Some(r), Some(terrain)) if !r.displaces() => {
                if terrain.shadowed(up, -dir, false) {
                    return light;
                }
                g.mu / shape_normal.dot(-dir).max(1e-12)
            }
            _ => 1.0,
        };
        light.direct = self.k_px * f_r * g.mu0 * foreshortening * cos_eps / d_sun2 * solid;
        light
    }

    /// Where the line of sight through pixel position `(u, v)` meets the plane of the first
    /// body's mesh facet `facet`: the line of sight (B), its `cos(eps)` and solid-angle factor,
    /// the range [m] and the facet's normal (B); `None` for a body that is not a mesh, or a
    /// plane met edge-on or behind the camera.
    #[inline]
    fn onto_facet(&self, u: f64, v: f64, facet: u32) -> Option<(DVec3, f64, f64, f64, DVec3)> {
        let Shape::Mesh(m) = &self.scene.body.shape else {
            return None;
        };
        let (dir, cos_eps, solid) = self.line_of_sight(u, v);
        let normal = m.normals()[facet as usize];
        let a = m.vertices_m()[m.facets()[facet as usize][0] as usize];
        let t = normal.dot(a - self.camera_m) / normal.dot(dir);
        (t.is_finite() && t > 0.0).then_some((dir, cos_eps, solid, t, normal))
    }

    /// What keeps the line of sight through `(u, v)` dark where it meets the first body and
    /// brings no light back: whether the Sun fails to light the point (its facet turned
    /// away, past the shape's terminator, or shadowed) and whether the camera fails to see it
    /// (turned away, or hidden by the terrain); `None` where the ray misses or meets another
    /// body. Each is asked in full, unlike [`Tracer::cast`], which stops at the first.
    ///
    /// A lit sliver may lie between a point the Sun alone fails and one the camera alone
    /// fails, where no ray of the rule lands: on Artemis I row 730 (191 km up, 108 deg of
    /// phase) strips 0.02 px across between the Sun's shadow and the ground a ridge hides
    /// from the camera, which the reference lost from whole pixels ([`reference`] asks this
    /// of its first rays).
    pub fn dark_because(&self, u: f64, v: f64) -> Option<(bool, bool)> {
        let FirstBodyPoint {
            dir,
            p,
            up,
            shape_normal,
            normal,
            facet,
            ..
        } = self.first_body_at(u, v)?;
        let s = (self.sun_m - p).normalize();
        let g = Local::new(normal, s, -dir);
        let camera_fails = g.mu <= 0.0
            || match (&self.scene.body.relief, &self.terrain) {
                (Some(r), Some(terrain)) if !r.displaces() => terrain.shadowed(up, -dir, false),
                _ => false,
            };
        let sun_fails = g.mu0 <= 0.0
            || self.past_shape_terminator(shape_normal, s)
            || !self.sees_sun(p, up, normal, s, facet);
        Some((sun_fails, camera_fails))
    }

    /// The light of the first body's mesh facet `facet` where the line of sight through pixel
    /// position `(u, v)` meets its plane, as if nothing hid the Sun: `(direct, scattered)`
    /// `(P/L)` per px^2 (`Tracer::first_body_light`); `None` where the plane is not met in
    /// front. What [`facet_light`] interpolates.
    pub fn facet_light(&self, u: f64, v: f64, facet: u32) -> Option<(f64, f64)> {
        let (dir, cos_eps, solid, t, normal) = self.onto_facet(u, v, facet)?;
        let p = self.camera_m + dir * t;
        let light = self.first_body_light(p, dir, cos_eps, solid, normal, Some(facet));
        Some((light.direct, light.scattered))
    }

    /// [`Tracer::cast_onto`] with the facet's light, unshadowed, given by `light` (`(direct,
    /// scattered)` at `(u, v)`, [`facet_light::FacetLights`]): only the range and, where the
    /// facet is not lit all over, whether the point sees the Sun, are cast. Without `range`,
    /// a facet lit all over or facing away from the Sun casts nothing and the hit's range is
    /// 0 (not cast).
    #[inline]
    pub fn cast_onto_with(
        &self,
        u: f64,
        v: f64,
        facet: u32,
        (direct, scattered): (f64, f64),
        range: bool,
    ) -> Hit {
        let unshadowed = direct <= 0.0 || self.sun_grid.as_ref().is_some_and(|g| g.clear(facet));
        if unshadowed && !range {
            return Hit {
                pl_per_px2: direct.max(0.0) + scattered,
                range_m: 0.0,
            };
        }
        let Some((dir, _, _, t, normal)) = self.onto_facet(u, v, facet) else {
            return self.cast_onto(u, v, facet);
        };
        let p = self.camera_m + dir * t;
        let sees_sun = unshadowed
            || self.sees_sun(
                p,
                p.normalize(),
                normal,
                (self.sun_m - p).normalize(),
                Some(facet),
            );
        Hit {
            pl_per_px2: if sees_sun {
                direct.max(0.0) + scattered
            } else {
                scattered
            },
            range_m: t,
        }
    }

    /// Whether a point of the first body whose shape has the outward normal `shape_normal`
    /// lies past the shape's own terminator (the Sun in unit direction `s`) under a DEM that
    /// tilts the normals only: the shape stays where it is, so its ground there faces away
    /// from the Sun however the DEM's normal leans. The renderer samples the shape's lit cap
    /// (Eqs. 13-19) and both terrains' shadow rays leave such points to this test; a
    /// displaced DEM meets its peaks lit beyond the terminator as geometry.
    #[inline]
    fn past_shape_terminator(&self, shape_normal: DVec3, s: DVec3) -> bool {
        matches!(&self.scene.body.relief, Some(r) if !r.displaces()) && shape_normal.dot(s) <= 0.0
    }

    /// The photometric geometry of the line of sight through `(u, v)` where it meets the first
    /// body in direct sunlight: `(mu0, mu, cos g, k)` with `k` the `(P/L)` per px^2 per unit of
    /// `f_r` (so that [`Tracer::cast`] gives `k f_r` there, scattered light aside). `None` where
    /// it misses, meets another body, or the point is unlit or shadowed. What the Hapke
    /// inversion ([`crate::inversion`]) fits the BRDF on.
    pub fn photometry(&self, u: f64, v: f64) -> Option<(f64, f64, f64, f64)> {
        let q = self.first_body_at(u, v)?;
        let to_sun = self.sun_m - q.p;
        let d_sun2 = to_sun.length_squared();
        let s = to_sun / d_sun2.sqrt();
        let g = Local::new(q.normal, s, -q.dir);
        if g.mu <= 0.0
            || g.mu0 <= 0.0
            || self.past_shape_terminator(q.shape_normal, s)
            || !self.sees_sun(q.p, q.up, q.normal, s, q.facet)
        {
            return None;
        }
        Some((
            g.mu0,
            g.mu,
            s.dot(-q.dir),
            self.k_px * g.mu0 * q.cos_eps / d_sun2 * q.solid,
        ))
    }

    /// Where the line of sight through `(u, v)` meets the first body ([`FirstBodyPoint`]);
    /// `None` where it misses or meets another body first.
    fn first_body_at(&self, u: f64, v: f64) -> Option<FirstBodyPoint> {
        let (dir, cos_eps, solid) = self.line_of_sight(u, v);
        let (t, shape_normal, facet, which) = self.nearest(dir)?;
        if which != 0 {
            return None;
        }
        let p = self.camera_m + dir * t;
        let up = p.normalize();
        let normal = match &self.scene.body.relief {
            Some(r) => r.at(up, false).normal,
            None => shape_normal,
        };
        Some(FirstBodyPoint {
            dir,
            cos_eps,
            solid,
            p,
            up,
            shape_normal,
            normal,
            facet,
        })
    }

    /// Whether the first body's surface point `p` (B; `up` its unit direction from the
    /// centre, `normal` the normal the BRDF sees) sees the Sun's centre in the unit direction
    /// `s`: no DEM relief ([`Terrain`]), no facet of its own mesh (SLIM Sec. 6.1: a ray from
    /// the facet to the Sun, not cast from a facet the Sun's grid knows to be lit all over)
    /// and no other body ([`Tracer::eclipsed`]) in the way. `facet`: the mesh's facet at `p`.
    #[inline]
    fn sees_sun(&self, p: DVec3, up: DVec3, normal: DVec3, s: DVec3, facet: Option<u32>) -> bool {
        if let Some(terrain) = &self.terrain
            && terrain.shadowed(up, s, self.displaced)
        {
            return false;
        }
        if let Shape::Mesh(m) = &self.scene.body.shape {
            let shadowed = match (&self.sun_grid, facet) {
                (Some(g), Some(f)) if g.clear(f) => false,
                (Some(g), _) => g.occluded(m.shadow_origin(p, normal, s), s),
                (None, _) => m.shadows(p, normal, s),
            };
            if shadowed {
                return false;
            }
        }
        !self.eclipsed(p, s, 0)
    }

    /// The nearest surface on the line of sight `dir` (unit, B): its range [m], outward
    /// normal (B), facet (a mesh's) and body (0 the first, `k + 1` the `k`-th placed one).
    #[inline]
    fn nearest(&self, dir: DVec3) -> Option<(f64, DVec3, Option<u32>, usize)> {
        let body = &self.scene.body;
        let mut best = match (&self.terrain, &body.shape) {
            (Some(terrain), _) if self.displaced => terrain
                .intersect(self.camera_m, dir, 0.0)
                .map(|t| (t, DVec3::ZERO, None, 0)),
            (_, Shape::Mesh(m)) => m
                .intersect(self.camera_m, dir, f64::INFINITY)
                .map(|h| (h.t_m, m.normals()[h.triangle as usize], Some(h.triangle), 0)),
            _ => body
                .shape
                .intersect_normal(self.camera_m, dir)
                .map(|(t, n)| (t, n, None, 0)),
        };
        for (k, o) in self.scene.others.iter().enumerate() {
            let (origin, d) = (o.to_body(self.camera_m), o.b_from_body.inverse() * dir);
            if let Some((t, n)) = o.body.shape.intersect_normal(origin, d)
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, o.b_from_body * n, None, k + 1));
            }
        }
        best
    }

    /// Whether a body other than `which` (0 the first, `k + 1` the `k`-th placed) hides the
    /// Sun's centre, in the unit direction `s`, from the point `p` (B): eclipses and the
    /// shadows bodies cast on each other (the Sun as a point: no penumbra).
    #[inline]
    fn eclipsed(&self, p: DVec3, s: DVec3, which: usize) -> bool {
        if which != 0 {
            let first = &self.scene.body.shape;
            if first.intersect(p, s).is_some() {
                return true;
            }
        }
        self.scene.others.iter().enumerate().any(|(k, o)| {
            k + 1 != which
                && o.body
                    .shape
                    .intersect(o.to_body(p), o.b_from_body.inverse() * s)
                    .is_some()
        })
    }

    /// `(P/L)` per px^2 per unit of `cos(eps) dOmega` of the placed body `k` at its point `p`
    /// (B) whose outward normal is `normal` (B), seen along `dir`, the Sun at `s` and `d_sun2`.
    fn shade_other(
        &self,
        k: usize,
        p: DVec3,
        dir: DVec3,
        s: DVec3,
        normal: DVec3,
        d_sun2: f64,
    ) -> f64 {
        let o = &self.scene.others[k];
        let g = Local::new(normal, s, -dir);
        if g.mu <= 0.0 || g.mu0 <= 0.0 {
            return 0.0;
        }
        let inv = o.b_from_body.inverse();
        let local = o.to_body(p);
        if let Shape::Mesh(m) = &o.body.shape
            && m.shadows(local, inv * normal, inv * s)
        {
            return 0.0;
        }
        if self.eclipsed(p, s, k + 1) {
            return 0.0;
        }
        let body = &o.body;
        let f_r = match &body.albedo_map {
            Some(m) => body
                .brdf
                .with_scale(m.scale_at(local.normalize(), body.brdf.scale()))
                .eval(&g),
            None => body.brdf.eval(&g),
        };
        self.k_px * f_r * g.mu0 / d_sun2
    }

    /// The same tracer with the irradiance scattered onto each facet of a mesh body
    /// (fractions of the solar irradiance at the body's centre, [`crate::irradiance`]) and the
    /// Bond albedo that reflects it.
    pub fn with_scattered(mut self, per_facet: &'a [f64], bond_albedo: f64) -> Self {
        self.scattered = Some((per_facet, bond_albedo / std::f64::consts::PI));
        self
    }
}

/// The pixel `p` of a `w x h` image (row-major) and its neighbours inside the image (up to
/// eight): where the ray casters look for edges of the light around a pixel.
pub fn around(p: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (i, j) = (p % w, p / w);
    let (x0, x1) = (i.saturating_sub(1), (i + 1).min(w - 1));
    let (y0, y1) = (j.saturating_sub(1), (j + 1).min(h - 1));
    (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| y * w + x))
}

/// The angle between two unit vectors [rad], accurate when it is tiny (where `acos` of the dot
/// product is not: a cell 1/256 px wide of a far body spans 4e-8 rad).
#[inline]
fn angle(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}
