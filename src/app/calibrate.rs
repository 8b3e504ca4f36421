//! `optistim calibrate SCENE.toml --out CURVE.csv`: measures the screen's calibration curve on
//! the bench of the scene's `[stimulator]` section (today the simulated camera, whose screen
//! responds as `true_response`), writes it in the format of `calibration/README.md` and
//! reports the points and the half-way residuals.

use super::AppError;
use crate::config::Config;
use crate::stimulator::calibrate::{CalibrationRun, Provenance, SimulatedBench, calibrate};
use crate::stimulator::camera::SimulatedCamera;
use std::path::Path;

/// Runs the ramp and writes the curve to `out`.
pub fn run(
    config: &Config,
    scene_name: &str,
    steps: usize,
    out: &Path,
) -> Result<CalibrationRun, AppError> {
    let st = config
        .stimulator
        .as_ref()
        .ok_or_else(|| AppError::NoStimulator(scene_name.to_string()))?;
    let cam = &config.scene.camera;
    let camera = SimulatedCamera::from_config(st, &cam.intrinsics, &cam.detector)?;
    let mut bench = SimulatedBench::new(camera, st.screen_px);
    let run = calibrate(
        &mut bench,
        st.levels(),
        steps,
        st.interp,
        Provenance {
            date: &today(),
            facility: "optistim simulated bench (simulated camera; not a measurement)",
        },
    )?;
    std::fs::write(out, &run.csv).map_err(|source| AppError::OutDir {
        path: out.display().to_string(),
        source,
    })?;
    Ok(run)
}

/// Today's UTC date, `YYYY-MM-DD` (days-from-civil inverted, H. Hinnant's algorithm).
fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}
