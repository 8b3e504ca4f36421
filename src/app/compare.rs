//! `optistim compare SCENE.toml PHOTO.png [--out DIR]`: renders the scene as its camera saves
//! it (DN at `saved_bit_depth`) and compares it with a real photograph through
//! [`crate::compare`]: NCC alignment, foreground, SSIM luminance / contrast / structure, and
//! the ratio of total DN real / rendered. With `--out`, writes `rendered.png` (aligned) and
//! `alignment.png` (red: real above the threshold, blue: rendered light, magenta: both).

use super::AppError;
use crate::compare::{Comparison, Gray, compare};
use crate::config::Config;
use crate::render::Renderer;
use serde::Serialize;
use std::path::Path;

#[derive(Debug, Serialize)]
pub struct CompareReport {
    pub scene: String,
    pub photo: String,
    pub photo_sha256: String,
    /// SSIM's `L` [DN]: the saved depth's full scale.
    pub full_scale_dn: f64,
    pub comparison: Comparison,
    /// The ADC gain [DN/e-, at `bit_depth`] at which the rendering's total DN would equal the
    /// photo's: the configured gain times `total_dn_ratio`, for a camera model without offset
    /// (`None` with one). A diagnostic of the camera model's absolute scale, never fed back;
    /// saturated photo pixels make it a lower bound.
    pub implied_adc_gain_dn_per_e: Option<f64>,
    pub render_ms: f64,
}

pub fn run(
    config: &Config,
    scene_name: &str,
    photo: &Path,
    max_shift_px: i64,
    out: Option<&Path>,
) -> Result<CompareReport, AppError> {
    let bytes = std::fs::read(photo).map_err(|source| crate::io::IoError::File {
        path: photo.display().to_string(),
        source,
    })?;
    let (pw, ph, real_dn) = crate::io::decode_png_gray(photo, &bytes)?;
    let t0 = std::time::Instant::now();
    let mut renderer = Renderer::new(config.settings.threads)?;
    let frame = renderer.render(&config.scene, &config.pose, &config.settings)?;
    let det = &config.scene.camera.detector;
    let size = (frame.width, frame.height);
    let (_, dn) = config
        .scene
        .record(|b| frame.band(b), size, config.pose.frame_id);
    let render_ms = t0.elapsed().as_secs_f64() * 1e3;

    let to_f64 = |v: &[u16]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
    let real = Gray::new(pw, ph, to_f64(&real_dn));
    let rendered = Gray::new(frame.width, frame.height, to_f64(&dn));
    let full_scale_dn = det.max_dn();
    let comparison = compare(&real, &rendered, full_scale_dn, max_shift_px)
        .map_err(|e| AppError::Compare(format!("{}: {e}", photo.display())))?;

    if let Some(out) = out {
        std::fs::create_dir_all(out).map_err(|source| AppError::OutDir {
            path: out.display().to_string(),
            source,
        })?;
        let [dx, dy] = comparison.shift_px;
        let aligned = rendered.shifted(dx, dy);
        let dn: Vec<u16> = aligned.dn.iter().map(|&v| v as u16).collect();
        crate::io::write_png_gray(&out.join("rendered.png"), pw, ph, &dn, det.saved_bits)?;
        let rgb: Vec<u8> = real
            .dn
            .iter()
            .zip(&aligned.dn)
            .flat_map(|(&a, &r)| {
                let red = if a > comparison.threshold_dn { 255 } else { 0 };
                let blue = if r > 0.0 { 255 } else { 0 };
                [red, 0, blue]
            })
            .collect();
        crate::io::write_png_rgb(&out.join("alignment.png"), pw, ph, &rgb)?;
    }
    Ok(CompareReport {
        scene: scene_name.to_string(),
        photo: photo.display().to_string(),
        photo_sha256: crate::io::sha256_hex(&bytes),
        full_scale_dn,
        implied_adc_gain_dn_per_e: (det.offset_dn == 0.0)
            .then_some(det.adc_gain_dn_per_e * comparison.total_dn_ratio),
        comparison,
        render_ms,
    })
}
