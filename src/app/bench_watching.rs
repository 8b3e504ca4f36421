//! `optistim bench-watching`: does watching disturb the loop? An in-process daemon (the
//! scene's `[stimulator]`, CPU presenter, lockstep) is streamed the same poses at 10 Hz in
//! rounds, alternately alone and while `clients` threads poll every HTTP endpoint; the report
//! gives the pose-to-presented latencies of both kinds and the ratio of their p99s (the bar of
//! issue 19, item 6: within 10 %), with what the pollers were served and how many images the
//! daemon made for them. Alone and watched interleave round by round, so that the machine's
//! drift hits both alike.
//!
//! The pollers stand in for operators' browsers, usually on other machines: on this one they
//! run only when the CPU is otherwise idle (Linux `SCHED_IDLE`), so what is measured is the
//! daemon's own work for them, not their CPU. On a 2-core machine 16 `SCHED_IDLE` threads
//! spinning with no HTTP at all raised the p99 by 12.6 %, hence the pause between requests.
//!
//! `tests/watching.rs` runs it for what it must never do (lose a frame, fail a request, make
//! an image more than once per frame); the latency ratio is a measurement, quoted from here.

use super::AppError;
use super::replay::{self, ReplayReport};
use crate::config::Config;
use crate::server::frames::{Mode, PresenterChoice};
use crate::server::protocol::PoseMsg;
use serde::Serialize;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

/// Every endpoint an operator's browser or a monitoring system polls.
pub const ENDPOINTS: [&str; 10] = [
    "/",
    "/health",
    "/status",
    "/metrics",
    "/frame/latest.png",
    "/frame/view.png",
    "/camera/latest.png",
    "/camera/view.png",
    "/calibration",
    "/config",
];

/// What to run.
#[derive(Debug, Clone)]
pub struct WatchingOptions {
    /// Rounds of the poses alone and watched, interleaved.
    pub rounds: usize,
    /// Polling clients.
    pub clients: usize,
    /// Each client's pause between requests [ms].
    pub poll_ms: u64,
    /// Pose rate [Hz].
    pub rate_hz: f64,
}

impl Default for WatchingOptions {
    /// As in the report that opened issue 19: 16 clients, each asking every 50 ms (twice per
    /// frame at 10 Hz, faster than any dashboard); 6 rounds.
    fn default() -> Self {
        WatchingOptions {
            rounds: 6,
            clients: 16,
            poll_ms: 50,
            rate_hz: 10.0,
        }
    }
}

/// Pose-to-presented latencies of one kind of round [ms].
#[derive(Debug, Serialize)]
pub struct Latencies {
    pub frames: usize,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    /// Each round's p99, to show the spread between rounds.
    pub p99_per_round_ms: Vec<f64>,
}

#[derive(Debug, Serialize)]
pub struct WatchingReport {
    pub scene: String,
    pub poses_per_round: usize,
    pub rounds: usize,
    pub clients: usize,
    pub poll_ms: u64,
    pub alone: Latencies,
    pub watched: Latencies,
    /// `watched.p99_ms / alone.p99_ms`: the bar is <= 1.10.
    pub p99_ratio: f64,
    /// Frames lost, answered with an error or dropped, over every round (must be 0).
    pub frames_not_presented: usize,
    /// HTTP requests answered 200, and not.
    pub requests_ok: u64,
    pub requests_failed: u64,
    /// The first failure, `endpoint -> status or error`.
    pub first_failure: Option<String>,
    pub bytes_served: u64,
    /// From `/status` at the end: frames presented, images made for viewers, simulated-camera
    /// captures, and the waits for a gap between frames that ran out.
    pub frames_presented: u64,
    pub images_made: u64,
    pub camera_captures: u64,
    pub served_during_frames: u64,
}

/// One `GET` with `Connection: close`: the status code and the body.
pub fn http_get(addr: SocketAddr, path: &str) -> std::io::Result<(u16, Vec<u8>)> {
    let mut s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(60)))?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: bench\r\nConnection: close\r\n\r\n"
    )?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw)?;
    let bad = || std::io::Error::new(std::io::ErrorKind::InvalidData, "not an HTTP answer");
    let head_end = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or_else(bad)?;
    let code = std::str::from_utf8(&raw[..head_end])
        .ok()
        .and_then(|h| h.split_whitespace().nth(1))
        .and_then(|c| c.parse().ok())
        .ok_or_else(bad)?;
    Ok((code, raw.split_off(head_end + 4)))
}

/// The calling thread runs only when the CPU is otherwise idle (Linux `SCHED_IDLE`).
fn idle_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: changes the calling thread's own scheduling policy; the parameter is read only.
    unsafe {
        let p = libc::sched_param { sched_priority: 0 };
        libc::sched_setscheduler(0, libc::SCHED_IDLE, &p);
    }
}

/// What the pollers share.
#[derive(Default)]
struct Served {
    stop: AtomicBool,
    ok: AtomicU64,
    failed: AtomicU64,
    bytes: AtomicU64,
    first_failure: std::sync::Mutex<Option<String>>,
}

fn poll(addr: SocketAddr, first: usize, poll_ms: u64, served: &Served) {
    idle_priority();
    let mut i = first;
    while !served.stop.load(Ordering::Relaxed) {
        let e = ENDPOINTS[i % ENDPOINTS.len()];
        match http_get(addr, e) {
            Ok((200, body)) => {
                served.ok.fetch_add(1, Ordering::Relaxed);
                served.bytes.fetch_add(body.len() as u64, Ordering::Relaxed);
            }
            other => {
                served.failed.fetch_add(1, Ordering::Relaxed);
                let mut f = served
                    .first_failure
                    .lock()
                    .unwrap_or_else(|p| p.into_inner());
                if f.is_none() {
                    *f = Some(match other {
                        Ok((code, _)) => format!("{e} -> {code}"),
                        Err(err) => format!("{e} -> {err}"),
                    });
                }
            }
        }
        i += 1;
        std::thread::sleep(Duration::from_millis(poll_ms));
    }
}

fn latencies(mut all: Vec<f64>, per_round: Vec<f64>) -> Latencies {
    let frames = all.len();
    let [p50_ms, p99_ms, max_ms] = crate::stats::quantiles(&mut all, [0.5, 0.99, 1.0]);
    Latencies {
        frames,
        p50_ms,
        p99_ms,
        max_ms,
        p99_per_round_ms: per_round,
    }
}

/// Runs the comparison over `poses` (in the scene's world frame, the body frame); a warm-up
/// pass first, so that first touches of buffers and maps are not the pollers' doing.
pub fn run(
    config: &Config,
    scene: &str,
    poses: &[PoseMsg],
    options: &WatchingOptions,
) -> Result<WatchingReport, AppError> {
    let loopback = "127.0.0.1:0".parse().expect("an address");
    let d = crate::server::Server::start(crate::server::ServeOptions {
        config: config.clone(),
        config_label: scene.into(),
        config_sha256: String::new(),
        listen: loopback,
        http: loopback,
        serial: None,
        presenter: PresenterChoice::Cpu,
        mode: Mode::Lockstep,
        record: None,
        access: Default::default(),
        surrender: None,
        corto: None,
    })?;
    let poses: Vec<PoseMsg> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| PoseMsg {
            frame_id: i as u64,
            ..p.clone()
        })
        .collect();
    let stream = |missing: &mut usize| -> Result<ReplayReport, AppError> {
        let io = |e: std::io::Error| AppError::Replay(format!("daemon: {e}"));
        let s = TcpStream::connect(d.tcp_addr).map_err(io)?;
        s.set_nodelay(true).map_err(io)?;
        let r = replay::stream(
            Box::new(s.try_clone().map_err(io)?),
            Box::new(s),
            &poses,
            options.rate_hz,
            Mode::Lockstep,
            "tcp",
            None,
        )?;
        *missing += r.sent - r.acked + r.lost + r.errors;
        Ok(r)
    };
    let p99 = |v: &[f64]| crate::stats::quantiles(&mut v.to_vec(), [0.99])[0];
    let mut missing = 0;
    stream(&mut missing)?;
    let (mut alone, mut watched) = (Vec::new(), Vec::new());
    let (mut round_alone, mut round_watched) = (Vec::new(), Vec::new());
    let served = Arc::new(Served::default());
    for _ in 0..options.rounds {
        let a = stream(&mut missing)?.daemon_latencies_ms;
        round_alone.push(p99(&a));
        alone.extend(a);
        served.stop.store(false, Ordering::Relaxed);
        let pollers: Vec<_> = (0..options.clients)
            .map(|k| {
                let (served, addr, ms) = (served.clone(), d.http_addr, options.poll_ms);
                std::thread::spawn(move || poll(addr, k, ms, &served))
            })
            .collect();
        // Let every poller be under way before the frames start.
        std::thread::sleep(Duration::from_millis(300));
        let w = stream(&mut missing);
        served.stop.store(true, Ordering::Relaxed);
        for p in pollers {
            let _ = p.join();
        }
        let w = w?.daemon_latencies_ms;
        round_watched.push(p99(&w));
        watched.extend(w);
    }
    let status = http_status(d.http_addr);
    d.shutdown();
    let status = status?;
    let count = |path: &[&str]| {
        path.iter()
            .try_fold(&status, |v, k| v.get(k))
            .and_then(|v| v.as_u64())
            .ok_or_else(|| AppError::Replay(format!("/status has no {}", path.join("."))))
    };
    let alone = latencies(alone, round_alone);
    let watched = latencies(watched, round_watched);
    Ok(WatchingReport {
        scene: scene.into(),
        poses_per_round: poses.len(),
        rounds: options.rounds,
        clients: options.clients,
        poll_ms: options.poll_ms,
        p99_ratio: watched.p99_ms / alone.p99_ms,
        alone,
        watched,
        frames_not_presented: missing,
        requests_ok: served.ok.load(Ordering::Relaxed),
        requests_failed: served.failed.load(Ordering::Relaxed),
        first_failure: served
            .first_failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone(),
        bytes_served: served.bytes.load(Ordering::Relaxed),
        frames_presented: count(&["frames_presented"])?,
        images_made: count(&["views", "images_made"])?,
        camera_captures: count(&["views", "camera_captures"])?,
        served_during_frames: count(&["views", "served_during_frames"])?,
    })
}

/// `/status` as JSON.
fn http_status(addr: SocketAddr) -> Result<serde_json::Value, AppError> {
    let e = |what: String| AppError::Replay(format!("/status: {what}"));
    match http_get(addr, "/status") {
        Ok((200, body)) => serde_json::from_slice(&body).map_err(|x| e(x.to_string())),
        Ok((code, _)) => Err(e(format!("status {code}"))),
        Err(x) => Err(e(x.to_string())),
    }
}
