//! The commands behind the binary. Each returns a typed result that `main.rs` prints.

pub mod bench;
pub mod bench_endpoints;
pub mod bench_watching;
pub mod calibrate;
pub mod compare;
pub mod exposure;
pub mod invert;
pub mod irradiance;
pub mod plan;
pub mod products;
pub mod render;
pub mod render_trajectory;
pub mod replay;
pub mod show;
pub mod stability;
pub mod sweep;
pub mod verify_budget;

/// Keeps the memory of freed frames in the process for the next frame (glibc on Linux; a no-op
/// elsewhere). glibc hands a block of 128 KiB or more straight back to the kernel when it is
/// freed, and the heap's top once 128 KiB of it is free: a frame's image buffers (8 MB each at
/// 1024 x 1024, f64) then come back as fresh pages, each zeroed by the kernel at its first
/// touch. On Bennu (`config/bennu.toml`) that was a quarter of the render's time (64 -> 49 ms,
/// `docs/performance.md`). Blocks up to 32 MiB (glibc's most) now come from the heap, which
/// keeps up to 1 GiB free before it shrinks. The binary calls it at start; a program embedding
/// the library decides for itself.
pub fn retain_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt sets two of the allocator's thresholds under its own lock; it touches
    // no memory of ours.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}

#[derive(Debug, thiserror::Error)]
pub enum AppError {
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error(transparent)]
    Render(#[from] crate::render::RenderError),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error(transparent)]
    Stimulator(#[from] crate::stimulator::StimulatorError),
    #[error(transparent)]
    Trajectory(#[from] crate::trajectory::TrajectoryError),
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    #[error(transparent)]
    Display(#[from] crate::display::DisplayError),
    #[error("compare: {0}")]
    Compare(String),
    #[error("invert: {0}")]
    Invert(String),
    #[error("irradiance: {0}")]
    Irradiance(String),
    #[error("stability: {0}")]
    Stability(String),
    #[error("sweep: {0}")]
    Sweep(String),
    #[error("verify-budget: {0}")]
    VerifyBudget(String),
    #[error("plan: {0}")]
    Plan(String),
    #[error("replay: {0}")]
    Replay(String),
    #[error(transparent)]
    Server(#[from] crate::server::ServerError),
    #[error("{0}: the scene has no [stimulator] section")]
    NoStimulator(String),
    #[error("exposure: {0}")]
    Exposure(String),
    #[error("frame images: {0}")]
    Images(String),
    #[error("{path}: cannot create the output folder: {source}")]
    OutDir {
        path: String,
        source: std::io::Error,
    },
}
