//! Exposure planning (Sec. 6.3.2, Eqs. 61-62) on the NRHO perilune passage: the bracket each
//! frame gets, checked against a direct count of saturated and under-noise pixels in frames
//! rendered again at the bracket's ends, the saturated ones as the detector's DN show them.

mod common;

use optistim::app::exposure::{self, ExposurePlan};
use optistim::app::products;
use optistim::render::Renderer;
use std::path::Path;

/// `config/nrho_bench.toml` at 256 x 256 px with the same field of view, noise off.
fn scene() -> optistim::config::Config {
    let text = std::fs::read_to_string("config/nrho_bench.toml")
        .unwrap()
        .replace("resolution_px = [1024, 1024]", "resolution_px = [256, 256]")
        .replace("pixel_pitch_m = 5.5e-6", "pixel_pitch_m = 2.2e-5")
        .replace("shot = true", "shot = false");
    optistim::config::parse(&text, "config/nrho_bench_256.toml").unwrap()
}

#[test]
fn perilune_bracket_matches_a_direct_count() {
    let poses =
        optistim::trajectory::read(Path::new("../shared/trajectories/nrho_2orbits.csv")).unwrap();
    // The perilune passage: 40 frames either side of the closest approach, every 8th.
    let closest = (0..poses.len())
        .min_by(|&a, &b| {
            let r = |i: usize| poses[i].1.camera_position_m.length();
            r(a).total_cmp(&r(b))
        })
        .unwrap();
    let passage: Vec<_> = poses[closest - 40..=closest + 40]
        .iter()
        .step_by(8)
        .copied()
        .collect();
    let mut config = scene();
    let keep = 0.95;
    let report = exposure::run(
        &config,
        &passage,
        ExposurePlan {
            keep,
            dnr_db: None,
            threads: 2,
        },
        &mut |_, _| {},
    )
    .unwrap();
    // DNR from the detector: 20 log10(20000 e- / 3 e-).
    assert!((report.dnr_db - 20.0 * (20000.0f64 / 3.0).log10()).abs() < 1e-9);
    assert_eq!(report.frames.len(), passage.len());
    let phases: Vec<f64> = report.frames.iter().map(|f| f.phase_deg).collect();
    let spread = phases.iter().cloned().fold(f64::MIN, f64::max)
        - phases.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 20.0, "the passage sweeps the phase: {phases:?}");

    let mut renderer = Renderer::new(2).unwrap();
    let fwc = report.full_well_e;
    let floor = report.noise_floor_e;
    let det0 = config.scene.camera.detector.clone();
    let dn_full_well = (det0.offset_dn + det0.adc_gain_dn_per_e * fwc).round() as u16;
    for (f, (_, pose)) in report.frames.iter().zip(&passage) {
        assert!(f.active_px > 1000 && f.bracketed, "{f:?}");
        assert!(f.t_lo_s < f.t_hi_s);
        // A separate render of the same frame, its signal counted directly.
        let (_, images) = products::make(&config, None, pose, &mut renderer).unwrap();
        let s: Vec<f64> = images
            .signal_e_per_s
            .iter()
            .copied()
            .filter(|&x| x > 0.0)
            .collect();
        assert_eq!(s.len(), f.active_px);
        let n = s.len() as f64;
        let saturated = |t: f64| s.iter().filter(|&&x| x * t > fwc).count() as f64 / n;
        let above_noise = |t: f64| s.iter().filter(|&&x| x * t >= floor).count() as f64 / n;
        // At its ends the bracket holds, and just beyond them it does not.
        assert!(saturated(f.t_hi_s) <= 1.0 - keep, "{f:?}");
        assert!(saturated(f.t_hi_s * 1.001) > 1.0 - keep, "{f:?}");
        assert!(above_noise(f.t_lo_s) >= keep, "{f:?}");
        assert!(above_noise(f.t_lo_s * 0.999) < keep, "{f:?}");
        // The detector agrees: exposed for just beyond t_hi (noise off), more than 1 - X of
        // the active pixels sit at the full-well DN; just inside, at most 1 - X.
        for (t, over) in [(f.t_hi_s * 0.999, false), (f.t_hi_s * 1.001, true)] {
            config.scene.camera.detector.exposure_s = t;
            let mut dn = Vec::new();
            config.scene.camera.detector.expose(
                &images.signal_e_per_s,
                (256, 256),
                pose.frame_id,
                &mut dn,
            );
            let at_cap = images
                .signal_e_per_s
                .iter()
                .zip(&dn)
                .filter(|(s, d)| **s > 0.0 && **d >= dn_full_well)
                .count() as f64
                / n;
            assert_eq!(
                at_cap > 1.0 - keep,
                over,
                "t = {t}: {at_cap} at the full well"
            );
        }
        config.scene.camera.detector.exposure_s = det0.exposure_s;
    }
    // The trajectory's bracket is the intersection of the frames'.
    let (lo, hi) = report.bracket_s.expect("one exposure serves the passage");
    let max_lo = report.frames.iter().map(|f| f.t_lo_s).fold(0.0, f64::max);
    let min_hi = report
        .frames
        .iter()
        .map(|f| f.t_hi_s)
        .fold(f64::MAX, f64::min);
    assert_eq!((lo, hi), (max_lo, min_hi));
    // The outputs.
    let dir = common::TempDir::new("exposure");
    exposure::write(&report, &dir.join("")).unwrap();
    for name in [
        "frames.csv",
        "loss.csv",
        "pooled.csv",
        "exposure.png",
        "exposure.svg",
    ] {
        assert!(dir.join(name).metadata().unwrap().len() > 100, "{name}");
    }
    let frames = std::fs::read_to_string(dir.join("frames.csv")).unwrap();
    assert_eq!(frames.lines().count(), passage.len() + 1);
}

#[test]
fn a_detector_without_readout_noise_needs_a_dynamic_range() {
    let text = std::fs::read_to_string("config/nrho_bench.toml")
        .unwrap()
        .replace("readout_sigma_e = 3.0", "");
    let config = optistim::config::parse(&text, "nrho_no_readout.toml").unwrap();
    let err = exposure::dynamic_range_db(&config, None).unwrap_err();
    assert!(err.to_string().contains("--dnr-db"), "{err}");
    assert_eq!(
        exposure::dynamic_range_db(&config, Some(60.0)).unwrap(),
        60.0
    );
    assert!(exposure::dynamic_range_db(&config, Some(-1.0)).is_err());
}
