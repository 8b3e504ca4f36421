//! The images HTTP serves, made at most once per frame, off the frame thread's way.
//!
//! Watching must never disturb the loop (a poll of `/camera/latest.png` by 16 clients once
//! took the pose-to-presented p99 from 26 ms to 1.8 s: each request captured a camera image
//! on the blocking pool). So every image is made by one worker thread in the background
//! ([`background_priority`], with its own one-thread rayon pool), at most once per frame and view,
//! and cached; requests for an image being made wait for it (at most [`MAX_WAITING`] per
//! view, then `503`); the simulated camera's capture is shared by its two views and taken
//! from the frame thread when a subscriber already made it.
//!
//! Priority alone does not keep the worker off a frame's CPU on a 2-core bench (a
//! `SCHED_IDLE` thread still runs in the frame's serial stages), so the worker also defers to
//! the frames: it starts a job between frames ([`FrameGate`]) and the job's loops pause
//! between slices of about a millisecond while a frame is in flight
//! ([`crate::background::checkpoint`]), for at most [`FrameGate::MAX_DEFER`] per image.
//!
//! Views: the screen's codes as a 16-bit PNG (what the screen shows, exactly), the screen
//! scaled for viewing (8-bit RGB, linear in DN, the image's highest unclipped code white,
//! clipped pixels red), and the same two for the simulated camera (its DN; saturated
//! pixels red). The scale comes with the image ([`Scale`], and HTTP headers).

use super::ScreenImage;
use crate::detector::{Bayer, Layout};
use crate::stimulator::camera::SimulatedCamera;
use serde::Serialize;
use std::sync::{Arc, Mutex, Weak};
use tokio::sync::oneshot;

/// Requests that may wait for one view's image; more are answered `503`.
pub const MAX_WAITING: usize = 256;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// The screen's codes, 16-bit grey.
    ScreenCodes = 0,
    /// The screen scaled for viewing, clipped pixels red.
    ScreenView = 1,
    /// The simulated camera's DN (its saved bits).
    CameraDn = 2,
    /// The simulated camera scaled for viewing, saturated pixels red.
    CameraView = 3,
}

impl View {
    pub fn is_camera(self) -> bool {
        matches!(self, View::CameraDn | View::CameraView)
    }
}

const VIEWS: usize = 4;

/// How a viewing image maps DN to grey.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Scale {
    /// The DN drawn white (grey is linear in DN from 0): the highest unclipped DN.
    pub white_dn: u32,
    /// Pixels drawn red: at the screen's highest code (F_eff above the screen's maximum),
    /// or at the camera's saturation.
    pub clipped_px: u64,
    /// The DN the red pixels are at or above.
    pub clip_dn: u32,
}

/// One made image.
#[derive(Debug)]
pub struct Image {
    /// The presented frame's sequence number ([`ScreenImage::seq`]) and the client's id.
    pub seq: u64,
    pub frame_id: u64,
    /// Shared with every response (no copy per request).
    pub png: axum::body::Bytes,
    /// For the viewing images.
    pub scale: Option<Scale>,
}

pub type Answer = Result<Arc<Image>, String>;

/// An image now, or a promise of it.
pub enum Get {
    Ready(Answer),
    Wait(oneshot::Receiver<Answer>),
}

struct Job {
    view: View,
    screen: Arc<ScreenImage>,
    screen_bits: u32,
    camera: Option<Arc<SimulatedCamera>>,
}

#[derive(Default)]
struct Inner {
    ready: [Option<Arc<Image>>; VIEWS],
    waiting: [Vec<oneshot::Sender<Answer>>; VIEWS],
    /// The latest capture of the simulated camera (frame sequence number, DN).
    camera: Option<(u64, Arc<Vec<u16>>)>,
    images_made: u64,
    captures_made: u64,
}

/// The image cache and its worker.
pub struct Views {
    inner: Mutex<Inner>,
    jobs: std::sync::mpsc::SyncSender<Job>,
    /// Frames in flight: the worker makes images between them.
    pub gate: Arc<FrameGate>,
}

impl Views {
    /// Starts the worker thread; it ends when the `Views` is dropped.
    pub fn start() -> std::io::Result<Arc<Views>> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Job>(VIEWS);
        let views = Arc::new(Views {
            inner: Mutex::new(Inner::default()),
            jobs: tx,
            gate: Arc::new(FrameGate::default()),
        });
        let weak = Arc::downgrade(&views);
        std::thread::Builder::new()
            .name("optistim-views".into())
            .spawn(move || worker(rx, weak))?;
        Ok(views)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// `view` of the frame `screen`: the cached image when it is of this frame, else a
    /// promise (the first request of a frame starts the making).
    pub fn get(
        &self,
        view: View,
        screen: Arc<ScreenImage>,
        screen_bits: u32,
        camera: Option<Arc<SimulatedCamera>>,
    ) -> Get {
        let mut inner = self.lock();
        let k = view as usize;
        if let Some(img) = &inner.ready[k]
            && img.seq == screen.seq
        {
            return Get::Ready(Ok(img.clone()));
        }
        if inner.waiting[k].len() >= MAX_WAITING {
            return Get::Ready(Err(BUSY.into()));
        }
        let (tx, rx) = oneshot::channel();
        let first = inner.waiting[k].is_empty();
        inner.waiting[k].push(tx);
        if first {
            let job = Job {
                view,
                screen,
                screen_bits,
                camera,
            };
            // One job per view at most is outstanding, so the queue (one slot per view)
            // never fills.
            if self.jobs.try_send(job).is_err() {
                for w in inner.waiting[k].drain(..) {
                    let _ = w.send(Err("the image worker stopped".into()));
                }
            }
        }
        Get::Wait(rx)
    }

    /// The frame thread's capture of the simulated camera (made for subscribers), so that
    /// the camera views need not capture it again.
    pub fn offer_camera(&self, seq: u64, dn: Arc<Vec<u16>>) {
        let mut inner = self.lock();
        if inner.camera.as_ref().is_none_or(|(s, _)| *s < seq) {
            inner.camera = Some((seq, dn));
        }
    }

    /// Images encoded and camera captures taken so far by the worker.
    pub fn made(&self) -> (u64, u64) {
        let inner = self.lock();
        (inner.images_made, inner.captures_made)
    }
}

/// Whether the frame thread has a frame in flight (from taking a pose to its ack). What
/// serves watchers, HTTP and this worker, waits for it to clear before working (at most
/// [`FrameGate::MAX_WAIT`]): they then take no CPU, memory bandwidth or kernel time from a
/// frame being made, only from the idle time between frames (issue 19: watching never
/// disturbs the loop). The flag is one atomic: the frame thread never waits on a lock the
/// background threads hold.
#[derive(Debug, Default)]
pub struct FrameGate {
    busy: std::sync::atomic::AtomicBool,
    /// Waits that ran out with a frame still in flight (watchers then served during it).
    ran_out: std::sync::atomic::AtomicU64,
}

impl FrameGate {
    /// The longest a watcher waits for the frames (in free-running mode at full rate there
    /// may be no gap: watchers are then served after this wait, at their low priority).
    pub const MAX_WAIT: std::time::Duration = std::time::Duration::from_millis(250);
    const POLL: std::time::Duration = std::time::Duration::from_millis(3);
    /// The longest an image being made defers to the frames, over all its pauses: it is
    /// made in the gaps between frames, in slices ([`crate::background`]), and after this
    /// goes on at its low priority (a frame loop with no gaps must not starve the dashboard).
    pub const MAX_DEFER: std::time::Duration = std::time::Duration::from_millis(1000);
    /// How often a paused background slice looks at the gate (the gaps at perilune are a
    /// few milliseconds).
    const BACKGROUND_POLL: std::time::Duration = std::time::Duration::from_millis(1);

    /// Marks a frame in flight until the guard drops.
    pub fn enter(&self) -> FrameGuard<'_> {
        self.busy.store(true, std::sync::atomic::Ordering::Release);
        FrameGuard(self)
    }

    fn busy(&self) -> bool {
        self.busy.load(std::sync::atomic::Ordering::Acquire)
    }

    /// Waits (asynchronously) until no frame is in flight, or `MAX_WAIT`.
    pub async fn idle(&self) {
        self.idle_before(std::time::Instant::now() + Self::MAX_WAIT)
            .await;
    }

    /// Waits (asynchronously) until no frame is in flight, or until `until`.
    pub async fn idle_before(&self, until: std::time::Instant) {
        while self.wait_on(until) {
            tokio::time::sleep(Self::POLL).await;
        }
    }

    /// Blocks the calling (background) thread until no frame is in flight, or until `until`.
    pub fn idle_until(&self, until: std::time::Instant) {
        while self.wait_on(until) {
            std::thread::sleep(Self::BACKGROUND_POLL);
        }
    }

    /// Whether a watcher should go on waiting: a frame is in flight and `until` is not
    /// reached (a wait that reaches it is counted).
    fn wait_on(&self, until: std::time::Instant) -> bool {
        if !self.busy() {
            return false;
        }
        if std::time::Instant::now() < until {
            return true;
        }
        self.ran_out
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        false
    }

    /// Waits for the frames that ran out (watchers served during a frame) so far.
    pub fn ran_out(&self) -> u64 {
        self.ran_out.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// A frame in flight ([`FrameGate::enter`]).
pub struct FrameGuard<'a>(&'a FrameGate);

impl Drop for FrameGuard<'_> {
    fn drop(&mut self) {
        self.0
            .busy
            .store(false, std::sync::atomic::Ordering::Release);
    }
}

/// The answer when too many requests wait.
pub const BUSY: &str = "too many requests wait for this image";

/// Puts the calling thread in the background: it runs when the frame thread and the pose
/// connections leave a core idle (Linux `SCHED_IDLE`, and nice 19 where that is refused).
/// Threads it starts inherit this. Under a frame loop that saturates every core the
/// dashboard then updates slowly; the frames keep their pace.
pub fn background_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: changes the calling thread's own scheduling; the parameter is only read.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19);
        let p = libc::sched_param { sched_priority: 0 };
        libc::sched_setscheduler(0, libc::SCHED_IDLE, &p);
    }
}

fn worker(rx: std::sync::mpsc::Receiver<Job>, views: Weak<Views>) {
    background_priority();
    // When the job being made stops deferring to the frames ([`FrameGate::MAX_DEFER`]).
    let deadline = Arc::new(Mutex::new(std::time::Instant::now()));
    let gate = match views.upgrade() {
        Some(v) => v.gate.clone(),
        None => return,
    };
    let (d, g) = (deadline.clone(), gate.clone());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name(|_| "optistim-views-pool".into())
        .start_handler(move |_| {
            background_priority();
            let (d, g) = (d.clone(), g.clone());
            // The job's loops pause between slices while a frame is in flight.
            crate::background::install(Arc::new(move || {
                let until = *d.lock().unwrap_or_else(|e| e.into_inner());
                g.idle_until(until);
            }));
        })
        .build();
    while let Ok(job) = rx.recv() {
        let Some(views) = views.upgrade() else { return };
        let until = std::time::Instant::now() + FrameGate::MAX_DEFER;
        *deadline.lock().unwrap_or_else(|e| e.into_inner()) = until;
        gate.idle_until(until);
        let k = job.view as usize;
        let answer = match &pool {
            Ok(p) => p.install(|| make(&views, &job)),
            Err(e) => Err(format!("image worker: {e}")),
        };
        let mut inner = views.lock();
        if let Ok(img) = &answer {
            inner.images_made += 1;
            if inner.ready[k].as_ref().is_none_or(|r| r.seq <= img.seq) {
                inner.ready[k] = Some(img.clone());
            }
        }
        for w in inner.waiting[k].drain(..) {
            let _ = w.send(answer.clone());
        }
    }
}

fn make(views: &Views, job: &Job) -> Answer {
    let (seq, frame_id) = (job.screen.seq, job.screen.frame_id);
    let [w, h] = job.screen_px();
    if !job.view.is_camera() {
        let max_code = (1u32 << job.screen_bits) - 1;
        // A colour screen's three planes of codes are an RGB image.
        let dn = &job.screen.dn;
        return match job.view {
            View::ScreenCodes => codes((seq, frame_id), w, h, dn, 16, &[]),
            _ => viewing((seq, frame_id), (w, h), dn, max_code, planes(dn, w * h)),
        };
    }
    let Some(camera) = &job.camera else {
        return Err("no simulated camera".into());
    };
    let [cw, ch] = camera.camera_px();
    let dn = capture(views, job, camera)?;
    let d = camera.detector();
    match job.view {
        View::CameraDn => {
            let text = crate::app::products::png_text(d);
            codes((seq, frame_id), cw, ch, &dn, d.saved_bits, &text)
        }
        _ => {
            // Saturation: the top of the saved range, or the full well if it comes first.
            let full_well_dn =
                (d.offset_dn + d.full_well_e * d.adc_gain_dn_per_e) / d.saved_dn_step();
            let sat = d.max_dn().min(full_well_dn.floor()).max(1.0) as u32;
            let (id, size) = ((seq, frame_id), (cw, ch));
            match d.layout {
                Layout::Bayer(order) => viewing(id, size, &dn, sat, mosaic(&dn, cw, ch, order)),
                Layout::Planes => viewing(id, size, &dn, sat, planes(&dn, cw * ch)),
            }
        }
    }
}

/// Pixel `i`'s `[R, G, B]` DN of an image of one plane (grey) or three (`n` pixels each).
fn planes(dn: &[u16], n: usize) -> impl Fn(usize) -> [u32; 3] + '_ {
    let colour = dn.len() >= 3 * n && n > 0;
    move |i| {
        if colour {
            [dn[i], dn[n + i], dn[2 * n + i]].map(u32::from)
        } else {
            [u32::from(dn[i]); 3]
        }
    }
}

/// Pixel `i`'s `[R, G, B]` DN for viewing a Bayer mosaic: its 2 x 2 cell's R, the mean of
/// its two G and its B (a cell-wise view, not a demosaicing: the camera's product is the raw
/// mosaic, `View::CameraDn`).
fn mosaic(dn: &[u16], w: usize, h: usize, order: Bayer) -> impl Fn(usize) -> [u32; 3] + '_ {
    move |i| {
        let (x0, y0) = ((i % w) & !1, (i / w) & !1);
        let (mut sum, mut count) = ([0u32; 3], [0u32; 3]);
        for (x, y) in [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)] {
            let (x, y) = (x.min(w - 1), y.min(h - 1));
            let b = order.band_at(x, y);
            sum[b] += u32::from(dn[y * w + x]);
            count[b] += 1;
        }
        [0, 1, 2].map(|b| sum[b] / count[b].max(1))
    }
}

impl Job {
    fn screen_px(&self) -> [usize; 2] {
        self.screen.screen_px
    }
}

/// The camera's image of the job's frame: the cached capture, else a new one.
fn capture(views: &Views, job: &Job, camera: &SimulatedCamera) -> Result<Arc<Vec<u16>>, String> {
    let seq = job.screen.seq;
    if let Some((s, dn)) = &views.lock().camera
        && *s == seq
    {
        return Ok(dn.clone());
    }
    let c = camera
        .capture_exposed(&job.screen.dn, job.screen.frame_id, job.screen.exposure_s)
        .map_err(|e| e.to_string())?;
    let dn = Arc::new(c.dn);
    let mut inner = views.lock();
    inner.captures_made += 1;
    if inner.camera.as_ref().is_none_or(|(s, _)| *s < seq) {
        inner.camera = Some((seq, dn.clone()));
    }
    Ok(dn)
}

/// An encoded image of frame `(seq, frame_id)`, or why it could not be encoded.
fn image(
    (seq, frame_id): (u64, u64),
    png: Result<Vec<u8>, png::EncodingError>,
    scale: Option<Scale>,
) -> Answer {
    let png = png.map_err(|e| e.to_string())?.into();
    Ok(Arc::new(Image {
        seq,
        frame_id,
        png,
        scale,
    }))
}

/// DN as they are, in a PNG of `bits` (16-bit above 8): grey, or RGB for three planes
/// (`crate::io::encode_png_planes`), with `text` chunks.
fn codes(
    id: (u64, u64),
    w: usize,
    h: usize,
    dn: &[u16],
    bits: u32,
    text: &[(&str, String)],
) -> Answer {
    image(id, crate::io::encode_png_planes(w, h, dn, bits, text), None)
}

/// DN scaled for viewing, pixel `i` being `rgb_of(i)` (the same DN thrice for grey): linear
/// in DN with the highest DN of `dn` below `clip_dn` white, and the pixels with a channel at
/// or above `clip_dn` red.
fn viewing(
    id: (u64, u64),
    (w, h): (usize, usize),
    dn: &[u16],
    clip_dn: u32,
    rgb_of: impl Fn(usize) -> [u32; 3],
) -> Answer {
    let n = w * h;
    let white = dn
        .iter()
        .map(|&v| u32::from(v))
        .filter(|&v| v < clip_dn)
        .max()
        .unwrap_or(0)
        .max(1);
    let scaled = |c: u32| ((c * 255 + white / 2) / white).min(255) as u8;
    let mut clipped = 0u64;
    let mut rgb = Vec::with_capacity(n * 3);
    for k in 0..n {
        if k % (1 << 16) == 0 {
            crate::background::checkpoint();
        }
        let v = rgb_of(k);
        if v.iter().any(|&c| c >= clip_dn) {
            clipped += 1;
            rgb.extend_from_slice(&[255, 0, 64]);
        } else if v[0] == v[1] && v[1] == v[2] {
            let g = scaled(v[0]);
            rgb.extend_from_slice(&[g, g, g]);
        } else {
            rgb.extend(v.map(scaled));
        }
    }
    let scale = Scale {
        white_dn: white,
        clipped_px: clipped,
        clip_dn,
    };
    image(id, crate::io::encode_png_rgb(w, h, &rgb), Some(scale))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_image_asked_for_during_a_frame_is_made_after_it() {
        let views = Views::start().unwrap();
        let screen = Arc::new(ScreenImage {
            seq: 1,
            frame_id: 9,
            exposure_s: None,
            screen_px: [64, 48],
            dn: vec![100; 64 * 48],
        });
        let guard = views.gate.enter();
        let Get::Wait(mut rx) = views.get(View::ScreenView, screen.clone(), 10, None) else {
            panic!("nothing was cached");
        };
        std::thread::sleep(std::time::Duration::from_millis(150));
        assert!(rx.try_recv().is_err(), "made while the frame was in flight");
        assert_eq!(views.made().0, 0);
        drop(guard);
        let img = rx.blocking_recv().unwrap().unwrap();
        assert_eq!((img.seq, img.frame_id), (1, 9));
        assert_eq!(views.gate.ran_out(), 0);
        // Once made, the frame's image is served from the cache.
        assert!(matches!(
            views.get(View::ScreenView, screen, 10, None),
            Get::Ready(Ok(_))
        ));
        assert_eq!(views.made().0, 1);
    }

    #[test]
    fn the_viewing_scale_makes_the_brightest_unclipped_dn_white_and_clips_red() {
        let dn = [0u16, 100, 349, 1023, 1023, 50];
        let img = viewing((1, 7), (3, 2), &dn, 1023, planes(&dn, 6)).unwrap();
        let s = img.scale.unwrap();
        assert_eq!((s.white_dn, s.clipped_px, s.clip_dn), (349, 2, 1023));
        let decoder = png::Decoder::new(std::io::Cursor::new(img.png.to_vec()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        assert_eq!(&buf[..9], &[0, 0, 0, 73, 73, 73, 255, 255, 255]);
        assert_eq!(&buf[9..12], &[255, 0, 64]);
    }
}
