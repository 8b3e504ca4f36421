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
use rayon::prelude::*;

/// A pixel's fragments cover it when their areas add up to 1 px^2 within this much.
pub const COVERED: f64 = 1e-9;

/// Two fragments overlapping by at most this much [px^2] meet along an edge only.
const OVERLAP_PX2: f64 = 1e-9;

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
    /// The corners in the image [px].
    corners: [DVec2; 3],
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
            corners: p,
            lo: p[0].min(p[1]).min(p[2]),
            hi: p[0].max(p[1]).max(p[2]),
        })
    }
}

impl Projected {
    /// The part of pixel `[x0, x0 + 1] x [y0, y0 + 1]` this facet (the `k`-th projected)
    /// covers, `None` for none. The pixel's corners against each edge: all inside, the whole
    /// pixel; all outside one edge, nothing; otherwise the pixel clipped by the edges that
    /// cross it (it lies inside the others' half-planes already), in closed form for one
    /// ([`pixel_cut`]).
    #[inline(always)]
    fn share(&self, k: u32, x0: f64, y0: f64) -> Option<Fragment> {
        let mut crossing = [[0.0; 3]; 3];
        let mut n_crossing = 0;
        for e in &self.edges {
            // The edge's least and greatest values over the pixel's corners.
            let at = e[0] * x0 + e[1] * y0 + e[2];
            if at + e[0].max(0.0) + e[1].max(0.0) <= 0.0 {
                return None;
            }
            if at + e[0].min(0.0) + e[1].min(0.0) < 0.0 {
                crossing[n_crossing] = *e;
                n_crossing += 1;
            }
        }
        let (area_px2, centroid) = if n_crossing == 0 {
            (1.0, DVec2::new(x0 + 0.5, y0 + 0.5))
        } else if n_crossing == 1 {
            pixel_cut(x0, y0, crossing[0])?
        } else {
            let (x1, y1) = (x0 + 1.0, y0 + 1.0);
            let square = [
                DVec2::new(x0, y0),
                DVec2::new(x1, y0),
                DVec2::new(x1, y1),
                DVec2::new(x0, y1),
            ];
            clip_polygon(&square, &crossing[..n_crossing])?
        };
        Some(Fragment {
            facet: self.facet,
            projected: k,
            area_px2,
            centroid,
        })
    }

    /// Whether the facet misses the pixel `[x0, x0 + 1] x [y0, y0 + 1]`: one edge is negative
    /// at all its corners, by more than a billionth of a pixel (so that no sample inside the
    /// pixel that the edge's own evaluation would put on the facet, or on the edge, is left
    /// out by rounding).
    #[inline(always)]
    fn misses_pixel(&self, x0: f64, y0: f64) -> bool {
        self.edges.iter().any(|e| {
            let most = e[0] * x0 + e[1] * y0 + e[2] + e[0].max(0.0) + e[1].max(0.0);
            most < -1e-9 * (e[0].abs() + e[1].abs())
        })
    }
}

/// The fragments of the pixels of one tile ([`Rasteriser::tile_fragments`]), with the
/// buffers reused from tile to tile.
#[derive(Default)]
pub struct TileFragments {
    unsorted: Vec<(u32, Fragment)>,
    sorted: Vec<Fragment>,
    starts: Vec<u32>,
    next: Vec<u32>,
    areas: Vec<f64>,
}

impl TileFragments {
    /// Tile-local pixel `p`'s fragments.
    #[inline]
    pub fn of(&self, p: usize) -> &[Fragment] {
        &self.sorted[self.starts[p] as usize..self.starts[p + 1] as usize]
    }

    /// The sum of their areas [px^2].
    #[inline]
    pub fn area(&self, p: usize) -> f64 {
        self.areas[p]
    }
}

/// The part of a pixel one facet covers ([`Rasteriser::fragments`]).
#[derive(Clone, Copy, Debug)]
pub struct Fragment {
    pub facet: u32,
    /// Its facet's place among the projected ones.
    projected: u32,
    /// Its area [px^2] and centroid [px].
    pub area_px2: f64,
    pub centroid: DVec2,
}

/// The pixels `i` of `[first, first + count)` with `i < hi` and `i + 1 > lo` (a box from `lo`
/// to `hi` [px] reaches them), as an inclusive range, empty when the first exceeds the last.
/// Truncation is the floor here (both ends past `first >= 0`), and costs no call to libm's
/// `floor`.
#[inline]
fn pixel_span(lo: f64, hi: f64, first: usize, count: usize) -> (usize, usize) {
    if hi <= first as f64 {
        return (1, 0);
    }
    let a = lo.max(first as f64) as usize;
    // The last pixel left of `hi`, `ceil(hi) - 1`: `t >= first + 1` where `t == hi`.
    let t = hi as usize;
    let b = if t as f64 == hi { t - 1 } else { t };
    (a, b.min(first + count - 1))
}

/// Room for a convex polygon's corners: a triangle clipped by up to seven lines, each of
/// which adds at most one.
type Corners = [DVec2; 10];

/// The part of the convex polygon `src` where `a x + b y + c >= 0`, into `dst`
/// (Sutherland-Hodgman; the crossing at `t = s0 / (s0 - s1)`); returns its corner count.
#[inline]
fn clip_line(src: &[DVec2], dst: &mut Corners, [a, b, c]: [f64; 3]) -> usize {
    let side = |p: DVec2| a * p.x + b * p.y + c;
    let mut n = 0;
    let mut sp = side(src[src.len() - 1]);
    let mut p = src[src.len() - 1];
    for &q in src {
        let sq = side(q);
        if (sp >= 0.0) != (sq >= 0.0) && n < dst.len() {
            dst[n] = p + (q - p) * (sp / (sp - sq));
            n += 1;
        }
        if sq >= 0.0 && n < dst.len() {
            dst[n] = q;
            n += 1;
        }
        (p, sp) = (q, sq);
    }
    n
}

/// The part of pixel `[x0, x0 + 1] x [y0, y0 + 1]` where `a x + b y + c >= 0`, for a line that
/// crosses it: its area [px^2] and centroid [px] in closed form (what [`clip_polygon`] gives
/// for the pixel's corners and one line, to rounding, at a third of its cost); `None` for no
/// area. One corner on the kept side: a right triangle at it; three: the pixel less such a
/// triangle at the fourth; two (adjacent, the line being straight): a trapezoid on their
/// side.
#[inline]
fn pixel_cut(x0: f64, y0: f64, [a, b, c]: [f64; 3]) -> Option<(f64, DVec2)> {
    // Corners 0 (x0, y0), 1 (x0 + 1, y0), 2 (x0 + 1, y0 + 1), 3 (x0, y0 + 1), in order round
    // the pixel.
    let f00 = a * x0 + b * y0 + c;
    let f = [f00, f00 + a, f00 + a + b, f00 + b];
    let corner = [
        DVec2::new(x0, y0),
        DVec2::new(x0 + 1.0, y0),
        DVec2::new(x0 + 1.0, y0 + 1.0),
        DVec2::new(x0, y0 + 1.0),
    ];
    let inside = f.map(|v| v >= 0.0);
    let count = inside.iter().filter(|&&i| i).count();
    // The right triangle at corner `k` cut off by the line (where `f` changes sign along both
    // of its sides): area and centroid.
    let triangle = |k: usize| {
        let (prev, next) = ((k + 3) % 4, (k + 1) % 4);
        let t_next = f[k] / (f[k] - f[next]);
        let t_prev = f[k] / (f[k] - f[prev]);
        let (to_next, to_prev) = (corner[next] - corner[k], corner[prev] - corner[k]);
        (
            0.5 * t_next * t_prev,
            corner[k] + (to_next * t_next + to_prev * t_prev) / 3.0,
        )
    };
    let (area, centroid) = match count {
        1 => triangle(inside.iter().position(|&i| i)?),
        3 => {
            let (cut, at) = triangle(inside.iter().position(|&i| !i)?);
            let area = 1.0 - cut;
            let centre = DVec2::new(x0 + 0.5, y0 + 0.5);
            (area, (centre - at * cut) / area)
        }
        2 => {
            // The kept side `k, k + 1`; the line meets the sides from `k` to `k - 1` and from
            // `k + 1` to `k + 2` at heights `h0` and `h1` (from the kept side).
            let k = (0..4).find(|&k| inside[k] && inside[(k + 1) % 4])?;
            let (k1, k2, k3) = ((k + 1) % 4, (k + 2) % 4, (k + 3) % 4);
            let h0 = f[k] / (f[k] - f[k3]);
            let h1 = f[k1] / (f[k1] - f[k2]);
            let sum = h0 + h1;
            if sum <= 0.0 {
                return None;
            }
            let (along, up) = (corner[k1] - corner[k], corner[k3] - corner[k]);
            let s = (h0 + 2.0 * h1) / (3.0 * sum);
            let t = (h0 * h0 + h0 * h1 + h1 * h1) / (3.0 * sum);
            (0.5 * sum, corner[k] + along * s + up * t)
        }
        _ => return None,
    };
    (area > 0.0).then_some((area, centroid))
}

/// Area [px^2] and centroid [px] of a convex polygon (the shoelace formula about its first
/// corner); `None` when it has no area.
fn area_centroid(p: &[DVec2]) -> Option<(f64, DVec2)> {
    if p.len() < 3 {
        return None;
    }
    let (mut twice, mut c) = (0.0, DVec2::ZERO);
    for k in 1..p.len() - 1 {
        let (u, v) = (p[k] - p[0], p[k + 1] - p[0]);
        let cross = u.x * v.y - u.y * v.x;
        twice += cross;
        c += (u + v) * cross;
    }
    if twice == 0.0 {
        return None;
    }
    Some((0.5 * twice.abs(), p[0] + c / (3.0 * twice)))
}

/// The convex polygon `corners` (a triangle, or a pixel's four corners) clipped by `lines`
/// (each keeping `a x + b y + c >= 0`, at most six with four corners): its area [px^2] and
/// centroid [px]; `None` when nothing is left.
fn clip_polygon(corners: &[DVec2], lines: &[[f64; 3]]) -> Option<(f64, DVec2)> {
    let (mut a, mut b): (Corners, Corners) = ([DVec2::ZERO; 10], [DVec2::ZERO; 10]);
    a[..corners.len()].copy_from_slice(corners);
    let (mut src, mut dst) = (&mut a, &mut b);
    let mut n = corners.len();
    for &line in lines {
        n = clip_line(&src[..n], dst, line);
        if n < 3 {
            return None;
        }
        std::mem::swap(&mut src, &mut dst);
    }
    area_centroid(&src[..n])
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
        // Vertices, then facets, projected in parallel (the order kept: facets stay in mesh
        // order in the bins).
        let image: Vec<(DVec2, f64)> = mesh
            .vertices_m()
            .par_iter()
            .map(|&v| {
                let c = camera_from_body * (v - camera_m);
                (c.z > near).then(|| (DVec2::from(intrinsics.project(c.x, c.y, c.z)), 1.0 / c.z))
            })
            .collect::<Option<_>>()?;
        let tiles = [w.div_ceil(tile), h.div_ceil(tile)];
        // A closed surface seen from outside shows only the fronts of its facets.
        let cull = mesh.report().open_edges == 0;
        let tile_of = |x: f64, end: usize| ((x.max(0.0) as usize) / tile).min(end - 1);
        let (projected, spans): (Vec<Projected>, Vec<[[usize; 2]; 2]>) = mesh
            .facets()
            .par_iter()
            .enumerate()
            .filter_map(|(f, tri)| {
                let p = tri.map(|k| image[k as usize].0);
                let inv_z = tri.map(|k| image[k as usize].1);
                let t = Projected::new(f as u32, p, *tri, inv_z, cull)?;
                let (lo, hi) = (t.lo, t.hi);
                if !(hi.x > 0.0 && hi.y > 0.0 && lo.x < w as f64 && lo.y < h as f64) {
                    return None;
                }
                let span = [
                    [tile_of(lo.x, tiles[0]), tile_of(hi.x, tiles[0])],
                    [tile_of(lo.y, tiles[1]), tile_of(hi.y, tiles[1])],
                ];
                Some((t, span))
            })
            .unzip();
        Some(Rasteriser {
            projected,
            bins: Bins::new(tiles, &spans),
            tile,
        })
    }

    /// Whether no projected facet's box reaches tile `(x, y)` (of the `tile` px given to
    /// [`Rasteriser::new`]): no line of sight through it meets the mesh.
    pub fn tile_is_empty(&self, x: usize, y: usize) -> bool {
        self.bins.cell(x, y).is_empty()
    }

    /// How many facets are projected.
    pub fn len(&self) -> usize {
        self.projected.len()
    }

    pub fn is_empty(&self) -> bool {
        self.projected.is_empty()
    }

    /// The `k`-th projected facet: its mesh index, its corners in the image [px] and its
    /// edges' equations (`A u + B v + C`, positive inside, summing to its doubled area).
    pub fn triangle(&self, k: usize) -> (u32, [DVec2; 3], [[f64; 3]; 3]) {
        let t = &self.projected[k];
        (t.facet, t.corners, t.edges)
    }

    /// The exact shares of pixel `(i, j)` (the square `[i, i + 1] x [j, j + 1]`) that the
    /// projected facets cover, as `fragments` (each facet's triangle clipped to the square);
    /// returns the sum of their areas [px^2]. On a closed mesh only fronts are projected, so a
    /// sum of 1 means one facet over every point of the pixel: nothing in it hides anything
    /// else, and the fragments tile it.
    pub fn fragments(&self, (i, j): (usize, usize), fragments: &mut Vec<Fragment>) -> f64 {
        fragments.clear();
        let (x0, y0) = (i as f64, j as f64);
        let mut sum = 0.0;
        for &k in self.bins.cell(i / self.tile, j / self.tile) {
            let t = &self.projected[k as usize];
            if t.hi.x <= x0 || t.lo.x >= x0 + 1.0 || t.hi.y <= y0 || t.lo.y >= y0 + 1.0 {
                continue;
            }
            if let Some(f) = t.share(k, x0, y0) {
                sum += f.area_px2;
                fragments.push(f);
            }
        }
        sum
    }

    /// [`Rasteriser::fragments`] for every pixel of the `cols x rows` pixels at `(i0, j0)`,
    /// which lie in one tile, facet by facet over the pixels each one's box reaches (no box
    /// test per pixel and facet): `tile.of(p)` are then tile-local pixel `p`'s fragments
    /// (`p = row * cols + col`), in the same order, and `tile.area(p)` their sum.
    pub fn tile_fragments(
        &self,
        (i0, j0): (usize, usize),
        (cols, rows): (usize, usize),
        tile: &mut TileFragments,
    ) {
        tile.unsorted.clear();
        tile.starts.clear();
        tile.starts.resize(cols * rows + 1, 0);
        tile.areas.clear();
        tile.areas.resize(cols * rows, 0.0);
        for &k in self.bins.cell(i0 / self.tile, j0 / self.tile) {
            let t = &self.projected[k as usize];
            let (xa, xb) = pixel_span(t.lo.x, t.hi.x, i0, cols);
            let (ya, yb) = pixel_span(t.lo.y, t.hi.y, j0, rows);
            for y in ya..=yb {
                for x in xa..=xb {
                    if let Some(f) = t.share(k, x as f64, y as f64) {
                        let p = (y - j0) * cols + (x - i0);
                        tile.areas[p] += f.area_px2;
                        tile.starts[p + 1] += 1;
                        tile.unsorted.push((p as u32, f));
                    }
                }
            }
        }
        // By pixel, keeping the facets' order within each.
        for p in 1..tile.starts.len() {
            tile.starts[p] += tile.starts[p - 1];
        }
        tile.sorted.clear();
        if let Some(&(_, any)) = tile.unsorted.first() {
            // Every slot is written below; `any` only fills them first.
            tile.sorted.resize(tile.unsorted.len(), any);
        }
        tile.next.clear();
        tile.next.extend_from_slice(&tile.starts[..cols * rows]);
        for &(p, f) in &tile.unsorted {
            let at = &mut tile.next[p as usize];
            tile.sorted[*at as usize] = f;
            *at += 1;
        }
    }

    /// Whether no two of pixel `(i, j)`'s `fragments` overlap (their facets' triangles meet
    /// within the pixel in no more than an edge): then, on a closed mesh, what they leave
    /// uncovered is where lines of sight miss the body, and the fragments are exact there too.
    pub fn single_layer(&self, (i, j): (usize, usize), fragments: &[Fragment]) -> bool {
        let (x0, y0) = (i as f64, j as f64);
        let pixel = [
            [1.0, 0.0, -x0],
            [-1.0, 0.0, x0 + 1.0],
            [0.0, 1.0, -y0],
            [0.0, -1.0, y0 + 1.0],
        ];
        fragments.iter().enumerate().all(|(k, a)| {
            let ta = &self.projected[a.projected as usize];
            fragments[k + 1..].iter().all(|b| {
                let e = self.projected[b.projected as usize].edges;
                let lines = [pixel[0], pixel[1], pixel[2], pixel[3], e[0], e[1], e[2]];
                clip_polygon(&ta.corners, &lines).is_none_or(|(area, _)| area <= OVERLAP_PX2)
            })
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
        facet.clear();
        facet.resize(cols * n * rows * n, NONE);
        depth.clear();
        depth.resize(cols * n * rows * n, 0.0);
        for &k in self.bins.cell(i0 / self.tile, j0 / self.tile) {
            self.fill_facet(k, (i0, j0), (cols, rows), n, facet, depth);
        }
    }

    /// [`Rasteriser::fill`] for the one pixel `(i, j)` whose `fragments` are known
    /// ([`Rasteriser::tile_fragments`]): only their facets are rasterised (a sample inside
    /// the pixel lies on no other's interior).
    pub fn fill_pixel(
        &self,
        (i, j): (usize, usize),
        n: usize,
        fragments: &[Fragment],
        facet: &mut Vec<u32>,
        depth: &mut Vec<f64>,
    ) {
        facet.clear();
        facet.resize(n * n, NONE);
        depth.clear();
        depth.resize(n * n, 0.0);
        for f in fragments {
            self.fill_facet(f.projected, (i, j), (1, 1), n, facet, depth);
        }
    }

    /// The `k`-th projected facet's samples in the region of [`Rasteriser::fill`], kept where
    /// it is nearer than what `depth` holds (`1/z`).
    #[inline]
    fn fill_facet(
        &self,
        k: u32,
        (i0, j0): (usize, usize),
        (cols, rows): (usize, usize),
        n: usize,
        facet: &mut [u32],
        depth: &mut [f64],
    ) {
        let width = cols * n;
        let step = 1.0 / n as f64;
        let t = &self.projected[k as usize];
        // The region's pixels the facet's bounding box reaches (a pixel at or past `hi`
        // has every sample past it).
        let (x0, x1) = pixel_span(t.lo.x, t.hi.x, i0, cols);
        let (y0, y1) = pixel_span(t.lo.y, t.hi.y, j0, rows);
        if x0 > x1 || y0 > y1 {
            return;
        }
        let [e0, e1, e2] = t.edges;
        for j in y0..=y1 {
            for i in x0..=x1 {
                // Its samples lie inside the pixel: none is on the facet where the
                // facet misses the pixel (most pixels of its box).
                if t.misses_pixel(i as f64, j as f64) {
                    continue;
                }
                for b in 0..n {
                    let y = j as f64 + (b as f64 + 0.5) * step;
                    let row = ((j - j0) * n + b) * width;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The share of pixel (2, 3) the triangle `t` covers, either winding.
    fn share(t: [(f64, f64); 3]) -> Option<(f64, DVec2)> {
        let p = t.map(|(x, y)| DVec2::new(x, y));
        let a = Projected::new(0, p, [0, 1, 2], [1.0; 3], false).unwrap();
        let b = Projected::new(0, [p[0], p[2], p[1]], [0, 1, 2], [1.0; 3], false).unwrap();
        let (fa, fb) = (a.share(0, 2.0, 3.0), b.share(0, 2.0, 3.0));
        assert_eq!(fa.is_some(), fb.is_some());
        fa.map(|f| {
            let g = fb.unwrap();
            assert!((f.area_px2 - g.area_px2).abs() < 1e-15);
            (f.area_px2, f.centroid)
        })
    }

    #[test]
    fn a_pixel_cut_by_one_line_is_the_polygon_clip() {
        // Lines through the pixel (2, 3) at every angle and offset that crosses it, against
        // the general clip of its four corners.
        let (x0, y0) = (2.0, 3.0);
        let square = [
            DVec2::new(x0, y0),
            DVec2::new(x0 + 1.0, y0),
            DVec2::new(x0 + 1.0, y0 + 1.0),
            DVec2::new(x0, y0 + 1.0),
        ];
        let mut compared = 0;
        for k in 0..72 {
            let angle = k as f64 * 5.0_f64.to_radians() + 0.01;
            let (a, b) = (3.0 * angle.cos(), 3.0 * angle.sin());
            for m in 1..40 {
                // Through the point (x0 + m/40, y0 + (40 - m)/40 * 0.9).
                let p = DVec2::new(x0 + m as f64 / 40.0, y0 + (40 - m) as f64 / 44.0);
                let line = [a, b, -(a * p.x + b * p.y)];
                let want = clip_polygon(&square, &[line]);
                let got = pixel_cut(x0, y0, line);
                match (want, got) {
                    (Some((wa, wc)), Some((ga, gc))) => {
                        assert!((wa - ga).abs() < 1e-13, "area {wa} {ga} line {line:?}");
                        assert!(
                            (wc - gc).length() < 1e-12,
                            "centroid {wc} {gc} line {line:?}"
                        );
                        compared += 1;
                    }
                    (w, g) => assert!(
                        w.is_none_or(|w| w.0 < 1e-15) && g.is_none_or(|g| g.0 < 1e-15),
                        "{w:?} {g:?} line {line:?}"
                    ),
                }
            }
        }
        assert!(compared > 2000, "{compared}");
    }

    #[test]
    fn a_boxs_pixel_span_is_the_floor_and_ceiling_definition() {
        // The pixels `i` in `[first, first + count)` with `i < hi` and `i + 1 > lo`, by
        // counting, against the span made by truncation.
        let ends = [
            0.0, 0.25, 1.0, 2.0, 2.5, 3.0, 7.999, 8.0, 9.5, 15.0, 16.0, 17.25, 1e9,
        ];
        for &lo in &[-3.5, -1.0, 0.0, 0.5, 1.0, 2.0, 2.5, 8.0, 9.25, 16.0, 20.0] {
            for &hi in &ends {
                if hi <= lo {
                    continue;
                }
                for (first, count) in [(0, 8), (8, 8), (2, 1), (16, 3)] {
                    let want: Vec<usize> = (first..first + count)
                        .filter(|&i| (i as f64) < hi && (i + 1) as f64 > lo)
                        .collect();
                    let (a, b) = pixel_span(lo, hi, first, count);
                    let got: Vec<usize> = (a..=b).collect();
                    assert_eq!(got, want, "lo {lo} hi {hi} first {first} count {count}");
                }
            }
        }
    }

    #[test]
    fn a_triangle_clipped_to_a_pixel_keeps_the_area_and_centroid_inside_it() {
        // Wholly inside: itself.
        let t = [(2.2, 3.1), (2.9, 3.2), (2.5, 3.9)];
        let (a, c) = share(t).unwrap();
        let want: f64 = 0.5 * (0.7 * 0.8 - 0.1 * 0.3);
        assert!((a - want).abs() < 1e-12, "{a}");
        let mean = t
            .iter()
            .fold(DVec2::ZERO, |m, &(x, y)| m + DVec2::new(x, y))
            / 3.0;
        assert!((c - mean).length() < 1e-12);
        // A big triangle covering the pixel: the whole pixel.
        let (a, c) = share([(-10.0, -10.0), (20.0, -10.0), (2.5, 20.0)]).unwrap();
        assert!((a - 1.0).abs() < 1e-12 && (c - DVec2::new(2.5, 3.5)).length() < 1e-12);
        // The diagonal half of the pixel below the line from its corner (2, 3) to (3, 4).
        let (a, c) = share([(2.0, 3.0), (10.0, 11.0), (10.0, -5.0)]).unwrap();
        assert!((a - 0.5).abs() < 1e-12, "{a}");
        assert!(
            (c - DVec2::new(2.0 + 2.0 / 3.0, 3.0 + 1.0 / 3.0)).length() < 1e-12,
            "{c}"
        );
        // A corner of the pixel cut off by a triangle's vertex: two edges cross it.
        let (a, _) = share([(2.5, 3.5), (2.5, -10.0), (20.0, 3.5)]).unwrap();
        assert!((a - 0.25).abs() < 1e-12, "{a}");
        // Beside the pixel, or touching it along its side only: nothing.
        assert!(share([(4.0, 3.0), (5.0, 3.0), (4.5, 4.0)]).is_none());
        assert!(share([(3.0, 3.0), (5.0, 3.0), (3.0, 4.0)]).is_none());
    }
}
