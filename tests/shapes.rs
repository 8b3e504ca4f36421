//! Non-spherical bodies (issue 3, item 4): a triaxial ellipsoid, and DEMs that displace the
//! surface, given as heights or as radii from the centre.
//!
//! At opposition a Lommel-Seeliger body reflects in proportion to its projected area (its
//! `f_r mu0 mu` is `w/(4 pi) mu/2` there, and `mu dA` is the projected area element), so an
//! ellipsoid of semi-axes (a, b, c) seen along X returns `b c / R^2` of a sphere of radius R
//! (`a c / R^2` along Y, `a b / R^2` along Z), and its lit pixels span `2b` and `2c` across.

mod common;
use common::*;
use optistim::render::Renderer;

const AXES: [f64; 3] = [2.4e6, 1.7374e6, 1.1e6];

/// A Lommel-Seeliger body seen from 400 R (through a 300 mm lens) along `axis` with the Sun (almost) behind the camera.
fn render(axis: usize, shape: &str) -> (f64, Vec<f64>, usize) {
    let mut cam = [0.0; 3];
    cam[axis] = 400.0 * R_MOON;
    let mut sun = [0.0; 3];
    sun[axis] = AU;
    sun[(axis + 1) % 3] = AU * 1e-4; // 0.006 deg of phase: the CSF needs a plane
    let spec = SceneSpec {
        brdf: "lommel_seeliger",
        camera_m: cam,
        sun_m: sun,
        resolution: [512, 512],
        focal_m: 0.3,
        render: "points_per_pixel = 1.0",
        ..Default::default()
    };
    let pl = image(&reshaped(spec.toml(), shape));
    (pl.iter().sum(), pl, spec.resolution[0] as usize)
}

/// A scene TOML with its sphere's `radius_m` line replaced by `shape`'s keys.
fn reshaped(text: String, shape: &str) -> String {
    text.replacen(&format!("radius_m = {R_MOON}\n"), shape, 1)
}

/// The (P/L) image of a scene TOML.
fn image(text: &str) -> Vec<f64> {
    let cfg = optistim::config::parse(text, "shape.toml").unwrap_or_else(|e| panic!("{e}"));
    Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap()
        .pl
}

/// `|b - a| / a` over the pixels where `a` exceeds 5 % of its peak, sorted.
fn relative_differences(a: &[f64], b: &[f64]) -> Vec<f64> {
    let peak = a.iter().cloned().fold(0.0, f64::max);
    let mut rel: Vec<f64> = a
        .iter()
        .zip(b)
        .filter(|(x, _)| **x > 0.05 * peak)
        .map(|(x, y)| (x - y).abs() / x)
        .collect();
    rel.sort_by(f64::total_cmp);
    rel
}

/// A body of albedo 0.2 seen obliquely from 72 R at 21 deg phase through a 60 mm lens
/// (512 x 512), trapezoidal rule: the DEM-shape comparisons' scene.
fn oblique_view() -> SceneSpec<'static> {
    SceneSpec {
        albedo: 0.2,
        camera_m: [60.0 * R_MOON, 35.0 * R_MOON, 20.0 * R_MOON],
        sun_m: [AU, 0.3 * AU, 0.0],
        resolution: [512, 512],
        focal_m: 0.06,
        render: "points_per_pixel = 1.0\nintegration = \"trapezoidal\"",
        ..Default::default()
    }
}

fn ellipsoid() -> String {
    format!("shape = \"ellipsoid\"\nsemi_axes_m = {AXES:?}\n")
}

#[test]
fn an_ellipsoid_at_opposition_reflects_its_projected_area() {
    // The axis indexes the camera's position and the other two semi-axes as well.
    #[allow(clippy::needless_range_loop)]
    for axis in 0..3 {
        let (sphere, _, _) = render(axis, &format!("radius_m = {R_MOON}\n"));
        let (ell, pl, w) = render(axis, &ellipsoid());
        let (p, q) = ((axis + 1) % 3, (axis + 2) % 3);
        let expect = AXES[p] * AXES[q] / (R_MOON * R_MOON);
        let ratio = ell / sphere;
        println!("along axis {axis}: ratio {ratio:.6} expected {expect:.6}");
        assert!(
            (ratio / expect - 1.0).abs() < 2e-3,
            "axis {axis}: {ratio} vs {expect}"
        );

        // Extent of the lit pixels across the image, against the projected semi-axes
        // (range 8 R minus the axis towards the camera, focal 30 mm, 5.5 um pixels).
        let peak = pl.iter().cloned().fold(0.0, f64::max);
        let (mut c0, mut c1, mut r0, mut r1) = (usize::MAX, 0, usize::MAX, 0);
        for (i, &v) in pl.iter().enumerate() {
            if v > 1e-3 * peak {
                let (c, r) = (i % w, i / w);
                (c0, c1, r0, r1) = (c0.min(c), c1.max(c), r0.min(r), r1.max(r));
            }
        }
        let range = 400.0 * R_MOON - AXES[axis];
        let px = |m: f64| 2.0 * m / range * 0.3 / 5.5e-6;
        let (du, dv) = ((c1 - c0 + 1) as f64, (r1 - r0 + 1) as f64);
        let mut seen = [du, dv];
        seen.sort_by(f64::total_cmp);
        let mut want = [px(AXES[p]), px(AXES[q])];
        want.sort_by(f64::total_cmp);
        println!("  extent {seen:?} px, projected axes {want:?} px");
        for k in 0..2 {
            assert!((seen[k] - want[k]).abs() < 3.0, "{seen:?} vs {want:?}");
        }
    }
}

#[test]
fn a_round_ellipsoid_renders_as_the_sphere() {
    let round = format!("shape = \"ellipsoid\"\nsemi_axes_m = [{R_MOON}, {R_MOON}, {R_MOON}]\n");
    let (s, ps, _) = render(0, &format!("radius_m = {R_MOON}\n"));
    let (e, pe, _) = render(0, &round);
    assert!((e / s - 1.0).abs() < 1e-3, "{e} vs {s}");
    let rel = relative_differences(&ps, &pe);
    let (median, p99) = (rel[rel.len() / 2], rel[rel.len() * 99 / 100]);
    println!(
        "round ellipsoid vs sphere: total {:.2e}, pixels median {median:.2e} p99 {p99:.2e}",
        e / s - 1.0
    );
    // The sphere's limb quadrangles are clipped exactly, the ellipsoid's by a clamped
    // trapezoidal rule: the limb pixels differ most.
    assert!(median < 1e-3 && p99 < 0.05, "{median} {p99}");
}

#[test]
fn ellipsoid_keys_are_checked() {
    let base = SceneSpec::default().toml();
    let bad = |from: &str, to: &str, key: &str| {
        assert_eq!(
            refusal(&base.replacen(from, to, 1), "s.toml").0,
            key,
            "{to:?}"
        );
    };
    let r = format!("radius_m = {R_MOON}\n");
    bad(&r, "shape = \"ellipsoid\"\n", "body.semi_axes_m");
    bad(
        &r,
        "shape = \"ellipsoid\"\nsemi_axes_m = [1.0, -2.0, 3.0]\n",
        "body.semi_axes_m[1]",
    );
    bad(
        &r,
        &format!("shape = \"ellipsoid\"\nsemi_axes_m = [1.0, 2.0, 3.0]\n{r}"),
        "body.radius_m",
    );
    bad(&r, "shape = \"torus\"\n", "body.shape");
    let text = base
        .replacen(
            &r,
            "shape = \"ellipsoid\"\nsemi_axes_m = [1e6, 1e6, 1e6]\n",
            1,
        )
        .replacen("[render]\n", "[render]\nintegration = \"exact\"\n", 1);
    match optistim::config::parse(&text, "s.toml") {
        Err(e @ optistim::config::ConfigError::Invalid { .. }) => {
            assert!(e.to_string().contains("non-spherical"), "{e}")
        }
        other => panic!("exact on an ellipsoid: {other:?}"),
    }
}

/// A global DEM of `w` x `h` texels displacing the sphere of `R_MOON`, of heights
/// `height_m(lon_deg, lat_deg)` at the texel centres.
fn global_dem(w: usize, h: usize, height_m: impl Fn(f64, f64) -> f64) -> optistim::body::Relief {
    use optistim::body::maps::{Encoding, Map};
    let heights = (0..w * h)
        .map(|i| {
            let lon = -180.0 + ((i % w) as f64 + 0.5) * 360.0 / w as f64;
            let lat = 90.0 - ((i / w) as f64 + 0.5) * 180.0 / h as f64;
            height_m(lon, lat)
        })
        .collect();
    let map = Map::from_values(
        std::path::Path::new("dem"),
        w,
        h,
        heights,
        &Encoding::default(),
    )
    .unwrap();
    optistim::body::Relief::new(map, R_MOON, true).unwrap()
}

/// The radii of the oblate spheroid (a, a, c) on a 720 x 360 grid, as a DEM displacing the
/// sphere of `R_MOON` (the heights the config makes of a DEM of radii).
fn spheroid_dem(a: f64, c: f64) -> optistim::body::Relief {
    global_dem(720, 360, |_, lat_deg| {
        let lat = lat_deg.to_radians();
        1.0 / ((lat.cos() / a).powi(2) + (lat.sin() / c).powi(2)).sqrt() - R_MOON
    })
}

/// The spheroid (a, a, c) analytic and as a DEM of radii, in `spec`'s scene.
fn spheroid_pair(
    spec: &SceneSpec,
    a: f64,
    c: f64,
) -> (optistim::config::Config, optistim::config::Config) {
    let sphere = spec.config();
    let mut ell = sphere.clone();
    ell.scene.body.shape = optistim::body::Shape::Ellipsoid(optistim::body::Ellipsoid {
        semi_axes_m: glam::DVec3::new(a, a, c),
    });
    let mut dem = sphere;
    dem.scene.body.relief = Some(spheroid_dem(a, c));
    (ell, dem)
}

/// The (P/L) image of a validated config.
fn rendered(cfg: &optistim::config::Config) -> Vec<f64> {
    Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap()
        .pl
}

/// A DEM given as radius from the centre (Vesta-like), displacing the surface: the radii of
/// an oblate spheroid (a, a, c) on a 720 x 360 grid render as the analytic ellipsoid.
#[test]
fn an_absolute_radius_dem_renders_as_the_shape_it_describes() {
    let (a, c) = (1.25 * R_MOON, 0.8 * R_MOON);
    let spec = oblique_view();
    let (ell, dem) = spheroid_pair(&spec, a, c);
    let (pe, pd, ps) = (rendered(&ell), rendered(&dem), rendered(&spec.config()));
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    let (te, td, ts) = (sum(&pe), sum(&pd), sum(&ps));
    let peak = pe.iter().cloned().fold(0.0, f64::max);
    let rel = relative_differences(&pe, &pd);
    let (median, p95) = (rel[rel.len() / 2], rel[rel.len() * 95 / 100]);
    let lit = |v: &[f64]| v.iter().filter(|&&x| x > 0.05 * peak).count();
    println!(
        "DEM of radii vs ellipsoid: total {:.2e} (the sphere is {:.2e} off), lit px {} vs {} \
         (sphere {}), pixels median {median:.2e} p95 {p95:.2e}",
        td / te - 1.0,
        ts / te - 1.0,
        lit(&pd),
        lit(&pe),
        lit(&ps)
    );
    assert!((td / te - 1.0).abs() < 5e-4, "{td} vs {te}");
    assert!(
        (ts / te - 1.0).abs() > 0.05,
        "the test must tell the shapes apart"
    );
    assert!(median < 1e-3 && p95 < 5e-3, "{median} {p95}");
    assert!((lit(&pd) as f64 / lit(&pe) as f64 - 1.0).abs() < 0.01);
}

/// The same spheroid of radii seen from close range, where the directions in which its
/// surface is seen reach beyond the visible cap of the sphere bounding it: the grid is bounded
/// by the caps of the sphere of its lowest point, and the DEM renders as the analytic
/// ellipsoid. (Bounded by the bounding sphere's caps, as before, it lost 3.7 % of the light
/// and 6 % of the lit pixels from 2 a, 14 % and 20 % from 1.6 a.)
#[test]
fn an_absolute_radius_dem_at_close_range_is_bounded_by_its_lowest_point() {
    let (a, c) = (1.25 * R_MOON, 0.8 * R_MOON);
    for (range, elevation) in [(2.0, 0.0), (1.6, 0.6f64)] {
        let spec = SceneSpec {
            albedo: 0.2,
            camera_m: [
                range * a * (1.0 - elevation * elevation).sqrt(),
                0.0,
                range * a * elevation,
            ],
            sun_m: [AU, 0.3 * AU, 0.0],
            resolution: [512, 512],
            focal_m: 0.0084 / range,
            render: "points_per_pixel = 1.0\nintegration = \"trapezoidal\"",
            ..Default::default()
        };
        let (ell, dem) = spheroid_pair(&spec, a, c);
        let (pe, pd) = (rendered(&ell), rendered(&dem));
        let sum = |v: &[f64]| v.iter().sum::<f64>();
        let lit = |v: &[f64]| v.iter().filter(|&&x| x > 0.0).count();
        let total = sum(&pd) / sum(&pe) - 1.0;
        println!(
            "spheroid of radii from {range} a: total {total:.2e}, lit px {} vs {}",
            lit(&pd),
            lit(&pe)
        );
        assert!(total.abs() < 2e-4, "{range} a: {total}");
        assert!(
            (lit(&pd) as f64 / lit(&pe) as f64 - 1.0).abs() < 1e-3,
            "{range} a: {} vs {}",
            lit(&pd),
            lit(&pe)
        );
    }
}

/// Terrain behind the limb stays hidden on a displaced DEM, and a peak tall enough to rise
/// over the limb is seen. A sphere with two Gaussian bumps (0.5 deg wide): one on the far
/// side, in both DEMs, keeping their highest point the same; and, in one DEM only, one 7 deg
/// beyond the limb seen from 3 R, at 60 deg latitude (where the grid's longitude-latitude box
/// reaches beyond the limb), its slopes facing the camera. At 8 km it stays below the
/// line of sight over the limb (14 km there): with ray marching and without self-shadowing the
/// image is the same, bit for bit, as without it (before directions below a point's
/// horizontal were marched, it lit pixels up to 22 % of the image's peak). At 25 km its top
/// rises over the limb: the pixels it lights are where per-pixel ray casts newly meet the
/// surface.
#[test]
fn terrain_behind_the_limb_stays_hidden_and_a_peak_over_it_is_seen() {
    use optistim::render::settings::SelfShadowing;
    let d = 3.0 * R_MOON;
    let spec = SceneSpec {
        albedo: 0.2,
        camera_m: [
            d * 30f64.to_radians().cos(),
            d * 30f64.to_radians().sin(),
            0.0,
        ],
        sun_m: [AU, 0.0, 0.0],
        resolution: [512, 512],
        focal_m: 0.0035,
        render: "points_per_pixel = 1.0",
        ..Default::default()
    };
    let render = |bump_m: f64, shadows: SelfShadowing| {
        let bump = |lon0: f64, lat0: f64, top: f64| {
            move |lon: f64, lat: f64| {
                let (dl, db) = ((lon - lon0) * lat0.to_radians().cos(), lat - lat0);
                top * (-(dl * dl + db * db) / (2.0 * 0.5 * 0.5)).exp()
            }
        };
        let (far, limb) = (bump(-150.0, 0.0, 25e3), bump(-35.0, 60.0, bump_m));
        let mut cfg = spec.config();
        cfg.scene.body.relief = Some(global_dem(1440, 720, |lon, lat| {
            far(lon, lat) + limb(lon, lat)
        }));
        cfg.settings.self_shadowing = shadows;
        cfg.settings.depth = true;
        let f = Renderer::new(0)
            .unwrap()
            .render(&cfg.scene, &cfg.pose, &cfg.settings)
            .unwrap();
        (f.pl, f.depth_m.unwrap())
    };
    for shadows in [SelfShadowing::RayMarching, SelfShadowing::Off] {
        let (without, hits_without) = render(0.0, shadows);
        let (hidden, _) = render(8e3, shadows);
        assert!(without == hidden, "{shadows:?}: the hidden bump shows");

        let (seen, hits_seen) = render(25e3, shadows);
        let met = |d: &[f64], i: usize| d[i].is_finite() && d[i] > 0.0;
        let new_hits: Vec<usize> = (0..seen.len())
            .filter(|&i| met(&hits_seen, i) && !met(&hits_without, i))
            .collect();
        let lit_anew: Vec<usize> = (0..seen.len())
            .filter(|&i| seen[i] > 0.0 && without[i] == 0.0)
            .collect();
        println!(
            "{shadows:?}: the peak over the limb: ray casts meet {} new pixels, {} are newly lit",
            new_hits.len(),
            lit_anew.len()
        );
        assert!(!new_hits.is_empty(), "the peak must rise over the limb");
        // Every newly lit pixel is one the ray casts newly meet, or next to one.
        let columns = spec.resolution[0] as usize;
        let near = |i: usize, j: usize| {
            let (x, y) = (
                |k: usize| (k % columns) as i64,
                |k: usize| (k / columns) as i64,
            );
            (x(i) - x(j)).abs() <= 1 && (y(i) - y(j)).abs() <= 1
        };
        assert!(!lit_anew.is_empty(), "{shadows:?}: the peak is not seen");
        assert!(
            lit_anew
                .iter()
                .all(|&i| new_hits.iter().any(|&j| near(i, j))),
            "{shadows:?}: {lit_anew:?} vs {new_hits:?}"
        );
    }
}

/// A constant DEM of height H, displacing, is the sphere of R + H; through the config, given
/// as radii (dem_values = "radius") in a float32 TIFF.
#[test]
fn a_displacing_dem_from_a_tiff_of_radii_is_the_bigger_sphere() {
    let dir = TempDir::new("dem");
    let tif = dir.join("radii.tif");
    let r2 = 1.1 * R_MOON;
    let data = vec![r2 as f32; 64 * 32];
    write_tiff::<tiff::encoder::colortype::Gray32Float>(&tif, 64, 32, &data);
    let spec = SceneSpec {
        albedo: 0.2,
        camera_m: [50.0 * R_MOON, 30.0 * R_MOON, 0.0],
        render: "integration = \"trapezoidal\"",
        ..Default::default()
    };
    let base = spec.toml();
    let keys = format!(
        "dem_map = {{ path = {:?} }}\ndem_values = \"radius\"\ndisplacement = true",
        tif.display().to_string()
    );
    let dem = spec.toml_with_body(&keys);
    let big = reshaped(base.clone(), &format!("radius_m = {r2}\n"));
    let total = |text: &str| image(text).iter().sum::<f64>();
    let (td, tb, ts) = (total(&dem), total(&big), total(&base));
    println!(
        "R + H sphere from a DEM: {:.2e} (R sphere {:.2e})",
        td / tb - 1.0,
        ts / tb - 1.0
    );
    assert!((td / tb - 1.0).abs() < 1e-4, "{td} vs {tb}");
    assert!((ts / tb - 1.0).abs() > 0.1);
    // Displacement without a DEM is refused.
    let bad = spec.toml_with_body("displacement = true");
    assert_eq!(refusal(&bad, "s.toml").0, "body.displacement");
}

/// DEM heights above an ellipsoid (`shape = "ellipsoid"` with `dem_map`, Vesta-like): a DEM of
/// zeros on a 720 x 360 grid, through the config, renders as the triaxial ellipsoid itself
/// (the heights become radii at the texel centres); without displacement it is refused.
#[test]
fn dem_heights_above_an_ellipsoid_keep_its_shape() {
    let dir = TempDir::new("ellipsoid_dem");
    let tif = dir.join("zero_heights.tif");
    let (w, h) = (720, 360);
    write_tiff::<tiff::encoder::colortype::Gray32Float>(
        &tif,
        w,
        h,
        &vec![0.0f32; (w * h) as usize],
    );
    let spec = oblique_view();
    let sphere = spec.toml();
    let ell = reshaped(sphere.clone(), &ellipsoid());
    let with_dem = |displacement: bool| {
        let keys = format!(
            "dem_map = {{ path = {:?} }}\ndisplacement = {displacement}",
            tif.display().to_string()
        );
        reshaped(spec.toml_with_body(&keys), &ellipsoid())
    };
    let (pe, pd, ps) = (image(&ell), image(&with_dem(true)), image(&sphere));
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    let (te, td, ts) = (sum(&pe), sum(&pd), sum(&ps));
    let rel = relative_differences(&pe, &pd);
    let (median, p95) = (rel[rel.len() / 2], rel[rel.len() * 95 / 100]);
    println!(
        "zero heights above the ellipsoid vs the ellipsoid: total {:.2e} (the sphere is {:.2e} \
         off), pixels median {median:.2e} p95 {p95:.2e}",
        td / te - 1.0,
        ts / te - 1.0
    );
    assert!((td / te - 1.0).abs() < 5e-4, "{td} vs {te}");
    assert!(
        (ts / te - 1.0).abs() > 0.05,
        "the test must tell the shapes apart"
    );
    assert!(median < 1e-3 && p95 < 5e-3, "{median} {p95}");
    // Heights above an ellipsoid without displacement are refused.
    assert_eq!(refusal(&with_dem(false), "ell.toml").0, "body.displacement");
}

/// The ellipsoid seen from close range is bounded and sampled in its parameter space, where
/// it is the unit sphere: the image matches an independent per-pixel ray cast (8 x 8 rays per
/// pixel on the analytic ellipsoid, each weighted by its solid angle), and the grid is spent on
/// what the camera sees. Two poses, 39 deg FOV: 1.3 semi-major axes from the centre, and 400 km
/// above the short axis's pole, inside the sphere that bounds the body. (Sampled over every
/// direction, as before the parameter space, the first pose kept 4 % of 410,000 quadrangles
/// and missed the ray cast by 1.1e-4 in total, 4.3e-5 median and 1.0e-4 p95 per pixel.)
#[test]
fn an_ellipsoid_at_close_range_matches_ray_casting() {
    for camera_m in [[2.6e6, 1.2e6, 1.0e6], [2e5, -1e5, 1.5e6]] {
        let spec = SceneSpec {
            brdf: "lommel_seeliger",
            albedo: 0.2,
            camera_m,
            sun_m: [AU, 0.5 * AU, 0.3 * AU],
            resolution: [256, 256],
            focal_m: 0.002,
            render: "points_per_pixel = 1.0",
            ..Default::default()
        };
        let text = reshaped(spec.toml(), &ellipsoid());
        let cfg = optistim::config::parse(&text, "shape.toml").unwrap_or_else(|e| panic!("{e}"));
        let frame = Renderer::new(0)
            .unwrap()
            .render(&cfg.scene, &cfg.pose, &cfg.settings)
            .unwrap();
        let reference = ray_cast(&cfg, 8);
        let (tr, tf) = (reference.iter().sum::<f64>(), frame.pl.iter().sum::<f64>());
        let rel = relative_differences(&reference, &frame.pl);
        let (median, p95) = (rel[rel.len() / 2], rel[rel.len() * 95 / 100]);
        let s = &frame.stats;
        let kept = s.points_kept as f64 / s.points_sampled as f64;
        println!(
            "camera at {camera_m:?}: against the ray cast total {:.2e}, pixels median \
             {median:.2e} p95 {p95:.2e}; {} of {} quadrangles kept, {} surface samples",
            tf / tr - 1.0,
            s.points_kept,
            s.points_sampled,
            s.surface_samples
        );
        assert!((tf / tr - 1.0).abs() < 1e-5, "{tf} vs {tr}");
        assert!(median < 2e-5 && p95 < 5e-5, "{median} {p95}");
        assert!(kept > 0.3, "{kept}");
    }
    // Inside the sphere that bounds the ellipsoid is allowed, inside the ellipsoid is not.
    let inside = SceneSpec {
        camera_m: [0.0, 0.0, 1.0e6],
        ..Default::default()
    };
    let text = reshaped(inside.toml(), &ellipsoid());
    assert_eq!(refusal(&text, "shape.toml").0, "pose.camera_position_m");
}

/// An albedo map on the ellipsoid is read where each surface point lies (its direction from
/// the centre), not at its parameter-space direction: with a map varying in longitude and
/// latitude, the close-range image still matches the ray cast, which looks the map up at each
/// ray's hit. (The renderer takes the map's value at each quadrangle's centre, the ray cast at
/// each ray: the map is smooth enough for that to stay small.)
#[test]
fn an_albedo_map_on_an_ellipsoid_is_read_where_the_surface_is() {
    let dir = TempDir::new("ellipsoid_albedo");
    let tif = dir.join("albedo.tif");
    let (w, h) = (720u32, 360u32);
    let values: Vec<f32> = (0..w * h)
        .map(|i| {
            let lon = ((i % w) as f64 + 0.5) / w as f64 * std::f64::consts::TAU;
            let lat = std::f64::consts::FRAC_PI_2
                - ((i / w) as f64 + 0.5) / h as f64 * std::f64::consts::PI;
            (0.15 + 0.08 * (2.0 * lon).sin() * lat.cos() + 0.04 * (3.0 * lat).sin()) as f32
        })
        .collect();
    write_tiff::<tiff::encoder::colortype::Gray32Float>(&tif, w, h, &values);
    let keys = format!("albedo_map = {{ path = {:?} }}", tif.display().to_string());
    let spec = SceneSpec {
        brdf: "lommel_seeliger",
        albedo: 0.2,
        camera_m: [2.6e6, 1.2e6, 1.0e6],
        sun_m: [AU, 0.5 * AU, 0.3 * AU],
        resolution: [256, 256],
        focal_m: 0.002,
        body: &keys,
        render: "points_per_pixel = 1.0",
        ..Default::default()
    };
    let cfg = optistim::config::parse(&reshaped(spec.toml(), &ellipsoid()), "shape.toml")
        .unwrap_or_else(|e| panic!("{e}"));
    let plain = optistim::config::parse(
        &reshaped(spec.toml_with_body(""), &ellipsoid()),
        "shape.toml",
    )
    .unwrap();
    let render = |cfg: &optistim::config::Config| {
        Renderer::new(0)
            .unwrap()
            .render(&cfg.scene, &cfg.pose, &cfg.settings)
            .unwrap()
            .pl
    };
    let (mapped, reference) = (render(&cfg), ray_cast(&cfg, 8));
    let rel = relative_differences(&reference, &mapped);
    let (median, p95) = (rel[rel.len() / 2], rel[rel.len() * 95 / 100]);
    // For scale: how far the map moves the image from a uniform albedo.
    let off = relative_differences(&render(&plain), &mapped);
    println!(
        "albedo map on the close ellipsoid against the ray cast: median {median:.2e} p95 \
         {p95:.2e} (the map against a uniform albedo: median {:.2e})",
        off[off.len() / 2]
    );
    assert!(median < 2e-3 && p95 < 1e-2, "{median} {p95}");
}

/// `(P/L)` per pixel of an undistorted camera by ray casting the analytic ellipsoid, `n x n`
/// rays per pixel: `A_sun A_cam sum f_r mu0 cos(eps) / d_sun^2 dOmega`, with the ray's solid
/// angle `dOmega = cos^3(eps) / (f_u f_v n^2)` (Eq. 9 with `mu dA / d^2 = dOmega`).
fn ray_cast(cfg: &optistim::config::Config, n: usize) -> Vec<f64> {
    let intr = &cfg.scene.camera.intrinsics;
    let (fu, fv) = intr.focal_px();
    let (shape, brdf) = (&cfg.scene.body.shape, &cfg.scene.body.brdf);
    let (cam, sun) = (cfg.pose.camera_position_m, cfg.pose.sun_position_m);
    let k = cfg.scene.sun.area_m2() * intr.aperture_area_m2();
    let axes = glam::DVec3::from(AXES);
    let w = intr.width_px as usize;
    let mut image = vec![0.0; w * intr.height_px as usize];
    for (px, out) in image.iter_mut().enumerate() {
        let (i, j) = ((px % w) as f64, (px / w) as f64);
        for a in 0..n {
            for b in 0..n {
                let u = i + (a as f64 + 0.5) / n as f64;
                let v = j + (b as f64 + 0.5) / n as f64;
                let (x, y) = intr.unproject(u, v);
                let ray = glam::DVec3::new(x, y, 1.0);
                let cos_eps = 1.0 / ray.length();
                let dir = cfg.pose.body_from_camera * ray.normalize();
                let Some(t) = shape.intersect(cam, dir) else {
                    continue;
                };
                let p = cam + dir * t;
                let normal = (p / (axes * axes)).normalize();
                let to_s = sun - p;
                let g = optistim::brdf::Local::new(normal, to_s.normalize(), -dir);
                if g.mu0 <= 0.0 || g.mu <= 0.0 {
                    continue;
                }
                let d_omega = cos_eps.powi(3) / (fu * fv * (n * n) as f64);
                // An albedo map is read along the hit point's direction from the centre.
                let f_r = match &cfg.scene.body.albedo_map {
                    Some(m) => brdf
                        .with_scale(m.scale_at(p.normalize(), brdf.scale()))
                        .eval(&g),
                    None => brdf.eval(&g),
                };
                *out += k * f_r * g.mu0 * cos_eps / to_s.length_squared() * d_omega;
            }
        }
    }
    image
}
