//! The commands behind the binary. Each returns a typed result that `main.rs` prints.

pub mod bench;
pub mod bench_endpoints;
pub mod calibrate;
pub mod compare;
pub mod exposure;
pub mod invert;
pub mod irradiance;
pub mod products;
pub mod render;
pub mod render_trajectory;
pub mod replay;
pub mod show;
pub mod stability;
pub mod sweep;
pub mod verify_budget;

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
