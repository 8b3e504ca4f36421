//! The GPU presenter's LUT pass, off-screen on whatever adapter wgpu finds (in CI: Mesa's
//! software Vulkan driver, lavapipe, which `.ci/run` installs): every screen pixel equals the
//! CPU reference (`Stimulator::process`) within 1 LSB.

mod common;
use common::rendered_signal;
use optistim::config;
use optistim::display::Presenter;
use optistim::stimulator::Stimulator;
use optistim::stimulator::dither::Dither;
use std::path::PathBuf;

fn check(bits: u32, dither: Dither) {
    let mut cfg = config::load(&PathBuf::from("config/stimulator.toml")).unwrap();
    let st = cfg.stimulator.as_mut().unwrap();
    st.screen_bits = bits;
    st.dither = dither;
    let st = cfg.stimulator.clone().unwrap();
    let cam = &cfg.scene.camera;
    let signal = rendered_signal(&cfg);
    let stim = Stimulator::new(&st, &cam.intrinsics, &cam.detector).unwrap();
    let cpu = stim.process(&signal).unwrap();

    let mut presenter = Presenter::new_headless(bits).unwrap_or_else(|e| panic!("{e}"));
    presenter.set_inverse(stim.inverse()).unwrap();
    let region = stim.resampler().region_px();
    let mut gpu = Vec::new();
    let mut times = Vec::new();
    for _ in 0..3 {
        let t = presenter
            .draw_offscreen(&st, region, &cpu.region_feff_w_m2, &mut gpu)
            .unwrap();
        times.push(t);
    }
    assert_eq!(gpu.len(), cpu.screen_dn.len());
    let (mut exact, mut off_by_one, mut worse) = (0usize, 0usize, 0usize);
    for (&g, &c) in gpu.iter().zip(&cpu.screen_dn) {
        match (g as i32 - c as i32).abs() {
            0 => exact += 1,
            1 => off_by_one += 1,
            _ => worse += 1,
        }
    }
    eprintln!(
        "{} | {bits} bit {dither:?}: {exact} px equal, {off_by_one} within 1 LSB, {worse} worse; \
         timings {:?}",
        presenter.adapter(),
        times.last().unwrap()
    );
    assert_eq!(worse, 0, "{worse} pixels differ by more than 1 LSB");
    // The region is not trivially dark: most of the Moon's pixels are above code 0.
    assert!(gpu.iter().filter(|&&x| x > 0).count() > 400_000);
}

#[test]
fn the_lut_pass_matches_the_cpu_reference_at_10_bit_dithered() {
    check(10, Dither::Ordered);
}

#[test]
fn the_lut_pass_matches_the_cpu_reference_at_10_bit_blue_noise() {
    check(10, Dither::BlueNoise);
}

#[test]
fn the_lut_pass_matches_the_cpu_reference_at_8_bit() {
    check(8, Dither::None);
}

/// A colour screen before a three-band camera (`config/stimulator_rgb.toml`): the pass solves
/// every pixel for its R, G, B codes through the cross-talk, as the CPU does, within 1 LSB on
/// every primary.
#[test]
fn the_colour_pass_matches_the_cpu_reference_within_one_lsb() {
    let cfg = config::load(&PathBuf::from("config/stimulator_rgb.toml")).unwrap();
    let st = cfg.stimulator.clone().unwrap();
    let cam = &cfg.scene.camera;
    let frame = optistim::render::Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    let size = (
        cam.intrinsics.width_px as usize,
        cam.intrinsics.height_px as usize,
    );
    let factors = cfg.scene.band_factors();
    let (signal, _) = cam.detector.image(|b| frame.band(b), size, &factors, 0);
    let stim = Stimulator::new(&st, &cam.intrinsics, &cam.detector).unwrap();
    assert_eq!(stim.dither_shift(), 1, "a Bayer camera spreads the dither");
    let cpu = stim.process(&signal).unwrap();

    let mut presenter = Presenter::new_headless(st.screen_bits).unwrap_or_else(|e| panic!("{e}"));
    let colour = stim.colour().expect("a colour screen");
    presenter
        .set_colour(stim.inverses(), colour, stim.dither_shift())
        .unwrap();
    let region = stim.resampler().region_px();
    let mut gpu = Vec::new();
    let t = presenter
        .draw_offscreen(&st, region, &cpu.region_feff_w_m2, &mut gpu)
        .unwrap();
    assert_eq!(gpu.len(), cpu.screen_dn.len());
    let n = st.screen_px[0] * st.screen_px[1];
    for (c, name) in ["R", "G", "B"].iter().enumerate() {
        let (g, k) = (&gpu[c * n..(c + 1) * n], &cpu.screen_dn[c * n..(c + 1) * n]);
        let (mut exact, mut off_by_one, mut worse) = (0usize, 0usize, 0usize);
        for (&a, &b) in g.iter().zip(k) {
            match (a as i32 - b as i32).abs() {
                0 => exact += 1,
                1 => off_by_one += 1,
                _ => worse += 1,
            }
        }
        eprintln!(
            "{} | {name}: {exact} px equal, {off_by_one} within 1 LSB, {worse} worse; timings {t:?}",
            presenter.adapter()
        );
        assert_eq!(worse, 0, "{name}: {worse} pixels differ by more than 1 LSB");
        assert!(g.iter().filter(|&&x| x > 0).count() > 400_000, "{name}");
    }
    // Back to a grey curve: one plane again.
    let grey = config::load(&PathBuf::from("config/stimulator.toml")).unwrap();
    let gst = grey.stimulator.clone().unwrap();
    let gstim = Stimulator::new(
        &gst,
        &grey.scene.camera.intrinsics,
        &grey.scene.camera.detector,
    )
    .unwrap();
    presenter.set_inverse(gstim.inverse()).unwrap();
    let flat = vec![1e-6; region[0] * region[1]];
    presenter
        .draw_offscreen(&gst, region, &flat, &mut gpu)
        .unwrap();
    assert_eq!(gpu.len(), n);
}
