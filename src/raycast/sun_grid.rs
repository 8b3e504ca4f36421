//! A mesh's shadows on itself through a grid seen from the Sun (after SLIM Sec. 6.1, which
//! traces solar rays through a uniform grid over the body; here the grid lies in the plane
//! across the Sun's direction, so a shadow ray never leaves its cell).
//!
//! On a closed surface a ray from a surface point toward the Sun that meets the body must
//! leave it again through a facet that faces the Sun. So only the sun-facing facets are
//! binned, by their projections along the Sun's direction from the body's centre, `s0`, into
//! square cells; a shadow ray from `p` is tested against the facets of the one cell `p`
//! projects into (Möller-Trumbore in f64). The Sun's direction seen from a point of the body
//! differs from `s0` by at most `R / d_sun`: the facets' footprints are widened by what that
//! turns into over the body's diameter, so that every facet a ray can meet is in its cell.
//!
//! Most facets are lit all over: no other sun-facing facet lies sunward of them across the
//! Sun's direction. Those are found once per frame ([`SunGrid::clear`]): a facet is clear when
//! every facet binned with it either lies wholly farther from the Sun than its nearest vertex
//! or has a projection that does not overlap its own (separated along one of the six edge
//! normals of the two projected triangles; neighbours that share an edge touch along it and
//! do not overlap). A shadow ray from a clear facet can meet nothing, so it is not cast: its
//! projection lies inside the facet's own, where no other facet lies in front. What this
//! leaves to chance is the shadow ray's lift off its facet (a millionth of the body's radius)
//! carrying its origin across the facet's edge into a neighbour's projection, and the Sun's
//! direction seen from each point, which differs from `s0` by at most `R / d_sun` (3e-9 rad
//! on Bennu): a strip micrometres wide along a facet's edge.
//!
//! Built per frame (the Sun moves) in `O(facets)`: for Bennu's 12,288 facets about a
//! millisecond. Open meshes (a ray can meet the back of a facet and stop there) keep the BVH.

use super::bins::Bins;
use crate::body::mesh::Mesh;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};

/// Cells per sun-facing facet, about.
const CELLS_PER_FACET: f64 = 2.0;

/// A sun-facing facet seen along the Sun's direction: its index in the mesh, its corners and
/// their box in the grid's plane [m], and its extent along the direction to the Sun [m].
struct SunFacing {
    facet: usize,
    corners: [DVec2; 3],
    lo: DVec2,
    hi: DVec2,
    near: f64,
    far: f64,
    /// The unit normals of its projected edges (zero for an edge of no length) and the
    /// projection's extent along each [m]: its side of every separating axis test.
    axes: [DVec2; 3],
    extent: [[f64; 2]; 3],
}

impl SunFacing {
    fn new(facet: usize, corners: [DVec2; 3], near: f64, far: f64) -> SunFacing {
        let axes = [0, 1, 2].map(|i| {
            let e = corners[(i + 1) % 3] - corners[i];
            DVec2::new(-e.y, e.x).normalize_or_zero()
        });
        SunFacing {
            facet,
            corners,
            lo: corners[0].min(corners[1]).min(corners[2]),
            hi: corners[0].max(corners[1]).max(corners[2]),
            near,
            far,
            axes,
            extent: axes.map(|n| interval(&corners, n)),
        }
    }

    /// Whether the projections of `self` and `other` overlap by more than `eps` [m] (no edge
    /// normal of either separates them).
    #[inline]
    fn overlaps(&self, other: &SunFacing, eps: f64) -> bool {
        let apart = |[a0, a1]: [f64; 2], [b0, b1]: [f64; 2]| a1 <= b0 + eps || b1 <= a0 + eps;
        !(0..3).any(|i| apart(self.extent[i], interval(&other.corners, self.axes[i])))
            && !(0..3).any(|i| apart(interval(&self.corners, other.axes[i]), other.extent[i]))
    }
}

/// A sun-facing facet's fields the lit-all-over test reads first, gathered per cell: its index
/// among the sun-facing, the first cell its box reaches, its extent along `s0` (the nearer end
/// raised by the tolerance) and its box [m].
struct Gathered {
    k: usize,
    first: [usize; 2],
    near: f64,
    far: f64,
    lo: DVec2,
    hi: DVec2,
}

/// The extent of the points `p` along the direction `n`.
#[inline]
fn interval(p: &[DVec2; 3], n: DVec2) -> [f64; 2] {
    let (a, b, c) = (p[0].dot(n), p[1].dot(n), p[2].dot(n));
    [a.min(b).min(c), a.max(b).max(c)]
}

/// The sun-facing facets of a mesh, binned across the Sun's direction.
pub struct SunGrid {
    /// Unit axes of the grid's plane, across `s0`.
    e1: DVec3,
    e2: DVec3,
    /// The grid's corner in the plane [m] and its cell side [m].
    lo: DVec2,
    cell_m: f64,
    cells: [usize; 2],
    /// Facets by cell, as indices of `tris`.
    bins: Bins,
    /// Per sun-facing facet: a vertex and two edges [m] (body frame).
    tris: Vec<[DVec3; 3]>,
    /// The Sun's direction from the body's centre, `s0`, and per sun-facing facet its
    /// sunmost vertex's coordinate along it [m].
    s0: DVec3,
    sunmost: Vec<f64>,
    /// Per facet of the mesh: lit all over (see the module's documentation).
    clear: Vec<bool>,
}

impl SunGrid {
    /// The grid of the closed `mesh` for the Sun at `sun_m` (body frame); `None` for an open
    /// mesh or a Sun inside the body's bounding sphere.
    pub fn new(mesh: &Mesh, sun_m: DVec3) -> Option<SunGrid> {
        let r = mesh.bounding_radius_m();
        let d_sun = sun_m.length();
        if mesh.report().open_edges != 0 || d_sun <= 2.0 * r || !d_sun.is_finite() {
            return None;
        }
        let s0 = sun_m / d_sun;
        let e1 = s0.any_orthonormal_vector();
        let e2 = s0.cross(e1);
        // How far a ray from a point of the body drifts across s0 over the body's diameter,
        // with a margin for rounding and for the shadow ray's lift off its facet.
        let spread = (r / (d_sun - r)).asin();
        let pad = 2.0 * r * spread * 2.0 + 1e-9 * r;
        let v = mesh.vertices_m();
        // The sun-facing facets: facing the Sun from some point of the body (a facet edge-on
        // to s0 may face the Sun seen from elsewhere). A mesh's normals are finite: its
        // vertices are, and its degenerate facets were dropped.
        let facing = -spread.sin();
        let normals = mesh.normals();
        let sun_facing: Vec<u32> = (0..normals.len() as u32)
            .filter(|&f| normals[f as usize].dot(s0) >= facing)
            .collect();
        if sun_facing.is_empty() {
            return None;
        }
        // Per sun-facing facet (in parallel, in facet order): a vertex and two edges, and its
        // projection and extent along s0 [m]; each written in place.
        let corners_of = |f: u32| mesh.facets()[f as usize].map(|k| v[k as usize]);
        let tris: Vec<[DVec3; 3]> = sun_facing
            .par_iter()
            .map(|&f| {
                let [a, b, c] = corners_of(f);
                [a, b - a, c - a]
            })
            .collect();
        let shadows_of: Vec<SunFacing> = sun_facing
            .par_iter()
            .map(|&f| {
                let [a, b, c] = corners_of(f);
                let p = [a, b, c].map(|x| DVec2::new(x.dot(e1), x.dot(e2)));
                let depth = [a, b, c].map(|x| x.dot(s0));
                SunFacing::new(
                    f as usize,
                    p,
                    depth[0].min(depth[1]).min(depth[2]),
                    depth[0].max(depth[1]).max(depth[2]),
                )
            })
            .collect();
        // The padded boxes across s0 [m].
        let (lo, hi) = shadows_of.iter().fold(
            (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
            |(lo, hi), a| (lo.min(a.lo), hi.max(a.hi)),
        );
        let (lo, hi) = (lo - DVec2::splat(pad), hi + DVec2::splat(pad));
        let extent = hi - lo;
        let cell_m = (extent.x * extent.y / (CELLS_PER_FACET * tris.len() as f64))
            .sqrt()
            .max(1e-12 * r);
        let cells = [
            ((extent.x / cell_m).ceil() as usize).clamp(1, 4096),
            ((extent.y / cell_m).ceil() as usize).clamp(1, 4096),
        ];
        let cell_m = (extent.x / cells[0] as f64).max(extent.y / cells[1] as f64);
        // Truncation is the floor here (negative values clamp to 0): no libm call.
        let index = |x: f64, n: usize| ((x / cell_m).max(0.0) as usize).min(n - 1);
        let spans: Vec<[[usize; 2]; 2]> = shadows_of
            .iter()
            .map(|f| {
                let (a, b) = (f.lo - DVec2::splat(pad) - lo, f.hi + DVec2::splat(pad) - lo);
                [
                    [index(a.x, cells[0]), index(b.x, cells[0])],
                    [index(a.y, cells[1]), index(b.y, cells[1])],
                ]
            })
            .collect();
        let bins = Bins::new(cells, &spans);
        // A facet is clear when no facet binned with it can lie sunward of it over its
        // projection. Separations are taken with a tolerance a billionth of the body's radius.
        let eps = 1e-9 * r;
        let sunmost: Vec<f64> = shadows_of.iter().map(|a| a.far).collect();
        // Cell by cell (rows in parallel), each pair of its facets in the first cell both
        // reach (so each pair once), tested both ways: the other's reach sunward first, then
        // the boxes, then the projections (the overlap test is symmetric). The cell's facets'
        // first cells, extents along s0 and boxes are gathered first, so that the pairs read
        // them from one small array.
        let blocked: Vec<AtomicBool> = (0..shadows_of.len())
            .map(|_| AtomicBool::new(false))
            .collect();
        (0..cells[1])
            .into_par_iter()
            .for_each_init(Vec::new, |local: &mut Vec<Gathered>, y| {
                for x in 0..cells[0] {
                    let items = bins.cell(x, y);
                    if items.len() < 2 {
                        continue;
                    }
                    local.clear();
                    local.extend(items.iter().map(|&g| {
                        let (g, f) = (g as usize, &shadows_of[g as usize]);
                        let [[x0, _], [y0, _]] = spans[g];
                        Gathered {
                            k: g,
                            first: [x0, y0],
                            near: f.near + eps,
                            far: f.far,
                            lo: f.lo,
                            hi: f.hi,
                        }
                    }));
                    for (i, a) in local.iter().enumerate() {
                        for b in &local[i + 1..] {
                            if x != a.first[0].max(b.first[0]) || y != a.first[1].max(b.first[1]) {
                                continue;
                            }
                            let b_over_a = b.far > a.near && !blocked[a.k].load(Relaxed);
                            let a_over_b = a.far > b.near && !blocked[b.k].load(Relaxed);
                            if (b_over_a || a_over_b)
                                && b.lo.cmplt(a.hi - eps).all()
                                && a.lo.cmplt(b.hi - eps).all()
                                && shadows_of[a.k].overlaps(&shadows_of[b.k], eps)
                            {
                                if b_over_a {
                                    blocked[a.k].store(true, Relaxed);
                                }
                                if a_over_b {
                                    blocked[b.k].store(true, Relaxed);
                                }
                            }
                        }
                    }
                }
            });
        let blocked: Vec<bool> = blocked.into_iter().map(AtomicBool::into_inner).collect();
        let mut clear = vec![false; mesh.facets().len()];
        for (a, blocked) in shadows_of.iter().zip(blocked) {
            clear[a.facet] = !blocked;
        }
        Some(SunGrid {
            e1,
            e2,
            lo,
            cell_m,
            cells,
            bins,
            tris,
            s0,
            sunmost,
            clear,
        })
    }

    /// Whether the mesh's facet `facet` is lit all over, so that no shadow ray from it needs
    /// casting (see the module's documentation).
    #[inline]
    pub fn clear(&self, facet: u32) -> bool {
        self.clear[facet as usize]
    }

    /// Whether a sun-facing facet lies on the ray `origin_m + t dir` (`dir` unit, toward the
    /// Sun), `t > 0`.
    #[inline]
    pub fn occluded(&self, origin_m: DVec3, dir: DVec3) -> bool {
        let q = DVec2::new(origin_m.dot(self.e1), origin_m.dot(self.e2)) - self.lo;
        let (x, y) = (q.x / self.cell_m, q.y / self.cell_m);
        // (Truncation is the floor of these non-negative values, without a libm call.)
        if !(x >= 0.0 && y >= 0.0 && x < self.cells[0] as f64 && y < self.cells[1] as f64) {
            return false;
        }
        // The ray's points sunward of its origin are farther along `s0` than it (the ray is
        // within `R / d_sun` of `s0`): a facet no part of which is farther cannot be met.
        let from = origin_m.dot(self.s0);
        self.bins.cell(x as usize, y as usize).iter().any(|&k| {
            if self.sunmost[k as usize] <= from {
                return false;
            }
            let [a, e1, e2] = self.tris[k as usize];
            let p = dir.cross(e2);
            let det = e1.dot(p);
            if det.abs() < 1e-300 {
                return false;
            }
            let inv = 1.0 / det;
            let s = origin_m - a;
            let u = s.dot(p) * inv;
            if !(0.0..=1.0).contains(&u) {
                return false;
            }
            let qv = s.cross(e1);
            let w = dir.dot(qv) * inv;
            w >= 0.0 && u + w <= 1.0 && e2.dot(qv) * inv > 0.0
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::mesh::{Mesh, geodesic_sphere};

    /// The lit-all-over flags are their definition: a sun-facing facet is blocked when another
    /// reaches farther sunward than its nearest vertex and their projections overlap (boxes,
    /// then the separating axes), over every pair of sun-facing facets (the grid's cells only
    /// prune pairs whose boxes are apart). On a bumpy sphere, for Suns all around it.
    #[test]
    fn the_clear_facets_are_those_no_pair_blocks() {
        let (mut v, f) = geodesic_sphere(1000.0, 8);
        // Radial bumps, so that facets shadow others.
        for (k, p) in v.iter_mut().enumerate() {
            let bump = 1.0 + 0.08 * ((k as f64 * 2.39).sin() * (k as f64 * 0.71).cos());
            *p *= bump;
        }
        let mesh = Mesh::new(v, f).unwrap();
        let (mut blocked_total, mut facing_total) = (0, 0);
        for k in 0..6 {
            let a = k as f64 * 1.1;
            let s0 = DVec3::new(a.cos(), a.sin() * 0.7, 0.5 * (a * 1.3).sin()).normalize();
            let grid = SunGrid::new(&mesh, s0 * 1.5e11).unwrap();
            let (e1, e2) = (grid.e1, grid.e2);
            let r = mesh.bounding_radius_m();
            let eps = 1e-9 * r;
            let facing = -(r / (1.5e11 - r)).asin().sin();
            let records: Vec<SunFacing> = (0..mesh.facets().len())
                .filter(|&f| mesh.normals()[f].dot(s0) >= facing)
                .map(|f| {
                    let c = mesh.facets()[f].map(|i| mesh.vertices_m()[i as usize]);
                    let d = c.map(|x| x.dot(s0));
                    SunFacing::new(
                        f,
                        c.map(|x| DVec2::new(x.dot(e1), x.dot(e2))),
                        d[0].min(d[1]).min(d[2]),
                        d[0].max(d[1]).max(d[2]),
                    )
                })
                .collect();
            for a in &records {
                let blocked = records.iter().any(|b| {
                    b.facet != a.facet
                        && b.far > a.near + eps
                        && b.lo.cmplt(a.hi - eps).all()
                        && a.lo.cmplt(b.hi - eps).all()
                        && a.overlaps(b, eps)
                });
                assert_eq!(
                    grid.clear(a.facet as u32),
                    !blocked,
                    "facet {}, Sun {k}",
                    a.facet
                );
                blocked_total += blocked as usize;
            }
            facing_total += records.len();
        }
        // Both kinds occur (1,128 of 3,843 blocked when written).
        assert!(
            blocked_total > 500 && blocked_total * 2 < facing_total,
            "{blocked_total} of {facing_total}"
        );
    }
}
