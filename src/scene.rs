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
    pub body: Body,
    pub camera: Camera,
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
