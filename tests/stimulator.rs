//! The stimulator chain end to end (issue 4; the paper's Fig. 39 in simulation): render ->
//! F_eff -> screen DN through the calibration -> the simulated camera's image of the screen,
//! compared with the image the flight camera would take in space.

mod common;
use common::{TempDir, rendered_signal, write_tiff};
use optistim::config::{self, Config};
use optistim::detector::noise::Noise;
use optistim::stimulator::Stimulator;
use optistim::stimulator::calibrate::{Provenance, SimulatedBench, calibrate};
use optistim::stimulator::calibration::{Curve, Interp};
use optistim::stimulator::camera::SimulatedCamera;
use std::path::PathBuf;
use std::sync::Arc;

/// `config/stimulator.toml` (the Moon at 20,000 km on a RETINA-like screen, 10 bit), noise
/// off so that the comparison sees the chain, not the noise.
fn moon_on_screen() -> Config {
    let mut cfg = config::load(&PathBuf::from("config/stimulator.toml")).unwrap();
    cfg.scene.camera.detector.noise = Noise::default();
    cfg
}

/// The Fig. 39 comparison: totals of (DN - offset) and the median per-pixel relative
/// difference over lit pixels (at least 100 electrons in the direct image).
struct Comparison {
    total: f64,
    median: f64,
    lit: usize,
}

impl Comparison {
    fn passes(&self) -> bool {
        self.total.abs() < 0.01 && self.median < 0.02
    }
}

/// Renders the scene, shows it on the screen through `calibration` and images the screen with
/// the simulated camera whose screen truly responds as `truth`.
fn compare(cfg: &Config, calibration: Curve, truth: Curve) -> Comparison {
    let det = &cfg.scene.camera.detector;
    let intr = &cfg.scene.camera.intrinsics;
    let st = cfg.stimulator.as_ref().unwrap();
    let signal = rendered_signal(cfg);
    let mut direct = Vec::new();
    det.expose(
        &signal,
        (intr.width_px as usize, intr.height_px as usize),
        0,
        &mut direct,
    );

    let stim = Stimulator::with_curve(st, intr, det, Arc::new(calibration)).unwrap();
    let shown = stim.process(&signal).unwrap();
    assert_eq!(shown.clips.above_max, 0);
    let camera = SimulatedCamera::new(st, truth, intr, det).unwrap();
    let seen = camera.capture(&shown.screen_dn, 0).unwrap();

    let off = det.offset_dn;
    let lit_e = 100.0 * det.adc_gain_dn_per_e;
    let (mut sum_d, mut sum_c) = (0.0, 0.0);
    let mut rel = Vec::new();
    for (&d, &c) in direct.iter().zip(&seen.dn) {
        let (d, c) = (d as f64 - off, c as f64 - off);
        sum_d += d;
        sum_c += c;
        if d >= lit_e {
            rel.push(((c - d) / d).abs());
        }
    }
    rel.sort_by(f64::total_cmp);
    let cmp = Comparison {
        total: sum_c / sum_d - 1.0,
        median: rel[rel.len() / 2],
        lit: rel.len(),
    };
    eprintln!(
        "total (DN - offset) camera/direct - 1 = {:+.3e}, median |diff| on {} lit px = {:.3e}",
        cmp.total, cmp.lit, cmp.median
    );
    cmp
}

fn example(interp: Interp) -> Curve {
    Curve::load(&PathBuf::from("calibration/example_gamma22.csv"), interp).unwrap()
}

/// A screen that does not respond as its calibration says: gamma 2.0 instead of 2.2 and 10 %
/// brighter at the top (the example's header, other points).
fn wrong_curve() -> Curve {
    let mut text = String::from(
        "# optistim screen calibration v1\n# date: 2026-11-22\n# facility: test\n# method: \
         synthetic, gamma 2.0\n# dn_full_scale: 255\ndn,feff_w_m2\n",
    );
    for dn in (0..=255).step_by(15) {
        let f = 2e-9 + (1.32e-5 - 2e-9) * (dn as f64 / 255.0).powf(2.0);
        text.push_str(&format!("{dn},{f:.6e}\n"));
    }
    Curve::parse(text.as_bytes(), "wrong", "<wrong>", Interp::Pchip).unwrap()
}

#[test]
fn the_camera_sees_on_the_screen_what_it_would_see_in_space() {
    let cfg = moon_on_screen();
    let st = cfg.stimulator.as_ref().unwrap();
    assert_eq!(st.screen_bits, 10);
    let cmp = compare(&cfg, example(Interp::Pchip), example(Interp::Pchip));
    assert!(cmp.lit > 100_000, "{} lit pixels", cmp.lit);
    assert!(
        cmp.passes(),
        "total {:+.3e} median {:.3e}",
        cmp.total,
        cmp.median
    );
}

#[test]
fn a_wrong_calibration_is_caught_by_the_same_comparison() {
    let cfg = moon_on_screen();
    let cmp = compare(&cfg, example(Interp::Pchip), wrong_curve());
    assert!(
        !cmp.passes(),
        "a mis-calibrated screen passed: total {:+.3e} median {:.3e}",
        cmp.total,
        cmp.median
    );
}

/// Replaying a curve changes the next frame and the frame says which curve made it.
#[test]
fn a_replayed_curve_is_used_and_reported() {
    let cfg = moon_on_screen();
    let det = &cfg.scene.camera.detector;
    let intr = &cfg.scene.camera.intrinsics;
    let st = cfg.stimulator.as_ref().unwrap();
    let signal = rendered_signal(&cfg);
    let mut stim = Stimulator::new(st, intr, det).unwrap();
    let a = stim.process(&signal).unwrap();
    let old = stim.replay(Arc::new(wrong_curve())).unwrap();
    assert_eq!(old.id, "example_gamma22");
    let b = stim.process(&signal).unwrap();
    assert_eq!(a.calibration_id, "example_gamma22");
    assert_eq!(b.calibration_id, "wrong");
    assert_ne!(a.calibration_sha256, b.calibration_sha256);
    assert_ne!(a.screen_dn, b.screen_dn);
}

/// `optistim calibrate`'s core on the simulated bench: the measured curve reproduces the
/// screen's true response at the measured codes, and half-way codes are reported as residuals.
#[test]
fn calibrating_the_simulated_screen_recovers_its_response() {
    let cfg = moon_on_screen();
    let det = &cfg.scene.camera.detector;
    let intr = &cfg.scene.camera.intrinsics;
    let st = cfg.stimulator.as_ref().unwrap();
    let truth = example(Interp::Pchip);
    let camera = SimulatedCamera::new(st, truth.clone(), intr, det).unwrap();
    let mut bench = SimulatedBench::new(camera, st.screen_px);
    let run = calibrate(
        &mut bench,
        st.levels(),
        33,
        Interp::Pchip,
        Provenance {
            date: "2026-11-22",
            facility: "test",
        },
    )
    .unwrap();
    let top = (st.levels() - 1) as f64;
    let mut worst = 0.0f64;
    for p in &run.points {
        let f = truth.feff_at(0, p.code as f64 / top * truth.dn_full_scale);
        worst = worst.max((p.feff_w_m2 / f - 1.0).abs());
    }
    eprintln!(
        "measured vs true at the ramp codes: {worst:.2e}; half-way residual max {:.2e}",
        run.max_abs_residual
    );
    assert!(worst < 2e-3, "{worst}");
    // Measured: 8e-4 at the ramp codes, 7.7e-3 half-way (near the dark end).
    assert!(run.max_abs_residual < 0.02, "{}", run.max_abs_residual);
    // The written file is a valid curve.
    Curve::parse(run.csv.as_bytes(), "m", "<m>", Interp::Pchip).unwrap();
}

/// Bad `[stimulator]` values name the file, the key, the value and what is allowed.
#[test]
fn bad_stimulator_sections_say_what_is_wrong() {
    let text = std::fs::read_to_string("config/stimulator.toml").unwrap();
    let cases = [
        (
            "screen_bit_depth = 10",
            "screen_bit_depth = 12",
            "stimulator.screen_bit_depth",
            "8 or 10",
        ),
        (
            "dither = \"ordered\"",
            "dither = \"blue\"",
            "stimulator.dither",
            "ordered",
        ),
        (
            "collimator_focal_length_m = 0.04472727272727273",
            "collimator_focal_length_m = 0.05",
            "stimulator.mapping",
            "area",
        ),
        (
            "# region_origin_px = [448, 88]",
            "region_origin_px = [1000, 88]",
            "stimulator.region_origin_px",
            "1024 x 1024 screen px inside the 1920 x 1200 screen",
        ),
        (
            "collimator_transmittance = 1.0",
            "collimator_transmittance = 1.5",
            "stimulator.collimator_transmittance",
            "(0, 1]",
        ),
        (
            "screen_pixel_pitch_m = 8.2e-6",
            "screen_pixel_pitch_m = nan",
            "stimulator.screen_pixel_pitch_m",
            "> 0",
        ),
    ];
    for (from, to, key, allowed) in cases {
        assert!(text.contains(from), "{from}");
        let e = config::parse(&text.replace(from, to), "config/stimulator.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("config/stimulator.toml") && e.contains(key) && e.contains(allowed),
            "{to}: {e}"
        );
    }
    // A missing curve file is named when the stimulator starts.
    let cfg = config::parse(
        &text.replace("example_gamma22.csv\"", "no_such_curve.csv\""),
        "config/stimulator.toml",
    )
    .unwrap();
    let cam = &cfg.scene.camera;
    let e = Stimulator::new(
        cfg.stimulator.as_ref().unwrap(),
        &cam.intrinsics,
        &cam.detector,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("no_such_curve.csv"), "{e}");
}

/// A measured non-uniformity map (`screen_non_uniformity_map`, a float TIFF of the region's
/// size) replaces the radial model: a map of 0.5 on the left half of the region halves what
/// the simulated camera sees there and leaves the right half as it was; a map of the wrong
/// size is refused with both sizes.
#[test]
fn a_non_uniformity_map_scales_what_the_camera_sees() {
    let mut cfg = moon_on_screen();
    let st = cfg.stimulator.clone().unwrap();
    let (intr, det) = (&cfg.scene.camera.intrinsics, &cfg.scene.camera.detector);
    let stim = Stimulator::new(&st, intr, det).unwrap();
    let [rw, rh] = stim.resampler().region_px();
    let shown = stim.process(&rendered_signal(&cfg)).unwrap();
    let flat = SimulatedCamera::from_config(&st, intr, det)
        .unwrap()
        .capture(&shown.screen_dn, 0)
        .unwrap();

    let dir = TempDir::new("nu");
    let write = |name: &str, w: usize, h: usize| {
        let path = dir.join(name);
        let gains: Vec<f32> = (0..w * h)
            .map(|i| if i % w < w / 2 { 0.5 } else { 1.0 })
            .collect();
        write_tiff::<tiff::encoder::colortype::Gray32Float>(&path, w as u32, h as u32, &gains);
        path
    };
    let st_map = cfg.stimulator.as_mut().unwrap();
    st_map.non_uniformity_map = Some(write("half.tif", rw, rh));
    let halved = SimulatedCamera::from_config(st_map, intr, det)
        .unwrap()
        .capture(&shown.screen_dn, 0)
        .unwrap();
    // One to one: camera column i sees region column i.
    let n = intr.width_px as usize;
    let half = |img: &[f64], left: bool| -> f64 {
        img.chunks(n)
            .map(|row| {
                if left {
                    row[..n / 2].iter().sum::<f64>()
                } else {
                    row[n / 2..].iter().sum()
                }
            })
            .sum()
    };
    let left = half(&halved.signal_e_per_s, true) / half(&flat.signal_e_per_s, true);
    let right = half(&halved.signal_e_per_s, false) / half(&flat.signal_e_per_s, false);
    assert!(
        (left - 0.5).abs() < 1e-9 && (right - 1.0).abs() < 1e-9,
        "{left} {right}"
    );

    st_map.non_uniformity_map = Some(write("small.tif", 16, 16));
    let e = SimulatedCamera::from_config(st_map, intr, det)
        .err()
        .expect("refused");
    assert!(e.to_string().contains("16 x 16 px"), "{e}");
}
