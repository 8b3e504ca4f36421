//! Pruning of inactive quadrangles (Sec. 4.5): FOV (Eqs. 26-27), observability (Eqs. 28-29)
//! and illumination (Eqs. 30-31).
//!
//! The FOV is tested at the midpoint, then, where that fails, over the box of the corners
//! (a quadrangle can straddle the frame's edge with its midpoint outside). The other
//! conditions are tested at the midpoint and at the four corners, with each point's own
//! directions to the camera and the Sun (finite distances). A quadrangle is kept when some
//! point is visible and some point is lit; it is marked as a *boundary* quadrangle (it
//! straddles the limb or the terminator) when any point fails either test, so the integration
//! step clamps its integrand there instead of trusting a closed form.

use super::sampling::GridTrig;
use super::view::View;
use glam::DVec3;
use rayon::prelude::*;

pub const PRUNED: u8 = 0;
pub const INTERIOR: u8 = 1;
pub const BOUNDARY: u8 = 2;

/// Classifies one quadrangle from the unit directions of its midpoint and corners.
#[inline(always)]
pub fn classify(view: &View, mid: DVec3, corners: [DVec3; 4]) -> u8 {
    let (p_mid, _) = view.surface(mid);
    if !view.in_fov(view.to_camera(p_mid)) && !view.corners_reach_fov(corners) {
        return PRUNED;
    }
    let (mut vis_any, mut lit_any, mut vis_all, mut lit_all) = (false, false, true, true);
    for dir in std::iter::once(mid).chain(corners) {
        let (p, n) = view.surface(dir);
        let vis = n.dot(view.cam_csf - p) > 0.0;
        let lit = n.dot(view.sun_csf - p) > 0.0;
        vis_any |= vis;
        lit_any |= lit;
        vis_all &= vis;
        lit_all &= lit;
    }
    if !(vis_any && lit_any) {
        PRUNED
    } else if vis_all && lit_all {
        INTERIOR
    } else {
        BOUNDARY
    }
}

/// Fills `keep` (row-major, latitude rows) with the class of every quadrangle; returns how
/// many are kept.
pub fn prune(view: &View, trig: &GridTrig, keep: &mut Vec<u8>) -> usize {
    let (nl, nk) = (trig.n_lon(), trig.n_lat());
    keep.clear();
    keep.resize(nl * nk, PRUNED);
    keep.par_chunks_mut(nl)
        .enumerate()
        .map(|(k, row)| {
            let mut kept = 0;
            for (i, out) in row.iter_mut().enumerate() {
                *out = classify(view, trig.mid_dir(i, k), trig.corner_dirs(i, k));
                kept += (*out != PRUNED) as usize;
            }
            kept
        })
        .sum()
}
