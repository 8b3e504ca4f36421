//! The daemon (`optistim serve`): pose streams over TCP and serial ([`protocol`],
//! [`connection`], [`serial`]), the frame pipeline on its own thread ([`frames`]), HTTP
//! control and monitoring ([`http`]) and the recording of every received message
//! ([`record`]).
//!
//! Threads: a tokio runtime runs the listeners, the connections and HTTP; one frame thread
//! renders and presents (rendering never runs on the runtime; the render pool is its own
//! rayon pool); with a window, one display thread runs the winit event loop; a serial line
//! has a reader and a writer thread. They meet in [`Shared`] and the [`frames::Intake`].

pub mod access;
pub mod connection;
pub mod corto;
pub mod frames;
pub mod http;
pub mod protocol;
pub mod record;
pub mod serial;
pub mod surrender;
pub mod views;

use crate::config::Config;
use crate::pipeline::FrameMaker;
use crate::stimulator::camera::SimulatedCamera;
use frames::{FrameThread, Intake, Mode, PresenterChoice};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use protocol::Message;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tokio::sync::{mpsc, watch};

/// The embedded default scene: the NRHO camera's Lambert Moon on a RETINA-like screen with
/// the built-in example calibration (`config/daemon.toml`).
pub const DEFAULT_CONFIG: &str = include_str!("../../config/daemon.toml");
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7878";
pub const DEFAULT_HTTP: &str = "127.0.0.1:7879";
/// The largest scene file a client may name [bytes].
pub const MAX_SCENE_BYTES: u64 = 1 << 20;

#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    #[error("{what} {addr}: {source}")]
    Bind {
        what: &'static str,
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("the scene has no [stimulator] section: the daemon drives a screen")]
    NoStimulator,
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    #[error("recording {path}: {source}")]
    Record {
        path: String,
        source: std::io::Error,
    },
    #[error("serial line {path}: {message}")]
    Serial { path: String, message: String },
    #[error("runtime: {0}")]
    Runtime(String),
    #[error(transparent)]
    Access(#[from] access::AccessError),
}

/// How to run the daemon.
pub struct ServeOptions {
    pub config: Config,
    /// Where the config came from (a path, or the embedded default), and its text's SHA-256.
    pub config_label: String,
    pub config_sha256: String,
    pub listen: SocketAddr,
    pub http: SocketAddr,
    pub serial: Option<(String, u32)>,
    pub presenter: PresenterChoice,
    pub mode: Mode,
    pub record: Option<PathBuf>,
    /// The access token, the scene folders, `--insecure` ([`access`]).
    pub access: access::Access,
    /// The SurRender-compatible endpoint's address ([`surrender`]), when served.
    pub surrender: Option<SocketAddr>,
    /// The CORTO-compatible endpoint's pose (UDP) and image (TCP) addresses ([`corto`]).
    pub corto: Option<(SocketAddr, SocketAddr)>,
}

/// Settings that may change while the daemon runs (`GET/PUT /config`, the `config` message).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RuntimeConfig {
    pub mode: Mode,
    /// Render into the hold buffer; present on a trigger.
    pub hold: bool,
    /// The renderer's settings preset (`default` | `high_accuracy`, or `custom` for a scene's
    /// own `[render]` knobs).
    pub preset: String,
    /// The scene in force: a scene TOML path on the daemon's machine (or the embedded
    /// default's label). A new scene must drive the same screen (size and DN depth).
    pub scene: String,
}

/// A change to [`RuntimeConfig`]: only the keys given change.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RuntimePatch {
    pub mode: Option<Mode>,
    pub hold: Option<bool>,
    pub preset: Option<String>,
    pub scene: Option<String>,
}

/// The latest presented screen.
pub struct ScreenImage {
    /// Frames presented before this one (the daemon's own count; client frame ids need not
    /// grow).
    pub seq: u64,
    pub frame_id: u64,
    pub exposure_s: Option<f64>,
    pub screen_px: [usize; 2],
    /// The screen's codes: one plane, or a colour screen's three (R, G, B).
    pub dn: Vec<u16>,
}

/// A compatible endpoint's way to the frame thread: its poses are presented on the screen like
/// any other, and their `(P/L)` comes back.
pub struct CompatLink {
    shared: Arc<Shared>,
    out: Outbound,
    rx: mpsc::Receiver<Message>,
}

impl CompatLink {
    pub fn new(shared: Arc<Shared>) -> CompatLink {
        let (out, rx) = shared.outbound(64);
        CompatLink { shared, out, rx }
    }

    /// Presents `pose` (blocking until the frame thread is done with it): its `(P/L)`, or why
    /// not (refused, dropped for a newer pose, failed).
    pub fn present(
        &mut self,
        pose: crate::scene::Pose,
        exposure_s: Option<f64>,
    ) -> Result<Vec<f64>, String> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let job = frames::Job {
            pose,
            exposure_s,
            bodies: None,
            received: Instant::now(),
            reply: self.out.clone(),
            products: Some(tx),
        };
        self.shared.stats.poses_received.inc();
        connection::submit(&self.shared, job).map_err(|e| e.message)?;
        let r = rx.recv_timeout(std::time::Duration::from_secs(120));
        // The acks and errors the frame thread sent this link.
        let mut error = None;
        while let Ok(m) = self.rx.try_recv() {
            if let Message::Error { message, .. } = m {
                error = Some(message);
            }
        }
        match r {
            Ok(p) => p.map(|p| p.pl),
            Err(_) => Err(error.unwrap_or_else(|| {
                "the pose was not presented (a newer pose replaced it, or the daemon stops)".into()
            })),
        }
    }
}

/// What the dashboard and `/status` show of the latest rendered frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub frame_id: u64,
    /// Per stage of the frame pipeline [ms]: render, signal, stimulator chain.
    pub stage_ms: crate::pipeline::FrameTimings,
    /// The renderer's own steps [ms].
    pub render_steps_ms: crate::render::StageTimings,
    pub phase_deg: f64,
    /// Pixels of lit, visible surface.
    pub covered_px: f64,
    pub clips: crate::stimulator::calibration::ClipCounts,
    /// With `fidelity = "budget"`: the settings chosen and the error they are predicted to
    /// make against the converged reference.
    pub plan: Option<crate::fidelity::budget::Plan>,
}

/// A connection's outbound queue: bounded, so that a client that does not read cannot grow
/// the daemon's memory; what does not fit is counted and dropped.
#[derive(Clone)]
pub struct Outbound {
    pub conn: u64,
    tx: mpsc::Sender<Message>,
    undelivered: Counter,
}

/// Camera frames are queued only while fewer messages than this wait (they are megabytes
/// each; acks and errors, tens of bytes, fill the rest of the queue).
const BULKY_QUEUE: usize = 16;

impl Outbound {
    /// Queues `m`, or counts it undelivered: a camera frame when [`BULKY_QUEUE`] messages
    /// already wait, anything when the queue is full. (A queue of 16 for everything once
    /// dropped an ack on a busy machine: 160 ms of a starved writer at 100 Hz.)
    pub fn send(&self, m: Message) {
        let waiting = self.tx.max_capacity() - self.tx.capacity();
        let bulky = matches!(m, Message::CameraFrame { .. });
        if (bulky && waiting >= BULKY_QUEUE) || self.tx.try_send(m).is_err() {
            self.undelivered.inc();
        }
    }
}

/// The daemon's counters and recent frame times.
pub struct Stats {
    pub registry: Registry,
    pub poses_received: Counter,
    pub frames_presented: Counter,
    pub poses_dropped: Counter,
    pub protocol_errors: Counter,
    pub render_failures: Counter,
    pub undelivered: Counter,
    pub clients: Gauge,
    pub latency_seconds: Histogram,
    pub render_seconds: Histogram,
    /// (presented at, latency ms, render ms) of the last frames.
    recent: Mutex<VecDeque<(Instant, f64, f64)>>,
}

const RECENT: usize = 1000;

impl Stats {
    fn new() -> Stats {
        let mut registry = Registry::with_prefix("optistim");
        let buckets = || {
            Histogram::new(prometheus_client::metrics::histogram::exponential_buckets(
                0.001, 1.6, 16,
            ))
        };
        let s = Stats {
            poses_received: Counter::default(),
            frames_presented: Counter::default(),
            poses_dropped: Counter::default(),
            protocol_errors: Counter::default(),
            render_failures: Counter::default(),
            undelivered: Counter::default(),
            clients: Gauge::default(),
            latency_seconds: buckets(),
            render_seconds: buckets(),
            recent: Mutex::new(VecDeque::with_capacity(RECENT)),
            registry: Registry::default(),
        };
        for (name, help, counter) in [
            ("poses_received", "Poses received", &s.poses_received),
            ("frames_presented", "Frames presented", &s.frames_presented),
            (
                "poses_dropped",
                "Poses replaced by a newer one before rendering (free-running)",
                &s.poses_dropped,
            ),
            (
                "protocol_errors",
                "Bad messages answered with an error",
                &s.protocol_errors,
            ),
            (
                "render_failures",
                "Poses that could not be rendered or presented",
                &s.render_failures,
            ),
            (
                "undelivered_messages",
                "Messages to clients dropped because the client did not read them",
                &s.undelivered,
            ),
        ] {
            registry.register(name, help, counter.clone());
        }
        registry.register("clients", "Connected clients", s.clients.clone());
        for (name, help, histogram) in [
            (
                "latency_seconds",
                "Pose received to frame presented",
                &s.latency_seconds,
            ),
            (
                "render_seconds",
                "Render and stimulator chain per frame",
                &s.render_seconds,
            ),
        ] {
            registry.register(name, help, histogram.clone());
        }
        Stats { registry, ..s }
    }

    fn record_frame(&self, latency_ms: f64, render_ms: f64) {
        self.frames_presented.inc();
        self.latency_seconds.observe(latency_ms * 1e-3);
        self.render_seconds.observe(render_ms * 1e-3);
        let mut r = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        if r.len() == RECENT {
            r.pop_front();
        }
        r.push_back((Instant::now(), latency_ms, render_ms));
    }

    /// Frames per second over the last 5 s, latency percentiles [ms] over the last frames,
    /// and the last 200 latencies (for the dashboard's chart).
    pub fn summary(&self) -> (f64, [f64; 3], Vec<f64>) {
        let r = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        let now = Instant::now();
        let fps = r
            .iter()
            .filter(|(t, ..)| now - *t < std::time::Duration::from_secs(5))
            .count() as f64
            / 5.0;
        let mut l: Vec<f64> = r.iter().map(|x| x.1).collect();
        let last = l[l.len().saturating_sub(200)..].to_vec();
        (fps, crate::stats::quantiles(&mut l, [0.5, 0.99, 1.0]), last)
    }
}

/// The scene in force: its validated config, where it came from, and its simulated camera.
#[derive(Clone)]
pub struct SceneState {
    pub config: Config,
    pub label: String,
    pub sha256: String,
    pub camera: Option<Arc<SimulatedCamera>>,
}

/// What the connections, HTTP and the frame thread share.
pub struct Shared {
    epoch: Instant,
    pub stats: Stats,
    runtime: Mutex<RuntimeConfig>,
    pub latest: Mutex<Option<Arc<ScreenImage>>>,
    /// The active curve's id and SHA-256.
    pub calibration: Mutex<(String, String)>,
    pub presenter: String,
    scene: Mutex<SceneState>,
    subscribers: Mutex<Vec<Outbound>>,
    pub intake: Arc<Intake>,
    pub recorder: Option<record::Recorder>,
    next_conn: std::sync::atomic::AtomicU64,
    pub shutdown: watch::Receiver<bool>,
    pub access: access::Access,
    /// The images HTTP serves, made at most once per frame at a low priority.
    pub views: Arc<views::Views>,
    /// The latest rendered frame's report: stage times, clips, the planner's choice.
    pub last_frame: Mutex<Option<FrameReport>>,
    /// The cancel flag of the scene's DEM-horizon warm-up, while one runs.
    horizon_warmup: Mutex<Option<Arc<std::sync::atomic::AtomicBool>>>,
}

impl Shared {
    /// Nanoseconds on the daemon's monotonic clock.
    pub fn ns(&self, t: Instant) -> u64 {
        t.saturating_duration_since(self.epoch).as_nanos() as u64
    }

    pub fn runtime(&self) -> RuntimeConfig {
        self.runtime
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// The scene in force.
    pub fn scene(&self) -> SceneState {
        self.scene.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Applies a run-time change, validated as a whole before anything changes. A new scene
    /// is loaded and its pipeline built here (blocking: call it off the runtime's workers),
    /// then handed to the frame thread, which switches before the next pose.
    pub fn apply(&self, patch: RuntimePatch) -> Result<RuntimeConfig, String> {
        let current = self.scene();
        let settings = match &patch.preset {
            Some(p) => Some(
                crate::render::Settings::preset(p)
                    .ok_or_else(|| format!("preset {p:?}: allowed are default, high_accuracy"))?,
            ),
            None => None,
        };
        let scene = match &patch.scene {
            Some(path) => Some(self.load_scene(path, &current)?),
            None => None,
        };
        let mut r = self.runtime.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(m) = patch.mode {
            r.mode = m;
        }
        if let Some(h) = patch.hold {
            r.hold = h;
        }
        if let Some((state, maker)) = scene {
            r.scene = state.label.clone();
            r.preset = "custom".into();
            if let Err(e) = self.warm_horizon(&state.config) {
                // Frames still compute the horizons they need; only the head start is lost.
                tracing::warn!(error = %e, "DEM horizon warm-up not started");
            }
            *self.scene.lock().unwrap_or_else(|e| e.into_inner()) = state;
            self.intake.control(frames::Control::Scene(Box::new(maker)));
        }
        if let (Some(p), Some(mut s)) = (patch.preset, settings) {
            s.threads = current.config.settings.threads;
            r.preset = p;
            self.intake.control(frames::Control::Settings(s));
        }
        tracing::info!(runtime = ?*r, "run-time settings changed");
        Ok(r.clone())
    }

    /// Horizons computed from the DEM fill on demand, so the first frames over a region would
    /// pay for them: when `config`'s body has such a horizon, a background thread computes it
    /// all (the frames' renderer shares the cache and never computes a texel twice). A
    /// warm-up still running for a previous scene is cancelled; shutdown stops it too.
    fn warm_horizon(&self, config: &crate::config::Config) -> std::io::Result<()> {
        use std::sync::atomic::{AtomicBool, Ordering};
        let mut slot = self
            .horizon_warmup
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(previous) = slot.take() {
            previous.store(true, Ordering::Relaxed);
        }
        let body = &config.scene.body;
        let Some(horizon) = body.relief.as_ref().and_then(|r| r.dem_horizon.clone()) else {
            return Ok(());
        };
        let cancel = Arc::new(AtomicBool::new(false));
        let (stop, cancelled) = (self.shutdown.clone(), cancel.clone());
        let body_name = body.name.clone();
        std::thread::Builder::new()
            .name("optistim-horizon".into())
            .spawn(move || {
                let t0 = Instant::now();
                let texels = horizon.warm(|| *stop.borrow() || cancelled.load(Ordering::Relaxed));
                tracing::info!(
                    body = %body_name,
                    texels,
                    seconds = t0.elapsed().as_secs_f64(),
                    cancelled = cancelled.load(Ordering::Relaxed),
                    "DEM horizon computed"
                );
            })?;
        *slot = Some(cancel);
        Ok(())
    }

    /// Loads and checks a scene named by a client for the screen in use, and builds its
    /// pipeline. The scene and every file it names must lie in the scene folders
    /// ([`access`]); nothing read elsewhere, nor a file that is not a scene, is echoed.
    fn load_scene(
        &self,
        named: &str,
        current: &SceneState,
    ) -> Result<(SceneState, FrameMaker), String> {
        let file = self.access.scene_path(named)?;
        let path = file.display().to_string();
        // A scene is a few kilobytes of TOML; anything much larger is not one.
        let len = std::fs::metadata(&file).map_or(0, |m| m.len());
        if len > MAX_SCENE_BYTES {
            return Err(format!(
                "scene {path}: {len} bytes; a scene file is at most {MAX_SCENE_BYTES}"
            ));
        }
        let text = std::fs::read_to_string(&file).map_err(|e| format!("scene {path}: {e}"))?;
        let allow = |p: &std::path::Path| self.access.allows(p);
        let config =
            crate::config::parse_confined(&text, &path, &allow).map_err(|e| e.to_string())?;
        let (Some(new), Some(old)) = (&config.stimulator, &current.config.stimulator) else {
            return Err(format!("scene {path}: no [stimulator] section"));
        };
        if (new.screen_px, new.screen_bits) != (old.screen_px, old.screen_bits) {
            return Err(format!(
                "scene {path}: a {:?} px {}-bit screen; the daemon drives a {:?} px {}-bit \
                 one (a different screen needs a restart)",
                new.screen_px, new.screen_bits, old.screen_px, old.screen_bits
            ));
        }
        let maker = FrameMaker::new(&config).map_err(|e| format!("scene {path}: {e}"))?;
        let state = SceneState {
            label: path.to_string(),
            sha256: crate::io::sha256_hex(text.as_bytes()),
            camera: maker.camera().cloned(),
            config,
        };
        Ok((state, maker))
    }

    pub fn subscribe(&self, out: &Outbound, on: bool) {
        let mut s = self.subscribers.lock().unwrap_or_else(|e| e.into_inner());
        s.retain(|o| o.conn != out.conn);
        if on {
            s.push(out.clone());
        }
    }

    fn subscribers(&self) -> Vec<Outbound> {
        let mut s = self.subscribers.lock().unwrap_or_else(|e| e.into_inner());
        s.retain(|o| !o.tx.is_closed());
        s.clone()
    }

    /// A new connection's outbound queue (`capacity` messages) and its receiving end.
    pub fn outbound(&self, capacity: usize) -> (Outbound, mpsc::Receiver<Message>) {
        let (tx, rx) = mpsc::channel(capacity);
        let conn = self
            .next_conn
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        (
            Outbound {
                conn,
                tx,
                undelivered: self.stats.undelivered.clone(),
            },
            rx,
        )
    }
}

/// A running daemon.
pub struct Server {
    pub tcp_addr: SocketAddr,
    pub http_addr: SocketAddr,
    pub shared: Arc<Shared>,
    stop: watch::Sender<bool>,
    runtime: Option<tokio::runtime::Runtime>,
    frame_thread: Option<std::thread::JoinHandle<()>>,
    http_thread: Option<std::thread::JoinHandle<()>>,
    /// The SurRender endpoint as bound.
    pub surrender_addr: Option<SocketAddr>,
    surrender_thread: Option<std::thread::JoinHandle<()>>,
    /// The CORTO endpoint's pose and image addresses as bound.
    pub corto_addrs: Option<(SocketAddr, SocketAddr)>,
    corto_threads: Vec<std::thread::JoinHandle<()>>,
}

/// What happened at shutdown.
#[derive(Debug, Serialize)]
pub struct ShutdownReport {
    /// Poses that were waiting and were answered `shutting_down` instead of rendered.
    pub poses_not_rendered: usize,
    pub frames_presented: u64,
    pub recording_flushed: bool,
}

impl Server {
    /// Binds the listeners, starts the frame thread and the runtime, and returns once the
    /// daemon serves.
    pub fn start(options: ServeOptions) -> Result<Server, ServerError> {
        if options.config.stimulator.is_none() {
            return Err(ServerError::NoStimulator);
        }
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("optistim-io")
            .enable_all()
            .build()
            .map_err(|e| ServerError::Runtime(e.to_string()))?;
        let bind = |what: &'static str, addr: SocketAddr| {
            runtime
                .block_on(tokio::net::TcpListener::bind(addr))
                .map_err(|source| ServerError::Bind { what, addr, source })
        };
        options.access.check_bind("pose listener", options.listen)?;
        options.access.check_bind("HTTP listener", options.http)?;
        if let Some(a) = options.surrender {
            options
                .access
                .check_bind_tokenless("SurRender listener", a)?;
        }
        let surrender_listener = match options.surrender {
            Some(addr) => {
                Some(
                    std::net::TcpListener::bind(addr).map_err(|source| ServerError::Bind {
                        what: "SurRender listener",
                        addr,
                        source,
                    })?,
                )
            }
            None => None,
        };
        let surrender_addr = surrender_listener
            .as_ref()
            .and_then(|l| l.local_addr().ok());
        let corto_sockets = match options.corto {
            Some((pose, image)) => {
                options
                    .access
                    .check_bind_tokenless("CORTO pose port", pose)?;
                options
                    .access
                    .check_bind_tokenless("CORTO image port", image)?;
                if options.config.corto_metres_per_unit.is_none() {
                    return Err(ServerError::Runtime(
                        "--corto-pose: the scene has no [corto] section (metres_per_unit: \
                         metres per Blender unit of the client's poses)"
                            .into(),
                    ));
                }
                let bind_err = |what, addr| move |source| ServerError::Bind { what, addr, source };
                Some((
                    std::net::UdpSocket::bind(pose).map_err(bind_err("CORTO pose port", pose))?,
                    std::net::TcpListener::bind(image)
                        .map_err(bind_err("CORTO image port", image))?,
                ))
            }
            None => None,
        };
        let corto_addrs = corto_sockets
            .as_ref()
            .and_then(|(u, t)| Some((u.local_addr().ok()?, t.local_addr().ok()?)));
        let tcp = bind("pose listener", options.listen)?;
        // HTTP runs on its own runtime, on a background thread: watching never takes the
        // frames' CPU (tests/watching.rs).
        let http_listener = std::net::TcpListener::bind(options.http)
            .and_then(|l| l.set_nonblocking(true).map(|()| l))
            .map_err(|source| ServerError::Bind {
                what: "HTTP listener",
                addr: options.http,
                source,
            })?;
        let tcp_addr = tcp
            .local_addr()
            .map_err(|e| ServerError::Runtime(e.to_string()))?;
        let http_addr = http_listener
            .local_addr()
            .map_err(|e| ServerError::Runtime(e.to_string()))?;
        let recorder = match &options.record {
            Some(p) => Some(
                record::Recorder::create(p).map_err(|source| ServerError::Record {
                    path: p.display().to_string(),
                    source,
                })?,
            ),
            None => None,
        };

        let maker = FrameMaker::new(&options.config)?;
        let curve = maker.stimulator().expect("checked").curve().clone();
        let camera = maker.camera().cloned();
        let intake = Arc::new(Intake::default());
        let (stop, stop_rx) = watch::channel(false);
        // The scene's own preset when it equals one by name; "custom" otherwise.
        let preset = ["default", "high_accuracy"]
            .into_iter()
            .find(|p| {
                crate::render::Settings::preset(p).is_some_and(|mut s| {
                    s.threads = options.config.settings.threads;
                    s.depth = options.config.settings.depth;
                    s == options.config.settings
                })
            })
            .unwrap_or("custom")
            .to_string();
        let (present, presenter) = frames::open_presenter(&maker, &options.presenter);
        let shared = Arc::new(Shared {
            epoch: Instant::now(),
            stats: Stats::new(),
            runtime: Mutex::new(RuntimeConfig {
                mode: options.mode,
                hold: false,
                preset,
                scene: options.config_label.clone(),
            }),
            latest: Mutex::new(None),
            calibration: Mutex::new((curve.id.clone(), curve.sha256.clone())),
            presenter: presenter.clone(),
            scene: Mutex::new(SceneState {
                config: options.config.clone(),
                label: options.config_label.clone(),
                sha256: options.config_sha256.clone(),
                camera,
            }),
            subscribers: Mutex::new(Vec::new()),
            intake,
            recorder,
            next_conn: std::sync::atomic::AtomicU64::new(1),
            shutdown: stop_rx.clone(),
            access: options.access.clone(),
            views: views::Views::start().map_err(|e| ServerError::Runtime(e.to_string()))?,
            last_frame: Mutex::new(None),
            horizon_warmup: Mutex::new(None),
        });
        shared
            .warm_horizon(&options.config)
            .map_err(|e| ServerError::Runtime(e.to_string()))?;
        let frame_thread = FrameThread::new(maker, present, shared.clone());
        let frame_thread = std::thread::Builder::new()
            .name("optistim-frames".into())
            .spawn(move || frame_thread.run())
            .map_err(|e| ServerError::Runtime(e.to_string()))?;

        runtime.spawn(connection::accept(tcp, shared.clone()));
        let surrender_thread = match surrender_listener {
            Some(l) => Some(
                surrender::spawn(l, shared.clone())
                    .map_err(|e| ServerError::Runtime(e.to_string()))?,
            ),
            None => None,
        };
        let corto_threads = match corto_sockets {
            Some((u, t)) => corto::spawn(u, t, shared.clone())
                .map_err(|e| ServerError::Runtime(e.to_string()))?,
            None => Vec::new(),
        };
        let http_thread = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("optistim-http".into())
                .spawn(move || {
                    views::background_priority();
                    let rt = tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build();
                    match rt {
                        Ok(rt) => rt.block_on(async move {
                            match tokio::net::TcpListener::from_std(http_listener) {
                                Ok(l) => http::serve(l, shared).await,
                                Err(e) => tracing::error!("HTTP listener: {e}"),
                            }
                        }),
                        Err(e) => tracing::error!("HTTP runtime: {e}"),
                    }
                })
                .map_err(|e| ServerError::Runtime(e.to_string()))?
        };
        if let Some((path, baud)) = &options.serial {
            serial::spawn(path, *baud, shared.clone(), runtime.handle().clone()).map_err(
                |message| ServerError::Serial {
                    path: path.clone(),
                    message,
                },
            )?;
        }
        tracing::info!(
            pose = %tcp_addr,
            http = %http_addr,
            serial = ?options.serial.as_ref().map(|s| &s.0),
            presenter = %presenter,
            mode = ?options.mode,
            config = %options.config_label,
            "optistim serving"
        );
        Ok(Server {
            tcp_addr,
            http_addr,
            shared,
            stop,
            runtime: Some(runtime),
            frame_thread: Some(frame_thread),
            http_thread: Some(http_thread),
            surrender_addr,
            surrender_thread,
            corto_addrs,
            corto_threads,
        })
    }

    /// The presenter in words.
    pub fn presenter(&self) -> &str {
        &self.shared.presenter
    }

    /// Stops: no new poses, the frame in flight is finished, waiting poses are answered
    /// `shutting_down`, connections close, the recording is flushed.
    pub fn shutdown(mut self) -> ShutdownReport {
        self.stop_now()
    }

    fn stop_now(&mut self) -> ShutdownReport {
        let _ = self.stop.send(true);
        let waiting = self.shared.intake.stop();
        let n = waiting.len();
        for job in waiting {
            job.reply.send(Message::from(protocol::ProtocolError {
                code: protocol::ErrorCode::ShuttingDown,
                message: "the daemon is shutting down; this pose was not rendered".into(),
                frame_id: Some(job.pose.frame_id),
            }));
        }
        if let Some(t) = self.frame_thread.take() {
            let _ = t.join();
        }
        // Let the connections write their last messages, then close them.
        if let Some(rt) = self.runtime.take() {
            rt.block_on(async { tokio::time::sleep(std::time::Duration::from_millis(100)).await });
            rt.shutdown_timeout(std::time::Duration::from_secs(2));
        }
        if let Some(t) = self.surrender_thread.take() {
            let _ = t.join();
        }
        for t in self.corto_threads.drain(..) {
            let _ = t.join();
        }
        // HTTP stops on the same signal once its requests are answered (2 s at most).
        if let Some(t) = self.http_thread.take() {
            let deadline = Instant::now() + std::time::Duration::from_secs(2);
            while !t.is_finished() && Instant::now() < deadline {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            if t.is_finished() {
                let _ = t.join();
            }
        }
        let flushed = self
            .shared
            .recorder
            .as_ref()
            .is_none_or(|r| r.flush().is_ok());
        let report = ShutdownReport {
            poses_not_rendered: n,
            frames_presented: self.shared.stats.frames_presented.get(),
            recording_flushed: flushed,
        };
        tracing::info!(?report, "optistim stopped");
        report
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if self.runtime.is_some() {
            self.stop_now();
        }
    }
}
