//! One pose's way to the screen, off the async runtime: render -> detector signal (one plane
//! per band) -> the stimulator chain (F_eff, screen region, clip counts; DN on the CPU or the
//! GPU; a colour camera on a colour screen), and the simulated camera that images the screen.
//! [`FrameMaker`] holds the per-scene state (renderer pool and buffers, the stimulator with its
//! current curve, the simulated camera) and reports every stage's time with every frame.

use crate::config::Config;
use crate::fidelity::budget::{Plan, Planner};
use crate::render::{FrameStats, RenderError, Renderer};
use crate::scene::Pose;
use crate::stimulator::calibration::Curve;
use crate::stimulator::camera::SimulatedCamera;
use crate::stimulator::{Stimulator, StimulatorError, StimulatorFrame};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error(transparent)]
    Stimulator(#[from] StimulatorError),
}

/// Time per stage of one frame [ms].
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct FrameTimings {
    pub render: f64,
    pub signal: f64,
    pub stimulator: f64,
}

/// One pose, made.
pub struct MadeFrame {
    pub frame_id: u64,
    /// `(P/L)` per camera pixel [sr m^2], as rendered.
    pub pl: Vec<f64>,
    /// The flight camera's signal [e-/s] (camera pixels, row-major; one plane per band).
    pub signal_e_per_s: Vec<f64>,
    pub stats: FrameStats,
    /// With a `[stimulator]` section: F_eff, the screen region, the clip counts, and (once
    /// inverted) the screen's DN.
    pub stimulator: Option<StimulatorFrame>,
    pub timings_ms: FrameTimings,
    /// With `fidelity = "budget"`: the settings the planner chose and the error it predicts.
    pub plan: Option<Plan>,
}

/// Per-scene state of the frame pipeline.
pub struct FrameMaker {
    config: Config,
    renderer: Renderer,
    stimulator: Option<Stimulator>,
    camera: Option<Arc<SimulatedCamera>>,
    planner: Option<Planner>,
}

impl FrameMaker {
    /// Loads the calibration and the simulated camera's true response of `config`'s
    /// `[stimulator]` section, when it has one.
    pub fn new(config: &Config) -> Result<FrameMaker, PipelineError> {
        let (stimulator, camera) = match &config.stimulator {
            Some(st) => {
                let intr = &config.scene.camera.intrinsics;
                let det = &config.scene.camera.detector;
                (
                    Some(Stimulator::new(st, intr, det)?),
                    Some(Arc::new(SimulatedCamera::from_config(st, intr, det)?)),
                )
            }
            None => (None, None),
        };
        Ok(FrameMaker {
            planner: config.planner(),
            renderer: Renderer::new(config.settings.threads)?,
            config: config.clone(),
            stimulator,
            camera,
        })
    }

    pub fn stimulator(&self) -> Option<&Stimulator> {
        self.stimulator.as_ref()
    }

    /// Replays another calibration curve from the next frame on; returns the old one (`None`
    /// without a stimulator; an error, the old curve kept, when the stimulator refuses it).
    pub fn replay(&mut self, curve: Arc<Curve>) -> Option<Result<Arc<Curve>, StimulatorError>> {
        self.stimulator.as_mut().map(|s| s.replay(curve))
    }

    /// The simulated camera, shared (it images any screen of DN codes on any thread).
    pub fn camera(&self) -> Option<&Arc<SimulatedCamera>> {
        self.camera.as_ref()
    }

    /// Moves the scene's further bodies (`Scene::others`, in order) to `placements`: each
    /// centre [m] and rotation from its frame, in the first body's frame. They stay there
    /// until moved again. Refused (nothing moves) when the count differs from the scene's, or
    /// when a body's bounding sphere would meet another's or hold the Sun.
    pub fn place_bodies(
        &mut self,
        placements: &[(glam::DVec3, glam::DQuat)],
    ) -> Result<(), PipelineError> {
        let scene = &self.config.scene;
        let bad = |value: String| {
            Err(PipelineError::Render(RenderError::BadPose {
                field: "bodies",
                value,
            }))
        };
        if placements.len() != scene.others.len() {
            return bad(format!(
                "{} bodies for a scene with {} further bodies",
                placements.len(),
                scene.others.len()
            ));
        }
        let spheres: Vec<(glam::DVec3, f64)> =
            std::iter::once((glam::DVec3::ZERO, scene.body.shape.bounding_radius_m()))
                .chain(
                    placements
                        .iter()
                        .zip(&scene.others)
                        .map(|((p, _), o)| (*p, o.body.shape.bounding_radius_m())),
                )
                .collect();
        if let Some((i, j)) = crate::scene::overlapping(&spheres) {
            return bad(format!(
                "bodies {i} and {j} overlap (their bounding spheres meet)"
            ));
        }
        for (k, (_, q)) in placements.iter().enumerate() {
            if !q.is_finite() || (q.length() - 1.0).abs() > 1e-6 {
                return bad(format!(
                    "bodies[{k}] attitude {q:?} is not a unit quaternion"
                ));
            }
        }
        for (o, (p, q)) in self.config.scene.others.iter_mut().zip(placements) {
            o.position_m = *p;
            o.b_from_body = *q;
        }
        Ok(())
    }

    /// Renders `pose` and runs the stimulator chain up to the screen region's F_eff and the
    /// clip counts ([`Stimulator::prepare`]): the screen's codes come from the presenter
    /// ([`crate::display`]) or from [`FrameMaker::invert_on_cpu`].
    pub fn render(&mut self, pose: &Pose) -> Result<MadeFrame, PipelineError> {
        let mut t = FrameTimings::default();
        let t0 = Instant::now();
        let cfg = &self.config;
        let renderer = &mut self.renderer;
        let (plan, frame) = crate::fidelity::budget::render_as_planned(
            self.planner.as_ref(),
            &cfg.scene,
            pose,
            &cfg.settings,
            |s| renderer.render(&cfg.scene, pose, s),
        )?;
        t.render = ms(t0);
        let t0 = Instant::now();
        // Eq. 45 per band: one plane per band (each band's own image when its distortion
        // moved it).
        let mut signal = Vec::new();
        let factors = cfg.scene.band_factors();
        crate::detector::Detector::signal_into(|b| frame.band(b), &factors, &mut signal);
        t.signal = ms(t0);
        let t0 = Instant::now();
        let stimulator = match &self.stimulator {
            Some(s) => Some(s.prepare(&signal)?),
            None => None,
        };
        t.stimulator = ms(t0);
        Ok(MadeFrame {
            frame_id: pose.frame_id,
            signal_e_per_s: signal,
            pl: frame.pl,
            stats: frame.stats,
            stimulator,
            timings_ms: t,
            plan,
        })
    }

    /// Fills the frame's screen codes on the CPU (the reference the GPU pass matches).
    pub fn invert_on_cpu(&self, frame: &mut MadeFrame) {
        if let (Some(s), Some(f)) = (&self.stimulator, frame.stimulator.as_mut()) {
            s.invert(f);
        }
    }

    /// Replaces the render settings (accuracy and speed knobs) from the next frame on; with
    /// `fidelity = "budget"` they are the base the planner's choices override.
    pub fn set_settings(&mut self, settings: crate::render::Settings) {
        self.config.settings = settings;
        self.planner = self.config.planner();
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
