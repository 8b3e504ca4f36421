//! Hapke inversion (issue 16, item 6): images of Bennu's shape model rendered with known
//! Hapke parameters, with shot and read noise, give them back within their estimated
//! uncertainties.

mod common;
use common::*;
use optistim::config::Config;
use optistim::inversion::{Image, NAMES, invert};
use optistim::render::Renderer;

const TRUTH: [f64; 6] = [0.25, 0.21, 0.85, 1.8, 0.07, 0.4084];

/// Bennu (km) seen from 1.2 km at `phase_deg`, the Sun in the equator.
fn scene(phase_deg: f64) -> Config {
    let path = std::fs::canonicalize("../shared/shapes/bennu_12k.obj").unwrap();
    let a = phase_deg.to_radians();
    let spec = SceneSpec {
        brdf: "hapke",
        albedo: TRUTH[0],
        resolution: [192, 192],
        focal_m: 0.0016,
        camera_m: [1200.0 * a.cos(), 1200.0 * a.sin(), 100.0],
        sun_m: [AU, 0.0, 0.0],
        noise: "shot = true\nreadout_sigma_e = 5.0",
        body: &format!(
            "hapke = [{}, {}, 0.0, 1.0, {}, {}, {}, 0.0]",
            TRUTH[1], TRUTH[2], TRUTH[3], TRUTH[4], TRUTH[5]
        ),
        ..Default::default()
    };
    let text = spec
        .toml()
        .replace(
            &format!("radius_m = {R_MOON}\n"),
            &format!(
                "shape = \"mesh\"\nmesh = {{ path = \"{}\", units = \"km\" }}\n",
                path.display()
            ),
        )
        .replace(
            "albedo_type = \"normal\"",
            "albedo_type = \"single_scattering\"",
        );
    let mut cfg = optistim::config::parse(&text, "<test>").unwrap_or_else(|e| panic!("{e}"));
    // An exposure that puts the brightest pixel near two thirds of the full well.
    let frame = Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    let peak = frame.pl.iter().cloned().fold(0.0, f64::max) * cfg.scene.signal_factor();
    let det = &mut cfg.scene.camera.detector;
    det.exposure_s = 0.66 * det.full_well_e / peak;
    det.adc_gain_dn_per_e = det.adc_max_dn() / det.full_well_e;
    cfg
}

#[test]
fn hapke_parameters_come_back_from_noisy_images_within_their_uncertainties() {
    let configs: Vec<Config> = [2.0, 25.0, 55.0, 85.0].iter().map(|&a| scene(a)).collect();
    let dns: Vec<Vec<u16>> = configs
        .iter()
        .map(|cfg| {
            let frame = Renderer::new(0)
                .unwrap()
                .render(&cfg.scene, &cfg.pose, &cfg.settings)
                .unwrap();
            let intr = &cfg.scene.camera.intrinsics;
            let size = (intr.width_px as usize, intr.height_px as usize);
            cfg.scene.record(|_| &frame.pl[..], size, 7).1
        })
        .collect();
    let images: Vec<Image> = configs
        .iter()
        .zip(&dns)
        .map(|(cfg, dn)| Image {
            scene: &cfg.scene,
            pose: cfg.pose,
            dn,
        })
        .collect();
    let start = [0.5, 0.4, 0.5, 1.0, 0.2, 0.3];
    let fit = invert(&images, start, 1).unwrap_or_else(|e| panic!("{e}"));
    eprintln!(
        "{} pixels, {} iterations, chi2/dof {:.3}, histogram chi2 {:.1} ({:.2e} per pixel)",
        fit.pixels, fit.iterations, fit.chi2_per_dof, fit.chi2_histogram, fit.chi2_histogram_per_px
    );
    for k in 0..6 {
        eprintln!(
            "{:>9}: {:.4} +- {:.4} (true {:.4}, {:+.2} sigma)",
            NAMES[k],
            fit.params[k],
            fit.sigma[k],
            TRUTH[k],
            (fit.params[k] - TRUTH[k]) / fit.sigma[k]
        );
    }
    assert!(fit.pixels > 10_000);
    assert!((fit.chi2_per_dof - 1.0).abs() < 0.1, "{}", fit.chi2_per_dof);
    for k in 0..6 {
        assert!(
            (fit.params[k] - TRUTH[k]).abs() <= 3.0 * fit.sigma[k],
            "{}: {} +- {} vs {}",
            NAMES[k],
            fit.params[k],
            fit.sigma[k],
            TRUTH[k]
        );
        assert!(
            fit.sigma[k] < 0.2 * TRUTH[k].max(0.1),
            "{} poorly constrained",
            NAMES[k]
        );
    }
}

#[test]
fn optistim_invert_reads_rendered_pngs() {
    // The command's path: scenes in memory, their image.png written by `optistim render`.
    let dir = std::env::temp_dir().join(format!("optistim-invert-{}", std::process::id()));
    let mut pairs = Vec::new();
    for (k, a) in [3.0, 40.0, 80.0].iter().enumerate() {
        let cfg = scene(*a);
        let out = dir.join(format!("img{k}"));
        optistim::app::render::run(
            &cfg,
            "bennu",
            &out,
            optistim::app::render::Method::Quadrangle,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        pairs.push((cfg, out.join("image.png")));
    }
    let fit = optistim::app::invert::run(&pairs, [0.5, 0.4, 0.5, 1.0, 0.2, 0.3], 1)
        .unwrap_or_else(|e| panic!("{e}"));
    for k in 0..6 {
        assert!(
            (fit.params[k] - TRUTH[k]).abs() <= 3.0 * fit.sigma[k],
            "{}: {} +- {}",
            NAMES[k],
            fit.params[k],
            fit.sigma[k]
        );
    }
    // A wrong image size is named.
    let (cfg, _) = &pairs[0];
    let mut small = cfg.clone();
    small.scene.camera.intrinsics.width_px = 100;
    let e = optistim::app::invert::run(&[(small, pairs[1].1.clone())], [0.5; 6], 1).unwrap_err();
    assert!(e.to_string().contains("192 x 192 pixels"), "{e}");
}
