//! The exact reference of a lone mesh body (`optistim render --reference`, chosen where it
//! applies): the part of every facet that is both lit and seen, found by clipping polygons,
//! and each pixel's share of it integrated by a triangle rule. No ray decides what is lit or
//! seen, so no sliver of light or of limb can slip between rays: the only approximations are
//! the rule on a smooth integrand and floating point.
//!
//! For each facet facing the camera (in parallel, summed in facet order, so the image is the
//! same bit for bit whatever the thread count):
//! 1. **Lit part** (SLIM Sec. 6.1's shadows, made exact). In the view from the Sun (an
//!    orthographic projection along the unit direction from the body's centre to the Sun) the
//!    facet is a triangle; every other facet whose projection overlaps it and lies sunward of
//!    it over that overlap (two facets that do not cross keep one order over their overlap: it
//!    is read at the overlap's centroid) removes the overlap from it. What is left is a set of
//!    disjoint convex polygons. (The Sun's direction varies over the body by its size over its
//!    distance, 3e-9 rad for Bennu: the shadows' edges move by a millionth of a metre. The Sun
//!    is a point, as for the ray caster: no penumbra.)
//! 2. **Seen part.** Those polygons, lifted onto the facet's plane and projected through the
//!    pinhole camera (Eq. 40; a planar convex polygon in front of the camera projects to a
//!    convex polygon), lose in the same way the overlaps of every facet nearer to the camera.
//! 3. **Pixels.** Each remaining polygon is cut by the pixel grid, and the integrand of
//!    [`super`] (Eq. 11 per unit solid angle of the line of sight, written in pixel
//!    coordinates, unshadowed: [`Tracer::facet_light`]) is integrated over each cut by the
//!    7-point rule of degree 5 on the triangles of a fan. The 3-point rule of degree 2 on the
//!    same triangles gives the error estimate, `|I7 - I3|` summed (an upper estimate: it is
//!    the lower rule's error).
//!
//! On a closed mesh only the facets facing the viewer can hide others (a line from a point of
//! the surface to the Sun, or to the camera, that the body blocks leaves it through a facet
//! facing the Sun, or enters it through one facing the camera); on an open one, every facet.
//!
//! It applies to one mesh body alone (no DEM, no placed bodies) seen through an undistorted
//! camera with every vertex in front of it; elsewhere [`render`] says why it does not, and
//! the adaptive cubature of [`super::reference`] is the reference. As that one, it leaves out
//! the light scattered between facets.
//!
//! Frames (`render.raycast_clip`, which the budget planner chooses where this applies:
//! [`render_frame`]) are clipped the same way, with two economies: the facets the Sun's grid
//! ([`super::sun_grid`]) knows to be lit all over are not clipped in the Sun's view, and each
//! facet's light is read from its quadratic element (`Element`) where that holds, else from
//! the 3-point rule. Their own error estimate (the elements' bound, the rule's departure from
//! the centroid) is the frame's `estimated_error`.

use super::Tracer;
use super::reference::{ReferenceFrame, ReferenceReport};
use crate::body::Shape;
use crate::body::mesh::Mesh;
use crate::render::{Frame, FrameStats, RenderError, StageTimings};
use crate::scene::{Pose, Scene};
use glam::{DMat3, DVec2, DVec3};
use rayon::prelude::*;
use std::time::Instant;

/// A convex polygon, counter-clockwise (positive signed area).
type Poly = Vec<DVec2>;

/// Polygons of less than this share of their facet's projected area are dropped (slivers
/// of floating point along shared edges).
const SLIVER: f64 = 1e-13;

/// More pieces than this in one facet: the facet's light is kept as it stands and the frame
/// counts it unconverged.
const MAX_PIECES: usize = 1 << 14;

/// Why the exact reference does not apply to a scene.
#[derive(Debug, thiserror::Error)]
#[error("the exact mesh reference does not apply: {0}")]
pub struct NotExact(pub &'static str);

/// Whether [`render`] applies to `scene` seen from `pose`, and why not.
pub fn applies(scene: &Scene, pose: &Pose) -> Result<(), NotExact> {
    let Shape::Mesh(m) = &scene.body.shape else {
        return Err(NotExact("the body is not a mesh"));
    };
    if scene.body.relief.is_some() {
        return Err(NotExact("the mesh carries a DEM"));
    }
    if !scene.others.is_empty() {
        return Err(NotExact("the scene has several bodies"));
    }
    let intr = &scene.camera.intrinsics;
    let own = scene.camera.detector.bands.iter().any(|b| {
        b.distortion
            .is_some_and(|d| d != intr.distortion && !d.is_identity())
    });
    if !intr.distortion.is_identity() || own {
        return Err(NotExact("the camera has a distortion"));
    }
    let camera_from_body = DMat3::from_quat(pose.body_from_camera).transpose();
    let near = 1e-9 * m.bounding_radius_m();
    if m.vertices_m()
        .iter()
        .any(|v| (camera_from_body * (*v - pose.camera_position_m)).z <= near)
    {
        return Err(NotExact("a vertex lies at or behind the camera's plane"));
    }
    Ok(())
}

/// Renders the exact reference of `scene` seen from `pose` (see the module's documentation).
pub fn render(scene: &Scene, pose: &Pose) -> Result<ReferenceFrame, RenderError> {
    crate::render::check_pose(scene, pose)?;
    applies(scene, pose).map_err(|e| RenderError::BadSettings {
        field: "reference",
        value: "exact".into(),
        allowed: e.0,
    })?;
    let mut r = render_camera(scene, pose)?;
    crate::render::with_band_distortions(scene, &mut r.frame, |s| {
        Ok(render_camera(s, pose)?.frame.pl)
    })?;
    Ok(r)
}

/// A mesh's facets projected into one view: per facet its triangle (counter-clockwise), the
/// depth of its corners (larger is nearer the viewer) and its bounding box; facets binned
/// over the view by their boxes.
struct View {
    tris: Vec<[DVec2; 3]>,
    depths: Vec<[f64; 3]>,
    /// Twice the triangle's area (0: edge-on, neither hides nor is hidden).
    area2: Vec<f64>,
    lo: Vec<DVec2>,
    hi: Vec<DVec2>,
    bins: Bins,
}

impl View {
    /// `project` gives a vertex's position in the view and its depth (larger nearer);
    /// `window` the region of the view that matters (`None`: all of it); `hides` whether a
    /// facet may hide another (only those binned are asked).
    fn new(
        m: &Mesh,
        project: impl Fn(DVec3) -> (DVec2, f64),
        window: Option<(DVec2, DVec2)>,
        hides: impl Fn(usize) -> bool,
    ) -> View {
        let pv: Vec<(DVec2, f64)> = m.vertices_m().iter().map(|v| project(*v)).collect();
        let n = m.facets().len();
        let (mut tris, mut depths, mut area2) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        let (mut lo, mut hi) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for f in m.facets() {
            let [a, b, c] = f.map(|k| pv[k as usize]);
            let s = cross(b.0 - a.0, c.0 - a.0);
            let (t, d) = if s >= 0.0 {
                ([a.0, b.0, c.0], [a.1, b.1, c.1])
            } else {
                ([a.0, c.0, b.0], [a.1, c.1, b.1])
            };
            tris.push(t);
            depths.push(d);
            area2.push(s.abs());
            lo.push(t[0].min(t[1]).min(t[2]));
            hi.push(t[0].max(t[1]).max(t[2]));
        }
        let bins = Bins::new(&lo, &hi, &area2, window, hides);
        View {
            tris,
            depths,
            area2,
            lo,
            hi,
            bins,
        }
    }

    /// The depth of facet `f`'s plane at `x` (barycentric in the view).
    fn depth_at(&self, f: usize, x: DVec2) -> f64 {
        let [a, b, c] = self.tris[f];
        let s = cross(b - a, c - a);
        let (wb, wc) = (cross(x - a, c - a) / s, cross(b - a, x - a) / s);
        let d = self.depths[f];
        d[0] + wb * (d[1] - d[0]) + wc * (d[2] - d[0])
    }

    /// Removes from `pieces` (polygons of facet `f`'s plane in this view) the overlap of every
    /// facet that lies nearer the viewer than `f` there. `tol`: depths closer than this are
    /// taken as equal. Returns false when the pieces exceed [`MAX_PIECES`].
    fn hide(&self, f: usize, pieces: &mut Vec<Poly>, tol: f64, scratch: &mut Scratch) -> bool {
        if self.area2[f] <= 0.0 {
            return true;
        }
        let min_area = SLIVER * 0.5 * self.area2[f];
        let deepest = self.depths[f].iter().copied().fold(f64::INFINITY, f64::min);
        let tri: Poly = self.tris[f].to_vec();
        self.bins.candidates(
            self.lo[f],
            self.hi[f],
            &mut scratch.candidates,
            &mut scratch.seen,
        );
        for &g in &scratch.candidates {
            let g = g as usize;
            if g == f
                || self.area2[g] <= 0.0
                || self.depths[g]
                    .iter()
                    .copied()
                    .fold(f64::NEG_INFINITY, f64::max)
                    <= deepest + tol
                || self.hi[g].x <= self.lo[f].x
                || self.lo[g].x >= self.hi[f].x
                || self.hi[g].y <= self.lo[f].y
                || self.lo[g].y >= self.hi[f].y
            {
                continue;
            }
            let overlap = intersect(&self.tris[g], &tri, &mut scratch.tmp);
            if area(&overlap) <= min_area {
                continue;
            }
            let c = overlap.iter().sum::<DVec2>() / overlap.len() as f64;
            if self.depth_at(g, c) <= self.depth_at(f, c) + tol {
                continue;
            }
            subtract(pieces, &overlap, min_area, &mut scratch.tmp);
            if pieces.is_empty() {
                return true;
            }
            if pieces.len() > MAX_PIECES {
                return false;
            }
        }
        true
    }
}

/// Facets binned over a view by their bounding boxes (compressed rows).
struct Bins {
    origin: DVec2,
    cell: f64,
    nx: usize,
    ny: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Bins {
    fn new(
        lo: &[DVec2],
        hi: &[DVec2],
        area2: &[f64],
        window: Option<(DVec2, DVec2)>,
        hides: impl Fn(usize) -> bool,
    ) -> Bins {
        let keep = |f: usize| {
            area2[f] > 0.0
                && hides(f)
                && window.is_none_or(|(a, b)| hi[f].cmpge(a).all() && lo[f].cmple(b).all())
        };
        let kept: Vec<usize> = (0..lo.len()).filter(|&f| keep(f)).collect();
        let (mut a, mut b) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        let mut side = 0.0;
        for &f in &kept {
            a = a.min(lo[f]);
            b = b.max(hi[f]);
            side += (hi[f] - lo[f]).max_element();
        }
        if let Some((wa, wb)) = window {
            a = a.max(wa);
            b = b.min(wb);
        }
        if kept.is_empty() || !(b.x > a.x && b.y > a.y) {
            return Bins {
                origin: DVec2::ZERO,
                cell: 1.0,
                nx: 0,
                ny: 0,
                start: vec![0],
                items: Vec::new(),
            };
        }
        // Cells about a facet's size, at most about 4 million.
        let span = b - a;
        let mut cell = (side / kept.len() as f64).max(1e-12 * span.max_element());
        cell = cell.max((span.x * span.y / 4e6).sqrt());
        let nx = ((span.x / cell).ceil() as usize).max(1);
        let ny = ((span.y / cell).ceil() as usize).max(1);
        let range = |f: usize| {
            let i0 = (((lo[f].x - a.x) / cell).floor().max(0.0) as usize).min(nx - 1);
            let i1 = (((hi[f].x - a.x) / cell).floor().max(0.0) as usize).min(nx - 1);
            let j0 = (((lo[f].y - a.y) / cell).floor().max(0.0) as usize).min(ny - 1);
            let j1 = (((hi[f].y - a.y) / cell).floor().max(0.0) as usize).min(ny - 1);
            (i0, i1, j0, j1)
        };
        let mut count = vec![0u32; nx * ny + 1];
        for &f in &kept {
            let (i0, i1, j0, j1) = range(f);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    count[j * nx + i + 1] += 1;
                }
            }
        }
        for k in 1..count.len() {
            count[k] += count[k - 1];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; count[nx * ny] as usize];
        for &f in &kept {
            let (i0, i1, j0, j1) = range(f);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    items[fill[j * nx + i] as usize] = f as u32;
                    fill[j * nx + i] += 1;
                }
            }
        }
        Bins {
            origin: a,
            cell,
            nx,
            ny,
            start: count,
            items,
        }
    }

    /// The facets binned in the cells the box `[lo, hi]` reaches, each once (in the cells'
    /// order: the same every time), `seen` marking them.
    fn candidates(&self, lo: DVec2, hi: DVec2, out: &mut Vec<u32>, seen: &mut Seen) {
        out.clear();
        seen.next();
        if self.nx == 0 {
            return;
        }
        let cell =
            |x: f64, o: f64, n: usize| (((x - o) / self.cell).floor().max(0.0) as usize).min(n - 1);
        let (i0, i1) = (
            cell(lo.x, self.origin.x, self.nx),
            cell(hi.x, self.origin.x, self.nx),
        );
        let (j0, j1) = (
            cell(lo.y, self.origin.y, self.ny),
            cell(hi.y, self.origin.y, self.ny),
        );
        for j in j0..=j1 {
            for i in i0..=i1 {
                let k = j * self.nx + i;
                let items = &self.items[self.start[k] as usize..self.start[k + 1] as usize];
                out.extend(items.iter().filter(|&&f| seen.first(f)));
            }
        }
    }
}

/// Per-thread buffers.
#[derive(Default)]
struct Scratch {
    candidates: Vec<u32>,
    seen: Seen,
    tmp: Vec<DVec2>,
}

/// Which facets a search has met: a stamp per facet, the search's own.
#[derive(Default)]
struct Seen {
    stamp: Vec<u32>,
    now: u32,
}

impl Seen {
    fn next(&mut self) {
        self.now = self.now.wrapping_add(1);
        if self.now == 0 {
            self.stamp.fill(0);
            self.now = 1;
        }
    }

    /// Whether facet `f` is met for the first time in this search (and marks it).
    #[inline]
    fn first(&mut self, f: u32) -> bool {
        let f = f as usize;
        if f >= self.stamp.len() {
            self.stamp.resize(f + 1, 0);
        }
        let new = self.stamp[f] != self.now;
        self.stamp[f] = self.now;
        new
    }
}

#[inline]
fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// The area of a polygon (positive counter-clockwise).
fn area(p: &[DVec2]) -> f64 {
    if p.len() < 3 {
        return 0.0;
    }
    let mut s = 0.0;
    for k in 0..p.len() {
        s += cross(p[k], p[(k + 1) % p.len()]);
    }
    0.5 * s
}

/// `poly` clipped to where `side >= 0` (Sutherland-Hodgman against one line), into `out`.
fn clip(poly: &[DVec2], side: impl Fn(DVec2) -> f64, out: &mut Vec<DVec2>) {
    out.clear();
    let n = poly.len();
    for k in 0..n {
        let (p, q) = (poly[k], poly[(k + 1) % n]);
        let (sp, sq) = (side(p), side(q));
        if sp >= 0.0 {
            out.push(p);
        }
        if (sp >= 0.0) != (sq >= 0.0) {
            out.push(p + (q - p) * (sp / (sp - sq)));
        }
    }
}

/// The left side of the directed line through `a` and `b`.
#[inline]
fn left_of(a: DVec2, b: DVec2) -> impl Fn(DVec2) -> f64 {
    move |x| cross(b - a, x - a)
}

/// The intersection of the triangle `t` and the convex polygon `p` (counter-clockwise).
fn intersect(t: &[DVec2; 3], p: &[DVec2], tmp: &mut Vec<DVec2>) -> Poly {
    let mut cur: Poly = t.to_vec();
    for k in 0..p.len() {
        clip(&cur, left_of(p[k], p[(k + 1) % p.len()]), tmp);
        std::mem::swap(&mut cur, tmp);
        if cur.len() < 3 {
            return Vec::new();
        }
    }
    cur
}

/// Removes the convex polygon `c` (counter-clockwise) from every piece of `pieces`: each
/// piece `P` becomes `P \ c` as convex pieces, `P` cut by each edge of `c` in turn (the part
/// outside the edge is kept, the part inside goes on to the next edge).
fn subtract(pieces: &mut Vec<Poly>, c: &[DVec2], min_area: f64, tmp: &mut Vec<DVec2>) {
    let (clo, chi) = bounds(c);
    // An edge much shorter than the polygon (a clipped corner, a vertex repeated where it
    // lay on a clipping line) gives no line to cut by: it is passed over, which removes a
    // sliver more than `c` of at most its length times the polygon's size.
    let short = (1e-10 * (chi - clo).max_element()).powi(2);
    let mut k = 0;
    let end = pieces.len();
    let mut kept = Vec::new();
    while k < end {
        let p = std::mem::take(&mut pieces[k]);
        k += 1;
        let (plo, phi) = bounds(&p);
        if phi.x <= clo.x || plo.x >= chi.x || phi.y <= clo.y || plo.y >= chi.y {
            kept.push(p);
            continue;
        }
        let mut rest = p;
        for e in 0..c.len() {
            let (a, b) = (c[e], c[(e + 1) % c.len()]);
            if (b - a).length_squared() <= short {
                continue;
            }
            // Outside the edge: its right side.
            clip(&rest, left_of(b, a), tmp);
            if area(tmp) > min_area {
                kept.push(tmp.clone());
            }
            clip(&rest, left_of(a, b), tmp);
            std::mem::swap(&mut rest, tmp);
            if area(&rest) <= min_area {
                break;
            }
        }
    }
    *pieces = kept;
}

fn bounds(p: &[DVec2]) -> (DVec2, DVec2) {
    p.iter().fold(
        (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
        |(a, b), &x| (a.min(x), b.max(x)),
    )
}

/// The 7-point rule of degree 5 on a triangle (Radon): barycentric nodes and weights (tested
/// against a fine sum below).
pub fn rule7() -> [([f64; 3], f64); 7] {
    let r = 15f64.sqrt();
    let (a, b) = ((6.0 - r) / 21.0, (6.0 + r) / 21.0);
    let (wa, wb) = ((155.0 - r) / 1200.0, (155.0 + r) / 1200.0);
    [
        ([1.0 / 3.0; 3], 9.0 / 40.0),
        ([a, a, 1.0 - 2.0 * a], wa),
        ([a, 1.0 - 2.0 * a, a], wa),
        ([1.0 - 2.0 * a, a, a], wa),
        ([b, b, 1.0 - 2.0 * b], wb),
        ([b, 1.0 - 2.0 * b, b], wb),
        ([1.0 - 2.0 * b, b, b], wb),
    ]
}

/// The 3-point rule of degree 2 on a triangle.
const RULE3: [([f64; 3], f64); 3] = [
    ([2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0], 1.0 / 3.0),
    ([1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0], 1.0 / 3.0),
    ([1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0], 1.0 / 3.0),
];

/// The light of facet `f` (direct, unshadowed: [`Tracer::facet_light`]) at pixel position `x`.
#[inline]
fn light(tracer: &Tracer, f: u32, x: DVec2) -> f64 {
    tracer
        .facet_light(x.x, x.y, f)
        .map_or(0.0, |(direct, _)| direct.max(0.0))
}

/// A triangle rule: barycentric nodes and weights (summing to 1).
type Rule = [([f64; 3], f64)];

/// The centroid rule, of degree 1.
const RULE1: [([f64; 3], f64); 1] = [([1.0 / 3.0; 3], 1.0)];

/// The light of facet `f` integrated over the convex polygon `cut` [px] by the rule `kept` on
/// the triangles of a fan, and the departure of the rule `lower` from it (the estimate): the
/// reference takes the 7-point rule and the 3-point one (10 evaluations a triangle), a frame's
/// facets that no element serves (the opposition surge's cusp, the Sun grazing the facet's
/// plane) the 3-point rule and the centroid (4).
fn integrate(tracer: &Tracer, f: u32, cut: &[DVec2], kept: &Rule, lower: &Rule) -> (f64, f64) {
    let (mut i, mut i_lower) = (0.0, 0.0);
    for k in 1..cut.len() - 1 {
        let (a, b, c) = (cut[0], cut[k], cut[k + 1]);
        let at = 0.5 * cross(b - a, c - a);
        if at <= 0.0 {
            continue;
        }
        let by = |rule: &Rule| {
            rule.iter()
                .map(|&(l, w)| w * light(tracer, f, a * l[0] + b * l[1] + c * l[2]))
                .sum::<f64>()
        };
        i += at * by(kept);
        i_lower += at * by(lower);
    }
    (i, (i - i_lower).abs())
}

/// A facet's light as the quadratic Lagrange element over its image (the projected corners
/// and the midpoints of the projected edges), as [`super::facet_light`] reads it for the
/// sampled frame: a flat facet's light varies smoothly over its image. Kept where it
/// reproduces the light at two more points (the centroid and `(1/2, 1/4, 1/4)`) within
/// [`ELEMENT_TOLERANCE`] of its brightest node; twice that tolerance, per px^2, is the
/// error estimate of every cut read from it. (The misses at the check points themselves fell
/// short of the pixels' errors: at a tolerance of 1e-6, over 50 frames around Bennu, the
/// worst frame's p99 measured 1.17 times the tolerance. Twice it bounded every frame there.)
struct Element {
    a: DVec2,
    e1: DVec2,
    e2: DVec2,
    inv: f64,
    /// Corners 0, 1, 2, then the midpoints of edges 12, 20, 01.
    nodes: [f64; 6],
}

/// The largest miss of the element at its check points, as a fraction of its brightest node.
const ELEMENT_TOLERANCE: f64 = 1e-5;

impl Element {
    /// The element of facet `f` whose image is `tri` [px], with its error bound [(P/L) per
    /// px^2]; `None` where it does not hold.
    fn new(tracer: &Tracer, f: u32, tri: &[DVec2; 3]) -> Option<(Element, f64)> {
        let [a, b, c] = *tri;
        let s = cross(b - a, c - a);
        if s <= 0.0 {
            return None;
        }
        let at = |x: DVec2| light(tracer, f, x);
        let nodes = [
            at(a),
            at(b),
            at(c),
            at(0.5 * (b + c)),
            at(0.5 * (c + a)),
            at(0.5 * (a + b)),
        ];
        let el = Element {
            a,
            e1: b - a,
            e2: c - a,
            inv: 1.0 / s,
            nodes,
        };
        let top = nodes.iter().copied().fold(0.0, f64::max);
        let mut miss: f64 = 0.0;
        for l in [[1.0 / 3.0; 3], [0.5, 0.25, 0.25]] {
            let x = a * l[0] + b * l[1] + c * l[2];
            miss = miss.max((el.at(x) - at(x)).abs());
        }
        (miss <= ELEMENT_TOLERANCE * top).then_some((el, 2.0 * ELEMENT_TOLERANCE * top))
    }

    /// The element's value at `x` [px].
    #[inline]
    fn at(&self, x: DVec2) -> f64 {
        let d = x - self.a;
        let l1 = cross(d, self.e2) * self.inv;
        let l2 = cross(self.e1, d) * self.inv;
        let l0 = 1.0 - l1 - l2;
        let n = &self.nodes;
        n[0] * l0 * (2.0 * l0 - 1.0)
            + n[1] * l1 * (2.0 * l1 - 1.0)
            + n[2] * l2 * (2.0 * l2 - 1.0)
            + 4.0 * (n[3] * l1 * l2 + n[4] * l2 * l0 + n[5] * l0 * l1)
    }

    /// The element integrated over the convex polygon `cut` [px]: on each triangle of a fan,
    /// its area times the mean of the element at the edges' midpoints (exact for a quadratic).
    fn integral(&self, cut: &[DVec2]) -> f64 {
        let mut sum = 0.0;
        for k in 1..cut.len() - 1 {
            let (a, b, c) = (cut[0], cut[k], cut[k + 1]);
            let at = 0.5 * cross(b - a, c - a);
            if at > 0.0 {
                sum += at / 3.0
                    * (self.at(0.5 * (a + b)) + self.at(0.5 * (b + c)) + self.at(0.5 * (c + a)));
            }
        }
        sum
    }
}

/// What one facet adds to the image: `(pixel, (P/L) [sr m^2], estimated error)` per cut, its
/// quadrature nodes, and whether its pieces ran past [`MAX_PIECES`].
struct FacetShare {
    cuts: Vec<(u32, f64, f64)>,
    nodes: u64,
    unconverged: bool,
}

/// How a cut's light is integrated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LightRule {
    /// The 7-point rule on the light itself, the 3-point rule beside it for the estimate.
    Exact,
    /// The facet's quadratic element ([`Element`]) where it holds, else the 3-point rule on
    /// the light, the centroid beside it for the estimate.
    Element,
}

/// A clipped image: `(P/L)` and each pixel's estimated error [sr m^2], the range at each
/// pixel's centre (when asked), the light's evaluations, the cuts and the facets whose pieces
/// ran past [`MAX_PIECES`].
struct Clipped {
    pl: Vec<f64>,
    error_pl: Vec<f64>,
    depth: Option<Vec<f64>>,
    nodes: u64,
    cuts: u64,
    unconverged: u64,
}

/// Per lit pixel (above a thousandth of the 99th percentile), the median, 99th percentile
/// and largest relative error estimate, and the total's.
fn estimate(pl: &[f64], error_pl: &[f64]) -> [f64; 4] {
    let total: f64 = pl.iter().sum();
    let floor = {
        let mut lit: Vec<f64> = pl.iter().copied().filter(|&x| x > 0.0).collect();
        if lit.is_empty() {
            f64::MIN_POSITIVE
        } else {
            1e-3 * crate::stats::selected_quantiles(&mut lit, [0.99])[0]
        }
    };
    let [median, p99, max] = super::reference::relative_quantiles(pl, error_pl, floor);
    let total_rel = if total > 0.0 {
        error_pl.iter().sum::<f64>() / total
    } else {
        0.0
    };
    [median, p99, max, total_rel]
}

/// The reference through the camera's own intrinsics.
fn render_camera(scene: &Scene, pose: &Pose) -> Result<ReferenceFrame, RenderError> {
    let t0 = Instant::now();
    let c = clipped(scene, pose, LightRule::Exact, true)?;
    let intr = &scene.camera.intrinsics;
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let [median, p99, max, est_total] = estimate(&c.pl, &c.error_pl);
    let seconds = t0.elapsed().as_secs_f64();
    let report = ReferenceReport {
        method: "exact",
        settings: None,
        rays: c.nodes + (w * h) as u64,
        cells: c.cuts,
        unconverged_cells: c.unconverged,
        unconverged_px: 0,
        est_error_total: est_total,
        est_error_median: median,
        est_error_p99: p99,
        est_error_max: max,
        signed_error_total: est_total,
        signed_error_p99: p99,
        seconds,
    };
    Ok(ReferenceFrame {
        frame: super::reference::reference_frame(pose, (w, h), c.pl, c.depth, seconds),
        error_pl: c.error_pl,
        report,
    })
}

/// A mesh frame clipped exactly (`render.raycast_clip`, [`crate::render::Renderer`]): as the
/// reference, but each facet's light read from its quadratic element where that holds, and
/// the frame's own error estimate (the elements' and the rule's) in its stats, infinite where
/// a facet's pieces ran past [`MAX_PIECES`] (so that a budget's plan says it is not met). One band's
/// image: the caller gives each band with a map of its own its frame.
pub fn render_frame(
    scene: &Scene,
    pose: &Pose,
    settings: &crate::render::Settings,
) -> Result<Frame, RenderError> {
    let t0 = Instant::now();
    applies(scene, pose).map_err(|e| RenderError::BadSettings {
        field: "raycast_clip",
        value: "true".into(),
        allowed: e.0,
    })?;
    let c = clipped(scene, pose, LightRule::Element, settings.depth)?;
    let intr = &scene.camera.intrinsics;
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let total: f64 = c.pl.iter().sum();
    let [mut median, mut p99, _, mut est_total] = estimate(&c.pl, &c.error_pl);
    if c.unconverged > 0 {
        // A facet whose pieces ran past MAX_PIECES kept light that facets nearer the Sun or
        // the camera may hide: the frame cannot say how far it is off, and says so.
        (median, p99, est_total) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let stats = FrameStats {
        phase_deg: super::reference::phase_deg(pose),
        surface_samples: c.nodes as usize,
        total_pl_points: total,
        total_pl_image: total,
        total_pl_gridded: total,
        timings_ms: StageTimings {
            integration: ms,
            total: ms,
            ..Default::default()
        },
        estimated_error: Some(crate::raycast::estimate::FrameEstimate {
            median,
            p99,
            total: est_total,
        }),
        ..Default::default()
    };
    Ok(Frame {
        width: w,
        height: h,
        pl: c.pl,
        band_pl: Vec::new(),
        depth_m: c.depth,
        stats,
    })
}

/// The lit and seen part of every facet, cut by the pixels and integrated by `rule`.
fn clipped(
    scene: &Scene,
    pose: &Pose,
    rule: LightRule,
    with_depth: bool,
) -> Result<Clipped, RenderError> {
    let Shape::Mesh(m) = &scene.body.shape else {
        return Err(RenderError::BadSettings {
            field: "reference",
            value: "exact".into(),
            allowed: "a mesh body",
        });
    };
    let intr = &scene.camera.intrinsics;
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let tracer = Tracer::new(scene, pose);
    let camera = pose.camera_position_m;
    let camera_from_body = DMat3::from_quat(pose.body_from_camera).transpose();
    let s = pose.sun_position_m.normalize();
    let e1 = s.any_orthonormal_vector();
    let e2 = s.cross(e1);
    // Depths closer than about a billionth of the body's size are taken as equal (in the
    // camera's view, that length at the farthest vertex, in `1 / z`).
    let tol = 1e-9 * m.bounding_radius_m();
    let z_far = m
        .vertices_m()
        .iter()
        .map(|v| (camera_from_body * (*v - camera)).z)
        .fold(0.0, f64::max);
    let tol_cam = tol / (z_far * z_far);

    // What may hide a facet: on a closed surface only the facets facing the viewer (a line
    // from a point of the surface to the Sun, or to the camera, that the body blocks leaves
    // it through a facet facing the Sun, or enters it through one facing the camera, farther
    // along that line); on an open one, every facet.
    let closed = m.report().open_edges == 0;
    let facing = |f: usize, eye: DVec3, at_infinity: bool| {
        let n = m.normals()[f];
        let corner = m.vertices_m()[m.facets()[f][0] as usize];
        !closed
            || if at_infinity {
                n.dot(eye) > 0.0
            } else {
                n.dot(eye - corner) > 0.0
            }
    };
    // The view from the Sun: depth along s (larger is sunward).
    let sun = View::new(
        m,
        |v| (DVec2::new(v.dot(e1), v.dot(e2)), v.dot(s)),
        None,
        |f| facing(f, s, true),
    );
    // The camera's view [px]: depth is `1 / z` (larger is nearer), which, unlike `z`, is
    // affine in the image plane.
    let to_px = |v: DVec3| {
        let c = camera_from_body * (v - camera);
        let [u, vv] = intr.project(c.x, c.y, c.z);
        (DVec2::new(u, vv), c)
    };
    let image = (DVec2::ZERO, DVec2::new(w as f64, h as f64));
    let cam = View::new(
        m,
        |v| {
            let (p, c) = to_px(v);
            (p, 1.0 / c.z)
        },
        Some(image),
        |f| facing(f, camera, false),
    );
    let r7 = rule7();

    let shares: Vec<FacetShare> = (0..m.facets().len())
        .into_par_iter()
        .map_init(Scratch::default, |scratch, f| {
            let mut share = FacetShare {
                cuts: Vec::new(),
                nodes: 0,
                unconverged: false,
            };
            let normal = m.normals()[f];
            let corner = m.vertices_m()[m.facets()[f][0] as usize];
            // Faces away from the camera or the Sun, or lies outside the image: no light.
            if normal.dot(camera - corner) <= 0.0
                || normal.dot(s) <= 0.0
                || cam.area2[f] <= 0.0
                || cam.hi[f].cmple(image.0).any()
                || cam.lo[f].cmpge(image.1).any()
            {
                return share;
            }
            // 1. The lit part, in the Sun's view (a frame, not the reference, takes the word of
            // the Sun's grid, [`super::sun_grid`], for the facets lit all over).
            let mut pieces: Vec<Poly> = vec![sun.tris[f].to_vec()];
            let lit_all_over = rule == LightRule::Element && tracer.lit_all_over_or_unlit(f as u32);
            if !lit_all_over && !sun.hide(f, &mut pieces, tol, scratch) {
                share.unconverged = true;
            }
            // 2. Onto the facet's plane, into the image, and what nearer facets hide.
            let plane = normal.dot(corner);
            let lift = |x: DVec2| {
                let q = e1 * x.x + e2 * x.y;
                q + s * ((plane - normal.dot(q)) / normal.dot(s))
            };
            let mut seen: Vec<Poly> = pieces
                .iter()
                .map(|p| {
                    let mut q: Poly = p.iter().map(|&x| to_px(lift(x)).0).collect();
                    if area(&q) < 0.0 {
                        q.reverse();
                    }
                    q
                })
                .filter(|q| area(q) > 0.0)
                .collect();
            if !cam.hide(f, &mut seen, tol_cam, scratch) {
                share.unconverged = true;
            }
            // 3. Cut by the pixels, integrated: by the rule on the light itself, or on the
            // facet's quadratic element where it holds.
            let element = match rule {
                LightRule::Exact => None,
                LightRule::Element if seen.is_empty() => None,
                LightRule::Element => {
                    share.nodes += 8;
                    Element::new(&tracer, f as u32, &cam.tris[f])
                }
            };
            let mut strip = Vec::new();
            let mut cell = Vec::new();
            for q in &seen {
                let (lo, hi) = bounds(q);
                let j0 = lo.y.floor().max(0.0) as usize;
                let j1 = (hi.y.ceil().min(h as f64) as usize).min(h);
                for j in j0..j1 {
                    let (top, bottom) = (j as f64, j as f64 + 1.0);
                    clip(q, |x| x.y - top, &mut scratch.tmp);
                    clip(&scratch.tmp, |x| bottom - x.y, &mut strip);
                    if strip.len() < 3 {
                        continue;
                    }
                    let (slo, shi) = bounds(&strip);
                    let i0 = slo.x.floor().max(0.0) as usize;
                    let i1 = (shi.x.ceil().min(w as f64) as usize).min(w);
                    for i in i0..i1 {
                        let (left, right) = (i as f64, i as f64 + 1.0);
                        clip(&strip, |x| x.x - left, &mut scratch.tmp);
                        clip(&scratch.tmp, |x| right - x.x, &mut cell);
                        if area(&cell) <= 0.0 {
                            continue;
                        }
                        let (v, e) = match &element {
                            Some((el, d)) => {
                                let v = el.integral(&cell);
                                (v, d * area(&cell))
                            }
                            None if rule == LightRule::Exact => {
                                share.nodes += 10 * (cell.len() as u64 - 2);
                                integrate(&tracer, f as u32, &cell, &r7, &RULE3)
                            }
                            None => {
                                share.nodes += 4 * (cell.len() as u64 - 2);
                                integrate(&tracer, f as u32, &cell, &RULE3, &RULE1)
                            }
                        };
                        share.cuts.push(((j * w + i) as u32, v, e));
                    }
                }
            }
            share
        })
        .collect();

    let mut pl = vec![0.0; w * h];
    let mut error_pl = vec![0.0; w * h];
    let (mut nodes, mut cuts, mut unconverged) = (0u64, 0u64, 0u64);
    for share in &shares {
        for &(p, v, e) in &share.cuts {
            pl[p as usize] += v;
            error_pl[p as usize] += e;
        }
        nodes += share.nodes;
        cuts += share.cuts.len() as u64;
        unconverged += u64::from(share.unconverged);
    }
    let total: f64 = pl.iter().sum();
    if !total.is_finite() {
        return Err(RenderError::NonFinite {
            stage: "clipped mesh frame",
            value: total,
        });
    }
    // The range at each pixel's centre (the depth image), by a ray.
    let depth = with_depth.then(|| {
        (0..w * h)
            .into_par_iter()
            .map(|p| {
                tracer
                    .cast((p % w) as f64 + 0.5, (p / w) as f64 + 0.5)
                    .range_m
            })
            .collect()
    });
    Ok(Clipped {
        pl,
        error_pl,
        depth,
        nodes,
        cuts,
        unconverged,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x0: f64, y0: f64, s: f64) -> Poly {
        vec![
            DVec2::new(x0, y0),
            DVec2::new(x0 + s, y0),
            DVec2::new(x0 + s, y0 + s),
            DVec2::new(x0, y0 + s),
        ]
    }

    #[test]
    fn a_hole_cut_from_a_square_leaves_its_area_in_convex_pieces() {
        let mut pieces = vec![square(0.0, 0.0, 4.0)];
        let mut tmp = Vec::new();
        subtract(&mut pieces, &square(1.0, 1.0, 1.0), 1e-15, &mut tmp);
        let a: f64 = pieces.iter().map(|p| area(p)).sum();
        assert!((a - 15.0).abs() < 1e-12, "{a}");
        assert!(pieces.iter().all(|p| area(p) > 0.0));
        // A second, overlapping hole and one outside.
        subtract(&mut pieces, &square(1.5, 1.5, 1.0), 1e-15, &mut tmp);
        subtract(&mut pieces, &square(10.0, 10.0, 1.0), 1e-15, &mut tmp);
        let a: f64 = pieces.iter().map(|p| area(p)).sum();
        assert!((a - (16.0 - 1.75)).abs() < 1e-12, "{a}");
        // Covered whole.
        subtract(&mut pieces, &square(-1.0, -1.0, 6.0), 1e-15, &mut tmp);
        assert!(pieces.is_empty());
    }

    #[test]
    fn a_hole_with_repeated_corners_cuts_only_itself() {
        // Clipping leaves a corner twice where it lay on a clipping line: the zero-length
        // edge must not keep the whole piece as "outside" it (Bennu's lit area came out up to
        // six times its facets' before this was handled).
        let mut pieces = vec![square(0.0, 0.0, 4.0)];
        let mut tmp = Vec::new();
        let mut hole = square(1.0, 1.0, 1.0);
        hole.insert(1, hole[0]);
        hole.push(hole[4]);
        subtract(&mut pieces, &hole, 1e-15, &mut tmp);
        let a: f64 = pieces.iter().map(|p| area(p)).sum();
        assert!((a - 15.0).abs() < 1e-12, "{a}");
    }

    /// The lit part of each of Bennu's facets at 131 deg of phase against the share of 210
    /// points on it whose shadow ray ([`Mesh::shadows`], the BVH) reaches the Sun.
    #[test]
    fn the_lit_part_of_bennus_facets_is_what_shadow_rays_find() {
        let m = Mesh::load(
            std::path::Path::new("../shared/shapes/bennu_12k.obj"),
            1000.0,
            DMat3::IDENTITY,
        )
        .unwrap();
        let s = DVec3::new(-1.1e11, 1.26e11, 0.0).normalize();
        let e1 = s.any_orthonormal_vector();
        let e2 = s.cross(e1);
        let sun = View::new(
            &m,
            |v| (DVec2::new(v.dot(e1), v.dot(e2)), v.dot(s)),
            None,
            |_| true,
        );
        let mut scratch = Scratch::default();
        let (mut worst, mut exact, mut rays, mut partly) = (0.0f64, 0.0, 0.0, 0);
        for f in 0..m.facets().len() {
            let n = m.normals()[f];
            if n.dot(s) <= 0.0 {
                continue;
            }
            let mut pieces: Vec<Poly> = vec![sun.tris[f].to_vec()];
            assert!(sun.hide(f, &mut pieces, 1e-6, &mut scratch));
            let lit = pieces.iter().map(|p| area(p)).sum::<f64>() / (0.5 * sun.area2[f]);
            let [a, b, c] = m.facets()[f].map(|k| m.vertices_m()[k as usize]);
            let k = 20;
            let (mut seen, mut all) = (0, 0);
            for i in 0..k {
                for j in 0..k - i {
                    let (u, v) = ((i as f64 + 0.33) / k as f64, (j as f64 + 0.33) / k as f64);
                    all += 1;
                    seen += usize::from(!m.shadows(a + (b - a) * u + (c - a) * v, n, s));
                }
            }
            let sampled = seen as f64 / all as f64;
            let weight = m.areas_m2()[f] * n.dot(s);
            exact += lit * weight;
            rays += sampled * weight;
            worst = worst.max((lit - sampled).abs());
            partly += usize::from(lit > 0.01 && lit < 0.99);
        }
        // Measured: worst facet 0.028 (the points' spacing across a shadow's edge), the lit
        // power 4.5e-5 apart, 296 facets partly lit.
        eprintln!("worst {worst}, lit power {exact} / {rays}, {partly} partly lit");
        assert!(worst < 0.05 && partly > 200, "{worst} {partly}");
        assert!((exact / rays - 1.0).abs() < 2e-4, "{exact} {rays}");
    }

    #[test]
    fn the_triangle_rules_integrate_their_degrees_exactly() {
        let (a, b, c) = (
            DVec2::new(0.3, 0.1),
            DVec2::new(2.0, 0.4),
            DVec2::new(0.7, 1.9),
        );
        let at = 0.5 * cross(b - a, c - a);
        let node = |l: [f64; 3]| a * l[0] + b * l[1] + c * l[2];
        // x^5 + x^2 y^3 against a fine midpoint sum over the triangle.
        let f = |x: DVec2| x.x.powi(5) + x.x * x.x * x.y.powi(3);
        let i7 = at * rule7().iter().map(|&(l, wt)| wt * f(node(l))).sum::<f64>();
        let n = 2000;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n - i {
                // Two sub-triangles per cell, by their centroids (second order).
                let (u, v) = (
                    (i as f64 + 1.0 / 3.0) / n as f64,
                    (j as f64 + 1.0 / 3.0) / n as f64,
                );
                sum += f(node([1.0 - u - v, u, v]));
                if i + j + 1 < n {
                    let (u, v) = (
                        (i as f64 + 2.0 / 3.0) / n as f64,
                        (j as f64 + 2.0 / 3.0) / n as f64,
                    );
                    sum += f(node([1.0 - u - v, u, v]));
                }
            }
        }
        let fine = sum * at / (n * n) as f64;
        assert!(((i7 - fine) / fine).abs() < 1e-5, "{i7} {fine}");
        // Degree 2 exactly by both.
        let g = |x: DVec2| 1.0 + x.x * x.y - 2.0 * x.y * x.y;
        let i7 = at * rule7().iter().map(|&(l, wt)| wt * g(node(l))).sum::<f64>();
        let i3 = at * RULE3.iter().map(|&(l, wt)| wt * g(node(l))).sum::<f64>();
        assert!((i7 - i3).abs() < 1e-13 * i7.abs(), "{i7} {i3}");
    }
}
