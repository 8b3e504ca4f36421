//! A real borderless fullscreen window under Xvfb: `optistim show` presents the stimulator
//! scene on monitor 0 of a 1280x1024x24 X server, with openbox as window manager (it resizes
//! the window after creation, so the surface reconfiguration and redraw are exercised), and a
//! screenshot of the root window (`xwd`) must show the CPU reference's DN at every pixel,
//! within 1 LSB. The screen runs at 8 bit, the X server's depth per channel.
//!
//! Needs `Xvfb`, `xwd` and `openbox` (`apt-get install xvfb x11-apps openbox`, which `.ci/run`
//! does); without them the test fails and says so.

mod common;
use optistim::config;
use optistim::stimulator::Stimulator;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const SCREEN: [usize; 2] = [1280, 1024];

/// Stops its child when dropped, so that a failing test leaves no X server behind: SIGTERM
/// first, which lets an X server remove its lock file and socket, then SIGKILL after 2 s.
struct Reaped(Child);
impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(2) {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Whether X display `n` can be taken: no lock file, or one naming a process that no longer
/// runs (a server killed without cleaning up, whose lock and socket are removed here so the
/// wait for the new socket cannot be fooled by the old one). A socket without a lock is
/// taken.
fn display_free(n: u32) -> bool {
    let lock = PathBuf::from(format!("/tmp/.X{n}-lock"));
    let socket = PathBuf::from(format!("/tmp/.X11-unix/X{n}"));
    match std::fs::read_to_string(&lock) {
        Ok(text) => {
            let alive = text
                .trim()
                .parse::<u32>()
                .is_ok_and(|pid| Path::new(&format!("/proc/{pid}")).exists());
            if alive {
                return false;
            }
            let _ = std::fs::remove_file(&lock);
            let _ = std::fs::remove_file(&socket);
            !lock.exists() && !socket.exists()
        }
        Err(_) => !socket.exists(),
    }
}

fn tool(name: &str) -> PathBuf {
    std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|d| d.join(name))
        .find(|p| p.is_file())
        .unwrap_or_else(|| {
            panic!("{name} not found: apt-get install xvfb x11-apps openbox (.ci/run does)")
        })
}

/// Starts Xvfb on the first free display from :91 and waits for its socket.
fn start_xvfb() -> (Reaped, String) {
    let xvfb = tool("Xvfb");
    for n in 91..120 {
        let socket = PathBuf::from(format!("/tmp/.X11-unix/X{n}"));
        if !display_free(n) {
            continue;
        }
        let screen = format!("{}x{}x24", SCREEN[0], SCREEN[1]);
        let child = Command::new(&xvfb)
            .args([
                &format!(":{n}"),
                "-screen",
                "0",
                &screen,
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start Xvfb");
        let mut x = Reaped(child);
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(20) {
            if socket.exists() {
                return (x, format!(":{n}"));
            }
            if let Ok(Some(_)) = x.0.try_wait() {
                break; // lost a race for this display: try the next
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    panic!("could not start Xvfb on any display :91-:119");
}

/// The tests of this file take X displays in turn: two Xvfb started at once on the same free
/// display number both see it free, the loser dies, and both tests would use the winner's.
static X_TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// An X server with openbox on it, and a private XDG runtime folder (`tag` names it); the
/// guard holds this file's X turn.
fn x_session(
    tag: &str,
) -> (
    std::sync::MutexGuard<'static, ()>,
    Reaped,
    String,
    Reaped,
    PathBuf,
) {
    let turn = X_TURN.lock().unwrap_or_else(|e| e.into_inner());
    let (xvfb, display) = start_xvfb();
    let xdg = std::env::temp_dir().join(format!("optistim-xdg-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&xdg).unwrap();
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&xdg, std::fs::Permissions::from_mode(0o700)).unwrap();
    }
    let wm = Reaped(
        Command::new(tool("openbox"))
            .env("DISPLAY", &display)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start openbox"),
    );
    (turn, xvfb, display, wm, xdg)
}

/// Reads an XWD dump (X11's `XWDFileHeader`, big-endian, then the colour map and the pixels)
/// of a 24/32-bit TrueColor screen: the red, green and blue channels of every pixel.
fn xwd_rgb(bytes: &[u8]) -> (usize, usize, [Vec<u8>; 3]) {
    let field = |i: usize| u32::from_be_bytes(bytes[4 * i..4 * i + 4].try_into().unwrap());
    let (header_size, width, height) = (field(0) as usize, field(4) as usize, field(5) as usize);
    let byte_order = field(7); // 0: LSB first
    let bits_per_pixel = field(11);
    let bytes_per_line = field(12) as usize;
    let masks = [field(14), field(15), field(16)];
    let ncolors = field(19) as usize;
    assert_eq!(bits_per_pixel, 32, "expected a 32-bit-per-pixel dump");
    let data = &bytes[header_size + 12 * ncolors..];
    let mut rgb: [Vec<u8>; 3] = Default::default();
    for row in data.chunks(bytes_per_line).take(height) {
        for px in row[..4 * width].chunks_exact(4) {
            let b: [u8; 4] = px.try_into().unwrap();
            let v = if byte_order == 0 {
                u32::from_le_bytes(b)
            } else {
                u32::from_be_bytes(b)
            };
            for (plane, mask) in rgb.iter_mut().zip(masks) {
                plane.push(((v & mask) >> mask.trailing_zeros()) as u8);
            }
        }
    }
    (width, height, rgb)
}

/// `config_file`'s stimulator scene on a 1280 x 1024 screen at 8 bit, rounded (no dither),
/// shown by `optistim show` fullscreen: a screenshot must show the CPU reference's codes, a
/// grey screen's in every channel, a colour screen's R, G, B in the red, green and blue
/// channels, within 1 LSB.
fn fullscreen_shows_the_expected_dn(config_file: &str, calibration: &str, tag: &str) {
    let (_turn, _xvfb, display, _wm, xdg) = x_session(tag);
    let dir = std::env::temp_dir().join(format!("optistim-window-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let absolute = std::fs::canonicalize(format!("calibration/{calibration}")).unwrap();
    let scene = std::fs::read_to_string(config_file)
        .unwrap()
        .replace("[1920, 1200]", "[1280, 1024]")
        .replace("screen_bit_depth = 10", "screen_bit_depth = 8")
        .replace("dither = \"ordered\"", "dither = \"none\"")
        .replace(
            &format!("\"../calibration/{calibration}\""),
            &format!("{:?}", absolute.display().to_string()),
        );
    let scene_path = dir.join("scene.toml");
    std::fs::write(&scene_path, scene).unwrap();
    let cfg = config::load(&scene_path).unwrap();
    let st = cfg.stimulator.clone().unwrap();
    assert_eq!(st.screen_px, SCREEN);
    let cam = &cfg.scene.camera;
    let frame = optistim::render::Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    let size = (frame.width, frame.height);
    let (signal, _) = cfg.scene.record(|b| frame.band(b), size, 0);
    let want = Stimulator::new(&st, &cam.intrinsics, &cam.detector)
        .unwrap()
        .process(&signal)
        .unwrap()
        .screen_dn;
    let n = SCREEN[0] * SCREEN[1];
    let planes = want.len() / n;

    let mut show = Reaped(
        Command::new(env!("CARGO_BIN_EXE_optistim"))
            .args(["show", scene_path.to_str().unwrap(), "--monitor", "0"])
            .args(["--seconds", "60"])
            .env("DISPLAY", &display)
            .env_remove("WAYLAND_DISPLAY")
            .env("XDG_RUNTIME_DIR", &xdg)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start optistim show"),
    );
    // Wait for the first presented frame (one JSON line per frame on stdout).
    let stdout = show.0.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let first = rx
        .recv_timeout(Duration::from_secs(120))
        .expect("optistim show presented no frame within 120 s (see its stderr above)");
    let presented: serde_json::Value = serde_json::from_str(&first).unwrap();
    assert_eq!(presented["window"], "fullscreen", "{first}");
    eprintln!("presented: {first}");

    // Screenshots until one matches: the window manager may still be placing the window.
    let t0 = Instant::now();
    let mut last = String::new();
    while t0.elapsed() < Duration::from_secs(30) {
        let shot = Command::new(tool("xwd"))
            .args(["-root", "-silent", "-display", &display])
            .output()
            .expect("run xwd");
        assert!(shot.status.success(), "xwd failed");
        let (w, h, rgb) = xwd_rgb(&shot.stdout);
        assert_eq!([w, h], SCREEN);
        let (mut equal, mut one, mut worse) = (0usize, 0usize, 0usize);
        for (c, channel) in rgb.iter().enumerate() {
            let expected = &want[(c % planes) * n..(c % planes + 1) * n];
            for (&got, &exp) in channel.iter().zip(expected) {
                match (got as i32 - exp as i32).abs() {
                    0 => equal += 1,
                    1 => one += 1,
                    _ => worse += 1,
                }
            }
        }
        last = format!("{equal} samples equal, {one} within 1 LSB, {worse} worse");
        if worse == 0 {
            eprintln!(
                "screenshot after {:.1} s: {last}",
                t0.elapsed().as_secs_f64()
            );
            // The image is there, not a black screen: the Moon's disk is lit in every channel.
            for channel in &rgb {
                assert!(channel.iter().filter(|&&v| v > 0).count() > 400_000);
            }
            let _ = std::fs::remove_dir_all(&dir);
            let _ = std::fs::remove_dir_all(&xdg);
            return;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    panic!("the screen never showed the expected DN: {last}");
}

#[test]
fn a_fullscreen_window_under_xvfb_shows_the_expected_dn() {
    fullscreen_shows_the_expected_dn("config/stimulator.toml", "example_gamma22.csv", "w");
}

/// The colour screen of `config/stimulator_rgb.toml` through the window's render pass
/// (`fs_rgb`): each primary's codes in its own channel.
#[test]
fn a_colour_screen_in_a_fullscreen_window_shows_each_primary() {
    fullscreen_shows_the_expected_dn("config/stimulator_rgb.toml", "example_rgb.csv", "c");
}

/// The daemon in window mode under Xvfb, streamed 50 NRHO poses in lockstep (automated, as a
/// bench's GNC simulator would): every pose presented in order, and the screen then shows the
/// latest frame's codes (`/frame/latest.png`) within 1 LSB.
#[test]
fn the_daemon_in_window_mode_streams_poses_in_lockstep_under_xvfb() {
    let (_turn, _xvfb, display, _wm, xdg) = x_session("d");
    let dir = std::env::temp_dir().join(format!("optistim-window-d-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = optistim::server::DEFAULT_CONFIG
        .replace("[1920, 1200]", "[1280, 1024]")
        .replace("screen_bit_depth = 10", "screen_bit_depth = 8")
        .replace("dither = \"ordered\"", "dither = \"none\"");
    let scene_path = dir.join("daemon.toml");
    std::fs::write(&scene_path, &scene).unwrap();
    let cfg = config::load(&scene_path).unwrap();
    assert_eq!(cfg.stimulator.as_ref().unwrap().screen_px, SCREEN);

    let mut serve = Reaped(
        Command::new(env!("CARGO_BIN_EXE_optistim"))
            .args(["serve", "--config", scene_path.to_str().unwrap()])
            .args(["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"])
            .args(["--present", "window", "--mode", "lockstep"])
            .env("DISPLAY", &display)
            .env_remove("WAYLAND_DISPLAY")
            .env("XDG_RUNTIME_DIR", &xdg)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start optistim serve"),
    );
    let mut lines = BufReader::new(serve.0.stdout.take().unwrap()).lines();
    let Some(Ok(line)) = lines.next() else {
        let mut err = String::new();
        if let Some(mut e) = serve.0.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut e, &mut err);
        }
        panic!(
            "the daemon stopped before serving: {:?}\n{err}",
            serve.0.wait()
        );
    };
    let first: serde_json::Value = serde_json::from_str(&line).expect("the daemon's address line");
    assert!(
        first["presenter"].as_str().unwrap().contains("window"),
        "{first}"
    );
    let addr: std::net::SocketAddr = first["listening"].as_str().unwrap().parse().unwrap();
    let http: std::net::SocketAddr = first["http"]
        .as_str()
        .unwrap()
        .trim_start_matches("http://")
        .parse()
        .unwrap();

    let all =
        optistim::app::replay::read_poses(Path::new("../shared/trajectories/nrho_2orbits.csv"))
            .unwrap();
    let poses: Vec<_> = all.into_iter().step_by(14).take(50).collect();
    let s = std::net::TcpStream::connect(addr).unwrap();
    let r = optistim::app::replay::stream(
        Box::new(s.try_clone().unwrap()),
        Box::new(s),
        &poses,
        20.0,
        optistim::server::frames::Mode::Lockstep,
        "window daemon",
        None,
    )
    .unwrap();
    eprintln!("window daemon: {}", serde_json::to_string(&r).unwrap());
    assert_eq!(
        (r.acked, r.lost, r.errors, r.dropped),
        (50, 0, 0, 0),
        "{r:?}"
    );
    assert!(r.in_order);

    // The screen shows the latest frame.
    let (code, png) = common::http(http, "GET", "/frame/latest.png", b"");
    assert_eq!(code, 200);
    let mut reader = png::Decoder::new(std::io::Cursor::new(png))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut buf).unwrap();
    let want: Vec<u16> = buf
        .chunks_exact(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect();
    let t0 = Instant::now();
    let mut last = String::new();
    while t0.elapsed() < Duration::from_secs(20) {
        let shot = Command::new(tool("xwd"))
            .args(["-root", "-silent", "-display", &display])
            .output()
            .expect("run xwd");
        let (w, h, [red, _, _]) = xwd_rgb(&shot.stdout);
        assert_eq!([w, h], SCREEN);
        let worse = red
            .iter()
            .zip(&want)
            .filter(|&(&g, &e)| (i32::from(g) - i32::from(e)).abs() > 1)
            .count();
        last = format!("{worse} px off by more than 1 LSB");
        if worse == 0 {
            assert!(want.iter().any(|&v| v > 0), "the last frame is not black");
            let _ = std::fs::remove_dir_all(&dir);
            let _ = std::fs::remove_dir_all(&xdg);
            return;
        }
        std::thread::sleep(Duration::from_millis(300));
    }
    panic!("the window does not show the latest frame: {last}");
}
