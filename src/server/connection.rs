//! One client connection, TCP or serial: reads messages (binary frames, or JSON lines when a
//! TCP client's first byte is `{`), answers each, records each, and hands poses to the frame
//! pipeline. A bad message gets an `error` and the connection stays usable; a client that does
//! not read loses its own messages (counted), never the daemon's memory; a vanished client
//! only ends its own connection.

use super::frames::Job;
use super::protocol::{
    self, Decoded, Decoder, ErrorCode, MAX_INBOUND_PAYLOAD, MAX_JSON_LINE, Message, PoseMsg,
    ProtocolError,
};
use super::{Outbound, RuntimePatch, Shared};
use crate::geometry::body_from_camera_wxyz;
use crate::scene::Pose;
use glam::DVec3;
use std::sync::Arc;
use std::time::Instant;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;

/// Messages waiting for a client before newer ones are dropped: acks and errors (tens of
/// bytes) up to 4096, about 40 s of a 100 Hz stream whose writer is starved, so a busy machine
/// loses none; camera frames (a 1024^2 one is 2 MiB) only while fewer than 16 messages wait,
/// which bounds a non-reading subscriber's cost ([`crate::server::Outbound::send`]).
const OUTBOUND_QUEUE: usize = 4096;

/// Accepts pose connections until shutdown.
pub async fn accept(listener: TcpListener, shared: Arc<Shared>) {
    let mut stop = shared.shutdown.clone();
    loop {
        tokio::select! {
            r = listener.accept() => match r {
                Ok((stream, peer)) => {
                    let _ = stream.set_nodelay(true);
                    tokio::spawn(serve(stream, format!("tcp:{peer}"), Wire::Sniff, shared.clone()));
                }
                Err(e) => {
                    tracing::warn!("accept: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                }
            },
            _ = stop.changed() => break,
        }
    }
}

/// How a connection's bytes are framed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    Binary,
    Json,
    /// Decided by the first byte: `{` is JSON lines, anything else binary.
    Sniff,
}

/// Serves one connection until it closes or the daemon stops.
pub async fn serve<S>(stream: S, peer: String, wire: Wire, shared: Arc<Shared>)
where
    S: AsyncRead + AsyncWrite + Send + 'static,
{
    let (mut rd, mut wr) = tokio::io::split(stream);
    let (out, mut outbound) = shared.outbound(OUTBOUND_QUEUE);
    shared.stats.clients.inc();
    tracing::info!(%peer, "client connected");
    let mut wire = wire;
    let (wire_tx, mut wire_rx) = tokio::sync::watch::channel(wire);
    // The writer: encodes in the connection's wire format.
    let writer = tokio::spawn(async move {
        while let Some(m) = outbound.recv().await {
            let w = *wire_rx.borrow_and_update();
            let bytes = match w {
                Wire::Json => protocol::encode_json(&m),
                _ => m.encode(),
            };
            if wr.write_all(&bytes).await.is_err() {
                break; // the client vanished
            }
        }
        let _ = wr.shutdown().await;
    });

    // A serial line is a cable on the bench; a TCP client shows the token when one is set.
    let authenticated = peer.starts_with("serial:") || !shared.access.requires_token();
    let mut conn = Conn {
        shared: shared.clone(),
        out: out.clone(),
        peer: peer.clone(),
        authenticated,
        closing: false,
    };
    let mut decoder = Decoder::new(MAX_INBOUND_PAYLOAD);
    let mut line = Vec::new();
    let mut skipping_line = false;
    let mut buf = vec![0u8; 16 * 1024];
    let mut stop = shared.shutdown.clone();
    loop {
        let n = tokio::select! {
            r = rd.read(&mut buf) => match r {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            },
            _ = stop.changed() => break,
        };
        let bytes = &buf[..n];
        if wire == Wire::Sniff {
            let first = bytes.iter().find(|b| !b.is_ascii_whitespace());
            if let Some(&b) = first {
                wire = if b == b'{' { Wire::Json } else { Wire::Binary };
                let _ = wire_tx.send(wire);
            }
        }
        match wire {
            Wire::Json => {
                for &b in bytes {
                    if b == b'\n' {
                        if !skipping_line && !conn.closing {
                            let text = String::from_utf8_lossy(&line).into_owned();
                            if !text.trim().is_empty() {
                                conn.json_line(&text);
                            }
                        }
                        line.clear();
                        skipping_line = false;
                    } else if !skipping_line {
                        line.push(b);
                        if line.len() > MAX_JSON_LINE {
                            conn.error(ProtocolError::new(
                                ErrorCode::TooLong,
                                format!("JSON line longer than {MAX_JSON_LINE} bytes skipped"),
                            ));
                            line.clear();
                            skipping_line = true;
                        }
                    }
                }
            }
            _ => {
                decoder.push(bytes);
                while !conn.closing {
                    match decoder.next_message() {
                        Decoded::Message(m) => conn.message(m),
                        Decoded::Error(e) => conn.error(e),
                        Decoded::NeedMore => break,
                    }
                }
            }
        }
        if conn.closing {
            tracing::warn!(%peer, "connection closed: no valid access token");
            break;
        }
    }
    // A refused connection's unread bytes are nobody's business.
    if !conn.closing
        && let Some(e) = decoder.finish()
    {
        conn.error(e);
    }
    if !conn.closing && !line.is_empty() && !skipping_line {
        conn.error(ProtocolError::new(
            ErrorCode::Truncated,
            format!("the stream ended inside a JSON line ({} bytes)", line.len()),
        ));
    }
    shared.subscribe(&out, false);
    drop(conn);
    drop(out);
    // The writer ends once every queued message (acks of frames still rendering included)
    // is written or the client is gone.
    let _ = tokio::time::timeout(std::time::Duration::from_secs(5), writer).await;
    shared.stats.clients.dec();
    tracing::info!(%peer, "client disconnected");
}

/// A connection's message handling.
struct Conn {
    shared: Arc<Shared>,
    out: Outbound,
    peer: String,
    /// Whether the connection may do more than say hello ([`super::access`]).
    authenticated: bool,
    /// Set when the connection is to be closed (after its answers are written).
    closing: bool,
}

impl Conn {
    fn json_line(&mut self, text: &str) {
        match protocol::decode_json(text) {
            Ok(m) => self.message(m),
            Err(e) => self.error(e),
        }
    }

    fn error(&mut self, e: ProtocolError) {
        self.shared.stats.protocol_errors.inc();
        tracing::debug!(peer = %self.peer, "bad message: {e}");
        if let Some(r) = &self.shared.recorder {
            r.error(&self.peer, self.shared.ns(Instant::now()), &e);
        }
        self.out.send(Message::from(e));
    }

    /// Refuses the connection: an `unauthorized` error, then it closes.
    fn refuse(&mut self, message: &str) {
        self.error(ProtocolError::new(ErrorCode::Unauthorized, message));
        self.closing = true;
    }

    fn message(&mut self, m: Message) {
        let received = Instant::now();
        if let Some(r) = &self.shared.recorder {
            match &m {
                // The token stays out of the recording.
                Message::Hello {
                    version_min,
                    version_max,
                    client,
                    token: Some(_),
                } => r.message(
                    &self.peer,
                    self.shared.ns(received),
                    &Message::Hello {
                        version_min: *version_min,
                        version_max: *version_max,
                        client: client.clone(),
                        token: Some("<redacted>".into()),
                    },
                ),
                m => r.message(&self.peer, self.shared.ns(received), m),
            }
        }
        if !self.authenticated && !matches!(m, Message::Hello { .. }) {
            return self.refuse(
                "this daemon asks for an access token: send hello with it before anything else",
            );
        }
        match m {
            Message::Hello {
                version_min,
                version_max,
                client,
                token,
            } => {
                if !self.shared.access.token_ok(token.as_deref()) {
                    return self.refuse("hello: the access token is missing or wrong");
                }
                self.authenticated = true;
                if !(version_min..=version_max).contains(&protocol::VERSION) {
                    return self.error(ProtocolError::new(
                        ErrorCode::BadVersion,
                        format!(
                            "client {client:?} speaks versions {version_min}-{version_max}; \
                             this daemon speaks {}",
                            protocol::VERSION
                        ),
                    ));
                }
                let mode = crate::config::spelled(&self.shared.runtime().mode);
                self.out.send(Message::HelloAck {
                    version: protocol::VERSION,
                    server: format!("optistim {}", env!("CARGO_PKG_VERSION")),
                    mode,
                });
            }
            Message::Pose(p) => {
                self.shared.stats.poses_received.inc();
                let frame_id = p.frame_id;
                let (pose, exposure_s) = match to_pose(&p) {
                    Ok(x) => x,
                    Err(mut e) => {
                        e.frame_id = Some(frame_id);
                        return self.error(e);
                    }
                };
                let bodies = match to_bodies(&p) {
                    Ok(b) => b,
                    Err(mut e) => {
                        e.frame_id = Some(frame_id);
                        return self.error(e);
                    }
                };
                let job = Job {
                    pose,
                    exposure_s,
                    bodies,
                    received,
                    reply: self.out.clone(),
                    products: None,
                };
                if let Err(e) = submit(&self.shared, job) {
                    self.error(e);
                }
            }
            Message::Config { json } => {
                let patch: Result<RuntimePatch, _> = serde_json::from_str(&json);
                // A new scene is loaded and built here: off the worker's async duties.
                let applied = tokio::task::block_in_place(|| {
                    patch
                        .map_err(|e| e.to_string())
                        .and_then(|p| self.shared.apply(p))
                });
                match applied {
                    Ok(r) => self.out.send(Message::ConfigAck {
                        json: serde_json::to_string(&r).unwrap_or_default(),
                    }),
                    Err(e) => self.error(ProtocolError::new(
                        ErrorCode::BadConfig,
                        format!("config {json}: {e}"),
                    )),
                }
            }
            Message::Subscribe { camera } => self.shared.subscribe(&self.out, camera),
            Message::Trigger => self
                .shared
                .intake
                .control(super::frames::Control::Trigger(self.out.clone())),
            other => self.error(ProtocolError::new(
                ErrorCode::UnknownType,
                format!(
                    "message type {:#04x} goes from the daemon to clients, not back",
                    other.kind()
                ),
            )),
        }
    }
}

/// Hands a pose to the frame thread in the daemon's mode; the poses it replaces (free-running)
/// are acked `dropped`.
pub fn submit(shared: &Shared, job: Job) -> Result<(), ProtocolError> {
    for d in shared.intake.push(job, shared.runtime().mode)? {
        shared.stats.poses_dropped.inc();
        d.reply.send(Message::Ack(protocol::AckMsg::dropped(
            d.pose.frame_id,
            shared.ns(d.received),
        )));
    }
    Ok(())
}

/// A unit quaternion (within 1e-6 of unit norm, then normalised) as a rotation; `name`
/// names it in the error.
fn unit_quat(name: &str, q: [f64; 4]) -> Result<glam::DQuat, ProtocolError> {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !q.iter().all(|x| x.is_finite()) || (n - 1.0).abs() > 1e-6 {
        return Err(ProtocolError::new(
            ErrorCode::BadValue,
            format!("{name} {q:?} has norm {n}, not 1 (within 1e-6)"),
        ));
    }
    Ok(body_from_camera_wxyz(q.map(|x| x / n)))
}

/// The rotation from the pose's world frame into the first body's frame.
fn body_from_world(p: &PoseMsg) -> Result<glam::DQuat, ProtocolError> {
    Ok(match p.body_attitude_wxyz {
        Some(q) => unit_quat("body_attitude_wxyz", q)?.inverse(),
        None => glam::DQuat::IDENTITY,
    })
}

/// The further bodies of a pose message in the first body's frame: each centre [m] and the
/// rotation from its frame into the first body's; `None` when the pose leaves them be.
pub fn to_bodies(p: &PoseMsg) -> Result<Option<Vec<(DVec3, glam::DQuat)>>, ProtocolError> {
    let Some(bodies) = &p.bodies else {
        return Ok(None);
    };
    let b_from_w = body_from_world(p)?;
    bodies
        .iter()
        .enumerate()
        .map(|(k, b)| {
            if !b.position_m.iter().all(|x| x.is_finite()) {
                return Err(ProtocolError::new(
                    ErrorCode::BadValue,
                    format!("bodies[{k}].position_m {:?} is not finite", b.position_m),
                ));
            }
            let q = unit_quat(&format!("bodies[{k}].attitude_wxyz"), b.attitude_wxyz)?;
            Ok((b_from_w * DVec3::from_array(b.position_m), b_from_w * q))
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// A pose message as the renderer's pose, and its exposure: every value finite, unit
/// quaternions (within 1e-6, then normalised), a positive exposure.
pub fn to_pose(p: &PoseMsg) -> Result<(Pose, Option<f64>), ProtocolError> {
    let bad = |m: String| ProtocolError::new(ErrorCode::BadValue, m);
    let finite = |name: &str, v: &[f64]| {
        if v.iter().all(|x| x.is_finite()) {
            Ok(())
        } else {
            Err(bad(format!("{name} {v:?} is not finite")))
        }
    };
    finite("time_tag_s", &[p.time_tag_s])?;
    finite("camera_position_m", &p.camera_position_m)?;
    finite("attitude_wxyz", &p.attitude_wxyz)?;
    finite("sun_position_m", &p.sun_position_m)?;
    let unit = |name: &str, q: [f64; 4]| {
        let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        if (n - 1.0).abs() > 1e-6 {
            Err(bad(format!(
                "{name} {q:?} has norm {n}, not 1 (within 1e-6)"
            )))
        } else {
            Ok(body_from_camera_wxyz(q.map(|x| x / n)))
        }
    };
    let world_from_camera = unit("attitude_wxyz", p.attitude_wxyz)?;
    let body_from_world = body_from_world(p)?;
    if let Some(e) = p.exposure_s
        && !(e.is_finite() && e > 0.0)
    {
        return Err(bad(format!("exposure_s {e} must be positive and finite")));
    }
    Ok((
        Pose {
            frame_id: p.frame_id,
            camera_position_m: body_from_world * DVec3::from_array(p.camera_position_m),
            body_from_camera: body_from_world * world_from_camera,
            sun_position_m: body_from_world * DVec3::from_array(p.sun_position_m),
        },
        p.exposure_s,
    ))
}
