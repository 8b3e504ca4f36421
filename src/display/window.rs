//! Window targets: the stimulator's borderless fullscreen window on a chosen monitor (exact
//! 1:1 pixels, vsync) and the operator's preview window (the whole screen scaled to fit). One
//! winit event loop runs them on the thread that calls [`run`]; frames, curve changes and the
//! request to stop arrive from any thread through [`DisplaySender`].
//!
//! Surfaces are reconfigured when a window is resized (a window manager resizes a fullscreen
//! window after it is created) and when the surface is outdated or lost; the current frame is
//! then drawn again, so a window never stays black or stale.

use super::{Binding, DisplayError, PresentTimings, Presenter};
use crate::stimulator::Drive;
use crate::stimulator::StimulatorConfig;
use std::sync::Arc;
use std::time::Instant;
use winit::application::ApplicationHandler;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop, EventLoopProxy};
use winit::window::{Fullscreen, Window, WindowId};

/// The stimulator's monitor, by index in the system's list or by (part of) its name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Monitor {
    Index(usize),
    Name(String),
}

impl std::fmt::Display for Monitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Monitor::Index(i) => write!(f, "{i}"),
            Monitor::Name(n) => write!(f, "{n:?}"),
        }
    }
}

impl std::str::FromStr for Monitor {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Monitor, Self::Err> {
        Ok(match s.parse() {
            Ok(i) => Monitor::Index(i),
            Err(_) => Monitor::Name(s.to_string()),
        })
    }
}

/// Which windows to open.
#[derive(Clone, Debug, Default)]
pub struct WindowOptions {
    /// The stimulator's borderless fullscreen window, on this monitor.
    pub fullscreen: Option<Monitor>,
    /// The operator's preview window.
    pub preview: bool,
    /// Stop after this instant (`None`: until the windows are closed or [`DisplayEvent::Quit`]).
    pub until: Option<Instant>,
}

/// What the display thread is told.
pub enum DisplayEvent {
    /// Show this frame: the screen region's F_eff [W/m^2] (region size, row-major).
    Frame {
        frame_id: u64,
        region_px: [usize; 2],
        region_feff_w_m2: Arc<Vec<f64>>,
    },
    /// A replayed calibration curve's drive (its inverse, or a colour screen's), for the
    /// frames that follow.
    Curve(Box<Drive>),
    Quit,
}

/// Which window: the stimulator's fullscreen one or the operator's preview.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    Fullscreen,
    Preview,
}

/// A frame that reached the screen.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Presented {
    pub frame_id: u64,
    /// The window it went to.
    pub window: Role,
    /// The monitor (name, size) of the fullscreen window.
    pub monitor: String,
    pub timings_ms: PresentTimings,
}

/// Sends [`DisplayEvent`]s to the display thread from any thread.
#[derive(Clone)]
pub struct DisplaySender(EventLoopProxy<DisplayEvent>);

impl DisplaySender {
    /// Fails when the display has stopped.
    pub fn send(&self, event: DisplayEvent) -> Result<(), DisplayError> {
        self.0
            .send_event(event)
            .map_err(|_| DisplayError::Window("the display has stopped".into()))
    }
}

/// Whether a display server is reachable (X11 or Wayland): the daemon presents off-screen
/// otherwise.
pub fn display_available() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

struct WinTarget {
    role: Role,
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    binding: Option<Binding>,
}

struct App<F: FnMut(Presented)> {
    presenter: Presenter,
    stimulator: StimulatorConfig,
    options: WindowOptions,
    targets: Vec<WinTarget>,
    monitor: String,
    /// The frame on screen, drawn again after a resize or an expose.
    current: Option<u64>,
    on_presented: F,
    error: Option<DisplayError>,
}

/// Runs the windows until they are closed, [`DisplayEvent::Quit`] arrives or
/// `options.until` passes. `on_ready` gets the sender once the event loop exists (call it
/// from another thread to feed frames); `on_presented` hears of every presented frame.
pub fn run(
    stimulator: &StimulatorConfig,
    drive: &Drive,
    options: WindowOptions,
    on_ready: impl FnOnce(DisplaySender),
    on_presented: impl FnMut(Presented),
) -> Result<(), DisplayError> {
    let mut builder = EventLoop::<DisplayEvent>::with_user_event();
    #[cfg(all(unix, not(target_os = "macos")))]
    {
        // The daemon runs the display on its own thread, not on main.
        use winit::platform::x11::EventLoopBuilderExtX11;
        builder.with_any_thread(true);
    }
    let event_loop = builder
        .build()
        .map_err(|e| DisplayError::Window(e.to_string()))?;
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(
        Box::new(event_loop.owned_display_handle()),
    ));
    let mut presenter = Presenter::with_instance(instance, stimulator.screen_bits)?;
    presenter.set_drive(drive)?;
    on_ready(DisplaySender(event_loop.create_proxy()));
    let mut app = App {
        presenter,
        stimulator: stimulator.clone(),
        options,
        targets: Vec::new(),
        monitor: String::new(),
        current: None,
        on_presented,
        error: None,
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| DisplayError::Window(e.to_string()))?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl<F: FnMut(Presented)> App<F> {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<(), DisplayError> {
        if let Some(wanted) = self.options.fullscreen.clone() {
            let monitors: Vec<_> = event_loop.available_monitors().collect();
            let found = monitors.iter().enumerate().find(|(i, m)| match &wanted {
                Monitor::Index(k) => i == k,
                Monitor::Name(n) => m.name().is_some_and(|name| name.contains(n.as_str())),
            });
            let Some((_, monitor)) = found else {
                let available = monitors
                    .iter()
                    .enumerate()
                    .map(|(i, m)| format!("{i}: {}", describe(m)))
                    .collect::<Vec<_>>()
                    .join(", ");
                return Err(DisplayError::NoMonitor {
                    wanted: wanted.to_string(),
                    available,
                });
            };
            let size = monitor.size();
            let want = self.stimulator.screen_px;
            if [size.width as usize, size.height as usize] != want {
                return Err(DisplayError::MonitorSize {
                    monitor: describe(monitor),
                    got: [size.width, size.height],
                    want,
                });
            }
            self.monitor = describe(monitor);
            // Size and position as well as fullscreen: without a window manager X ignores
            // the fullscreen request.
            let attributes = Window::default_attributes()
                .with_title("optistim stimulator")
                .with_decorations(false)
                .with_inner_size(size)
                .with_position(monitor.position())
                .with_fullscreen(Some(Fullscreen::Borderless(Some(monitor.clone()))));
            self.add(event_loop, Role::Fullscreen, attributes)?;
        }
        if self.options.preview {
            let [w, h] = self.stimulator.screen_px.map(|x| x as f64);
            let scale = (960.0 / w).min(600.0 / h).min(1.0);
            let attributes = Window::default_attributes()
                .with_title("optistim preview")
                .with_inner_size(winit::dpi::PhysicalSize::new(
                    (w * scale).round() as u32,
                    (h * scale).round() as u32,
                ));
            self.add(event_loop, Role::Preview, attributes)?;
        }
        Ok(())
    }

    fn add(
        &mut self,
        event_loop: &ActiveEventLoop,
        role: Role,
        attributes: winit::window::WindowAttributes,
    ) -> Result<(), DisplayError> {
        let window = Arc::new(
            event_loop
                .create_window(attributes)
                .map_err(|e| DisplayError::Window(e.to_string()))?,
        );
        let surface = self
            .presenter
            .instance
            .create_surface(window.clone())
            .map_err(|e| DisplayError::Window(e.to_string()))?;
        let caps = surface.get_capabilities(&self.presenter.adapter);
        let bits = self.presenter.bits;
        // The stimulator's screen needs its DN depth exactly; the operator's preview may
        // show a 10-bit screen at 8 bit.
        let wanted: &[wgpu::TextureFormat] = match (bits > 8, role) {
            (true, Role::Fullscreen) => &[wgpu::TextureFormat::Rgb10a2Unorm],
            (true, _) => &[
                wgpu::TextureFormat::Rgb10a2Unorm,
                wgpu::TextureFormat::Bgra8Unorm,
                wgpu::TextureFormat::Rgba8Unorm,
            ],
            (false, _) => &[
                wgpu::TextureFormat::Bgra8Unorm,
                wgpu::TextureFormat::Rgba8Unorm,
            ],
        };
        // Calibrated DN are written as they are: never an sRGB format.
        let format = wanted
            .iter()
            .copied()
            .find(|f| caps.formats.contains(f))
            .ok_or_else(|| DisplayError::SurfaceFormat {
                bits,
                offered: format!("{:?}", caps.formats),
            })?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(
                &self.presenter.adapter,
                size.width.max(1),
                size.height.max(1),
            )
            .ok_or_else(|| DisplayError::Window("surface not supported by the adapter".into()))?;
        config.format = format;
        config.present_mode = wgpu::PresentMode::Fifo; // vsync
        surface.configure(&self.presenter.device, &config);
        tracing::info!(
            ?role,
            format = ?format,
            width = config.width,
            height = config.height,
            "window opened"
        );
        self.targets.push(WinTarget {
            role,
            window,
            surface,
            config,
            binding: None,
        });
        Ok(())
    }

    /// Draws the current frame into target `i`; `Ok(None)` when the surface skipped it
    /// (occluded, timed out).
    fn present(&mut self, i: usize) -> Result<Option<PresentTimings>, DisplayError> {
        let mut t = PresentTimings::default();
        let t0 = Instant::now();
        let mut retried = false;
        let frame = loop {
            let target = &mut self.targets[i];
            match target.surface.get_current_texture() {
                wgpu::CurrentSurfaceTexture::Success(f)
                | wgpu::CurrentSurfaceTexture::Suboptimal(f) => break f,
                wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                    return Ok(None);
                }
                wgpu::CurrentSurfaceTexture::Outdated if !retried => {
                    retried = true;
                    tracing::info!(role = ?target.role, "surface outdated: reconfigured");
                    target
                        .surface
                        .configure(&self.presenter.device, &target.config);
                }
                wgpu::CurrentSurfaceTexture::Lost if !retried => {
                    retried = true;
                    tracing::info!(role = ?target.role, "surface lost: recreated");
                    target.surface = self
                        .presenter
                        .instance
                        .create_surface(target.window.clone())
                        .map_err(|e| DisplayError::Window(e.to_string()))?;
                    target
                        .surface
                        .configure(&self.presenter.device, &target.config);
                }
                other => {
                    return Err(DisplayError::Window(format!(
                        "no surface texture: {}",
                        match other {
                            wgpu::CurrentSurfaceTexture::Validation => "validation error",
                            _ => "outdated or lost again after a reconfiguration",
                        }
                    )));
                }
            }
        };
        let target = &mut self.targets[i];
        let target_px = [target.config.width, target.config.height];
        let (w, h) = (target_px[0] as f32, target_px[1] as f32);
        let [sw, sh] = self.stimulator.screen_px.map(|x| x as f32);
        let scale = if target.role == Role::Fullscreen {
            [1.0, 1.0]
        } else {
            let s = (sw / w).max(sh / h);
            [s, s]
        };
        let view = frame.texture.create_view(&Default::default());
        let mut binding = target.binding.take();
        let format = target.config.format;
        let encoder = self
            .presenter
            .encode_pass(&mut binding, &view, format, target_px, scale);
        self.targets[i].binding = binding;
        let encoder = encoder?;
        t.lut_pass = super::ms(t0);
        let t0 = Instant::now();
        self.presenter.queue.submit([encoder.finish()]);
        self.targets[i].window.pre_present_notify();
        self.presenter.queue.present(frame);
        t.readback = super::ms(t0);
        Ok(Some(t))
    }

    fn present_all(&mut self, upload_ms: f64) -> Result<(), DisplayError> {
        for i in 0..self.targets.len() {
            self.present_and_report(i, upload_ms)?;
        }
        Ok(())
    }

    /// Presents the current frame (if any) in target `i` and reports it.
    fn present_and_report(&mut self, i: usize, upload_ms: f64) -> Result<(), DisplayError> {
        let Some(frame_id) = self.current else {
            return Ok(());
        };
        if let Some(mut t) = self.present(i)? {
            t.upload = upload_ms;
            (self.on_presented)(Presented {
                frame_id,
                window: self.targets[i].role,
                monitor: self.monitor.clone(),
                timings_ms: t,
            });
        }
        Ok(())
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: DisplayError) {
        tracing::debug!("display stops: {e}");
        self.error = Some(e);
        event_loop.exit();
    }
}

fn describe(m: &winit::monitor::MonitorHandle) -> String {
    let s = m.size();
    format!(
        "{} {}x{}",
        m.name().unwrap_or_else(|| "unnamed".into()),
        s.width,
        s.height
    )
}

impl<F: FnMut(Presented)> ApplicationHandler<DisplayEvent> for App<F> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.targets.is_empty()
            && let Err(e) = self.open(event_loop)
        {
            self.fail(event_loop, e);
        }
    }

    fn user_event(&mut self, event_loop: &ActiveEventLoop, event: DisplayEvent) {
        let result = match event {
            DisplayEvent::Frame {
                frame_id,
                region_px,
                region_feff_w_m2,
            } => self
                .presenter
                .upload(&self.stimulator, region_px, &region_feff_w_m2)
                .and_then(|upload| {
                    self.current = Some(frame_id);
                    self.present_all(upload)
                }),
            DisplayEvent::Curve(drive) => self.presenter.set_drive(&drive),
            DisplayEvent::Quit => {
                event_loop.exit();
                Ok(())
            }
        };
        if let Err(e) = result {
            self.fail(event_loop, e);
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, id: WindowId, event: WindowEvent) {
        let Some(i) = self.targets.iter().position(|t| t.window.id() == id) else {
            return;
        };
        match event {
            WindowEvent::CloseRequested => {
                if self.targets[i].role == Role::Fullscreen || self.targets.len() == 1 {
                    event_loop.exit();
                } else {
                    self.targets.remove(i);
                }
            }
            WindowEvent::Resized(size) if size.width > 0 && size.height > 0 => {
                let target = &mut self.targets[i];
                target.config.width = size.width;
                target.config.height = size.height;
                target
                    .surface
                    .configure(&self.presenter.device, &target.config);
                tracing::debug!(role = ?target.role, ?size, "surface reconfigured");
                target.window.request_redraw();
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.present_and_report(i, 0.0) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        match self.options.until {
            Some(t) if Instant::now() >= t => event_loop.exit(),
            Some(t) => event_loop.set_control_flow(ControlFlow::WaitUntil(t)),
            None => event_loop.set_control_flow(ControlFlow::Wait),
        }
    }
}
