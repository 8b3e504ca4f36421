//! Projection and distortion of points (Sec. 4.7, Eqs. 39-40): quadrangle midpoints and, for
//! kernels that use the footprint, the grid vertices (shared by neighbouring quadrangles, so
//! their projected polygons tile the image). Distortion is applied to the points before
//! gridding, so energy lands where the rays go. Coordinates are on the fine grid.

use super::pruning::PRUNED;
use super::sampling::GridTrig;
use super::view::View;
use rayon::prelude::*;

const NAN2: [f64; 2] = [f64::NAN, f64::NAN];

/// Projected midpoints of kept quadrangles (NaN elsewhere).
pub fn project_midpoints(view: &View, trig: &GridTrig, keep: &[u8], out: &mut Vec<[f64; 2]>) {
    let nl = trig.n_lon();
    out.clear();
    out.resize(keep.len(), NAN2);
    out.par_chunks_mut(nl).enumerate().for_each(|(k, row)| {
        for (i, o) in row.iter_mut().enumerate() {
            if keep[k * nl + i] != PRUNED {
                let p = view.surface(trig.mid_dir(i, k)).0;
                *o = view.pixel(view.to_camera(p)).unwrap_or(NAN2);
            }
        }
    });
}

/// Projected grid vertices, `(n_lon + 1) x (n_lat + 1)`, row-major (NaN behind the camera).
pub fn project_vertices(view: &View, trig: &GridTrig, out: &mut Vec<[f64; 2]>) {
    let nv = trig.n_lon() + 1;
    out.clear();
    out.resize(nv * (trig.n_lat() + 1), NAN2);
    out.par_chunks_mut(nv).enumerate().for_each(|(k, row)| {
        for (i, o) in row.iter_mut().enumerate() {
            let p = view.surface(trig.vertex_dir(i, k)).0;
            *o = view.pixel(view.to_camera(p)).unwrap_or(NAN2);
        }
    });
}
