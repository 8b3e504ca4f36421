//! The SurRender client, exactly as published (`../shared/clients/surrender`), drives
//! optistim's SurRender endpoint (issue 19, items 1 and 3): set-up, 50 NRHO poses in both
//! quaternion orders and both camera-axis conventions, image retrieval (plain and
//! compressed), depth, state, and a call optistim does not serve (a clear error; the
//! connection stays). Every image equals what the renderer gives for the same pose, as
//! `optistim render` computes it (checked through `power.fits` for two poses).
//!
//! Needs Python with NumPy < 1.24 (the client uses `np.float`): `OPTISTIM_PYTHON`, which
//! `.ci/run` points at its venv, or `python3`.

mod common;
use common::*;
use glam::DQuat;
use optistim::app::replay;
use optistim::server::frames::{Mode, PresenterChoice};
use std::path::Path;

const NRHO: &str = "../shared/trajectories/nrho_2orbits.csv";

fn python() -> String {
    std::env::var("OPTISTIM_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// Reads one array of an `.npz` (NumPy's zip of `.npy` files): shape and little-endian data.
fn npz(path: &Path, name: &str) -> (Vec<usize>, Vec<u8>, String) {
    let out = std::process::Command::new(python())
        .args([
            "-c",
            "import numpy as np,sys; a=np.load(sys.argv[1])[sys.argv[2]]; \
             sys.stdout.buffer.write((str(list(a.shape))+'|'+a.dtype.str+'|').encode()+a.tobytes())",
        ])
        .arg(path)
        .arg(name)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let b = out.stdout;
    let first = b.iter().position(|&c| c == b'|').unwrap();
    let second = first + 1 + b[first + 1..].iter().position(|&c| c == b'|').unwrap();
    let shape: Vec<usize> = serde_json::from_slice(&b[..first]).unwrap();
    let dtype = String::from_utf8_lossy(&b[first + 1..second]).into_owned();
    (shape, b[second + 1..].to_vec(), dtype)
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn the_published_surrender_client_drives_optistim_unchanged() {
    let text = small_daemon_config();
    let config = optistim::config::parse(&text, "<test>").unwrap();
    let mut o = serve_options(&text, PresenterChoice::Cpu, Mode::Free, None, None);
    o.surrender = Some("127.0.0.1:0".parse().unwrap());
    let d = optistim::server::Server::start(o).unwrap();
    let port = d.surrender_addr.unwrap().port();

    // 50 poses spread over the NRHO; every fifth in OpenGL axes, x y z w.
    let all = replay::read_poses(Path::new(NRHO)).unwrap();
    let step = all.len() / 50;
    let poses: Vec<_> = all.into_iter().step_by(step).take(50).collect();
    let flip = DQuat::from_xyzw(1.0, 0.0, 0.0, 0.0);
    let json_poses: Vec<_> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let [w, x, y, z] = p.attitude_wxyz;
            let gl = DQuat::from_xyzw(x, y, z, w) * flip;
            serde_json::json!({
                "camera_m": p.camera_position_m,
                "sun_m": p.sun_position_m,
                "q_wxyz": p.attitude_wxyz,
                "q_gl_xyzw": [gl.x, gl.y, gl.z, gl.w],
                "convention": if i % 5 == 4 { "xyz_scalar_z_back" } else { "scalar_first_z_front" },
            })
        })
        .collect();
    let cam = &config.scene.camera.intrinsics;
    let (fu, fv) = cam.focal_px();
    let fov = |n: u32, f: f64| (2.0 * (f64::from(n) / 2.0 / f).atan()).to_degrees();
    let dir = TempDir::new("surrender");
    let job = serde_json::json!({
        "width": cam.width_px,
        "height": cam.height_px,
        "fov_deg": [fov(cam.width_px, fu), fov(cam.height_px, fv)],
        "exposure_s": config.scene.camera.detector.exposure_s,
        "poses": json_poses,
    });
    std::fs::write(dir.join("poses.json"), job.to_string()).unwrap();
    let out = dir.join("out.npz");
    let run = std::process::Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/clients/surrender_drive.py"))
        .arg(port.to_string())
        .arg(dir.join("poses.json"))
        .arg(&out)
        .output()
        .unwrap_or_else(|e| panic!("{}: {e}", python()));
    assert!(
        run.status.success(),
        "the SurRender client failed (Python with NumPy < 1.24 needed: OPTISTIM_PYTHON):\n{}\n{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );

    // Every render went onto the stimulator's screen too (the client's camera is the scene's).
    assert_eq!(d.shared.stats.frames_presented.get(), 50);
    let (shape, bytes, dtype) = npz(&out, "images");
    assert_eq!(dtype, "<f4");
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    assert_eq!(shape, vec![50, h, w]);
    let images = f32s(&bytes);

    // What `optistim render` computes for each pose (app::render's path: the scene's
    // settings with depth, power = (P/L) times the Sun's radiance integral).
    let mut renderer = optistim::render::Renderer::new(config.settings.threads).unwrap();
    let mut settings = config.settings.clone();
    settings.depth = true;
    let radiance = config.scene.sun.radiance_integral(config.power_band_m);
    let mut lit_frames = 0;
    for (i, p) in poses.iter().enumerate() {
        let (mut pose, _) = optistim::server::connection::to_pose(p).unwrap();
        pose.frame_id = i as u64;
        let f = renderer.render(&config.scene, &pose, &settings).unwrap();
        let want: Vec<f32> = f.pl.iter().map(|x| (x * radiance) as f32).collect();
        let got = &images[i * w * h..(i + 1) * w * h];
        if i % 5 != 4 {
            assert!(
                got.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "pose {i}: the client's image differs from the render"
            );
        } else {
            // The OpenGL attitude went through a conversion and back (an ulp or two of the
            // quaternion): equal to float rounding.
            let top = want.iter().fold(0f32, |m, &x| m.max(x));
            let worst = got
                .iter()
                .zip(&want)
                .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(
                worst <= 1e-5 * top,
                "pose {i} (OpenGL axes): {worst} of {top}"
            );
        }
        lit_frames += usize::from(want.iter().any(|&x| x > 0.0));
    }
    assert!(lit_frames > 40, "only {lit_frames} frames show the Moon");

    // `optistim render` itself, through its power.fits, for the last pose.
    let last = poses.last().unwrap();
    let mut c = config.clone();
    let (mut pose, _) = optistim::server::connection::to_pose(last).unwrap();
    pose.frame_id = 49;
    c.pose = pose;
    let fits_dir = dir.join("render");
    optistim::app::render::run(
        &c,
        "surrender test",
        &fits_dir,
        optistim::app::render::Method::Quadrangle,
    )
    .unwrap();
    let (fw, fh, power, _) = optistim::io::fits::read(&fits_dir.join("power.fits")).unwrap();
    assert_eq!((fw, fh), (w, h));
    let got = &images[49 * w * h..];
    assert!(
        got.iter()
            .zip(&power)
            .all(|(a, b)| a.to_bits() == (*b as f32).to_bits()),
        "the last pose differs from optistim render's power.fits"
    );

    // Compressed retrieval, depth, the RGBA variant, the refusal.
    let (_, comp, _) = npz(&out, "compressed");
    assert_eq!(f32s(&comp), got, "compressed = plain");
    let (dshape, depth, ddt) = npz(&out, "depth");
    assert_eq!((dshape, ddt.as_str()), (vec![h, w], "<f8"));
    assert!(
        depth
            .chunks_exact(8)
            .any(|c| f64::from_le_bytes(c.try_into().unwrap()).is_finite())
    );
    let (rshape, _, _) = npz(&out, "rgba");
    assert_eq!(rshape, vec![h, w, 4]);
    let (_, refused, _) = npz(&out, "refused");
    let refused: String = refused
        .chunks_exact(4)
        .filter_map(|c| char::from_u32(u32::from_le_bytes(c.try_into().unwrap())))
        .collect();
    assert!(
        refused.contains("createBody") && refused.contains("scene file"),
        "{refused}"
    );
    let (_, after, _) = npz(&out, "after");
    assert_eq!(after.len(), 16, "getImageSize answered after the refusal");
    d.shutdown();
}

/// At most [`surrender::MAX_CONNECTIONS`] SurRender clients at once (each has a thread and a
/// renderer): the next is told so and closed; a freed place is taken again.
#[test]
fn surrender_connections_are_bounded() {
    use optistim::server::surrender::{self, MAX_CONNECTIONS, QVar};
    let mut o = serve_options(
        &small_daemon_config(),
        PresenterChoice::Cpu,
        Mode::Free,
        None,
        None,
    );
    o.surrender = Some("127.0.0.1:0".parse().unwrap());
    let d = optistim::server::Server::start(o).unwrap();
    let addr = d.surrender_addr.unwrap();
    let version = |s: &mut std::net::TcpStream| {
        use std::io::Write;
        s.write_all(&surrender::encode_hash(&[(
            String::new(),
            QVar::String("version".into()),
        )]))
        .unwrap();
        surrender::read_hash(s).unwrap()
    };
    let mut held: Vec<_> = (0..MAX_CONNECTIONS)
        .map(|_| {
            let mut s = std::net::TcpStream::connect(addr).unwrap();
            assert_eq!(version(&mut s)[0].1, QVar::String("version".into()));
            s
        })
        .collect();
    let mut extra = std::net::TcpStream::connect(addr).unwrap();
    let refusal = surrender::read_hash(&mut extra).unwrap();
    let text = match &refusal[1].1 {
        QVar::Bytes(b) => String::from_utf8_lossy(b).into_owned(),
        other => panic!("{other:?}"),
    };
    assert!(
        text.contains("[error]") && text.contains("clients at once"),
        "{text}"
    );
    drop(held.pop());
    let t0 = std::time::Instant::now();
    loop {
        let mut s = std::net::TcpStream::connect(addr).unwrap();
        let h = surrender::read_hash(&mut {
            use std::io::Write;
            s.write_all(&surrender::encode_hash(&[(
                String::new(),
                QVar::String("version".into()),
            )]))
            .unwrap();
            &s
        });
        if matches!(h.as_deref(), Ok([(_, QVar::String(v)), ..]) if v == "version") {
            break;
        }
        assert!(t0.elapsed().as_secs() < 10, "the freed place was not taken");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    d.shutdown();
}

/// A camera other than the scene's (another image size and field of view): rendered for the
/// client with a pinhole camera of the scene's pixel pitch, not presented, and the client is
/// warned; the image has the size asked for and equals the renderer's for that camera.
#[test]
fn another_camera_is_rendered_for_the_client_only_with_a_warning() {
    use optistim::server::surrender::{self, QVar};
    use std::io::Write;
    let text = small_daemon_config();
    let config = optistim::config::parse(&text, "<test>").unwrap();
    let mut o = serve_options(&text, PresenterChoice::Cpu, Mode::Free, None, None);
    o.surrender = Some("127.0.0.1:0".parse().unwrap());
    let d = optistim::server::Server::start(o).unwrap();
    let mut s = std::net::TcpStream::connect(d.surrender_addr.unwrap()).unwrap();
    fn send(s: &mut std::net::TcpStream, fields: Vec<(String, QVar)>) -> Vec<(String, QVar)> {
        s.write_all(&surrender::encode_hash(&fields)).unwrap();
        surrender::read_hash(s).unwrap()
    }
    let cmd = |c: &str| (String::new(), QVar::String(c.into()));
    let (w, h) = (64u32, 48u32);
    let fov_x = 20f64;
    let fov_y = (2.0 * ((f64::from(h) / f64::from(w)) * (fov_x.to_radians() / 2.0).tan()).atan())
        .to_degrees();
    send(
        &mut s,
        vec![
            cmd("setImageSize"),
            ("width".into(), QVar::Int(w as i32)),
            ("height".into(), QVar::Int(h as i32)),
        ],
    );
    send(
        &mut s,
        vec![
            cmd("setCameraFOVDeg"),
            ("fov_x".into(), QVar::Double(fov_x)),
            ("fov_y".into(), QVar::Double(fov_y)),
        ],
    );
    let warned = send(&mut s, vec![cmd("render")]);
    let text_of = |h: &[(String, QVar)]| match h.iter().find(|(k, _)| k == "data") {
        Some((_, QVar::Bytes(b))) => String::from_utf8_lossy(b).into_owned(),
        _ => String::new(),
    };
    assert!(
        text_of(&warned).contains("[warning] render") && text_of(&warned).contains("not presented"),
        "{warned:?}"
    );
    let _reply = surrender::read_hash(&mut s).unwrap();
    let img = send(&mut s, vec![cmd("getImageGray32F")]);
    let get = |k: &str| img.iter().find(|(key, _)| key == k).map(|(_, v)| v.clone());
    assert_eq!(get("w"), Some(QVar::Int(w as i32)));
    assert_eq!(get("h"), Some(QVar::Int(h as i32)));
    let Some(QVar::Bytes(data)) = get("image_data") else {
        panic!("{img:?}")
    };
    assert_eq!(data.len(), (w * h * 4) as usize);
    assert_eq!(d.shared.stats.frames_presented.get(), 0, "not presented");

    // The same camera, rendered here: pitch kept, focal length from fov_x, no distortion.
    let mut c = config.clone();
    let i = &mut c.scene.camera.intrinsics;
    let f_px = f64::from(w) / 2.0 / (fov_x.to_radians() / 2.0).tan();
    i.width_px = w;
    i.height_px = h;
    i.focal_length_m = f_px * i.pixel_pitch_m[0];
    i.pixel_pitch_m[1] = i.pixel_pitch_m[0];
    i.principal_point_px = [f64::from(w) / 2.0, f64::from(h) / 2.0];
    i.distortion = Default::default();
    let mut pose = c.pose;
    pose.frame_id = 0;
    let mut renderer = optistim::render::Renderer::new(1).unwrap();
    let f = optistim::app::render::frame(&c, &pose, &mut renderer).unwrap();
    let radiance = c.scene.sun.radiance_integral(c.power_band_m);
    let got: Vec<f32> = data
        .chunks_exact(4)
        .map(|b| f32::from_ne_bytes(b.try_into().unwrap()))
        .collect();
    // Rows come bottom-up.
    for y in 0..h as usize {
        for x in 0..w as usize {
            let want = (f.pl[y * w as usize + x] * radiance) as f32;
            let g = got[(h as usize - 1 - y) * w as usize + x];
            assert_eq!(g.to_bits(), want.to_bits(), "pixel {x},{y}");
        }
    }
    d.shutdown();
}
