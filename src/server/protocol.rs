//! The pose protocol (`docs/protocol.md`, byte by byte): binary frames for TCP and serial,
//! and a JSON-lines variant on TCP for scripts. Both carry the same [`Message`]s.
//!
//! Binary frame: `A5 5A` sync, version (u8), message type (u8), payload length (u32 LE),
//! payload (little-endian fields), CRC-32 (IEEE, u32 LE) over version, type, length and
//! payload. [`Decoder`] finds frames in a byte stream, resynchronises after garbage, a bad CRC
//! or an absurd length, and reports each problem as a [`ProtocolError`] without losing the
//! frames that follow.

use serde::{Deserialize, Serialize};

pub const SYNC: [u8; 2] = [0xA5, 0x5A];
pub const VERSION: u8 = 1;
/// Sync, version, type, length.
pub const HEADER_LEN: usize = 8;
pub const CRC_LEN: usize = 4;
/// The largest payload a client may send [bytes] (a pose is 97 to 137 bytes; a config change
/// a few hundred).
pub const MAX_INBOUND_PAYLOAD: u32 = 64 * 1024;
/// The longest JSON line a client may send [bytes].
pub const MAX_JSON_LINE: usize = 64 * 1024;

/// Message type codes: client to daemon below 0x80, daemon to client from 0x80.
pub mod kind {
    pub const HELLO: u8 = 0x01;
    pub const POSE: u8 = 0x02;
    pub const CONFIG: u8 = 0x03;
    pub const SUBSCRIBE: u8 = 0x04;
    pub const TRIGGER: u8 = 0x05;
    pub const HELLO_ACK: u8 = 0x81;
    pub const ACK: u8 = 0x82;
    pub const CONFIG_ACK: u8 = 0x83;
    pub const CAMERA_FRAME: u8 = 0x84;
    pub const ERROR: u8 = 0xEE;
}

/// Error codes of the `error` message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u16)]
pub enum ErrorCode {
    /// Bytes that are not a frame (no sync word), or a payload that does not parse.
    Malformed = 1,
    BadCrc = 2,
    /// A length beyond [`MAX_INBOUND_PAYLOAD`] or a JSON line beyond [`MAX_JSON_LINE`].
    TooLong = 3,
    UnknownType = 4,
    BadVersion = 5,
    /// A value out of its domain: NaN or infinite, a non-unit quaternion, a negative exposure.
    BadValue = 6,
    CameraInsideBody = 7,
    /// The frame could not be rendered or presented.
    Render = 8,
    /// The lockstep queue is full.
    Busy = 9,
    BadConfig = 10,
    /// The connection closed in the middle of a frame.
    Truncated = 11,
    /// The daemon is shutting down; the pose was not rendered.
    ShuttingDown = 12,
    /// The daemon asks for an access token and the connection has not given it in its
    /// `hello`; the connection is closed.
    Unauthorized = 13,
}

impl ErrorCode {
    /// The code sent as `v`; an unknown one reads as `Malformed`.
    pub fn from_u16(v: u16) -> ErrorCode {
        use ErrorCode::*;
        match v {
            2 => BadCrc,
            3 => TooLong,
            4 => UnknownType,
            5 => BadVersion,
            6 => BadValue,
            7 => CameraInsideBody,
            8 => Render,
            9 => Busy,
            10 => BadConfig,
            11 => Truncated,
            12 => ShuttingDown,
            13 => Unauthorized,
            _ => Malformed,
        }
    }
}

/// A problem with what a client sent; the connection stays usable.
#[derive(Clone, Debug, PartialEq, Serialize, thiserror::Error)]
#[error("{code:?}: {message}")]
pub struct ProtocolError {
    pub code: ErrorCode,
    pub message: String,
    /// The frame id the problem concerns, when known.
    pub frame_id: Option<u64>,
}

impl ProtocolError {
    pub fn new(code: ErrorCode, message: impl Into<String>) -> ProtocolError {
        ProtocolError {
            code,
            message: message.into(),
            frame_id: None,
        }
    }
}

/// A camera pose (`docs/protocol.md`): positions in the world frame [m], attitude scalar
/// first, camera -> world; the world frame is the body frame unless the body's attitude
/// (body -> world) is given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseMsg {
    pub frame_id: u64,
    /// The simulator's time tag [s] (echoed in the recording; not interpreted).
    pub time_tag_s: f64,
    pub camera_position_m: [f64; 3],
    pub attitude_wxyz: [f64; 4],
    pub sun_position_m: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body_attitude_wxyz: Option<[f64; 4]>,
    /// The simulated camera's exposure for this frame [s] (the scene's otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_s: Option<f64>,
    /// The scene's further bodies (`[[body]]` after the first), in order, in the world frame:
    /// each one's centre and attitude (its frame -> world). They stay where a pose last put
    /// them (where the scene file puts them before any).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bodies: Option<Vec<BodyPoseMsg>>,
}

/// Where one of the further bodies is, in the world frame of a [`PoseMsg`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyPoseMsg {
    pub position_m: [f64; 3],
    pub attitude_wxyz: [f64; 4],
}

/// What became of a pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum AckStatus {
    /// Rendered and presented.
    Presented = 0,
    /// Replaced by a newer pose before it was rendered (free-running mode).
    Dropped = 1,
    /// Rendered into the hold buffer; presented on the next trigger (a second ack follows).
    Held = 2,
}

/// The acknowledgement of one pose. Times are nanoseconds on the daemon's monotonic clock
/// since it started; 0 where a stage did not happen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AckMsg {
    pub frame_id: u64,
    pub status: AckStatus,
    pub received_ns: u64,
    pub render_start_ns: u64,
    pub render_end_ns: u64,
    pub presented_ns: u64,
    pub render_ms: f64,
    /// Pixels with no light, below the screen's dark level, above its maximum.
    pub clipped_black: u64,
    pub clipped_below_dark: u64,
    pub clipped_above_max: u64,
    pub calibration_id: String,
    /// With `fidelity = "budget"`: what the planner chose for the frame and the error it
    /// predicts (absent otherwise; in the binary payload, after the calibration id).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<AckFidelity>,
    /// With `--record`: the received messages the recording has failed to write so far
    /// (disk full, ...), absent while it has written every one (in the binary payload, a u64
    /// after the fidelity tail).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recording_failed: Option<u64>,
}

/// Bytes of the binary ack's fidelity tail.
const FIDELITY_TAIL: usize = 37;

/// The fidelity planner's choice for one frame ([`crate::fidelity::budget::Plan`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AckFidelity {
    pub points_per_pixel: f64,
    pub boundary_nodes: u8,
    /// 0 off, 1 ray marching, 2 horizon map.
    pub self_shadowing: u8,
    pub predicted_median: f64,
    pub predicted_p99: f64,
    pub predicted_total: f64,
    pub meets_budget: bool,
    /// How the albedo map was read: 0 per quadrangle's point, 1 per quadrangle's area, 2
    /// over each pixel's footprint, 3 over each pixel's footprint with the relief's shading
    /// and shadows (`MapFilter::Relief`).
    #[serde(default)]
    pub map_filter: u8,
    /// Under the relief filter, how many times finer a pixel's reads could get where they
    /// disagree (`render.relief_refine`: 1, 2, 4 or 8; 1 elsewhere).
    #[serde(default = "one")]
    pub relief_refine: u8,
}

fn one() -> u8 {
    1
}

impl AckFidelity {
    pub fn of(p: &crate::fidelity::budget::Plan) -> AckFidelity {
        use crate::render::settings::SelfShadowing;
        AckFidelity {
            points_per_pixel: p.points_per_pixel,
            boundary_nodes: p.boundary_nodes.min(255) as u8,
            self_shadowing: match p.self_shadowing {
                SelfShadowing::Off => 0,
                SelfShadowing::RayMarching => 1,
                SelfShadowing::HorizonMap => 2,
            },
            predicted_median: p.predicted.median,
            predicted_p99: p.predicted.p99,
            predicted_total: p.predicted.total,
            meets_budget: p.meets_budget,
            map_filter: match p.map_filter {
                crate::render::MapFilter::Point => 0,
                crate::render::MapFilter::Area => 1,
                crate::render::MapFilter::Pixel => 2,
                crate::render::MapFilter::Relief => 3,
            },
            relief_refine: p.relief_refine.min(255) as u8,
        }
    }
}

impl AckMsg {
    /// The ack of a pose replaced by a newer one before it was rendered.
    pub fn dropped(frame_id: u64, received_ns: u64) -> AckMsg {
        AckMsg {
            frame_id,
            status: AckStatus::Dropped,
            received_ns,
            render_start_ns: 0,
            render_end_ns: 0,
            presented_ns: 0,
            render_ms: 0.0,
            clipped_black: 0,
            clipped_below_dark: 0,
            clipped_above_max: 0,
            calibration_id: String::new(),
            fidelity: None,
            recording_failed: None,
        }
    }
}

/// Every message of the protocol, in both directions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Message {
    /// Version negotiation: the client's supported range.
    Hello {
        version_min: u8,
        version_max: u8,
        client: String,
        /// The access token, when the daemon asks for one (`serve --token-file`); a binary
        /// hello carries it as an optional trailing string. Never recorded.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        token: Option<String>,
    },
    Pose(PoseMsg),
    /// Run-time settings, a JSON object (`docs/protocol.md`: the keys of `GET /config`).
    Config {
        json: String,
    },
    /// Receive (or stop receiving) the simulated camera's image of every frame.
    Subscribe {
        camera: bool,
    },
    /// Present the frame in the hold buffer.
    Trigger,
    HelloAck {
        version: u8,
        server: String,
        mode: String,
    },
    Ack(AckMsg),
    /// The run-time settings now in force, a JSON object.
    ConfigAck {
        json: String,
    },
    /// The simulated camera's image [DN], row-major.
    CameraFrame {
        frame_id: u64,
        width: u32,
        height: u32,
        bit_depth: u8,
        dn: Vec<u16>,
    },
    Error {
        code: ErrorCode,
        frame_id: Option<u64>,
        message: String,
    },
}

impl From<ProtocolError> for Message {
    fn from(e: ProtocolError) -> Message {
        Message::Error {
            code: e.code,
            frame_id: e.frame_id,
            message: e.message,
        }
    }
}

impl Message {
    /// The binary type code.
    pub fn kind(&self) -> u8 {
        match self {
            Message::Hello { .. } => kind::HELLO,
            Message::Pose(_) => kind::POSE,
            Message::Config { .. } => kind::CONFIG,
            Message::Subscribe { .. } => kind::SUBSCRIBE,
            Message::Trigger => kind::TRIGGER,
            Message::HelloAck { .. } => kind::HELLO_ACK,
            Message::Ack(_) => kind::ACK,
            Message::ConfigAck { .. } => kind::CONFIG_ACK,
            Message::CameraFrame { .. } => kind::CAMERA_FRAME,
            Message::Error { .. } => kind::ERROR,
        }
    }

    /// The message as one binary frame.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer(Vec::with_capacity(128));
        match self {
            Message::Hello {
                version_min,
                version_max,
                client,
                token,
            } => {
                w.u8(*version_min);
                w.u8(*version_max);
                w.str(client);
                if let Some(t) = token {
                    w.str(t);
                }
            }
            Message::Pose(p) => {
                w.u64(p.frame_id);
                w.f64(p.time_tag_s);
                w.f64s(&p.camera_position_m);
                w.f64s(&p.attitude_wxyz);
                w.f64s(&p.sun_position_m);
                w.u8(u8::from(p.body_attitude_wxyz.is_some())
                    | (u8::from(p.exposure_s.is_some()) << 1)
                    | (u8::from(p.bodies.is_some()) << 2));
                if let Some(q) = p.body_attitude_wxyz {
                    w.f64s(&q);
                }
                if let Some(e) = p.exposure_s {
                    w.f64(e);
                }
                if let Some(bodies) = &p.bodies {
                    // At most 255 (the encoder of a longer list sends the first 255).
                    let n = bodies.len().min(255);
                    w.u8(n as u8);
                    for b in &bodies[..n] {
                        w.f64s(&b.position_m);
                        w.f64s(&b.attitude_wxyz);
                    }
                }
            }
            Message::Config { json } | Message::ConfigAck { json } => {
                w.0.extend_from_slice(json.as_bytes())
            }
            Message::Subscribe { camera } => w.u8(u8::from(*camera)),
            Message::Trigger => {}
            Message::HelloAck {
                version,
                server,
                mode,
            } => {
                w.u8(*version);
                w.str(server);
                w.str(mode);
            }
            Message::Ack(a) => {
                w.u64(a.frame_id);
                w.u8(a.status as u8);
                for t in [
                    a.received_ns,
                    a.render_start_ns,
                    a.render_end_ns,
                    a.presented_ns,
                ] {
                    w.u64(t);
                }
                w.f64(a.render_ms);
                for c in [a.clipped_black, a.clipped_below_dark, a.clipped_above_max] {
                    w.u64(c);
                }
                w.str(&a.calibration_id);
                if let Some(f) = &a.fidelity {
                    w.f64(f.points_per_pixel);
                    w.u8(f.boundary_nodes);
                    w.u8(f.self_shadowing);
                    w.f64(f.predicted_median);
                    w.f64(f.predicted_p99);
                    w.f64(f.predicted_total);
                    w.u8(u8::from(f.meets_budget));
                    w.u8(f.map_filter);
                    w.u8(f.relief_refine);
                }
                if let Some(n) = a.recording_failed {
                    w.u64(n);
                }
            }
            Message::CameraFrame {
                frame_id,
                width,
                height,
                bit_depth,
                dn,
            } => {
                w.u64(*frame_id);
                w.u32(*width);
                w.u32(*height);
                w.u8(*bit_depth);
                // Little-endian on the wire, as read back: one copy where the host agrees.
                if cfg!(target_endian = "little") {
                    w.0.extend_from_slice(bytemuck::cast_slice(dn));
                } else {
                    dn.iter().for_each(|&x| w.u16(x));
                }
            }
            Message::Error {
                code,
                frame_id,
                message,
            } => {
                w.u16(*code as u16);
                w.u64(frame_id.map_or(u64::MAX, |f| f));
                w.str(message);
            }
        }
        frame(self.kind(), &w.0)
    }

    /// Parses the payload of a frame of type `kind`.
    pub fn decode(kind: u8, payload: &[u8]) -> Result<Message, ProtocolError> {
        let mut r = Reader { b: payload, i: 0 };
        let m = match kind {
            kind::HELLO => Message::Hello {
                version_min: r.u8()?,
                version_max: r.u8()?,
                client: r.str()?,
                token: if r.i < payload.len() {
                    Some(r.str()?)
                } else {
                    None
                },
            },
            kind::POSE => {
                let frame_id = r.u64()?;
                let time_tag_s = r.f64()?;
                let camera_position_m = r.f64s()?;
                let attitude_wxyz = r.f64s()?;
                let sun_position_m = r.f64s()?;
                let flags = r.u8()?;
                if flags & !7 != 0 {
                    return Err(malformed(format!("pose flags {flags:#04x}: only bits 0-2")));
                }
                let body_attitude_wxyz = if flags & 1 != 0 {
                    Some(r.f64s()?)
                } else {
                    None
                };
                let exposure_s = if flags & 2 != 0 { Some(r.f64()?) } else { None };
                let bodies = if flags & 4 != 0 {
                    let n = r.u8()?;
                    let mut v = Vec::with_capacity(n as usize);
                    for _ in 0..n {
                        v.push(BodyPoseMsg {
                            position_m: r.f64s()?,
                            attitude_wxyz: r.f64s()?,
                        });
                    }
                    Some(v)
                } else {
                    None
                };
                Message::Pose(PoseMsg {
                    frame_id,
                    time_tag_s,
                    camera_position_m,
                    attitude_wxyz,
                    sun_position_m,
                    body_attitude_wxyz,
                    exposure_s,
                    bodies,
                })
            }
            kind::CONFIG | kind::CONFIG_ACK => {
                let json = std::str::from_utf8(payload)
                    .map_err(|e| malformed(format!("config text is not UTF-8: {e}")))?
                    .to_string();
                r.i = payload.len();
                if kind == kind::CONFIG {
                    Message::Config { json }
                } else {
                    Message::ConfigAck { json }
                }
            }
            kind::SUBSCRIBE => Message::Subscribe {
                camera: r.u8()? & 1 != 0,
            },
            kind::TRIGGER => Message::Trigger,
            kind::HELLO_ACK => Message::HelloAck {
                version: r.u8()?,
                server: r.str()?,
                mode: r.str()?,
            },
            kind::ACK => {
                let frame_id = r.u64()?;
                let status = match r.u8()? {
                    0 => AckStatus::Presented,
                    1 => AckStatus::Dropped,
                    2 => AckStatus::Held,
                    s => return Err(malformed(format!("ack status {s}"))),
                };
                Message::Ack(AckMsg {
                    frame_id,
                    status,
                    received_ns: r.u64()?,
                    render_start_ns: r.u64()?,
                    render_end_ns: r.u64()?,
                    presented_ns: r.u64()?,
                    render_ms: r.f64()?,
                    clipped_black: r.u64()?,
                    clipped_below_dark: r.u64()?,
                    clipped_above_max: r.u64()?,
                    calibration_id: r.str()?,
                    // Optional tails, told apart by their lengths: fidelity (37 bytes),
                    // then the recording's failures (8).
                    fidelity: if payload.len() - r.i >= FIDELITY_TAIL {
                        Some(AckFidelity {
                            points_per_pixel: r.f64()?,
                            boundary_nodes: r.u8()?,
                            self_shadowing: r.u8()?,
                            predicted_median: r.f64()?,
                            predicted_p99: r.f64()?,
                            predicted_total: r.f64()?,
                            meets_budget: r.u8()? != 0,
                            map_filter: r.u8()?,
                            relief_refine: r.u8()?,
                        })
                    } else {
                        None
                    },
                    recording_failed: if r.i < payload.len() {
                        Some(r.u64()?)
                    } else {
                        None
                    },
                })
            }
            kind::CAMERA_FRAME => {
                let frame_id = r.u64()?;
                let width = r.u32()?;
                let height = r.u32()?;
                let bit_depth = r.u8()?;
                // One plane, or a camera's planes one after the other (a camera of several
                // bands with a full image per band): as many whole planes as the payload holds.
                let n = width as usize * height as usize;
                let planes = ((r.b.len() - r.i) / (2 * n).max(1)).max(1);
                let bytes = r.take(2 * n * planes)?;
                Message::CameraFrame {
                    frame_id,
                    width,
                    height,
                    bit_depth,
                    dn: bytes
                        .chunks_exact(2)
                        .map(|b| u16::from_le_bytes([b[0], b[1]]))
                        .collect(),
                }
            }
            kind::ERROR => {
                let code = ErrorCode::from_u16(r.u16()?);
                let frame_id = Some(r.u64()?).filter(|&f| f != u64::MAX);
                Message::Error {
                    code,
                    frame_id,
                    message: r.str()?,
                }
            }
            k => {
                return Err(ProtocolError::new(
                    ErrorCode::UnknownType,
                    format!("unknown message type {k:#04x}"),
                ));
            }
        };
        if r.i != payload.len() {
            return Err(malformed(format!(
                "{} bytes after the end of a {:#04x} payload",
                payload.len() - r.i,
                kind
            )));
        }
        Ok(m)
    }
}

/// One frame around `payload`.
pub fn frame(kind: u8, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len() + CRC_LEN);
    out.extend_from_slice(&SYNC);
    out.push(VERSION);
    out.push(kind);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = crc32fast::hash(&out[2..]);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

fn malformed(message: String) -> ProtocolError {
    ProtocolError::new(ErrorCode::Malformed, message)
}

struct Writer(Vec<u8>);
impl Writer {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64s(&mut self, v: &[f64]) {
        v.iter().for_each(|&x| self.f64(x));
    }
    /// u16 length, then UTF-8 bytes (cut at 65535 bytes on a character boundary).
    fn str(&mut self, s: &str) {
        let mut end = s.len().min(u16::MAX as usize);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        self.u16(end as u16);
        self.0.extend_from_slice(&s.as_bytes()[..end]);
    }
}

struct Reader<'a> {
    b: &'a [u8],
    i: usize,
}
impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], ProtocolError> {
        let end = self.i.checked_add(n).filter(|&e| e <= self.b.len());
        let Some(end) = end else {
            return Err(malformed(format!(
                "payload ends at byte {} where {n} more were expected",
                self.b.len()
            )));
        };
        let s = &self.b[self.i..end];
        self.i = end;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, ProtocolError> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, ProtocolError> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().expect("2")))
    }
    fn u32(&mut self) -> Result<u32, ProtocolError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn u64(&mut self) -> Result<u64, ProtocolError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }
    fn f64(&mut self) -> Result<f64, ProtocolError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }
    fn f64s<const N: usize>(&mut self) -> Result<[f64; N], ProtocolError> {
        let mut v = [0.0; N];
        for x in &mut v {
            *x = self.f64()?;
        }
        Ok(v)
    }
    fn str(&mut self) -> Result<String, ProtocolError> {
        let n = self.u16()? as usize;
        let b = self.take(n)?;
        String::from_utf8(b.to_vec()).map_err(|e| malformed(format!("string is not UTF-8: {e}")))
    }
}

/// Finds frames in a byte stream.
pub struct Decoder {
    buf: Vec<u8>,
    max_payload: u32,
}

/// What [`Decoder::next_message`] found.
#[derive(Debug, PartialEq)]
pub enum Decoded {
    Message(Message),
    /// A bad frame or garbage, reported; decoding goes on after it.
    Error(ProtocolError),
    /// Wait for more bytes.
    NeedMore,
}

impl Decoder {
    pub fn new(max_payload: u32) -> Decoder {
        Decoder {
            buf: Vec::new(),
            max_payload,
        }
    }

    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held that are not yet a whole frame.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// The next message or error in the bytes pushed so far.
    pub fn next_message(&mut self) -> Decoded {
        // Garbage before a sync word is skipped and reported once per run.
        let start = self.buf.windows(2).position(|w| w == SYNC);
        let skip = match start {
            Some(s) => s,
            // Keep a last byte that may be the first half of a sync word.
            None => self
                .buf
                .len()
                .saturating_sub(usize::from(self.buf.last() == Some(&SYNC[0]))),
        };
        if skip > 0 {
            self.buf.drain(..skip);
            return Decoded::Error(malformed(format!(
                "{skip} bytes that are not a frame skipped (no sync word A5 5A)"
            )));
        }
        if self.buf.len() < HEADER_LEN {
            return Decoded::NeedMore;
        }
        let version = self.buf[2];
        let kind = self.buf[3];
        let len = u32::from_le_bytes(self.buf[4..8].try_into().expect("4"));
        if version != VERSION {
            self.buf.drain(..2);
            return Decoded::Error(ProtocolError::new(
                ErrorCode::BadVersion,
                format!("frame version {version}; this daemon speaks {VERSION}"),
            ));
        }
        if len > self.max_payload {
            self.buf.drain(..2);
            return Decoded::Error(ProtocolError::new(
                ErrorCode::TooLong,
                format!(
                    "payload length {len} exceeds {} bytes (type {kind:#04x})",
                    self.max_payload
                ),
            ));
        }
        let total = HEADER_LEN + len as usize + CRC_LEN;
        if self.buf.len() < total {
            return Decoded::NeedMore;
        }
        let body = &self.buf[2..HEADER_LEN + len as usize];
        let crc = u32::from_le_bytes(self.buf[total - 4..total].try_into().expect("4"));
        let computed = crc32fast::hash(body);
        if crc != computed {
            // The length may be the corrupted field: resynchronise on the next sync word.
            self.buf.drain(..2);
            return Decoded::Error(ProtocolError::new(
                ErrorCode::BadCrc,
                format!(
                    "CRC {crc:08x} where the frame's bytes give {computed:08x} (type {kind:#04x})"
                ),
            ));
        }
        let result = Message::decode(kind, &self.buf[HEADER_LEN..HEADER_LEN + len as usize]);
        self.buf.drain(..total);
        match result {
            Ok(m) => Decoded::Message(m),
            Err(e) => Decoded::Error(e),
        }
    }

    /// At the end of the stream: an error if a frame was cut off.
    pub fn finish(&mut self) -> Option<ProtocolError> {
        let n = std::mem::take(&mut self.buf).len();
        (n > 0).then(|| {
            ProtocolError::new(
                ErrorCode::Truncated,
                format!("the stream ended inside a frame ({n} bytes held)"),
            )
        })
    }
}

/// Parses one JSON line (a [`Message`] with its `type`).
pub fn decode_json(line: &str) -> Result<Message, ProtocolError> {
    serde_json::from_str(line).map_err(|e| {
        let code = if e.to_string().contains("unknown variant") {
            ErrorCode::UnknownType
        } else {
            ErrorCode::Malformed
        };
        ProtocolError::new(code, format!("JSON message: {e}"))
    })
}

/// One JSON line, newline included.
pub fn encode_json(m: &Message) -> Vec<u8> {
    let mut v = serde_json::to_vec(m).unwrap_or_default();
    v.push(b'\n');
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> Message {
        Message::Pose(PoseMsg {
            frame_id: 7,
            time_tag_s: 1.5,
            camera_position_m: [1e7, 2.0, -3.0],
            attitude_wxyz: [1.0, 0.0, 0.0, 0.0],
            sun_position_m: [1.5e11, 0.0, 0.0],
            body_attitude_wxyz: Some([0.0, 1.0, 0.0, 0.0]),
            exposure_s: Some(1e-3),
            bodies: Some(vec![BodyPoseMsg {
                position_m: [2e7, 1.0, 0.5],
                attitude_wxyz: [0.0, 0.0, 1.0, 0.0],
            }]),
        })
    }

    #[test]
    fn every_message_round_trips_through_a_frame_and_json() {
        let msgs = vec![
            Message::Hello {
                version_min: 1,
                version_max: 1,
                client: "gnc".into(),
                token: None,
            },
            Message::Hello {
                version_min: 1,
                version_max: 2,
                client: "gnc".into(),
                token: Some("0123456789abcdef".into()),
            },
            pose(),
            Message::Config {
                json: r#"{"mode":"lockstep"}"#.into(),
            },
            Message::Subscribe { camera: true },
            Message::Trigger,
            Message::HelloAck {
                version: 1,
                server: "optistim".into(),
                mode: "free".into(),
            },
            Message::Ack(AckMsg {
                frame_id: 7,
                status: AckStatus::Presented,
                received_ns: 1,
                render_start_ns: 2,
                render_end_ns: 3,
                presented_ns: 4,
                render_ms: 12.5,
                clipped_black: 10,
                clipped_below_dark: 2,
                clipped_above_max: 0,
                calibration_id: "example".into(),
                fidelity: None,
                recording_failed: Some(3),
            }),
            Message::Ack(AckMsg {
                frame_id: 8,
                status: AckStatus::Held,
                received_ns: 1,
                render_start_ns: 2,
                render_end_ns: 3,
                presented_ns: 0,
                render_ms: 40.0,
                clipped_black: 0,
                clipped_below_dark: 0,
                clipped_above_max: 0,
                calibration_id: "example".into(),
                fidelity: Some(AckFidelity {
                    points_per_pixel: 0.5,
                    boundary_nodes: 4,
                    self_shadowing: 2,
                    predicted_median: 8e-4,
                    predicted_p99: 1.2e-2,
                    predicted_total: 3e-6,
                    meets_budget: true,
                    map_filter: 2,
                    relief_refine: 1,
                }),
                recording_failed: None,
            }),
            Message::CameraFrame {
                frame_id: 7,
                width: 2,
                height: 2,
                bit_depth: 12,
                dn: vec![1, 2, 3, 4095],
            },
            Message::Error {
                code: ErrorCode::BadCrc,
                frame_id: None,
                message: "x".into(),
            },
        ];
        let mut d = Decoder::new(u32::MAX);
        for m in &msgs {
            d.push(&m.encode());
        }
        for m in &msgs {
            assert_eq!(d.next_message(), Decoded::Message(m.clone()));
            let line = encode_json(m);
            assert_eq!(
                decode_json(std::str::from_utf8(&line).unwrap()).unwrap(),
                *m
            );
        }
        assert_eq!(d.next_message(), Decoded::NeedMore);
    }

    #[test]
    fn the_decoder_reports_bad_frames_and_finds_the_next_good_one() {
        let good = pose().encode();
        let mut bad_crc = good.clone();
        let n = bad_crc.len();
        bad_crc[n - 1] ^= 0xff;
        let mut huge = good.clone();
        huge[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        let mut unknown = frame(0x42, &[]);
        unknown.truncate(unknown.len());
        let mut d = Decoder::new(MAX_INBOUND_PAYLOAD);
        d.push(b"garbage");
        d.push(&bad_crc);
        d.push(&huge);
        d.push(&unknown);
        d.push(&good[..10]); // a frame cut short, then a good one
        d.push(&good);
        let mut codes = Vec::new();
        let mut poses = 0;
        loop {
            match d.next_message() {
                Decoded::Message(Message::Pose(_)) => poses += 1,
                Decoded::Message(m) => panic!("{m:?}"),
                Decoded::Error(e) => codes.push(e.code),
                Decoded::NeedMore => break,
            }
        }
        assert_eq!(poses, 1, "{codes:?}");
        for c in [
            ErrorCode::Malformed,
            ErrorCode::BadCrc,
            ErrorCode::TooLong,
            ErrorCode::UnknownType,
        ] {
            assert!(codes.contains(&c), "{c:?} not in {codes:?}");
        }
        assert!(d.finish().is_none());
        d.push(&good[..20]);
        assert_eq!(d.next_message(), Decoded::NeedMore);
        assert_eq!(d.finish().map(|e| e.code), Some(ErrorCode::Truncated));
    }
}
