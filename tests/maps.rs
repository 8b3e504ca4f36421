//! Albedo maps in the renderer (issue 3, item 1, part): a uniform map equals the constant
//! albedo; a two-valued map shows its two albedos on the two halves of the disk; the shared
//! lunar map renders through `config/moon.toml`.

mod common;
use common::*;
use optistim::body::AlbedoMap;
use optistim::body::maps::{Encoding, Map};
use optistim::render::Renderer;
use std::path::Path;
use std::sync::Arc;

fn total(cfg: &optistim::config::Config) -> (f64, Vec<f64>) {
    let f = Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    (f.pl.iter().sum(), f.pl)
}

fn with_map(values: impl Fn(usize) -> f64, w: usize, h: usize) -> optistim::config::Config {
    let mut cfg = SceneSpec {
        albedo: 0.2,
        // Zero phase, the camera over longitude 0.
        camera_m: [10.0 * R_MOON, 0.0, 0.0],
        ..Default::default()
    }
    .config();
    let map = Map::from_values(
        Path::new("test"),
        w,
        h,
        (0..w * h).map(|i| values(i % w)).collect(),
        &Encoding::default(),
    )
    .unwrap();
    // The spec's albedo is a normal albedo: for Lambert, scale = value (rho = p_N).
    let scale_per_value = cfg.scene.body.brdf.scale() / 0.2;
    cfg.scene.body.albedo_map = Some(AlbedoMap {
        map: Arc::new(map),
        scale_per_value,
    });
    cfg
}

#[test]
fn a_uniform_map_renders_as_the_constant_albedo() {
    let plain = SceneSpec {
        albedo: 0.2,
        camera_m: [10.0 * R_MOON, 0.0, 0.0],
        ..Default::default()
    }
    .config();
    let (t0, _) = total(&plain);
    let (t1, _) = total(&with_map(|_| 0.2, 16, 8));
    // Maps hold f32: 0.2 is 0.2 to 1.5e-8.
    assert!((t1 / t0 - 1.0).abs() < 1e-7, "{t1} vs {t0}");
}

#[test]
fn a_two_valued_map_shows_both_albedos_on_their_halves() {
    // West of longitude 0 (the left half of the map's columns): 0.1; east: 0.3. Bilinear
    // interpolation blends the two over one texel (0.18 deg at 2048 columns) about lon 0.
    let w = 2048;
    let cfg = with_map(|c| if c < w / 2 { 0.1 } else { 0.3 }, w, 32);
    let (_, pl) = total(&cfg);
    let n = cfg.scene.camera.intrinsics.width_px as usize;
    let (mut left, mut right) = (0.0, 0.0);
    for row in pl.chunks(n) {
        left += row[..n / 2].iter().sum::<f64>();
        right += row[n / 2..].iter().sum::<f64>();
    }
    let ratio = left.max(right) / left.min(right);
    eprintln!("half-disk flux ratio {ratio:.5} (map 3)");
    assert!((ratio - 3.0).abs() < 0.05, "{ratio}");
}

#[test]
fn the_moon_renders_with_the_shared_albedo_map() {
    let cfg =
        optistim::config::load(Path::new("config/moon.toml")).unwrap_or_else(|e| panic!("{e}"));
    let map = cfg
        .scene
        .body
        .albedo_map
        .as_ref()
        .expect("config/moon.toml has a map");
    assert_eq!((map.map.width, map.map.height), (2048, 1024));
    let (t, pl) = total(&cfg);
    assert!(t.is_finite() && t > 0.0);
    // Maria and highlands: the lit pixels span a wide range of brightness.
    let mut lit: Vec<f64> = pl.into_iter().filter(|&v| v > 0.0).collect();
    lit.sort_by(f64::total_cmp);
    let (p10, p90) = (lit[lit.len() / 10], lit[lit.len() * 9 / 10]);
    assert!(p90 / p10 > 1.8, "{p10} .. {p90}");
}
