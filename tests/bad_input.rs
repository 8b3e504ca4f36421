//! Bad input: malformed or out-of-range scene values give an error naming the file, the key,
//! the value and what is allowed; bad poses give a render error; nothing panics.

mod common;
use common::*;
use optistim::config::{self, ConfigError};
use optistim::render::{RenderError, Renderer};

/// Replaces the first occurrence of `from` in the default scene text with `to` and parses it.
fn parse_with(from: &str, to: &str) -> Result<config::Config, ConfigError> {
    let text = SceneSpec::default().toml();
    assert!(text.contains(from), "test bug: {from:?} not in the scene");
    config::parse(&text.replacen(from, to, 1), "scene.toml")
}

/// Asserts an `Invalid` error on `key` whose message holds every piece of `expect`.
fn invalid(from: &str, to: &str, key: &str, expect: &[&str]) {
    let r = std::panic::catch_unwind(|| parse_with(from, to));
    let err = match r {
        Ok(Ok(_)) => panic!("{to:?} was accepted"),
        Ok(Err(e)) => e,
        Err(_) => panic!("{to:?} panicked"),
    };
    let msg = err.to_string();
    match &err {
        ConfigError::Invalid { file, key: k, .. } => {
            assert_eq!(file, "scene.toml", "{msg}");
            assert_eq!(k, key, "{msg}");
        }
        other => panic!("{to:?}: expected an Invalid error on {key}, got {other:?}"),
    }
    assert!(msg.starts_with("scene.toml: "), "{msg}");
    for e in expect {
        assert!(msg.contains(e), "{msg:?} lacks {e:?}");
    }
}

#[test]
fn out_of_range_values_name_file_key_value_and_allowed() {
    invalid(
        "radius_m = 1737400",
        "radius_m = -5.0",
        "body.radius_m",
        &["-5", "> 0"],
    );
    invalid(
        "radius_m = 1737400",
        "radius_m = nan",
        "body.radius_m",
        &["NaN"],
    );
    invalid(
        "radius_m = 1737400",
        "radius_m = inf",
        "body.radius_m",
        &["inf"],
    );
    invalid(
        "brdf = \"lambert\"",
        "brdf = \"velvet\"",
        "body.brdf",
        &["velvet", "lambert", "phong"],
    );
    invalid("albedo = 0.12", "albedo = 1.7", "body.albedo", &["1.7"]);
    invalid(
        "albedo_type = \"normal\"",
        "albedo_type = \"spherical\"",
        "body.albedo_type",
        &["normal", "geometric", "bond"],
    );
    invalid(
        "resolution_px = [256, 256]",
        "resolution_px = [0, 256]",
        "camera.resolution_px",
        &["0"],
    );
    invalid(
        "f_number = 2.0",
        "f_number = -2.0",
        "camera.f_number",
        &["-2"],
    );
    invalid(
        "bit_depth = 12",
        "bit_depth = 40",
        "camera.bit_depth",
        &["40"],
    );
    invalid(
        "bit_depth = 12",
        "bit_depth = 12\nsaved_bit_depth = 14",
        "camera.saved_bit_depth",
        &["14", "camera.bit_depth"],
    );
    invalid(
        "bit_depth = 12",
        "bit_depth = 12\npsf_sigma_px = -1.0",
        "camera.psf_sigma_px",
        &["-1"],
    );
    invalid(
        "albedo = 0.12",
        "albedo = 0.12\nhorizon_map = { path = \"h.tif\" }",
        "body.horizon_map",
        &["dem_map"],
    );
    invalid(
        "albedo = 0.12",
        "albedo = 0.12\nhorizon_azimuths = 16",
        "body.horizon_azimuths",
        &["dem_map"],
    );
    invalid(
        "[render]",
        "[render]\nself_shadowing = \"always\"",
        "render.self_shadowing",
        &["always", "ray_marching", "horizon_map"],
    );
    // Shadows that cannot be cast are refused, not silently dropped.
    invalid(
        "[render]",
        "[render]\nself_shadowing = \"ray_marching\"",
        "render.self_shadowing",
        &["ray_marching", "dem_map"],
    );
    invalid(
        "[render]",
        "[render]\nself_shadowing = \"horizon_map\"",
        "render.self_shadowing",
        &["horizon_map", "body.horizon_map"],
    );
    invalid(
        "value = [0.5, 0.6, 0.2]",
        "value = [0.5, 1.6, 0.2]",
        "camera.qe",
        &["1.6"],
    );
    invalid(
        "wavelength_nm = [400, 700, 1000]",
        "wavelength_nm = [400, 1000, 700]",
        "camera.qe",
        &["increase"],
    );
    invalid(
        "value = [0.5, 0.6, 0.2]",
        "value = [0.5, 0.6]",
        "camera.qe",
        &["length"],
    );
    invalid(
        "temperature_k = 5782.0",
        "temperature_k = 0.0",
        "sun.temperature_k",
        &["0"],
    );
    invalid(
        "spectrum = \"blackbody\"",
        "spectrum = \"led\"",
        "sun.spectrum",
        &["led", "blackbody"],
    );
    invalid(
        "[render]",
        "[render]\ngridding = \"cubic\"",
        "render.gridding",
        &["cubic", "polygon", "gaussian"],
    );
    invalid(
        "[render]",
        "[render]\nsupersampling = 0",
        "render.supersampling",
        &["[1, 16]"],
    );
    invalid(
        "[render]",
        "[render]\nrelief_refine = 3",
        "render.relief_refine",
        &["3", "1, 2, 4 or 8"],
    );
    invalid(
        "[render]",
        "[render]\nmap_read_spacing_texels = 0.01",
        "render.map_read_spacing_texels",
        &["0.01", "0.0625 to 1 texel"],
    );
    invalid(
        "[render]",
        "[render]\nmap_read_spacing_texels = nan",
        "render.map_read_spacing_texels",
        &["NaN", "0.0625 to 1 texel"],
    );
    invalid(
        "[render]",
        "[render]\ngridding = \"gaussian\"\ngaussian_window_px = 4",
        "render.gaussian_window_px",
        &["odd"],
    );
    invalid(
        "[render]",
        "[render]\npoints_per_pixel = -1.0",
        "render.points_per_pixel",
        &["-1"],
    );
    invalid(
        "seed = 5",
        "seed = 5\nreadout_sigma_e = -3.0",
        "camera.noise.readout_sigma_e",
        &["-3"],
    );
    invalid(
        "look_at_body = true",
        "attitude_wxyz = [1.0, 0.0, 0.0, 0.5]",
        "pose.attitude_wxyz",
        &["unit quaternion"],
    );
    invalid(
        "look_at_body = true",
        "attitude_wxyz = [nan, 0.0, 0.0, 1.0]",
        "pose.attitude_wxyz",
        &["NaN"],
    );
    invalid(
        "look_at_body = true",
        "look_at_body = true\nattitude_wxyz = [1.0, 0.0, 0.0, 0.0]",
        "pose.look_at_body",
        &["not both"],
    );
    invalid(
        "camera_position_m = [17374000.0, 0.0, 0.0]",
        "camera_position_m = [1000.0, 0.0, 0.0]",
        "pose.camera_position_m",
        &["outside the body"],
    );
    invalid(
        "camera_position_m = [17374000.0, 0.0, 0.0]",
        "camera_position_m = [nan, 0.0, 0.0]",
        "pose.camera_position_m",
        &["NaN"],
    );
}

#[test]
fn malformed_files_name_the_file_and_the_place() {
    for (from, to, expect) in [
        ("radius_m = 1737400", "radius_m = = 3", "line"),
        ("radius_m = 1737400", "radius_m = \"big\"", "radius_m"),
        (
            "radius_m = 1737400",
            "radius_m = 1737400\nradius_km = 3",
            "radius_km",
        ),
        ("[render]", "[rendr]", "rendr"),
    ] {
        let err = parse_with(from, to).expect_err(to);
        let msg = err.to_string();
        assert!(matches!(err, ConfigError::Parse { .. }), "{msg}");
        assert!(msg.starts_with("scene.toml: "), "{msg}");
        assert!(msg.contains(expect), "{msg:?} lacks {expect:?}");
    }
    let missing = config::load(std::path::Path::new("no/such/scene.toml")).unwrap_err();
    assert!(missing.to_string().contains("no/such/scene.toml"));
}

#[test]
fn bad_poses_are_render_errors_not_panics() {
    let cfg = SceneSpec::default().config();
    let mut r = Renderer::new(1).unwrap();
    let mut try_pose = |f: &dyn Fn(&mut optistim::scene::Pose)| {
        let mut p = cfg.pose;
        f(&mut p);
        r.render(&cfg.scene, &p, &cfg.settings).map(|_| ())
    };
    assert!(matches!(
        try_pose(&|p| p.camera_position_m = glam::DVec3::new(0.5 * R_MOON, 0.0, 0.0)),
        Err(RenderError::CameraInsideBody { .. })
    ));
    assert!(matches!(
        try_pose(&|p| p.camera_position_m.y = f64::NAN),
        Err(RenderError::BadPose {
            field: "camera_position_m",
            ..
        })
    ));
    assert!(matches!(
        try_pose(&|p| p.sun_position_m.z = f64::INFINITY),
        Err(RenderError::BadPose {
            field: "sun_position_m",
            ..
        })
    ));
    assert!(matches!(
        try_pose(&|p| p.body_from_camera = glam::DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0)),
        Err(RenderError::BadPose {
            field: "attitude",
            ..
        })
    ));
    assert!(matches!(
        try_pose(&|p| p.body_from_camera = glam::DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0)),
        Err(RenderError::BadPose {
            field: "attitude",
            ..
        })
    ));
    // A camera on the surface, a Sun at the centre: errors too.
    assert!(try_pose(&|p| p.camera_position_m = glam::DVec3::new(R_MOON, 0.0, 0.0)).is_err());
    assert!(try_pose(&|p| p.sun_position_m = glam::DVec3::ZERO).is_err());
    // The renderer still works after all of that.
    assert!(try_pose(&|_| {}).is_ok());
}

#[test]
fn the_binary_reports_bad_files_and_exits_nonzero() {
    let dir = std::env::temp_dir().join(format!("optistim-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.toml");
    let text = SceneSpec::default()
        .toml()
        .replacen("albedo = 0.12", "albedo = -0.12", 1);
    std::fs::write(&path, text).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(["render", path.to_str().unwrap(), "--out"])
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("bad.toml") && stderr.contains("body.albedo"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_binary_names_a_missing_file_once_and_survives_a_closed_stdout() {
    let bin = env!("CARGO_BIN_EXE_optistim");
    let dir = std::env::temp_dir().join(format!("optistim-pipe-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The cause is quoted once, not once by our error and again by its source.
    let out = std::process::Command::new(bin)
        .args(["render", "/nonexistent/scene.toml"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert_eq!(
        stderr.matches("No such file or directory").count(),
        1,
        "{stderr}"
    );
    // A reader that goes away before the result is printed (`optistim ... | head -c 0`).
    let path = dir.join("scene.toml");
    std::fs::write(&path, SceneSpec::default().toml()).unwrap();
    let mut child = std::process::Command::new(bin)
        .args(["render", path.to_str().unwrap(), "--out"])
        .arg(dir.join("out"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `optistim verify-budget --render`: `[render]` keys over a scene file's for one run. They
/// override the file's (here its `points_per_pixel`, and a key it does not set), an invalid
/// value is refused as in the file itself, and text that is not TOML names `--render`.
#[test]
fn render_keys_given_beside_a_file_override_its_own() {
    let dir = std::env::temp_dir().join(format!("optistim-render-keys-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.toml");
    std::fs::write(&path, SceneSpec::default().toml()).unwrap();
    let plain = config::load_with_render(&path, "").unwrap();
    assert_eq!(plain.settings, config::load(&path).unwrap().settings);
    let cfg = config::load_with_render(&path, "points_per_pixel = 2.0\nrelief_refine = 4").unwrap();
    assert_eq!(
        cfg.settings.points,
        optistim::render::PointBudget::PerPixel(2.0)
    );
    assert_eq!(cfg.settings.relief_refine, 4);
    assert_ne!(plain.settings.points, cfg.settings.points);
    match config::load_with_render(&path, "relief_refine = 5") {
        Err(ConfigError::Invalid { key, .. }) => assert_eq!(key, "render.relief_refine"),
        other => panic!("{other:?}"),
    }
    match config::load_with_render(&path, "relief_refine = ") {
        Err(ConfigError::Parse { file, .. }) => assert_eq!(file, "--render"),
        other => panic!("{other:?}"),
    }
    std::fs::remove_dir_all(&dir).ok();
}
