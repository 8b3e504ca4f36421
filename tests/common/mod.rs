//! Scene builders shared by the integration tests.
#![allow(dead_code)]

use optistim::config::{self, Config};
use optistim::render::Renderer;

pub const AU: f64 = 1.495978707e11;
pub const R_MOON: f64 = 1737400.0;

/// A scene TOML with a sphere of `brdf` and the given camera; `body` and `render` are extra
/// `[body]` and `[render]` text.
#[derive(Clone, Copy)]
pub struct SceneSpec<'a> {
    pub brdf: &'a str,
    pub albedo: f64,
    pub camera_m: [f64; 3],
    pub sun_m: [f64; 3],
    pub attitude: Option<[f64; 4]>,
    pub resolution: [u32; 2],
    pub pixel_m: f64,
    pub focal_m: f64,
    pub distortion: &'a str,
    pub body: &'a str,
    pub render: &'a str,
    pub noise: &'a str,
}

impl Default for SceneSpec<'_> {
    fn default() -> Self {
        SceneSpec {
            brdf: "lambert",
            albedo: 0.12,
            camera_m: [10.0 * R_MOON, 0.0, 0.0],
            sun_m: [AU, 0.0, 0.0],
            attitude: None,
            resolution: [256, 256],
            pixel_m: 5.5e-6,
            focal_m: 0.03,
            distortion: "",
            body: "",
            render: "",
            noise: "",
        }
    }
}

impl SceneSpec<'_> {
    pub fn toml(&self) -> String {
        let pose = match self.attitude {
            Some(q) => format!("attitude_wxyz = {q:?}"),
            None => "look_at_body = true".into(),
        };
        format!(
            r#"
[sun]
spectrum = "blackbody"
temperature_k = 5782.0
radius_m = 6.957e8
position_m = {sun:?}

[body]
name = "Test"
radius_m = {R_MOON}
brdf = "{brdf}"
albedo = {albedo}
albedo_type = "normal"
{body}

[camera]
resolution_px = {res:?}
pixel_pitch_m = {pix}
focal_length_m = {focal}
f_number = 2.0
exposure_s = 1e-4
full_well_e = 30000.0
adc_gain_dn_per_e = 0.1
bit_depth = 12
qe = {{ wavelength_nm = [400, 700, 1000], value = [0.5, 0.6, 0.2] }}
{distortion}

[camera.noise]
seed = 5
{noise}

[pose]
camera_position_m = {cam:?}
{pose}

[render]
{render}
"#,
            sun = self.sun_m,
            brdf = self.brdf,
            albedo = self.albedo,
            res = self.resolution,
            pix = self.pixel_m,
            focal = self.focal_m,
            distortion = self.distortion,
            body = self.body,
            noise = self.noise,
            cam = self.camera_m,
            pose = pose,
            render = self.render,
        )
    }

    /// The same scene with `body` as its extra `[body]` text.
    pub fn toml_with_body(&self, body: &str) -> String {
        SceneSpec { body, ..*self }.toml()
    }

    pub fn config(&self) -> Config {
        config::parse(&self.toml(), "<test>").unwrap_or_else(|e| panic!("{e}"))
    }
}

/// The key and value a scene text is refused with (`ConfigError::Invalid`); panics when it
/// parses, or fails otherwise. `file` places its relative map paths.
pub fn refusal(text: &str, file: &str) -> (String, String) {
    match config::parse(text, file) {
        Err(config::ConfigError::Invalid { key, value, .. }) => (key, value),
        other => panic!("expected a refused key: {:?}", other.map(|_| ())),
    }
}

/// The flight camera's signal image [e-/s] for the scene and pose of `cfg`.
pub fn rendered_signal(cfg: &Config) -> Vec<f64> {
    let det = &cfg.scene.camera.detector;
    let frame = Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    det.signal(&frame.pl, cfg.scene.signal_factor())
}

/// A daemon started in this process on free loopback ports, with `config_text` (a scene with
/// a `[stimulator]` section) and the presenter chosen.
pub fn start_daemon(
    config_text: &str,
    presenter: optistim::server::frames::PresenterChoice,
    mode: optistim::server::frames::Mode,
    serial: Option<String>,
    record: Option<std::path::PathBuf>,
) -> optistim::server::Server {
    optistim::server::Server::start(serve_options(config_text, presenter, mode, serial, record))
        .unwrap_or_else(|e| panic!("{e}"))
}

/// What [`start_daemon`] starts, for tests that change something first.
pub fn serve_options(
    config_text: &str,
    presenter: optistim::server::frames::PresenterChoice,
    mode: optistim::server::frames::Mode,
    serial: Option<String>,
    record: Option<std::path::PathBuf>,
) -> optistim::server::ServeOptions {
    let cfg = config::parse(config_text, "<test daemon>").unwrap_or_else(|e| panic!("{e}"));
    optistim::server::ServeOptions {
        config: cfg,
        config_label: "<test daemon>".into(),
        config_sha256: "test".into(),
        listen: "127.0.0.1:0".parse().unwrap(),
        http: "127.0.0.1:0".parse().unwrap(),
        serial: serial.map(|s| (s, 115_200)),
        presenter,
        mode,
        record,
        // Tests name scenes they write under the temporary folder.
        access: optistim::server::access::Access::new(None, &[std::env::temp_dir()], false)
            .unwrap(),
        surrender: None,
        corto: None,
    }
}

/// The daemon's default scene made small (a 256 x 256 camera on a 512 x 512 screen), for
/// tests that exercise the protocol rather than the picture.
pub fn small_daemon_config() -> String {
    optistim::server::DEFAULT_CONFIG
        .replace("resolution_px = [1024, 1024]", "resolution_px = [256, 256]")
        .replace(
            "screen_resolution_px = [1920, 1200]",
            "screen_resolution_px = [512, 512]",
        )
}

/// One HTTP/1.1 request with `Connection: close`: the status code and the body.
pub fn http(addr: std::net::SocketAddr, method: &str, path: &str, body: &[u8]) -> (u16, Vec<u8>) {
    http_with(addr, method, path, &[], body)
}

/// [`http`] with extra header lines (`"Authorization: Bearer ..."`).
pub fn http_with(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &[&str],
    body: &[u8],
) -> (u16, Vec<u8>) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(60)))
        .unwrap();
    let extra: String = headers.iter().map(|h| format!("{h}\r\n")).collect();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: test\r\nConnection: close\r\n{extra}Content-Length: {}\r\n\r\n",
        body.len()
    )
    .unwrap();
    s.write_all(body).unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("HTTP header");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let status: u16 = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    let mut body = raw[split + 4..].to_vec();
    if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        body = dechunk(&body);
    }
    (status, body)
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let n = usize::from_str_radix(std::str::from_utf8(&b[..eol]).unwrap().trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 2 + n + 2..];
    }
}

/// A blocking protocol client for tests: binary frames over TCP.
pub struct Client {
    pub stream: std::net::TcpStream,
    decoder: optistim::server::protocol::Decoder,
}

impl Client {
    pub fn connect(addr: std::net::SocketAddr) -> Client {
        let stream = std::net::TcpStream::connect(addr).unwrap();
        stream.set_nodelay(true).unwrap();
        Client {
            stream,
            decoder: optistim::server::protocol::Decoder::new(u32::MAX),
        }
    }

    /// A client on an existing stream (e.g. the reading half of another client).
    pub fn from_stream(stream: std::net::TcpStream) -> Client {
        Client {
            stream,
            decoder: optistim::server::protocol::Decoder::new(u32::MAX),
        }
    }

    pub fn send_raw(&mut self, bytes: &[u8]) {
        use std::io::Write;
        self.stream.write_all(bytes).unwrap();
    }

    pub fn send(&mut self, m: &optistim::server::protocol::Message) {
        self.send_raw(&m.encode());
    }

    /// The next message, or `None` after `timeout`.
    pub fn recv(
        &mut self,
        timeout: std::time::Duration,
    ) -> Option<optistim::server::protocol::Message> {
        use optistim::server::protocol::Decoded;
        use std::io::Read;
        let deadline = std::time::Instant::now() + timeout;
        loop {
            match self.decoder.next_message() {
                Decoded::Message(m) => return Some(m),
                Decoded::Error(e) => panic!("the daemon sent a bad frame: {e}"),
                Decoded::NeedMore => {}
            }
            let left = deadline.checked_duration_since(std::time::Instant::now())?;
            self.stream
                .set_read_timeout(Some(left.max(std::time::Duration::from_millis(1))))
                .unwrap();
            let mut buf = [0u8; 65536];
            match self.stream.read(&mut buf) {
                Ok(0) => return None,
                Ok(n) => self.decoder.push(&buf[..n]),
                Err(_) => return None,
            }
        }
    }
}

/// A pose the default daemon scene renders: the NRHO stream's first row.
pub fn nrho_pose(frame_id: u64) -> optistim::server::protocol::PoseMsg {
    optistim::server::protocol::PoseMsg {
        frame_id,
        time_tag_s: frame_id as f64,
        camera_position_m: [-13138330.133, 0.0, -69999778.510],
        attitude_wxyz: [
            0.704066432124,
            -0.065501596596,
            0.065501596596,
            -0.704066432124,
        ],
        sun_position_m: [-21942843927.655, -147906691958.697, -4652417884.904],
        body_attitude_wxyz: None,
        exposure_s: None,
        bodies: None,
    }
}

/// This process's resident memory [bytes] (Linux).
pub fn rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

/// A fresh folder `optistim-{tag}-{pid}` under the system's temporary folder, removed when
/// dropped (a failing test leaves nothing behind either).
pub struct TempDir(pub std::path::PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("optistim-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    pub fn join(&self, name: &str) -> std::path::PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Writes a `width` x `height` TIFF of colour type `C` (e.g. `Gray32Float`, `RGB16`) to `path`.
pub fn write_tiff<C: tiff::encoder::colortype::ColorType>(
    path: &std::path::Path,
    width: u32,
    height: u32,
    data: &[C::Inner],
) where
    [C::Inner]: tiff::encoder::TiffValue,
{
    let file = std::fs::File::create(path).unwrap();
    tiff::encoder::TiffEncoder::new(file)
        .unwrap()
        .write_image::<C>(width, height, data)
        .unwrap();
}
