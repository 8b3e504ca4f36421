//! Conventions (docs/conventions.md): a camera on +X_B looking at the centre with the documented
//! quaternion (0.5, -0.5, -0.5, 0.5) puts the north pole at the top of the image, and the
//! sub-solar side where it belongs, in the rendered frame and in the written files.

mod common;
use common::*;
use optistim::render::{Frame, Renderer};

const Q_DOC: [f64; 4] = [0.5, -0.5, -0.5, 0.5];

/// A camera on +X_B with the documented attitude; the Sun 1 au away along `sun_dir`.
fn config(sun_dir: [f64; 3]) -> optistim::config::Config {
    SceneSpec {
        camera_m: [20.0 * R_MOON, 0.0, 0.0],
        sun_m: sun_dir.map(|x| x * AU),
        attitude: Some(Q_DOC),
        focal_m: 0.01,
        ..Default::default()
    }
    .config()
}

fn render(sun_dir: [f64; 3]) -> (optistim::config::Config, Frame) {
    let cfg = config(sun_dir);
    let f = Renderer::new(2)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    (cfg, f)
}

const TOP: usize = 0;
const BOTTOM: usize = 1;
const LEFT: usize = 2;
const RIGHT: usize = 3;

/// Energy in the top, bottom, left and right halves of the image.
fn halves(f: &Frame) -> [f64; 4] {
    let (w, h) = (f.width, f.height);
    let mut s = [0.0; 4];
    for j in 0..h {
        for i in 0..w {
            let x = f.pl[j * w + i];
            s[if j < h / 2 { 0 } else { 1 }] += x;
            s[if i < w / 2 { 2 } else { 3 }] += x;
        }
    }
    s
}

#[test]
fn documented_quaternion_has_the_documented_axes() {
    let q = optistim::geometry::body_from_camera_wxyz(Q_DOC);
    let close = |a: glam::DVec3, b: glam::DVec3| (a - b).length() < 1e-12;
    assert!(close(q * glam::DVec3::X, glam::DVec3::Y), "X_C = +Y_B");
    assert!(close(q * glam::DVec3::Y, -glam::DVec3::Z), "Y_C = -Z_B");
    assert!(close(q * glam::DVec3::Z, -glam::DVec3::X), "Z_C = -X_B");
}

#[test]
fn north_pole_projects_to_the_top_centre() {
    let (cfg, _) = render([1.0, 0.0, 0.0]);
    let q = cfg.pose.body_from_camera;
    let north = glam::DVec3::new(0.0, 0.0, R_MOON);
    let p_cam = q.inverse() * (north - cfg.pose.camera_position_m);
    let [u, v] = cfg
        .scene
        .camera
        .intrinsics
        .project(p_cam.x, p_cam.y, p_cam.z);
    let (w, h) = (256.0, 256.0);
    assert!((u - w / 2.0).abs() < 1e-6, "u = {u}");
    assert!(
        v < h / 2.0 - 20.0,
        "north pole at v = {v}: not above the centre"
    );
}

/// With the Sun along `sun_dir`, the `lit` half holds the energy, the opposite half none,
/// and the two halves across the other axis get equal shares.
fn lights_one_half(sun_dir: [f64; 3], lit: usize, dark: usize, even: [usize; 2]) {
    let (_, f) = render(sun_dir);
    let e = halves(&f);
    assert!(e[lit] > 0.0);
    assert!(
        e[dark] < 1e-3 * e[lit],
        "lit {:e}, dark {:e}",
        e[lit],
        e[dark]
    );
    let ratio = e[even[0]] / e[even[1]];
    assert!((ratio - 1.0).abs() < 1e-3, "unbalanced halves: {e:?}");
}

#[test]
fn sun_at_north_lights_the_top_half() {
    lights_one_half([0.0, 0.0, 1.0], TOP, BOTTOM, [LEFT, RIGHT]);
}

#[test]
fn sun_at_plus_y_lights_the_right_half() {
    lights_one_half([0.0, 1.0, 0.0], RIGHT, LEFT, [TOP, BOTTOM]);
}

#[test]
fn written_files_keep_the_orientation() {
    // Through `optistim render`: the PNG's first row is the image top; the FITS reader (rows
    // stored bottom-up, ROWORDER) gives the same top-down image back.
    let cfg = config([0.0, 0.0, 1.0]);
    let dir = std::env::temp_dir().join(format!("optistim-conv-{}", std::process::id()));
    optistim::app::render::run(
        &cfg,
        "conventions",
        &dir,
        optistim::app::render::Method::Quadrangle,
    )
    .unwrap();
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(dir.join("image.png")).unwrap(),
    ));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let (w, h) = (info.width as usize, info.height as usize);
    let dn =
        |i: usize, j: usize| u16::from_be_bytes([buf[2 * (j * w + i)], buf[2 * (j * w + i) + 1]]);
    let (mut top, mut bottom) = (0u64, 0u64);
    for j in 0..h {
        for i in 0..w {
            *(if j < h / 2 { &mut top } else { &mut bottom }) += dn(i, j) as u64;
        }
    }
    assert!(top > 10 * bottom.max(1), "PNG top {top}, bottom {bottom}");

    let (fw, fh, power, header) = optistim::io::fits::read(&dir.join("power.fits")).unwrap();
    assert_eq!((fw, fh), (w, h));
    assert!(header.contains("BOTTOM_UP"));
    let top: f64 = power[..w * h / 2].iter().sum();
    let bottom: f64 = power[w * h / 2..].iter().sum();
    assert!(
        top > 0.0 && bottom < 1e-3 * top,
        "FITS top {top:e}, bottom {bottom:e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
