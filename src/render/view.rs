//! One frame's geometry, derived once from the pose: the CSF (Sec. 4.1), the camera and Sun
//! positions in it, and `camera_from_csf`. Every later step works in CSF, over the grid's
//! directions ([`Grid`]).

use super::settings::{FovShape, SelfShadowing};
use crate::body::{Relief, ReliefSample, Shape};
use crate::brdf::Local;
use crate::camera::Intrinsics;
use crate::geometry::CsfFrame;
use crate::scene::Pose;
use glam::{DMat3, DVec3};

pub struct View<'a> {
    pub intrinsics: &'a Intrinsics,
    pub shape: &'a Shape,
    /// The DEM, if any: it tilts the normals the BRDF sees, may displace the surface and cast
    /// shadows.
    pub relief: Option<&'a Relief>,
    /// How the relief hides the Sun and the camera (`Off` without a relief).
    pub shadows: SelfShadowing,
    pub csf: CsfFrame,
    pub csf_from_body: DMat3,
    pub camera_from_csf: DMat3,
    /// Camera position in CSF [m].
    pub cam_csf: DVec3,
    /// Sun position in CSF [m].
    pub sun_csf: DVec3,
    /// The space the longitude-latitude grid is laid in.
    pub grid: Grid,
    /// Super-sampling factor: pixel coordinates are on a grid this many times finer.
    pub m: f64,
    pub fov: FovShape,
    /// Cosine of the cone FOV half-angle (Eq. 26).
    pub cone_cos: f64,
    /// A point is in the frustum when its pixel lies within the frame grown by this [fine px].
    pub margin_px: f64,
}

/// The space the longitude-latitude grid is laid in, and what a grid direction means.
///
/// For a sphere, displaced or not, the grid is the CSF itself and a direction is the surface
/// point's direction from the centre. An undisplaced triaxial ellipsoid `P = A u` (`A` the
/// diagonal of its semi-axes, `u` on the unit sphere) is laid out in its *parameter space*
/// `x' = A^-1 x`, where it is the unit sphere: there, with the CSF built from `C' = A^-1 C` and
/// `S' = A^-1 S`, the grid direction is `u` itself. Visibility and lighting are the unit
/// sphere's exactly, since `n . (C - P) = u . (C' - u) / |A^-1 u|` with
/// `n = A^-1 u / |A^-1 u|` (and the same for the Sun), so the sphere's bounding (Eqs. 13-19)
/// and projected-uniform sampling serve the ellipsoid at any range. The affine map is
/// `csf_from_grid = csf_from_body A body_from_grid`; the normal over `u` is
/// `normalize(csf_from_grid^-T u)` and the area per unit solid angle of `u` is
/// `det A |A^-1 u|` (from `(A x) x (A y) = det A A^-T (x x y)`).
#[derive(Clone, Copy, Debug)]
pub struct Grid {
    /// Camera and Sun positions in the grid's CSF [m, or semi-axes in parameter space].
    pub cam: DVec3,
    pub sun: DVec3,
    /// Phase angle in the grid's CSF [rad] (the pose's own in [`View::csf`]).
    pub phase_rad: f64,
    /// Radius of the sphere bounding the surface in the grid's space (1 in parameter space).
    pub radius: f64,
    /// Radius of a sphere the surface contains (`radius` but for a displacing DEM, whose
    /// lowest point it is): its visible and lit caps bound the directions where the surface
    /// can be seen and lit.
    pub radius_min: f64,
    affine: Option<Affine>,
}

#[derive(Clone, Copy, Debug)]
struct Affine {
    csf_from_grid: DMat3,
    grid_from_csf: DMat3,
    /// `csf_from_grid^-T`: takes `u` to the (unnormalised) normal.
    normal_from_grid: DMat3,
    /// `body_from_csf csf_from_grid`: takes `u` to the body-frame point.
    body_from_grid: DMat3,
    /// `det A / R^2` [m]: times `|A^-1 u|` [1/m], the area factor relative to `R^2`.
    det_over_r2: f64,
}

/// The surface at one point, as the integrand needs it: see [`View::surface_point`].
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// CSF point [m].
    pub p: DVec3,
    /// The normal the BRDF sees (CSF).
    pub normal: DVec3,
    /// Area per solid angle relative to the shape's bounding `R^2`.
    pub area: f64,
    pub horizon_sin: Option<f64>,
    /// On a displaced surface, the DEM at the point ([`Relief::at`]), whose ground slope
    /// [`View::ground_area`] makes the area the point shows the camera.
    pub ground: Option<ReliefSample>,
}

impl<'a> View<'a> {
    pub fn new(
        intrinsics: &'a Intrinsics,
        shape: &'a Shape,
        relief: Option<&'a Relief>,
        self_shadowing: SelfShadowing,
        pose: &Pose,
        m: u32,
        fov: FovShape,
    ) -> Self {
        let camera_from_body = DMat3::from_quat(pose.body_from_camera.inverse());
        let image_up_body = pose.body_from_camera * DVec3::NEG_Y;
        let csf = CsfFrame::new(pose.sun_position_m, pose.camera_position_m, image_up_body);
        let csf_from_body = csf.csf_from_body();
        let half = intrinsics.circumscribed_half_angle();
        let cam_csf = csf_from_body * pose.camera_position_m;
        let sun_csf = csf_from_body * pose.sun_position_m;
        let displaced = relief.is_some_and(|r| r.displaces());
        let grid = match shape {
            Shape::Ellipsoid(e) if !displaced => {
                let a = DMat3::from_diagonal(e.semi_axes_m);
                let a_inv = DMat3::from_diagonal(DVec3::ONE / e.semi_axes_m);
                let (sun_p, cam_p) = (a_inv * pose.sun_position_m, a_inv * pose.camera_position_m);
                let par = CsfFrame::new(sun_p, cam_p, a_inv * image_up_body);
                let csf_from_grid = csf_from_body * a * par.body_from_csf;
                let r = e.max_axis_m();
                Grid {
                    cam: par.csf_from_body() * cam_p,
                    sun: par.csf_from_body() * sun_p,
                    phase_rad: par.phase_rad,
                    radius: 1.0,
                    radius_min: 1.0,
                    affine: Some(Affine {
                        csf_from_grid,
                        grid_from_csf: csf_from_grid.inverse(),
                        normal_from_grid: csf_from_body * a_inv * par.body_from_csf,
                        body_from_grid: a * par.body_from_csf,
                        det_over_r2: a.determinant() / (r * r),
                    }),
                }
            }
            _ => {
                let radius = crate::body::rendered_radius_m(shape, relief);
                Grid {
                    cam: cam_csf,
                    sun: sun_csf,
                    phase_rad: csf.phase_rad,
                    radius,
                    radius_min: match relief {
                        Some(r) if r.displaces() => r.lowest_radius_m().min(radius),
                        _ => radius,
                    },
                    affine: None,
                }
            }
        };
        View {
            intrinsics,
            shape,
            relief,
            shadows: if relief.is_some() {
                self_shadowing
            } else {
                SelfShadowing::Off
            },
            csf_from_body,
            csf,
            camera_from_csf: camera_from_body * csf.body_from_csf,
            cam_csf,
            sun_csf,
            grid,
            m: m as f64,
            fov,
            cone_cos: (half + 1e-3).min(std::f64::consts::PI).cos(),
            margin_px: 4.0 * m as f64,
        }
    }

    /// Everything the integrand needs at the surface over CSF unit direction `dir`: the point,
    /// the normal the BRDF sees (the shape's, or the DEM's), the area per solid angle
    /// ([`View::area_factor`]), on a displaced surface the DEM's sample there (whose ground
    /// slope gives the area the point shows the camera where the terrain may hide it:
    /// [`SurfacePoint::ground`]) and, with horizon-map shadows, the sine of the local horizon
    /// (for [`View::shadow`]). One relief lookup.
    #[inline]
    pub fn surface_point(&self, dir: DVec3) -> SurfacePoint {
        let Some(r) = self.relief else {
            let (p, n) = self.surface(dir);
            return SurfacePoint {
                p,
                normal: n,
                area: self.area_factor(dir, p, n),
                horizon_sin: None,
                ground: None,
            };
        };
        let horizon = self.shadows == SelfShadowing::HorizonMap;
        let at = r.at(self.body_dir(dir), horizon);
        let normal = self.csf_from_body * at.normal;
        // The geometric normal is the DEM's where it displaces the surface, the shape's else.
        let (p, n_geo) = if r.displaces() {
            (dir * (r.reference_radius_m() + at.height_m), normal)
        } else {
            self.surface(dir)
        };
        let ground = r.displaces().then_some(at);
        SurfacePoint {
            p,
            normal,
            area: self.area_factor(dir, p, n_geo),
            horizon_sin: at.horizon_sin,
            ground,
        }
    }

    /// Hides what the relief hides at the surface point `p` over CSF unit direction `dir`:
    /// `g.mu0` (the Sun) and `g.mu` (the camera) become 0 where the terrain blocks them
    /// (ray marching), or where they rise less than the horizon: the DEM's own in their
    /// azimuth, or the horizon map's (`horizon_sin` from [`View::surface_point`]).
    ///
    /// On a displaced surface a direction below the point's horizontal (far-side terrain
    /// facing the camera behind the limb, a slope facing the Sun beyond the terminator, a
    /// peak seen or lit over the horizon) is beyond what a horizon holds: it is ray-marched
    /// whatever the mode, and towards the camera even without self-shadowing, since what
    /// lies behind the limb is not seen.
    #[inline]
    pub fn shadow(&self, dir: DVec3, p: DVec3, horizon_sin: Option<f64>, g: &mut Local) {
        let Some(r) = self.relief else {
            return;
        };
        let occluded = |up, to| r.occluded(up, to);
        if self.shadows == SelfShadowing::RayMarching {
            return self.hide(dir, p, g, [true, true], occluded);
        }
        // Below the horizontal: `(target - p) . dir <= 0`, `dir` being `p`'s direction.
        let below = |target: DVec3| r.displaces() && (target - p).dot(dir) <= 0.0;
        let shadows = self.shadows != SelfShadowing::Off;
        let sun_below = shadows && g.mu0 > 0.0 && below(self.sun_csf);
        let cam_below = g.mu > 0.0 && below(self.cam_csf);
        if sun_below || cam_below {
            self.hide(dir, p, g, [sun_below, cam_below], occluded);
        }
        if !shadows {
            return;
        }
        if r.dem_horizon.is_some() {
            // Looked up once for both directions; it leaves those below the horizontal alone.
            if (g.mu0 > 0.0 || g.mu > 0.0)
                && let Some(h) = r.dem_horizon_at(self.body_dir(dir))
            {
                self.hide(dir, p, g, [true, true], |_, to| h.hides(to));
            }
            return;
        }
        let top = r.horizon_sin_max();
        let low = |mu: f64| mu > 0.0 && mu < top;
        if (low(g.mu0) || low(g.mu))
            && let Some(h) = horizon_sin
        {
            if !sun_below && g.mu0 < h {
                g.mu0 = 0.0;
            }
            if !cam_below && g.mu < h {
                g.mu = 0.0;
            }
        }
    }

    /// The area per solid angle, relative to the shape's bounding `R^2`, that the displaced
    /// surface point `sp` over CSF direction `dir` shows the camera along CSF unit `c_hat`:
    /// `(n_g . c) (|p| / R)^2` with `n_g` the ground's own normal ([`Relief::ground_normal`],
    /// from [`SurfacePoint::ground`]), 0 where it faces away; `None` off a displaced surface.
    #[inline]
    pub fn ground_area(&self, sp: &SurfacePoint, dir: DVec3, c_hat: DVec3) -> Option<f64> {
        let (r, at) = (self.relief?, sp.ground.as_ref()?);
        let ground = self.csf_from_body * r.ground_from(self.body_dir(dir), at);
        let rb = self.shape.bounding_radius_m();
        Some(ground.dot(c_hat).max(0.0) * sp.p.length_squared() / (rb * rb))
    }

    /// Whether the camera (along CSF unit `c_hat`) is lower over the surface point over CSF
    /// direction `dir` than the relief's steep slopes ([`Relief::below_steep_slopes`]);
    /// false without a relief. For a sphere's grid (the CSF itself, as a displacing DEM's
    /// is), `dir` is the point's direction from the centre and the test, a dot product, is
    /// the same in either frame.
    #[inline]
    pub fn camera_below_steep_slopes(&self, dir: DVec3, c_hat: DVec3) -> bool {
        debug_assert!(self.grid.affine.is_none());
        self.relief
            .is_some_and(|r| r.below_steep_slopes(dir, c_hat))
    }

    /// Zeroes `g.mu0` (when `sun`) and `g.mu` (when `cam`) where `hidden(up, toward)` (body
    /// frame: the point's direction from the centre, the unit direction to the Sun or the
    /// camera) says so.
    #[inline(always)]
    fn hide(
        &self,
        dir: DVec3,
        p: DVec3,
        g: &mut Local,
        [sun, cam]: [bool; 2],
        hidden: impl Fn(DVec3, DVec3) -> bool,
    ) {
        let up = self.body_dir(dir);
        let to = |target: DVec3| self.csf.body_from_csf * (target - p).normalize();
        if sun && g.mu0 > 0.0 && hidden(up, to(self.sun_csf)) {
            g.mu0 = 0.0;
        }
        if cam && g.mu > 0.0 && hidden(up, to(self.cam_csf)) {
            g.mu = 0.0;
        }
    }

    /// Surface point [m] and outward unit normal (CSF) over the grid's unit direction `dir`
    /// ([`Grid`]): an ellipsoid through its parameter space, a sphere directly; a displacing
    /// DEM moves the point to `R + h` and turns the normal to its own.
    #[inline(always)]
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        if let Some(a) = &self.grid.affine {
            return (
                a.csf_from_grid * dir,
                (a.normal_from_grid * dir).normalize(),
            );
        }
        if let Some(r) = self.relief.filter(|r| r.displaces()) {
            let at = r.at(self.csf.body_from_csf * dir, false);
            let p = dir * (r.reference_radius_m() + at.height_m);
            return (p, self.csf_from_body * at.normal);
        }
        // What is left is a sphere (an undisplaced ellipsoid has its parameter space), which
        // looks the same in CSF as in the body frame.
        debug_assert!(self.shape.is_round());
        self.shape.surface(dir)
    }

    /// The body-frame unit direction from the centre to the surface point over the grid's
    /// direction `dir`: where maps are looked up.
    #[inline(always)]
    pub fn body_dir(&self, dir: DVec3) -> DVec3 {
        match &self.grid.affine {
            Some(a) => (a.body_from_grid * dir).normalize(),
            None => self.csf.body_from_csf * dir,
        }
    }

    /// The surface area per unit solid angle of the grid's directions at the point `p` with
    /// (geometric) normal `n` over the grid's unit direction `dir`, relative to the shape's
    /// bounding `R^2`: `(|p|/R)^2 / (n . dir)` (1 on an undisplaced sphere), and
    /// `det A |A^-1 u| / R^2` on an ellipsoid's parameter sphere ([`Grid`]).
    #[inline(always)]
    pub fn area_factor(&self, dir: DVec3, p: DVec3, n: DVec3) -> f64 {
        if let Some(a) = &self.grid.affine {
            return a.det_over_r2 * (a.normal_from_grid * dir).length();
        }
        if self.shape.is_round() && !self.displaced() {
            return 1.0;
        }
        let r = self.shape.bounding_radius_m();
        p.length_squared() / (r * r) / n.dot(dir).max(1e-9)
    }

    /// Whether the grid's space is a sphere's ([`Grid`]): then the visible-cap bounds and the
    /// projected-uniform spacing apply; else the grid covers every direction, uniformly.
    pub fn sphere_like(&self) -> bool {
        self.shape.is_round() || self.grid.affine.is_some()
    }

    /// A point [m] (CSF) of the surface over the grid's direction `dir`, for range estimates:
    /// the point itself on an ellipsoid, else on the shape's bounding sphere.
    #[inline(always)]
    pub fn rough_point(&self, dir: DVec3) -> DVec3 {
        match &self.grid.affine {
            Some(a) => a.csf_from_grid * dir,
            None => dir * self.shape.bounding_radius_m(),
        }
    }

    /// The CSF point [m] of a point of the grid's space.
    #[inline(always)]
    pub fn csf_from_grid(&self, p: DVec3) -> DVec3 {
        match &self.grid.affine {
            Some(a) => a.csf_from_grid * p,
            None => p,
        }
    }

    /// The camera's line of sight along the CSF unit direction `dir_csf` in the grid's space:
    /// origin and unit direction.
    #[inline(always)]
    pub fn grid_ray(&self, dir_csf: DVec3) -> (DVec3, DVec3) {
        match &self.grid.affine {
            Some(a) => (self.grid.cam, (a.grid_from_csf * dir_csf).normalize()),
            None => (self.cam_csf, dir_csf),
        }
    }

    /// Whether a DEM displaces the surface.
    #[inline(always)]
    pub fn displaced(&self) -> bool {
        self.relief.is_some_and(|r| r.displaces())
    }

    /// The exactly known lit and visible region in the grid's longitude and latitude, where
    /// there is one: an undisplaced sphere's, and an ellipsoid's, which is its parameter
    /// sphere's ([`Grid`]).
    pub fn lit_visible(&self) -> Option<crate::body::LitVisible> {
        if self.grid.affine.is_some() {
            return Some(crate::body::LitVisible::new(
                1.0,
                self.grid.sun,
                self.grid.cam,
            ));
        }
        if self.displaced() {
            return None;
        }
        self.shape.lit_visible(self.sun_csf, self.cam_csf)
    }

    /// Camera-frame coordinates of a CSF point.
    #[inline(always)]
    pub fn to_camera(&self, p_csf: DVec3) -> DVec3 {
        self.camera_from_csf * (p_csf - self.cam_csf)
    }

    /// Fine-grid pixel coordinates of a camera-frame point, if in front of the camera.
    #[inline(always)]
    pub fn pixel(&self, p_cam: DVec3) -> Option<[f64; 2]> {
        if p_cam.z <= 0.0 {
            return None;
        }
        let [u, v] = self.intrinsics.project(p_cam.x, p_cam.y, p_cam.z);
        Some([u * self.m, v * self.m])
    }

    /// FOV test (Eqs. 26-27) of a quadrangle whose midpoint failed [`View::in_fov`]: whether
    /// its corners (CSF unit directions) reach into the field all the same. For the frustum,
    /// whether the box around the corners that project overlaps the frame grown by the
    /// margin; for the cone, whether a corner is inside it. A quadrangle larger than the
    /// margin can straddle the frame's edge with its midpoint outside: pruning it by its
    /// midpoint alone lost 3.3e-4 of the light at 1/16 per pixel on the Artemis I close
    /// approach, where the Moon overfills the frame (all of it in the first 3 columns).
    pub fn corners_reach_fov(&self, corners: [DVec3; 4]) -> bool {
        let cam = corners.map(|d| self.to_camera(self.surface(d).0));
        match self.fov {
            FovShape::Cone => cam.iter().any(|&p| self.in_fov(p)),
            FovShape::Frustum => {
                let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for [u, v] in cam.iter().filter_map(|&p| self.pixel(p)) {
                    lo = [lo[0].min(u), lo[1].min(v)];
                    hi = [hi[0].max(u), hi[1].max(v)];
                }
                self.box_meets_frame(lo, hi)
            }
        }
    }

    /// Whether the box `lo..hi` of fine-grid pixel coordinates meets the frame grown by the
    /// margin.
    #[inline(always)]
    fn box_meets_frame(&self, lo: [f64; 2], hi: [f64; 2]) -> bool {
        let (w, h) = (
            self.intrinsics.width_px as f64 * self.m,
            self.intrinsics.height_px as f64 * self.m,
        );
        hi[0] >= -self.margin_px
            && hi[1] >= -self.margin_px
            && lo[0] <= w + self.margin_px
            && lo[1] <= h + self.margin_px
    }

    /// FOV test (Eqs. 26-27) of a camera-frame point.
    #[inline(always)]
    pub fn in_fov(&self, p_cam: DVec3) -> bool {
        match self.fov {
            FovShape::Cone => p_cam.z >= self.cone_cos * p_cam.length(),
            FovShape::Frustum => self
                .pixel(p_cam)
                .is_some_and(|uv| self.box_meets_frame(uv, uv)),
        }
    }
}
