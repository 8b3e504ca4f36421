//! Multi-band cameras (issue 17): the geometry is rendered once and every band's signal is
//! that (P/L) times the band's own integral of Eq. 45; a Bayer sensor records each pixel's
//! band; `power.fits` and `signal.fits` are cubes, `image.png` is RGB (or the raw mosaic).

mod common;

use common::{SceneSpec, refusal};
use optistim::app::products;
use optistim::config::{self, Config};
use optistim::radiometry::{C, H, K_B};
use optistim::render::Renderer;

const MONO_QE: &str = "qe = { wavelength_nm = [400, 700, 1000], value = [0.5, 0.6, 0.2] }";

/// Three flat bands: R 600-700 nm (QE 0.4), G 500-600 (0.6), B 400-500 (0.5).
const RGB: [(&str, f64, f64, f64); 3] = [
    ("R", 600.0, 700.0, 0.4),
    ("G", 500.0, 600.0, 0.6),
    ("B", 400.0, 500.0, 0.5),
];

/// The scene of `spec` with the camera's one QE curve replaced by `bands` (and `extra`
/// camera keys, e.g. the mosaic).
fn with_bands(spec: &SceneSpec, extra: &str, bands: &[(&str, f64, f64, f64)]) -> String {
    let tables = band_tables(bands);
    let text = spec.toml();
    assert!(text.contains(MONO_QE));
    text.replace(MONO_QE, &format!("{extra}\n{tables}"))
}

/// `[[camera.band]]` tables of flat bands `(name, from nm, to nm, QE)`.
fn band_tables(bands: &[(&str, f64, f64, f64)]) -> String {
    bands
        .iter()
        .map(|(name, lo, hi, qe)| {
            format!(
                "\n[[camera.band]]\nname = \"{name}\"\n\
                 qe = {{ wavelength_nm = [{lo}, {hi}], value = [{qe}, {qe}] }}\n"
            )
        })
        .collect()
}

fn parse(text: &str) -> Config {
    config::parse(text, "<test>").unwrap_or_else(|e| panic!("{e}"))
}

/// `G(a) = integral from a to infinity of x^2 / (e^x - 1) dx = sum_n e^(-n a) (a^2/n + 2a/n^2
/// + 2/n^3)`: the photon count of a black body above `x = h c / (lambda k T)`.
fn g(a: f64) -> f64 {
    (1..200)
        .map(|n| {
            let n = n as f64;
            (-n * a).exp() * (a * a / n + 2.0 * a / (n * n) + 2.0 / (n * n * n))
        })
        .sum()
}

/// The factor of Eq. 45 of a flat band `[lo, hi]` nm of QE `qe` (transmittance 1) under a
/// black body of `t_k` scaled by `scale`, in closed form: the photon radiance
/// `2 c (k T / h c)^3 [G(x_hi) - G(x_lo)]`.
fn analytic_factor(lo_nm: f64, hi_nm: f64, qe: f64, t_k: f64, scale: f64) -> f64 {
    let x = |nm: f64| H * C / (nm * 1e-9 * K_B * t_k);
    scale * qe * 2.0 * C * (K_B * t_k / (H * C)).powi(3) * (g(x(hi_nm)) - g(x(lo_nm)))
}

#[test]
fn every_band_is_the_one_render_times_its_own_band_integral() {
    let spec = SceneSpec {
        resolution: [96, 96],
        ..Default::default()
    };
    let cfg = parse(&with_bands(&spec, "", &RGB));
    let det = &cfg.scene.camera.detector;
    assert_eq!(det.bands.len(), 3);
    let mut r = Renderer::new(0).unwrap();
    let frame = r.render(&cfg.scene, &cfg.pose, &cfg.settings).unwrap();
    let n = frame.width * frame.height;
    let (signal, dn) = cfg
        .scene
        .record(|_| &frame.pl[..], (frame.width, frame.height), 0);
    assert_eq!(signal.len(), 3 * n);
    assert_eq!(dn.len(), 3 * n, "a full image per band");
    let factors = cfg.scene.band_factors();
    for (b, &(name, lo, hi, qe)) in RGB.iter().enumerate() {
        let want = analytic_factor(lo, hi, qe, 5782.0, 1.0);
        let rel = factors[b] / want - 1.0;
        assert!(
            rel.abs() < 1e-9,
            "{name}: {} vs {want}: {rel:e}",
            factors[b]
        );
        // Every pixel of the band is the one (P/L) image times its factor.
        let plane = &signal[b * n..(b + 1) * n];
        for (s, pl) in plane.iter().zip(&frame.pl) {
            assert!((s - pl * want).abs() <= 1e-9 * (pl * want).abs(), "{name}");
        }
    }
    // The ratio of two bands' total signals is the ratio of their integrals.
    let total = |b: usize| signal[b * n..(b + 1) * n].iter().sum::<f64>();
    let ratio = total(0) / total(2);
    let want = analytic_factor(600.0, 700.0, 0.4, 5782.0, 1.0)
        / analytic_factor(400.0, 500.0, 0.5, 5782.0, 1.0);
    assert!((ratio / want - 1.0).abs() < 1e-9, "{ratio} vs {want}");
}

#[test]
fn a_bayer_sensor_records_each_pixels_own_band() {
    let spec = SceneSpec {
        resolution: [64, 48],
        camera_m: [4.0 * common::R_MOON, 0.0, 0.0],
        ..Default::default()
    };
    let planes = parse(&with_bands(&spec, "", &RGB));
    let mut r = Renderer::new(0).unwrap();
    let frame = r
        .render(&planes.scene, &planes.pose, &planes.settings)
        .unwrap();
    let size = (frame.width, frame.height);
    let n = size.0 * size.1;
    let (_, full) = planes.scene.record(|_| &frame.pl[..], size, 3);
    for (order, cells) in [
        ("RGGB", [0, 1, 1, 2]),
        ("BGGR", [2, 1, 1, 0]),
        ("GRBG", [1, 0, 2, 1]),
        ("GBRG", [1, 2, 0, 1]),
    ] {
        let cfg = parse(&with_bands(&spec, &format!("mosaic = \"{order}\""), &RGB));
        let (signal, mosaic) = cfg.scene.record(|_| &frame.pl[..], size, 3);
        assert_eq!(signal.len(), 3 * n, "{order}: every band's signal");
        assert_eq!(mosaic.len(), n, "{order}: one raw mosaic");
        let mut lit = [0usize; 3];
        for y in 0..size.1 {
            for x in 0..size.0 {
                let b = cells[(y % 2) * 2 + x % 2];
                let i = y * size.0 + x;
                // Noiseless: the mosaic's pixel is its band's full image's.
                assert_eq!(mosaic[i], full[b * n + i], "{order} at ({x}, {y})");
                lit[b] += (mosaic[i] > 0) as usize;
            }
        }
        assert!(lit.iter().all(|&k| k > 50), "{order}: {lit:?}");
    }
}

#[test]
fn cubes_and_colour_images_carry_every_band() {
    let spec = SceneSpec {
        resolution: [40, 30],
        camera_m: [4.0 * common::R_MOON, 0.0, 0.0],
        ..Default::default()
    };
    let cfg = parse(&with_bands(&spec, "", &RGB));
    let mut r = Renderer::new(0).unwrap();
    let (meta, images) = products::make(&cfg, None, &cfg.pose, &mut r).unwrap();
    let files = products::encode(&cfg, &meta, images.view()).unwrap();
    let file = |name: &str| &files.iter().find(|(n, _)| *n == name).unwrap().1;
    let header = |bytes: &[u8]| String::from_utf8_lossy(&bytes[..2880 * 2]).to_string();
    let card = |h: &str, key: &str| {
        h.as_bytes()
            .chunks(80)
            .map(|c| String::from_utf8_lossy(c).to_string())
            .find(|c| c.starts_with(&format!("{key:<8}=")))
            .unwrap_or_else(|| panic!("no {key}"))
    };
    for name in ["power.fits", "signal.fits"] {
        let h = header(file(name));
        assert!(card(&h, "NAXIS").contains(" 3 "), "{name}");
        assert!(card(&h, "NAXIS3").contains(" 3 "), "{name}");
        assert!(card(&h, "BAND1").contains("'R"), "{name}");
        assert!(card(&h, "BAND3").contains("'B"), "{name}");
        assert!(card(&h, "BAND2LO").contains("5.0000"), "{name}");
        assert!(card(&h, "BAND2HI").contains("6.0000"), "{name}");
        // Three planes of 40 x 30 doubles after the header, padded to whole blocks.
        let len = file(name).len();
        assert!(len >= 2880 + 3 * 40 * 30 * 8 && len % 2880 == 0, "{name}");
    }
    // The depth stays one image.
    assert!(card(&header(file("depth.fits")), "NAXIS").contains(" 2 "));
    // image.png: RGB, each channel its band's DN.
    let png = file("image.png");
    let decoder = png::Decoder::new(std::io::Cursor::new(png.as_slice()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!((info.width, info.height), (40, 30));
    let n = 40 * 30;
    for i in 0..n {
        for b in 0..3 {
            let v = u16::from_be_bytes([buf[6 * i + 2 * b], buf[6 * i + 2 * b + 1]]);
            assert_eq!(v, images.dn[b * n + i]);
        }
    }
    // A Bayer camera's image.png is the raw mosaic, its pattern in the metadata.
    let bayer = parse(&with_bands(&spec, "mosaic = \"BGGR\"", &RGB));
    let (meta, images) = products::make(&bayer, None, &bayer.pose, &mut r).unwrap();
    let files = products::encode(&bayer, &meta, images.view()).unwrap();
    let png = &files.iter().find(|(n, _)| *n == "image.png").unwrap().1;
    let reader = png::Decoder::new(std::io::Cursor::new(png.as_slice()))
        .read_info()
        .unwrap();
    assert_eq!(reader.info().color_type, png::ColorType::Grayscale);
    let text: Vec<(String, String)> = reader
        .info()
        .uncompressed_latin1_text
        .iter()
        .map(|t| (t.keyword.clone(), t.text.clone()))
        .collect();
    assert!(
        text.contains(&("bayer_pattern".into(), "BGGR".into())),
        "{text:?}"
    );
    let signal = &files.iter().find(|(n, _)| *n == "signal.fits").unwrap().1;
    assert!(card(&header(signal), "BAYERPAT").contains("'BGGR"));
}

#[test]
fn bad_bands_are_refused_by_name() {
    let spec = SceneSpec::default();
    let both = spec.toml().replace(
        MONO_QE,
        &format!("{MONO_QE}\n[[camera.band]]\nname = \"R\"\n{MONO_QE}\n"),
    );
    assert_eq!(refusal(&both, "<t>").0, "camera.qe");
    let two = with_bands(&spec, "mosaic = \"RGGB\"", &RGB[..2]);
    assert_eq!(refusal(&two, "<t>").0, "camera.mosaic");
    let order = with_bands(&spec, "mosaic = \"RGBG\"", &RGB);
    assert_eq!(
        refusal(&order, "<t>"),
        ("camera.mosaic".into(), "\"RGBG\"".into())
    );
    let power = with_bands(&spec, "power_band_nm = [400, 700]", &RGB);
    assert_eq!(refusal(&power, "<t>").0, "camera.power_band_nm");
    let same = with_bands(&spec, "", &[RGB[0], RGB[0]]);
    assert_eq!(refusal(&same, "<t>").0, "camera.band[1].name");
    let spectrum =
        spec.toml_with_body("reflectance_spectrum = { table = \"mars\", reference_nm = 550 }");
    assert_eq!(
        refusal(&spectrum, "<t>").0,
        "body.reflectance_spectrum.table"
    );
    let reference =
        spec.toml_with_body("reflectance_spectrum = { table = \"moon\", reference_nm = -5 }");
    assert_eq!(
        refusal(&reference, "<t>").0,
        "body.reflectance_spectrum.reference_nm"
    );
}

/// A reflectance spectrum moves each band's factor by the spectrum's weight in that band,
/// relative to its reference: a flat band around the reference is unchanged, and a linear
/// spectrum over a flat band is its mean over the band's photons.
#[test]
fn a_reflectance_spectrum_weights_each_band() {
    let spec = SceneSpec::default();
    let body = "reflectance_spectrum = { wavelength_nm = [400, 700], value = [0.5, 1.1], \
                reference_nm = 550 }";
    let grey = parse(&with_bands(&spec, "", &RGB));
    let red = parse(&with_bands(&SceneSpec { body, ..spec }, "", &RGB));
    let (kg, kr) = (grey.scene.band_factors(), red.scene.band_factors());
    // r(lambda) / r(550) = (0.5 + 0.6 (lambda - 400) / 300) / 0.8: the B band (400-500 nm)
    // is dimmer, the R band (600-700) brighter.
    assert!(kr[2] / kg[2] < 0.8 && kr[0] / kg[0] > 1.2, "{kr:?} {kg:?}");
    // Photon-weighted: sum over the band of r N_lambda against sum of N_lambda, by the
    // midpoint rule on 1 nm steps (1e-6 is far below the spectrum's own effect).
    let planck_photons = |nm: f64| {
        let l = nm * 1e-9;
        2.0 * C / l.powi(4) / ((H * C / (l * K_B * 5782.0)).exp() - 1.0)
    };
    for (b, &(name, lo, hi, _)) in RGB.iter().enumerate() {
        let (mut num, mut den) = (0.0, 0.0);
        let steps = (hi - lo) as usize * 10;
        for k in 0..steps {
            let nm = lo + (k as f64 + 0.5) * (hi - lo) / steps as f64;
            let r = (0.5 + 0.6 * (nm - 400.0) / 300.0) / 0.8;
            num += r * planck_photons(nm);
            den += planck_photons(nm);
        }
        let want = num / den;
        let got = kr[b] / kg[b];
        assert!((got / want - 1.0).abs() < 1e-6, "{name}: {got} vs {want}");
    }
}

/// Lateral chromatic aberration (Sec. 6.1.2): a band with Brown coefficients of its own has
/// the same cloud projected through them before gridding. A small full Moon near the
/// image's corner lands, in each band, where the band's own distortion puts its centre, and
/// each band keeps the cloud's energy. Longitudinal aberration: a band's own PSF blurs that
/// band's DN only, keeping its signal.
#[test]
fn chromatic_aberrations_move_and_blur_each_band_on_its_own() {
    let spec = SceneSpec {
        resolution: [200, 200],
        focal_m: 0.01,
        camera_m: [800.0 * common::R_MOON, 0.0, 0.0],
        ..Default::default()
    };
    let bands = "\n[[camera.band]]\nname = \"R\"\n\
                 qe = { wavelength_nm = [600, 700], value = [0.4, 0.4] }\n\
                 distortion = { k1 = 2.0 }\n\
                 \n[[camera.band]]\nname = \"G\"\n\
                 qe = { wavelength_nm = [500, 600], value = [0.6, 0.6] }\n\
                 psf_sigma_px = 1.5\n\
                 \n[[camera.band]]\nname = \"B\"\n\
                 qe = { wavelength_nm = [400, 500], value = [0.5, 0.5] }\n\
                 distortion = { k1 = -2.0 }\n";
    let mut cfg = parse(&spec.toml().replace(MONO_QE, bands));
    // Turn the camera so that the Moon sits at 80 % of the half field along both axes.
    let intr = cfg.scene.camera.intrinsics.clone();
    let half = 100.0 / intr.focal_px().0;
    let t = glam::DVec3::new(0.8 * half, 0.8 * half, 1.0).normalize();
    cfg.pose.body_from_camera *= glam::DQuat::from_rotation_arc(t, glam::DVec3::Z);
    let mut r = Renderer::new(0).unwrap();
    let frame = r.render(&cfg.scene, &cfg.pose, &cfg.settings).unwrap();
    assert_eq!(frame.band_pl.len(), 2, "R and B have their own distortion");
    let (w, h) = (frame.width, frame.height);
    let centroid = |img: &[f64]| {
        let (mut su, mut sv, mut s) = (0.0, 0.0, 0.0);
        for (i, &x) in img.iter().enumerate() {
            su += x * ((i % w) as f64 + 0.5);
            sv += x * ((i / w) as f64 + 0.5);
            s += x;
        }
        ([su / s, sv / s], s)
    };
    let centre_cam = cfg.pose.body_from_camera.inverse() * -cfg.pose.camera_position_m;
    let mut seen = Vec::new();
    for (b, k1) in [(0, 2.0), (1, 0.0), (2, -2.0)] {
        let mut own = intr.clone();
        own.distortion.k1 = k1;
        let want = own.project(centre_cam.x, centre_cam.y, centre_cam.z);
        let (got, total) = centroid(frame.band(b));
        let miss = ((got[0] - want[0]).powi(2) + (got[1] - want[1]).powi(2)).sqrt();
        assert!(
            miss < 0.02,
            "band {b}: centroid {got:?}, its distortion puts it at {want:?}"
        );
        let energy = total / frame.stats.total_pl_points - 1.0;
        assert!(energy.abs() < 1e-9, "band {b}: energy {energy:e}");
        seen.push(got);
    }
    // The bands fall apart by more than a pixel: the test would see a missing distortion.
    let spread = ((seen[0][0] - seen[2][0]).powi(2) + (seen[0][1] - seen[2][1]).powi(2)).sqrt();
    assert!(spread > 1.5, "{spread}");

    // Longitudinal: G's own PSF blurs G's DN and keeps G's signal sharp and whole.
    let (signal, dn) = cfg.scene.record(|b| frame.band(b), (w, h), 0);
    let n = w * h;
    let k = cfg.scene.band_factors();
    for (s, pl) in signal[n..2 * n].iter().zip(&frame.pl) {
        assert!((s - pl * k[1]).abs() <= 1e-12 * s.abs().max(1e-300));
    }
    let mut sharp = cfg.clone();
    sharp.scene.camera.detector.bands[1].psf_sigma_px = None;
    let (_, dn_sharp) = sharp.scene.record(|b| frame.band(b), (w, h), 0);
    let peak = |d: &[u16]| d.iter().copied().max().unwrap();
    let sum = |d: &[u16]| d.iter().map(|&x| x as f64).sum::<f64>();
    let (g, g_sharp) = (&dn[n..2 * n], &dn_sharp[n..2 * n]);
    assert!(peak(g) < peak(g_sharp), "{} vs {}", peak(g), peak(g_sharp));
    assert!(
        (sum(g) / sum(g_sharp) - 1.0).abs() < 0.01,
        "{} vs {}",
        sum(g),
        sum(g_sharp)
    );
    // R and B were not touched by G's PSF.
    assert_eq!(&dn[..n], &dn_sharp[..n]);
}

/// A grey screen cannot stimulate a colour camera: the stimulator (and so the daemon) refuses
/// a camera of several bands on a curve of one column by name, rather than driving its first
/// band.
#[test]
fn a_grey_screen_refuses_several_bands() {
    let text = std::fs::read_to_string("config/stimulator.toml").unwrap();
    let mono = text
        .lines()
        .find(|l| l.starts_with("qe = "))
        .expect("config/stimulator.toml has one qe curve")
        .to_string();
    let bands = band_tables(&RGB);
    // The bands go after the camera's last key: before its next table.
    let without = text.replace(&format!("{mono}\n"), "");
    let at = without
        .find("\n[camera.noise]")
        .expect("a [camera.noise] table");
    let colour = format!("{}\n{bands}{}", &without[..at], &without[at..]);
    // Read as if it were config/stimulator.toml: its paths resolve the same.
    let cfg = config::parse(&colour, "config/stimulator.toml").unwrap();
    let st = cfg.stimulator.as_ref().unwrap();
    let cam = &cfg.scene.camera;
    let err = optistim::stimulator::Stimulator::new(st, &cam.intrinsics, &cam.detector)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("example_gamma22")
            && err.contains("1 F_eff columns")
            && err.contains("3 bands"),
        "{err}"
    );
    // The daemon's frame maker refuses it the same way.
    let err = optistim::pipeline::FrameMaker::new(&cfg)
        .err()
        .expect("refused");
    assert!(err.to_string().contains("1 F_eff columns"), "{err}");
}

/// Maps per band (`[[body.band_map]]`): an RGB file's channels as the R, G and B bands'
/// albedos. Each band's image is the one rendered with its map as the body's albedo map (the
/// geometry integrated once with the mean map; Lambert is linear in the albedo, so to
/// rounding), and the bands differ where the channels do. Bad band maps are refused by key.
#[test]
fn each_band_can_carry_its_own_albedo_map() {
    use common::{TempDir, write_tiff};
    let dir = TempDir::new("band_maps");
    let tif = dir.join("rgb.tif");
    // 64 x 32 texels: R bright in the west, B bright in the north, G flat.
    let (w, h) = (64usize, 32usize);
    let px: Vec<u16> = (0..w * h)
        .flat_map(|i| {
            let (c, r) = (i % w, i / w);
            let red = if c < w / 2 { 50_000 } else { 20_000 };
            let blue = if r < h / 2 { 45_000 } else { 15_000 };
            [red, 30_000, blue]
        })
        .collect();
    write_tiff::<tiff::encoder::colortype::RGB16>(&tif, w as u32, h as u32, &px);
    let map = |extra: &str| {
        format!(
            "map = {{ path = {:?}, domain = [0.0, 0.5] }}{extra}",
            tif.display().to_string()
        )
    };
    let body = format!(
        "albedo_map = {{ path = {:?}, domain = [0.0, 0.5] }}",
        tif.display().to_string()
    );
    let spec = SceneSpec {
        camera_m: [6.0e6, 2.0e6, 1.0e6],
        render: "map_filter = \"pixel\"",
        body: &body,
        ..Default::default()
    };
    let band_maps: String = ["R", "G", "B"]
        .iter()
        .enumerate()
        .map(|(c, b)| {
            format!(
                "\n[[body.band_map]]\nband = \"{b}\"\nchannel = {c}\n{}\n",
                map("")
            )
        })
        .collect();
    let text = with_bands(&spec, "", &RGB) + &band_maps;
    let cfg = parse(&text);
    assert_eq!(cfg.scene.body.band_maps.len(), 3);
    let mut renderer = Renderer::new(0).unwrap();
    let frame = renderer
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    for b in 0..3 {
        let mut alone = cfg.clone();
        alone.scene.body.albedo_map = Some(cfg.scene.body.band_map(b).unwrap().clone());
        alone.scene.body.band_maps.clear();
        let own = renderer
            .render(&alone.scene, &alone.pose, &alone.settings)
            .unwrap();
        let (got, want) = (frame.band(b), &own.pl);
        let worst = got
            .iter()
            .zip(want)
            .map(|(g, w)| (g - w).abs())
            .fold(0.0, f64::max);
        let peak = want.iter().cloned().fold(0.0, f64::max);
        eprintln!(
            "band {b}: total {:.6e} vs its map alone {:.6e}; worst pixel {:.1e} of the peak",
            sum(got),
            sum(want),
            worst / peak
        );
        assert!((sum(got) / sum(want) - 1.0).abs() < 1e-9);
        assert!(worst < 1e-9 * peak);
    }
    // The channels differ, and so do the bands (G is the flat one).
    let (r, g) = (sum(frame.band(0)), sum(frame.band(1)));
    assert!((r / g - 1.0).abs() > 0.05, "R {r} G {g}");

    // Refusals, by key.
    let refused = |extra: &str, render: &str| {
        let s = SceneSpec { render, ..spec };
        refusal(&(with_bands(&s, "", &RGB) + extra), "<t>").0
    };
    let one = |band: &str, extra: &str| {
        format!("\n[[body.band_map]]\nband = \"{band}\"\n{}\n", map(extra))
    };
    assert_eq!(
        refused(&one("NIR", ""), "map_filter = \"pixel\""),
        "body.band_map[0].band"
    );
    assert_eq!(
        refused(&(one("R", "") + &one("R", "")), "map_filter = \"pixel\""),
        "body.band_map[1].band"
    );
    assert_eq!(
        refused(&one("R", "\nchannel = 3"), "map_filter = \"pixel\""),
        "body.band_map[0].channel"
    );
    assert_eq!(
        refused(&one("R", ""), "map_filter = \"area\""),
        "render.map_filter"
    );
    let no_map = SceneSpec { body: "", ..spec };
    assert_eq!(
        refusal(&(with_bands(&no_map, "", &RGB) + &one("R", "")), "<t>").0,
        "body.band_map[0]"
    );
}
