//! A SurRender-compatible endpoint (`optistim serve --surrender ADDR`, port 5151 by
//! convention): the subset of the SurRender client API a GNC loop needs, so that scripts
//! written for SurRender (`../shared/clients/surrender`, unchanged) drive optistim.
//!
//! The wire (read from `surrender_client_base.py`): each message is a Qt `QDataStream` of a
//! `QHash<QString, QVariant>`, big-endian: u32 count, then per entry a key (u32 byte length,
//! UTF-16BE; `0xFFFFFFFF` is the empty string) and a value (u32 type, u8 null flag, payload).
//! The key `""` names the command. Every command is answered by a hash whose `""` is the
//! command (with its results); a refused command is first answered by a log message
//! (`{"": "", "data": "[error] ..."}`), which the client raises as a `RuntimeError`, and the
//! connection stays. Units, frames and the image's meaning: `docs/protocol.md`, "SurRender".
//!
//! Each connection is served by its own thread with blocking I/O (never the async runtime);
//! its frames go through the frame thread, or through a renderer of its own for a camera
//! other than the scene's. The body, its reflectance and maps come from the scene the daemon runs.

use crate::config::Config;
use crate::render::Renderer;
use glam::{DQuat, DVec3};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::time::Duration;

/// The largest string or byte array a client may send [bytes].
pub const MAX_ITEM: usize = 64 << 20;
/// The most elements of a list or hash.
pub const MAX_ELEMENTS: usize = 1 << 20;
/// SurRender connections served at once (each has a thread, and maybe a renderer); more are told
/// so and closed.
pub const MAX_CONNECTIONS: usize = 16;
const MAX_DEPTH: usize = 16;

/// A `QVariant` of the types the client writes and reads.
#[derive(Clone, Debug, PartialEq)]
pub enum QVar {
    Invalid,
    Bool(bool),
    Int(i32),
    UInt(u32),
    ULongLong(u64),
    Double(f64),
    String(String),
    List(Vec<QVar>),
    Hash(Vec<(String, QVar)>),
    Bytes(Vec<u8>),
}

mod t {
    pub const INVALID: u32 = 0;
    pub const BOOL: u32 = 1;
    pub const INT: u32 = 2;
    pub const UINT: u32 = 3;
    pub const ULONGLONG: u32 = 5;
    pub const DOUBLE: u32 = 6;
    pub const MAP: u32 = 8;
    pub const LIST: u32 = 9;
    pub const STRING: u32 = 10;
    pub const BYTEARRAY: u32 = 12;
    pub const HASH: u32 = 28;
}

#[derive(Debug, thiserror::Error)]
pub enum WireError {
    #[error("connection: {0}")]
    Io(#[from] std::io::Error),
    #[error("malformed message: {0}")]
    Malformed(String),
}

impl QVar {
    fn f64(&self) -> Option<f64> {
        match *self {
            QVar::Double(x) => Some(x),
            QVar::Int(i) => Some(f64::from(i)),
            QVar::UInt(u) => Some(f64::from(u)),
            QVar::ULongLong(u) => Some(u as f64),
            _ => None,
        }
    }
    fn vec(&self) -> Option<Vec<f64>> {
        match self {
            QVar::List(l) => l.iter().map(QVar::f64).collect(),
            _ => None,
        }
    }
}

struct Reader<'a, R: Read>(&'a mut R);

impl<R: Read> Reader<'_, R> {
    fn bytes(&mut self, n: usize) -> Result<Vec<u8>, WireError> {
        if n > MAX_ITEM {
            return Err(WireError::Malformed(format!(
                "an item of {n} bytes (at most {MAX_ITEM})"
            )));
        }
        let mut b = vec![0; n];
        self.0.read_exact(&mut b)?;
        Ok(b)
    }
    fn u8(&mut self) -> Result<u8, WireError> {
        Ok(self.bytes(1)?[0])
    }
    fn u32(&mut self) -> Result<u32, WireError> {
        let b = self.bytes(4)?;
        Ok(u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Result<u64, WireError> {
        let b = self.bytes(8)?;
        Ok(u64::from_be_bytes(b.try_into().expect("8 bytes")))
    }
    fn string(&mut self) -> Result<String, WireError> {
        let n = self.u32()?;
        if n == u32::MAX {
            return Ok(String::new());
        }
        let b = self.bytes(n as usize)?;
        if b.len() % 2 != 0 {
            return Err(WireError::Malformed("a UTF-16 string of odd length".into()));
        }
        let units: Vec<u16> = b
            .chunks_exact(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]))
            .collect();
        String::from_utf16(&units).map_err(|e| WireError::Malformed(e.to_string()))
    }
    fn count(&mut self) -> Result<usize, WireError> {
        let n = self.u32()? as usize;
        if n > MAX_ELEMENTS {
            return Err(WireError::Malformed(format!("a collection of {n} items")));
        }
        Ok(n)
    }
    fn hash(&mut self, depth: usize) -> Result<Vec<(String, QVar)>, WireError> {
        let n = self.count()?;
        let mut out = Vec::with_capacity(n.min(64));
        for _ in 0..n {
            let k = self.string()?;
            out.push((k, self.value(depth + 1)?));
        }
        Ok(out)
    }
    fn value(&mut self, depth: usize) -> Result<QVar, WireError> {
        if depth > MAX_DEPTH {
            return Err(WireError::Malformed("values nested too deep".into()));
        }
        let ty = self.u32()?;
        let _null = self.u8()?;
        Ok(match ty {
            t::INVALID => QVar::Invalid,
            t::BOOL => QVar::Bool(self.u8()? != 0),
            t::INT => QVar::Int(self.u32()? as i32),
            t::UINT => QVar::UInt(self.u32()?),
            t::ULONGLONG => QVar::ULongLong(self.u64()?),
            t::DOUBLE => QVar::Double(f64::from_bits(self.u64()?)),
            t::STRING => QVar::String(self.string()?),
            t::HASH | t::MAP => QVar::Hash(self.hash(depth)?),
            t::LIST => {
                let n = self.count()?;
                let mut l = Vec::with_capacity(n.min(64));
                for _ in 0..n {
                    l.push(self.value(depth + 1)?);
                }
                QVar::List(l)
            }
            t::BYTEARRAY => {
                let n = self.u32()?;
                QVar::Bytes(if n == u32::MAX {
                    Vec::new()
                } else {
                    self.bytes(n as usize)?
                })
            }
            other => return Err(WireError::Malformed(format!("QVariant type {other}"))),
        })
    }
}

/// Reads one `QHash<QString, QVariant>` message.
pub fn read_hash(r: &mut impl Read) -> Result<Vec<(String, QVar)>, WireError> {
    Reader(r).hash(0)
}

fn put_string(out: &mut Vec<u8>, s: &str) {
    if s.is_empty() {
        out.extend_from_slice(&u32::MAX.to_be_bytes());
        return;
    }
    let units: Vec<u16> = s.encode_utf16().collect();
    out.extend_from_slice(&((units.len() * 2) as u32).to_be_bytes());
    for u in units {
        out.extend_from_slice(&u.to_be_bytes());
    }
}

fn put_value(out: &mut Vec<u8>, v: &QVar) {
    let head = |out: &mut Vec<u8>, ty: u32| {
        out.extend_from_slice(&ty.to_be_bytes());
        out.push(0);
    };
    match v {
        QVar::Invalid => head(out, t::INVALID),
        QVar::Bool(b) => {
            head(out, t::BOOL);
            out.push(u8::from(*b));
        }
        QVar::Int(i) => {
            head(out, t::INT);
            out.extend_from_slice(&i.to_be_bytes());
        }
        QVar::UInt(u) => {
            head(out, t::UINT);
            out.extend_from_slice(&u.to_be_bytes());
        }
        QVar::ULongLong(u) => {
            head(out, t::ULONGLONG);
            out.extend_from_slice(&u.to_be_bytes());
        }
        QVar::Double(x) => {
            head(out, t::DOUBLE);
            out.extend_from_slice(&x.to_bits().to_be_bytes());
        }
        QVar::String(s) => {
            head(out, t::STRING);
            put_string(out, s);
        }
        QVar::List(l) => {
            head(out, t::LIST);
            out.extend_from_slice(&(l.len() as u32).to_be_bytes());
            for x in l {
                put_value(out, x);
            }
        }
        QVar::Hash(h) => {
            head(out, t::HASH);
            put_hash(out, h);
        }
        QVar::Bytes(b) => {
            head(out, t::BYTEARRAY);
            if b.is_empty() {
                out.extend_from_slice(&u32::MAX.to_be_bytes());
            } else {
                out.extend_from_slice(&(b.len() as u32).to_be_bytes());
                out.extend_from_slice(b);
            }
        }
    }
}

fn put_hash(out: &mut Vec<u8>, h: &[(String, QVar)]) {
    out.extend_from_slice(&(h.len() as u32).to_be_bytes());
    for (k, v) in h {
        put_string(out, k);
        put_value(out, v);
    }
}

/// One message as bytes.
pub fn encode_hash(h: &[(String, QVar)]) -> Vec<u8> {
    let mut out = Vec::new();
    put_hash(&mut out, h);
    out
}

/// Quaternion component order (`setConventions`' `quaternion_convention`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum QuaternionOrder {
    /// 0: `x, y, z, w`.
    XyzScalar,
    /// 1: `w, x, y, z`.
    ScalarXyz,
}

/// The camera frame's axes (`camera_convention`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum CameraAxes {
    /// 0: X right, Y up, the boresight along -Z (OpenGL).
    ZBackward,
    /// 1: X right, Y down, the boresight along +Z (optistim's own, `docs/conventions.md`).
    ZFrontward,
}

/// What a client has set; world frame positions [m], attitudes object -> world.
#[derive(Clone, Debug, serde::Serialize)]
struct State {
    quaternion: QuaternionOrder,
    camera_axes: CameraAxes,
    camera_position_m: [f64; 3],
    camera_attitude_wxyz: [f64; 4],
    sun_position_m: [f64; 3],
    body_position_m: [f64; 3],
    body_attitude_wxyz: [f64; 4],
    fov_rad: [f64; 2],
    image_px: [u32; 2],
    integration_time_s: f64,
    /// The Sun's total radiant intensity [W/sr] when set (`setSunPower`).
    sun_power_w_sr: Option<f64>,
    compression_level: i32,
    frames_rendered: u64,
}

/// The last rendered frame.
struct Rendered {
    w: usize,
    h: usize,
    power_w: Vec<f64>,
    /// `(P/L)` scaled for the Sun's power set, for the DN images (made when asked: the
    /// detector's noises cost more than the render of a small body).
    pl_scaled: Vec<f64>,
}

/// One client's session.
pub struct Session {
    config: Config,
    /// The frame thread, when the session runs in the daemon: frames of the stimulator's own
    /// camera are presented on the screen.
    link: Option<super::CompatLink>,
    /// The last render's scene and pose (for the depth map, computed when asked).
    last_config: Option<Config>,
    /// A warning for the client, sent before the answer of the call that raised it.
    warning: Option<String>,
    body_name: String,
    state: State,
    /// For frames rendered here (another camera than the scene's, or no frame thread): made
    /// on the first such frame.
    renderer: Option<Renderer>,
    last: Option<Rendered>,
}

/// The version string `version` answers.
pub fn version() -> String {
    format!(
        "optistim {} (SurRender client protocol subset)",
        env!("CARGO_PKG_VERSION")
    )
}

impl Session {
    /// A session; with `link`, frames of the scene's own camera go through the frame thread
    /// and onto the stimulator's screen.
    pub fn new(config: &Config, link: Option<super::CompatLink>) -> Session {
        let c = &config.scene.camera.intrinsics;
        let (fu, fv) = c.focal_px();
        let fov = |n: u32, f: f64| 2.0 * (f64::from(n) / 2.0 / f).atan();
        let q = |q: DQuat| [q.w, q.x, q.y, q.z];
        Session {
            body_name: config.scene.body.name.clone(),
            state: State {
                quaternion: QuaternionOrder::XyzScalar,
                camera_axes: CameraAxes::ZBackward,
                camera_position_m: config.pose.camera_position_m.to_array(),
                camera_attitude_wxyz: q(config.pose.body_from_camera),
                sun_position_m: config.pose.sun_position_m.to_array(),
                body_position_m: [0.0; 3],
                body_attitude_wxyz: [1.0, 0.0, 0.0, 0.0],
                fov_rad: [fov(c.width_px, fu), fov(c.height_px, fv)],
                image_px: [c.width_px, c.height_px],
                integration_time_s: config.scene.camera.detector.exposure_s,
                sun_power_w_sr: None,
                compression_level: 0,
                frames_rendered: 0,
            },
            renderer: None,
            config: config.clone(),
            link,
            last_config: None,
            warning: None,
            last: None,
        }
    }

    /// Answers one message: the bytes to send back.
    pub fn handle(&mut self, msg: &[(String, QVar)]) -> Vec<u8> {
        let cmd = match field(msg, "") {
            Some(QVar::String(s)) => s.clone(),
            _ => String::new(),
        };
        let mut out = Vec::new();
        let log = |out: &mut Vec<u8>, text: String| {
            put_hash(
                out,
                &[
                    (String::new(), QVar::String(String::new())),
                    ("data".into(), QVar::Bytes(text.into_bytes())),
                ],
            );
        };
        match self.command(&cmd, msg) {
            Ok(mut fields) => {
                if let Some(w) = self.warning.take() {
                    log(&mut out, format!("[warning] {cmd}: {w}\n"));
                }
                fields.insert(0, (String::new(), QVar::String(cmd)));
                put_hash(&mut out, &fields);
            }
            Err(e) => {
                tracing::debug!(command = %cmd, "SurRender call refused: {e}");
                let name = if cmd.is_empty() { "?" } else { &cmd };
                log(&mut out, format!("[error] {name}: {e}\n"));
                put_hash(&mut out, &[(String::new(), QVar::String(cmd))]);
            }
        }
        out
    }

    fn command(
        &mut self,
        cmd: &str,
        msg: &[(String, QVar)],
    ) -> Result<Vec<(String, QVar)>, String> {
        let get = |k: &str| field(msg, k);
        let num = |k: &str| {
            get(k)
                .and_then(QVar::f64)
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{k}: a finite number is needed"))
        };
        let vec = |k: &str, n: usize| {
            get(k)
                .and_then(QVar::vec)
                .filter(|v| v.len() == n && v.iter().all(|x| x.is_finite()))
                .ok_or_else(|| format!("{k}: {n} finite numbers are needed"))
        };
        let s = &mut self.state;
        let none = Vec::new();
        match cmd {
            "" => Err("a message without a command (its \"\" key)".into()),
            "version" => Ok(vec![("version".into(), QVar::String(version()))]),
            "close" => Ok(none),
            "setConventions" => {
                s.quaternion = match num("quaternion_convention")? as i64 {
                    0 => QuaternionOrder::XyzScalar,
                    1 => QuaternionOrder::ScalarXyz,
                    v => return Err(format!("quaternion_convention {v}: 0 (XYZ_SCALAR) or 1")),
                };
                s.camera_axes = match num("camera_convention")? as i64 {
                    0 => CameraAxes::ZBackward,
                    1 => CameraAxes::ZFrontward,
                    v => return Err(format!("camera_convention {v}: 0 (Z_BACKWARD) or 1")),
                };
                Ok(none)
            }
            "getConventions" => Ok(vec![(
                "conventions".into(),
                QVar::List(vec![
                    QVar::Int(s.quaternion as i32),
                    QVar::Int(s.camera_axes as i32),
                ]),
            )]),
            "setObjectPosition" => {
                let p = vec("pos", 3)?;
                let p = [p[0], p[1], p[2]];
                match object(msg, &self.body_name)? {
                    Object::Camera => s.camera_position_m = p,
                    Object::Sun => s.sun_position_m = p,
                    Object::Body => s.body_position_m = p,
                }
                Ok(none)
            }
            "setObjectAttitude" => {
                let q = vec("attitude", 4)?;
                let wxyz = match s.quaternion {
                    QuaternionOrder::XyzScalar => [q[3], q[0], q[1], q[2]],
                    QuaternionOrder::ScalarXyz => [q[0], q[1], q[2], q[3]],
                };
                let n = wxyz.iter().map(|x| x * x).sum::<f64>().sqrt();
                if (n - 1.0).abs() > 1e-6 {
                    return Err(format!("attitude {q:?} has norm {n}, not 1 (within 1e-6)"));
                }
                let wxyz = wxyz.map(|x| x / n);
                match object(msg, &self.body_name)? {
                    Object::Camera => {
                        // Stored for optistim's camera axes.
                        let q = crate::geometry::body_from_camera_wxyz(wxyz);
                        let q = match s.camera_axes {
                            CameraAxes::ZFrontward => q,
                            CameraAxes::ZBackward => q * flip(),
                        };
                        s.camera_attitude_wxyz = [q.w, q.x, q.y, q.z];
                    }
                    Object::Sun => {}
                    Object::Body => s.body_attitude_wxyz = wxyz,
                }
                Ok(none)
            }
            "setCameraFOVDeg" | "setCameraFOVRad" => {
                let k = if cmd == "setCameraFOVDeg" {
                    std::f64::consts::PI / 180.0
                } else {
                    1.0
                };
                let fov = [num("fov_x")? * k, num("fov_y")? * k];
                if fov.iter().any(|&f| !(f > 0.0 && f < std::f64::consts::PI)) {
                    return Err(format!("fov {fov:?} rad: each in (0, pi)"));
                }
                s.fov_rad = fov;
                Ok(none)
            }
            "getCameraFOVDeg" | "getCameraFOVRad" => {
                let k = if cmd == "getCameraFOVDeg" {
                    180.0 / std::f64::consts::PI
                } else {
                    1.0
                };
                Ok(vec![(
                    "fov".into(),
                    QVar::List(vec![
                        QVar::Double(s.fov_rad[0] * k),
                        QVar::Double(s.fov_rad[1] * k),
                    ]),
                )])
            }
            "setImageSize" => {
                let (w, h) = (num("width")?, num("height")?);
                if !(1.0..=16384.0).contains(&w) || !(1.0..=16384.0).contains(&h) {
                    return Err(format!("{w} x {h} px: each side in 1..16384"));
                }
                s.image_px = [w as u32, h as u32];
                Ok(none)
            }
            "getImageSize" => Ok(vec![(
                "size".into(),
                QVar::List(vec![
                    QVar::Int(s.image_px[0] as i32),
                    QVar::Int(s.image_px[1] as i32),
                ]),
            )]),
            "setIntegrationTime" => {
                let t = num("integration_time")?;
                if t <= 0.0 {
                    return Err(format!("integration_time {t} s: must be > 0"));
                }
                s.integration_time_s = t;
                Ok(none)
            }
            "getIntegrationTime" => Ok(vec![(
                "integration_time".into(),
                QVar::Double(s.integration_time_s),
            )]),
            "setSunPower" => {
                let p = get("sun_color")
                    .and_then(QVar::vec)
                    .filter(|v| !v.is_empty() && v.iter().all(|x| x.is_finite() && *x >= 0.0))
                    .ok_or("sun_color: one or more finite, non-negative numbers [W/sr]")?;
                s.sun_power_w_sr = Some(p.iter().sum());
                Ok(none)
            }
            "setCompressionLevel" => {
                let l = num("compression_level")?;
                if !(0.0..=9.0).contains(&l) {
                    return Err(format!("compression_level {l}: 0 to 9"));
                }
                s.compression_level = l as i32;
                Ok(none)
            }
            "getState" => Ok(vec![(
                "state".into(),
                QVar::String(serde_json::to_string(&*s).unwrap_or_default()),
            )]),
            "render" => {
                self.warning = self.render()?;
                Ok(none)
            }
            "getImage" | "getImageGray32F" | "getImageRGBA8" | "getImageGray8" | "getDepthMap" => {
                self.image(cmd)
            }
            other => Err(format!(
                "{other} is not served by optistim's SurRender endpoint (it serves version, \
                 setConventions, setObjectPosition / Attitude for camera, sun and {:?}, \
                 setCameraFOVDeg / Rad, setImageSize, setSunPower, setIntegrationTime, \
                 setCompressionLevel, render, getImage and its Gray32F / RGBA8 / Gray8 and \
                 depth variants, getState and their getters); the body, its reflectance and \
                 maps come from the scene file the daemon runs (docs/protocol.md)",
                self.body_name
            )),
        }
    }

    /// The scene of the daemon with the session's camera and pose.
    fn frame_config(&self) -> Result<Config, String> {
        let s = &self.state;
        let mut c = self.config.clone();
        let i = &mut c.scene.camera.intrinsics;
        let [w, h] = s.image_px;
        let (fu, fv) = i.focal_px();
        let own_fov =
            |n: u32, f: f64, fov: f64| (2.0 * (f64::from(n) / 2.0 / f).atan() - fov).abs();
        let own = [w, h] == [i.width_px, i.height_px]
            && own_fov(w, fu, s.fov_rad[0]) < 1e-9
            && own_fov(h, fv, s.fov_rad[1]) < 1e-9;
        // The scene's own camera stays exactly as it is (it is the one the stimulator's chain
        // is calibrated for); another size or field of view makes a pinhole camera.
        if !own {
            // Square pixels: the pitch stays, the focal length follows the horizontal FOV.
            let f_px = f64::from(w) / 2.0 / (s.fov_rad[0] / 2.0).tan();
            let fov_y = 2.0 * (f64::from(h) / 2.0 / f_px).atan();
            if (fov_y - s.fov_rad[1]).abs() > 1e-6 * s.fov_rad[1].max(1.0) {
                return Err(format!(
                    "fov_y {:.6} deg does not match a {w} x {h} px image of square pixels with \
                     fov_x {:.6} deg (it would be {:.6} deg)",
                    s.fov_rad[1].to_degrees(),
                    s.fov_rad[0].to_degrees(),
                    fov_y.to_degrees()
                ));
            }
            i.width_px = w;
            i.height_px = h;
            i.focal_length_m = f_px * i.pixel_pitch_m[0];
            i.pixel_pitch_m[1] = i.pixel_pitch_m[0];
            i.principal_point_px = [f64::from(w) / 2.0, f64::from(h) / 2.0];
            i.distortion = Default::default();
        }
        c.scene.camera.detector.exposure_s = s.integration_time_s;
        let body_from_world = DQuat::from_xyzw(
            s.body_attitude_wxyz[1],
            s.body_attitude_wxyz[2],
            s.body_attitude_wxyz[3],
            s.body_attitude_wxyz[0],
        )
        .inverse();
        let b = DVec3::from_array(s.body_position_m);
        let q = s.camera_attitude_wxyz;
        c.pose = crate::scene::Pose {
            frame_id: s.frames_rendered,
            camera_position_m: body_from_world * (DVec3::from_array(s.camera_position_m) - b),
            body_from_camera: body_from_world * DQuat::from_xyzw(q[1], q[2], q[3], q[0]),
            sun_position_m: body_from_world * (DVec3::from_array(s.sun_position_m) - b),
        };
        Ok(c)
    }

    /// Renders the session's pose: through the frame thread (and onto the screen) when the
    /// camera is the scene's own, else here for the client only (with a warning).
    fn render(&mut self) -> Result<Option<String>, String> {
        let c = self.frame_config()?;
        let own_camera = c.scene.camera.intrinsics == self.config.scene.camera.intrinsics;
        let mut warning = None;
        let pl = match (&mut self.link, own_camera) {
            (Some(link), true) => link.present(c.pose, Some(self.state.integration_time_s))?,
            (link, _) => {
                if link.is_some() {
                    warning = Some(
                        "the image size or field of view differs from the stimulator's camera: \
                         rendered for the client, not presented on the screen"
                            .to_string(),
                    );
                }
                let renderer = match &mut self.renderer {
                    Some(r) => r,
                    None => self
                        .renderer
                        .insert(Renderer::new(c.settings.threads).map_err(|e| e.to_string())?),
                };
                crate::app::render::frame(&c, &c.pose, renderer)
                    .map_err(|e| e.to_string())?
                    .pl
            }
        };
        let sun = &c.scene.sun;
        let scale = self
            .state
            .sun_power_w_sr
            .map_or(1.0, |p| p / (sun.radiance_integral(None) * sun.area_m2()));
        let radiance = sun.radiance_integral(c.power_band_m) * scale;
        let power_w = pl.iter().map(|x| x * radiance).collect();
        let pl_scaled: Vec<f64> = pl.iter().map(|x| x * scale).collect();
        let (w, h) = (
            c.scene.camera.intrinsics.width_px as usize,
            c.scene.camera.intrinsics.height_px as usize,
        );
        self.last = Some(Rendered {
            w,
            h,
            power_w,
            pl_scaled,
        });
        self.last_config = Some(c);
        self.state.frames_rendered += 1;
        Ok(warning)
    }

    fn image(&self, cmd: &str) -> Result<Vec<(String, QVar)>, String> {
        let r = self
            .last
            .as_ref()
            .ok_or("no image rendered yet: call render first")?;
        let (w, h) = (r.w, r.h);
        let dn8 = || -> Result<Vec<u8>, String> {
            let c = self.last_config.as_ref().ok_or("no image rendered yet")?;
            let det = &c.scene.camera.detector;
            let dn = c
                .scene
                .record_dn(|_| &r.pl_scaled[..], (w, h), c.pose.frame_id);
            let shift = det.saved_bits.saturating_sub(8);
            Ok(dn.iter().map(|&d| (d >> shift).min(255) as u8).collect())
        };
        // The client flips rows (np.flipud): rows go bottom-up.
        let rows = |i: usize| {
            (0..h)
                .rev()
                .flat_map(move |y| (0..w).map(move |x| (y * w + x) * i))
        };
        let mut data = Vec::new();
        let key = match cmd {
            "getImage" => {
                for i in rows(1) {
                    let p = r.power_w[i] as f32;
                    for v in [p, p, p, 1.0f32] {
                        data.extend_from_slice(&v.to_ne_bytes());
                    }
                }
                "image_data"
            }
            "getImageGray32F" => {
                for i in rows(1) {
                    data.extend_from_slice(&(r.power_w[i] as f32).to_ne_bytes());
                }
                "image_data"
            }
            "getImageRGBA8" => {
                let dn8 = dn8()?;
                for i in rows(1) {
                    let g = dn8[i];
                    data.extend_from_slice(&[g, g, g, 255]);
                }
                "image_data"
            }
            "getImageGray8" => {
                let dn8 = dn8()?;
                data.extend(rows(1).map(|i| dn8[i]));
                "image_data"
            }
            _ => {
                // The range along each pixel's line of sight, computed when asked.
                let c = self.last_config.as_ref().ok_or("no image rendered yet")?;
                let body = &c.scene.body;
                let depth = crate::render::depth::depth_map(
                    &c.scene.camera.intrinsics,
                    &body.shape,
                    body.relief.as_ref(),
                    &c.pose,
                );
                for i in rows(1) {
                    data.extend_from_slice(&depth[i].to_ne_bytes());
                }
                "depth_data"
            }
        };
        let level = self.state.compression_level;
        let compressed = level > 0;
        if compressed {
            // qCompress: the uncompressed size (u32, big-endian), then a zlib stream.
            let mut z = flate2::write::ZlibEncoder::new(
                (data.len() as u32).to_be_bytes().to_vec(),
                flate2::Compression::new(level as u32),
            );
            z.write_all(&data).map_err(|e| e.to_string())?;
            data = z.finish().map_err(|e| e.to_string())?;
        }
        Ok(vec![
            ("w".into(), QVar::Int(w as i32)),
            ("h".into(), QVar::Int(h as i32)),
            ("compressed".into(), QVar::Bool(compressed)),
            (key.into(), QVar::Bytes(data)),
        ])
    }
}

/// Optistim's camera axes from OpenGL's (a half turn about X).
fn flip() -> DQuat {
    DQuat::from_xyzw(1.0, 0.0, 0.0, 0.0)
}

enum Object {
    Camera,
    Sun,
    Body,
}

fn field<'a>(msg: &'a [(String, QVar)], k: &str) -> Option<&'a QVar> {
    msg.iter().find(|(key, _)| key == k).map(|(_, v)| v)
}

fn object(msg: &[(String, QVar)], body: &str) -> Result<Object, String> {
    match field(msg, "object_name") {
        Some(QVar::String(n)) if n == "camera" => Ok(Object::Camera),
        Some(QVar::String(n)) if n.eq_ignore_ascii_case("sun") => Ok(Object::Sun),
        Some(QVar::String(n)) if n == body => Ok(Object::Body),
        Some(QVar::String(n)) => Err(format!(
            "object {n:?}: this scene has \"camera\", \"sun\" and its body {body:?}"
        )),
        _ => Err("object_name: a string is needed".into()),
    }
}

/// Accepts SurRender clients until `stop` is set; one thread per connection.
pub fn spawn(
    listener: TcpListener,
    shared: Arc<super::Shared>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    listener.set_nonblocking(true)?;
    std::thread::Builder::new()
        .name("optistim-surrender".into())
        .spawn(move || {
            let stop = shared.shutdown.clone();
            let live = Arc::new(std::sync::atomic::AtomicUsize::new(0));
            while !*stop.borrow() {
                match listener.accept() {
                    Ok((mut stream, peer)) => {
                        use std::sync::atomic::Ordering;
                        if live.fetch_add(1, Ordering::SeqCst) >= MAX_CONNECTIONS {
                            live.fetch_sub(1, Ordering::SeqCst);
                            tracing::warn!(%peer, "SurRender: {MAX_CONNECTIONS} clients already");
                            let log = format!(
                                "[error] this daemon serves {MAX_CONNECTIONS} SurRender clients \
                                 at once; the connection is closed\n"
                            );
                            let _ = stream.set_nonblocking(false);
                            let _ = stream.write_all(&encode_hash(&[
                                (String::new(), QVar::String(String::new())),
                                ("data".into(), QVar::Bytes(log.into_bytes())),
                            ]));
                            continue;
                        }
                        let (shared, done) = (shared.clone(), live.clone());
                        let spawned = std::thread::Builder::new()
                            .name("optistim-surrender-conn".into())
                            .spawn(move || {
                                serve(stream, peer.to_string(), shared);
                                done.fetch_sub(1, Ordering::SeqCst);
                            });
                        if spawned.is_err() {
                            live.fetch_sub(1, Ordering::SeqCst);
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                    Err(e) => {
                        tracing::warn!("SurRender accept: {e}");
                        std::thread::sleep(Duration::from_millis(50));
                    }
                }
            }
        })
}

fn serve(stream: TcpStream, peer: String, shared: Arc<super::Shared>) {
    let _ = stream.set_nonblocking(false);
    let _ = stream.set_nodelay(true);
    let config = shared.scene().config;
    let mut session = Session::new(&config, Some(super::CompatLink::new(shared.clone())));
    shared.stats.clients.inc();
    tracing::info!(%peer, "SurRender client connected");
    let (Ok(mut rd), mut wr) = (stream.try_clone(), stream) else {
        shared.stats.clients.dec();
        return;
    };
    let mut rd = std::io::BufReader::new(&mut rd);
    // A read times out now and then so that the connection notices shutdown; a message is
    // read whole once its first byte came.
    loop {
        if *shared.shutdown.borrow() {
            break;
        }
        let _ = rd
            .get_ref()
            .set_read_timeout(Some(Duration::from_millis(200)));
        let mut first = [0u8; 1];
        match rd.read(&mut first) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue;
            }
            Err(_) => break,
        }
        let _ = rd.get_ref().set_read_timeout(Some(Duration::from_secs(30)));
        let mut chained = (&first[..]).chain(&mut rd);
        let msg = match read_hash(&mut chained) {
            Ok(m) => m,
            Err(e) => {
                // The stream cannot be resynchronised: say why, then close.
                shared.stats.protocol_errors.inc();
                tracing::warn!(%peer, "SurRender: {e}");
                let log = format!("[error] {e}; the connection is closed\n");
                let _ = wr.write_all(&encode_hash(&[
                    (String::new(), QVar::String(String::new())),
                    ("data".into(), QVar::Bytes(log.into_bytes())),
                ]));
                break;
            }
        };
        let is_close = matches!(msg.iter().find(|(k, _)| k.is_empty()), Some((_, QVar::String(c))) if c == "close");
        let answer = session.handle(&msg);
        if wr.write_all(&answer).is_err() || is_close {
            break;
        }
    }
    shared.stats.clients.dec();
    tracing::info!(%peer, "SurRender client disconnected");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hash_round_trips_through_the_qt_wire() {
        let h = vec![
            (String::new(), QVar::String("setObjectPosition".into())),
            ("object_name".into(), QVar::String("caméra".into())),
            (
                "pos".into(),
                QVar::List(vec![QVar::Double(1.5), QVar::Int(-2), QVar::UInt(3)]),
            ),
            ("b".into(), QVar::Bool(true)),
            ("n".into(), QVar::ULongLong(1 << 40)),
            ("data".into(), QVar::Bytes(vec![1, 2, 3])),
            ("empty".into(), QVar::Bytes(vec![])),
            ("none".into(), QVar::Invalid),
            (
                "nested".into(),
                QVar::Hash(vec![("x".into(), QVar::Double(f64::MAX))]),
            ),
        ];
        let bytes = encode_hash(&h);
        assert_eq!(read_hash(&mut &bytes[..]).unwrap(), h);
        // Cut anywhere: an error, never a panic.
        for n in 0..bytes.len() {
            assert!(read_hash(&mut &bytes[..n]).is_err());
        }
    }

    #[test]
    fn hostile_sizes_are_refused_before_allocating() {
        let mut b = 1u32.to_be_bytes().to_vec();
        b.extend_from_slice(&0x7fff_fff0u32.to_be_bytes()); // a 2 GB key
        assert!(matches!(
            read_hash(&mut &b[..]),
            Err(WireError::Malformed(_))
        ));
        let b = 0xffff_fff0u32.to_be_bytes();
        assert!(read_hash(&mut &b[..]).is_err());
    }
}
