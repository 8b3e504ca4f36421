//! The frame pipeline: poses arrive from the connections through the [`Intake`], one
//! dedicated thread renders and presents them (never the async runtime), and every pose is
//! acknowledged: presented, dropped for a newer one (free-running), or refused with an error.
//!
//! Modes ([`Mode`]): free-running keeps only the newest pose waiting (the ones it replaces
//! are acked as dropped and counted); lockstep renders every pose in order (a bounded queue;
//! beyond it the pose is refused as busy). With `hold`, a frame is rendered into the hold
//! buffer and acked as held, and the next trigger presents it (a second ack).

use super::protocol::{AckFidelity, AckMsg, AckStatus, ErrorCode, Message, ProtocolError};
use super::{Outbound, Shared};
use crate::display::Presenter;
use crate::display::window::{self, DisplayEvent, DisplaySender, Monitor, Presented};
use crate::pipeline::{FrameMaker, MadeFrame, PipelineError};
use crate::render::RenderError;
use crate::scene::Pose;
use crate::stimulator::calibration::Curve;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::mpsc as std_mpsc;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// The lockstep queue's length; poses beyond it are refused (`busy`).
pub const LOCKSTEP_QUEUE: usize = 64;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Latest pose wins; stale poses are dropped and counted.
    #[default]
    Free,
    /// Every pose is rendered in order and acked once presented.
    Lockstep,
}

/// One pose on its way.
pub struct Job {
    pub pose: Pose,
    pub exposure_s: Option<f64>,
    /// Where the scene's further bodies are from this frame on (first body's frame: centre
    /// [m], rotation from each one's frame), when the pose moves them.
    pub bodies: Option<Vec<(glam::DVec3, glam::DQuat)>>,
    pub received: Instant,
    /// Where the ack goes: the connection's outbound queue.
    pub reply: Outbound,
    /// For the compatible endpoints: the frame's products once presented (or why not). A
    /// pose dropped before rendering drops the sender.
    pub products: Option<std_mpsc::SyncSender<Result<Products, String>>>,
}

/// What a presented frame hands back to a compatible endpoint.
pub struct Products {
    pub frame_id: u64,
    /// `(P/L)` per camera pixel [sr m^2].
    pub pl: Vec<f64>,
}

/// What the frame thread is told besides poses.
pub enum Control {
    /// Replay another calibration curve; the answer says whether it was taken.
    Replay(Arc<Curve>, std_mpsc::Sender<Result<(), String>>),
    Settings(crate::render::Settings),
    /// Switch to another scene (same screen), from the next pose on.
    Scene(Box<FrameMaker>),
    /// Present the held frame; errors go to `reply`.
    Trigger(Outbound),
}

#[derive(Default)]
struct State {
    poses: VecDeque<Job>,
    controls: VecDeque<Control>,
    stop: bool,
}

/// The hand-over between the connections and the frame thread.
#[derive(Default)]
pub struct Intake {
    state: Mutex<State>,
    wake: Condvar,
}

impl Intake {
    /// Queues a pose. In free-running mode the poses still waiting are replaced (returned,
    /// to be acked as dropped); in lockstep a full queue refuses the pose.
    pub fn push(&self, job: Job, mode: Mode) -> Result<Vec<Job>, ProtocolError> {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if s.stop {
            let frame_id = job.pose.frame_id;
            return Err(ProtocolError {
                code: ErrorCode::ShuttingDown,
                message: "the daemon is shutting down".into(),
                frame_id: Some(frame_id),
            });
        }
        let dropped = match mode {
            Mode::Free => s.poses.drain(..).collect(),
            Mode::Lockstep if s.poses.len() >= LOCKSTEP_QUEUE => {
                let frame_id = job.pose.frame_id;
                return Err(ProtocolError {
                    code: ErrorCode::Busy,
                    message: format!("{LOCKSTEP_QUEUE} poses already wait: wait for their acks"),
                    frame_id: Some(frame_id),
                });
            }
            Mode::Lockstep => Vec::new(),
        };
        s.poses.push_back(job);
        self.wake.notify_one();
        Ok(dropped)
    }

    pub fn control(&self, c: Control) {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        s.controls.push_back(c);
        self.wake.notify_one();
    }

    /// Stops the frame thread after the frame in flight; returns the poses still waiting.
    pub fn stop(&self) -> Vec<Job> {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        s.stop = true;
        self.wake.notify_all();
        s.poses.drain(..).collect()
    }

    fn next(&self) -> Option<Result<Job, Control>> {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(c) = s.controls.pop_front() {
                return Some(Err(c));
            }
            if s.stop {
                return None;
            }
            if let Some(j) = s.poses.pop_front() {
                return Some(Ok(j));
            }
            s = self.wake.wait(s).unwrap_or_else(|e| e.into_inner());
        }
    }
}

/// Where frames go.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PresenterChoice {
    /// A fullscreen window when a display exists, off-screen otherwise.
    Auto,
    /// Off-screen on the GPU (or Mesa's software adapter), read back.
    Offscreen,
    /// The fullscreen window on this monitor (plus the preview when asked).
    Window { monitor: Monitor, preview: bool },
    /// Off-screen on the CPU reference (no wgpu adapter needed).
    Cpu,
}

/// Where the frame thread puts frames.
pub enum Present {
    Gpu(Box<Presenter>),
    Cpu,
    Window {
        tx: DisplaySender,
        presented: std_mpsc::Receiver<Result<Presented, String>>,
    },
}

/// A frame rendered into the hold buffer.
struct Held {
    job: Job,
    made: MadeFrame,
    render_start: Instant,
    render_end: Instant,
}

/// The frame thread's state.
pub struct FrameThread {
    maker: FrameMaker,
    present: Present,
    shared: Arc<Shared>,
    held: Option<Held>,
}

/// Opens the presenter chosen, falling back with a warning to off-screen and then to the CPU;
/// returns it and its description in words.
pub fn open_presenter(maker: &FrameMaker, choice: &PresenterChoice) -> (Present, String) {
    let st = maker
        .stimulator()
        .expect("the daemon's scene has a [stimulator]");
    let config = st.config();
    let want_window = match choice {
        PresenterChoice::Auto => window::display_available().then_some((Monitor::Index(0), false)),
        PresenterChoice::Window { monitor, preview } => Some((monitor.clone(), *preview)),
        _ => None,
    };
    if let Some((monitor, preview)) = want_window {
        match spawn_display(config, st.drive(), monitor.clone(), preview) {
            Ok((tx, presented)) => {
                return (
                    Present::Window { tx, presented },
                    format!("fullscreen window on monitor {monitor}"),
                );
            }
            Err(e) => tracing::warn!("no window ({e}); presenting off-screen"),
        }
    }
    if *choice != PresenterChoice::Cpu {
        match Presenter::new_headless(config.screen_bits)
            .and_then(|mut p| p.set_drive(&st.drive()).map(|()| p))
        {
            Ok(p) => {
                let words = format!("off-screen on {}", p.adapter());
                return (Present::Gpu(Box::new(p)), words);
            }
            Err(e) => tracing::warn!("no GPU presenter ({e}); presenting on the CPU"),
        }
    }
    (Present::Cpu, "off-screen on the CPU reference".into())
}

impl FrameThread {
    pub fn new(maker: FrameMaker, present: Present, shared: Arc<Shared>) -> FrameThread {
        FrameThread {
            maker,
            present,
            shared,
            held: None,
        }
    }

    /// Runs until the intake stops.
    pub fn run(mut self) {
        let intake = self.shared.intake.clone();
        while let Some(next) = intake.next() {
            match next {
                Ok(job) => self.frame(job),
                Err(Control::Replay(curve, answer)) => {
                    let _ = answer.send(self.replay(curve));
                }
                Err(Control::Settings(s)) => self.maker.set_settings(s),
                Err(Control::Scene(maker)) => self.switch_scene(*maker),
                Err(Control::Trigger(reply)) => self.trigger(reply),
            }
        }
        if let Some(h) = self.held.take() {
            tracing::info!(
                frame_id = h.job.pose.frame_id,
                "held frame dropped at shutdown"
            );
        }
        if let Present::Window { tx, .. } = &self.present {
            let _ = tx.send(DisplayEvent::Quit);
        }
    }

    /// The new scene's pipeline and its curve; a held frame of the old scene is dropped.
    fn switch_scene(&mut self, maker: FrameMaker) {
        let curve = maker
            .stimulator()
            .expect("checked by Shared::apply")
            .curve()
            .clone();
        self.maker = maker;
        if let Some(h) = self.held.take() {
            self.drop_held(h);
        }
        if let Err(e) = self.replay(curve) {
            tracing::error!("the new scene's calibration could not be uploaded: {e}");
        }
        tracing::info!(scene = %self.shared.scene().label, "scene switched");
    }

    /// A held frame that will never be presented: counted and acked as dropped.
    fn drop_held(&self, h: Held) {
        self.shared.stats.poses_dropped.inc();
        let ack = self.ack(&h, AckStatus::Dropped, None);
        h.job.reply.send(Message::Ack(ack));
    }

    /// Replays `curve` in the stimulator and the presenter (the stimulator's inverse is the
    /// one uploaded); if the presenter refuses it, the stimulator goes back to its old curve.
    fn replay(&mut self, curve: Arc<Curve>) -> Result<(), String> {
        let (id, sha) = (curve.id.clone(), curve.sha256.clone());
        let old = self
            .maker
            .replay(curve)
            .expect("the daemon has a stimulator")
            .map_err(|e| e.to_string())?;
        let drive = self.maker.stimulator().expect("has one").drive();
        let uploaded = match &mut self.present {
            Present::Gpu(p) => p.set_drive(&drive).map_err(|e| e.to_string()),
            Present::Window { tx, .. } => tx
                .send(DisplayEvent::Curve(Box::new(drive)))
                .map_err(|e| e.to_string()),
            Present::Cpu => Ok(()),
        };
        if let Err(e) = uploaded {
            // The old curve was in use a moment ago: taking it back cannot fail.
            let _ = self.maker.replay(old);
            return Err(e);
        }
        *self
            .shared
            .calibration
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = (id, sha);
        Ok(())
    }

    fn frame(&mut self, job: Job) {
        // Watchers wait while this frame is in flight (until its ack, or its error).
        let gate = self.shared.views.gate.clone();
        let _in_flight = gate.enter();
        let render_start = Instant::now();
        let placed = match &job.bodies {
            Some(b) => self.maker.place_bodies(b),
            None => Ok(()),
        };
        let made = match placed.and_then(|()| self.maker.render(&job.pose)) {
            Ok(m) => m,
            Err(e) => {
                self.shared.stats.render_failures.inc();
                let code = match &e {
                    PipelineError::Render(RenderError::CameraInsideBody { .. }) => {
                        ErrorCode::CameraInsideBody
                    }
                    PipelineError::Render(RenderError::BadPose { .. }) => ErrorCode::BadValue,
                    _ => ErrorCode::Render,
                };
                if let Some(p) = &job.products {
                    let _ = p.try_send(Err(e.to_string()));
                }
                job.reply.send(Message::from(ProtocolError {
                    code,
                    message: e.to_string(),
                    frame_id: Some(job.pose.frame_id),
                }));
                return;
            }
        };
        let render_end = Instant::now();
        *self
            .shared
            .last_frame
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = Some(super::FrameReport {
            frame_id: made.frame_id,
            stage_ms: made.timings_ms,
            render_steps_ms: made.stats.timings_ms,
            phase_deg: made.stats.phase_deg,
            covered_px: made.stats.covered_px,
            clips: made
                .stimulator
                .as_ref()
                .map(|s| s.clips)
                .unwrap_or_default(),
            plan: made.plan.clone(),
        });
        if self.shared.runtime().hold {
            let held = Held {
                job,
                made,
                render_start,
                render_end,
            };
            let ack = self.ack(&held, AckStatus::Held, None);
            held.job.reply.send(Message::Ack(ack));
            if let Some(old) = self.held.replace(held) {
                self.drop_held(old);
            }
            return;
        }
        self.present_and_ack(Held {
            job,
            made,
            render_start,
            render_end,
        });
    }

    fn trigger(&mut self, reply: Outbound) {
        match self.held.take() {
            Some(h) => self.present_and_ack(h),
            None => reply.send(Message::from(ProtocolError::new(
                ErrorCode::BadConfig,
                "trigger with an empty hold buffer (set hold and send a pose first)",
            ))),
        }
    }

    fn present_and_ack(&mut self, mut h: Held) {
        let frame_id = h.job.pose.frame_id;
        if let Err(e) = self.present(&mut h.made) {
            self.shared.stats.render_failures.inc();
            if let Some(p) = &h.job.products {
                let _ = p.try_send(Err(format!("presenting: {e}")));
            }
            h.job.reply.send(Message::from(ProtocolError {
                code: ErrorCode::Render,
                message: format!("presenting: {e}"),
                frame_id: Some(frame_id),
            }));
            return;
        }
        let presented = Instant::now();
        let ack = self.ack(&h, AckStatus::Presented, Some(presented));
        // Counted and published before the ack leaves, so that whoever holds the ack sees the
        // frame in /status and /frame/latest.png.
        self.shared.stats.record_frame(
            (presented - h.job.received).as_secs_f64() * 1e3,
            (h.render_end - h.render_start).as_secs_f64() * 1e3,
        );
        let config = self.maker.stimulator().expect("has one").config();
        let latest = Arc::new(super::ScreenImage {
            seq: self.shared.stats.frames_presented.get(),
            frame_id,
            exposure_s: h.job.exposure_s,
            screen_px: config.screen_px,
            dn: h.made.stimulator.take().expect("has one").screen_dn,
        });
        *self.shared.latest.lock().unwrap_or_else(|e| e.into_inner()) = Some(latest.clone());
        h.job.reply.send(Message::Ack(ack));
        self.publish_camera(&latest);
        if let Some(p) = h.job.products.take() {
            let _ = p.try_send(Ok(Products {
                frame_id,
                pl: std::mem::take(&mut h.made.pl),
            }));
        }
    }

    /// Puts the frame on the screen; afterwards `made`'s screen codes are filled.
    fn present(&mut self, made: &mut MadeFrame) -> Result<(), String> {
        let st = self.maker.stimulator().expect("has a stimulator");
        let region = st.resampler().region_px();
        match &mut self.present {
            Present::Gpu(p) => {
                let f = made.stimulator.as_mut().expect("has a stimulator");
                let mut dn = std::mem::take(&mut f.screen_dn);
                p.draw_offscreen(st.config(), region, &f.region_feff_w_m2, &mut dn)
                    .map_err(|e| e.to_string())?;
                f.screen_dn = dn;
            }
            Present::Cpu => self.maker.invert_on_cpu(made),
            Present::Window { tx, presented } => {
                // The region's F_eff goes to the display thread and comes back for the CPU
                // inversion below (the display drops its reference once uploaded).
                let f = made.stimulator.as_mut().expect("has a stimulator");
                let feff = Arc::new(std::mem::take(&mut f.region_feff_w_m2));
                let sent = tx.send(DisplayEvent::Frame {
                    frame_id: made.frame_id,
                    region_px: region,
                    region_feff_w_m2: feff.clone(),
                });
                let back = |f: &mut crate::stimulator::StimulatorFrame| {
                    f.region_feff_w_m2 = Arc::try_unwrap(feff).unwrap_or_else(|a| (*a).clone());
                };
                if let Err(e) = sent {
                    back(f);
                    return Err(e.to_string());
                }
                let deadline = Instant::now() + Duration::from_secs(2);
                let shown = loop {
                    let left = deadline.saturating_duration_since(Instant::now());
                    match presented.recv_timeout(left) {
                        Ok(Ok(p))
                            if p.frame_id == made.frame_id
                                && p.window == window::Role::Fullscreen =>
                        {
                            break Ok(());
                        }
                        Ok(Ok(_)) => continue,
                        Ok(Err(e)) => break Err(format!("the display stopped: {e}")),
                        Err(_) => break Err("the window did not present within 2 s".into()),
                    }
                };
                back(f);
                shown?;
                // The screen's codes for the latest-frame image and the simulated camera.
                self.maker.invert_on_cpu(made);
            }
        }
        Ok(())
    }

    fn ack(&self, h: &Held, status: AckStatus, presented: Option<Instant>) -> AckMsg {
        let ns = |t: Instant| self.shared.ns(t);
        // The clip counts and the curve of the frame itself (a held frame may predate a replay).
        let (clips, calibration_id) = h
            .made
            .stimulator
            .as_ref()
            .map(|s| (s.clips, s.calibration_id.clone()))
            .unwrap_or_default();
        AckMsg {
            frame_id: h.job.pose.frame_id,
            status,
            received_ns: ns(h.job.received),
            render_start_ns: ns(h.render_start),
            render_end_ns: ns(h.render_end),
            presented_ns: presented.map_or(0, ns),
            render_ms: (h.render_end - h.render_start).as_secs_f64() * 1e3,
            clipped_black: clips.black,
            clipped_below_dark: clips.below_dark,
            clipped_above_max: clips.above_max,
            calibration_id,
            fidelity: h.made.plan.as_ref().map(AckFidelity::of),
            recording_failed: self
                .shared
                .recorder
                .as_ref()
                .map(|r| r.health().failed)
                .filter(|&n| n > 0),
        }
    }

    /// The simulated camera's image of the frame, to every subscriber (after the ack, so
    /// that it never delays one).
    fn publish_camera(&self, latest: &super::ScreenImage) {
        let subscribers = self.shared.subscribers();
        if subscribers.is_empty() {
            return;
        }
        let Some(camera) = self.maker.camera() else {
            return;
        };
        match camera.capture_exposed(&latest.dn, latest.frame_id, latest.exposure_s) {
            Ok(c) => {
                // The camera views of HTTP reuse this capture.
                self.shared
                    .views
                    .offer_camera(latest.seq, Arc::new(c.dn.clone()));
                let [w, h] = camera.camera_px();
                let msg = Message::CameraFrame {
                    frame_id: latest.frame_id,
                    width: w as u32,
                    height: h as u32,
                    bit_depth: camera.detector().saved_bits as u8,
                    dn: c.dn,
                };
                for s in subscribers {
                    s.send(msg.clone());
                }
            }
            Err(e) => tracing::warn!("simulated camera: {e}"),
        }
    }
}

/// Starts the display thread (winit event loop) and waits until its windows exist.
fn spawn_display(
    config: &crate::stimulator::StimulatorConfig,
    drive: crate::stimulator::Drive,
    monitor: Monitor,
    preview: bool,
) -> Result<(DisplaySender, std_mpsc::Receiver<Result<Presented, String>>), String> {
    let (ready_tx, ready_rx) = std_mpsc::channel();
    let (presented_tx, presented_rx) = std_mpsc::channel();
    let config = config.clone();
    std::thread::Builder::new()
        .name("optistim-display".into())
        .spawn(move || {
            let errors = presented_tx.clone();
            let ready = ready_tx.clone();
            let result = window::run(
                &config,
                &drive,
                window::WindowOptions {
                    fullscreen: Some(monitor),
                    preview,
                    until: None,
                },
                move |tx| {
                    let _ = ready.send(Ok(tx));
                },
                move |p| {
                    let _ = presented_tx.send(Ok(p));
                },
            );
            let reason = match result {
                Ok(()) => "the windows were closed".to_string(),
                Err(e) => e.to_string(),
            };
            let _ = ready_tx.send(Err(reason.clone()));
            let _ = errors.send(Err(reason));
        })
        .map_err(|e| e.to_string())?;
    let tx = ready_rx
        .recv_timeout(Duration::from_secs(20))
        .map_err(|_| "the display did not start within 20 s".to_string())??;
    // The event loop exists; a window that cannot open reports here at once.
    match presented_rx.recv_timeout(Duration::from_millis(500)) {
        Err(_) | Ok(Ok(_)) => Ok((tx, presented_rx)),
        Ok(Err(e)) => Err(e),
    }
}
