//! Primary visibility by rasterisation: which facet of a mesh body each line of sight of the
//! sampled frame ([`super::sampled`]) meets first, without a ray.
//!
//! For a pinhole camera (no Brown distortion, Eq. 39 the identity) the projection of Eq. 40 is
//! projective, so a facet's image is a triangle and a line of sight meets the facet exactly
//! when its sample position lies inside that triangle. The facets are projected once per frame
//! and scan-converted over the regular grid of `n x n` sample positions per pixel that the
//! sampled frame casts; a depth test on `1/z` (linear in the image plane) keeps the nearest.
//! The ray caster then only intersects each sample's own facet (a plane), and casts through the
//! BVH where the raster cannot decide: a sample exactly on a projected edge, or where the
//! rasterisation does not apply (a distorted camera, a facet at or behind the camera's plane).
//!
//! Edges are evaluated in one orientation (from the lower vertex index to the higher) by
//! every facet that shares them, so that two neighbours agree bit for bit on which side of
//! their common edge a sample lies: no sample falls in a crack between them.
//!
//! Bands of rows are filled by separate threads, each facet in index order: the buffer does
//! not depend on the thread count.

use crate::body::mesh::Mesh;
use crate::camera::Intrinsics;
use glam::{DMat3, DVec2, DVec3};
use rayon::prelude::*;

/// A sample that sees no facet.
pub const NONE: u32 = u32::MAX;
/// A sample exactly on a projected edge: cast through the BVH.
pub const UNDECIDED: u32 = u32::MAX - 1;

/// Rows of samples per band (one thread's share).
const BAND: usize = 16;

/// The first facet seen at each sample position of an `n x n` grid per pixel.
pub struct FacetBuffer {
    /// Samples per pixel side.
    pub n: usize,
    /// Samples per row (`n` times the image's width).
    pub width: usize,
    /// Facet index per sample, row-major; [`NONE`] or [`UNDECIDED`].
    pub facet: Vec<u32>,
}

impl FacetBuffer {
    /// The facet seen at sample `(a, b)` (`0..n` each) of pixel `(i, j)`.
    #[inline]
    pub fn at(&self, i: usize, j: usize, a: usize, b: usize) -> u32 {
        self.facet[(j * self.n + b) * self.width + i * self.n + a]
    }
}

/// A facet's projection, in sample units (pixel coordinates times `n`).
struct Projected {
    facet: u32,
    /// Vertices in the image, with their `1/z` [1/m] and their indices in the mesh.
    p: [DVec2; 3],
    inv_z: [f64; 3],
    index: [u32; 3],
    /// Sample rows and columns the triangle's bounding box spans (inclusive).
    rows: (usize, usize),
    cols: (usize, usize),
}

/// Rasterises the `mesh` (body frame) seen from `camera_m` (B) with the camera's attitude
/// `camera_from_body` at `n x n` samples per pixel: `None` where rasterisation does not apply
/// (a distorted camera, or a facet that reaches the camera's plane).
pub fn rasterise(
    mesh: &Mesh,
    camera_m: DVec3,
    camera_from_body: DMat3,
    intrinsics: &Intrinsics,
    n: usize,
) -> Option<FacetBuffer> {
    if !intrinsics.distortion.is_identity() || n == 0 {
        return None;
    }
    let (width, height) = (
        intrinsics.width_px as usize * n,
        intrinsics.height_px as usize * n,
    );
    let (fu, fv) = intrinsics.focal_px();
    let [cu, cv] = intrinsics.principal_point_px;
    let skew = intrinsics.skew_px;
    let s = n as f64;
    // Vertices in the image (sample units) with 1/z; None when one reaches the camera plane.
    // A vertex in front by less than a millionth of the mesh's size counts as reaching it.
    let near = 1e-6 * mesh.bounding_radius_m();
    let mut image = Vec::with_capacity(mesh.vertices_m().len());
    for &v in mesh.vertices_m() {
        let c = camera_from_body * (v - camera_m);
        image.push((c.z > near).then(|| {
            let (x, y) = (c.x / c.z, c.y / c.z);
            (
                DVec2::new(s * (fu * x + skew * y + cu), s * (fv * y + cv)),
                1.0 / c.z,
            )
        }));
    }
    let mut projected = Vec::with_capacity(mesh.facets().len());
    for (f, tri) in mesh.facets().iter().enumerate() {
        let mut p = [DVec2::ZERO; 3];
        let mut inv_z = [0.0; 3];
        for k in 0..3 {
            let (q, w) = image[tri[k] as usize]?;
            (p[k], inv_z[k]) = (q, w);
        }
        // Samples sit at (I + 0.5, J + 0.5): those the bounding box may hold.
        let lo = p[0].min(p[1]).min(p[2]);
        let hi = p[0].max(p[1]).max(p[2]);
        if hi.x < 0.5 || hi.y < 0.5 || lo.x > width as f64 - 0.5 || lo.y > height as f64 - 0.5 {
            continue;
        }
        let first = |x: f64| (x - 0.5).ceil().max(0.0) as usize;
        let last = |x: f64, end: usize| ((x - 0.5).floor().max(0.0) as usize).min(end - 1);
        let (r0, r1) = (first(lo.y), last(hi.y, height));
        let (c0, c1) = (first(lo.x), last(hi.x, width));
        if r0 > r1 || c0 > c1 {
            continue;
        }
        projected.push(Projected {
            facet: f as u32,
            p,
            inv_z,
            index: *tri,
            rows: (r0, r1),
            cols: (c0, c1),
        });
    }
    // Facets by the bands their rows reach, in facet order.
    let bands = height.div_ceil(BAND);
    let mut by_band: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (k, t) in projected.iter().enumerate() {
        for list in &mut by_band[t.rows.0 / BAND..=t.rows.1 / BAND] {
            list.push(k as u32);
        }
    }
    let mut facet = vec![NONE; width * height];
    facet
        .par_chunks_mut(BAND * width)
        .zip(by_band.par_iter())
        .enumerate()
        .for_each_init(
            Vec::new,
            |depth: &mut Vec<f64>, (band, (out, list))| {
                depth.clear();
                depth.resize(out.len(), 0.0);
                let rows = (band * BAND, band * BAND + out.len() / width - 1);
                for &k in list {
                    fill(&projected[k as usize], rows, width, out, depth);
                }
            },
        );
    Some(FacetBuffer { n, width, facet })
}

/// The signed doubled area of `(a, b, q)`, with the edge taken from its lower vertex index
/// to its higher: the same bits in both facets that share the edge.
#[inline(always)]
fn edge(a: (DVec2, u32), b: (DVec2, u32), q: DVec2) -> f64 {
    let (a, b, sign) = if a.1 < b.1 {
        (a.0, b.0, 1.0)
    } else {
        (b.0, a.0, -1.0)
    };
    sign * ((b.x - a.x) * (q.y - a.y) - (b.y - a.y) * (q.x - a.x))
}

/// Scan-converts one projected facet over the band's rows `rows` (inclusive, in samples).
fn fill(t: &Projected, rows: (usize, usize), width: usize, out: &mut [u32], depth: &mut [f64]) {
    let v = |k: usize| (t.p[k], t.index[k]);
    // Orientation: which sign of the edge functions is inside.
    let area = edge(v(0), v(1), t.p[2]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let side = area.signum();
    let inv_area = 1.0 / area.abs();
    for r in rows.0.max(t.rows.0)..=rows.1.min(t.rows.1) {
        let y = r as f64 + 0.5;
        let row = (r - rows.0) * width;
        for c in t.cols.0..=t.cols.1 {
            let q = DVec2::new(c as f64 + 0.5, y);
            // Barycentric weights (times the area) of vertices 2, 0 and 1.
            let w2 = side * edge(v(0), v(1), q);
            let w0 = side * edge(v(1), v(2), q);
            let w1 = side * edge(v(2), v(0), q);
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            let inv_z = (w0 * t.inv_z[0] + w1 * t.inv_z[1] + w2 * t.inv_z[2]) * inv_area;
            let k = row + c;
            if inv_z > depth[k] {
                depth[k] = inv_z;
                out[k] = if w0 == 0.0 || w1 == 0.0 || w2 == 0.0 {
                    UNDECIDED
                } else {
                    t.facet
                };
            }
        }
    }
}
