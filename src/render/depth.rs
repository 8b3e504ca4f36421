//! Range to the surface along each pixel's line of sight [m], NaN where the line of sight
//! misses the body: one ray per pixel centre, distortion inverted; a displacing DEM is
//! intersected by marching ([`Relief::intersect_displaced`]).

use crate::body::{Relief, Shape};
use crate::camera::Intrinsics;
use crate::scene::Pose;
use glam::DVec3;
use rayon::prelude::*;

/// The unit direction (body frame) of the line of sight through image point `(u, v)` [px],
/// distortion inverted.
#[inline]
pub fn line_of_sight(intrinsics: &Intrinsics, pose: &Pose, u: f64, v: f64) -> DVec3 {
    let (x, y) = intrinsics.unproject(u, v);
    (pose.body_from_camera * DVec3::new(x, y, 1.0)).normalize()
}

pub fn depth_map(
    intrinsics: &Intrinsics,
    shape: &Shape,
    relief: Option<&Relief>,
    pose: &Pose,
) -> Vec<f64> {
    let displaced = relief.filter(|r| r.displaces());
    let (w, h) = (intrinsics.width_px as usize, intrinsics.height_px as usize);
    let mut out = vec![f64::NAN; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        for (i, o) in row.iter_mut().enumerate() {
            let dir = line_of_sight(intrinsics, pose, i as f64 + 0.5, j as f64 + 0.5);
            let hit = match displaced {
                Some(r) => r.intersect_displaced(pose.camera_position_m, dir),
                None => shape.intersect(pose.camera_position_m, dir),
            };
            if let Some(t) = hit {
                *o = t;
            }
        }
    });
    out
}
