//! Primary visibility by rasterisation: which facet of a mesh body each line of sight of the
//! sampled frame ([`super::sampled`]) meets first, without a ray.
//!
//! For a pinhole camera (no Brown distortion, Eq. 39 the identity) the projection of Eq. 40 is
//! projective, so a facet's image is a triangle and a line of sight meets the facet exactly
//! when its sample position lies inside that triangle. The facets are projected once per frame
//! and binned by the tiles of the image their bounding boxes reach; a region of the image (a
//! tile in the first pass, one pixel at the edges of the light) is then scan-converted over
//! the same sample positions the sampled frame casts (`n x n` per pixel), with a depth test on
//! `1/z` (linear in the image plane) keeping the nearest. The ray caster then only meets each
//! sample's own facet (a plane), and casts through the BVH where the raster cannot decide: a
//! sample exactly on a projected edge, or where the rasterisation does not apply (a distorted
//! camera, a vertex at or behind the camera's plane).
//!
//! Edges are evaluated in one orientation (from the lower vertex index to the higher) by
//! every facet that shares them, so that two neighbours agree bit for bit on which side of
//! their common edge a sample lies: no sample falls in a crack between them.

use super::bins::Bins;
use crate::body::mesh::Mesh;
use crate::camera::Intrinsics;
use glam::{DMat3, DVec2, DVec3};

/// A sample that sees no facet.
pub const NONE: u32 = u32::MAX;
/// A sample exactly on a projected edge: cast through the BVH.
pub const UNDECIDED: u32 = u32::MAX - 1;

/// A facet's projection [px].
struct Projected {
    facet: u32,
    /// Per edge opposite vertex `k`, `(A, B, C)` such that `A u + B v + C` is the doubled
    /// area of the triangle `(edge, q)`, positive inside; computed from the edge's lower
    /// vertex index to its higher, the sign then set, so that the facets sharing an edge
    /// evaluate it with the same bits.
    edges: [[f64; 3]; 3],
    /// `1/z` [1/m] of the vertices divided by the doubled area: the depth is
    /// `sum_k w_k inv_z[k]` with `w_k` the edge values.
    inv_z: [f64; 3],
    lo: DVec2,
    hi: DVec2,
}

impl Projected {
    /// The facet `f` with vertices `p` (image) of mesh indices `index` and `1/z` [1/m]:
    /// `None` when it has no area in the image, or shows its back and `cull`.
    fn new(f: u32, p: [DVec2; 3], index: [u32; 3], inv_z: [f64; 3], cull: bool) -> Option<Self> {
        // Edge opposite vertex k: from vertex k+1 to k+2.
        let mut edges = [[0.0; 3]; 3];
        for (k, e) in edges.iter_mut().enumerate() {
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            let (a, b, sign) = if index[i] < index[j] {
                (p[i], p[j], 1.0)
            } else {
                (p[j], p[i], -1.0)
            };
            let (ea, eb) = (-(b.y - a.y), b.x - a.x);
            let ec = -(ea * a.x + eb * a.y);
            *e = [sign * ea, sign * eb, sign * ec];
        }
        let area = {
            let [a, b, c] = edges[2];
            a * p[2].x + b * p[2].y + c
        };
        if area == 0.0 || !area.is_finite() {
            return None;
        }
        // The image's v axis points down: a facet wound counter-clockwise seen from outside
        // (its front) has a negative doubled area here.
        if cull && area > 0.0 {
            return None;
        }
        let side = area.signum();
        for e in &mut edges {
            *e = e.map(|x| side * x);
        }
        let inv_area = 1.0 / area.abs();
        Some(Projected {
            facet: f,
            edges,
            inv_z: inv_z.map(|x| x * inv_area),
            lo: p[0].min(p[1]).min(p[2]),
            hi: p[0].max(p[1]).max(p[2]),
        })
    }
}

/// A mesh's facets projected into one frame's image and binned by tiles.
pub struct Rasteriser {
    projected: Vec<Projected>,
    /// Per tile of `tile x tile` px, the projected facets that may cover it, in facet order.
    bins: Bins,
    tile: usize,
}

impl Rasteriser {
    /// Projects the `mesh` (body frame) seen from `camera_m` (B) with the camera's attitude
    /// `camera_from_body`, binned by tiles of `tile` px: `None` where rasterisation does not
    /// apply (a distorted camera, or a vertex that reaches the camera's plane).
    pub fn new(
        mesh: &Mesh,
        camera_m: DVec3,
        camera_from_body: DMat3,
        intrinsics: &Intrinsics,
        tile: usize,
    ) -> Option<Rasteriser> {
        if !intrinsics.distortion.is_identity() || tile == 0 {
            return None;
        }
        let (w, h) = (intrinsics.width_px as usize, intrinsics.height_px as usize);
        // A vertex in front by less than a millionth of the mesh's size reaches the plane.
        let near = 1e-6 * mesh.bounding_radius_m();
        let mut image = Vec::with_capacity(mesh.vertices_m().len());
        for &v in mesh.vertices_m() {
            let c = camera_from_body * (v - camera_m);
            if c.z <= near {
                return None;
            }
            image.push((DVec2::from(intrinsics.project(c.x, c.y, c.z)), 1.0 / c.z));
        }
        let tiles = [w.div_ceil(tile), h.div_ceil(tile)];
        let mut projected = Vec::with_capacity(mesh.facets().len());
        let mut spans = Vec::with_capacity(mesh.facets().len());
        // A closed surface seen from outside shows only the fronts of its facets.
        let cull = mesh.report().open_edges == 0;
        for (f, tri) in mesh.facets().iter().enumerate() {
            let p = tri.map(|k| image[k as usize].0);
            let inv_z = tri.map(|k| image[k as usize].1);
            let Some(t) = Projected::new(f as u32, p, *tri, inv_z, cull) else {
                continue;
            };
            let (lo, hi) = (t.lo, t.hi);
            if !(hi.x > 0.0 && hi.y > 0.0 && lo.x < w as f64 && lo.y < h as f64) {
                continue;
            }
            let tile_of = |x: f64, end: usize| ((x.max(0.0) as usize) / tile).min(end - 1);
            spans.push([
                [tile_of(lo.x, tiles[0]), tile_of(hi.x, tiles[0])],
                [tile_of(lo.y, tiles[1]), tile_of(hi.y, tiles[1])],
            ]);
            projected.push(t);
        }
        Some(Rasteriser {
            projected,
            bins: Bins::new(tiles, &spans),
            tile,
        })
    }

    /// The first facet at each of the `n x n` samples per pixel of the pixels `[i0, i0 + cols)
    /// x [j0, j0 + rows)`, which lie in one tile: `facet` gets `rows n x cols n` entries,
    /// row-major ([`NONE`], [`UNDECIDED`] or a facet index); `depth` is scratch. Sample `(a, b)`
    /// of pixel `(i, j)` sits at `(i + (a + 0.5) / n, j + (b + 0.5) / n)`, where
    /// [`super::sampled`] casts.
    pub fn fill(
        &self,
        (i0, j0): (usize, usize),
        (cols, rows): (usize, usize),
        n: usize,
        facet: &mut Vec<u32>,
        depth: &mut Vec<f64>,
    ) {
        let width = cols * n;
        facet.clear();
        facet.resize(width * rows * n, NONE);
        depth.clear();
        depth.resize(width * rows * n, 0.0);
        let step = 1.0 / n as f64;
        for &k in self.bins.cell(i0 / self.tile, j0 / self.tile) {
            let t = &self.projected[k as usize];
            // The region's pixels the facet's bounding box reaches.
            let span = |lo: f64, hi: f64, first: usize, count: usize| {
                let a = (lo.floor().max(first as f64) as usize).max(first);
                let b = (hi.floor().max(0.0) as usize).min(first + count - 1);
                (a, b)
            };
            let (x0, x1) = span(t.lo.x, t.hi.x, i0, cols);
            let (y0, y1) = span(t.lo.y, t.hi.y, j0, rows);
            if x0 > x1 || y0 > y1 {
                continue;
            }
            let [e0, e1, e2] = t.edges;
            for j in y0..=y1 {
                for b in 0..n {
                    let y = j as f64 + (b as f64 + 0.5) * step;
                    let row = ((j - j0) * n + b) * width;
                    for i in x0..=x1 {
                        for a in 0..n {
                            let q = DVec2::new(i as f64 + (a as f64 + 0.5) * step, y);
                            // Barycentric weights (times the doubled area).
                            let w0 = e0[0] * q.x + e0[1] * q.y + e0[2];
                            let w1 = e1[0] * q.x + e1[1] * q.y + e1[2];
                            let w2 = e2[0] * q.x + e2[1] * q.y + e2[2];
                            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                                continue;
                            }
                            let inv_z = w0 * t.inv_z[0] + w1 * t.inv_z[1] + w2 * t.inv_z[2];
                            let s = row + (i - i0) * n + a;
                            if inv_z > depth[s] {
                                depth[s] = inv_z;
                                facet[s] = if w0 == 0.0 || w1 == 0.0 || w2 == 0.0 {
                                    UNDECIDED
                                } else {
                                    t.facet
                                };
                            }
                        }
                    }
                }
            }
        }
    }
}
