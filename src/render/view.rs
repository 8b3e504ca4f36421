//! One frame's geometry, derived once from the pose: the CSF (Sec. 4.1), the camera and Sun
//! positions in it, and `camera_from_csf`. Every later step works in CSF.

use super::settings::{FovShape, SelfShadowing};
use crate::body::{Relief, Shape};
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
    /// Super-sampling factor: pixel coordinates are on a grid this many times finer.
    pub m: f64,
    pub fov: FovShape,
    /// Cosine of the cone FOV half-angle (Eq. 26).
    pub cone_cos: f64,
    /// A point is in the frustum when its pixel lies within the frame grown by this [fine px].
    pub margin_px: f64,
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
            cam_csf: csf_from_body * pose.camera_position_m,
            sun_csf: csf_from_body * pose.sun_position_m,
            m: m as f64,
            fov,
            cone_cos: (half + 1e-3).min(std::f64::consts::PI).cos(),
            margin_px: 4.0 * m as f64,
        }
    }

    /// Everything the integrand needs at the surface over CSF unit direction `dir`: the point,
    /// the normal the BRDF sees (the shape's, or the DEM's), the area per solid angle
    /// ([`View::area_factor`]) and, with horizon-map shadows, the sine of the local horizon
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
            };
        };
        let horizon = self.shadows == SelfShadowing::HorizonMap;
        let at = r.at(self.csf.body_from_csf * dir, horizon);
        let normal = self.csf_from_body * at.normal;
        // The geometric normal is the DEM's where it displaces the surface, the shape's else.
        let (p, n_geo) = if r.displaces() {
            (dir * (r.reference_radius_m() + at.height_m), normal)
        } else {
            self.surface(dir)
        };
        SurfacePoint {
            p,
            normal,
            area: self.area_factor(dir, p, n_geo),
            horizon_sin: at.horizon_sin,
        }
    }

    /// Hides what the relief hides at the surface point `p` over CSF unit direction `dir`:
    /// `g.mu0` (the Sun) and `g.mu` (the camera) become 0 where the terrain blocks them
    /// (ray marching), or where they rise less than the horizon map's horizon
    /// (`horizon_sin` from [`View::surface_point`]). Nothing without self-shadowing.
    #[inline]
    pub fn shadow(&self, dir: DVec3, p: DVec3, horizon_sin: Option<f64>, g: &mut Local) {
        let Some(r) = self.relief else {
            return;
        };
        match self.shadows {
            SelfShadowing::Off => {}
            SelfShadowing::RayMarching => {
                let up = self.csf.body_from_csf * dir;
                let to = |target: DVec3| self.csf.body_from_csf * (target - p).normalize();
                if g.mu0 > 0.0 && r.occluded(up, to(self.sun_csf)) {
                    g.mu0 = 0.0;
                }
                if g.mu > 0.0 && r.occluded(up, to(self.cam_csf)) {
                    g.mu = 0.0;
                }
            }
            SelfShadowing::HorizonMap => {
                let top = r.horizon_sin_max();
                let low = |mu: f64| mu > 0.0 && mu < top;
                if (low(g.mu0) || low(g.mu))
                    && let Some(h) = horizon_sin
                {
                    if g.mu0 < h {
                        g.mu0 = 0.0;
                    }
                    if g.mu < h {
                        g.mu = 0.0;
                    }
                }
            }
        }
    }

    /// Surface point [m] and outward unit normal (CSF) over the CSF unit direction `dir`: a
    /// round shape is asked directly, another one in the body frame; a displacing DEM moves
    /// the point to `R + h` and turns the normal to its own.
    #[inline(always)]
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        if let Some(r) = self.relief.filter(|r| r.displaces()) {
            let at = r.at(self.csf.body_from_csf * dir, false);
            let p = dir * (r.reference_radius_m() + at.height_m);
            return (p, self.csf_from_body * at.normal);
        }
        if self.shape.is_round() {
            return self.shape.surface(dir);
        }
        let (p, n) = self.shape.surface(self.csf.body_from_csf * dir);
        (self.csf_from_body * p, self.csf_from_body * n)
    }

    /// The surface area per unit solid angle at the point `p` with (geometric) normal `n` over
    /// the unit direction `dir`, relative to the shape's bounding `R^2`:
    /// `(|p|/R)^2 / (n . dir)` (1 on an undisplaced sphere).
    #[inline(always)]
    pub fn area_factor(&self, dir: DVec3, p: DVec3, n: DVec3) -> f64 {
        if self.shape.is_round() && !self.displaced() {
            return 1.0;
        }
        let r = self.shape.bounding_radius_m();
        p.length_squared() / (r * r) / n.dot(dir).max(1e-9)
    }

    /// Whether a DEM displaces the surface.
    #[inline(always)]
    pub fn displaced(&self) -> bool {
        self.relief.is_some_and(|r| r.displaces())
    }

    /// The radius of a sphere containing the surface as rendered (relief included) [m].
    pub fn bounding_radius_m(&self) -> f64 {
        match self.relief {
            Some(r) if r.displaces() => r.bounding_radius_m().max(self.shape.bounding_radius_m()),
            _ => self.shape.bounding_radius_m(),
        }
    }

    /// The exactly known lit and visible region, where there is one (an undisplaced sphere).
    pub fn lit_visible(&self) -> Option<crate::body::LitVisible> {
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

    /// FOV test (Eqs. 26-27) of a camera-frame point.
    #[inline(always)]
    pub fn in_fov(&self, p_cam: DVec3) -> bool {
        match self.fov {
            FovShape::Cone => p_cam.z >= self.cone_cos * p_cam.length(),
            FovShape::Frustum => match self.pixel(p_cam) {
                Some([u, v]) => {
                    let (w, h) = (
                        self.intrinsics.width_px as f64 * self.m,
                        self.intrinsics.height_px as f64 * self.m,
                    );
                    u >= -self.margin_px
                        && v >= -self.margin_px
                        && u <= w + self.margin_px
                        && v <= h + self.margin_px
                }
                None => false,
            },
        }
    }
}
