//! `optistim replay FILE --rate HZ --to ADDR`: a GNC-simulator stand-in. Streams a pose file
//! (a trajectory CSV or JSONL of `../shared/trajectories/`, or a daemon recording) to a
//! daemon over TCP or a serial line with the binary protocol, and reports what came back.
//!
//! Lockstep: each pose waits for its ack (at most the rate). Free-running: poses go out at the
//! rate whatever comes back; the daemon drops stale ones and says so in their acks.

use super::AppError;
use crate::server::frames::Mode;
use crate::server::protocol::{AckStatus, Decoded, Decoder, Message, PoseMsg, VERSION};
use serde::Serialize;
use std::collections::HashMap;
use std::io::{Read, Write};
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// How long to wait for an ack before counting the pose as lost.
const ACK_TIMEOUT: Duration = Duration::from_secs(30);

#[derive(Debug, Default, Serialize)]
pub struct Latency {
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

/// What came back.
#[derive(Debug, Default, Serialize)]
pub struct ReplayReport {
    pub to: String,
    pub mode: Mode,
    pub rate_hz: f64,
    pub sent: usize,
    /// Acks with status presented.
    pub acked: usize,
    pub dropped: usize,
    pub errors: usize,
    /// Poses with no answer at all.
    pub lost: usize,
    /// Presented acks that came in frame-id order.
    pub in_order: bool,
    /// Frames presented more than once.
    pub presented_twice: usize,
    /// Client side: pose sent -> presented ack received [ms].
    pub latency_ms: Latency,
    /// Daemon side: pose received -> presented [ms], from the acks' time stamps.
    pub daemon_latency_ms: Latency,
    /// The same per presented frame, in the order the acks came.
    #[serde(skip)]
    pub daemon_latencies_ms: Vec<f64>,
    /// Daemon side, what the latency adds to the frame's render time (queueing, presenting)
    /// [ms]: `presented - received - render_ms`.
    pub overhead_ms: Latency,
    /// The render time the acks report [ms].
    pub render_ms: Latency,
    pub elapsed_s: f64,
    /// The first few error messages.
    pub error_messages: Vec<String>,
}

/// `n` poses spread evenly over `all` (every `len / n`-th, from the first); all when fewer.
pub fn spread(all: Vec<PoseMsg>, n: usize) -> Vec<PoseMsg> {
    let step = (all.len() / n.max(1)).max(1);
    all.into_iter().step_by(step).take(n).collect()
}

/// Reads the poses of a trajectory (CSV/JSONL) or a daemon recording (JSONL with `msg`).
pub fn read_poses(path: &Path) -> Result<Vec<PoseMsg>, AppError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| AppError::Replay(format!("{}: cannot read: {e}", path.display())))?;
    let first = text.lines().find(|l| !l.trim().is_empty()).unwrap_or("");
    if path.extension().is_some_and(|e| e == "jsonl") && first.contains("\"peer\"") {
        let mut out = Vec::new();
        for (i, line) in text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
        {
            let v: serde_json::Value = serde_json::from_str(line).map_err(|e| {
                AppError::Replay(format!("{}: line {}: {e}", path.display(), i + 1))
            })?;
            if let Some(m) = v.get("msg")
                && let Ok(Message::Pose(p)) = serde_json::from_value::<Message>(m.clone())
            {
                out.push(p);
            }
        }
        return Ok(out);
    }
    Ok(crate::trajectory::read(path)?
        .into_iter()
        .map(|(t_s, p)| PoseMsg {
            frame_id: p.frame_id,
            time_tag_s: t_s,
            camera_position_m: p.camera_position_m.to_array(),
            attitude_wxyz: crate::geometry::wxyz(p.body_from_camera),
            sun_position_m: p.sun_position_m.to_array(),
            body_attitude_wxyz: None,
            exposure_s: None,
            bodies: None,
        })
        .collect())
}

/// Streams `poses` over a connection (`reader` and `writer` are its two halves).
pub fn stream(
    mut reader: Box<dyn Read + Send>,
    mut writer: Box<dyn Write + Send>,
    poses: &[PoseMsg],
    rate_hz: f64,
    mode: Mode,
    to: &str,
    token: Option<&str>,
) -> Result<ReplayReport, AppError> {
    let io = |e: std::io::Error| AppError::Replay(format!("{to}: {e}"));
    let (tx, rx) = mpsc::channel::<(Message, Instant)>();
    std::thread::spawn(move || {
        let mut d = Decoder::new(u32::MAX);
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            match reader.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => d.push(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(_) => break,
            }
            loop {
                match d.next_message() {
                    Decoded::Message(m) => {
                        if tx.send((m, Instant::now())).is_err() {
                            return;
                        }
                    }
                    Decoded::Error(_) => {}
                    Decoded::NeedMore => break,
                }
            }
        }
    });
    let recv = |timeout: Duration| rx.recv_timeout(timeout).ok();

    let hello = Message::Hello {
        version_min: VERSION,
        version_max: VERSION,
        client: "optistim replay".into(),
        token: token.map(str::to_string),
    };
    writer.write_all(&hello.encode()).map_err(io)?;
    let mode_json = serde_json::to_string(&serde_json::json!({ "mode": mode })).unwrap_or_default();
    writer
        .write_all(&Message::Config { json: mode_json }.encode())
        .map_err(io)?;
    writer.flush().map_err(io)?;
    // The hello and config answers.
    let mut answered = 0;
    while answered < 2 {
        match recv(Duration::from_secs(10)) {
            Some((Message::HelloAck { .. } | Message::ConfigAck { .. }, _)) => answered += 1,
            Some((Message::Error { message, .. }, _)) => {
                return Err(AppError::Replay(format!("{to}: refused: {message}")));
            }
            Some(_) => {}
            None => return Err(AppError::Replay(format!("{to}: no answer to hello"))),
        }
    }

    let mut t = Tally {
        r: ReplayReport {
            to: to.to_string(),
            mode,
            rate_hz,
            in_order: true,
            ..Default::default()
        },
        ..Default::default()
    };
    let period = Duration::from_secs_f64(1.0 / rate_hz.max(1e-3));
    let t0 = Instant::now();
    for (i, p) in poses.iter().enumerate() {
        // Free-running: take acks while waiting for the next slot.
        let due = t0 + period.mul_f64(i as f64);
        while let Some(left) = due.checked_duration_since(Instant::now()) {
            match recv(left) {
                Some((m, at)) => {
                    t.handle(m, at);
                }
                None => break,
            }
        }
        writer
            .write_all(&Message::Pose(p.clone()).encode())
            .map_err(io)?;
        writer.flush().map_err(io)?;
        t.sent_at.insert(p.frame_id, Instant::now());
        t.r.sent += 1;
        if mode == Mode::Lockstep {
            let deadline = Instant::now() + ACK_TIMEOUT;
            while let Some((m, at)) = recv(deadline.saturating_duration_since(Instant::now())) {
                if t.handle(m, at) == Some(p.frame_id) {
                    break;
                }
            }
        }
    }
    // The last answers.
    let deadline = Instant::now() + ACK_TIMEOUT;
    while t.answered.len() < t.sent_at.len() {
        match recv(deadline.saturating_duration_since(Instant::now())) {
            Some((m, at)) => {
                t.handle(m, at);
            }
            None => break,
        }
    }
    let mut r = t.r;
    r.lost = t
        .sent_at
        .keys()
        .filter(|f| !t.answered.contains_key(f))
        .count();
    r.elapsed_s = t0.elapsed().as_secs_f64();
    r.latency_ms = percentiles(t.lat);
    r.daemon_latencies_ms = t.dlat.clone();
    r.daemon_latency_ms = percentiles(t.dlat);
    r.overhead_ms = percentiles(t.overhead);
    r.render_ms = percentiles(t.render);
    Ok(r)
}

/// The answers so far.
#[derive(Default)]
struct Tally {
    r: ReplayReport,
    sent_at: HashMap<u64, Instant>,
    /// Frame id -> presented (true) or otherwise answered (false).
    answered: HashMap<u64, bool>,
    lat: Vec<f64>,
    dlat: Vec<f64>,
    overhead: Vec<f64>,
    render: Vec<f64>,
    last_presented: Option<u64>,
}

impl Tally {
    /// Counts one message; returns the frame id it answers.
    fn handle(&mut self, m: Message, at: Instant) -> Option<u64> {
        let r = &mut self.r;
        match m {
            Message::Ack(a) => {
                match a.status {
                    AckStatus::Presented => {
                        if self.answered.get(&a.frame_id) == Some(&true) {
                            r.presented_twice += 1;
                        }
                        self.answered.insert(a.frame_id, true);
                        r.acked += 1;
                        if self.last_presented.is_some_and(|l| a.frame_id <= l) {
                            r.in_order = false;
                        }
                        self.last_presented = Some(a.frame_id);
                        if let Some(s) = self.sent_at.get(&a.frame_id) {
                            self.lat.push((at - *s).as_secs_f64() * 1e3);
                        }
                        let d = a.presented_ns.saturating_sub(a.received_ns) as f64 * 1e-6;
                        self.dlat.push(d);
                        self.overhead.push(d - a.render_ms);
                        self.render.push(a.render_ms);
                    }
                    AckStatus::Dropped => {
                        self.answered.entry(a.frame_id).or_insert(false);
                        r.dropped += 1;
                    }
                    AckStatus::Held => {}
                }
                Some(a.frame_id)
            }
            Message::Error {
                frame_id, message, ..
            } => {
                r.errors += 1;
                if r.error_messages.len() < 10 {
                    r.error_messages.push(message);
                }
                if let Some(f) = frame_id {
                    self.answered.entry(f).or_insert(false);
                }
                frame_id
            }
            _ => None,
        }
    }
}

fn percentiles(mut v: Vec<f64>) -> Latency {
    let [p50, p99, max] = crate::stats::quantiles(&mut v, [0.5, 0.99, 1.0]);
    Latency { p50, p99, max }
}

/// Streams over TCP (`host:port`) or a serial line (`serial:PATH[@BAUD]`).
pub fn run(
    file: &Path,
    to: &str,
    rate_hz: f64,
    frames: Option<usize>,
    mode: Mode,
    token: Option<&str>,
) -> Result<ReplayReport, AppError> {
    let mut poses = read_poses(file)?;
    if let Some(n) = frames {
        poses.truncate(n);
    }
    if poses.is_empty() {
        return Err(AppError::Replay(format!("{}: no poses", file.display())));
    }
    let (reader, writer): (Box<dyn Read + Send>, Box<dyn Write + Send>) =
        if let Some(spec) = to.strip_prefix("serial:") {
            let (path, baud) = match spec.rsplit_once('@') {
                Some((p, b)) => (
                    p,
                    b.parse()
                        .map_err(|_| AppError::Replay(format!("{to}: baud {b:?}")))?,
                ),
                None => (spec, 115_200),
            };
            let port = serialport::new(path, baud)
                .timeout(Duration::from_millis(100))
                .open()
                .map_err(|e| AppError::Replay(format!("{to}: {e}")))?;
            let w = port
                .try_clone()
                .map_err(|e| AppError::Replay(format!("{to}: {e}")))?;
            (Box::new(port), Box::new(w))
        } else {
            let s = std::net::TcpStream::connect(to)
                .map_err(|e| AppError::Replay(format!("{to}: {e}")))?;
            let _ = s.set_nodelay(true);
            let w = s
                .try_clone()
                .map_err(|e| AppError::Replay(format!("{to}: {e}")))?;
            (Box::new(s), Box::new(w))
        };
    stream(reader, writer, &poses, rate_hz, mode, to, token)
}
