//! The validated world a frame is rendered from: the Sun, the body, the camera; and the pose
//! that changes every frame. Built by [`crate::config`], consumed by [`crate::render`] and
//! [`crate::detector`].

use crate::body::Body;
use crate::camera::Intrinsics;
use crate::detector::Detector;
use crate::radiometry::SunSpectrum;
use glam::{DQuat, DVec3};

/// The camera: geometry and detector.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    pub detector: Detector,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub sun: SunSpectrum,
    /// The body the pose is written in (its frame B is the scene's frame).
    pub body: Body,
    /// Further bodies (`[[body]]` after the first), placed in B: a moon beside its planet,
    /// a binary's secondary. Rendered by the ray caster, with mutual occlusion and shadows.
    pub others: Vec<Placed>,
    pub camera: Camera,
}

impl Scene {
    /// Whether the ray caster renders this scene ([`crate::raycast::sampled`]): a mesh body,
    /// or several bodies; else the quadrangle pipeline.
    pub fn is_ray_cast(&self) -> bool {
        !self.others.is_empty() || matches!(self.body.shape, crate::body::Shape::Mesh(_))
    }

    /// The signal factor of Eq. 45 of every band of the camera for light reflected by the
    /// body (its spectral shape inside each band's integral) [e- s^-1 per sr m^2 of (P/L)].
    pub fn band_factors(&self) -> Vec<f64> {
        let spectrum = self.body.spectrum.as_ref();
        self.camera.detector.band_factors(&self.sun, spectrum)
    }

    /// A rendered frame through the camera ([`crate::detector::Detector::image`]): band
    /// `b` sees the `(P/L)` image `pl(b)` of `size` (the frame's, or its own under a
    /// distortion of its own: `render::Frame::band`). Returns every band's signal [e-/s] and
    /// the DN the camera hands out.
    pub fn record<'a>(
        &self,
        pl: impl Fn(usize) -> &'a [f64] + Sync,
        size: (usize, usize),
        frame_id: u64,
    ) -> (Vec<f64>, Vec<u16>) {
        let factors = self.band_factors();
        self.camera.detector.image(pl, size, &factors, frame_id)
    }

    /// The DN alone of [`Scene::record`], bit for bit the same
    /// ([`crate::detector::Detector::dn_into`]: no signal planes but those a PSF blurs).
    pub fn record_dn<'a>(
        &self,
        pl: impl Fn(usize) -> &'a [f64] + Sync,
        size: (usize, usize),
        frame_id: u64,
    ) -> Vec<u16> {
        let factors = self.band_factors();
        let mut dn = Vec::new();
        self.camera
            .detector
            .dn_into(pl, size, &factors, frame_id, &mut dn);
        dn
    }

    /// The first band's factor ([`Scene::band_factors`]): a monochrome camera's.
    pub fn signal_factor(&self) -> f64 {
        let b = self.camera.detector.band();
        let spectrum = self.body.spectrum.as_ref();
        self.sun
            .reflected_signal_integral(&b.qe, &b.transmittance, spectrum)
    }

    /// W per sr m^2 of (P/L) over `band_m` (the whole spectrum when `None`): the Sun's
    /// radiance after reflection by the body (Eq. 9).
    pub fn radiance_w(&self, band_m: Option<(f64, f64)>) -> f64 {
        self.sun
            .reflected_radiance_integral(band_m, self.body.spectrum.as_ref())
    }
}

/// A body placed in the first body's frame B.
#[derive(Clone, Debug, PartialEq)]
pub struct Placed {
    pub body: Body,
    /// Its centre in B [m].
    pub position_m: DVec3,
    /// Rotation taking its own frame's vectors into B.
    pub b_from_body: DQuat,
}

/// The first pair `(i, j)`, `i < j`, of bodies whose bounding spheres meet, the bodies given as
/// `(centre [m], bounding radius [m])` in B, the first body first: the smallest `j` that
/// meets any body before it. Bodies may not overlap (`[[body]]`, the pose's `bodies`).
pub fn overlapping(spheres: &[(DVec3, f64)]) -> Option<(usize, usize)> {
    (1..spheres.len()).find_map(|j| {
        (0..j)
            .find(|&i| (spheres[i].0 - spheres[j].0).length() <= spheres[i].1 + spheres[j].1)
            .map(|i| (i, j))
    })
}

impl Placed {
    /// A point [m] of B in the body's own frame.
    #[inline]
    pub fn to_body(&self, p_b: DVec3) -> DVec3 {
        self.b_from_body.inverse() * (p_b - self.position_m)
    }

    /// Whether a point of B lies inside the body.
    pub fn contains(&self, p_b: DVec3) -> bool {
        self.body.shape.contains(self.to_body(p_b))
    }
}

/// Everything that changes from frame to frame, in the body-fixed frame B.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Frame counter: seeds the temporal noises of this frame.
    pub frame_id: u64,
    /// Camera position relative to the body centre [m].
    pub camera_position_m: DVec3,
    /// Rotation taking camera-frame vectors into the body frame.
    pub body_from_camera: DQuat,
    /// Sun position relative to the body centre [m].
    pub sun_position_m: DVec3,
}
