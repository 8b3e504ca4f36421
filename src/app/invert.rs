//! `optistim invert SCENE=IMAGE ...`: the Hapke parameters of a body from images of it
//! ([`crate::inversion`]), each image a PNG of saved DN (as `optistim render` writes
//! `image.png`) with the scene file that gives its body, camera, detector and pose.

use super::AppError;
use crate::config::Config;
use crate::inversion::{Image, Inversion, invert};
use std::path::PathBuf;

/// Fits the parameters to the `(scene, image)` pairs from `start` (`w, b, c, B0, h, theta`).
pub fn run(
    pairs: &[(Config, PathBuf)],
    start: [f64; 6],
    samples: u32,
) -> Result<Inversion, AppError> {
    let mut dns = Vec::with_capacity(pairs.len());
    for (cfg, path) in pairs {
        let bytes = std::fs::read(path).map_err(|source| crate::io::IoError::File {
            path: path.display().to_string(),
            source,
        })?;
        let (w, h, dn) = crate::io::decode_png_gray(path, &bytes)?;
        let intr = &cfg.scene.camera.intrinsics;
        if (w, h) != (intr.width_px as usize, intr.height_px as usize) {
            return Err(AppError::Invert(format!(
                "{}: {w} x {h} pixels, the scene's camera has {} x {}",
                path.display(),
                intr.width_px,
                intr.height_px
            )));
        }
        dns.push(dn);
    }
    let images: Vec<Image> = pairs
        .iter()
        .zip(&dns)
        .map(|((cfg, _), dn)| Image {
            scene: &cfg.scene,
            pose: cfg.pose,
            dn,
        })
        .collect();
    invert(&images, start, samples).map_err(|e| AppError::Invert(e.to_string()))
}
