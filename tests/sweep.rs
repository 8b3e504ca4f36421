//! `optistim sweep`: a small grid (two analytic scenes at 64 x 64, four settings), run twice
//! in a fresh folder: every row present with its time and errors, the more accurate settings
//! measured as more accurate, fronts marked, the peers and both charts written, and the
//! references reused the second time.

mod common;
use common::*;

const SWEEP: &str = r#"
repeats = 2

[[scene]]
name = "near"
file = "scene.toml"
[[scene.peer]]
name = "Peer"
time_s = 4.75
median = 5.4e-5
p99 = 1.8e-3
total = 5.6e-6

[[scene]]
name = "far half"
file = "scene.toml"
[scene.patch.pose]
camera_position_m = [0.0, 52122000.0, 0.0]
[scene.patch.camera]
focal_length_m = 0.04

[[setting]]
name = "coarse"
render = { points_per_pixel = 0.0625, min_points = 16, boundary_nodes = 2 }

[[setting]]
name = "default"
render = { preset = "default" }

[[setting]]
name = "fine"
render = { points_per_pixel = 4.0, boundary_nodes = 8 }

[[setting]]
name = "impossible"
render = { integration = "exact", brdf_is_not_a_render_key = 1 }
"#;

#[test]
fn a_sweep_measures_every_setting_against_the_reference_and_charts_the_front() {
    let dir = TempDir::new("sweep");
    let scene = SceneSpec {
        resolution: [64, 64],
        pixel_m: 5.5e-6 * 16.0,
        focal_m: 0.003073203,
        camera_m: [5212200.0, 0.0, 0.0],
        ..Default::default()
    };
    std::fs::write(dir.join("scene.toml"), scene.toml()).unwrap();
    std::fs::write(dir.join("sweep.toml"), SWEEP).unwrap();
    let out = dir.join("out");
    let mut lines = Vec::new();
    let report = optistim::app::sweep::run(&dir.join("sweep.toml"), &out, None, |l| {
        lines.push(l.to_string())
    })
    .unwrap();
    assert_eq!(report.rows, 8);
    assert!(report.scenes.iter().all(|s| !s.reference_reused));
    let mut csv = csv::Reader::from_path(out.join("sweep.csv")).unwrap();
    let rows: Vec<csv::StringRecord> = csv.records().map(|r| r.unwrap()).collect();
    let head = csv.headers().unwrap().clone();
    let col = |name: &str| head.iter().position(|h| h == name).unwrap();
    let get = |scene: &str, setting: &str, c: &str| -> String {
        rows.iter()
            .find(|r| &r[col("scene")] == scene && &r[col("setting")] == setting)
            .unwrap()[col(c)]
        .to_string()
    };
    for scene in ["near", "far half"] {
        let err = |s: &str, c: &str| get(scene, s, c).parse::<f64>().unwrap();
        eprintln!(
            "{scene}: coarse median {:.2e} default {:.2e} fine {:.2e}; total {:.2e} {:.2e} {:.2e}",
            err("coarse", "err_median"),
            err("default", "err_median"),
            err("fine", "err_median"),
            err("coarse", "err_total"),
            err("default", "err_total"),
            err("fine", "err_total")
        );
        assert!(err("fine", "err_median") < err("coarse", "err_median"));
        assert!(err("fine", "err_p99") < err("coarse", "err_p99"));
        assert!(err("fine", "err_total") < err("coarse", "err_total"));
        assert!(err("fine", "ssim") > 0.999);
        for s in ["coarse", "default", "fine"] {
            assert!(err(s, "time_ms_median") > 0.0 && err(s, "lit_px") > 100.0);
            assert_eq!(get(scene, s, "failure"), "");
        }
        // The finest setting is the most accurate: nothing can dominate it.
        assert_eq!(get(scene, "fine", "front"), "true");
        // A setting the scene cannot take is reported, not fatal.
        assert!(get(scene, "impossible", "failure").contains("brdf_is_not_a_render_key"));
        assert_eq!(get(scene, "impossible", "front"), "false");
    }
    for chart in ["front.png", "front.svg"] {
        let len = std::fs::metadata(out.join(chart)).unwrap().len();
        assert!(len > 10_000, "{chart}: {len} bytes");
    }
    let svg = std::fs::read_to_string(out.join("front.svg")).unwrap();
    assert!(svg.contains("Peer") && svg.contains("Pareto front") && svg.contains("far half"));

    // Run again: the references come from the cache, the figures are the same.
    let again = optistim::app::sweep::run(&dir.join("sweep.toml"), &out, None, |_| {}).unwrap();
    assert!(again.scenes.iter().all(|s| s.reference_reused));
    let mut csv2 = csv::Reader::from_path(out.join("sweep.csv")).unwrap();
    let rows2: Vec<csv::StringRecord> = csv2.records().map(|r| r.unwrap()).collect();
    for (a, b) in rows.iter().zip(&rows2) {
        assert_eq!(a[col("err_median")], b[col("err_median")]);
        assert_eq!(a[col("err_total")], b[col("err_total")]);
    }
}

/// A sweep's unpatched scene keys its reference by the scene file's own text, as
/// `verify-budget` does: the references a budget check cached, copied into a sweep's folder,
/// are reused for the same file, pose and reference settings, and give the same figures as a
/// reference the sweep renders itself. A patched scene (whose text is the patched table's)
/// renders its own.
#[test]
fn a_sweep_reuses_the_references_of_a_budget_check_on_the_same_file() {
    use optistim::raycast::reference::{ReferenceMethod, ReferenceSettings};
    let dir = TempDir::new("sweep-reuse");
    let nrho = std::fs::read_to_string("../shared/trajectories/nrho_2orbits.csv").unwrap();
    let trajectory = dir.join("one.csv");
    std::fs::write(
        &trajectory,
        nrho.lines().take(2).collect::<Vec<_>>().join("\n") + "\n",
    )
    .unwrap();
    let path = dir.join("scene.toml");
    let spec = SceneSpec {
        resolution: [24, 24],
        pixel_m: 5.5e-6 * 40.0,
        ..Default::default()
    };
    // A comment the re-serialised table of a patched scene would lose.
    std::fs::write(&path, format!("# the scene\n{}", spec.toml())).unwrap();
    let cfg = optistim::config::load(&path).unwrap();
    let reference = ReferenceSettings {
        tolerance: 1e-3,
        max_depth: 4,
        ..Default::default()
    };
    let check = dir.join("check");
    optistim::app::verify_budget::run(
        &cfg,
        path.to_str().unwrap(),
        &trajectory,
        1,
        Some(&[0]),
        &reference,
        ReferenceMethod::Cubature,
        &check,
        false,
        |_| {},
    )
    .unwrap();
    let sweep = |patch: &str| {
        format!(
            "repeats = 1\n[reference]\ntolerance = 1e-3\nmax_depth = 4\n\
             [[scene]]\nname = \"row 0\"\nfile = \"scene.toml\"\ntrajectory = \"one.csv\"\npose = 0\n{patch}\
             [[setting]]\nname = \"default\"\nrender = {{ preset = \"default\" }}\n"
        )
    };
    let run = |name: &str, text: String, copied: bool| {
        let file = dir.join(&format!("{name}.toml"));
        std::fs::write(&file, text).unwrap();
        let out = dir.join(name);
        if copied {
            std::fs::create_dir_all(out.join("references")).unwrap();
            for f in std::fs::read_dir(check.join("references")).unwrap() {
                let f = f.unwrap().path();
                std::fs::copy(&f, out.join("references").join(f.file_name().unwrap())).unwrap();
            }
        }
        let report = optistim::app::sweep::run(&file, &out, None, |_| {}).unwrap();
        let mut csv = csv::Reader::from_path(out.join("sweep.csv")).unwrap();
        let head = csv.headers().unwrap().clone();
        // Every column but the times.
        let figures: Vec<Vec<String>> = csv
            .records()
            .map(|r| {
                let r = r.unwrap();
                head.iter()
                    .zip(r.iter())
                    .filter(|(h, _)| !h.starts_with("time_ms"))
                    .map(|(_, v)| v.to_string())
                    .collect()
            })
            .collect();
        (report.scenes[0].reference_reused, figures)
    };
    let (reused, copied) = run("copied", sweep(""), true);
    assert!(reused, "the budget check's reference was not reused");
    let (reused, fresh) = run("fresh", sweep(""), false);
    assert!(!reused);
    assert_eq!(copied, fresh);
    // Patched (here with what the file already says), the scene is keyed by its table's text.
    let patch = "[scene.patch.camera]\nresolution_px = [24, 24]\n";
    let (reused, _) = run("patched", sweep(patch), true);
    assert!(!reused);
}
