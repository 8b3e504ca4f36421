//! `optistim render-trajectory`'s library half: shards make the same dataset as one run, a
//! rerun renders nothing finished, and a frame that cannot be written stops the run with an
//! error naming it (no hang, no panic, nothing half-written under a final name).

mod common;

use optistim::app::render_trajectory::{self, Shard};
use std::path::Path;

fn setup() -> (optistim::config::Config, Vec<(f64, optistim::scene::Pose)>) {
    let text = std::fs::read_to_string("config/nrho_bench.toml")
        .unwrap()
        .replace("resolution_px = [1024, 1024]", "resolution_px = [64, 64]")
        .replace("pixel_pitch_m = 5.5e-6", "pixel_pitch_m = 8.8e-5");
    let config = optistim::config::parse(&text, "config/nrho_bench_64.toml").unwrap();
    let poses =
        optistim::trajectory::read(Path::new("../shared/trajectories/nrho_2orbits.csv")).unwrap();
    (config, poses.into_iter().step_by(70).collect())
}

fn files(root: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for d in std::fs::read_dir(root.join("frames")).unwrap() {
        let d = d.unwrap().path();
        for f in std::fs::read_dir(&d).unwrap() {
            let f = f.unwrap().path();
            let name = f.strip_prefix(root).unwrap().display().to_string();
            out.push((name, std::fs::read(&f).unwrap()));
        }
    }
    out.sort();
    out
}

/// One run over every pose into `root`, with 2 threads.
fn whole_run(
    config: &optistim::config::Config,
    poses: &[(f64, optistim::scene::Pose)],
    root: &Path,
) -> Result<render_trajectory::TrajectoryReport, optistim::app::AppError> {
    render_trajectory::run(config, poses, root, Shard::WHOLE, 2, &mut |_, _| {})
}

#[test]
fn shards_and_reruns_make_the_same_dataset() {
    let (config, poses) = setup();
    let whole = common::TempDir::new("traj-whole");
    let report = whole_run(&config, &poses, &whole.join("")).unwrap();
    assert_eq!(
        (report.frames, report.rendered, report.resumed),
        (poses.len(), poses.len(), 0)
    );
    let sharded = common::TempDir::new("traj-shards");
    let mut progress = Vec::new();
    for index in 0..3 {
        let shard = Shard { index, count: 3 };
        render_trajectory::run(&config, &poses, &sharded.join(""), shard, 1, &mut |d, t| {
            progress.push((d, t))
        })
        .unwrap();
        assert!(sharded.join(&shard.manifest_name()).exists());
    }
    assert_eq!(files(&whole.join("")), files(&sharded.join("")));
    assert_eq!(progress.last().map(|p| p.0), progress.last().map(|p| p.1));
    // The manifest lists every frame in order, as frame.json has it.
    let manifest = std::fs::read_to_string(whole.join("manifest.jsonl")).unwrap();
    assert_eq!(manifest.lines().count(), poses.len());
    // A rerun renders nothing and rewrites nothing.
    let before = files(&whole.join(""));
    let again = whole_run(&config, &poses, &whole.join("")).unwrap();
    assert_eq!((again.rendered, again.resumed), (0, poses.len()));
    assert_eq!(files(&whole.join("")), before);
}

#[test]
fn a_frame_that_cannot_be_written_stops_the_run_with_its_name() {
    let (config, poses) = setup();
    let dir = common::TempDir::new("traj-fail");
    let root = dir.join("");
    std::fs::create_dir_all(root.join("frames")).unwrap();
    // Frame 3's folder is a file: its images cannot be written.
    std::fs::write(root.join("frames/000003"), b"in the way").unwrap();
    let err = whole_run(&config, &poses, &root).unwrap_err().to_string();
    assert!(err.contains("000003"), "{err}");
    // The frames before it are finished and whole; no manifest claims the run is complete.
    for i in 0..3 {
        assert!(render_trajectory::finished(&root, i).is_some(), "frame {i}");
    }
    assert!(!root.join("manifest.jsonl").exists());
    // Once the obstacle is gone, a rerun completes what is missing only.
    std::fs::remove_file(root.join("frames/000003")).unwrap();
    let report = whole_run(&config, &poses, &root).unwrap();
    assert!(report.resumed >= 3 && report.rendered + report.resumed == poses.len());
}
