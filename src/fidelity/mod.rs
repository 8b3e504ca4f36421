//! Fidelity: how far a frame is from the truth, and (as the planner grows) the cheapest
//! settings that keep it inside a budget. It owns no pixels: it reads frames and the converged
//! reference ([`crate::raycast::reference`]) and hands settings to the renderers.
//!
//! - [`metrics`]: a frame's error against its reference (total, median / p95 / p99 per lit
//!   pixel, SSIM), the figures the sweep charts and the budget is written in.

pub mod budget;
pub mod metrics;
