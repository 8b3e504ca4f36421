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
    /// DEM slopes that tilt the normals the BRDF sees, if any.
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

    /// The normal the BRDF sees at the surface over CSF unit direction `dir`: the shape's
    /// `n`, tilted by the relief when there is one; with horizon-map shadows, also the sine of
    /// the local horizon there (for [`View::shadow`]).
    #[inline]
    pub fn shading_normal(&self, dir: DVec3, n: DVec3) -> (DVec3, Option<f64>) {
        match self.relief {
            Some(r) => {
                let horizon = self.shadows == SelfShadowing::HorizonMap;
                let (n_body, h) = r.normal_and_horizon(self.csf.body_from_csf * dir, horizon);
                (self.csf_from_body * n_body, h)
            }
            None => (n, None),
        }
    }

    /// Hides what the relief hides at the surface point `p` over CSF unit direction `dir`:
    /// `g.mu0` (the Sun) and `g.mu` (the camera) become 0 where the terrain blocks them
    /// (ray marching), or where they rise less than the horizon map's horizon
    /// (`horizon_sin` from [`View::shading_normal`]). Nothing without self-shadowing.
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
    /// round shape is asked directly, another one in the body frame.
    #[inline(always)]
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        if self.shape.is_round() {
            return self.shape.surface(dir);
        }
        let (p, n) = self.shape.surface(self.csf.body_from_csf * dir);
        (self.csf_from_body * p, self.csf_from_body * n)
    }

    /// The surface area per unit solid angle at the point `p` with normal `n` over the unit
    /// direction `dir`, relative to the bounding sphere's `R^2`: `(|p|/R)^2 / (n . dir)`
    /// (1 on a sphere).
    #[inline(always)]
    pub fn area_factor(&self, dir: DVec3, p: DVec3, n: DVec3) -> f64 {
        if self.shape.is_round() {
            return 1.0;
        }
        let r = self.shape.bounding_radius_m();
        p.length_squared() / (r * r) / n.dot(dir)
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
