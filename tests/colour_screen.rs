//! The stimulator chain in colour (issue 17): a camera of three bands looks at an RGB screen
//! whose primaries each excite every band. The rendered colour image -> each band's F_eff ->
//! per pixel the primaries solved through the cross-talk matrix -> R, G, B codes -> the
//! simulated colour camera's image of the screen, compared band by band with the image the
//! camera would take in space.

mod common;
use optistim::config::{self, Config};
use optistim::detector::noise::Noise;
use optistim::detector::{Detector, Layout};
use optistim::render::Renderer;
use optistim::stimulator::Stimulator;
use optistim::stimulator::calibrate::{Provenance, SimulatedBench, calibrate};
use optistim::stimulator::calibration::{Curve, Interp};
use optistim::stimulator::camera::SimulatedCamera;
use std::path::PathBuf;
use std::sync::Arc;

/// `config/stimulator_rgb.toml` (the red Moon at 20,000 km, an RGGB camera, an RGB screen at
/// 10 bit), noise off so that the comparison sees the chain.
fn moon_on_colour_screen() -> Config {
    let mut cfg = config::load(&PathBuf::from("config/stimulator_rgb.toml")).unwrap();
    cfg.scene.camera.detector.noise = Noise::default();
    cfg
}

fn example() -> Curve {
    Curve::load(&PathBuf::from("calibration/example_rgb.csv"), Interp::Pchip).unwrap()
}

/// The example with its `# crosstalk` lines replaced by `rows` (band, values).
fn with_crosstalk(rows: &[(&str, [f64; 3])]) -> Curve {
    let text = std::fs::read_to_string("calibration/example_rgb.csv").unwrap();
    let mut out: String = text
        .lines()
        .filter(|l| !l.starts_with("# crosstalk"))
        .map(|l| format!("{l}\n"))
        .collect();
    let at = out.find("dn,").unwrap();
    let lines: String = rows
        .iter()
        .map(|(b, r)| format!("# crosstalk {b}: {}, {}, {}\n", r[0], r[1], r[2]))
        .collect();
    out.insert_str(at, &lines);
    Curve::parse(out.as_bytes(), "edited", "<edited>", Interp::Pchip)
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Per band: total (DN - offset) camera / direct - 1 and the median per-pixel relative
/// difference over the band's lit pixels (at least 100 electrons in the direct image).
struct Comparison {
    total: [f64; 3],
    median: [f64; 3],
    lit: [usize; 3],
}

impl Comparison {
    fn passes(&self) -> bool {
        (0..3).all(|b| self.total[b].abs() < 0.01 && self.median[b] < 0.02)
    }

    fn assert_passes(&self) {
        assert!(
            self.passes(),
            "total {:?} median {:?}",
            self.total,
            self.median
        );
    }
}

/// The band pixel `i` of a `width`-pixel-wide frame of `dn` records.
fn band_of(det: &Detector, i: usize, width: usize, n: usize) -> usize {
    match det.layout {
        Layout::Planes => i / n,
        Layout::Bayer(order) => order.band_at(i % width, i / width),
    }
}

/// Renders the colour scene, shows it on the screen through `calibration`, and images the
/// screen with the simulated camera whose screen truly responds as `truth`.
fn compare(cfg: &Config, calibration: Curve, truth: Curve) -> Comparison {
    let det = &cfg.scene.camera.detector;
    let intr = &cfg.scene.camera.intrinsics;
    let st = cfg.stimulator.as_ref().unwrap();
    let frame = Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let factors = cfg.scene.band_factors();
    let (signal, direct) = det.image(|b| frame.band(b), (w, h), &factors, 0);
    assert_eq!(signal.len(), 3 * w * h);

    let stim = Stimulator::with_curve(st, intr, det, Arc::new(calibration)).unwrap();
    let shown = stim.process(&signal).unwrap();
    assert_eq!(shown.screen_dn.len(), 3 * st.screen_px[0] * st.screen_px[1]);
    eprintln!("clips {:?}", shown.clips);
    let camera = SimulatedCamera::new(st, truth, intr, det).unwrap();
    let seen = camera.capture(&shown.screen_dn, 0).unwrap();
    assert_eq!(seen.dn.len(), direct.len());

    let off = det.offset_dn;
    let lit_dn = 100.0 * det.adc_gain_dn_per_e;
    let (mut sum_d, mut sum_c) = ([0.0; 3], [0.0; 3]);
    let mut rel: [Vec<f64>; 3] = Default::default();
    for (i, (&d, &c)) in direct.iter().zip(&seen.dn).enumerate() {
        let b = band_of(det, i, w, w * h);
        let (d, c) = (d as f64 - off, c as f64 - off);
        sum_d[b] += d;
        sum_c[b] += c;
        if d >= lit_dn {
            rel[b].push(((c - d) / d).abs());
        }
    }
    let cmp = Comparison {
        total: [0, 1, 2].map(|b| sum_c[b] / sum_d[b] - 1.0),
        median: [0, 1, 2].map(|b| {
            rel[b].sort_by(f64::total_cmp);
            rel[b][rel[b].len() / 2]
        }),
        lit: [0, 1, 2].map(|b| rel[b].len()),
    };
    for (b, band) in det.bands.iter().enumerate() {
        eprintln!(
            "{}: total (DN - offset) camera/direct - 1 = {:+.3e}, median |diff| on {} lit px = {:.3e}",
            band.name, cmp.total[b], cmp.lit[b], cmp.median[b]
        );
    }
    cmp
}

#[test]
fn the_colour_camera_sees_on_the_colour_screen_what_it_would_see_in_space() {
    let cfg = moon_on_colour_screen();
    assert!(matches!(cfg.scene.camera.detector.layout, Layout::Bayer(_)));
    let cmp = compare(&cfg, example(), example());
    assert!(cmp.lit.iter().all(|&n| n > 20_000), "{:?}", cmp.lit);
    cmp.assert_passes();
    // The same camera with a full image per band (three chips).
    let mut planes = cfg.clone();
    planes.scene.camera.detector.layout = Layout::Planes;
    let cmp = compare(&planes, example(), example());
    assert!(cmp.lit.iter().all(|&n| n > 100_000), "{:?}", cmp.lit);
    cmp.assert_passes();
}

/// The screen's primaries excite the other bands as the example's matrix says, but the
/// calibration claims no cross-talk (or a matrix off by a fifth): the same comparison fails.
#[test]
fn a_wrong_crosstalk_matrix_is_caught_by_the_same_comparison() {
    let cfg = moon_on_colour_screen();
    let identity = with_crosstalk(&[
        ("R", [1.0, 0.0, 0.0]),
        ("G", [0.0, 1.0, 0.0]),
        ("B", [0.0, 0.0, 1.0]),
    ]);
    let cmp = compare(&cfg, identity, example());
    assert!(
        !cmp.passes(),
        "no cross-talk passed: {:?} {:?}",
        cmp.total,
        cmp.median
    );
    let off = with_crosstalk(&[
        ("R", [1.0, 0.0921, 0.0364]),
        ("G", [0.2609 * 0.8, 1.0, 0.2704 * 0.8]),
        ("B", [0.0733, 0.3843, 1.0]),
    ]);
    let cmp = compare(&cfg, off, example());
    assert!(
        !cmp.passes(),
        "a matrix off by 20 % passed: {:?} {:?}",
        cmp.total,
        cmp.median
    );
}

/// `optistim calibrate`'s ramp, one primary at a time, on the simulated colour bench
/// recovers each primary's curve and the cross-talk matrix (noise on: the config's).
#[test]
fn calibrating_the_colour_screen_recovers_its_curves_and_crosstalk() {
    let cfg = config::load(&PathBuf::from("config/stimulator_rgb.toml")).unwrap();
    let det = &cfg.scene.camera.detector;
    let intr = &cfg.scene.camera.intrinsics;
    let st = cfg.stimulator.as_ref().unwrap();
    let truth = example();
    let camera = SimulatedCamera::new(st, truth.clone(), intr, det).unwrap();
    let mut bench = SimulatedBench::new(camera, st.screen_px);
    let run = calibrate(
        &mut bench,
        st.levels(),
        17,
        Interp::Pchip,
        Provenance {
            date: "2026-11-24",
            facility: "test",
        },
    )
    .unwrap();
    let mut worst_x = 0.0f64;
    for (band, row) in &run.crosstalk {
        let want = &truth.crosstalk.iter().find(|(b, _)| b == band).unwrap().1;
        for c in 0..3 {
            worst_x = worst_x.max((row[c] - want[c]).abs());
        }
    }
    let top = (st.levels() - 1) as f64;
    let mut worst = 0.0f64;
    for p in &run.points {
        let f = truth.feff_at(p.primary, p.code as f64 / top * truth.dn_full_scale);
        worst = worst.max((p.feff_w_m2 / f - 1.0).abs());
    }
    eprintln!(
        "cross-talk: worst |measured - true| {worst_x:.2e}; curves at the ramp codes: {worst:.2e}; \
         half-way residual max {:.2e}",
        run.max_abs_residual
    );
    assert_eq!(run.crosstalk.len(), 3);
    assert!(worst_x < 2e-3, "{worst_x}");
    assert!(worst < 5e-3, "{worst}");
    assert!(run.max_abs_residual < 0.03, "{}", run.max_abs_residual);
    // The written file is a valid colour curve with its cross-talk, and it drives the chain.
    let measured = Curve::parse(run.csv.as_bytes(), "m", "<m>", Interp::Pchip).unwrap();
    assert_eq!(measured.channels(), 3);
    let mut quiet = cfg.clone();
    quiet.scene.camera.detector.noise = Noise::default();
    let cmp = compare(&quiet, measured, example());
    cmp.assert_passes();
}

/// A colour a screen cannot show: a band lit with its neighbours dark needs negative
/// primaries (the cross-talk lights the neighbours); those pixels are clipped to the dark
/// code and counted, never wrapped or dropped.
#[test]
fn colours_outside_the_gamut_are_clipped_and_counted() {
    let cfg = moon_on_colour_screen();
    let det = &cfg.scene.camera.detector;
    let intr = &cfg.scene.camera.intrinsics;
    let st = cfg.stimulator.as_ref().unwrap();
    let stim = Stimulator::with_curve(st, intr, det, Arc::new(example())).unwrap();
    let n = (intr.width_px * intr.height_px) as usize;
    // The G band alone at a tenth of its screen's range over the first 1000 pixels.
    let mut signal = vec![0.0; 3 * n];
    let g = 1e-6 / stim.ks()[1];
    signal[n..n + 1000].fill(g);
    let frame = stim.process(&signal).unwrap();
    assert_eq!(frame.clips.below_dark, 1000);
    assert_eq!(frame.clips.black as usize, n - 1000);
    assert_eq!(frame.clips.above_max, 0);
}

/// A colour camera needs the cross-talk of each of its bands: a curve that lacks one is
/// refused by name.
#[test]
fn a_colour_curve_without_a_band_s_crosstalk_is_refused() {
    let cfg = moon_on_colour_screen();
    let st = cfg.stimulator.as_ref().unwrap();
    let cam = &cfg.scene.camera;
    let partial = with_crosstalk(&[("R", [1.0, 0.1, 0.0]), ("G", [0.1, 1.0, 0.1])]);
    let err = Stimulator::with_curve(st, &cam.intrinsics, &cam.detector, Arc::new(partial))
        .err()
        .expect("refused")
        .to_string();
    assert!(err.contains("crosstalk B"), "{err}");
}

/// The daemon drives the colour camera on the colour screen (off-screen on the GPU adapter):
/// poses in lockstep are presented, subscribers get the simulated camera's raw mosaic, and
/// the dashboard's images are in colour (the screen's codes an RGB PNG, the camera's view a
/// cell-wise RGB view of its mosaic). Needs `../shared/trajectories/` beside the checkout.
#[test]
fn the_daemon_drives_a_colour_camera_on_a_colour_screen() {
    use common::{Client, http, start_daemon};
    use optistim::server::frames::{Mode, PresenterChoice};
    use optistim::server::protocol::Message;
    use std::time::Duration;
    let text = std::fs::read_to_string("config/stimulator_rgb.toml")
        .unwrap()
        .replace("\"../calibration/", "\"calibration/");
    let daemon = start_daemon(
        &text,
        PresenterChoice::Offscreen,
        Mode::Lockstep,
        None,
        None,
    );
    eprintln!("presenter: {}", daemon.presenter());
    let mut sub = Client::connect(daemon.tcp_addr);
    sub.send(&Message::Subscribe { camera: true });
    std::thread::sleep(Duration::from_millis(200));

    let mut poses = optistim::app::replay::read_poses(std::path::Path::new(
        "../shared/trajectories/nrho_2orbits.csv",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    poses.truncate(3);
    let s = std::net::TcpStream::connect(daemon.tcp_addr).unwrap();
    let (r, w): (
        Box<dyn std::io::Read + Send>,
        Box<dyn std::io::Write + Send>,
    ) = (Box::new(s.try_clone().unwrap()), Box::new(s));
    let run =
        optistim::app::replay::stream(r, w, &poses, 5.0, Mode::Lockstep, "tcp", None).unwrap();
    assert_eq!(run.acked, 3, "{:?}", run.error_messages);

    let (mut frames, mut red, mut blue) = (0, 0.0, 0.0);
    let order = optistim::detector::Bayer::Rggb;
    while let Some(m) = sub.recv(Duration::from_secs(2)) {
        if let Message::CameraFrame {
            width, height, dn, ..
        } = m
        {
            assert_eq!((width, height, dn.len()), (1024, 1024, 1024 * 1024));
            for (i, &v) in dn.iter().enumerate() {
                match order.band_at(i % 1024, i / 1024) {
                    0 => red += v as f64,
                    2 => blue += v as f64,
                    _ => {}
                }
            }
            frames += 1;
        }
    }
    assert_eq!(frames, 3);
    assert!(red != blue && red > 0.0, "R {red} B {blue}");

    let decode = |bytes: &[u8]| {
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes.to_vec()))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        (info.color_type, info.bit_depth, buf)
    };
    // /status says what the camera frames hold.
    let (code, body) = http(daemon.http_addr, "GET", "/status", b"");
    assert_eq!(code, 200);
    let status: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(
        status["camera"],
        serde_json::json!({"bands": ["R", "G", "B"], "mosaic": "RGGB"})
    );
    let (code, body) = http(daemon.http_addr, "GET", "/frame/latest.png", b"");
    assert_eq!(code, 200);
    let (colour, depth, _) = decode(&body);
    assert_eq!(
        (colour, depth),
        (png::ColorType::Rgb, png::BitDepth::Sixteen)
    );
    let (code, body) = http(daemon.http_addr, "GET", "/camera/view.png", b"");
    assert_eq!(code, 200);
    let (colour, _, rgb) = decode(&body);
    assert_eq!(colour, png::ColorType::Rgb);
    assert!(
        rgb.chunks(3).any(|p| p[0] != p[2]),
        "the camera's view shows colour"
    );
    let (code, body) = http(daemon.http_addr, "GET", "/camera/latest.png", b"");
    assert_eq!(code, 200);
    let (colour, _, _) = decode(&body);
    assert_eq!(colour, png::ColorType::Grayscale, "the raw mosaic");
    // A grey curve cannot drive this camera: refused, the colour one stays; a colour one is
    // replayed.
    let grey = std::fs::read("calibration/example_gamma22.csv").unwrap();
    let (code, body) = http(daemon.http_addr, "PUT", "/calibration", &grey);
    let text = String::from_utf8_lossy(&body);
    assert_eq!(code, 422, "{text}");
    assert!(text.contains("1 F_eff columns"), "{text}");
    let rgb = std::fs::read("calibration/example_rgb.csv").unwrap();
    let (code, body) = http(daemon.http_addr, "PUT", "/calibration", &rgb);
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    daemon.shutdown();
}
