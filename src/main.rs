//! The `optistim` binary: arguments, logging of errors, exit codes. The work is in the library.

use anyhow::Context;
use clap::{Parser, Subcommand};
use optistim::{app, config, render::Settings};
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

/// Prints a line of a command's result to stdout. A closed pipe (`optistim ... | head`)
/// ends the output quietly, as in other command-line tools, instead of panicking as
/// `println!` does; any other write error is the command's error.
macro_rules! out {
    ($($arg:tt)*) => {{
        if let Err(e) = writeln!(std::io::stdout(), $($arg)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
            return Err(e.into());
        }
    }};
}

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
        /// Render the converged reference instead (per-pixel ray casting with adaptive
        /// cubature over each pixel's footprint; slow); also writes error.fits.
        #[arg(long)]
        reference: bool,
        /// The reference's relative tolerance per pixel.
        #[arg(long, default_value_t = 1e-6)]
        tolerance: f64,
        /// The reference's deepest subdivision (halvings of a pixel's side).
        #[arg(long, default_value_t = 10)]
        max_depth: u32,
        /// Points per pixel side of the reference's lattice over the cells near an edge whose
        /// rays agree (0: none; see `ReferenceSettings::lattice_per_px`).
        #[arg(long, default_value_t = 64)]
        lattice: u32,
        /// Which reference: `auto` is the exact one for a lone mesh body through an
        /// undistorted camera (polygons clipped, no rays), else the cubature.
        #[arg(long, value_enum, default_value = "auto")]
        reference_method: optistim::raycast::reference::ReferenceMethod,
    },
    /// Render every pose of a trajectory (or shard I of N) to a dataset folder: per frame
    /// DIR/frames/NNNNNN/{power,signal,depth}.fits, image.png and frame.json, and a manifest.
    /// Resumable: frames already finished are neither rendered nor rewritten.
    RenderTrajectory {
        /// Pose stream, CSV or JSON lines (../shared/trajectories/).
        trajectory: PathBuf,
        /// Scene TOML (body, Sun, camera, [render]).
        #[arg(long)]
        scene: PathBuf,
        /// Dataset folder.
        #[arg(long, default_value = "out/dataset")]
        out: PathBuf,
        /// Only shard I of N (from 0): a contiguous block of the frames.
        #[arg(long, default_value = "0/1")]
        shard: String,
        /// Render threads (0: RAYON_NUM_THREADS, else the CPUs this process may use).
        #[arg(long, default_value_t = 0)]
        threads: usize,
    },
    /// Exposure planning along a trajectory (Sec. 6.3.2, Eqs. 61-62): per frame the time
    /// before saturation and before noise of every active pixel, the information loss against
    /// exposure and the optimal bracket for X; writes frames.csv, loss.csv, pooled.csv,
    /// exposure.png and exposure.svg, and prints the summary.
    Exposure {
        /// Pose stream, CSV or JSON lines.
        trajectory: PathBuf,
        /// Scene TOML (its camera's detector: full well, readout noise, exposure).
        #[arg(long)]
        scene: PathBuf,
        #[arg(long, default_value = "out/exposure")]
        out: PathBuf,
        /// X: the fraction of active pixels to keep above noise and below saturation.
        #[arg(long, default_value_t = 0.95)]
        keep: f64,
        /// The detector's dynamic range [dB] (default: 20 log10(full well / readout sigma)).
        #[arg(long)]
        dnr_db: Option<f64>,
        /// Only frames FROM..TO of the stream (indices, TO excluded), every EVERY-th.
        #[arg(long, default_value_t = 0)]
        from: usize,
        #[arg(long)]
        to: Option<usize>,
        #[arg(long, default_value_t = 1)]
        every: usize,
        /// Render threads (0: all).
        #[arg(long, default_value_t = 0)]
        threads: usize,
    },
    /// The speed-accuracy front: a grid of scenes x settings, each timed and measured against
    /// the scene's converged reference; writes sweep.csv, front.png and front.svg.
    Sweep {
        /// Sweep TOML (e.g. sweeps/issue15.toml).
        sweep: PathBuf,
        /// Output folder (references are cached in DIR/references).
        #[arg(long, default_value = "out/sweep")]
        out: PathBuf,
        /// Also fit the fidelity planner's error model on the sweep's ladder rows and write
        /// it here (config/error_model.toml is the shipped one).
        #[arg(long)]
        fit: Option<PathBuf>,
    },
    /// What the fidelity planner chooses for every pose of a stream and the error it
    /// predicts, without rendering (milliseconds a pose): writes one CSV row per pose and
    /// prints the share predicted to meet the budget and the runs of rows that are not.
    Plan {
        /// Pose stream (CSV, as `bench`).
        trajectory: PathBuf,
        /// Scene file (its [render.budget], or the default budget).
        #[arg(long)]
        scene: PathBuf,
        /// The per-pose CSV.
        #[arg(long, default_value = "out/plan.csv")]
        out: PathBuf,
    },
    /// The fidelity planner checked over a pose stream: N frames spread over it, each as
    /// `fidelity = "budget"` plans it and at every fixed rung of its ladder, against the
    /// converged reference; writes DIR/frames.csv and prints the summary.
    VerifyBudget {
        /// Pose stream (CSV, as `bench`).
        trajectory: PathBuf,
        /// Scene file (its [render.budget], or the default budget).
        #[arg(long)]
        scene: PathBuf,
        /// Frames spread evenly over the whole stream.
        #[arg(long, default_value_t = 50)]
        frames: usize,
        /// These rows of the stream (0-based, comma-separated) instead of `--frames`.
        #[arg(long, value_delimiter = ',')]
        rows: Option<Vec<usize>>,
        /// Frames already measured in DIR/frames.csv on the same inputs are read, not
        /// measured again: a run goes on where an interrupted one stopped.
        #[arg(long, default_value = "out/verify-budget")]
        out: PathBuf,
        /// The reference's relative tolerance per pixel.
        #[arg(long, default_value_t = 1e-5)]
        tolerance: f64,
        #[arg(long, default_value_t = 8)]
        max_depth: u32,
        /// As `render --lattice`.
        #[arg(long, default_value_t = 64)]
        lattice: u32,
        /// Which reference (as `render --reference-method`).
        #[arg(long, value_enum, default_value = "auto")]
        reference_method: optistim::raycast::reference::ReferenceMethod,
        /// `[render]` keys over the scene file's for the frames, as TOML (e.g.
        /// "relief_refine = 4"); the references, which read none, stay the file's (cached).
        #[arg(long, default_value = "")]
        render: String,
        /// Also write each budgeted frame's (P/L) as DIR/frames/ROW.f64 (little-endian f64,
        /// row by row; the reference's is DIR/references/KEY.f64 after a head of five f64).
        #[arg(long)]
        keep_frames: bool,
    },
    /// Fits the fidelity planner's error model on the ladder rows of one or more sweep CSVs.
    FitModel {
        /// One or more sweep CSVs (their ladder rows are fitted together).
        #[arg(required = true)]
        csv: Vec<PathBuf>,
        #[arg(long, default_value = "config/error_model.toml")]
        out: PathBuf,
    },
    /// The Hapke parameters w, b, c, B0, h, theta of a body from images of it (SLIM Sec. 11),
    /// with their uncertainties and the radiance histograms' chi-square (SLIM Eq. 15).
    Invert {
        /// SCENE=IMAGE pairs: a scene file (the body's shape, the camera, the detector and the
        /// pose of that image) and the image as a PNG of saved DN (`optistim render`'s
        /// image.png).
        #[arg(required = true)]
        images: Vec<String>,
        /// Starting values: w,b,c,B0,h,theta_rad.
        #[arg(long, value_delimiter = ',', default_value = "0.3,0.3,0.5,1.0,0.1,0.3")]
        start: Vec<f64>,
        /// Lines of sight per pixel side (as the renderer's raycast_samples).
        #[arg(long, default_value_t = 1)]
        samples: u32,
    },
    /// The surface irradiance of a mesh body (SLIM Secs. 6.1-6.2, 9.3): per facet, direct
    /// (with the body's own shadows) and scattered between facets (Lambertian radiosity,
    /// `--orders` Jacobi iterations); writes DIR/irradiance.csv and DIR/irradiance.ply (face
    /// properties, W/m^2); with `--steps N`, also the mean, min, max and lit fraction over one
    /// rotation about the body's +Z in N steps.
    Irradiance {
        /// Scene TOML with a mesh body (e.g. config/bennu.toml); its pose gives the Sun.
        scene: PathBuf,
        #[arg(long, default_value = "out/irradiance")]
        out: PathBuf,
        /// Orders of scattering (0: direct light only).
        #[arg(long, default_value_t = 3)]
        orders: u32,
        /// Rotation steps for the statistics (0: none).
        #[arg(long, default_value_t = 0)]
        steps: u32,
    },
    /// The stability suite: the renderer where methods fail (extreme ranges and phases, the
    /// body cut or behind the camera, degenerate poses, broken maps, DEM cliffs, extreme Hapke,
    /// a 10:1 ellipsoid, 1 x 1 and 8192 x 8192 images), each case time-limited; writes the
    /// report as Markdown.
    Stability {
        /// The report (e.g. docs/stability.md).
        #[arg(long, default_value = "docs/stability.md")]
        out: PathBuf,
        /// Time limit per case [s].
        #[arg(long, default_value_t = 300)]
        limit_s: u64,
    },
    /// Render a scene as its camera saves it and compare it with a real photograph: NCC
    /// alignment, SSIM luminance / contrast / structure over the foreground, total DN ratio.
    Compare {
        /// Scene TOML (e.g. config/bfs_25mm.toml).
        scene: PathBuf,
        /// The photograph: one-channel PNG of the camera's size.
        photo: PathBuf,
        /// Largest alignment shift searched [px].
        #[arg(long, default_value_t = 20)]
        max_shift: i64,
        /// Write rendered.png (aligned) and alignment.png here.
        #[arg(long)]
        out: Option<PathBuf>,
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
        /// A second scene file rendered pose by pose in turn with `--scene` (the machine's
        /// drift hits both alike): both reports, and how many times faster `--scene` is at the
        /// median and the slowest frame. Per-frame lines then carry `"scene": 0` or `1`.
        #[arg(long)]
        against: Option<PathBuf>,
    },
    /// The daemon: poses over TCP (binary frames or JSON lines) and serial in, calibrated
    /// frames out on the stimulator's screen (fullscreen when a display exists, off-screen
    /// otherwise), HTTP control and monitoring. Stops cleanly on SIGINT/SIGTERM.
    Serve(Box<ServeArgs>),
    /// Stream a pose file (trajectory CSV/JSONL or a recording) to a daemon and report the acks.
    Replay {
        file: PathBuf,
        /// Poses per second.
        #[arg(long, default_value_t = 10.0)]
        rate: f64,
        /// host:port, or serial:PATH[@BAUD].
        #[arg(long, default_value = optistim::server::DEFAULT_LISTEN)]
        to: String,
        #[arg(long)]
        frames: Option<usize>,
        /// lockstep | free.
        #[arg(long, default_value = "lockstep")]
        mode: String,
        /// Write the report (JSON) here as well as to stdout.
        #[arg(long)]
        report: Option<PathBuf>,
        /// The daemon's access token (serve --token-file), sent in the hello.
        #[arg(long)]
        token_file: Option<PathBuf>,
    },
    /// What the SurRender and CORTO endpoints add to a frame's latency over the native
    /// protocol, for the same poses (an in-process daemon serving all three, lockstep).
    BenchEndpoints {
        /// Trajectory CSV (positions and attitudes in the body frame).
        trajectory: PathBuf,
        /// Scene with a [stimulator] section (default: the embedded config/daemon.toml).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Poses, spread over the trajectory.
        #[arg(long, default_value_t = 100)]
        frames: usize,
        /// cpu | offscreen (the GPU presenter) | auto.
        #[arg(long, default_value = "cpu")]
        present: String,
    },
    /// Does watching disturb the loop? The daemon's pose-to-presented latency, streamed at
    /// 10 Hz in lockstep, alone and while clients poll every HTTP endpoint (rounds
    /// interleaved); the p99 ratio, what was served and the images made for it.
    BenchWatching {
        /// Trajectory CSV (positions and attitudes in the body frame).
        trajectory: PathBuf,
        /// Scene with a [stimulator] section (default: the embedded config/daemon.toml).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Poses per round, spread over the trajectory.
        #[arg(long, default_value_t = 100)]
        frames: usize,
        /// Rounds alone and watched, interleaved.
        #[arg(long, default_value_t = 6)]
        rounds: usize,
        /// Polling clients.
        #[arg(long, default_value_t = 16)]
        clients: usize,
        /// Each client's pause between requests [ms].
        #[arg(long, default_value_t = 50)]
        poll_ms: u64,
    },
    /// Time the stimulator's per-frame path on the GPU: F_eff -> screen region -> LUT pass ->
    /// presented off-screen and read back; per stage, with the CPU reference's agreement.
    BenchDisplay {
        /// Scene TOML with a [stimulator] section.
        #[arg(long, default_value = "config/stimulator.toml")]
        scene: PathBuf,
        /// Screen size WxH overriding the scene's (the image centred, one-to-one).
        #[arg(long, default_value = "1024x1024")]
        screen: String,
        #[arg(long, default_value_t = 50)]
        frames: usize,
    },
    /// Show the scene's frame on the stimulator's monitor (borderless fullscreen, 1:1 pixels,
    /// vsync) and/or in a preview window; one JSON line per presented frame.
    Show {
        /// Scene TOML with a [stimulator] section.
        scene: PathBuf,
        /// The stimulator's monitor, by index or by (part of) its name (default: 0, unless only
        /// --preview is given).
        #[arg(long)]
        monitor: Option<String>,
        /// Also open the operator's preview window.
        #[arg(long)]
        preview: bool,
        /// Close after this many seconds (default: when the window is closed).
        #[arg(long)]
        seconds: Option<f64>,
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
        Command::Render {
            scene,
            out,
            reference,
            tolerance,
            max_depth,
            lattice,
            reference_method,
        } => {
            let cfg = config::load(&scene)?;
            let method = if reference {
                app::render::Method::Reference(
                    optistim::raycast::reference::ReferenceSettings {
                        tolerance,
                        max_depth,
                        lattice_per_px: lattice,
                        threads: cfg.settings.threads,
                        ..Default::default()
                    },
                    reference_method,
                )
            } else {
                app::render::Method::Quadrangle
            };
            let summary = app::render::run(&cfg, &scene.display().to_string(), &out, method)?;
            out!("{}", serde_json::to_string(&summary)?);
        }
        Command::RenderTrajectory {
            trajectory,
            scene,
            out,
            shard,
            threads,
        } => {
            let cfg = config::load(&scene)?;
            let shard = app::render_trajectory::Shard::parse(&shard).map_err(anyhow::Error::msg)?;
            let poses = optistim::trajectory::read(&trajectory)?;
            let bar = indicatif::ProgressBar::new(shard.range(poses.len()).len() as u64)
                .with_style(
                    indicatif::ProgressStyle::with_template(
                        "{bar:40} {pos}/{len} frames, {per_sec}, {eta} left",
                    )
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
                );
            let report =
                app::render_trajectory::run(&cfg, &poses, &out, shard, threads, &mut |done, _| {
                    bar.set_position(done as u64)
                })?;
            bar.finish_and_clear();
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::Exposure {
            trajectory,
            scene,
            out,
            keep,
            dnr_db,
            from,
            to,
            every,
            threads,
        } => {
            let cfg = config::load(&scene)?;
            let all = optistim::trajectory::read(&trajectory)?;
            let to = to.unwrap_or(all.len()).min(all.len());
            anyhow::ensure!(
                from < to,
                "--from {from} --to {to}: no frames ({} in the stream)",
                all.len()
            );
            anyhow::ensure!(every >= 1, "--every: at least 1");
            let poses: Vec<_> = all[from..to].iter().step_by(every).copied().collect();
            let bar = indicatif::ProgressBar::new(poses.len() as u64);
            let plan = app::exposure::ExposurePlan {
                keep,
                dnr_db,
                threads,
            };
            let report = app::exposure::run(&cfg, &poses, plan, &mut |done, _| {
                bar.set_position(done as u64)
            })?;
            bar.finish_and_clear();
            app::exposure::write(&report, &out)?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::Invert {
            images,
            start,
            samples,
        } => {
            let start: [f64; 6] = start
                .try_into()
                .map_err(|v: Vec<f64>| anyhow::anyhow!("--start: 6 values, got {}", v.len()))?;
            let mut pairs = Vec::new();
            for arg in &images {
                let (scene, image) = arg
                    .split_once('=')
                    .with_context(|| format!("{arg:?}: expected SCENE=IMAGE"))?;
                pairs.push((
                    config::load(std::path::Path::new(scene))?,
                    PathBuf::from(image),
                ));
            }
            let fit = app::invert::run(&pairs, start, samples)?;
            out!("{}", serde_json::to_string(&fit)?);
        }
        Command::Irradiance {
            scene,
            out,
            orders,
            steps,
        } => {
            let cfg = config::load(&scene)?;
            let summary = app::irradiance::run(&cfg, &out, orders, steps)?;
            out!("{}", serde_json::to_string(&summary)?);
        }
        Command::Stability { out, limit_s } => {
            let work =
                std::env::temp_dir().join(format!("optistim-stability-{}", std::process::id()));
            let reports =
                app::stability::run(&work, std::time::Duration::from_secs(limit_s), |r| {
                    eprintln!("{}: {:?} ({:.0} ms)", r.case, r.outcome, r.ms)
                })?;
            std::fs::write(&out, app::stability::markdown(&reports, &work))
                .with_context(|| format!("writing {}", out.display()))?;
            let wrong = reports.iter().filter(|r| !r.as_expected()).count();
            out!(
                "{}",
                serde_json::json!({"cases": reports.len(), "not_as_expected": wrong, "report": out})
            );
            if wrong > 0 {
                anyhow::bail!(
                    "{wrong} cases not as expected (see {}; the cases' scenes are in {})",
                    out.display(),
                    work.display()
                );
            }
            let _ = std::fs::remove_dir_all(&work);
        }
        Command::Sweep { sweep, out, fit } => {
            let report = app::sweep::run(&sweep, &out, fit.as_deref(), |line| eprintln!("{line}"))?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::VerifyBudget {
            trajectory,
            scene,
            frames,
            rows,
            out,
            tolerance,
            max_depth,
            lattice,
            reference_method,
            render,
            keep_frames,
        } => {
            let cfg = config::load_with_render(&scene, &render)?;
            let reference = optistim::raycast::reference::ReferenceSettings {
                tolerance,
                max_depth,
                lattice_per_px: lattice,
                ..Default::default()
            };
            let report = app::verify_budget::run(
                &cfg,
                &scene.display().to_string(),
                &trajectory,
                frames,
                rows.as_deref(),
                &reference,
                reference_method,
                &out,
                keep_frames,
                |line| eprintln!("{line}"),
            )?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::Plan {
            trajectory,
            scene,
            out,
        } => {
            let cfg = config::load(&scene)?;
            let report = app::plan::run(&cfg, &scene.display().to_string(), &trajectory, &out)?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::FitModel { csv, out } => {
            let (m, rows) = app::sweep::fit_csv(&csv)?;
            let names: Vec<String> = csv.iter().map(|c| c.display().to_string()).collect();
            let how = format!(
                "optistim fit-model {} --out {}",
                names.join(" "),
                out.display()
            );
            std::fs::write(&out, app::sweep::model_text(&m, &how, &rows))
                .with_context(|| format!("{}", out.display()))?;
            out!("{}", serde_json::to_string(&m)?);
        }
        Command::Compare {
            scene,
            photo,
            max_shift,
            out,
        } => {
            let cfg = config::load(&scene)?;
            let report = app::compare::run(
                &cfg,
                &scene.display().to_string(),
                &photo,
                max_shift,
                out.as_deref(),
            )?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::Bench {
            trajectory,
            scene,
            preset,
            threads,
            frames,
            per_frame,
            against,
        } => {
            let tune = |mut cfg: config::Config| -> anyhow::Result<config::Config> {
                if let Some(p) = &preset {
                    cfg.settings = Settings::preset(p).with_context(|| {
                        format!("--preset {p}: allowed are default, high_accuracy")
                    })?;
                }
                if let Some(t) = threads {
                    cfg.settings.threads = t;
                }
                Ok(cfg)
            };
            let cfg = tune(match &scene {
                Some(p) => config::load(p)?,
                None => config::parse(
                    app::bench::DEFAULT_SCENE,
                    "<embedded config/nrho_bench.toml>",
                )?,
            })?;
            let mut sink = match &per_frame {
                Some(p) => Some(std::io::BufWriter::new(
                    std::fs::File::create(p).with_context(|| format!("{}", p.display()))?,
                )),
                None => None,
            };
            // The first failed write of a per-frame line, reported once the run is over.
            let mut failed: Option<std::io::Error> = None;
            let mut write = |line: String| {
                if let Some(w) = sink.as_mut() {
                    use std::io::Write;
                    if let Err(e) = writeln!(w, "{line}") {
                        failed.get_or_insert(e);
                    }
                }
            };
            match &against {
                None => {
                    let report = app::bench::run(&cfg, trajectory.as_deref(), frames, |row| {
                        write(serde_json::to_string(row).unwrap_or_default())
                    })?;
                    out!("{}", serde_json::to_string(&report)?);
                }
                Some(a) => {
                    let other = tune(config::load(a)?)?;
                    let report = app::bench::compare(
                        &cfg,
                        &other,
                        trajectory.as_deref(),
                        frames,
                        |which, row| {
                            let mut v = serde_json::to_value(row).unwrap_or_default();
                            if let serde_json::Value::Object(o) = &mut v {
                                o.insert("scene".into(), which.into());
                            }
                            write(v.to_string())
                        },
                    )?;
                    out!("{}", serde_json::to_string(&report)?);
                }
            }
            if let (Some(w), Some(p)) = (sink.as_mut(), &per_frame) {
                use std::io::Write;
                let flushed = w.flush();
                if let Some(e) = failed.or(flushed.err()) {
                    return Err(e).with_context(|| format!("--per-frame {}", p.display()));
                }
            }
        }
        Command::Serve(args) => serve(*args)?,
        Command::Replay {
            file,
            rate,
            to,
            frames,
            mode,
            report,
            token_file,
        } => {
            let mode = parse_mode(&mode)?;
            let token = token_file
                .map(|f| optistim::server::access::Access::read_token_file(&f))
                .transpose()?;
            let r = app::replay::run(&file, &to, rate, frames, mode, token.as_deref())?;
            let text = serde_json::to_string_pretty(&r)?;
            if let Some(p) = report {
                std::fs::write(&p, &text).with_context(|| format!("{}", p.display()))?;
            }
            out!("{}", serde_json::to_string(&r)?);
        }
        Command::BenchEndpoints {
            trajectory,
            scene,
            frames,
            present,
        } => {
            use optistim::server::frames::PresenterChoice;
            let (cfg, label) = daemon_scene(scene.as_deref())?;
            let poses = app::replay::spread(app::replay::read_poses(&trajectory)?, frames);
            let presenter = match present.as_str() {
                "cpu" => PresenterChoice::Cpu,
                "offscreen" => PresenterChoice::Offscreen,
                "auto" => PresenterChoice::Auto,
                other => anyhow::bail!("--present {other}: allowed are cpu, offscreen, auto"),
            };
            let report = app::bench_endpoints::run(&cfg, &label, &poses, presenter)?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::BenchWatching {
            trajectory,
            scene,
            frames,
            rounds,
            clients,
            poll_ms,
        } => {
            let (cfg, label) = daemon_scene(scene.as_deref())?;
            let poses = app::replay::spread(app::replay::read_poses(&trajectory)?, frames);
            let options = app::bench_watching::WatchingOptions {
                rounds,
                clients,
                poll_ms,
                ..Default::default()
            };
            let report = app::bench_watching::run(&cfg, &label, &poses, &options)?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::BenchDisplay {
            scene,
            screen,
            frames,
        } => {
            let cfg = config::load(&scene)?;
            let screen_px = parse_size(&screen)
                .with_context(|| format!("--screen {screen}: expected WxH, e.g. 1024x1024"))?;
            let report = app::bench::run_display(
                &cfg,
                &scene.display().to_string(),
                Some(screen_px),
                frames,
            )?;
            out!("{}", serde_json::to_string(&report)?);
        }
        Command::Show {
            scene,
            monitor,
            preview,
            seconds,
        } => {
            let cfg = config::load(&scene)?;
            let options = app::show::ShowOptions {
                monitor: monitor.map(|m| m.parse().expect("infallible")),
                preview,
                seconds,
            };
            app::show::run(&cfg, &scene.display().to_string(), options, |p| {
                use std::io::Write;
                let mut out = std::io::stdout().lock();
                let _ = writeln!(out, "{}", serde_json::to_string(&p).unwrap_or_default());
                let _ = out.flush();
            })?;
        }
        Command::Calibrate { scene, steps, out } => {
            let cfg = config::load(&scene)?;
            let run = app::calibrate::run(&cfg, &scene.display().to_string(), steps, &out)?;
            out!("{}", serde_json::to_string(&run)?);
        }
    }
    Ok(())
}

/// `optistim serve`'s arguments.
#[derive(clap::Args)]
struct ServeArgs {
    /// Scene TOML with a [stimulator] section (default: the embedded config/daemon.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Pose listener (port 0 picks a free port; the chosen one is printed).
    #[arg(long, default_value = optistim::server::DEFAULT_LISTEN)]
    listen: std::net::SocketAddr,
    /// HTTP listener.
    #[arg(long, default_value = optistim::server::DEFAULT_HTTP)]
    http: std::net::SocketAddr,
    /// Serial line with the binary protocol (e.g. /dev/ttyUSB0).
    #[arg(long)]
    serial: Option<String>,
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// auto (fullscreen window when a display exists) | offscreen | window | cpu.
    #[arg(long, default_value = "auto")]
    present: String,
    /// The stimulator's monitor for the window, by index or name.
    #[arg(long, default_value = "0")]
    monitor: String,
    /// Also open the operator's preview window (with --present window).
    #[arg(long)]
    preview: bool,
    /// free (latest pose wins) | lockstep (every pose, in order).
    #[arg(long, default_value = "free")]
    mode: String,
    /// Record every received message (JSON lines) to this file.
    #[arg(long)]
    record: Option<PathBuf>,
    /// The access token (first line; the file mode 600): required on mutating HTTP calls
    /// and in a TCP client's hello. Needed to listen on anything but loopback.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Listen on non-loopback addresses without a token (anyone who reaches the ports
    /// steers the bench).
    #[arg(long)]
    insecure: bool,
    /// Also serve SurRender clients here (port 5151 by convention; docs/protocol.md).
    #[arg(long)]
    surrender: Option<std::net::SocketAddr>,
    /// Also serve CORTO's decoupled in-the-loop client: its pose port (UDP, 51001 in its
    /// script) ...
    #[arg(long, requires = "corto_image")]
    corto_pose: Option<std::net::SocketAddr>,
    /// ... and its image port (TCP, 30001); the scene needs a [corto] section.
    #[arg(long, requires = "corto_pose")]
    corto_image: Option<std::net::SocketAddr>,
    /// A folder that scenes named over the network, and the files they name, must lie in
    /// (repeatable; default: the folder of --config).
    #[arg(long)]
    scene_dir: Vec<PathBuf>,
}

fn parse_mode(s: &str) -> anyhow::Result<optistim::server::frames::Mode> {
    serde_json::from_value(serde_json::Value::String(s.into()))
        .with_context(|| format!("--mode {s}: allowed are free, lockstep"))
}

#[allow(clippy::too_many_arguments)]
fn serve(args: ServeArgs) -> anyhow::Result<()> {
    use optistim::server::{self, access::Access, frames::PresenterChoice};
    let ServeArgs {
        config: path,
        listen,
        http,
        serial,
        baud,
        present,
        monitor,
        preview,
        mode,
        record,
        token_file,
        insecure,
        scene_dir,
        surrender,
        corto_pose,
        corto_image,
    } = args;
    let token = token_file
        .map(|f| Access::read_token_file(&f))
        .transpose()?;
    // Scenes named over the network stay in these folders: by default the config's own.
    let scene_dirs = match (&scene_dir[..], &path) {
        ([], Some(p)) => vec![
            p.parent()
                .filter(|d| !d.as_os_str().is_empty())
                .map_or_else(|| PathBuf::from("."), PathBuf::from),
        ],
        _ => scene_dir,
    };
    let access = Access::new(token.as_deref(), &scene_dirs, insecure)?;
    let (text, label) = match &path {
        Some(p) => (
            std::fs::read_to_string(p).with_context(|| format!("{}", p.display()))?,
            p.display().to_string(),
        ),
        None => (
            server::DEFAULT_CONFIG.to_string(),
            "<embedded config/daemon.toml>".to_string(),
        ),
    };
    let cfg = config::parse(&text, &label)?;
    let sha = optistim::io::sha256_hex(text.as_bytes());
    let presenter = match present.as_str() {
        "auto" => PresenterChoice::Auto,
        "offscreen" => PresenterChoice::Offscreen,
        "cpu" => PresenterChoice::Cpu,
        "window" => PresenterChoice::Window {
            monitor: monitor.parse().expect("infallible"),
            preview,
        },
        other => anyhow::bail!("--present {other}: allowed are auto, offscreen, window, cpu"),
    };
    let daemon = server::Server::start(server::ServeOptions {
        config: cfg,
        config_label: label.clone(),
        config_sha256: sha,
        listen,
        http,
        serial: serial.map(|s| (s, baud)),
        presenter,
        mode: parse_mode(&mode)?,
        record,
        access,
        surrender,
        corto: corto_pose.zip(corto_image),
    })?;
    // The addresses as bound (port 0 picks a free one), for people and scripts (a closed
    // stdout does not stop the daemon).
    let _ = writeln!(
        std::io::stdout(),
        "{}",
        serde_json::json!({
            "listening": daemon.tcp_addr.to_string(),
            "http": format!("http://{}", daemon.http_addr),
            "surrender": daemon.surrender_addr.map(|a| a.to_string()),
            "corto": daemon.corto_addrs.map(|(p, i)| [p.to_string(), i.to_string()]),
            "presenter": daemon.presenter(),
            "config": label,
        })
    );
    wait_for_signal()?;
    let report = daemon.shutdown();
    // Whoever started the daemon may have stopped reading its stdout: a closed pipe is not
    // a reason to fail a clean stop.
    let _ = writeln!(std::io::stdout(), "{}", serde_json::to_string(&report)?);
    Ok(())
}

/// Blocks until SIGINT or SIGTERM.
fn wait_for_signal() -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        #[cfg(unix)]
        {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
            tokio::select! {
                r = tokio::signal::ctrl_c() => r?,
                _ = term.recv() => {}
            }
        }
        #[cfg(not(unix))]
        tokio::signal::ctrl_c().await?;
        tracing::info!("signal received: stopping");
        Ok::<(), std::io::Error>(())
    })?;
    Ok(())
}

/// The scene a benchmarked daemon serves, and its label: the file named, or the embedded
/// default.
fn daemon_scene(scene: Option<&std::path::Path>) -> anyhow::Result<(config::Config, String)> {
    let (text, label) = match scene {
        Some(p) => (
            std::fs::read_to_string(p).with_context(|| format!("{}", p.display()))?,
            p.display().to_string(),
        ),
        None => (
            optistim::server::DEFAULT_CONFIG.to_string(),
            "<embedded config/daemon.toml>".to_string(),
        ),
    };
    Ok((config::parse(&text, &label)?, label))
}

fn parse_size(s: &str) -> Option<[usize; 2]> {
    let (w, h) = s.split_once('x')?;
    Some([w.trim().parse().ok()?, h.trim().parse().ok()?])
}

/// The error and its causes, each cause once: our typed errors often quote their source in
/// their own message already (`file: cannot read: No such file or directory`).
fn message(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg += ": ";
            msg += &c;
        }
    }
    msg
}

fn main() -> ExitCode {
    optistim::app::retain_freed_memory();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "optistim=info,winit=error,warn".into()),
        )
        .init();
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("optistim: error: {}", message(&e));
            ExitCode::FAILURE
        }
    }
}
