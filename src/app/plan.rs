//! `optistim plan TRAJECTORY --scene FILE --out FILE.csv`: what the fidelity planner chooses
//! for every pose of a stream and what error it predicts, without rendering; and the
//! stretches of the stream where it does not expect to meet the budget.
//!
//! Planning alone takes milliseconds a frame (the probe of what the frame shows and the error
//! model, [`crate::fidelity::budget`]: the Artemis I flyby's 1,441 poses in 7 s on 2 cores),
//! so a bench sees before a run which frames will not claim the budget, and by how much each
//! figure is predicted over it. A frame is counted once, at the plan it starts from: a frame
//! whose relief reads estimate their own error is judged again once it is rendered
//! ([`crate::fidelity::budget::Plan::observe`]), which planning alone does not do. The
//! measured error is `verify-budget`'s.

use super::AppError;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// One pose as planned.
#[derive(Clone, Debug, Serialize)]
pub struct PlannedFrame {
    pub row: usize,
    pub frame_id: u64,
    pub range_m: f64,
    pub phase_deg: f64,
    /// Lit pixels the planner's probe found (0: nothing lit, predicted exact).
    pub lit_px: f64,
    pub points_per_pixel: f64,
    pub self_shadowing: String,
    pub map_filter: String,
    pub relief_refine: u32,
    pub predicted_median: f64,
    pub predicted_p99: f64,
    pub predicted_total: f64,
    pub meets_budget: bool,
    /// Why the frame lies outside what the error model was fitted on ("" where it does not).
    pub outside_model: String,
}

/// The stream as planned.
#[derive(Debug, Serialize)]
pub struct PlanReport {
    pub trajectory: String,
    pub scene: String,
    pub budget: crate::fidelity::budget::Budget,
    pub frames: usize,
    /// Frames with nothing lit.
    pub unlit: usize,
    pub predicted_to_meet: usize,
    pub share_predicted_to_meet: f64,
    /// The runs of consecutive rows not predicted to meet the budget, first and last.
    pub not_predicted_to_meet: Vec<[usize; 2]>,
    /// Of those frames, how many are predicted over the budget on each figure.
    pub over_median: usize,
    pub over_p99: usize,
    pub over_total: usize,
    pub seconds: f64,
    pub csv: String,
}

/// Plans every pose of `trajectory` with `config`'s budget (the default budget where the file
/// has none), writes one row per pose to `out` (CSV) and returns the summary.
pub fn run(
    config: &crate::config::Config,
    scene_label: &str,
    trajectory: &Path,
    out: &Path,
) -> Result<PlanReport, AppError> {
    let t0 = Instant::now();
    let poses = crate::trajectory::read(trajectory)?;
    let planner = config
        .planner_or_default()
        .map_err(|e| AppError::Plan(e.to_string()))?;
    let budget = planner.budget();
    let frames: Vec<PlannedFrame> = poses
        .iter()
        .enumerate()
        .map(|(row, (_, pose))| {
            let plan = planner.plan(&config.scene, pose);
            PlannedFrame {
                row,
                frame_id: pose.frame_id,
                range_m: pose.camera_position_m.length(),
                phase_deg: plan.features.phase_deg,
                lit_px: plan.features.lit_px,
                points_per_pixel: plan.points_per_pixel,
                self_shadowing: format!("{:?}", plan.self_shadowing),
                map_filter: format!("{:?}", plan.map_filter),
                relief_refine: plan.relief_refine,
                predicted_median: plan.predicted.median,
                predicted_p99: plan.predicted.p99,
                predicted_total: plan.predicted.total,
                meets_budget: plan.meets_budget,
                outside_model: plan.outside_model.unwrap_or("").to_string(),
            }
        })
        .collect();
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| AppError::OutDir {
            path: dir.display().to_string(),
            source,
        })?;
    }
    let bad = |e: &dyn std::fmt::Display| AppError::Plan(format!("{}: {e}", out.display()));
    let mut wr = csv::Writer::from_path(out).map_err(|e| bad(&e))?;
    for f in &frames {
        wr.serialize(f).map_err(|e| bad(&e))?;
    }
    wr.flush().map_err(|e| bad(&e))?;
    let short: Vec<&PlannedFrame> = frames.iter().filter(|f| !f.meets_budget).collect();
    let over = |figure: fn(&PlannedFrame) -> f64, limit: f64| {
        // Above the budget, or unknown (NaN).
        let above = |x: f64| x.partial_cmp(&limit).is_none_or(|o| o.is_gt());
        short.iter().filter(|f| above(figure(f))).count()
    };
    let met = frames.len() - short.len();
    Ok(PlanReport {
        trajectory: trajectory.display().to_string(),
        scene: scene_label.to_string(),
        budget,
        frames: frames.len(),
        unlit: frames.iter().filter(|f| f.lit_px == 0.0).count(),
        predicted_to_meet: met,
        share_predicted_to_meet: met as f64 / frames.len().max(1) as f64,
        not_predicted_to_meet: runs(short.iter().map(|f| f.row)),
        over_median: over(|f| f.predicted_median, budget.median),
        over_p99: over(|f| f.predicted_p99, budget.p99),
        over_total: over(|f| f.predicted_total, budget.total),
        seconds: t0.elapsed().as_secs_f64(),
        csv: out.display().to_string(),
    })
}

/// Increasing row numbers as runs of consecutive rows, `[first, last]`.
fn runs(rows: impl Iterator<Item = usize>) -> Vec<[usize; 2]> {
    let mut out: Vec<[usize; 2]> = Vec::new();
    for r in rows {
        match out.last_mut() {
            Some(last) if last[1] + 1 == r => last[1] = r,
            _ => out.push([r, r]),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::runs;

    #[test]
    fn rows_gather_into_runs() {
        assert_eq!(
            runs([3, 4, 5, 9, 11, 12].into_iter()),
            vec![[3, 5], [9, 9], [11, 12]]
        );
        assert!(runs(std::iter::empty()).is_empty());
    }
}
