//! `optistim show SCENE`: renders the scene's pose once, runs it through the stimulator chain
//! and shows it on the stimulator's monitor (borderless fullscreen, 1:1 pixels, vsync) and/or
//! in the operator's preview window until the windows close or `--seconds` pass. One JSON line
//! per presented frame goes to `report`.

use super::AppError;
use crate::config::Config;
use crate::display::window::{self, DisplayEvent, Monitor, Presented, WindowOptions};
use crate::pipeline::FrameMaker;
use std::sync::Arc;
use std::time::{Duration, Instant};

pub struct ShowOptions {
    /// The stimulator's monitor; `None` with `preview`: the preview only.
    pub monitor: Option<Monitor>,
    pub preview: bool,
    pub seconds: Option<f64>,
}

pub fn run(
    config: &Config,
    scene_name: &str,
    options: ShowOptions,
    report: impl FnMut(Presented),
) -> Result<(), AppError> {
    let st = config
        .stimulator
        .as_ref()
        .ok_or_else(|| AppError::NoStimulator(scene_name.to_string()))?;
    let mut maker = FrameMaker::new(config)?;
    let made = maker.render(&config.pose)?;
    let stimulator = maker
        .stimulator()
        .expect("the scene has a [stimulator] section");
    let frame = made.stimulator.expect("made with a stimulator");
    let region_px = stimulator.resampler().region_px();
    let fullscreen = match (options.monitor, options.preview) {
        (None, false) => Some(Monitor::Index(0)),
        (m, _) => m,
    };
    let event = DisplayEvent::Frame {
        frame_id: made.frame_id,
        region_px,
        region_feff_w_m2: Arc::new(frame.region_feff_w_m2),
    };
    let mut sent = Ok(());
    window::run(
        st,
        &stimulator.drive(),
        WindowOptions {
            fullscreen,
            preview: options.preview,
            until: options
                .seconds
                .map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0))),
        },
        |tx| sent = tx.send(event),
        report,
    )?;
    Ok(sent?)
}
