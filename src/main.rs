//! The `optistim` binary: arguments, logging of errors, exit codes. The work is in the library.

use anyhow::Context;
use clap::{Parser, Subcommand};
use optistim::{app, config, render::Settings};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    version,
    about = "Physically based rendering for HIL optical stimulators"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render one scene file to power.fits, signal.fits, depth.fits and image.png.
    Render {
        /// Scene TOML (see docs/scene.md).
        scene: PathBuf,
        /// Output folder.
        #[arg(long, default_value = "out")]
        out: PathBuf,
    },
    /// Render every pose of a trajectory and report frame times.
    Bench {
        /// Pose stream, CSV or JSON lines (../shared/trajectories/); without it, the scene's
        /// own pose is rendered `--frames` times (default 20).
        trajectory: Option<PathBuf>,
        /// Scene TOML for the body, Sun spectrum and camera (default: embedded Lambert Moon,
        /// NRHO camera).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Settings preset overriding the scene's: default | high_accuracy.
        #[arg(long)]
        preset: Option<String>,
        /// Render threads (0 = all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Only the first N frames.
        #[arg(long)]
        frames: Option<usize>,
        /// Write one JSON line per frame to this file.
        #[arg(long)]
        per_frame: Option<PathBuf>,
    },
    /// Measure the screen's calibration curve on the bench of the scene's [stimulator]
    /// section (the simulated camera) and write it as CSV (calibration/README.md).
    Calibrate {
        /// Scene TOML with a [stimulator] section.
        scene: PathBuf,
        /// Codes in the ramp (quadratically spaced, denser at the dark end).
        #[arg(long, default_value_t = 33)]
        steps: usize,
        /// Curve file to write.
        #[arg(long, default_value = "calibration/measured.csv")]
        out: PathBuf,
    },
}

fn run() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Render { scene, out } => {
            let cfg = config::load(&scene)?;
            let summary = app::render::run(&cfg, &scene.display().to_string(), &out)?;
            println!("{}", serde_json::to_string(&summary)?);
        }
        Command::Bench {
            trajectory,
            scene,
            preset,
            threads,
            frames,
            per_frame,
        } => {
            let mut cfg = match &scene {
                Some(p) => config::load(p)?,
                None => config::parse(
                    app::bench::DEFAULT_SCENE,
                    "<embedded config/nrho_bench.toml>",
                )?,
            };
            if let Some(p) = preset {
                cfg.settings = Settings::preset(&p)
                    .with_context(|| format!("--preset {p}: allowed are default, high_accuracy"))?;
            }
            if let Some(t) = threads {
                cfg.settings.threads = t;
            }
            let mut sink = match &per_frame {
                Some(p) => Some(std::io::BufWriter::new(
                    std::fs::File::create(p).with_context(|| format!("{}", p.display()))?,
                )),
                None => None,
            };
            let report = app::bench::run(&cfg, trajectory.as_deref(), frames, |row| {
                if let Some(w) = sink.as_mut() {
                    use std::io::Write;
                    let _ = writeln!(w, "{}", serde_json::to_string(row).unwrap_or_default());
                }
            })?;
            println!("{}", serde_json::to_string(&report)?);
        }
        Command::Calibrate { scene, steps, out } => {
            let cfg = config::load(&scene)?;
            let run = app::calibrate::run(&cfg, &scene.display().to_string(), steps, &out)?;
            println!("{}", serde_json::to_string(&run)?);
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("optistim: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
