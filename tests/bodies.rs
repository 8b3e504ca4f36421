//! Several bodies in one scene (issue 16, item 3): a moon eclipsing its planet. The light the
//! planet loses in the image equals a geometric computation of the moon's shadow over the
//! planet's surface (no ray casting: a surface quadrature with the shadow cone's test), the
//! shadowed pixels are the ones whose surface point the geometry puts in the shadow, and a mesh
//! body beside a sphere occludes and shadows it the same way.

mod common;
use common::*;
use glam::DVec3;
use optistim::config::Config;
use optistim::render::Renderer;

const R1: f64 = 1.0e6;
const R2: f64 = 3.0e5;
/// The moon, between the planet and the Sun.
const MOON: [f64; 3] = [4.0e6, 0.3e6, 0.2e6];

/// The planet seen from 20,000 km at 90 deg of phase, the moon beside it in the image.
fn scene(with_moon: bool, moon_shape: &str) -> Config {
    let spec = SceneSpec {
        resolution: [512, 512],
        focal_m: 0.00525,
        camera_m: [0.0, 2.0e7, 0.0],
        sun_m: [AU, 0.0, 0.0],
        ..Default::default()
    };
    let mut text = spec
        .toml()
        .replace(&format!("radius_m = {R_MOON}"), &format!("radius_m = {R1}"))
        .replace("[body]", "[[body]]");
    if with_moon {
        text = text.replace(
            "[camera]\n",
            &format!(
                "[[body]]\nname = \"moon\"\n{moon_shape}\nposition_m = {MOON:?}\nbrdf = \"lambert\"\n\
                 albedo = 0.3\nalbedo_type = \"normal\"\n\n[camera]\n"
            ),
        );
    }
    optistim::config::parse(&text, "<test>").unwrap_or_else(|e| panic!("{e}"))
}

fn render(cfg: &Config) -> Vec<f64> {
    let mut s = cfg.settings.clone();
    s.raycast_edge_samples = 8;
    Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &s)
        .unwrap_or_else(|e| panic!("{e}"))
        .pl
}

/// Whether the segment from `p` to the Sun passes through the moon's sphere.
fn in_shadow(p: DVec3, sun: DVec3) -> bool {
    let c = DVec3::from_array(MOON);
    let d = sun - p;
    let len = d.length();
    let u = d / len;
    let t = (c - p).dot(u).clamp(0.0, len);
    (p + u * t - c).length() < R2
}

#[test]
fn an_eclipse_takes_the_light_of_the_geometric_shadow() {
    let cfg = scene(true, "radius_m = 3.0e5");
    let alone = scene(false, "");
    let with = render(&cfg);
    let without = render(&alone);
    // The planet's pixels: lit without the moon (the moon's own pixels are apart).
    let lost: f64 = (0..with.len())
        .filter(|&p| without[p] > 0.0)
        .map(|p| without[p] - with[p])
        .sum();
    // The same from the geometry: (P/L) = A_sun A_cam f_r mu0 mu dA / (d_sun^2 d_cam^2) over
    // the planet's shadowed, lit and visible surface (a 4000 x 2000 longitude-latitude rule).
    let sun = cfg.pose.sun_position_m;
    let cam = cfg.pose.camera_position_m;
    let k = cfg.scene.sun.area_m2() * cfg.scene.camera.intrinsics.aperture_area_m2();
    let f_r = cfg.scene.body.brdf.scale() / std::f64::consts::PI;
    let (nl, nb) = (4000, 2000);
    let (dl, db) = (
        std::f64::consts::TAU / nl as f64,
        std::f64::consts::PI / nb as f64,
    );
    let mut want = 0.0;
    let mut shadow_area = 0.0;
    for j in 0..nb {
        let lat = -std::f64::consts::FRAC_PI_2 + (j as f64 + 0.5) * db;
        for i in 0..nl {
            let lon = (i as f64 + 0.5) * dl;
            let n = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
            let p = n * R1;
            let (ts, tc) = (sun - p, cam - p);
            let (mu0, mu) = (n.dot(ts.normalize()), n.dot(tc.normalize()));
            if mu0 <= 0.0 || mu <= 0.0 || !in_shadow(p, sun) {
                continue;
            }
            let da = R1 * R1 * lat.cos() * dl * db;
            shadow_area += da;
            want += k * f_r * mu0 * mu * da / (ts.length_squared() * tc.length_squared());
        }
    }
    let total: f64 = without.iter().sum();
    eprintln!(
        "light lost {lost:.4e} (geometry {want:.4e}, {:.2} % of the planet's light); shadow \
         {:.0} km^2 in view",
        100.0 * want / total,
        shadow_area * 1e-6
    );
    assert!(want > 0.01 * total, "the shadow is in view");
    assert!((lost / want - 1.0).abs() < 0.01, "{lost} vs {want}");

    // Pixel by pixel: a pixel whose centre's surface point is in the geometric shadow is dark,
    // and one well outside it keeps its light.
    let tracer = optistim::raycast::Tracer::new(&cfg.scene, &cfg.pose);
    let intr = &cfg.scene.camera.intrinsics;
    let q = glam::DMat3::from_quat(cfg.pose.body_from_camera);
    let (mut dark, mut wrong) = (0, 0);
    for j in 0..512 {
        for i in 0..512 {
            let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
            let (x, y) = intr.unproject(u, v);
            let dir = (q * DVec3::new(x, y, 1.0)).normalize();
            let Some(t) = optistim::geometry::ray_sphere(cam, dir, R1) else {
                continue;
            };
            let p = cam + dir * t;
            if p.normalize().dot((sun - p).normalize()) <= 0.0 {
                continue;
            }
            let shadowed = in_shadow(p, sun);
            let got = tracer.cast(u, v).pl_per_px2 == 0.0;
            dark += shadowed as usize;
            wrong += (shadowed != got) as usize;
        }
    }
    eprintln!("{dark} pixel centres in the shadow, {wrong} disagree");
    assert!(dark > 150 && wrong == 0, "{dark} {wrong}");
}

#[test]
fn a_mesh_moon_eclipses_like_the_sphere_it_approximates() {
    // The moon as a geodesic mesh of 20k facets: the same shadow within its faceting.
    let dir = std::env::temp_dir().join(format!("optistim-bodies-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (v, f) = optistim::body::mesh::geodesic_sphere(R2, 32);
    let mut obj = String::new();
    for p in &v {
        obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &f {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let path = dir.join("moon.obj");
    std::fs::write(&path, obj).unwrap();
    let mesh_moon = scene(
        true,
        &format!(
            "shape = \"mesh\"\nmesh = {{ path = \"{}\", units = \"m\" }}",
            path.display()
        ),
    );
    let sphere_moon = scene(true, "radius_m = 3.0e5");
    let (a, b) = (render(&mesh_moon), render(&sphere_moon));
    let (sa, sb): (f64, f64) = (a.iter().sum(), b.iter().sum());
    eprintln!("mesh moon {sa:.6e}, sphere moon {sb:.6e}");
    assert!((sa / sb - 1.0).abs() < 1e-3, "{sa} vs {sb}");
}

#[test]
fn the_pose_protocol_moves_the_further_bodies() {
    use optistim::server::frames::{Mode, PresenterChoice};
    use optistim::server::protocol::{BodyPoseMsg, Message, PoseMsg};
    use std::io::{BufRead, BufReader, Write};
    // The daemon's scene with a moon of 200 km added.
    let text = small_daemon_config().replace("[body]", "[[body]]").replace(
        "[camera]\n",
        "[[body]]\nname = \"moonlet\"\nradius_m = 5.0e5\nposition_m = [0.0, 0.0, 9.0e6]\n\
         brdf = \"lambert\"\nalbedo = 0.3\nalbedo_type = \"normal\"\n\n[camera]\n",
    );
    let d = start_daemon(&text, PresenterChoice::Cpu, Mode::Lockstep, None, None);
    let s = std::net::TcpStream::connect(d.tcp_addr).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(60)))
        .unwrap();
    let mut w = s.try_clone().unwrap();
    let mut lines = BufReader::new(s).lines();
    // 30 deg of phase: the moon's shadow on the planet's day side in view.
    let cam = DVec3::new(8.66e7, 5.0e7, 0.0);
    let q = optistim::geometry::look_at(cam, DVec3::ZERO, DVec3::Z);
    let pose = |id: u64, moon: Option<[f64; 3]>| PoseMsg {
        frame_id: id,
        time_tag_s: id as f64,
        camera_position_m: cam.to_array(),
        attitude_wxyz: optistim::geometry::wxyz(q),
        sun_position_m: [AU, 0.0, 0.0],
        body_attitude_wxyz: None,
        exposure_s: None,
        bodies: moon.map(|p| {
            vec![BodyPoseMsg {
                position_m: p,
                attitude_wxyz: [1.0, 0.0, 0.0, 0.0],
            }]
        }),
    };
    let mut ask = |m: PoseMsg| -> (serde_json::Value, Vec<u8>) {
        writeln!(w, "{}", serde_json::to_string(&Message::Pose(m)).unwrap()).unwrap();
        let reply: serde_json::Value =
            serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
        (reply, http(d.http_addr, "GET", "/frame/latest.png", b"").1)
    };
    // The moon between the Sun and the planet: its shadow on the planet.
    let (a, shadowed) = ask(pose(1, Some([6.0e6, 0.0, 0.0])));
    assert_eq!(a["status"].as_str(), Some("presented"), "{a}");
    // Out of the sunlight's way: the planet whole.
    let (b, whole) = ask(pose(2, Some([0.0, 0.0, 9.0e6])));
    assert_eq!(b["status"].as_str(), Some("presented"), "{b}");
    assert!(shadowed != whole, "moving the moon changes the screen");
    // A pose without bodies leaves them where the last one put them.
    let (c, same) = ask(pose(3, None));
    assert_eq!(c["status"].as_str(), Some("presented"), "{c}");
    assert!(same == whole, "a pose without bodies keeps them");
    // Two bodies for a scene with one, or one inside the planet: refused, named, the daemon
    // serving on.
    let mut two = pose(4, Some([0.0, 0.0, 9.0e6]));
    let first = two.bodies.as_ref().unwrap()[0];
    two.bodies.as_mut().unwrap().push(first);
    let (e, _) = ask(two);
    assert_eq!(e["code"].as_str(), Some("bad_value"), "{e}");
    assert!(e["message"].as_str().unwrap().contains("2 bodies"), "{e}");
    let (e, _) = ask(pose(5, Some([2.0e6, 0.0, 0.0])));
    assert!(e["message"].as_str().unwrap().contains("overlap"), "{e}");
    let (f, again) = ask(pose(6, None));
    assert_eq!(f["status"].as_str(), Some("presented"), "{f}");
    assert!(again == whole, "the refused poses moved nothing");
}
